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
   warm-started from the last ``P`` (:func:`.mimo_lq.riccati_step`), or the full doubling solve
   for a fresh model (the first design, after an alarm or a rejected design); the gain is used
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

Lane records: a ``float64`` record (fields :class:`MimoRecord`) with the estimator's fields
first, and an ``int64`` record (:data:`MIMO_INTS`); configuration :class:`MimoConfig`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from stcgym.adaptive.kernels.controller import change_alarm, inflate_covariance, probe_sign
from stcgym.adaptive.kernels.mimo_lq import (
    P_MAX,
    dare_solve,
    design_checks,
    design_work_size,
    feedback_law,
    lq_gain,
    riccati_step,
)
from stcgym.adaptive.kernels.records import view2d
from stcgym.adaptive.kernels.safe_set import NONFINITE, NOT_STABILISABLE, OK
from stcgym.adaptive.kernels.state_matrix import (
    RESET,
    state_matrix_initial,
    state_matrix_layout,
    state_matrix_update,
)
from stcgym.envs.compiled import Layout, lane, lanes

__all__ = [
    "MIMO_INTS",
    "MimoConfig",
    "MimoInts",
    "MimoRecord",
    "mimo_record",
    "mimo_step",
    "mimo_steps",
]


class MimoRecord(NamedTuple):
    """Offsets of the fields of the controller's float lane record (:func:`mimo_record`)."""

    theta: int  # estimator: Theta = [A B]^T (q, n)
    S: int
    R: int
    gram: int
    cross: int
    z: int  # [x(t); u(t)], the next regressor
    e: int  # innovation (n)
    rank: int
    work: int  # the estimator's scratch
    design: int  # design scratch (design_work_size)
    Qw: int  # LQ state weight (n, n)
    Rw: int  # LQ input weight (m, m)
    Nw: int  # LQ cross weight (n, m)
    A: int  # model of the estimate (n, n)
    B: int  # (n, m)
    P_lq: int  # Riccati matrix of the gain in use (n, n)
    P_try: int  # candidate Riccati matrix (n, n)
    K: int  # gain in use (m, n)
    K_try: int  # candidate gain (m, n)
    F: int  # reference feed-forward in use (m, n)
    has_gain: int  # 1.0 once a design was accepted
    ews: int  # short EWMA of ||e||^2
    ewl: int  # long EWMA of ||e||^2
    ymax: int  # largest |x_i| seen while probing
    cmax: int  # largest state cost (x - r)^T Q (x - r) seen while probing
    u_low: int  # lower end of every input's range (m)
    u_high: int  # upper end of every input's range (m)


class MimoInts(NamedTuple):
    """Fields of the controller's ``int64`` lane record."""

    t: int
    episode: int
    seed: int
    n_rejected: int  # designs rejected by the safe set
    n_alarms: int  # detected changes (covariance resets)
    n_saturated: int  # samples with a saturated input
    closed_t: int  # sample at which the loop closed (-1: still open)
    last_alarm: int
    last_reason: int  # status code of the last design
    n_probe: int
    n_resets: int  # estimator covariance restarts (health check)
    fresh: int  # 1: the next design is a full solve


#: Offsets of the int record's fields (``g[MIMO_INTS.t]``).
MIMO_INTS = MimoInts(*range(len(MimoInts._fields)))


class MimoConfig(NamedTuple):
    """Configuration of :func:`mimo_step` (built once by the Python controller)."""

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


def mimo_record(
    n: int, m: int, Q: NDArray, R: NDArray, N: NDArray, low: NDArray, high: NDArray
) -> tuple[Layout, MimoRecord, NDArray]:
    """Float record of one lane, its offsets and its initial value (weights ``Q``, ``R``,
    ``N``; input range ``[low, high]``, ``m`` values each)."""
    lay = state_matrix_layout(n, m)
    lay.add("design", (design_work_size(n, m),))
    lay.add("Qw", (n, n))
    lay.add("Rw", (m, m))
    lay.add("Nw", (n, m))
    lay.add("A", (n, n))
    lay.add("B", (n, m))
    for name in ("P_lq", "P_try"):
        lay.add(name, (n, n))
    for name in ("K", "K_try", "F"):
        lay.add(name, (m, n))
    for name in ("has_gain", "ews", "ewl", "ymax", "cmax"):
        lay.add(name)
    lay.add("u_low", (m,))
    lay.add("u_high", (m,))
    at = lay.record(MimoRecord)
    init = lay.empty(1)[0]
    state_matrix_initial(lay, init, n, m)
    init[at.Qw : at.Qw + n * n] = np.asarray(Q, dtype=float).ravel()
    init[at.Rw : at.Rw + m * m] = np.asarray(R, dtype=float).ravel()
    init[at.Nw : at.Nw + n * m] = np.asarray(N, dtype=float).ravel()
    init[at.P_lq : at.P_lq + n * n] = np.asarray(Q, dtype=float).ravel()
    init[at.u_low : at.u_low + m] = np.asarray(low, dtype=float).ravel()
    init[at.u_high : at.u_high + m] = np.asarray(high, dtype=float).ravel()
    return lay, at, init


@lane(inline=True)
def _model(f, at, n, m, A, B):
    """``[A_hat B_hat] = Theta^T``."""
    q = n + m
    theta = view2d(f, at.theta, q, n)
    for i in range(n):
        for j in range(n):
            A[i, j] = theta[j, i]
        for j in range(m):
            B[i, j] = theta[n + j, i]


@lane(inline=True)
def _copy(f, src, dst, size):
    for i in range(size):
        f[dst + i] = f[src + i]


