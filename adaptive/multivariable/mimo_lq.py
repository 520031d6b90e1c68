"""Multi-input LQ design and the feed-forward tracking law, as lane functions.

For a model ``x+ = A x + B u`` (``n`` states, ``m`` inputs) and the stage cost
``e^T Q e + u^T R u + 2 e^T N u``, ``e = x - r`` (python-control's ``dlqr(A, B, Q, R, N)``
convention; the StateSpace env's cost is ``Q = I``, ``R = rho I``, ``N = 0``), the joint weight
``W = [[Q, N], [N^T, R]]`` positive semidefinite and ``R`` positive definite:

``lq_gain``
    ``K = (R + B^T P B)^{-1} (B^T P A + N^T)`` (``m x n``).
``riccati_step``
    One iteration of the Riccati difference equation in Joseph form,
    ``P <- [I; -K]^T W [I; -K] + (A - B K)^T P (A - B K)`` with ``K`` the gain of ``P`` (stays
    symmetric positive semidefinite): the warm-started per-sample design of the self-tuning
    controller.
``dare_solve``
    The stabilising solution of the discrete algebraic Riccati equation: the structure-preserving
    doubling algorithm (:func:`doubling`, also used by the single-input :func:`.lq.dare`) on
    the problem without cross weight (state weight ``Q_N = Q - N R^{-1} N^T``), with Newton's
    method (Hewer 1971) from a regularised weight where doubling stops at a solution that is not
    stabilising. The full solve for a fresh model and the known-model oracle (tested against
    python-control's ``dlqr``).
``steady_state_feedforward``
    For a constant reference ``r`` the cheapest equilibrium ``(x_s, u_s)``, from the KKT system
    of the average-cost LQ tracking problem; linear in ``r`` (``x_s = M_x r``, ``u_s = M_u r``),
    so the law ``u = u_s - K (x - x_s)`` is ``u = -K x + F r`` with ``F = M_u + K M_x``.
``schur_stable``
    ``rho(M) < 1`` tested by repeated squaring; undecided counts as unstable.
``feedback_law``
    ``u = sat(-K x + F r)``, saturated per input.

Matrices are C-ordered rows of the lane state; the scratch is a :data:`MimoDesignWork` (named
fields, one row a lane, shapes in :func:`mimo_design_shapes`), of which each function uses lane
``lane_i`` and the fields it names.

Status codes (:mod:`.safe_set`): ``NOT_STABILISABLE`` when ``(A, B)`` is not stabilisable (the
regularised problem has no stabilising solution either), ``UNIT_CIRCLE_MODE`` when it is but a
mode on the unit circle is unobservable through ``Q_N`` (the largest solution's closed loop
keeps it), ``NOT_CONVERGED`` when an iteration runs out of steps.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

from numpy.typing import NDArray

from stcgym.adaptive.control.safe_set import (
    B_SMALL,
    DC_SINGULAR,
    GAIN_LARGE,
    NONFINITE,
    NOT_CONVERGED,
    NOT_STABILISABLE,
    OK,
    UNIT_CIRCLE_MODE,
)
from stcgym.lanes.compiled import fields_of, lane, lanes, make_work
from stcgym.lanes.linalg import copy_matrix, invert, matmul, max_abs

__all__ = [
    "P_MAX",
    "ClosedLoopWork",
    "CrossWeightWork",
    "DoublingWork",
    "FeedforwardWork",
    "GainWork",
    "LQProblem",
    "MimoDesignWork",
    "dare_solve",
    "design_checks",
    "doubling",
    "doubling_shapes",
    "feedback_law",
    "feedback_laws",
    "lq_gain",
    "mimo_design_shapes",
    "mimo_design_work",
    "riccati_step",
    "schur_stable",
    "steady_state_feedforward",
]

#: Riccati iterates above this are taken as diverging (a model that is not stabilisable).
P_MAX = 1e150
#: Newton steps of the fallback solve (quadratic convergence needs a handful; a problem with a
#: mode on the unit circle that ``Q`` does not see converges only linearly and ends here).
NEWTON_MAX_ITER = 100
#: Squarings of the stability test (the power ``2^40`` decides spectral radii below
#: ``1 - 1e-11``).
MAX_SQUARINGS = 40


class LQProblem(NamedTuple):
    """The stage cost's weights and the solve's limits (the multivariable controller passes its
    own configuration, which has these fields)."""

    Q: NDArray  # state weight (n, n)
    R: NDArray  # input weight (m, m), positive definite
    N: NDArray  # cross weight (n, m)
    solve_tol: float  # the last doubling or Newton increment, relative to max |P|
    solve_max_iter: int  # doubling steps (each squares the horizon)


class GainWork(NamedTuple):
    """The LQ gain of a Riccati matrix (:func:`lq_gain`)."""

    PB: NDArray  # P B (n, m)
    S: NDArray  # R + B^T P B, reduced by the inversion (m, m)
    S_inv: NDArray  # (R + B^T P B)^{-1} (m, m)
    BPA: NDArray  # B^T P A + N^T (m, n)


class ClosedLoopWork(NamedTuple):
    """A gain's closed loop: the Riccati iteration and the stability test."""

    A_cl: NDArray  # A - B K (n, n)
    P_Acl: NDArray  # P A_cl (n, n)
    RK: NDArray  # R K (m, n)
    X: NDArray  # the stability test's power M^(2^k) (n, n)
    X2: NDArray  # its square (n, n)


