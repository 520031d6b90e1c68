"""The random reference and the random jump: their distributions and their bad input."""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest

from stcgym.envs import RandomJump, RandomSteps, make_reference
from stcgym.envs.schedules import NEVER


def _segments(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Levels and hold lengths of a piecewise-constant trace (the last segment may be cut)."""
    starts = np.concatenate(([0], np.flatnonzero(np.diff(r)) + 1))
    holds = np.diff(np.concatenate((starts, [r.size])))
    return r[starts], holds


def test_random_steps_levels_and_holds_are_uniform_in_their_ranges():
    ref = make_reference({"kind": "random_steps", "amplitude": 2.0, "hold": [5, 15], "offset": 1})
    assert isinstance(ref, RandomSteps) and ref.hold == (5, 15)
    levels, holds = [], []
    for seed in range(40):
        ref.reset(np.random.default_rng(seed))
        lv, hd = _segments(ref.values(np.arange(2000)))
        levels.append(lv)
        holds.append(hd[:-1])  # the last hold is cut by the end of the trace
    levels, holds = np.concatenate(levels), np.concatenate(holds)
    n = levels.size  # about 40 * 200 = 8000 levels
    assert np.all((levels >= -1.0) & (levels <= 3.0))
    # Uniform on [-1, 3]: mean 1, sd 4 / sqrt(12); 5 standard errors; both ends reached.
    assert abs(levels.mean() - 1.0) < 5 * (4 / np.sqrt(12)) / np.sqrt(n)
    assert levels.min() < -0.99 and levels.max() > 2.99
    # Holds: integers uniform on 5..15 (11 values), every one drawn.
    assert holds.min() == 5 and holds.max() == 15 and set(holds.tolist()) == set(range(5, 16))
    counts = np.bincount(holds - 5, minlength=11)
    m = holds.size
    assert np.all(np.abs(counts - m / 11) < 5 * np.sqrt(m / 11 * (1 - 1 / 11)))


def test_random_steps_is_a_function_of_its_generator_and_of_k_only():
    """Asked step by step, in one call, backwards or far ahead: the same signal."""
    a, b = RandomSteps(hold=(1, 3)), RandomSteps(hold=(1, 3))
    a.reset(np.random.default_rng(4))
    b.reset(np.random.default_rng(4))
    stepwise = np.array([a(k) for k in range(500)])
    np.testing.assert_array_equal(b.values(np.arange(500)[::-1])[::-1], stepwise)
    c = RandomSteps(hold=(1, 3))
    c.reset(np.random.default_rng(4))
    assert c(499) == stepwise[499] and c(3) == stepwise[3]
    d = RandomSteps(hold=(1, 3))
    d.reset(np.random.default_rng(5))
    assert not np.array_equal(d.values(np.arange(500)), stepwise)
    # A fixed hold: one level per block of that many steps.
    e = RandomSteps(amplitude=1.0, hold=4)
    e.reset(np.random.default_rng(0))
    r = e.values(np.arange(40))
    assert np.all(r.reshape(10, 4) == r[::4, None]) and np.unique(r).size == 10
    assert repr(e) == "RandomSteps(amplitude=1.0, hold=(4, 4), offset=0.0)"
    twin = pickle.loads(pickle.dumps(e))
    np.testing.assert_array_equal(twin.values(np.arange(300)), e.values(np.arange(300)))


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"amplitude": -1.0}, ValueError, "amplitude"),
        ({"amplitude": "big"}, TypeError, "amplitude"),
        ({"hold": 0}, ValueError, "hold must be an integer >= 1"),
        ({"hold": [5, 2]}, ValueError, "low <= high"),
        ({"hold": [1, 2, 3]}, ValueError, "range"),
        ({"hold": 2.5}, ValueError, "hold"),
        ({"offset": float("nan")}, ValueError, "offset"),
    ],
)
def test_random_steps_bad_input(kwargs, error, match):
    with pytest.raises(error, match=match):
        RandomSteps(**kwargs)


def test_random_jump_steps_and_probability():
    """Per lane: the jump with probability p, at a step uniform on [low, high]; the values
    switch to ``after`` exactly there and next_change announces it."""
    B = 4000
    schedule = RandomJump(after=[9.0, 9.0], at=(10, 19), probability=0.3)
    schedule.allocate(B)
    nominal = np.tile([1.0, 2.0], (B, 1))
    rngs = [np.random.default_rng(s) for s in np.random.SeedSequence(1).spawn(B)]
    schedule.reset_lanes(np.arange(B), nominal, rngs)
    step = schedule.next_change(np.zeros(B, dtype=np.int64))
    jumps = step != NEVER
    assert abs(jumps.mean() - 0.3) < 5 * np.sqrt(0.3 * 0.7 / B)
    assert set(step[jumps].tolist()) == set(range(10, 20))
    counts = np.bincount(step[jumps] - 10, minlength=10)
    m = jumps.sum()
    assert np.all(np.abs(counts - m / 10) < 5 * np.sqrt(m / 10 * 0.9))
    for k in (0, 9, 10, 15, 19, 100):
        values = schedule.values(np.full(B, k))
        after = jumps & (k >= step)
        np.testing.assert_array_equal(values[after], np.tile([9.0, 9.0], (after.sum(), 1)))
        np.testing.assert_array_equal(values[~after], np.tile([1.0, 2.0], ((~after).sum(), 1)))
    later = schedule.next_change(np.full(B, 19))
    assert np.all(later == NEVER)  # after the last possible jump step, nothing changes


def test_random_jump_single_lane_pickle_and_bad_input():
    schedule = RandomJump([0.5, 0.5], at=7)
    schedule.reset(np.array([1.0, 1.0]), np.random.default_rng(0))
    assert schedule(6).tolist() == [1.0, 1.0] and schedule(7).tolist() == [0.5, 0.5]
    twin = copy.deepcopy(pickle.loads(pickle.dumps(schedule)))
    assert twin(7).tolist() == [0.5, 0.5] and twin.at == (7, 7)
    never = RandomJump([0.5, 0.5], at=(1, 5), probability=0.0)
    never.reset(np.array([1.0, 1.0]), np.random.default_rng(0))
    assert never(1000).tolist() == [1.0, 1.0]
    with pytest.raises(ValueError, match="shape of the plant parameters"):
        schedule.reset(np.array([1.0, 1.0, 1.0]), np.random.default_rng(0))
    for kwargs, match in (
        ({"at": -1}, "at must be an integer >= 0"),
        ({"at": (9, 3)}, "low <= high"),
        ({"probability": 1.5}, "probability"),
    ):
        with pytest.raises(ValueError, match=match):
            RandomJump(**{"after": [0.5, 0.5], "at": 3, **kwargs})
    with pytest.raises(ValueError, match="finite"):
        RandomJump([np.nan, 0.5], at=3)
