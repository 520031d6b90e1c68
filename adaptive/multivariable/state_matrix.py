"""``[A B]`` from measured states (Kunik, Kovalenko & Al Sadi 2001) as a lane function.

Model ``x(t+1) = A x(t) + B u(t) = C z(t)``, ``z(t) = [x(t); u(t)]`` with ``n`` states and ``m``
inputs (the paper's ``m`` and ``N``), ``q = n + m`` unknowns per state row. The state holds
``Theta = C^T`` (``q x n``, the layout of the matrix RLS of
:func:`stcgym.adaptive.multivariable.multichannel.matrix_rls_step`, whose rows share the regressor
``z``).

*Minimum-norm phase* (rank of the regressors seen so far ``< q``), ``R(0) = I``, ``e = x(t+1) -
C z``: a regressor independent of the past ones (``z^T R z > tol z^T z``) gives eq. (17)-(18)::

    C <- C + e z^T R / (z^T R z),      R <- R - R z z^T R / (z^T R z)

so that ``C = X Z^+`` interpolates every independent sample. A dependent regressor leaves ``C``
as it is (the paper assumes independence); it is still counted in the weighted Gram matrix
``G = sum lambda^{t-i} z z^T`` and in ``H = sum lambda^{t-i} z x(i+1)^T``.
*Switch* when the rank reaches ``q``: ``P = G^{-1}`` (19) and ``Theta = G^{-1} H``, the batch
least-squares estimate (11) of every sample so far, dependent ones included.
*RLS phase* (20)-(21): the shared square-root matrix RLS step on ``P = S S^T``. When its health
check fails the sample is discarded, ``P`` restarts at ``p0 I`` and ``Theta`` is kept
(status ``RESET``).

Lane state: :class:`StateMatrixState` and its scratch :class:`StateMatrixWork`, named tuples of
batched arrays (lane ``i``'s field ``f`` is ``state.f[i]``; shapes in
:func:`state_matrix_shapes`).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from stcgym.adaptive.estimation.least_squares import (
    OK,
    LeastSquaresWork,
    least_squares_shapes,
    upper_factor,
)
from stcgym.adaptive.multivariable.multichannel import matrix_rls_step
from stcgym.lanes.compiled import fields_of, lane, lane_state, make_work
from stcgym.lanes.linalg import copy_matrix, invert

__all__ = [
    "DEPENDENT",
    "RESET",
    "StateMatrixPhaseWork",
    "StateMatrixState",
    "StateMatrixWork",
    "make_state_matrix",
    "state_matrix_shapes",
    "state_matrix_update",
]

#: Status codes of :func:`state_matrix_update` besides ``OK``.
DEPENDENT = 1  # minimum-norm phase, regressor in the span already seen: C unchanged
RESET = 2  # RLS phase, health check failed: sample discarded, P <- p0 I


class StateMatrixState(NamedTuple):
    """The estimator's lane state: field ``f`` of lane ``i`` is ``state.f[i]`` (shapes in
    :func:`state_matrix_shapes`)."""

    theta: NDArray  # Theta = C^T = [A B]^T (q, n)
    S: NDArray  # upper factor of P = S S^T (q, q), RLS phase
    R: NDArray  # projector of the minimum-norm phase (q, q)
    gram: NDArray  # G = sum lambda^(t-i) z z^T (q, q)
    cross: NDArray  # H = sum lambda^(t-i) z x(i+1)^T (q, n)
    z: NDArray  # the regressor [x(t); u(t)] of the next update (q)
    e: NDArray  # innovation x(t+1) - C z of the last update (n)
    rank: NDArray  # regressors accepted as independent (int; q: RLS phase)


class StateMatrixPhaseWork(NamedTuple):
    """The scratch of the minimum-norm phase and of the switch to RLS."""

    Rz: NDArray  # R z of the minimum-norm phase (q)
    M: NDArray  # G, then the symmetric part of G^{-1} at the switch (q, q)
    Ginv: NDArray  # G^{-1} at the switch (q, q)
    T: NDArray  # G^{-1} H at the switch, kept only if finite (q, n)


#: The estimator's scratch, one row a lane (its content is irrelevant between calls): the fields
#: of :class:`StateMatrixPhaseWork` and of the RLS phase's
#: :class:`~stcgym.adaptive.estimation.least_squares.LeastSquaresWork` (``d = q`` rows of the
#: regressor, ``n`` outputs).
StateMatrixWork = NamedTuple(  # type: ignore[misc]
    "StateMatrixWork", fields_of(StateMatrixPhaseWork, LeastSquaresWork)
)


def state_matrix_shapes(
    n: int, m: int
) -> tuple[dict[str, tuple[int, ...]], dict[str, tuple[int, ...]]]:
    """The shapes of one lane's :class:`StateMatrixState` and :class:`StateMatrixWork` fields
    for ``n`` states and ``m`` inputs (``q = n + m``): the one place they are declared."""
    n, q = int(n), int(n) + int(m)
    state = {
        "theta": (q, n),
        "S": (q, q),
        "R": (q, q),
        "gram": (q, q),
        "cross": (q, n),
        "z": (q,),
        "e": (n,),
        "rank": (),
    }
    work = {
        "Rz": (q,),
        "M": (q, q),
        "Ginv": (q, q),
        "T": (q, n),
        **least_squares_shapes(q, n),
    }
    return state, work


_DTYPES: dict[str, Any] = {"rank": np.int64}


def make_state_matrix(n: int, m: int, num_lanes: int) -> tuple[StateMatrixState, Any]:
    """The state of ``num_lanes`` lanes before the first sample and their scratch: ``C = 0``,
    ``R = I``, empty sums, rank 0."""
    shapes, work = state_matrix_shapes(n, m)
    state = lane_state(StateMatrixState, shapes, num_lanes, _DTYPES)
    state.R[:] = np.eye(shapes["R"][0])
    return state, make_work(StateMatrixWork, work, num_lanes)


@lane(inline=True)
def _switch_to_rls(est, work, lane_i, p0):
    """``P = G^{-1}`` (19) and ``Theta = G^{-1} H`` (11) of lane ``lane_i``; a singular ``G`` keeps
    ``Theta`` and starts ``P`` at ``p0 I``."""
    theta = est.theta[lane_i]
    S = est.S[lane_i]
    gram = est.gram[lane_i]
    cross = est.cross[lane_i]
    M = work.M[lane_i]
    Ginv = work.Ginv[lane_i]
    T = work.T[lane_i]
    q, n = theta.shape
    copy_matrix(gram, M)
    ok = invert(M, Ginv)
    if ok:
        for i in range(q):  # symmetric part, then its factor (M is free again)
            for j in range(q):
                M[i, j] = 0.5 * (Ginv[i, j] + Ginv[j, i])
        ok = upper_factor(M, S)
    if ok:  # Theta = G^{-1} H, kept only if finite
        for i in range(q):
            for j in range(n):
                acc = 0.0
                for k in range(q):
                    acc += Ginv[i, k] * cross[k, j]
                T[i, j] = acc
                ok = ok and math.isfinite(acc)
        if ok:
            copy_matrix(T, theta)
    if not ok:
        _restart_covariance(S, p0)


@lane(inline=True)
def _restart_covariance(S, p0):
    """``P = p0 I`` (``S = sqrt(p0) I``)."""
    s = math.sqrt(p0)
    q = S.shape[0]
    for i in range(q):
        for j in range(q):
            S[i, j] = s if i == j else 0.0


@lane
def state_matrix_update(est, work, lane_i, x_next, lam, tol, p0):
    """One sample ``(z(t), x(t+1))`` of lane ``lane_i`` of the estimator (module docstring);
    returns the status.

    ``est``/``work``: a :class:`StateMatrixState` and its :class:`StateMatrixWork`. ``z(t)`` is
    read from the state (the caller writes it after choosing ``u(t)``); the innovation ``e =
    x(t+1) - C z(t)`` is written to the state before the update.
    """
    theta = est.theta[lane_i]
    q, n = theta.shape
    z = est.z[lane_i]
    e = est.e[lane_i]
    for j in range(n):
        acc = x_next[j]
        for i in range(q):
            acc -= theta[i, j] * z[i]
        e[j] = acc
    rank = est.rank[lane_i]
    S = est.S[lane_i]
    if rank >= q:
        status = matrix_rls_step(theta, S, est.z[lane_i : lane_i + 1], x_next, lam, work, lane_i)
        if status != OK:
            _restart_covariance(S, p0)
            return RESET
        return OK
    gram = est.gram[lane_i]
    cross = est.cross[lane_i]
    for i in range(q):
        for j in range(q):
            gram[i, j] = lam * gram[i, j] + z[i] * z[j]
        for j in range(n):
            cross[i, j] = lam * cross[i, j] + z[i] * x_next[j]
    R = est.R[lane_i]
    Rz = work.Rz[lane_i]
    gamma = 0.0
    zz = 0.0
    for i in range(q):
        acc = 0.0
        for k in range(q):
            acc += R[i, k] * z[k]
        Rz[i] = acc
        gamma += z[i] * acc
        zz += z[i] * z[i]
    if not (zz > 0.0 and gamma > tol * zz and math.isfinite(gamma)):
        return DEPENDENT
    for i in range(q):  # (17): C^T += R z e^T / gamma
        for j in range(n):
            theta[i, j] += Rz[i] * e[j] / gamma
    for i in range(q):  # (18)
        for k in range(q):
            R[i, k] -= Rz[i] * Rz[k] / gamma
    rank += 1
    est.rank[lane_i] = rank
    if rank == q:
        _switch_to_rls(est, work, lane_i, p0)
    return OK
