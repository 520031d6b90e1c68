"""Hyperparameter tuning on the validation split: the same Optuna budget for every RL agent and
for the self-tuning controller (the full tier; ``--tune-trials N``).

Each study runs ``N`` trials of Optuna's TPE sampler (seeded) and scores a trial by the median
cost ratio to the LQG yardstick on the training distribution's validation episodes, the score
the plateau rule reads; the test episodes are never seen. An RL trial trains the agent with the
sampled hyperparameters for a fraction of its cap (``tune_fraction``) and keeps its best
validation score; its first trial is the default recipe, and a trial whose PPO updates leave
the usual range (:func:`unhealthy`) fails, as a diverged one does: a short trial rewards steps
too large to last (a learning rate of 2.8e-3, picked without this rule, had median approx_kl
0.4-2.1 and left PPO at 8.7x LQG on L1, against 2.4-2.6x for the default recipe). A
self-tuning controller trial runs the controller with the sampled options on the same
validation episodes. The best trial's settings then train every run of the agent
(``BenchConfig.algo_configs``) and configure the tuned self-tuning controller ``stc_tuned``
(``BenchConfig.tuned``); ``config.json`` and the report keep every study's trials.

The search spaces (:func:`sample_rl`, :func:`sample_stc`) follow the RL Zoo's samplers where it
has one (learning rate, rollout length, discount, GAE, network size but for the PPO agents, whose
network is the ablation's; ``rl_zoo3/hyperparams_opt.py``)
and, for the self-tuning controller, span its documented options (closed-loop pole, forgetting
factor, probe amplitude, change-detection threshold, the estimator's measurement noise).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from stcgym.agents.benchmark.scenarios import TrainingEnv
from stcgym.agents.evaluation.env_spec import EnvSpec
from stcgym.agents.evaluation.episodes import EpisodeSet, run_episodes
from stcgym.agents.rl.configs import RECURRENT_ALGORITHMS, AlgoConfig, base_algorithm

__all__ = [
    "FAILED",
    "TuningTask",
    "apply_rl_params",
    "default_params",
    "sample_rl",
    "sample_stc",
    "stc_options",
    "tune_rl",
    "tune_stc",
    "unhealthy",
]


def sample_rl(trial: Any, algo: str) -> dict[str, Any]:
    """Sampled hyperparameters of ``algo``: ``{"hyperparams": {...}}``, with ``"net_width"``
    where the width is searched (not for the PPO agents) and ``"lstm_hidden_size"`` for the
    recurrent ones."""
    base = base_algorithm(algo)
    hp: dict[str, Any] = {
        # up to 1e-3: PPO's updates at 2.8e-3 had median approx_kl 0.4-2.1 on the family
        "learning_rate": trial.suggest_float("learning_rate", 1e-4, 1e-3, log=True),
        # the range of the seeded ablation behind the default (benchmarks/rl_ablation.py)
        "gamma": trial.suggest_categorical("gamma", [0.9, 0.95, 0.99]),
    }
    out: dict[str, Any] = {"hyperparams": hp}
    if base != "ppo":
        # the PPO agents' network is the ablation's (agents/rl/configs.py): a trial of a tenth
        # of the cap favours the small network that learns first, not the one that ends best
        out["net_width"] = trial.suggest_categorical("net_width", [64, 128])
    if base in ("sac", "td3"):
        hp["batch_size"] = trial.suggest_categorical("batch_size", [128, 256, 512])
        hp["tau"] = trial.suggest_categorical("tau", [0.005, 0.01, 0.02])
    else:
        hp["n_steps"] = trial.suggest_categorical("n_steps", [256, 512, 1024])
        hp["gae_lambda"] = trial.suggest_categorical("gae_lambda", [0.9, 0.95, 0.98])
    if algo in RECURRENT_ALGORITHMS:
        out["lstm_hidden_size"] = trial.suggest_categorical("lstm_hidden_size", [64, 128, 256])
    return out


def apply_rl_params(config: AlgoConfig, params: dict[str, Any]) -> AlgoConfig:
    """A copy of ``config`` with the sampled ``params`` of :func:`sample_rl` applied."""
    out = copy.deepcopy(config)
    out.hyperparams.update(params["hyperparams"])
    kwargs = dict(out.hyperparams.get("policy_kwargs", {}))
    width = params.get("net_width")
    if "lstm_hidden_size" in params:
        kwargs["lstm_hidden_size"] = int(params["lstm_hidden_size"])
    if width is not None:
        lstm = "lstm_hidden_size" in params
        kwargs["net_arch"] = {"pi": [width], "vf": [width]} if lstm else [width, width]
    out.hyperparams["policy_kwargs"] = kwargs
    # the evaluation interval stays a whole number of rollouts
    rollout = int(out.hyperparams.get("n_steps", 1)) * int(out.n_envs)
    out.eval_interval = max(rollout, (out.eval_interval // rollout) * rollout)
    return out


def sample_stc(trial: Any) -> dict[str, Any]:
    """Sampled options of the self-tuning controller (:func:`stc_options` turns them into its
    keyword arguments)."""
    return {
        "pole": trial.suggest_float("pole", 0.2, 0.85),
        "forgetting": trial.suggest_float("forgetting", 0.98, 1.0),
        "probe_amplitude": trial.suggest_float("probe_amplitude", 0.1, 1.0, log=True),
        "change_threshold": trial.suggest_float("change_threshold", 3.0, 10.0),
        "measurement_noise": trial.suggest_float("measurement_noise", 1.0, 100.0, log=True),
    }


def stc_options(params: dict[str, Any]) -> dict[str, Any]:
    """The :class:`~stcgym.adaptive.SelfTuningController` keyword arguments of
    :func:`sample_stc`'s ``params``."""
    return {
        "poles": float(params["pole"]),
        "estimator_options": {
            "forgetting": float(params["forgetting"]),
            "measurement_noise": float(params["measurement_noise"]),
        },
        "startup": {"probe_amplitude": float(params["probe_amplitude"])},
        "change_detection": {"threshold": float(params["change_threshold"])},
    }


