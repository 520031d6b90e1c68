"""Linear-quadratic designs on the (integral-augmented) model: lane functions.

``lq_design(theta, cfg, weights, P, gain, w, lane_i) -> int``
    Self-tuning LQ: **one** Riccati iteration per call on the (augmented) model of ``theta``
    (``cfg``: a :class:`.safe_set.DesignConfig`), warm-started from ``P`` (``m x m``,
    C-contiguous 2-D, updated in place); the gain is the LQ gain of the updated ``P``.
    ``weights`` (``[q_y, q_i, rho]``, :class:`LQWeights`; built by :func:`lq_weights`): state
    weight ``Q = q_y c^T c`` (+ ``q_i`` on the integrator), input weight ``rho``; defaults
    ``DEFAULT_LQ_WEIGHTS = (1, 1e-4, 1e-2)``, explained in
    :class:`stcgym.adaptive.control.options.LawOptions`. Initialise ``P`` with :func:`lq_initial_P`
    (``= Q``) or a converged solution; a ``P`` that is not finite on entry restarts from ``Q``.
    ``w``: an :data:`LQWork` (:func:`lq_work`), of which lane ``lane_i`` is used.
``lq_solve(theta, cfg, weights, P, gain, w, lane_i, tol, max_iter) -> int``
    The same design solved to convergence (structured doubling, for a fresh model; ``w`` an
    :data:`LQSolveWork`);
``dare(A, b, Q, rho, char_A, P, K, w, lane_i, tol, max_iter) -> int``
    The discrete algebraic Riccati equation of a general single-input pair (status 0 / 6 / 7;
    ``char_A`` the coefficients of ``det(zI - A)``; ``w`` a :data:`DareWork`).
``kalman_covariance(theta, form, W, R, P, w, lane_i, tol, max_iter) -> int``
    The steady-state Kalman filter covariance of the canonical model of ``theta``: :func:`dare`
    on the dual problem.

Batch loops ``lq_solve_lanes`` and ``kalman_covariance_lanes`` (the scratch has a row a lane).
:data:`COMPILED_DESIGN` is the self-tuning controller's LQ design: :func:`lq_design` with the
weights of its compiled argument :class:`LQDesign`, its lane state :class:`LQState` the Riccati
matrix it warm-starts from.
Status codes and the gain written (:class:`.safe_set.Gain`): :mod:`.safe_set`.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.control.safe_set import (
    NOT_STABILISABLE,
    OK,
    DesignWork,
    design_shapes,
    design_start,
    finish,
)
from stcgym.adaptive.estimation.state_estimation import is_schur_stable
from stcgym.adaptive.kernels.canonical import augmented_characteristic, model_matrices
from stcgym.adaptive.multivariable.mimo_lq import P_MAX, DoublingWork, doubling, doubling_shapes
from stcgym.adaptive.variants import CompiledDesign
from stcgym.lanes.compiled import fields_of, lane, lanes, make_work, read_only
from stcgym.lanes.linalg import all_finite, copy_matrix, copy_vector, matmul, max_abs
from stcgym.lanes.validation import real_in

__all__ = [
    "COMPILED_DESIGN",
    "DEFAULT_LQ_WEIGHTS",
    "P_MAX",
    "DareWork",
    "LQDesign",
    "LQSolveWork",
    "LQState",
    "LQWeights",
    "LQWork",
    "RiccatiStepWork",
    "SolveWork",
    "dare_work",
    "lq_shapes",
    "lq_work",
    "weight_fields",
    "dare",
    "kalman_covariance",
    "kalman_covariance_lanes",
    "lq_design",
    "lq_initial_P",
    "lq_solve",
    "lq_solve_lanes",
    "lq_weights",
]


class LQWeights(NamedTuple):
    """The entries of the LQ weight vector by name (:func:`weight_fields` reads them)."""

    q_y: float  # output: Q = q_y c^T c
    q_i: float  # integrator state (augmented model)
    rho: float  # input


DEFAULT_LQ_WEIGHTS = (1.0, 1e-4, 1e-2)


@lane(inline=True)
def weight_fields(weights):
    """The weight vector ``weights`` (float64, length 3) as an :class:`LQWeights`: the one place
    that knows the order of its entries (a vector, not the named tuple, is what the lane
    functions take, for the reason given in :func:`.safe_set.safe_bounds`)."""
    return LQWeights(weights[0], weights[1], weights[2])


def lq_weights(
    q_y: float = DEFAULT_LQ_WEIGHTS[0],
    q_i: float = DEFAULT_LQ_WEIGHTS[1],
    rho: float = DEFAULT_LQ_WEIGHTS[2],
    *,
    integral: bool = True,
) -> NDArray[np.float64]:
    """Validated LQ weight vector ``[q_y, q_i, rho]`` for :func:`lq_design` / :func:`lq_solve`.

    ``q_y`` (output) and ``rho`` (input) must be finite and > 0; ``q_i`` (integrator) > 0 with
    integral action (with ``q_i = 0`` the integrator is invisible to the cost, so no LQ gain
    stabilises it) and >= 0 without. Raises ``ValueError`` naming the weight.
    """
    weights = LQWeights(
        real_in(q_y, "LQ weight q_y", 0.0, math.inf, lo_open=True, hi_open=True),
        real_in(q_i, "LQ weight q_i", 0.0, math.inf, lo_open=bool(integral), hi_open=True),
        real_in(rho, "LQ weight rho", 0.0, math.inf, lo_open=True, hi_open=True),
    )
    return np.array(weights, dtype=np.float64)


def lq_initial_P(n: int, integral: bool, weights: ArrayLike) -> NDArray[np.float64]:
    """Cold start of the one-step Riccati iteration: ``P = Q`` (``m x m``; ``weights`` any
    sequence ``(q_y, q_i, rho)``)."""
    w = LQWeights(*weights)
    m = int(n) + int(bool(integral))
    P = np.zeros((m, m))
    P[0, 0] = w.q_y
    if integral:
        P[n, n] = w.q_i
    return P


class RiccatiStepWork(NamedTuple):
    """The one-step Riccati iteration of :func:`lq_design` (and the weight of :func:`lq_solve`)."""

    Q: NDArray  # the state weight q_y c^T c (+ q_i on the integrator) (m, m)
    A_cl: NDArray  # the closed loop A_aug - b_aug K (m, m)
    P_Acl: NDArray  # P A_cl (m, m)


class SolveWork(NamedTuple):
    """The solve to convergence (:func:`lq_solve`): its solution and the closed-loop test."""

    P_sol: NDArray  # the solution, until the safe set has accepted its gain (m, m)
    char_A: NDArray  # [a_1..a_m] of det(zI - A) (m,)
    char_cl: NDArray  # the coefficients of det(zI - A + b K) (m,)
    adj_v: NDArray  # v_k = A v_{k-1} + a_k b of the adjugate expansion (m,)
    adj_v_next: NDArray  # its successor (m,)


#: The scratch of :func:`dare`: the fields of :class:`.mimo_lq.DoublingWork` and
#: :class:`SolveWork`, one row a lane.
DareWork = NamedTuple("DareWork", fields_of(DoublingWork, SolveWork))  # type: ignore[misc]
#: The scratch of the one-step LQ design :func:`lq_design`: the fields of
#: :data:`.safe_set.DesignWork` and :class:`RiccatiStepWork`, one row a lane.
LQWork = NamedTuple("LQWork", fields_of(DesignWork, RiccatiStepWork))  # type: ignore[misc]
#: The scratch of the LQ design solved to convergence :func:`lq_solve`: the fields of
#: :data:`LQWork` and :data:`DareWork`, one row a lane.
LQSolveWork = NamedTuple("LQSolveWork", fields_of(LQWork, DareWork))  # type: ignore[misc]


def lq_shapes(n: int, integral: bool) -> dict[str, tuple[int, ...]]:
    """The shapes of one lane's :data:`LQSolveWork` fields (hence of every LQ scratch) for
    order ``n`` (``m = n + integral``): the one place they are declared, with
    :func:`.safe_set.design_shapes` and :func:`.mimo_lq.doubling_shapes`."""
    m = int(n) + int(bool(integral))
    return {
        **design_shapes(n, integral),
        **dict.fromkeys((*RiccatiStepWork._fields, "P_sol"), (m, m)),
        **doubling_shapes(m),
        **dict.fromkeys(("char_A", "char_cl", "adj_v", "adj_v_next"), (m,)),
    }


def lq_work(n: int, integral: bool, num_lanes: int = 1, *, solve: bool = False) -> Any:
    """An :data:`LQWork` (``solve=True``: an :data:`LQSolveWork`) of ``num_lanes`` lanes."""
    return make_work(LQSolveWork if solve else LQWork, lq_shapes(n, integral), num_lanes)


def dare_work(m: int, num_lanes: int = 1) -> Any:
    """A :data:`DareWork` of ``num_lanes`` lanes for a pair of order ``m``."""
    return make_work(DareWork, lq_shapes(m, False), num_lanes)


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
    matmul(P, Acl, T)  # T = P Acl
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
    """Write the state weight ``Q = q_y c^T c (+ q_i on the integrator)`` (``m x m``)."""
    m = Q.shape[0]
    w = weight_fields(weights)
    for i in range(m):
        for j in range(m):
            Q[i, j] = 0.0
    Q[0, 0] = w.q_y
    if integral:
        Q[n, n] = w.q_i


@lane(entry=True, inline=True)
def lq_design(theta, cfg, weights, P, gain, w, lane_i):
    """One Riccati iteration on the (augmented) model of ``theta`` warm-started from ``P``.

    Returns the status code; lane ``lane_i`` of ``gain`` (a :class:`.safe_set.Gain`) is written
    only on ``OK``. A Riccati matrix that is not
    finite on entry or blows up (``> P_MAX``: the model is not stabilisable) is re-initialised
    to ``Q`` and ``NOT_STABILISABLE`` returned.
    """
    status, rcond = design_start(theta, cfg, w, lane_i)
    if status != OK:
        return status
    Ad = w.A_aug[lane_i]
    bd = w.b_aug[lane_i]
    K = w.K[lane_i]
    Q = w.Q[lane_i]
    _weight_matrix(theta.size // 2, cfg.integral, weights, Q)
    if not all_finite(P):
        copy_matrix(Q, P)
    rho = weight_fields(weights).rho
    _riccati_step(Ad, bd, Q, rho, P, K, w.A_cl[lane_i], w.P_Acl[lane_i])
    if not (max_abs(P) <= P_MAX):
        copy_matrix(Q, P)
        return NOT_STABILISABLE
    _lq_gain(Ad, bd, rho, P, K)
    return finish(theta, cfg, rcond, gain, w, lane_i)


class LQDesign(NamedTuple):
    """The compiled argument of the controller's LQ design."""

    weights: NDArray  # [q_y, q_i, rho], read-only float64 (lq_weights)


