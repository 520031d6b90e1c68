"""Stable-Baselines3 agents: training, saving/loading and the policy-protocol adapter.

Training (:func:`train_agent`) runs on ``n_envs`` lanes of the scenario's native vector
environment (:meth:`~stcgym.agents.evaluation.env_spec.EnvSpec.make_vec`, one compiled step for
all lanes) behind SB3's ``VecMonitor`` (``monitor.csv``: raw episode returns, the scored cost),
:class:`~stcgym.agents.rl.vec_env.VecHistoryWindow` (the observation window and the training
reward: the scored per-step cost, a diverged episode charged for the steps it did not live) and
SB3's ``VecNormalize`` (observation normalisation and a running reward scale, as the RL Zoo's
``normalize``). A callback evaluates the deterministic policy at log-spaced training steps
through the bench's own evaluation loop on fixed validation episodes, so the learning curve is
on the score the bench reports (:mod:`stcgym.agents.rl.learning_curve`); the curve also goes
through SB3's logger (TensorBoard with ``tensorboard_log``). Recurrent agents (sb3-contrib
``RecurrentPPO``) go through the same code; :class:`~stcgym.agents.rl.policy.SB3Policy`
carries their LSTM state.

A saved agent is a folder with ``model.zip`` (SB3) and ``agent.json`` (algorithm, config, seed,
window, the observation normaliser's statistics, training environment, steps, wall time,
learning curve); :func:`load_agent` returns an :class:`~stcgym.agents.rl.policy.SB3Policy` ready for
:func:`stcgym.agents.evaluation.evaluate.evaluate`.
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

from stcgym.agents.evaluation.env_spec import EnvSpec
from stcgym.agents.evaluation.episodes import EpisodeSet
from stcgym.agents.rl.configs import AlgoConfig, algorithm_class, with_action_unit
from stcgym.agents.rl.interfaces import InterfaceSpec
from stcgym.agents.rl.learning_curve import (
    CurveOptions,
    curve_checkpoints,
    curve_cost,
    make_curve_callback,
)
from stcgym.agents.rl.policy import ObsNorm, SB3Policy
from stcgym.agents.rl.stopping import StopSummary
from stcgym.agents.rl.wrappers import WindowConfig

__all__ = [
    "TrainedAgent",
    "build_model",
    "check_trainable",
    "curve_checkpoints",
    "curve_cost",
    "load_agent",
    "improved_on_start",
    "measured_action_unit",
    "train_agent",
]


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
    #: how training ended (with a plateau rule; ``None`` for a fixed budget)
    stop: StopSummary | None = None
    #: the health of each policy update (:func:`~stcgym.agents.rl.learning_curve.update_record`)
    updates: list[dict[str, float]] = field(default_factory=list)


def _progress_bar_wanted(progress: bool | None) -> bool:
    if progress is not None:
        return progress
    # SB3's rich bar redraws in place; piped into a log file it only adds noise.
    return sys.stderr.isatty()


def interface_of(config: AlgoConfig, train_spec: EnvSpec, seed: int) -> InterfaceSpec:
    """The interface of an agent of ``config`` trained on ``train_spec`` with ``seed``: told
    the training distribution's order, its run the seed."""
    order = train_spec.order if config.interface.get("kind", "window") != "window" else None
    return InterfaceSpec.of(config.interface, order, seed)