def _study(seed: int) -> Any:
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    return optuna.create_study(direction="minimize", sampler=optuna.samplers.TPESampler(seed=seed))


def _summary(study: Any) -> dict[str, Any]:
    return {
        "best_value": float(study.best_value),
        "best_params": dict(study.best_params),
        "trials": [float(t.value) for t in study.trials if t.value is not None],
    }


@dataclass(frozen=True)
class TuningTask:
    """One RL agent's study, a job for the executor (the studies run side by side): ``trials``
    trials, each training ``algo`` from ``config`` with the sampled settings for ``steps`` env
    steps on ``train`` and scored on ``curve_episodes`` of ``curve`` against ``reference``,
    the yardstick's cost on each of them."""

    algo: str
    config: AlgoConfig
    train: EnvSpec
    curve: EnvSpec
    curve_episodes: EpisodeSet
    reference: tuple[float, ...]
    trials: int
    steps: int
    seed: int = 0

    @property
    def name(self) -> str:
        return f"tune_{self.algo}"


#: A trial whose updates leave the usual range by this factor (median approx_kl over 0.06,
#: clip fraction over 0.3) fails: its early score comes from steps too large to last.
UNHEALTHY_FACTOR = {"approx_kl": 2.0, "clip_fraction": 1.5}
#: The score of a failed trial (diverged, or unhealthy updates).
FAILED = 1e12


