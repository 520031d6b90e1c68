"""The joint state/parameter estimator of Ding & Ma (2014) as two lane functions on a lane record.

Published interface (used by the self-tuning controller's lane step; signatures fixed)
------------------------------------------------------------------------------------
``spec = EstimatorSpec.build(name, n, **make_estimator_keywords)``
    Frozen description of one estimator configuration (validated exactly like
    :func:`stcgym.adaptive.make_estimator`, which builds one itself). It gives

    * ``spec.layout`` -- the :class:`~stcgym.envs.compiled.Layout` of the estimator's record;
      ``spec.size`` floats per lane;
    * ``spec.cfg_f`` (float64) and ``spec.cfg_i`` (int64) -- the configuration arrays every lane
      function takes; ``cfg_i[C_OFF + k]`` is the offset of field ``FIELDS[k]`` *relative to the
      start of the estimator's record*;
    * ``spec.initial_record()`` -- one lane's record at ``t = 0`` (shape ``(size,)``);
    * ``spec.offset(name)`` -- the offset of a field, e.g. ``"theta"`` (2n), ``"x_hat"`` (n),
      ``"S"`` (2n x 2n, row-major: the upper-triangular factor of ``P = S S^T``; block-diagonal
      ``diag(S_a, S_b)`` for D- rules; absent (size 0) for SG/MISG), ``"P1"`` (n x n), ``"Q"``
      (n x n, the KF process-noise covariance, may be overwritten before every state step),
      ``"E"`` (p, the innovation ``E(p, t)``), ``"r"`` (2, SG/MISG normalisers).

``status = estimator_update(rec, off, cfg_f, cfg_i, y)``
    Measurement step at time ``t`` on the estimator record stored in ``rec[off : off + size]``
    (``rec`` a 1-D float64 array, e.g. the controller's own lane record): shift the stacked
    window ``Phi(p, t)``, ``Y(p, t)`` (eq. (19)-(20), (74)-(75)), compute the innovation
    ``E(p, t) = Y(p, t) - Phi(p, t)^T theta_hat(t-1)`` and update ``theta_hat(t)`` with the rule:
    SG (12)-(15), MISG (16)-(22), RLS (32)-(36), MILS (37)-(44), D-SG (96)-(103), D-MISG
    (104)-(117), D-RLS (124)-(133), D-MILS (134)-(145); as a whole O-RLS (54)-(57), KF-MILS
    (73)-(79). Returns a bit set of ``ST_*`` events (0: nothing happened).
``status = estimator_predict(rec, off, cfg_f, cfg_i, u)``
    State step with the applied ``u(t)``: ``A_hat(t)``, ``b_hat(t)`` from ``theta_hat(t)``
    ((59)-(60), (83)-(84)), ``x_hat(t+1)`` by the open-loop observer (58), the closed-loop
    observer (50) or the Kalman filter (80)-(82), and ``phi_hat(t+1)`` ((57)/(153)). Returns
    ``ST_STATE_RESET`` / ``ST_KF_RESET`` bits or 0.
    With ``regressor="filtered"`` (not the paper's default, see below) ``phi_hat(t+1)`` is
    built from the measurement-corrected estimate ``x_hat(t|t)``.
``ok = estimator_restart(rec, off, cfg_i, theta, P)``
    Restart the parameter estimate at ``theta`` (2n) with covariance ``P`` (2n x 2n; only its
    diagonal blocks for D- rules); SG/MISG: ``r <- r(0)``; empties the finite-history window.
    Returns ``False`` and leaves the record untouched when ``P`` is not positive definite.
``reset_covariance(rec, off, cfg_i)``
    ``P <- P(0)`` (``r <- r(0)``), window emptied, ``theta`` kept: the documented safe action.

Batch loops: ``update_lanes(R, cfg_f, cfg_i, y, status)``, ``predict_lanes(R, cfg_f, cfg_i, u,
status)`` run the lane functions over the rows of a ``(B, size)`` record (``prange``);
``run_lane(rec, cfg_f, cfg_i, u, y, thetas, status, stop)`` runs ``T`` steps of one lane.

The record (floats only, so it embeds in any caller's float record) holds: the parameters,
the factor of ``P`` and ``P(0)``'s factor (for the safe reset), the state estimate and
``x_hat(1)``, the regressor ``phi_hat(t+1)``, the stacked ``Phi``, ``Y``, ``E``, the Kalman
``P1``, ``P1(1)``, ``Q``, ``L1``, the finite-history buffer, event counters, the time ``t``, the
adaptation switch and scratch space (``"work"``), so that a lane function never allocates.

The regressor in closed loop (``regressor="filtered"``)
------------------------------------------------------
The paper builds ``phi_hat(t)`` from the state *predictions* ``x_hat(t-i)`` of (46)/(66):
``x1_hat(t|t-1)`` is a simulation of the current model (the open-loop observer (46) has no
output injection at all; the Kalman filter (66) weighs ``y`` only through ``L1``), so in closed
loop an early wrong or unstable model feeds its own errors back into the regressor, and the
estimate settles on a wrong model or the state estimate diverges with an unstable ``A_hat``.
``benchmarks/startup.py`` measures it: with the paper's regressor the self-tuning controller
loses about a quarter of a random family of second-order plants with O-RLS or KF-MILS.

``regressor="filtered"`` takes the measured ``y(t)`` into the state estimate before it enters
the regressor (the output injection of the filter-error method, R. E. Maine & K. W. Iliff,
SIAM J. Appl. Math. 41(3), 1981; R. Ding & L. Zhuang, "Parameter and state estimator for
state space models", 2014, eliminate the states and run least squares on input-output data for
the same canonical models):
``x_hat(t|t) = x_hat(t) + g [y(t) - c x_hat(t)]`` replaces ``x_hat(t)`` in (9)/(57)/(76) or
(153), where

* **Kalman filter**: ``g = P1(t) c^T / (R + c P1(t) c^T)``, the filtered estimate of the same
  filter; (80)-(82) are unchanged, since ``x_hat(t+1) = A_hat x_hat(t|t) + b_hat u(t)`` is what
  (80) computes. While the model is uncertain (large ``P1``, e.g. with the controller's
  process noise) ``x1_hat(t|t)`` follows ``y``; once it is good it follows the model, which
  removes the noise from the regressor (no equation-error bias).
* **open-loop observer**: the observer has no noise model, so it trusts ``y`` completely:
  ``g = A_hat^{n-1} e_n`` (``e_1`` in the observer form), for which ``c g = 1``, i.e.
  ``x1_hat(t|t) = y(t)``, and the state is propagated from it,
  ``x_hat(t+1) = A_hat x_hat(t|t) + b_hat u(t)``: the closed-loop observer (50) with
  ``K(t) = A_hat(t) g``, for which ``A_hat - K c`` is nilpotent (deadbeat) whatever
  ``theta_hat``, so the state estimate cannot diverge with an unstable model. In the observer
  form ``phi_hat`` then holds the measured outputs: equation-error least squares, consistent
  only for white equation noise.

The default ``"predicted"`` is the paper's algorithm (tested against a dense reference of its
formulas); the self-tuning controller uses ``"filtered"``.

Status bits
-----------
``ST_RESET`` the covariance (normaliser) was reset to ``P(0)`` (``r(0)``) after an overflow or
a failed health check (``ST_PD_LOST`` set as well when the factor check failed);
``ST_PROJECTED`` an unstable ``A_hat`` was rejected (``project_stable``); ``ST_RECOMPUTED`` a
finite-history downdate was ill-conditioned and the window estimate was recomputed by replay;
``ST_FROZEN`` the "frozen on a wrong model" signal switched on (see below); ``ST_STATE_RESET``
``x_hat(t+1)`` was not finite and was reset to ``x_hat(1)``; ``ST_KF_RESET`` the Kalman
covariance was not finite and was reset to ``P1(1)``.

Frozen-estimator signal
-----------------------
With the paper's ``p0 = 1e6`` an early unstable ``A_hat`` can drive the open-loop state estimate
to huge values; the huge regressors collapse ``P`` before ``theta`` is right and with
``lambda = 1`` it never recovers. Every least-squares update therefore tracks exponential means
(rate ``FROZEN_RATE = 1e-3``, i.e. over about 1000 steps) of ``e(t)^2``, ``y(t)^2`` and the gain
``q(t) = phi_hat(t)^T P(t-1) phi_hat(t)``. The ``frozen`` flag switches on when, after
``2 / FROZEN_RATE`` steps, the mean gain is below ``FROZEN_GAIN = 1e-3`` (``theta`` absorbs at
most 0.1 % of an innovation per step: ``P`` has collapsed) while the mean innovation power
exceeds ``frozen_ratio`` (default ``FROZEN_RATIO = 0.05``) times the mean output power (the
model explains less than 95 % of the output); it switches off below half that ratio. The
residual-input cross-correlation was tried first and rejected: a frozen pseudo-linear
regression's innovation is nearly uncorrelated with the last ``n`` inputs (|rho| ~ 0.01-0.04).
Measurement: ``benchmarks/estimators_perf.py --frozen``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from numbers import Integral, Real
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.kernels.canonical import companion_into
from stcgym.adaptive.kernels.least_squares import (
    block_trace_is_finite,
    carlson_update,
    downdate_block,
    factor_is_healthy,
    gradient_increment,
    least_squares_increment,
    upper_factor,
)
from stcgym.adaptive.kernels.records import copy_matrix, view2d
from stcgym.adaptive.kernels.state_estimation import (
    advance_regressor,
    filtered_state,
    is_schur_stable,
    kalman_step,
    observer_step,
)
from stcgym.envs.canonical import as_finite_vector, check_form
from stcgym.envs.compiled import Layout, lane, lanes, prange

__all__ = [
    "ALGORITHMS",
    "FIELDS",
    "RULES",
    "STATE_ESTIMATORS",
    "EstimatorSpec",
    "estimator_predict",
    "estimator_restart",
    "estimator_update",
    "parse_name",
    "predict_lanes",
    "reset_covariance",
    "run_lane",
    "update_lanes",
]

RULES: tuple[str, ...] = ("SG", "MISG", "RLS", "MILS")
STATE_ESTIMATORS: tuple[str, ...] = ("O", "KF", "CO")
#: Which state estimate the regressor ``phi_hat`` is built from (see :meth:`EstimatorSpec.build`).
REGRESSORS: tuple[str, ...] = ("predicted", "filtered")
#: The 16 algorithms of the paper (``CO-...`` variants are accepted as well).
ALGORITHMS: tuple[str, ...] = tuple(
    f"{s}-{d}{r}" for d in ("", "D-") for r in RULES for s in ("O", "KF")
)

# ---- cfg_i: integer configuration --------------------------------------------------------
C_N, C_P, C_RULE, C_DEC, C_STATE, C_FORM, C_W, C_CHECK, C_STACKED, C_PROJECT = range(10)
C_FILTERED = 10  # 1: the regressor takes the measurement-corrected state x_hat(t|t)
C_OFF = 16  # cfg_i[C_OFF + k] = offset of FIELDS[k] in the estimator record
RULE_SG, RULE_MISG, RULE_RLS, RULE_MILS = range(4)
STATE_O, STATE_CO, STATE_KF = range(3)
# ---- cfg_f: float configuration ----------------------------------------------------------
F_LAM, F_R, F_RATE, F_RATIO, F_GAIN = range(5)
#: Frozen-signal defaults (see the module docstring; calibrated in ``stcgym.adaptive.recursive``).
FROZEN_RATE = 1e-3
FROZEN_RATIO = 0.05
FROZEN_GAIN = 1e-3

# ---- status bits ---------------------------------------------------------------------------
ST_RESET, ST_PROJECTED, ST_RECOMPUTED, ST_FROZEN = 1, 2, 4, 8
ST_STATE_RESET, ST_KF_RESET, ST_PD_LOST = 16, 32, 64

#: Record fields in ``cfg_i`` order (the lane functions index them by position).
FIELDS: tuple[str, ...] = (
    "theta", "S", "S0", "r", "r0", "x_hat", "x_init", "xs", "phi", "Phi", "Y", "E", "y",
    "K", "P1", "P1_init", "Q", "L1", "theta0", "hist_Phi", "hist_Y", "t", "phase", "enabled",
    "n_resets", "n_state_resets", "n_kf_resets", "n_projections", "n_window_recomputes",
    "count", "ewma_e2", "ewma_y2", "ewma_q", "frozen", "work",
)  # fmt: skip
(
    THETA, S_, S0_, R_, R0_, X, X0, XS, PHI, PHIS, Y_, E_, YLAST, K_, P1_, P10_, Q_, L1_,
    THETA0, HPHI, HY, T_, PHASE, ENABLED, NRES, NSRES, NKF, NPROJ, NREC, COUNT, EWE, EWY, EWQ,
    FROZEN, WORK,
) = range(len(FIELDS))  # fmt: skip


# ============================================================================================
# Lane functions
# ============================================================================================


@lane
def _o(cfg_i: NDArray, off: int, k: int) -> int:
    return off + cfg_i[C_OFF + k]


@lane
def reset_covariance(rec: NDArray, off: int, cfg_i: NDArray) -> None:
    """``P <- P(0)`` / ``r <- r(0)`` and an empty finite-history window; ``theta`` kept."""
    d = 2 * cfg_i[C_N]
    if cfg_i[C_RULE] >= RULE_RLS:
        o, o0 = _o(cfg_i, off, S_), _o(cfg_i, off, S0_)
        for i in range(d * d):
            rec[o + i] = rec[o0 + i]
    else:
        o, o0 = _o(cfg_i, off, R_), _o(cfg_i, off, R0_)
        rec[o] = rec[o0]
        rec[o + 1] = rec[o0 + 1]
    rec[_o(cfg_i, off, COUNT)] = 0.0


@lane
def _innovation(theta: NDArray, Phi: NDArray, Y: NDArray, p: int, E: NDArray) -> None:
    """``E(p, t) = Y(p, t) - Phi(p, t)^T theta``, eq. (17), (38)."""
    d = theta.shape[0]
    for k in range(p):
        acc = Y[k]
        for i in range(d):
            acc -= Phi[k, i] * theta[i]
        E[k] = acc


@lane
def _rule_increment(
    rec: NDArray,
    off: int,
    cfg_f: NDArray,
    cfg_i: NDArray,
    Phi: NDArray,
    E: NDArray,
    lam: float,
    delta: NDArray,
    K: NDArray,
    w: NDArray,
) -> bool:
    """``delta = increment of theta`` for the plain rule or both halves of a D- rule (each half
    sees the same innovation ``E`` computed with ``theta(t-1)``, (96)-(97), (124)); updates
    ``P`` / ``r``. Returns ``False`` on overflow."""
    n = cfg_i[C_N]
    d = 2 * n
    p = cfg_i[C_P]
    rule = cfg_i[C_RULE]
    nblocks = 2 if cfg_i[C_DEC] else 1
    ok = True
    for blk in range(nblocks):
        lo = 0 if nblocks == 1 else blk * n
        hi = d if nblocks == 1 else lo + n
        if rule >= RULE_RLS:
            S = view2d(rec, _o(cfg_i, off, S_), d, d)
            alpha = least_squares_increment(
                S, lo, hi, Phi, E, p, lam, rule == RULE_RLS, delta, K, w
            )
            ok = ok and alpha > 0.0 and math.isfinite(alpha) and block_trace_is_finite(S, lo, hi)
        else:
            o = _o(cfg_i, off, R_) + blk
            r = gradient_increment(rec[o], lo, hi, Phi, E, p, lam, cfg_i[C_STACKED] != 0, delta)
            ok = ok and r > 0.0 and math.isfinite(r)
            if ok:
                rec[o] = r
    return ok


@lane
def _replay_window(rec: NDArray, off: int, cfg_i: NDArray, theta_w: NDArray) -> None:
    """Exact finite-history estimate by replaying the stored blocks from ``P(0)``: plain rules
    also replay ``theta`` from ``theta(0)`` into ``theta_w`` (regularised least squares over the
    window); D- rules recompute each half's ``P`` only (the hierarchical update is kept)."""
    n = cfg_i[C_N]
    d = 2 * n
    p = cfg_i[C_P]
    W = cfg_i[C_W]
    dec = cfg_i[C_DEC] != 0
    rule = cfg_i[C_RULE]
    count = int(rec[_o(cfg_i, off, COUNT)])  # read before the reset empties the window
    reset_covariance(rec, off, cfg_i)
    S = view2d(rec, _o(cfg_i, off, S_), d, d)
    work = rec[_o(cfg_i, off, WORK) :]
    delta, K, w = work[:d], work[d : 2 * d], work[2 * d : 3 * d]
    E = work[5 * d : 5 * d + p]
    th0 = rec[_o(cfg_i, off, THETA0) :]
    for i in range(d):
        theta_w[i] = th0[i]
    hPhi = rec[_o(cfg_i, off, HPHI) :]
    hY = rec[_o(cfg_i, off, HY) :]
    first = count % W  # the oldest block (the newest was written just before)
    for m in range(W):
        k = (first + m) % W
        Phi = view2d(hPhi, k * p * d, p, d)
        Yk = hY[k * p : (k + 1) * p]
        if dec:
            for blk in range(2):
                lo = blk * n
                for j in range(p):
                    carlson_update(S, lo, lo + n, Phi[j], 1.0, K)
        else:
            _innovation(theta_w, Phi, Yk, p, E)
            least_squares_increment(S, 0, d, Phi, E, p, 1.0, rule == RULE_RLS, delta, K, w)
            for i in range(d):
                theta_w[i] += delta[i]
    rec[_o(cfg_i, off, COUNT)] = count


