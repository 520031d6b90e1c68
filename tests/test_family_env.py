"""stcgym/PlantFamily-v0: the plants of one split, the family's defaults, random jumps, the
vector env lane by lane, and bad input."""

from __future__ import annotations

import copy
import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import stcgym.envs  # noqa: F401  (registers the ids)
from stcgym.envs.families import draw_plant, get_family
from stcgym.envs.family_env import PlantFamilyEnv, PlantFamilyVectorEnv
from stcgym.envs.schedules import NEVER

ENV_ID = "stcgym/PlantFamily-v0"

#: A small family with everything random: short episodes, so that tests see many of them.
SMALL = {
    "name": "small",
    "seed": 11,
    "count": 30,
    "steps": 60,
    "noise_std": 0.05,
    "initial_state_std": 0.3,
    "reference": {"kind": "random_steps", "amplitude": 1.0, "hold": [3, 9]},
    "poles": {"unstable_share": 0.3},
    "zeros": {"nonminimum_phase_share": 0.3},
    "negative_gain_share": 0.5,
    "y_bound": 50.0,
    "jump": {
        "at": [0.2, 0.8],
        "probability": 0.6,
        "magnitude_scale": [0.8, 1.1],
        "dc_gain_scale": [0.5, 2.0],
    },
    "splits": {"train": [0, 20], "test": [20, 30]},
    "variants": {"third": {"count": 5, "order": 3}},
}


def _theta(plant, after=False):
    return np.concatenate((plant.a_after, plant.b_after) if after else (plant.a, plant.b))


def test_gymnasium_env_checker_passes():
    for kwargs in ({}, {"family": SMALL, "split": "third"}):
        env = gym.make(ENV_ID, **kwargs)
        check_env(env.unwrapped, skip_render_check=True)


def test_the_env_draws_only_the_plants_of_its_split_uniformly():
    family = get_family(SMALL)
    env = gym.make(ENV_ID, family=SMALL, split="test")
    counts = dict.fromkeys(range(20, 30), 0)
    for seed in range(1000):
        _, info = env.reset(seed=seed)
        name = info["plant"]
        index = int(name.rsplit("/", 1)[1])
        assert name == f"small-v1/test/{index}" and 20 <= index < 30
        assert env.unwrapped.plant.name == name
        np.testing.assert_array_equal(info["theta"], _theta(draw_plant(family, index)))
        counts[index] += 1
    # Uniform over 10 plants: each count ~ Binomial(1000, 0.1), sd 9.5; 5 sd.
    assert all(abs(c - 100) < 48 for c in counts.values()), counts
    # A variant: its own plants (and order).
    env = gym.make(ENV_ID, family=SMALL, split="third")
    _, info = env.reset(seed=0)
    third = get_family(SMALL).variant("third")
    index = int(info["plant"].rsplit("/", 1)[1])
    assert info["plant"].startswith("small-v1/third/") and env.unwrapped.n_states == 3
    np.testing.assert_array_equal(info["theta"], _theta(draw_plant(third, index)))
    assert env.observation_space.shape == (2,) and info["x"].shape == (3,)


def test_defaults_come_from_the_family_and_keywords_override_them():
    env = gym.make(ENV_ID).unwrapped
    family = get_family("siso2-v1")
    assert env.family.key == "siso2-v1" and env.split == "train"
    assert env.indices == range(0, 1000) and len(env.members) == 1000
    assert (env.noise_std, env.control_cost, env.action_bound, env.y_bound) == (
        0.05,
        0.01,
        10.0,
        20.0,
    )
    assert env.initial_state_std == 0.5 and env.steps == 1000
    assert env.jump_range == (300, 700) and env.jump_probability == 0.5
    assert type(env.reference[0]).__name__ == "RandomSteps"
    assert env.reference[0].hold == (25, 75) and env.reference[0].amplitude == 1.0
    assert gym.make(ENV_ID).spec.max_episode_steps is None  # the env truncates itself
    env = gym.make(
        ENV_ID,
        family=family,
        split="validation",
        noise_std=0.0,
        reference="zero",
        control_cost=0.1,
        action_bound=2.0,
        y_bound=5.0,
        initial_state_std=0.0,
        steps=200,
        jump_probability=1.0,
    ).unwrapped
    assert (env.noise_std, env.control_cost, env.action_bound, env.y_bound) == (0, 0.1, 2, 5)
    assert env.initial_state_std == 0.0 and env.steps == 200
    assert env.jump_range == (60, 140) and env.jump_probability == 1.0  # fractions of 200
    obs, info = env.reset(seed=1)
    assert obs[1] == 0.0 and np.all(info["x"] == 0.0)