class LQState(NamedTuple):
    """The lane state of the controller's LQ design."""

    P: NDArray  # the Riccati matrix of the one-step iteration (m, m)


@lane(inline=True)
def controller_design(design, theta, cfg, state, gain, w, lane_i):
    """Step 3 of the self-tuning controller: :func:`lq_design` with the weights of
    ``design`` (an :class:`LQDesign`) from lane ``lane_i``'s Riccati matrix of ``state`` (an
    :class:`LQState`)."""
    return lq_design(theta, cfg, design.weights, state.P[lane_i], gain, w, lane_i)


def _argument(n: int, law: Any) -> LQDesign:
    return LQDesign(read_only(law.lq_weights))


def _cold_start(n: int, law: Any, num_lanes: int) -> LQState:
    """Every lane's Riccati matrix at :func:`lq_initial_P` of ``law.lq_weights``."""
    P = lq_initial_P(n, law.integral, np.asarray(law.lq_weights, dtype=float))
    return LQState(np.repeat(P[None], int(num_lanes), axis=0))


COMPILED_DESIGN = CompiledDesign(
    argument=LQDesign,
    step=controller_design,
    make_argument=_argument,
    make_state=_cold_start,
    make_work=lq_work,
)


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
    copy_vector(b, v)
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
        copy_vector(w, v)
    return is_schur_stable(c, m, c)


