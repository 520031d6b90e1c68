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
    ``A:B`` (plant ``A`` jumping to plant ``B``). Window agents are the ones trained on the
    pre-jump plant (``nominal:A``): the jump is as new to them as to the self-tuning
    controller. The known-model oracle is told the new parameters at the jump.

Recurrent agents (``rppo``, sb3-contrib's RecurrentPPO: the adaptive-RL baseline) are trained on
the plant family only and evaluated on the ``family`` and ``jump`` scenarios.

Every controller meets the same episodes: evaluation seed ``s`` means ``env.reset(seed=s)``
(same noise, same reference) for all of them, and the controller's own random parts (the
self-tuning controller's probe) are seeded with ``s`` too, so every episode and every lane has
its own controller seed. The loop and the per-episode metrics are those of
:mod:`stcgym.agents.evaluate`; the metrics relative to the oracle on the same episode (cost
ratios, steps to get within 1.2x, re-convergence after the jump) are those of
:mod:`stcgym.agents.response`, computed here from the per-step costs.

Controllers
-----------
``ppo``, ``sac``, ``td3``, ``a2c``, ``rppo``: Stable-Baselines3 / sb3-contrib agents
(:mod:`stcgym.agents.sb3`), one model per training environment and training seed. ``stc``:
:class:`~stcgym.adaptive.SelfTuningController` with its defaults; ``stc_lq`` and
``stc_kfmils``: the same with the self-tuning LQ design and on the paper's KF-MILS estimator
(:mod:`stcgym.agents.controllers`). ``oracle``:
:class:`~stcgym.adaptive.KnownModelController`, the same design on the true parameters (always
evaluated: every ratio is taken to it). ``lqg``: :class:`~stcgym.adaptive.LQGController`, the
optimal linear controller for the bench's cost on the true (pre-jump) parameters.

Execution
---------
The classical controllers run in the driver first (seconds). Every RL training job (training
env x agent x seed) is a JSON task (:mod:`stcgym.agents.training`) run by the executor of
:mod:`stcgym.agents.executors` (``jobs`` local processes, or Ray), longest first; the driver
writes every result as the jobs finish and logs ``job k/N, ETA`` for the whole run.

Output (``<out>/<run>/``): ``config.json`` (written first), ``metrics.csv`` (one row per
controller x scenario x seed x training seed, appended and flushed row by row, so an
interrupted run keeps every finished row), ``learning_curves.csv``, ``report.md``, PNG plots
and ``models/``.
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

from stcgym.agents.configs import (
    ALGORITHMS,
    RECURRENT_ALGORITHMS,
    AlgoConfig,
    apply_overrides,
    default_config,
)
from stcgym.agents.controllers import CONTROLLERS, ControllerInfo, stc_takes_seed
from stcgym.agents.evaluate import EnvSpec, Episode, evaluate, run_episode
from stcgym.agents.response import curve_settling_step, settling_step
from stcgym.envs.catalogue import TIMEVARYING2_AFTER, get_plant, plant_names

__all__ = [
    "BenchConfig",
    "BenchInputError",
    "CONTROLLERS",
    "ControllerInfo",
    "METRIC_COLUMNS",
    "Scenario",
    "build_config",
    "check_runnable",
    "estimate_seconds",
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
    "controller_seed",
    "cost",
    "cost_ratio",
    "cost_start",
    "cost_steady",
    "steady_ratio",
    "steps_to_oracle",
    "cost_post_jump",
    "post_jump_ratio",
    "reconverge_steps",
    "effort",
    "bounded",
    "steps_run",
    "clip_frac",
    "overshoot_pct",
    "settling_steps",
    "startup_settling_steps",
    "data_steps",
    "train_steps",
    "train_wall_s",
    "step_us",
]

SCENARIO_KINDS = ("nominal", "family", "jump")
#: Allowed cost ratio to the oracle in ``steps_to_oracle`` and ``reconverge_steps``.
TOLERANCE = 1.2


class BenchInputError(ValueError):
    """Bad bench input (names, budgets, output folder, dependencies), raised before any work."""


# ---------------------------------------------------------------------------------- config
@dataclass
class BenchConfig:
    """Everything a bench run depends on; ``config.json`` is this, as written."""

    run: str
    out: str = "results"
    mode: str = "quick"
    scenarios: list[str] = field(default_factory=lambda: list(SCENARIO_KINDS))
    plants: list[str] = field(default_factory=lambda: ["stable2"])
    family_train: list[str] = field(default_factory=lambda: ["stable2", "unstable2", "integrator2"])
    family_test: list[str] = field(default_factory=lambda: ["lightly_damped2", "nonminphase2"])
    jumps: list[str] = field(default_factory=lambda: ["timevarying2"])
    agents: list[str] = field(
        default_factory=lambda: [
            "ppo",
            "sac",
            "rppo",
            "stc",
            "stc_lq",
            "stc_kfmils",
            "oracle",
            "lqg",
        ]
    )
    train_steps: dict[str, int] = field(default_factory=dict)
    train_seeds: int = 3
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
    jobs: int = 2
    executor: str = "local"
    address: str | None = None
    tensorboard_log: str | None = None
    bootstrap_reps: int = 2000

    @property
    def run_dir(self) -> Path:
        return Path(self.out) / self.run

    @property
    def rl_agents(self) -> list[str]:
        return [a for a in self.agents if a in ALGORITHMS]

    @property
    def classical(self) -> list[str]:
        """Classical controllers in evaluation order: the oracle first (every ratio needs it)."""
        names = [a for a in self.agents if a in CONTROLLERS]
        return ["oracle", *[a for a in names if a != "oracle"]]

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
    plants=["stable2"],
    jumps=["timevarying2"],
    agents=["ppo", "sac", "rppo", "stc", "stc_lq", "stc_kfmils", "oracle", "lqg"],
    train_seeds=3,
    seeds=5,
    episode_steps=1000,
)
FULL = dict(
    mode="full",
    plants=["stable2", "lightly_damped2", "unstable2", "nonminphase2", "integrator2", "stable4"],
    jumps=["timevarying2", "stable2:unstable2"],
    agents=["ppo", "sac", "td3", "a2c", "rppo", "stc", "stc_lq", "stc_kfmils", "oracle", "lqg"],
    train_seeds=5,
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
    jobs: int | None = None,
    executor: str = "local",
    address: str | None = None,
    tensorboard_log: str | None = None,
    bootstrap_reps: int = 2000,
) -> BenchConfig:
    """Build and validate a :class:`BenchConfig` (raises :class:`BenchInputError`).

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
    cfg.first_seed, cfg.noise_std = first_seed, noise_std
    cfg.train_y_bound = train_y_bound
    cfg.curve_points, cfg.plots, cfg.progress = curve_points, bool(plots), progress
    cfg.jobs = jobs if jobs is not None else min(2, os.cpu_count() or 1)
    cfg.executor, cfg.address = executor, address
    cfg.tensorboard_log = None if tensorboard_log is None else str(tensorboard_log)
    cfg.bootstrap_reps = bootstrap_reps
    cfg.overrides = list(hp)
    try:
        validate(cfg, train_steps)
    except BenchInputError:
        raise
    except ValueError as exc:
        raise BenchInputError(str(exc)) from exc
    return cfg


def _finite(value: Any, name: str, *, positive: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan
    if not math.isfinite(v) or (v <= 0 if positive else v < 0):
        what = "a positive number" if positive else "a finite number >= 0"
        raise ValueError(f"{name} must be {what}, got {value!r}")
    return v


def validate(cfg: BenchConfig, train_steps: str | int | dict | None = None) -> None:
    """Check every input, fill in training budgets and algorithm configs; raise ``ValueError``."""
    from stcgym.agents.configs import validate_config
    from stcgym.agents.executors import EXECUTORS

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
    if "oracle" not in cfg.agents:
        cfg.agents.append("oracle")  # the reference of every ratio
    names = set(plant_names())
    for what in ("plants", "family_train", "family_test"):
        bad = [p for p in getattr(cfg, what) if p not in names]
        if bad:
            raise ValueError(f"unknown plant(s) {bad} in {what}; catalogue: {sorted(names)}")
    if "nominal" in cfg.scenarios and not cfg.plants:
        raise ValueError("the nominal scenario needs at least one plant (--plants)")
    recurrent = [a for a in cfg.rl_agents if a in RECURRENT_ALGORITHMS]
    if "family" in cfg.scenarios or recurrent:
        if not cfg.family_train:
            raise ValueError("the family scenario and recurrent agents need --family-train plants")
        if "family" in cfg.scenarios and not cfg.family_test:
            raise ValueError("the family scenario needs --family-test plants")
        overlap = sorted(set(cfg.family_train) & set(cfg.family_test))
        if overlap:
            raise ValueError(f"held-out plants {overlap} are also in the training family")
        orders = {get_plant(p).n for p in cfg.family_train + cfg.family_test}
        if len(orders) > 1:
            raise ValueError("family_train and family_test plants must share one order")
    if recurrent and not {"family", "jump"} & set(cfg.scenarios):
        raise ValueError(
            f"{recurrent} are evaluated on the family and jump scenarios only; add one of them"
        )
    if "jump" in cfg.scenarios:
        if not cfg.jumps:
            raise ValueError("the jump scenario needs at least one --jump")
        for spec in cfg.jumps:
            _, before, _ = parse_jump(spec)
            if recurrent and get_plant(before).n != get_plant(cfg.family_train[0]).n:
                raise ValueError(f"--jump {spec!r}: recurrent agents need the family's order")
    for name in (
        "train_seeds",
        "seeds",
        "episode_steps",
        "train_episode_steps",
        "curve_points",
        "jobs",
        "bootstrap_reps",
    ):
        setattr(cfg, name, _positive_int(getattr(cfg, name), f"--{name.replace('_', '-')}"))
    if cfg.episode_steps < 20:
        raise ValueError(f"--episode-steps must be >= 20, got {cfg.episode_steps}")
    try:
        first = int(cfg.first_seed)
    except (TypeError, ValueError):
        first = -1
    if first != cfg.first_seed or first < 0:
        raise ValueError(f"--first-seed must be an integer >= 0, got {cfg.first_seed!r}")
    cfg.first_seed = first
    cfg.noise_std = _finite(cfg.noise_std, "--noise")
    if cfg.train_y_bound is not None:
        cfg.train_y_bound = _finite(cfg.train_y_bound, "--train-y-bound", positive=True)
    if cfg.noise_std == 0 and "lqg" in cfg.agents:
        raise ValueError("the lqg oracle needs --noise > 0 (its Kalman filter assumes it)")
    if cfg.executor not in EXECUTORS:
        raise ValueError(f"--executor must be one of {EXECUTORS}, got {cfg.executor!r}")
    if cfg.address is not None and cfg.executor != "ray":
        raise ValueError("--address needs --executor ray")
    if cfg.tensorboard_log is not None and not cfg.rl_agents:
        raise ValueError("--tensorboard-log needs at least one RL agent in --agents")
    # Training budgets and configs: defaults of the mode, then --train-steps and --hp.
    configs = {a: default_config(a) for a in cfg.rl_agents}
    apply_overrides(configs, cfg.overrides)
    for c in configs.values():
        validate_config(c)
    given = parse_train_steps(train_steps, cfg.rl_agents)
    extra = sorted(set(given) - set(cfg.rl_agents))
    if extra and isinstance(train_steps, str) and "=" in train_steps:
        raise ValueError(f"--train-steps names {extra}, which are not among --agents")
    cfg.train_steps = {
        a: given.get(a, configs[a].quick_steps if cfg.mode == "quick" else configs[a].full_steps)
        for a in cfg.rl_agents
    }
    cfg.algo_configs = {a: configs[a].to_dict() for a in cfg.rl_agents}


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

    def train_key_for(self, algo: str) -> str | None:
        """The training environment of ``algo``'s agents evaluated here (``None``: not here)."""
        if algo in RECURRENT_ALGORITHMS:
            return "family" if self.kind in ("family", "jump") else None
        return self.train_key


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
    """``train_key -> (training env, learning-curve env)`` for every key an RL agent uses.

    The training environment is the evaluation one, with shorter episodes; ``train_y_bound``
    (times the reference amplitude) optionally replaces the divergence bound, so that training
    episodes end (and are charged to the end, see :class:`~stcgym.agents.wrappers.
    TrainingReward`) earlier. In our tests a bound of 10 got SAC and TD3 out of a saturated
    local optimum on ``unstable2`` but made exploration end episodes all the time on the
    high-gain ``stable2`` and ruined them there, so the default keeps the environment's bound.
    The learning curve is always measured on the evaluation settings.
    """
    keys = dict.fromkeys(
        k for sc in scenarios for a in cfg.rl_agents if (k := sc.train_key_for(a)) is not None
    )
    envs: dict[str, tuple[EnvSpec, EnvSpec]] = {}
    for key in keys:
        plants = cfg.family_train if key == "family" else [key.split(":", 1)[1]]
        curve = cfg.env_spec(plants, cfg.train_episode_steps)
        train = curve
        if cfg.train_y_bound is not None:
            train = cfg.env_spec(
                plants, cfg.train_episode_steps, y_bound=cfg.train_y_bound * curve.amplitude
            )
        envs[key] = (train, curve)
    return envs


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
        mods = ["stable_baselines3", "torch", "rliable"]
        if any(a in RECURRENT_ALGORITHMS for a in cfg.rl_agents):
            mods.append("sb3_contrib")
        if cfg.tensorboard_log:
            mods.append("tensorboard")
        if cfg.progress:
            mods += ["tqdm", "rich"]
        for mod in mods:
            try:
                __import__(mod)
            except ImportError:
                missing.append(f"{mod} (pip install 'stcgym[rl]')")
    else:
        try:
            __import__("rliable")
        except ImportError:
            missing.append("rliable for the confidence intervals (pip install 'stcgym[rl]')")
    if cfg.executor == "ray":
        try:
            __import__("ray")
        except ImportError:
            missing.append("ray for --executor ray (pip install 'stcgym[ray]')")
    if cfg.plots:
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            missing.append("matplotlib for the plots (pip install 'stcgym[plot]' or --no-plots)")
    if missing:
        raise BenchInputError("missing dependencies: " + "; ".join(missing))


