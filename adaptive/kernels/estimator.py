"""The joint state/parameter estimator of Ding & Ma (2014) as two lane functions on a lane record.

Published interface (used by the self-tuning controller's lane step)
------------------------------------------------------------------
``spec = EstimatorSpec.build(name, n, **make_estimator_keywords)`` (:mod:`.estimator_spec`)
describes one configuration: ``spec.config`` (an :class:`EstimatorConfig`) and the record's
offsets ``spec.at`` (an :class:`EstimatorRecord`; ``spec.record(base)`` for a record stored at
``base`` of a larger lane record, such as the controller's).

``status = estimator_update(rec, at, cfg, y, windowed=True)``
    Measurement step at time ``t`` on the estimator record stored in ``rec`` at the offsets
    ``at`` (``rec`` a 1-D float64 array, e.g. the controller's own lane record): shift the
    stacked window ``Phi(p, t)``, ``Y(p, t)`` (eq. (19)-(20), (74)-(75)), compute the innovation
    ``E(p, t) = Y(p, t) - Phi(p, t)^T theta_hat(t-1)`` and update ``theta_hat(t)`` with the rule:
    SG (12)-(15), MISG (16)-(22), RLS (32)-(36), MILS (37)-(44), D-SG (96)-(103), D-MISG
    (104)-(117), D-RLS (124)-(133), D-MILS (134)-(145); as a whole O-RLS (54)-(57), KF-MILS
    (73)-(79). Returns a bit set of ``ST_*`` events (0: nothing happened).
``status = estimator_predict(rec, at, cfg, u)``
    State step with the applied ``u(t)``: ``A_hat(t)``, ``b_hat(t)`` from ``theta_hat(t)``
    ((59)-(60), (83)-(84)), ``x_hat(t+1)`` by the open-loop observer (58), the closed-loop
    observer (50) or the Kalman filter (80)-(82), and ``phi_hat(t+1)`` ((57)/(153)). Returns
    ``ST_STATE_RESET`` / ``ST_KF_RESET`` bits or 0.
    With ``regressor="filtered"`` (not the paper's default, see below) ``phi_hat(t+1)`` is
    built from the measurement-corrected estimate ``x_hat(t|t)``.
``ok = estimator_restart(rec, at, cfg, theta, P)``
    Restart the parameter estimate at ``theta`` (2n) with covariance ``P`` (2n x 2n; only its
    diagonal blocks for D- rules); SG/MISG: ``r <- r(0)``; empties the finite-history window.
    Returns ``False`` and leaves the record untouched when ``P`` is not positive definite.
``reset_covariance(rec, at, cfg)``
    ``P <- P(0)`` (``r <- r(0)``), window emptied, ``theta`` kept: the documented safe action.

The batch loops over lanes and the ``T``-step loop of one lane are in :mod:`.estimator_lanes`.

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

  With output noise that bias costs the loop (``O-RLS`` settles at ``a = [-1.57, 0.53]`` on a
  plant with ``a = [-1.7, 0.66]``), and the paper's regressor, unbiased where it converges, is
  lost from a cold start. ``injection = gamma`` and ``injection_warmup = N`` sit between the
  two: the whole injection for the first ``N`` steps (a cold start from ``theta = 0`` needs it),
  then ``g <- gamma g``, i.e. the closed-loop observer (50) with ``K = gamma A_hat g``. In the
  observer form its error dynamics ``A_hat (I - gamma g c)`` have the characteristic
  polynomial ``z^n + (1 - gamma)(a_1 z^{n-1} + ... + a_n)``: every coefficient of ``A_hat``'s
  shrunk by ``1 - gamma``, so the observer stays stable on moderately unstable models
  (``a = [-1.7, 0.66]``, ``gamma = 0.4``: poles of magnitude 0.63), while the regressor
  keeps ``1 - gamma`` of the model's noise-free prediction, which reduces the
  equation-error bias (the stabilised output-error idea of the filter-error method).
  ``benchmarks/startup.py`` measures it; the self-tuning controller takes ``gamma = 0.4``,
  ``N = 50`` for the ``O-`` estimators.

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
model explains less than 95 % of the output); it switches off below half that ratio (a
frozen pseudo-linear regression's innovation is nearly uncorrelated with the last ``n``
inputs, so their cross-correlation would not show it).
Measurement: ``benchmarks/estimators_perf.py --frozen``.
"""

