"""Hyperparameters of the RL agents, one readable config per algorithm.

The defaults are the RL Baselines3 Zoo's entries for its closest problems, ``Pendulum-v1``
(``ppo.yml``, ``sac.yml``, ``td3.yml``, ``a2c.yml``: one bounded continuous action, a dense
quadratic cost) and, for RecurrentPPO, ``PendulumNoVel-v1`` in ``ppo_lstm.yml`` (the same task
observed without velocity, so the memory must infer it). Every setting that differs from the
Zoo's is listed in :data:`~stcgym.agents.rl.zoo_departures.ZOO_DEPARTURES` with its reason and
measurement (the report prints the list); the main ones: PPO's and RecurrentPPO's update (16
lanes of 256 steps, so that one update sees 16 plants, minibatches of 256, lr 3e-4,
``target_kl`` 0.03: with the Zoo's settings approx_kl and clip_fraction were 4-6x and 2x their
usual ranges; ``gamma`` is the Zoo's 0.9, chosen again by an ablation of 0.9 / 0.95 / 0.99,
``benchmarks/rl_ablation.py``), observation and reward normalisation (SB3's ``VecNormalize``,
the Zoo's ``normalize``: the observation mixes signals of different scales), and small networks
or LSTMs where the Zoo's would not train on two CPU cores in the time a tier has. Every agent
trains on the score per step (``reward = "lqg_ratio"``, :mod:`stcgym.agents.rl.reward`).

Besides the keyword arguments of the Stable-Baselines3 constructor (``hyperparams``) a config
holds the bench-level knobs the Zoo keeps next to them: the number of parallel training envs
(``n_envs``), reward and observation normalisation (``normalize_reward``, ``normalize_obs``), a
fixed ``reward_scale``, Gaussian exploration noise for TD3 (``noise_std``), the observation
window (``window``: :class:`~stcgym.agents.rl.wrappers.WindowConfig`, the integral of the
tracking error on by default) and the training caps of each bench tier (``quick_steps``,
``standard_steps`` on one plant and ``standard_family_steps`` on a plant family, ``full_steps``)
with the evaluation interval of the plateau rule (``eval_interval``,
:mod:`stcgym.agents.rl.stopping`): every tier trains an agent until its learning curve plateaus
or it reaches the tier's cap. The standard tier gives PPO and RecurrentPPO 10^6 environment
steps on the family (through the native vector env); SAC, on 8 lanes with a quarter of the
Zoo's gradient steps per environment step, gets 2 x 10^5.

``eval_interval`` is a whole number of PPO / RecurrentPPO rollouts (``n_steps x n_envs``), so
that each evaluation sees a freshly updated policy.

Override anything from the command line with ``--hp ALGO.KEY=VALUE``
(:mod:`stcgym.agents.rl.overrides`); every value is checked by the rules of
:mod:`stcgym.agents.rl.config_rules`.
"""

from __future__ import annotations

import copy
from dataclasses import asdict, dataclass, field
from typing import Any

from stcgym.agents.rl.config_rules import HYPERPARAMETER_RULES, RESERVED_ARGS, validate_config
from stcgym.agents.rl.interfaces import InterfaceSpec

__all__ = [
    "ABLATIONS",
    "ALGORITHMS",
    "FAMILY_ALGORITHMS",
    "INFORMED",
    "HYPERPARAMETER_RULES",
    "RECURRENT_ALGORITHMS",
    "TRUE_PARAMETER_ALGORITHMS",
    "RESERVED_ARGS",
    "validate_config",
    "AlgoConfig",
    "DEFAULT_CONFIGS",
    "agent_knowledge",
    "algorithm_class",
    "base_algorithm",
    "default_config",
    "with_action_unit",
]

#: RL agents the bench knows, with the Stable-Baselines3 (or sb3-contrib) class name.
ALGORITHMS: dict[str, str] = {
    "ppo": "PPO",
    "sac": "SAC",
    "td3": "TD3",
    "a2c": "A2C",
    "rppo": "RecurrentPPO",
    "ppo_noint": "PPO",
    "theta_ppo": "PPO",
    "theta_sac": "SAC",
    "residual_ppo": "PPO",
    "oracle_ppo": "PPO",
}

#: Ablations: ``agent -> (the agent it varies, what differs)``, each with its own default
#: config (the full tier runs them).
ABLATIONS: dict[str, tuple[str, str]] = {
    "ppo_noint": ("ppo", "PPO without the integral of the tracking error among its inputs"),
}

