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
5. **control**: for the first ``probe_steps`` samples, or while no design has been accepted,
   a zero-mean probe ``+-probe_amplitude * min(1, probe_output / max |y|)`` whose signs come
   from a counter-based hash of ``(seed, episode, t)``, extended up to ``max_probe_steps``
   while ``max |y| < probe_output`` (:class:`~stcgym.adaptive.options.StartupOptions`);
   afterwards the tracking law ``u = sat(N r - K_x x(t|t) - k_i xi)`` with
   conditional-integration anti-windup (``law.track``);
6. **process noise and state step**: ``Q(t)`` from the parameter covariance (the model error a
   wrong ``theta_hat`` injects into each state row), the Kalman time update with the applied
   ``u(t)`` (``state_estimation.kalman_step``), and the estimator's state step / regressor
   shift. For the paper's KF estimators the same ``Q(t)`` is written into the estimator's own
   filter.

Lane records: a ``float64`` record (fields :class:`ControllerRecord`, placed by
:func:`controller_record`) holding the estimator's record first, and an ``int64`` record (fields
:class:`ControllerInts`, offsets :data:`INTS`) with the step counter, the episode, the seed and
the counters; the configuration is a :class:`ControllerConfig`.

Compile only what is used: ``est_cfg is None`` (extended least squares) and ``lq_weights is
None`` (pole placement) are decided on the arguments' types, which numba prunes before typing,
so each estimator family and design is a compiled version of its own; single plant and batch
call the same version.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from numpy.typing import NDArray

from stcgym.adaptive.kernels.canonical import model_matrices
from stcgym.adaptive.kernels.estimator import estimator_predict, estimator_update
from stcgym.adaptive.kernels.extended_ls import extended_ls_push, extended_ls_update
from stcgym.adaptive.kernels.law import LAW, LAW_SIZE, track
from stcgym.adaptive.kernels.lq import lq_design
from stcgym.adaptive.kernels.pole_placement import place_design
from stcgym.adaptive.kernels.records import copy_matrix, view2d
from stcgym.adaptive.kernels.safe_set import OK, gain_size, work_size
from stcgym.adaptive.kernels.state_estimation import filtered_state, kalman_step
from stcgym.envs.compiled import Layout, lane, lanes

__all__ = [
    "INTS",
    "ControllerConfig",
    "ControllerInts",
    "ControllerRecord",
    "controller_record",
    "controller_step",
    "controllers_step",
    "hash32",
    "probe_sign",
]


class ControllerRecord(NamedTuple):
    """Offsets of the fields of the controller's float lane record (:func:`controller_record`).

    The extended-least-squares record comes first (``est``; empty with a paper estimator,
    whose state is a lane state of its own): ``theta``, ``S``, ``phi``, ``scratch`` locate the
    fields the ELS lane functions read. The scalar fields hold the controller's own state.
    """

    est: int  # start of the ELS record
    theta: int  # ELS theta_hat (3n)
    S: int  # upper factor of ELS's P = S S^T (3n, 3n)
    phi: int  # ELS regressor
    scratch: int  # ELS scratch
    work: int  # design and Kalman scratch f[work : work_end], shared with the estimator's
    work_end: int
    ews: int  # short EWMA of e(t)^2
    ewl: int  # long EWMA of e(t)^2
    u: int  # last applied input
    e: int  # last innovation
    ymax: int  # largest |y| seen while probing
    x: int  # x(t+1|t) of the controller's Kalman filter (n)
    x_next: int  # (n)
    P1: int  # its covariance (n, n)
    Q: int  # its process noise (n, n)
    L1: int  # its gain (n)
    xf: int  # x(t|t) (n)
    gain: int  # gain record (n + 4)
    law: int  # tracking-law state (3)
    P_lq: int  # Riccati matrix of the LQ design (m, m; empty for pole placement)
    A: int  # model in force (n, n)
    b: int  # (n)


