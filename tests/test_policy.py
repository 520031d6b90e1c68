"""The policy base (stcgym.adaptive.policy.LanePolicy): the self-tuning controller, the two
known-model oracles and the SB3 adapter share one ``predict``, so they accept and reject the same
calls in the same way."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from stcgym.adaptive import KnownModelController, LQGController, Policy, SelfTuningController
from stcgym.adaptive.policy import LanePolicy
from stcgym.agents.rl.policy import SB3Policy
from stcgym.agents.rl.wrappers import WindowConfig

A_S2, B_S2 = (-1.5, 0.7), (1.0, 0.5)


class _LinearModel:
    """Stands in for an SB3 model: a fixed linear function of the window features."""

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        obs = np.asarray(obs, dtype=np.float64)
        return np.tanh(obs @ np.linspace(-0.05, 0.05, obs.shape[-1]))[:, None], state


def _make(kind: str, num_envs: int | None, seed: int = 0) -> LanePolicy:
    lanes = 1 if num_envs is None else num_envs
    a, b = (A_S2, B_S2) if num_envs is None else ([A_S2] * lanes, [B_S2] * lanes)
    if kind == "stc":
        return SelfTuningController(2, num_envs=num_envs, seed=seed)  # lane i: seed + i
    if kind == "oracle":
        return KnownModelController(a, b, num_envs=num_envs)
    if kind == "lqg":
        return LQGController(a, b, num_envs=num_envs)
    return SB3Policy(_LinearModel(), WindowConfig(window=3), 10.0, num_envs=num_envs)


KINDS = ["stc", "oracle", "lqg", "sb3"]


def _obs(lanes: int, k: int) -> np.ndarray:
    return np.column_stack([0.1 * np.arange(lanes) + 0.01 * k, np.ones(lanes)])


@pytest.mark.parametrize("kind", KINDS)
def test_shapes_state_and_lanes_equal_single_policies(kind: str) -> None:
    batch = _make(kind, 3)
    singles = [_make(kind, None, seed=i) for i in range(3)]
    assert isinstance(batch, Policy) and isinstance(batch, LanePolicy)
    token = object()
    for k in range(12):
        starts = np.array([k == 0, k in (0, 5), k == 0])
        u, state = batch.predict(_obs(3, k), state=token, episode_start=starts)
        assert u.shape == (3, 1) and state is token
        for i, pol in enumerate(singles):
            u_i, state_i = pol.predict(_obs(3, k)[i], episode_start=bool(starts[i]))
            assert u_i.shape == (1,) and state_i is None
            if kind == "sb3":  # the network runs on a batch: BLAS may round differently
                assert u_i[0] == pytest.approx(u[i, 0], rel=1e-12)
            else:
                assert u_i[0] == u[i, 0]  # the same compiled lane step
    # a list observation and a plain call take the validating and the fast path alike
    twin = pickle.loads(pickle.dumps(singles[0]))
    assert singles[0].predict(np.array([0.2, 1.0]))[0][0] == twin.predict([0.2, 1.0])[0][0]


@pytest.mark.parametrize("kind", KINDS)
def test_a_batch_for_another_number_of_lanes_is_rejected_naming_the_shape(kind: str) -> None:
    single, batch = _make(kind, None), _make(kind, 3)
    single.predict(np.array([0.1, 1.0]))
    batch.predict(_obs(3, 0))
    for pol, bad, expected in (
        (single, _obs(3, 1), r"\(2,\) for num_envs=None"),
        (single, _obs(1, 1), r"\(2,\) for num_envs=None"),
        (batch, _obs(2, 1), r"\(3, 2\), one row per lane"),
        (batch, _obs(3, 1)[0], r"\(3, 2\), one row per lane"),
    ):
        before = pickle.dumps(pol)
        with pytest.raises(ValueError, match="observation must have shape " + expected):
            pol.predict(bad)
        assert pickle.dumps(pol) == before


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"observation": [np.nan, 1.0]}, "observation must be finite"),
        ({"observation": "ab"}, "observation"),
        ({"observation": [0.1, 1.0], "episode_start": [True, False]}, "episode_start"),
        ({"observation": [0.1, 1.0], "episode_start": [0.5]}, "episode_start must be booleans"),
    ],
)
def test_bad_calls_raise_naming_the_argument_and_change_nothing(
    kind: str, kwargs: dict, match: str
) -> None:
    pol = _make(kind, None)
    pol.predict(np.array([0.1, 1.0]))
    before = pickle.dumps(pol)
    with pytest.raises(ValueError, match=match):
        pol.predict(**kwargs)
    assert pickle.dumps(pol) == before


@pytest.mark.parametrize("kind", KINDS)
def test_reset_lanes_equals_episode_start(kind: str) -> None:
    by_reset, by_start = _make(kind, 3), _make(kind, 3)
    for k in range(6):
        by_reset.predict(_obs(3, k))
        by_start.predict(_obs(3, k))
    by_reset.reset(lanes=[False, True, False])
    u_reset = by_reset.predict(_obs(3, 6))[0]
    u_start = by_start.predict(_obs(3, 6), episode_start=[False, True, False])[0]
    np.testing.assert_array_equal(u_reset, u_start)
    for lanes in ([3], [True, False], [[0]], [0.5]):
        with pytest.raises(ValueError, match="lanes"):
            by_reset.reset(lanes=lanes)
