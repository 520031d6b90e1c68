"""The self-tuning controller step, written once as a compiled lane function.

One call of :func:`controller_step` advances one plant's controller by one sample
(convention of :mod:`stcgym.envs.compiled`): it reads ``y(t)``, ``r(t)`` and returns ``u(t)``.
Every step, in this order:

1. **estimator measurement step** with ``y(t)``: ``theta_hat(t)`` and the innovation ``e(t)``
   (a paper estimator of :mod:`.estimator` -- O-RLS, KF-MILS, ... -- or extended least squares
   on the ARMAX form, :mod:`.extended_ls`);
2. **change detection**: a short and a long EWMA of ``e(t)^2``; when the short one exceeds
   ``reset_threshold`` times the long one (in closed loop, at most once per ``reset_holdoff``
   steps) ``P`` is multiplied by ``reset_inflation`` (covariance resetting, Astrom & Wittenmark
   sec. 11.2), which lets the estimate follow a parameter jump;
3. **design** (certainty equivalence): ``A_hat, b_hat`` from ``theta_hat(t)`` (observer
   canonical form, Ding & Ma 2014 eq. (1)-(5)); pole placement by Ackermann's formula on the
   integral-augmented model, or one Riccati iteration of the LQ problem on it; the result is used
   only inside the **safe set** (finite, ``max |b_hat| >= b_min``, controllable with reciprocal
   condition ``>= rcond_min``, no zero at ``z = 1``, ``max |K|, |N| <= gain_max``), else the
   last good gains stay (:mod:`.design`: ``place_design``, ``lq_design``);
4. **state estimate**: a Kalman filter on the estimated model, corrected by ``y(t)``
   (``x(t|t)``);
5. **control**: for the first ``probe_steps`` samples (default ``2n``), or while no design has
   been accepted, a small zero-mean probe ``+-probe_amplitude`` whose signs come from a
   counter-based hash of ``(seed, episode, t)`` (reproducible per lane and per episode, never the
   same sequence for every episode or lane). The probe is bounded by the observed output: with
   ``y_max = max |y|`` seen so far, its amplitude is ``probe_amplitude * min(1, probe_output /
   y_max)`` (a high-gain or unstable plant is probed gently), and it runs on past
   ``probe_steps``, up to ``max_probe_steps`` (default ``5n``), while ``y_max < probe_output`` (a
   low-gain plant whose response is still buried in the noise gets more data before the first
   design is trusted). Afterwards the tracking law
   ``u = sat(N r - K_x x(t|t) - k_i xi)`` with conditional-integration anti-windup
   (``design.track``);
6. **process noise and state step**: ``Q(t)`` from the parameter covariance (the model error a
   wrong ``theta_hat`` injects into each state row), the Kalman time update with the applied
   ``u(t)`` (``state_estimation.kalman_step``), and the estimator's state step / regressor
   shift. For the paper's KF estimators the same ``Q(t)`` is written into the estimator's own
   filter.

Lane records: a ``float64`` record (layout :func:`controller_layout`) holding the estimator's
sub-record first, and an ``int64`` record (indices ``I_*``) with the step counter, the episode,
the seed and the counters.
"""

from __future__ import annotations

import math

import numpy as np

from stcgym.adaptive.kernels import design as dz
from stcgym.adaptive.kernels.estimator import estimator_predict, estimator_update
from stcgym.adaptive.kernels.extended_ls import extended_ls_push, extended_ls_update
from stcgym.adaptive.kernels.records import view2d
from stcgym.adaptive.kernels.state_estimation import kalman_step
from stcgym.envs.compiled import Layout, lane, lanes, prange

__all__ = [
    "FLOAT_FIELDS",
    "controller_layout",
    "controller_step",
    "controllers_step",
    "hash32",
    "probe_sign",
]

#: Fields of the float lane record, in the order of the offsets array ``off``.
FLOAT_FIELDS = (
    "est", "x", "x_next", "P1", "Q", "L1", "xf", "gain", "law", "P_lq", "A", "b", "work", "misc",
)  # fmt: skip
(O_EST, O_X, O_XN, O_P1, O_Q, O_L1, O_XF, O_GAIN, O_LAW, O_PLQ, O_A, O_B, O_WORK,
 O_MISC) = range(14)  # fmt: skip