class ControllerInts(NamedTuple):
    """Fields of the controller's ``int64`` lane record."""

    t: int  # samples since the last reset
    episode: int
    seed: int
    n_rejected: int  # designs rejected by the safe set
    n_alarms: int  # detected changes (covariance resets)
    n_saturated: int
    closed_t: int  # sample at which the loop closed (-1: still open)
    last_alarm: int
    last_reason: int  # status code of the last design
    n_probe: int  # probe samples applied
    est_status: int  # the estimator's status bits, or-ed
    n_kf_resets: int


#: Offsets of the int record's fields (``g[INTS.t]``); its length is ``len(INTS)``.
INTS = ControllerInts(*range(len(ControllerInts._fields)))


class ControllerConfig(NamedTuple):
    """Configuration of :func:`controller_step` (built once by the Python controller)."""

    n: int
    d: int  # estimator's parameter count (2n, ELS 3n)
    integral: bool
    feedforward: bool
    anti_windup: bool
    filtered: bool  # the law acts on x(t|t) (else x(t|t-1))
    probe_steps: int
    probe_max: int  # longest probe (samples) while the output stays below probe_output
    detect: bool  # change detection on
    holdoff: int
    form: int  # canonical form of theta_hat (OBSERVER / OBSERVABILITY)
    action_bound: float
    probe_amplitude: float
    q_gain: float  # process noise from the parameter covariance
    q_floor: float
    R: float  # measurement-noise variance of the controller's filter
    threshold: float  # change detection: ews > threshold * ewl
    inflation: float  # P <- inflation P on a detected change
    p0: float  # ELS: P(0) = p0 I
    forgetting: float  # ELS: lambda
    ew_short: float  # EWMA rates of e^2
    ew_long: float
    probe_output: float  # output level that scales the probe down and ends it early
    safe: NDArray  # [b_min, rcond_min, dc_rcond_min, gain_max]
    alpha: NDArray  # closed-loop characteristic polynomial (m; pole placement)


def controller_record(
    n: int, est: Layout, est_fields: dict[str, int], est_scratch: int = 0, lq: bool = True
) -> tuple[Layout, ControllerRecord]:
    """Float record of one lane (the ELS record ``est`` first, empty for a paper estimator)
    and its offsets.

    ``est_fields``: offsets, inside ``est``, of ``theta``, ``S``, ``phi``, ``scratch``.
    ``est_scratch``: the number of floats at the end of the ELS record that are pure scratch.
    The controller's own scratch (design and Kalman step) starts there and only the part that
    does not fit is added: the estimator's steps and the design never run at the same time.
    ``lq=False`` leaves out the Riccati matrix of ``design="lq"``.
    """
    m = n + 1
    need = max(work_size(n), 2 * n * n)
    lay = Layout()
    lay.add("est", (est.size,))
    lay.add("work", (max(need - est_scratch, 0),))  # continues the estimator's scratch
    for name in ("ews", "ewl", "u", "e", "ymax"):  # directly after "work": the scratch end
        lay.add(name)
    lay.add("x", (n,))
    lay.add("x_next", (n,))
    lay.add("P1", (n, n))
    lay.add("Q", (n, n))
    lay.add("L1", (n,))
    lay.add("xf", (n,))
    lay.add("gain", (gain_size(n),))
    lay.add("law", (LAW_SIZE,))
    lay.add("P_lq", (m, m) if lq else (0,))
    lay.add("A", (n, n))
    lay.add("b", (n,))
    base = lay.offset("est")
    inside = {k: base + v for k, v in est_fields.items()}
    own = {k: lay.offset(k) for k in ControllerRecord._fields if k in lay.fields}
    own["work"] -= min(est_scratch, need)  # the scratch is f[work : work_end]
    own["work_end"] = lay.offset("ews")
    return lay, ControllerRecord(**own, **inside)


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


