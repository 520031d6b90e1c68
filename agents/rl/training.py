"""One RL training job of ``stcgym bench`` as a task: train, then evaluate where it is used.

A task is plain JSON data (:func:`training_task` builds it), so the bench hands it to the
executor of :mod:`stcgym.agents.executors` (a local process pool or Ray) and resumable stores
can key it by :func:`~stcgym.agents.executors.task_id`. :func:`train_and_evaluate` is the
module-level function the workers call: it trains the agent (learning curve on the validation
episodes, plateau rule), then runs it on every test episode of the scenarios that use it, one
batch of lanes per scenario. It returns plain data (the learning curve, how training stopped,
per-episode metrics that need the traces, a few traces for the plots) and writes the per-step
costs of every scenario next to the model (``costs_<scenario>.npy``, float32, ``(episodes,
steps)``, plain numpy data), from which the driver computes every cost figure; it writes
nothing else but the agent's own model folder and TensorBoard run.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from stcgym.agents.evaluation.env_spec import EnvSpec
from stcgym.agents.evaluation.episodes import EpisodeSet, run_episodes
from stcgym.agents.evaluation.evaluate import response_metrics
from stcgym.agents.rl.configs import AlgoConfig
from stcgym.agents.rl.learning_curve import summarise_updates
from stcgym.agents.rl.stopping import PlateauRule

__all__ = ["TRACE_EPISODES", "costs_file", "train_and_evaluate", "training_task"]

#: Episodes of each scenario whose traces come back for the plots.
TRACE_EPISODES = 2


def costs_file(scenario: str) -> str:
    """The file name of a scenario's per-step costs in an agent's model folder."""
    return "costs_" + scenario.replace(":", "-").replace("/", "-") + ".npy"


def training_task(
    *,
    algo: str,
    config: AlgoConfig,
    seed: int,
    steps: int,
    eval_interval: int,
    plateau: PlateauRule,
    train_key: str,
    train_env: EnvSpec,
    curve_env: EnvSpec,
    curve_episodes: EpisodeSet,
    curve_points: int,
    curve_reference: Sequence[float] | None,
    evaluations: Sequence[dict[str, Any]],
    model_dir: str,
    tensorboard_log: str | None,
    progress: bool | None = False,
) -> dict[str, Any]:
    """The JSON task of one (training env, agent, seed).

    ``steps`` is the cap: training stops earlier at the plateau of the learning curve
    (``plateau``, judged every ``eval_interval`` env steps on ``curve_episodes`` of
    ``curve_env``, scored against ``curve_reference``, the yardstick's cost per episode).
    ``evaluations`` are ``{"scenario", "env" (EnvSpec dict), "episodes" (EpisodeSet dict)}``:
    the scenarios that use this agent and their test episodes.
    """
    return {
        "name": f"{train_key.replace(':', '-')}_{algo}_s{seed}",
        "algo": algo,
        "config": config.to_dict(),
        "seed": int(seed),
        "steps": int(steps),
        "eval_interval": int(eval_interval),
        "plateau": plateau.to_dict(),
        "train_key": train_key,
        "train_env": train_env.to_dict(),
        "curve_env": curve_env.to_dict(),
        "curve_episodes": curve_episodes.to_dict(),
        "curve_points": int(curve_points),
        "curve_reference": None if curve_reference is None else [float(c) for c in curve_reference],
        "evaluations": list(evaluations),
        "model_dir": str(model_dir),
        "tensorboard_log": tensorboard_log,
        "progress": progress,
    }


def _traces(batch: Any, count: int) -> dict[str, Any]:
    k = min(count, batch.num_episodes)
    return {name: np.asarray(getattr(batch, name)[:k]).tolist() for name in ("y", "r", "u")}


def train_and_evaluate(task: dict[str, Any]) -> dict[str, Any]:
    """Train the agent of ``task`` and evaluate it on the task's scenarios (worker side)."""
    from stcgym.agents.rl.sb3 import train_agent

    config = AlgoConfig.from_dict(task["config"])
    folder = Path(task["model_dir"])
    agent = train_agent(
        task["algo"],
        config,
        EnvSpec.from_dict(task["train_env"]),
        task["steps"],
        task["seed"],
        out_dir=folder,
        curve_spec=EnvSpec.from_dict(task["curve_env"]),
        curve_episodes=EpisodeSet.from_dict(task["curve_episodes"]),
        curve_points=task["curve_points"],
        curve_reference=task["curve_reference"],
        plateau=PlateauRule(**task["plateau"]),
        eval_interval=task["eval_interval"],
        progress=task["progress"],
        tensorboard_log=task["tensorboard_log"],
        tb_log_name=task["name"],
    )
    evaluations = []
    for ev in task["evaluations"]:
        spec = EnvSpec.from_dict(ev["env"])
        batch = run_episodes(
            lambda plants, seeds: agent.policy.with_lanes(len(plants), seeds, plants),
            spec,
            EpisodeSet.from_dict(ev["episodes"]),
            informed=agent.policy.informed,
        )
        name = costs_file(ev["scenario"])
        np.save(folder / name, batch.cost.astype(np.float32), allow_pickle=False)
        metrics = response_metrics(batch, spec)
        evaluations.append(
            {
                "scenario": ev["scenario"],
                "costs": name,
                "jump_step": batch.jump_step.tolist(),
                "metrics": {k: v.tolist() for k, v in metrics.items()},
                "traces": _traces(batch, TRACE_EPISODES),
            }
        )
    return {
        "algo": agent.algo,
        "seed": agent.seed,
        "steps": agent.steps,
        "wall_s": agent.wall_s,
        "best_step": agent.best_step,
        "stop": agent.stop.to_dict(),
        "curve": [[int(s), float(c)] for s, c in agent.curve],
        "updates": agent.updates,
        "update_summary": summarise_updates(agent.updates),
        "evaluations": evaluations,
    }