@lane
def _slide_window(
    rec: NDArray,
    off: int,
    cfg_i: NDArray,
    theta: NDArray,
    Phi: NDArray,
    Y: NDArray,
    delta: NDArray,
) -> int:
    """Finite history: store block ``t``, remove block ``t - W`` by an exact downdate (or
    recompute by replay when the downdate is ill-conditioned). Adjusts ``delta``."""
    n = cfg_i[C_N]
    d = 2 * n
    p = cfg_i[C_P]
    W = cfg_i[C_W]
    oc = _o(cfg_i, off, COUNT)
    count = int(rec[oc])
    k = count % W
    rec[oc] = count + 1
    hPhi = view2d(rec[_o(cfg_i, off, HPHI) :], k * p * d, p, d)
    hY = rec[_o(cfg_i, off, HY) + k * p : _o(cfg_i, off, HY) + (k + 1) * p]
    if count >= W:
        work = rec[_o(cfg_i, off, WORK) :]
        w = work[2 * d : 4 * d]
        E_old = work[5 * d + p : 5 * d + 2 * p]
        tw = work[4 * d : 5 * d]
        for i in range(d):
            tw[i] = theta[i] + delta[i]
        _innovation(tw, hPhi, hY, p, E_old)
        S = view2d(rec, _o(cfg_i, off, S_), d, d)
        saved = view2d(work, 5 * d + 2 * p, d, d)
        copy_matrix(S, saved)
        nblocks = 2 if cfg_i[C_DEC] else 1
        ok = True
        for blk in range(nblocks):
            lo = 0 if nblocks == 1 else blk * n
            hi = d if nblocks == 1 else lo + n
            if ok:
                ok = downdate_block(S, lo, hi, hPhi, E_old, p, delta, w)
        if not ok:
            copy_matrix(saved, S)
            copy_matrix(Phi[:p], hPhi)
            for j in range(p):
                hY[j] = Y[j]
            rec[_o(cfg_i, off, NREC)] += 1.0
            _replay_window(rec, off, cfg_i, tw)
            if not cfg_i[C_DEC]:
                for i in range(d):
                    delta[i] = tw[i] - theta[i]
            return ST_RECOMPUTED
    copy_matrix(Phi[:p], hPhi)
    for j in range(p):
        hY[j] = Y[j]
    return 0


