"""The joint state/parameter estimators of Ding & Ma (2014): the recursive estimators
(their specification, the compiled step and batch loops, views and health) and the
iterative ones, their flop counts and the dense numpy statement of the paper's algorithms."""
