"""Canonical envs with plants of one's own (PlantSpec objects, names looked up among the env's
plants first) and the constructor's random initial state."""

from __future__ import annotations

import functools

import gymnasium as gym
import numpy as np
import pytest

import stcgym.envs  # noqa: F401  (registers the ids)
from stcgym.envs import PlantSpec, RandomJump, get_plant
from stcgym.envs.vector import ObserverCanonicalVectorEnv

OBSERVER = "stcgym/ObserverCanonical-v0"
OBSERVABILITY = "stcgym/ObservabilityCanonical-v0"
#: A plant of one's own that jumps at a random step (a picklable schedule factory).
MINE = PlantSpec(
    "mine",
    (-1.2, 0.4),
    (0.3, -0.2),
    "two real poles, one zero",
    schedule=functools.partial(RandomJump, (-1.0, 0.3, 0.5, 0.1), (5, 15), 1.0),
)
#: Same name as a catalogue plant, other coefficients: the env's own plant wins.
SHADOW = PlantSpec("unstable2", (-0.5, 0.06), (1.0, 0.0), "not the catalogue's")


def test_a_plant_list_mixes_names_and_specs():
    env = gym.make(OBSERVER, plant=["stable2", MINE]).unwrapped
    assert [p.name for p in env.members] == ["stable2", "mine"]
    names = {env.reset(seed=s)[1]["theta"].tolist() == list(MINE.theta) for s in range(40)}
    assert names == {True, False}  # both plants drawn
    _, info = env.reset(seed=0, options={"plant": "mine"})
    assert env.plant is MINE and info["theta"].tolist() == list(MINE.theta)
    for _ in range(15):  # MINE's own schedule: a jump at a step in 5..15
        _, _, _, _, info = env.step(np.zeros(1))
    assert info["theta"].tolist() == [-1.0, 0.3, 0.5, 0.1]
    env = gym.make(OBSERVER, plant=[SHADOW, "stable2"]).unwrapped
    _, info = env.reset(seed=0, options={"plant": "unstable2"})
    assert env.plant is SHADOW and info["theta"].tolist() == [-0.5, 0.06, 1.0, 0.0]
    _, info = env.reset(seed=0, options={"plant": get_plant("unstable2")})  # a spec: itself
    assert info["theta"].tolist() == [-1.7, 0.66, 0.5, 0.3]
    _, info = env.reset(seed=0, options={"plant": "nonminphase2"})  # the catalogue
    assert info["theta"].tolist() == [-1.5, 0.7, -0.5, 1.0]


def test_a_spec_is_the_same_plant_in_both_forms_jump_included():
    """The observability env converts a PlantSpec's b, and its RandomJump target, to Markov
    parameters: the same output until the jump (the jump keeps each form's state, so the
    forms part there), the converted target after it, at the same drawn step."""
    kwargs = dict(plant=MINE, reference="zero")
    envs = [gym.make(env_id, **kwargs).unwrapped for env_id in (OBSERVER, OBSERVABILITY)]
    steps = []
    for env in envs:
        env.reset(seed=3)
        steps.append(int(env.schedule.next_change(np.zeros(1, dtype=np.int64))[0]))
    assert steps[0] == steps[1] and 5 <= steps[0] <= 15
    u = np.random.default_rng(0).uniform(-1, 1, steps[0])
    y = [[env.step(np.array([v]))[4]["y_clean"] for v in u] for env in envs]
    np.testing.assert_allclose(y[0], y[1], rtol=1e-10, atol=1e-12)
    after = PlantSpec("after", (-1.0, 0.3), (0.5, 0.1), "")
    np.testing.assert_array_equal(envs[0].theta, after.theta)
    np.testing.assert_allclose(envs[1].theta, envs[1].theta_of(after), rtol=1e-12)


