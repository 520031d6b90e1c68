"""The jobs of a ``stcgym bench`` run (classical evaluations, reference runs, RL trainings),
their estimated cost, and the ``job k/N, ETA`` log."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from stcgym.agents.benchmark.config import BenchConfig
from stcgym.agents.benchmark.evaluate import EnvSpec
from stcgym.agents.benchmark.scenarios import Scenario, make_scenarios, training_envs
from stcgym.agents.controllers import controllers_for
from stcgym.agents.rl.configs import AlgoConfig

__all__ = [
    "SECONDS_PER_EVAL_STEP",
    "SECONDS_PER_STEP",
    "JobProgress",
    "estimate_seconds",
    "format_duration",
    "job_weights",
    "rl_tasks",
]


#: Rough CPU seconds per training env step on the 2-core development machine when nothing
#: else runs (torch on one thread; PPO 30k, SAC 1.5k and RecurrentPPO 4k steps timed with
#: start-up included); only the ETA and the announced estimate use them. With the other
#: core busy too each takes 2-3x as long; the ETA rescales by the jobs already finished.
SECONDS_PER_STEP = {"ppo": 2.0e-3, "a2c": 2.0e-3, "sac": 7.0e-3, "td3": 6.5e-3, "rppo": 5.5e-3}
#: Seconds per evaluated controller step (python loop).
SECONDS_PER_EVAL_STEP = 1.5e-4


def job_weights(cfg: BenchConfig, scenarios: Sequence[Scenario], tasks: Sequence[dict]) -> dict:
    """Estimated seconds of every job, RL jobs at their cap (the plateau rule may stop them
    earlier; the ETA then adapts)."""
    from stcgym.agents.rl.sb3 import curve_checkpoints

    classical = cfg.seeds * cfg.episode_steps * SECONDS_PER_EVAL_STEP
    episode = cfg.curve_seeds * cfg.train_episode_steps * SECONDS_PER_EVAL_STEP
    out = {
        ("classical", sc.name): classical * len(controllers_for(cfg.classical, sc.env))
        for sc in scenarios
    }
    for t in tasks:
        plants = len(t["curve_env"]["plants"])
        interval = t["config"]["eval_interval"]
        curve = 1 + len(curve_checkpoints(t["steps"], cfg.curve_points, interval))
        evals = sum(len(e["seeds"]) for e in t["evaluations"]) * cfg.episode_steps
        out[("rl", t["name"])] = (
            t["steps"] * SECONDS_PER_STEP.get(t["algo"], 5e-3)
            + curve * episode * plants
            + evals * 2 * SECONDS_PER_EVAL_STEP
        )
    return out


def estimate_seconds(cfg: BenchConfig) -> float:
    """Rough wall time of ``cfg`` on ``cfg.jobs`` cores (announced before long runs)."""
    scenarios = make_scenarios(cfg)
    weights = job_weights(cfg, scenarios, rl_tasks(cfg, scenarios, {}, {}))
    rl = sum(w for (kind, _), w in weights.items() if kind == "rl")
    return sum(weights.values()) - rl + rl / max(1, cfg.jobs)


def format_duration(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "?"
    s = int(round(seconds))
    if s >= 3600:
        return f"{s // 3600}h{(s % 3600) // 60:02d}m"
    return f"{s // 60}m{s % 60:02d}s" if s >= 60 else f"{s}s"


class JobProgress:
    """``job k/N, ETA`` over the whole run: classical evaluations and RL jobs, weighted.

    Weights are estimated seconds (:data:`SECONDS_PER_STEP`); the ETA is the estimated work
    left, each kind of job (``"classical"``, ``"reference"``, ``"rl"``) scaled by how much
    slower or faster the finished jobs of that kind ran than estimated, RL jobs divided over
    the ``jobs`` parallel workers.
    """

    def __init__(self, weights: dict[Any, float], log: Callable[[str], None], jobs: int) -> None:
        self.weights, self.log, self.jobs = dict(weights), log, max(1, int(jobs))
        self.done: dict[Any, float] = {}
        self.t0 = self._last = time.perf_counter()

    def drop(self, key: Any) -> None:
        """Take a job out of the plan (finished by an earlier run: ``--resume``)."""
        self.weights.pop(key, None)
        self._last = time.perf_counter()

    def finish(self, key: Any, what: str, seconds: float | None = None) -> None:
        now = time.perf_counter()
        self.done[key] = (now - self._last) if seconds is None else seconds
        self._last = now
        eta = 0.0
        for kind in {k[0] for k in self.weights}:
            todo = sum(w for k, w in self.weights.items() if k[0] == kind and k not in self.done)
            est = sum(self.weights[k] for k in self.done if k[0] == kind)
            took = sum(s for k, s in self.done.items() if k[0] == kind)
            scale = took / est if est > 0 else 1.0
            eta += todo * scale / (self.jobs if kind == "rl" else 1)
        self.log(
            f"job {len(self.done)}/{len(self.weights)} done ({what}); elapsed "
            f"{format_duration(now - self.t0)}, ETA {format_duration(eta)}"
        )


def rl_tasks(
    cfg: BenchConfig,
    scenarios: Sequence[Scenario],
    envs: dict[str, tuple[EnvSpec, EnvSpec]],
    references: dict[str, float],
    run_dir: Path | None = None,
) -> list[dict[str, Any]]:
    """The RL jobs, longest first (so that two workers finish together)."""
    from stcgym.agents.rl.training import training_task

    envs = envs or training_envs(cfg, scenarios)
    curve_seeds = [10_000 + i for i in range(cfg.curve_seeds)]
    tasks = []
    for key, (train_spec, curve_spec) in envs.items():
        for algo in cfg.rl_agents:
            users = [sc for sc in scenarios if sc.train_key_for(algo) == key]
            if not users:
                continue
            for ts in range(cfg.train_seeds):
                name = f"{key.replace(':', '-')}_{algo}_s{ts}"
                evaluations = [
                    {
                        "scenario": sc.name,
                        "env": sc.env.to_dict(),
                        "plant": sc.plant,
                        "seeds": cfg.eval_seeds,
                        "trace_seed": cfg.eval_seeds[0] if ts == 0 else None,
                    }
                    for sc in users
                ]
                tb = None
                if cfg.tensorboard_log is not None:
                    tb = str(Path(cfg.tensorboard_log) / cfg.run)
                tasks.append(
                    training_task(
                        algo=algo,
                        config=AlgoConfig.from_dict(cfg.algo_configs[algo]),
                        seed=ts,
                        steps=cfg.cap(algo, key),
                        plateau=cfg.plateau,
                        train_key=key,
                        train_env=train_spec,
                        curve_env=curve_spec,
                        curve_seeds=curve_seeds,
                        curve_points=cfg.curve_points,
                        curve_reference=references.get(key),
                        evaluations=evaluations,
                        model_dir=None if run_dir is None else str(run_dir / "models" / name),
                        tensorboard_log=tb,
                        progress=cfg.progress if cfg.jobs == 1 else False,
                    )
                )
    cost = {t["name"]: t["steps"] * SECONDS_PER_STEP.get(t["algo"], 5e-3) for t in tasks}
    return sorted(tasks, key=lambda t: -cost[t["name"]])
