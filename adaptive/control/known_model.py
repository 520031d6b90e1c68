"""The known-model controllers' step (the oracles of :mod:`stcgym.adaptive.control.oracles`).

``known_model_propose(f, at, n, s, y, r, filtered, integral, anti_windup, action_bound) -> int``
computes one step (Kalman correction, the tracking law :func:`~.law.track`, Kalman prediction)
of the lane record ``f`` (fields :class:`OracleRecord`, offsets ``at``) into the proposal buffer
``s`` (``oracle_scratch_size(n)`` floats) without touching ``f``;
``known_model_commit(f, at, n, s) -> u`` makes it the state. The batch loops
``known_model_propose_lanes`` / ``known_model_commit_lanes`` let a batched ``predict`` reject a
step atomically (no lane changes unless every lane's proposal is finite).
"""

from __future__ import annotations

import math
from typing import NamedTuple

from stcgym.adaptive.control.law import LAW, LAW_SIZE, track
from stcgym.adaptive.estimation.state_estimation import filtered_state, kalman_step
from stcgym.adaptive.kernels.records import view2d
from stcgym.envs.compiled import lane, lanes

__all__ = [
    "OracleRecord",
    "known_model_commit",
    "known_model_commit_lanes",
    "known_model_propose",
    "known_model_propose_lanes",
    "oracle_scratch_size",
]


class OracleRecord(NamedTuple):
    """Offsets of a known-model oracle's lane record (built with
    :meth:`stcgym.envs.compiled.Layout.record` by :mod:`stcgym.adaptive.control.oracles`)."""

    A: int  # (n, n) model in force
    b: int  # (n,)
    Q: int  # (n, n) Kalman filter process-noise covariance
    R: int  # ()     Kalman filter measurement-noise variance
    x: int  # (n,)   x(t|t-1)
    x_filt: int  # (n,) x(t|t)
    P: int  # (n, n) P(t) of the filter
    innov: int  # () last innovation
    gain: int  # (n + 3,) gain record
    law: int  # (3,)  tracking-law state
    t: int  # ()     steps taken


def oracle_scratch_size(n: int) -> int:
    """Per-lane proposal buffer of :func:`known_model_propose`: ``[x (n), x_filt (n), P (n^2),
    innov, law (3), u, L1 (n)]`` followed by ``2 n^2`` floats of work."""
    n = int(n)
    return 3 * n + 3 * n * n + 5


@lane(entry=True)
def known_model_propose(f, at, n, s, y, r, filtered, integral, anti_windup, action_bound):
    """One step of a known-model controller, written to the proposal buffer ``s`` only.

    The Kalman correction with ``y(t)`` (:func:`filtered_state`), the tracking law on ``x(t|t)``
    (``filtered``) or ``x(t|t-1)`` (:func:`track`), the Kalman time update with the applied
    ``u(t)`` (:func:`kalman_step`). Returns 0 when everything proposed is finite (then
    :func:`known_model_commit` makes it the state), 1 otherwise; the record ``f`` is only read.
    """
    A = view2d(f, at.A, n, n)
    b = f[at.b : at.b + n]
    Q = view2d(f, at.Q, n, n)
    R = f[at.R]
    x = f[at.x : at.x + n]
    P = view2d(f, at.P, n, n)
    gain = f[at.gain : at.gain + n + 3]
    law = f[at.law : at.law + LAW_SIZE]
    k = 2 * n + n * n
    x_next = s[0:n]
    x_filt = s[n : 2 * n]
    P_next = view2d(s, 2 * n, n, n)
    law_next = s[k + 1 : k + 4]
    L1 = s[k + 5 : k + 5 + n]
    work = s[k + 5 + n : k + 5 + n + 2 * n * n]
    innov = filtered_state(x, P, R, y, x_filt)
    xc = x_filt if filtered else x
    # a known model always has a gain (its design must succeed)
    u, xi, saturated, u_unsat = track(
        gain, True, law[LAW.xi], xc, y, r, 0.0, action_bound, integral, anti_windup
    )
    law_next[LAW.xi] = xi
    law_next[LAW.saturated] = 1.0 if saturated else 0.0
    law_next[LAW.u_unsat] = u_unsat
    for i in range(n):
        for j in range(n):
            P_next[i, j] = P[i, j]
    kf_status = kalman_step(A, b, P_next, Q, R, x, u, y, x_next, L1, work)
    s[k] = innov
    s[k + 4] = u
    if kf_status != 0:
        return 1
    for i in range(k + 5):
        if not math.isfinite(s[i]):
            return 1
    return 0


@lane(entry=True)
def known_model_commit(f, at, n, s):
    """Make the proposal ``s`` of :func:`known_model_propose` the lane's state; returns ``u``."""
    k = 2 * n + n * n
    for i in range(n):
        f[at.x + i] = s[i]
        f[at.x_filt + i] = s[n + i]
    for i in range(n * n):
        f[at.P + i] = s[2 * n + i]
    f[at.innov] = s[k]
    for i in range(LAW_SIZE):
        f[at.law + i] = s[k + 1 + i]
    f[at.t] += 1.0
    return s[k + 4]


@lanes
def known_model_propose_lanes(
    F, at, n, S, y, r, filtered, integral, anti_windup, action_bound, status, first, last
):
    """Batch of :func:`known_model_propose` (lane ``i``: record ``F[i]``, buffer ``S[i]``)."""
    for i in range(first, last):
        status[i] = known_model_propose(
            F[i], at, n, S[i], y[i], r[i], filtered, integral, anti_windup, action_bound
        )


@lanes
def known_model_commit_lanes(F, at, n, S, u, first, last):
    """Batch of :func:`known_model_commit`; writes the applied inputs into ``u``."""
    for i in range(first, last):
        u[i] = known_model_commit(F[i], at, n, S[i])
