"""The multivariable self-tuning LQ step, written once as a compiled lane function.

One call of :func:`mimo_step` advances one plant's controller by one sample: it reads the
measured state ``x(t)`` (the StateSpace env's output with ``C = I``) and the reference ``r(t)``
and writes ``u(t)``. Every step, in this order:

1. **estimator update** with ``x(t)``: the sample ``(z(t-1), x(t))``, ``z = [x; u]``, of the
   ``[A B]`` estimator of Kunik, Kovalenko & Al Sadi (2001) (:mod:`.state_matrix`: minimum-norm
   phase (17)-(18), then RLS (20)-(21) on the shared square-root matrix RLS step);
2. **change detection**: a short and a long EWMA of ``||e(t)||^2``; when the short one exceeds
   ``threshold`` times the long one (closed loop, at most once per ``holdoff`` steps) ``P`` is
   multiplied by ``inflation`` (covariance resetting) and the next design is a full solve;
3. **design** (certainty equivalence, once the estimate has full rank): one Riccati iteration
   warm-started from the last ``P`` (:func:`.mimo_lq.riccati_step`), or the full solve
   (:func:`.mimo_lq.dare_solve`) for a fresh model (the first design, after an alarm or a
   rejected design) and when the iteration lags a settled model (the model moved by less than
   ``settle_tol`` of its largest entry since the last sample, yet the iteration step moved
   ``P`` by more than ``lag_tol`` of its largest entry: the warm start filters a model that
   still moves, and would only slowly reach the solution of one that has stopped); the gain is used
   only inside the **safe set** (finite, ``max |B_hat| >= b_min``, ``A_hat - B_hat K`` Schur
   stable, an equilibrium for every reference, ``max |K|, |F| <= gain_max``), else the last good
   gain stays;
4. **control**: for the first ``probe_steps`` samples (default ``n + m + 1``), and until a
   design has been accepted, a zero-mean probe ``+-a`` on every input with signs hashed from
   ``(seed, episode, t, input)`` and ``a = probe_amplitude min(1, probe_output / max |x|)``,
   capped at ``sqrt(share c_max / trace(R))`` (``c_max`` the largest state cost
   ``(x - r)^T Q (x - r)`` seen while probing) so that the probe's input cost is a small share
   of the cost it is there to remove, on any scale of state and input. A capped probe stops
   after ``probe_min`` samples (default ``n + m``, the fewest that give a full-rank estimate:
   every further open-loop sample costs more than it adds); an uncapped one runs on up to
   ``max_probe_steps`` (default ``5 (n + m)``) while ``max |x| < probe_output``. Then
   ``u = sat(-K x + F r)`` (:func:`.mimo_lq.feedback_law`).

Lane state: :class:`MimoState` (the controller's fields and counters) and its scratch
:class:`MimoWork`, named tuples of batched arrays (lane ``i``'s field ``f`` is ``state.f[i]``;
shapes in :func:`mimo_shapes`); the estimator's state and scratch are its own
(:class:`.state_matrix.StateMatrixState`). The configuration :class:`MimoConfig`, the same
for every lane, holds the LQ weights ``Q``, ``R``, ``N``.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from stcgym.adaptive.control.controller_step import change_alarm, inflate_covariance, probe_sign
from stcgym.adaptive.control.safe_set import NONFINITE, NOT_STABILISABLE, OK
from stcgym.adaptive.multivariable.mimo_lq import (
    P_MAX,
    dare_solve,
    design_checks,
    feedback_law,
    lq_gain,
    mimo_design_work,
    riccati_step,
)
from stcgym.adaptive.multivariable.state_matrix import RESET, state_matrix_update
from stcgym.lanes.compiled import lane, lane_state, lanes
from stcgym.lanes.linalg import all_finite, copy_matrix, copy_vector, max_abs

__all__ = [
    "COUNTERS",
    "MimoConfig",
    "MimoState",
    "MimoWork",
    "make_mimo_state",
    "mimo_shapes",
    "mimo_step",
    "mimo_steps",
]


class MimoState(NamedTuple):
    """The controller's lane state: field ``f`` of lane ``i`` is ``state.f[i]`` (a batch of
    ``B`` lanes holds ``(B, *shape)`` arrays; shapes in :func:`mimo_shapes`)."""

    A: NDArray  # model of the estimate A_hat (n, n)
    B: NDArray  # B_hat (n, m)
    P_lq: NDArray  # Riccati matrix of the gain in use (n, n)
    P_try: NDArray  # candidate Riccati matrix (n, n)
    K: NDArray  # gain in use (m, n)
    K_try: NDArray  # candidate gain (m, n)
    F: NDArray  # reference feed-forward in use (m, n)
    has_gain: NDArray  # a design has been accepted since the reset (bool)
    ews: NDArray  # short EWMA of ||e||^2
    ewl: NDArray  # long EWMA of ||e||^2
    ymax: NDArray  # largest |x_i| seen while probing
    cmax: NDArray  # largest state cost (x - r)^T Q (x - r) seen while probing
    u_low: NDArray  # lower end of every input's range (m)
    u_high: NDArray  # upper end of every input's range (m)
    fresh: NDArray  # the next design is a full solve (bool)
    t: NDArray  # samples since the last reset (int)
    episode: NDArray  # episodes started (int; the probe's sequence)
    seed: NDArray  # the probe's seed (int)
    n_rejected: NDArray  # designs rejected by the safe set
    n_alarms: NDArray  # detected changes (covariance resets)
    n_saturated: NDArray  # samples with a saturated input
    closed_t: NDArray  # sample at which the loop closed (-1: still open)
    last_alarm: NDArray  # the sample of the last detected change
    last_reason: NDArray  # status code of the last design
    n_probe: NDArray  # probe samples applied
    n_resets: NDArray  # estimator covariance restarts (health check)
    n_catch_up: NDArray  # full solves for an iteration lagging a settled model


class MimoWork(NamedTuple):
    """The controller's scratch, one row a lane (its content is irrelevant between calls)."""

    design: Any  # the design's scratch (a mimo_lq.MimoDesignWork)


