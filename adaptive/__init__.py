"""Joint state/parameter estimators and the self-tuning controller.

Recursive estimators of Ding & Ma (2014) (``make_estimator``: O-/KF-/CO- x SG, MISG, RLS, MILS,
plain or model-decomposition D-), iterative batch estimators (``fit_iterative``: GI, LSI, D-GI,
D-LSI with an observer or a Kalman filter), multichannel estimators (``MatrixRLS``,
``StateMatrixEstimator``), closed-form pole placement, the self-tuning pole-placement controller
and the known-model oracles, all behind one SB3-style policy protocol; batched (``num_envs``)
versions of the estimators and the controller for many plants at numpy speed.
"""

from __future__ import annotations

from stcgym.adaptive import flops
from stcgym.adaptive.batched import BatchedSelfTuningController, FastLoop, make_batched_estimator
from stcgym.adaptive.controller import SelfTuningController, TrackingLaw
from stcgym.adaptive.iterative import ITERATIVE_NAMES, IterativeResult, fit_iterative
from stcgym.adaptive.multichannel import MatrixRLS, StateMatrixEstimator
from stcgym.adaptive.oracles import KalmanObserver, KnownModelController, LQGController
from stcgym.adaptive.placement import (
    UncontrollableError,
    ackermann,
    augment_integral,
    place_poles,
)
from stcgym.adaptive.policy import Policy, StatefulPolicy, reset_policy
from stcgym.adaptive.recursive import ALGORITHMS, RecursiveEstimator, make_estimator, parse_name
from stcgym.adaptive.rules import NumericalHealthError

__all__ = [
    "ALGORITHMS",
    "BatchedSelfTuningController",
    "FastLoop",
    "ITERATIVE_NAMES",
    "IterativeResult",
    "KalmanObserver",
    "KnownModelController",
    "LQGController",
    "MatrixRLS",
    "NumericalHealthError",
    "Policy",
    "RecursiveEstimator",
    "SelfTuningController",
    "StateMatrixEstimator",
    "StatefulPolicy",
    "TrackingLaw",
    "UncontrollableError",
    "ackermann",
    "augment_integral",
    "fit_iterative",
    "flops",
    "make_batched_estimator",
    "make_estimator",
    "parse_name",
    "place_poles",
    "reset_policy",
]