from __future__ import annotations

import math

from numpy.typing import NDArray

from stcgym.adaptive.kernels.canonical import companion_into
from stcgym.adaptive.kernels.estimator_spec import (
    ALGORITHMS,
    FROZEN_GAIN,
    FROZEN_RATE,
    FROZEN_RATIO,
    REGRESSORS,
    RULES,
    STATE_ESTIMATORS,
    EstimatorConfig,
    EstimatorSpec,
    EstimatorState,
    EstimatorWork,
    parse_name,
    upper_cholesky,
)
from stcgym.adaptive.kernels.least_squares import (
    block_trace_is_finite,
    carlson_update,
    downdate_block,
    factor_is_healthy,
    gradient_increment,
    least_squares_increment,
    projection_increment,
    upper_factor,
)
from stcgym.adaptive.kernels.linalg import matvec
from stcgym.adaptive.kernels.records import copy_matrix, copy_vector
from stcgym.adaptive.kernels.state_estimation import (
    advance_regressor,
    filtered_state,
    is_schur_stable,
    kalman_step,
    observer_step,
)
from stcgym.adaptive.kernels.variants import RULES as _RULES
from stcgym.adaptive.kernels.variants import STATE_ESTIMATORS as _STATES
from stcgym.envs.compiled import lane

__all__ = [
    "ALGORITHMS",
    "FROZEN_GAIN",
    "FROZEN_RATE",
    "FROZEN_RATIO",
    "REGRESSORS",
    "RULES",
    "STATE_ESTIMATORS",
    "EstimatorConfig",
    "EstimatorSpec",
    "EstimatorState",
    "EstimatorWork",
    "estimator_predict",
    "estimator_restart",
    "estimator_update",
    "parse_name",
    "reset_covariance",
    "upper_cholesky",
]

# ---- the variants' codes (compile-time constants; compared for equality only) ------------------
RULE_SG, RULE_MISG = _RULES["SG"].code, _RULES["MISG"].code
RULE_RLS, RULE_MILS = _RULES["RLS"].code, _RULES["MILS"].code
RULE_NG = _RULES["NG"].code
STATE_CO, STATE_KF = _STATES["CO"].code, _STATES["KF"].code

# ---- status bits (values, not offsets) -------------------------------------------------------
ST_RESET, ST_PROJECTED, ST_RECOMPUTED, ST_FROZEN = 1, 2, 4, 8
ST_STATE_RESET, ST_KF_RESET, ST_PD_LOST = 16, 32, 64


# ============================================================================================
# Lane functions: ``s`` the estimator's lane state, ``w`` its scratch (:class:`EstimatorState`,
# :class:`EstimatorWork`: named batched arrays), ``i`` the lane
# ============================================================================================


@lane(entry=True)
def reset_covariance(s: EstimatorState, i: int, cfg: EstimatorConfig) -> None:
    """``P <- P(0)`` / ``r <- r(0)`` and an empty finite-history window; ``theta`` kept."""
    copy_matrix(s.S0[i], s.S[i])  # empty without a covariance
    copy_vector(s.r0[i], s.r[i])  # empty without normalisers
    s.count[i] = 0


@lane
def _innovation(theta: NDArray, Phi: NDArray, Y: NDArray, p: int, E: NDArray) -> None:
    """``E(p, t) = Y(p, t) - Phi(p, t)^T theta``, eq. (17), (38)."""
    d = theta.shape[0]
    for k in range(p):
        acc = Y[k]
        for i in range(d):
            acc -= Phi[k, i] * theta[i]
        E[k] = acc


