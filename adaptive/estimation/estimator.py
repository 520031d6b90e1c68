"""The joint state/parameter estimator of Ding & Ma (2014): the lane functions of one step.

Lane ``lane_i`` of the state ``s`` (an :class:`EstimatorState`) and of the scratch ``w`` (an
:class:`EstimatorWork`), with the configuration ``cfg`` of :class:`EstimatorSpec`:

``status = estimator_update(s, w, lane_i, cfg, y, windowed=None)``
    Measurement step at time ``t``: shift the stacked ``Phi(p, t)``, ``Y(p, t)`` ((19)-(20),
    (74)-(75)), the innovation ``E(p, t) = Y(p, t) - Phi(p, t)^T theta_hat(t-1)`` and the rule
    of :data:`.variants.RULES`: SG (12)-(15), MISG (16)-(22), RLS (32)-(36), MILS (37)-(44),
    their D- forms (96)-(145), NG (the projection algorithm); as a whole O-RLS (54)-(57),
    KF-MILS (73)-(79). ``windowed=True`` compiles the finite-history downdate and replay.
``status = estimator_predict(s, w, lane_i, cfg, u)``
    State step with ``u(t)``: ``A_hat(t)``, ``b_hat(t)`` ((59)-(60), (83)-(84)),
    ``x_hat(t+1)`` by the open-loop observer (58), the closed-loop observer (50) or the Kalman
    filter (80)-(82), and ``phi_hat(t+1)`` ((57)/(153)); with ``regressor="filtered"`` (not
    the paper's) ``phi_hat`` is built from ``x_hat(t|t) = x_hat(t) + g [y(t) - c x_hat(t)]``.
``ok = estimator_restart(s, w, lane_i, cfg, theta, P)``
    Restart at ``theta`` with covariance ``P`` (only its diagonal blocks for D- rules); the
    normalisers back to ``r(0)``; the window emptied. ``False`` (nothing changed) when ``P`` is
    not positive definite.
``reset_covariance(s, lane_i, cfg)``
    ``P <- P(0)`` (``r <- r(0)``), window emptied, ``theta`` kept: the documented safe action.

The batch loops and the ``T``-step loop of one lane are in :mod:`.estimator_lanes`.

Status bits: ``ST_RESET`` (covariance or normaliser reset after an overflow or a failed health
check; with ``ST_PD_LOST`` when the factor check failed), ``ST_PROJECTED`` (an unstable
``A_hat`` rejected, ``project_stable``), ``ST_RECOMPUTED`` (an ill-conditioned downdate replaced
by a replay), ``ST_FROZEN`` (the "frozen on a wrong model" signal switched on: the mean gain
``phi^T P phi`` below ``FROZEN_GAIN`` while the mean innovation power exceeds ``frozen_ratio``
times the mean output power, after ``2 / FROZEN_RATE`` steps; off below half that ratio),
``ST_STATE_RESET`` (``x_hat(t+1)`` not finite: back to ``x_hat(1)``), ``ST_KF_RESET`` (the
Kalman covariance not finite: back to ``P1(1)``). Why the filtered regressor and the frozen
signal exist, and what was measured: the design notes of the documentation.
"""

from __future__ import annotations

import math

from numpy.typing import NDArray

from stcgym.adaptive.estimation.estimator_spec import (
    EstimatorConfig,
    EstimatorState,
    EstimatorWork,
)
from stcgym.adaptive.estimation.least_squares import (
    block_trace_is_finite,
    carlson_update,
    downdate_block,
    factor_is_healthy,
    gradient_increment,
    innovation,
    least_squares_increment,
    projection_increment,
    upper_factor,
)
from stcgym.adaptive.estimation.state_estimation import (
    advance_regressor,
    filtered_state,
    is_schur_stable,
    kalman_step,
    observer_step,
)
from stcgym.adaptive.kernels.canonical import companion_into
from stcgym.adaptive.variants import RULES as _RULES
from stcgym.adaptive.variants import STATE_ESTIMATORS as _STATES
from stcgym.envs.dynamics import matvec
from stcgym.lanes.compiled import lane
from stcgym.lanes.linalg import copy_matrix, copy_vector