class DoublingWork(NamedTuple):
    """The structure-preserving doubling iteration (:func:`doubling`)."""

    A_k: NDArray  # the iterates A_k, G_k, H_k (n, n)
    G_k: NDArray
    H_k: NDArray
    W: NDArray  # I + G_k H_k, then the products of a step (n, n)
    W_inv: NDArray  # W^{-1} (n, n)
    T1: NDArray  # W^{-1} A_k (n, n)
    T2: NDArray  # W^{-1} G_k (n, n)
    T3: NDArray  # H_k W^{-1} A_k, A_k W^{-1} G_k (n, n)


class CrossWeightWork(NamedTuple):
    """The solve of :func:`dare_solve`: the problem without cross weight and Newton's method."""

    R_lu: NDArray  # R, reduced by the inversion (m, m)
    R_inv: NDArray  # R^{-1} (m, m)
    RinvNt: NDArray  # R^{-1} N^T (m, n)
    RinvBt: NDArray  # R^{-1} B^T (m, n)
    A_N: NDArray  # A - B R^{-1} N^T (n, n)
    Q_N: NDArray  # Q - N R^{-1} N^T (n, n)
    P_sol: NDArray  # the solution until it is accepted (n, n)
    K_sol: NDArray  # its gain (m, n)
    P_prev: NDArray  # Newton's previous iterate (n, n)


class FeedforwardWork(NamedTuple):
    """The cheapest equilibrium (:func:`steady_state_feedforward`) and the safe set."""

    KKT: NDArray  # the KKT matrix, reduced by the inversion (2n + m, 2n + m)
    KKT_inv: NDArray  # its inverse (2n + m, 2n + m)
    M_x: NDArray  # x_s = M_x r (n, n)
    M_u: NDArray  # u_s = M_u r, then F = M_u + K M_x (m, n)
    F_try: NDArray  # the candidate feed-forward (m, n)


#: The scratch of the multi-input designs: the fields of :class:`GainWork`,
#: :class:`ClosedLoopWork`, :class:`DoublingWork`, :class:`CrossWeightWork` and
#: :class:`FeedforwardWork`, one row a lane (``w.K_sol[lane]``), shapes in
#: :func:`mimo_design_shapes`.
MimoDesignWork = NamedTuple(  # type: ignore[misc]
    "MimoDesignWork",
    fields_of(GainWork, ClosedLoopWork, DoublingWork, CrossWeightWork, FeedforwardWork),
)


def doubling_shapes(n: int) -> dict[str, tuple[int, ...]]:
    """The shapes of the :class:`DoublingWork` fields for ``n`` states (every one ``n x n``)."""
    return dict.fromkeys(DoublingWork._fields, (int(n), int(n)))


def mimo_design_shapes(n: int, m: int) -> dict[str, tuple[int, ...]]:
    """The shapes of one lane's :data:`MimoDesignWork` fields for ``n`` states and ``m``
    inputs: the one place they are declared."""
    n, m = int(n), int(m)
    s = 2 * n + m
    return {
        "PB": (n, m),
        **dict.fromkeys(("S", "S_inv", "R_lu", "R_inv"), (m, m)),
        **dict.fromkeys(("BPA", "RK", "RinvNt", "RinvBt", "K_sol", "M_u", "F_try"), (m, n)),
        **dict.fromkeys(("A_cl", "P_Acl", "X", "X2", "A_N", "Q_N", "P_sol", "P_prev"), (n, n)),
        **doubling_shapes(n),
        **dict.fromkeys(("KKT", "KKT_inv"), (s, s)),
        "M_x": (n, n),
    }