@pytest.mark.parametrize(
    ("plant", "error", "match"),
    [
        ([MINE, PlantSpec("mine", (0.1, 0.0), (1.0, 0.0), "")], ValueError, "two different"),
        ([PlantSpec("bad", (np.nan, 0.0), (1.0, 0.0), "")], ValueError, "finite"),
        ([PlantSpec("short", (0.1,), (1.0, 0.0), "")], ValueError, "the same length"),
        (["stable2", get_plant("stable4")], ValueError, "one order"),
        ([3], TypeError, "plant name or a PlantSpec"),
        (3, TypeError, "plant must be"),
        ([], ValueError, "non-empty"),
    ],
)
def test_bad_plants_raise(plant, error, match):
    with pytest.raises(error, match=match):
        gym.make(OBSERVER, plant=plant)


@pytest.mark.equality
def test_vector_env_takes_one_plant_per_lane():
    kwargs = dict(plant=["stable2", MINE, SHADOW], noise_std=0.1, reference="prbs")
    venv = ObserverCanonicalVectorEnv(num_envs=3, **kwargs)
    options = {"plant": ["mine", "unstable2", "nonminphase2"]}
    obs, infos = venv.reset(seed=4, options=options)
    assert [p.name for p in venv.plants] == ["mine", "unstable2", "nonminphase2"]
    assert venv.plants[1] is SHADOW and venv.plant_index.tolist() == [1, 2, -1]
    singles = [gym.make(OBSERVER, **kwargs) for _ in range(3)]
    outs = [e.reset(seed=4 + i, options={"plant": p}) for i, (e, p) in
            enumerate(zip(singles, options["plant"], strict=True))]  # fmt: skip
    for _ in range(20):  # MINE jumps within these steps, in the lane as in its single env
        for i, (o, info) in enumerate(outs):
            np.testing.assert_array_equal(obs[i], o)
            np.testing.assert_array_equal(infos["theta"][i], info["theta"])
        obs, _, _, _, infos = venv.step(np.full((3, 1), 0.2))
        outs = [(o, info) for o, _, _, _, info in (e.step(np.array([0.2])) for e in singles)]
    with pytest.raises(ValueError, match="num_envs=3 plants"):
        venv.reset(seed=0, options={"plant": ["stable2", "mine"]})
    with pytest.raises(ValueError, match="order 4"):
        venv.reset(seed=0, options={"plant": ["stable2", "stable4", "mine"]})


@pytest.mark.equality
@pytest.mark.parametrize("env_id", [OBSERVER, "stcgym/StateSpace-v0"])
def test_initial_state_std_argument_draws_as_the_reset_option(env_id):
    """The constructor's initial_state_std gives the x(0) that the reset option gives (same
    stream), in single and vector envs and across autoresets; options take precedence."""
    kwargs = dict(noise_std=0.1)
    if env_id == OBSERVER:
        kwargs["plant"] = ["stable2", "unstable2"]  # the draw stream also picks the plant
    env = gym.make(env_id, initial_state_std=0.7, **kwargs)
    plain = gym.make(env_id, **kwargs)
    for seed in range(5):
        _, info = env.reset(seed=seed)
        _, want = plain.reset(seed=seed, options={"initial_state_std": 0.7})
        np.testing.assert_array_equal(info["x"], want["x"])
        assert np.any(info["x"] != 0)
    n = info["x"].size
    _, info = env.reset(seed=0, options={"initial_state": np.ones(n)})
    np.testing.assert_array_equal(info["x"], np.ones(n))
    _, info = env.reset(seed=0, options={"initial_state_std": 0.0})
    np.testing.assert_array_equal(info["x"], np.zeros(n))
    venv = gym.make_vec(env_id, num_envs=3, initial_state_std=0.7, max_episode_steps=5, **kwargs)
    _, infos = venv.reset(seed=10)
    for _ in range(5):
        venv.step(np.zeros((3, venv.n_inputs)))
    _, _, _, _, infos = venv.step(np.zeros((3, venv.n_inputs)))  # autoreset: second episode
    single = gym.make(env_id, initial_state_std=0.7, **kwargs)
    single.reset(seed=12)
    _, want = single.reset()
    np.testing.assert_array_equal(infos["x"][2], want["x"])
    with pytest.raises(ValueError, match="initial_state_std"):
        gym.make(env_id, initial_state_std=-1.0)
    with pytest.raises(ValueError, match="no process noise or initial state"):
        gym.make("stcgym/MultichannelStatic-v0", initial_state_std=0.5)