# misc floats (relative to off[O_MISC]); M_YMAX: largest |y| seen while probing
M_EWS, M_EWL, M_U, M_E, M_YMAX = range(5)
N_MISC = 5
# int record
I_T, I_EPISODE, I_SEED, I_N_REJECTED, I_N_ALARMS, I_N_SATURATED = range(6)
I_CLOSED_T, I_LAST_ALARM, I_LAST_REASON, I_N_PROBE, I_EST_STATUS, I_N_KF_RESETS = range(6, 12)
N_INT = 12
# float config (``cf``); ``alpha`` (m values) from C_ALPHA
C_ACTION_BOUND, C_PROBE, C_Q_GAIN, C_Q_FLOOR, C_R, C_THRESHOLD, C_INFLATION = range(7)
C_P0, C_LAMBDA, C_EW_SHORT, C_EW_LONG = range(7, 11)
C_SAFE = 11  # 4 values: b_min, rcond_min, dc_rcond_min, gain_max
C_WEIGHTS = 15  # 3 values: q_y, q_i, rho
C_PROBE_OUTPUT = 18  # output level that scales the probe down and ends it early
C_ALPHA = 19
# int config (``ci``)
K_N, K_INTEGRAL, K_FEEDFORWARD, K_ANTI_WINDUP, K_FILTERED, K_PROBE_STEPS = range(6)
K_DESIGN, K_DETECT, K_HOLDOFF, K_EST, K_FORM, K_D = range(6, 12)
K_TH, K_S, K_E, K_EQ = range(12, 16)  # paper estimator: offsets of theta, S, E, Q in the record
K_ELS = 16  # ELS: offsets (absolute) of theta, S, phi, scratch: 4 values
K_PROBE_MAX = 20  # longest probe (samples) while the output stays below the probe level
N_KCFG = 21
# estimator kinds and design kinds
PAPER, ELS = 0, 1
POLE_PLACEMENT, LQ = 0, 1


def controller_layout(
    n: int, est_size: int, est_scratch: int = 0, lq: bool = True
) -> tuple[Layout, np.ndarray]:
    """Float record of one lane (the estimator's record first) and its offsets array.

    ``est_scratch``: the number of floats at the end of the estimator's record that are pure
    scratch (its ``work`` field). The controller's own scratch (design and Kalman step) starts
    there and only the part that does not fit is added: the estimator's steps and the design
    never run at the same time, and sharing the scratch keeps a lane small (memory per plant
    is what limits a sweep). ``lq=False`` leaves out the Riccati matrix of ``design="lq"``.
    """
    m = n + 1
    need = max(dz.work_size(n), 2 * n * n)
    lay = Layout()
    lay.add("est", (est_size,))
    lay.add("work", (max(need - est_scratch, 0),))  # continues the estimator's scratch
    lay.add("misc", (N_MISC,))  # directly after "work": the scratch ends at off[O_MISC]
    lay.add("x", (n,))
    lay.add("x_next", (n,))
    lay.add("P1", (n, n))
    lay.add("Q", (n, n))
    lay.add("L1", (n,))
    lay.add("xf", (n,))
    lay.add("gain", (dz.gain_size(n),))
    lay.add("law", (dz.LAW_SIZE,))
    lay.add("P_lq", (m, m) if lq else (0,))
    lay.add("A", (n, n))
    lay.add("b", (n,))
    off = lay.offsets(FLOAT_FIELDS)
    off[O_WORK] -= min(est_scratch, need)  # the scratch is f[off[O_WORK] : off[O_MISC]]
    return lay, off


# ---------------------------------------------------------------------------------- probe
@lane(inline=True)
def hash32(x):
    """32-bit integer hash (``lowbias32``, C. Wellons): a counter-based random generator."""
    x = x & 0xFFFFFFFF
    x ^= x >> 16
    x = (x * 0x7FEB352D) & 0xFFFFFFFF
    x ^= x >> 15
    x = (x * 0x846CA68B) & 0xFFFFFFFF
    x ^= x >> 16
    return x


@lane(inline=True)
def probe_sign(seed, episode, t):
    """``+-1`` from ``hash(seed, episode, t)``: a fresh, reproducible sequence per lane/episode."""
    h = hash32(hash32(hash32(seed) ^ (episode & 0xFFFFFFFF)) ^ (t & 0xFFFFFFFF))
    return 1.0 if (h >> 7) & 1 else -1.0


