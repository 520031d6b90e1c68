"""The ``stcgym bench`` run: classical controllers, reference runs, RL jobs, ``metrics.csv``.

See :mod:`stcgym.agents.benchmark` for the scenarios, controllers and outputs.
"""

from __future__ import annotations

import datetime as _dt
import json
import sys
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from stcgym.agents.benchmark.classical_store import (
    CLASSICAL_FOLDER,
    ClassicalEpisodes,
    ClassicalStore,
    classical_id,
)
from stcgym.agents.benchmark.config import BenchConfig
from stcgym.agents.benchmark.metrics_csv import (
    METRIC_COLUMNS,
    TOLERANCE,
    MetricsWriter,
    format_value,
)
from stcgym.agents.benchmark.plan import (
    OUTPUT_SECONDS_PER_SCENARIO,
    JobProgress,
    agent_config,
    classical_seconds,
    estimate_seconds,
    format_duration,
    job_weights,
    reference_weights,
    rl_tasks,
)
from stcgym.agents.benchmark.rows import Yardstick, episode_rows, rl_steps_to_target
from stcgym.agents.benchmark.rundir import (
    JOBS_FOLDER,
    check_runnable,
    job_id,
    prepare_run_dir,
    versions,
)
from stcgym.agents.benchmark.scenarios import (
    Scenario,
    TrainingEnv,
    make_scenarios,
    training_envs,
)
from stcgym.agents.controllers import CONTROLLERS, YARDSTICK, controller_seeds, controllers_for
from stcgym.agents.evaluation.episodes import run_episodes
from stcgym.agents.evaluation.evaluate import response_metrics

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
    #: False when the time limit stopped the run first (``--resume`` continues it)
    complete: bool = True


@dataclass
class RunRecord:
    """One run of a controller on a scenario's episodes: per-step costs ``(B, T)`` (float32)
    and the episodes' jump steps, as the plots and the report read them."""

    run: int
    cost: np.ndarray
    jump_step: np.ndarray


@dataclass
class Collected:
    """What the plots and the report need besides the rows (kept in the driver's memory)."""

    #: (scenario, controller) -> the traces of the first episodes of the first run (y, r, u,
    #: and theta, theta_hat for the self-tuning controllers)
    traces: dict[tuple[str, str], dict[str, np.ndarray]] = field(default_factory=dict)
    #: (scenario, controller) -> every run's per-step costs
    costs: dict[tuple[str, str], list[RunRecord]] = field(default_factory=dict)
    #: learning-curve rows (train_env, algo, train_seed, steps, score)
    curves: list[dict[str, Any]] = field(default_factory=list)
    #: train_env -> the yardstick's mean cost per step on each learning-curve episode
    curve_references: dict[str, list[float]] = field(default_factory=dict)
    #: train_env -> the action bound and the LQG input peaks it was set from
    bounds: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: (train_env, algo, train_seed) -> how training ended (StopSummary.to_dict())
    stops: dict[tuple[str, str, int], dict[str, Any]] = field(default_factory=dict)
    #: the command line of the run (its first session's)
    argv: list[str] | None = None


