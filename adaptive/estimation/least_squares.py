"""Least-squares and gradient parameter updates as lane functions (Ding & Ma 2014, section 1 and 3).

Published interface (other modules build on these signatures; they do not change):

``least_squares_step(theta, S, Phi, Y, lam, w, lane_i) -> int``
    One recursive least-squares step on a *generic* regressor: ``theta`` (d,), ``S`` (d, d) the
    upper-triangular factor of ``P = S S^T`` (updated in place), ``Phi`` (p, d) whose row ``j``
    is the regressor ``phi(t - j)^T`` (``p = 1``: RLS (32)-(36); ``p > 1``: the multi-innovation
    MILS (37)-(44)), ``Y`` (p,) the matching outputs, ``lam`` the forgetting factor in (0, 1]
    (``P^{-1}(t) = lam P^{-1}(t-1) + Phi^T Phi``); its scratch is lane ``lane_i`` of the
    :class:`LeastSquaresWork` fields of ``w`` (shapes :func:`least_squares_shapes`). On return
    ``w.E[lane]`` holds the innovation ``E(p, t) = Y - Phi theta(t-1)`` (eq. (38)). Returns
    ``OK`` (0) or ``FAIL_COVARIANCE`` (1): then ``theta`` is untouched and ``S`` must be reset by
    the caller (e.g. to ``S(0)``).
``least_squares_downdate(theta, S, Phi, Y, w, lane_i) -> int``
    Removes a data block (finite history): ``P^{-1} <- P^{-1} - Phi^T Phi`` and
    ``theta <- theta - P Phi^T E`` with ``E = Y - Phi theta`` (the same scratch and
    :class:`DowndateWork`'s). Returns ``OK``
    or ``FAIL_DOWNDATE`` (``S``, ``theta`` restored: the block could not be removed accurately,
    ``1 - phi^T P phi <= DOWNDATE_TOL``).
``upper_factor(P, S) -> bool``
    ``S`` upper triangular with ``S S^T = P`` (``P`` symmetric positive definite); ``False``
    when ``P`` is not (``S`` then undefined). Use it to restart an estimator at a given ``P``.

Square-root form
----------------
``P`` is never formed. It is kept as an upper-triangular factor ``P = S S^T`` and updated by
Carlson's square-root measurement update (Carlson 1973; Bierman, *Factorization Methods for
Discrete Sequential Estimation*, 1977, ch. V): with ``f = S^T phi`` and
``alpha_0 = lam``, ``alpha_j = alpha_{j-1} + f_j^2``, every column ``j`` of ``S`` is rotated in
place so that ``S_new S_new^T = P - P phi phi^T P / alpha_d`` (the numerator and denominator of
(33)-(34)); the gain ``L(t) = P(t-1) phi / alpha_d`` (33) comes out of the same loop. The
multi-innovation update (39)-(40) ``P(t) = [lam P^{-1}(t-1) + Phi^T Phi]^{-1}`` is ``p`` such
rank-one updates, and its increment is ``L(t) E(p, t) = P(t) Phi^T E(p, t)`` (41). In exact
arithmetic this is the paper's RLS/MILS; in floating point ``P`` stays symmetric positive
definite by construction. Finite history downdate: ``P_new = P + P phi phi^T P / g`` with
``g = 1 - phi^T P phi``, a Givens rank-one *update* of the factor once ``g > DOWNDATE_TOL``.
Health check (one, used everywhere, ``O(d^2)`` after every update): :func:`factor_is_healthy`.
Design notes: square-root covariance, the one health check.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

from numpy.typing import NDArray

from stcgym.lanes.compiled import fields_of, lane, make_work
from stcgym.lanes.linalg import copy_matrix

__all__ = [
    "DOWNDATE_TOL",
    "FAIL_COVARIANCE",
    "FAIL_DOWNDATE",
    "OK",
    "DowndateWork",
    "LeastSquaresWork",
    "WindowedLeastSquaresWork",
    "carlson_update",
    "factor_is_healthy",
    "gradient_increment",
    "innovation",
    "least_squares_downdate",
    "least_squares_increment",
    "least_squares_shapes",
    "least_squares_step",
    "least_squares_work",
    "projection_increment",
    "rank_one_update",
    "upper_factor",
]

OK = 0
FAIL_COVARIANCE = 1
FAIL_DOWNDATE = 2

#: Smallest acceptable pivot ``1 - phi^T P phi`` of a finite-history downdate (else the window
#: is recomputed by replay). A downdate with pivot ``g`` loses about ``eps / g`` of relative
#: accuracy, and the loss never decays (what is added and removed later is exact), so a limit
#: of ``1e-8`` lets errors of ``1e-8 .. 1e-5`` accumulate when dominant samples leave the window.
DOWNDATE_TOL = 1e-4


class LeastSquaresWork(NamedTuple):
    """The scratch of :func:`least_squares_step`, one row a lane (shapes in
    :func:`least_squares_shapes`; a caller's scratch may hold more fields)."""

    delta: NDArray  # the increment of theta (d,)
    gain: NDArray  # a factor update's P phi (the numerator of L(t), (33)); MILS: Phi^T E (d,)
    E: NDArray  # the innovation E(p, t) = Y - Phi theta(t-1) (p,)
    factor_work: NDArray  # the factor updates' scratch (2 d,)


class DowndateWork(NamedTuple):
    """The scratch :func:`least_squares_downdate` needs besides :class:`LeastSquaresWork`."""

    S_saved: NDArray  # S before a downdate, restored when it fails (d, d)


#: The scratch of the finite-history least squares (:func:`least_squares_step` and
#: :func:`least_squares_downdate`): the fields of both parts.
WindowedLeastSquaresWork = NamedTuple(  # type: ignore[misc]
    "WindowedLeastSquaresWork", fields_of(LeastSquaresWork, DowndateWork)
)


def least_squares_shapes(d: int, p: int, window: bool = False) -> dict[str, tuple[int, ...]]:
    """The shapes of one lane's :class:`LeastSquaresWork` fields (``window=True``: of
    :data:`WindowedLeastSquaresWork`) for ``d`` parameters and blocks of ``p`` rows: the one
    place they are declared."""
    d, p = int(d), int(p)
    shapes = {"delta": (d,), "gain": (d,), "E": (p,), "factor_work": (2 * d,)}
    return {**shapes, "S_saved": (d, d)} if window else shapes


def least_squares_work(d: int, p: int, num_lanes: int = 1, *, window: bool = False) -> Any:
    """A zeroed :class:`LeastSquaresWork` (``window=True``: :data:`WindowedLeastSquaresWork`)
    of ``num_lanes`` lanes."""
    fields = WindowedLeastSquaresWork if window else LeastSquaresWork
    return make_work(fields, least_squares_shapes(d, p, window), num_lanes)


@lane
def carlson_update(
    S: NDArray, lo: int, hi: int, phi: NDArray, alpha0: float, P_phi: NDArray
) -> float:
    """``P <- P - P phi phi^T P / (alpha0 + phi^T P phi)`` on the block ``[lo, hi)`` of ``S``.

    ``S`` is upper triangular with ``P = S S^T``; only rows/columns ``lo..hi-1`` are read and
    written. ``P_phi[lo:hi]`` receives ``P_old phi`` (the unnormalised gain of (33)). Returns
    ``alpha = alpha0 + phi^T P_old phi`` (the denominator of (33)).
    """
    for i in range(lo, hi):
        P_phi[i] = 0.0
    alpha = alpha0
    for j in range(lo, hi):
        fj = 0.0
        for i in range(lo, j + 1):
            fj += S[i, j] * phi[i]
        alpha_new = alpha + fj * fj
        inv_r = 1.0 / math.sqrt(alpha * alpha_new)
        b = alpha * inv_r  # sqrt(alpha / alpha_new)
        c = fj * inv_r  # fj / sqrt(alpha alpha_new)
        for i in range(lo, j + 1):
            sij = S[i, j]
            S[i, j] = b * sij - c * P_phi[i]
            P_phi[i] += fj * sij
        alpha = alpha_new
    return alpha


@lane
def rank_one_update(S: NDArray, lo: int, hi: int, v: NDArray) -> None:
    """``S S^T <- S S^T + v v^T`` on the block ``[lo, hi)`` by Givens rotations (``v`` is
    overwritten). ``S`` stays upper triangular with a positive diagonal."""
    for j in range(hi - 1, lo - 1, -1):
        sjj = S[j, j]
        r = math.hypot(sjj, v[j])
        if r == 0.0:
            continue
        c = sjj / r
        s = v[j] / r
        for i in range(lo, j + 1):
            sij = S[i, j]
            S[i, j] = c * sij + s * v[i]
            v[i] = c * v[i] - s * sij


@lane(entry=True)
def factor_is_healthy(S: NDArray, lo: int, hi: int) -> bool:
    """The one positive-definiteness check: every entry of the block finite, every diagonal
    entry strictly positive (``P = S S^T`` is then positive definite). Unlike a Cholesky test
    of ``P`` it does not fail for a legitimately ill-conditioned ``P``."""
    for j in range(lo, hi):
        if not S[j, j] > 0.0:  # also False for NaN
            return False
        for i in range(lo, j + 1):
            if not math.isfinite(S[i, j]):
                return False
    return True


@lane
def innovation(theta: NDArray, Phi: NDArray, Y: NDArray, p: int, E: NDArray) -> None:
    """``E(p, t) = Y(p, t) - Phi(p, t)^T theta``, eq. (17), (38)."""
    d = theta.shape[0]
    for k in range(p):
        acc = Y[k]
        for i in range(d):
            acc -= Phi[k, i] * theta[i]
        E[k] = acc


@lane
def _phi_t_e(Phi: NDArray, E: NDArray, p: int, lo: int, hi: int, out: NDArray) -> None:
    """``out[lo:hi] = Phi^T E`` on the block ``[lo, hi)`` (the first ``p`` rows of ``Phi``)."""
    for i in range(lo, hi):
        acc = 0.0
        for k in range(p):
            acc += Phi[k, i] * E[k]
        out[i] = acc


@lane
def _p_times(S: NDArray, lo: int, hi: int, g: NDArray, w: NDArray, out: NDArray) -> None:
    """``out[lo:hi] = S S^T g`` on the block (``w`` scratch)."""
    for j in range(lo, hi):
        acc = 0.0
        for i in range(lo, j + 1):
            acc += S[i, j] * g[i]
        w[j] = acc
    for i in range(lo, hi):
        acc = 0.0
        for j in range(i, hi):
            acc += S[i, j] * w[j]
        out[i] = acc


@lane(entry=True)
def least_squares_increment(
    S: NDArray,
    lo: int,
    hi: int,
    Phi: NDArray,
    E: NDArray,
    p: int,
    lam: float,
    scalar: bool,
    delta: NDArray,
    gain: NDArray,
    w: NDArray,
) -> float:
    """Update the factor of ``P`` with the first ``p`` rows of ``Phi`` on the block ``[lo, hi)``
    and write ``L(t) E(p, t)`` into ``delta[lo:hi]``.

    ``scalar`` (RLS, ``p = 1``): ``L(t) = P(t-1) phi / (lam + phi^T P(t-1) phi)``, eq. (33);
    otherwise (MILS, any ``p``) ``L(t) E = P(t) Phi^T E``, eq. (39)-(41), so that "MILS with
    ``p = 1`` equals RLS" compares two different formulas. Returns the last denominator
    ``denom`` (``> 0`` and finite unless ``P`` overflowed).
    """
    inv_sqrt_lam = 1.0 / math.sqrt(lam) if lam != 1.0 else 1.0
    denom = carlson_update(S, lo, hi, Phi[0], lam, gain)
    if lam != 1.0:
        for j in range(lo, hi):
            for i in range(lo, j + 1):
                S[i, j] *= inv_sqrt_lam
    if scalar:
        scale = E[0] / denom
        for i in range(lo, hi):
            delta[i] = gain[i] * scale
        return denom
    for k in range(1, p):
        denom = carlson_update(S, lo, hi, Phi[k], 1.0, gain)
    _phi_t_e(Phi, E, p, lo, hi, gain)  # g = Phi^T E on the block
    _p_times(S, lo, hi, gain, w, delta)
    return denom


@lane
def gradient_increment(
    r: float,
    lo: int,
    hi: int,
    Phi: NDArray,
    E: NDArray,
    p: int,
    lam: float,
    stacked: bool,
    delta: NDArray,
) -> float:
    """SG / MISG increment on the block ``[lo, hi)``: returns ``r(t)`` and writes
    ``Phi^T E / r(t)`` into ``delta[lo:hi]``.

    ``r(t) = lam r(t-1) + ||phi_hat(t)||^2`` (13), (18), (98)-(99); with ``stacked`` the increment
    is ``||Phi(p, t)||^2`` (remark 1, (116)-(117)). ``lam = 1`` is the paper.
    """
    inc = 0.0
    rows = p if stacked else 1
    for k in range(rows):
        for i in range(lo, hi):
            inc += Phi[k, i] * Phi[k, i]
    r_new = lam * r + inc
    inv_r = 1.0 / r_new
    _phi_t_e(Phi, E, p, lo, hi, delta)
    for i in range(lo, hi):
        delta[i] *= inv_r
    return r_new


@lane
def projection_increment(
    lo: int, hi: int, phi: NDArray, e: float, parameters: NDArray, delta: NDArray
) -> float:
    """Normalised-gradient (projection) increment on the block ``[lo, hi)``: writes
    ``mu phi e / (bias + phi^T phi)`` into ``delta[lo:hi]`` and returns the denominator.

    Astrom & Wittenmark, *Adaptive Control* (2nd ed., 1995), sec. 2.3, the projection
    algorithm; MATLAB's ``recursiveLS`` ``"NormalizedGradient"``. ``parameters`` are the
    rule's, in the order it declares them: ``mu`` (``adaptation_gain``, in ``(0, 2)``) and
    the bias (``normalization_bias``, ``> 0``).
    """
    mu, bias = parameters[0], parameters[1]
    norm = bias
    for i in range(lo, hi):
        norm += phi[i] * phi[i]
    scale = mu * e / norm
    for i in range(lo, hi):
        delta[i] = phi[i] * scale
    return norm


@lane(entry=True)
def block_trace_is_finite(S: NDArray, lo: int, hi: int) -> bool:
    """``trace(P) = ||S||_F^2`` is finite (it bounds every entry of ``P``; NaN propagates)."""
    acc = 0.0
    for j in range(lo, hi):
        for i in range(lo, j + 1):
            acc += S[i, j] * S[i, j]
    return math.isfinite(acc)


@lane(inline=True)
def least_squares_step(
    theta: NDArray, S: NDArray, Phi: NDArray, Y: NDArray, lam: float, w: Any, lane_i: int
) -> int:
    """One RLS (``p = 1``, (32)-(36)) or MILS (``p > 1``, (37)-(44)) step on a generic
    regressor, with lane ``lane_i`` of the scratch ``w``; see the module docstring for the
    arguments."""
    d = theta.shape[0]
    p = Phi.shape[0]
    delta = w.delta[lane_i]
    gain = w.gain[lane_i]
    E = w.E[lane_i]
    innovation(theta, Phi, Y, p, E)  # E(p, t) = Y(p, t) - Phi(p, t)^T theta(t-1)  (38); (32)
    # L(t) (33)/(39) and P(t) = S S^T (34)/(40) by Carlson's rotations; delta = L(t) E(p, t)
    denom = least_squares_increment(
        S, 0, d, Phi, E, p, lam, p == 1, delta, gain, w.factor_work[lane_i]
    )
    if not (denom > 0.0 and math.isfinite(denom) and factor_is_healthy(S, 0, d)):
        return FAIL_COVARIANCE
    for j in range(d):
        if not math.isfinite(delta[j]):
            return FAIL_COVARIANCE
    for j in range(d):
        theta[j] += delta[j]  # theta(t) = theta(t-1) + L(t) E(p, t)            (32)/(37)
    return OK


@lane
def downdate_block(
    S: NDArray, lo: int, hi: int, Phi: NDArray, E: NDArray, p: int, delta: NDArray, w: NDArray
) -> bool:
    """Finite history: remove the rows of ``Phi`` from the block ``[lo, hi)`` of ``P^{-1}``
    (``P^{-1} <- P^{-1} - Phi^T Phi``) and *add* ``-P_new Phi^T E`` to ``delta[lo:hi]``.

    ``w`` is scratch of length ``>= 2 * len(theta)``. Returns ``False`` (``S`` partly changed:
    the caller restores it) when ``1 - phi^T P phi <= DOWNDATE_TOL`` for a row.
    """
    d = w.shape[0] // 2
    f = w[:d]
    v = w[d : 2 * d]
    for k in range(p):
        q = 0.0
        for j in range(lo, hi):
            acc = 0.0
            for i in range(lo, j + 1):
                acc += S[i, j] * Phi[k, i]
            f[j] = acc
            q += acc * acc
        g = 1.0 - q
        if not g > DOWNDATE_TOL:
            return False
        scale = 1.0 / math.sqrt(g)
        for i in range(lo, hi):  # v = S f / sqrt(g) = P phi / sqrt(g)
            acc = 0.0
            for j in range(i, hi):
                acc += S[i, j] * f[j]
            v[i] = acc * scale
        rank_one_update(S, lo, hi, v)
    if not block_trace_is_finite(S, lo, hi):
        return False
    _phi_t_e(Phi, E, p, lo, hi, f)
    _p_times(S, lo, hi, f, v, f)
    for i in range(lo, hi):
        delta[i] -= f[i]
    return True


@lane(inline=True)
def least_squares_downdate(
    theta: NDArray, S: NDArray, Phi: NDArray, Y: NDArray, w: Any, lane_i: int
) -> int:
    """Remove one data block from a least-squares estimate; see the module docstring."""
    d = theta.shape[0]
    p = Phi.shape[0]
    delta = w.delta[lane_i]
    E = w.E[lane_i]
    saved = w.S_saved[lane_i]
    copy_matrix(S, saved)
    innovation(theta, Phi, Y, p, E)
    for i in range(d):
        delta[i] = 0.0
    if not downdate_block(S, 0, d, Phi, E, p, delta, w.factor_work[lane_i]):
        copy_matrix(saved, S)
        return FAIL_DOWNDATE
    for i in range(d):
        theta[i] += delta[i]
    return OK


@lane(entry=True)
def upper_factor(P: NDArray, S: NDArray) -> bool:
    """Upper-triangular ``S`` with ``S S^T = P`` (a Cholesky factorisation run from the last
    row/column backwards); ``False`` if ``P`` is not symmetric positive definite."""
    d = P.shape[0]
    for i in range(d):
        for j in range(d):
            S[i, j] = 0.0
    for j in range(d - 1, -1, -1):
        acc = P[j, j]
        for k in range(j + 1, d):
            acc -= S[j, k] * S[j, k]
        if not (acc > 0.0 and math.isfinite(acc)):
            return False
        sjj = math.sqrt(acc)
        S[j, j] = sjj
        for i in range(j - 1, -1, -1):
            acc = P[i, j]
            for k in range(j + 1, d):
                acc -= S[i, k] * S[j, k]
            S[i, j] = acc / sjj
    return True