def mimo_design_work(n: int, m: int, num_lanes: int = 1) -> Any:
    """A :data:`MimoDesignWork` of ``num_lanes`` lanes for ``n`` states and ``m`` inputs."""
    return make_work(MimoDesignWork, mimo_design_shapes(n, m), num_lanes)


@lane(inline=True)
def _closed_loop(A, B, K, Acl):
    """``Acl = A - B K``."""
    matmul(B, K, Acl, False, False)
    for i in range(A.shape[0]):
        for j in range(A.shape[0]):
            Acl[i, j] = A[i, j] - Acl[i, j]


@lane(entry=True, inline=True)
def lq_gain(A, B, c, P, K, w, lane_i):
    """``K = (R + B^T P B)^{-1} (B^T P A + N^T)`` (``R``, ``N`` of the :class:`LQProblem`
    ``c``); ``False`` when ``R + B^T P B`` is singular (scratch: the :class:`GainWork` fields of
    lane ``lane_i`` of ``w``)."""
    R, N = c.R, c.N
    n = A.shape[0]
    m = B.shape[1]
    PB = w.PB[lane_i]
    Sm = w.S[lane_i]
    Sinv = w.S_inv[lane_i]
    T = w.BPA[lane_i]
    matmul(P, B, PB, False, False)
    matmul(B, PB, Sm, True, False)
    for i in range(m):
        for j in range(m):
            Sm[i, j] += R[i, j]
    if not invert(Sm, Sinv):
        return False
    matmul(PB, A, T, True, False)  # B^T P A (P symmetric)
    for i in range(m):
        for j in range(n):
            T[i, j] += N[j, i]
    matmul(Sinv, T, K, False, False)
    return True


@lane(inline=True)
def _stage_weight(Q, R, N, K, KR, M):
    """``M = [I; -K]^T W [I; -K] = Q - N K - K^T N^T + K^T R K`` (symmetric; ``KR`` ``m x n``
    scratch)."""
    n = Q.shape[0]
    m = R.shape[0]
    matmul(R, K, KR, False, False)
    for i in range(n):
        for j in range(i, n):
            acc = Q[i, j]
            for k in range(m):
                acc += K[k, i] * KR[k, j] - N[i, k] * K[k, j] - K[k, i] * N[j, k]
            M[i, j] = acc
            M[j, i] = acc


@lane(inline=True)
def riccati_step(A, B, c, P, K, w, lane_i):
    """One Riccati iteration (Joseph form) on ``P`` in place for the :class:`LQProblem` ``c``;
    ``K`` the gain of the old ``P``. Returns ``False`` when the gain is undefined."""
    n = A.shape[0]
    if not lq_gain(A, B, c, P, K, w, lane_i):
        return False
    Acl = w.A_cl[lane_i]
    T = w.P_Acl[lane_i]
    KR = w.RK[lane_i]
    _closed_loop(A, B, K, Acl)
    matmul(P, Acl, T, False, False)
    _stage_weight(c.Q, c.R, c.N, K, KR, P)
    for i in range(n):
        for j in range(i, n):
            acc = 0.0
            for k in range(n):
                acc += Acl[k, i] * T[k, j]
            P[i, j] += acc
            if j > i:
                P[j, i] += acc
    return True


@lane(inline=True)
def schur_stable(M, w, lane_i):
    """Spectral radius of ``M`` below 1, by repeated squaring (scratch ``w.X``, ``w.X2``).

    Stable when ``||M^(2^k)||_F < 1/2`` for some ``k <= MAX_SQUARINGS``; unstable when a norm
    exceeds ``1e100`` or is not finite; undecided counts as unstable.
    """
    n = M.shape[0]
    X = w.X[lane_i]
    Y = w.X2[lane_i]
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
def doubling(Ak, Gk, Hk, w, lane_i, tol, max_iter):
    """The structure-preserving doubling iteration, from ``A_0``, ``G_0``, ``H_0`` in ``Ak``,
    ``Gk``, ``Hk`` (``n x n``, overwritten; ``G_0`` and ``H_0`` symmetric):
    ``W = I + G_k H_k``, ``A_{k+1} = A_k W^{-1} A_k``, ``G_{k+1} = G_k + A_k W^{-1} G_k A_k^T``,
    ``H_{k+1} = H_k + A_k^T H_k W^{-1} A_k`` (both kept symmetric), until the step of ``H`` is at
    most ``tol max(1, |H_k|)``; ``H_k -> P``, the stabilising DARE solution when there is one.

    Returns ``OK`` (``Hk`` converged), ``NOT_STABILISABLE`` (a singular ``W``, or an iterate
    above :data:`P_MAX` or not finite: diverging) or ``NOT_CONVERGED``. Scratch: the
    :class:`DoublingWork` fields of lane ``lane_i`` of ``w``.
    """
    n = Ak.shape[0]
    W = w.W[lane_i]
    Winv = w.W_inv[lane_i]
    T1 = w.T1[lane_i]
    T2 = w.T2[lane_i]
    T3 = w.T3[lane_i]
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


