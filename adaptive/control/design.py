"""Certainty-equivalence design and tracking law: the lane functions, gathered by concept.

Every function works on one plant's small arrays (see :mod:`stcgym.envs.compiled` for the lane
convention: no BLAS/LAPACK, small dense loops written out, status codes instead of
exceptions). The self-tuning controller, the known-model oracles
(:mod:`stcgym.adaptive.control.oracles`) and the public numpy helpers of
:mod:`stcgym.adaptive.control.placement` all call these, for one plant or inside a batch loop over
lanes. Each piece has one home:

* :mod:`.canonical` -- the canonical-form model ``(A, b)`` of ``theta = [a; b]`` and its
  integral augmentation;
* :mod:`.linalg` -- the small dense linear algebra the designs use;
* :mod:`.safe_set` -- the safe set every design passes (status codes, ``safe_set()``), the gain
  it writes on success (``Gain``, ``make_gain``) and the designs' scratch (``DesignWork``,
  ``design_work``);
* :mod:`.pole_placement` -- Ackermann's formula (``place_design``, ``ackermann_gain``);
* :mod:`.lq` -- the one-step and solved LQ designs, the DARE, the steady-state Kalman
  covariance;
* :mod:`.law` -- the tracking law with anti-windup (``track``);
* :mod:`.known_model` -- the oracles' step on a known model;
* :mod:`.state_estimation` -- the Kalman filter (``kalman_step``, ``filtered_state``).

This module re-exports their public names, so ``design.place_design`` and the like keep
working.
"""

from __future__ import annotations

from stcgym.adaptive.control.known_model import (
    OracleProposal,
    OracleState,
    known_model_commit,
    known_model_commit_lanes,
    known_model_propose,
    known_model_propose_lanes,
    make_oracle_state,
)
from stcgym.adaptive.control.law import track
from stcgym.adaptive.control.lq import (
    DEFAULT_LQ_WEIGHTS,
    P_MAX,
    DareWork,
    LQSolveWork,
    LQWeights,
    LQWork,
    dare,
    dare_work,
    kalman_covariance,
    kalman_covariance_lanes,
    lq_design,
    lq_initial_P,
    lq_solve,
    lq_solve_lanes,
    lq_weights,
    lq_work,
)
from stcgym.adaptive.control.pole_placement import (
    ackermann_gain,
    place_design,
    place_design_lanes,
)
from stcgym.adaptive.control.safe_set import (
    B_SMALL,
    DC_RCOND_FLOOR,
    DC_SINGULAR,
    GAIN_LARGE,
    NONFINITE,
    NOT_CONVERGED,
    NOT_STABILISABLE,
    OK,
    RCOND_FLOOR,
    STATUS_NAMES,
    UNCONTROLLABLE,
    DesignConfig,
    DesignWork,
    Gain,
    SafeSetBounds,
    design_work,
    feedback_gain,
    gain_shapes,
    make_gain,
    safe_set,
    steady_state,
)
from stcgym.adaptive.estimation.state_estimation import filtered_state
from stcgym.adaptive.kernels.canonical import (
    OBSERVABILITY,
    OBSERVER,
    model_matrices,
    model_matrices_lanes,
)

__all__ = [
    "B_SMALL",
    "DC_RCOND_FLOOR",
    "DC_SINGULAR",
    "DEFAULT_LQ_WEIGHTS",
    "GAIN_LARGE",
    "NONFINITE",
    "NOT_CONVERGED",
    "NOT_STABILISABLE",
    "OBSERVABILITY",
    "OBSERVER",
    "OK",
    "P_MAX",
    "RCOND_FLOOR",
    "STATUS_NAMES",
    "UNCONTROLLABLE",
    "DesignConfig",
    "DesignWork",
    "DareWork",
    "Gain",
    "LQSolveWork",
    "LQWeights",
    "LQWork",
    "OracleProposal",
    "OracleState",
    "SafeSetBounds",
    "ackermann_gain",
    "dare",
    "design_work",
    "dare_work",
    "feedback_gain",
    "filtered_state",
    "gain_shapes",
    "kalman_covariance",
    "kalman_covariance_lanes",
    "known_model_commit",
    "known_model_commit_lanes",
    "known_model_propose",
    "known_model_propose_lanes",
    "lq_design",
    "lq_initial_P",
    "lq_solve",
    "lq_solve_lanes",
    "lq_weights",
    "lq_work",
    "make_gain",
    "make_oracle_state",
    "model_matrices",
    "model_matrices_lanes",
    "place_design",
    "place_design_lanes",
    "safe_set",
    "steady_state",
    "track",
]
