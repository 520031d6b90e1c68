"""The lane framework every compiled step of stcgym is written in.

:mod:`.compiled` -- the lane-function convention: the ``@lane`` / ``@lanes`` decorators, named
lane state (``lane_state``), the compiled-type cache of a call (``FixedTypes``);
:mod:`.numba_internals` -- the only module that touches numba's internals;
:mod:`.kernel_cache` -- where the compiled kernels are cached and why an edit never runs stale
code; :mod:`.linalg` -- small dense linear algebra and copies written out for lane functions;
:mod:`.validation` -- the checks of user input shared by :mod:`stcgym.envs` and
:mod:`stcgym.adaptive` (a ``ValueError`` naming the parameter).

The plants (:mod:`stcgym.envs`) and the estimators and controllers (:mod:`stcgym.adaptive`)
both import it; it imports neither.
"""
