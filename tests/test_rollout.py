"""Compiled rollout (stcgym.adaptive.control.rollout): plant + controller fused, one plant or a
batch."""

from __future__ import annotations

import numpy as np
import pytest

from stcgym.adaptive.control.controller import SelfTuningController
from stcgym.adaptive.control.rollout import rollout
from stcgym.envs import PLANTS
from stcgym.envs.canonical import companion_A

T = 300
REF = np.array([1.0 if (k % 100) < 50 else -1.0 for k in range(T + 1)])


def test_rollout_equals_the_predict_loop_on_the_same_noise() -> None:
    spec = PLANTS["unstable2"]
    z = np.random.default_rng(3).standard_normal((1, T + 1))
    res = rollout(SelfTuningController(2, seed=4), spec.theta, T, reference=REF, z=z, traces=True)
    ctl = SelfTuningController(2, seed=4)
    A, b = companion_A(np.array(spec.a)), np.array(spec.b)
    x = np.zeros(2)
    y = 0.05 * z[0, 0]
    us, cost = [], 0.0
    for k in range(T):
        u = float(np.clip(ctl.predict(np.array([y, REF[k]]))[0][0], -10, 10))
        us.append(u)
        x = A @ x + b * u
        cost += (x[0] - REF[k + 1]) ** 2 + 0.01 * u * u
        y = x[0] + 0.05 * z[0, k + 1]
    np.testing.assert_allclose(res.u[0], us, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(res.cost[0, 0], cost, rtol=1e-9)
    assert not res.diverged[0] and res.steps_run[0] == T


@pytest.mark.equality
def test_batch_rollout_lanes_equal_single_rollouts() -> None:
    thetas = np.array([PLANTS[p].theta for p in ("stable2", "unstable2", "integrator2")])
    z = np.random.default_rng(0).standard_normal((3, T + 1))
    batch = rollout(
        SelfTuningController(2, num_envs=3, seed=[1, 2, 3]), thetas, T, reference=REF, z=z,
        window=100,
    )  # fmt: skip
    for i in range(3):
        one = rollout(
            SelfTuningController(2, seed=i + 1), thetas[i], T, reference=REF, z=z[i : i + 1],
            window=100,
        )  # fmt: skip
        np.testing.assert_array_equal(one.cost[0], batch.cost[i])
    assert batch.cost.shape == (3, 3)


def test_open_loop_unstable_plant_diverges_and_stops() -> None:
    ctl = SelfTuningController(2, safe_set={"gain_max": 1e-9})  # never closes the loop
    res = rollout(ctl, PLANTS["unstable2"].theta, T, reference=REF, y_bound=5.0, window=100)
    assert res.diverged[0] and res.steps_run[0] < T


def test_a_diverged_lane_is_charged_its_last_cost_to_the_end() -> None:
    """The divergence rule: the last per-step cost for every step not lived, in every window."""
    ctl = SelfTuningController(2, num_envs=2, safe_set={"gain_max": 1e-9})  # never closes
    theta = np.array([PLANTS["unstable2"].theta, PLANTS["stable2"].theta])
    res = rollout(ctl, theta, T, reference=REF, y_bound=5.0, window=100)
    assert list(res.diverged) == [True, False] and res.steps_run[1] == T
    last = res.steps_run[0] - 1
    assert last < 100 and res.cost[0, 2] > 0  # charged for windows it did not live
    np.testing.assert_array_equal(res.step_cost[0, last:], res.step_cost[0, last])
    assert res.step_cost[0, last] > (5.0 - 1.0) ** 2 / 2  # |y| > y_bound, |r| = 1
    np.testing.assert_allclose(res.cost, res.step_cost.reshape(2, 3, 100).sum(axis=2), rtol=1e-12)
    assert res.cost[0, 2] == pytest.approx(100 * res.step_cost[0, last], rel=1e-12)


def test_rollout_bad_arguments() -> None:
    ctl = SelfTuningController(2, num_envs=2)
    with pytest.raises(ValueError, match="theta"):
        rollout(ctl, np.zeros((3, 4)), T, reference=REF)
    with pytest.raises(ValueError, match="reference"):
        rollout(ctl, PLANTS["stable2"].theta, T, reference=REF[:10])
    with pytest.raises(ValueError, match="steps"):
        rollout(ctl, PLANTS["stable2"].theta, 0, reference=REF)
