"""Stable-Baselines3 agents: training, saving/loading and the policy-protocol adapter.

Training (:func:`train_agent`) runs on ``n_envs`` copies of the scenario's environment behind
:class:`~stcgym.agents.wrappers.HistoryWindow` (the observation window) and
:class:`~stcgym.agents.wrappers.TrainingReward` (compressed per-step cost; a diverged episode
pays for the steps it did not live), each with a SB3 ``Monitor`` on the raw environment
(``monitor/*.monitor.csv``: raw episode returns). A callback evaluates the deterministic
policy every ``curve_every`` steps through the bench's own evaluation loop, so the learning
curve is on exactly the cost the bench reports.

A saved agent is a folder with ``model.zip`` (SB3) and ``agent.json`` (algorithm, config, seed,
window, training environment, steps, wall time, learning curve); :func:`load_agent` returns an
:class:`SB3Policy` ready for :func:`stcgym.agents.evaluate.evaluate`.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.agents.configs import AlgoConfig, algorithm_class
from stcgym.agents.evaluate import EnvSpec, run_episode
from stcgym.agents.wrappers import HistoryBuffer, HistoryWindow, TrainingReward, WindowConfig

__all__ = ["SB3Policy", "TrainedAgent", "load_agent", "train_agent", "curve_cost"]


class SB3Policy:
    """An SB3 model behind the shared policy protocol, fed with raw ``[y, r]`` observations.

    The model was trained on :class:`~stcgym.agents.wrappers.HistoryWindow` features; this
    adapter rebuilds them itself from the raw observations it is given and the actions it
    returned (a :class:`~stcgym.agents.wrappers.HistoryBuffer` per batch lane), and rescales the
    model's ``[-1, 1]`` action to ``[-action_bound, action_bound]``. ``episode_start`` (or
    :meth:`reset`) starts a new window.

    Parameters
    ----------
    model
        A trained SB3 model (``predict`` on the window features).
    window
        The :class:`~stcgym.agents.wrappers.WindowConfig` the model was trained with.
    action_bound
        The environment's action bound.
    """

    def __init__(self, model: Any, window: WindowConfig, action_bound: float) -> None:
        self.model, self.window, self.action_bound = model, window, float(action_bound)
        self._buf: HistoryBuffer | None = None

    def reset(self) -> None:
        """Forget the window (the next observation starts an episode)."""
        self._buf = None

    def predict(
        self,
        observation: ArrayLike,
        state: Any = None,
        episode_start: ArrayLike | bool | None = None,
        deterministic: bool = True,
    ) -> tuple[NDArray, Any]:
        """SB3-style step on ``[y, r]`` (shape ``(2,)``) or a batch ``(B, 2)``."""
        obs = np.asarray(observation, dtype=float)
        single = obs.ndim == 1
        obs = obs.reshape(-1, 2)
        batch = obs.shape[0]
        if not np.all(np.isfinite(obs)):
            raise ValueError(f"observation must be finite, got {observation!r}")
        starts = (
            np.zeros(batch, bool)
            if episode_start is None
            else np.broadcast_to(np.asarray(episode_start, bool).reshape(-1), (batch,))
        )
        if self._buf is None or self._buf.batch != batch:
            self._buf = HistoryBuffer(self.window, self.action_bound, batch)
            starts = np.ones(batch, bool)
        if np.any(starts):
            self._buf.start(obs, starts)
        if not np.all(starts):
            self._buf.push_obs(obs, ~starts)
        a, _ = self.model.predict(self._buf.features(), deterministic=deterministic)
        u = np.clip(np.asarray(a, dtype=float).reshape(batch), -1.0, 1.0) * self.action_bound
        self._buf.push_action(u)
        return (u.reshape(1) if single else u.reshape(batch, 1)), state


@dataclass
class TrainedAgent:
    """A trained model and what the bench reports about its training."""

    algo: str
    policy: SB3Policy
    config: AlgoConfig
    seed: int
    train_spec: EnvSpec
    steps: int  # environment steps actually used (all training envs together)
    wall_s: float
    curve: list[tuple[int, float]] = field(default_factory=list)
    path: Path | None = None
    #: training step of the kept checkpoint (``steps`` unless ``keep_best`` picked an earlier one)
    best_step: int | None = None


def curve_cost(policy: Any, spec: EnvSpec, seeds: Sequence[int], plants: Sequence[str]) -> float:
    """Mean cost per step over ``seeds`` x ``plants`` (the learning-curve metric)."""
    costs = [
        float(np.mean(run_episode(policy, spec, s, plant=p).cost)) for p in plants for s in seeds
    ]
    return float(np.mean(costs))


def _progress_bar_wanted(progress: bool | None) -> bool:
    if progress is not None:
        return progress
    # SB3's rich bar redraws in place; piped into a log file it only adds noise.
    return sys.stderr.isatty()


def _make_callback(
    curve: list, policy: SB3Policy, every: int, evaluate_curve: Any, keep_best: bool
) -> Any:
    import copy

    from stable_baselines3.common.callbacks import BaseCallback

    class _Curve(BaseCallback):
        # Recorded at the start of a rollout, i.e. right after the previous policy update (PPO
        # collects n_steps x n_envs before it learns; SAC/TD3 update after every rollout).
        def _on_training_start(self) -> None:
            self.best_cost, self.best_state, self.best_step = float("inf"), None, 0
            self._record()

        def _record(self) -> None:
            cost = evaluate_curve(policy)
            curve.append((int(self.num_timesteps), cost))
            self._next = self.num_timesteps + every
            if keep_best and cost < self.best_cost:
                self.best_cost, self.best_step = cost, int(self.num_timesteps)
                self.best_state = copy.deepcopy(self.model.policy.state_dict())

        def _on_rollout_start(self) -> None:
            if self.num_timesteps >= self._next:
                self._record()

        def _on_step(self) -> bool:
            return True

        def _on_training_end(self) -> None:
            if curve[-1][0] != self.num_timesteps:
                self._record()
            if keep_best and self.best_state is not None and self.best_cost < curve[-1][1]:
                self.model.policy.load_state_dict(self.best_state)
            else:
                self.best_step = int(self.num_timesteps)

    return _Curve()


def train_agent(
    algo: str,
    config: AlgoConfig,
    train_spec: EnvSpec,
    steps: int,
    seed: int,
    *,
    out_dir: str | Path | None = None,
    curve_spec: EnvSpec | None = None,
    curve_plants: Sequence[str] | None = None,
    curve_seeds: Sequence[int] = (10_000, 10_001),
    curve_points: int = 10,
    keep_best: bool = True,
    progress: bool | None = None,
) -> TrainedAgent:
    """Train one agent.

    Parameters
    ----------
    algo
        ``"ppo"``, ``"sac"``, ``"td3"`` or ``"a2c"``.
    config
        Its :class:`~stcgym.agents.configs.AlgoConfig`.
    train_spec
        Training environment (a single plant, or a family drawn per episode).
    steps
        Environment steps of training (``> 0``).
    seed
        Seeds SB3 (network init, exploration) and the training environments.
    out_dir
        Where to save ``model.zip``, ``agent.json`` and the monitor logs (nothing saved when
        ``None``).
    curve_spec, curve_plants, curve_seeds, curve_points
        Learning curve: every ``steps / curve_points`` steps the deterministic policy runs one
        episode of ``curve_spec`` (default ``train_spec``) per seed and plant (default the
        training plants); the mean cost per step is recorded.
    keep_best
        Keep the checkpoint with the lowest learning-curve cost rather than the last one (RL
        Zoo's ``EvalCallback`` best model). The curve episodes use their own seeds, so this is
        model selection on validation episodes, not on the bench's evaluation episodes.
    progress
        SB3's progress bar; default on when stderr is a terminal.
    """
    import torch
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.noise import NormalActionNoise
    from stable_baselines3.common.vec_env import VecNormalize

    if int(steps) != steps or steps < 1:
        raise ValueError(f"training steps must be a positive integer, got {steps!r}")
    # Small MLPs: one thread is faster than two fighting over a shared 2-core machine.
    torch.set_num_threads(1)
    window = WindowConfig(**config.window)
    out = None if out_dir is None else Path(out_dir)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)

    def wrap(env: Any) -> Any:
        env = HistoryWindow(env, window)
        return TrainingReward(env, train_spec.steps, config.reward_scale, config.cost_squash)

    vec = make_vec_env(
        train_spec.make,
        n_envs=int(config.n_envs),
        seed=int(seed),
        monitor_dir=None if out is None else str(out / "monitor"),
        wrapper_class=wrap,
    )
    if config.normalize_reward:
        vec = VecNormalize(
            vec, norm_obs=False, norm_reward=True, gamma=config.hyperparams.get("gamma", 0.99)
        )
    kwargs = dict(config.hyperparams)
    if config.noise_std > 0:
        kwargs["action_noise"] = NormalActionNoise(np.zeros(1), config.noise_std * np.ones(1))
    model = algorithm_class(algo)(config.policy, vec, seed=int(seed), device="cpu", **kwargs)

    policy = SB3Policy(model, window, train_spec.action_bound)
    cspec = curve_spec or train_spec
    cplants = list(curve_plants or train_spec.plants)
    curve: list[tuple[int, float]] = []
    callback = _make_callback(
        curve,
        policy,
        max(1, int(steps) // max(1, curve_points)),
        lambda p: curve_cost(p, cspec, curve_seeds, cplants),
        keep_best,
    )
    t0 = time.perf_counter()
    model.learn(int(steps), callback=callback, progress_bar=_progress_bar_wanted(progress))
    wall = time.perf_counter() - t0
    vec.close()
    # PPO/A2C finish their last rollout, so the steps used can exceed the budget asked for.
    used = int(model.num_timesteps)
    agent = TrainedAgent(
        algo, policy, config, int(seed), train_spec, used, wall, curve, out, callback.best_step
    )
    if out is not None:
        save_agent(agent, out)
    return agent


def save_agent(agent: TrainedAgent, folder: str | Path) -> Path:
    """Write ``model.zip`` and ``agent.json`` into ``folder``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    agent.policy.model.save(folder / "model.zip")
    meta = {
        "algo": agent.algo,
        "seed": agent.seed,
        "steps": agent.steps,
        "wall_s": agent.wall_s,
        "config": agent.config.to_dict(),
        "window": agent.policy.window.to_dict(),
        "action_bound": agent.policy.action_bound,
        "train_spec": agent.train_spec.to_dict(),
        "curve": [list(p) for p in agent.curve],
        "best_step": agent.best_step,
    }
    (folder / "agent.json").write_text(json.dumps(meta, indent=2))
    return folder


def load_agent(folder: str | Path) -> TrainedAgent:
    """Reload an agent saved by :func:`train_agent` (``folder`` holds ``agent.json``)."""
    folder = Path(folder)
    meta_file = folder / "agent.json"
    if not meta_file.is_file():
        raise FileNotFoundError(f"{folder} holds no agent.json (not a saved stcgym agent)")
    meta = json.loads(meta_file.read_text())
    model = algorithm_class(meta["algo"]).load(folder / "model.zip", device="cpu")
    window = WindowConfig(**meta["window"])
    policy = SB3Policy(model, window, meta["action_bound"])
    spec = meta["train_spec"]
    spec["plants"] = tuple(spec["plants"])
    return TrainedAgent(
        meta["algo"],
        policy,
        AlgoConfig.from_dict(meta["config"]),
        meta["seed"],
        EnvSpec(**spec),
        meta["steps"],
        meta["wall_s"],
        [tuple(p) for p in meta["curve"]],
        folder,
        meta.get("best_step"),
    )