__all__ = [
    "estimator_predict",
    "estimator_restart",
    "estimator_update",
    "reset_covariance",
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
# :class:`EstimatorWork`: named batched arrays), ``lane_i`` the lane
# ============================================================================================


@lane(entry=True)
def reset_covariance(s: EstimatorState, lane_i: int, cfg: EstimatorConfig) -> None:
    """``P <- P(0)`` / ``r <- r(0)`` and an empty finite-history window; ``theta`` kept."""
    copy_matrix(s.S0[lane_i], s.S[lane_i])  # empty without a covariance
    copy_vector(s.r0[lane_i], s.r[lane_i])  # empty without normalisers
    s.count[lane_i] = 0


@lane(inline=True)
def _rule_increment(
    s: EstimatorState, w: EstimatorWork, lane_i: int, cfg: EstimatorConfig, Phi: NDArray, E: NDArray
) -> bool:
    """``w.delta = increment of theta`` for the plain rule or both halves of a D- rule (each
    half sees the same innovation ``E`` computed with ``theta(t-1)``, (96)-(97), (124));
    updates ``P`` / ``r``. Returns ``False`` on overflow."""
    n = cfg.n
    d = 2 * n
    p = cfg.p
    lam = cfg.forgetting
    S, r, delta, gain, scratch = (
        s.S[lane_i],
        s.r[lane_i],
        w.delta[lane_i],
        w.gain[lane_i],
        w.factor_work[lane_i],
    )
    nblocks = 2 if cfg.decomposed else 1
    ok = True
    for blk in range(nblocks):
        lo = 0 if nblocks == 1 else blk * n
        hi = d if nblocks == 1 else lo + n
        if cfg.rule == RULE_RLS or cfg.rule == RULE_MILS:
            denom = least_squares_increment(
                S, lo, hi, Phi, E, p, lam, cfg.rule == RULE_RLS, delta, gain, scratch
            )
            ok = ok and denom > 0.0 and math.isfinite(denom) and block_trace_is_finite(S, lo, hi)
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
    s: EstimatorState, w: EstimatorWork, lane_i: int, cfg: EstimatorConfig, theta_w: NDArray
) -> None:
    """Exact finite-history estimate by replaying the stored blocks from ``P(0)``: plain rules
    also replay ``theta`` from ``theta(0)`` into ``theta_w`` (regularised least squares over the
    window); D- rules recompute each half's ``P`` only (the hierarchical update is kept)."""
    n = cfg.n
    d = 2 * n
    p = cfg.p
    W = cfg.window
    count = s.count[lane_i]  # read before the reset empties the window
    reset_covariance(s, lane_i, cfg)
    S, theta0, hist_Phi, hist_Y = (
        s.S[lane_i],
        s.theta0[lane_i],
        s.hist_Phi[lane_i],
        s.hist_Y[lane_i],
    )
    delta, gain, scratch, E = (
        w.delta[lane_i],
        w.gain[lane_i],
        w.factor_work[lane_i],
        w.E_replay[lane_i],
    )
    copy_vector(theta0, theta_w)
    first = count % W  # the oldest block (the newest was written just before)
    for m in range(W):
        k = (first + m) % W
        Phi = hist_Phi[k]
        Yk = hist_Y[k]
        if cfg.decomposed:
            for blk in range(2):
                lo = blk * n
                for j in range(p):
                    carlson_update(S, lo, lo + n, Phi[j], 1.0, gain)
        else:
            innovation(theta_w, Phi, Yk, p, E)
            scalar = cfg.rule == RULE_RLS
            least_squares_increment(S, 0, d, Phi, E, p, 1.0, scalar, delta, gain, scratch)
            for j in range(d):
                theta_w[j] += delta[j]
    s.count[lane_i] = count