# ------------------------------------------------------------------------ parameter covariance
@lane(inline=True)
def covariance_entry(f, ci, i, j):
    """``P_ij = (S S^T)_ij`` of the estimator's square-root factor (0 for SG/MISG)."""
    d = ci[K_D]
    o = ci[K_ELS + 1] if ci[K_EST] == ELS else ci[K_S]
    if o < 0:
        return 0.0
    acc = 0.0
    for k in range(max(i, j), d):  # S upper triangular
        acc += f[o + i * d + k] * f[o + j * d + k]
    return acc


@lane(inline=True)
def inflate_covariance(f, ci, factor):
    """``P <- factor P`` (covariance resetting on a detected change): ``S <- sqrt(factor) S``."""
    d = ci[K_D]
    o = ci[K_ELS + 1] if ci[K_EST] == ELS else ci[K_S]
    if o < 0:
        return
    scale = math.sqrt(factor)
    for i in range(d * d):
        f[o + i] *= scale


@lane(inline=True)
def process_noise(f, ci, n, y, u, q, q_floor, Q):
    """``Q = q [y^2 P_aa + u^2 P_bb - y u (P_ab + P_ba)] + q_floor I``.

    Row ``i`` of the one-step model error is ``-(a_i - a_hat_i) x_1 + (b_i - b_hat_i) u`` (observer
    form; a scale for the observability form), with ``Cov(theta - theta_hat) ~ P`` and
    ``x_1 ~ y``: large while the parameters are uncertain (the filter follows ``y``), vanishing
    as ``P`` shrinks (the filter becomes the noise-free observer of the oracle)."""
    for i in range(n):
        for j in range(i, n):
            v = q * (
                y * y * covariance_entry(f, ci, i, j)
                + u * u * covariance_entry(f, ci, n + i, n + j)
                - y * u * (covariance_entry(f, ci, i, n + j) + covariance_entry(f, ci, j, n + i))
            )
            if i == j:
                v += q_floor
            Q[i, j] = v
            Q[j, i] = v


