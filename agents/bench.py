"""``stcgym bench``: the self-tuning controller against RL agents and known-model oracles.

Scenarios
---------
``nominal:P``
    Plant ``P``. RL agents are trained on ``P`` and evaluated on ``P``.
``family:P``
    RL agents are trained on episodes drawn at random from the training family
    (``family_train``) and evaluated on the held-out plant ``P`` (``family_test``); the
    self-tuning controller meets ``P`` for the first time, as in every episode.
``jump:SPEC``
    The plant's parameters jump in the middle of the episode (step ``T/2``). ``SPEC`` is
    ``timevarying2`` (the catalogue's jump: ``stable2`` to ``TIMEVARYING2_AFTER``) or
    ``A:B`` (plant ``A`` jumping to plant ``B``). RL agents are the ones trained on the
    pre-jump plant (``nominal:A``): the jump is as new to them as to the self-tuning
    controller. The known-model oracle is told the new parameters at the jump.

Every controller meets the same episodes: evaluation seed ``s`` means ``env.reset(seed=s)``
(same noise, same reference) for all of them; the loop and the metrics are those of
:mod:`stcgym.agents.evaluate`.

Controllers
-----------
``ppo``, ``sac``, ``td3``, ``a2c``: Stable-Baselines3 agents (:mod:`stcgym.agents.sb3`), one
model per training environment and training seed. ``stc``: :class:`~stcgym.adaptive.controller.
SelfTuningController` with its defaults. ``oracle``: :class:`~stcgym.adaptive.oracles.
KnownModelController`, the same design on the true parameters. ``lqg``:
:class:`~stcgym.adaptive.oracles.LQGController`, the optimal linear controller for the bench's
cost on the true (pre-jump) parameters.

Output (``<out>/<run>/``): ``config.json`` (written first), ``metrics.csv`` (one row per
controller x scenario x seed, appended and flushed row by row, so an interrupted run keeps
every finished row), ``learning_curves.csv``, ``report.md``, PNG plots and ``models/``.
"""

from __future__ import annotations

import csv
import datetime as _dt
import json
import math
import os
import platform
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from stcgym.agents.configs import ALGORITHMS, AlgoConfig, apply_overrides, default_config
from stcgym.agents.evaluate import EnvSpec, Episode, evaluate
from stcgym.envs.catalogue import TIMEVARYING2_AFTER, get_plant, plant_names

__all__ = [
    "BenchConfig",
    "BenchInputError",
    "CONTROLLERS",
    "METRIC_COLUMNS",
    "Scenario",
    "build_config",
    "run_bench",
]

#: Columns of ``metrics.csv``, in order.
METRIC_COLUMNS = [
    "scenario",
    "kind",
    "plant",
    "controller",
    "family",
    "seed",
    "train_seed",
    "cost",
    "cost_start",
    "cost_steady",
    "cost_post_jump",
    "reconverge_steps",
    "effort",
    "bounded",
    "steps_run",
    "clip_frac",
    "data_steps",
    "train_steps",
    "train_wall_s",
    "step_us",
]

SCENARIO_KINDS = ("nominal", "family", "jump")


class BenchInputError(ValueError):
    """Bad bench input (names, budgets, output folder, dependencies), raised before training."""


# ---------------------------------------------------------------------------------- config
@dataclass
class BenchConfig:
    """Everything a bench run depends on; ``config.json`` is this, as written."""

    run: str
    out: str = "results"
    mode: str = "quick"
    scenarios: list[str] = field(default_factory=lambda: list(SCENARIO_KINDS))
    plants: list[str] = field(default_factory=lambda: ["stable2", "unstable2"])
    family_train: list[str] = field(default_factory=lambda: ["stable2", "unstable2", "integrator2"])
    family_test: list[str] = field(default_factory=lambda: ["lightly_damped2", "nonminphase2"])
    jumps: list[str] = field(default_factory=lambda: ["timevarying2"])
    agents: list[str] = field(default_factory=lambda: ["ppo", "sac", "td3", "stc", "oracle", "lqg"])
    train_steps: dict[str, int] = field(default_factory=dict)
    train_seeds: int = 1
    seeds: int = 5
    first_seed: int = 1000
    episode_steps: int = 1000
    train_episode_steps: int = 500
    train_y_bound: float | None = None
    noise_std: float = 0.05
    control_cost: float = 0.01
    action_bound: float = 10.0
    curve_points: int = 10
    curve_seeds: int = 2
    algo_configs: dict[str, dict[str, Any]] = field(default_factory=dict)
    overrides: list[str] = field(default_factory=list)
    plots: bool = True
    progress: bool | None = None

    @property
    def run_dir(self) -> Path:
        return Path(self.out) / self.run

    @property
    def rl_agents(self) -> list[str]:
        return [a for a in self.agents if a in ALGORITHMS]

    @property
    def eval_seeds(self) -> list[int]:
        return [self.first_seed + i for i in range(self.seeds)]

    def env_spec(self, plants: Sequence[str], steps: int, **kw: Any) -> EnvSpec:
        return EnvSpec(
            tuple(plants),
            steps=steps,
            noise_std=self.noise_std,
            control_cost=self.control_cost,
            action_bound=self.action_bound,
            **kw,
        )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


