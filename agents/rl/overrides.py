"""``--hp ALGO.KEY=VALUE``: overrides of the RL agents' configs
(:mod:`stcgym.agents.rl.configs`) from the command line or a list of strings.

``VALUE`` is read as a Python literal when it is one (``3e-4``, ``True``, ``[32, 32]``,
``{"net_arch": [32]}``) and as a string otherwise; dotted keys reach into dicts
(``ppo.policy_kwargs.net_arch=[32,32]``)::

    stcgym bench --quick --hp ppo.learning_rate=3e-4 --hp sac.hyperparams.batch_size=128

A key that is neither a config field nor a constructor argument of the algorithm is an error;
every value is checked by the rules of :mod:`stcgym.agents.rl.config_rules`.
"""

from __future__ import annotations

import ast
import inspect
from dataclasses import fields
from typing import Any

from stcgym.agents.rl.config_rules import RESERVED_ARGS, validate_config
from stcgym.agents.rl.configs import ALGORITHMS, AlgoConfig, algorithm_class, default_config

__all__ = ["apply_overrides", "parse_override"]


def parse_override(text: str) -> tuple[str, list[str], Any]:
    """``"ppo.learning_rate=3e-4"`` -> ``("ppo", ["learning_rate"], 0.0003)``."""
    if "=" not in text:
        raise ValueError(f"--hp expects ALGO.KEY=VALUE, got {text!r}")
    key, raw = text.split("=", 1)
    parts = [p for p in key.strip().split(".") if p]
    if len(parts) < 2:
        raise ValueError(f"--hp expects ALGO.KEY=VALUE (e.g. ppo.learning_rate=3e-4), got {text!r}")
    try:
        value = ast.literal_eval(raw.strip())
    except (ValueError, SyntaxError):
        value = raw.strip()
    return parts[0].lower(), parts[1:], value


def _constructor_args(algo: str) -> set[str]:
    params = inspect.signature(algorithm_class(algo).__init__).parameters
    return {p for p in params if p not in ("self", "policy", "env", "_init_setup_model")}


def apply_overrides(
    configs: dict[str, AlgoConfig], overrides: list[str] | tuple[str, ...]
) -> dict[str, AlgoConfig]:
    """Apply ``--hp`` overrides to ``configs`` (in place) and return them.

    A first key that names an :class:`AlgoConfig` field sets that field (``ppo.n_envs=8``);
    otherwise it is a constructor argument (``ppo.learning_rate=3e-4`` is short for
    ``ppo.hyperparams.learning_rate=3e-4``).

    Parameters
    ----------
    configs : dict of str to AlgoConfig
        Configs by algorithm; an override of an algorithm not in it adds its default config.
    overrides : sequence of str
        ``"ALGO.KEY=VALUE"`` (``KEY`` may be dotted into a dict field); ``VALUE`` is read as a
        Python literal, else kept as a string.

    Returns
    -------
    dict of str to AlgoConfig
        ``configs``, changed in place.

    Raises
    ------
    ValueError
        A malformed override, an unknown algorithm or key, a reserved argument (``seed``,
        ``verbose``, ...) or a value its rule rejects, before anything is trained.

    Examples
    --------
    >>> from stcgym.agents import apply_overrides
    >>> configs = apply_overrides({}, ["ppo.learning_rate=3e-4", "ppo.n_envs=8"])
    >>> configs["ppo"].hyperparams["learning_rate"], configs["ppo"].n_envs
    (0.0003, 8)
    >>> apply_overrides({}, ["ppo.lerning_rate=1"])
    Traceback (most recent call last):
    ...
    ValueError: --hp 'ppo.lerning_rate=1': 'lerning_rate' is neither a config field ...
    """
    config_fields = {f.name for f in fields(AlgoConfig)} - {"algo"}
    for text in overrides:
        algo, path, value = parse_override(text)
        if algo not in ALGORITHMS:
            raise ValueError(f"--hp {text!r}: algorithm must be one of {sorted(ALGORITHMS)}")
        if algo not in configs:
            configs[algo] = default_config(algo)
        cfg = configs[algo]
        if path[0] in config_fields and len(path) == 1:
            setattr(cfg, path[0], value)
            _check(cfg, text)
            continue
        if path[0] in config_fields:
            target = getattr(cfg, path[0])
            if not isinstance(target, dict):
                raise ValueError(f"--hp {text!r}: {algo}.{path[0]} is not a dict")
            path = path[1:]
        elif path[0] in RESERVED_ARGS or path[0] in _constructor_args(algo):
            target = cfg.hyperparams  # short for ALGO.hyperparams.KEY
        else:
            raise ValueError(
                f"--hp {text!r}: {path[0]!r} is neither a config field "
                f"({sorted(config_fields)}) nor an argument of {ALGORITHMS[algo]}"
            )
        if target is cfg.hyperparams:
            _check_argument(algo, path[0], text)
        for p in path[:-1]:
            target = target.setdefault(p, {})
            if not isinstance(target, dict):
                raise ValueError(f"--hp {text!r}: {p!r} is not a dict")
        target[path[-1]] = value
        _check(cfg, text)
    return configs


def _check_argument(algo: str, name: str, text: str) -> None:
    """A constructor argument an override may set: not one the bench sets itself."""
    if name in RESERVED_ARGS:
        raise ValueError(f"--hp {text!r}: {name!r} is not a hyperparameter ({RESERVED_ARGS[name]})")
    if name not in _constructor_args(algo):
        raise ValueError(
            f"--hp {text!r}: {name!r} is not an argument of "
            f"{ALGORITHMS[algo]} (known: {sorted(_constructor_args(algo))})"
        )


def _check(cfg: AlgoConfig, text: str) -> None:
    try:
        validate_config(cfg)
    except ValueError as exc:
        raise ValueError(f"--hp {text!r}: {exc}") from None
