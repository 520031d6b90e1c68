"""The closed-loop driver: every cost that ``stcgym bench`` and ``stcgym sweep`` report.

:func:`run_closed_loop` starts a new episode of a controller on an environment that has just
been reset and runs it for a given number of steps; it returns the per-step cost of every lane
scored by the one divergence rule of :func:`stcgym.adaptive.control.rollout.charge_divergence`: a
lane
that diverges (``|y| > y_bound``) is flagged and charged its last per-step cost for every step
it did not live, so a diverged run never looks better than a bounded one and every figure stays
finite. Two routes, the same numbers:

* the compiled rollout (:func:`stcgym.adaptive.control.rollout.rollout`) when the controller is the
  compiled :class:`~stcgym.adaptive.SelfTuningController` on a native canonical vector env
  whose next steps it can take whole (:meth:`~stcgym.envs.vector.LinearPlantVectorEnv.lookahead`:
  references, noise, and parameters that are constant or jump once, at the same step for every
  lane) and the caller needs no per-step hook; the env itself is not stepped then;
* otherwise the same loop through ``policy.predict`` (RL agents, the oracles, LQG, and any
  controller on a single env, under drift, or when a hook must run every step).

Either way the policy starts a new episode on every lane first (``policy.reset()``, see
:func:`stcgym.adaptive.policy.reset_policy`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stcgym.adaptive.control.rollout import charge_divergence
from stcgym.adaptive.policy import reset_policy

__all__ = ["LoopResult", "run_closed_loop"]

#: ``before_step(k)``: called before the action of step ``k`` is chosen (e.g. to tell an oracle
#: the parameters in force).
BeforeStep = Callable[[int], None]
#: ``on_step(k, action, obs, info)``: called after step ``k`` with the action sent and what
#: the env returned (a single env's ``info``, or a vector env's infos).
OnStep = Callable[[int, NDArray, NDArray, dict[str, Any]], None]


@dataclass
class LoopResult:
    """Per-step costs ``(B, T)`` under the divergence rule, and each lane's outcome.

    ``predict_s`` is the wall time spent in ``predict`` (0 on the compiled route).
    """

    cost: NDArray
    diverged: NDArray
    steps_run: NDArray
    predict_s: float = 0.0


def run_closed_loop(
    policy: Any,
    env: Any,
    obs: NDArray,
    steps: int,
    *,
    before_step: BeforeStep | None = None,
    on_step: OnStep | None = None,
) -> LoopResult:
    """Run a new episode of ``policy`` for ``steps`` steps on ``env``, reset just before.

    Parameters
    ----------
    policy
        A controller or agent with ``predict(obs, deterministic=True)`` and ``reset()`` (called
        first: a new episode on every lane).
    env
        A single Gymnasium env (one lane) or a native vector env (``B`` lanes, each scored
        until it first terminates; what a lane does after its autoreset is not scored).
    obs
        The observation returned by the reset, ``(2 p,)`` or ``(B, 2 p)`` for ``p`` outputs.
    steps
        Episode length ``T``.
    before_step, on_step
        Per-step hooks (they force the ``predict`` route).

    Returns
    -------
    LoopResult
        Per-step costs ``(B, T)`` (``B = 1`` for a single env) under the divergence rule, the
        lanes that diverged and the steps each lived.
    """
    reset_policy(policy)
    if before_step is None and on_step is None:
        inputs = _rollout_inputs(policy, env, obs, steps)
        if inputs is not None:
            return _compiled(policy, steps, inputs)
    return _predict_loop(policy, env, obs, steps, before_step, on_step)


def _predict_loop(
    policy: Any,
    env: Any,
    obs: NDArray,
    steps: int,
    before_step: BeforeStep | None,
    on_step: OnStep | None,
) -> LoopResult:
    single = np.ndim(obs) == 1
    B = 1 if single else len(obs)
    cost = np.zeros((B, steps))
    alive = np.ones(B, dtype=bool)
    steps_run = np.full(B, steps, dtype=np.int64)
    wall = 0.0
    for k in range(steps):
        if before_step is not None:
            before_step(k)
        t0 = time.perf_counter()
        action, _ = policy.predict(obs, deterministic=True)
        wall += time.perf_counter() - t0
        action = np.asarray(action, dtype=float).reshape(-1 if single else (B, -1))
        obs, reward, terminated, _, info = env.step(action)
        cost[alive, k] = -np.atleast_1d(reward)[alive]
        if on_step is not None:
            on_step(k, action, obs, info)
        died = alive & np.atleast_1d(terminated)
        steps_run[died] = k + 1
        alive &= ~died
        if not alive.any():
            break  # a single env is not stepped past its end
    charge_divergence(cost, steps_run)
    return LoopResult(cost, ~alive, steps_run, wall)


def _rollout_inputs(policy: Any, env: Any, obs: NDArray, steps: int) -> dict[str, Any] | None:
    """What :func:`~stcgym.adaptive.control.rollout.rollout` needs to take ``env``'s next ``steps``
    steps whole, or ``None`` when the compiled route does not apply."""
    from stcgym.adaptive import SelfTuningController
    from stcgym.envs.vector import CanonicalPlantVectorEnv

    if not (
        isinstance(policy, SelfTuningController)
        and isinstance(env, CanonicalPlantVectorEnv)
        and policy.B == env.num_envs
        and policy.n == env.n_states
        and policy.form == env.form
        and policy.action_bound == env.action_bound
        and env.process_noise_std == 0
        and np.all(env.t == 0)
    ):
        return None
    ahead = env.lookahead(steps)
    theta, jump = env.params.copy(), None
    params = ahead["params"]  # (B, T, 2n) in force at each step, None when constant
    if params is not None:
        changed = np.any(params != theta[:, None, :], axis=2).any(axis=0)
        if changed.any():
            J = int(np.argmax(changed))  # the first step at which some lane's plant changes
            after = params[:, J]
            if not np.array_equal(
                params[:, J:], np.broadcast_to(after[:, None], params[:, J:].shape)
            ):
                return None  # drift, or jumps at different steps: the predict route
            jump = (J, after)
    sigma = env.noise_std
    z = np.zeros((env.num_envs, steps + 1))
    if sigma > 0:
        # y(0) = x(0) + sigma z(0): the reset's noise, then the env's own stream
        z[:, 0] = (obs[:, 0] - env.x[:, 0]) / sigma
        z[:, 1:] = ahead["z_v"][:, :, 0]
    reference = np.concatenate((obs[:, 1:2], ahead["r"][:, :, 0]), axis=1)
    return dict(
        theta=theta,
        reference=reference,
        z=z,
        x0=env.x.copy(),
        noise_std=sigma,
        control_cost=env.control_cost,
        y_bound=env.y_bound,
        jump=jump,
    )


def _compiled(policy: Any, steps: int, inputs: dict[str, Any]) -> LoopResult:
    from stcgym.adaptive.control.rollout import rollout

    res = rollout(policy, inputs.pop("theta"), steps, **inputs)
    return LoopResult(res.step_cost, res.diverged, res.steps_run)