@lane(inline=True)
def _rule_increment(
    s: EstimatorState, w: EstimatorWork, i: int, cfg: EstimatorConfig, Phi: NDArray, E: NDArray
) -> bool:
    """``w.delta = increment of theta`` for the plain rule or both halves of a D- rule (each
    half sees the same innovation ``E`` computed with ``theta(t-1)``, (96)-(97), (124));
    updates ``P`` / ``r``. Returns ``False`` on overflow."""
    n = cfg.n
    d = 2 * n
    p = cfg.p
    lam = cfg.forgetting
    S, r, delta, K, scratch = s.S[i], s.r[i], w.delta[i], w.K[i], w.w[i]
    nblocks = 2 if cfg.decomposed else 1
    ok = True
    for blk in range(nblocks):
        lo = 0 if nblocks == 1 else blk * n
        hi = d if nblocks == 1 else lo + n
        if cfg.rule == RULE_RLS or cfg.rule == RULE_MILS:
            alpha = least_squares_increment(
                S, lo, hi, Phi, E, p, lam, cfg.rule == RULE_RLS, delta, K, scratch
            )
            ok = ok and alpha > 0.0 and math.isfinite(alpha) and block_trace_is_finite(S, lo, hi)
        elif cfg.rule == RULE_SG or cfg.rule == RULE_MISG:
            r_new = gradient_increment(r[blk], lo, hi, Phi, E, p, lam, cfg.stacked_r, delta)
            ok = ok and r_new > 0.0 and math.isfinite(r_new)
            if ok:
                r[blk] = r_new
        elif cfg.rule == RULE_NG:
            norm = projection_increment(lo, hi, Phi[0], E[0], cfg.rule_parameters, delta)
            ok = ok and norm > 0.0 and math.isfinite(norm)
        else:  # a rule without an increment here: report it, never apply stale scratch
            ok = False
    return ok


@lane
def _replay_window(
    s: EstimatorState, w: EstimatorWork, i: int, cfg: EstimatorConfig, theta_w: NDArray
) -> None:
    """Exact finite-history estimate by replaying the stored blocks from ``P(0)``: plain rules
    also replay ``theta`` from ``theta(0)`` into ``theta_w`` (regularised least squares over the
    window); D- rules recompute each half's ``P`` only (the hierarchical update is kept)."""
    n = cfg.n
    d = 2 * n
    p = cfg.p
    W = cfg.window
    count = s.count[i]  # read before the reset empties the window
    reset_covariance(s, i, cfg)
    S, theta0, hist_Phi, hist_Y = s.S[i], s.theta0[i], s.hist_Phi[i], s.hist_Y[i]
    delta, K, scratch, E = w.delta[i], w.K[i], w.w[i], w.E_replay[i]
    for j in range(d):
        theta_w[j] = theta0[j]
    first = count % W  # the oldest block (the newest was written just before)
    for m in range(W):
        k = (first + m) % W
        Phi = hist_Phi[k]
        Yk = hist_Y[k]
        if cfg.decomposed:
            for blk in range(2):
                lo = blk * n
                for j in range(p):
                    carlson_update(S, lo, lo + n, Phi[j], 1.0, K)
        else:
            _innovation(theta_w, Phi, Yk, p, E)
            scalar = cfg.rule == RULE_RLS
            least_squares_increment(S, 0, d, Phi, E, p, 1.0, scalar, delta, K, scratch)
            for j in range(d):
                theta_w[j] += delta[j]
    s.count[i] = count


@lane
def _slide_window(
    s: EstimatorState,
    w: EstimatorWork,
    i: int,
    cfg: EstimatorConfig,
    theta: NDArray,
    Phi: NDArray,
    Y: NDArray,
) -> int:
    """Finite history: store block ``t``, remove block ``t - W`` by an exact downdate (or
    recompute by replay when the downdate is ill-conditioned). Adjusts ``w.delta``."""
    n = cfg.n
    d = 2 * n
    p = cfg.p
    W = cfg.window
    count = s.count[i]
    k = count % W
    s.count[i] = count + 1
    hPhi = s.hist_Phi[i][k]
    hY = s.hist_Y[i][k]
    delta = w.delta[i]
    if count >= W:
        E_old, tw = w.E_old[i], w.theta_prev[i]
        for j in range(d):
            tw[j] = theta[j] + delta[j]
        _innovation(tw, hPhi, hY, p, E_old)
        S, saved = s.S[i], w.S_saved[i]
        copy_matrix(S, saved)
        nblocks = 2 if cfg.decomposed else 1
        ok = True
        for blk in range(nblocks):
            lo = 0 if nblocks == 1 else blk * n
            hi = d if nblocks == 1 else lo + n
            if ok:
                ok = downdate_block(S, lo, hi, hPhi, E_old, p, delta, w.w[i])
        if not ok:
            copy_matrix(saved, S)
            copy_matrix(Phi[:p], hPhi)
            for j in range(p):
                hY[j] = Y[j]
            s.n_window_recomputes[i] += 1
            _replay_window(s, w, i, cfg, tw)
            if not cfg.decomposed:
                for j in range(d):
                    delta[j] = tw[j] - theta[j]
            return ST_RECOMPUTED
    copy_matrix(Phi[:p], hPhi)
    for j in range(p):
        hY[j] = Y[j]
    return 0


