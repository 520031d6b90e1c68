"""The settings of a ``stcgym bench`` run: :class:`BenchConfig`, the quick, standard and full
presets, and the checks every value passes before any work starts (:func:`build_config`).

Every tier evaluates every controller on the same fixed episodes of each scenario
(:mod:`stcgym.agents.benchmark.scenarios`) and trains each RL agent, with ``train_seeds``
training runs, until its learning curve on the validation split plateaus or it reaches the
tier's cap (:class:`~stcgym.agents.rl.stopping.PlateauRule`: ``patience`` evaluations, one every
``eval_interval`` env steps of the algorithm, without a gain of more than ``min_improvement``).
The tiers differ in caps (``AlgoConfig.quick_steps``, ``standard_steps`` on one plant and
``standard_family_steps`` on the family, ``full_steps``), runs, test plants, held-out
distributions and agents. At the quick tier RL trains on a MIMO plant for
:data:`QUICK_MIMO_INTERVALS` evaluation intervals. Outside the quick tier an algorithm's
evaluation interval is at least :data:`EVALUATIONS_PER_CAP`-th of its cap, so that the plateau
rule's patience spans a fixed share of the budget.
"""

from __future__ import annotations

import datetime as _dt
import math
import os
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from stcgym.agents.benchmark.mimo import check_mimo_plants
from stcgym.agents.benchmark.tiers import FAMILY_KINDS, MODES, SCENARIO_KINDS
from stcgym.agents.controllers import CONTROLLERS, YARDSTICK
from stcgym.agents.rl.configs import ALGORITHMS, FAMILY_ALGORITHMS, default_config
from stcgym.agents.rl.overrides import apply_overrides
from stcgym.agents.rl.stopping import PlateauRule
from stcgym.envs.catalogue import get_plant, plant_names
from stcgym.envs.families import LADDER

__all__ = [
    "EVALUATIONS_PER_CAP",
    "QUICK_MIMO_INTERVALS",
    "BenchConfig",
    "BenchInputError",
    "build_config",
    "is_family_key",
    "parse_train_steps",
    "validate",
]

#: Quick-tier RL cap in the mimo scenario: this many evaluation intervals (at most quick_steps).
QUICK_MIMO_INTERVALS = {"ppo": 2, "a2c": 2, "sac": 1, "td3": 1}
#: Outside the quick tier, evaluations of the plateau rule per cap at most.
EVALUATIONS_PER_CAP = 20


class BenchInputError(ValueError):
    """Bad bench input (names, budgets, output folder, dependencies), raised before any work."""


