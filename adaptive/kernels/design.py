"""Certainty-equivalence design and tracking law: compiled lane functions (one implementation).

Every function here works on one plant's small arrays (see :mod:`stcgym.envs.compiled` for the
lane convention: no BLAS/LAPACK, small dense loops written out, status codes instead of
exceptions). The self-tuning controller, the known-model oracles
(:mod:`stcgym.adaptive.oracles`) and the public numpy helpers of
:mod:`stcgym.adaptive.placement` all call these, for one plant or inside a ``prange`` over lanes.

Model and augmentation
----------------------
``theta = [a1..an, b1..bn]`` of a canonical form (Ding & Ma 2014, observer form eq. (1)-(5),
``form = OBSERVER`` (0); observability form eq. (146)-(147), ``form = OBSERVABILITY`` (1)), with
``c = [1, 0, ..., 0]``; :func:`model_matrices` builds ``(A, b)``. With ``integral = True`` the
design runs on the integral-augmented model of ``xi(t+1) = xi(t) + r(t) - y(t)``,

    A_aug = [[A, 0], [-c, 1]],  b_aug = [b; 0]    (m = n + 1 states; m = n without integral).

Gain record ``gain`` (float64, length ``gain_size(n) = n + 4``)
--------------------------------------------------------------
``gain[0:n] = K_x``, ``gain[n] = k_i`` (0 without integral action), ``gain[n + 1] = N``
(reference feed-forward, 0 when off), ``gain[n + 2] = 1.0`` once a design has succeeded
(``has_gain``; 0.0 = no gain yet, the law then applies only the excitation) and
``gain[n + 3]`` the reciprocal condition number of the accepted design's controllability matrix.
The design functions write ``gain`` **only on success**: a rejected model keeps the last good
gain.

Safe set ``safe`` (float64, length 4; :func:`safe_set` builds and validates it)
------------------------------------------------------------------------------
``[b_min, rcond_min, dc_rcond_min, gain_max]``, tested in this order, first failure reported:

==== ================== ==============================================================
code name               meaning
==== ================== ==============================================================
0    ``ok``             gain accepted and written
1    ``nonfinite``      ``theta`` is not finite
2    ``b_small``        ``max |b| < b_min``
3    ``uncontrollable`` reciprocal 1-norm condition of the column-normalised controllability
                        matrix of the (augmented) model ``<= max(rcond_min, 1e-14)``
4    ``dc_singular``    feed-forward on and the steady-state (Rosenbrock) matrix
                        ``[[A - I, b], [c, 0]]`` has rcond ``< max(dc_rcond_min, 1e-13)``
                        (a zero at ``z = 1``: no steady state for a constant reference)
5    ``gain_large``     ``max(|K|, |N|) > gain_max`` (or non-finite)
6    ``not_stabilisable`` LQ: the Riccati iterate / doubling blew up (``> 1e150``) or the
                        converged gain does not give a Schur-stable closed loop (Schur-Cohn
                        test of its characteristic polynomial); the one-step
                        variant re-initialises ``P`` to the state weight ``Q``
7    ``not_converged``  LQ solve: no convergence within ``max_iter`` doubling steps
==== ================== ==============================================================

``STATUS_NAMES[code]`` gives the name (the reason strings of the former ``TrackingLaw.design``).

Work array ``work``
-------------------
Scratch, float64, 1-D: ``work_size(n) = 5 (n+1)^2 + 9 (n+1)`` floats for ``place_design`` and
``lq_design`` (72 at ``n = 2``), ``solve_work_size(n) = 13 (n+1)^2 + 9 (n+1)`` for ``lq_solve``
(the solve-to-convergence variant, meant for a fresh model, not every step). Its content is
irrelevant between calls; one per thread (or per lane) is enough, never shared by two lanes
running at the same time. A shorter array raises ``ValueError`` (numba's constant-message
raise) instead of corrupting the result.

Lane functions (all ``@lane``; arrays are float64 unless noted)
--------------------------------------------------------------
``place_design(theta, form, integral, feedforward, alpha, safe, gain, work) -> int``
    Ackermann pole placement of the ``m`` poles with monic characteristic polynomial
    ``z^m + alpha[0] z^{m-1} + ... + alpha[m-1]`` (``alpha`` length ``m``) on the (augmented)
    model of ``theta``; ``N = u_ss + K_x x_ss`` from the steady state. Returns the status code.
``lq_design(theta, form, integral, feedforward, weights, safe, P, gain, work) -> int``
    Self-tuning LQ: **one** Riccati iteration per call on the (augmented) model of ``theta``,
    warm-started from ``P`` (``m x m``, C-contiguous 2-D, updated in place); the gain is the LQ
    gain of the updated ``P``. ``weights = [q_y, q_i, rho]``: state weight ``Q = q_y c^T c``
    (+ ``q_i`` on the integrator), input weight ``rho``; defaults ``DEFAULT_LQ_WEIGHTS``
    ``= [1, 1e-4, 1e-2]`` (the envs' cost ``(y - r)^2 + rho u^2`` with their default
    ``control_cost = 0.01``, as the LQG oracle, and a small weight that keeps the integrator
    detectable: with ``1e-2`` the self-tuning LQ loop cost 1.04-1.21x the oracle's in steady
    state, with ``1e-4`` 1.01-1.04x).
    :func:`lq_weights` validates them. Initialise ``P`` with :func:`lq_initial_P` (``= Q``) or a
    converged solution; a ``P`` that is not finite on entry restarts from ``Q``.
``lq_solve(theta, form, integral, feedforward, weights, safe, P, gain, work, tol, max_iter)``
    ``-> int``: the same design solved to convergence (structured doubling, for a fresh model);
    writes the stabilising DARE solution into ``P`` on success.
``track(gain, law, x, y, r, excitation, action_bound, integral, anti_windup) -> float``
    The tracking law ``u = sat(-K_x x - k_i xi + N r + e)`` with anti-windup by conditional
    integration, over the law state ``law`` (length ``LAW_SIZE = 3``:
    ``[xi, saturated (0/1), u_unsat]``); advances ``xi`` and returns the applied ``u``.
    ``action_bound = inf`` means no saturation; ``integral``/``anti_windup`` are booleans.
``filtered_state(x, P1, R, y, x_filt) -> float``
    The current estimate ``x(t|t)`` of the seed paper's Kalman filter (eq. (66)-(72)); written
    in :mod:`stcgym.adaptive.kernels.state_estimation` beside its time update ``kalman_step``
    (one Kalman filter, also used by the estimators' filtered regressor) and re-exported here.

Known-model loop (the oracles of :mod:`stcgym.adaptive.oracles`): ``known_model_propose(f, off,
n, s, y, r, filtered, integral, anti_windup, action_bound) -> int`` computes one step (Kalman
correction, :func:`track`, Kalman prediction) of the lane record ``f`` (fields
``ORACLE_FIELDS``, offsets ``off``) into the proposal buffer ``s`` (``oracle_scratch_size(n)``)
without touching ``f``; ``known_model_commit(f, off, n, s) -> u`` makes it the state. The batch
loops ``known_model_propose_lanes`` / ``known_model_commit_lanes`` let a batched ``predict``
reject a step atomically (no lane changes unless every lane's proposal is finite).

Batch loops (``@lanes``, a ``prange`` over the rows; each lane allocates its own scratch):
``model_matrices_lanes(thetas, form, A, b)``, ``place_design_lanes(thetas, form, integral,
feedforward, alpha, safe, gains, status)``, ``lq_solve_lanes(thetas, form, integral,
feedforward, weights, safe, Ps, gains, status, tol, max_iter)`` and
``kalman_covariance_lanes(thetas, form, W, R, Ps, status, tol, max_iter)`` (the steady-state
Kalman filter covariance of each lane's canonical model, lane function
``kalman_covariance(theta, form, W, R, P, tol, max_iter) -> int``: :func:`dare` on the dual
problem). A single plant calls the lane functions directly (no thread pool, no parallel
compile).

General-matrix building blocks (used by the public numpy helpers of ``placement``; on an
``m x m`` pair ``ackermann_gain`` needs ``work_size(m - 1)`` floats, ``dare``
``solve_work_size(m - 1)``, ``steady_state`` on ``n x n`` ``work_size(n)``):
``ackermann_gain(A, b, alpha, K, work) -> rcond`` (``rcond <= 0``: singular; ``K`` written only
when ``rcond > 0``), ``steady_state(A, b, x_ss, work) -> (u_ss, rcond)``,
``dare(A, b, Q, rho, char_A, P, K, work, tol, max_iter) -> int`` (status 0 / 6 / 7; ``char_A``
the coefficients of ``det(zI - A)``).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from stcgym.adaptive.kernels.records import view2d, view3d
from stcgym.adaptive.kernels.state_estimation import (
    filtered_state,
    is_schur_stable,
    kalman_step,
)
from stcgym.envs.compiled import lane, lanes, prange

__all__ = [
    "DEFAULT_LQ_WEIGHTS",
    "LAW_SIZE",
    "OBSERVABILITY",
    "OBSERVER",
    "STATUS_NAMES",
    "ackermann_gain",
    "dare",
    "gain_size",
    "ORACLE_FIELDS",
    "filtered_state",
    "kalman_covariance",
    "kalman_covariance_lanes",
    "known_model_commit",
    "known_model_commit_lanes",
    "known_model_propose",
    "known_model_propose_lanes",
    "lq_design",
    "lq_initial_P",
    "lq_weights",
    "lq_solve",
    "lq_solve_lanes",
    "model_matrices",
    "model_matrices_lanes",
    "oracle_scratch_size",
    "place_design",
    "place_design_lanes",
    "safe_set",
    "steady_state",
    "track",
    "solve_work_size",
    "work_size",
]

OBSERVER = 0
OBSERVABILITY = 1

OK = 0
NONFINITE = 1
B_SMALL = 2
UNCONTROLLABLE = 3
DC_SINGULAR = 4
GAIN_LARGE = 5
NOT_STABILISABLE = 6
NOT_CONVERGED = 7
STATUS_NAMES = (
    "ok",
    "nonfinite",
    "b_small",
    "uncontrollable",
    "dc_singular",
    "gain_large",
    "not_stabilisable",
    "not_converged",
)

# Safe-set vector entries.
B_MIN, RCOND_MIN, DC_RCOND_MIN, GAIN_MAX = 0, 1, 2, 3
# Law-state entries.
XI, SATURATED, U_UNSAT = 0, 1, 2
LAW_SIZE = 3
# LQ weights entries and defaults.
Q_Y, Q_I, RHO = 0, 1, 2
DEFAULT_LQ_WEIGHTS = (1.0, 1e-4, 1e-2)

#: Riccati iterates above this are taken as diverging (a non-stabilisable model).
P_MAX = 1e150
#: Floors of the conditioning tests (below them a "solution" is rounding noise).
RCOND_FLOOR = 1e-14
DC_RCOND_FLOOR = 1e-13

# Work layout, in units of mm = n + 1: [5 matrices (13 to solve) | 9 vectors].
_N_MAT = 5  # matrix slots every design needs, each mm x mm
_N_VEC = 9  # vector slots, each mm
_N_MAT_SOLVE = 13  # matrix slots of the solve-to-convergence variants
_A, _AD, _M0, _M1, _M2, _M3, _M4, _M5, _M6, _M7, _M8, _M9, _M10 = range(13)
_BD, _KW, _XSS, _V0, _V1, _V2, _V3, _V4, _V5 = range(9)


def gain_size(n: int) -> int:
    """Length of the gain record: ``[K_x (n), k_i, N, has_gain, rcond]``."""
    return int(n) + 4


def work_size(n: int) -> int:
    """Scratch length of ``place_design``, ``lq_design`` (and ``ackermann_gain``,
    ``steady_state``) for order ``n``: ``5 (n+1)^2 + 9 (n+1)``."""
    mm = int(n) + 1
    return _N_MAT * mm * mm + _N_VEC * mm


def solve_work_size(n: int) -> int:
    """Scratch length of ``lq_solve`` (and ``dare``) for order ``n``: ``13 (n+1)^2 + 9 (n+1)``."""
    mm = int(n) + 1
    return _N_MAT_SOLVE * mm * mm + _N_VEC * mm


def safe_set(
    b_min: float = 0.0,
    rcond_min: float = 0.0,
    dc_rcond_min: float = 0.0,
    gain_max: float = math.inf,
) -> NDArray[np.float64]:
    """Validated safe-set vector ``[b_min, rcond_min, dc_rcond_min, gain_max]``.

    Raises ``ValueError`` naming the setting for anything but a finite ``b_min >= 0``,
    ``0 <= rcond_min < 1``, ``0 <= dc_rcond_min < 1`` and ``gain_max > 0`` (``inf`` allowed):
    ``gain_max <= 0`` would reject every design and leave the loop open for ever.
    """
    vals = {}
    for name, value in (
        ("b_min", b_min),
        ("rcond_min", rcond_min),
        ("dc_rcond_min", dc_rcond_min),
        ("gain_max", gain_max),
    ):
        try:
            vals[name] = float(value)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{name} must be a real number, got {value!r}") from exc
    if not (math.isfinite(vals["b_min"]) and vals["b_min"] >= 0.0):
        raise ValueError(f"b_min must be a finite number >= 0, got {b_min!r}")
    for name in ("rcond_min", "dc_rcond_min"):
        if not (0.0 <= vals[name] < 1.0):
            raise ValueError(
                f"{name} must lie in [0, 1) (a reciprocal condition), got {vals[name]}"
            )
    if not vals["gain_max"] > 0.0:  # also rejects nan
        raise ValueError(
            f"gain_max must be > 0 (inf for no limit), got {gain_max!r}: with gain_max <= 0 every "
            "design is rejected and the loop never closes"
        )
    return np.array(
        [vals["b_min"], vals["rcond_min"], vals["dc_rcond_min"], vals["gain_max"]],
        dtype=np.float64,
    )


def lq_weights(
    q_y: float = DEFAULT_LQ_WEIGHTS[0],
    q_i: float = DEFAULT_LQ_WEIGHTS[1],
    rho: float = DEFAULT_LQ_WEIGHTS[2],
    *,
    integral: bool = True,
) -> NDArray[np.float64]:
    """Validated LQ weights ``[q_y, q_i, rho]`` for :func:`lq_design` / :func:`lq_solve`.

    ``q_y`` (output) and ``rho`` (input) must be finite and > 0; ``q_i`` (integrator) > 0 with
    integral action (with ``q_i = 0`` the integrator is invisible to the cost, so no LQ gain
    stabilises it) and >= 0 without. Raises ``ValueError`` naming the weight.
    """
    vals = []
    for name, value, positive in (
        ("q_y", q_y, True),
        ("q_i", q_i, bool(integral)),
        ("rho", rho, True),
    ):
        try:
            v = float(value)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"LQ weight {name} must be a real number, got {value!r}") from exc
        ok = (0.0 < v if positive else 0.0 <= v) and math.isfinite(v)
        if not ok:
            raise ValueError(
                f"LQ weight {name} must be a finite number {'>' if positive else '>='} 0, "
                f"got {value!r}"
            )
        vals.append(v)
    return np.array(vals, dtype=np.float64)


def lq_initial_P(n: int, integral: bool, weights: NDArray) -> NDArray[np.float64]:
    """Cold start of the one-step Riccati iteration: ``P = Q`` (``m x m``)."""
    m = int(n) + int(bool(integral))
    P = np.zeros((m, m))
    P[0, 0] = weights[Q_Y]
    if integral:
        P[n, n] = weights[Q_I]
    return P


# ------------------------------------------------------------------------------ small helpers
@lane(inline=True)
def _split_work(work, mm, n_mat):
    """The scratch as ``Ws`` ``(n_mat, mm, mm)`` and ``Vs`` ``(9, mm)`` views (every slot after
    that a cheap basic slice ``Ws[slot, :m, :m]``). A scratch shorter than that would corrupt
    the result, so it is an error. Inlined into its caller: a lane function compiled without
    NRT may return views only where numba inlines it."""
    if work.size < n_mat * mm * mm + _N_VEC * mm:
        raise ValueError("work array too short: see work_size(n) / solve_work_size(n)")
    return view3d(work, 0, n_mat, mm, mm), view2d(work, n_mat * mm * mm, _N_VEC, mm)


@lane(inline=True)
def _all_finite(v):
    for i in range(v.size):
        if not math.isfinite(v.flat[i]):
            return False
    return True


@lane(inline=True)
def _matmul(X, Y, out, trans_x=False, trans_y=False):
    """``out = op(X) @ op(Y)`` for small square matrices, ``op`` the transpose when asked
    (``out`` distinct from ``X`` and ``Y``)."""
    m = X.shape[0]
    for i in range(m):
        for j in range(m):
            s = 0.0
            for k in range(m):
                s += (X[k, i] if trans_x else X[i, k]) * (Y[j, k] if trans_y else Y[k, j])
            out[i, j] = s


@lane(inline=True)
def _norm1(M):
    """Largest absolute column sum."""
    m = M.shape[0]
    best = 0.0
    for j in range(m):
        s = 0.0
        for i in range(m):
            s += abs(M[i, j])
        if s > best or not math.isfinite(s):
            best = s
    return best


@lane(inline=True)
def _max_abs(M):
    best = 0.0
    for i in range(M.size):
        v = abs(M.flat[i])
        if v > best or not math.isfinite(v):
            best = v
    return best


@lane(inline=True)
def _invert(M, Minv):
    """Gauss-Jordan inverse with partial pivoting; ``M`` is destroyed. False if singular."""
    m = M.shape[0]
    for i in range(m):
        for j in range(m):
            Minv[i, j] = 1.0 if i == j else 0.0
    for col in range(m):
        piv = col
        best = abs(M[col, col])
        for i in range(col + 1, m):
            if abs(M[i, col]) > best:
                best = abs(M[i, col])
                piv = i
        if not (best > 0.0 and math.isfinite(best)):
            return False
        if piv != col:
            for j in range(m):
                tmp = M[col, j]
                M[col, j] = M[piv, j]
                M[piv, j] = tmp
                tmp = Minv[col, j]
                Minv[col, j] = Minv[piv, j]
                Minv[piv, j] = tmp
        inv_p = 1.0 / M[col, col]
        for j in range(m):
            M[col, j] *= inv_p
            Minv[col, j] *= inv_p
        for i in range(m):
            if i != col:
                f = M[i, col]
                if f != 0.0:
                    for j in range(m):
                        M[i, j] -= f * M[col, j]
                        Minv[i, j] -= f * Minv[col, j]
    return True


# ------------------------------------------------------------------------------ model
@lane(inline=True)
def model_matrices(theta, form, A, b):
    """Write the canonical-form ``A`` (``n x n``) and ``b`` of ``theta = [a; b]``.

    Observer form, eq. (1): first column ``-a``, ones above the diagonal. Observability form,
    eq. (146): ones above the diagonal, last row ``[-a_n, ..., -a_1]``.
    """
    n = theta.size // 2
    for i in range(n):
        for j in range(n):
            A[i, j] = 1.0 if j == i + 1 else 0.0
        b[i] = theta[n + i]
    if form == OBSERVER:
        for i in range(n):
            A[i, 0] = -theta[i]
    else:
        for j in range(n):
            A[n - 1, j] = -theta[n - 1 - j]


@lane(inline=True)
def _augment(A, b, integral, Ad, bd):
    """``(A_aug, b_aug)`` of the integral state ``xi(t+1) = xi(t) + r(t) - c x(t)`` (or a copy)."""
    n = A.shape[0]
    for i in range(n):
        for j in range(n):
            Ad[i, j] = A[i, j]
        bd[i] = b[i]
    if integral:
        for j in range(n + 1):
            Ad[n, j] = 0.0
            Ad[j, n] = 0.0
        Ad[n, 0] = -1.0
        Ad[n, n] = 1.0
        bd[n] = 0.0


# ------------------------------------------------------------------------------ pole placement
@lane(inline=True)
def _controllability(A, b, Ws, Vs):
    """Invert the column-normalised controllability matrix ``Ctrb / norms``.

    Leaves ``Cn^{-1}`` in matrix slot ``_M2`` and the column norms in vector slot ``_V0``;
    returns the reciprocal 1-norm condition of ``Cn`` (0.0 when singular or non-finite).
    """
    m = A.shape[0]
    C = Ws[_M0, :m, :m]
    T = Ws[_M1, :m, :m]
    Cinv = Ws[_M2, :m, :m]
    norms = Vs[_V0, :m]
    v = Vs[_V1, :m]
    w = Vs[_V2, :m]
    for i in range(m):
        v[i] = b[i]
    for k in range(m):
        s = 0.0
        for i in range(m):
            C[i, k] = v[i]
            s += v[i] * v[i]
        norms[k] = math.sqrt(s)
        for i in range(m):
            acc = 0.0
            for j in range(m):
                acc += A[i, j] * v[j]
            w[i] = acc
        for i in range(m):
            v[i] = w[i]
    for k in range(m):
        if not (norms[k] > 0.0 and math.isfinite(norms[k])):
            return 0.0
    for i in range(m):
        for k in range(m):
            C[i, k] /= norms[k]
            T[i, k] = C[i, k]
    if not _invert(T, Cinv):
        return 0.0
    rcond = 1.0 / (_norm1(C) * _norm1(Cinv))
    if not math.isfinite(rcond):
        return 0.0
    return rcond


@lane(inline=True)
def _ackermann_from_ctrb(A, alpha, K, Ws, Vs):
    """``K = e_m^T Ctrb^{-1} phi_d(A) = sum_k alpha_{m-k} w^T A^k`` with ``w`` the last row of
    ``Ctrb^{-1}`` (``phi_d(A)`` never formed: ``m`` row-vector/matrix products)."""
    m = A.shape[0]
    Cinv = Ws[_M2, :m, :m]
    norms = Vs[_V0, :m]
    v = Vs[_V1, :m]
    w = Vs[_V2, :m]
    for j in range(m):
        v[j] = Cinv[m - 1, j] / norms[m - 1]
        K[j] = alpha[m - 1] * v[j]
    for k in range(1, m + 1):
        coef = alpha[m - 1 - k] if k < m else 1.0
        for j in range(m):
            acc = 0.0
            for i in range(m):
                acc += v[i] * A[i, j]
            w[j] = acc
        for j in range(m):
            v[j] = w[j]
            K[j] += coef * v[j]


@lane
def ackermann_gain(A, b, alpha, K, work):
    """Ackermann gain of a general pair ``(A, b)`` (``m x m``; ``work`` of ``work_size(m - 1)``).

    ``eig(A - b K)`` are the roots of ``z^m + alpha[0] z^{m-1} + ... + alpha[m-1]``. Returns the
    reciprocal 1-norm condition of the column-normalised controllability matrix (``<= 0``:
    singular or non-finite, ``K`` untouched).
    """
    mm = A.shape[0]
    Ws, Vs = _split_work(work, mm, _N_MAT)
    rcond = _controllability(A, b, Ws, Vs)
    if rcond > 0.0:
        _ackermann_from_ctrb(A, alpha, K, Ws, Vs)
    return rcond


@lane(inline=True)
def _steady_state(A, b, x_ss, Ws):
    n = A.shape[0]
    M = Ws[_M0, : n + 1, : n + 1]
    Minv = Ws[_M1, : n + 1, : n + 1]
    T = Ws[_M2, : n + 1, : n + 1]
    for i in range(n + 1):
        for j in range(n + 1):
            M[i, j] = 0.0
    for i in range(n):
        for j in range(n):
            M[i, j] = A[i, j] - (1.0 if i == j else 0.0)
        M[i, n] = b[i]
    M[n, 0] = 1.0
    for i in range(n + 1):
        for j in range(n + 1):
            T[i, j] = M[i, j]
    if not _invert(T, Minv) or not _all_finite(Minv):
        for i in range(n):
            x_ss[i] = 0.0
        return 0.0, 0.0
    for i in range(n):
        x_ss[i] = Minv[i, n]
    rcond = 1.0 / (_norm1(M) * _norm1(Minv))
    return Minv[n, n], rcond


@lane
def steady_state(A, b, x_ss, work):
    """Steady state of ``x = A x + b u``, ``y = x_1 = 1``: writes ``x_ss``, returns
    ``(u_ss, rcond)`` from the Rosenbrock system ``[[A - I, b], [c, 0]] [x_ss; u_ss] = [0; 1]``
    (regular exactly when the model has no zero at ``z = 1``; works with an integrator in ``A``).
    ``rcond = 0``: singular (``x_ss = 0``, ``u_ss = 0``)."""
    mm = A.shape[0] + 1
    Ws, _ = _split_work(work, mm, _N_MAT)
    return _steady_state(A, b, x_ss, Ws)


@lane(inline=True)
def _prepare(theta, form, integral, safe, Ws, Vs):
    """The safe-set tests every design shares, in order (finite, ``b_min``, controllability);
    builds ``A``, ``b`` and ``(A_aug, b_aug)`` in the work and leaves ``Ctrb^{-1}`` there.
    Returns ``(status, rcond)``."""
    n = theta.size // 2
    if not _all_finite(theta):
        return NONFINITE, 0.0
    bmax = 0.0
    for i in range(n):
        bmax = max(bmax, abs(theta[n + i]))
    if bmax < safe[B_MIN]:
        return B_SMALL, 0.0
    m = n + (1 if integral else 0)
    A = Ws[_A, :n, :n]
    Ad = Ws[_AD, :m, :m]
    b = Vs[_V3, :n]
    bd = Vs[_BD, :m]
    model_matrices(theta, form, A, b)
    _augment(A, b, integral, Ad, bd)
    rcond = _controllability(Ad, bd, Ws, Vs)
    if not rcond > max(safe[RCOND_MIN], RCOND_FLOOR):
        return UNCONTROLLABLE, rcond
    return OK, rcond


@lane(inline=True)
def _finish(theta, integral, feedforward, safe, K, rcond, gain, Ws, Vs):
    """Feed-forward from the steady state, the gain bound, and the commit of ``gain``."""
    n = theta.size // 2
    A = Ws[_A, :n, :n]
    b = Vs[_V3, :n]
    x_ss = Vs[_XSS, :n]
    N = 0.0
    if feedforward:
        u_ss, dc_rcond = _steady_state(A, b, x_ss, Ws)
        if not dc_rcond >= max(safe[DC_RCOND_MIN], DC_RCOND_FLOOR):
            return DC_SINGULAR
        N = u_ss
        for i in range(n):
            N += K[i] * x_ss[i]
    m = n + (1 if integral else 0)
    kmax = abs(N)
    for i in range(m):
        if abs(K[i]) > kmax or not math.isfinite(K[i]):
            kmax = abs(K[i]) if math.isfinite(K[i]) else math.inf
    if not (kmax <= safe[GAIN_MAX] and math.isfinite(N)):
        return GAIN_LARGE
    for i in range(n):
        gain[i] = K[i]
    gain[n] = K[n] if integral else 0.0
    gain[n + 1] = N
    gain[n + 2] = 1.0
    gain[n + 3] = rcond
    return OK


@lane
def place_design(theta, form, integral, feedforward, alpha, safe, gain, work):
    """Pole placement on the (augmented) model of ``theta``; see the module docstring.

    Returns the status code; ``gain`` is written only when it is ``OK`` (0).
    """
    mm = theta.size // 2 + 1
    Ws, Vs = _split_work(work, mm, _N_MAT)
    status, rcond = _prepare(theta, form, integral, safe, Ws, Vs)
    if status != OK:
        return status
    n = theta.size // 2
    m = n + (1 if integral else 0)
    K = Vs[_KW, :m]
    _ackermann_from_ctrb(Ws[_AD, :m, :m], alpha, K, Ws, Vs)
    return _finish(theta, integral, feedforward, safe, K, rcond, gain, Ws, Vs)


# ------------------------------------------------------------------------------ LQ
@lane(inline=True)
def _lq_gain(A, b, rho, P, K):
    """``K = (rho + b^T P b)^{-1} b^T P A``; returns ``rho + b^T P b``."""
    m = A.shape[0]
    s = rho
    for i in range(m):
        for j in range(m):
            s += b[i] * P[i, j] * b[j]
    for j in range(m):
        acc = 0.0
        for i in range(m):
            Pb_i = 0.0
            for k in range(m):
                Pb_i += P[i, k] * b[k]
            acc += Pb_i * A[i, j]
        K[j] = acc / s
    return s


@lane(inline=True)
def _riccati_step(A, b, Q, rho, P, K, Acl, T):
    """``P <- Q + (A - b K)^T P (A - b K) + rho K^T K`` with ``K`` the gain of ``P`` (the
    Joseph form of the Riccati difference equation: stays symmetric positive semidefinite)."""
    m = A.shape[0]
    _lq_gain(A, b, rho, P, K)
    for i in range(m):
        for j in range(m):
            Acl[i, j] = A[i, j] - b[i] * K[j]
    _matmul(P, Acl, T)  # T = P Acl
    for i in range(m):
        for j in range(i, m):
            acc = 0.0
            for k in range(m):
                acc += Acl[k, i] * T[k, j]
            v = Q[i, j] + acc + rho * K[i] * K[j]
            P[i, j] = v
    for i in range(m):
        for j in range(i):
            P[i, j] = P[j, i]


@lane(inline=True)
def _weight_matrix(n, integral, weights, Q):
    m = Q.shape[0]
    for i in range(m):
        for j in range(m):
            Q[i, j] = 0.0
    Q[0, 0] = weights[Q_Y]
    if integral:
        Q[n, n] = weights[Q_I]


@lane
def lq_design(theta, form, integral, feedforward, weights, safe, P, gain, work):
    """One Riccati iteration on the (augmented) model of ``theta`` warm-started from ``P``.

    Returns the status code; ``gain`` is written only on ``OK``. A Riccati matrix that is not
    finite on entry or blows up (``> P_MAX``: the model is not stabilisable) is re-initialised
    to ``Q`` and ``NOT_STABILISABLE`` returned.
    """
    mm = theta.size // 2 + 1
    Ws, Vs = _split_work(work, mm, _N_MAT)
    status, rcond = _prepare(theta, form, integral, safe, Ws, Vs)
    if status != OK:
        return status
    n = theta.size // 2
    m = n + (1 if integral else 0)
    Ad = Ws[_AD, :m, :m]
    bd = Vs[_BD, :m]
    # the controllability scratch is dead now: Q, A - b K and a product take its slots
    Q = Ws[_M2, :m, :m]
    _weight_matrix(n, integral, weights, Q)
    if not _all_finite(P):
        for i in range(m):
            for j in range(m):
                P[i, j] = Q[i, j]
    K = Vs[_KW, :m]
    Acl = Ws[_M0, :m, :m]
    T = Ws[_M1, :m, :m]
    _riccati_step(Ad, bd, Q, weights[RHO], P, K, Acl, T)
    if not (_max_abs(P) <= P_MAX):
        for i in range(m):
            for j in range(m):
                P[i, j] = Q[i, j]
        return NOT_STABILISABLE
    _lq_gain(Ad, bd, weights[RHO], P, K)
    return _finish(theta, integral, feedforward, safe, K, rcond, gain, Ws, Vs)


@lane(inline=True)
def _closed_loop_is_stable(A, b, char_A, K, v, w, c):
    """Every root of ``det(zI - A + b K)`` strictly inside the unit circle.

    ``det(zI - A + b K) = det(zI - A) + K adj(zI - A) b`` with ``adj(zI - A) = sum_k z^{m-1-k}
    E_k``, ``E_0 = I``, ``E_k = A E_{k-1} + a_k I``; so the coefficients are
    ``c_k = a_k + K v_{k-1}``, ``v_0 = b``, ``v_k = A v_{k-1} + a_k b`` (``char_A = [a_1..a_m]``
    of ``det(zI - A)``, known exactly from ``theta``), followed by the Schur-Cohn test. Unlike an
    eigenvalue routine this stays accurate for the nearly defective closed loops of a large
    gain.
    """
    m = A.shape[0]
    for i in range(m):
        v[i] = b[i]
    for k in range(m):
        acc = char_A[k]
        for i in range(m):
            acc += K[i] * v[i]
        c[k] = acc
        for i in range(m):
            t = char_A[k] * b[i]
            for j in range(m):
                t += A[i, j] * v[j]
            w[i] = t
        for i in range(m):
            v[i] = w[i]
    return is_schur_stable(c, m, c)


@lane
def _dare(A, b, Q, rho, char_A, P, K, Ws, Vs, tol, max_iter):
    """Stabilising solution of ``P = Q + A^T P A - A^T P b (rho + b^T P b)^{-1} b^T P A`` by the
    structure-preserving doubling algorithm (quadratic convergence):

        W = I + G_k H_k,  A_{k+1} = A_k W^{-1} A_k,  G_{k+1} = G_k + A_k W^{-1} G_k A_k^T,
        H_{k+1} = H_k + A_k^T H_k W^{-1} A_k,    A_0 = A, G_0 = b b^T / rho, H_0 = Q -> P.
    """
    m = A.shape[0]
    Ak = Ws[_M3, :m, :m]
    Gk = Ws[_M4, :m, :m]
    Hk = Ws[_M5, :m, :m]
    W = Ws[_M6, :m, :m]
    Winv = Ws[_M7, :m, :m]
    T1 = Ws[_M8, :m, :m]
    T2 = Ws[_M9, :m, :m]
    T3 = Ws[_M0, :m, :m]
    T4 = Ws[_M1, :m, :m]
    for i in range(m):
        for j in range(m):
            Ak[i, j] = A[i, j]
            Gk[i, j] = b[i] * b[j] / rho
            Hk[i, j] = 0.5 * (Q[i, j] + Q[j, i])
    converged = False
    for _ in range(max_iter):
        _matmul(Gk, Hk, W)
        for i in range(m):
            W[i, i] += 1.0
        if not _invert(W, Winv):
            return NOT_STABILISABLE
        _matmul(Winv, Ak, T1)  # W^{-1} A_k
        _matmul(Winv, Gk, T2)  # W^{-1} G_k
        _matmul(Hk, T1, T4)  # H_k W^{-1} A_k
        _matmul(Ak, T4, W, True, False)  # A_k^T H_k W^{-1} A_k
        dH = _max_abs(W)
        for i in range(m):
            for j in range(m):
                Hk[i, j] += 0.5 * (W[i, j] + W[j, i])
        _matmul(Ak, T2, T3)
        _matmul(T3, Ak, W, False, True)  # A_k W^{-1} G_k A_k^T
        for i in range(m):
            for j in range(m):
                Gk[i, j] += 0.5 * (W[i, j] + W[j, i])
        _matmul(Ak, T1, W)
        for i in range(m):
            for j in range(m):
                Ak[i, j] = W[i, j]
        hmax = _max_abs(Hk)
        if not hmax <= P_MAX or not _all_finite(Gk) or not _all_finite(Ak):
            return NOT_STABILISABLE
        if dH <= tol * max(1.0, hmax):
            converged = True
            break
    if not converged:
        return NOT_CONVERGED
    for i in range(m):
        for j in range(m):
            P[i, j] = Hk[i, j]
    _lq_gain(A, b, rho, P, K)
    v = Vs[_V1, :m]
    w = Vs[_V2, :m]
    c = Vs[_V4, :m]
    if not _closed_loop_is_stable(A, b, char_A, K, v, w, c):
        return NOT_STABILISABLE
    return OK


@lane
def dare(A, b, Q, rho, char_A, P, K, work, tol, max_iter):
    """Discrete algebraic Riccati equation of a general single-input pair (see :func:`_dare`).

    ``char_A = [a_1, ..., a_m]``: the characteristic polynomial ``det(zI - A)`` (for the test
    of the closed loop). Writes the stabilising ``P`` and the gain ``K`` on success; returns ``OK``,
    ``NOT_STABILISABLE`` (diverging doubling or a closed loop that is not Schur: no stabilising
    solution) or ``NOT_CONVERGED``.
    """
    mm = A.shape[0]
    Ws, Vs = _split_work(work, mm, _N_MAT_SOLVE)
    return _dare(A, b, Q, rho, char_A, P, K, Ws, Vs, tol, max_iter)


@lane(inline=True)
def _augmented_characteristic(theta, integral, out):
    """``[c_1..c_m]`` of ``det(zI - A_aug) = (z^n + a_1 z^{n-1} + ... + a_n)(z - 1)`` (both
    canonical forms: ``A_aug`` is block triangular), or ``a`` itself without integral action."""
    n = theta.size // 2
    if not integral:
        for k in range(n):
            out[k] = theta[k]
        return
    prev = 1.0
    for k in range(n):
        out[k] = theta[k] - prev
        prev = theta[k]
    out[n] = -prev


@lane
def lq_solve(theta, form, integral, feedforward, weights, safe, P, gain, work, tol, max_iter):
    """The LQ design of :func:`lq_design` solved to convergence (doubling) for a fresh model.

    ``work`` of ``solve_work_size(n)`` floats; ``tol`` (e.g. ``1e-12``) bounds the last
    doubling increment of ``P`` relative to ``max(1, max |P|)``, ``max_iter`` (e.g. 64) the
    number of doubling steps (each squares the horizon).

    Writes the Riccati solution into ``P`` and the gain into ``gain`` on ``OK``; both are left
    untouched otherwise.
    """
    mm = theta.size // 2 + 1
    Ws, Vs = _split_work(work, mm, _N_MAT_SOLVE)
    status, rcond = _prepare(theta, form, integral, safe, Ws, Vs)
    if status != OK:
        return status
    n = theta.size // 2
    m = n + (1 if integral else 0)
    Ad = Ws[_AD, :m, :m]
    bd = Vs[_BD, :m]
    Q = Ws[_M2, :m, :m]
    _weight_matrix(n, integral, weights, Q)
    Psol = Ws[_M10, :m, :m]
    K = Vs[_KW, :m]
    # _dare uses slots M0, M1, M3..M9; Q lives in M2 and the solution in M10 until the
    # safe set has accepted the gain.
    char_A = Vs[_V5, :m]
    _augmented_characteristic(theta, integral, char_A)
    status = _dare(Ad, bd, Q, weights[RHO], char_A, Psol, K, Ws, Vs, tol, max_iter)
    if status != OK:
        return status
    status = _finish(theta, integral, feedforward, safe, K, rcond, gain, Ws, Vs)
    if status == OK:
        for i in range(m):
            for j in range(m):
                P[i, j] = Psol[i, j]
    return status


# ------------------------------------------------------------------------------ tracking law
@lane(inline=True)
def track(gain, law, x, y, r, excitation, action_bound, integral, anti_windup):
    """``u(t) = sat(-K_x x(t) - k_i xi(t) + N r(t) + e(t))``; advances ``xi`` to ``xi(t+1)``.

    ``xi(t+1) = xi(t) + r(t) - y(t)`` (integral of the measured tracking error), frozen while
    the input is saturated and the error would drive it further into saturation (conditional
    integration: ``d u / d xi = -k_i``). Without a gain yet (``gain[n + 2] == 0``) only the
    excitation is applied and ``xi`` stays.
    """
    n = x.size
    has_gain = gain[n + 2] > 0.0
    if has_gain:
        u = gain[n + 1] * r + excitation - gain[n] * law[XI]
        for i in range(n):
            u -= gain[i] * x[i]
    else:
        u = excitation
    law[U_UNSAT] = u
    if abs(u) > action_bound:
        u_sat = math.copysign(action_bound, u)
        law[SATURATED] = 1.0
    else:
        u_sat = u
        law[SATURATED] = 0.0
    if integral and has_gain:
        err = r - y
        if not (anti_windup and law[SATURATED] > 0.0 and (-gain[n] * err) * u > 0.0):
            law[XI] += err
    return u_sat


# ------------------------------------------------------------------------------ known-model loop
#: Fields of a known-model oracle's lane record, in the order of its offsets array ``off``
#: (built with :class:`stcgym.envs.compiled.Layout` by :mod:`stcgym.adaptive.oracles`).
ORACLE_FIELDS = (
    "A",  # (n, n) model in force
    "b",  # (n,)
    "Q",  # (n, n) Kalman filter process-noise covariance
    "R",  # ()     Kalman filter measurement-noise variance
    "x",  # (n,)   x(t|t-1)
    "x_filt",  # (n,) x(t|t)
    "P",  # (n, n) P(t) of the filter
    "innov",  # () last innovation
    "gain",  # (n + 4,) gain record
    "law",  # (3,)  tracking-law state [xi, saturated, u_unsat]
    "t",  # ()     steps taken
)
_OA, _OB, _OQ, _OR, _OX, _OXF, _OP, _OINNOV, _OGAIN, _OLAW, _OT = range(11)


def oracle_scratch_size(n: int) -> int:
    """Per-lane proposal buffer of :func:`known_model_propose`: ``[x (n), x_filt (n), P (n^2),
    innov, law (3), u, L1 (n)]`` followed by ``2 n^2`` floats of work."""
    n = int(n)
    return 3 * n + 3 * n * n + 5


@lane
def known_model_propose(f, off, n, s, y, r, filtered, integral, anti_windup, action_bound):
    """One step of a known-model controller, written to the proposal buffer ``s`` only.

    The Kalman correction with ``y(t)`` (:func:`filtered_state`), the tracking law on ``x(t|t)``
    (``filtered``) or ``x(t|t-1)`` (:func:`track`), the Kalman time update with the applied
    ``u(t)`` (``kalman_step`` of :mod:`stcgym.adaptive.kernels.state_estimation`). Returns 0
    when everything proposed is finite (then :func:`known_model_commit` makes it the state),
    1 otherwise; the record ``f`` is only read.
    """
    A = view2d(f, off[_OA], n, n)
    b = f[off[_OB] : off[_OB] + n]
    Q = view2d(f, off[_OQ], n, n)
    x = f[off[_OX] : off[_OX] + n]
    P = view2d(f, off[_OP], n, n)
    gain = f[off[_OGAIN] : off[_OGAIN] + n + 4]
    law = f[off[_OLAW] : off[_OLAW] + LAW_SIZE]
    k = 2 * n + n * n
    x_next = s[0:n]
    x_filt = s[n : 2 * n]
    P_next = view2d(s, 2 * n, n, n)
    law_next = s[k + 1 : k + 4]
    L1 = s[k + 5 : k + 5 + n]
    work = s[k + 5 + n : k + 5 + n + 2 * n * n]
    innov = filtered_state(x, P, f[off[_OR]], y, x_filt)
    for i in range(LAW_SIZE):
        law_next[i] = law[i]
    xc = x_filt if filtered else x
    u = track(gain, law_next, xc, y, r, 0.0, action_bound, integral, anti_windup)
    for i in range(n):
        for j in range(n):
            P_next[i, j] = P[i, j]
    kf_status = kalman_step(A, b, P_next, Q, f[off[_OR]], x, u, y, x_next, L1, work)
    s[k] = innov
    s[k + 4] = u
    if kf_status != 0:
        return 1
    for i in range(k + 5):
        if not math.isfinite(s[i]):
            return 1
    return 0


@lane
def known_model_commit(f, off, n, s):
    """Make the proposal ``s`` of :func:`known_model_propose` the lane's state; returns ``u``."""
    k = 2 * n + n * n
    for i in range(n):
        f[off[_OX] + i] = s[i]
        f[off[_OXF] + i] = s[n + i]
    for i in range(n * n):
        f[off[_OP] + i] = s[2 * n + i]
    f[off[_OINNOV]] = s[k]
    for i in range(LAW_SIZE):
        f[off[_OLAW] + i] = s[k + 1 + i]
    f[off[_OT]] += 1.0
    return s[k + 4]