@lane(inline=True)
def _gain(S: NDArray, phi: NDArray) -> float:
    """``q = phi^T P phi = ||S^T phi||^2`` (over both halves for D- rules)."""
    d = phi.shape[0]
    q = 0.0
    for j in range(d):
        acc = 0.0
        for i in range(j + 1):
            acc += S[i, j] * phi[i]
        q += acc * acc
    return q


@lane(inline=True)
def estimator_update(
    s: EstimatorState,
    w: EstimatorWork,
    i: int,
    cfg: EstimatorConfig,
    y: float,
    windowed: bool | None = None,
) -> int:
    """Measurement step at time ``t`` of lane ``i``; see the module docstring.

    ``windowed``: ``True`` where the configuration may have a finite history window
    (``cfg.window > 0``). Left out (``None``), the compiled version has no window code at all
    (numba prunes the branch on the argument's type before it types the function), so a
    caller that never slides a window (the self-tuning controller) does not compile the
    downdate and replay; that version raises ``ValueError`` on a configuration with a window.
    """
    if windowed is None and cfg.window > 0:
        raise ValueError("estimator_update: a configuration with window > 0 needs windowed=True")
    n = cfg.n
    d = 2 * n
    p = cfg.p
    theta, Phi, Y, E, phi = s.theta[i], s.Phi[i], s.Y[i], s.E[i], s.phi[i]
    for k in range(p - 1, 0, -1):  # column j of the paper's Phi(p, t) is phi_hat(t - j)
        for j in range(d):
            Phi[k, j] = Phi[k - 1, j]
        Y[k] = Y[k - 1]
    for j in range(d):
        Phi[0, j] = phi[j]
    Y[0] = y
    t = s.t[i] + 1
    s.t[i] = t
    s.y[i] = y
    s.phase[i] = True
    status = 0
    _innovation(theta, Phi, Y, p, E)
    if not s.enabled[i]:
        return status
    delta, theta_prev = w.delta[i], w.theta_prev[i]
    S = s.S[i]
    least_squares = cfg.covariance
    q = _gain(S, phi) if least_squares else 0.0
    ok = _rule_increment(s, w, i, cfg, Phi, E)
    if windowed is not None and ok and cfg.window > 0:
        status |= _slide_window(s, w, i, cfg, theta, Phi, Y)
    if ok:
        for j in range(d):
            ok = ok and math.isfinite(delta[j])
    check = cfg.check_every
    if ok and least_squares and check > 0 and t % check == 0:
        if cfg.decomposed:
            healthy = factor_is_healthy(S, 0, n) and factor_is_healthy(S, n, d)
        else:
            healthy = factor_is_healthy(S, 0, d)
        if not healthy:
            ok = False
            status |= ST_PD_LOST
    if not ok:
        reset_covariance(s, i, cfg)
        s.n_resets[i] += 1
        return status | ST_RESET
    if cfg.project_stable:
        for j in range(d):
            theta_prev[j] = theta[j]
    for j in range(d):
        theta[j] += delta[j]
    if cfg.project_stable and not is_schur_stable(theta, n, w.K[i]):
        for j in range(d):
            theta[j] = theta_prev[j]
        s.n_projections[i] += 1
        status |= ST_PROJECTED
    if least_squares:
        status |= _frozen_signal(s, i, cfg, E[0], y, q, t)
    return status