@lane
def _design(f, g, at, cfg):
    """Step 3: a candidate gain (Riccati step or full solve), accepted in the safe set."""
    n = cfg.n
    m = cfg.m
    A = view2d(f, at.A, n, n)
    B = view2d(f, at.B, n, m)
    _model(f, at, n, m, A, B)
    Q = view2d(f, at.Qw, n, n)
    R = view2d(f, at.Rw, m, m)
    N = view2d(f, at.Nw, n, m)
    P = view2d(f, at.P_try, n, n)
    K = view2d(f, at.K_try, m, n)
    work = f[at.design : at.Qw]  # the design scratch ends where the weights start
    fresh = g[MIMO_INTS.fresh] != 0 or f[at.has_gain] <= 0.0
    for i in range((n + m) * n):
        if not math.isfinite(f[at.theta + i]):
            return NONFINITE
    if fresh:
        status = dare_solve(A, B, Q, R, N, P, K, work, cfg.solve_tol, cfg.solve_max_iter)
        if status != OK:
            return status
    else:
        _copy(f, at.P_lq, at.P_try, n * n)
        riccati_step(A, B, Q, R, N, P, K, work)
        big = False
        for i in range(n * n):
            big = big or not abs(f[at.P_try + i]) <= P_MAX
        if big or not lq_gain(A, B, R, N, P, K, work):
            _copy(f, at.Qw, at.P_lq, n * n)  # restart the iteration at P = Q
            return NOT_STABILISABLE
    F = view2d(f, at.F, m, n)
    status = design_checks(A, B, Q, R, N, K, F, cfg.b_min, cfg.gain_max, work)
    if status == OK:
        _copy(f, at.P_try, at.P_lq, n * n)
        _copy(f, at.K_try, at.K, m * n)
        f[at.has_gain] = 1.0
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
def mimo_step(f, g, at, cfg, x, r, u):
    """One sample of the controller (module docstring, steps 1-4): ``u(t)`` from ``x(t)``,
    ``r(t)`` (1-D arrays of ``n``, ``n`` and ``m`` floats)."""
    n = cfg.n
    m = cfg.m
    q = n + m
    t = g[MIMO_INTS.t]
    # -- 1. estimator update with the sample (z(t-1), x(t))
    e2 = 0.0
    if t > 0:
        status = state_matrix_update(f, at, n, m, x, cfg.forgetting, cfg.dependence_tol, cfg.p0)
        if status == RESET:
            g[MIMO_INTS.n_resets] += 1
        for i in range(n):
            e2 += f[at.e + i] * f[at.e + i]
    # -- 2. change detection: covariance resetting on a jump of the innovation variance (no
    # sample at t = 0, before the first estimator update)
    closed_t = g[MIMO_INTS.closed_t]
    alarm, f[at.ews], f[at.ewl] = change_alarm(
        cfg, f[at.ews], f[at.ewl], e2, t > 0, t, closed_t, g[MIMO_INTS.last_alarm]
    )
    if alarm:
        inflate_covariance(view2d(f, at.S, q, q), cfg.inflation)
        g[MIMO_INTS.n_alarms] += 1
        g[MIMO_INTS.last_alarm] = t
        g[MIMO_INTS.fresh] = 1
    # -- 3. certainty-equivalence design once the estimate has full rank
    if f[at.rank] >= q:
        status = _design(f, g, at, cfg)
        g[MIMO_INTS.last_reason] = status
        if status == OK:
            g[MIMO_INTS.fresh] = 0
        else:
            g[MIMO_INTS.n_rejected] += 1
            g[MIMO_INTS.fresh] = 1
    # -- 4. control: the probe while the loop is open, then the feedback law
    open_loop = closed_t < 0
    ymax = f[at.ymax]
    cmax = f[at.cmax]
    if open_loop:
        for i in range(n):
            ymax = max(ymax, abs(x[i]))
        f[at.ymax] = ymax
        cmax = max(cmax, _state_cost(view2d(f, at.Qw, n, n), x, r))
        f[at.cmax] = cmax
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
    low = f[at.u_low : at.u_low + m]
    high = f[at.u_high : at.u_high + m]
    if probing or f[at.has_gain] <= 0.0:
        seed = g[MIMO_INTS.seed]
        episode = g[MIMO_INTS.episode]
        for j in range(m):
            u[j] = min(max(amp * probe_sign(seed, episode, t * m + j), low[j]), high[j])
        g[MIMO_INTS.n_probe] += 1
    else:
        if open_loop:
            g[MIMO_INTS.closed_t] = t
        K = view2d(f, at.K, m, n)
        F = view2d(f, at.F, m, n)
        saturated = feedback_law(K, F, x, r, cfg.action_bound, u)
        for j in range(m):
            if not low[j] <= u[j] <= high[j]:
                u[j] = min(max(u[j], low[j]), high[j])
                saturated += 1
        if saturated > 0:
            g[MIMO_INTS.n_saturated] += 1
    # -- the next regressor z(t) = [x(t); u(t)]
    for i in range(n):
        f[at.z + i] = x[i]
    for j in range(m):
        f[at.z + n + j] = u[j]
    g[MIMO_INTS.t] = t + 1


@lanes
def mimo_steps(F, G, at, cfg, X, Rr, U, first, last):
    """:func:`mimo_step` for every lane (``X``, ``Rr`` ``(B, n)``, ``U`` ``(B, m)``)."""
    for i in range(first, last):
        mimo_step(F[i], G[i], at, cfg, X[i], Rr[i], U[i])