def check_runnable(cfg: BenchConfig) -> None:
    """The checks that need more than the config: dependencies, and every agent's model built
    once by SB3 itself. Raises :class:`BenchInputError`."""
    _check_dependencies(cfg)
    if cfg.rl_agents:
        _check_trainable(cfg, training_envs(cfg, make_scenarios(cfg)))


def _check_trainable(cfg: BenchConfig, envs: dict[str, tuple[EnvSpec, EnvSpec]]) -> None:
    """Build every agent's model once (and drop it): SB3's own checks run before any work."""
    from stcgym.agents.sb3 import check_trainable

    for algo in cfg.rl_agents:
        key = "family" if algo in RECURRENT_ALGORITHMS else next(iter(envs))
        try:
            check_trainable(algo, AlgoConfig.from_dict(cfg.algo_configs[algo]), envs[key][0])
        except ValueError as exc:
            raise BenchInputError(str(exc)) from exc


def _versions() -> dict[str, str]:
    out = {"python": platform.python_version(), "platform": platform.platform()}
    for mod in ("numpy", "gymnasium", "control", "stable_baselines3", "torch"):
        try:
            out[mod] = __import__(mod).__version__
        except ImportError:
            pass
    return out


# ---------------------------------------------------------------------------------- time
#: Rough CPU seconds per training env step on the 2-core development machine (torch on one
#: thread, learning curve included); only the ETA and the announced estimate use them.
SECONDS_PER_STEP = {"ppo": 2.0e-3, "a2c": 2.0e-3, "sac": 2.0e-2, "td3": 1.8e-2, "rppo": 1.7e-2}
#: Seconds per evaluated controller step (python loop).
SECONDS_PER_EVAL_STEP = 1.5e-4


