"""What every value of an RL agent's config must be, checked before anything is trained.

Stable-Baselines3 asserts some of its constructor arguments only when the model is built, or,
like ``batch_size=0``, not at all: :func:`validate_config` checks a whole
:class:`~stcgym.agents.AlgoConfig` against the rules below (one per constructor argument and
per config field) and names the key of the first value it rejects. ``--hp`` overrides
(:func:`~stcgym.agents.apply_overrides`) are checked by the same rules.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from stcgym.agents.rl.configs import AlgoConfig

__all__ = [
    "FIELD_RULES",
    "HYPERPARAMETER_RULES",
    "POLICIES",
    "RESERVED_ARGS",
    "validate_config",
]

#: Keyword arguments the bench sets itself; ``--hp`` may not touch them.
RESERVED_ARGS: dict[str, str] = {
    "tensorboard_log": "use --tensorboard-log DIR",
    "verbose": "set by the bench",
    "seed": "use --train-seeds",
    "device": "the bench trains on the CPU",
    "env": "set by the bench",
    "policy": "use ALGO.policy (a config field)",
    "action_noise": "use ALGO.noise_std",
    "replay_buffer_class": "not configurable from the command line",
    "replay_buffer_kwargs": "not configurable from the command line",
}


# ------------------------------------------------------------------------------ value rules
def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _rule(check: Callable[[Any], bool], expected: str) -> tuple[Callable[[Any], bool], str]:
    return check, expected


_POSITIVE = _rule(lambda v: _is_num(v) and v > 0, "a positive number")
_NONNEG = _rule(lambda v: _is_num(v) and v >= 0, "a number >= 0")
_UNIT = _rule(lambda v: _is_num(v) and 0 <= v <= 1, "a number in [0, 1]")
_DISCOUNT = _rule(lambda v: _is_num(v) and 0 < v <= 1, "a number in (0, 1]")
_COUNT = _rule(lambda v: _is_int(v) and v >= 1, "an integer >= 1")
_COUNT0 = _rule(lambda v: _is_int(v) and v >= 0, "an integer >= 0")
_BOOL = _rule(lambda v: isinstance(v, bool), "True or False")
_OPT_POSITIVE = _rule(lambda v: v is None or (_is_num(v) and v > 0), "None or a positive number")


def _train_freq(v: Any) -> bool:
    if _is_int(v):
        return v >= 1
    return (
        isinstance(v, (list, tuple))
        and len(v) == 2
        and _is_int(v[0])
        and v[0] >= 1
        and v[1] in ("step", "episode")
    )


def _ent_coef(v: Any) -> bool:
    if isinstance(v, str) and (v == "auto" or v.startswith("auto_")):
        try:
            return v == "auto" or float(v[5:]) > 0
        except ValueError:
            return False
    return _is_num(v) and v >= 0


#: What each constructor argument must be (SB3's own rules, checked before anything starts:
#: SB3 asserts some of them only when the model is built or, like ``batch_size=0``, not at all).
HYPERPARAMETER_RULES: dict[str, tuple[Callable[[Any], bool], str]] = {
    "learning_rate": _POSITIVE,
    "gamma": _DISCOUNT,
    "gae_lambda": _UNIT,
    "tau": _DISCOUNT,
    "clip_range": _POSITIVE,
    "clip_range_vf": _OPT_POSITIVE,
    "ent_coef": _rule(_ent_coef, "a number >= 0 (SAC also 'auto' or 'auto_<init>')"),
    "vf_coef": _NONNEG,
    "max_grad_norm": _POSITIVE,
    "batch_size": _COUNT,
    "n_steps": _COUNT,
    "n_epochs": _COUNT,
    "buffer_size": _COUNT,
    "learning_starts": _COUNT0,
    "train_freq": _rule(_train_freq, "an integer >= 1 or [N, 'step'|'episode']"),
    "gradient_steps": _rule(lambda v: _is_int(v) and (v >= 1 or v == -1), "an integer >= 1 or -1"),
    "policy_delay": _COUNT,
    "target_policy_noise": _NONNEG,
    "target_noise_clip": _NONNEG,
    "target_update_interval": _COUNT,
    "target_entropy": _rule(lambda v: v == "auto" or _is_num(v), "'auto' or a number"),
    "target_kl": _OPT_POSITIVE,
    "use_sde": _BOOL,
    "use_sde_at_warmup": _BOOL,
    "sde_sample_freq": _rule(lambda v: _is_int(v) and v >= -1, "an integer >= -1"),
    "normalize_advantage": _BOOL,
    "use_rms_prop": _BOOL,
    "rms_prop_eps": _POSITIVE,
    "optimize_memory_usage": _BOOL,
    "stats_window_size": _COUNT,
    "policy_kwargs": _rule(lambda v: isinstance(v, dict), "a dict"),
}

#: What each :class:`AlgoConfig` field must be.
FIELD_RULES: dict[str, tuple[Callable[[Any], bool], str]] = {
    "n_envs": _COUNT,
    "normalize_reward": _BOOL,
    "normalize_obs": _BOOL,
    "reward": _rule(lambda v: v in ("lqg_ratio", "cost"), "'lqg_ratio' or 'cost'"),
    "cost_cap": _OPT_POSITIVE,
    "reward_scale": _POSITIVE,
    "cost_squash": _OPT_POSITIVE,
    "noise_std": _NONNEG,
    "quick_steps": _COUNT,
    "standard_steps": _COUNT,
    "standard_family_steps": _COUNT,
    "full_steps": _COUNT,
    "eval_interval": _COUNT,
    "policy": _rule(lambda v: isinstance(v, str) and bool(v), "a policy name such as MlpPolicy"),
    "window": _rule(lambda v: isinstance(v, dict), "a dict of WindowConfig fields"),
    "interface": _rule(lambda v: isinstance(v, dict), "a dict of InterfaceSpec fields"),
    "hyperparams": _rule(lambda v: isinstance(v, dict), "a dict"),
}

#: Policy names each algorithm accepts (SB3's ``policy_aliases``).
POLICIES: dict[str, tuple[str, ...]] = {
    "ppo": ("MlpPolicy",),
    "a2c": ("MlpPolicy",),
    "sac": ("MlpPolicy",),
    "td3": ("MlpPolicy",),
    "rppo": ("MlpLstmPolicy",),
}


def validate_config(cfg: AlgoConfig) -> None:
    """Check every value of ``cfg`` against the rules above; ``ValueError`` names the key.

    Beyond single values: PPO-family rollouts need ``n_steps * n_envs > 1`` and PPO's
    minibatches ``batch_size > 1`` (SB3 asserts both only when the model is built).
    """
    from stcgym.agents.rl.configs import base_algorithm
    from stcgym.agents.rl.interfaces import InterfaceSpec
    from stcgym.agents.rl.wrappers import WindowConfig

    name = cfg.algo
    kind = base_algorithm(name)  # an ablation or informed agent: its base agent's rules
    for key, (check, expected) in FIELD_RULES.items():
        value = getattr(cfg, key)
        if not check(value):
            raise ValueError(f"{name}.{key} must be {expected}, got {value!r}")
    if cfg.policy not in POLICIES.get(kind, (cfg.policy,)):
        raise ValueError(f"{name}.policy must be one of {POLICIES[kind]}, got {cfg.policy!r}")
    try:
        WindowConfig(**cfg.window)
    except TypeError as exc:
        raise ValueError(f"{name}.window: {exc}") from None
    bad = sorted(set(cfg.interface) & {"order", "run"})
    if bad:
        raise ValueError(f"{name}.interface.{bad[0]} is set by the bench, not a config value")
    try:
        InterfaceSpec(**cfg.interface)
    except TypeError as exc:
        raise ValueError(f"{name}.interface: {exc}") from None
    except ValueError as exc:
        raise ValueError(f"{name}.{exc}") from None
    for key, value in cfg.hyperparams.items():
        if key in RESERVED_ARGS:
            raise ValueError(f"{name}.{key} is not a hyperparameter ({RESERVED_ARGS[key]})")
        rule = HYPERPARAMETER_RULES.get(key)
        if rule is not None and not rule[0](value):
            raise ValueError(f"{name}.{key} must be {rule[1]}, got {value!r}")
    hp = cfg.hyperparams
    if kind in ("ppo", "a2c", "rppo") and hp.get("n_steps", 2) * cfg.n_envs < 2:
        raise ValueError(f"{name}: n_steps * n_envs must be > 1 (SB3's rollout rule)")
    if kind in ("ppo", "rppo") and hp.get("batch_size", 2) < 2:
        raise ValueError(f"{name}.batch_size must be > 1 (PPO normalises advantages per batch)")
    if kind == "sac" and "ent_coef" in hp and not _ent_coef(hp["ent_coef"]):
        raise ValueError(f"{name}.ent_coef must be a number >= 0, 'auto' or 'auto_<init>'")
    if kind != "sac" and isinstance(hp.get("ent_coef"), str):
        raise ValueError(f"{name}.ent_coef must be a number >= 0, got {hp['ent_coef']!r}")