@lane
def _doubling_from(B, delta, c, w, lane_i):
    """:func:`doubling` from ``A_0 = A_N``, ``G_0 = B R^{-1} B^T``, ``H_0 = Q_N + delta I``
    (``A_N``, ``R^{-1}``, ``Q_N`` in ``w`` from :func:`dare_solve`); the result in
    ``w.H_k[lane]``."""
    AN = w.A_N[lane_i]
    QN = w.Q_N[lane_i]
    Rinv = w.R_inv[lane_i]
    n = AN.shape[0]
    Ak = w.A_k[lane_i]
    Gk = w.G_k[lane_i]
    Hk = w.H_k[lane_i]
    RB = w.RinvBt[lane_i]
    matmul(Rinv, B, RB, False, True)  # R^{-1} B^T
    matmul(B, RB, Gk, False, False)
    copy_matrix(AN, Ak)
    copy_matrix(QN, Hk)
    for i in range(n):
        Hk[i, i] += delta
    return doubling(Ak, Gk, Hk, w, lane_i, c.solve_tol, c.solve_max_iter)


@lane
def _stabilising_gain(A, B, c, P, K, w, lane_i):
    """``K`` the gain of ``P``, and whether ``A - B K`` is Schur stable."""
    if not lq_gain(A, B, c, P, K, w, lane_i):
        return False
    Acl = w.A_cl[lane_i]
    _closed_loop(A, B, K, Acl)
    return schur_stable(Acl, w, lane_i)


@lane
def _stein(F0, X, c, w, lane_i):
    """``X <- sum_k F0^{kT} X F0^k``, the solution of the Stein equation ``X = F0^T X F0 + M``
    from ``X = M`` on entry: Smith's doubling ``X_{j+1} = X_j + F_j^T X_j F_j``,
    ``F_{j+1} = F_j^2``, which is :func:`doubling` with ``A_0 = F0``, ``G_0 = 0``, ``H_0 = X``.
    Returns ``OK``, ``NOT_STABILISABLE`` (diverging: ``F0`` is not Schur stable) or
    ``NOT_CONVERGED``."""
    n = F0.shape[0]
    F = w.A_k[lane_i]
    G = w.G_k[lane_i]
    copy_matrix(F0, F)
    for i in range(n):
        for j in range(n):
            G[i, j] = 0.0
    return doubling(F, G, X, w, lane_i, c.solve_tol, c.solve_max_iter)


@lane
def _newton(A, B, c, P, K, w, lane_i):
    """Newton's method (Hewer's iteration, :func:`dare_solve`) from the stabilising gain ``K``.
    Returns ``OK`` with the stabilising solution in ``P`` and its gain in ``K``,
    ``UNIT_CIRCLE_MODE`` when the limit's closed loop is not Schur stable, or
    ``NOT_CONVERGED``."""
    n = A.shape[0]
    tol = c.solve_tol
    Acl = w.A_cl[lane_i]
    KR = w.RK[lane_i]
    Pprev = w.P_prev[lane_i]
    d_prev = math.inf
    status = NOT_CONVERGED
    for _ in range(NEWTON_MAX_ITER):
        copy_matrix(P, Pprev)
        _closed_loop(A, B, K, Acl)
        _stage_weight(c.Q, c.R, c.N, K, KR, P)
        if _stein(Acl, P, c, w, lane_i) != OK:
            # the previous gain stabilised, this one barely does: the iterates approach a
            # closed loop on the unit circle
            copy_matrix(Pprev, P)
            status = UNIT_CIRCLE_MODE
            break
        if not lq_gain(A, B, c, P, K, w, lane_i):
            return NOT_STABILISABLE
        d = 0.0
        for i in range(n):
            for j in range(n):
                d = max(d, abs(P[i, j] - Pprev[i, j]))
        pmax = max_abs(P)
        # converged, or at the rounding floor (no progress once near the solution)
        if d <= tol * pmax or (d >= d_prev and d <= 1e-6 * pmax):
            status = OK
            break
        d_prev = d
    if status == NOT_CONVERGED:
        return status
    if not _stabilising_gain(A, B, c, P, K, w, lane_i):
        return UNIT_CIRCLE_MODE
    return status


