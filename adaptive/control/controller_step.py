"""The self-tuning controller step, written once as a compiled lane function.

One call of :func:`controller_step` advances one plant's controller by one sample
(convention of :mod:`stcgym.lanes.compiled`): it reads ``y(t)``, ``r(t)`` and returns ``u(t)``.
Every step, in this order:

1. **estimator measurement step** with ``y(t)``: ``theta_hat(t)`` and the innovation ``e(t)``
   (a paper estimator of :mod:`.estimator` -- O-RLS, KF-MILS, ... -- or extended least squares
   on the ARMAX form, :mod:`.extended_ls`);
2. **change detection**: a short and a long EWMA of ``e(t)^2``; when the short one exceeds
   ``threshold`` times the long one (in closed loop, at most once per ``holdoff`` steps) ``P``
   is multiplied by ``inflation`` (covariance resetting, Astrom & Wittenmark sec. 11.2);
3. **design** (certainty equivalence) on ``A_hat, b_hat`` of ``theta_hat(t)`` (observer
   canonical form, Ding & Ma 2014 eq. (1)-(5)): Ackermann pole placement or one Riccati
   iteration of the LQ problem on the integral-augmented model, accepted only inside the **safe
   set** (:mod:`.safe_set`), else the last good gain stays;
4. **state estimate**: a Kalman filter on the estimated model, corrected by ``y(t)``
   (``x(t|t)``);
5. **control**: for the first ``probe_steps`` samples, or while no design has been accepted,
   a zero-mean probe ``+-probe_amplitude * min(1, probe_output / max |y|)`` with signs from a
   counter-based hash of ``(seed, episode, t)``, extended up to ``probe_max`` samples while
   ``max |y| < probe_output``; afterwards the tracking law ``u = sat(N r - K_x x(t|t) - k_i
   xi)`` with conditional-integration anti-windup (:func:`.law.track`);
6. **process noise and state step**: ``Q(t)`` from the parameter covariance, the Kalman time
   update with the applied ``u(t)`` (``state_estimation.kalman_step``), the estimator's state
   step / regressor shift (a paper KF estimator's filter gets the same ``Q(t)``).

Steps 1-5 are :func:`controller_act` and step 6 is :func:`controller_commit`, so that a caller
that gives the plant another input than the controller's (a residual agent's correction on top
of it) hands the applied one to the time update: the estimator's regressor and the Kalman
filter then hold the input the plant really got, not a silent input disturbance.
:func:`controller_step` is the two in a row, on the input the controller chose.

Lane state: :class:`ControllerState` (the controller's own fields and counters) and its scratch
:class:`ControllerWork`, named tuples of batched arrays (lane ``i``'s field ``f`` is
``state.f[i]``; shapes in :func:`controller_shapes`); the estimator's state and scratch are its
own (:class:`.estimator_spec.EstimatorState` or :class:`.extended_ls.ExtendedLSState`).
The estimator (``est_cfg`` or ``els_cfg`` is ``None``) and the design (the class of its
compiled argument ``design``, :func:`design_gain`) are decided on the arguments' types: numba
prunes a branch under ``x is not None`` before typing when ``x`` is ``None``, and types the
design's call for its argument's class only, so each estimator family and design is a compiled
version of its own, shared by single plant and batch. The design's compiled argument, lane
state (``ControllerState.design``) and scratch (``ControllerWork.design``) are its
registry entry's (:class:`stcgym.adaptive.variants.CompiledDesign`).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from stcgym.adaptive.control.extended_ls import extended_ls_push, extended_ls_update
from stcgym.adaptive.control.law import track
from stcgym.adaptive.control.safe_set import OK, make_gain
from stcgym.adaptive.estimation.estimator import estimator_predict, estimator_update
from stcgym.adaptive.estimation.state_estimation import filtered_state, kalman_step
from stcgym.adaptive.kernels.canonical import model_matrices
from stcgym.adaptive.variants import CompiledDesign, compiled_design
from stcgym.lanes.compiled import chosen_by_type, lane, lane_state, lanes
from stcgym.lanes.linalg import copy_matrix, copy_vector

__all__ = [
    "COUNTERS",
    "ControllerConfig",
    "ControllerState",
    "ControllerWork",
    "change_alarm",
    "design_gain",
    "controller_shapes",
    "controller_act",
    "controller_commit",
    "controller_step",
    "controllers_act",
    "controllers_commit",
    "controllers_step",
    "hash32",
    "make_controller_state",
    "probe_sign",
]


class ControllerState(NamedTuple):
    """The controller's lane state: field ``f`` of lane ``i`` is ``state.f[i]`` (a batch of
    ``B`` lanes holds ``(B, *shape)`` arrays; shapes in :func:`controller_shapes`)."""

    ews: NDArray  # short EWMA of e(t)^2
    ewl: NDArray  # long EWMA of e(t)^2
    e: NDArray  # the last innovation e(t)
    eps: NDArray  # the residual of e(t) the regressor keeps (extended least squares; else e)
    y: NDArray  # the last measured output y(t)
    u: NDArray  # the last applied input u(t)
    ymax: NDArray  # the largest |y| seen while the loop was open
    x: NDArray  # x(t+1|t) of the controller's Kalman filter (n)
    P1: NDArray  # its covariance (n, n)
    xf: NDArray  # x(t|t) (n)
    x_next: NDArray  # the time update's x(t+1|t) (n)
    L1: NDArray  # the filter's gain (n)
    Q: NDArray  # its process noise Q(t) (n, n)
    gain: Any  # the last accepted design: a safe_set.Gain (K_x, k_i, N, rcond)
    has_gain: NDArray  # a design has been accepted since the reset (bool)
    design: Any  # the design's own lane state (CompiledDesign.make_state; the LQ design's
    # Riccati matrix, nothing for pole placement)
    xi: NDArray  # the tracking law's integrator xi(t)
    saturated: NDArray  # the last input was saturated (bool)
    u_unsat: NDArray  # the last input before saturation
    t: NDArray  # samples since the last reset (int)
    episode: NDArray  # episodes started (int; the probe's sequence)
    seed: NDArray  # the probe's seed (int)
    closed_t: NDArray  # the sample the loop closed at (-1: still open)
    last_alarm: NDArray  # the sample of the last detected change
    last_reason: NDArray  # the status code of the last design
    n_rejected: NDArray  # designs rejected by the safe set
    n_alarms: NDArray  # detected changes (covariance resets)
    n_saturated: NDArray  # saturated inputs
    n_probe: NDArray  # probe samples applied
    n_kf_resets: NDArray  # resets of the Kalman filter on numerical trouble
    est_status: NDArray  # the estimator's status bits, or-ed


class ControllerWork(NamedTuple):
    """The controller's scratch, one row a lane (its content is irrelevant between calls)."""

    design: Any  # the design's scratch (CompiledDesign.make_work: a safe_set.DesignWork for
    # pole placement, lq.LQWork); its model A, b of theta_hat(t) is also the Kalman filter's
    AP: NDArray  # the Kalman time update's A P1 (n, n)
    P_upd: NDArray  # its P1(t+1) until it is accepted (n, n)