# ------------------------------------------------------------------------ change detection
@lane(inline=True)
def change_alarm(f, at, cfg, e2, update, t, closed_t, last_alarm):
    """Step 2 of both controllers: the innovation-power test of covariance resetting.

    With ``update``, the short and long exponentially weighted means of ``e2 = |e(t)|^2`` at
    ``f[at.ews]``, ``f[at.ewl]`` take the sample (weights ``cfg.ew_short``, ``cfg.ew_long``).
    True (an alarm) when detection is on (``cfg.detect``), the loop closed at ``closed_t >= 0``,
    more than ``cfg.holdoff`` steps have passed since then and since ``last_alarm``, and the
    short mean exceeds ``cfg.threshold`` times the long mean before this sample.
    """
    ews = f[at.ews]
    ewl_prev = f[at.ewl]
    if update:
        ews += cfg.ew_short * (e2 - ews)
        f[at.ews] = ews
        f[at.ewl] = ewl_prev + cfg.ew_long * (e2 - ewl_prev)
    return (
        cfg.detect
        and closed_t >= 0
        and t - closed_t > cfg.holdoff
        and t - last_alarm > cfg.holdoff
        and ews > cfg.threshold * ewl_prev
    )


# ------------------------------------------------------------------------ parameter covariance
@lane(inline=True)
def covariance_entry(S, i, j):
    """``P_ij = (S S^T)_ij`` of the estimator's square-root factor ``S`` (0 without one)."""
    d = S.shape[0]
    if d == 0:
        return 0.0
    acc = 0.0
    for k in range(max(i, j), d):  # S upper triangular
        acc += S[i, k] * S[j, k]
    return acc


@lane(inline=True)
def inflate_covariance(S, factor):
    """``P <- factor P`` (covariance resetting on a detected change): ``S <- sqrt(factor) S``
    (nothing without a covariance)."""
    scale = math.sqrt(factor)
    for i in range(S.shape[0]):
        for j in range(S.shape[1]):
            S[i, j] *= scale


@lane(inline=True)
def process_noise(S, n, y, u, q, q_floor, Q):
    """``Q = q [y^2 P_aa + u^2 P_bb - y u (P_ab + P_ba)] + q_floor I``.

    Row ``i`` of the one-step model error is ``-(a_i - a_hat_i) x_1 + (b_i - b_hat_i) u`` (observer
    form; a scale for the observability form), with ``Cov(theta - theta_hat) ~ P`` and
    ``x_1 ~ y``: large while the parameters are uncertain (the filter follows ``y``), vanishing
    as ``P`` shrinks (the filter becomes the noise-free observer of the oracle)."""
    for i in range(n):
        for j in range(i, n):
            v = q * (
                y * y * covariance_entry(S, i, j)
                + u * u * covariance_entry(S, n + i, n + j)
                - y * u * (covariance_entry(S, i, n + j) + covariance_entry(S, j, n + i))
            )
            if i == j:
                v += q_floor
            Q[i, j] = v
            Q[j, i] = v