@lane(entry=True)
def dare_solve(A, B, c, P, K, w, lane_i):
    """Stabilising DARE solution ``P`` and its gain ``K``.

    The cross weight is removed first (``A_N = A - B R^{-1} N^T``, ``Q_N = Q - N R^{-1} N^T``;
    the gain is then ``K = K_N + R^{-1} N^T``), then the structure-preserving doubling algorithm
    (:func:`doubling` from ``A_0 = A_N``, ``G_0 = B R^{-1} B^T``, ``H_0 = Q_N``) solves it.
    Doubling converges to the stabilising solution only when the dual equation has one too,
    i.e. when ``(Q_N, A_N)`` is detectable; with a positive semidefinite ``Q_N`` that leaves an
    unstable mode unweighted it stops at another solution. Its closed loop is then not Schur
    stable, and the solve falls back on Newton's method (Hewer 1971, "An iterative technique for
    the computation of the steady state gains for the discrete optimal regulator", IEEE TAC
    16(4)): from the stabilising gain of the regularised weight ``Q_N + delta I`` (doubling
    again, always detectable), ``P_k`` solves the Stein equation
    ``P = (A - B K_k)^T P (A - B K_k) + [I; -K_k]^T W [I; -K_k]`` (:func:`_stein`) and
    ``K_{k+1}`` is the gain of ``P_k``. The iterates stay stabilising and decrease to the
    largest solution, quadratically when it is stabilising: it exists whenever ``(A, B)`` is
    stabilisable and no mode on the unit circle is unobservable through ``Q_N``.

    Returns ``OK``, ``NOT_STABILISABLE`` (``(A, B)`` not stabilisable, or ``R`` singular),
    ``UNIT_CIRCLE_MODE`` (a mode on the unit circle unobservable through ``Q_N``) or
    ``NOT_CONVERGED``. ``P`` and ``K`` are written only on ``OK``. ``c``: the weights and limits
    (an :class:`LQProblem`); ``w``: a :data:`MimoDesignWork` for ``(n, m)``
    (:func:`mimo_design_work`), lane ``lane_i`` used.
    """
    Q, R, N = c.Q, c.R, c.N
    n = A.shape[0]
    if w.A_N.shape[1] != n or w.R_inv.shape[1] != B.shape[1]:
        raise ValueError("dare_solve: w is not the scratch of this (n, m) (mimo_design_work)")
    Rinv = w.R_inv[lane_i]
    Rc = w.R_lu[lane_i]
    RNt = w.RinvNt[lane_i]
    AN = w.A_N[lane_i]
    QN = w.Q_N[lane_i]
    copy_matrix(R, Rc)
    if not invert(Rc, Rinv):
        return NOT_STABILISABLE
    # remove the cross weight: A_N = A - B R^{-1} N^T, Q_N = Q - N R^{-1} N^T
    matmul(Rinv, N, RNt, False, True)
    matmul(B, RNt, AN, False, False)
    matmul(N, RNt, QN, False, False)
    for i in range(n):
        for j in range(n):
            AN[i, j] = A[i, j] - AN[i, j]
    for i in range(n):
        for j in range(i, n):
            v = 0.5 * (Q[i, j] + Q[j, i]) - 0.5 * (QN[i, j] + QN[j, i])
            QN[i, j] = v
            QN[j, i] = v
    Psol = w.P_sol[lane_i]
    Kt = w.K_sol[lane_i]
    status = _doubling_from(B, 0.0, c, w, lane_i)
    if status == OK:
        copy_matrix(w.H_k[lane_i], Psol)
        if _stabilising_gain(A, B, c, Psol, Kt, w, lane_i):
            copy_matrix(Psol, P)
            copy_matrix(Kt, K)
            return OK
    if status == NOT_CONVERGED:
        return status
    # doubling stopped at a solution that is not stabilising (or diverged): start Newton's
    # method from the stabilising gain of the regularised weight Q_N + delta I
    bmax = max_abs(B)
    delta = max_abs(QN)
    if bmax > 0.0:
        delta = max(delta, max_abs(R) / (bmax * bmax))
    if not delta > 0.0:
        delta = 1.0
    status = _doubling_from(B, delta, c, w, lane_i)
    if status == NOT_CONVERGED:
        return status
    if status != OK:
        return NOT_STABILISABLE
    copy_matrix(w.H_k[lane_i], Psol)
    if not _stabilising_gain(A, B, c, Psol, Kt, w, lane_i):
        return NOT_STABILISABLE
    status = _newton(A, B, c, Psol, Kt, w, lane_i)
    if status != OK:
        return status
    copy_matrix(Psol, P)
    copy_matrix(Kt, K)
    return OK


