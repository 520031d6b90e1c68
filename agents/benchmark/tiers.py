"""The tiers of ``stcgym bench``: the scenario kinds and each tier's preset
(``--smoke``, the quick default, ``--standard``, ``--full``), which
:func:`~stcgym.agents.benchmark.config.build_config` completes into a
:class:`~stcgym.agents.benchmark.config.BenchConfig`."""

from __future__ import annotations

from stcgym.envs.mimo_plants import mimo_plant_names

__all__ = ["FAMILY_KINDS", "FULL", "MODES", "QUICK", "SCENARIO_KINDS", "SMOKE", "STANDARD"]

SCENARIO_KINDS = (
    "nominal", "family", "ood", "jump", "ladder", "mimo", "mimo_switch", "mimo_family",
)  # fmt: skip
#: The scenario kinds on the plant family's splits and variants (``cfg.family``)
FAMILY_KINDS = ("family", "ood", "jump")

_CLASSICAL = ["stc", "stc_lq", "stc_kfmils", "stc_mimo", "oracle", "lqg", "zero"]
#: RL agents that know what the estimator knows (stcgym.agents.rl.interfaces)
_INFORMED = ["theta_ppo", "theta_sac", "residual_ppo"]
QUICK = dict(
    mode="quick",
    scenarios=[k for k in SCENARIO_KINDS if k not in ("ladder", "mimo_switch", "mimo_family")],
    plants=["stable2"],
    ood=["ood_near_zero", "ood_order3"],
    # RecurrentPPO is the slowest to train (about a quarter of the tier's CPU time) and at
    # smoke-test budgets learns no more than the others: the standard tier trains it
    agents=["ppo", "sac", "theta_ppo", *_CLASSICAL],
    train_seeds=3,
    test_plants=40,
    nominal_episodes=20,
    curve_episodes=10,
    curve_points=5,
)
#: Five training runs, the whole test split, every held-out variant and rung of the ladder, RL
#: caps of 1e6 steps on the family for PPO and RecurrentPPO (about 2 hours on 2 cores at the
#: caps: ``stcgym bench --standard --plan``).
STANDARD = dict(
    QUICK,
    mode="standard",
    scenarios=list(SCENARIO_KINDS),
    mimo_plants=["quadruple_tank", "quadruple_tank_nmp"],
    # with the two references that locate RL's failure: PPO told the true parameters, and
    # the best fixed PI law of the training split
    agents=[
        "ppo",
        "sac",
        "rppo",
        "theta_ppo",
        "residual_ppo",
        "oracle_ppo",
        "fixed_pi",
        "stc_tuned",
        *_CLASSICAL,
    ],  # fmt: skip
    ood=[
        "ood_fast_unstable",
        "ood_near_zero",
        "ood_lightly_damped",
        "ood_high_gain",
        "ood_order3",
    ],
    train_seeds=5,
    test_plants=None,
    nominal_episodes=100,
    curve_episodes=20,
    curve_points=10,
    # the same small Optuna budget for PPO and the self-tuning controller, on the family's
    # validation split
    tune_trials=10,
    tune_agents=["ppo"],
)
FULL = dict(
    STANDARD,
    mode="full",
    # every MIMO plant with an LQ yardstick for its cost (not ac1: mimo.has_yardstick)
    mimo_plants=[p for p in mimo_plant_names() if p != "ac1"],
    plants=["stable2", "unstable2"],
    agents=[
        "ppo",
        "ppo_noint",
        "sac",
        "td3",
        "a2c",
        "rppo",
        *_INFORMED,
        "oracle_ppo",
        "fixed_pi",
        "stc_tuned",
        *_CLASSICAL,
    ],  # fmt: skip
    train_seeds=10,
    episodes_per_plant=2,
    curve_episodes=50,
    tune_trials=20,
    tune_agents=None,
)
#: A one-minute end-to-end run (``stcgym bench --smoke``): every stage once, on a handful of
#: short episodes, PPO for one evaluation interval; its numbers check that things run, nothing
#: more.
SMOKE = dict(
    QUICK,
    mode="smoke",
    scenarios=["nominal", "family"],
    agents=["ppo", "stc", "stc_lq", "lqg", "zero"],
    train_seeds=1,
    test_plants=5,
    nominal_episodes=5,
    curve_episodes=4,
    curve_points=2,
    bound_plants=20,
    episode_steps=200,
)
MODES = {"smoke": SMOKE, "quick": QUICK, "standard": STANDARD, "full": FULL}