#: The integer fields of :class:`ControllerState` (the counters; the others are float64
#: except the flags ``has_gain``, ``saturated``).
COUNTERS = ControllerState._fields[ControllerState._fields.index("t") :]
_DTYPES: dict[str, Any] = {
    **dict.fromkeys(COUNTERS, np.int64),
    "has_gain": np.bool_,
    "saturated": np.bool_,
}


def controller_shapes(n: int) -> tuple[dict[str, tuple[int, ...]], dict[str, tuple[int, ...]]]:
    """The shapes of one lane's :class:`ControllerState` and :class:`ControllerWork` fields for
    order ``n``: the one place they are declared. The design's lane state and scratch (the
    fields ``design``) are the design's own (:class:`.variants.CompiledDesign`), the gain a lane
    state of its own (:func:`.safe_set.gain_shapes`)."""
    n = int(n)
    state: dict[str, tuple[int, ...]] = {
        **dict.fromkeys(("x", "xf", "x_next", "L1"), (n,)),
        **dict.fromkeys(("P1", "Q"), (n, n)),
    }
    for scalar in ControllerState._fields:
        if scalar not in ("gain", "design"):
            state.setdefault(scalar, ())
    work = dict.fromkeys(("AP", "P_upd"), (n, n))
    return state, work


def make_controller_state(
    n: int, num_lanes: int, law: Any, design: CompiledDesign
) -> tuple[ControllerState, ControllerWork]:
    """A :class:`ControllerState` of ``num_lanes`` lanes and their scratch for the law ``law``
    (a ``LawOptions``) and the compiled design ``design``: zeros, but the design's lane state
    at its cold start."""
    shapes, work = controller_shapes(n)
    nested = {"gain": make_gain(n, num_lanes), "design": design.make_state(n, law, num_lanes)}
    return (
        lane_state(ControllerState, shapes, num_lanes, _DTYPES, nested),
        ControllerWork(
            design.make_work(n, law.integral, num_lanes),
            **{f: np.zeros((num_lanes, *shape)) for f, shape in work.items()},
        ),
    )


