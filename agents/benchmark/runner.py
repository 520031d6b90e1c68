"""The ``stcgym bench`` run: classical controllers, reference runs, RL jobs, ``metrics.csv``.

See :mod:`stcgym.agents.benchmark` for the scenarios, controllers and outputs.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import sys
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from stcgym.agents.benchmark.config import BenchConfig
from stcgym.agents.benchmark.evaluate import EnvSpec, Episode, evaluate, run_episode
from stcgym.agents.benchmark.metrics_csv import (
    METRIC_COLUMNS,
    TOLERANCE,
    MetricsWriter,
    format_value,
    ratio,
)
from stcgym.agents.benchmark.plan import (
    JobProgress,
    estimate_seconds,
    format_duration,
    job_weights,
    reference_weights,
    rl_tasks,
)
from stcgym.agents.benchmark.response import curve_settling_step, settling_step
from stcgym.agents.benchmark.rundir import (
    JOBS_FOLDER,
    check_runnable,
    job_id,
    prepare_run_dir,
    versions,
)
from stcgym.agents.benchmark.scenarios import Scenario, make_scenarios, training_envs
from stcgym.agents.controllers import CONTROLLERS, controllers_for

__all__ = [
    "METRIC_COLUMNS",
    "TOLERANCE",
    "BenchResult",
    "check_runnable",
    "job_id",
    "prepare_run_dir",
    "run_bench",
]


@dataclass
class BenchResult:
    """What :func:`run_bench` produced (also on disk under ``run_dir``)."""

    run_dir: Path
    rows: list[dict[str, Any]]
    curves: list[dict[str, Any]]
    wall_s: float


@dataclass
class Collected:
    """What the plots and the report need besides the rows (kept in the driver's memory)."""

    #: (scenario, controller) -> Episode of the first evaluation seed (first training seed)
    traces: dict[tuple[str, str], Episode] = field(default_factory=dict)
    #: (scenario, controller) -> per-step costs of every episode of the first training seed
    costs: dict[tuple[str, str], list[np.ndarray]] = field(default_factory=dict)
    #: learning-curve rows (train_env, algo, train_seed, steps, cost, cost_to_oracle)
    curves: list[dict[str, Any]] = field(default_factory=list)
    #: train_env -> controller -> mean cost on the learning-curve episodes
    reference_lines: dict[str, dict[str, float]] = field(default_factory=dict)
    #: train_env -> (window ends, cost / oracle per window and episode, first online controller)
    adaptation: dict[str, tuple[np.ndarray, np.ndarray, str]] = field(default_factory=dict)
    #: (train_env, algo, train_seed) -> how training ended (StopSummary.to_dict())
    stops: dict[tuple[str, str, int], dict[str, Any]] = field(default_factory=dict)


def run_bench(
    cfg: BenchConfig,
    *,
    overwrite: bool = False,
    log: Callable[[str], None] | None = None,
    argv: Sequence[str] | None = None,
    checked: bool = False,
    resume: bool = False,
) -> BenchResult:
    """Run the bench described by a validated ``cfg`` (see :func:`build_config`).

    All checks (names, budgets, hyperparameters against SB3, dependencies, output folder)
    happen before anything is evaluated or trained (``checked=True``: :func:`check_runnable`
    has been called already). Rows are appended to ``metrics.csv`` as
    episodes finish; on ``KeyboardInterrupt`` (or any error) the finished rows stay, a partial
    ``report.md`` is written and the exception is re-raised.

    Each finished RL job is kept in ``jobs/<id>.json``. ``resume=True`` continues the run in
    ``cfg.run_dir`` (``cfg`` read back from its ``config.json``): the classical controllers
    are evaluated again (deterministic, and cheap next to training), the finished RL jobs are
    read back instead of retrained, and the rest are trained; the tables and the report are
    rebuilt, so they equal those of an uninterrupted run.
    """
    from stcgym.agents.benchmark.report import write_report
    from stcgym.agents.executors import write_atomic

    t_start = time.perf_counter()
    log = log or (lambda msg: print(msg, file=sys.stderr, flush=True))
    if not checked:
        check_runnable(cfg)
    scenarios = make_scenarios(cfg)
    envs = training_envs(cfg, scenarios)
    run_dir = prepare_run_dir(cfg, overwrite, resume)
    config_doc = {
        "bench": cfg.to_dict(),
        "scenarios": [
            {
                "name": s.name,
                "kind": s.kind,
                "plant": s.plant,
                "train_env": s.train_key,
                "env": s.env.to_dict(),
            }
            for s in scenarios
        ],
        "argv": list(argv) if argv is not None else None,
        "versions": versions(),
        "started": _dt.datetime.now().isoformat(timespec="seconds"),
    }
    wall_before = 0.0  # the earlier sessions of a resumed run
    sessions = 1
    if resume:
        first = json.loads((run_dir / "config.json").read_text())
        wall_before = float(first.get("wall_s", 0.0))
        sessions = int(first.get("sessions", 1)) + 1
        config_doc["started"] = first.get("started")
        config_doc["resumed"] = [*first.get("resumed", []), config_doc.pop("argv")]
        config_doc["argv"] = first.get("argv")
    write_atomic(run_dir / "config.json", json.dumps(config_doc, indent=2))
    writer = MetricsWriter(run_dir / "metrics.csv")
    state = _RunState(cfg, run_dir, writer, log, t_start)

    def report(interrupted: bool) -> None:
        # the wall time of every session so far, kept in config.json for the next --resume
        wall = wall_before + time.perf_counter() - t_start
        config_doc["wall_s"], config_doc["sessions"] = wall, sessions
        write_atomic(run_dir / "config.json", json.dumps(config_doc, indent=2))
        write_report(
            run_dir,
            cfg,
            scenarios,
            writer.rows,
            state.data,
            wall,
            interrupted=interrupted,
            sessions=sessions,
        )

    try:
        state.run(scenarios, envs)
    except BaseException as exc:  # Ctrl-C or a crash: keep what is finished, then re-raise
        writer.close()
        what = "interrupted" if isinstance(exc, KeyboardInterrupt) else f"failed ({exc!r})"
        log(f"{what}: {len(writer.rows)} finished rows kept in {run_dir / 'metrics.csv'}")
        try:
            report(True)
        except Exception as report_exc:  # never mask the original error
            log(f"could not write the partial report: {report_exc!r}")
        raise
    writer.close()
    plots = _start_plots(run_dir, cfg, scenarios, writer.rows, state) if cfg.plots else None
    t0 = time.perf_counter()
    report(False)
    state.log(f"report written ({time.perf_counter() - t0:.0f} s)")
    if plots is not None:
        plots()
    wall = time.perf_counter() - t_start
    log(f"done in {format_duration(wall)}: {run_dir}")
    return BenchResult(run_dir, writer.rows, state.data.curves, wall)


def _start_plots(
    run_dir: Path, cfg: BenchConfig, scenarios: list[Scenario], rows: list, state: _RunState
) -> Callable[[], None]:
    """Start writing the plots; the returned call waits for them.

    With more than one job they are drawn in a process of their own while the driver writes
    the report (each takes seconds of one core; the workers are done by then)."""
    from stcgym.agents.benchmark.plots import write_plots

    t0 = time.perf_counter()
    args = (run_dir, cfg, scenarios, rows, state.data)
    if cfg.jobs == 1:
        write_plots(*args)
        state.log(f"plots written ({time.perf_counter() - t0:.0f} s)")
        return lambda: None
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    pool = ProcessPoolExecutor(1, mp_context=get_context("spawn"))
    future = pool.submit(write_plots, *args)

    def wait() -> None:
        try:
            future.result()
        finally:
            pool.shutdown()
        state.log(f"plots written ({time.perf_counter() - t0:.0f} s, next to the report)")

    return wait


class _RunState:
    """The bench's driver: classical controllers, reference runs, then the RL jobs."""

    def __init__(self, cfg, run_dir, writer, log, t0) -> None:
        self.cfg, self.run_dir, self.writer, self._log, self.t0 = cfg, run_dir, writer, log, t0
        self.data = Collected()
        # (scenario, seed) -> the oracle's episode costs and metrics (the reference of ratios)
        self.oracle: dict[tuple[str, int], tuple[np.ndarray, dict[str, float]]] = {}
        self.scenarios: dict[str, Scenario] = {}
        # set when the driver fails while the classical controllers run in a thread
        self.halt = threading.Event()

    def log(self, msg: str) -> None:
        self._log(f"[{time.perf_counter() - self.t0:7.1f} s] {msg}")

    # -- rows ------------------------------------------------------------------------------
    def _row(
        self,
        sc: Scenario,
        controller: str,
        seed: int,
        cost: np.ndarray,
        metrics: dict[str, float],
        extra: dict[str, Any],
    ) -> dict[str, Any]:
        """One ``metrics.csv`` row, with the ratios to the oracle on the same episode."""
        T = len(cost)
        J = sc.env.jump_step
        span = sc.env.period
        ref_cost, ref = self.oracle.get((sc.name, seed), (None, None))
        row = {
            "scenario": sc.name,
            "kind": sc.kind,
            "plant": sc.plant if sc.jump_to is None else sc.name.split(":", 1)[1],
            "controller": controller,
            "seed": seed,
            **metrics,
            **extra,
        }
        if ref is not None:
            row["cost_ratio"] = ratio(metrics["cost"], ref["cost"])
            row["steady_ratio"] = ratio(metrics["cost_steady"], ref["cost_steady"])
            if J is not None:
                row["post_jump_ratio"] = ratio(metrics["cost_post_jump"], ref["cost_post_jump"])
                row["reconverge_steps"] = settling_step(
                    cost, ref_cost, span=span, start=J, tol=TOLERANCE
                )
            if "steps_to_oracle" not in extra:
                row["steps_to_oracle"] = settling_step(
                    cost, ref_cost, span=span, stop=J or T, tol=TOLERANCE
                )
        return row

    def _write(self, row: dict[str, Any], ep_cost: np.ndarray, first_model: bool) -> None:
        self.writer.write(row)
        if first_model:
            self.data.costs.setdefault((row["scenario"], row["controller"]), []).append(ep_cost)

    # -- classical -------------------------------------------------------------------------
    def _classical(self, sc: Scenario, name: str) -> None:
        cfg = self.cfg
        info = CONTROLLERS[name]
        # the self-tuning controllers (random probe) take the episode's seed
        seeded = info.kind == "adaptive"

        def on_episode(ep: Episode, metrics: dict[str, float]) -> None:
            if self.halt.is_set():
                raise _Stop
            if name == "oracle":
                self.oracle[(sc.name, ep.seed)] = (ep.cost, metrics)
            extra = {
                "family": info.kind,
                "train_seed": "",
                "controller_seed": ep.seed if seeded else "",
                "train_steps": 0,
                "train_wall_s": 0.0,
                # online learners adapt on the whole episode; the oracles know the model
                "data_steps": ep.steps_run if info.online else 0,
            }
            self._write(self._row(sc, name, ep.seed, ep.cost, metrics, extra), ep.cost, True)
            if ep.seed == cfg.eval_seeds[0]:
                self.data.traces[(sc.name, name)] = ep

        evaluate(
            info.build(cfg, sc),
            sc.env,
            cfg.eval_seeds,
            plant=sc.plant,
            on_episode=on_episode,
            record_theta=info.kind == "adaptive",
        )

    def _references(self, key: str, curve_spec: EnvSpec, progress: JobProgress) -> None:
        """Classical controllers on the learning-curve episodes: the levels RL is compared to,
        and the first online controller's per-window cost against its adaptation steps."""
        cfg = self.cfg
        seeds = [10_000 + i for i in range(cfg.curve_seeds)]
        sc = Scenario(key, "curve", curve_spec, curve_spec.plants[0], key)
        runs: dict[str, list[np.ndarray]] = {}
        for name in controllers_for(cfg.classical, curve_spec):
            factory = CONTROLLERS[name].build(cfg, sc)
            runs[name] = [
                run_episode(factory, curve_spec, s, plant=p).cost
                for p in curve_spec.plants
                for s in seeds
            ]
        self.data.reference_lines[key] = {n: float(np.mean(c)) for n, c in runs.items()}
        if (learner := next((n for n in runs if CONTROLLERS[n].online), None)) is not None:
            w = max(1, curve_spec.period // 2)  # one reference step per window
            T = curve_spec.steps
            ends = np.arange(w, T + 1, w)
            ratios = np.array(
                [
                    [ratio(float(c[e - w : e].sum()), float(o[e - w : e].sum())) for e in ends]
                    for c, o in zip(runs[learner], runs["oracle"], strict=True)
                ]
            )
            self.data.adaptation[key] = (ends, ratios, learner)
        progress.finish(("reference", key), f"reference runs on {key}")

    # -- RL --------------------------------------------------------------------------------
    def _collect(self, task: dict[str, Any], result: dict[str, Any]) -> None:
        key, algo, ts = task["train_key"], result["algo"], result["seed"]
        oracle_level = self.data.reference_lines.get(key, {}).get("oracle")
        for s, c in result["curve"]:
            self.data.curves.append(
                {
                    "train_env": key,
                    "algo": algo,
                    "train_seed": ts,
                    "steps": s,
                    "cost": c,
                    "cost_to_oracle": ratio(c, oracle_level) if oracle_level else math.nan,
                }
            )
        self._write_curves()
        stop = self.data.stops[(key, algo, ts)] = result["stop"]
        to_oracle = (
            curve_settling_step(result["curve"], oracle_level, TOLERANCE)
            if oracle_level
            else math.nan
        )
        for ep in result["episodes"]:
            sc = self.scenarios[ep["scenario"]]
            cost = np.asarray(ep["cost"], dtype=float)
            extra = {
                "family": "rl",
                "train_seed": ts,
                "controller_seed": ts,
                "train_steps": result["steps"],
                "train_cap": stop["cap"],
                "train_stop": stop["status"],
                "train_last_improvement": stop["last_improvement_step"],
                "train_wall_s": result["wall_s"],
                "data_steps": result["steps"],
                "steps_to_oracle": to_oracle,
            }
            row = self._row(sc, algo, ep["seed"], cost, ep["metrics"], extra)
            self._write(row, cost, ts == 0)
            if ep["trace"] is not None:
                tr = ep["trace"]
                self.data.traces[(sc.name, algo)] = Episode(
                    ep["seed"],
                    ep["plant"],
                    np.asarray(tr["y"], dtype=float),
                    np.asarray(tr["r"], dtype=float),
                    np.asarray(tr["u"], dtype=float),
                    cost,
                    int(ep["metrics"]["steps_run"]),
                    not ep["metrics"]["bounded"],
                    0,
                    ep["metrics"]["step_us"],
                )

    def _classical_all(self, scenarios: Sequence[Scenario], progress: JobProgress) -> None:
        for sc in scenarios:
            for name in controllers_for(self.cfg.classical, sc.env):  # those on its plants
                self._classical(sc, name)
            progress.finish(("classical", sc.name), f"classical controllers on {sc.name}")

    def run(self, scenarios: list[Scenario], envs: dict[str, tuple[EnvSpec, EnvSpec]]) -> None:
        """Reference runs, then the RL jobs on the workers while the driver evaluates the
        classical controllers (one core's work, which would otherwise leave a worker's core
        idle); the RL results are written once the classical rows (the oracle's) are in."""
        from stcgym.agents.executors import ResultStore, run_tasks
        from stcgym.agents.rl.training import train_and_evaluate

        cfg = self.cfg
        self.scenarios = {sc.name: sc for sc in scenarios}
        planned = rl_tasks(cfg, scenarios, envs, {}, self.run_dir)
        weights = job_weights(cfg, scenarios, planned) | reference_weights(cfg, envs)
        progress = JobProgress(weights, self.log, cfg.jobs)
        workers = "worker" if cfg.jobs == 1 else "workers"
        self.log(
            f"{len(weights)} jobs ({len(planned)} RL trainings on {cfg.jobs} {workers}), "
            f"estimated {format_duration(estimate_seconds(cfg))}"
        )
        for key, (_, curve_spec) in envs.items():
            self._references(key, curve_spec, progress)
        if not planned:
            self._classical_all(scenarios, progress)
            return
        refs = {k: v["oracle"] for k, v in self.data.reference_lines.items()}
        tasks = rl_tasks(cfg, scenarios, envs, refs, self.run_dir)
        store = ResultStore(self.run_dir / JOBS_FOLDER)
        finished = store.done()
        todo, ready = [], []
        for task in tasks:
            if job_id(task) in finished:
                ready.append((task, store.load(job_id(task))))
                progress.drop(("rl", task["name"]))
            else:
                todo.append(task)
        if ready:
            self.log(f"{len(ready)} finished RL jobs read back from {store.folder}")
        # the classical controllers run in a thread while the workers train; when the RL jobs
        # run in this process (one job, or jobs=1) they go first instead
        background = cfg.executor == "ray" or (cfg.jobs > 1 and len(todo) > 1)
        failures = []
        with ThreadPoolExecutor(1, thread_name_prefix="classical") as pool:
            if background:
                classical = pool.submit(self._classical_all, scenarios, progress)
            else:
                classical = Future()
                self._classical_all(scenarios, progress)
                classical.set_result(None)
            try:
                for out in run_tasks(
                    train_and_evaluate,
                    todo,
                    executor=cfg.executor,
                    jobs=cfg.jobs,
                    address=cfg.address,
                    threads=1,
                ):
                    name = out.task["name"]
                    if out.error is not None:
                        failures.append(name)
                        self.log(f"RL job {name} FAILED:\n{out.error}")
                    else:
                        store.save(job_id(out.task), out.result)
                        ready.append((out.task, out.result))
                    progress.finish(("rl", name), f"{name}, {out.seconds:.0f} s", out.seconds)
                    if classical.done():
                        classical.result()  # the thread's error, raised in this one
                        while ready:
                            self._collect(*ready.pop(0))
            except BaseException:
                # the thread stops at its next episode (leaving the block waits for it) and
                # its own error, if any, is dropped
                self.halt.set()
                raise
            classical.result()
        for task, result in ready:
            self._collect(task, result)
        if failures:
            raise RuntimeError(f"{len(failures)} RL job(s) failed: {', '.join(failures)}")

    def _write_curves(self) -> None:
        from stcgym.agents.executors import write_atomic

        cols = ["train_env", "algo", "train_seed", "steps", "cost", "cost_to_oracle"]
        lines = [",".join(cols)]
        for row in self.data.curves:
            lines.append(",".join(str(format_value(row[c])) for c in cols))
        write_atomic(self.run_dir / "learning_curves.csv", "\n".join(lines) + "\n")


class _Stop(Exception):
    """Raised in the classical evaluations when the driver stops (an error or Ctrl-C)."""