def test_the_env_truncates_at_its_episode_length():
    env = gym.make(ENV_ID, family=SMALL)
    env.reset(seed=0)
    flags = [env.step(np.zeros(1))[3] for _ in range(60)]
    assert flags == [False] * 59 + [True]
    short = gym.make(ENV_ID, family=SMALL, max_episode_steps=20)
    short.reset(seed=0)
    assert [short.step(np.zeros(1))[3] for _ in range(20)][-2:] == [False, True]


def test_jump_time_and_probability_per_episode():
    """Whether an episode jumps (probability 0.6) and when (uniform on steps 12..48 of 60):
    the frequencies within binomial tolerance, every step of the range drawn; the parameters
    change to the plant's drawn after-jump plant at that step and not before."""
    family = get_family(SMALL)
    env = gym.make(ENV_ID, family=SMALL).unwrapped
    n, steps = 3000, []
    for seed in range(n):
        env.reset(seed=seed)
        steps.append(int(env.schedule.next_change(np.zeros(1, dtype=np.int64))[0]))
    steps = np.array(steps)
    jumped = steps != NEVER
    sd = np.sqrt(0.6 * 0.4 / n)
    assert abs(jumped.mean() - 0.6) < 5 * sd
    at = steps[jumped]
    assert at.min() == 12 and at.max() == 48 and set(at.tolist()) == set(range(12, 49))
    # Uniform on 37 values: each count ~ Binomial(m, 1/37).
    m = at.size
    counts = np.bincount(at - 12, minlength=37)
    assert np.all(np.abs(counts - m / 37) < 5 * np.sqrt(m / 37 * (1 - 1 / 37)))
    # The parameters in force, step by step, for a few episodes.
    for seed in range(6):
        _, info = env.reset(seed=seed)
        plant = draw_plant(family, int(info["plant"].rsplit("/", 1)[1]))
        k_jump = steps[seed]
        for k in range(1, 60):
            _, _, terminated, _, info = env.step(np.zeros(1))
            expected = _theta(plant, after=k >= k_jump)
            np.testing.assert_array_equal(info["theta"], expected)
            if terminated:  # an unstable plant left y_bound
                break
    for p, expected in ((0.0, 0.0), (1.0, 1.0)):
        env = gym.make(ENV_ID, family=SMALL, jump_probability=p).unwrapped
        share = []
        for seed in range(200):
            env.reset(seed=seed)
            share.append(env.schedule.next_change(np.zeros(1, dtype=np.int64))[0] != NEVER)
        assert np.mean(share) == expected