# --------------------------------------------------------------------------------- the step
@lane(entry=True, inline=True)
def controller_step(f, g, at, cfg, est, est_work, lane, est_cfg, lq_weights, y, r):
    """One sample of the self-tuning controller (module docstring, steps 1-6); returns ``u(t)``.

    ``f``/``g``: the lane's float and int records (offsets ``at``, a :class:`ControllerRecord`,
    and :data:`INTS`); ``cfg``: a :class:`ControllerConfig`; ``est``/``est_work``/``est_cfg``:
    the paper estimator's lane state, scratch and configuration (its lane ``lane``), all
    ``None`` for extended least squares; ``lq_weights``: ``[q_y, q_i, rho]`` of the LQ design,
    ``None`` for pole placement. The two ``is None`` tests are resolved at compile time
    (module docstring).
    """
    n = cfg.n
    d = cfg.d
    m = n + (1 if cfg.integral else 0)
    t = g[INTS.t]
    # -- 1. estimator measurement step
    if est_cfg is None:  # extended least squares
        theta = f[at.theta : at.theta + 2 * n]
        S = view2d(f, at.S, d, d)
        e, eps = extended_ls_update(f, at, d, y, cfg.forgetting, cfg.p0)
    else:
        theta = est.theta[lane]
        S = est.S[lane]
        g[INTS.est_status] |= estimator_update(est, est_work, lane, est_cfg, y)
        e = est.E[lane][0]
        eps = e
    f[at.e] = e
    # -- 2. change detection: covariance resetting on a jump of the innovation variance
    closed_t = g[INTS.closed_t]
    if change_alarm(f, at, cfg, e * e, True, t, closed_t, g[INTS.last_alarm]):
        inflate_covariance(S, cfg.inflation)
        g[INTS.n_alarms] += 1
        g[INTS.last_alarm] = t
    # -- 3. certainty-equivalence design inside the safe set (gain written only on success)
    gain = f[at.gain : at.gain + n + 4]
    work = f[at.work : at.work_end]
    if lq_weights is None:
        status = place_design(
            theta, cfg.form, cfg.integral, cfg.feedforward, cfg.alpha, cfg.safe, gain, work
        )
    else:
        P_lq = view2d(f, at.P_lq, m, m)
        status = lq_design(
            theta, cfg.form, cfg.integral, cfg.feedforward, lq_weights, cfg.safe, P_lq, gain,
            work,
        )  # fmt: skip
    g[INTS.last_reason] = status
    if status != OK:
        g[INTS.n_rejected] += 1
    # -- 4. state estimate x(t|t): Kalman filter on the estimated model
    A = view2d(f, at.A, n, n)
    b = f[at.b : at.b + n]
    model_matrices(theta, cfg.form, A, b)
    x = f[at.x : at.x + n]
    P1 = view2d(f, at.P1, n, n)
    xf = f[at.xf : at.xf + n]
    filtered_state(x, P1, cfg.R, y, xf)
    # -- 5. control: the probe while the loop is open, then the tracking law
    bound = cfg.action_bound
    law = f[at.law : at.law + LAW_SIZE]
    level = cfg.probe_output
    open_loop = closed_t < 0
    ymax = f[at.ymax]
    if open_loop:
        ymax = max(ymax, abs(y))
        f[at.ymax] = ymax
    probing = open_loop and (t < cfg.probe_steps or (t < cfg.probe_max and ymax < level))
    if probing or gain[n + 2] <= 0.0:
        # the probe is scaled down once the output exceeds the probe level
        amp = cfg.probe_amplitude * (level / ymax if ymax > level else 1.0)
        u = min(max(amp * probe_sign(g[INTS.seed], g[INTS.episode], t), -bound), bound)
        g[INTS.n_probe] += 1
        law[LAW.saturated] = 0.0
    else:
        if open_loop:
            g[INTS.closed_t] = t
        xc = xf if cfg.filtered else x
        u = track(gain, law, xc, y, r, 0.0, bound, cfg.integral, cfg.anti_windup)
        if law[LAW.saturated] > 0.0:
            g[INTS.n_saturated] += 1
    f[at.u] = u
    # -- 6. process noise, Kalman time update, estimator state step
    Q = view2d(f, at.Q, n, n)
    process_noise(S, n, y, u, cfg.q_gain, cfg.q_floor, Q)
    x_next = f[at.x_next : at.x_next + n]
    L1 = f[at.L1 : at.L1 + n]
    if kalman_step(A, b, P1, Q, cfg.R, x, u, y, x_next, L1, work) == 0:
        for i in range(n):
            x[i] = x_next[i]
    else:  # numerical trouble in the filter: back to x(1) = 0, P1(1) = I (counted)
        g[INTS.n_kf_resets] += 1
        for i in range(n):
            x[i] = 0.0
            for j in range(n):
                P1[i, j] = 1.0 if i == j else 0.0
    if est_cfg is None:
        extended_ls_push(f, at, n, d, y, u, eps)
    else:
        Q_est = est.Q[lane]
        if Q_est.shape[0] == n:  # the paper's Kalman filter gets the same process noise
            copy_matrix(Q, Q_est)
        g[INTS.est_status] |= estimator_predict(est, est_work, lane, est_cfg, u)
    g[INTS.t] = t + 1
    return u


@lanes
def controllers_step(F, G, at, cfg, est, est_work, est_cfg, lq_weights, y, r, u, first, last):
    """:func:`controller_step` for every lane: ``u[i]`` from ``y[i]``, ``r[i]``."""
    for i in range(first, last):
        u[i] = controller_step(
            F[i], G[i], at, cfg, est, est_work, i, est_cfg, lq_weights, y[i], r[i]
        )