@lane
def _dare(A, b, Q, rho, char_A, P, K, w, lane_i, tol, max_iter):
    """Stabilising solution of ``P = Q + A^T P A - A^T P b (rho + b^T P b)^{-1} b^T P A`` by the
    structure-preserving doubling algorithm (quadratic convergence; :func:`.mimo_lq.doubling`):

        W = I + G_k H_k,  A_{k+1} = A_k W^{-1} A_k,  G_{k+1} = G_k + A_k W^{-1} G_k A_k^T,
        H_{k+1} = H_k + A_k^T H_k W^{-1} A_k,    A_0 = A, G_0 = b b^T / rho, H_0 = Q -> P,

    on the :data:`DareWork` fields of lane ``lane_i`` of ``w``.
    """
    m = A.shape[0]
    Ak = w.A_k[lane_i]
    Gk = w.G_k[lane_i]
    Hk = w.H_k[lane_i]
    for i in range(m):
        for j in range(m):
            Ak[i, j] = A[i, j]
            Gk[i, j] = b[i] * b[j] / rho
            Hk[i, j] = 0.5 * (Q[i, j] + Q[j, i])
    status = doubling(Ak, Gk, Hk, w, lane_i, tol, max_iter)
    if status != OK:
        return status
    copy_matrix(Hk, P)
    _lq_gain(A, b, rho, P, K)
    c = w.char_cl[lane_i]
    if not _closed_loop_is_stable(A, b, char_A, K, w.adj_v[lane_i], w.adj_v_next[lane_i], c):
        return NOT_STABILISABLE
    return OK