class ControllerConfig(NamedTuple):
    """Configuration of :func:`controller_step` (built once by the Python controller)."""

    n: int
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
    ew_short: float  # EWMA rates of e^2
    ew_long: float
    probe_output: float  # output level that scales the probe down and ends it early
    safe: NDArray  # [b_min, rcond_min, dc_rcond_min, gain_max]
    char_poly: NDArray  # closed-loop characteristic polynomial coefficients (m; pole placement)


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
def change_alarm(cfg, ews, ewl, e2, update, t, closed_t, last_alarm):
    """Step 2 of both controllers: the innovation-power test of covariance resetting.

    Returns ``(alarm, ews, ewl)``. With ``update``, the short and long exponentially weighted
    means ``ews``, ``ewl`` of ``e2 = |e(t)|^2`` take the sample (weights ``cfg.ew_short``,
    ``cfg.ew_long``). An alarm when detection is on (``cfg.detect``), the loop closed at
    ``closed_t >= 0``, more than ``cfg.holdoff`` steps have passed since then and since
    ``last_alarm``, and the short mean exceeds ``cfg.threshold`` times the long mean before this
    sample.
    """
    ewl_prev = ewl
    if update:
        ews += cfg.ew_short * (e2 - ews)
        ewl = ewl_prev + cfg.ew_long * (e2 - ewl_prev)
    alarm = (
        cfg.detect
        and closed_t >= 0
        and t - closed_t > cfg.holdoff
        and t - last_alarm > cfg.holdoff
        and ews > cfg.threshold * ewl_prev
    )
    return alarm, ews, ewl


# ------------------------------------------------------------------------ parameter covariance
@lane(inline=True)
def covariance_entry(S, lane_i, j):
    """``P_ij = (S S^T)_ij`` of the estimator's square-root factor ``S`` (0 without one)."""
    d = S.shape[0]
    if d == 0:
        return 0.0
    acc = 0.0
    for k in range(max(lane_i, j), d):  # S upper triangular
        acc += S[lane_i, k] * S[j, k]
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


@chosen_by_type(lambda argument: compiled_design(argument).step)
def design_gain(design, theta, cfg, state, gain, w, lane_i):
    """Step 3: the certainty-equivalence design whose compiled argument is ``design`` (its
    :class:`~stcgym.adaptive.variants.CompiledDesign`'s lane function, chosen by the class of
    ``design`` at compile time) on ``theta``, from its lane state ``state``, into lane
    ``lane_i`` of ``gain`` on success, with its scratch ``w``; returns the status code."""
    step = compiled_design(type(design)).step
    return step(design, theta, cfg, state, gain, w, lane_i)


class ControllerArgs(NamedTuple):
    """The compiled arguments of one controller, in the order every step function takes them
    (spread: ``controller_step(*args, lane_i, y, r)``, ``controllers_step(*args, y, r, u)``).

    ``est_cfg`` / ``els_cfg`` (one of them ``None``) and the class of ``design`` choose the
    compiled version (:func:`stcgym.adaptive.variants.compiled_version`).
    """

    s: ControllerState  # the controller's lane state
    w: ControllerWork  # its scratch
    cfg: ControllerConfig
    est: Any  # the estimator's lane state: EstimatorState or ExtendedLSState
    est_work: Any  # its scratch: EstimatorWork or ExtendedLSWork
    est_cfg: Any  # the paper estimator's EstimatorConfig, or None (extended least squares)
    els_cfg: Any  # extended least squares' ExtendedLSConfig, or None (a paper estimator)
    design: Any  # the design's compiled argument (CompiledDesign.argument: LQ's weights)


