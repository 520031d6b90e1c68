"""The agent told the true parameters (``oracle_ppo``): what it observes in training and in
evaluation is the lane's plant, across autoresets and parameter jumps."""

from __future__ import annotations

import numpy as np
import pytest

from stcgym.agents.evaluation.env_spec import EnvSpec
from stcgym.agents.evaluation.episodes import EpisodeSet, run_episodes
from stcgym.agents.rl.configs import agent_knowledge, default_config
from stcgym.agents.rl.interfaces import InterfaceSpec
from stcgym.agents.rl.policy import SB3Policy
from stcgym.agents.rl.vec_env import SB3VecEnv, VecHistoryWindow
from stcgym.agents.rl.wrappers import WindowConfig

# every episode jumps, between steps 18 and 42 of 60
SPEC = EnvSpec(family="ladder-l4-v1", split="validation", steps=60, jump_probability=1.0,
               action_bound=27.0)  # fmt: skip
WINDOW = WindowConfig(window=2)


def test_training_features_hold_each_lanes_true_parameters():
    lanes = SB3VecEnv(SPEC.make_vec(4, info_keys=()))
    native = lanes.venv
    interface = InterfaceSpec("true", order=2)
    venv = VecHistoryWindow(lanes, WINDOW, SPEC.steps, interface=interface,
                            true_params=lambda: native.params)  # fmt: skip
    venv.seed(3)
    obs = venv.reset()
    np.testing.assert_array_equal(obs[:, -4:], native.params.astype(np.float32))
    rng = np.random.default_rng(0)
    jumps = restarts = 0
    before = native.params.copy()
    for _ in range(150):
        venv.step_async(rng.uniform(-0.02, 0.02, size=(4, 1)))
        obs, _, dones, infos = venv.step_wait()
        np.testing.assert_array_equal(obs[:, -4:], native.params.astype(np.float32))
        for i in np.flatnonzero(dones):  # the last features still hold the old plant's
            last = infos[i]["terminal_observation"][-4:]
            np.testing.assert_array_equal(last, before[i].astype(np.float32))
            restarts += 1
        jumps += int(np.sum(np.any(native.params != before, axis=1) & ~dones))
        before = native.params.copy()
    assert jumps >= 4 and restarts >= 4


def test_evaluation_tells_the_agent_the_plant_and_every_jump():
    """``theta_hat`` recorded by the evaluation loop is what the agent observes: the true
    parameters at every step, the jump's step included."""
    from stable_baselines3 import PPO

    interface = InterfaceSpec("true", order=2, action_unit=3.0)
    train = VecHistoryWindow(SB3VecEnv(SPEC.make_vec(2, info_keys=())), WINDOW, SPEC.steps,
                             interface=interface)  # fmt: skip
    model = PPO("MlpPolicy", train, seed=0, device="cpu", n_steps=64, batch_size=64)
    policy = SB3Policy(model, WINDOW, SPEC.action_bound, interface=interface)
    assert policy.informed
    episodes = EpisodeSet.of(SPEC, 1, 500, max_plants=5)
    batch = run_episodes(
        lambda plants, seeds: policy.with_lanes(len(plants), seeds, plants),
        SPEC, episodes, informed=True, record_theta=True,
    )  # fmt: skip
    assert np.all(batch.jump_step > 0)
    lived = np.isfinite(batch.theta_hat[:, :, 0])
    assert lived[:, :10].all()
    np.testing.assert_array_equal(batch.theta_hat[lived], batch.theta[:, :-1][lived])


def test_the_uninformed_agents_are_told_nothing_and_the_table_says_what_it_is_given():
    window_only = InterfaceSpec()
    from stable_baselines3 import PPO

    env = VecHistoryWindow(SB3VecEnv(SPEC.make_vec(1, info_keys=())), WINDOW, SPEC.steps)
    policy = SB3Policy(PPO("MlpPolicy", env, device="cpu"), WINDOW, 27.0, interface=window_only)
    assert not policy.informed and policy.theta is None
    with pytest.raises(ValueError, match="is told no model"):
        policy.set_model([0.1, 0.2], [1.0, 0.5])
    row = agent_knowledge("oracle_ppo", default_config("oracle_ppo").to_dict())
    assert "true (a, b)" in row["model"] and "privileged" in row["model"]
    assert "LQG cost" in agent_knowledge("ppo", default_config("ppo").to_dict())["data"]
    raw = default_config("ppo")
    raw.reward = "cost"
    assert "LQG" not in agent_knowledge("ppo", raw.to_dict())["data"]