@lane
def _slide_window(
    s: EstimatorState,
    w: EstimatorWork,
    lane_i: int,
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
    count = s.count[lane_i]
    k = count % W
    s.count[lane_i] = count + 1
    hPhi = s.hist_Phi[lane_i][k]
    hY = s.hist_Y[lane_i][k]
    delta = w.delta[lane_i]
    if count >= W:
        E_old, tw = w.E_old[lane_i], w.theta_prev[lane_i]
        for j in range(d):
            tw[j] = theta[j] + delta[j]
        innovation(tw, hPhi, hY, p, E_old)
        S, saved = s.S[lane_i], w.S_saved[lane_i]
        copy_matrix(S, saved)
        nblocks = 2 if cfg.decomposed else 1
        ok = True
        for blk in range(nblocks):
            lo = 0 if nblocks == 1 else blk * n
            hi = d if nblocks == 1 else lo + n
            if ok:
                ok = downdate_block(S, lo, hi, hPhi, E_old, p, delta, w.factor_work[lane_i])
        if not ok:
            copy_matrix(saved, S)
            copy_matrix(Phi[:p], hPhi)
            copy_vector(Y, hY)
            s.n_window_recomputes[lane_i] += 1
            _replay_window(s, w, lane_i, cfg, tw)
            if not cfg.decomposed:
                for j in range(d):
                    delta[j] = tw[j] - theta[j]
            return ST_RECOMPUTED
    copy_matrix(Phi[:p], hPhi)
    copy_vector(Y, hY)
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
    lane_i: int,
    cfg: EstimatorConfig,
    y: float,
    windowed: bool | None = None,
) -> int:
    """Measurement step at time ``t`` of lane ``lane_i``; see the module docstring.

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
    theta, Phi, Y, E, phi = s.theta[lane_i], s.Phi[lane_i], s.Y[lane_i], s.E[lane_i], s.phi[lane_i]
    # Phi(p, t), Y(p, t): column j of the paper's Phi is phi_hat(t - j)      (41)-(42), (19)-(20)
    for k in range(p - 1, 0, -1):
        for j in range(d):
            Phi[k, j] = Phi[k - 1, j]
        Y[k] = Y[k - 1]
    for j in range(d):
        Phi[0, j] = phi[j]
    Y[0] = y
    t = s.t[lane_i] + 1
    s.t[lane_i] = t
    s.y[lane_i] = y
    s.phase[lane_i] = True
    status = 0
    innovation(theta, Phi, Y, p, E)  # E(p, t) = Y(p, t) - Phi^T theta(t-1)       (38), (17)
    if not s.enabled[lane_i]:
        return status
    delta, theta_prev = w.delta[lane_i], w.theta_prev[lane_i]
    S = s.S[lane_i]
    least_squares = cfg.covariance
    q = _gain(S, phi) if least_squares else 0.0
    # delta = L(t) E(p, t) with L, P of (33)-(34) / (39)-(40); Phi E / r(t) with r of (13) / (18)
    ok = _rule_increment(s, w, lane_i, cfg, Phi, E)
    if windowed is not None and ok and cfg.window > 0:
        status |= _slide_window(s, w, lane_i, cfg, theta, Phi, Y)
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
        reset_covariance(s, lane_i, cfg)
        s.n_resets[lane_i] += 1
        return status | ST_RESET
    if cfg.project_stable:
        copy_vector(theta, theta_prev)
    for j in range(d):
        theta[j] += delta[j]  # theta(t) = theta(t-1) + delta           (32), (37); (12), (16)
    # the gain vector's row is scratch here: the Schur test of A_hat(t) runs in it
    if cfg.project_stable and not is_schur_stable(theta, n, w.gain[lane_i]):
        copy_vector(theta_prev, theta)
        s.n_projections[lane_i] += 1
        status |= ST_PROJECTED
    if least_squares:
        status |= _frozen_signal(s, lane_i, cfg, E[0], y, q, t)
    return status


@lane(inline=True)
def _frozen_signal(
    s: EstimatorState, lane_i: int, cfg: EstimatorConfig, e: float, y: float, q: float, t: int
) -> int:
    """Update the running means of ``e^2``, ``y^2``, ``q`` and the ``frozen`` flag."""
    rate = cfg.frozen_rate
    ewma_e2 = s.ewma_e2[lane_i] + rate * (e * e - s.ewma_e2[lane_i])
    ewma_y2 = s.ewma_y2[lane_i] + rate * (y * y - s.ewma_y2[lane_i])
    ewma_q = s.ewma_q[lane_i] + rate * (q - s.ewma_q[lane_i])
    s.ewma_e2[lane_i] = ewma_e2
    s.ewma_y2[lane_i] = ewma_y2
    s.ewma_q[lane_i] = ewma_q
    was = s.frozen[lane_i]
    # hysteresis: on above ratio * mean y^2, off again below half of that
    ratio = cfg.frozen_ratio * (0.5 if was else 1.0)
    frozen = (
        t * rate > 2.0 and ewma_e2 > ratio * ewma_y2 and ewma_y2 > 0.0 and ewma_q < cfg.frozen_gain
    )
    s.frozen[lane_i] = frozen
    return ST_FROZEN if (frozen and not was) else 0


@lane(inline=True)
def estimator_predict(
    s: EstimatorState, w: EstimatorWork, lane_i: int, cfg: EstimatorConfig, u: float
) -> int:
    """State step of lane ``lane_i`` with the applied input ``u(t)``; see the module docstring."""
    n = cfg.n
    theta, x, y = s.theta[lane_i], s.x_hat[lane_i], s.y[lane_i]
    A, x_next, x_reg = w.A[lane_i], w.x_next[lane_i], w.x_reg[lane_i]
    companion_into(theta, n, cfg.observability, A)
    b = theta[n:]
    status = 0
    if cfg.filtered:
        _corrected_state(s, lane_i, cfg, A, x, y, x_reg, x_next)
    if cfg.state == STATE_KF:
        P1, L1 = s.P1[lane_i], s.L1[lane_i]
        if (
            kalman_step(
                A, b, P1, s.Q[lane_i], cfg.R, x, u, y, x_next, L1, w.AP[lane_i], w.P_upd[lane_i]
            )
            != 0
        ):
            copy_matrix(s.P1_init[lane_i], P1)
            for j in range(n):
                L1[j] = 0.0
            s.n_kf_resets[lane_i] += 1
            status |= ST_KF_RESET
    else:  # filtered O: x_hat(t+1) = A_hat x_hat(t|t) + b_hat u(t), the injection is in x_reg
        xo = x_reg if cfg.filtered else x
        observer_step(A, b, xo, u, y, s.K[lane_i], cfg.state == STATE_CO, x_next)
    advance_regressor(
        s.phi[lane_i], s.xs[lane_i], x_reg if cfg.filtered else x, u, n, cfg.observability
    )
    finite = True
    for j in range(n):
        finite = finite and math.isfinite(x_next[j])
    if not finite:
        copy_vector(s.x_init[lane_i], x_next)
        s.n_state_resets[lane_i] += 1
        status |= ST_STATE_RESET
    copy_vector(x_next, x)
    s.phase[lane_i] = False
    return status


@lane
def _corrected_state(
    s: EstimatorState,
    lane_i: int,
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
        filtered_state(x, s.P1[lane_i], cfg.R, y, x_reg)
        return
    innov = y - x[0]
    if s.t[lane_i] > cfg.injection_warmup:  # after the warm-up: a fraction of the injection
        innov *= cfg.injection
    for j in range(n):  # g = A^{n-1} e_n, built in x_reg
        x_reg[j] = 1.0 if j == n - 1 else 0.0
    for _ in range(n - 1):
        matvec(A, x_reg, tmp)
        copy_vector(tmp, x_reg)
    for j in range(n):
        x_reg[j] = x[j] + x_reg[j] * innov


@lane(entry=True)
def estimator_restart(
    s: EstimatorState,
    w: EstimatorWork,
    lane_i: int,
    cfg: EstimatorConfig,
    theta: NDArray,
    P: NDArray,
) -> bool:
    """Restart lane ``lane_i`` at ``theta`` and ``P``; see the module docstring."""
    n = cfg.n
    if cfg.covariance:
        F = w.S_saved[lane_i]
        if cfg.decomposed:
            F[:, :] = 0.0
            ok = upper_factor(P[:n, :n], F[:n, :n]) and upper_factor(P[n:, n:], F[n:, n:])
        else:
            ok = upper_factor(P, F)
        if not ok:
            return False
        copy_matrix(F, s.S[lane_i])
    else:
        reset_covariance(s, lane_i, cfg)
    s.count[lane_i] = 0
    copy_vector(theta, s.theta[lane_i])
    return True
