"""The one closed-loop driver: the same lanes through bench-style evaluation, the sweep and the
compiled rollout give the same costs, scored by the same divergence rule."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from family_envs import single_family_env

import stcgym.adaptive.control.rollout as rollout_module
import stcgym.envs  # noqa: F401  (registers the ids)
from stcgym.adaptive import SelfTuningController
from stcgym.adaptive.control.rollout import charge_divergence, rollout
from stcgym.agents.closed_loop import run_closed_loop
from stcgym.agents.evaluation.evaluate import run_episode
from stcgym.agents.sweeps.chunk import _vector_env, closed_loop
from stcgym.envs.families import draw_plant, load_family
from stcgym.envs.signals import Jumps

FAMILY = {
    "name": "lanes",
    "seed": 5,
    "count": 6,
    "order": 2,
    "poles": {"unstable_share": 0.5, "complex_share": 0.5},
    "zeros": {"nonminimum_phase_share": 0.3},
    "steps": 150,
    "y_bound": 20.0,
    "reference": {"kind": "square", "period": 30},
    "jump": {"at": 0.5, "magnitude_scale": [0.8, 1.0], "dc_gain_scale": [0.5, 2.0]},
}


@dataclass
class LaneSpec:
    """One lane of the family as a single env: what ``run_episode`` builds and reads."""

    fam: Any
    plant: Any
    steps: int

    @property
    def action_bound(self) -> float:
        return self.fam["action_bound"]

    def make(self) -> gym.Env:
        p, fam = self.plant, self.fam
        schedule = Jumps({fam.jump_step: np.r_[p.a_after, p.b_after]})
        return single_family_env(fam, p, self.steps, schedule=schedule)


def test_charge_divergence_repeats_the_last_cost_of_a_diverged_lane():
    cost = np.array([[1.0, 2.0, 3.0, 4.0], [5.0, 6.0, 0.0, 0.0], [7.0, 0.0, 0.0, 0.0]])
    charge_divergence(cost, [4, 2, 1])
    np.testing.assert_array_equal(
        cost, [[1.0, 2.0, 3.0, 4.0], [5.0, 6.0, 6.0, 6.0], [7.0, 7.0, 7.0, 7.0]]
    )


def test_bench_sweep_and_rollout_give_the_same_costs(monkeypatch):
    """Six lanes (two of them diverge after the jump, within ``y_bound = 20``) through the
    sweep (compiled rollout), the driver's predict loop on the same vector env, and
    ``run_episode`` on one single env per lane."""
    fam = load_family(FAMILY)
    plants = [draw_plant(fam, i) for i in range(fam.count)]
    seeds = [21 + i for i in range(fam.count)]
    T = fam.steps
    # the sweep: the native vector env and the compiled rollout
    rollouts = []

    def counted(*args, **kwargs):
        rollouts.append(1)
        return rollout(*args, **kwargs)

    monkeypatch.setattr(rollout_module, "rollout", counted)
    swept = closed_loop({"kind": "stc"}, fam, plants, seeds)
    assert rollouts == [1]
    # the same driver through predict (a per-step hook forces that route)
    venv = _vector_env(fam, plants)  # the sweep's env of these lanes
    obs, _ = venv.reset(seed=seeds)
    ctl = SelfTuningController(2, num_envs=len(plants), action_bound=fam["action_bound"])
    stepped = run_closed_loop(ctl, venv, obs, T, before_step=lambda k: None)
    for res in (swept, stepped):
        assert res.cost.shape == (len(plants), T)
    np.testing.assert_allclose(swept.cost, stepped.cost, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(swept.diverged, stepped.diverged)
    np.testing.assert_array_equal(swept.steps_run, stepped.steps_run)
    # bench-style: one single env per lane, its own controller (lane i of the batch: seed i)
    for i, (plant, seed) in enumerate(zip(plants, seeds, strict=True)):
        single = SelfTuningController(2, action_bound=fam["action_bound"], seed=i)
        ep = run_episode(single, LaneSpec(fam, plant, T), seed)
        np.testing.assert_allclose(ep.cost, swept.cost[i], rtol=1e-9, atol=1e-12)
        assert ep.diverged == swept.diverged[i] and ep.steps_run == swept.steps_run[i]
    # the rule: a diverged lane is charged its last cost to the end
    assert swept.diverged.any() and not swept.diverged.all()
    for i in np.flatnonzero(swept.diverged):
        last = swept.steps_run[i] - 1
        assert last < T - 1
        np.testing.assert_array_equal(swept.cost[i, last:], swept.cost[i, last])
        assert swept.cost[i, last] > (fam["y_bound"] - 1.0) ** 2 / 4
