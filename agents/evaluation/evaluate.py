"""One evaluation loop for every controller, and the metrics the bench reports.

Every controller (an SB3 model behind :class:`~stcgym.agents.rl.policy.SB3Policy`, the self-tuning
controller, the known-model oracles) is driven through the shared policy protocol
(:mod:`stcgym.adaptive.policy`) by the closed-loop driver
(:func:`stcgym.agents.closed_loop.run_closed_loop`): ``policy.reset()``, then
``policy.predict(obs, deterministic=True)`` on the *raw* observation
``[y(k), r(k)]`` of the environment (``y`` the plant's outputs: the state ``x`` of a MIMO
plant, :class:`~stcgym.agents.evaluation.mimo.MimoEnvSpec`). For a given :class:`EnvSpec` and
seed the environment is built afresh and reset with ``reset(seed=seed)``, so every controller
in a comparison meets the same plant, the same output noise and the same reference.

Scoring
-------
Everything is computed from the environment's reward, ``cost(k) = -reward(k) = (y_clean(k+1) -
r(k+1))^2 + rho u(k)^2``:

* ``cost``: mean cost per step over the episode;
* ``cost_start``, ``cost_steady``, ``cost_post_jump``: mean cost over the windows of
  :func:`default_windows` (steps ``[0, T/10)``, ``[T/2, T)``; with a jump at ``J``: steady is the
  pre-jump ``[J/2, J)`` and post-jump is ``[J + 0.3 (T-J), J + 0.6 (T-J))``, i.e. 0-200,
  1000-2000 and 1300-1600 for a 2000-step episode with the jump at 1000);
* ``effort``: mean ``||u(k)||^2`` (plant units) over the steps run;
* ``bounded``: the episode did not diverge (``|y|`` stayed below the environment's ``y_bound``);
* ``overshoot_pct``, ``settling_steps``: step response at the reference steps of the steady
  window, ``startup_settling_steps`` at the first reference step (step 0), see
  :func:`stcgym.agents.evaluation.response.step_response` (one output only: ``nan`` for a MIMO
  plant, whose references need not all be equilibria);
* the metrics relative to the oracle on the same episode (cost ratios, adaptation and
  re-convergence steps, :mod:`stcgym.agents.evaluation.response`) need the oracle's run and
  are computed by the bench from ``Episode.cost``.
* ``step_us``: wall time of one ``predict`` call, microseconds (mean over the episode).

The loop is :func:`stcgym.agents.closed_loop.run_closed_loop`: a diverged episode ends early
and is charged by its divergence rule (:func:`stcgym.adaptive.control.rollout.charge_divergence`:
its
last step's cost for every step it did not live), so failed runs rank worst in every statistic
and all numbers stay finite.

Statistics over seeds (:func:`summarize`): median, inter-quartile range, CVaR of the worst
quarter (mean of the ``ceil(n/4)`` largest values) and failure rate.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from stcgym.agents.closed_loop import run_closed_loop
from stcgym.agents.evaluation.env_spec import EnvSpec
from stcgym.agents.evaluation.response import step_response
from stcgym.agents.evaluation.statistics import summarize
from stcgym.envs.catalogue import PlantSpec

__all__ = [
    "EnvSpec",
    "Episode",
    "EvalResult",
    "PolicyFactory",
    "Windows",
    "cost_metrics",
    "default_windows",
    "episode_metrics",
    "response_metrics",
    "evaluate",
    "run_episode",
    "summarize",
]


def _reset_episode(env: gym.Env, seed: int, plant: str | None) -> tuple[Any, Any, Any]:
    options = None if plant is None else {"plant": plant}
    obs, info = env.reset(seed=int(seed), options=options)
    return obs, info, env.unwrapped.plant


#: ``factory(plant, seed) -> policy``: the controller for one episode on ``plant`` (the
#: catalogue plant in force at the start of the episode, which only the oracles may look at);
#: ``seed`` is the episode's seed, so a controller with random parts (the self-tuning
#: controller's probe) draws its own stream in every episode.
PolicyFactory = Callable[[PlantSpec, int], Any]


@dataclass
class Episode:
    """Traces of one episode (length ``T``; ``y``, ``r`` have ``T + 1`` samples).

    ``y`` is the noise-free output (the one the cost scores); after a divergence ``y`` and ``r``
    are ``nan``.

    ``cost`` holds the charged cost per step, including the charge of a diverged run for the
    steps it did not live (``steps_run`` tells where it ended).

    Parameters
    ----------
    seed : int
        The episode's seed.
    plant : str
        Catalogue name of the plant the episode ran on.
    y, r : ndarray, shape (T + 1,) or (T + 1, p)
        Noise-free output and reference, ``y(0..T)``, ``r(0..T)`` (``p`` outputs of a MIMO
        plant).
    u : ndarray, shape (T,) or (T, m)
        Applied (clipped) input (``m`` inputs of a MIMO plant).
    cost : ndarray, shape (T,)
        Charged cost per step.
    steps_run : int
        Steps before the end or the divergence.
    diverged : bool
        Whether ``|y|`` left the env's ``y_bound``.
    n_clipped : int
        Steps whose action was clipped.
    step_us : float
        Mean wall time of one ``predict`` call, microseconds.
    theta, theta_hat : ndarray or None
        With ``record_theta``: the true parameters ``(T + 1, 2n)`` and the policy's estimate
        ``(T, 2n)`` (a MIMO plant: ``[A B]`` flattened row by row).

    Examples
    --------
    See :func:`run_episode`, which returns one.
    """

    seed: int
    plant: str
    y: NDArray
    r: NDArray
    u: NDArray
    cost: NDArray
    steps_run: int
    diverged: bool
    n_clipped: int
    step_us: float
    #: with ``record_theta``: true parameters ``(T + 1, 2n)`` and the policy's ``theta`` after
    #: each step ``(T, 2n)`` (``nan`` where the policy has none)
    theta: NDArray | None = None
    theta_hat: NDArray | None = None


def run_episode(
    policy: Any,
    spec: EnvSpec,
    seed: int,
    *,
    plant: str | None = None,
    record_theta: bool = False,
) -> Episode:
    """Run ``policy`` for one episode of ``spec`` from ``reset(seed=seed)``.

    ``policy`` is a policy, or a :data:`PolicyFactory` called with the plant drawn by the reset
    and the seed. ``plant`` picks one member of a family (``reset(options={"plant": plant})``);
    by default the environment draws it from the seed. The policy is reset before the first
    step. ``record_theta`` keeps the true parameters and the policy's estimates
    (``policy.theta``) per step.

    Parameters
    ----------
    policy : Policy or PolicyFactory
        The controller, or ``factory(plant_spec, seed) -> policy``.
    spec : EnvSpec
        The scenario's environment (built afresh).
    seed : int
        ``env.reset(seed=seed)``.
    plant : str, optional
        Family member to run on (default: the environment's draw).
    record_theta : bool, default False
        Keep :attr:`Episode.theta` and :attr:`Episode.theta_hat`.

    Returns
    -------
    Episode
        The traces; a diverged episode ends early and is charged for the rest.

    Raises
    ------
    ValueError
        From the environment (an unknown ``plant``) or from the policy (a rejected
        observation).

    Examples
    --------
    >>> from stcgym.adaptive import KnownModelController
    >>> from stcgym.agents import EnvSpec, run_episode
    >>> spec = EnvSpec("unstable2", steps=200)
    >>> def oracle(plant, seed):
    ...     return KnownModelController(plant.a, plant.b, action_bound=spec.action_bound)
    >>> ep = run_episode(oracle, spec, seed=0, record_theta=True)
    >>> ep.plant, ep.steps_run, ep.diverged, ep.y.shape, ep.u.shape
    ('unstable2', 200, False, (201,), (200,))
    >>> ep.theta.shape, ep.theta_hat.shape  # the oracle has no estimate: nan
    ((201, 4), (200, 4))
    >>> bool(np.isnan(ep.theta_hat).all()), round(float(ep.cost.mean()), 4)
    (True, 0.1301)
    """
    env = spec.make()
    # a spec's own reset (a MIMO spec's); any object with make, steps and action_bound will do
    obs, info, drawn = getattr(spec, "reset_episode", _reset_episode)(env, seed, plant)
    name = drawn.name if drawn is not None else "?"
    if not hasattr(policy, "predict"):
        policy = policy(drawn, int(seed))
    T = spec.steps
    plant_env = env.unwrapped
    p_y, m = plant_env.n_outputs, env.action_space.shape[0]  # outputs, inputs
    # the traces hold the performance output z = C_z x where the cost weighs one, else y
    C_z = getattr(plant_env, "C_z", None)
    p = p_y if C_z is None else C_z.shape[0]
    out = () if p == 1 else (p,)  # a SISO plant keeps 1-D traces

    def output(info: dict[str, Any]) -> NDArray:
        z = info["y_clean"] if C_z is None else C_z @ info["x"]
        return np.reshape(z, out)

    def reference(obs: NDArray) -> NDArray:  # r of z (a target state observed: C_z r_x)
        r_obs = obs[p_y:]
        return np.reshape(r_obs if r_obs.size == p else C_z @ r_obs, out)

    y, r = np.zeros((T + 1, *out)), np.zeros((T + 1, *out))
    u = np.zeros((T, *(() if m == 1 else (m,))))
    low, high = env.action_space.low, env.action_space.high
    y[0], r[0] = output(info), reference(obs)
    n_clipped = 0
    theta = theta_hat = None
    if record_theta:
        true = np.ravel(info["theta"] if "theta" in info else info["params"])
        theta = np.full((T + 1, true.size), np.nan)
        theta_hat = np.full((T, true.size), np.nan)
        theta[0] = true

    def record(k: int, action: NDArray, obs: NDArray, info: dict[str, Any]) -> None:
        nonlocal n_clipped
        u[k] = np.clip(np.reshape(action, low.shape), low, high).reshape(u.shape[1:])
        y[k + 1], r[k + 1] = output(info), reference(obs)
        n_clipped = int(info["n_clipped"])
        if record_theta:
            theta[k + 1] = np.ravel(info["theta"] if "theta" in info else info["params"])
            est = getattr(policy, "theta", None)
            if est is not None and np.size(est) == theta.shape[1]:
                theta_hat[k] = np.ravel(est)

    loop = run_closed_loop(policy, env, obs, T, on_step=record)
    env.close()
    steps_run = int(loop.steps_run[0])
    y[steps_run + 1 :], r[steps_run + 1 :] = np.nan, np.nan
    return Episode(
        int(seed),
        name,
        y,
        r,
        u,
        loop.cost[0],
        steps_run,
        bool(loop.diverged[0]),
        n_clipped,
        1e6 * loop.predict_s / steps_run,
        theta,
        theta_hat,
    )


@dataclass(frozen=True)
class Windows:
    """Half-open step windows ``(start, stop)`` for the cost columns."""

    start: tuple[int, int]
    steady: tuple[int, int]
    post_jump: tuple[int, int] | None = None
    jump_step: int | None = None


def default_windows(steps: int, jump_step: int | None = None) -> Windows:
    """The windows of the module docstring for an episode of ``steps`` steps."""
    T = int(steps)
    start = (0, max(1, T // 10))
    if jump_step is None:
        return Windows(start, (T // 2, T))
    J = int(jump_step)
    post = (J + int(0.3 * (T - J)), max(J + int(0.6 * (T - J)), J + int(0.3 * (T - J)) + 1))
    return Windows(start, (J // 2, J), post, J)


def _window_mean(x: NDArray, window: tuple[int, int]) -> float:
    lo, hi = window
    return float(np.mean(x[lo:hi])) if hi > lo else math.nan


def episode_metrics(ep: Episode, windows: Windows, period: int) -> dict[str, float]:
    """The per-episode columns of ``metrics.csv`` (see the module docstring)."""
    u = ep.u[: ep.steps_run].reshape(ep.steps_run, -1)
    m = {
        "cost": float(np.mean(ep.cost)),
        "cost_start": _window_mean(ep.cost, windows.start),
        "cost_steady": _window_mean(ep.cost, windows.steady),
        "cost_post_jump": math.nan,
        "effort": float(np.mean(np.sum(u**2, axis=1))) if len(u) else math.nan,
        "bounded": int(not ep.diverged),
        "steps_run": ep.steps_run,
        "clip_frac": ep.n_clipped / max(ep.steps_run, 1),
        "step_us": ep.step_us,
    }
    if windows.post_jump is not None:
        m["cost_post_jump"] = _window_mean(ep.cost, windows.post_jump)
    if ep.y.ndim > 1:  # several outputs: no step-response figures (module docstring)
        nan = math.nan
        return {**m, "overshoot_pct": nan, "settling_steps": nan, "startup_settling_steps": nan}
    steady = step_response(ep.y, ep.r, start=windows.steady[0], stop=windows.steady[1])
    startup = step_response(ep.y, ep.r, start=0, stop=min(len(ep.r), max(2, period // 2)))
    m["overshoot_pct"] = steady["overshoot_pct"]
    m["settling_steps"] = steady["settling_steps"]
    m["startup_settling_steps"] = startup["settling_steps"]
    return m


def cost_metrics(cost: NDArray, jump_step: NDArray) -> dict[str, NDArray]:
    """The cost columns of a batch of episodes, from the per-step (charged) costs.

    Parameters
    ----------
    cost : ndarray, shape (B, T)
        Per-step costs of ``B`` episodes.
    jump_step : ndarray of int, shape (B,)
        Each episode's jump step (``-1``: none).

    Returns
    -------
    dict of str to ndarray, shape (B,)
        ``cost`` (mean per step), ``cost_start`` (steps ``[0, T/10)``), ``cost_steady`` (the
        second half, ``[T/2, T)``; before the jump ``[J/2, J)`` in an episode with one) and
        ``cost_post_jump`` (``[J, T)``: the whole re-adaptation; ``nan`` without a jump).

    Examples
    --------
    >>> import numpy as np
    >>> from stcgym.agents.evaluation.evaluate import cost_metrics
    >>> m = cost_metrics(np.arange(20.0).reshape(2, 10), np.array([-1, 6]))
    >>> m["cost"].tolist(), m["cost_steady"].tolist(), m["cost_post_jump"].tolist()
    ([4.5, 14.5], [7.0, 14.0], [nan, 17.5])
    """
    B, T = cost.shape
    out = {
        "cost": cost.mean(axis=1),
        "cost_start": cost[:, : max(1, T // 10)].mean(axis=1),
        "cost_steady": np.empty(B),
        "cost_post_jump": np.full(B, math.nan),
    }
    for i, J in enumerate(np.asarray(jump_step)):
        lo, hi = (T // 2, T) if J < 1 else (int(J) // 2, int(J))
        out["cost_steady"][i] = cost[i, lo:hi].mean()
        if J >= 1:
            out["cost_post_jump"][i] = cost[i, int(J) :].mean()
    return out


def response_metrics(batch: Any, spec: EnvSpec) -> dict[str, NDArray]:
    """The per-episode columns of a :class:`~stcgym.agents.evaluation.episodes.BatchEpisodes`
    that need the traces: ``effort`` (mean ``||u||^2``), ``bounded``, ``steps_run``,
    ``clip_frac``, ``step_us`` (predict time per lane and step), and the step response of
    the second half (``overshoot_pct``, ``settling_steps``) and of the first reference step
    (``startup_settling_steps``; one output only, :func:`~stcgym.agents.evaluation.response.
    step_response`); on a MIMO plant the tracking error per channel and the cross-channel
    disturbance (:func:`~stcgym.agents.evaluation.mimo.channel_metrics`)."""
    B, T = batch.cost.shape
    lived = np.maximum(batch.steps_run, 1)
    u = np.nan_to_num(batch.u.reshape(B, T, -1))
    out = {
        "effort": np.sum(u**2, axis=(1, 2)) / lived,
        "bounded": (~np.asarray(batch.diverged, dtype=bool)).astype(float),
        "steps_run": batch.steps_run.astype(float),
        "clip_frac": batch.n_clipped / lived,
        "step_us": np.full(B, 1e6 * batch.predict_s / (B * T)),
    }
    names = ("overshoot_pct", "settling_steps", "startup_settling_steps")
    for name in names:
        out[name] = np.full(B, math.nan)
    if batch.y.ndim == 2:  # one output: the step response
        first = max(2, spec.span)
        for i in range(B):
            steady = step_response(batch.y[i], batch.r[i], start=T // 2, stop=T + 1)
            start = step_response(batch.y[i], batch.r[i], start=0, stop=min(T + 1, first))
            out["overshoot_pct"][i] = steady["overshoot_pct"]
            out["settling_steps"][i] = steady["settling_steps"]
            out["startup_settling_steps"][i] = start["settling_steps"]
    elif spec.plant_kind == "mimo":  # several channels: tracking per channel, cross-coupling
        from stcgym.agents.evaluation.mimo import channel_metrics

        out.update(channel_metrics(batch.y, batch.r, spec.span))
    return out


@dataclass
class EvalResult:
    """Episodes and their metrics, in the order of the seeds.

    Parameters
    ----------
    episodes : list of Episode
        One per seed.
    metrics : list of dict
        The per-episode columns of ``metrics.csv`` (:func:`episode_metrics`), one per seed.

    Examples
    --------
    See :func:`evaluate`, which returns one.
    """

    episodes: list[Episode] = field(default_factory=list)
    metrics: list[dict[str, float]] = field(default_factory=list)


def evaluate(
    policy_factory: PolicyFactory,
    env_spec: EnvSpec,
    seeds: Sequence[int],
    steps: int | None = None,
    *,
    plant: str | None = None,
    windows: Windows | None = None,
    on_episode: Callable[[Episode, dict[str, float]], None] | None = None,
    record_theta: bool = False,
) -> EvalResult:
    """Evaluate one controller on ``env_spec`` for every seed.

    Parameters
    ----------
    policy_factory
        ``factory(plant_spec, seed) -> policy``, called once per episode after the reset (it
        may return the same object each time; it is reset). A plain policy object is accepted
        too.
    env_spec
        The scenario's environment.
    seeds
        Episode seeds; seed ``s`` means ``env.reset(seed=s)`` for every controller.
    steps
        Episode length; default ``env_spec.steps``.
    plant
        Family member to evaluate on (default: the environment's own draw).
    windows
        Cost windows; default :func:`default_windows`.
    on_episode
        Called after each episode with the episode and its metrics (the bench writes a CSV row
        there, so an interrupted run keeps what it finished).
    record_theta
        Keep the true and estimated parameters per step (:func:`run_episode`).

    Returns
    -------
    EvalResult
        The episodes and their metrics, in the order of ``seeds``.

    Raises
    ------
    ValueError
        From :class:`EnvSpec` (a bad ``steps``), the environment or the policy.

    Examples
    --------
    The known-model oracle on three seeds of ``unstable2``, summarised:

    >>> from stcgym.adaptive import KnownModelController
    >>> from stcgym.agents import EnvSpec, evaluate, summarize
    >>> spec = EnvSpec("unstable2", steps=200)
    >>> def oracle(plant, seed):
    ...     return KnownModelController(plant.a, plant.b, action_bound=spec.action_bound)
    >>> result = evaluate(oracle, spec, seeds=[0, 1, 2])
    >>> len(result.episodes), [round(m["cost"], 4) for m in result.metrics]
    (3, [0.1301, 0.1276, 0.1302])
    >>> costs = [m["cost"] for m in result.metrics]
    >>> stats = summarize(costs, [not m["bounded"] for m in result.metrics])
    >>> round(stats["median"], 4), stats["failure_rate"]
    (0.1301, 0.0)
    """
    if steps is not None and steps != env_spec.steps:
        env_spec = replace(env_spec, steps=int(steps))
    windows = windows or default_windows(env_spec.steps, env_spec.jump_step)
    result = EvalResult()
    for seed in seeds:
        ep = run_episode(
            policy_factory, env_spec, int(seed), plant=plant, record_theta=record_theta
        )
        metrics = episode_metrics(ep, windows, env_spec.period)
        result.episodes.append(ep)
        result.metrics.append(metrics)
        if on_episode is not None:
            on_episode(ep, metrics)
    return result