def test_plants_chosen_by_name_or_index_and_bad_options_change_nothing():
    env = gym.make(ENV_ID, family=SMALL, split="test").unwrapped
    _, info = env.reset(seed=0, options={"plant": 25})
    assert info["plant"] == "small-v1/test/25"
    _, info = env.reset(seed=0, options={"plant": "small-v1/test/27"})
    assert info["plant"] == "small-v1/test/27"
    _, info = env.reset(seed=0, options={"plant": "stable2"})  # the catalogue too
    assert info["plant"] == "stable2" and info["theta"].tolist() == [-1.5, 0.7, 1.0, 0.5]
    env.reset(seed=3)
    env.step(np.ones(1))
    before = (env.x.copy(), env.t, env.theta, env.plant)
    for bad, error in (
        (5, ValueError),  # an index of another split
        ("small-v1/train/5", ValueError),
        ("stable4", ValueError),  # another order
        (2.0, TypeError),
    ):
        with pytest.raises(error, match=r"options\['plant'\]|order n=2"):
            env.reset(seed=1, options={"plant": bad})
        after = (env.x, env.t, env.theta, env.plant)
        np.testing.assert_array_equal(after[0], before[0])
        assert after[1] == before[1] and after[3] == before[3]
        np.testing.assert_array_equal(after[2], before[2])


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"split": "validation"}, ValueError, r"split must be one of \['train', 'test', 'third'\]"),
        ({"family": "siso9-v1"}, ValueError, "registered name"),
        ({"jump_probability": 1.5}, ValueError, "jump_probability"),
        ({"plant": "stable2"}, TypeError, "draws its plants from the family"),
        ({"a": [0.5], "b": [1.0]}, TypeError, "draws its plants"),
        ({"steps": 2}, ValueError, r"jump\.at"),
        ({"steps": 1}, ValueError, "steps must be an integer >= 2"),
        ({"noise_std": -1.0}, ValueError, "noise_std"),
        ({"initial_state": [1.0, 0.0]}, ValueError, "initial_state or initial_state_std"),
    ],
)
def test_bad_arguments_are_clear_errors(kwargs, error, match):
    with pytest.raises(error, match=match):
        gym.make(ENV_ID, **{"family": SMALL, **kwargs})


def test_a_jump_probability_needs_a_jump():
    family = {**SMALL, "jump": None}
    with pytest.raises(ValueError, match="has no jump"):
        PlantFamilyEnv(family, "train", jump_probability=0.5)
    assert PlantFamilyEnv(family, "train", jump_probability=0.0).jump_probability == 0.0


def _run_pair(kwargs, *, B=4, T=250, seed=5, mode="NextStep"):
    """The vector env and B single envs (NEXT_STEP autoreset by hand), one action sequence."""
    venv = gym.make_vec(ENV_ID, num_envs=B, autoreset_mode=mode, **kwargs)
    singles = [gym.make(ENV_ID, **kwargs) for _ in range(B)]
    vo, vi = venv.reset(seed=seed)
    outs = [e.reset(seed=seed + i) for i, e in enumerate(singles)]
    yield vo, vi, outs, None
    rng = np.random.default_rng(seed)
    ended = np.zeros(B, dtype=bool)
    for _ in range(T):
        a = rng.uniform(-2, 2, size=(B, 1))
        vout = venv.step(a)
        outs = []
        for i, e in enumerate(singles):
            out = (*e.reset(), 0.0, False, False) if ended[i] else e.step(a[i])
            if not ended[i]:
                out = (out[0], out[4], out[1], out[2], out[3])
            outs.append(out)
            ended[i] = out[3] or out[4]
        yield vout[0], vout[4], outs, vout


@pytest.mark.equality
@pytest.mark.parametrize(
    "kwargs",
    [
        {"family": SMALL},
        {"family": SMALL, "split": "third", "jump_probability": 1.0},
        {"family": "siso2-v1", "split": "test", "steps": 80},
    ],
)
def test_lane_i_is_the_single_env_reset_with_seed_s_plus_i(kwargs):
    """Observations, rewards, flags and infos bit for bit, across autoresets and jumps: the
    same compiled plant step, the same per-episode streams (plant draw, initial state,
    reference, jump) in both."""
    for vo, vi, outs, vout in _run_pair(kwargs):
        for i, out in enumerate(outs):
            np.testing.assert_array_equal(vo[i], out[0])
            for key, value in out[1].items():
                assert vi["_" + key][i]
                if key == "plant":
                    assert vi[key][i] == value
                else:
                    np.testing.assert_array_equal(vi[key][i], value)
            if vout is not None:
                assert vout[1][i] == out[2]
                assert (vout[2][i], vout[3][i]) == (out[3], out[4])
    # The jumps were exercised: some lane's parameters left its plant's nominal ones.
    venv = gym.make_vec(ENV_ID, num_envs=8, **kwargs)
    venv.reset(seed=0)
    changed = False
    for _ in range(80):
        nominal = np.array([venv.unwrapped._members_theta[j] for j in venv.unwrapped.plant_index])
        _, _, _, _, infos = venv.step(np.zeros((8, 1)))
        changed |= bool(np.any(infos["theta"] != nominal))
    assert changed


