"""Tests of the recursive joint state/parameter estimators (issue 3).

Every expected value comes from an independent computation: regularised batch least squares by
numpy on regressors built here from python-control simulations, hand-worked tiny cases, a
textbook Kalman filter written here, and the paper's flop formulas typed in from tables 1-4.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from true_state import (
    A_TRUE,
    B_TRUE,
    FORMS,
    THETA_TRUE,
    rel_err,
    simulate,
)

from stcgym.adaptive.estimation import flops
from stcgym.adaptive.estimation.estimator_spec import ALGORITHMS, parse_name
from stcgym.adaptive.estimation.factory import make_estimator
from stcgym.adaptive.estimation.health import NumericalHealthError
from stcgym.adaptive.estimation.recursive import RecursiveEstimator, is_schur_stable
from stcgym.adaptive.variants import variant
from stcgym.envs.canonical import canonical_matrices

# --------------------------------------------------------------------------------------------
# Names, factory and validation
# --------------------------------------------------------------------------------------------


def test_sixteen_names_compose_from_parts():
    assert len(ALGORITHMS) == 16 and len(set(ALGORITHMS)) == 16
    for name in ALGORITHMS:
        state, dec, rule = parse_name(name.lower())
        for form in FORMS:
            est = make_estimator(name.lower(), 2, p=3 if rule in ("MISG", "MILS") else 1, form=form)
            assert est.name == name
            assert (est.spec.state, est.spec.rule, est.spec.decomposed) == (state, rule, dec)
            assert (est.P is None) == (rule in ("SG", "MISG"))
            assert (est.P1 is None) == (state == "O")
            assert (est.r is None) or est.r.shape == ((2,) if dec else (1,))
    co = make_estimator("co-d-mils", 2, p=2, observer_gain=[0.1, 0.2])
    assert co.spec.state == "CO" and co.name == "CO-D-MILS"
    # an O- name with a gain is the closed-loop observer (50) as well
    assert make_estimator("O-RLS", 2, observer_gain=[0.0, 0.0]).name == "CO-RLS"


def test_paper_initial_values():
    est = make_estimator("KF-RLS", 3)
    np.testing.assert_array_equal(est.theta, np.full(6, 1e-6))
    np.testing.assert_array_equal(est.P, 1e6 * np.eye(6))
    np.testing.assert_array_equal(est.x_hat, np.full(3, 1e-6))
    np.testing.assert_array_equal(est.P1, np.eye(3))
    assert est.t == 0
    sg = make_estimator("O-D-SG", 2)
    np.testing.assert_array_equal(sg.r, [1.0, 1.0])
    assert sg.P is None and sg.P1 is None


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"name": "O-XLS"}, "unknown algorithm"),
        ({"name": "KF-E-RLS"}, "unknown algorithm"),
        ({"name": 3}, "name must be a string"),
        ({"n": 0}, "n must be an integer >= 1"),
        ({"n": 2.5}, "n must be an integer"),
        ({"n": True}, "n must be an integer"),
        ({"name": "O-MILS", "p": 0}, "p must be an integer >= 1"),
        ({"p": 2}, "p .innovation length. applies to MISG/MILS"),
        ({"forgetting": 0.0}, r"forgetting \(lambda\) must lie in \(0, 1\]"),
        ({"forgetting": 1.01}, r"forgetting \(lambda\)"),
        ({"forgetting": float("nan")}, r"forgetting \(lambda\)"),
        ({"p0": -1.0}, "p0 must be a finite number > 0"),
        ({"p0": float("inf")}, "p0 must be a finite real number"),
        ({"form": "controller"}, "form must be one of"),
        ({"theta0": [1.0, 2.0]}, "theta0 must have length 4"),
        ({"theta0": [1.0, 2.0, np.nan, 0.0]}, "theta0 must be finite"),
        ({"x_init": [1.0, 2.0, 3.0]}, "x_init must have length 2"),
        ({"P0": -1.0}, "P0 must be a positive scalar"),
        ({"P0": [1.0, 1.0, 0.0, 1.0]}, "P0 must be a positive scalar"),
        ({"P0": np.ones((3, 3))}, "P0 must be .* 4x4 matrix"),
        ({"P0": np.diag([1.0, 1.0, 1.0, -1.0])}, "smallest eigenvalue"),
        ({"P0": np.triu(np.ones((4, 4)))}, "not symmetric"),
        ({"name": "O-D-RLS", "P0": np.ones((4, 4)) + 3 * np.eye(4)}, "block-diagonal"),
        ({"name": "O-SG", "P0": 1.0}, "P0 applies to RLS/MILS"),
        ({"r0": 2.0}, "r0 applies to SG/MISG"),
        ({"name": "O-SG", "r0": 0.0}, "r0 must be a finite number > 0"),
        ({"stacked_r": True}, "stacked_r applies to SG/MISG"),
        ({"name": "O-MISG", "window": 10}, "window .* RLS/MILS rules only"),
        ({"window": 0}, "window must be an integer >= 1"),
        ({"window": 10, "forgetting": 0.99}, "mutually exclusive"),
        ({"process_noise": 0.1}, "apply to KF state estimators only"),
        ({"name": "KF-RLS", "observer_gain": [1.0, 0.0]}, "observer_gain applies to O/CO"),
        ({"name": "CO-RLS"}, "needs observer_gain"),
        ({"name": "CO-RLS", "observer_gain": [1.0]}, "observer_gain must be a finite vector"),
        ({"name": "KF-RLS", "P1_init": -1.0}, "P1_init must be"),
        ({"name": "KF-RLS", "process_noise": -1.0}, "process_noise must be"),
        ({"name": "KF-RLS", "measurement_noise": 0.0}, "measurement_noise must be"),
        ({"on_failure": "ignore"}, "on_failure must be"),
        ({"pd_check_every": -1}, "pd_check_every must be"),
    ],
)
def test_bad_construction_arguments(kwargs, match):
    args = {"name": "O-RLS", "n": 2}
    args.update(kwargs)
    name, n = args.pop("name"), args.pop("n")
    with pytest.raises(ValueError, match=match):
        make_estimator(name, n, **args)


def test_bad_data_and_call_order():
    est = make_estimator("KF-MILS", 2, p=3)
    with pytest.raises(RuntimeError, match="predict.. must follow update"):
        est.predict(1.0)
    bad_values = ((np.nan, ValueError), (np.inf, ValueError), ("a", TypeError), ([1, 2], TypeError))
    for bad, error in bad_values:
        with pytest.raises(error, match=r"y\(t\) must be a finite real number"):
            est.update(bad)
    est.update(np.float32(0.5))  # numpy scalars and 1-element arrays are fine
    with pytest.raises(RuntimeError, match="update.. called twice"):
        est.update(1.0)
    with pytest.raises(ValueError, match=r"u\(t\) must be a finite real number"):
        est.predict(-np.inf)
    with pytest.raises(ValueError, match="x_next must have length 2"):
        est.predict(1.0, x_next=[1.0])
    est.predict(np.array([1.0]))
    with pytest.raises(ValueError, match="same length"):
        est.run([1.0, 2.0], [1.0])
    with pytest.raises(ValueError, match="u must be finite"):
        est.run([1.0, np.nan], [1.0, 2.0])
    est.update(0.0)
    with pytest.raises(RuntimeError, match="between update.. and predict"):
        est.run([1.0], [1.0])


# --------------------------------------------------------------------------------------------
# Conventions: zero before t = 1, regressors, stacked windows
# --------------------------------------------------------------------------------------------


def test_regressors_and_windows_are_zero_before_t1():
    x1 = [0.3, -0.7]
    for form in FORMS:
        est = make_estimator("O-MILS", 2, p=4, form=form, x_init=x1, theta0=np.zeros(4))
        est.update(2.0)
        np.testing.assert_array_equal(est.phi, np.zeros(4))  # phi_hat(1) = 0
        np.testing.assert_array_equal(est.Phi, np.zeros((4, 4)))
        np.testing.assert_array_equal(est.innovation, [2.0, 0.0, 0.0, 0.0])
        assert est.e == 2.0
        est.predict(1.5)
        est.update(-1.0)
        Phi = est.Phi
        if form == "observer":  # [-x1(1), -x1(0), u(1), u(0)]
            np.testing.assert_array_equal(Phi[:, 0], [-0.3, 0.0, 1.5, 0.0])
        else:  # [-x2(0), -x1(0), u(1), u(0)]: x(t - n) = x(0) = 0
            np.testing.assert_array_equal(Phi[:, 0], [0.0, 0.0, 1.5, 0.0])
        np.testing.assert_array_equal(Phi[:, 1:], np.zeros((4, 3)))
        est.predict(0.5)
        est.update(0.0)
        if form == "observability":  # t = 3: [-x2(1), -x1(1), u(2), u(1)]
            np.testing.assert_array_equal(est.phi, [0.7, -0.3, 0.5, 1.5])
        assert np.count_nonzero(est.Phi[:, 3]) == 0  # phi_hat(0)


@pytest.mark.parametrize("form", FORMS)
def test_open_loop_observer_with_true_parameters_reproduces_the_plant(form):
    """With theta frozen at the truth, (46) is the plant itself: x_hat(t) = x(t)."""
    rng = np.random.default_rng(1)
    u = rng.standard_normal(60)
    X, y = simulate(A_TRUE, B_TRUE, form, u)
    est = make_estimator("O-RLS", 2, form=form, theta0=THETA_TRUE, x_init=[0.0, 0.0])
    est.enabled = False
    for k in range(60):
        est.update(y[k])
        np.testing.assert_allclose(est.x_hat, X[:, k], atol=1e-12)
        assert est.e == pytest.approx(y[k] - est.phi @ THETA_TRUE)
        est.predict(u[k])
    np.testing.assert_array_equal(est.theta, THETA_TRUE)


@pytest.mark.parametrize("form", FORMS)
def test_kalman_filter_matches_a_textbook_filter(form):
    """(66)-(68) with Q, R against a filter written out here with numpy (frozen parameters)."""
    rng = np.random.default_rng(2)
    u = rng.standard_normal(40)
    X, y = simulate(A_TRUE, B_TRUE, form, u, noise_std=0.3, seed=2)
    Q = np.array([[0.02, 0.01], [0.01, 0.03]])
    R = 0.5
    est = make_estimator(
        "KF-RLS",
        2,
        form=form,
        theta0=THETA_TRUE,
        x_init=[1.0, -1.0],
        P1_init=[2.0, 3.0],
        process_noise=Q,
        measurement_noise=R,
    )
    est.enabled = False
    A, B, C, _ = canonical_matrices(A_TRUE, B_TRUE, form)
    x, P = np.array([1.0, -1.0]), np.diag([2.0, 3.0])
    for k in range(40):
        est.update(y[k])
        # predictor form: gain K = A P C^T (C P C^T + R)^-1
        S = (C @ P @ C.T).item() + R
        K = (A @ P @ C.T).ravel() / S
        x = A @ x + B.ravel() * u[k] + K * (y[k] - (C @ x).item())
        P = A @ P @ A.T - np.outer(K, K) * S + Q
        np.testing.assert_allclose(est.predict(u[k]), x, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(est.P1, P, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(est.L1, K, rtol=1e-10, atol=1e-12)


def test_paper_kalman_gain_dies_out_and_process_noise_keeps_it():
    rng = np.random.default_rng(3)
    u = rng.standard_normal(300)
    _, y = simulate(A_TRUE, B_TRUE, "observer", u, noise_std=0.1)
    paper = make_estimator("KF-RLS", 2)
    paper.run(u[:50], y[:50])
    assert np.linalg.norm(paper.L1) < 1e-8
    noisy = make_estimator("KF-RLS", 2, process_noise=0.01)
    noisy.run(u, y)
    assert np.linalg.norm(noisy.L1) > 1e-2
    # Q set after construction (the controller's adaptive process noise) takes effect too.
    late = make_estimator("KF-RLS", 2)
    late.Q = 0.01 * np.eye(2)
    np.testing.assert_array_equal(
        late.run(u, y), make_estimator("KF-RLS", 2, process_noise=0.01).run(u, y)
    )
    with pytest.raises(ValueError, match="Q"):
        late.Q = np.eye(3)


def test_closed_loop_observer_deadbeat_gain_recovers_the_state():
    """Observer form, K = -a: A - K c is nilpotent, so x_hat(t) = x(t) for t > n (no noise)."""
    rng = np.random.default_rng(4)
    u = rng.standard_normal(30)
    X, y = simulate(A_TRUE, B_TRUE, "observer", u)
    for gain in (-A_TRUE, lambda a, b: -a):
        est = make_estimator("CO-RLS", 2, theta0=THETA_TRUE, x_init=[5.0, -5.0], observer_gain=gain)
        est.enabled = False
        xs = []
        for k in range(30):
            est.update(y[k])
            xs.append(est.predict(u[k]))
        np.testing.assert_allclose(np.array(xs)[2:].T, X[:, 3:31], atol=1e-12)
        assert abs(xs[0][0] - X[0, 1]) > 1.0  # and the plain open-loop observer would not


# --------------------------------------------------------------------------------------------
# Convergence on simulated open-loop data
# --------------------------------------------------------------------------------------------
#
# Plant A_TRUE/B_TRUE (poles 0.3 +- 0.33i), unit white input, output noise std 0.1, p = 5 for
# MISG/MILS, t = 3000. With the paper's p0 = 1e6 the RLS/MILS family freezes on roughly one run
# in four (an early unstable A_hat makes the open-loop observer's x_hat huge, which collapses P
# before theta is right) and D-RLS/D-MILS overshoot (each half absorbs the whole innovation while
# P is huge), see the report; with p0 = 10 every algorithm converges on every seed we tried. The
# bounds below are about 1.5x the worst error over 20 seeds (p0 = 10), checked here on 3 seeds.
# SG-type rules have a step ~ 1/t and are still far from the truth at t = 3000 (the paper's
# known slow convergence); D- rules converge slowly in the observer form, where phi_a(t) =
# -x1(t-1..t-n) is correlated with psi(t), but not in the observability form, where
# phi_a(t) = -x(t-n) is uncorrelated with psi(t) = u(t-1..t-n) for a white input.

P0_PRACTICAL = 10.0
SEEDS = (0, 1, 2)
BOUNDS = {
    "observer": {
        "SG": 0.40,
        "MISG": 0.12,
        "RLS": 0.04,
        "MILS": 0.05,
        "D-SG": 0.32,
        "D-MISG": 0.05,
        "D-RLS": 0.25,
        "D-MILS": 0.25,
    },
    "observability": {
        "SG": 0.60,
        "MISG": 0.15,
        "RLS": 0.03,
        "MILS": 0.04,
        "D-SG": 0.50,
        "D-MISG": 0.05,
        "D-RLS": 0.10,
        "D-MILS": 0.05,
    },
}


@pytest.fixture(scope="module")
def open_loop_data():
    """``{(form, seed): (u, y)}``, 3000 samples each."""
    data = {}
    for seed in SEEDS:
        u = np.random.default_rng(seed).standard_normal(3000)
        for form in FORMS:
            data[form, seed] = (u, simulate(A_TRUE, B_TRUE, form, u, 0.1, seed=seed)[1])
    return data


@pytest.fixture(scope="module")
def final_errors(open_loop_data):
    """``{(name, form): [error at t = 3000 per seed]}`` with p0 = 10."""
    errs = {}
    for (form, _seed), (u, y) in open_loop_data.items():
        for name in ALGORITHMS:
            est = make_estimator(name, 2, p=5 if "MI" in name else 1, form=form, p0=P0_PRACTICAL)
            errs.setdefault((name, form), []).append(rel_err(est.run(u, y)[-1]))
            assert est.n_resets == 0 and est.health["n_state_resets"] == 0
    return {k: np.array(v) for k, v in errs.items()}


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("name", ALGORITHMS)
def test_convergence_by_t3000(final_errors, name, form):
    err = final_errors[name, form]
    assert err.max() < BOUNDS[form][name.split("-", 1)[1]], err


def test_misg_beats_sg_at_equal_data(final_errors):
    """The paper's claim: p = 5 innovations give a smaller error on every seed, and a clearly
    smaller one in the median."""
    for form in FORMS:
        for d in ("", "D-"):
            for s in ("O", "KF"):
                sg, misg = final_errors[f"{s}-{d}SG", form], final_errors[f"{s}-{d}MISG", form]
                assert np.all(misg < sg), (form, d, s, sg, misg)
                assert np.median(misg) < 0.6 * np.median(sg), (form, d, s, sg, misg)


def test_mils_versus_rls_is_measured(final_errors, record_property):
    """The paper: MILS improves on RLS only very little. Measured, not assumed (medians over 20
    seeds are in the report: MILS is not better, 10-20 % worse at t = 3000, ~50 % worse at
    t = 100). Here only "same order of magnitude" is asserted; the ratios are recorded."""
    for form in FORMS:
        for d in ("", "D-"):
            r = np.median(final_errors[f"O-{d}RLS", form])
            m = np.median(final_errors[f"O-{d}MILS", form])
            record_property(f"{form} {d}MILS/{d}RLS error ratio", round(float(m / r), 3))
            assert 0.2 < m / r < 5.0, (form, d, r, m)


def test_paper_defaults_for_the_gradient_rules(open_loop_data):
    """p0 = 1e6 (the paper) only sets theta(0), x_hat(1) for SG/MISG: same bounds as above.
    (RLS/MILS with p0 = 1e6 freeze on a sizeable fraction of seeds, so no bound is claimed.)"""
    for name in ("O-MISG", "KF-SG", "O-D-MISG"):
        for seed in SEEDS:
            u, y = open_loop_data["observer", seed]
            est = make_estimator(name, 2, p=5 if "MI" in name else 1)
            assert rel_err(est.run(u, y)[-1]) < BOUNDS["observer"][name.split("-", 1)[1]]


def test_d_rls_with_a_huge_p0_double_counts_the_innovation():
    """Why D-RLS misbehaves with p0 = 1e6: on the first informative step each half (a and b)
    explains the whole innovation, so the new prediction error is -e(t) instead of ~0."""
    for name, residual in (("O-D-RLS", -3.0), ("O-RLS", 0.0)):
        est = make_estimator(name, 1, theta0=[0.0, 0.0], x_init=[-2.0])
        est.update(7.0)
        est.predict(1.0)
        theta = est.update(3.0)  # phi(2) = [2, 1], e(2) = 3
        assert 3.0 - est.phi @ theta == pytest.approx(residual, abs=1e-5)


def test_forgetting_tracks_a_parameter_jump():
    rng = np.random.default_rng(10)
    u = rng.standard_normal(1200)
    theta2 = np.array([-0.3, 0.1, 0.8, 0.6])
    _, y1 = simulate(A_TRUE, B_TRUE, "observer", u, 0.05, seed=10)
    _, y2 = simulate(theta2[:2], theta2[2:], "observer", u, 0.05, seed=11)
    y = np.r_[y1[:600], y2[600:]]  # plant changes at t = 601 (states re-simulated: fine here)
    errs = {}
    for lam in (1.0, 0.97):
        est = make_estimator("O-RLS", 2, forgetting=lam)
        errs[lam] = rel_err(est.run(u, y)[-1], theta2)
    assert errs[0.97] < 0.05 < errs[1.0]


# --------------------------------------------------------------------------------------------
# MATLAB-style options: P0 forms, enable flag, reset, readable innovation/covariance
# --------------------------------------------------------------------------------------------


def test_initial_covariance_as_scalar_vector_or_matrix():
    M = np.array([[2.0, 0.5, 0, 0], [0.5, 3.0, 0, 0], [0, 0, 4.0, 0.1], [0, 0, 0.1, 5.0]])
    for P0, expected in ((7.0, 7.0 * np.eye(4)), ([1, 2, 3, 4], np.diag([1.0, 2, 3, 4])), (M, M)):
        for name in ("O-RLS", "KF-D-MILS"):
            est = make_estimator(name, 2, p=2, P0=P0) if "MILS" in name else None
            est = est or make_estimator(name, 2, P0=P0)
            expected_blocks = expected.copy()
            if "D-" in name:  # D- rules: P0 must be block-diagonal (M is)
                expected_blocks[:2, 2:] = expected_blocks[2:, :2] = 0.0
            np.testing.assert_allclose(est.P, expected_blocks, rtol=1e-14, atol=1e-14)


def test_enable_flag_freezes_parameters_but_tracks_the_state(open_loop_data):
    u, y = open_loop_data["observer", 0]
    est = make_estimator("KF-MILS", 2, p=3)
    est.run(u[:500], y[:500])
    theta, P = est.theta, est.P
    est.enabled = False
    x_prev = est.x_hat
    for k in range(500, 520):
        np.testing.assert_array_equal(est.update(y[k]), theta)
        assert est.innovation.shape == (3,)
        x_new = est.predict(u[k])
        assert not np.array_equal(x_new, x_prev)
        x_prev = x_new
    np.testing.assert_array_equal(est.P, P)
    est.enabled = True
    est.update(y[520])
    assert not np.array_equal(est.theta, theta)


def test_reset_restarts_from_the_initial_conditions(open_loop_data):
    u, y = open_loop_data["observability", 0]
    est = make_estimator("KF-D-RLS", 2, form="observability")
    first = est.run(u[:300], y[:300])
    est.reset()
    assert est.t == 0
    np.testing.assert_array_equal(est.run(u[:300], y[:300]), first)


def test_run_equals_the_step_loop_and_continues(open_loop_data):
    u, y = open_loop_data["observer", 0]
    a, b = make_estimator("O-D-MISG", 2, p=4), make_estimator("O-D-MISG", 2, p=4)
    out = np.vstack([a.run(u[:100], y[:100]), a.run(u[100:200], y[100:200])])
    assert out.shape == (200, 4) and a.t == 200
    for k in range(200):
        np.testing.assert_array_equal(b.update(y[k]), out[k])
        b.predict(u[k])


# --------------------------------------------------------------------------------------------
# Numerical health
# --------------------------------------------------------------------------------------------


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
def test_covariance_overflow_is_reset_with_a_warning():
    # lambda = 0.5 and no excitation: P doubles every step and overflows near t = 1000.
    est = make_estimator("O-RLS", 1, forgetting=0.5, theta0=[0.1, 0.2])
    with pytest.warns(RuntimeWarning, match="P reset to P"):
        thetas = est.run(np.zeros(1100), np.zeros(1100))
    assert est.n_resets >= 1 and "t=" in est.health["last_event"]
    assert np.all(np.isfinite(thetas)) and np.all(np.isfinite(est.P))
    strict = make_estimator("O-MILS", 1, p=2, forgetting=0.5, on_failure="raise")
    with pytest.raises(NumericalHealthError, match="O-MILS at t="):
        strict.run(np.zeros(1100), np.zeros(1100))


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
def test_state_overflow_is_reset_with_a_warning():
    est = make_estimator("O-SG", 1, theta0=[-3.0, 0.0], x_init=[1.0])
    est.enabled = False  # unstable frozen model: x_hat grows like 3^t
    with pytest.warns(RuntimeWarning, match="x_hat.t.1. is not finite"):
        est.run(np.zeros(700), np.zeros(700))
    assert est.health["n_state_resets"] >= 1 and np.all(np.isfinite(est.x_hat))


def test_lost_positive_definiteness_is_detected():
    est = make_estimator("O-RLS", 2, on_failure="raise", pd_check_every=1)
    est._field("S")[0, :, 3] = 0.0  # corrupt the factor of P: singular
    before = [field.copy() for field in est.state]
    with pytest.raises(NumericalHealthError, match="not symmetric positive definite"):
        est.update(1.0)
    for field, saved in zip(est.state, before, strict=True):  # left exactly as before the call
        np.testing.assert_array_equal(field, saved)
    lenient = make_estimator("O-RLS", 2, pd_check_every=1)
    lenient._field("S")[0, :, 3] = 0.0
    with pytest.warns(RuntimeWarning, match="P reset to P"):
        lenient.update(1.0)
    np.testing.assert_allclose(lenient.P, 1e6 * np.eye(4), rtol=1e-14)


def test_project_stable_keeps_every_a_hat_stable(open_loop_data):
    u, y = open_loop_data["observer", 0]
    est = make_estimator("O-RLS", 2, project_stable=True)
    for k in range(400):
        th = est.update(y[k])
        assert np.all(np.abs(np.roots(np.r_[1.0, th[:2]])) < 1.0)
        est.predict(u[k])
    assert rel_err(est.theta) < 0.1


# --------------------------------------------------------------------------------------------
# Flops: tables 1-4 typed in from the paper
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 2, 3, 5, 8])
@pytest.mark.parametrize("p", [1, 2, 4, 7])
def test_flops_equal_tables_1_to_4(n, p):
    assert make_estimator("O-RLS", n).flops_per_step == 16 * n**2 + 16 * n - 1
    kf_mils = make_estimator("KF-MILS", n, p=p).flops_per_step
    assert kf_mils == (
        16 * n**2 * p + 8 * n * p**2 + 4 * n * p + 2 * p**3 - 2 * p**2 + p + 4 * n**2 + 10 * n - 1
    )
    for s in ("O", "KF"):
        assert make_estimator(f"{s}-D-RLS", n).flops_parameters == 8 * n**2 + 12 * n
        d_mils = make_estimator(f"{s}-D-MILS", n, p=p).flops_parameters
        assert d_mils == 8 * n**2 * p + 8 * n * p**2 + 4 * p**3 + 4 * n * p - 4 * p**2
    o = make_estimator("O-D-RLS", n)
    assert o.flops_per_step == o.flops_parameters + 4 * n - 1  # + open-loop observer (table 1)


def test_documented_flops_are_consistent():
    for n in range(1, 6):
        assert flops.misg(n, 1) == flops.sg(n) and flops.d_misg(n, 1) == flops.d_sg(n)
        assert flops.mils(n, 1) == flops.rls(n) + 1
        for p in range(1, 5):
            assert sum(variant("KF-MILS").flops(n, p)) == flops.kf_mils(n, p)
            for name in ALGORITHMS:
                est = make_estimator(name, n, p=p if "MI" in name else 1)
                assert est.flops_per_step == sum(variant(name).flops(n, p))
                assert est.flops_per_step == est.flops_parameters + est.flops_state


# --------------------------------------------------------------------------------------------
# Misc
# --------------------------------------------------------------------------------------------


def test_is_schur_stable_against_roots():
    rng = np.random.default_rng(11)
    for _ in range(500):
        a = rng.normal(size=rng.integers(1, 6)) * rng.choice([0.3, 1.0, 2.0])
        assert is_schur_stable(a) == bool(np.all(np.abs(np.roots(np.r_[1.0, a])) < 1.0))
    assert not is_schur_stable([math.nan])


def test_repr_and_type():
    est = make_estimator("kf-d-mils", 2, p=3)
    assert isinstance(est, RecursiveEstimator)
    assert "KF-D-MILS" in repr(est) and "p=3" in repr(est)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        est.update(1.0)
        est.predict(0.0)