@lane
def _gain(rec: NDArray, off: int, cfg_i: NDArray, phi: NDArray) -> float:
    """``q = phi^T P phi = ||S^T phi||^2`` (over both halves for D- rules)."""
    d = 2 * cfg_i[C_N]
    S = view2d(rec, _o(cfg_i, off, S_), d, d)
    q = 0.0
    for j in range(d):
        acc = 0.0
        for i in range(j + 1):
            acc += S[i, j] * phi[i]
        q += acc * acc
    return q


@lane
def estimator_update(rec: NDArray, off: int, cfg_f: NDArray, cfg_i: NDArray, y: float) -> int:
    """Measurement step at time ``t``; see the module docstring."""
    n = cfg_i[C_N]
    d = 2 * n
    p = cfg_i[C_P]
    rule = cfg_i[C_RULE]
    theta = rec[_o(cfg_i, off, THETA) : _o(cfg_i, off, THETA) + d]
    Phi = view2d(rec, _o(cfg_i, off, PHIS), p, d)
    Y = rec[_o(cfg_i, off, Y_) : _o(cfg_i, off, Y_) + p]
    E = rec[_o(cfg_i, off, E_) : _o(cfg_i, off, E_) + p]
    phi = rec[_o(cfg_i, off, PHI) : _o(cfg_i, off, PHI) + d]
    for k in range(p - 1, 0, -1):  # column j of the paper's Phi(p, t) is phi_hat(t - j)
        for i in range(d):
            Phi[k, i] = Phi[k - 1, i]
        Y[k] = Y[k - 1]
    for i in range(d):
        Phi[0, i] = phi[i]
    Y[0] = y
    ot = _o(cfg_i, off, T_)
    t = rec[ot] + 1.0
    rec[ot] = t
    rec[_o(cfg_i, off, YLAST)] = y
    rec[_o(cfg_i, off, PHASE)] = 1.0
    status = 0
    _innovation(theta, Phi, Y, p, E)
    if rec[_o(cfg_i, off, ENABLED)] == 0.0:
        return status
    work = rec[_o(cfg_i, off, WORK) :]
    delta, K, w = work[:d], work[d : 2 * d], work[2 * d : 4 * d]
    theta_prev = work[4 * d : 5 * d]
    least_squares = rule >= RULE_RLS
    q = _gain(rec, off, cfg_i, phi) if least_squares else 0.0
    ok = _rule_increment(rec, off, cfg_f, cfg_i, Phi, E, cfg_f[F_LAM], delta, K, w)
    if ok and cfg_i[C_W] > 0:
        status |= _slide_window(rec, off, cfg_i, theta, Phi, Y, delta)
    if ok:
        for i in range(d):
            ok = ok and math.isfinite(delta[i])
    check = cfg_i[C_CHECK]
    if ok and least_squares and check > 0 and int(t) % check == 0:
        S = view2d(rec, _o(cfg_i, off, S_), d, d)
        if cfg_i[C_DEC]:
            healthy = factor_is_healthy(S, 0, n) and factor_is_healthy(S, n, d)
        else:
            healthy = factor_is_healthy(S, 0, d)
        if not healthy:
            ok = False
            status |= ST_PD_LOST
    if not ok:
        reset_covariance(rec, off, cfg_i)
        rec[_o(cfg_i, off, NRES)] += 1.0
        return status | ST_RESET
    if cfg_i[C_PROJECT]:
        for i in range(d):
            theta_prev[i] = theta[i]
    for i in range(d):
        theta[i] += delta[i]
    if cfg_i[C_PROJECT] and not is_schur_stable(theta, n, K):
        for i in range(d):
            theta[i] = theta_prev[i]
        rec[_o(cfg_i, off, NPROJ)] += 1.0
        status |= ST_PROJECTED
    if least_squares:
        status |= _frozen_signal(rec, off, cfg_f, cfg_i, E[0], y, q, t)
    return status