def _training_env(config: AlgoConfig, train_spec: EnvSpec, seed: int, monitor: Any) -> Any:
    """``n_envs`` lanes of the native vector env of ``train_spec``, seeded ``seed + i``,
    behind ``VecMonitor`` (raw returns into the file ``monitor``), the window, the agent's
    interface and the training reward (:class:`~stcgym.agents.rl.vec_env.VecHistoryWindow`;
    ``config.reward``: :mod:`stcgym.agents.rl.reward`) and ``VecNormalize``."""
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from stcgym.agents.rl.vec_env import SB3VecEnv, VecHistoryWindow

    window = WindowConfig(**config.window)
    lanes = SB3VecEnv(train_spec.make_vec(int(config.n_envs), info_keys=()))
    lanes.seed(int(seed))
    vec = VecMonitor(lanes, filename=monitor)
    score = {}
    if config.reward == "lqg_ratio" and train_spec.plant_kind == "siso":
        from stcgym.agents.rl.reward import plant_lqg_costs

        native = lanes.venv
        score = dict(
            plant_costs=plant_lqg_costs(train_spec),
            plant_index=lambda: native.plant_index,
            cost_cap=config.cost_cap,
        )
    interface = interface_of(config, train_spec, seed)
    if interface.kind == "true":  # the lanes' true parameters, read after every step
        native_params = lanes.venv
        score["true_params"] = lambda: native_params.params
    vec = VecHistoryWindow(
        vec, window, train_spec.steps, config.reward_scale, config.cost_squash,
        interface=interface, **score,
    )  # fmt: skip
    if config.normalize_obs or config.normalize_reward:
        vec = VecNormalize(
            vec,
            norm_obs=config.normalize_obs,
            norm_reward=config.normalize_reward,
            clip_obs=window.obs_clip,
            gamma=config.hyperparams.get("gamma", 0.99),
        )
    return vec


def build_model(
    algo: str,
    config: AlgoConfig,
    vec: Any,
    seed: int,
    *,
    tensorboard_log: str | None = None,
    hyperparams: dict[str, Any] | None = None,
) -> Any:
    """The SB3 / sb3-contrib model of ``config`` on the vector env ``vec`` (CPU).

    A residual agent's policy starts with a mean action of exactly zero: the last layer of
    its mean (PPO's ``action_net``, SAC's and TD3's ``actor.mu``) is zeroed, so the
    deterministic agent starts as the controller it corrects and learns from there (the
    layer's gradient does not vanish: its input, the last hidden layer, is not zero).
    """
    from stable_baselines3.common.noise import NormalActionNoise

    kwargs = dict(config.hyperparams if hyperparams is None else hyperparams)
    if config.noise_std > 0:
        dim = vec.action_space.shape[0]
        kwargs["action_noise"] = NormalActionNoise(np.zeros(dim), config.noise_std * np.ones(dim))
    model = algorithm_class(algo)(
        config.policy,
        vec,
        seed=int(seed),
        device="cpu",
        tensorboard_log=tensorboard_log,
        **kwargs,
    )
    if config.interface.get("kind") == "residual":
        _zero_mean_action(model.policy)
    return model


def _zero_mean_action(policy: Any) -> None:
    """Zero the layer that outputs the policy's mean action (and its target copy)."""
    import torch

    layers = [getattr(policy, "action_net", None)]
    for actor in ("actor", "actor_target"):
        layers.append(getattr(getattr(policy, actor, None), "mu", None))
    layers = [layer for layer in layers if layer is not None]
    if not layers:
        raise ValueError(f"{type(policy).__name__} has no mean-action layer to start at zero")
    with torch.no_grad():
        for layer in layers:
            linear = [m for m in layer.modules() if isinstance(m, torch.nn.Linear)]
            last = linear[-1]  # (TD3's mu ends with a tanh)
            last.weight.zero_()
            last.bias.zero_()


#: Training episodes :func:`measured_action_unit` runs LQG on.
UNIT_EPISODES = 20


