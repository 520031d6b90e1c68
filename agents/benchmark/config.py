"""The settings of a ``stcgym bench`` run: :class:`BenchConfig`, the quick, standard and full
presets, and the checks every value passes before any work starts (:func:`build_config`).

Every tier trains each RL agent until its learning curve plateaus or it reaches the tier's cap
(:class:`~stcgym.agents.rl.stopping.PlateauRule`: ``patience`` evaluations, one every
``eval_interval`` env steps of the algorithm, without a gain of more than ``min_improvement``);
the tiers differ in their caps (``AlgoConfig.quick_steps``, ``standard_steps`` and
``standard_family_steps``, ``full_steps``) and, for ``full``, in plants, agents and seeds. Every
tier runs the four scenarios, ``mimo`` (:mod:`stcgym.agents.benchmark.mimo`) included; at the
quick tier RL trains there for :data:`QUICK_MIMO_INTERVALS` evaluation intervals, and the
learning curves have :data:`QUICK_CURVE_POINTS` points before the first interval and
:data:`QUICK_CURVE_SEEDS` episode per plant and point.
"""

from __future__ import annotations

import datetime as _dt
import math
import os
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from stcgym.agents.benchmark.evaluate import EnvSpec
from stcgym.agents.benchmark.mimo import MimoEnvSpec, check_mimo_plants
from stcgym.agents.benchmark.scenarios import parse_jump
from stcgym.agents.controllers import CONTROLLERS
from stcgym.agents.rl.configs import (
    ALGORITHMS,
    RECURRENT_ALGORITHMS,
    apply_overrides,
    default_config,
)
from stcgym.agents.rl.stopping import PlateauRule
from stcgym.envs.catalogue import get_plant, plant_names
from stcgym.envs.mimo_plants import mimo_plant_names

__all__ = [
    "FULL",
    "MODES",
    "QUICK",
    "QUICK_CURVE_POINTS",
    "QUICK_CURVE_SEEDS",
    "QUICK_MIMO_INTERVALS",
    "SCENARIO_KINDS",
    "STANDARD",
    "BenchConfig",
    "BenchInputError",
    "build_config",
    "parse_train_steps",
    "validate",
]

SCENARIO_KINDS = ("nominal", "family", "jump", "mimo")
#: The scenarios of the quick tier: all of them.
QUICK_SCENARIOS = SCENARIO_KINDS
#: Quick-tier RL cap in the mimo scenario: this many evaluation intervals (at most quick_steps):
#: two for the on-policy agents, one for the off-policy ones (SAC's learning curve on the
#: quadruple tank is flat between one and two intervals, PPO's still falls by a fifth).
QUICK_MIMO_INTERVALS = {"ppo": 2, "a2c": 2, "sac": 1, "td3": 1}
#: Learning-curve points before the first evaluation interval at the quick tier (10 at the
#: others): PPO's and RecurrentPPO's ten fall on five rollouts anyway, and half of SAC's ten
#: come before it starts learning (``learning_starts``), where the policy is the untrained one.
QUICK_CURVE_POINTS = 5
#: Learning-curve episodes per plant and point at the quick tier (2 at the others): the
#: reference is a fixed square wave and the noise small, so a second seed moves a point little.
QUICK_CURVE_SEEDS = 1


class BenchInputError(ValueError):
    """Bad bench input (names, budgets, output folder, dependencies), raised before any work."""