#: The integer fields of :class:`MimoState` (the counters; the others are float64 except the
#: flags ``has_gain`` and ``fresh``).
COUNTERS = MimoState._fields[MimoState._fields.index("t") :]
_DTYPES: dict[str, Any] = {
    **dict.fromkeys(COUNTERS, np.int64),
    "has_gain": np.bool_,
    "fresh": np.bool_,
}


def mimo_shapes(n: int, m: int) -> dict[str, tuple[int, ...]]:
    """The shapes of one lane's :class:`MimoState` fields for ``n`` states and ``m`` inputs:
    the one place they are declared. The scratch :class:`MimoWork` is the design's own
    (:func:`.mimo_lq.mimo_design_shapes`)."""
    n, m = int(n), int(m)
    state: dict[str, tuple[int, ...]] = {
        **dict.fromkeys(("A", "P_lq", "P_try"), (n, n)),
        "B": (n, m),
        **dict.fromkeys(("K", "K_try", "F"), (m, n)),
        **dict.fromkeys(("u_low", "u_high"), (m,)),
    }
    for scalar in MimoState._fields:
        state.setdefault(scalar, ())
    return state


def make_mimo_state(n: int, m: int, num_lanes: int) -> tuple[MimoState, MimoWork]:
    """A zeroed :class:`MimoState` of ``num_lanes`` lanes and their scratch."""
    return (
        lane_state(MimoState, mimo_shapes(n, m), num_lanes, _DTYPES),
        MimoWork(mimo_design_work(n, m, num_lanes)),
    )


class MimoConfig(NamedTuple):
    """Configuration of :func:`mimo_step` (built once by the Python controller); it is also the
    design's :class:`.mimo_lq.LQProblem` (``Q``, ``R``, ``N``, ``solve_tol``,
    ``solve_max_iter``) and safe set (``b_min``, ``gain_max``)."""

    n: int
    m: int
    probe_steps: int
    probe_min: int  # probe length when the probe is capped by the state cost
    probe_max: int
    detect: bool
    holdoff: int
    action_bound: float
    probe_amplitude: float
    probe_output: float
    probe_cost_share: float  # the probe's input cost at most this share of the state cost
    input_weight: float  # trace(R): the probe's input cost per unit amplitude squared
    threshold: float
    inflation: float
    ew_short: float
    ew_long: float
    forgetting: float
    dependence_tol: float
    p0: float  # P <- p0 I after a failed health check
    b_min: float
    gain_max: float
    solve_tol: float
    solve_max_iter: int
    settle_tol: float  # the model counts as settled when it moved less than this (relative)
    lag_tol: float  # the iteration lags when one step moves P by more than this (relative)
    Q: NDArray  # LQ weights of the stage cost e^T Q e + u^T R u + 2 e^T N u: (n, n)
    R: NDArray  # (m, m)
    N: NDArray  # (n, m)