def measured_action_unit(config: AlgoConfig, train_spec: EnvSpec) -> AlgoConfig:
    """``config`` with its action unit measured where it asks for it (``"lqg"``): the
    :func:`~stcgym.agents.evaluation.bounds.lqg_action_unit` of the LQG controller's inputs
    on :data:`UNIT_EPISODES` training episodes of ``train_spec`` (seeds from the bench's
    ``BOUND_SEED``). The bench measures it on its own bound episodes before it trains."""
    from stcgym.agents.evaluation.bounds import BOUND_SEED, lqg_action_unit, lqg_inputs
    from stcgym.agents.rl.interfaces import MEASURED_UNIT

    if config.interface.get("action_unit") != MEASURED_UNIT:
        return config
    names = train_spec.plant_names()[:UNIT_EPISODES]
    per_plant = -(-UNIT_EPISODES // len(names))
    episodes = EpisodeSet.of(train_spec, per_plant, BOUND_SEED, UNIT_EPISODES)
    return with_action_unit(config, lqg_action_unit(lqg_inputs(train_spec, episodes)))


def check_trainable(algo: str, config: AlgoConfig, train_spec: EnvSpec) -> None:
    """Build (and discard) the model of ``config``, so SB3's own checks run before any work.

    Catches what the value rules of :mod:`stcgym.agents.rl.configs` cannot see, such as a
    ``policy_kwargs`` entry the policy class does not take. Raises ``ValueError``. The replay
    buffer is built with at most 1000 entries (its size was checked already).
    """
    import torch

    torch.set_num_threads(1)
    config = with_action_unit(config, train_spec.action_bound)  # any unit will do for a check
    hp = dict(config.hyperparams)
    if "buffer_size" in hp or algo in ("sac", "td3"):
        hp["buffer_size"] = min(int(hp.get("buffer_size", 1000)), 1000)
    vec = _training_env(config, train_spec, 0, None)
    try:
        build_model(algo, config, vec, 0, hyperparams=hp)
    except (TypeError, ValueError, AssertionError, KeyError) as exc:
        raise ValueError(f"{algo}: SB3 rejects the configuration: {exc}") from None
    finally:
        vec.close()


def train_agent(
    algo: str,
    config: AlgoConfig,
    train_spec: EnvSpec,
    steps: int,
    seed: int,
    *,
    curve: CurveOptions | None = None,
    out_dir: str | Path | None = None,
    progress: bool | None = None,
    tensorboard_log: str | Path | None = None,
    tb_log_name: str | None = None,
) -> TrainedAgent:
    """Train one agent.

    Parameters
    ----------
    algo
        ``"ppo"``, ``"sac"``, ``"td3"``, ``"a2c"`` or ``"rppo"`` (sb3-contrib RecurrentPPO).
    config
        Its :class:`~stcgym.agents.rl.configs.AlgoConfig`; an action unit it asks to be
        measured (``"lqg"``) is measured first (:func:`measured_action_unit`).
    train_spec
        Training environment (catalogue plants, or a family split drawn per episode).
    steps
        Environment steps of training (``> 0``): the budget, or the cap with ``plateau``.
    seed
        Seeds SB3 (network init, exploration) and the training lanes (``seed + i``).
    curve
        The learning curve, the checkpoint kept and the plateau rule
        (:class:`~stcgym.agents.rl.learning_curve.CurveOptions`; ``None``: its defaults, ten
        points on two episodes per plant of ``train_spec``, the best checkpoint kept, no
        plateau rule). Its episodes are validation episodes, never the bench's test episodes.
    out_dir
        Where to save ``model.zip``, ``agent.json`` and ``monitor.csv`` (nothing saved when
        ``None``).
    progress
        SB3's progress bar; default on when stderr is a terminal.
    tensorboard_log, tb_log_name
        TensorBoard folder and run name: SB3's training statistics and the learning curve
        (``eval/curve_score``) are written there.

    Returns
    -------
    TrainedAgent
        The policy (an :class:`SB3Policy` for one env), its config, seed, training spec, steps
        used, wall time, learning curve ``[(step, score), ...]``, folder, kept step and stop
        summary.

    Raises
    ------
    ValueError
        ``steps`` not a positive integer, or a plateau rule's interval that exceeds ``steps``;
        an unknown ``algo`` or a config value its rule rejects.

    Examples
    --------
    A deliberately tiny PPO run (128 steps) saved and reloaded:

    >>> import tempfile
    >>> import numpy as np
    >>> from stcgym.agents import CurveOptions, EnvSpec, default_config, load_agent, train_agent
    >>> config = default_config("ppo")
    >>> config.n_envs = 1
    >>> config.hyperparams.update(n_steps=64, batch_size=64)
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     agent = train_agent("ppo", config, EnvSpec("stable2", steps=100), 128, seed=0,
    ...                         curve=CurveOptions(points=2), out_dir=folder)
    ...     again = load_agent(folder)
    >>> agent.algo, agent.steps, [step for step, cost in agent.curve]
    ('ppo', 128, [0, 64, 128])
    >>> agent.policy.reset()
    >>> obs = np.array([0.2, 1.0])
    >>> np.allclose(agent.policy.predict(obs)[0], again.policy.predict(obs)[0])
    True
    """
    import torch

    if int(steps) != steps or steps < 1:
        raise ValueError(f"training steps must be a positive integer, got {steps!r}")
    curve_options = CurveOptions() if curve is None else curve
    plateau, eval_interval = curve_options.plateau, curve_options.interval
    if plateau is not None and eval_interval > steps:
        raise ValueError(
            f"the cap of {steps} steps is below one evaluation interval ({eval_interval})"
        )
    # Small MLPs: one thread is faster than two fighting over a shared 2-core machine.
    torch.set_num_threads(1)
    config = measured_action_unit(config, train_spec)
    window = WindowConfig(**config.window)
    out = None if out_dir is None else Path(out_dir)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    vec = _training_env(config, train_spec, seed, None if out is None else str(out / "monitor"))
    tb = None if tensorboard_log is None else str(tensorboard_log)
    model = build_model(algo, config, vec, seed, tensorboard_log=tb)
    normaliser = vec if getattr(vec, "norm_obs", False) else None

    cspec = curve_options.spec or train_spec
    episodes = curve_options.episodes or EpisodeSet.of(cspec, 2, 10_000, max_plants=20)
    reference = curve_options.reference
    lanes = SB3Policy(
        model, window, train_spec.action_bound, None, train_spec.channels,
        interface=interface_of(config, train_spec, seed),
    ).with_lanes(len(episodes.seeds), episodes.seeds)  # fmt: skip

    def snapshot() -> ObsNorm | None:
        # the policy evaluated (and kept) is the network with the statistics of that moment
        lanes.obs_norm = None if normaliser is None else ObsNorm.of(normaliser)
        return lanes.obs_norm

    def restore(norm: ObsNorm | None) -> None:
        lanes.obs_norm = norm

    scores: list[tuple[int, float]] = []  # the learning curve
    updates: list[dict[str, float]] = []
    if lanes.informed:  # told the plants the episodes start on, and every jump

        def measure(p: SB3Policy) -> float:
            def builder(plants: list[Any], seeds: list[int]) -> SB3Policy:
                return p.with_lanes(len(plants), seeds, plants)

            return curve_cost(builder, cspec, episodes, reference, informed=True)
    else:

        def measure(p: SB3Policy) -> float:
            return curve_cost(p, cspec, episodes, reference)

    callback = make_curve_callback(
        scores,
        lanes,
        curve_checkpoints(int(steps), curve_options.points, eval_interval if plateau else None),
        measure,
        curve_options.keep_best,
        plateau,
        eval_interval,
        int(steps),
        snapshot,
        restore,
        updates,
    )
    t0 = time.perf_counter()
    model.learn(
        int(steps),
        callback=callback,
        progress_bar=_progress_bar_wanted(progress),
        tb_log_name=tb_log_name or algo.upper(),
    )
    wall = time.perf_counter() - t0
    vec.close()
    # PPO/A2C finish their last rollout, so the steps used can exceed the budget asked for.
    used = int(model.num_timesteps)
    stop = None
    if plateau is not None:
        status = "cap" if callback.stopped_at is None else "plateau"
        stop = callback.tracker.summary(status, used, int(steps), eval_interval)
        stop.best_step, stop.improved = (
            callback.best_step,
            improved_on_start(scores, callback.best_step),
        )
    agent = TrainedAgent(
        algo,
        lanes.with_lanes(None),
        config,
        int(seed),
        train_spec,
        used,
        wall,
        scores,
        out,
        callback.best_step,
        stop,
        updates,
    )
    if out is not None:
        save_agent(agent, out)
    return agent


def improved_on_start(curve: Sequence[tuple[int, float]], kept_step: int) -> bool:
    """Whether the checkpoint kept at ``kept_step`` scores below the untrained policy (the
    curve's step 0): ``False`` for a run kept at step 0, or one whose kept score (its last
    evaluation at or before ``kept_step``) is not lower.

    Examples
    --------
    >>> from stcgym.agents.rl.sb3 import improved_on_start
    >>> improved_on_start([(0, 10.0), (100, 8.0)], 100), improved_on_start([(0, 10.0)], 0)
    (True, False)
    """
    scores = dict(curve)
    measured = [step for step in scores if step <= kept_step]
    if kept_step <= 0 or 0 not in scores or not measured:
        return False
    # a run stopped by the rule ends a step or two after its last evaluation
    return bool(scores[max(measured)] < scores[0])


def save_agent(agent: TrainedAgent, folder: str | Path) -> Path:
    """Write ``model.zip`` and ``agent.json`` into ``folder``."""
    from stcgym.agents.executors import write_atomic

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    agent.policy.model.save(folder / "model.zip")
    norm = agent.policy.obs_norm
    meta = {
        "algo": agent.algo,
        "seed": agent.seed,
        "steps": agent.steps,
        "wall_s": agent.wall_s,
        "config": agent.config.to_dict(),
        "window": agent.policy.window.to_dict(),
        "obs_norm": None if norm is None else norm.to_dict(),
        "action_bound": agent.policy.action_bound,
        "channels": list(agent.policy.channels),
        "interface": agent.policy.interface.to_dict(),
        "train_spec": agent.train_spec.to_dict(),
        "curve": [list(p) for p in agent.curve],
        "best_step": agent.best_step,
        "stop": None if agent.stop is None else agent.stop.to_dict(),
        "updates": agent.updates,
    }
    write_atomic(folder / "agent.json", json.dumps(meta, indent=2))
    return folder


def load_agent(folder: str | Path) -> TrainedAgent:
    """Reload an agent saved by :func:`train_agent` (``folder`` holds ``agent.json``).

    The model file is a Stable-Baselines3 zip, which holds pickles: load agents from trusted
    sources only.

    Parameters
    ----------
    folder : str or pathlib.Path
        The ``out_dir`` of :func:`train_agent` (``agent.json`` and ``model.zip``).

    Returns
    -------
    TrainedAgent
        As :func:`train_agent` returned it, with the model loaded on the CPU.

    Raises
    ------
    FileNotFoundError
        ``folder`` holds no ``agent.json`` (or no ``model.zip``).

    Examples
    --------
    See :func:`train_agent` for a save and reload;

    >>> from stcgym.agents import load_agent
    >>> load_agent("no/such/folder")
    Traceback (most recent call last):
    ...
    FileNotFoundError: no/such/folder holds no agent.json (not a saved stcgym agent)
    """
    folder = Path(folder)
    meta_file = folder / "agent.json"
    if not meta_file.is_file():
        raise FileNotFoundError(f"{folder} holds no agent.json (not a saved stcgym agent)")
    meta = json.loads(meta_file.read_text())
    model = algorithm_class(meta["algo"]).load(folder / "model.zip", device="cpu")
    window = WindowConfig(**meta["window"])
    channels = tuple(meta.get("channels", (1, 1)))
    norm = ObsNorm.from_dict(meta.get("obs_norm"))
    interface = InterfaceSpec.from_dict(meta.get("interface"))
    policy = SB3Policy(
        model, window, meta["action_bound"], channels=channels, obs_norm=norm,
        interface=interface,
    )  # fmt: skip
    return TrainedAgent(
        meta["algo"],
        policy,
        AlgoConfig.from_dict(meta["config"]),
        meta["seed"],
        EnvSpec.from_dict(meta["train_spec"]),
        meta["steps"],
        meta["wall_s"],
        [tuple(p) for p in meta["curve"]],
        folder,
        meta.get("best_step"),
        None if meta.get("stop") is None else StopSummary(**meta["stop"]),
        meta.get("updates", []),
    )
