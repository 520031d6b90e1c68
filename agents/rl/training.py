"""One RL training job of ``stcgym bench`` as a task: train, then evaluate where it is used.

A task is plain JSON data (:func:`training_task` builds it), so the bench hands it to the
executor of :mod:`stcgym.agents.executors` (a local process pool or Ray) and resumable stores
can key it by :func:`~stcgym.agents.executors.task_id`. :func:`train_and_evaluate` is the
module-level function the workers call; it returns plain data (metrics and per-step costs of
every evaluation episode, the learning curve, how training stopped, one trace per scenario for
the plots). It writes only the agent's own model folder and TensorBoard run; the driver writes
every result file.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from stcgym.agents.benchmark.evaluate import EnvSpec, evaluate
from stcgym.agents.rl.configs import AlgoConfig
from stcgym.agents.rl.stopping import PlateauRule

__all__ = ["train_and_evaluate", "training_task"]


def training_task(
    *,
    algo: str,
    config: AlgoConfig,
    seed: int,
    steps: int,
    plateau: PlateauRule,
    train_key: str,
    train_env: EnvSpec,
    curve_env: EnvSpec,
    curve_seeds: Sequence[int],
    curve_points: int,
    curve_reference: float | None,
    evaluations: Sequence[dict[str, Any]],
    model_dir: str | None,
    tensorboard_log: str | None,
    progress: bool | None = False,
) -> dict[str, Any]:
    """The JSON task of one (training env, agent, seed).

    ``steps`` is the cap: training stops earlier at the plateau of the learning curve
    (``plateau``, judged every ``config.eval_interval`` env steps). ``evaluations`` are
    ``{"scenario", "env" (EnvSpec dict), "plant", "seeds", "trace_seed"}``: the scenarios that
    use this agent, the evaluation seeds, and the seed whose traces come back for the plots
    (``None``: none).
    """
    return {
        "name": f"{train_key.replace(':', '-')}_{algo}_s{seed}",
        "algo": algo,
        "config": config.to_dict(),
        "seed": int(seed),
        "steps": int(steps),
        "plateau": plateau.to_dict(),
        "train_key": train_key,
        "train_env": train_env.to_dict(),
        "curve_env": curve_env.to_dict(),
        "curve_seeds": [int(s) for s in curve_seeds],
        "curve_points": int(curve_points),
        "curve_reference": None if curve_reference is None else float(curve_reference),
        "evaluations": list(evaluations),
        "model_dir": model_dir,
        "tensorboard_log": tensorboard_log,
        "progress": progress,
    }


def train_and_evaluate(task: dict[str, Any]) -> dict[str, Any]:
    """Train the agent of ``task`` and evaluate it on the task's scenarios (worker side)."""
    from stcgym.agents.rl.sb3 import train_agent

    config = AlgoConfig.from_dict(task["config"])
    agent = train_agent(
        task["algo"],
        config,
        EnvSpec.from_dict(task["train_env"]),
        task["steps"],
        task["seed"],
        out_dir=task["model_dir"],
        curve_spec=EnvSpec.from_dict(task["curve_env"]),
        curve_seeds=task["curve_seeds"],
        curve_points=task["curve_points"],
        curve_reference=task["curve_reference"],
        plateau=PlateauRule(**task["plateau"]),
        eval_interval=config.eval_interval,
        progress=task["progress"],
        tensorboard_log=task["tensorboard_log"],
        tb_log_name=task["name"],
    )
    episodes = []
    for ev in task["evaluations"]:
        res = evaluate(agent.policy, EnvSpec.from_dict(ev["env"]), ev["seeds"], plant=ev["plant"])
        for ep, metrics in zip(res.episodes, res.metrics, strict=True):
            trace = None
            if ep.seed == ev["trace_seed"]:
                trace = {"y": ep.y.tolist(), "r": ep.r.tolist(), "u": ep.u.tolist()}
            episodes.append(
                {
                    "scenario": ev["scenario"],
                    "seed": ep.seed,
                    "plant": ep.plant,
                    "metrics": metrics,
                    "cost": ep.cost.tolist(),
                    "trace": trace,
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
        "episodes": episodes,
    }
