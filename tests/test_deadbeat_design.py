"""The deadbeat design, a design added through the registry of variants
(stcgym.adaptive.variants.DESIGNS): against python-control's ``acker`` with every pole
at the origin, the nilpotent closed loop, its oracle."""

from __future__ import annotations

import control
import gymnasium as gym
import numpy as np
import pytest

import stcgym.envs  # noqa: F401  (registers the envs)
from stcgym.adaptive import KnownModelController, SelfTuningController
from stcgym.adaptive.variants import DESIGNS, PLACEMENT
from stcgym.envs import get_plant
from stcgym.envs.canonical import companion_A


def _augmented(theta: np.ndarray, form: str = "observer") -> tuple[np.ndarray, np.ndarray]:
    """``[[A, 0], [-c, 1]]``, ``[b; 0]`` of the canonical model of ``theta``."""
    n = theta.size // 2
    A = companion_A(theta[:n], form)
    Aa = np.zeros((n + 1, n + 1))
    Aa[:n, :n] = A
    Aa[n, 0] = -1.0
    Aa[n, n] = 1.0
    return Aa, np.r_[theta[n:], 0.0]


def test_the_self_tuning_controller_places_every_pole_at_the_origin():
    """On the noise-free ``unstable2`` the loop holds, and the gain in force is python-control's
    ``acker`` with every pole at 0 on the controller's own estimate; that closed loop is
    nilpotent."""
    env = gym.make("stcgym/ObserverCanonical-v0", plant="unstable2", noise_std=0.0)
    ctl = SelfTuningController(2, design="deadbeat", env=env, poles=0.9)  # poles: ignored
    np.testing.assert_array_equal(ctl.poles, np.zeros(3))
    obs, _ = env.reset(seed=0)
    for _ in range(300):
        action, _ = ctl.predict(obs)
        obs, _, terminated, _, info = env.step(action)
        assert not terminated
    np.testing.assert_allclose(ctl.theta, info["theta"], atol=1e-3)
    Aa, ba = _augmented(ctl.theta)
    K_ref = np.ravel(control.acker(Aa, ba[:, None], np.zeros(3)))
    np.testing.assert_allclose(ctl.K, K_ref, rtol=1e-8, atol=1e-10)
    closed = Aa - np.outer(ba, ctl.K)
    assert np.max(np.abs(np.linalg.matrix_power(closed, 3))) < 1e-9 * np.max(np.abs(closed)) ** 3


def test_the_registry_entry_and_its_oracle():
    design = DESIGNS["deadbeat"]
    assert design.compiled == PLACEMENT and design.poles == 0.0  # Ackermann, every pole at 0
    plant = get_plant("stable2")
    oracle = design.make_oracle(plant.a, plant.b)
    assert isinstance(oracle, KnownModelController)
    np.testing.assert_array_equal(oracle.poles, np.zeros(3))
    Aa, ba = _augmented(np.r_[plant.a, plant.b])
    K_ref = np.ravel(control.acker(Aa, ba[:, None], np.zeros(3)))
    np.testing.assert_allclose(oracle.K, K_ref, rtol=1e-8, atol=1e-10)
    # the other designs' oracles resolve the same way
    assert type(DESIGNS["pole_placement"].make_oracle(plant.a, plant.b)) is KnownModelController


def test_an_unknown_design_lists_the_registry():
    with pytest.raises(ValueError, match="design must be one of .*'deadbeat'"):
        SelfTuningController(2, design="minimum_variance")
