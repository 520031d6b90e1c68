"""The known-model controllers' step (the oracles of :mod:`stcgym.adaptive.control.oracles`).

``known_model_propose(s, p, lane_i, y, r, filtered, integral, anti_windup, action_bound) -> int``
computes one step (Kalman correction, the tracking law :func:`~.law.track`, Kalman prediction)
of lane ``lane_i`` of the lane state ``s`` (:class:`OracleState`) into the proposal ``p``
(:class:`OracleProposal`) without touching ``s``; ``known_model_commit(s, p, lane_i) -> u`` makes
it the state. Both are named tuples of batched arrays (lane ``i``'s field ``f`` is ``s.f[i]``;
shapes in :func:`oracle_shapes`). The batch loops ``known_model_propose_lanes`` /
``known_model_commit_lanes`` let a batched ``predict`` reject a step atomically (no lane changes
unless every lane's proposal is finite).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from stcgym.adaptive.control.law import track
from stcgym.adaptive.control.safe_set import make_gain
from stcgym.adaptive.estimation.state_estimation import filtered_state, kalman_step
from stcgym.lanes.compiled import lane, lane_state, lanes
from stcgym.lanes.linalg import all_finite, copy_matrix, copy_vector

__all__ = [
    "OracleProposal",
    "OracleState",
    "known_model_commit",
    "known_model_commit_lanes",
    "known_model_propose",
    "known_model_propose_lanes",
    "make_oracle_state",
    "oracle_shapes",
]


class OracleState(NamedTuple):
    """A known-model oracle's lane state: field ``f`` of lane ``i`` is ``state.f[i]`` (shapes in
    :func:`oracle_shapes`)."""

    A: NDArray  # the model in force (n, n)
    b: NDArray  # (n,)
    Q: NDArray  # the Kalman filter's process-noise covariance (n, n)
    R: NDArray  # its measurement-noise variance
    x: NDArray  # x(t|t-1) (n,)
    x_filt: NDArray  # x(t|t) (n,)
    P: NDArray  # the filter's P(t) (n, n)
    innov: NDArray  # the last innovation
    gain: Any  # the design in force: a safe_set.Gain (K_x, k_i, N, rcond)
    xi: NDArray  # the tracking law's integrator xi(t)
    saturated: NDArray  # the last input was saturated (bool)
    u_unsat: NDArray  # the last input before saturation
    t: NDArray  # steps taken (int)
    A0: NDArray  # the initial values a reset restores: A, b, Q, P (and the oracle's gain)
    b0: NDArray
    Q0: NDArray
    P0: NDArray


class OracleProposal(NamedTuple):
    """One step of :func:`known_model_propose`, made the state by :func:`known_model_commit`:
    one row a lane (shapes in :func:`oracle_shapes`)."""

    x: NDArray  # x(t+1|t) (n,)
    x_filt: NDArray  # x(t|t) (n,)
    P: NDArray  # P(t+1) (n, n)
    innov: NDArray  # the innovation of y(t)
    xi: NDArray  # xi(t+1)
    saturated: NDArray  # u(t) saturated (bool)
    u_unsat: NDArray  # u(t) before saturation
    u: NDArray  # u(t)
    L1: NDArray  # the filter's gain (n,)
    AP: NDArray  # the Kalman time update's A P1 (n, n)
    P_upd: NDArray  # its P1(t+1) until it is accepted (n, n)


#: The fields of :class:`OracleState` that are not float64.
_DTYPES: dict[str, Any] = {"t": np.int64, "saturated": np.bool_}


def oracle_shapes(n: int) -> tuple[dict[str, tuple[int, ...]], dict[str, tuple[int, ...]]]:
    """The shapes of one lane's :class:`OracleState` and :class:`OracleProposal` fields for
    order ``n``: the one place they are declared."""
    n = int(n)
    state: dict[str, tuple[int, ...]] = {
        **dict.fromkeys(("A", "Q", "P", "A0", "Q0", "P0"), (n, n)),
        **dict.fromkeys(("b", "x", "x_filt", "b0"), (n,)),
    }
    for scalar in OracleState._fields:
        if scalar != "gain":  # a lane state of its own (safe_set.gain_shapes)
            state.setdefault(scalar, ())
    proposal: dict[str, tuple[int, ...]] = {
        **dict.fromkeys(("x", "x_filt", "L1"), (n,)),
        **dict.fromkeys(("P", "AP", "P_upd"), (n, n)),
    }
    for scalar in OracleProposal._fields:
        proposal.setdefault(scalar, ())
    return state, proposal


def make_oracle_state(n: int, num_lanes: int) -> tuple[OracleState, OracleProposal]:
    """A zeroed :class:`OracleState` of ``num_lanes`` lanes and their proposal."""
    state, proposal = oracle_shapes(n)
    return (
        lane_state(OracleState, state, num_lanes, _DTYPES, {"gain": make_gain(n, num_lanes)}),
        lane_state(OracleProposal, proposal, num_lanes, _DTYPES),
    )


@lane(entry=True)
def known_model_propose(s, p, lane_i, y, r, filtered, integral, anti_windup, action_bound):
    """One step of a known-model controller, written to lane ``lane_i`` of the proposal ``p``.

    The Kalman correction with ``y(t)`` (:func:`filtered_state`), the tracking law on ``x(t|t)``
    (``filtered``) or ``x(t|t-1)`` (:func:`track`), the Kalman time update with the applied
    ``u(t)`` (:func:`kalman_step`). Returns 0 when everything proposed is finite (then
    :func:`known_model_commit` makes it the state), 1 otherwise; the state ``s`` is only read.
    """
    x = s.x[lane_i]
    P = s.P[lane_i]
    R = s.R[lane_i]
    x_next = p.x[lane_i]
    x_filt = p.x_filt[lane_i]
    P_next = p.P[lane_i]
    innov = filtered_state(x, P, R, y, x_filt)
    xc = x_filt if filtered else x
    # a known model always has a gain (its design must succeed)
    u, xi, saturated, u_unsat = track(
        s.gain, lane_i, True, s.xi[lane_i], xc, y, r, 0.0, action_bound, integral, anti_windup
    )
    p.xi[lane_i] = xi
    p.saturated[lane_i] = saturated
    p.u_unsat[lane_i] = u_unsat
    copy_matrix(P, P_next)
    kf_status = kalman_step(
        s.A[lane_i], s.b[lane_i], P_next, s.Q[lane_i], R, x, u, y, x_next, p.L1[lane_i],
        p.AP[lane_i], p.P_upd[lane_i],
    )  # fmt: skip
    p.innov[lane_i] = innov
    p.u[lane_i] = u
    if kf_status != 0:
        return 1
    finite = all_finite(x_next) and all_finite(x_filt) and all_finite(P_next)
    for v in (innov, xi, u_unsat, u):
        finite = finite and math.isfinite(v)
    return 0 if finite else 1


@lane(entry=True)
def known_model_commit(s, p, lane_i):
    """Make lane ``lane_i`` of the proposal ``p`` of :func:`known_model_propose` the lane's state;
    returns ``u``."""
    x, x_filt, P = s.x[lane_i], s.x_filt[lane_i], s.P[lane_i]
    x_next, x_filt_next, P_next = p.x[lane_i], p.x_filt[lane_i], p.P[lane_i]
    copy_vector(x_next, x)
    copy_vector(x_filt_next, x_filt)
    copy_matrix(P_next, P)
    s.innov[lane_i] = p.innov[lane_i]
    s.xi[lane_i] = p.xi[lane_i]
    s.saturated[lane_i] = p.saturated[lane_i]
    s.u_unsat[lane_i] = p.u_unsat[lane_i]
    s.t[lane_i] += 1
    return p.u[lane_i]


@lanes
def known_model_propose_lanes(
    s, p, y, r, filtered, integral, anti_windup, action_bound, status, first, last
):
    """Batch of :func:`known_model_propose` (lane ``i``: ``y[i]``, ``r[i]``, ``status[i]``)."""
    for i in range(first, last):
        status[i] = known_model_propose(
            s, p, i, y[i], r[i], filtered, integral, anti_windup, action_bound
        )


@lanes
def known_model_commit_lanes(s, p, u, first, last):
    """Batch of :func:`known_model_commit`; writes the applied inputs into ``u``."""
    for i in range(first, last):
        u[i] = known_model_commit(s, p, i)