@lane
def _frozen_signal(
    rec: NDArray, off: int, cfg_f: NDArray, cfg_i: NDArray, e: float, y: float, q: float, t: float
) -> int:
    """Update the running means of ``e^2``, ``y^2``, ``q`` and the ``frozen`` flag."""
    rate = cfg_f[F_RATE]
    oe, oy, oq = _o(cfg_i, off, EWE), _o(cfg_i, off, EWY), _o(cfg_i, off, EWQ)
    rec[oe] += rate * (e * e - rec[oe])
    rec[oy] += rate * (y * y - rec[oy])
    rec[oq] += rate * (q - rec[oq])
    of = _o(cfg_i, off, FROZEN)
    was = rec[of] != 0.0
    # hysteresis: on above ratio * mean y^2, off again below half of that
    ratio = cfg_f[F_RATIO] * (0.5 if was else 1.0)
    frozen = (
        t * rate > 2.0 and rec[oe] > ratio * rec[oy] and rec[oy] > 0.0 and rec[oq] < cfg_f[F_GAIN]
    )
    rec[of] = 1.0 if frozen else 0.0
    return ST_FROZEN if (frozen and not was) else 0


@lane
def estimator_predict(rec: NDArray, off: int, cfg_f: NDArray, cfg_i: NDArray, u: float) -> int:
    """State step with the applied input ``u(t)``; see the module docstring."""
    n = cfg_i[C_N]
    d = 2 * n
    p = cfg_i[C_P]
    state = cfg_i[C_STATE]
    observability = cfg_i[C_FORM] != 0
    theta = rec[_o(cfg_i, off, THETA) : _o(cfg_i, off, THETA) + d]
    x = rec[_o(cfg_i, off, X) : _o(cfg_i, off, X) + n]
    y = rec[_o(cfg_i, off, YLAST)]
    work = rec[_o(cfg_i, off, WORK) :]
    base = 5 * d + 2 * p + d * d
    A = view2d(work, base, n, n)
    x_next = work[base + n * n : base + n * n + n]
    kf_work = work[base + n * n + n : base + 3 * n * n + n]
    x_reg = work[base + 3 * n * n + n : base + 3 * n * n + 2 * n]
    companion_into(theta, n, observability, A)
    b = theta[n:]
    status = 0
    filtered = cfg_i[C_FILTERED] != 0
    if filtered:
        _corrected_state(rec, off, cfg_f, cfg_i, A, x, y, x_reg, x_next)
    if state == STATE_KF:
        P1 = view2d(rec, _o(cfg_i, off, P1_), n, n)
        Q = view2d(rec, _o(cfg_i, off, Q_), n, n)
        L1 = rec[_o(cfg_i, off, L1_) : _o(cfg_i, off, L1_) + n]
        if kalman_step(A, b, P1, Q, cfg_f[F_R], x, u, y, x_next, L1, kf_work) != 0:
            o0, o1 = _o(cfg_i, off, P10_), _o(cfg_i, off, P1_)
            for i in range(n * n):
                rec[o1 + i] = rec[o0 + i]
            for i in range(n):
                L1[i] = 0.0
            rec[_o(cfg_i, off, NKF)] += 1.0
            status |= ST_KF_RESET
    else:  # filtered O: x_hat(t+1) = A_hat x_hat(t|t) + b_hat u(t), the injection is in x_reg
        K = rec[_o(cfg_i, off, K_) : _o(cfg_i, off, K_) + n]
        observer_step(A, b, x_reg if filtered else x, u, y, K, state == STATE_CO, x_next)
    phi = rec[_o(cfg_i, off, PHI) : _o(cfg_i, off, PHI) + d]
    xs = view2d(rec, _o(cfg_i, off, XS), n if observability else 0, n)
    advance_regressor(phi, xs, x_reg if filtered else x, u, n, observability)
    finite = True
    for i in range(n):
        finite = finite and math.isfinite(x_next[i])
    if not finite:
        ox0 = _o(cfg_i, off, X0)
        for i in range(n):
            x_next[i] = rec[ox0 + i]
        rec[_o(cfg_i, off, NSRES)] += 1.0
        status |= ST_STATE_RESET
    for i in range(n):
        x[i] = x_next[i]
    rec[_o(cfg_i, off, PHASE)] = 0.0
    return status


