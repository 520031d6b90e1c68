"""The normalised-gradient (projection) rule ``NG``, a rule added through the registry of variants
(stcgym.adaptive.variants): against the equations by hand, the dense reference, its
defining property, its flops, its keywords, single = lane."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stcgym.adaptive import EstimatorSpec, SelfTuningController, make_estimator
from stcgym.adaptive.estimation import flops as F
from stcgym.adaptive.estimation.reference import ReferenceEstimator
from stcgym.adaptive.variants import variant

REF_RTOL = 1e-9


def _data(T=120, seed=0):
    rng = np.random.default_rng(seed)
    u = rng.choice([-1.0, 1.0], size=T)
    y = np.zeros(T)
    x = np.zeros(2)
    for k in range(T):  # the observer-form plant a = [-1.5, 0.7], b = [1, 0.5]
        y[k] = x[0] + 0.05 * rng.standard_normal()
        x = np.array([1.5 * x[0] + x[1] + u[k], -0.7 * x[0] + 0.5 * u[k]])
    return u, y


def test_first_steps_by_hand():
    """n = 1, O-NG: phi(1) = 0 leaves theta; predict(u(1)) gives x_hat(2) and the regressor
    phi(2) = [-x_hat(1), u(1)] (eq. (57)); the update is theta + mu phi e / (alpha + phi^T phi),
    e = y(2) - phi^T theta."""
    mu, alpha = 0.5, 0.1
    est = make_estimator("O-NG", 1, p0=10.0, adaptation_gain=mu, normalization_bias=alpha)
    theta0 = np.full(2, 0.1)
    np.testing.assert_array_equal(est.update(2.0), theta0)  # phi(1) = 0
    x2 = est.predict(1.0)
    # open-loop observer: x(2) = -a_hat x(1) + b_hat u(1), x(1) = 1/p0
    np.testing.assert_allclose(x2, [-0.1 * 0.1 + 0.1 * 1.0], rtol=1e-15)
    phi = np.array([-0.1, 1.0])  # x_hat(1) = 1/p0
    e = 3.0 - phi @ theta0
    expected = theta0 + mu * phi * e / (alpha + phi @ phi)
    np.testing.assert_allclose(est.update(3.0), expected, rtol=1e-15, atol=1e-16)
    assert est.P is None and est.r is None


@pytest.mark.parametrize("form", ["observer", "observability"])
@pytest.mark.parametrize("name", ["O-NG", "KF-NG", "O-D-NG", "KF-D-NG", "CO-NG"])
def test_equals_the_dense_reference(name, form):
    u, y = _data()
    kw: dict = {"adaptation_gain": 0.3, "normalization_bias": 0.5}
    if name.startswith("KF"):
        kw |= {"process_noise": 0.01, "measurement_noise": 0.5}
    if name.startswith("CO"):
        kw["observer_gain"] = [0.3, -0.1]
    est = make_estimator(name, 2, p0=100.0, form=form, **kw)
    ref = ReferenceEstimator(EstimatorSpec.build(name, 2, p0=100.0, form=form, **kw))
    for k in range(len(u)):
        np.testing.assert_allclose(est.update(y[k]), ref.update(y[k]), rtol=REF_RTOL, atol=1e-12)
        np.testing.assert_allclose(est.predict(u[k]), ref.predict(u[k]), rtol=REF_RTOL, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(
    theta=st.lists(st.floats(-2, 2), min_size=4, max_size=4),
    x=st.floats(-3, 3),
    u=st.floats(-3, 3).filter(lambda v: abs(v) > 1e-3),
    y=st.floats(-5, 5),
)
def test_unit_gain_projects_onto_the_measurement(theta, x, u, y):
    """With mu = 1 the updated estimate explains the new measurement up to the bias:
    ``y - phi^T theta(t) = alpha / (alpha + phi^T phi) e(t)`` (the projection of theta(t-1)
    onto ``{theta : phi^T theta = y}`` as alpha -> 0)."""
    alpha = 1e-3
    est = make_estimator("O-NG", 2, theta0=theta, x_init=[x, 0.0], normalization_bias=alpha)
    est.update(0.0)
    est.predict(u)
    phi = est.phi.copy()
    e = y - phi @ est.theta
    after = est.update(y)
    np.testing.assert_allclose(
        y - phi @ after, alpha / (alpha + phi @ phi) * e, rtol=1e-9, atol=1e-12
    )


def test_flops_and_the_registry_entry():
    assert variant("O-NG").flops(3) == (12 * 3 + 2, F.open_loop_observer(3))
    assert sum(variant("KF-D-NG").flops(2)) == 12 * 2 + 4 + F.kalman_filter(2)
    # the paper's 16 names stay the paper's
    from stcgym.adaptive import ALGORITHMS

    assert len(ALGORITHMS) == 16 and not any(a.endswith("NG") for a in ALGORITHMS)


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"adaptation_gain": 2.0}, ValueError, r"adaptation_gain \(mu\) must lie in \(0, 2\)"),
        ({"adaptation_gain": 0.0}, ValueError, "adaptation_gain"),
        ({"normalization_bias": 0.0}, ValueError, "normalization_bias"),
        ({"p": 2}, ValueError, "p .innovation length. applies to MISG/MILS"),
        ({"forgetting": 0.9}, ValueError, "forgetting applies to SG/MISG/RLS/MILS rules only"),
        ({"P0": 1.0}, ValueError, "P0 applies to RLS/MILS"),
        ({"step": 1.0}, TypeError, "unexpected keyword argument 'step'"),
    ],
)
def test_keywords_are_checked(kwargs, error, match):
    with pytest.raises(error, match=match):
        make_estimator("O-NG", 2, **kwargs)
    if "adaptation_gain" in kwargs:  # a rule's own keyword on another rule
        with pytest.raises(ValueError, match="adaptation_gain applies to NG rules only, not RLS"):
            make_estimator("O-RLS", 2, adaptation_gain=0.5)


@pytest.mark.equality
def test_single_equals_lane_bit_for_bit():
    u, y = _data(60)
    single = make_estimator("KF-D-NG", 2, adaptation_gain=0.8)
    batch = make_estimator("KF-D-NG", 2, adaptation_gain=0.8, num_envs=3)
    for k in range(len(u)):
        th = single.update(y[k])
        ths = batch.update(np.full(3, y[k]))
        single.predict(u[k])
        batch.predict(np.full(3, u[k]))
        for i in range(3):
            np.testing.assert_array_equal(ths[i], th)


def test_the_controller_runs_it_and_warns():
    with pytest.warns(UserWarning, match="does not hold the loop"):
        ctl = SelfTuningController(2, estimator="o-ng")
    assert ctl.estimator == "O-NG"
    u, _ = ctl.predict(np.array([0.1, 1.0]))
    assert u.shape == (1,) and np.isfinite(u[0])
