"""Joint state/parameter estimators and the self-tuning controller.

Recursive estimators of Ding & Ma (2014) (``make_estimator``: O-/KF-/CO- x SG, MISG, RLS, MILS,
plain or model-decomposition D-), iterative batch estimators (``fit_iterative``: GI, LSI, D-GI,
D-LSI with an observer or a Kalman filter), multichannel estimators (``MatrixRLS``,
``StateMatrixEstimator``), closed-form pole placement, the self-tuning pole-placement controller
and the known-model oracles, all behind one SB3-style policy protocol; batched (``num_envs``)
versions of the estimators and the controller for many plants, compiled lane functions whose
single plant equals its lane of a batch bit for bit.
"""

from __future__ import annotations

from stcgym.adaptive.control.controller import SelfTuningController
from stcgym.adaptive.control.options import (
    ChangeDetection,
    EstimatorOptions,
    LawOptions,
    SafeSet,
    StartupOptions,
)
from stcgym.adaptive.control.oracles import KalmanObserver, KnownModelController, LQGController
from stcgym.adaptive.control.placement import (
    UncontrollableError,
    ackermann,
    augment_integral,
    lq_gain,
    place_poles,
)
from stcgym.adaptive.estimation import estimator_spec as _spec
from stcgym.adaptive.estimation import flops
from stcgym.adaptive.estimation import iterative as _iterative
from stcgym.adaptive.estimation.estimator_spec import EstimatorSettings, EstimatorSpec, parse_name
from stcgym.adaptive.estimation.factory import make_estimator
from stcgym.adaptive.estimation.health import NumericalHealthError
from stcgym.adaptive.estimation.iterative import IterativeResult, fit_iterative
from stcgym.adaptive.estimation.recursive import RecursiveEstimator
from stcgym.adaptive.multivariable.controller import MultivariableSelfTuningController
from stcgym.adaptive.multivariable.lqr import LQRController
from stcgym.adaptive.multivariable.multichannel import MatrixRLS, StateMatrixEstimator
from stcgym.adaptive.policy import Policy, reset_policy
from stcgym.adaptive.regression.greybox import (
    AffineStateSpace,
    GreyBoxRegression,
    NotLinearInParameters,
)
from stcgym.adaptive.regression.rls import RecursiveLeastSquares

# The public data names are bound here with their doc comments: the API reference reads a data
# name's text from the module that exports it.

#: The 16 recursive estimators of Ding & Ma (2014) by name, ``<state>-[D-]<rule>``: state
#: estimator ``O`` (open-loop observer) or ``KF`` (Kalman filter), ``D-`` for model
#: decomposition, rule ``SG``, ``MISG``, ``RLS`` or ``MILS``. :func:`make_estimator` also accepts
#: the closed-loop observer variants ``CO-...``.
ALGORITHMS: tuple[str, ...] = _spec.ALGORITHMS

#: The 8 iterative (batch) estimators of Ding & Ma (2014), section 5, by name, for
#: :func:`fit_iterative`: ``O`` or ``KF`` state re-estimation, ``D-`` for model decomposition,
#: rule ``GI`` (gradient) or ``LSI`` (least squares).
ITERATIVE_NAMES: tuple[str, ...] = _iterative.ITERATIVE_NAMES

__all__ = [
    "ALGORITHMS",
    "ChangeDetection",
    "EstimatorOptions",
    "LawOptions",
    "SafeSet",
    "StartupOptions",
    "AffineStateSpace",
    "GreyBoxRegression",
    "NotLinearInParameters",
    "RecursiveLeastSquares",
    "EstimatorSettings",
    "EstimatorSpec",
    "ITERATIVE_NAMES",
    "IterativeResult",
    "KalmanObserver",
    "KnownModelController",
    "LQGController",
    "LQRController",
    "MatrixRLS",
    "NumericalHealthError",
    "Policy",
    "RecursiveEstimator",
    "SelfTuningController",
    "MultivariableSelfTuningController",
    "StateMatrixEstimator",
    "UncontrollableError",
    "ackermann",
    "augment_integral",
    "fit_iterative",
    "flops",
    "make_estimator",
    "parse_name",
    "lq_gain",
    "place_poles",
    "reset_policy",
]