@lane(inline=True)
def _model_change(theta, A, B):
    """``max |[A_hat B_hat] - Theta^T| / max |[A_hat B_hat]|``: how far the estimate ``Theta``
    moved from the last design's model (``inf`` when that model is zero)."""
    n, m = B.shape
    change = 0.0
    size = 0.0
    for i in range(n):
        for j in range(n):
            change = max(change, abs(A[i, j] - theta[j, i]))
            size = max(size, abs(A[i, j]))
        for j in range(m):
            change = max(change, abs(B[i, j] - theta[n + j, i]))
            size = max(size, abs(B[i, j]))
    return change / size if size > 0.0 else math.inf


@lane(inline=True)
def _lagging(P, P_prev, tol):
    """``max |P - P_prev| > tol max |P_prev|``: the Riccati iteration is still far from its
    fixed point."""
    n = P.shape[0]
    step = 0.0
    size = 0.0
    for i in range(n):
        for j in range(n):
            step = max(step, abs(P[i, j] - P_prev[i, j]))
            size = max(size, abs(P_prev[i, j]))
    return step > tol * size


@lane(inline=True)
def _model(theta, A, B):
    """``[A_hat B_hat] = Theta^T``."""
    n, m = B.shape
    for i in range(n):
        for j in range(n):
            A[i, j] = theta[j, i]
        for j in range(m):
            B[i, j] = theta[n + j, i]


@lane(inline=True)
def _design(s, w, est, lane_i, cfg):
    """Step 3: a candidate gain (Riccati step or full solve), accepted in the safe set."""
    theta = est.theta[lane_i]
    A = s.A[lane_i]
    B = s.B[lane_i]
    settled = _model_change(theta, A, B) < cfg.settle_tol
    _model(theta, A, B)
    P = s.P_try[lane_i]
    K = s.K_try[lane_i]
    P_lq = s.P_lq[lane_i]
    work = w.design
    fresh = s.fresh[lane_i] or not s.has_gain[lane_i]
    if not all_finite(theta):
        return NONFINITE
    if fresh:
        status = dare_solve(A, B, cfg, P, K, work, lane_i)
        if status != OK:
            return status
    else:
        copy_matrix(P_lq, P)
        riccati_step(A, B, cfg, P, K, work, lane_i)
        if not max_abs(P) <= P_MAX or not lq_gain(A, B, cfg, P, K, work, lane_i):
            copy_matrix(cfg.Q, P_lq)  # restart the iteration at P = Q
            return NOT_STABILISABLE
        if settled and _lagging(P, P_lq, cfg.lag_tol):
            s.n_catch_up[lane_i] += 1
            status = dare_solve(A, B, cfg, P, K, work, lane_i)
            if status != OK:
                return status
    status = design_checks(A, B, cfg, K, s.F[lane_i], work, lane_i)
    if status == OK:
        copy_matrix(P, P_lq)
        copy_matrix(K, s.K[lane_i])
        s.has_gain[lane_i] = True
    return status


@lane(inline=True)
def _state_cost(Q, x, r):
    """``(x - r)^T Q (x - r)``."""
    n = x.size
    acc = 0.0
    for i in range(n):
        for j in range(n):
            acc += (x[i] - r[i]) * Q[i, j] * (x[j] - r[j])
    return acc