#: Recurrent (LSTM) agents: the adaptive-RL baseline. They are trained on the randomised plant
#: family, never on one plant, and evaluated where adaptation is asked for (held-out plants,
#: parameter jumps): the meta-RL recipe, where the memory must identify the plant in context.
RECURRENT_ALGORITHMS: tuple[str, ...] = ("rppo",)

#: Agents that know what a classical part knows (:mod:`stcgym.agents.rl.interfaces`): ``agent
#: -> (the agent it extends, what it is given)``. The estimate-conditioned agents observe an
#: estimator's online estimate besides their window; the residual agent corrects the
#: self-tuning controller's input. They are trained on the randomised SISO plant family.
INFORMED: dict[str, tuple[str, str]] = {
    "theta_ppo": ("ppo", "PPO observing the self-tuning controller's online estimate (its "
                  "extended least squares: theta_hat, log10 diag P, the innovation) besides "
                  "its window"),
    "theta_sac": ("sac", "SAC observing the self-tuning controller's online estimate besides "
                  "its window"),
    "residual_ppo": ("ppo", "PPO correcting the self-tuning controller's input by at most a "
                     "quarter of the action bound, starting at zero"),
    "oracle_ppo": ("ppo", "PPO observing the true plant parameters (a, b), told every jump: "
                   "privileged, the universal policy with identification given"),
}  # fmt: skip

#: Agents trained on the SISO plant family only (never on one plant or a MIMO plant).
FAMILY_ALGORITHMS: tuple[str, ...] = (*RECURRENT_ALGORITHMS, *INFORMED)


def base_algorithm(agent: str) -> str:
    """The algorithm whose rules and tuning space ``agent`` follows (``ppo_noint``,
    ``theta_ppo`` and ``residual_ppo``: ``ppo``; ``theta_sac``: ``sac``)."""
    for table in (ABLATIONS, INFORMED):
        if agent in table:
            return table[agent][0]
    return agent


