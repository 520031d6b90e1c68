"""Compiled closed-loop rollout: ``T`` steps of plant + self-tuning controller in one call.

For sweeps over many plants (e.g. chunks of ~1e4 lanes): the plant step of
:mod:`stcgym.envs.dynamics` (``canonical_plant_step``, the env's own step: clipping, output noise,
divergence test, reward) and the controller step of :mod:`stcgym.adaptive.control.controller_step`
run fused in one compiled loop per lane, in one batch loop over lanes. A lane stops at its first
divergence (``|y| > y_bound``), like an env episode that terminates.

Divergence rule
---------------
Every closed-loop cost in stcgym (``stcgym bench``, ``stcgym sweep``, the benchmark scripts,
this rollout) is scored by one rule, :func:`charge_divergence`: a lane that diverges at step
``k`` (``|y| > y_bound``, the env terminates) is flagged ``diverged`` and charged its last
per-step cost, the one of step ``k``, for every step ``k + 1 .. T - 1`` it did not live. That
cost is at least about ``(y_bound - |r|)^2`` per step, so a diverged run never looks better than
one that stayed bounded at any sensible cost, every figure stays finite, and the episode's mean
or sum is over all ``T`` steps whatever happened.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.control.controller import SelfTuningController
from stcgym.adaptive.control.controller_step import controller_step
from stcgym.envs.dynamics import canonical_plant_step
from stcgym.envs.lanes import per_lane
from stcgym.lanes.compiled import lane, lanes
from stcgym.lanes.validation import integer, non_negative

__all__ = ["RolloutResult", "charge_divergence", "rollout"]


@dataclass
class RolloutResult:
    """Per-window costs, divergence flags and optional traces of a :func:`rollout`."""

    cost: NDArray
    diverged: NDArray
    steps_run: NDArray
    y: NDArray | None = None
    u: NDArray | None = None
    step_cost: NDArray | None = None


def charge_divergence(cost: NDArray, steps_run: ArrayLike) -> NDArray:
    """Apply the divergence rule (module docstring) to per-step costs, in place.

    Parameters
    ----------
    cost
        Per-step costs ``(B, T)``; row ``i`` is valid for its first ``steps_run[i]`` steps.
    steps_run
        Steps each lane lived, ``(B,)``; ``steps_run[i] < T`` means lane ``i`` diverged at
        step ``steps_run[i] - 1``.

    Returns
    -------
    NDArray
        ``cost``, each diverged lane's steps from ``steps_run[i]`` on set to its last cost.
    """
    T = cost.shape[1]
    for i in np.flatnonzero(np.asarray(steps_run) < T):
        last = int(steps_run[i]) - 1
        cost[i, last + 1 :] = cost[i, last]
    return cost


@lane(inline=True)
def rollout_lane(s, w, cfg, est, est_work, est_cfg, els_cfg, design, lane_i, x, theta,
                 theta_after, jump_at, form, bound, sigma_v, z, r, rho, y_bound, window, cost,
                 y_tr, u_tr, traces):  # fmt: skip
    """``T = r.size - 1`` closed-loop steps of lane ``lane_i`` (the arguments before ``lane_i``: the
    controller's :class:`~stcgym.adaptive.control.controller_step.ControllerArgs`); returns
    ``(steps_run, diverged)``."""
    T = r.shape[0] - 1
    none = z[0:0]  # no schedule: an empty view (lane functions never allocate)
    y = x[0] + sigma_v * z[0]
    if traces:
        y_tr[0] = y
    for k in range(T):
        u_raw = controller_step(s, w, cfg, est, est_work, est_cfg, els_cfg, design, lane_i, y, r[k])
        th = theta_after if k >= jump_at else theta
        reward, _, diverged, u, _, y = canonical_plant_step(
            x, th, u_raw, bound, 0.0, none, sigma_v, z[k + 1], r[k + 1], rho, y_bound, form
        )
        cost[k // window] += -reward
        if traces:
            y_tr[k + 1] = y
            u_tr[k] = u
        if diverged:
            return k + 1, True
    return T, False


@lanes(min_lanes=1)  # a lane is a whole episode
def rollout_lanes(s, w, cfg, est, est_work, est_cfg, els_cfg, design, X, Theta,
                  Theta_after, jump_at, form, bound, sigma_v, Z, R, rho, y_bound, window, Cost, Y,
                  U, traces, steps_run, diverged, first: int, last: int):  # fmt: skip
    """:func:`rollout_lane` for every lane (``R``, ``Theta``... one row per lane)."""
    for i in range(first, last):
        steps_run[i], diverged[i] = rollout_lane(
            s, w, cfg, est, est_work, est_cfg, els_cfg, design, i, X[i], Theta[i],
            Theta_after[i], jump_at, form, bound, sigma_v, Z[i], R[i], rho, y_bound, window,
            Cost[i], Y[i], U[i], traces,
        )  # fmt: skip


def _per_lane(value: ArrayLike, B: int, width: int, name: str) -> NDArray:
    """One row of ``width`` per lane (one for all lanes or one each), C-contiguous."""
    return np.ascontiguousarray(per_lane(value, B, (width,), name))


def rollout(
    controller: SelfTuningController,
    theta: ArrayLike,
    steps: int,
    *,
    reference: ArrayLike,
    noise_std: float = 0.05,
    z: ArrayLike | int = 0,
    control_cost: float = 0.01,
    y_bound: float = 100.0,
    x0: ArrayLike | None = None,
    window: int | None = None,
    traces: bool = False,
    jump: tuple[int, ArrayLike] | None = None,
) -> RolloutResult:
    """Run ``steps`` closed-loop steps of ``controller`` on canonical plants, in one compiled
    call.

    Parameters
    ----------
    controller
        A :class:`~stcgym.adaptive.control.controller.SelfTuningController` with ``num_envs = B``
        (or
        ``None`` for one plant); its lane state is advanced in place (call
        ``controller.reset()`` first for a fresh episode) and its ``action_bound`` is the
        plant's.
    theta
        Plant parameters ``[a; b]`` in the controller's canonical form, ``(2n,)`` (every lane)
        or ``(B, 2n)``.
    steps
        ``T``, the closed-loop steps.
    reference
        ``r(0..T)``, ``(T + 1,)`` (every lane) or ``(B, T + 1)``; the controller sees ``r(k)``
        at step ``k``, and the cost of step ``k`` is ``(y_clean(k+1) - r(k+1))^2 + rho u(k)^2``
        (the env's ``-reward``, ``rho = control_cost``).
    noise_std, z
        Output noise ``noise_std * z``, ``z`` ``(B, T + 1)`` standard normals (``z[:, 0]`` for
        ``y(0)``), or an int: the seed they are drawn from (``numpy.random.default_rng(z)``).
    control_cost
        ``rho``.
    y_bound
        Divergence bound: a lane stops at its first ``|y| > y_bound`` (module docstring).
    x0
        Initial plant state ``(n,)`` or ``(B, n)`` (zeros by default).
    window
        The result's ``cost`` holds sums over consecutive windows of this many steps (default:
        one window, the whole episode), ``(B, ceil(T / window))``.
    traces
        Also return ``y`` (measured, ``(B, T + 1)``) and ``u`` (applied, ``(B, T)``).
    jump
        ``(step, theta_after)``: the parameters switch to ``theta_after`` at ``step``.

    Returns
    -------
    RolloutResult
        ``step_cost`` ``(B, T)`` (a diverged lane charged by :func:`charge_divergence`),
        ``cost`` (its window sums), ``diverged`` ``(B,)`` bool, ``steps_run`` ``(B,)``, and
        ``y``/``u`` (or ``None``); for one plant the leading lane axis is kept (``B = 1``).

    Raises
    ------
    ValueError
        ``controller`` not a ``SelfTuningController``; an array of the wrong shape, a
        negative ``noise_std`` or a ``window`` below 1 (naming the parameter).
    """
    if not isinstance(controller, SelfTuningController):
        raise ValueError(f"controller must be a SelfTuningController, got {controller!r}")
    steps = integer(steps, "steps")
    B, n = controller.B, controller.n
    th = _per_lane(theta, B, 2 * n, "theta")
    if jump is None:
        jump_at, th_after = steps + 1, th
    else:
        jump_at = int(jump[0])
        th_after = _per_lane(jump[1], B, 2 * n, "jump theta")
    R = _per_lane(reference, B, steps + 1, "reference")
    X = _per_lane(np.zeros(n) if x0 is None else x0, B, n, "x0").copy()
    noise_std = non_negative(noise_std, "noise_std")
    if isinstance(z, (int, np.integer)):
        Z = np.random.default_rng(z).standard_normal((B, steps + 1))
    else:
        Z = _per_lane(z, B, steps + 1, "z")
    window = steps if window is None else int(window)
    if window < 1:
        raise ValueError(f"window must be a positive integer, got {window!r}")
    step_cost = np.zeros((B, steps))
    Y = np.zeros((B, steps + 1)) if traces else np.zeros((B, 0))
    U = np.zeros((B, steps)) if traces else np.zeros((B, 0))
    steps_run = np.zeros(B, dtype=np.int64)
    diverged = np.zeros(B, dtype=bool)
    form = 1 if controller.form == "observability" else 0
    # the compiled loop sums over windows of 1 step: the rule needs each lane's last cost
    rollout_lanes(
        *controller.compiled_args, X, th, th_after, jump_at, form, controller.action_bound,
        float(noise_std), Z, R,
        float(control_cost), float(y_bound), 1, step_cost, Y, U, bool(traces), steps_run,
        diverged,
    )  # fmt: skip
    charge_divergence(step_cost, steps_run)
    cost = np.add.reduceat(step_cost, np.arange(0, steps, window), axis=1)
    return RolloutResult(
        cost, diverged, steps_run, Y if traces else None, U if traces else None, step_cost
    )
