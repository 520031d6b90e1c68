"""Hyperparameters of the RL agents, one readable config per algorithm.

The defaults follow the RL Baselines3 Zoo entries for ``Pendulum-v1`` (the Zoo's closest
problem: one bounded continuous action, dense quadratic cost, a few hundred steps per
episode), with two deliberate changes:

* small ``[64, 64]`` networks everywhere: the observation is a short window of scalars and the
  bench must train on two CPU cores in minutes (the Zoo's ``[400, 300]`` TD3 network is ~20x
  slower per gradient step here for no measurable gain on these plants);
* ``gamma = 0.95``: a tracking cost is immediate, so a horizon of ~20 steps (the closed-loop
  settling time of the catalogue plants) is enough and learns faster than 0.99.

Besides the keyword arguments of the Stable-Baselines3 constructor (``hyperparams``) a config
holds the bench-level knobs the Zoo keeps next to them: the number of parallel training envs
(``n_envs``), reward normalisation (``normalize_reward``, the Zoo's ``normalize``), a fixed
``reward_scale`` (off-policy learners), Gaussian exploration noise for TD3 (``noise_std``) and
the default training budget of the quick and full bench (``quick_steps``, ``full_steps``).

Override anything from the command line with ``--hp ALGO.KEY=VALUE``; ``VALUE`` is read as a
Python literal when it is one (``3e-4``, ``True``, ``[32, 32]``, ``{"net_arch": [32]}``) and as
a string otherwise; dotted keys reach into dicts (``ppo.policy_kwargs.net_arch=[32,32]``)::

    stcgym bench --quick --hp ppo.learning_rate=3e-4 --hp sac.hyperparams.batch_size=128

A key that is neither a config field nor a constructor argument of the algorithm is an error.
"""

from __future__ import annotations

import ast
import copy
import inspect
from dataclasses import asdict, dataclass, field, fields
from typing import Any

__all__ = [
    "ALGORITHMS",
    "AlgoConfig",
    "DEFAULT_CONFIGS",
    "algorithm_class",
    "apply_overrides",
    "default_config",
    "parse_override",
]

#: Algorithms the bench knows, with the Stable-Baselines3 class name.
ALGORITHMS: dict[str, str] = {"ppo": "PPO", "sac": "SAC", "td3": "TD3", "a2c": "A2C"}


def algorithm_class(algo: str) -> type:
    """The Stable-Baselines3 class of ``algo`` (imported lazily: SB3 pulls torch in)."""
    import stable_baselines3

    key = algo.lower()
    if key not in ALGORITHMS:
        raise ValueError(f"RL algorithm must be one of {sorted(ALGORITHMS)}, got {algo!r}")
    return getattr(stable_baselines3, ALGORITHMS[key])


@dataclass
class AlgoConfig:
    """One algorithm's training recipe (see the module docstring for each field)."""

    algo: str
    hyperparams: dict[str, Any]
    n_envs: int = 1
    normalize_reward: bool = False
    reward_scale: float = 1.0
    cost_squash: float | None = 1.0
    noise_std: float = 0.0
    quick_steps: int = 10_000
    full_steps: int = 100_000
    policy: str = "MlpPolicy"
    window: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return copy.deepcopy(asdict(self))

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> AlgoConfig:
        return cls(**copy.deepcopy(data))


_NET = {"net_arch": [64, 64]}

