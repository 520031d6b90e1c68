"""Multi-input LQ design and the feed-forward tracking law, as lane functions.

For a model ``x+ = A x + B u`` (``n`` states, ``m`` inputs) and the stage cost
``(x - r)^T Q (x - r) + u^T R u`` (the StateSpace env's cost with ``Q = I``, ``R = rho I``):

``lq_gain``
    ``K = (R + B^T P B)^{-1} B^T P A`` (``m x n``).
``riccati_step``
    One iteration of the Riccati difference equation in Joseph form,
    ``P <- Q + (A - B K)^T P (A - B K) + K^T R K`` with ``K`` the gain of ``P`` (stays symmetric
    positive semidefinite): the warm-started per-sample design of the self-tuning controller.
``dare_solve``
    The stabilising solution of the discrete algebraic Riccati equation by the
    structure-preserving doubling algorithm (``A_0 = A``, ``G_0 = B R^{-1} B^T``, ``H_0 = Q``;
    ``W = I + G_k H_k``, ``A_{k+1} = A_k W^{-1} A_k``, ``G_{k+1} = G_k + A_k W^{-1} G_k A_k^T``,
    ``H_{k+1} = H_k + A_k^T H_k W^{-1} A_k``, ``H_k -> P``): the full solve for a fresh model and
    the known-model oracle (tested against python-control's ``dlqr``). The iteration itself,
    ``doubling``, also serves the single-input :func:`.lq.dare`.
``steady_state_feedforward``
    For a constant reference ``r`` the cheapest equilibrium ``(x_s, u_s)``: minimise
    ``(x_s - r)^T Q (x_s - r) + u_s^T R u_s`` subject to ``(A - I) x_s + B u_s = 0`` (the
    stationary point of the average-cost LQ tracking problem), from the KKT system
    ``[[Q, 0, (A - I)^T], [0, R, B^T], [A - I, B, 0]] [x_s; u_s; mu] = [Q r; 0; 0]``. Linear in
    ``r``: ``x_s = M_x r``, ``u_s = M_u r``, and the law ``u = u_s - K (x - x_s)`` is
    ``u = -K x + F r`` with ``F = M_u + K M_x``. With fewer inputs than states not every
    reference is an equilibrium; this is the equilibrium nearest to it in the cost.
``schur_stable``
    ``rho(M) < 1`` tested by repeated squaring: ``||M^(2^k)||_F < 1/2`` for some ``k <= 40``
    (stable), a norm above ``1e100`` or not finite (unstable); undecided counts as unstable.
``feedback_law``
    ``u = sat(-K x + F r)``, saturated per input.

Matrices are C-ordered views into the lane record or a scratch vector (``view2d``); scratch of
``design_work_size(n, m)`` floats.
"""

from __future__ import annotations

import math

from stcgym.adaptive.kernels.linalg import invert, matmul, max_abs
from stcgym.adaptive.kernels.records import copy_matrix, view2d
from stcgym.adaptive.kernels.safe_set import (
    B_SMALL,
    DC_SINGULAR,
    GAIN_LARGE,
    NONFINITE,
    NOT_CONVERGED,
    NOT_STABILISABLE,
    OK,
)
from stcgym.envs.compiled import lane, lanes

__all__ = [
    "P_MAX",
    "dare_solve",
    "design_checks",
    "doubling",
    "design_work_size",
    "feedback_law",
    "feedback_laws",
    "lq_gain",
    "riccati_step",
    "schur_stable",
    "steady_state_feedforward",
]

#: Riccati iterates above this are taken as diverging (a model that is not stabilisable).
P_MAX = 1e150
#: Squarings of the stability test (the power ``2^40`` decides spectral radii below
#: ``1 - 1e-11``).
MAX_SQUARINGS = 40


def design_work_size(n: int, m: int) -> int:
    """Scratch floats of the designs: 12 slots of ``(2n + m)^2``."""
    s = 2 * n + m
    return 12 * s * s


