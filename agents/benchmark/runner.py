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
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from stcgym.agents.benchmark.adaptation import summarize_adaptation
from stcgym.agents.benchmark.config import BenchConfig
from stcgym.agents.benchmark.metrics_csv import METRIC_COLUMNS, TOLERANCE
from stcgym.agents.benchmark.plan import (
    OUTPUT_SECONDS_PER_SCENARIO,
    JobProgress,
    agent_config,
    classical_seconds,
    estimate_seconds,
    format_duration,
    job_weights,
    rl_tasks,
)
from stcgym.agents.benchmark.rows import Yardstick, episode_rows, rl_steps_to_target
from stcgym.agents.benchmark.rundir import (
    check_runnable,
    classical_key,
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
from stcgym.agents.benchmark.store import STORE_FOLDER, JobRecord, ResultsStore, ScenarioResult
from stcgym.agents.controllers import CONTROLLERS, YARDSTICK, controller_seeds, controllers_for
from stcgym.agents.evaluation.episodes import run_episodes
from stcgym.agents.evaluation.evaluate import response_metrics

if TYPE_CHECKING:
    from stcgym.agents.rl.training import TrainingResult, TrainingTask

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
    workers while the driver evaluates the other classical controllers.

    Each finished job is written to the results store (``store/``, one record per job:
    :mod:`~stcgym.agents.benchmark.store`) as soon as it finishes; the report, ``metrics.csv``,
    ``learning_curves.csv``, ``statistics.json`` and the figures are then rendered from the
    store alone (:func:`~stcgym.agents.benchmark.render.render_run`, also ``stcgym report``).
    On ``KeyboardInterrupt`` (or any error) a partial report is rendered from the records
    finished so far and the exception is re-raised.

    ``resume=True`` continues the run in ``cfg.run_dir`` (``cfg`` read back from its
    ``config.json``, the action bounds included): the records the plan asks for that the store
    holds are used as they are, the rest is run. The store can come from a clone of a
    repository: trained models are not needed.

    ``time_limit`` (seconds from the call, e.g. a batch system's wall-time allocation): no RL
    job or classical evaluation starts unless its estimated duration
    (:func:`~stcgym.agents.benchmark.plan.job_weights`, times :data:`TIME_LIMIT_MARGIN`) ends
    before the limit, less the time to write the report; jobs are then taken longest first
    among those that fit. What could not start is left for ``--resume``: the report is
    rendered as partial, without plots, and ``BenchResult.complete`` is False. A job already
    running when the limit passes is not stopped.
    """
    from stcgym.agents.benchmark.render import render_run
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
        config_doc["bound_measurements"] = first.get("bound_measurements", {})
        if "zoo_departures" in first:
            config_doc["zoo_departures"] = first["zoo_departures"]
    state = _RunState(cfg, run_dir, log, t_start)
    if time_limit is not None:
        state.deadline = t_start + float(time_limit)
    scenarios: list[Scenario] = []

    def write_config() -> None:
        from stcgym.agents.rl.zoo_departures import ZOO_DEPARTURES

        config_doc["bench"] = state.cfg.to_dict()
        # the departures from the RL Zoo these agents train with, for the report to cite
        config_doc.setdefault(
            "zoo_departures",
            {a: [list(row) for row in ZOO_DEPARTURES.get(a, [])] for a in state.cfg.rl_agents},
        )
        measured = config_doc.get("bound_measurements", {})
        config_doc["bound_measurements"] = {**measured, **state.bounds}
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
        # the wall time of every session so far, for the next --resume
        config_doc["wall_s"] = wall_before + time.perf_counter() - t_start
        config_doc["sessions"] = sessions
        write_atomic(run_dir / "config.json", json.dumps(config_doc, indent=2))

    def render(interrupted: bool, time_limited: bool = False, plots: bool = False) -> Any:
        write_config()
        return render_run(
            run_dir, interrupted=interrupted, time_limited=time_limited, plots=plots,
            log=state.log,
        )  # fmt: skip

    write_config()
    try:
        plan = state.plan()
        scenarios = plan.scenarios
        write_config()
        state.run(plan)
    except BaseException as exc:  # Ctrl-C or a crash: keep what is finished, then re-raise
        what = "interrupted" if isinstance(exc, KeyboardInterrupt) else f"failed ({exc!r})"
        log(f"{what}: the finished jobs are kept in {run_dir / STORE_FOLDER}")
        try:
            render(True)
        except Exception as report_exc:  # never mask the original error
            log(f"could not write the partial report: {report_exc!r}")
        raise
    if state.left:
        rendered = render(False, time_limited=True)
        wall = time.perf_counter() - t_start
        log(f"time limit: stopped after {format_duration(wall)} with {state.left} left "
            f"(partial report); continue with: stcgym bench --resume {run_dir}")  # fmt: skip
        return BenchResult(run_dir, rendered.rows, rendered.curves, wall, complete=False)
    rendered = render(False, plots=state.cfg.plots)
    wall = time.perf_counter() - t_start
    log(f"done in {format_duration(wall)}: {run_dir}")
    return BenchResult(run_dir, rendered.rows, rendered.curves, wall)


#: Controller seeds of run ``run`` on the episodes ``seeds`` (one definition, shared with the
#: residual RL agent's controller).
_lane_seeds = controller_seeds


def _trace(batch: Any, theta: bool) -> dict[str, np.ndarray]:
    """The first episode's signals (y, r, u; and theta, theta_hat for a self-tuning
    controller), as ``(1, T, ...)`` arrays."""
    names = ("y", "r", "u", "theta", "theta_hat") if theta else ("y", "r", "u")
    return {n: np.asarray(getattr(batch, n))[:1] for n in names}


@dataclass(frozen=True)
class RunPlan:
    """What a run's jobs read, computed once before any starts (:meth:`_RunState.plan`): the
    config with its measured bounds and units and tuned settings, the scenarios, the RL
    training envs and the yardstick's cost on each env's learning-curve episodes."""

    cfg: BenchConfig
    scenarios: list[Scenario]
    envs: dict[str, TrainingEnv]
    curve_references: dict[str, list[float]]


@dataclass
class _Evaluated:
    """One run of a classical controller on a scenario's episodes, before it is scored."""

    cost: np.ndarray
    jump_step: np.ndarray
    metrics: dict[str, np.ndarray]
    trace: dict[str, np.ndarray] = field(default_factory=dict)


#: Update records an RL job's store record keeps at most (SAC logs one per gradient step).
MAX_UPDATES_KEPT = 100


def _thinned(updates: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """At most :data:`MAX_UPDATES_KEPT` of a run's update records, evenly spaced, the last
    one always kept: what the report summarises and the store keeps small."""
    if len(updates) <= MAX_UPDATES_KEPT:
        return list(updates)
    keep = np.unique(np.linspace(0, len(updates) - 1, MAX_UPDATES_KEPT).round().astype(int))
    return [updates[i] for i in keep]


def _rl_settings(task: TrainingTask) -> dict[str, Any]:
    """What an RL job's record says of its settings (the id hashes all of them)."""
    data = task.to_dict()
    keys = ("algo", "seed", "steps", "train_key", "eval_interval", "plateau", "config")
    return {k: data[k] for k in keys}


class _RunState:
    """The bench's driver: action bounds, yardstick runs, classical controllers, RL jobs; every
    finished job goes to the results store."""

    def __init__(self, cfg, run_dir, log, t0) -> None:
        self.cfg, self.run_dir, self._log, self.t0 = cfg, run_dir, log, t0
        self.store = ResultsStore(run_dir / STORE_FOLDER, METRIC_COLUMNS)
        #: train_env -> the action bound and the LQG input peaks it was set from
        self.bounds: dict[str, dict[str, Any]] = {}
        #: train_env -> the yardstick's mean cost per step on each learning-curve episode
        self.curve_references: dict[str, list[float]] = {}
        # scenario -> the yardstick's and zero input's numbers per episode
        self.yard: dict[str, Yardstick] = {}
        self.scenarios: dict[str, Scenario] = {}
        # set when the driver fails while the classical controllers run in a thread
        self.halt = threading.Event()
        self.kept = 0  # how many classical records were read back
        # the time limit (perf_counter), and what it left for a resumed run ("" when nothing)
        self.deadline: float | None = None
        self.left = ""
        self._reserve = 0.0  # seconds kept for the report and the tables at the end

    def log(self, msg: str) -> None:
        self._log(f"[{time.perf_counter() - self.t0:7.1f} s] {msg}")

    # -- before anything is compared -------------------------------------------------------
    def plan(self) -> RunPlan:
        """Everything the jobs need, computed once before any of them starts: the action
        bounds and units, the scenarios and training envs with those bounds, the yardstick's
        cost on the learning-curve episodes, and (with tuning trials) the tuned settings. The
        measured and tuned values go into a new config (``self.cfg``), which the jobs read and
        nothing changes after."""
        self.cfg = self._with_bounds(make_scenarios(self.cfg))
        scenarios = make_scenarios(self.cfg)
        envs = training_envs(self.cfg, scenarios)
        references = {key: self._curve_reference(env) for key, env in envs.items()}
        self.curve_references = references
        if self.cfg.tune_trials and not self.cfg.tuned:
            self.cfg = self.tune(envs["family"])
        return RunPlan(self.cfg, scenarios, envs, references)

    def _with_bounds(self, scenarios: list[Scenario]) -> BenchConfig:
        """The config with the action bound and the RL agents' action unit of every training
        distribution not in ``cfg.action_bounds`` / ``cfg.action_units`` yet (a resumed run
        reads them back), measured from the LQG yardstick's input range."""
        from stcgym.agents.evaluation.bounds import bound_of_peaks, lqg_action_unit, lqg_inputs

        bounds, units = dict(self.cfg.action_bounds), dict(self.cfg.action_units)
        for key, env in training_envs(self.cfg, scenarios).items():
            if key in bounds and key in units:
                continue
            inputs = lqg_inputs(env.train, env.bound_episodes)
            peaks = inputs.max(axis=(1, 2))
            units[key] = lqg_action_unit(inputs)
            if key in bounds:  # a run from before the units: its bound stays
                continue
            bounds[key] = bound_of_peaks(peaks)
            self.bounds[key] = {
                "bound": bounds[key],
                "episodes": len(peaks),
                "peak_median": float(np.median(peaks)),
                "peak_max": float(np.max(peaks)),
            }
            self.log(f"action bound of {key}: {bounds[key]:g}, RL action unit "
                     f"{units[key]:g} (LQG's input peaks: median "
                     f"{np.median(peaks):.3g}, max {np.max(peaks):.3g} over {len(peaks)} "
                     "training episodes)")  # fmt: skip
        return replace(self.cfg, action_bounds=bounds, action_units=units)

    def _yardstick(self, sc: Scenario) -> None:
        """LQG and zero input on the scenario's episodes: the reference of every row. Always
        evaluated (a second or two a scenario), since the other rows are scored against them;
        their own records are written once."""
        lqg = self._evaluate(sc, YARDSTICK, 0)
        zero = self._evaluate(sc, "zero", 0)
        self.yard[sc.name] = Yardstick(
            lqg.cost, lqg.jump_step, zero.cost.mean(axis=1), zero.metrics["bounded"] > 0
        )
        for name, episodes in ((YARDSTICK, lqg), ("zero", zero)):
            if self.store.load(*classical_key(self.cfg, sc, name, 0)) is None:
                self._save_classical(sc, name, 0, episodes)

    def _curve_reference(self, env: TrainingEnv) -> list[float]:
        """The yardstick's mean cost per step on each learning-curve episode of ``env``."""
        builder = CONTROLLERS[YARDSTICK].build(self.cfg, env.curve_scenario)
        batch = run_episodes(builder, env.curve, env.curve_episodes, informed=True)
        return [float(c) for c in batch.cost.mean(axis=1)]

    # -- classical controllers -------------------------------------------------------------
    def _evaluate(self, sc: Scenario, name: str, run: int) -> _Evaluated:
        """Run ``run`` of the classical controller ``name`` on the scenario's episodes."""
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
        return _Evaluated(
            cost=batch.cost,
            jump_step=batch.jump_step,
            metrics=response_metrics(batch, sc.env),
            trace=_trace(batch, info.kind == "adaptive") if run == 0 else {},
        )

    def _scored(
        self, sc: Scenario, name: str, family: str, run: int, cost: np.ndarray, metrics: dict,
        trace: dict, *, online: bool, **kw: Any,
    ) -> ScenarioResult:  # fmt: skip
        """The rows and the adaptation summary of one run on ``sc``'s episodes."""
        yard = self.yard[sc.name]
        rows = episode_rows(sc, name, family, run, cost, metrics, yard, online=online, **kw)
        summary = summarize_adaptation(
            cost, yard.cost, yard.jump_step, sc.env.span, align=sc.kind == "jump"
        )
        return ScenarioResult(rows, summary, trace)

    def _save_classical(self, sc: Scenario, name: str, run: int, episodes: _Evaluated) -> None:
        info = CONTROLLERS[name]
        label, rid = classical_key(self.cfg, sc, name, run)
        result = self._scored(
            sc, name, info.kind, run, episodes.cost, episodes.metrics, episodes.trace,
            online=info.online, extra={"train_steps": 0, "train_wall_s": 0.0},
        )  # fmt: skip
        settings = {"scenario": sc.name, "controller": name, "run": run}
        self.store.save(JobRecord("classical", label, rid, settings, {sc.name: result}))

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
        runs = self.cfg.runs_of(name)
        each = classical_seconds(self.cfg, sc, name) / runs
        for run in range(runs):
            if self.halt.is_set():
                raise _Stop
            if self.store.load(*classical_key(self.cfg, sc, name, run)) is not None:
                self.kept += 1  # kept whatever the time limit
                continue
            if not self.fits(each):
                return False
            self._save_classical(sc, name, run, self._evaluate(sc, name, run))
        return True

    # -- tuning ----------------------------------------------------------------------------
    def tune(self, env: TrainingEnv) -> BenchConfig:
        """The studies of :mod:`~stcgym.agents.benchmark.tuning` on the family's validation
        episodes: every RL agent's in the executor, the self-tuning controller's here; returns
        the config with the best settings (and so ``config.json``)."""
        from stcgym.agents.benchmark.tuning import TuningTask, apply_rl_params, tune_rl, tune_stc
        from stcgym.agents.executors import run_tasks
        from stcgym.agents.rl.configs import AlgoConfig

        cfg, reference = self.cfg, self.curve_references["family"]
        t0 = time.perf_counter()
        tasks = [
            TuningTask(
                algo=algo,
                config=agent_config(cfg, algo, "family"),
                train=env.train,
                curve=env.curve,
                curve_episodes=env.curve_episodes,
                reference=tuple(reference),
                trials=cfg.tune_trials,
                steps=max(1, int(cfg.tune_fraction * cfg.family_train_steps[algo])),
            )
            for algo in cfg.tuned_rl_agents
        ]
        tuned: dict[str, dict[str, Any]] = {}
        runs = run_tasks(tune_rl, tasks, executor=cfg.executor, jobs=cfg.jobs,
                         address=cfg.address, threads=1)  # fmt: skip
        for out in runs:
            if out.error is not None:
                raise RuntimeError(f"tuning {out.task.algo} failed:\n{out.error}")
            tuned[out.task.algo] = out.result
        if "stc_tuned" in cfg.agents:
            tuned["stc"] = tune_stc(cfg, env, reference, cfg.tune_trials)
        configs = dict(cfg.algo_configs)
        for algo in cfg.tuned_rl_agents:
            base = AlgoConfig.from_dict(cfg.algo_configs[algo])
            configs[algo] = apply_rl_params(base, tuned[algo]["params"]).to_dict()
        self.log(
            f"tuned {', '.join(tuned)} on the validation split ({cfg.tune_trials} trials each, "
            f"{time.perf_counter() - t0:.0f} s)"
        )
        return replace(cfg, algo_configs=configs, tuned=tuned)

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
        if self.kept:
            self.log(f"{self.kept} classical evaluations read back from {self.store.folder}")
        return unfinished

    # -- RL --------------------------------------------------------------------------------
    def _record(self, task: TrainingTask, result: TrainingResult) -> JobRecord:
        """The store's record of a finished RL job: its rows on every scenario it is scored
        on, against the yardstick, with its learning curve and how training stopped."""
        # with the step of the checkpoint training kept (0: the untrained policy)
        stop = {**result.stop, "kept_step": result.best_step}
        folder = Path(task.model_dir)
        scenarios = {}
        for ev in result.evaluations:
            sc = self.scenarios[ev.scenario]
            cost = np.load(folder / ev.costs, allow_pickle=False).astype(float)
            ratios = cost.mean(axis=1) / self.yard[sc.name].metrics["cost"]
            target = rl_steps_to_target(result.curve, ratios, sc.in_distribution)
            extra = {
                "train_steps": result.steps,
                "train_cap": stop["cap"],
                "train_stop": stop["status"],
                "train_last_improvement": stop["last_improvement_step"],
                "train_kept_step": stop["kept_step"],
                "train_wall_s": result.wall_s,
                "data_steps": result.steps,
            }
            metrics = {k: np.asarray(v, dtype=float) for k, v in ev.metrics.items()}
            trace = {}
            if result.seed == 0:
                trace = {k: np.asarray(v, dtype=float)[:1] for k, v in ev.traces.items()}
            scenarios[sc.name] = self._scored(
                sc, result.algo, "rl", result.seed, cost, metrics, trace, online=False,
                steps_to_target=target, extra=extra,
            )  # fmt: skip
        return JobRecord(
            "rl", task.name, job_id(task), _rl_settings(task), scenarios,
            curve=[(int(s), float(c)) for s, c in result.curve],
            diagnostics=_thinned(result.updates), stop=stop, train_key=task.train_key,
            algo=result.algo, seed=int(result.seed), wall_s=float(result.wall_s),
        )  # fmt: skip

    def run(self, plan: RunPlan) -> None:
        """Yardstick runs, then the RL jobs on the workers while the driver evaluates the
        classical controllers (one core's work, which would otherwise leave a worker's core
        idle); each finished job is written to the store at once."""
        from stcgym.agents.executors import run_tasks
        from stcgym.agents.rl.training import train_and_evaluate

        cfg, scenarios, envs = plan.cfg, plan.scenarios, plan.envs
        self.scenarios = {sc.name: sc for sc in scenarios}
        planned = rl_tasks(cfg, scenarios, envs, {}, self.run_dir)
        weights = job_weights(cfg, scenarios, planned)  # (the references ran while planning)
        progress = JobProgress(weights, self.log, cfg.jobs)
        workers = "worker" if cfg.jobs == 1 else "workers"
        kept = frozenset(self.store.ids())
        left = f" (the store holds {len(kept)} records)" if kept else ""
        self.log(
            f"{len(weights)} jobs ({len(planned)} RL trainings on {cfg.jobs} {workers}), "
            f"estimated {format_duration(estimate_seconds(cfg, kept))}{left}"
        )
        for sc in scenarios:
            self._yardstick(sc)
        self.log("yardstick and zero input evaluated on every scenario")
        self._reserve = OUTPUT_SECONDS_PER_SCENARIO * len(scenarios) + REPORT_RESERVE_SECONDS
        if not planned:
            self._leave(self._classical_all(scenarios, progress), [])
            return
        tasks = rl_tasks(cfg, scenarios, envs, plan.curve_references, self.run_dir)
        todo = []
        for task in tasks:
            if self.store.load(task.name, job_id(task)) is not None:
                progress.drop(("rl", task.name))
            else:
                todo.append(task)
        if len(todo) < len(tasks):
            self.log(f"{len(tasks) - len(todo)} finished RL jobs read back from "
                     f"{self.store.folder}")  # fmt: skip
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
                    admit=lambda task: self.fits(weights[("rl", task.name)]),
                ):
                    name = out.task.name
                    ran.add(name)
                    if out.error is not None:
                        failures.append(name)
                        self.log(f"RL job {name} FAILED:\n{out.error}")
                    else:
                        self.store.save(self._record(out.task, out.result))
                    progress.finish(("rl", name), f"{name}, {out.seconds:.0f} s", out.seconds)
                    if classical.done():
                        classical.result()  # the thread's error, raised in this one
            except BaseException:
                # the thread stops at its next run (leaving the block waits for it) and its
                # own error, if any, is dropped
                self.halt.set()
                raise
            unfinished = classical.result()
        if failures:
            raise RuntimeError(f"{len(failures)} RL job(s) failed: {', '.join(failures)}")
        self._leave(unfinished, [t.name for t in todo if t.name not in ran])

    def _leave(self, classical: int, rl: list[str]) -> None:
        """Note what the time limit left for a resumed run (``self.left``)."""
        parts = []
        if rl:
            parts.append(f"{len(rl)} RL job{'s' if len(rl) > 1 else ''} ({', '.join(rl)})")
        if classical:
            parts.append(f"the classical controllers on {classical} scenario(s)")
        self.left = " and ".join(parts)


#: Estimated durations are multiplied by this before a job is started under a time limit (the
#: estimates are for the 2-core development machine and vary with the load).
TIME_LIMIT_MARGIN = 1.25
#: Seconds kept at the end of a time-limited run for the tables and the report, besides
#: ``OUTPUT_SECONDS_PER_SCENARIO`` per scenario.
REPORT_RESERVE_SECONDS = 30.0


class _Stop(Exception):
    """Raised in the classical evaluations when the driver stops (an error or Ctrl-C)."""