@lane(entry=True, inline=True)
def steady_state_feedforward(A, B, c, K, F, w, lane_i):
    """``F = M_u + K M_x`` of the cheapest equilibrium; ``False`` when the KKT matrix is
    singular (no equilibrium for some reference: an uncontrollable mode at ``z = 1``). ``F`` is
    written only on success.

    For a constant reference ``r``: minimise ``[x_s - r; u_s]^T W [x_s - r; u_s]`` subject to
    ``(A - I) x_s + B u_s = 0`` (the stationary point of the average-cost LQ tracking problem),
    from the KKT system
    ``[[Q, N, (A - I)^T], [N^T, R, B^T], [A - I, B, 0]] [x_s; u_s; mu] = [Q r; N^T r; 0]``,
    linear in ``r``: ``x_s = M_x r``, ``u_s = M_u r``, and the law ``u = u_s - K (x - x_s)`` is
    ``u = -K x + F r``. With fewer inputs than states not every reference is an equilibrium;
    this is the equilibrium nearest to it in the cost (``Q``, ``R``, ``N`` of the
    :class:`LQProblem` ``c``).
    """
    Q, R, N = c.Q, c.R, c.N
    n = A.shape[0]
    m = B.shape[1]
    s = 2 * n + m
    M = w.KKT[lane_i]
    Minv = w.KKT_inv[lane_i]
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
            M[i, n + j] = N[i, j]
            M[n + j, i] = N[i, j]
    for i in range(m):
        for j in range(m):
            M[n + i, n + j] = R[i, j]
    if not invert(M, Minv):
        return False
    Mx = w.M_x[lane_i]
    Mu = w.M_u[lane_i]
    for i in range(n):  # M_x = Minv[:n, :n] Q + Minv[:n, n:n+m] N^T
        for j in range(n):
            acc = 0.0
            for k in range(n):
                acc += Minv[i, k] * Q[k, j]
            for k in range(m):
                acc += Minv[i, n + k] * N[j, k]
            Mx[i, j] = acc
    for i in range(m):  # M_u = Minv[n:n+m, :n] Q + Minv[n:n+m, n:n+m] N^T
        for j in range(n):
            acc = 0.0
            for k in range(n):
                acc += Minv[n + i, k] * Q[k, j]
            for k in range(m):
                acc += Minv[n + i, n + k] * N[j, k]
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


@lane(inline=True)
def design_checks(A, B, cfg, K, F, w, lane_i):
    """The safe set of a candidate gain ``K`` on the model ``(A, B)``: finite, ``max |B| >=
    cfg.b_min``, closed loop Schur stable, feed-forward defined (the weights of ``cfg``, an
    :class:`LQProblem` with ``b_min`` and ``gain_max``, such as the multivariable controller's
    configuration), ``max |K|, |F| <= cfg.gain_max``. Writes ``F`` (on success) and returns the
    status code of :mod:`.safe_set`."""
    if not (max_abs(A) < math.inf and max_abs(B) < math.inf):
        return NONFINITE
    if not max_abs(B) >= cfg.b_min:
        return B_SMALL
    Acl = w.A_cl[lane_i]
    _closed_loop(A, B, K, Acl)
    if not schur_stable(Acl, w, lane_i):
        return NOT_STABILISABLE
    Fc = w.F_try[lane_i]
    if not steady_state_feedforward(A, B, cfg, K, Fc, w, lane_i):
        return DC_SINGULAR
    gain_max = cfg.gain_max
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
