"""One RL training job of ``stcgym bench`` as a task: train, then evaluate where it is used.

A task is a typed record (:class:`TrainingTask`, whose :meth:`~TrainingTask.to_dict` is the JSON
data its id hashes), so the bench hands it to the executor of :mod:`stcgym.agents.executors` (a
local process pool or Ray) and the results store keys it by its settings.
:func:`train_and_evaluate` is the module-level function the workers call: it trains the agent
(learning curve on the validation episodes, plateau rule), then runs it on every test episode
of the scenarios that use it, one batch of lanes per scenario. It returns a
:class:`TrainingResult` (the learning curve, how training stopped, per-episode metrics that
need the traces, a few traces for the plots) and writes the per-step
costs of every scenario next to the model (``costs_<scenario>.npy``, float32, ``(episodes,
steps)``, plain numpy data), from which the driver computes every cost figure; it writes
nothing else but the agent's own model folder and TensorBoard run.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from stcgym.agents.evaluation.env_spec import EnvSpec
from stcgym.agents.evaluation.episodes import EpisodeSet, run_episodes
from stcgym.agents.evaluation.evaluate import response_metrics
from stcgym.agents.rl.configs import AlgoConfig
from stcgym.agents.rl.stopping import PlateauRule

__all__ = [
    "TRACE_EPISODES",
    "Evaluation",
    "EvaluationResult",
    "TrainingResult",
    "TrainingTask",
    "costs_file",
    "train_and_evaluate",
]

#: Episodes of each scenario whose traces come back for the plots.
TRACE_EPISODES = 2


def costs_file(scenario: str) -> str:
    """The file name of a scenario's per-step costs in an agent's model folder."""
    return "costs_" + scenario.replace(":", "-").replace("/", "-") + ".npy"


@dataclass(frozen=True)
class Evaluation:
    """A scenario that uses the trained agent: its name, env and test episodes."""

    scenario: str
    env: EnvSpec
    episodes: EpisodeSet

    def to_dict(self) -> dict[str, Any]:
        return {"scenario": self.scenario, "env": self.env.to_dict(),
                "episodes": self.episodes.to_dict()}  # fmt: skip


@dataclass(frozen=True)
class TrainingTask:
    """One (training env, agent, seed) job: train, then evaluate where the agent is used.

    ``steps`` is the cap: training stops earlier at the plateau of the learning curve
    (``plateau``, judged every ``eval_interval`` env steps on ``curve_episodes`` of
    ``curve_env``, scored against ``curve_reference``, the yardstick's cost per episode).
    ``evaluations``: the scenarios that use this agent, with their test episodes.
    :meth:`to_dict` is the task as JSON data, what its id hashes
    (:func:`~stcgym.agents.benchmark.rundir.job_id`).
    """

    algo: str
    config: AlgoConfig
    seed: int
    steps: int
    eval_interval: int
    plateau: PlateauRule
    train_key: str
    train_env: EnvSpec
    curve_env: EnvSpec
    curve_episodes: EpisodeSet
    curve_points: int
    curve_reference: tuple[float, ...] | None
    evaluations: tuple[Evaluation, ...]
    model_dir: str
    tensorboard_log: str | None = None
    progress: bool | None = False

    @property
    def name(self) -> str:
        """``<train key>_<algo>_s<seed>``, the job's label (``:`` written ``-``)."""
        return f"{self.train_key.replace(':', '-')}_{self.algo}_s{self.seed}"

    def to_dict(self) -> dict[str, Any]:
        reference = self.curve_reference
        return {
            "name": self.name,
            "algo": self.algo,
            "config": self.config.to_dict(),
            "seed": int(self.seed),
            "steps": int(self.steps),
            "eval_interval": int(self.eval_interval),
            "plateau": self.plateau.to_dict(),
            "train_key": self.train_key,
            "train_env": self.train_env.to_dict(),
            "curve_env": self.curve_env.to_dict(),
            "curve_episodes": self.curve_episodes.to_dict(),
            "curve_points": int(self.curve_points),
            "curve_reference": None if reference is None else [float(c) for c in reference],
            "evaluations": [e.to_dict() for e in self.evaluations],
            "model_dir": str(self.model_dir),
            "tensorboard_log": self.tensorboard_log,
            "progress": self.progress,
        }


@dataclass(frozen=True)
class EvaluationResult:
    """The trained agent on one scenario's test episodes: the file of its per-step costs (in
    the model folder), the jump steps, the per-episode metrics that need the traces, and the
    first episodes' traces."""

    scenario: str
    costs: str
    jump_step: list[int]
    metrics: dict[str, list[float]]
    traces: dict[str, list]


@dataclass(frozen=True)
class TrainingResult:
    """What a :class:`TrainingTask` returns: the agent's training (env steps, wall time, the
    step of the checkpoint kept, how it stopped, the learning curve, SB3's update records)
    and its evaluations."""

    algo: str
    seed: int
    steps: int
    wall_s: float
    best_step: int
    stop: dict[str, Any]
    curve: list[tuple[int, float]]
    updates: list[dict[str, Any]]
    evaluations: tuple[EvaluationResult, ...]


def _traces(batch: Any, count: int) -> dict[str, Any]:
    k = min(count, batch.num_episodes)
    return {name: np.asarray(getattr(batch, name)[:k]).tolist() for name in ("y", "r", "u")}


def train_and_evaluate(task: TrainingTask) -> TrainingResult:
    """Train the agent of ``task`` and evaluate it on the task's scenarios (worker side)."""
    from stcgym.agents.rl.learning_curve import CurveOptions
    from stcgym.agents.rl.sb3 import train_agent

    folder = Path(task.model_dir)
    agent = train_agent(
        task.algo,
        task.config,
        task.train_env,
        task.steps,
        task.seed,
        curve=CurveOptions(
            spec=task.curve_env,
            episodes=task.curve_episodes,
            points=task.curve_points,
            reference=task.curve_reference,
            plateau=task.plateau,
            interval=task.eval_interval,
        ),
        out_dir=folder,
        progress=task.progress,
        tensorboard_log=task.tensorboard_log,
        tb_log_name=task.name,
    )
    evaluations = []
    for ev in task.evaluations:
        batch = run_episodes(
            lambda plants, seeds: agent.policy.with_lanes(len(plants), seeds, plants),
            ev.env,
            ev.episodes,
            informed=agent.policy.informed,
        )
        name = costs_file(ev.scenario)
        np.save(folder / name, batch.cost.astype(np.float32), allow_pickle=False)
        metrics = response_metrics(batch, ev.env)
        evaluations.append(
            EvaluationResult(
                scenario=ev.scenario,
                costs=name,
                jump_step=batch.jump_step.tolist(),
                metrics={k: v.tolist() for k, v in metrics.items()},
                traces=_traces(batch, TRACE_EPISODES),
            )
        )
    return TrainingResult(
        algo=agent.algo,
        seed=agent.seed,
        steps=agent.steps,
        wall_s=agent.wall_s,
        best_step=agent.best_step,
        stop=agent.stop.to_dict(),
        curve=[(int(s), float(c)) for s, c in agent.curve],
        updates=list(agent.updates),
        evaluations=tuple(evaluations),
    )