@lane
def _corrected_state(
    rec: NDArray,
    off: int,
    cfg_f: NDArray,
    cfg_i: NDArray,
    A: NDArray,
    x: NDArray,
    y: float,
    x_reg: NDArray,
    tmp: NDArray,
) -> None:
    """The measurement-corrected state ``x_hat(t|t) = x_hat(t) + g [y(t) - c x_hat(t)]`` of the
    ``regressor="filtered"`` option: ``g = P1 c^T / (R + c P1 c^T)`` for the Kalman filter (its
    filtered estimate), ``g = A_hat^{n-1} e_n`` for the observer (``c g = 1``, so
    ``x1_hat(t|t) = y(t)``, and ``A_hat (I - g c)`` is nilpotent: ``g = e_1`` in the observer
    form). ``tmp`` (n) is scratch."""
    n = cfg_i[C_N]
    if cfg_i[C_STATE] == STATE_KF:
        filtered_state(x, view2d(rec, _o(cfg_i, off, P1_), n, n), cfg_f[F_R], y, x_reg)
        return
    innov = y - x[0]
    for i in range(n):  # g = A^{n-1} e_n, built in x_reg
        x_reg[i] = 1.0 if i == n - 1 else 0.0
    for _ in range(n - 1):
        for i in range(n):
            acc = 0.0
            for j in range(n):
                acc += A[i, j] * x_reg[j]
            tmp[i] = acc
        for i in range(n):
            x_reg[i] = tmp[i]
    for i in range(n):
        x_reg[i] = x[i] + x_reg[i] * innov


