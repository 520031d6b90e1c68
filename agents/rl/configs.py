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
the training caps of each bench tier (``quick_steps``, ``standard_steps`` and
``standard_family_steps``, ``full_steps``) and the evaluation interval of the plateau rule
(``eval_interval``, :mod:`stcgym.agents.rl.stopping`): every tier trains an agent until its
learning curve plateaus or it reaches the tier's cap.

* quick: what fits three training seeds of PPO, SAC and RecurrentPPO on two training
  environments into the 10 minutes of ``make bench`` on 2 cores (SAC and TD3 make one gradient
  step per environment step, ~7 ms on one core, so they get the smallest budget); most agents
  reach the cap before a plateau, which the report says.
* standard (about an hour on 2 cores): the single-plant caps are the Zoo's tuned
  ``n_timesteps`` for ``Pendulum-v1`` (``hyperparams/ppo.yml`` 1e5, ``sac.yml`` and
  ``td3.yml`` 2e4; A2C gets 4e5 instead of ``a2c.yml``'s 1e6); agents trained on the
  randomised plant family get 3-5x more (``standard_family_steps``: PPO 3e5, SAC and TD3
  1e5), RecurrentPPO the Zoo's budget of its closest entry, ``PendulumNoVel-v1`` in
  ``hyperparams/ppo_lstm.yml`` (1e5). The Zoo tuned these budgets to where the learning curve
  has levelled off on the pendulum; the plateau rule stops a run earlier when ours levels off
  first, and the report says which runs hit the cap before a plateau.
* full: long caps for a day on 2 cores.

``eval_interval`` is a whole number of PPO / RecurrentPPO rollouts (``n_steps x n_envs``), so
that each evaluation sees a freshly updated policy.

Override anything from the command line with ``--hp ALGO.KEY=VALUE``; ``VALUE`` is read as a
Python literal when it is one (``3e-4``, ``True``, ``[32, 32]``, ``{"net_arch": [32]}``) and as
a string otherwise; dotted keys reach into dicts (``ppo.policy_kwargs.net_arch=[32,32]``)::

    stcgym bench --quick --hp ppo.learning_rate=3e-4 --hp sac.hyperparams.batch_size=128

A key that is neither a config field nor a constructor argument of the algorithm is an error;
every value is checked by the rules of :mod:`stcgym.agents.rl.config_rules`.
"""

from __future__ import annotations

import ast
import copy
import inspect
from dataclasses import asdict, dataclass, field, fields
from typing import Any

from stcgym.agents.rl.config_rules import HYPERPARAMETER_RULES, RESERVED_ARGS, validate_config

__all__ = [
    "ALGORITHMS",
    "HYPERPARAMETER_RULES",
    "RECURRENT_ALGORITHMS",
    "RESERVED_ARGS",
    "validate_config",
    "AlgoConfig",
    "DEFAULT_CONFIGS",
    "algorithm_class",
    "apply_overrides",
    "default_config",
    "parse_override",
]

#: Algorithms the bench knows, with the Stable-Baselines3 (or sb3-contrib) class name.
ALGORITHMS: dict[str, str] = {
    "ppo": "PPO",
    "sac": "SAC",
    "td3": "TD3",
    "a2c": "A2C",
    "rppo": "RecurrentPPO",
}

#: Recurrent (LSTM) agents: the adaptive-RL baseline. They are trained on the randomised plant
#: family, never on one plant, and evaluated where adaptation is asked for (held-out plants,
#: parameter jumps): the meta-RL recipe, where the memory must identify the plant in context.
RECURRENT_ALGORITHMS: tuple[str, ...] = ("rppo",)


def algorithm_class(algo: str) -> type:
    """The SB3 / sb3-contrib class of ``algo`` (imported lazily: SB3 pulls torch in)."""
    key = algo.lower()
    if key not in ALGORITHMS:
        raise ValueError(f"RL algorithm must be one of {sorted(ALGORITHMS)}, got {algo!r}")
    if key in RECURRENT_ALGORITHMS:
        import sb3_contrib

        return getattr(sb3_contrib, ALGORITHMS[key])
    import stable_baselines3

    return getattr(stable_baselines3, ALGORITHMS[key])


@dataclass
class AlgoConfig:
    """One algorithm's training recipe (see the module docstring for each field).

    A plain dataclass: :func:`validate_config` checks it (the bench does before training).

    Parameters
    ----------
    algo : str
        ``"ppo"``, ``"sac"``, ``"td3"``, ``"a2c"`` or ``"rppo"`` (:data:`ALGORITHMS`).
    hyperparams : dict
        Keyword arguments of the Stable-Baselines3 constructor.
    n_envs : int, default 1
        Parallel training environments.
    normalize_reward : bool, default False
        Reward normalisation (the Zoo's ``normalize``).
    reward_scale : float, default 1.0
        Fixed factor on the training reward (:class:`~stcgym.agents.TrainingReward`).
    cost_squash : float or None, default 1.0
        Cost compression of :class:`~stcgym.agents.TrainingReward`.
    noise_std : float, default 0.0
        Gaussian exploration noise (TD3).
    quick_steps, standard_steps, standard_family_steps, full_steps : int
        Training caps of the bench tiers.
    eval_interval : int, default 10000
        Steps between the evaluations of the plateau rule.
    policy : str, default "MlpPolicy"
        SB3 policy class name.
    window : dict
        Fields of :class:`~stcgym.agents.WindowConfig` (its defaults when empty).

    Examples
    --------
    >>> from stcgym.agents import AlgoConfig, default_config
    >>> cfg = default_config("ppo")
    >>> cfg.algo, cfg.n_envs, cfg.hyperparams["learning_rate"]
    ('ppo', 4, 0.001)
    >>> AlgoConfig.from_dict(cfg.to_dict()) == cfg
    True
    """

    algo: str
    hyperparams: dict[str, Any]
    n_envs: int = 1
    normalize_reward: bool = False
    reward_scale: float = 1.0
    cost_squash: float | None = 1.0
    noise_std: float = 0.0
    quick_steps: int = 10_000
    standard_steps: int = 100_000
    standard_family_steps: int = 100_000
    full_steps: int = 100_000
    eval_interval: int = 10_000
    policy: str = "MlpPolicy"
    window: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """The config as JSON data (a deep copy; :meth:`from_dict` reads it back)."""
        return copy.deepcopy(asdict(self))

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> AlgoConfig:
        """Inverse of :meth:`to_dict`.

        Parameters
        ----------
        data : dict
            The fields (deep-copied).

        Returns
        -------
        AlgoConfig
        """
        return cls(**copy.deepcopy(data))


_NET = {"net_arch": [64, 64]}

# The off-policy learners (SAC, TD3) share the Zoo's Pendulum-v1 recipe (lr 1e-3, batch 256,
# one gradient step per environment step) and the training caps: the Zoo's n_timesteps for
# Pendulum-v1 is 2e4 in both sac.yml and td3.yml.
_OFF_POLICY: dict[str, Any] = {
    "learning_rate": 1e-3,
    "buffer_size": 200_000,
    "batch_size": 256,
    "gamma": 0.95,
    "learning_starts": 500,
    "train_freq": 1,
    "gradient_steps": 1,
}
_OFF_POLICY_BUDGETS: dict[str, int] = {
    "quick_steps": 6_000,
    "standard_steps": 20_000,
    "standard_family_steps": 100_000,
    "full_steps": 100_000,
    "eval_interval": 2_000,
}

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
        quick_steps=40_960,
        standard_steps=100_000,  # Zoo ppo.yml Pendulum-v1 n_timesteps
        standard_family_steps=300_000,
        full_steps=400_000,
        eval_interval=10_240,  # 5 rollouts of 4 x 512
    ),
    # Zoo Pendulum-v1: lr 1e-3, otherwise SB3 defaults (buffer 1e6, batch 256, tau 0.005).
    "sac": AlgoConfig(
        "sac",
        {**_OFF_POLICY, "policy_kwargs": dict(_NET)},
        **_OFF_POLICY_BUDGETS,
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
            **_OFF_POLICY,
            "target_policy_noise": 0.05,
            "target_noise_clip": 0.1,
            "policy_kwargs": dict(_NET),
        },
        reward_scale=0.1,
        noise_std=0.05,
        **_OFF_POLICY_BUDGETS,
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
        # the Zoo's 1e6 (a2c.yml Pendulum-v1) would take ~30 min per seed here: the full cap
        standard_steps=400_000,
        standard_family_steps=400_000,
        full_steps=400_000,
        eval_interval=20_480,  # 320 rollouts of 8 x 8
    ),
    # sb3-contrib RecurrentPPO, after the Zoo's ppo_lstm entries for the velocity-free
    # Pendulum (n_envs 4, gamma 0.9, lr 1e-3, LSTM policy with a [64] head): an LSTM of 32
    # units over a 2-sample window of y, r, u, e, so that the memory, not the window, has to
    # identify the plant. Trained on the plant family only (see RECURRENT_ALGORITHMS).
    "rppo": AlgoConfig(
        "rppo",
        {
            "learning_rate": 1e-3,
            "n_steps": 256,
            "batch_size": 256,
            "n_epochs": 10,
            "gamma": 0.95,
            "gae_lambda": 0.95,
            "clip_range": 0.2,
            "ent_coef": 0.0,
            "policy_kwargs": {
                "lstm_hidden_size": 32,
                "net_arch": [64],
                "log_std_init": -2.0,
            },
        },
        n_envs=4,
        normalize_reward=True,
        quick_steps=15_360,
        standard_steps=100_000,  # Zoo ppo_lstm.yml PendulumNoVel-v1 n_timesteps
        standard_family_steps=100_000,
        full_steps=300_000,
        eval_interval=5_120,  # 5 rollouts of 4 x 256
        policy="MlpLstmPolicy",
        window={"window": 2},
    ),
}


def default_config(algo: str) -> AlgoConfig:
    """A fresh (deep-copied) default config of ``algo``.

    Parameters
    ----------
    algo : str
        An algorithm of :data:`DEFAULT_CONFIGS` (case-insensitive).

    Returns
    -------
    AlgoConfig
        A copy: changing it leaves the defaults alone.

    Raises
    ------
    ValueError
        An unknown ``algo``, listing the known ones.

    Examples
    --------
    >>> from stcgym.agents import default_config
    >>> default_config("SAC").hyperparams["gamma"]
    0.95
    >>> default_config("dqn")
    Traceback (most recent call last):
    ...
    ValueError: RL algorithm must be one of ['a2c', 'ppo', 'rppo', 'sac', 'td3'], got 'dqn'
    """
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
        if path[0] in config_fields:
            if len(path) == 1:
                setattr(cfg, path[0], value)
                _check(cfg, text)
                continue
            target, path = getattr(cfg, path[0]), path[1:]
            if not isinstance(target, dict):
                raise ValueError(f"--hp {text!r}: {algo}.{path[0]} is not a dict")
            if target is cfg.hyperparams and path[0] in RESERVED_ARGS:
                raise ValueError(
                    f"--hp {text!r}: {path[0]!r} is not a hyperparameter ({RESERVED_ARGS[path[0]]})"
                )
            if target is cfg.hyperparams and path[0] not in _constructor_args(algo):
                raise ValueError(
                    f"--hp {text!r}: {path[0]!r} is not an argument of "
                    f"{ALGORITHMS[algo]} (known: {sorted(_constructor_args(algo))})"
                )
        else:
            if path[0] in RESERVED_ARGS:
                raise ValueError(
                    f"--hp {text!r}: {path[0]!r} is not a hyperparameter ({RESERVED_ARGS[path[0]]})"
                )
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
        _check(cfg, text)
    return configs


def _check(cfg: AlgoConfig, text: str) -> None:
    try:
        validate_config(cfg)
    except ValueError as exc:
        raise ValueError(f"--hp {text!r}: {exc}") from None