@lane(inline=True)
def _frozen_signal(
    s: EstimatorState, i: int, cfg: EstimatorConfig, e: float, y: float, q: float, t: int
) -> int:
    """Update the running means of ``e^2``, ``y^2``, ``q`` and the ``frozen`` flag."""
    rate = cfg.frozen_rate
    ewma_e2 = s.ewma_e2[i] + rate * (e * e - s.ewma_e2[i])
    ewma_y2 = s.ewma_y2[i] + rate * (y * y - s.ewma_y2[i])
    ewma_q = s.ewma_q[i] + rate * (q - s.ewma_q[i])
    s.ewma_e2[i] = ewma_e2
    s.ewma_y2[i] = ewma_y2
    s.ewma_q[i] = ewma_q
    was = s.frozen[i]
    # hysteresis: on above ratio * mean y^2, off again below half of that
    ratio = cfg.frozen_ratio * (0.5 if was else 1.0)
    frozen = (
        t * rate > 2.0 and ewma_e2 > ratio * ewma_y2 and ewma_y2 > 0.0 and ewma_q < cfg.frozen_gain
    )
    s.frozen[i] = frozen
    return ST_FROZEN if (frozen and not was) else 0


@lane(inline=True)
def estimator_predict(
    s: EstimatorState, w: EstimatorWork, i: int, cfg: EstimatorConfig, u: float
) -> int:
    """State step of lane ``i`` with the applied input ``u(t)``; see the module docstring."""
    n = cfg.n
    theta, x, y = s.theta[i], s.x_hat[i], s.y[i]
    A, x_next, x_reg = w.A[i], w.x_next[i], w.x_reg[i]
    companion_into(theta, n, cfg.observability, A)
    b = theta[n:]
    status = 0
    if cfg.filtered:
        _corrected_state(s, i, cfg, A, x, y, x_reg, x_next)
    if cfg.state == STATE_KF:
        P1, L1 = s.P1[i], s.L1[i]
        if kalman_step(A, b, P1, s.Q[i], cfg.R, x, u, y, x_next, L1, w.kalman[i]) != 0:
            copy_matrix(s.P1_init[i], P1)
            for j in range(n):
                L1[j] = 0.0
            s.n_kf_resets[i] += 1
            status |= ST_KF_RESET
    else:  # filtered O: x_hat(t+1) = A_hat x_hat(t|t) + b_hat u(t), the injection is in x_reg
        xo = x_reg if cfg.filtered else x
        observer_step(A, b, xo, u, y, s.K[i], cfg.state == STATE_CO, x_next)
    advance_regressor(s.phi[i], s.xs[i], x_reg if cfg.filtered else x, u, n, cfg.observability)
    finite = True
    for j in range(n):
        finite = finite and math.isfinite(x_next[j])
    if not finite:
        copy_vector(s.x_init[i], x_next)
        s.n_state_resets[i] += 1
        status |= ST_STATE_RESET
    for j in range(n):
        x[j] = x_next[j]
    s.phase[i] = False
    return status


@lane
def _corrected_state(
    s: EstimatorState,
    i: int,
    cfg: EstimatorConfig,
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
    form), scaled by ``injection`` after the first ``injection_warmup`` steps. ``tmp`` (n) is
    scratch."""
    n = cfg.n
    if cfg.state == STATE_KF:
        filtered_state(x, s.P1[i], cfg.R, y, x_reg)
        return
    innov = y - x[0]
    if s.t[i] > cfg.injection_warmup:  # after the warm-up: a fraction of the injection
        innov *= cfg.injection
    for j in range(n):  # g = A^{n-1} e_n, built in x_reg
        x_reg[j] = 1.0 if j == n - 1 else 0.0
    for _ in range(n - 1):
        matvec(A, x_reg, tmp)
        for j in range(n):
            x_reg[j] = tmp[j]
    for j in range(n):
        x_reg[j] = x[j] + x_reg[j] * innov


@lane(entry=True)
def estimator_restart(
    s: EstimatorState, w: EstimatorWork, i: int, cfg: EstimatorConfig, theta: NDArray, P: NDArray
) -> bool:
    """Restart lane ``i`` at ``theta`` and ``P``; see the module docstring."""
    n = cfg.n
    d = 2 * n
    if cfg.covariance:
        F = w.S_saved[i]
        if cfg.decomposed:
            F[:, :] = 0.0
            ok = upper_factor(P[:n, :n], F[:n, :n]) and upper_factor(P[n:, n:], F[n:, n:])
        else:
            ok = upper_factor(P, F)
        if not ok:
            return False
        copy_matrix(F, s.S[i])
    else:
        reset_covariance(s, i, cfg)
    s.count[i] = 0
    th = s.theta[i]
    for j in range(d):
        th[j] = theta[j]
    return True