DEFAULT_CONFIGS: dict[str, AlgoConfig] = {
    # Zoo Pendulum-v1: n_envs 4, n_steps 1024, gamma 0.9, lr 1e-3, gSDE with sde_sample_freq 4.
    "ppo": AlgoConfig(
        "ppo",
        {
            "learning_rate": 1e-3,
            "n_steps": 512,
            "batch_size": 64,
            "n_epochs": 10,
            "gamma": 0.95,
            "gae_lambda": 0.95,
            "clip_range": 0.2,
            "ent_coef": 0.0,
            "policy_kwargs": {**_NET, "log_std_init": -2.0},
        },
        n_envs=4,
        normalize_reward=True,
        quick_steps=40_000,
        full_steps=400_000,
    ),
    # Zoo Pendulum-v1: lr 1e-3, otherwise SB3 defaults (buffer 1e6, batch 256, tau 0.005).
    "sac": AlgoConfig(
        "sac",
        {
            "learning_rate": 1e-3,
            "buffer_size": 200_000,
            "batch_size": 256,
            "gamma": 0.95,
            "learning_starts": 500,
            "train_freq": 1,
            "gradient_steps": 1,
            "policy_kwargs": dict(_NET),
        },
        quick_steps=12_000,
        full_steps=100_000,
    ),
    # Zoo Pendulum-v1: normal action noise 0.1, lr 1e-3, batch 256, train_freq 1. Rewards
    # scaled by 0.1: at 1.0 the deterministic actor ran into the input bound early and stayed
    # there on stable2 (SAC's entropy term gets it out; TD3 has none). Target
    # policy smoothing is cut from SB3's 0.2 (clip 0.5) to 0.05 (clip 0.1): with a +-10 input
    # range and useful inputs of ~0.1, 0.2 of the normalised range smooths the critic over
    # inputs that saturate the plant, and the actor runs into the bound and stays there.
    "td3": AlgoConfig(
        "td3",
        {
            "learning_rate": 1e-3,
            "buffer_size": 200_000,
            "batch_size": 256,
            "gamma": 0.95,
            "learning_starts": 500,
            "train_freq": 1,
            "gradient_steps": 1,
            "target_policy_noise": 0.05,
            "target_noise_clip": 0.1,
            "policy_kwargs": dict(_NET),
        },
        reward_scale=0.1,
        noise_std=0.05,
        quick_steps=12_000,
        full_steps=100_000,
    ),
    # Zoo Pendulum-v1 (A2C): n_envs 8, n_steps 8, gamma 0.9, RMSprop, gSDE, log_std_init -2.
    "a2c": AlgoConfig(
        "a2c",
        {
            "learning_rate": 7e-4,
            "n_steps": 8,
            "gamma": 0.95,
            "gae_lambda": 0.9,
            "vf_coef": 0.4,
            "ent_coef": 0.0,
            "max_grad_norm": 0.5,
            "use_rms_prop": True,
            "normalize_advantage": False,
            "use_sde": True,
            "policy_kwargs": {**_NET, "log_std_init": -2.0, "ortho_init": False},
        },
        n_envs=8,
        normalize_reward=True,
        quick_steps=40_000,
        full_steps=400_000,
    ),
}


def default_config(algo: str) -> AlgoConfig:
    """A fresh (deep-copied) default config of ``algo``."""
    key = algo.lower()
    if key not in DEFAULT_CONFIGS:
        raise ValueError(f"RL algorithm must be one of {sorted(DEFAULT_CONFIGS)}, got {algo!r}")
    return copy.deepcopy(DEFAULT_CONFIGS[key])


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
    ``ppo.hyperparams.learning_rate=3e-4``). Raises ``ValueError`` for an unknown algorithm or
    key, before anything is trained.
    """
    config_fields = {f.name for f in fields(AlgoConfig)} - {"algo"}
    for text in overrides:
        algo, path, value = parse_override(text)
        if algo not in ALGORITHMS:
            raise ValueError(f"--hp {text!r}: algorithm must be one of {sorted(ALGORITHMS)}")
        if algo not in configs:
            configs[algo] = default_config(algo)
        cfg = configs[algo]
        if path[0] in config_fields:
            if len(path) == 1:
                setattr(cfg, path[0], value)
                continue
            target, path = getattr(cfg, path[0]), path[1:]
            if not isinstance(target, dict):
                raise ValueError(f"--hp {text!r}: {algo}.{path[0]} is not a dict")
            if target is cfg.hyperparams and path[0] not in _constructor_args(algo):
                raise ValueError(
                    f"--hp {text!r}: {path[0]!r} is not an argument of "
                    f"{ALGORITHMS[algo]} (known: {sorted(_constructor_args(algo))})"
                )
        else:
            if path[0] not in _constructor_args(algo):
                raise ValueError(
                    f"--hp {text!r}: {path[0]!r} is neither a config field "
                    f"({sorted(config_fields)}) nor an argument of {ALGORITHMS[algo]}"
                )
            target = cfg.hyperparams
        for p in path[:-1]:
            target = target.setdefault(p, {})
            if not isinstance(target, dict):
                raise ValueError(f"--hp {text!r}: {p!r} is not a dict")
        target[path[-1]] = value
    return configs
