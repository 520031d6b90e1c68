"""Where each default RL config of :mod:`stcgym.agents.rl.configs` departs from the RL Zoo
entry it follows, with the reason and, where one was made, the measurement: what a bench
report lists beside its training table, and what a run records in its ``config.json``.
"""

from __future__ import annotations

__all__ = ["ZOO_DEPARTURES"]

#: Where a default config departs from the Zoo entry it follows: ``agent -> [(setting, Zoo
#: value, ours, reason)]`` (the report prints it).
ZOO_DEPARTURES: dict[str, list[tuple[str, str, str, str]]] = {
    "ppo": [
        ("n_envs x n_steps", "4 x 1024", "16 x 256", "one update sees 16 plants, not about 4"),
        ("batch_size, learning_rate, target_kl", "64, 1e-3, none", "256, 3e-4, 0.03",
         "healthy updates: on ladder-l1-v1 (3 seeds, 1e5 steps) the Zoo's update had median "
         "approx_kl 0.088 and clip_fraction 0.38 and stayed near the untrained policy "
         "(median 15.1x LQG, untrained 16.6-17.9x); ours 0.027 and 0.19, and 6.5x"),
        ("reward", "the environment's", "cost / the plant's LQG cost, capped at 100 per step",
         "the score per step: on ladder-l4-v1 (3 seeds, 1e5 steps) median 14.3x LQG against "
         "20.7x on the raw cost (zero input 19.4x); on ladder-l1-v1, where nothing diverges, "
         "6.5x and 6.9x"),
        ("log_std_init", "0 (SB3's default)", "-5", "exploration in the range of useful inputs, "
         "a small fraction of the action bound: with the default the gSDE noise saturates "
         "the action and the first updates make the policy far worse than the untrained one"),
        ("action scale", "the box [-1, 1] is the action bound", "one action unit is the "
         "input LQG stays within on 99 % of the training steps; the box widened to keep the "
         "bound",
         "the bound is set by LQG's rare largest transients: in units of it the useful inputs "
         "are about 1 %, and each optimiser step of the mean action a large input (the policy "
         "got worse as it trained)"),
        ("net_arch", "[64, 64]", "[256, 256]", "capacity: on ladder-l1-v1 (10^6 steps) PPO "
         "told the true parameters 1.77x and 1.86x LQG (2 seeds) against 2.96-3.27x (3 "
         "seeds; 2.77x and 3.14x after 3 x 10^6 steps), the window PPO 2.42x and 2.62x "
         "against 2.97-3.06x"),
        ("normalize", "off", "observations and rewards", "signals of mixed scales; costs "
         "spanning orders of magnitude across plants"),
        ("n_timesteps", "1e5", "cap 1e6 on the family (2e5 on one plant), plateau rule",
         "a plant family is a harder task than one pendulum"),
    ],
    "sac": [
        ("reward", "the environment's", "cost / the plant's LQG cost, capped", "as for PPO"),
        ("net_arch", "[256, 256]", "[64, 64]", "one gradient step per env step on a CPU core: "
         "4x fewer multiply-adds fit the tier's time"),
        ("learning_starts", "100", "1000", "one episode of random actions before learning"),
        ("n_envs, gradient_steps", "1, 1 (one gradient step per env step)",
         "8, 2 (a quarter of the gradient steps per env step)",
         "about 4x the env steps per second on one CPU core; what it costs at 10^5 steps: "
         "benchmarks/rl_ablation_summary.json"),
        ("normalize", "off", "observations and rewards", "as for PPO"),
        ("n_timesteps", "2e4", "cap 2e5 on the family (5e4 on one plant), plateau rule",
         "what fits the tier's time"),
    ],
    "td3": [
        ("reward", "the environment's", "cost / the plant's LQG cost, capped", "as for PPO"),
        ("net_arch", "[400, 300]", "[64, 64]", "as for SAC"),
        ("normalize", "off", "observations and rewards", "as for PPO"),
    ],
    "a2c": [
        ("reward", "the environment's", "cost / the plant's LQG cost, capped", "as for PPO"),
        ("learning_rate", "lin_7e-4", "7e-4", "a constant rate, as every other agent's"),
        ("action scale", "the box [-1, 1] is the action bound", "as for PPO", "as for PPO"),
        ("n_timesteps", "1e6", "cap 1e6 on the family (4e5 on one plant), plateau rule",
         "what fits the tier's time"),
    ],
    "rppo": [
        ("n_envs x n_steps", "4 x 1024", "16 x 256", "as for PPO"),
        ("batch_size, learning_rate, target_kl", "128 (default), 1e-3, none", "256, 3e-4, 0.03",
         "as for PPO (chosen on PPO; one RecurrentPPO run on ladder-l1-v1, 1e5 steps: "
         "median approx_kl 0.024, clip_fraction 0.20)"),
        ("reward", "the environment's", "cost / the plant's LQG cost, capped", "as for PPO"),
        ("lstm_hidden_size", "256 (default)", "128 (the Zoo's PyBullet entries)",
         "the LSTM dominates the CPU time of a step; 1e6 steps must fit the tier"),
        ("net_arch", "default", "pi [64], vf [64] after the LSTM", "small heads, as PPO's"),
        ("n_timesteps", "1e5", "cap 1e6 on the family, plateau rule",
         "identifying a plant from a family is harder than a pendulum's velocity"),
        ("normalize", "off (PendulumNoVel-v1; on in its other continuous entries)",
         "observations and rewards", "as for PPO"),
        ("log_std_init", "0 (SB3's default)", "-5", "as for PPO"),
        ("action scale", "the box [-1, 1] is the action bound", "as for PPO", "as for PPO"),
    ],
}  # fmt: skip
ZOO_DEPARTURES["ppo_noint"] = ZOO_DEPARTURES["ppo"]
ZOO_DEPARTURES["theta_ppo"] = ZOO_DEPARTURES["ppo"]
ZOO_DEPARTURES["theta_sac"] = ZOO_DEPARTURES["sac"]
ZOO_DEPARTURES["oracle_ppo"] = ZOO_DEPARTURES["ppo"]
ZOO_DEPARTURES["residual_ppo"] = [
    *(entry for entry in ZOO_DEPARTURES["ppo"] if entry[0] != "log_std_init"),
    ("action_net init", "orthogonal, gain 0.01", "zeros",
     "the mean residual starts at exactly 0: the agent starts as the self-tuning controller"),
    ("log_std_init", "0 (SB3's default)", "-2", "exploration around the controller's input: "
     "with the default the noise is a large input disturbance of the loop (on the family "
     "1.8x LQG before training, 150x after 4096 steps)"),
]  # fmt: skip