@lanes
def known_model_propose_lanes(
    F, off, n, S, y, r, filtered, integral, anti_windup, action_bound, status
):
    """Batch of :func:`known_model_propose` (lane ``i``: record ``F[i]``, buffer ``S[i]``)."""
    for i in prange(F.shape[0]):
        status[i] = known_model_propose(
            F[i], off, n, S[i], y[i], r[i], filtered, integral, anti_windup, action_bound
        )


@lanes
def known_model_commit_lanes(F, off, n, S, u):
    """Batch of :func:`known_model_commit`; writes the applied inputs into ``u``."""
    for i in prange(F.shape[0]):
        u[i] = known_model_commit(F[i], off, n, S[i])


# ------------------------------------------------------------------------------ batch loops
@lanes
def model_matrices_lanes(thetas, form, A, b):
    """:func:`model_matrices` for every lane: ``A`` ``(B, n, n)``, ``b`` ``(B, n)``."""
    for i in prange(thetas.shape[0]):
        model_matrices(thetas[i], form, A[i], b[i])


@lanes(allocates=True)
def place_design_lanes(thetas, form, integral, feedforward, alpha, safe, gains, status):
    """:func:`place_design` for every lane (``thetas`` ``(B, 2n)``, ``gains`` ``(B, n + 4)``,
    ``status`` ``(B,)`` int64); each lane allocates its own scratch."""
    mm = thetas.shape[1] // 2 + 1
    for i in prange(thetas.shape[0]):
        work = np.empty(_N_MAT * mm * mm + _N_VEC * mm)
        status[i] = place_design(
            thetas[i], form, integral, feedforward, alpha, safe, gains[i], work
        )