@dataclass(frozen=True)
class BenchConfig:
    """Everything a bench run depends on; ``config.json`` is this, as written.

    Frozen: :func:`build_config` validates and completes it once, and a run derives the values
    it measures or tunes (action bounds and units, tuned settings) into a new config with
    :func:`dataclasses.replace` while it plans (:mod:`~stcgym.agents.benchmark.runner`),
    before any job starts; nothing changes it while the jobs run.
    """

    run: str
    out: str = "results"
    mode: str = "quick"
    scenarios: list[str] = field(default_factory=lambda: list(SCENARIO_KINDS))
    #: catalogue plants of the nominal scenarios
    plants: list[str] = field(default_factory=lambda: ["stable2"])
    #: the plant family (a registered name: stcgym.envs.families.FAMILIES)
    family: str = "siso2-v1"
    #: the family's held-out variants tested (the ood scenarios)
    ood: list[str] = field(default_factory=lambda: ["ood_near_zero", "ood_order3"])
    #: the rungs of the difficulty ladder tested beside the family (the ladder scenarios: each
    #: rung's test split, its RL agents trained on its training split)
    ladder: list[str] = field(default_factory=lambda: list(LADDER[:3]))
    #: the RL agents trained on each rung (those of ``agents``; the classical ones run on all):
    #: the window PPO and the two references that locate its failure, PPO told the true
    #: parameters and (classical) the best fixed PI law
    ladder_agents: list[str] = field(default_factory=lambda: ["ppo", "oracle_ppo"])
    #: MIMO catalogue plants of the mimo scenarios (mimo_switch: the quadruple tank's valves)
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
            "zero",
        ]
    )
    #: training cap per algorithm of the agents trained on one plant ...
    train_steps: dict[str, int] = field(default_factory=dict)
    #: ... and of those trained on the plant family, and on a MIMO plant
    family_train_steps: dict[str, int] = field(default_factory=dict)
    mimo_train_steps: dict[str, int] = field(default_factory=dict)
    #: the plateau rule (stcgym.agents.rl.stopping.PlateauRule)
    patience: int = PlateauRule.patience
    min_improvement: float = PlateauRule.min_improvement
    min_train_fraction: float = PlateauRule.min_fraction
    #: --eval-interval: every algorithm's evaluation interval (None: each config's own)
    eval_interval: int | None = None
    #: runs per controller: RL training seeds, self-tuning controller seeds
    train_seeds: int = 3
    #: test plants per family split (None: all of them) and episodes on each
    test_plants: int | None = 40
    episodes_per_plant: int = 1
    #: episodes of a nominal or MIMO scenario (one plant)
    nominal_episodes: int = 20
    #: validation episodes of a learning-curve point
    curve_episodes: int = 10
    #: training episodes on which LQG's input range sets the action bound
    bound_plants: int = 200
    first_seed: int = 1000
    #: episode length (None: the family's)
    episode_steps: int | None = None
    #: output noise (None: the family's)
    noise_std: float | None = None
    #: the action bound of each training distribution (measured at the start of a run)
    action_bounds: dict[str, float] = field(default_factory=dict)
    #: the Gaussian-policy RL agents' action unit of each training distribution (measured
    #: with the bound: bounds.lqg_action_unit)
    action_units: dict[str, float] = field(default_factory=dict)
    curve_points: int = 5
    #: Optuna trials per RL agent and for the self-tuning controller on the validation split
    #: (0: no tuning), each RL trial training for tune_fraction of the agent's family cap
    tune_trials: int = 0
    tune_fraction: float = 0.1
    #: the RL agents tuned (None: every RL agent of ``agents``)
    tune_agents: list[str] | None = None
    #: the studies' results (filled by a run that tunes): agent -> summary and best params
    tuned: dict[str, dict[str, Any]] = field(default_factory=dict)
    algo_configs: dict[str, dict[str, Any]] = field(default_factory=dict)
    overrides: list[str] = field(default_factory=list)
    plots: bool = True
    progress: bool | None = None
    jobs: int = 2
    executor: str = "local"
    address: str | None = None
    tensorboard_log: str | None = None
    bootstrap_reps: int = 1000

    @property
    def run_dir(self) -> Path:
        return Path(self.out) / self.run

    @property
    def rl_agents(self) -> list[str]:
        return [a for a in self.agents if a in ALGORITHMS]

    @property
    def tuned_rl_agents(self) -> list[str]:
        """The RL agents whose hyperparameters a run with tuning trials tunes."""
        if not self.tune_trials:
            return []
        return [a for a in self.rl_agents if self.tune_agents is None or a in self.tune_agents]

    @property
    def classical(self) -> list[str]:
        """Classical controllers in evaluation order: the yardstick and zero input first (every
        ratio and score needs them)."""
        names = [a for a in self.agents if a in CONTROLLERS]
        first = [YARDSTICK, "zero"]
        return [*first, *[a for a in names if a not in first]]

    def runs_of(self, controller: str) -> int:
        """Runs of the classical ``controller``: one per seed for one with random parts (the
        self-tuning controllers' probes), one for a deterministic one."""
        return self.train_seeds if CONTROLLERS[controller].seeded else 1

    @property
    def plateau(self) -> PlateauRule:
        return PlateauRule(self.min_improvement, self.patience, self.min_train_fraction)

    def cap(self, algo: str, train_key: str) -> int:
        """The training cap of ``algo``'s agents on the training env ``train_key``."""
        if train_key.startswith("mimo"):
            return self.mimo_train_steps[algo]
        family = is_family_key(train_key)
        return (self.family_train_steps if family else self.train_steps)[algo]

    def trains_on(self, algo: str, train_key: str) -> bool:
        """Whether the RL agent ``algo`` trains on ``train_key``: a rung of the ladder
        (``"family:<rung>"``) trains the :attr:`ladder_agents` only."""
        return not train_key.startswith("family:") or algo in self.ladder_agents

    def eval_interval_for(self, algo: str, train_key: str) -> int:
        """The plateau rule's evaluation interval of ``algo`` on ``train_key``: the config's,
        outside the quick tier a whole multiple of it with at most
        :data:`EVALUATIONS_PER_CAP` evaluations up to the cap."""
        base = int(self.algo_configs[algo]["eval_interval"])
        if self.mode in ("smoke", "quick") or self.eval_interval is not None:
            return base
        return base * max(1, math.ceil(self.cap(algo, train_key) / (EVALUATIONS_PER_CAP * base)))

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> BenchConfig:
        """The config of a ``config.json`` (``ValueError`` for keys this version lacks)."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown bench settings {unknown} (written by another version?)")
        return cls(**dict(data))


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


#: BenchConfig fields that take a comma-separated string or a sequence of names
_NAME_LISTS = (
    "scenarios",
    "plants",
    "ood",
    "ladder",
    "ladder_agents",
    "tune_agents",
    "mimo_plants",
    "agents",
)
#: BenchConfig fields a run derives from the preset, the caps or its own measurements
_DERIVED = (
    "mode",
    "family_train_steps",
    "mimo_train_steps",
    "action_bounds",
    "action_units",
    "tuned",
    "algo_configs",
)


def build_config(
    mode: str | None = None,
    *,
    quick: bool = True,
    train_steps: str | int | dict | None = None,
    **settings: Any,
) -> BenchConfig:
    """Build and validate a :class:`BenchConfig` (raises :class:`BenchInputError`).

    Parameters
    ----------
    mode
        The preset, ``"smoke"``, ``"quick"``, ``"standard"`` or ``"full"``; ``None``: quick
        or full as ``quick`` says.
    train_steps
        The training caps: ``20000`` (every algorithm), ``"ppo=40000,sac=10000"`` or a dict
        (``None``: the preset's caps).
    **settings
        Any other field of :class:`BenchConfig` (``run``, ``agents``, ``train_seeds``,
        ``patience``, ``jobs``, ...); ``None`` or absent: the preset's value, else the field's
        default (``jobs``: at most 2, the cores there are). The list fields (``scenarios``,
        ``plants``, ``ood``, ``ladder``, ``ladder_agents``, ``tune_agents``, ``mimo_plants``,
        ``agents``) take a comma-separated string or a sequence.

    Nothing is trained or written here.
    """
    settable = {f.name for f in fields(BenchConfig)} - {*_DERIVED, "train_steps"}
    unknown = sorted(set(settings) - settable)
    if unknown:
        raise TypeError(
            f"build_config() got unexpected keyword arguments {unknown}; "
            f"the settings are BenchConfig's fields {sorted(settable)}"
        )
    mode = mode if mode is not None else ("quick" if quick else "full")
    if mode not in MODES:
        raise BenchInputError(f"mode must be one of {sorted(MODES)}, got {mode!r}")
    preset = MODES[mode]
    given = {k: v for k, v in settings.items() if v is not None}
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    cfg = BenchConfig(run=given.pop("run", "") or f"{stamp}-{preset['mode']}")
    for key, value in preset.items():
        _set(cfg, key, value if not isinstance(value, list) else list(value))
    for name, value in given.items():
        _set(cfg, name, _split(value) if name in _NAME_LISTS else value)
    if "tune_trials" not in given and not set(FAMILY_KINDS) & set(cfg.scenarios):
        # the preset's studies tune on the family's validation split: none without the family
        _set(cfg, "tune_trials", 0)
        if "agents" not in given:
            _set(cfg, "agents", [a for a in cfg.agents if a != "stc_tuned"])
    if "jobs" not in given:
        _set(cfg, "jobs", min(2, os.cpu_count() or 1))
    for name, kind in (("out", str), ("family", str), ("plots", bool), ("overrides", list)):
        _set(cfg, name, kind(getattr(cfg, name)))
    if cfg.tensorboard_log is not None:
        _set(cfg, "tensorboard_log", str(cfg.tensorboard_log))
    try:
        validate(cfg, train_steps)
    except BenchInputError:
        raise
    except ValueError as exc:
        raise BenchInputError(str(exc)) from exc
    return cfg


def _set(cfg: BenchConfig, name: str, value: Any) -> None:
    """Set a field of a config :func:`build_config` is completing, before anyone else sees it
    (the frozen dataclass's own ``__post_init__`` idiom)."""
    object.__setattr__(cfg, name, value)


def is_family_key(train_key: str) -> bool:
    """Whether a training key is a plant family's training split: ``"family"`` (the bench's
    family) or ``"family:<rung>"`` (a rung of the ladder)."""
    return train_key == "family" or train_key.startswith("family:")


def _finite(value: Any, name: str, *, positive: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan
    if not math.isfinite(v) or (v <= 0 if positive else v < 0):
        what = "a positive number" if positive else "a finite number >= 0"
        raise ValueError(f"{name} must be {what}, got {value!r}")
    return v


def _check_names(cfg: BenchConfig) -> None:
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
    missing = [name for name in (YARDSTICK, "zero") if name not in cfg.agents]
    _set(cfg, "agents", [*cfg.agents, *missing])  # every ratio and score needs them
    bad = [p for p in cfg.plants if p not in plant_names()]
    if bad:
        raise ValueError(f"unknown plant(s) {bad} in --plants; catalogue: {plant_names()}")
    if any(get_plant(p).schedule is not None for p in cfg.plants):
        raise ValueError("--plants takes time-invariant plants (jumps: the jump scenario)")
    if "nominal" in cfg.scenarios and not cfg.plants:
        raise ValueError("the nominal scenario needs at least one plant (--plants)")
    check_mimo_plants(cfg.mimo_plants, yardstick=False)  # names only: the rest comes last
    if "mimo" in cfg.scenarios and not cfg.mimo_plants:
        raise ValueError("the mimo scenario needs at least one plant (--mimo-plants)")
    from stcgym.envs.families import get_family

    try:
        fam = get_family(cfg.family)
    except (KeyError, ValueError, FileNotFoundError) as exc:
        raise ValueError(f"--family: {exc}") from None
    missing = [s for s in ("train", "validation", "test") if s not in fam.splits]
    if missing:
        raise ValueError(f"--family {cfg.family!r} needs the splits train, validation and test")
    bad = [v for v in cfg.ood if v not in fam.variant_names]
    if bad:
        raise ValueError(f"unknown --ood variant(s) {bad}; {cfg.family} has {fam.variant_names}")
    if "ood" in cfg.scenarios and not cfg.ood:
        raise ValueError("the ood scenarios need at least one --ood variant")
    _check_ladder(cfg)
    unknown = [a for a in cfg.tune_agents or [] if a not in ALGORITHMS]
    if unknown:
        raise ValueError(
            f"--tune-agents: unknown RL agent(s) {unknown}; choose from {sorted(ALGORITHMS)}"
        )
    if "stc_tuned" in cfg.agents and not (cfg.tune_trials or "stc" in cfg.tuned):
        raise ValueError("stc_tuned needs tuning trials (--tune-trials N, N >= 1)")
    if cfg.tune_trials and not set(FAMILY_KINDS) & set(cfg.scenarios):
        raise ValueError("--tune-trials tunes on the family's validation split: add its scenarios")
    family_only = [a for a in cfg.rl_agents if a in FAMILY_ALGORITHMS]
    on_ladder = "ladder" in cfg.scenarios and set(family_only) <= set(cfg.ladder_agents)
    if family_only and not (set(FAMILY_KINDS) & set(cfg.scenarios) or on_ladder):
        raise ValueError(
            f"{family_only} train on the plant family: add the family, ood or jump scenario"
        )


def _check_ladder(cfg: BenchConfig) -> None:
    """The rungs (registered families with the three splits) and the agents trained on them."""
    from stcgym.envs.families import get_family

    if "ladder" in cfg.scenarios and not cfg.ladder:
        raise ValueError("the ladder scenarios need at least one rung (--ladder)")
    if len(set(cfg.ladder)) != len(cfg.ladder):
        raise ValueError(f"--ladder lists a rung twice: {cfg.ladder}")
    for rung in cfg.ladder:
        try:
            fam = get_family(rung)
        except (KeyError, ValueError, FileNotFoundError) as exc:
            raise ValueError(f"--ladder: {exc}") from None
        if any(s not in fam.splits for s in ("train", "validation", "test")):
            raise ValueError(f"--ladder: {rung!r} needs the splits train, validation and test")
    unknown = [a for a in cfg.ladder_agents if a not in ALGORITHMS]
    if unknown:
        raise ValueError(
            f"--ladder-agents: unknown RL agent(s) {unknown}; choose from {sorted(ALGORITHMS)}"
        )


def _check_numbers(cfg: BenchConfig) -> None:
    for name in (
        "train_seeds",
        "episodes_per_plant",
        "nominal_episodes",
        "curve_episodes",
        "bound_plants",
        "curve_points",
        "jobs",
        "bootstrap_reps",
    ):
        _set(cfg, name, _positive_int(getattr(cfg, name), f"--{name.replace('_', '-')}"))
    if cfg.test_plants is not None:
        _set(cfg, "test_plants", _positive_int(cfg.test_plants, "--test-plants"))
    if cfg.tune_trials:
        _set(cfg, "tune_trials", _positive_int(cfg.tune_trials, "--tune-trials"))
        if not 0 < float(cfg.tune_fraction) <= 1:
            raise ValueError(f"tune_fraction must be in (0, 1], got {cfg.tune_fraction!r}")
        try:
            import optuna  # noqa: F401
        except ImportError:
            raise ValueError("--tune-trials needs optuna (pip install 'stcgym[rl]')") from None
    if cfg.episode_steps is not None:
        _set(cfg, "episode_steps", _positive_int(cfg.episode_steps, "--episode-steps"))
        if cfg.episode_steps < 20:
            raise ValueError(f"--episode-steps must be >= 20, got {cfg.episode_steps}")
    try:
        first = int(cfg.first_seed)
    except (TypeError, ValueError):
        first = -1
    if first != cfg.first_seed or first < 0:
        raise ValueError(f"--first-seed must be an integer >= 0, got {cfg.first_seed!r}")
    _set(cfg, "first_seed", first)
    if cfg.noise_std is not None:
        _set(cfg, "noise_std", _finite(cfg.noise_std, "--noise", positive=True))
    from stcgym.agents.executors import EXECUTORS

    if cfg.executor not in EXECUTORS:
        raise ValueError(f"--executor must be one of {EXECUTORS}, got {cfg.executor!r}")
    if cfg.address is not None and cfg.executor != "ray":
        raise ValueError("--address needs --executor ray")
    if cfg.tensorboard_log is not None and not cfg.rl_agents:
        raise ValueError("--tensorboard-log needs at least one RL agent in --agents")
    for name in ("action_bounds", "action_units"):
        what = name.replace("_", " ")[:-1]  # "action bound", "action unit"
        values = getattr(cfg, name).items()
        _set(cfg, name, {k: _finite(v, f"{what} of {k}", positive=True) for k, v in values})


def validate(cfg: BenchConfig, train_steps: str | int | dict | None = None) -> None:
    """Check every input, fill in training budgets and algorithm configs; raise ``ValueError``."""
    from stcgym.agents.rl.configs import validate_config

    _check_names(cfg)
    _check_numbers(cfg)
    # Training caps and configs: defaults of the mode, then --eval-interval, --hp and
    # --train-steps (which sets the cap on one plant and on the family alike).
    cfg.plateau  # noqa: B018  (the PlateauRule's ValueError names the option)
    configs = {a: default_config(a) for a in cfg.rl_agents}
    if cfg.eval_interval is not None:
        _set(cfg, "eval_interval", _positive_int(cfg.eval_interval, "--eval-interval"))
        for c in configs.values():
            c.eval_interval = cfg.eval_interval
    apply_overrides(configs, cfg.overrides)
    for c in configs.values():
        validate_config(c)
    given = parse_train_steps(train_steps, cfg.rl_agents)
    extra = sorted(set(given) - set(cfg.rl_agents))
    if extra and isinstance(train_steps, str) and "=" in train_steps:
        raise ValueError(f"--train-steps names {extra}, which are not among --agents")
    for name, cap in (("train_steps", _single_cap), ("family_train_steps", _family_cap)):
        caps = {a: given.get(a, cap(configs[a], cfg.mode)) for a in cfg.rl_agents}
        _set(cfg, name, caps)
    mimo_caps = {
        a: given.get(a, _mimo_cap(configs[a], cfg.mode))
        for a in cfg.rl_agents
        if a not in FAMILY_ALGORITHMS  # (trained on the SISO family only)
    }
    _set(cfg, "mimo_train_steps", mimo_caps)
    for a in cfg.rl_agents:
        caps = [cfg.family_train_steps[a]]
        if a not in FAMILY_ALGORITHMS:  # these agents train on the family only
            caps.append(cfg.train_steps[a])
            if {"mimo", "mimo_switch", "mimo_family"} & set(cfg.scenarios):
                caps.append(cfg.mimo_train_steps[a])
        interval = configs[a].eval_interval
        if min(caps) < interval:
            raise ValueError(
                f"--train-steps: the {a} cap of {min(caps)} env steps is below one evaluation "
                f"interval of the plateau rule ({a}.eval_interval = {interval}); raise the cap "
                "or lower --eval-interval"
            )
    _set(cfg, "algo_configs", {a: configs[a].to_dict() for a in cfg.rl_agents})
    if {"mimo", "mimo_switch", "mimo_family"} & set(cfg.scenarios):
        check_mimo_plants(cfg.mimo_plants)  # compiles the Riccati solver: after every cheap check


def _single_cap(config: Any, mode: str) -> int:
    """The default cap on one plant: the config's for the tier; one evaluation interval in the
    smoke run."""
    if mode == "smoke":
        return config.eval_interval
    return getattr(config, _MODE_CAPS[mode][0])


def _family_cap(config: Any, mode: str) -> int:
    """The default cap on the plant family (as :func:`_single_cap`)."""
    if mode == "smoke":
        return config.eval_interval
    return getattr(config, _MODE_CAPS[mode][1])


def _mimo_cap(config: Any, mode: str) -> int:
    """The default cap on a MIMO plant: the single-plant cap of standard and full, and in quick
    :data:`QUICK_MIMO_INTERVALS` evaluation intervals (at most ``quick_steps``)."""
    if mode == "smoke":
        return config.eval_interval
    if mode == "quick":
        intervals = QUICK_MIMO_INTERVALS.get(config.algo, 1)
        return min(config.quick_steps, intervals * config.eval_interval)
    return getattr(config, _MODE_CAPS[mode][0])


#: The AlgoConfig fields of each mode's caps: (one plant, the plant family).
_MODE_CAPS = {
    "quick": ("quick_steps", "quick_steps"),
    "standard": ("standard_steps", "standard_family_steps"),
    "full": ("standard_steps", "full_steps"),
}