# --------------------------------------------------------------------------------- the step
@lane(entry=True, inline=True)
def controller_step(s, w, cfg, est, est_work, est_cfg, els_cfg, design, lane_i, y, r):
    """One sample of the self-tuning controller (module docstring, steps 1-6); returns ``u(t)``.

    The arguments before ``lane_i`` are one :class:`ControllerArgs`, spread:
    ``s``/``w``: the controllers' :class:`ControllerState` and :class:`ControllerWork`, of
    which this call reads and writes lane ``lane_i`` only; ``cfg``: a :class:`ControllerConfig`;
    ``est``/``est_work``: the estimator's lane state and scratch, either an ``EstimatorState``
    and ``EstimatorWork`` with the paper estimator's configuration ``est_cfg`` (``els_cfg``
    ``None``), or an ``ExtendedLSState`` and ``ExtendedLSWork`` with extended least squares'
    ``els_cfg`` (``est_cfg`` ``None``); ``design``: the design's compiled argument. The
    ``None`` arguments and the design are resolved at compile time (module docstring). It is
    :func:`controller_act` followed by :func:`controller_commit` of the input it chose.
    """
    u = controller_act(s, w, cfg, est, est_work, est_cfg, els_cfg, design, lane_i, y, r)
    controller_commit(s, w, cfg, est, est_work, est_cfg, els_cfg, design, lane_i, u)
    return u


@lane(inline=True, inline_ir=True)
def controller_act(s, w, cfg, est, est_work, est_cfg, els_cfg, design, lane_i, y, r):
    """Steps 1-5 of :func:`controller_step` (arguments alike): the estimator's measurement
    step with ``y(t)``, change detection, design, ``x(t|t)`` and the input ``u(t)`` the law
    chooses, which it returns. The time update (step 6) waits for :func:`controller_commit`
    with the input the plant was actually given; ``y(t)`` and the residual it needs are kept
    in the lane state (``s.y``, ``s.eps``), the estimated model in the lane's design scratch.
    """
    n = cfg.n
    t = s.t[lane_i]
    theta = est.theta[lane_i][: 2 * n]  # [a; b] (extended least squares: of [a; b; c])
    S = est.S[lane_i]
    # -- 1. estimator measurement step (each branch compiled only in its own version)
    e = eps = 0.0
    if els_cfg is not None:  # extended least squares
        e, eps = extended_ls_update(est, est_work, lane_i, y, els_cfg.forgetting, els_cfg.p0)
    if est_cfg is not None:  # a paper estimator
        s.est_status[lane_i] |= estimator_update(est, est_work, lane_i, est_cfg, y)
        e = est.E[lane_i][0]
        eps = e
    s.e[lane_i] = e
    s.eps[lane_i] = eps
    s.y[lane_i] = y
    # -- 2. change detection: covariance resetting on a jump of the innovation variance
    closed_t = s.closed_t[lane_i]
    alarm, s.ews[lane_i], s.ewl[lane_i] = change_alarm(
        cfg, s.ews[lane_i], s.ewl[lane_i], e * e, True, t, closed_t, s.last_alarm[lane_i]
    )
    if alarm:
        inflate_covariance(S, cfg.inflation)
        s.n_alarms[lane_i] += 1
        s.last_alarm[lane_i] = t
    # -- 3. certainty-equivalence design inside the safe set (gain written only on success)
    status = design_gain(design, theta, cfg, s.design, s.gain, w.design, lane_i)
    s.last_reason[lane_i] = status
    if status == OK:
        s.has_gain[lane_i] = True
    else:
        s.n_rejected[lane_i] += 1
    # -- 4. state estimate x(t|t): Kalman filter on the estimated model (built by the design
    # too, when the design got that far: the same numbers)
    A = w.design.A[lane_i]
    b = w.design.b[lane_i]
    model_matrices(theta, cfg.form, A, b)
    xf = s.xf[lane_i]
    filtered_state(s.x[lane_i], s.P1[lane_i], cfg.R, y, xf)
    # -- 5. control: the probe while the loop is open, then the tracking law
    return control(s, lane_i, cfg, y, r, xf if cfg.filtered else s.x[lane_i])


