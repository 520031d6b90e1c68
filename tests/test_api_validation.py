"""Malformed input to the self-tuning controller and the estimators (issue 14's property).

For every public constructor setting and every ``predict``/``update`` argument, a malformed
value gives either a clear exception of a documented type (``ValueError`` or ``TypeError``)
whose message names the argument, or a working object whose outputs are finite. Never a raw
numpy/numba error, never NaN/inf silently, and a rejected call leaves the object exactly as it
was (its pickle does not change).
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stcgym.adaptive import RecursiveLeastSquares, SelfTuningController, make_estimator

MALFORMED = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-3, 3),
    st.booleans(),
    st.text(max_size=3),
    st.none(),
    st.complex_numbers(max_magnitude=3, allow_nan=False, allow_infinity=False),
    st.lists(st.floats(-2, 2), max_size=4),
    st.lists(st.lists(st.floats(-2, 2), max_size=2), max_size=2),
)
SLOW = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _names(exc: BaseException, *candidates: str) -> bool:
    text = str(exc)
    return any(c in text for c in candidates)


@SLOW
@given(
    key=st.sampled_from(["n", "poles", "action_bound", "seed", "estimator", "design", "form"]),
    value=MALFORMED,
)
def test_controller_settings_raise_naming_the_setting_or_work(key: str, value) -> None:
    kwargs = {"n": 2, key: value}
    try:
        ctl = SelfTuningController(**kwargs)
    except (ValueError, TypeError) as exc:
        assert _names(exc, key, "plant order"), (key, value, exc)
        return
    u, _ = ctl.predict(np.array([0.1, 1.0]))
    assert u.shape == (1,) and np.all(np.isfinite(u))


@pytest.mark.parametrize("value", [[[], [0.0]], [[0.1], [0.2, 0.3]], [[0.5, 0.5], [0.5]]])
def test_ragged_seed_is_rejected_naming_the_setting(value) -> None:
    # a ragged nested list made numpy raise its own "inhomogeneous shape" error
    with pytest.raises(ValueError, match="seed must be"):
        SelfTuningController(2, seed=value)


@SLOW
@given(obs=MALFORMED)
def test_controller_predict_rejects_bad_observations_without_changing_state(obs) -> None:
    ctl = SelfTuningController(2, seed=3)
    ctl.predict(np.array([0.2, 1.0]))
    before = pickle.dumps(ctl)
    try:
        u, _ = ctl.predict(obs)
    except (ValueError, TypeError) as exc:
        assert _names(exc, "observation"), (obs, exc)
        assert pickle.dumps(ctl) == before
        return
    assert np.all(np.isfinite(u))


@pytest.mark.parametrize("num_envs", [None, 3])
def test_controller_rejects_huge_observation_and_continues_identically(num_envs) -> None:
    """issue 14: ``predict([1e200, 1])`` used to leave the controller half-stepped."""
    ctl = SelfTuningController(2, num_envs=num_envs)
    twin = SelfTuningController(2, num_envs=num_envs)
    good = np.array([0.3, 1.0]) if num_envs is None else np.tile([0.3, 1.0], (num_envs, 1))
    bad = good.copy()
    bad[..., 0] = 1e200
    ctl.predict(good)
    twin.predict(good)
    with pytest.raises(ValueError, match="observation"):
        ctl.predict(bad)
    for _ in range(5):
        np.testing.assert_array_equal(ctl.predict(good)[0], twin.predict(good)[0])


@SLOW
@given(
    key=st.sampled_from(["p", "p0", "forgetting", "window", "theta0", "P0", "form"]),
    value=MALFORMED,
)
def test_estimator_settings_raise_naming_the_setting_or_work(key: str, value) -> None:
    try:
        est = make_estimator("KF-MILS", 2, **{key: value})
    except (ValueError, TypeError) as exc:
        assert _names(exc, key), (key, value, exc)
        return
    theta = est.update(0.5)
    est.predict(1.0)
    assert np.all(np.isfinite(theta))


@SLOW
@given(value=MALFORMED, which=st.sampled_from(["update", "predict"]))
def test_estimator_steps_reject_bad_values_without_changing_state(value, which: str) -> None:
    est = make_estimator("O-RLS", 2, p0=100.0)
    est.update(0.1)
    est.predict(1.0)
    if which == "predict":  # the protocol: update(y(t)) -> u(t) -> predict(u(t))
        est.update(0.2)
    before = pickle.dumps(est)
    try:
        out = est.update(value) if which == "update" else est.predict(value)
    except (ValueError, TypeError) as exc:
        assert _names(exc, "y", "u", "output", "input"), (which, value, exc)
        assert pickle.dumps(est) == before
        return
    assert np.all(np.isfinite(out))


@SLOW
@given(phi=MALFORMED, y=MALFORMED)
def test_regressor_rls_rejects_bad_data_without_changing_state(phi, y) -> None:
    est = RecursiveLeastSquares(2, P0=10.0)
    est.update([1.0, 0.5], 0.2)
    before = pickle.dumps(est)
    try:
        theta = est.update(phi, y)
    except (ValueError, TypeError) as exc:
        assert _names(exc, "phi", "y"), (phi, y, exc)
        assert pickle.dumps(est) == before
        return
    assert np.all(np.isfinite(theta))
