"""The jobs of a ``stcgym bench`` run (classical evaluations, reference runs, RL trainings),
their estimated cost, and the ``job k/N, ETA`` log."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Collection, Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stcgym.agents.benchmark.config import BenchConfig
from stcgym.agents.benchmark.rundir import classical_key, job_id
from stcgym.agents.benchmark.scenarios import Scenario, TrainingEnv, make_scenarios, training_envs
from stcgym.agents.controllers import controllers_for
from stcgym.agents.evaluation.env_spec import EnvSpec
from stcgym.agents.rl.configs import AlgoConfig, with_action_unit

if TYPE_CHECKING:
    from stcgym.agents.rl.training import TrainingTask

__all__ = [
    "SECONDS_PER_EVAL_STEP",
    "SECONDS_PER_EVAL_LANE_STEP",
    "SECONDS_PER_POLICY_STEP",
    "SECONDS_PER_STEP",
    "JobProgress",
    "agent_config",
    "classical_seconds",
    "curve_evaluations",
    "describe_plan",
    "estimate_seconds",
    "format_duration",
    "parse_duration",
    "job_weights",
    "reference_weights",
    "rl_tasks",
    "schedule",
    "tuning_seconds",
]


#: Wall seconds per training env step of one worker on the 2-core development machine, the
#: other core busy with the other worker (torch on one thread, the native vector env): measured
#: on the quick tier's jobs (learning-curve and test episodes taken out) and on the standard
#: run's RecurrentPPO jobs. Only the schedule, the ETA, the announced estimate and
#: ``--time-limit`` use them.
SECONDS_PER_STEP = {
    # PPO's update on 16 lanes x 256 steps, batch 256: 10^6 env steps of training (validation
    # curve included) in 74-78 s per core on the family (results/ladder-l1-standard)
    "ppo": 0.08e-3,
    "ppo_noint": 0.08e-3,
    "oracle_ppo": 0.085e-3,
    "a2c": 0.9e-3,
    # SAC on 8 lanes, 2 gradient steps per vector step (a quarter of one per env step):
    # 10^5 steps of ladder-l1-v1 in 217 s, learning curve included, beside another job (the
    # standard run's family jobs, beside a test suite too: 1.8 x 10^5 steps in 805 s)
    "sac": 2.0e-3,
    "td3": 9.5e-3,
    # RecurrentPPO with PPO's update (16 lanes x 256 steps): 6.8 x 10^5 steps on the family
    # in 358-385 s, learning curves included, beside another job and a test run (the
    # standard run's first two)
    "rppo": 0.56e-3,
    # their estimator or controller on every lane: 1.05-1.2x their base agent's (measured
    # against it in one process)
    "theta_ppo": 0.09e-3,
    "residual_ppo": 0.1e-3,
    "theta_sac": 2.1e-3,
}
#: Seconds per batched step of an RL policy in a learning-curve or evaluation episode (SB3's
#: predict on all lanes at once: about constant up to a few hundred lanes) and per lane.
SECONDS_PER_POLICY_STEP = {"rppo": 1.2e-3}
DEFAULT_POLICY_STEP = 0.5e-3
SECONDS_PER_LANE_STEP = 2e-6
#: Seconds per evaluated step of a batch of classical controllers (python loop around the
#: compiled batch step) and per lane: SISO plants, and MIMO ones (the self-tuning LQ
#: controller solves its Riccati equation every step: its 3 runs of 20 quadruple-tank
#: episodes of 1000 steps took 1.7 s in the quick tier, 2.8e-5 s a lane step, with two RL
#: workers on the same cores; twice that here, as he1 and the larger plants were not timed).
SECONDS_PER_EVAL_STEP = 1.5e-4
SECONDS_PER_EVAL_LANE_STEP = 2.5e-6
SECONDS_PER_MIMO_EVAL_LANE_STEP = 5e-5
#: A worker's start: a fresh process importing torch, SB3 and the compiled kernels.
WORKER_START_SECONDS = 4.0
#: Plots and report per scenario (they are written side by side when ``jobs > 1``).
OUTPUT_SECONDS_PER_SCENARIO = 2.5


def _batch_seconds(spec: EnvSpec, lanes: int, per_step: float, per_lane: float) -> float:
    """A batch of ``lanes`` episodes of ``spec``, in blocks of at most ``MAX_LANES``."""
    from stcgym.agents.evaluation.episodes import MAX_LANES

    blocks = -(-lanes // MAX_LANES)
    return spec.steps * (blocks * per_step + lanes * per_lane)


def classical_seconds(cfg: BenchConfig, sc: Scenario, name: str) -> float:
    """Estimated seconds of every run of the classical controller ``name`` on ``sc``."""
    from stcgym.agents.controllers import CONTROLLERS

    runs = cfg.runs_of(name)
    lane = SECONDS_PER_EVAL_LANE_STEP
    if sc.env.plant_kind == "mimo" and CONTROLLERS[name].online:
        lane = SECONDS_PER_MIMO_EVAL_LANE_STEP
    seconds = runs * _batch_seconds(sc.env, len(sc.episodes.seeds), SECONDS_PER_EVAL_STEP, lane)
    if name == "fixed_pi" and sc.kind in ("nominal", "family", "ladder"):
        # its tuning on the scenario's training split (the held-out and jump scenarios reuse
        # the family's, cached within the process)
        from stcgym.agents.fixed_pi import TUNING_EVALUATIONS, TUNING_PLANTS

        batch = _batch_seconds(sc.env, TUNING_PLANTS, SECONDS_PER_EVAL_STEP, lane)
        seconds += TUNING_EVALUATIONS * batch
    return seconds


def curve_evaluations(task: TrainingTask) -> int:
    """How many learning-curve evaluations an RL job runs at its cap: step 0, then the first
    rollout boundary at or after each checkpoint (checkpoints inside one rollout share it)."""
    from stcgym.agents.rl.sb3 import curve_checkpoints

    hp = task.config.hyperparams
    step = hp.get("n_steps", hp.get("train_freq", 1))  # (train_freq may be (n, "episode"))
    per_rollout = max(1, (step if isinstance(step, int) else 1) * int(task.config.n_envs))
    marks = curve_checkpoints(task.steps, task.curve_points, task.eval_interval)
    boundaries = {-(-m // per_rollout) * per_rollout for m in marks if m > 0}
    return 1 + len(boundaries)


def job_weights(
    cfg: BenchConfig, scenarios: Sequence[Scenario], tasks: Sequence[TrainingTask]
) -> dict:
    """Estimated seconds of every job, RL jobs at their cap (the plateau rule may stop them
    earlier; the ETA then adapts): training steps, learning-curve episodes and evaluation
    episodes of the policy, classical controllers on the scenarios."""
    out = {
        ("classical", sc.name): sum(
            classical_seconds(cfg, sc, name) for name in controllers_for(cfg.classical, sc.env)
        )
        for sc in scenarios
    }
    for t in tasks:
        per_step = SECONDS_PER_POLICY_STEP.get(t.algo, DEFAULT_POLICY_STEP)
        lanes = len(t.curve_episodes.seeds)
        curve_s = _batch_seconds(t.curve_env, lanes, per_step, SECONDS_PER_LANE_STEP)
        evals = sum(
            _batch_seconds(e.env, len(e.episodes.seeds), per_step, SECONDS_PER_LANE_STEP)
            for e in t.evaluations
        )
        train = t.steps * SECONDS_PER_STEP.get(t.algo, 5e-3)
        out[("rl", t.name)] = train + curve_evaluations(t) * curve_s + evals
    return out


def schedule(weights: Sequence[float], jobs: int) -> list[float]:
    """Each worker's busy seconds when ``jobs`` workers take the jobs in the given order, the
    next job going to the first free worker (as the process pool does), each worker paying
    :data:`WORKER_START_SECONDS` once."""
    workers = [WORKER_START_SECONDS] * max(1, min(int(jobs), len(weights)))
    for w in weights:
        i = min(range(len(workers)), key=workers.__getitem__)
        workers[i] += w
    return workers if weights else []


def reference_weights(cfg: BenchConfig, envs: dict[str, TrainingEnv]) -> dict:
    """Estimated seconds of the reference runs: the yardstick on the training episodes that set
    each action bound and on the learning-curve episodes."""
    per_step, lane = SECONDS_PER_EVAL_STEP, SECONDS_PER_EVAL_LANE_STEP
    return {
        ("reference", key): _batch_seconds(env.train, len(env.bound_episodes.seeds), per_step, lane)
        + _batch_seconds(env.curve, len(env.curve_episodes.seeds), per_step, lane)
        for key, env in envs.items()
    }


#: Learning-curve evaluations of one RL tuning trial (step 0 and its two curve points).
TUNING_CURVE_EVALUATIONS = 3


def tuning_seconds(cfg: BenchConfig, envs: dict[str, TrainingEnv]) -> float:
    """Estimated wall seconds of the tuning studies (:meth:`_RunState.tune`): each tuned RL
    agent's trials on one worker, the studies side by side, then the self-tuning controller's
    trials in the driver."""
    if not cfg.tune_trials or "family" not in envs:
        return 0.0
    env = envs["family"]
    lanes = len(env.curve_episodes.seeds)
    studies = []
    for algo in cfg.tuned_rl_agents:
        per_step = SECONDS_PER_POLICY_STEP.get(algo, DEFAULT_POLICY_STEP)
        curve = _batch_seconds(env.curve, lanes, per_step, SECONDS_PER_LANE_STEP)
        steps = max(1, int(cfg.tune_fraction * cfg.family_train_steps[algo]))
        trial = steps * SECONDS_PER_STEP.get(algo, 5e-3) + TUNING_CURVE_EVALUATIONS * curve
        studies.append(cfg.tune_trials * trial)
    rl = max(schedule(studies, cfg.jobs)) if studies else 0.0
    stc = 0.0
    if "stc_tuned" in cfg.agents:
        per_step, lane = SECONDS_PER_EVAL_STEP, SECONDS_PER_EVAL_LANE_STEP
        stc = cfg.tune_trials * _batch_seconds(env.curve, lanes, per_step, lane)
    return rl + stc


def estimate_seconds(cfg: BenchConfig, kept: frozenset[str] = frozenset()) -> float:
    """Rough wall time of ``cfg`` on ``cfg.jobs`` cores (announced before long runs).

    The reference runs come first, in the driver, then the tuning studies (with tuning
    trials: :func:`tuning_seconds`); then the RL jobs on ``cfg.jobs`` workers,
    longest first, while the driver evaluates the classical controllers (their work shares
    the cores); then the plots and the report, side by side.

    ``kept`` holds the ids of the records a store already has (:meth:`~stcgym.agents.
    benchmark.store.ResultsStore.ids`): those jobs are left out, and so are the tuning
    studies where ``cfg`` carries their outcome, as a resumed run skips them. The default
    (nothing kept) is the run from an empty store.
    """
    scenarios = make_scenarios(cfg)
    envs = training_envs(cfg, scenarios)
    tasks = rl_tasks(cfg, scenarios, envs, {})
    weights = job_weights(cfg, scenarios, tasks)
    classical = sum(
        classical_seconds(cfg, sc, name) * _share_left(cfg, sc, name, kept)
        for sc in scenarios
        for name in controllers_for(cfg.classical, sc.env)
    )
    references = sum(reference_weights(cfg, envs).values())
    rl = [weights[("rl", t.name)] for t in tasks if job_id(t) not in kept]
    cores = max(1, cfg.jobs)
    if not rl:
        train = classical
    else:
        # the classical evaluations take their share of the cores from the workers
        train = max(schedule(rl, cfg.jobs)) + classical / cores
    tuning = 0.0 if kept and cfg.tuned else tuning_seconds(cfg, envs)
    output = OUTPUT_SECONDS_PER_SCENARIO * len(scenarios) * (1 if cores > 1 else 2)
    return references + tuning + train + output


def _share_left(cfg: BenchConfig, sc: Scenario, name: str, kept: frozenset[str]) -> float:
    """The share of the runs of classical controller ``name`` on ``sc`` not in ``kept``."""
    if not kept:
        return 1.0
    runs = cfg.runs_of(name)
    return (runs - _runs_kept(cfg, sc, name, kept)) / runs


def _runs_kept(cfg: BenchConfig, sc: Scenario, name: str, kept: Collection[str]) -> int:
    """How many runs of classical controller ``name`` on ``sc`` have their record in
    ``kept``."""
    return sum(classical_key(cfg, sc, name, r)[1] in kept for r in range(cfg.runs_of(name)))


def parse_duration(text: str) -> float:
    """Seconds of a duration written ``2h45m``, ``90m``, ``1h``, ``45s``, ``1.5h`` or ``3600``
    (seconds); :class:`~stcgym.agents.benchmark.config.BenchInputError` otherwise."""
    import re

    from stcgym.agents.benchmark.config import BenchInputError

    units = {"h": 3600.0, "m": 60.0, "s": 1.0}
    spec = str(text).strip().lower()
    parts = re.findall(r"(\d+(?:\.\d+)?)([hms])", spec)
    if re.fullmatch(r"\d+(?:\.\d+)?", spec):
        seconds = float(spec)
    elif parts and "".join(f"{v}{u}" for v, u in parts) == spec:
        seconds = sum(float(v) * units[u] for v, u in parts)
    else:
        seconds = math.nan
    if not (math.isfinite(seconds) and seconds > 0):
        raise BenchInputError(
            f"--time-limit must be a positive duration such as 2h45m, 90m or 3600 (seconds), "
            f"got {text!r}"
        )
    return seconds


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


def agent_config(cfg: BenchConfig, algo: str, key: str) -> AlgoConfig:
    """The config ``algo`` trains with on the training distribution ``key``: the run's, with
    the distribution's action unit where the config asks for the measured one (training
    measures it itself when the run has none for ``key``)."""
    config = AlgoConfig.from_dict(cfg.algo_configs[algo])
    unit = cfg.action_units.get(key)
    return config if unit is None else with_action_unit(config, unit)


def rl_tasks(
    cfg: BenchConfig,
    scenarios: Sequence[Scenario],
    envs: dict[str, TrainingEnv],
    references: dict[str, list[float]],
    run_dir: Path | None = None,
) -> list[TrainingTask]:
    """The RL jobs, longest first by :func:`job_weights`; ``references`` holds the yardstick's
    cost on each learning-curve episode of every training key."""
    from stcgym.agents.rl.training import Evaluation, TrainingTask

    tasks = []
    folder = Path("models") if run_dir is None else run_dir / "models"
    tb = None if cfg.tensorboard_log is None else str(Path(cfg.tensorboard_log) / cfg.run)
    for key, env in envs.items():
        for algo in cfg.rl_agents:
            if not cfg.trains_on(algo, key):
                continue
            users = [sc for sc in scenarios if sc.train_key_for(algo) == key]
            if not users:
                continue
            evaluations = tuple(Evaluation(sc.name, sc.env, sc.episodes) for sc in users)
            reference = references.get(key)
            for ts in range(cfg.train_seeds):
                task = TrainingTask(
                    algo=algo,
                    config=agent_config(cfg, algo, key),
                    seed=ts,
                    steps=cfg.cap(algo, key),
                    eval_interval=cfg.eval_interval_for(algo, key),
                    plateau=cfg.plateau,
                    train_key=key,
                    train_env=env.train,
                    curve_env=env.curve,
                    curve_episodes=env.curve_episodes,
                    curve_points=cfg.curve_points,
                    curve_reference=None if reference is None else tuple(reference),
                    evaluations=evaluations,
                    model_dir="",
                    tensorboard_log=tb,
                    progress=cfg.progress if cfg.jobs == 1 else False,
                )
                tasks.append(replace(task, model_dir=str(folder / task.name)))
    # longest first (training, curve and evaluation episodes), so that the workers finish
    # together: a long job taken last would leave the other worker idle
    cost = job_weights(cfg, [], tasks)
    return sorted(tasks, key=lambda t: -cost[("rl", t.name)])


def describe_plan(cfg: BenchConfig) -> str:
    """The jobs of ``cfg`` with their estimated seconds, those its run folder's store already
    holds marked ``kept``, and the whole run's estimate (``stcgym bench --plan``)."""
    from stcgym.agents.benchmark.metrics_csv import METRIC_COLUMNS
    from stcgym.agents.benchmark.store import STORE_FOLDER, ResultsStore

    scenarios = make_scenarios(cfg)
    envs = training_envs(cfg, scenarios)
    tasks = rl_tasks(cfg, scenarios, envs, {})
    weights = job_weights(cfg, scenarios, tasks)
    kept = ResultsStore(cfg.run_dir / STORE_FOLDER, METRIC_COLUMNS).ids()
    lines = [f"stcgym bench plan: {cfg.mode} tier, run folder {cfg.run_dir}", ""]
    lines.append("classical evaluations (the driver), estimated seconds:")
    for sc in scenarios:
        names = controllers_for(cfg.classical, sc.env)
        cells = []
        for name in names:
            held = _runs_kept(cfg, sc, name, kept)
            cells.append(f"{name} x{cfg.runs_of(name)}" + (f" ({held} kept)" if held else ""))
        lines.append(f"  {sc.name} ({len(sc.episodes.seeds)} episodes): {', '.join(cells)}; "
                     f"{weights[('classical', sc.name)]:.0f} s")  # fmt: skip
    tuning = tuning_seconds(cfg, envs)
    if tuning:
        studies = [*cfg.tuned_rl_agents, *(["stc"] if "stc_tuned" in cfg.agents else [])]
        lines += ["", f"tuning before the jobs: {cfg.tune_trials} Optuna trials each for "
                  f"{', '.join(studies)}; {format_duration(tuning)}"]  # fmt: skip
    if tasks:
        lines += ["", f"RL training jobs ({len(tasks)}, longest first; at their cap):"]
        for t in tasks:
            mark = "  kept" if job_id(t) in kept else ""
            lines.append(f"  {t.name}: cap {t.steps} env steps, "
                         f"{format_duration(weights[('rl', t.name)])}{mark}")  # fmt: skip
    lines += [
        "",
        f"estimated wall time on {cfg.jobs} worker(s), from an empty store: "
        f"{format_duration(estimate_seconds(cfg))} (every RL agent at its cap; the plateau "
        "rule can only shorten a run)",
    ]
    if kept:
        left = sum(job_id(t) not in kept for t in tasks)
        lines.append(
            f"still to run, the store holding the rest: {left} of the {len(tasks)} RL jobs, "
            f"estimated {format_duration(estimate_seconds(cfg, frozenset(kept)))}"
        )
    return "\n".join(lines)