@dataclass
class BenchConfig:
    """Everything a bench run depends on; ``config.json`` is this, as written."""

    run: str
    out: str = "results"
    mode: str = "quick"
    scenarios: list[str] = field(default_factory=lambda: list(QUICK_SCENARIOS))
    plants: list[str] = field(default_factory=lambda: ["stable2"])
    family_train: list[str] = field(default_factory=lambda: ["stable2", "unstable2", "integrator2"])
    family_test: list[str] = field(default_factory=lambda: ["lightly_damped2", "nonminphase2"])
    jumps: list[str] = field(default_factory=lambda: ["timevarying2"])
    #: MIMO catalogue plants of the mimo scenario
    mimo_plants: list[str] = field(default_factory=lambda: ["quadruple_tank"])
    agents: list[str] = field(
        default_factory=lambda: [
            "ppo",
            "sac",
            "rppo",
            "stc",
            "stc_lq",
            "stc_kfmils",
            "stc_mimo",
            "oracle",
            "lqg",
        ]
    )
    #: training cap per algorithm of the agents trained on one plant ...
    train_steps: dict[str, int] = field(default_factory=dict)
    #: ... and of those trained on the randomised plant family, and on a MIMO plant
    family_train_steps: dict[str, int] = field(default_factory=dict)
    mimo_train_steps: dict[str, int] = field(default_factory=dict)
    #: the plateau rule (stcgym.agents.rl.stopping.PlateauRule)
    patience: int = 3
    min_improvement: float = 0.05
    min_train_fraction: float = 0.25
    #: --eval-interval: every algorithm's evaluation interval (None: each config's own)
    eval_interval: int | None = None
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
        """The bench's environment on ``plants`` (a :class:`~stcgym.agents.benchmark.mimo.
        MimoEnvSpec` for a MIMO catalogue plant)."""
        mimo = len(plants) > 0 and plants[0] in mimo_plant_names()
        return (MimoEnvSpec if mimo else EnvSpec)(
            tuple(plants),
            steps=steps,
            noise_std=self.noise_std,
            control_cost=self.control_cost,
            action_bound=self.action_bound,
            **kw,
        )

    @property
    def plateau(self) -> PlateauRule:
        return PlateauRule(self.min_improvement, self.patience, self.min_train_fraction)

    def cap(self, algo: str, train_key: str) -> int:
        """The training cap of ``algo``'s agents on the training env ``train_key``."""
        if train_key.startswith("mimo:"):
            return self.mimo_train_steps[algo]
        return (self.family_train_steps if train_key == "family" else self.train_steps)[algo]

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> BenchConfig:
        """The config of a ``config.json`` (``ValueError`` for keys this version lacks)."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown bench settings {unknown} (written by another version?)")
        data = dict(data)
        # written before the family had caps of its own: the single-plant caps applied
        data.setdefault("family_train_steps", dict(data.get("train_steps", {})))
        return cls(**data)


QUICK = dict(
    mode="quick",
    scenarios=list(QUICK_SCENARIOS),
    plants=["stable2"],
    jumps=["timevarying2"],
    # stc_mimo runs in the mimo scenario only, the others in the SISO ones only
    agents=["ppo", "sac", "rppo", "stc", "stc_lq", "stc_kfmils", "stc_mimo", "oracle", "lqg"],
    train_seeds=3,
    seeds=5,
    episode_steps=1000,
    curve_points=QUICK_CURVE_POINTS,
    curve_seeds=QUICK_CURVE_SEEDS,
)
#: The quick scenarios and seeds; RL caps from the Zoo (about an hour).
STANDARD = dict(QUICK, mode="standard", curve_points=10, curve_seeds=2)
FULL = dict(
    mode="full",
    scenarios=list(SCENARIO_KINDS),
    mimo_plants=mimo_plant_names(),
    plants=["stable2", "lightly_damped2", "unstable2", "nonminphase2", "integrator2", "stable4"],
    jumps=["timevarying2", "stable2:unstable2"],
    agents=[
        *("ppo", "sac", "td3", "a2c", "rppo"),
        *("stc", "stc_lq", "stc_kfmils", "stc_mimo", "oracle", "lqg"),
    ],
    train_seeds=5,
    seeds=20,
    episode_steps=2000,
    curve_points=10,
    curve_seeds=2,
)
MODES = {"quick": QUICK, "standard": STANDARD, "full": FULL}


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
    mode: str | None = None,
    run: str | None = None,
    out: str = "results",
    scenarios: str | Sequence[str] | None = None,
    plants: str | Sequence[str] | None = None,
    family_train: str | Sequence[str] | None = None,
    family_test: str | Sequence[str] | None = None,
    jumps: str | Sequence[str] | None = None,
    mimo_plants: str | Sequence[str] | None = None,
    agents: str | Sequence[str] | None = None,
    train_steps: str | int | dict | None = None,
    patience: int = 3,
    min_improvement: float = 0.05,
    min_train_fraction: float = 0.25,
    eval_interval: int | None = None,
    train_seeds: int | None = None,
    seeds: int | None = None,
    first_seed: int = 1000,
    episode_steps: int | None = None,
    train_episode_steps: int | None = None,
    noise_std: float = 0.05,
    train_y_bound: float | None = None,
    hp: Sequence[str] = (),
    curve_points: int | None = None,
    plots: bool = True,
    progress: bool | None = None,
    jobs: int | None = None,
    executor: str = "local",
    address: str | None = None,
    tensorboard_log: str | None = None,
    bootstrap_reps: int = 2000,
) -> BenchConfig:
    """Build and validate a :class:`BenchConfig` (raises :class:`BenchInputError`).

    Defaults come from the preset ``mode`` (``"quick"``, ``"standard"`` or ``"full"``; without
    it ``quick`` picks quick or full); every list argument takes a comma-separated string or a
    sequence. Nothing is trained or written here.
    """
    mode = mode if mode is not None else ("quick" if quick else "full")
    if mode not in MODES:
        raise BenchInputError(f"mode must be one of {sorted(MODES)}, got {mode!r}")
    preset = MODES[mode]
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
        ("mimo_plants", mimo_plants),
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
    if curve_points is not None:
        cfg.curve_points = curve_points
    cfg.plots, cfg.progress = bool(plots), progress
    cfg.jobs = jobs if jobs is not None else min(2, os.cpu_count() or 1)
    cfg.executor, cfg.address = executor, address
    cfg.tensorboard_log = None if tensorboard_log is None else str(tensorboard_log)
    cfg.bootstrap_reps = bootstrap_reps
    cfg.patience, cfg.min_improvement, cfg.eval_interval = patience, min_improvement, eval_interval
    cfg.min_train_fraction = min_train_fraction
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
    from stcgym.agents.executors import EXECUTORS
    from stcgym.agents.rl.configs import validate_config

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
    check_mimo_plants(cfg.mimo_plants)
    if "mimo" in cfg.scenarios and not cfg.mimo_plants:
        raise ValueError("the mimo scenario needs at least one plant (--mimo-plants)")
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
    if "jump" in cfg.scenarios and not cfg.jumps:
        raise ValueError("the jump scenario needs at least one --jump")
    # every --jump is checked, also when the jump scenario is not among --scenarios
    for spec in cfg.jumps:
        _, before, _ = parse_jump(spec)
        if "jump" in cfg.scenarios and recurrent:
            if get_plant(before).n != get_plant(cfg.family_train[0]).n:
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
    # Training caps and configs: defaults of the mode, then --eval-interval, --hp and
    # --train-steps (which sets the cap on one plant and on the family alike).
    cfg.plateau  # noqa: B018  (the PlateauRule's ValueError names the option)
    configs = {a: default_config(a) for a in cfg.rl_agents}
    if cfg.eval_interval is not None:
        cfg.eval_interval = _positive_int(cfg.eval_interval, "--eval-interval")
        for c in configs.values():
            c.eval_interval = cfg.eval_interval
    apply_overrides(configs, cfg.overrides)
    for c in configs.values():
        validate_config(c)
    given = parse_train_steps(train_steps, cfg.rl_agents)
    extra = sorted(set(given) - set(cfg.rl_agents))
    if extra and isinstance(train_steps, str) and "=" in train_steps:
        raise ValueError(f"--train-steps names {extra}, which are not among --agents")
    single, family = _MODE_CAPS[cfg.mode]
    cfg.train_steps = {a: given.get(a, getattr(configs[a], single)) for a in cfg.rl_agents}
    cfg.family_train_steps = {a: given.get(a, getattr(configs[a], family)) for a in cfg.rl_agents}
    cfg.mimo_train_steps = {
        a: given.get(a, _mimo_cap(configs[a], cfg.mode))
        for a in cfg.rl_agents
        if a not in RECURRENT_ALGORITHMS  # (trained on the SISO family only)
    }
    for a in cfg.rl_agents:
        caps = [cfg.family_train_steps[a]]
        if a not in RECURRENT_ALGORITHMS:  # recurrent agents train on the family only
            caps.append(cfg.train_steps[a])
            if "mimo" in cfg.scenarios:
                caps.append(cfg.mimo_train_steps[a])
        interval = configs[a].eval_interval
        if min(caps) < interval:
            raise ValueError(
                f"--train-steps: the {a} cap of {min(caps)} env steps is below one evaluation "
                f"interval of the plateau rule ({a}.eval_interval = {interval}); raise the cap "
                "or lower --eval-interval"
            )
    cfg.algo_configs = {a: configs[a].to_dict() for a in cfg.rl_agents}


def _mimo_cap(config: Any, mode: str) -> int:
    """The default cap on a MIMO plant: the single-plant cap of standard and full, and in quick
    :data:`QUICK_MIMO_INTERVALS` evaluation intervals (at most ``quick_steps``)."""
    if mode == "quick":
        return min(config.quick_steps, QUICK_MIMO_INTERVALS[config.algo] * config.eval_interval)
    return getattr(config, _MODE_CAPS[mode][0])


#: The AlgoConfig fields of each mode's caps: (one plant, the plant family).
_MODE_CAPS = {
    "quick": ("quick_steps", "quick_steps"),
    "standard": ("standard_steps", "standard_family_steps"),
    "full": ("full_steps", "full_steps"),
}
