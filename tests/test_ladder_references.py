"""The ladder's robust-control reference ``fixed_pi``: the PI law step by step, its tuning on
the training split, and its registry entry."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stcgym.agents.controllers import CONTROLLERS
from stcgym.agents.evaluation.env_spec import EnvSpec
from stcgym.agents.evaluation.episodes import EpisodeSet, run_episodes
from stcgym.agents.fixed_pi import FixedPI, _score, training_split, tune_fixed_pi

SMALL = EnvSpec(family="ladder-l1-v1", split="train", steps=200, action_bound=25.0)


@settings(max_examples=30, deadline=None)
@given(
    kp=st.floats(-3, 3),
    ki=st.floats(-1, 1),
    bound=st.floats(0.1, 10),
    e=st.lists(st.floats(-5, 5), min_size=1, max_size=30),
)
def test_the_law_is_pi_with_conditional_integration(kp, ki, bound, e):
    pi = FixedPI(kp, ki, bound)
    s = 0.0
    for err in e:
        u = pi.predict(np.array([0.0, err]))[0][0]
        v = kp * err + ki * (s + err)
        expected = min(max(v, -bound), bound)
        assert u == pytest.approx(expected, abs=1e-9)
        if expected == v or np.sign(ki * err) != np.sign(v):
            s += err
    pi.reset()
    assert pi.predict(np.array([0.0, 1.0]))[0][0] == pytest.approx(np.clip(kp + ki, -bound, bound))


def test_bad_gains_are_refused():
    with pytest.raises(ValueError, match="kp must be a finite number"):
        FixedPI(float("nan"), 0.1, 1.0)
    with pytest.raises(ValueError, match="action_bound must be positive"):
        FixedPI(0.1, 0.1, 0.0)


def test_tuning_beats_other_gains_on_its_episodes_and_is_deterministic():
    gains = tune_fixed_pi.__wrapped__(SMALL, 20)
    again = tune_fixed_pi.__wrapped__(SMALL, 20)
    assert gains == again and gains.kp > 0 and gains.ki > 0  # positive-gain plants
    episodes = EpisodeSet.of(SMALL, 1, 40_000, 20)
    lqg = CONTROLLERS["lqg"].build(None, SimpleNamespace(env=SMALL))
    ref = run_episodes(lqg, SMALL, episodes, informed=True).cost.mean(axis=1)
    assert _score(gains.kp, gains.ki, SMALL, episodes, ref) == pytest.approx(gains.score)
    rng = np.random.default_rng(0)
    for kp, ki in np.exp(rng.uniform(np.log([0.01, 0.001]), np.log([3.0, 1.0]), size=(5, 2))):
        assert gains.score <= _score(kp, ki, SMALL, episodes, ref) + 1e-12
    # the sign is tuned too: the best law of negative-gain plants has negative gains
    assert _score(-gains.kp, -gains.ki, SMALL, episodes, ref) > 2 * gains.score


def test_the_registry_tunes_on_the_training_split_of_the_scenario():
    test = replace(SMALL, split="test")
    assert training_split(test) == SMALL
    assert training_split(EnvSpec("stable2")) == EnvSpec("stable2")
    info = CONTROLLERS["fixed_pi"]
    assert not info.informed and info.knows["model"].startswith("none")
    tune_fixed_pi.cache_clear()
    builder = info.build(None, SimpleNamespace(env=test, controller_order=2))
    gains = tune_fixed_pi(SMALL)
    policy = builder([None] * 3, [0, 1, 2])
    assert (policy.kp, policy.ki, policy.num_envs) == (gains.kp, gains.ki, 3)
