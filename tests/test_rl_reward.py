"""The training objective: each plant's LQG cost per step, and the reward in units of it on the
single env and on the native vector env."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import stcgym.envs  # noqa: F401  (registers the ids)
from stcgym.adaptive import LawOptions, LQGController
from stcgym.adaptive.control.options import cost_weights
from stcgym.agents.evaluation.env_spec import EnvSpec
from stcgym.agents.rl.reward import LQG_COST_EPISODES, LQG_COST_SEED, plant_lqg_costs
from stcgym.agents.rl.vec_env import SB3VecEnv, VecHistoryWindow
from stcgym.agents.rl.wrappers import TrainingReward, WindowConfig, training_reward

SPEC = EnvSpec(family="ladder-l4-v1", split="validation", action_bound=27.0)


def _lqg_episode_cost(spec: EnvSpec, plant: str, seed: int) -> float:
    """LQG on one episode, stepped through the single gymnasium env by hand."""
    env = spec.make(action_bound=1e9)
    obs, info = env.reset(seed=seed, options={"plant": plant})
    p = env.unwrapped.plant
    law = LawOptions(integral=False, lq_weights=cost_weights(spec.control_cost))
    lqg = LQGController(np.array(p.a), np.array(p.b), law=law, noise_std=spec.noise_std,
                        action_bound=1e9)  # fmt: skip
    total, steps, done = 0.0, 0, False
    while not done:
        u, _ = lqg.predict(obs)
        obs, reward, terminated, truncated, _ = env.step(u)
        total, steps, done = total - reward, steps + 1, terminated or truncated
    assert steps == spec.steps
    return total / steps


def test_plant_costs_are_lqg_run_on_each_plant_by_hand():
    costs = plant_lqg_costs(SPEC)
    names = SPEC.plant_names()
    assert costs.shape == (len(names),) and np.all(costs > 0)
    for j in (0, 37, 99):
        seeds = [LQG_COST_SEED + LQG_COST_EPISODES * j + e for e in range(LQG_COST_EPISODES)]
        by_hand = np.mean([_lqg_episode_cost(SPEC, names[j], s) for s in seeds])
        assert costs[j] == pytest.approx(by_hand, rel=1e-9)
    # cached, read-only, and the same whatever the spec's action bound (LQG runs unbounded)
    assert plant_lqg_costs(SPEC) is costs and not costs.flags.writeable
    other = EnvSpec(family="ladder-l4-v1", split="validation", action_bound=5.0)
    np.testing.assert_array_equal(plant_lqg_costs(other), costs)


@settings(max_examples=50, deadline=None)
@given(
    cost=st.floats(0.0, 1e4),
    lqg=st.floats(1e-3, 10.0),
    cap=st.floats(1.0, 1e3),
    steps=st.integers(1, 1000),
    diverged=st.booleans(),
)
def test_the_reward_is_the_capped_ratio_and_a_divergence_costs_the_cap_at_most(
    cost, lqg, cap, steps, diverged
):
    r = float(training_reward(-cost, steps, diverged, 1000, lqg_cost=lqg, cost_cap=cap))
    per_step = min(cost / lqg, cap)
    lived = 1 + (1000 - steps if diverged else 0)
    assert r == pytest.approx(-per_step * lived, rel=1e-12, abs=1e-12)
    assert -r <= cap * 1000 * (1 + 1e-12)


def test_vector_lanes_are_charged_their_own_plants_lqg_cost():
    """Every lane's reward is its env's cost over the LQG cost of the plant it ran that step on
    (across autoresets), as the single env with the same seed gives it."""
    costs = plant_lqg_costs(SPEC)
    spec = EnvSpec(family="ladder-l4-v1", split="validation", action_bound=27.0, steps=60)
    lanes = SB3VecEnv(spec.make_vec(3, info_keys=()))
    native = lanes.venv
    venv = VecHistoryWindow(lanes, WindowConfig(window=2), spec.steps, plant_costs=costs,
                            plant_index=lambda: native.plant_index, cost_cap=100.0)  # fmt: skip
    raw = SB3VecEnv(spec.make_vec(3, info_keys=()))
    venv.seed(5)
    raw.seed(5)
    venv.reset()
    raw.reset()
    names = spec.plant_names()
    singles = []
    for i in range(3):
        env = TrainingReward(spec.make(), horizon=spec.steps, cost_cap=100.0,
                             plant_costs=dict(zip(names, costs, strict=True)))  # fmt: skip
        env.reset(seed=5 + i)
        singles.append(env)
    actions = np.random.default_rng(1).uniform(-0.3, 0.3, size=(130, 3, 1))
    k, charged = np.zeros(3, int), 0
    for a in actions:
        plant = native.plant_index.copy()
        venv.step_async(a)
        _, r, dones, _ = venv.step_wait()
        raw.step_async(a * 27.0)
        _, cost, raw_dones, _ = raw.step_wait()
        k += 1
        left = np.where(dones & (k < spec.steps), spec.steps - k, 0)
        charged += int(np.count_nonzero(left))
        expected = np.maximum(cost / costs[plant], -100.0) * (1 + left)
        np.testing.assert_allclose(r, expected, rtol=1e-6)
        k[dones] = 0
        for i, env in enumerate(singles):
            _, r_i, terminated, truncated, _ = env.step(a[i] * 27.0)
            assert r_i == pytest.approx(float(r[i]), rel=1e-5)
            if terminated or truncated:
                assert dones[i]
                env.reset()
        assert np.array_equal(dones, raw_dones)
    assert charged > 0  # the actions were chosen so that some lane diverges


def test_a_plant_without_an_lqg_cost_is_refused_on_reset():
    env = TrainingReward(gym.make("stcgym/ObserverCanonical-v0", plant="stable2"), horizon=10,
                         plant_costs={"unstable2": 0.1})  # fmt: skip
    with pytest.raises(ValueError, match="no LQG cost of the plant 'stable2'"):
        env.reset(seed=0)
