"""The difficulty ladder: each rung's plants obey its definition (python-control on the drawn
transfer functions), the rungs are nested, and L4 is siso2-v1's distribution."""

from __future__ import annotations

import control
import gymnasium as gym
import numpy as np
import pytest

import stcgym.envs  # noqa: F401  (registers the ids)
from stcgym.envs.families import LADDER, draw_plant, get_family

#: (negative gains, nonminimum-phase zeros, unstable poles) present on each rung
FEATURES = {
    "ladder-l1-v1": (False, False, False),
    "ladder-l2-v1": (True, False, False),
    "ladder-l3-v1": (True, True, False),
    "ladder-l4-v1": (True, True, True),
}


def _roots(plant):
    sys = control.tf(plant.b, np.concatenate(([1.0], plant.a)), dt=1)
    return sys.poles(), sys.zeros(), float(np.real(sys.dcgain()))


@pytest.mark.parametrize("name", LADDER)
def test_each_rung_draws_only_what_it_is_defined_by(name):
    """On every plant of the rung (1300, all splits): the features it lacks never occur, the
    features it has do, at siso2-v1's shares (within 5 standard errors)."""
    family = get_family(name)
    negative, nonminimum, unstable = FEATURES[name]
    counts = np.zeros(3)
    for i in range(family.count):
        poles, zeros, gain = _roots(draw_plant(family, i))
        found = (gain < 0, np.abs(zeros).max() > 1.0, np.abs(poles).max() > 1.0)
        for k, (seen, allowed) in enumerate(
            zip(found, (negative, nonminimum, unstable), strict=True)
        ):
            assert allowed or not seen, (name, i, ("negative", "nmp", "unstable")[k])
        counts += found
    shares = counts / family.count
    expected = np.array(
        [0.5 if negative else 0, 0.25 if nonminimum else 0, 0.25 if unstable else 0]
    )
    se = np.sqrt(np.maximum(expected * (1 - expected), 1e-12) / family.count)
    assert np.all(np.abs(shares - expected) <= 5 * se + 1e-12), (name, shares)


@pytest.mark.parametrize("name", LADDER)
def test_each_rung_has_siso2s_splits_and_no_jump_unless_asked(name):
    family, base = get_family(name), get_family("siso2-v1")
    assert family.splits == base.splits
    assert set(family.variant_names) <= set(base.variant_names)
    assert family.jump_probability == 0.0
    assert family.jump_range() == base.jump_range()
    env = gym.make("stcgym/PlantFamily-v0", family=name, split="test")
    assert env.unwrapped.jump_probability == 0.0
    for variant in family.variant_names:
        poles, zeros, gain = _roots(draw_plant(family.variant(variant), 7))
        assert FEATURES[name][0] or gain > 0


def test_l4_is_siso2_v1():
    """Plant for plant (before and after the jump) and, with the jump switched on, episode for
    episode."""
    l4, base = get_family("ladder-l4-v1"), get_family("siso2-v1")
    for i in range(base.count):
        a, b = draw_plant(l4, i), draw_plant(base, i)
        for field in ("a", "b", "a_after", "b_after"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    envs = [
        gym.make("stcgym/PlantFamily-v0", family="ladder-l4-v1", jump_probability=0.5),
        gym.make("stcgym/PlantFamily-v0", family="siso2-v1"),
    ]
    rng = np.random.default_rng(0)
    for seed in range(4):
        traces = []
        actions = rng.normal(size=200)
        for env in envs:
            obs, info = env.reset(seed=seed)
            ys = [obs]
            for u in actions:
                obs, *_ = env.step(np.array([u]))
                ys.append(obs)
            traces.append(np.array(ys))
        np.testing.assert_array_equal(traces[0], traces[1])


def test_the_rungs_are_nested():
    """A rung's plant i is the next rung's plant i wherever that lies inside the rung (L1's:
    L2's with its gain made positive)."""
    rungs = [get_family(name) for name in LADDER]
    kept = np.zeros(3, int)
    for i in range(0, 1300, 3):
        plants = [draw_plant(f, i) for f in rungs]
        l1, l2 = plants[0], plants[1]
        np.testing.assert_array_equal(l1.b, np.sign(l2.dc_gain) * l2.b)
        np.testing.assert_array_equal(l1.a, l2.a)
        for k in (1, 2):
            lower, upper = plants[k], plants[k + 1]
            inside = (
                (np.abs(upper.zeros).max() < 1.0) if k == 1 else (np.abs(upper.poles).max() < 1)
            )
            if inside:
                kept[k] += 1
                np.testing.assert_array_equal(lower.a, upper.a)
                np.testing.assert_array_equal(lower.b, upper.b)
    assert kept[1] > 300 and kept[2] > 300