def _job_weights(cfg: BenchConfig, scenarios: Sequence[Scenario], tasks: Sequence[dict]) -> dict:
    classical = cfg.seeds * cfg.episode_steps * SECONDS_PER_EVAL_STEP
    curve = cfg.curve_points * cfg.curve_seeds * cfg.train_episode_steps * SECONDS_PER_EVAL_STEP
    out = {("classical", sc.name): classical * len(cfg.classical) for sc in scenarios}
    for t in tasks:
        plants = len(t["curve_env"]["plants"])
        evals = sum(len(e["seeds"]) for e in t["evaluations"]) * cfg.episode_steps
        out[("rl", t["name"])] = (
            t["steps"] * SECONDS_PER_STEP.get(t["algo"], 5e-3)
            + curve * plants
            + evals * 2 * SECONDS_PER_EVAL_STEP
        )
    return out


def estimate_seconds(cfg: BenchConfig) -> float:
    """Rough wall time of ``cfg`` on ``cfg.jobs`` cores (announced before long runs)."""
    scenarios = make_scenarios(cfg)
    weights = _job_weights(cfg, scenarios, _tasks(cfg, scenarios, {}, {}))
    rl = sum(w for (kind, _), w in weights.items() if kind == "rl")
    return sum(weights.values()) - rl + rl / max(1, cfg.jobs)


