"""A batch of controllers is B lanes of one lane step: single == lane of the batch, bit for bit."""

from __future__ import annotations

import gymnasium as gym
import numba
import numpy as np
import pytest

import stcgym.envs  # noqa: F401  (registers the envs)
from stcgym.adaptive.control import controller_step as kc
from stcgym.adaptive.control.controller import SelfTuningController


def _closed_loop(ctls: list, venv: gym.vector.VectorEnv, steps: int, batched: bool) -> np.ndarray:
    obs, _ = venv.reset(seed=[11, 12, 13])
    us = []
    for _ in range(steps):
        if batched:
            u = ctls[0].predict(obs)[0]
        else:
            u = np.array([c.predict(o)[0] for c, o in zip(ctls, obs, strict=True)])
        us.append(u.ravel())
        obs, *_ = venv.step(u.reshape(-1, 1))
    return np.array(us)


@pytest.mark.equality
@pytest.mark.parametrize(
    "kw",
    [
        {},
        {"design": "lq"},
        {"estimator": "KF-MILS", "estimator_options": {"p": 3}},
        {"estimator": "O-RLS"},
    ],
)
@pytest.mark.parametrize("blocks", [False, True])
def test_single_controllers_equal_their_lanes_bit_for_bit(
    kw: dict, blocks: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The same compiled lane function runs in both: equality is exact, on any CPU, also when
    the batch runs in blocks of rows on two threads (``blocks``: one lane a thread suffices)."""
    if blocks:
        if numba.config.NUMBA_NUM_THREADS < 2:
            pytest.skip("one thread: no blocks")
        monkeypatch.setattr(kc.controllers_step, "min_lanes", 1)
        monkeypatch.setattr(numba, "get_num_threads", lambda: 2)
    seeds = [4, 5, 6]

    def venv() -> gym.vector.VectorEnv:
        return gym.make_vec(
            "stcgym/ObserverCanonical-v0", num_envs=3, plant="stable2", noise_std=0.05,
            max_episode_steps=10_000,
        )  # fmt: skip

    v1, v2 = venv(), venv()
    for v in (v1, v2):
        v.reset(seed=[11, 12, 13])
    batch = SelfTuningController(2, num_envs=3, seed=seeds, **kw)
    singles = [SelfTuningController(2, seed=s, **kw) for s in seeds]
    ub = _closed_loop([batch], v1, 150, batched=True)
    us = _closed_loop(singles, v2, 150, batched=False)
    np.testing.assert_array_equal(ub, us)
    for i, c in enumerate(singles):
        np.testing.assert_array_equal(batch.theta[i], c.theta)


def test_episode_start_resets_only_flagged_lanes() -> None:
    ctl = SelfTuningController(2, num_envs=3)
    obs = np.tile([0.2, 1.0], (3, 1))
    for _ in range(10):
        ctl.predict(obs)
    ctl.predict(obs, episode_start=np.array([False, True, False]))
    assert list(ctl.t) == [11, 1, 11]
    assert list(ctl.diagnostics["episode"]) == [0, 1, 0]


def test_memory_per_lane_is_small() -> None:
    assert SelfTuningController(2, num_envs=10).nbytes_per_lane <= 2048