@lane(entry=True)
def dare(A, b, Q, rho, char_A, P, K, w, lane_i, tol, max_iter):
    """Discrete algebraic Riccati equation of a general single-input pair (see :func:`_dare`).

    ``char_A = [a_1, ..., a_m]``: the characteristic polynomial ``det(zI - A)`` (for the test
    of the closed loop); ``w``: a :data:`DareWork` of order ``m`` (:func:`dare_work`),
    lane ``lane_i`` used. Writes the stabilising ``P`` and the gain ``K`` on success; returns
    ``OK``, ``NOT_STABILISABLE`` (diverging doubling or a closed loop that is not Schur: no
    stabilising solution) or ``NOT_CONVERGED``.
    """
    if w.A_k.shape[1] != A.shape[0]:
        raise ValueError("dare: w is not the scratch of this order (dare_work(m))")
    return _dare(A, b, Q, rho, char_A, P, K, w, lane_i, tol, max_iter)


@lane(entry=True)
def lq_solve(theta, cfg, weights, P, gain, w, lane_i, tol, max_iter):
    """The LQ design of :func:`lq_design` solved to convergence (doubling) for a fresh model.

    ``w``: an :data:`LQSolveWork` (``lq_work(n, integral, solve=True)``), lane ``lane_i`` used;
    ``tol`` (e.g. ``1e-12``) bounds the last doubling increment of ``P`` relative to
    ``max(1, max |P|)``, ``max_iter`` (e.g. 64) the number of doubling steps (each squares the
    horizon).

    Writes the Riccati solution into ``P`` and the design into lane ``lane_i`` of ``gain`` (a
    :class:`.safe_set.Gain`) on ``OK``; both are left untouched otherwise.
    """
    status, rcond = design_start(theta, cfg, w, lane_i)
    if status != OK:
        return status
    Ad = w.A_aug[lane_i]
    Q = w.Q[lane_i]
    _weight_matrix(theta.size // 2, cfg.integral, weights, Q)
    Psol = w.P_sol[lane_i]
    char_A = w.char_A[lane_i]
    augmented_characteristic(theta, cfg.integral, char_A)
    rho = weight_fields(weights).rho
    status = _dare(Ad, w.b_aug[lane_i], Q, rho, char_A, Psol, w.K[lane_i], w, lane_i, tol, max_iter)
    if status != OK:
        return status
    status = finish(theta, cfg, rcond, gain, w, lane_i)
    if status == OK:
        copy_matrix(Psol, P)
    return status


@lanes(min_lanes=4)  # a solve to convergence a lane
def lq_solve_lanes(thetas, cfg, weights, Ps, gains, status, w, tol, max_iter, first, last):
    """:func:`lq_solve` for every lane (``Ps`` ``(B, m, m)``, ``gains`` a
    :class:`.safe_set.Gain` and ``w`` an :data:`LQSolveWork` of ``B`` lanes)."""
    for i in range(first, last):
        status[i] = lq_solve(thetas[i], cfg, weights, Ps[i], gains, w, i, tol, max_iter)


@lane(allocates=True, entry=True)
def kalman_covariance(theta, form, W, R, P, w, lane_i, tol, max_iter):
    """Steady-state (a-priori) Kalman filter covariance of the canonical model of ``theta``:
    the stabilising solution of the dual Riccati equation ``dare(A^T, c^T, W, R)`` (``W``
    ``(n, n)`` process noise, ``R`` the measurement variance; ``P`` ``(n, n)`` out; ``w`` a
    :data:`DareWork` of order ``n``, lane ``lane_i`` used). Returns the status of
    :func:`dare`."""
    n = theta.size // 2
    A = np.empty((n, n))
    b = np.empty(n)
    model_matrices(theta, form, A, b)
    At = np.ascontiguousarray(A.T)
    c = np.zeros(n)
    c[0] = 1.0
    char_A = np.ascontiguousarray(theta[:n])  # det(zI - A^T) = z^n + a_1 z^{n-1} + ...
    K = np.empty(n)
    return dare(At, c, W, R, char_A, P, K, w, lane_i, tol, max_iter)


@lanes(allocates=True, min_lanes=4)  # a solve to convergence a lane
def kalman_covariance_lanes(thetas, form, W, R, Ps, status, w, tol, max_iter, first, last):
    """:func:`kalman_covariance` for every lane (``W``, ``Ps`` ``(B, n, n)``, ``w`` a
    :data:`DareWork` of ``B`` lanes)."""
    for i in range(first, last):
        status[i] = kalman_covariance(thetas[i], form, W[i], R, Ps[i], w, i, tol, max_iter)