@lane(inline=True, inline_ir=True)
def controller_commit(s, w, cfg, est, est_work, est_cfg, els_cfg, design, lane_i, u):
    """Step 6 of :func:`controller_step` with the input ``u(t)`` the plant was given (the
    one :func:`controller_act` chose, or another: a residual on top of it, a clipped one;
    ``design`` is not read: every step function takes the same :class:`ControllerArgs`):
    process noise, the Kalman time update, the estimator's state step or regressor shift;
    the sample ends (``t`` advances). Reads ``y(t)`` and the residual :func:`controller_act`
    kept and its model ``A, b`` of ``theta_hat(t)`` in the lane's design scratch.
    """
    n = cfg.n
    y = s.y[lane_i]
    S = est.S[lane_i]
    A = w.design.A[lane_i]
    b = w.design.b[lane_i]
    x = s.x[lane_i]
    P1 = s.P1[lane_i]
    s.u[lane_i] = u
    # -- 6. process noise, Kalman time update, estimator state step
    Q = s.Q[lane_i]
    process_noise(S, n, y, u, cfg.q_gain, cfg.q_floor, Q)
    x_next = s.x_next[lane_i]
    if (
        kalman_step(
            A, b, P1, Q, cfg.R, x, u, y, x_next, s.L1[lane_i], w.AP[lane_i], w.P_upd[lane_i]
        )
        == 0
    ):
        copy_vector(x_next, x)
    else:  # numerical trouble in the filter: back to x(1) = 0, P1(1) = I (counted)
        s.n_kf_resets[lane_i] += 1
        for k in range(n):
            x[k] = 0.0
            for j in range(n):
                P1[k, j] = 1.0 if k == j else 0.0
    if els_cfg is not None:
        extended_ls_push(est, lane_i, n, y, u, s.eps[lane_i])
    if est_cfg is not None:
        Q_est = est.Q[lane_i]
        if Q_est.shape[0] == n:  # the paper's Kalman filter gets the same process noise
            copy_matrix(Q, Q_est)
        s.est_status[lane_i] |= estimator_predict(est, est_work, lane_i, est_cfg, u)
    s.t[lane_i] += 1


@lane(inline=True)
def control(s, lane_i, cfg, y, r, xc):
    """Step 5: the probe while the loop is open (and while no design has been accepted), else
    the tracking law on the state estimate ``xc``; returns ``u(t)``, closes the loop on its
    first law sample (``closed_t``) and counts probe and saturated samples."""
    t = s.t[lane_i]
    closed_t = s.closed_t[lane_i]
    bound = cfg.action_bound
    level = cfg.probe_output
    open_loop = closed_t < 0
    ymax = s.ymax[lane_i]
    if open_loop:
        ymax = max(ymax, abs(y))
        s.ymax[lane_i] = ymax
    probing = open_loop and (t < cfg.probe_steps or (t < cfg.probe_max and ymax < level))
    if probing or not s.has_gain[lane_i]:
        # the probe is scaled down once the output exceeds the probe level
        amp = cfg.probe_amplitude * (level / ymax if ymax > level else 1.0)
        u = min(max(amp * probe_sign(s.seed[lane_i], s.episode[lane_i], t), -bound), bound)
        s.n_probe[lane_i] += 1
        s.saturated[lane_i] = False
        return u
    if open_loop:
        s.closed_t[lane_i] = t
    u, s.xi[lane_i], saturated, s.u_unsat[lane_i] = track(
        s.gain, lane_i, True, s.xi[lane_i], xc, y, r, 0.0, bound, cfg.integral, cfg.anti_windup
    )
    s.saturated[lane_i] = saturated
    if saturated:
        s.n_saturated[lane_i] += 1
    return u


@lanes
def controllers_step(s, w, cfg, est, est_work, est_cfg, els_cfg, design, y, r, u, first, last):
    """:func:`controller_step` for every lane: ``u[i]`` from ``y[i]``, ``r[i]``."""
    for i in range(first, last):
        u[i] = controller_step(s, w, cfg, est, est_work, est_cfg, els_cfg, design, i, y[i], r[i])


@lanes
def controllers_act(s, w, cfg, est, est_work, est_cfg, els_cfg, design, y, r, u, first, last):
    """:func:`controller_act` for every lane: ``u[i]`` from ``y[i]``, ``r[i]``."""
    for i in range(first, last):
        u[i] = controller_act(s, w, cfg, est, est_work, est_cfg, els_cfg, design, i, y[i], r[i])


@lanes
def controllers_commit(s, w, cfg, est, est_work, est_cfg, els_cfg, design, u, first, last):
    """:func:`controller_commit` for every lane with the applied input ``u[i]``."""
    for i in range(first, last):
        controller_commit(s, w, cfg, est, est_work, est_cfg, els_cfg, design, i, u[i])