@lanes(allocates=True)
def lq_solve_lanes(
    thetas, form, integral, feedforward, weights, safe, Ps, gains, status, tol, max_iter
):
    """:func:`lq_solve` for every lane (``Ps`` ``(B, m, m)``)."""
    mm = thetas.shape[1] // 2 + 1
    for i in prange(thetas.shape[0]):
        work = np.empty(_N_MAT_SOLVE * mm * mm + _N_VEC * mm)
        status[i] = lq_solve(
            thetas[i],
            form,
            integral,
            feedforward,
            weights,
            safe,
            Ps[i],
            gains[i],
            work,
            tol,
            max_iter,
        )


@lane(allocates=True)
def kalman_covariance(theta, form, W, R, P, tol, max_iter):
    """Steady-state (a-priori) Kalman filter covariance of the canonical model of ``theta``:
    the stabilising solution of the dual Riccati equation ``dare(A^T, c^T, W, R)`` (``W``
    ``(n, n)`` process noise, ``R`` the measurement variance; ``P`` ``(n, n)`` out). Returns
    the status of :func:`dare`."""
    n = theta.size // 2
    A = np.empty((n, n))
    b = np.empty(n)
    model_matrices(theta, form, A, b)
    At = np.ascontiguousarray(A.T)
    c = np.zeros(n)
    c[0] = 1.0
    char_A = np.ascontiguousarray(theta[:n])  # det(zI - A^T) = z^n + a_1 z^{n-1} + ...
    K = np.empty(n)
    work = np.empty(_N_MAT_SOLVE * n * n + _N_VEC * n)
    return dare(At, c, W, R, char_A, P, K, work, tol, max_iter)


@lanes(allocates=True)
def kalman_covariance_lanes(thetas, form, W, R, Ps, status, tol, max_iter):
    """:func:`kalman_covariance` for every lane (``W``, ``Ps`` ``(B, n, n)``)."""
    for i in prange(thetas.shape[0]):
        status[i] = kalman_covariance(thetas[i], form, W[i], R, Ps[i], tol, max_iter)