@lane(returns_views=True)
def _slot(work, k, rows, cols):
    """Slot ``k`` of the scratch as a ``rows x cols`` matrix (slots of ``(2n + m)^2`` floats,
    ``work.size / 12``)."""
    return view2d(work, k * (work.size // 12), rows, cols)


@lane(inline=True)
def _closed_loop(A, B, K, Acl):
    """``Acl = A - B K``."""
    matmul(B, K, Acl, False, False)
    for i in range(A.shape[0]):
        for j in range(A.shape[0]):
            Acl[i, j] = A[i, j] - Acl[i, j]


@lane(entry=True)
def lq_gain(A, B, R, P, K, work):
    """``K = (R + B^T P B)^{-1} B^T P A``; ``False`` when ``R + B^T P B`` is singular."""
    n = A.shape[0]
    m = B.shape[1]
    PB = _slot(work, 0, n, m)
    Sm = _slot(work, 1, m, m)
    Sinv = _slot(work, 2, m, m)
    T = _slot(work, 3, m, n)
    matmul(P, B, PB, False, False)
    matmul(B, PB, Sm, True, False)
    for i in range(m):
        for j in range(m):
            Sm[i, j] += R[i, j]
    if not invert(Sm, Sinv):
        return False
    matmul(PB, A, T, True, False)  # B^T P A (P symmetric)
    matmul(Sinv, T, K, False, False)
    return True


@lane
def riccati_step(A, B, Q, R, P, K, work):
    """One Riccati iteration (Joseph form) on ``P`` in place; ``K`` the gain of the old ``P``.
    Returns ``False`` when the gain is undefined."""
    n = A.shape[0]
    m = B.shape[1]
    if not lq_gain(A, B, R, P, K, work):
        return False
    Acl = _slot(work, 4, n, n)
    T = _slot(work, 5, n, n)
    KR = _slot(work, 6, m, n)
    _closed_loop(A, B, K, Acl)
    matmul(P, Acl, T, False, False)
    matmul(R, K, KR, False, False)
    for i in range(n):
        for j in range(i, n):
            acc = Q[i, j]
            for k in range(n):
                acc += Acl[k, i] * T[k, j]
            for k in range(m):
                acc += K[k, i] * KR[k, j]
            P[i, j] = acc
            P[j, i] = acc
    return True


@lane
def schur_stable(M, work):
    """Spectral radius of ``M`` below 1, by repeated squaring (module docstring)."""
    n = M.shape[0]
    X = _slot(work, 7, n, n)
    Y = _slot(work, 8, n, n)
    copy_matrix(M, X)
    for _ in range(MAX_SQUARINGS):
        fro = 0.0
        for i in range(n):
            for j in range(n):
                fro += X[i, j] * X[i, j]
        if not math.isfinite(fro) or fro > 1e200:
            return False
        if fro < 0.25:
            return True
        matmul(X, X, Y, False, False)
        copy_matrix(Y, X)
    return False


@lane
def doubling(Ak, Gk, Hk, W, Winv, T1, T2, T3, tol, max_iter):
    """The structure-preserving doubling iteration, from ``A_0``, ``G_0``, ``H_0`` in ``Ak``,
    ``Gk``, ``Hk`` (``n x n``, overwritten; ``G_0`` and ``H_0`` symmetric):
    ``W = I + G_k H_k``, ``A_{k+1} = A_k W^{-1} A_k``, ``G_{k+1} = G_k + A_k W^{-1} G_k A_k^T``,
    ``H_{k+1} = H_k + A_k^T H_k W^{-1} A_k`` (both kept symmetric), until the step of ``H`` is at
    most ``tol max(1, |H_k|)``; ``H_k -> P``, the stabilising DARE solution when there is one.

    Returns ``OK`` (``Hk`` converged), ``NOT_STABILISABLE`` (a singular ``W``, or an iterate
    above :data:`P_MAX` or not finite: diverging) or ``NOT_CONVERGED``. ``W``, ``Winv``,
    ``T1``-``T3``: ``n x n`` scratch.
    """
    n = Ak.shape[0]
    for _ in range(max_iter):
        matmul(Gk, Hk, W, False, False)
        for i in range(n):
            W[i, i] += 1.0
        if not invert(W, Winv):
            return NOT_STABILISABLE
        matmul(Winv, Ak, T1, False, False)  # W^{-1} A_k
        matmul(Winv, Gk, T2, False, False)  # W^{-1} G_k
        matmul(Hk, T1, T3, False, False)  # H_k W^{-1} A_k
        matmul(Ak, T3, W, True, False)  # A_k^T H_k W^{-1} A_k
        dH = max_abs(W)
        for i in range(n):
            for j in range(n):
                Hk[i, j] += 0.5 * (W[i, j] + W[j, i])
        matmul(Ak, T2, T3, False, False)
        matmul(T3, Ak, W, False, True)  # A_k W^{-1} G_k A_k^T
        for i in range(n):
            for j in range(n):
                Gk[i, j] += 0.5 * (W[i, j] + W[j, i])
        matmul(Ak, T1, W, False, False)
        copy_matrix(W, Ak)
        hmax = max_abs(Hk)
        if not hmax <= P_MAX or not max_abs(Gk) <= P_MAX or not max_abs(Ak) <= P_MAX:
            return NOT_STABILISABLE
        if dH <= tol * max(1.0, hmax):
            return OK
    return NOT_CONVERGED


@lane(entry=True)
def dare_solve(A, B, Q, R, P, K, work, tol, max_iter):
    """Stabilising DARE solution ``P`` and its gain ``K`` by doubling; returns ``OK``,
    ``NOT_STABILISABLE`` (diverging, singular, or a closed loop that is not Schur stable) or
    ``NOT_CONVERGED``. ``P`` and ``K`` are written only on ``OK``."""
    n = A.shape[0]
    m = B.shape[1]
    Ak = _slot(work, 0, n, n)
    Gk = _slot(work, 1, n, n)
    Hk = _slot(work, 2, n, n)
    W = _slot(work, 3, n, n)
    Winv = _slot(work, 4, n, n)
    T1 = _slot(work, 5, n, n)
    T2 = _slot(work, 6, n, n)
    T3 = _slot(work, 7, n, n)
    Rinv = _slot(work, 8, m, m)
    RB = _slot(work, 9, m, n)
    Rc = _slot(work, 10, m, m)
    copy_matrix(R, Rc)
    if not invert(Rc, Rinv):
        return NOT_STABILISABLE
    matmul(Rinv, B, RB, False, True)  # R^{-1} B^T
    matmul(B, RB, Gk, False, False)
    for i in range(n):
        for j in range(n):
            Ak[i, j] = A[i, j]
            Hk[i, j] = 0.5 * (Q[i, j] + Q[j, i])
    status = doubling(Ak, Gk, Hk, W, Winv, T1, T2, T3, tol, max_iter)
    if status != OK:
        return status
    # the gain from H_k (slots 0-3 and 11 are free now; lq_gain uses 0-3)
    Psol = _slot(work, 11, n, n)
    copy_matrix(Hk, Psol)
    Kt = _slot(work, 9, m, n)
    if not lq_gain(A, B, R, Psol, Kt, work):
        return NOT_STABILISABLE
    Acl = _slot(work, 4, n, n)
    _closed_loop(A, B, Kt, Acl)
    if not schur_stable(Acl, work):
        return NOT_STABILISABLE
    copy_matrix(Psol, P)
    copy_matrix(Kt, K)
    return OK


@lane(entry=True)
def steady_state_feedforward(A, B, Q, R, K, F, work):
    """``F = M_u + K M_x`` of the cheapest equilibrium (module docstring); ``False`` when the
    KKT matrix is singular (no equilibrium for some reference: an uncontrollable mode at
    ``z = 1``). ``F`` is written only on success."""
    n = A.shape[0]
    m = B.shape[1]
    s = 2 * n + m
    M = _slot(work, 0, s, s)
    Minv = _slot(work, 1, s, s)
    for i in range(s):
        for j in range(s):
            M[i, j] = 0.0
    for i in range(n):
        for j in range(n):
            M[i, j] = Q[i, j]
            a = A[i, j] - (1.0 if i == j else 0.0)
            M[n + m + i, j] = a
            M[j, n + m + i] = a
        for j in range(m):
            M[n + m + i, n + j] = B[i, j]
            M[n + j, n + m + i] = B[i, j]
    for i in range(m):
        for j in range(m):
            M[n + i, n + j] = R[i, j]
    if not invert(M, Minv):
        return False
    Mx = _slot(work, 2, n, n)
    Mu = _slot(work, 3, m, n)
    for i in range(n):  # M_x = Minv[:n, :n] Q
        for j in range(n):
            acc = 0.0
            for k in range(n):
                acc += Minv[i, k] * Q[k, j]
            Mx[i, j] = acc
    for i in range(m):
        for j in range(n):
            acc = 0.0
            for k in range(n):
                acc += Minv[n + i, k] * Q[k, j]
            Mu[i, j] = acc
    for i in range(m):
        for j in range(n):
            acc = Mu[i, j]
            for k in range(n):
                acc += K[i, k] * Mx[k, j]
            if not math.isfinite(acc):
                return False
            Mu[i, j] = acc
    copy_matrix(Mu, F)
    return True


@lane
def design_checks(A, B, Q, R, K, F, safe_b_min, gain_max, work):
    """The safe set of a candidate gain ``K`` on the model ``(A, B)``: finite, ``max |B| >=
    b_min``, closed loop Schur stable, feed-forward defined, ``max |K|, |F| <= gain_max``.
    Writes ``F`` (on success) and returns the status code of :mod:`.safe_set`."""
    n = A.shape[0]
    m = B.shape[1]
    if not (max_abs(A) < math.inf and max_abs(B) < math.inf):
        return NONFINITE
    if not max_abs(B) >= safe_b_min:
        return B_SMALL
    Acl = _slot(work, 4, n, n)
    _closed_loop(A, B, K, Acl)
    if not schur_stable(Acl, work):
        return NOT_STABILISABLE
    Fc = _slot(work, 10, m, n)
    if not steady_state_feedforward(A, B, Q, R, K, Fc, work):
        return DC_SINGULAR
    if not (max_abs(K) <= gain_max and max_abs(Fc) <= gain_max):
        return GAIN_LARGE
    copy_matrix(Fc, F)
    return OK


@lane(inline=True)
def feedback_law(K, F, x, r, bound, u):
    """``u = sat(-K x + F r)`` per input; returns the number of saturated inputs."""
    m = K.shape[0]
    n = K.shape[1]
    saturated = 0
    for i in range(m):
        acc = 0.0
        for j in range(n):
            acc += F[i, j] * r[j] - K[i, j] * x[j]
        if abs(acc) > bound:
            acc = math.copysign(bound, acc)
            saturated += 1
        u[i] = acc
    return saturated


@lanes(min_lanes=1 << 12)  # one matrix-vector product a lane
def feedback_laws(K, F, X, Rr, bound, U, first, last):
    """:func:`feedback_law` for every lane (``K``, ``F`` ``(B, m, n)``)."""
    for i in range(first, last):
        feedback_law(K[i], F[i], X[i], Rr[i], bound, U[i])