@lane(entry=True)
def mimo_step(s, w, est, est_work, lane_i, cfg, x, r, u):
    """One sample of lane ``lane_i`` of the controller (module docstring, steps 1-4): ``u(t)``
    from ``x(t)``, ``r(t)`` (1-D arrays of ``n``, ``n`` and ``m`` floats).

    ``s``/``w``: the controllers' :class:`MimoState` and :class:`MimoWork`; ``est``/``est_work``:
    the estimator's :class:`.state_matrix.StateMatrixState` and its scratch; ``cfg``: a
    :class:`MimoConfig`.
    """
    n = cfg.n
    m = cfg.m
    q = n + m
    t = s.t[lane_i]
    # -- 1. estimator update with the sample (z(t-1), x(t))
    e2 = 0.0
    if t > 0:
        status = state_matrix_update(est, est_work, lane_i, x, cfg.forgetting, cfg.dependence_tol,
                                     cfg.p0)  # fmt: skip
        if status == RESET:
            s.n_resets[lane_i] += 1
        e = est.e[lane_i]
        for i in range(n):
            e2 += e[i] * e[i]
    # -- 2. change detection: covariance resetting on a jump of the innovation variance (no
    # sample at t = 0, before the first estimator update)
    closed_t = s.closed_t[lane_i]
    alarm, s.ews[lane_i], s.ewl[lane_i] = change_alarm(
        cfg, s.ews[lane_i], s.ewl[lane_i], e2, t > 0, t, closed_t, s.last_alarm[lane_i]
    )
    if alarm:
        inflate_covariance(est.S[lane_i], cfg.inflation)
        s.n_alarms[lane_i] += 1
        s.last_alarm[lane_i] = t
        s.fresh[lane_i] = True
    # -- 3. certainty-equivalence design once the estimate has full rank
    if est.rank[lane_i] >= q:
        status = _design(s, w, est, lane_i, cfg)
        s.last_reason[lane_i] = status
        if status == OK:
            s.fresh[lane_i] = False
        else:
            s.n_rejected[lane_i] += 1
            s.fresh[lane_i] = True
    # -- 4. control: the probe while the loop is open, then the feedback law
    open_loop = closed_t < 0
    ymax = s.ymax[lane_i]
    cmax = s.cmax[lane_i]
    if open_loop:
        for i in range(n):
            ymax = max(ymax, abs(x[i]))
        s.ymax[lane_i] = ymax
        cmax = max(cmax, _state_cost(cfg.Q, x, r))
        s.cmax[lane_i] = cmax
    level = cfg.probe_output
    amp = cfg.probe_amplitude * (level / ymax if ymax > level else 1.0)
    # the probe follows the scale of the state and the input: its input cost a^2 trace(R)
    # stays a small share of the state cost it is there to remove (a plant at its reference
    # is probed with the full amplitude)
    capped = False
    if cmax > 0.0:
        cap = math.sqrt(cfg.probe_cost_share * cmax / cfg.input_weight)
        if cap < amp:
            amp = cap
            capped = True
    # an excited state needs no longer probe: the extension is for a plant near rest
    extend = t < cfg.probe_max and ymax < level and not capped
    probing = open_loop and (t < (cfg.probe_min if capped else cfg.probe_steps) or extend)
    low = s.u_low[lane_i]
    high = s.u_high[lane_i]
    if probing or not s.has_gain[lane_i]:
        seed = s.seed[lane_i]
        episode = s.episode[lane_i]
        for j in range(m):
            u[j] = min(max(amp * probe_sign(seed, episode, t * m + j), low[j]), high[j])
        s.n_probe[lane_i] += 1
    else:
        if open_loop:
            s.closed_t[lane_i] = t
        saturated = feedback_law(s.K[lane_i], s.F[lane_i], x, r, cfg.action_bound, u)
        for j in range(m):
            if not low[j] <= u[j] <= high[j]:
                u[j] = min(max(u[j], low[j]), high[j])
                saturated += 1
        if saturated > 0:
            s.n_saturated[lane_i] += 1
    # -- the next regressor z(t) = [x(t); u(t)]
    z = est.z[lane_i]
    copy_vector(x, z)
    for j in range(m):
        z[n + j] = u[j]
    s.t[lane_i] = t + 1


@lanes
def mimo_steps(s, w, est, est_work, cfg, X, Rr, U, first, last):
    """:func:`mimo_step` for every lane (``X``, ``Rr`` ``(B, n)``, ``U`` ``(B, m)``)."""
    for i in range(first, last):
        mimo_step(s, w, est, est_work, i, cfg, X[i], Rr[i], U[i])
