"""The parameter rules of the recursive estimators against regularised batch least squares by
numpy (on true regressors built from python-control simulations) and hand-worked tiny cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
from true_state import (
    A_TRUE,
    B_TRUE,
    FORMS,
    run_with_true_state,
    simulate,
    true_regressors,
    true_state_data,
)

from stcgym.adaptive.estimation.factory import make_estimator

# --------------------------------------------------------------------------------------------
# Parameter rules against batch least squares and hand-worked cases
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("state", ["O", "KF", "CO"])
@pytest.mark.parametrize("p0", [1e6, 10.0])
def test_rls_with_true_state_is_regularised_batch_least_squares(form, state, p0):
    T = 200
    u, X, y, H = true_state_data(5, T, form)
    theta0 = np.array([0.3, -0.2, 0.1, 0.4])
    kw = {"observer_gain": [0.2, 0.1]} if state == "CO" else {}
    est = make_estimator(f"{state}-RLS", 2, form=form, p0=p0, theta0=theta0, x_init=X[:, 0], **kw)
    thetas = run_with_true_state(est, X, u, y)
    for t in (3, 10, 50, T):
        Ht, Yt = H[:t], y[:t]
        expected = np.linalg.solve(Ht.T @ Ht + np.eye(4) / p0, Ht.T @ Yt + theta0 / p0)
        np.testing.assert_allclose(thetas[t - 1], expected, rtol=1e-6, atol=1e-9)
    expected_P = np.linalg.inv(H.T @ H + np.eye(4) / p0)
    np.testing.assert_allclose(est.P, expected_P, rtol=1e-6, atol=1e-12)


def test_rls_forgetting_is_exponentially_weighted_least_squares():
    T, lam, p0 = 150, 0.95, 100.0
    u, X, y, H = true_state_data(6, T, "observer")
    est = make_estimator("O-RLS", 2, p0=p0, forgetting=lam, x_init=X[:, 0])
    thetas = run_with_true_state(est, X, u, y)
    theta0 = np.full(4, 1.0 / p0)
    for t in (5, 40, T):
        w = lam ** np.arange(t - 1, -1, -1.0)
        M = (H[:t].T * w) @ H[:t] + lam**t * np.eye(4) / p0
        v = (H[:t].T * w) @ y[:t] + lam**t * theta0 / p0
        np.testing.assert_allclose(thetas[t - 1], np.linalg.solve(M, v), rtol=1e-7, atol=1e-10)


def test_mils_forgetting_is_exponentially_weighted_stacked_least_squares():
    T, lam, p0, p = 100, 0.9, 100.0, 3
    u, X, y, H = true_state_data(12, T, "observability")
    est = make_estimator(
        "KF-MILS", 2, p=p, p0=p0, forgetting=lam, form="observability", x_init=X[:, 0]
    )
    thetas = run_with_true_state(est, X, u, y)
    theta0 = np.full(4, 1.0 / p0)
    for t in (2, 30, T):
        M, v = lam**t * np.eye(4) / p0, lam**t * theta0 / p0
        for s in range(1, t + 1):  # block s weighted lambda^(t-s)
            rows = np.array([r for r in range(s, s - p, -1) if r >= 1]) - 1
            M = M + lam ** (t - s) * H[rows].T @ H[rows]
            v = v + lam ** (t - s) * H[rows].T @ y[rows]
        np.testing.assert_allclose(thetas[t - 1], np.linalg.solve(M, v), rtol=1e-7, atol=1e-10)


@pytest.mark.parametrize("name", ["O-RLS", "KF-MILS"])
def test_finite_history_is_least_squares_over_the_window(name):
    T, W, p, p0 = 160, 25, (3 if "MILS" in name else 1), 50.0
    u, X, y, H = true_state_data(7, T, "observer")
    est = make_estimator(name, 2, p=p, p0=p0, window=W, x_init=X[:, 0])
    thetas = run_with_true_state(est, X, u, y)
    theta0 = np.full(4, 1.0 / p0)
    for t in (10, W, W + 1, 77, T):
        # stacked blocks s = t-W+1..t (s >= 1); each block holds rows s, s-1, ..., s-p+1 (>= 1)
        rows = [r for s in range(max(1, t - W + 1), t + 1) for r in range(s, s - p, -1) if r >= 1]
        Hw, Yw = H[np.array(rows) - 1], y[np.array(rows) - 1]
        expected = np.linalg.solve(Hw.T @ Hw + np.eye(4) / p0, Hw.T @ Yw + theta0 / p0)
        np.testing.assert_allclose(thetas[t - 1], expected, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("spike", [3e3, 3e4])
def test_finite_history_stays_exact_when_dominant_samples_leave_the_window(spike):
    """Three input spikes dominate the window while they are in it: removing one is an
    ill-conditioned downdate (pivot ``1 - phi^T P phi`` about ``1e-7`` for ``3e3``, ``1e-9``
    for ``3e4``). The estimate must still be least squares over the window (the independent
    QR solution of the regularised window problem), with the window recomputed by replay."""
    rng = np.random.default_rng(3)
    T, W, p0 = 120, 10, 50.0
    u = rng.standard_normal(T)
    u[[20, 45, 70]] *= spike
    X, y = simulate(A_TRUE, B_TRUE, "observer", u, noise_std=0.2, seed=3)
    H = true_regressors(X, u, 2, "observer")
    est = make_estimator("O-RLS", 2, p0=p0, window=W, x_init=X[:, 0])
    thetas = run_with_true_state(est, X, u, y)
    theta0 = np.full(4, 1.0 / p0)
    for t in range(W + 1, T + 1):
        rows = np.arange(t - W + 1, t + 1) - 1
        stacked = np.vstack([H[rows], np.eye(4) / math.sqrt(p0)])
        expected = np.linalg.lstsq(stacked, np.r_[y[rows], theta0 / math.sqrt(p0)], rcond=None)[0]
        np.testing.assert_allclose(thetas[t - 1], expected, rtol=5e-7, err_msg=f"t = {t}")
    assert est.health["n_window_recomputes"] > 0


def test_mils_with_true_state_is_batch_least_squares_on_stacked_windows():
    T, p, p0 = 120, 4, 10.0
    u, X, y, H = true_state_data(8, T, "observability")
    est = make_estimator("O-MILS", 2, p=p, p0=p0, form="observability", x_init=X[:, 0])
    thetas = run_with_true_state(est, X, u, y)
    theta0 = np.full(4, 1.0 / p0)
    rows = [r for s in range(1, T + 1) for r in range(s, s - p, -1) if r >= 1]
    Hs, Ys = H[np.array(rows) - 1], y[np.array(rows) - 1]
    expected = np.linalg.solve(Hs.T @ Hs + np.eye(4) / p0, Hs.T @ Ys + theta0 / p0)
    np.testing.assert_allclose(thetas[-1], expected, rtol=1e-7, atol=1e-10)


@pytest.mark.parametrize(
    ("multi", "single"),
    [("O-MILS", "O-RLS"), ("KF-D-MILS", "KF-D-RLS"), ("O-MISG", "O-SG"), ("KF-D-MISG", "KF-D-SG")],
)
def test_innovation_length_one_equals_the_scalar_rule_step_for_step(multi, single):
    rng = np.random.default_rng(9)
    u = rng.standard_normal(400)
    _, y = simulate(A_TRUE, B_TRUE, "observer", u, noise_std=0.1)
    e1, e2 = make_estimator(multi, 2, p=1), make_estimator(single, 2)
    for k in range(400):
        np.testing.assert_allclose(e1.update(y[k]), e2.update(y[k]), rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(e1.predict(u[k]), e2.predict(u[k]), rtol=1e-9, atol=1e-12)
    if e1.P is not None:
        np.testing.assert_allclose(e1.P, e2.P, rtol=1e-9, atol=1e-12)


def _hand_case(name, p):
    """n = 1, theta(0) = 0, P(0) = I (or r(0) = 1); true states injected so that
    phi_a(2) = 2, psi(2) = 1, y(2) = 3 and phi_a(3) = 1, psi(3) = -1, y(3) = 0.5."""
    kw = {"P0": 1.0} if name.endswith("LS") else {}
    est = make_estimator(name, 1, p=p, theta0=[0.0, 0.0], x_init=[-2.0], **kw)
    est.update(7.0)  # phi_hat(1) = 0: no change
    est.predict(1.0, x_next=[-1.0])
    step2 = est.update(3.0)
    P2 = est.P
    est.predict(-1.0, x_next=[0.0])
    step3 = est.update(0.5)
    return step2, P2, step3, est.P


def test_d_rls_hand_worked():
    # t=2: e = 3, L1 = 2/5, L2 = 1/2 -> a = 1.2, b = 1.5, P1 = 0.2, P2 = 0.5
    # t=3: e = 0.5 - (1.2 - 1.5) = 0.8, L1 = 0.2/1.2, L2 = -0.5/1.5 -> a = 4/3, b = 37/30
    step2, P2, step3, P3 = _hand_case("O-D-RLS", 1)
    np.testing.assert_allclose(step2, [1.2, 1.5], rtol=1e-12)
    np.testing.assert_allclose(P2, np.diag([0.2, 0.5]), rtol=1e-12)
    np.testing.assert_allclose(step3, [4 / 3, 37 / 30], rtol=1e-12)
    np.testing.assert_allclose(P3, np.diag([1 / 6, 1 / 3]), rtol=1e-12)
    # plain RLS couples a and b: phi = [2, 1], P = I -> L = [1/3, 1/6], theta = [1, 0.5]
    np.testing.assert_allclose(_hand_case("O-RLS", 1)[0], [1.0, 0.5], rtol=1e-12)


def test_d_mils_hand_worked():
    # t=2: Phi_a = [2, 0], Psi = [1, 0] (t = 1 column is zero) -> same as D-RLS
    # t=3: Phi_a = [1, 2], Psi = [-1, 1], Y = [0.5, 3], E = [0.8, -0.9]
    #   S1 = [[1.2, .4], [.4, 1.8]], S1^-1 = [[.9, -.2], [-.2, .6]], L1 = [.1, .2] -> a = 1.1
    #   S2 = [[1.5, -.5], [-.5, 1.5]], S2^-1 = [[.75, .25], [.25, .75]], L2 = [-.25, .25]
    #   -> b = 1.075; P1 = 0.1, P2 = 0.25
    step2, P2, step3, P3 = _hand_case("KF-D-MILS", 2)
    np.testing.assert_allclose(step2, [1.2, 1.5], rtol=1e-12)
    np.testing.assert_allclose(P2, np.diag([0.2, 0.5]), rtol=1e-12)
    np.testing.assert_allclose(step3, [1.1, 1.075], rtol=1e-12)
    np.testing.assert_allclose(P3, np.diag([0.1, 0.25]), rtol=1e-12)


def test_d_sg_and_misg_hand_worked():
    # D-SG: r1 = 1 + 4 = 5, r2 = 1 + 1 = 2 -> a = 2*3/5, b = 3/2; then r1 = 6, r2 = 3
    step2, _, step3, _ = _hand_case("O-D-SG", 1)
    np.testing.assert_allclose(step2, [1.2, 1.5], rtol=1e-12)
    np.testing.assert_allclose(step3, [1.2 + 0.8 / 6, 1.5 - 0.8 / 3], rtol=1e-12)
    # MISG p=2 at t=3: E = [0.8, -0.9]; r = 6 (plain, ||phi(2)||^2 = 5, then + 2)
    # plain MISG t=2: phi = [2, 1], r = 1 + 5 = 6, theta = phi * 3 / 6 = [1, 0.5]
    step2, _, step3, _ = _hand_case("O-MISG", 2)
    np.testing.assert_allclose(step2, [1.0, 0.5], rtol=1e-12)
    # t=3: E = [0.5 - (1 - 0.5), 3 - (2 + 0.5)] = [0, 0.5]; r = 6 + 2 = 8
    # theta = [1, 0.5] + ([1, -1] * 0 + [2, 1] * 0.5) / 8 = [1.125, 0.5625]
    np.testing.assert_allclose(step3, [1.125, 0.5625], rtol=1e-12)


def test_misg_stacked_r_option():
    est = make_estimator("O-MISG", 1, p=2, theta0=[0.0, 0.0], x_init=[-2.0], stacked_r=True)
    est.update(7.0)
    est.predict(1.0, x_next=[-1.0])
    est.update(3.0)
    est.predict(-1.0, x_next=[0.0])
    est.update(0.5)
    # r(2) = 1 + ||Phi(2, 2)||^2 = 6; r(3) = 6 + ||[[1, 2], [-1, 1]]||^2 = 13
    np.testing.assert_allclose(est.r, [13.0])