def unhealthy(updates: list[dict[str, float]]) -> list[str]:
    """The diagnostics whose median over ``updates`` is above :data:`UNHEALTHY_FACTOR` times
    the top of their usual range (:data:`~stcgym.agents.rl.learning_curve.HEALTHY`).

    Examples
    --------
    >>> from stcgym.agents.benchmark.tuning import unhealthy
    >>> unhealthy([{"approx_kl": 0.02, "clip_fraction": 0.2}] * 3)
    []
    >>> unhealthy([{"approx_kl": 0.4, "clip_fraction": 0.42}] * 3)
    ['approx_kl', 'clip_fraction']
    """
    from stcgym.agents.rl.learning_curve import HEALTHY, summarise_updates

    summary = summarise_updates(updates)
    return [
        name
        for name, factor in UNHEALTHY_FACTOR.items()
        if name in summary and summary[name]["median"] > factor * HEALTHY[name][1]
    ]


def default_params(config: AlgoConfig, algo: str) -> dict[str, Any]:
    """The settings of ``config`` in the search space of :func:`sample_rl` (Optuna's trial
    parameters), so that a study's first trial is the default recipe."""
    hp, base = config.hyperparams, base_algorithm(algo)
    out: dict[str, Any] = {"learning_rate": hp["learning_rate"], "gamma": hp["gamma"]}
    arch = hp.get("policy_kwargs", {}).get("net_arch")
    if base != "ppo" and arch is not None:
        out["net_width"] = (arch["pi"] if isinstance(arch, dict) else arch)[0]
    if base in ("sac", "td3"):
        out.update(batch_size=hp["batch_size"], tau=hp.get("tau", 0.005))
    else:
        out.update(n_steps=hp["n_steps"], gae_lambda=hp["gae_lambda"])
    if algo in RECURRENT_ALGORITHMS:
        out["lstm_hidden_size"] = hp["policy_kwargs"]["lstm_hidden_size"]
    return out


def tune_rl(task: TuningTask) -> dict[str, Any]:
    """One RL agent's study; returns its summary with the best trial's parameters
    (:func:`sample_rl` form). The first trial is the default recipe (:func:`default_params`),
    so a study keeps the defaults unless a trial scores better; a trial whose updates are
    unhealthy (:func:`unhealthy`) scores :data:`FAILED`."""
    from stcgym.agents.rl.learning_curve import CurveOptions
    from stcgym.agents.rl.sb3 import train_agent

    sampled: dict[int, dict[str, Any]] = {}

    def objective(trial: Any) -> float:
        params = sampled[trial.number] = sample_rl(trial, task.algo)
        curve = CurveOptions(task.curve, task.curve_episodes, 2, task.reference)
        agent = train_agent(
            task.algo, apply_rl_params(task.config, params), task.train, task.steps,
            task.seed + trial.number, curve=curve,
        )  # fmt: skip
        best = min(score for _, score in agent.curve)
        return FAILED if unhealthy(agent.updates) or not math.isfinite(best) else best

    study = _study(task.seed)
    study.enqueue_trial(default_params(task.config, task.algo))
    study.optimize(objective, n_trials=task.trials)
    return {**_summary(study), "params": sampled[study.best_trial.number]}


def tune_stc(cfg: Any, env: TrainingEnv, reference: list[float], trials: int, seed: int = 0):
    """The self-tuning controller's study on ``env``'s validation episodes (the same number of
    trials as each RL agent's); returns its summary with the best trial's parameters."""
    from stcgym.agents.controllers import self_tuning

    ref = np.asarray(reference, dtype=float)
    sampled: dict[int, dict[str, Any]] = {}
    sc = env.curve_scenario

    def objective(trial: Any) -> float:
        params = sampled[trial.number] = sample_stc(trial)
        builder = self_tuning(cfg, sc, **stc_options(params))
        shift = 7919 * trial.number  # every trial its own probe streams

        def lanes(plants: list[Any], seeds: list[int]) -> Any:
            return builder(plants, [int(s) + shift for s in seeds])

        batch = run_episodes(lanes, env.curve, env.curve_episodes)
        return float(np.median(batch.cost.mean(axis=1) / ref))

    study = _study(seed)
    study.optimize(objective, n_trials=int(trials))
    return {**_summary(study), "params": sampled[study.best_trial.number]}