def agent_knowledge(agent: str, config: dict[str, Any]) -> dict[str, str]:
    """What an RL agent of ``config`` (an :class:`AlgoConfig` as a dict) is given, for the
    report's knowledge table: ``{"order", "integral", "model", "data"}``.

    Examples
    --------
    >>> from stcgym.agents.rl.configs import agent_knowledge, default_config
    >>> agent_knowledge("theta_ppo", default_config("theta_ppo").to_dict())["order"]
    "the training distribution's n (its estimator's), a window of 10 past y, r, u, e"
    """
    window = config.get("window", {})
    interface = config.get("interface", {})
    kind = interface.get("kind", "window")
    w = window.get("window", 10)
    memory = "an LSTM over the episode, " if agent in RECURRENT_ALGORITHMS else ""
    seen = f"a window of {w} past y, r, u, e"
    integral = (
        "the integral of e = r - y as an input" if window.get("include_integral", True) else "none"
    )
    data = "its training distribution's episodes (up to its cap)"
    if config.get("reward", "lqg_ratio") == "lqg_ratio":
        # asymmetric actor-critic: privileged information in the reward, never in the input
        data += "; in training, each plant's LQG cost (the reward's unit: privileged)"
    if kind == "estimate":
        name = InterfaceSpec(**interface).estimator  # (a record without one: the default)
        if name == "ELS":
            name = "the self-tuning controller's extended least squares (ELS)"
        return {
            "order": f"the training distribution's n (its estimator's), {seen}",
            "integral": integral,
            "model": f"none: the online estimate of {name} on the same data (theta_hat, "
            "log10 diag P, innovation) as an input",
            "data": data,
        }
    if kind == "true":
        return {
            "order": f"the training distribution's n (the parameters' length), {seen}",
            "integral": integral,
            "model": "true (a, b) of the plant as an input, told the jump (privileged)",
            "data": data,
        }
    if kind == "residual":
        fraction = float(interface.get("fraction", 0.25))
        return {
            "order": f"the training distribution's n (the controller's), {seen}",
            "integral": "the controller's, with anti-windup; " + integral,
            "model": "none: the self-tuning controller inside (identified online), its input "
            f"corrected by at most {fraction:g} x the action bound",
            "data": data + "; the episode so far (the controller)",
        }
    return {"order": f"none ({memory}{seen})", "integral": integral, "model": "none",
            "data": data}  # fmt: skip


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
        Running reward scaling (SB3's ``VecNormalize``, the Zoo's ``normalize``).
    normalize_obs : bool, default True
        Observation normalisation (``VecNormalize``; its statistics travel with the model).
    reward : str, default "lqg_ratio"
        The training reward (:mod:`stcgym.agents.rl.reward`): ``"lqg_ratio"``, the scored
        per-step cost in units of the episode's plant's LQG cost, capped at ``cost_cap``
        (SISO plants; multivariable plants train on the raw cost); ``"cost"``, the raw
        per-step cost (an ablation).
    cost_cap : float or None, default 100.0
        The largest per-step cost of ``"lqg_ratio"`` in LQG units, also the charge per step of
        a diverged episode's remainder (``None``: no cap).
    reward_scale : float, default 1.0
        Fixed factor on the training reward (:class:`~stcgym.agents.TrainingReward`).
    cost_squash : float or None, default None
        Cost compression of :class:`~stcgym.agents.TrainingReward` (an ablation; ``None``
        trains on the scored cost).
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
    interface : dict
        Fields of :class:`~stcgym.agents.rl.interfaces.InterfaceSpec` (empty: the window
        alone; ``{"kind": "estimate"}``, ``{"kind": "residual", "fraction": 0.25}``).

    Examples
    --------
    >>> from stcgym.agents import AlgoConfig, default_config
    >>> cfg = default_config("ppo")
    >>> cfg.algo, cfg.n_envs, cfg.hyperparams["gamma"]
    ('ppo', 16, 0.9)
    >>> AlgoConfig.from_dict(cfg.to_dict()) == cfg
    True
    """

    algo: str
    hyperparams: dict[str, Any]
    n_envs: int = 1
    normalize_reward: bool = False
    normalize_obs: bool = True
    reward: str = "lqg_ratio"
    cost_cap: float | None = 100.0
    reward_scale: float = 1.0
    cost_squash: float | None = None
    noise_std: float = 0.0
    quick_steps: int = 10_000
    standard_steps: int = 100_000
    standard_family_steps: int = 100_000
    full_steps: int = 100_000
    eval_interval: int = 10_000
    policy: str = "MlpPolicy"
    window: dict[str, Any] = field(default_factory=dict)
    interface: dict[str, Any] = field(default_factory=dict)

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
#: The PPO agents' networks (policy and value function): 256 x 256, four times the Zoo's
#: width. Measured on ladder-l1-v1 with the update below, 10^6 steps, validation median cost /
#: LQG (``benchmarks/rl_ablation.py --recipe healthy_wide``): PPO told the true parameters
#: 1.77x and 1.86x (2 seeds) against 2.96-3.27x with 64 x 64 (3 seeds; 2.77x and 3.14x after
#: 3 x 10^6 steps), the window PPO 2.42x and 2.62x against 2.97-3.06x; about the same wall
#: time per step on a CPU core (the plant and the rollout dominate).
_PPO_NET = {"net_arch": [256, 256]}

# The off-policy learners share the Zoo's Pendulum-v1 recipe (sac.yml, td3.yml: lr 1e-3, SB3's
# defaults otherwise: buffer 1e6, batch 256, tau 0.005, one gradient step per env step).
_OFF_POLICY: dict[str, Any] = {
    "learning_rate": 1e-3,
    "buffer_size": 1_000_000,
    "batch_size": 256,
    "gamma": 0.99,
    "learning_starts": 1_000,
    "train_freq": 1,
    "gradient_steps": 1,
}
_OFF_POLICY_BUDGETS: dict[str, int] = {
    "quick_steps": 6_000,
    "standard_steps": 50_000,
    "standard_family_steps": 200_000,
    "full_steps": 200_000,
    "eval_interval": 2_000,
}

#: The initial log standard deviation of PPO's and RecurrentPPO's gSDE exploration weights. The
#: action bound is 1.5x the largest input LQG needs, and most useful inputs are a small fraction
#: of it: with SB3's default (0) the noise of the 64 latent features (about 8x the weights'
#: standard deviation) saturates the action, so the first updates learn from bang-bang inputs
#: (on ``stable2``, action bound 2.9: PPO's validation cost went from 0.34 to 63 per step after
#: its first update; with -5 it falls to 0.021 within 8e4 steps, LQG's is about 0.015).
_LOG_STD_INIT = -5.0

#: The action unit of the Gaussian-policy agents (PPO, A2C, RecurrentPPO and the agents built
#: on PPO): measured by the bench from the LQG controller's inputs on the training
#: episodes (:mod:`stcgym.agents.rl.interfaces`, "The action unit"; SAC's and TD3's squashed
#: actions span their box whatever its width, so they keep the box ``[-1, 1]``).
_GAUSSIAN = {"action_unit": "lqg"}

#: PPO's and RecurrentPPO's update, chosen by the ablation of the RL-baselines page
#: (``benchmarks/rl_ablation.py``): 16 lanes, so that one update sees 16 plants (the Zoo's
#: 4 x 1024 sees about 4), of 256 steps, minibatches of 256, lr 3e-4 and ``target_kl`` 0.03
#: (SB3 ends an update's epochs once the KL estimate passes 1.5 x 0.03). With the Zoo's
#: settings every update had approx_kl about 0.12 and clip_fraction about 0.43; with these,
#: medians of 0.025 and 0.19. ``gamma`` 0.9 (the Zoo's): of 0.9 / 0.95 / 0.99 (3 seeds each on
#: ladder-l1-v1 and ladder-l4-v1, 1e5 steps) the discount that learned fastest on L1, and
#: within the seeds' spread of the best on L4.
_HEALTHY_ENVS = 16
_HEALTHY_PPO: dict[str, Any] = {
    "learning_rate": 3e-4,
    "n_steps": 256,
    "batch_size": 256,
    "target_kl": 0.03,
    "gamma": 0.9,
}
#: The rest of PPO's and RecurrentPPO's recipe, the Zoo's in ``ppo.yml`` and ``ppo_lstm.yml``
#: alike: 10 epochs, gae 0.95, clip 0.2, no entropy bonus, gSDE resampled every 4 steps.
_PPO: dict[str, Any] = {
    **_HEALTHY_PPO,
    "n_epochs": 10,
    "gae_lambda": 0.95,
    "clip_range": 0.2,
    "ent_coef": 0.0,
    "use_sde": True,
    "sde_sample_freq": 4,
}

DEFAULT_CONFIGS: dict[str, AlgoConfig] = {
    # Zoo ppo.yml Pendulum-v1: n_envs 4, n_steps 1024, gae 0.95, gamma 0.9, 10 epochs, lr 1e-3,
    # clip 0.2, no entropy bonus, gSDE resampled every 4 steps. The update (16 lanes x 256
    # steps, batches of 256, lr 3e-4, target_kl) is the measured departure of _HEALTHY_PPO
    # (ZOO_DEPARTURES); gamma 0.9, the Zoo's, was measured too.
    "ppo": AlgoConfig(
        "ppo",
        {**_PPO, "policy_kwargs": {**_PPO_NET, "log_std_init": _LOG_STD_INIT}},
        n_envs=_HEALTHY_ENVS,
        normalize_reward=True,
        quick_steps=40_960,
        standard_steps=200_000,
        standard_family_steps=1_000_000,
        full_steps=2_000_000,
        eval_interval=20_480,  # 5 rollouts of 16 x 256
        interface=dict(_GAUSSIAN),
    ),
    # SAC steps 8 lanes of the native vector env and makes 2 gradient steps per vector step, a
    # quarter of the Zoo's gradient steps per env step: 4x its env steps per second on a CPU
    # core (see ZOO_DEPARTURES and benchmarks/rl_ablation.py for what it costs in quality)
    "sac": AlgoConfig(
        "sac",
        {**_OFF_POLICY, "gradient_steps": 2, "policy_kwargs": dict(_NET)},
        n_envs=8,
        normalize_reward=True,
        **_OFF_POLICY_BUDGETS,
    ),
    # Zoo td3.yml Pendulum-v1: normal action noise 0.1, lr 1e-3, batch 256, train_freq 1.
    "td3": AlgoConfig(
        "td3",
        {**_OFF_POLICY, "policy_kwargs": dict(_NET)},
        normalize_reward=True,
        noise_std=0.1,
        **_OFF_POLICY_BUDGETS,
    ),
    # Zoo a2c.yml Pendulum: normalize, n_envs 8, n_steps 8, gamma 0.99, gae 0.9, RMSprop, gSDE,
    # log_std_init -2, no orthogonal init, normalised advantages off, lr 7e-4 (linear decay).
    "a2c": AlgoConfig(
        "a2c",
        {
            "learning_rate": 7e-4,
            "n_steps": 8,
            "gamma": 0.99,
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
        standard_steps=400_000,
        standard_family_steps=1_000_000,
        full_steps=2_000_000,
        eval_interval=20_480,  # 320 rollouts of 8 x 8
        interface=dict(_GAUSSIAN),
    ),
    # sb3-contrib RecurrentPPO after the Zoo's ppo_lstm.yml PendulumNoVel-v1 (n_envs 4, n_steps
    # 1024, gae 0.95, gamma 0.9, 10 epochs, lr 1e-3, clip 0.2, gSDE every 4 steps; an LSTM of
    # the policy's default size) with its continuous-control entries' `normalize: true`. It
    # observes one sample (y, r, u, e and the integral) per step, so that the memory, not a
    # window, has to identify the plant; it is trained on the plant family with parameter
    # jumps at random times, the adaptation it is evaluated on.
    "rppo": AlgoConfig(
        "rppo",
        {
            **_PPO,
            "policy_kwargs": {
                "lstm_hidden_size": 128,
                "net_arch": dict(pi=[64], vf=[64]),
                "log_std_init": _LOG_STD_INIT,
            },
        },
        n_envs=_HEALTHY_ENVS,
        normalize_reward=True,
        quick_steps=20_480,
        standard_steps=1_000_000,
        standard_family_steps=1_000_000,
        full_steps=1_000_000,
        eval_interval=20_480,  # 5 rollouts of 16 x 256
        policy="MlpLstmPolicy",
        window={"window": 1},
        interface=dict(_GAUSSIAN),
    ),
}


def _derived(
    agent: str, *, window: dict[str, Any] | None = None, interface: dict[str, Any] | None = None
) -> AlgoConfig:
    """The config of an ablation or an informed agent: that of the agent it varies or extends
    (:func:`base_algorithm`: same recipe, same budgets) under its own name, with the fields of
    ``window`` and ``interface`` changed."""
    base = copy.deepcopy(DEFAULT_CONFIGS[base_algorithm(agent)])
    base.algo = agent
    base.window = {**base.window, **(window or {})}
    base.interface = {**base.interface, **(interface or {})}
    return base


DEFAULT_CONFIGS["ppo_noint"] = _derived("ppo_noint", window={"include_integral": False})
# The controller's own extended least squares: from about step 50 on the closer estimate on
# the family's test episodes whatever inputs the agent applies (benchmarks/estimate_choice.py;
# at the last step the median relative error is 0.042 against O-RLS's 0.074 under the
# controller's inputs, 0.25 against 0.42 under a trained theta_ppo's), at the same cost per
# step in training. A config without an estimator (a record of an earlier run) means O-RLS.
_ESTIMATE = {"kind": "estimate", "estimator": "ELS"}
DEFAULT_CONFIGS["theta_ppo"] = _derived("theta_ppo", interface=dict(_ESTIMATE))
DEFAULT_CONFIGS["theta_sac"] = _derived("theta_sac", interface=dict(_ESTIMATE))
DEFAULT_CONFIGS["residual_ppo"] = _derived(
    "residual_ppo", interface={"kind": "residual", "fraction": 0.25}
)
DEFAULT_CONFIGS["oracle_ppo"] = _derived("oracle_ppo", interface={"kind": "true"})
#: The agents told the true plant parameters (the ``"true"`` interface): they run only on
#: plants of their training distribution's order.
TRUE_PARAMETER_ALGORITHMS: tuple[str, ...] = tuple(
    a for a, c in DEFAULT_CONFIGS.items() if c.interface.get("kind") == "true"
)
# Exploration around the controller's input (the Zoo's log_std_init -2 of A2C Pendulum and its
# MuJoCo entries): with SB3's default the noise is itself a large input disturbance of the
# loop (on the family the validation cost went from 1.8x LQG to 150x within 4096 steps).
DEFAULT_CONFIGS["residual_ppo"].hyperparams["policy_kwargs"]["log_std_init"] = -2.0


def with_action_unit(config: AlgoConfig, unit: float) -> AlgoConfig:
    """``config`` with the action unit ``unit`` where it asks for the measured one (its
    interface's ``action_unit`` is ``"lqg"``); otherwise ``config`` unchanged. A copy either
    way.

    Examples
    --------
    >>> from stcgym.agents.rl.configs import default_config, with_action_unit
    >>> with_action_unit(default_config("ppo"), 5.4).interface
    {'action_unit': 5.4}
    >>> with_action_unit(default_config("sac"), 5.4).interface
    {}
    """
    from stcgym.agents.rl.interfaces import MEASURED_UNIT

    out = copy.deepcopy(config)
    if out.interface.get("action_unit") == MEASURED_UNIT:
        out.interface["action_unit"] = float(unit)
    return out


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
    0.99
    >>> default_config("dqn")
    Traceback (most recent call last):
    ...
    ValueError: RL algorithm must be one of ['a2c', 'oracle_ppo', ...], got 'dqn'
    """
    key = algo.lower()
    if key not in DEFAULT_CONFIGS:
        raise ValueError(f"RL algorithm must be one of {sorted(DEFAULT_CONFIGS)}, got {algo!r}")
    return copy.deepcopy(DEFAULT_CONFIGS[key])