QUICK = dict(
    mode="quick",
    plants=["stable2", "unstable2"],
    jumps=["timevarying2"],
    agents=["ppo", "sac", "td3", "stc", "oracle", "lqg"],
    train_seeds=1,
    seeds=5,
    episode_steps=1000,
)
FULL = dict(
    mode="full",
    plants=["stable2", "lightly_damped2", "unstable2", "nonminphase2", "integrator2", "stable4"],
    jumps=["timevarying2", "stable2:unstable2"],
    agents=["ppo", "sac", "td3", "a2c", "stc", "oracle", "lqg"],
    train_seeds=3,
    seeds=20,
    episode_steps=2000,
)


def _split(value: str | Sequence[str] | None) -> list[str] | None:
    if value is None:
        return None
    items = value.split(",") if isinstance(value, str) else list(value)
    return [s.strip().lower() for s in items if s.strip()]


def _positive_int(value: Any, name: str) -> int:
    try:
        v = int(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive integer, got {value!r}") from None
    if v != float(value) or v <= 0:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return v


def parse_train_steps(value: str | int | dict | None, algos: Sequence[str]) -> dict[str, int]:
    """``"20000"`` (every algorithm) or ``"ppo=40000,sac=10000"`` -> ``{algo: steps}``."""
    if value is None or value == "":
        return {}
    if isinstance(value, dict):
        items = list(value.items())
    elif isinstance(value, int) or "=" not in str(value):
        return {a: _positive_int(value, "--train-steps") for a in algos}
    else:
        items = [tuple(p.split("=", 1)) for p in str(value).split(",") if p.strip()]
    out = {}
    for algo, steps in items:
        key = str(algo).strip().lower()
        if key not in ALGORITHMS:
            raise ValueError(f"--train-steps: unknown RL algorithm {algo!r} ({sorted(ALGORITHMS)})")
        out[key] = _positive_int(steps, f"--train-steps {key}")
    return out


def build_config(
    *,
    quick: bool = True,
    run: str | None = None,
    out: str = "results",
    scenarios: str | Sequence[str] | None = None,
    plants: str | Sequence[str] | None = None,
    family_train: str | Sequence[str] | None = None,
    family_test: str | Sequence[str] | None = None,
    jumps: str | Sequence[str] | None = None,
    agents: str | Sequence[str] | None = None,
    train_steps: str | int | dict | None = None,
    train_seeds: int | None = None,
    seeds: int | None = None,
    first_seed: int = 1000,
    episode_steps: int | None = None,
    train_episode_steps: int | None = None,
    noise_std: float = 0.05,
    train_y_bound: float | None = None,
    hp: Sequence[str] = (),
    curve_points: int = 10,
    plots: bool = True,
    progress: bool | None = None,
) -> BenchConfig:
    """Build and validate a :class:`BenchConfig` (raises ``ValueError`` on bad input).

    Defaults come from the quick or full preset; every list argument takes a comma-separated
    string or a sequence. Nothing is trained or written here.
    """
    preset = QUICK if quick else FULL
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    cfg = BenchConfig(run=run or f"{stamp}-{preset['mode']}", out=str(out))
    for key, value in preset.items():
        setattr(cfg, key, value if not isinstance(value, list) else list(value))
    for name, value in (
        ("scenarios", scenarios),
        ("plants", plants),
        ("family_train", family_train),
        ("family_test", family_test),
        ("jumps", jumps),
        ("agents", agents),
    ):
        parsed = _split(value)
        if parsed is not None:
            setattr(cfg, name, parsed)
    if train_seeds is not None:
        cfg.train_seeds = train_seeds
    if seeds is not None:
        cfg.seeds = seeds
    if episode_steps is not None:
        cfg.episode_steps = episode_steps
    if train_episode_steps is not None:
        cfg.train_episode_steps = train_episode_steps
    cfg.first_seed, cfg.noise_std = int(first_seed), float(noise_std)
    cfg.train_y_bound = None if train_y_bound is None else float(train_y_bound)
    cfg.curve_points, cfg.plots, cfg.progress = curve_points, bool(plots), progress
    cfg.overrides = list(hp)
    try:
        validate(cfg, train_steps)
    except BenchInputError:
        raise
    except ValueError as exc:
        raise BenchInputError(str(exc)) from exc
    return cfg


def validate(cfg: BenchConfig, train_steps: str | int | dict | None = None) -> None:
    """Check every input, fill in training budgets and algorithm configs; raise ``ValueError``."""
    if not cfg.run or any(c in cfg.run for c in "/\\") or cfg.run in (".", ".."):
        raise ValueError(f"run name must be a plain folder name, got {cfg.run!r}")
    unknown = [s for s in cfg.scenarios if s not in SCENARIO_KINDS]
    if unknown or not cfg.scenarios:
        raise ValueError(f"scenarios must be a non-empty subset of {SCENARIO_KINDS}, got {unknown}")
    unknown = [a for a in cfg.agents if a not in ALGORITHMS and a not in CONTROLLERS]
    if unknown or not cfg.agents:
        raise ValueError(
            f"unknown agent(s) {unknown}; choose from {sorted(ALGORITHMS) + sorted(CONTROLLERS)}"
        )
    if len(set(cfg.agents)) != len(cfg.agents):
        raise ValueError(f"agents listed twice: {cfg.agents}")
    names = set(plant_names())
    for what in ("plants", "family_train", "family_test"):
        bad = [p for p in getattr(cfg, what) if p not in names]
        if bad:
            raise ValueError(f"unknown plant(s) {bad} in {what}; catalogue: {sorted(names)}")
    if "nominal" in cfg.scenarios and not cfg.plants:
        raise ValueError("the nominal scenario needs at least one plant (--plants)")
    if "family" in cfg.scenarios:
        if not cfg.family_train or not cfg.family_test:
            raise ValueError("the family scenario needs --family-train and --family-test plants")
        overlap = sorted(set(cfg.family_train) & set(cfg.family_test))
        if overlap:
            raise ValueError(f"held-out plants {overlap} are also in the training family")
        orders = {get_plant(p).n for p in cfg.family_train + cfg.family_test}
        if len(orders) > 1:
            raise ValueError("family_train and family_test plants must share one order")
    if "jump" in cfg.scenarios:
        if not cfg.jumps:
            raise ValueError("the jump scenario needs at least one --jump")
        for spec in cfg.jumps:
            parse_jump(spec)
    for name in ("train_seeds", "seeds", "episode_steps", "train_episode_steps", "curve_points"):
        setattr(cfg, name, _positive_int(getattr(cfg, name), f"--{name.replace('_', '-')}"))
    if cfg.episode_steps < 20:
        raise ValueError(f"--episode-steps must be >= 20, got {cfg.episode_steps}")
    if not (math.isfinite(cfg.noise_std) and cfg.noise_std >= 0):
        raise ValueError(f"--noise must be a finite number >= 0, got {cfg.noise_std}")
    if cfg.train_y_bound is not None and not (
        math.isfinite(cfg.train_y_bound) and cfg.train_y_bound > 0
    ):
        raise ValueError(f"--train-y-bound must be a positive number, got {cfg.train_y_bound}")
    if cfg.noise_std == 0 and "lqg" in cfg.agents:
        raise ValueError("the lqg oracle needs --noise > 0 (its Kalman filter assumes it)")
    # Training budgets and configs: defaults of the mode, then --train-steps and --hp.
    configs = {a: default_config(a) for a in cfg.rl_agents}
    apply_overrides(configs, cfg.overrides)
    given = parse_train_steps(train_steps, cfg.rl_agents)
    extra = sorted(set(given) - set(cfg.rl_agents))
    if extra and isinstance(train_steps, str) and "=" in train_steps:
        raise ValueError(f"--train-steps names {extra}, which are not among --agents")
    cfg.train_steps = {
        a: given.get(a, configs[a].quick_steps if cfg.mode == "quick" else configs[a].full_steps)
        for a in cfg.rl_agents
    }
    cfg.algo_configs = {a: configs[a].to_dict() for a in cfg.rl_agents}
    for a, c in configs.items():
        _positive_int(c.n_envs, f"{a}.n_envs")


def parse_jump(spec: str) -> tuple[str, str, tuple[float, ...]]:
    """``"timevarying2"`` or ``"A:B"`` -> ``(label, pre-jump plant, post-jump theta)``."""
    s = spec.strip().lower()
    if s == "timevarying2":
        return s, "stable2", tuple(TIMEVARYING2_AFTER[0] + TIMEVARYING2_AFTER[1])
    if ":" not in s:
        raise ValueError(
            f"--jump must be 'timevarying2' or 'BEFORE:AFTER' plant names, got {spec!r}"
        )
    before, after = (p.strip() for p in s.split(":", 1))
    a, b = get_plant(before), get_plant(after)  # raises on unknown names
    if a.n != b.n:
        raise ValueError(f"--jump {spec!r}: both plants must have the same order")
    if before == after:
        raise ValueError(f"--jump {spec!r}: the plant must change")
    return f"{before}>{after}", before, tuple(b.theta)


# ---------------------------------------------------------------------------------- scenarios
@dataclass(frozen=True)
class Scenario:
    """One evaluation setting: environment, plant and the RL training environment it uses."""

    name: str
    kind: str
    env: EnvSpec
    plant: str
    train_key: str
    jump_to: tuple[float, ...] | None = None


def make_scenarios(cfg: BenchConfig) -> list[Scenario]:
    T = cfg.episode_steps
    out: list[Scenario] = []
    if "nominal" in cfg.scenarios:
        for p in cfg.plants:
            out.append(Scenario(f"nominal:{p}", "nominal", cfg.env_spec([p], T), p, f"nominal:{p}"))
    if "family" in cfg.scenarios:
        for p in cfg.family_test:
            out.append(Scenario(f"family:{p}", "family", cfg.env_spec([p], T), p, "family"))
    if "jump" in cfg.scenarios:
        for spec in cfg.jumps:
            label, before, theta = parse_jump(spec)
            env = cfg.env_spec([before], T, jump_step=T // 2, jump_to=theta)
            out.append(Scenario(f"jump:{label}", "jump", env, before, f"nominal:{before}", theta))
    return out


def training_envs(
    cfg: BenchConfig, scenarios: Sequence[Scenario]
) -> dict[str, tuple[EnvSpec, EnvSpec]]:
    """``train_key -> (training env, learning-curve env)`` for every key the scenarios use.

    The training environment is the evaluation one, with shorter episodes; ``train_y_bound``
    (times the reference amplitude) optionally replaces the divergence bound, so that training
    episodes end (and are charged to the end, see :class:`~stcgym.agents.wrappers.
    TrainingReward`) earlier. In our tests a bound of 10 got SAC and TD3 out of a saturated
    local optimum on ``unstable2`` but made exploration end episodes all the time on the
    high-gain ``stable2`` and ruined them there, so the default keeps the environment's bound.
    The learning curve is always measured on the evaluation settings.
    """
    envs: dict[str, tuple[EnvSpec, EnvSpec]] = {}
    for sc in scenarios:
        if sc.train_key in envs:
            continue
        plants = cfg.family_train if sc.train_key == "family" else [sc.train_key.split(":", 1)[1]]
        curve = cfg.env_spec(plants, cfg.train_episode_steps)
        train = curve
        if cfg.train_y_bound is not None:
            train = cfg.env_spec(
                plants, cfg.train_episode_steps, y_bound=cfg.train_y_bound * curve.amplitude
            )
        envs[sc.train_key] = (train, curve)
    return envs


# ---------------------------------------------------------------------------------- controllers
class _SwitchingOracle:
    """Known-model oracle told the true parameters at the jump (policy protocol)."""

    def __init__(self, base: Any, jump_step: int, theta: Sequence[float]) -> None:
        n = len(theta) // 2
        self.base, self.jump_step = base, int(jump_step)
        self.after = (np.asarray(theta[:n]), np.asarray(theta[n:]))
        self._k = 0

    def reset(self) -> None:
        self.base.reset()  # also restores the initial (pre-jump) model
        self._k = 0

    def predict(
        self, observation: Any, state: Any = None, episode_start: Any = None, deterministic=True
    ) -> tuple[Any, Any]:
        if episode_start is not None and np.any(episode_start):
            self.reset()
        # The schedule's value at step J governs the transition J -> J+1, so the model is
        # switched before the input of step J is chosen.
        if self._k == self.jump_step:
            self.base.set_model(*self.after)
        self._k += 1
        return self.base.predict(observation, state, None, deterministic)


@dataclass(frozen=True)
class ControllerInfo:
    """A classical controller of the bench.

    ``build(cfg, scenario) -> factory(plant_spec) -> policy``; ``online`` marks a controller that
    learns from the episode (its data use is the episode's steps).
    """

    kind: str
    build: Callable[[BenchConfig, Scenario], Callable[[Any], Any]]
    online: bool = False
    description: str = ""


def _stc(cfg: BenchConfig, sc: Scenario) -> Callable[[Any], Any]:
    from stcgym.adaptive.controller import SelfTuningController

    return lambda plant: SelfTuningController(plant.n, action_bound=cfg.action_bound)


def _oracle(cfg: BenchConfig, sc: Scenario) -> Callable[[Any], Any]:
    from stcgym.adaptive.oracles import KnownModelController

    def factory(plant: Any) -> Any:
        base = KnownModelController(plant.a, plant.b, action_bound=cfg.action_bound)
        if sc.env.jump_step is None:
            return base
        return _SwitchingOracle(base, sc.env.jump_step, sc.jump_to)

    return factory


def _lqg(cfg: BenchConfig, sc: Scenario) -> Callable[[Any], Any]:
    from stcgym.adaptive.oracles import LQGController

    return lambda plant: LQGController(
        plant.a,
        plant.b,
        control_cost=cfg.control_cost,
        noise_std=cfg.noise_std,
        action_bound=cfg.action_bound,
    )


#: Classical controllers by name (tests may register more).
CONTROLLERS: dict[str, ControllerInfo] = {
    "stc": ControllerInfo("adaptive", _stc, True, "self-tuning controller (KF-MILS, defaults)"),
    "oracle": ControllerInfo(
        "oracle", _oracle, False, "known-model controller (regulator's design, true parameters)"
    ),
    "lqg": ControllerInfo("oracle", _lqg, False, "LQG on the true pre-jump parameters"),
}


# ---------------------------------------------------------------------------------- output
class MetricsWriter:
    """Append rows to ``metrics.csv``, flushed to disk one by one."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.rows: list[dict[str, Any]] = []
        new = not path.exists() or path.stat().st_size == 0
        self._fh = open(path, "a", newline="")  # noqa: SIM115  (kept open for the whole run)
        self._csv = csv.DictWriter(self._fh, METRIC_COLUMNS, extrasaction="ignore")
        if new:
            self._csv.writeheader()
            self._flush()

    def _flush(self) -> None:
        self._fh.flush()
        os.fsync(self._fh.fileno())

    def write(self, row: dict[str, Any]) -> None:
        self._csv.writerow({k: _fmt(row.get(k, "")) for k in METRIC_COLUMNS})
        self._flush()
        self.rows.append(row)

    def close(self) -> None:
        self._fh.close()


def _fmt(v: Any) -> Any:
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v:.6g}"
    return v


def _check_writable(folder: Path) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / ".write-test"
        probe.write_text("ok")
        probe.unlink()
    except OSError as exc:
        raise BenchInputError(f"output folder {folder} cannot be written: {exc}") from exc


def _check_dependencies(cfg: BenchConfig) -> None:
    missing = []
    if cfg.rl_agents:
        for mod in ("stable_baselines3", "torch"):
            try:
                __import__(mod)
            except ImportError:
                missing.append(f"{mod} (pip install 'stcgym[rl]')")
        if cfg.progress:
            for mod in ("tqdm", "rich"):
                try:
                    __import__(mod)
                except ImportError:
                    missing.append(f"{mod} for the progress bar (pip install 'stcgym[rl]')")
    if cfg.plots:
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            missing.append("matplotlib for the plots (pip install 'stcgym[plot]' or --no-plots)")
    if missing:
        raise BenchInputError("missing dependencies: " + "; ".join(missing))


def _versions() -> dict[str, str]:
    out = {"python": platform.python_version(), "platform": platform.platform()}
    for mod in ("numpy", "gymnasium", "control", "stable_baselines3", "torch"):
        try:
            out[mod] = __import__(mod).__version__
        except ImportError:
            pass
    return out


# ---------------------------------------------------------------------------------- run
@dataclass
class BenchResult:
    """What :func:`run_bench` produced (also on disk under ``run_dir``)."""

    run_dir: Path
    rows: list[dict[str, Any]]
    curves: list[dict[str, Any]]
    wall_s: float


def prepare_run_dir(cfg: BenchConfig, overwrite: bool = False) -> Path:
    """Create ``<out>/<run>``; refuse to mix two runs in one folder."""
    run_dir = cfg.run_dir
    _check_writable(Path(cfg.out))
    if (run_dir / "metrics.csv").exists() and not overwrite:
        raise BenchInputError(
            f"{run_dir} already holds a run; pick another --run or pass --overwrite"
        )
    _check_writable(run_dir)
    if overwrite:
        for name in ("metrics.csv", "learning_curves.csv", "report.md"):
            (run_dir / name).unlink(missing_ok=True)
    return run_dir


def run_bench(
    cfg: BenchConfig,
    *,
    overwrite: bool = False,
    log: Callable[[str], None] | None = None,
    argv: Sequence[str] | None = None,
) -> BenchResult:
    """Run the bench described by a validated ``cfg`` (see :func:`build_config`).

    All checks (names, budgets, dependencies, output folder) happen before anything is
    trained. Rows are appended to ``metrics.csv`` as episodes finish; on ``KeyboardInterrupt``
    (or any error) the finished rows stay, a partial ``report.md`` is written and the exception
    is re-raised.
    """
    t_start = time.perf_counter()
    log = log or (lambda msg: print(msg, file=sys.stderr, flush=True))
    _check_dependencies(cfg)
    scenarios = make_scenarios(cfg)
    run_dir = prepare_run_dir(cfg, overwrite)
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
        "versions": _versions(),
        "started": _dt.datetime.now().isoformat(timespec="seconds"),
    }
    (run_dir / "config.json").write_text(json.dumps(config_doc, indent=2))
    writer = MetricsWriter(run_dir / "metrics.csv")
    state = _RunState(cfg, run_dir, writer, log, t_start)
    from stcgym.agents.report import write_report

    try:
        state.run(scenarios)
    except BaseException as exc:  # Ctrl-C or a crash: keep what is finished, then re-raise
        writer.close()
        what = "interrupted" if isinstance(exc, KeyboardInterrupt) else f"failed ({exc!r})"
        log(f"{what}: {len(writer.rows)} finished rows kept in {run_dir / 'metrics.csv'}")
        try:
            write_report(
                run_dir,
                cfg,
                scenarios,
                writer.rows,
                state.curves,
                state.reference_lines,
                time.perf_counter() - t_start,
                interrupted=True,
            )
        except Exception as report_exc:  # never mask the original error
            log(f"could not write the partial report: {report_exc!r}")
        raise
    writer.close()
    wall = time.perf_counter() - t_start
    write_report(run_dir, cfg, scenarios, writer.rows, state.curves, state.reference_lines, wall)
    if cfg.plots:
        from stcgym.agents.plots import write_plots

        write_plots(
            run_dir,
            cfg,
            scenarios,
            state.traces,
            state.jump_costs,
            state.curves,
            state.reference_lines,
        )
    log(f"done in {wall:.0f} s: {run_dir}")
    return BenchResult(run_dir, writer.rows, state.curves, wall)


class _RunState:
    """The bench's loop: classical controllers first (fast), then each RL training job."""

    def __init__(self, cfg, run_dir, writer, log, t0) -> None:
        self.cfg, self.run_dir, self.writer, self._log, self.t0 = cfg, run_dir, writer, log, t0
        self.traces: dict[tuple[str, str], Episode] = {}  # (scenario, controller) -> seed-0 run
        self.jump_costs: dict[tuple[str, str], list[Any]] = {}
        self.curves: list[dict[str, Any]] = []
        # training key -> controller -> curve-metric cost (horizontal lines of the curve plot)
        self.reference_lines: dict[str, dict[str, float]] = {}

    def log(self, msg: str) -> None:
        self._log(f"[{time.perf_counter() - self.t0:7.1f} s] {msg}")

    def _evaluate(
        self, sc: Scenario, controller: str, factory: Any, extra: dict[str, Any], online: bool
    ) -> None:
        cfg = self.cfg
        first = cfg.eval_seeds[0]
        first_model = extra["train_seed"] in (0, "")

        def on_episode(ep: Episode, metrics: dict[str, float]) -> None:
            row = {
                "scenario": sc.name,
                "kind": sc.kind,
                "plant": sc.plant if sc.jump_to is None else sc.name.split(":", 1)[1],
                "controller": controller,
                "seed": ep.seed,
                **metrics,
                # environment steps of training plus adaptation (online learners adapt on the
                # whole episode; the oracles and the frozen RL policies do not learn from it)
                "data_steps": extra["train_steps"] + (ep.steps_run if online else 0),
                **extra,
            }
            self.writer.write(row)
            if first_model and ep.seed == first:
                self.traces[(sc.name, controller)] = ep
            if first_model and sc.kind == "jump":
                self.jump_costs.setdefault((sc.name, controller), []).append(ep.cost)

        evaluate(factory, sc.env, cfg.eval_seeds, plant=sc.plant, on_episode=on_episode)

    def run(self, scenarios: list[Scenario]) -> None:
        cfg = self.cfg
        classical = [a for a in cfg.agents if a in CONTROLLERS]
        for sc in scenarios:
            for name in classical:
                info = CONTROLLERS[name]
                self.log(f"evaluate {name} on {sc.name} ({cfg.seeds} seeds)")
                self._evaluate(
                    sc,
                    name,
                    info.build(cfg, sc),
                    {
                        "family": info.kind,
                        "train_seed": "",
                        "train_steps": 0,
                        "train_wall_s": 0.0,
                    },
                    info.online,
                )
        if not cfg.rl_agents:
            return
        from stcgym.agents.sb3 import curve_cost, train_agent

        envs = training_envs(cfg, scenarios)
        curve_seeds = [10_000 + i for i in range(cfg.curve_seeds)]
        for key, (train_spec, curve_spec) in envs.items():
            # Horizontal lines of the learning-curve plot: the classical controllers on the
            # episodes the curve is measured on.
            lines = {}
            for name in classical:
                sc = Scenario(key, "curve", curve_spec, curve_spec.plants[0], key)
                lines[name] = curve_cost(
                    CONTROLLERS[name].build(cfg, sc), curve_spec, curve_seeds, curve_spec.plants
                )
            self.reference_lines[key] = lines
            users = [sc for sc in scenarios if sc.train_key == key]
            for algo in cfg.rl_agents:
                config = AlgoConfig.from_dict(cfg.algo_configs[algo])
                for ts in range(cfg.train_seeds):
                    steps = cfg.train_steps[algo]
                    self.log(f"train {algo} on {key} (seed {ts}, {steps} steps)")
                    agent = train_agent(
                        algo,
                        config,
                        train_spec,
                        steps,
                        ts,
                        out_dir=self.run_dir / "models" / f"{key.replace(':', '-')}_{algo}_s{ts}",
                        curve_spec=curve_spec,
                        curve_seeds=curve_seeds,
                        curve_points=cfg.curve_points,
                        progress=cfg.progress,
                    )
                    self.log(f"trained {algo} on {key} in {agent.wall_s:.1f} s")
                    for s, c in agent.curve:
                        self.curves.append(
                            {
                                "train_env": key,
                                "algo": algo,
                                "train_seed": ts,
                                "steps": s,
                                "cost": c,
                            }
                        )
                    self._write_curves()
                    for sc in users:
                        self.log(f"evaluate {algo} (seed {ts}) on {sc.name}")
                        self._evaluate(
                            sc,
                            algo,
                            agent.policy,
                            {
                                "family": "rl",
                                "train_seed": ts,
                                "train_steps": agent.steps,
                                "train_wall_s": agent.wall_s,
                            },
                            False,
                        )

    def _write_curves(self) -> None:
        with open(self.run_dir / "learning_curves.csv", "w", newline="") as fh:
            w = csv.DictWriter(fh, ["train_env", "algo", "train_seed", "steps", "cost"])
            w.writeheader()
            for row in self.curves:
                w.writerow({k: _fmt(v) for k, v in row.items()})