# --------------------------------------------------------------------------------- the step
@lane
def controller_step(f, g, off, cf, ci, ecf, eci, y, r):
    """One sample of the self-tuning controller (module docstring, steps 1-6); returns ``u(t)``.

    ``f``/``g``: the lane's float and int records; ``off``: offsets of :data:`FLOAT_FIELDS`;
    ``cf``/``ci``: controller configuration; ``ecf``/``eci``: the paper estimator's
    configuration (unused for ELS).
    """
    n = ci[K_N]
    d = ci[K_D]
    integral = ci[K_INTEGRAL] != 0
    m = n + ci[K_INTEGRAL]
    t = g[I_T]
    mi = off[O_MISC]
    form = ci[K_FORM]
    # -- 1. estimator measurement step
    if ci[K_EST] == ELS:
        e, eps = extended_ls_update(f, ci[K_ELS : K_ELS + 4], d, y, cf[C_LAMBDA], cf[C_P0])
        theta = f[ci[K_ELS] : ci[K_ELS] + 2 * n]
    else:
        g[I_EST_STATUS] |= estimator_update(f, off[O_EST], ecf, eci, y)
        e = f[ci[K_E]]
        eps = e
        theta = f[ci[K_TH] : ci[K_TH] + 2 * n]
    f[mi + M_E] = e
    # -- 2. change detection: covariance resetting on a jump of the innovation variance
    e2 = e * e
    ewl_prev = f[mi + M_EWL]
    f[mi + M_EWS] += cf[C_EW_SHORT] * (e2 - f[mi + M_EWS])
    f[mi + M_EWL] += cf[C_EW_LONG] * (e2 - ewl_prev)
    holdoff = ci[K_HOLDOFF]
    if (
        ci[K_DETECT] != 0
        and g[I_CLOSED_T] >= 0
        and t - g[I_CLOSED_T] > holdoff
        and t - g[I_LAST_ALARM] > holdoff
        and f[mi + M_EWS] > cf[C_THRESHOLD] * ewl_prev
    ):
        inflate_covariance(f, ci, cf[C_INFLATION])
        g[I_N_ALARMS] += 1
        g[I_LAST_ALARM] = t
    # -- 3. certainty-equivalence design inside the safe set (gain written only on success)
    gain = f[off[O_GAIN] : off[O_GAIN] + n + 4]
    work = f[off[O_WORK] : off[O_MISC]]
    safe = cf[C_SAFE : C_SAFE + 4]
    if ci[K_DESIGN] == LQ:
        P_lq = view2d(f, off[O_PLQ], m, m)
        status = dz.lq_design(
            theta, form, integral, ci[K_FEEDFORWARD] != 0, cf[C_WEIGHTS : C_WEIGHTS + 3], safe,
            P_lq, gain, work,
        )  # fmt: skip
    else:
        status = dz.place_design(
            theta, form, integral, ci[K_FEEDFORWARD] != 0, cf[C_ALPHA : C_ALPHA + m], safe,
            gain, work,
        )  # fmt: skip
    g[I_LAST_REASON] = status
    if status != dz.OK:
        g[I_N_REJECTED] += 1
    # -- 4. state estimate x(t|t): Kalman filter on the estimated model
    A = view2d(f, off[O_A], n, n)
    b = f[off[O_B] : off[O_B] + n]
    dz.model_matrices(theta, form, A, b)
    x = f[off[O_X] : off[O_X] + n]
    P1 = view2d(f, off[O_P1], n, n)
    xf = f[off[O_XF] : off[O_XF] + n]
    dz.filtered_state(x, P1, cf[C_R], y, xf)
    # -- 5. control: the probe while the loop is open, then the tracking law
    bound = cf[C_ACTION_BOUND]
    law = f[off[O_LAW] : off[O_LAW] + dz.LAW_SIZE]
    level = cf[C_PROBE_OUTPUT]
    open_loop = g[I_CLOSED_T] < 0
    if open_loop:
        f[mi + M_YMAX] = max(f[mi + M_YMAX], abs(y))
    ymax = f[mi + M_YMAX]
    probing = open_loop and (t < ci[K_PROBE_STEPS] or (t < ci[K_PROBE_MAX] and ymax < level))
    if probing or gain[n + 2] <= 0.0:
        # the probe is scaled down once the output exceeds the probe level
        amp = cf[C_PROBE] * (level / ymax if ymax > level else 1.0)
        u = min(max(amp * probe_sign(g[I_SEED], g[I_EPISODE], t), -bound), bound)
        g[I_N_PROBE] += 1
        law[1] = 0.0
    else:
        if g[I_CLOSED_T] < 0:
            g[I_CLOSED_T] = t
        xc = xf if ci[K_FILTERED] != 0 else x
        u = dz.track(gain, law, xc, y, r, 0.0, bound, integral, ci[K_ANTI_WINDUP] != 0)
        if law[1] > 0.0:
            g[I_N_SATURATED] += 1
    f[mi + M_U] = u
    # -- 6. process noise, Kalman time update, estimator state step
    Q = view2d(f, off[O_Q], n, n)
    process_noise(f, ci, n, y, u, cf[C_Q_GAIN], cf[C_Q_FLOOR], Q)
    xn = f[off[O_XN] : off[O_XN] + n]
    L1 = f[off[O_L1] : off[O_L1] + n]
    if kalman_step(A, b, P1, Q, cf[C_R], x, u, y, xn, L1, work) == 0:
        for i in range(n):
            x[i] = xn[i]
    else:  # numerical trouble in the filter: back to x(1) = 0, P1(1) = I (counted)
        g[I_N_KF_RESETS] += 1
        for i in range(n):
            x[i] = 0.0
            for j in range(n):
                P1[i, j] = 1.0 if i == j else 0.0
    if ci[K_EST] == ELS:
        extended_ls_push(f, ci[K_ELS : K_ELS + 4], n, d, y, u, eps)
    else:
        if ci[K_EQ] >= 0:  # the paper's Kalman filter gets the same process noise
            for i in range(n * n):
                f[ci[K_EQ] + i] = f[off[O_Q] + i]
        g[I_EST_STATUS] |= estimator_predict(f, off[O_EST], ecf, eci, u)
    g[I_T] = t + 1
    return u


@lanes
def controllers_step(F, G, off, cf, ci, ecf, eci, y, r, u):
    """:func:`controller_step` for every lane: ``u[i]`` from ``y[i]``, ``r[i]``."""
    for i in prange(F.shape[0]):
        u[i] = controller_step(F[i], G[i], off, cf, ci, ecf, eci, y[i], r[i])