@lane
def estimator_restart(rec: NDArray, off: int, cfg_i: NDArray, theta: NDArray, P: NDArray) -> bool:
    """Restart at ``theta`` and ``P``; see the module docstring."""
    n = cfg_i[C_N]
    d = 2 * n
    if cfg_i[C_RULE] >= RULE_RLS:
        p = cfg_i[C_P]
        F = view2d(rec[_o(cfg_i, off, WORK) :], 5 * d + 2 * p, d, d)
        if cfg_i[C_DEC]:
            F[:, :] = 0.0
            ok = upper_factor(P[:n, :n], F[:n, :n]) and upper_factor(P[n:, n:], F[n:, n:])
        else:
            ok = upper_factor(P, F)
        if not ok:
            return False
        copy_matrix(F, view2d(rec, _o(cfg_i, off, S_), d, d))
    else:
        reset_covariance(rec, off, cfg_i)
    rec[_o(cfg_i, off, COUNT)] = 0.0
    o = _o(cfg_i, off, THETA)
    for i in range(d):
        rec[o + i] = theta[i]
    return True


@lanes
def update_lanes(R: NDArray, cfg_f: NDArray, cfg_i: NDArray, y: NDArray, status: NDArray) -> None:
    """``estimator_update`` on every row of ``R`` (one lane per row)."""
    for i in prange(R.shape[0]):
        status[i] = estimator_update(R[i], 0, cfg_f, cfg_i, y[i])


@lanes
def predict_lanes(R: NDArray, cfg_f: NDArray, cfg_i: NDArray, u: NDArray, status: NDArray) -> None:
    """``estimator_predict`` on every row of ``R``."""
    for i in prange(R.shape[0]):
        status[i] = estimator_predict(R[i], 0, cfg_f, cfg_i, u[i])


@lane
def run_lane(
    rec: NDArray,
    cfg_f: NDArray,
    cfg_i: NDArray,
    u: NDArray,
    y: NDArray,
    thetas: NDArray,
    status: NDArray,
    stop_mask: int,
) -> int:
    """``T`` steps ``update(y[k])``, ``predict(u[k])`` of one lane; ``thetas[k] = theta_hat``
    after the update, ``status[k]`` the events of step ``k``. Stops after the first step whose
    status has a bit of ``stop_mask``; returns the number of steps done."""
    d = 2 * cfg_i[C_N]
    o = cfg_i[C_OFF + THETA]
    for k in range(u.shape[0]):
        st = estimator_update(rec, 0, cfg_f, cfg_i, y[k])
        for i in range(d):
            thetas[k, i] = rec[o + i]
        if st & stop_mask:
            status[k] = st
            return k + 1
        st |= estimator_predict(rec, 0, cfg_f, cfg_i, u[k])
        status[k] = st
        if st & stop_mask:
            return k + 1
    return u.shape[0]


# ============================================================================================
# Python side: validation and the spec
# ============================================================================================


def parse_name(name: str) -> tuple[str, bool, str]:
    """Split a paper name into ``(state estimator, decomposed, rule)``.

    ``"KF-D-MILS" -> ("KF", True, "MILS")``; case-insensitive; the state estimator is one of
    ``O``, ``KF``, ``CO`` (closed-loop observer, needs ``observer_gain``).
    """
    if not isinstance(name, str):
        raise ValueError(f"name must be a string such as 'KF-D-MILS', got {name!r}")
    parts = name.strip().upper().split("-")
    ok = (
        len(parts) in (2, 3)
        and parts[0] in STATE_ESTIMATORS
        and parts[-1] in RULES
        and (len(parts) == 2 or parts[1] == "D")
    )
    if not ok:
        raise ValueError(
            f"unknown algorithm {name!r}; expected '<state>-[D-]<rule>' with state in "
            f"{STATE_ESTIMATORS} and rule in {RULES}, e.g. one of {ALGORITHMS}"
        )
    return parts[0], len(parts) == 3, parts[-1]


def check_int(value: Any, name: str, minimum: int) -> int:
    """An integer ``>= minimum`` (booleans rejected), else ``ValueError`` naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, Integral) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def check_positive(value: Any, name: str) -> float:
    """A finite positive real number, else ``ValueError`` naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, Real):
        raise ValueError(f"{name} must be a finite positive real number, got {value!r}")
    v = float(value)
    if not (math.isfinite(v) and v > 0.0):
        raise ValueError(f"{name} must be a finite positive real number, got {value!r}")
    return v


def check_covariance(value: Any, dim: int, name: str, *, allow_singular: bool = False) -> NDArray:
    """A ``dim x dim`` covariance from a scalar, a vector (diagonal) or a matrix."""
    expected = (
        f"{name} must be a positive {'or zero ' if allow_singular else ''}scalar, a vector of "
        f"length {dim} or a symmetric positive {'semi' if allow_singular else ''}definite "
        f"{dim}x{dim} matrix"
    )
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{expected}, got {value!r}") from exc
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{expected}; it is not finite: {value!r}")
    if arr.ndim == 0 or (arr.ndim == 1 and arr.size == dim):
        diag = np.broadcast_to(arr, (dim,))
        if np.any(diag < 0) or (not allow_singular and np.any(diag <= 0)):
            raise ValueError(f"{expected}, got {value!r}")
        return np.diag(diag).astype(float)
    if arr.shape != (dim, dim):
        raise ValueError(f"{expected}, got shape {arr.shape}")
    scale = max(float(np.abs(arr).max()), 1e-300)
    if not np.allclose(arr, arr.T, rtol=0.0, atol=1e-12 * scale):
        raise ValueError(f"{expected}; it is not symmetric")
    M = 0.5 * (arr + arr.T)
    lam_min = float(np.linalg.eigvalsh(M).min())
    if lam_min < -1e-12 * scale or (not allow_singular and lam_min <= 0.0):
        raise ValueError(f"{expected}; its smallest eigenvalue is {lam_min:g}")
    return M


def upper_cholesky(P: NDArray) -> NDArray:
    """Upper-triangular ``S`` with ``S S^T = P`` (``P`` symmetric positive definite)."""
    S = np.zeros_like(P)
    if not upper_factor(np.ascontiguousarray(P, dtype=float), S):
        raise ValueError("P is not symmetric positive definite")
    return S


