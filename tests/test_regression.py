"""Tests of RecursiveLeastSquares (RLS on user regressors; Voevoda & Troshina 2016, (2)-(4)).

Independent references: the regularised normal equations solved with ``numpy.linalg.solve``
(forgetting and finite history included), a hand-worked scalar case, and bit-for-bit equality
of a batch lane with a single estimator (the same compiled lane function runs on both sides).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stcgym.adaptive.regression.rls import NumericalHealthError, RecursiveLeastSquares


def batch_ls(Phi, Y, P0, theta0, lam=1.0):
    """``(lam^T P0^{-1} + sum lam^{T-t} phi^T phi)^{-1} (lam^T P0^{-1} theta0 + ...)``.

    ``Phi`` (T, p, d), ``Y`` (T, p); returns ``(theta, P)``.
    """
    T = Phi.shape[0]
    w = lam ** np.arange(T - 1, -1, -1)
    prior = lam**T * np.linalg.inv(P0)
    info = prior + np.einsum("t,tri,trj->ij", w, Phi, Phi)
    rhs = prior @ theta0 + np.einsum("t,tri,tr->i", w, Phi, Y)
    return np.linalg.solve(info, rhs), np.linalg.inv(info)


def test_hand_worked_scalar_case():
    # P0 = 0.5; (phi, y) = (1, 2): K = 0.5 / 1.5 = 1/3, theta = 2/3, P = 1/3;
    # (phi, y) = (2, 2): K = P(1) phi / (1 + phi P(1) phi) = (2/3) / (7/3) = 2/7, theta = 6/7
    est = RecursiveLeastSquares(1, P0=0.5)
    np.testing.assert_allclose(est.update([1.0], 2.0), [2 / 3], rtol=1e-15)
    np.testing.assert_allclose([est.K[0], est.P[0, 0], est.innovation[0]], [1 / 3, 1 / 3, 2.0])
    np.testing.assert_allclose(est.update([2.0], 2.0), [6 / 7], rtol=1e-15)
    np.testing.assert_allclose([est.K[0], est.P[0, 0]], [2 / 7, 1 / 7], rtol=1e-15)
    np.testing.assert_allclose([est.y_hat[0], est.innovation[0]], [4 / 3, 2 / 3], rtol=1e-15)
    assert est.t == 2


@pytest.mark.parametrize(
    "P0",
    [2.0, np.array([0.5, 3.0, 10.0]), np.array([[2.0, 0.3, 0.0], [0.3, 1.0, 0.1], [0, 0.1, 0.5]])],
    ids=["scalar", "vector", "matrix"],
)
@pytest.mark.parametrize("lam", [1.0, 0.95])
@pytest.mark.parametrize("p", [1, 2])
def test_equals_regularised_batch_least_squares(P0, lam, p):
    rng = np.random.default_rng(0)
    d, T = 3, 80
    Phi = rng.standard_normal((T, p, d))
    Y = Phi @ np.array([1.0, -2.0, 0.5]) + 0.1 * rng.standard_normal((T, p))
    theta0 = rng.standard_normal(d)
    est = RecursiveLeastSquares(d, p, theta0=theta0, P0=P0, forgetting=lam)
    for k in range(T):
        est.update(Phi[k] if p > 1 else Phi[k, 0], Y[k] if p > 1 else Y[k, 0])
    P0m = np.diag(np.broadcast_to(P0, (d,))) if np.ndim(P0) < 2 else P0
    theta, P = batch_ls(Phi, Y, P0m, theta0, lam)
    np.testing.assert_allclose(est.theta, theta, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(est.P, P, rtol=1e-9, atol=1e-14)
    # run() is the same lane function stepped in a compiled loop
    again = RecursiveLeastSquares(d, p, theta0=theta0, P0=P0, forgetting=lam)
    history = again.run(Phi if p > 1 else Phi[:, 0], Y if p > 1 else Y[:, 0])
    assert history.shape == (T, d)
    np.testing.assert_array_equal(history[-1], est.theta)


def test_gain_is_equation_3_for_a_vector_output():
    rng = np.random.default_rng(1)
    est = RecursiveLeastSquares(3, 2, P0=5.0)
    for _ in range(4):
        est.update(rng.standard_normal((2, 3)), rng.standard_normal(2))
    P_prev, theta_prev = est.P, est.theta
    Phi, Y = rng.standard_normal((2, 3)), rng.standard_normal(2)
    est.update(Phi, Y)
    K = P_prev @ Phi.T @ np.linalg.inv(np.eye(2) + Phi @ P_prev @ Phi.T)  # (3)
    np.testing.assert_allclose(est.K, K, rtol=1e-10)
    np.testing.assert_allclose(est.theta, theta_prev + K @ (Y - Phi @ theta_prev), rtol=1e-10)
    np.testing.assert_allclose(est.P, P_prev - K @ Phi @ P_prev, rtol=1e-9, atol=1e-14)  # (4)


@settings(max_examples=40, deadline=None)
@given(
    d=st.integers(1, 4),
    T=st.integers(1, 30),
    p0=st.floats(0.1, 100.0),
    seed=st.integers(0, 2**32 - 1),
)
def test_property_rls_is_the_regularised_estimate(d, T, p0, seed):
    rng = np.random.default_rng(seed)
    Phi = rng.standard_normal((T, 1, d)) * rng.uniform(0.1, 10.0)
    Y = rng.standard_normal((T, 1))
    est = RecursiveLeastSquares(d, P0=p0)
    est.run(Phi[:, 0], Y[:, 0])
    theta, P = batch_ls(Phi, Y, p0 * np.eye(d), np.zeros(d))
    scale = 1.0 + np.abs(theta).max()
    np.testing.assert_allclose(est.theta, theta, rtol=1e-7, atol=1e-9 * scale)
    np.testing.assert_allclose(est.P, P, rtol=1e-7, atol=1e-10 * p0)
    assert np.all(np.linalg.eigvalsh(est.P) > 0)


# ------------------------------------------------------------------ finite history


@pytest.mark.parametrize("p", [1, 2])
def test_window_is_the_estimate_over_the_last_samples(p):
    rng = np.random.default_rng(2)
    d, T, W = 2, 60, 15
    Phi = rng.standard_normal((T, p, d))
    Y = rng.standard_normal((T, p))
    theta0 = np.array([0.3, -0.2])
    est = RecursiveLeastSquares(d, p, theta0=theta0, P0=4.0, window=W)
    history = est.run(Phi if p > 1 else Phi[:, 0], Y if p > 1 else Y[:, 0])
    for t in (5, W, W + 1, T):
        lo = max(0, t - W)
        theta, _ = batch_ls(Phi[lo:t], Y[lo:t], 4.0 * np.eye(d), theta0)
        np.testing.assert_allclose(history[t - 1], theta, rtol=1e-9, atol=1e-12)
    assert est.n_recomputes == 0


def test_window_recomputes_when_a_dominant_sample_leaves():
    """A huge sample leaving the window would cancel all digits: recomputed exactly instead."""
    rng = np.random.default_rng(3)
    d, T, W = 2, 30, 8
    Phi = rng.standard_normal((T, 1, d))
    Phi[4] *= 1e6
    Y = rng.standard_normal((T, 1))
    est = RecursiveLeastSquares(d, P0=1.0, window=W)
    history = est.run(Phi[:, 0], Y[:, 0])
    assert est.n_recomputes >= 1
    for t in (W + 5, T):  # t = 13: sample 4 has just left
        theta, P = batch_ls(Phi[t - W : t], Y[t - W : t], np.eye(d), np.zeros(d))
        np.testing.assert_allclose(history[t - 1], theta, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(est.P, P, rtol=1e-8)


@settings(max_examples=25, deadline=None)
@given(
    d=st.integers(1, 3),
    W=st.integers(1, 12),
    T=st.integers(1, 40),
    spikes=st.sets(st.integers(0, 39), max_size=3),
    seed=st.integers(0, 2**32 - 1),
)
def test_property_window_is_the_estimate_over_the_last_W(d, W, T, spikes, seed):
    """Whatever the data (spikes of 1e4 make downdates ill-conditioned): the last W samples."""
    rng = np.random.default_rng(seed)
    Phi = rng.standard_normal((T, 1, d))
    Phi[[k for k in spikes if k < T]] *= 1e4
    Y = rng.standard_normal((T, 1))
    est = RecursiveLeastSquares(d, P0=3.0, window=W)
    history = est.run(Phi[:, 0], Y[:, 0])
    for t in {T, max(1, T - W // 2)}:
        lo = max(0, t - W)
        theta, P = batch_ls(Phi[lo:t], Y[lo:t], 3 * np.eye(d), np.zeros(d))
        # accuracy of any least-squares solver: eps x condition number of the information
        cond = np.linalg.cond(P)
        scale = 1.0 + np.abs(theta).max()
        atol = (1e-10 + 1e-13 * cond) * scale
        np.testing.assert_allclose(history[t - 1], theta, rtol=1e-6, atol=atol)


# ------------------------------------------------------------------ P0 = 0, enable, reset


def test_zero_P0_never_moves():
    """Voevoda & Troshina (2016), after (4): with P0 = 0 the recursion never leaves theta0."""
    rng = np.random.default_rng(4)
    est = RecursiveLeastSquares(2, P0=0.0, theta0=[0.1, 0.2])
    history = est.run(rng.standard_normal((50, 2)), rng.standard_normal(50))
    np.testing.assert_array_equal(history, np.broadcast_to([0.1, 0.2], (50, 2)))
    np.testing.assert_array_equal(est.P, np.zeros((2, 2)))
    assert est.t == 50 and est.innovation[0] != 0.0


def test_disabled_estimator_freezes_theta_and_P_but_predicts():
    rng = np.random.default_rng(5)
    Phi, Y = rng.standard_normal((20, 3)), rng.standard_normal(20)
    est = RecursiveLeastSquares(3, P0=10.0)
    est.run(Phi[:10], Y[:10])
    theta, P = est.theta, est.P
    est.enabled = False
    est.update(Phi[10], Y[10])
    np.testing.assert_array_equal(est.theta, theta)
    np.testing.assert_array_equal(est.P, P)
    np.testing.assert_allclose(est.y_hat, [Phi[10] @ theta])
    np.testing.assert_allclose(est.predict(Phi[11]), [Phi[11] @ theta])
    est.enabled = True
    est.run(Phi[11:], Y[11:])
    keep = np.r_[0:10, 11:20]  # the frozen sample never entered the estimate
    expected, _ = batch_ls(Phi[keep, None], Y[keep, None], 10.0 * np.eye(3), np.zeros(3))
    np.testing.assert_allclose(est.theta, expected, rtol=1e-9)


def test_reset_all_or_some_lanes():
    rng = np.random.default_rng(6)
    est = RecursiveLeastSquares(2, theta0=[1.0, 2.0], P0=3.0, num_envs=3)
    est.run(rng.standard_normal((3, 10, 2)), rng.standard_normal((3, 10)))
    before = est.theta
    est.reset(lanes=[1])
    np.testing.assert_array_equal(est.theta[[0, 2]], before[[0, 2]])
    np.testing.assert_array_equal(est.theta[1], [1.0, 2.0])
    np.testing.assert_allclose(est.P[1], 3.0 * np.eye(2), rtol=1e-15)
    np.testing.assert_array_equal(est.t, [10, 0, 10])
    est.reset()
    np.testing.assert_array_equal(est.theta, np.broadcast_to([1.0, 2.0], (3, 2)))
    np.testing.assert_array_equal(est.t, [0, 0, 0])


# ------------------------------------------------------------------ lanes


@pytest.mark.parametrize(
    "kwargs", [{}, {"forgetting": 0.9}, {"window": 5}, {"num_outputs": 2}], ids=str
)
def test_batch_lanes_equal_single_estimators_bit_for_bit(kwargs):
    rng = np.random.default_rng(7)
    B, T, d = 4, 25, 3
    p = kwargs.get("num_outputs", 1)
    Phi = rng.standard_normal((B, T, p, d))
    Y = rng.standard_normal((B, T, p))
    batch = RecursiveLeastSquares(d, P0=2.0, num_envs=B, **kwargs)
    stepped = RecursiveLeastSquares(d, P0=2.0, num_envs=B, **kwargs)
    squeeze = (lambda a: a[..., 0, :]) if p == 1 else (lambda a: a)
    squeeze_y = (lambda a: a[..., 0]) if p == 1 else (lambda a: a)
    history = batch.run(squeeze(Phi), squeeze_y(Y))
    for t in range(T):
        stepped.update(squeeze(Phi[:, t]), squeeze_y(Y[:, t]))
    np.testing.assert_array_equal(stepped.theta, history[:, -1])
    for i in range(B):
        single = RecursiveLeastSquares(d, P0=2.0, **kwargs)
        np.testing.assert_array_equal(single.run(squeeze(Phi[i]), squeeze_y(Y[i])), history[i])
        np.testing.assert_array_equal(single.P, batch.P[i])


# ------------------------------------------------------------------ numerical health


def test_overflow_resets_the_covariance_and_warns():
    est = RecursiveLeastSquares(2, P0=1.0, theta0=[0.5, 0.5], num_envs=2)
    est.update([[1.0, 0.0], [0.0, 1.0]], [1.0, 1.0])
    theta = est.theta
    with pytest.warns(RuntimeWarning, match=r"lane\(s\) \[1\].*P reset to P0"):
        est.update([[1.0, 0.0], [1e200, 1e200]], [1.0, 1.0])
    np.testing.assert_array_equal(est.theta[1], theta[1])  # last finite theta kept
    np.testing.assert_array_equal(est.P[1], np.eye(2))
    np.testing.assert_array_equal(est.n_resets, [0, 1])
    assert np.all(np.isfinite(est.theta))


def test_overflow_raises_and_leaves_the_state_unchanged():
    est = RecursiveLeastSquares(2, P0=1.0, on_failure="raise")
    est.update([1.0, 0.0], 1.0)
    theta, P, t = est.theta, est.P, est.t
    with pytest.raises(NumericalHealthError, match="failing step was not applied"):
        est.update([1e200, 1e200], 1.0)
    np.testing.assert_array_equal(est.theta, theta)
    np.testing.assert_array_equal(est.P, P)
    assert est.t == t
    with pytest.raises(NumericalHealthError, match="run\\(\\) step 2"):
        est.run([[1.0, 0.0], [0.0, 1.0], [1e200, 1.0]], [1.0, 1.0, 1.0])


# ------------------------------------------------------------------ bad input


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"num_params": 0}, "num_params must be an integer >= 1"),
        ({"num_outputs": 1.5}, "num_outputs must be an integer"),
        ({"P0": -1.0}, "P0 must be a positive scalar"),
        ({"P0": [1.0, 0.0]}, "P0 must be a positive scalar"),
        ({"P0": [[1.0, 2.0], [0.0, 1.0]]}, "not symmetric"),
        ({"P0": [[1.0, 2.0], [2.0, 1.0]]}, "smallest eigenvalue is -1"),
        ({"P0": np.ones((3, 3))}, r"got shape \(3, 3\)"),
        ({"P0": np.nan}, "not finite"),
        ({"theta0": [1.0]}, "theta0 must be a finite vector of length 2"),
        ({"forgetting": 0.0}, "forgetting must lie in"),
        ({"forgetting": 0.9, "window": 5}, "exclusive"),
        ({"P0": 0.0, "window": 5}, "needs a positive definite P0"),
        ({"window": 0}, "window must be an integer >= 1"),
        ({"on_failure": "ignore"}, "on_failure must be"),
        ({"num_envs": 0}, "num_envs must be an integer >= 1"),
    ],
)
def test_bad_options_name_the_argument(kwargs, match):
    args = {"num_params": 2, **kwargs}
    with pytest.raises(ValueError, match=match):
        RecursiveLeastSquares(**args)


def test_bad_data_names_the_argument_and_changes_nothing():
    est = RecursiveLeastSquares(2, P0=1.0, num_envs=3)
    snapshot = (est.theta, est.P, est.t)
    cases = [
        (np.zeros((3, 3)), np.zeros(3), r"phi must have shape \(3, 2\)"),
        (np.zeros((2, 2)), np.zeros(2), r"phi must have shape \(3, 2\)"),
        (np.zeros((3, 2)), np.zeros((3, 2)), r"y must have shape \(3,\)"),
        (np.full((3, 2), np.nan), np.zeros(3), "phi must be finite"),
        (np.zeros((3, 2)), np.array([0.0, np.inf, 0.0]), "y must be finite"),
    ]
    for phi, y, match in cases:
        with pytest.raises(ValueError, match=match):
            est.update(phi, y)
    with pytest.raises(ValueError, match=r"y must have shape \(3, 4\)"):
        est.run(np.zeros((3, 4, 2)), np.zeros((3, 5)))
    with pytest.raises(ValueError, match=r"lanes must be integers in \[0, 3\)"):
        est.reset(lanes=[3])
    with pytest.raises(ValueError, match=r"lanes as a boolean mask must have shape \(3,\)"):
        est.reset(lanes=[True, False])
    np.testing.assert_array_equal(est.theta, snapshot[0])
    np.testing.assert_array_equal(est.P, snapshot[1])
    np.testing.assert_array_equal(est.t, snapshot[2])
    vector = RecursiveLeastSquares(3, 2)
    with pytest.raises(ValueError, match=r"phi must have shape \(2, 3\) \(num_outputs x"):
        vector.update(np.zeros((3, 2)), np.zeros(2))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        vector.update(np.zeros((2, 3)), np.zeros(2))  # all-zero data: a valid, empty step