def run_bench(
    cfg: BenchConfig,
    *,
    overwrite: bool = False,
    log: Callable[[str], None] | None = None,
    argv: Sequence[str] | None = None,
    checked: bool = False,
    resume: bool = False,
    time_limit: float | None = None,
) -> BenchResult:
    """Run the bench described by a validated ``cfg`` (see :func:`build_config`).

    All checks (names, budgets, hyperparameters against SB3, dependencies, output folder)
    happen before anything is evaluated or trained (``checked=True``: :func:`check_runnable`
    has been called already). First the action bound of each training distribution is set from
    the LQG yardstick (:mod:`~stcgym.agents.evaluation.bounds`) and written into
    ``config.json``; then the yardstick and zero input run on every scenario, the RL jobs on the
    workers while the driver evaluates the other classical controllers. Rows are appended to
    ``metrics.csv`` run by run; on ``KeyboardInterrupt`` (or any error) the finished rows stay,
    a partial ``report.md`` is written and the exception is re-raised.

    Each finished RL job is kept in ``jobs/<id>.json``, each classical controller's episodes in
    ``jobs/classical/`` (:mod:`~stcgym.agents.benchmark.classical_store`). ``resume=True``
    continues the run in ``cfg.run_dir`` (``cfg`` read back from its ``config.json``, the action
    bounds included): what is kept is read back instead of evaluated or trained again, and the
    rest is run; the tables and the report are rebuilt, so they equal those of an uninterrupted
    run.

    ``time_limit`` (seconds from the call, e.g. a batch system's wall-time allocation): no RL
    job or classical evaluation starts unless its estimated duration
    (:func:`~stcgym.agents.benchmark.plan.job_weights`, times :data:`TIME_LIMIT_MARGIN`) ends
    before the limit, less the time to write the report; jobs are then taken longest first
    among those that fit. What could not start is left for ``--resume``: the report is
    written as partial, without plots, and ``BenchResult.complete`` is False. A job already
    running when the limit passes is not stopped.
    """
    from stcgym.agents.benchmark.report import write_report
    from stcgym.agents.executors import write_atomic

    t_start = time.perf_counter()
    log = log or (lambda msg: print(msg, file=sys.stderr, flush=True))
    if not checked:
        check_runnable(cfg)
    run_dir = prepare_run_dir(cfg, overwrite, resume)
    config_doc: dict[str, Any] = {
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
    writer = MetricsWriter(run_dir / "metrics.csv")
    state = _RunState(cfg, run_dir, writer, log, t_start)
    if time_limit is not None:
        state.deadline = t_start + float(time_limit)
    state.data.argv = config_doc["argv"]
    scenarios: list[Scenario] = []

    def write_config() -> None:
        config_doc["bench"] = cfg.to_dict()
        config_doc["scenarios"] = [
            {
                "name": s.name,
                "kind": s.kind,
                "train_env": s.train_key,
                "env": s.env.to_dict(),
                "episodes": len(s.episodes.seeds),
            }
            for s in scenarios
        ]
        write_atomic(run_dir / "config.json", json.dumps(config_doc, indent=2))

    def report(interrupted: bool, time_limited: bool = False) -> None:
        # the wall time of every session so far, kept in config.json for the next --resume
        config_doc["wall_s"] = wall_before + time.perf_counter() - t_start
        config_doc["sessions"] = sessions
        write_config()
        write_report(
            run_dir,
            cfg,
            scenarios,
            writer.rows,
            state.data,
            config_doc["wall_s"],
            interrupted=interrupted,
            time_limited=time_limited,
            sessions=sessions,
        )

    write_config()
    try:
        state.measure_bounds(make_scenarios(cfg))
        scenarios = make_scenarios(cfg)  # with the bounds
        write_config()
        state.run(scenarios, training_envs(cfg, scenarios))
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
    if state.left:
        report(False, time_limited=True)
        wall = time.perf_counter() - t_start
        log(f"time limit: stopped after {format_duration(wall)} with {state.left} left "
            f"(partial report); continue with: stcgym bench --resume {run_dir}")  # fmt: skip
        return BenchResult(run_dir, writer.rows, state.data.curves, wall, complete=False)
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


#: Controller seeds of run ``run`` on the episodes ``seeds`` (one definition, shared with the
#: residual RL agent's controller).
_lane_seeds = controller_seeds


def _trace(batch: Any, count: int, theta: bool) -> dict[str, np.ndarray]:
    names = ("y", "r", "u", "theta", "theta_hat") if theta else ("y", "r", "u")
    return {n: np.asarray(getattr(batch, n))[:count] for n in names}


class _RunState:
    """The bench's driver: action bounds, yardstick runs, classical controllers, RL jobs."""

    def __init__(self, cfg, run_dir, writer, log, t0) -> None:
        self.cfg, self.run_dir, self.writer, self._log, self.t0 = cfg, run_dir, writer, log, t0
        self.data = Collected()
        # scenario -> the yardstick's and zero input's numbers per episode
        self.yard: dict[str, Yardstick] = {}
        self.scenarios: dict[str, Scenario] = {}
        # set when the driver fails while the classical controllers run in a thread
        self.halt = threading.Event()
        # the classical controllers' episodes, kept for a resumed run
        self.classical_store = ClassicalStore(run_dir / JOBS_FOLDER / CLASSICAL_FOLDER)
        self.classical_kept = 0  # how many were read back
        # the time limit (perf_counter), and what it left for a resumed run ("" when nothing)
        self.deadline: float | None = None
        self.left = ""
        self._reserve = 0.0  # seconds kept for the report and the tables at the end

    def log(self, msg: str) -> None:
        self._log(f"[{time.perf_counter() - self.t0:7.1f} s] {msg}")

    # -- before anything is compared -------------------------------------------------------
    def measure_bounds(self, scenarios: list[Scenario]) -> None:
        """The action bound and the RL agents' action unit of every training distribution not
        in ``cfg.action_bounds`` / ``cfg.action_units`` yet (a resumed run reads them back),
        from the LQG yardstick's input range."""
        from stcgym.agents.evaluation.bounds import bound_of_peaks, lqg_action_unit, lqg_inputs

        for key, env in training_envs(self.cfg, scenarios).items():
            if key in self.cfg.action_bounds and key in self.cfg.action_units:
                continue
            inputs = lqg_inputs(env.train, env.bound_episodes)
            peaks = inputs.max(axis=(1, 2))
            bound = bound_of_peaks(peaks)
            self.cfg.action_units[key] = lqg_action_unit(inputs)
            if key in self.cfg.action_bounds:  # a run from before the units: its bound stays
                continue
            self.cfg.action_bounds[key] = bound
            self.data.bounds[key] = {
                "bound": bound,
                "episodes": len(peaks),
                "peak_median": float(np.median(peaks)),
                "peak_max": float(np.max(peaks)),
            }
            self.log(f"action bound of {key}: {bound:g}, RL action unit "
                     f"{self.cfg.action_units[key]:g} (LQG's input peaks: median "
                     f"{np.median(peaks):.3g}, max {np.max(peaks):.3g} over {len(peaks)} "
                     "training episodes)")  # fmt: skip

    def _yardstick(self, sc: Scenario) -> None:
        """LQG and zero input on the scenario's episodes: the reference of every row."""
        lqg = self._kept(sc, YARDSTICK, 0) or self._evaluated(sc, YARDSTICK, 0)
        zero = self._kept(sc, "zero", 0) or self._evaluated(sc, "zero", 0)
        self.yard[sc.name] = Yardstick(
            lqg.cost, lqg.jump_step, zero.cost.mean(axis=1), zero.metrics["bounded"] > 0
        )
        for name, episodes in ((YARDSTICK, lqg), ("zero", zero)):
            self._classical_rows(sc, name, 0, episodes)

    def _curve_reference(self, env: TrainingEnv) -> list[float]:
        """The yardstick's mean cost per step on each learning-curve episode of ``env``."""
        from types import SimpleNamespace

        sc = SimpleNamespace(env=env.curve, controller_order=env.curve.order)
        builder = CONTROLLERS[YARDSTICK].build(self.cfg, sc)
        batch = run_episodes(builder, env.curve, env.curve_episodes, informed=True)
        return [float(c) for c in batch.cost.mean(axis=1)]

    # -- classical controllers -------------------------------------------------------------
    def _classical_key(self, sc: Scenario, name: str, run: int) -> tuple[str, str]:
        """The label and id run ``run`` of ``name`` on ``sc`` is kept under."""
        scenario = {
            "name": sc.name,
            "env": sc.env.to_dict(),
            "episodes": sc.episodes.to_dict(),
            "controller_order": sc.controller_order,
        }
        return f"{sc.name}.{name}.run{run}", classical_id(self.cfg.to_dict(), scenario, name, run)

    def _kept(self, sc: Scenario, name: str, run: int) -> ClassicalEpisodes | None:
        """Run ``run`` of ``name`` on ``sc`` as an earlier session of this run kept it
        (``--resume``), or None."""
        kept = self.classical_store.load(*self._classical_key(sc, name, run))
        self.classical_kept += kept is not None
        return kept

    def _evaluated(self, sc: Scenario, name: str, run: int) -> ClassicalEpisodes:
        """Run ``run`` of the classical controller ``name`` on the scenario's episodes, kept
        for a resumed run."""
        label, tid = self._classical_key(sc, name, run)
        info = CONTROLLERS[name]
        seeds = dict(zip(sc.episodes.seeds, _lane_seeds(sc.episodes.seeds, run), strict=True))
        builder = info.build(self.cfg, sc)
        batch = run_episodes(
            lambda plants, lanes: builder(plants, [seeds[s] for s in lanes]),
            sc.env,
            sc.episodes,
            informed=info.informed,
            record_theta=info.kind == "adaptive",
        )
        episodes = ClassicalEpisodes(
            cost=batch.cost,
            jump_step=batch.jump_step,
            metrics=response_metrics(batch, sc.env),
            trace=_trace(batch, 2, info.kind == "adaptive") if run == 0 else {},
        )
        self.classical_store.save(label, tid, episodes)
        return episodes

    def _classical_rows(self, sc: Scenario, name: str, run: int, episodes: ClassicalEpisodes):
        info = CONTROLLERS[name]
        rows = episode_rows(
            sc,
            name,
            info.kind,
            run,
            episodes.cost,
            episodes.metrics,
            self.yard[sc.name],
            online=info.online,
            extra={"train_steps": 0, "train_wall_s": 0.0},
        )
        self.writer.write(rows)
        self.data.costs.setdefault((sc.name, name), []).append(
            RunRecord(run, episodes.cost.astype(np.float32), episodes.jump_step)
        )
        if run == 0:
            self.data.traces[(sc.name, name)] = episodes.trace

    def fits(self, seconds: float) -> bool:
        """Whether work estimated at ``seconds`` ends before the time limit (always without
        one)."""
        if self.deadline is None:
            return True
        end = time.perf_counter() + TIME_LIMIT_MARGIN * seconds
        return end <= self.deadline - self._reserve

    def _classical(self, sc: Scenario, name: str) -> bool:
        """Every run of ``name`` on ``sc``; False when the time limit left some for a resumed
        run."""
        runs = self.cfg.train_seeds if CONTROLLERS[name].seeded else 1
        each = classical_seconds(self.cfg, sc, name) / runs
        for run in range(runs):
            if self.halt.is_set():
                raise _Stop
            episodes = self._kept(sc, name, run)  # read back whatever the time limit
            if episodes is None:
                if not self.fits(each):
                    return False
                episodes = self._evaluated(sc, name, run)
            self._classical_rows(sc, name, run, episodes)
        return True

    # -- tuning ----------------------------------------------------------------------------
    def tune(self, env: TrainingEnv) -> None:
        """The studies of :mod:`~stcgym.agents.benchmark.tuning` on the family's validation
        episodes: every RL agent's in the executor, the self-tuning controller's here; the best
        settings go into ``cfg`` (and so ``config.json``)."""
        from stcgym.agents.benchmark.tuning import apply_rl_params, tune_rl, tune_stc
        from stcgym.agents.executors import run_tasks
        from stcgym.agents.rl.configs import AlgoConfig

        cfg, reference = self.cfg, self.data.curve_references["family"]
        t0 = time.perf_counter()
        tasks = [
            {
                "name": f"tune_{algo}",
                "algo": algo,
                "config": agent_config(cfg, algo, "family").to_dict(),
                "train": env.train.to_dict(),
                "curve": env.curve.to_dict(),
                "curve_episodes": env.curve_episodes.to_dict(),
                "reference": reference,
                "trials": cfg.tune_trials,
                "steps": max(1, int(cfg.tune_fraction * cfg.family_train_steps[algo])),
                "seed": 0,
            }
            for algo in cfg.rl_agents
        ]
        tuned: dict[str, dict[str, Any]] = {}
        runs = run_tasks(tune_rl, tasks, executor=cfg.executor, jobs=cfg.jobs,
                         address=cfg.address, threads=1)  # fmt: skip
        for out in runs:
            if out.error is not None:
                raise RuntimeError(f"tuning {out.task['algo']} failed:\n{out.error}")
            tuned[out.task["algo"]] = out.result
        if "stc_tuned" in cfg.agents:
            tuned["stc"] = tune_stc(cfg, env, reference, cfg.tune_trials)
        for algo in cfg.rl_agents:
            base = AlgoConfig.from_dict(cfg.algo_configs[algo])
            cfg.algo_configs[algo] = apply_rl_params(base, tuned[algo]["params"]).to_dict()
        cfg.tuned = tuned
        self.log(
            f"tuned {', '.join(tuned)} on the validation split ({cfg.tune_trials} trials each, "
            f"{time.perf_counter() - t0:.0f} s)"
        )

    def _classical_all(self, scenarios: Sequence[Scenario], progress: JobProgress) -> int:
        """The classical controllers on every scenario; returns the scenarios the time limit
        left unfinished."""
        unfinished = 0
        for sc in scenarios:
            complete = True
            for name in controllers_for(self.cfg.classical, sc.env):  # those on its plants
                if name not in (YARDSTICK, "zero"):
                    complete = self._classical(sc, name) and complete
            if complete:
                progress.finish(("classical", sc.name), f"classical controllers on {sc.name}")
            unfinished += not complete
        if self.classical_kept:
            self.log(f"{self.classical_kept} classical evaluations read back from "
                     f"{self.classical_store.folder}")  # fmt: skip
        return unfinished

    # -- RL --------------------------------------------------------------------------------
    def _collect(self, task: dict[str, Any], result: dict[str, Any]) -> None:
        key, algo, ts = task["train_key"], result["algo"], result["seed"]
        for s, c in result["curve"]:
            self.data.curves.append(
                {"train_env": key, "algo": algo, "train_seed": ts, "steps": s, "score": c}
            )
        self._write_curves()
        # with the step of the checkpoint training kept (0: the untrained policy)
        stop = self.data.stops[(key, algo, ts)] = {
            **result["stop"],
            "kept_step": result["best_step"],
        }
        folder = Path(task["model_dir"])
        for ev in result["evaluations"]:
            sc = self.scenarios[ev["scenario"]]
            cost = np.load(folder / ev["costs"], allow_pickle=False).astype(float)
            yard = self.yard[sc.name]
            ratios = cost.mean(axis=1) / yard.metrics["cost"]
            target = rl_steps_to_target(result["curve"], ratios, sc.in_distribution)
            extra = {
                "train_steps": result["steps"],
                "train_cap": stop["cap"],
                "train_stop": stop["status"],
                "train_last_improvement": stop["last_improvement_step"],
                "train_wall_s": result["wall_s"],
                "data_steps": result["steps"],
            }
            metrics = {k: np.asarray(v, dtype=float) for k, v in ev["metrics"].items()}
            rows = episode_rows(
                sc, algo, "rl", ts, cost, metrics, yard, online=False,
                steps_to_target=target, extra=extra,
            )  # fmt: skip
            self.writer.write(rows)
            self.data.costs.setdefault((sc.name, algo), []).append(
                RunRecord(ts, cost.astype(np.float32), np.asarray(ev["jump_step"]))
            )
            if ts == 0:
                self.data.traces[(sc.name, algo)] = {
                    k: np.asarray(v, dtype=float) for k, v in ev["traces"].items()
                }

    def run(self, scenarios: list[Scenario], envs: dict[str, TrainingEnv]) -> None:
        """Yardstick runs, then the RL jobs on the workers while the driver evaluates the
        classical controllers (one core's work, which would otherwise leave a worker's core
        idle); the RL results are written once the classical rows are in."""
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
        for key, env in envs.items():
            self.data.curve_references[key] = self._curve_reference(env)
            progress.finish(("reference", key), f"yardstick on the {key} curve episodes")
        if cfg.tune_trials and not cfg.tuned:
            self.tune(envs["family"])
        for sc in scenarios:
            self._yardstick(sc)
        self.log("yardstick and zero input evaluated on every scenario")
        self._reserve = OUTPUT_SECONDS_PER_SCENARIO * len(scenarios) + REPORT_RESERVE_SECONDS
        if not planned:
            self._leave(self._classical_all(scenarios, progress), [])
            return
        tasks = rl_tasks(cfg, scenarios, envs, self.data.curve_references, self.run_dir)
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
        failures, ran = [], set()
        with ThreadPoolExecutor(1, thread_name_prefix="classical") as pool:
            if background:
                classical = pool.submit(self._classical_all, scenarios, progress)
            else:
                classical = Future()
                classical.set_result(self._classical_all(scenarios, progress))
            try:
                for out in run_tasks(
                    train_and_evaluate,
                    todo,
                    executor=cfg.executor,
                    jobs=cfg.jobs,
                    address=cfg.address,
                    threads=1,
                    admit=lambda task: self.fits(weights[("rl", task["name"])]),
                ):
                    name = out.task["name"]
                    ran.add(name)
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
                # the thread stops at its next run (leaving the block waits for it) and its
                # own error, if any, is dropped
                self.halt.set()
                raise
            unfinished = classical.result()
        for task, result in ready:
            self._collect(task, result)
        if failures:
            raise RuntimeError(f"{len(failures)} RL job(s) failed: {', '.join(failures)}")
        self._leave(unfinished, [t["name"] for t in todo if t["name"] not in ran])

    def _leave(self, classical: int, rl: list[str]) -> None:
        """Note what the time limit left for a resumed run (``self.left``)."""
        parts = []
        if rl:
            parts.append(f"{len(rl)} RL job{'s' if len(rl) > 1 else ''} ({', '.join(rl)})")
        if classical:
            parts.append(f"the classical controllers on {classical} scenario(s)")
        self.left = " and ".join(parts)

    def _write_curves(self) -> None:
        from stcgym.agents.executors import write_atomic

        cols = ["train_env", "algo", "train_seed", "steps", "score"]
        lines = [",".join(cols)]
        for row in self.data.curves:
            lines.append(",".join(str(format_value(row[c])) for c in cols))
        write_atomic(self.run_dir / "learning_curves.csv", "\n".join(lines) + "\n")


#: Estimated durations are multiplied by this before a job is started under a time limit (the
#: estimates are for the 2-core development machine and vary with the load).
TIME_LIMIT_MARGIN = 1.25
#: Seconds kept at the end of a time-limited run for the tables and the report, besides
#: ``OUTPUT_SECONDS_PER_SCENARIO`` per scenario.
REPORT_RESERVE_SECONDS = 30.0


class _Stop(Exception):
    """Raised in the classical evaluations when the driver stops (an error or Ctrl-C)."""