@dataclass(frozen=True, eq=False)
class EstimatorSpec:
    """One validated estimator configuration: record layout, config arrays, initial record.

    Build it with :meth:`build` (the keywords of :func:`stcgym.adaptive.make_estimator`).
    ``theta0``, ``P0``, ``x_init``, ``P1_init``, ``Q`` are the per-lane initial values written
    by :meth:`initial_record`. ``observer_gain`` may be a callable (evaluated by the Python
    class before every state step); the lane functions read the gain ``K`` from the record.
    """

    name: str
    n: int
    p: int
    form: str
    state: str
    rule: str
    decomposed: bool
    forgetting: float
    window: int | None
    stacked_r: bool
    project_stable: bool
    pd_check_every: int
    on_failure: str
    enabled: bool
    theta0: NDArray = field(repr=False)
    P0: NDArray | None = field(repr=False)
    r0: float = 1.0
    x_init: NDArray = field(default=None, repr=False)  # type: ignore[assignment]
    P1_init: NDArray | None = field(default=None, repr=False)
    Q: NDArray | None = field(default=None, repr=False)
    R: float = 1.0
    observer_gain: Any = field(default=None, repr=False)
    frozen: tuple[float, float, float] = (FROZEN_RATE, FROZEN_RATIO, FROZEN_GAIN)
    regressor: str = "predicted"

    # ---- construction ---------------------------------------------------------------------
    @classmethod
    def build(
        cls,
        name: str,
        n: int,
        *,
        p: int = 1,
        p0: float = 1e6,
        form: str = "observer",
        forgetting: float = 1.0,
        window: int | None = None,
        theta0: ArrayLike | None = None,
        P0: ArrayLike | None = None,
        r0: float | None = None,
        stacked_r: bool = False,
        x_init: ArrayLike | None = None,
        P1_init: ArrayLike | None = None,
        process_noise: ArrayLike | None = None,
        measurement_noise: float | None = None,
        observer_gain: Any = None,
        enabled: bool = True,
        on_failure: str = "reset",
        pd_check_every: int = 1,
        project_stable: bool = False,
        frozen_ratio: float = FROZEN_RATIO,
        regressor: str = "predicted",
    ) -> EstimatorSpec:
        """Validate ``make_estimator``'s arguments (a ``ValueError`` naming the argument)."""
        state, decomposed, rule = parse_name(name)
        n = check_int(n, "n", 1)
        p = check_int(p, "p", 1)
        if rule in ("SG", "RLS") and p != 1:
            raise ValueError(
                f"p (innovation length) applies to MISG/MILS; {rule} has p = 1, got p={p}"
            )
        p0 = check_positive(p0, "p0")
        form = check_form(form)
        lam = forgetting
        if isinstance(lam, bool) or not isinstance(lam, Real) or not (0.0 < float(lam) <= 1.0):
            raise ValueError(f"forgetting (lambda) must be a real number in (0, 1], got {lam!r}")
        lam = float(lam)
        least_squares = rule in ("RLS", "MILS")
        if window is not None:
            window = check_int(window, "window", 1)
            if not least_squares:
                raise ValueError("window (finite history) applies to RLS/MILS rules only")
            if lam != 1.0:
                raise ValueError("window and forgetting < 1 are mutually exclusive")
        d = 2 * n
        theta0_arr = (
            np.full(d, 1.0 / p0) if theta0 is None else as_finite_vector(theta0, "theta0", length=d)
        )
        if P0 is not None and not least_squares:
            raise ValueError(f"P0 applies to RLS/MILS rules only, not {rule}")
        if r0 is not None and least_squares:
            raise ValueError(f"r0 applies to SG/MISG rules only, not {rule}")
        if stacked_r and least_squares:
            raise ValueError(f"stacked_r applies to SG/MISG rules only, not {rule}")
        P0_mat = None
        if least_squares:
            P0_mat = p0 * np.eye(d) if P0 is None else check_covariance(P0, d, "P0")
            if decomposed and (np.any(P0_mat[:n, n:] != 0.0) or np.any(P0_mat[n:, :n] != 0.0)):
                raise ValueError(
                    "P0 must be block-diagonal diag(P_a, P_b) for D- rules (separate a and b "
                    "covariances)"
                )
        r0_val = 1.0 if r0 is None else check_positive(r0, "r0")
        x_init_arr = (
            np.full(n, 1.0 / p0) if x_init is None else as_finite_vector(x_init, "x_init", length=n)
        )
        kf = {
            "P1_init": P1_init,
            "process_noise": process_noise,
            "measurement_noise": measurement_noise,
        }
        P1 = Q = None
        R = 1.0
        gain: Any = None
        if state == "KF":
            if observer_gain is not None:
                raise ValueError("observer_gain applies to O/CO state estimators, not KF")
            P1 = np.eye(n) if P1_init is None else check_covariance(P1_init, n, "P1_init")
            Q = (
                np.zeros((n, n))
                if process_noise is None
                else check_covariance(process_noise, n, "process_noise", allow_singular=True)
            )
            if measurement_noise is not None:
                R = check_positive(measurement_noise, "measurement_noise")
        else:
            given = [k for k, v in kf.items() if v is not None]
            if given:
                raise ValueError(f"{', '.join(given)} apply to KF state estimators only")
            if state == "CO" and observer_gain is None:
                raise ValueError("CO (closed-loop observer) needs observer_gain=K (or a callable)")
            if observer_gain is not None:
                state = "CO"
                if callable(observer_gain):
                    gain = observer_gain
                else:
                    K = np.asarray(observer_gain, dtype=float)
                    if K.shape != (n,) or not np.all(np.isfinite(K)):
                        raise ValueError(
                            f"observer_gain must be a finite vector of length n={n} or a "
                            f"callable (a_hat, b_hat) -> K, got {observer_gain!r}"
                        )
                    gain = K.copy()
        if on_failure not in ("reset", "raise"):
            raise ValueError(f"on_failure must be 'reset' or 'raise', got {on_failure!r}")
        pd_check_every = check_int(pd_check_every, "pd_check_every", 0)
        if (
            isinstance(frozen_ratio, bool)
            or not isinstance(frozen_ratio, Real)
            or not (float(frozen_ratio) > 0.0)
        ):
            raise ValueError(
                f"frozen_ratio must be a positive real number (math.inf disables the frozen "
                f"signal), got {frozen_ratio!r}"
            )
        if regressor not in REGRESSORS:
            raise ValueError(f"regressor must be one of {REGRESSORS}, got {regressor!r}")
        if regressor == "filtered" and state == "CO":
            raise ValueError(
                "regressor='filtered' applies to the open-loop observer (O) and the Kalman filter "
                "(KF); the closed-loop observer (CO, observer_gain) has its own output injection"
            )
        canonical = f"{state}-{'D-' if decomposed else ''}{rule}"
        return cls(
            name=canonical,
            n=n,
            p=p,
            form=form,
            state=state,
            rule=rule,
            decomposed=decomposed,
            forgetting=lam,
            window=window,
            stacked_r=bool(stacked_r),
            project_stable=bool(project_stable),
            pd_check_every=pd_check_every,
            on_failure=on_failure,
            enabled=bool(enabled),
            theta0=theta0_arr,
            P0=P0_mat,
            r0=r0_val,
            x_init=x_init_arr,
            P1_init=P1,
            Q=Q,
            R=R,
            observer_gain=gain,
            frozen=(FROZEN_RATE, float(frozen_ratio), FROZEN_GAIN),
            regressor=regressor,
        )

    def __post_init__(self) -> None:
        n, p, d = self.n, self.p, 2 * self.n
        ls = self.rule in ("RLS", "MILS")
        W = self.window or 0
        kf = self.state == "KF"
        shapes: dict[str, tuple[int, ...]] = {
            "theta": (d,),
            "S": (d, d) if ls else (0,),
            "S0": (d, d) if ls else (0,),
            "r": (0,) if ls else (2,),
            "r0": (0,) if ls else (2,),
            "x_hat": (n,),
            "x_init": (n,),
            "xs": (n, n) if self.form == "observability" else (0,),
            "phi": (d,),
            "Phi": (p, d),
            "Y": (p,),
            "E": (p,),
            "K": (n,) if self.state == "CO" else (0,),
            "P1": (n, n) if kf else (0,),
            "P1_init": (n, n) if kf else (0,),
            "Q": (n, n) if kf else (0,),
            "L1": (n,) if kf else (0,),
            "theta0": (d,) if W else (0,),
            "hist_Phi": (W, p, d) if W else (0,),
            "hist_Y": (W, p) if W else (0,),
            # delta, K, w (2d), theta_prev / replay; E, E_old; saved S; A, x_next, 2 n^2 (KF)
            # x_hat(t|t) of the filtered regressor (n)
            "work": (5 * d + 2 * p + d * d + 3 * n * n + 2 * n,),
        }
        layout = Layout()
        for name in FIELDS:
            layout.add(name, shapes.get(name, ()))
        cfg_i = np.zeros(C_OFF + len(FIELDS), dtype=np.int64)
        cfg_i[C_N] = n
        cfg_i[C_P] = p
        cfg_i[C_RULE] = RULES.index(self.rule)
        cfg_i[C_DEC] = int(self.decomposed)
        cfg_i[C_STATE] = {"O": STATE_O, "CO": STATE_CO, "KF": STATE_KF}[self.state]
        cfg_i[C_FORM] = int(self.form == "observability")
        cfg_i[C_W] = W
        cfg_i[C_CHECK] = self.pd_check_every
        cfg_i[C_STACKED] = int(self.stacked_r)
        cfg_i[C_PROJECT] = int(self.project_stable)
        cfg_i[C_FILTERED] = int(self.regressor == "filtered")
        cfg_i[C_OFF:] = layout.offsets(FIELDS)
        cfg_f = np.array([self.forgetting, self.R, *self.frozen], dtype=np.float64)
        cfg_i.setflags(write=False)
        cfg_f.setflags(write=False)
        object.__setattr__(self, "layout", layout)
        object.__setattr__(self, "cfg_i", cfg_i)
        object.__setattr__(self, "cfg_f", cfg_f)

    # ---- the record -----------------------------------------------------------------------
    layout: Layout = field(init=False, repr=False)
    cfg_i: NDArray = field(init=False, repr=False)
    cfg_f: NDArray = field(init=False, repr=False)

    @property
    def size(self) -> int:
        """Floats per lane record."""
        return self.layout.size

    @property
    def least_squares(self) -> bool:
        return self.rule in ("RLS", "MILS")

    def offset(self, name: str) -> int:
        """Offset of the field ``name`` relative to the start of the estimator record."""
        return self.layout.offset(name)

    def initial_record(self, theta0: NDArray | None = None, P0: NDArray | None = None) -> NDArray:
        """One lane's record at ``t = 0`` (``theta_hat(0)``, ``P(0)``, ``x_hat(1)``, ...),
        optionally with this lane's own ``theta0`` / ``P0``."""
        lay = self.layout
        rec = lay.empty(1)
        th0 = self.theta0 if theta0 is None else theta0
        lay.view(rec, "theta")[0] = th0
        if self.window:
            lay.view(rec, "theta0")[0] = th0
        if self.least_squares:
            P = self.P0 if P0 is None else P0
            n = self.n
            if self.decomposed:
                S0 = np.zeros_like(P)
                S0[:n, :n] = upper_cholesky(P[:n, :n])
                S0[n:, n:] = upper_cholesky(P[n:, n:])
            else:
                S0 = upper_cholesky(P)
            lay.view(rec, "S")[0] = S0
            lay.view(rec, "S0")[0] = S0
        else:
            lay.view(rec, "r")[0] = self.r0
            lay.view(rec, "r0")[0] = self.r0
        lay.view(rec, "x_hat")[0] = self.x_init
        lay.view(rec, "x_init")[0] = self.x_init
        if self.state == "KF":
            lay.view(rec, "P1")[0] = self.P1_init
            lay.view(rec, "P1_init")[0] = self.P1_init
            lay.view(rec, "Q")[0] = self.Q
        if self.state == "CO" and not callable(self.observer_gain):
            lay.view(rec, "K")[0] = self.observer_gain
        lay.view(rec, "enabled")[0] = float(self.enabled)
        return rec[0]