def test_vector_env_options_per_lane_and_truncation():
    venv = gym.make_vec(ENV_ID, num_envs=3, family=SMALL, split="test")
    assert isinstance(venv, PlantFamilyVectorEnv) and venv.max_episode_steps == 60
    assert venv.family.key == "small-v1" and venv.split == "test"
    _, infos = venv.reset(seed=0, options={"plant": [21, "small-v1/test/22", "stable2"]})
    assert infos["plant"].tolist() == ["small-v1/test/21", "small-v1/test/22", "stable2"]
    assert venv.plant_index.tolist() == [1, 2, -1]
    single = gym.make(ENV_ID, family=SMALL, split="test")
    _, info = single.reset(seed=1, options={"plant": 22})
    obs, _ = venv.reset(seed=0, options={"plant": [21, 22, 23]})
    np.testing.assert_array_equal(obs[1], single.reset(seed=1, options={"plant": 22})[0])
    venv.step(np.ones((3, 1)))
    before = (venv.x.copy(), venv.t.copy(), venv.theta, list(venv.plants))
    for bad in ([21, 22], [21, 22, 5], "nope"):
        with pytest.raises(ValueError, match=r"options\['plant'\]"):
            venv.reset(seed=0, options={"plant": bad})
        np.testing.assert_array_equal(venv.x, before[0])
        np.testing.assert_array_equal(venv.t, before[1])
        np.testing.assert_array_equal(venv.theta, before[2])
        assert venv.plants == before[3]
    assert (
        gym.make_vec(ENV_ID, num_envs=2, family=SMALL, max_episode_steps=20).max_episode_steps == 20
    )
    assert (
        gym.make_vec(ENV_ID, num_envs=2, family=SMALL, max_episode_steps=90).max_episode_steps == 60
    )
    venv = gym.make_vec(ENV_ID, num_envs=3, family=SMALL, initial_state_std=0.0)
    venv.reset(seed=0)  # x stays 0 with u = 0: no lane ends before the time limit
    truncated = [venv.step(np.zeros((3, 1)))[3].all() for _ in range(60)]
    assert truncated == [False] * 59 + [True]


@pytest.mark.equality
@pytest.mark.parametrize("vector", [False, True])
@pytest.mark.parametrize("clone", [pickle.dumps, copy.deepcopy])
def test_envs_pickle_and_continue_identically(vector, clone):
    if vector:
        env, a = gym.make_vec(ENV_ID, num_envs=3, family=SMALL), np.full((3, 1), 0.5)
    else:
        env, a = gym.make(ENV_ID, family=SMALL).unwrapped, np.array([0.5])
    env.reset(seed=2)
    for _ in range(10):
        env.step(a)
    twin = clone(env)
    twin = pickle.loads(twin) if clone is pickle.dumps else twin
    for _ in range(130):  # across jumps and autoresets
        out, out_twin = env.step(a), twin.step(a)
        for value, value_twin in zip(out[:4], out_twin[:4], strict=True):
            np.testing.assert_array_equal(value, value_twin)
        if not vector and (out[2] or out[3]):
            np.testing.assert_array_equal(env.reset()[0], twin.reset()[0])


@pytest.mark.equality
def test_native_vector_env_equals_gymnasiums_sync_vector_env():
    """gym.make_vec's two routes give the same episodes: the native env and SyncVectorEnv of
    single envs (whose truncation is the env's own, there being no TimeLimit)."""
    kwargs = dict(family=SMALL, split="train")
    sync = gym.make_vec(ENV_ID, num_envs=3, vectorization_mode="sync", **kwargs)
    native = gym.make_vec(ENV_ID, num_envs=3, **kwargs)
    np.testing.assert_array_equal(sync.reset(seed=4)[0], native.reset(seed=4)[0])
    actions = np.random.default_rng(1).uniform(-1, 1, (150, 3, 1))
    for a in actions:
        for x, y in zip(sync.step(a)[:4], native.step(a)[:4], strict=True):
            np.testing.assert_array_equal(x, y)
