"""``[A B]`` from measured states (Kunik, Kovalenko & Al Sadi 2001) as a lane function.

Model ``x(t+1) = A x(t) + B u(t) = C z(t)``, ``z(t) = [x(t); u(t)]`` with ``n`` states and ``m``
inputs (the paper's ``m`` and ``N``), ``q = n + m`` unknowns per state row. The record holds
``Theta = C^T`` (``q x n``, the layout of the matrix RLS of
:func:`stcgym.adaptive.multichannel.matrix_rls_step`, whose rows share the regressor ``z``).

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
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from stcgym.adaptive.kernels.least_squares import OK, upper_factor
from stcgym.adaptive.kernels.linalg import invert
from stcgym.adaptive.kernels.records import view2d
from stcgym.adaptive.multichannel import matrix_rls_step
from stcgym.envs.compiled import Layout, lane

__all__ = [
    "DEPENDENT",
    "RESET",
    "StateMatrixRecord",
    "state_matrix_initial",
    "state_matrix_layout",
    "state_matrix_update",
]

#: Status codes of :func:`state_matrix_update` besides ``OK``.
DEPENDENT = 1  # minimum-norm phase, regressor in the span already seen: C unchanged
RESET = 2  # RLS phase, health check failed: sample discarded, P <- p0 I


class StateMatrixRecord(NamedTuple):
    """Offsets of the estimator's fields in a lane record."""

    theta: int  # Theta = C^T = [A B]^T (q, n)
    S: int  # upper factor of P = S S^T (q, q), RLS phase
    R: int  # projector of the minimum-norm phase (q, q)
    gram: int  # G = sum lambda^(t-i) z z^T (q, q)
    cross: int  # H = sum lambda^(t-i) z x(i+1)^T (q, n)
    z: int  # the regressor [x(t); u(t)] of the next update (q)
    e: int  # innovation x(t+1) - C z of the last update (n)
    rank: int  # regressors accepted as independent (q: RLS phase)
    work: int  # scratch, work_size(n, m) floats


def work_size(n: int, m: int) -> int:
    q = n + m
    return max(3 * q + n, 2 * q * q)


def state_matrix_layout(n: int, m: int, lay: Layout | None = None) -> Layout:
    """Add the estimator's fields to ``lay`` (a new layout by default) and return it."""
    q = n + m
    lay = Layout() if lay is None else lay
    lay.add("theta", (q, n))
    lay.add("S", (q, q))
    lay.add("R", (q, q))
    lay.add("gram", (q, q))
    lay.add("cross", (q, n))
    lay.add("z", (q,))
    lay.add("e", (n,))
    lay.add("rank")
    lay.add("work", (work_size(n, m),))
    return lay


def state_matrix_initial(lay: Layout, rec: NDArray, n: int, m: int) -> None:
    """Initial values in the record ``rec``: ``C = 0``, ``R = I``, empty sums, rank 0."""
    q = n + m
    rec[lay.offset("theta") : lay.offset("theta") + q * n] = 0.0
    o = lay.offset("R")
    rec[o : o + q * q] = np.eye(q).ravel()


@lane(inline=True, entry=True)
def _switch_to_rls(f, at, n, q, p0):
    """``P = G^{-1}`` (19) and ``Theta = G^{-1} H`` (11); a singular ``G`` keeps ``Theta`` and
    starts ``P`` at ``p0 I``."""
    theta = view2d(f, at.theta, q, n)
    S = view2d(f, at.S, q, q)
    M = view2d(f, at.work, q, q)
    Ginv = view2d(f, at.work + q * q, q, q)
    gram = view2d(f, at.gram, q, q)
    cross = view2d(f, at.cross, q, n)
    for i in range(q):
        for j in range(q):
            M[i, j] = gram[i, j]
    ok = invert(M, Ginv)
    if ok:
        for i in range(q):  # symmetric part, then its factor (M is free again)
            for j in range(q):
                M[i, j] = 0.5 * (Ginv[i, j] + Ginv[j, i])
        ok = upper_factor(M, S)
    if ok:  # Theta = G^{-1} H into the scratch (M is free again), kept only if finite
        T = view2d(f, at.work, q, n)
        for i in range(q):
            for j in range(n):
                acc = 0.0
                for k in range(q):
                    acc += Ginv[i, k] * cross[k, j]
                T[i, j] = acc
                ok = ok and math.isfinite(acc)
        if ok:
            for i in range(q):
                for j in range(n):
                    theta[i, j] = T[i, j]
    if not ok:
        _restart_covariance(f, at, q, p0)


@lane(inline=True)
def _restart_covariance(f, at, q, p0):
    s = math.sqrt(p0)
    for i in range(q):
        for j in range(q):
            f[at.S + i * q + j] = s if i == j else 0.0


@lane
def state_matrix_update(f, at, n, m, x_next, lam, tol, p0):
    """One sample ``(z(t), x(t+1))`` of the estimator (module docstring); returns the status.

    ``z(t)`` is read from the record (the caller writes it after choosing ``u(t)``); the
    innovation ``e = x(t+1) - C z(t)`` is written to the record before the update.
    """
    q = n + m
    theta = view2d(f, at.theta, q, n)
    z = f[at.z : at.z + q]
    e = f[at.e : at.e + n]
    for j in range(n):
        acc = x_next[j]
        for i in range(q):
            acc -= theta[i, j] * z[i]
        e[j] = acc
    rank = int(f[at.rank])
    if rank >= q:
        status = matrix_rls_step(theta, view2d(f, at.S, q, q), view2d(f, at.z, 1, q), x_next,
                                 lam, f[at.work : at.work + 3 * q + n])  # fmt: skip
        if status != OK:
            _restart_covariance(f, at, q, p0)
            return RESET
        return OK
    gram = view2d(f, at.gram, q, q)
    cross = view2d(f, at.cross, q, n)
    for i in range(q):
        for j in range(q):
            gram[i, j] = lam * gram[i, j] + z[i] * z[j]
        for j in range(n):
            cross[i, j] = lam * cross[i, j] + z[i] * x_next[j]
    R = view2d(f, at.R, q, q)
    Rz = f[at.work : at.work + q]
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
    f[at.rank] = rank
    if rank == q:
        _switch_to_rls(f, at, n, q, p0)
    return OK