def _duration(seconds: float) -> str:
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
            f"{_duration(now - self.t0)}, ETA {_duration(eta)}"
        )


# ---------------------------------------------------------------------------------- run
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
    #: train_env -> (window end steps, stc cost / oracle cost per window, one row per episode)
    adaptation: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)


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
    checked: bool = False,
) -> BenchResult:
    """Run the bench described by a validated ``cfg`` (see :func:`build_config`).

    All checks (names, budgets, hyperparameters against SB3, dependencies, output folder)
    happen before anything is evaluated or trained (``checked=True``: :func:`check_runnable`
    has been called already). Rows are appended to ``metrics.csv`` as
    episodes finish; on ``KeyboardInterrupt`` (or any error) the finished rows stay, a partial
    ``report.md`` is written and the exception is re-raised.
    """
    from stcgym.agents.executors import write_atomic
    from stcgym.agents.report import write_report

    t_start = time.perf_counter()
    log = log or (lambda msg: print(msg, file=sys.stderr, flush=True))
    if not checked:
        check_runnable(cfg)
    scenarios = make_scenarios(cfg)
    envs = training_envs(cfg, scenarios)
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
    write_atomic(run_dir / "config.json", json.dumps(config_doc, indent=2))
    writer = MetricsWriter(run_dir / "metrics.csv")
    state = _RunState(cfg, run_dir, writer, log, t_start)

    def report(interrupted: bool) -> None:
        write_report(
            run_dir,
            cfg,
            scenarios,
            writer.rows,
            state.data,
            time.perf_counter() - t_start,
            interrupted=interrupted,
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
    if cfg.plots:
        from stcgym.agents.plots import write_plots

        t0 = time.perf_counter()
        write_plots(run_dir, cfg, scenarios, writer.rows, state.data)
        state.log(f"plots written ({time.perf_counter() - t0:.0f} s)")
    t0 = time.perf_counter()
    report(False)
    state.log(f"report written ({time.perf_counter() - t0:.0f} s)")
    wall = time.perf_counter() - t_start
    log(f"done in {_duration(wall)}: {run_dir}")
    return BenchResult(run_dir, writer.rows, state.data.curves, wall)


def _tasks(
    cfg: BenchConfig,
    scenarios: Sequence[Scenario],
    envs: dict[str, tuple[EnvSpec, EnvSpec]],
    references: dict[str, float],
    run_dir: Path | None = None,
) -> list[dict[str, Any]]:
    """The RL jobs, longest first (so that two workers finish together)."""
    from stcgym.agents.training import training_task

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
                        steps=cfg.train_steps[algo],
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


class _RunState:
    """The bench's driver: classical controllers, reference runs, then the RL jobs."""

    def __init__(self, cfg, run_dir, writer, log, t0) -> None:
        self.cfg, self.run_dir, self.writer, self._log, self.t0 = cfg, run_dir, writer, log, t0
        self.data = Collected()
        # (scenario, seed) -> the oracle's episode costs and metrics (the reference of ratios)
        self.oracle: dict[tuple[str, int], tuple[np.ndarray, dict[str, float]]] = {}
        self.scenarios: dict[str, Scenario] = {}

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
            row["cost_ratio"] = _ratio(metrics["cost"], ref["cost"])
            row["steady_ratio"] = _ratio(metrics["cost_steady"], ref["cost_steady"])
            if J is not None:
                row["post_jump_ratio"] = _ratio(metrics["cost_post_jump"], ref["cost_post_jump"])
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
        seeded = info.kind == "adaptive" and stc_takes_seed()

        def on_episode(ep: Episode, metrics: dict[str, float]) -> None:
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
        and the self-tuning controller's per-window cost against its adaptation steps."""
        cfg = self.cfg
        seeds = [10_000 + i for i in range(cfg.curve_seeds)]
        sc = Scenario(key, "curve", curve_spec, curve_spec.plants[0], key)
        runs: dict[str, list[np.ndarray]] = {}
        for name in cfg.classical:
            factory = CONTROLLERS[name].build(cfg, sc)
            runs[name] = [
                run_episode(factory, curve_spec, s, plant=p).cost
                for p in curve_spec.plants
                for s in seeds
            ]
        self.data.reference_lines[key] = {n: float(np.mean(c)) for n, c in runs.items()}
        if "stc" in runs:
            w = max(1, curve_spec.period // 2)  # one reference step per window
            T = curve_spec.steps
            ends = np.arange(w, T + 1, w)
            ratios = np.array(
                [
                    [_ratio(float(c[e - w : e].sum()), float(o[e - w : e].sum())) for e in ends]
                    for c, o in zip(runs["stc"], runs["oracle"], strict=True)
                ]
            )
            self.data.adaptation[key] = (ends, ratios)
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
                    "cost_to_oracle": _ratio(c, oracle_level) if oracle_level else math.nan,
                }
            )
        self._write_curves()
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

    def run(self, scenarios: list[Scenario], envs: dict[str, tuple[EnvSpec, EnvSpec]]) -> None:
        from stcgym.agents.executors import run_tasks

        cfg = self.cfg
        self.scenarios = {sc.name: sc for sc in scenarios}
        planned = _tasks(cfg, scenarios, envs, {}, self.run_dir)
        weights = _job_weights(cfg, scenarios, planned)
        for key, (_, curve_spec) in envs.items():
            weights[("reference", key)] = (
                len(cfg.classical)
                * cfg.curve_seeds
                * len(curve_spec.plants)
                * curve_spec.steps
                * SECONDS_PER_EVAL_STEP
            )
        progress = JobProgress(weights, self.log, cfg.jobs)
        workers = "worker" if cfg.jobs == 1 else "workers"
        self.log(
            f"{len(weights)} jobs ({len(planned)} RL trainings on {cfg.jobs} {workers}), "
            f"estimated {_duration(estimate_seconds(cfg))}"
        )
        for sc in scenarios:
            for name in cfg.classical:
                self._classical(sc, name)
            progress.finish(("classical", sc.name), f"classical controllers on {sc.name}")
        for key, (_, curve_spec) in envs.items():
            self._references(key, curve_spec, progress)
        if not planned:
            return
        refs = {k: v["oracle"] for k, v in self.data.reference_lines.items()}
        tasks = _tasks(cfg, scenarios, envs, refs, self.run_dir)
        from stcgym.agents.training import train_and_evaluate

        failures = []
        for out in run_tasks(
            train_and_evaluate,
            tasks,
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
                self._collect(out.task, out.result)
            progress.finish(("rl", name), f"{name}, {out.seconds:.0f} s", out.seconds)
        if failures:
            raise RuntimeError(f"{len(failures)} RL job(s) failed: {', '.join(failures)}")

    def _write_curves(self) -> None:
        from stcgym.agents.executors import write_atomic

        cols = ["train_env", "algo", "train_seed", "steps", "cost", "cost_to_oracle"]
        lines = [",".join(cols)]
        for row in self.data.curves:
            lines.append(",".join(str(_fmt(row[c])) for c in cols))
        write_atomic(self.run_dir / "learning_curves.csv", "\n".join(lines) + "\n")


def _ratio(x: float, ref: float | None) -> float:
    if ref is None or not math.isfinite(x) or not ref > 0:
        return math.nan if ref is None or math.isnan(x) else math.inf
    return x / ref
