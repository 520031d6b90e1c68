"""Multivariable identification and control of measured-state plants: the ``[A B]``
estimator, matrix RLS, the multi-input LQ design and the multivariable self-tuning
controller with its LQR oracle."""
