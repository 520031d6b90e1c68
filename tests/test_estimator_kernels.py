"""The compiled estimator lane functions against the dense-numpy reference of the paper's
formulas (stcgym.adaptive.estimation.reference), single versus batched lanes, and the lifecycle of
the one estimator class (pickle, deepcopy, failed calls, bad batched input)."""

from __future__ import annotations

import copy
import pickle
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from lane_call import call

from stcgym.adaptive import NumericalHealthError, RecursiveEstimator, make_estimator
from stcgym.adaptive.estimation.estimator_lanes import predict_lanes, update_lanes
from stcgym.adaptive.estimation.estimator_spec import ALGORITHMS, EstimatorSpec
from stcgym.adaptive.estimation.least_squares import (
    OK,
    carlson_update,
    least_squares_step,
    least_squares_work,
    rank_one_update,
    upper_factor,
)
from stcgym.adaptive.estimation.reference import ReferenceEstimator
from stcgym.adaptive.estimation.state_estimation import kalman_step
from stcgym.adaptive.kernels.canonical import companion_into
from stcgym.envs.canonical import canonical_matrices, companion_A
from stcgym.lanes.compiled import set_lanes

FORMS = ("observer", "observability")
A_TRUE, B_TRUE = np.array([-0.6, 0.2]), np.array([0.5, 1.0])
#: Kernels vs the dense reference: relative agreement of theta, x_hat and P over 200 steps
#: with p0 = 100 (the explicit-P reference itself loses digits with p0 = 1e6).
REF_RTOL = 1e-9


def data(T=200, seed=0, form="observer", noise=0.1):
    rng = np.random.default_rng(seed)
    u = rng.standard_normal(T)
    A, B, _, _ = canonical_matrices(A_TRUE, B_TRUE, form)
    x = np.zeros(2)
    y = np.empty(T)
    for k in range(T):
        y[k] = x[0] + noise * rng.standard_normal()
        x = A @ x + B[:, 0] * u[k]
    return u, y


def spd(rng, d):
    M = rng.standard_normal((d, d))
    return M @ M.T + 0.5 * np.eye(d)


# --------------------------------------------------------------------------------------------
# Building blocks
# --------------------------------------------------------------------------------------------


@settings(max_examples=40, deadline=None, derandomize=True)
@given(d=st.integers(1, 8), seed=st.integers(0, 2**31 - 1), lam=st.sampled_from([1.0, 0.9]))
def test_carlson_update_is_the_rls_covariance_update(d, seed, lam):
    rng = np.random.default_rng(seed)
    P = spd(rng, d)
    S = np.zeros((d, d))
    assert upper_factor(P, S)
    np.testing.assert_allclose(S @ S.T, P, rtol=1e-12, atol=1e-12)
    assert np.all(np.tril(S, -1) == 0.0)
    phi = rng.standard_normal(d)
    Kv = np.zeros(d)
    alpha = call(carlson_update, S, 0, d, phi, lam, Kv)
    s = lam + phi @ P @ phi
    assert alpha == pytest.approx(s, rel=1e-12)
    np.testing.assert_allclose(Kv, P @ phi, rtol=1e-10, atol=1e-12)
    expected = P - np.outer(P @ phi, P @ phi) / s  # (34) before the division by lambda
    np.testing.assert_allclose(S @ S.T, expected, rtol=1e-9, atol=1e-11)
    assert np.all(np.tril(S, -1) == 0.0) and np.all(np.diag(S) > 0.0)
    v = rng.standard_normal(d)
    before = S @ S.T
    call(rank_one_update, S, 0, d, v.copy())
    np.testing.assert_allclose(S @ S.T, before + np.outer(v, v), rtol=1e-9, atol=1e-11)
    assert np.all(np.tril(S, -1) == 0.0)


def test_upper_factor_rejects_indefinite_matrices():
    S = np.zeros((2, 2))
    assert not upper_factor(np.array([[1.0, 2.0], [2.0, 1.0]]), S)
    assert not upper_factor(np.array([[1.0, 0.0], [0.0, np.nan]]), S)


@pytest.mark.parametrize("p", [1, 3])
def test_generic_least_squares_step_against_the_dense_formulas(p):
    """The grey-box interface: RLS (33)-(35) / MILS (39)-(41) on user regressors."""
    rng = np.random.default_rng(p)
    d, lam = 5, 0.97
    P = 10.0 * np.eye(d)
    S = np.zeros((d, d))
    upper_factor(P, S)
    theta = rng.standard_normal(d)
    theta_ref = theta.copy()
    work = least_squares_work(d, p)
    for _ in range(50):
        Phi, Y = rng.standard_normal((p, d)), rng.standard_normal(p)
        assert call(least_squares_step, theta, S, Phi, Y, lam, work, 0) == OK
        E = Y - Phi @ theta_ref
        L = P @ Phi.T @ np.linalg.inv(lam * np.eye(p) + Phi @ P @ Phi.T)
        P = (P - L @ Phi @ P) / lam
        theta_ref = theta_ref + L @ E
        np.testing.assert_allclose(work.E[0], E, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(theta, theta_ref, rtol=1e-9)
    np.testing.assert_allclose(S @ S.T, P, rtol=1e-8, atol=1e-14)


@pytest.mark.parametrize("form", FORMS)
def test_kalman_step_matches_a_textbook_filter(form):
    """(66)-(68) with Q and R, on the canonical model built by companion_into."""
    rng = np.random.default_rng(3)
    n = 3
    theta = np.r_[0.2, -0.1, 0.05, rng.standard_normal(n)]
    A = np.zeros((n, n))
    call(companion_into, theta, n, form == "observability", A)
    np.testing.assert_array_equal(A, companion_A(theta[:n], form))
    P1 = np.eye(n)
    Q = 0.01 * np.eye(n)
    R = 0.5
    x = rng.standard_normal(n)
    x_ref, P_ref = x.copy(), P1.copy()
    x_next, L1, AP, P_upd = np.zeros(n), np.zeros(n), np.zeros((n, n)), np.zeros((n, n))
    C = np.eye(n)[:1]
    for _ in range(20):
        u, y = rng.standard_normal(2)
        assert kalman_step(A, theta[n:], P1, Q, R, x, u, y, x_next, L1, AP, P_upd) == 0
        S = (C @ P_ref @ C.T).item() + R
        Kg = (A @ P_ref @ C.T).ravel() / S
        x_ref = A @ x_ref + theta[n:] * u + Kg * (y - x_ref[0])
        P_ref = A @ P_ref @ A.T - np.outer(Kg, Kg) * S + Q
        x = x_next.copy()
        np.testing.assert_allclose(x, x_ref, rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(P1, P_ref, rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(L1, Kg, rtol=1e-12)


# --------------------------------------------------------------------------------------------
# Every algorithm against the dense reference
# --------------------------------------------------------------------------------------------

NAMES = [*ALGORITHMS, "CO-RLS", "CO-D-MISG"]


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("name", NAMES)
def test_kernels_equal_the_dense_reference(name, form):
    u, y = data(form=form)
    mi = "MI" in name
    kw: dict = {"p": 3} if mi else {}
    if name.startswith("CO"):
        kw["observer_gain"] = [0.3, -0.1]
    lam = 0.98 if "RLS" in name else 1.0
    if name.startswith("KF"):
        kw |= {"process_noise": 0.01, "measurement_noise": 0.5}
    est = make_estimator(name, 2, p0=100.0, form=form, forgetting=lam, **kw)
    ref = ReferenceEstimator(
        EstimatorSpec.build(name, 2, p0=100.0, form=form, forgetting=lam, **kw)
    )
    for k in range(len(u)):
        th = est.update(y[k])
        th_ref = ref.update(y[k])
        np.testing.assert_allclose(th, th_ref, rtol=REF_RTOL, atol=1e-12)
        np.testing.assert_allclose(est.innovation, ref.E, rtol=REF_RTOL, atol=1e-11)
        np.testing.assert_allclose(est.predict(u[k]), ref.predict(u[k]), rtol=REF_RTOL, atol=1e-12)
    np.testing.assert_allclose(est.phi, ref.Phi[:, 0], rtol=REF_RTOL, atol=1e-12)
    if est.P is not None:
        np.testing.assert_allclose(est.P, ref.P, rtol=1e-8, atol=1e-12)
    if name.startswith("KF"):
        np.testing.assert_allclose(est.P1, ref.P1, rtol=REF_RTOL, atol=1e-12)


# --------------------------------------------------------------------------------------------
# The closed-loop regressor option (regressor="filtered")
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("name", ["O-RLS", "KF-MILS", "O-D-SG", "KF-D-RLS", "O-MISG"])
def test_filtered_regressor_equals_the_dense_reference(name, form):
    u, y = data(form=form)
    kw: dict = {"p": 3} if "MI" in name else {}
    if name.startswith("KF"):
        kw |= {"process_noise": 0.01, "measurement_noise": 0.5}
    est = make_estimator(name, 2, p0=100.0, form=form, regressor="filtered", **kw)
    ref = ReferenceEstimator(
        EstimatorSpec.build(name, 2, p0=100.0, form=form, regressor="filtered", **kw)
    )
    paper = ReferenceEstimator(EstimatorSpec.build(name, 2, p0=100.0, form=form, **kw))
    for k in range(len(u)):
        th, th_ref, th_paper = est.update(y[k]), ref.update(y[k]), paper.update(y[k])
        np.testing.assert_allclose(th, th_ref, rtol=REF_RTOL, atol=1e-12)
        np.testing.assert_allclose(est.predict(u[k]), ref.predict(u[k]), rtol=REF_RTOL, atol=1e-12)
        paper.predict(u[k])
    np.testing.assert_allclose(est.phi, ref.Phi[:, 0], rtol=REF_RTOL, atol=1e-12)
    # the option changes the algorithm: the paper's regressor gives other estimates
    assert np.max(np.abs(th_ref - th_paper)) > 1e-6


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("name", ["O-RLS", "O-MISG", "O-D-MILS"])
def test_partial_injection_equals_the_dense_reference(name, form):
    u, y = data(form=form)
    kw: dict = {"p": 3} if "MI" in name else {}
    opts = {"injection": 0.4, "injection_warmup": 10}
    est = make_estimator(name, 2, p0=100.0, form=form, regressor="filtered", **opts, **kw)
    filtered = {"p0": 100.0, "form": form, "regressor": "filtered"}
    ref = ReferenceEstimator(EstimatorSpec.build(name, 2, **filtered, **opts, **kw))
    whole = ReferenceEstimator(EstimatorSpec.build(name, 2, **filtered, **kw))
    for k in range(len(u)):
        th, th_ref, th_whole = est.update(y[k]), ref.update(y[k]), whole.update(y[k])
        np.testing.assert_allclose(th, th_ref, rtol=REF_RTOL, atol=1e-12)
        np.testing.assert_allclose(est.predict(u[k]), ref.predict(u[k]), rtol=REF_RTOL, atol=1e-12)
        whole.predict(u[k])
        if k < 10:  # the warm-up: the whole injection
            np.testing.assert_allclose(th_ref, th_whole, rtol=1e-12, atol=1e-14)
    assert np.max(np.abs(th_ref - th_whole)) > 1e-6


@pytest.mark.parametrize(("injection", "bounded"), [(0.4, True), (0.1, False)])
def test_partial_injection_error_dynamics_shrink_the_characteristic_polynomial(injection, bounded):
    """Observer form, a fixed unstable model (poles 1.2, 1.1): the observer error dynamics
    ``A (I - injection g c)`` have the characteristic polynomial
    ``z^2 + (1 - injection)(a_1 z + a_2)``, stable for 0.4 (poles of magnitude 0.89), unstable
    for 0.1 (1.09)."""
    a = np.array([-2.3, 1.32])
    radius = np.max(np.abs(np.roots(np.r_[1.0, (1.0 - injection) * a])))
    assert (radius < 1.0) == bounded
    kw = {"theta0": np.r_[a, 0.5, 0.2], "enabled": False, "regressor": "filtered"}
    est = make_estimator("O-RLS", 2, injection=injection, **kw)
    u, y = data(T=300, seed=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for k in range(len(u)):
            est.update(y[k])
            est.predict(u[k])
    grew = np.max(np.abs(est.x_hat)) > 1e6 or est.health["n_state_resets"] > 0
    assert grew != bounded


def test_filtered_open_loop_observer_is_least_squares_on_measured_outputs():
    """Observer form, ``g = c^T``: ``phi_hat(t) = [-y(t-1), -y(t-2), u(t-1), u(t-2)]``, so
    O-RLS with ``P(0) = p0 I`` is regularised batch least squares on input-output data."""
    u, y = data(T=300, seed=3, noise=0.05)
    p0 = 1e3
    est = make_estimator("O-RLS", 2, p0=p0, theta0=np.zeros(4), regressor="filtered")
    th = est.run(u, y)[-1]
    yp = np.r_[0.0, 0.0, y]
    up = np.r_[0.0, 0.0, u]
    H = np.column_stack([-yp[1:-1], -yp[:-2], up[1:-1], up[:-2]])  # rows t = 1..T
    theta_ls = np.linalg.solve(H.T @ H + np.eye(4) / p0, H.T @ y)
    np.testing.assert_allclose(th, theta_ls, rtol=1e-8, atol=1e-10)
    # and it is close to the plant (white noise on y; a small equation-error bias only)
    np.testing.assert_allclose(th, np.r_[A_TRUE, B_TRUE], atol=0.05)


@pytest.mark.parametrize("form", FORMS)
def test_filtered_open_loop_observer_is_deadbeat_on_an_unstable_model(form):
    """The paper's open-loop observer of an unstable model diverges whatever the data; the
    output injection of ``regressor="filtered"`` keeps the state estimate bounded (in the
    observability form too, where ``g = c^T`` would leave the eigenvalue ``-a_1 = 2.3``)."""
    a_unstable = np.array([-2.3, 1.32])  # poles 1.2, 1.1
    kw = {"theta0": np.r_[a_unstable, 0.5, 0.2], "enabled": False, "form": form}  # fixed model
    paper = make_estimator("O-RLS", 2, **kw)
    filt = make_estimator("O-RLS", 2, regressor="filtered", **kw)
    u, y = data(T=200, seed=1, form=form)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for k in range(len(u)):
            for e in (paper, filt):
                e.update(y[k])
                e.predict(u[k])
    assert np.max(np.abs(paper.x_hat)) > 1e6 or paper.health["n_state_resets"] > 0
    assert np.max(np.abs(filt.x_hat)) < 100.0


def test_filtered_regressor_is_validated():
    with pytest.raises(ValueError, match="regressor must be one of"):
        make_estimator("KF-RLS", 2, regressor="smoothed")
    with pytest.raises(ValueError, match="closed-loop observer"):
        make_estimator("CO-RLS", 2, observer_gain=[0.1, 0.0], regressor="filtered")
    with pytest.raises(ValueError, match="injection and injection_warmup apply to the open-loop"):
        make_estimator("KF-RLS", 2, regressor="filtered", injection=0.5)
    with pytest.raises(ValueError, match="injection and injection_warmup apply to the open-loop"):
        make_estimator("O-RLS", 2, injection_warmup=5)  # the paper's regressor
    with pytest.raises(ValueError, match=r"injection must lie in \[0, 1\]"):
        make_estimator("O-RLS", 2, regressor="filtered", injection=-0.1)
    with pytest.raises(ValueError, match="injection_warmup"):
        make_estimator("O-RLS", 2, regressor="filtered", injection_warmup=-1)


# --------------------------------------------------------------------------------------------
# A single estimator is its lane of a batch, bit for bit (same compiled code on both sides)
# --------------------------------------------------------------------------------------------


@pytest.mark.equality
@pytest.mark.parametrize(
    ("name", "kw"),
    [
        ("O-RLS", {}),
        ("KF-MILS", {"p": 5, "process_noise": 1e-3}),
        ("KF-D-MISG", {"p": 2, "form": "observability"}),
        ("O-D-RLS", {"window": 20, "p0": 50.0}),
        ("O-MILS", {"p": 2, "project_stable": True}),
    ],
)
def test_single_estimator_equals_its_lane_bit_for_bit(name, kw):
    B, T = 5, 150
    rng = np.random.default_rng(7)
    U = rng.standard_normal((T, B))
    Y = rng.standard_normal((T, B))
    batch = make_estimator(name, 2, num_envs=B, **kw)
    assert isinstance(batch, RecursiveEstimator)
    singles = [make_estimator(name, 2, **kw) for _ in range(B)]
    for k in range(T):
        th = batch.update(Y[k])
        for i, s in enumerate(singles):
            np.testing.assert_array_equal(s.update(Y[k, i]), th[i])
        x = batch.predict(U[k])
        for i, s in enumerate(singles):
            np.testing.assert_array_equal(s.predict(U[k, i]), x[i])
    for i, s in enumerate(singles):
        for single_field, batch_field in zip(s.state, batch.state, strict=True):
            np.testing.assert_array_equal(single_field[0], batch_field[i])
    # and run() (a compiled T-step loop) is the same lane function again
    again = make_estimator(name, 2, **kw)
    np.testing.assert_array_equal(again.run(U[:, 0], Y[:, 0])[-1], singles[0].theta)


def test_batched_lanes_have_their_own_initial_values():
    theta0 = np.array([[0.1, 0.2, 0.3, 0.4], [0.0, 0.0, 1.0, 1.0]])
    P0 = np.array([np.eye(4), 3 * np.eye(4)])
    est = make_estimator("O-RLS", 2, num_envs=2, theta0=theta0, P0=P0)
    np.testing.assert_array_equal(est.theta, theta0)
    np.testing.assert_allclose(est.P, P0, rtol=1e-14)
    est.update([1.0, 2.0])
    est.predict([0.5, 0.5])
    est.reset(lanes=[1])
    np.testing.assert_array_equal(est.theta[1], theta0[1])
    assert est.t.tolist() == [1, 0]


# --------------------------------------------------------------------------------------------
# Lifecycle: pickle / deepcopy, failed calls, bad batched input, unknown keywords
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("num_envs", [None, 3])
@pytest.mark.parametrize("name", ["KF-MILS", "O-D-SG"])
def test_pickle_and_deepcopy_continue_identically(name, num_envs):
    u, y = data(T=60)
    p = 3 if "MI" in name else 1
    est = make_estimator(name, 2, p=p, num_envs=num_envs)
    B = 1 if num_envs is None else num_envs

    def step(e, k):
        yk = y[k] if num_envs is None else np.full(B, y[k])
        uk = u[k] if num_envs is None else np.full(B, u[k])
        th = e.update(yk)
        e.predict(uk)
        return th

    for k in range(30):
        step(est, k)
    clones = [pickle.loads(pickle.dumps(est)), copy.deepcopy(est)]
    for c in clones:
        assert type(c) is RecursiveEstimator and c.num_envs == num_envs
    for k in range(30, 60):
        th = step(est, k)
        for c in clones:
            np.testing.assert_array_equal(step(c, k), th)
    for c in clones:
        assert_same_state(c, est)


def assert_same_state(a, b):
    """Every field of two estimators' lane states is equal (bit for bit)."""
    for x, y in zip(a.state, b.state, strict=True):
        np.testing.assert_array_equal(x, y)


def test_a_rejected_or_failed_call_leaves_the_estimator_unchanged():
    est = make_estimator("KF-MILS", 2, p=3, on_failure="raise")
    u, y = data(T=20)
    est.run(u, y)
    before = copy.deepcopy(est)
    for bad, error in ((np.nan, ValueError), ("a", TypeError), ([1.0, 2.0], TypeError)):
        with pytest.raises(error, match=r"y\(t\) must be a finite real number"):
            est.update(bad)
    assert_same_state(est, before)
    est._field("S")[0, 1, 1] = 0.0  # corrupt: rank lost
    corrupted = copy.deepcopy(est)
    with pytest.raises(NumericalHealthError):
        est.update(1.0)
    assert_same_state(est, corrupted)
    with pytest.raises(NumericalHealthError):  # run() is all-or-nothing too
        est.run(u, y)
    assert_same_state(est, corrupted)


def test_batched_bad_input_names_the_argument():
    est = make_estimator("O-RLS", 2, num_envs=4)
    with pytest.raises(ValueError, match=r"y\(t\) must have shape \(4,\)"):
        est.update(np.ones(3))
    est.update(np.ones(4))
    with pytest.raises(ValueError, match=r"u\(t\) must have shape \(4,\)"):
        est.predict(np.ones(5))
    with pytest.raises(ValueError, match=r"lanes must be integers in \[0, 4\)"):
        est.reset(lanes=[7])
    with pytest.raises(ValueError, match=r"lanes must be integers in \[0, 4\)"):
        est.reset(lanes=[-1])
    with pytest.raises(ValueError, match=r"lanes as a boolean mask must have shape \(4,\)"):
        est.reset(lanes=[True, False])
    with pytest.raises(ValueError, match="lanes must be lane indices"):
        est.reset(lanes=[0.5])
    with pytest.raises(ValueError, match=r"enabled must be a bool or one flag per lane"):
        est.enabled = [True, False]
    with pytest.raises(ValueError, match="per-lane theta0"):
        make_estimator("O-RLS", 2, num_envs=4, theta0=np.zeros((3, 4)))
    with pytest.raises(ValueError, match="num_envs must be an integer >= 1"):
        make_estimator("O-RLS", 2, num_envs=0)
    est.predict(np.zeros(4))
    est.reset(lanes=np.array([True, False, True, False]))
    assert est.t.tolist() == [0, 1, 0, 1]


def test_an_unknown_keyword_is_a_type_error_naming_it():
    with pytest.raises(TypeError, match="unexpected keyword.*windw"):
        make_estimator("O-RLS", 2, windw=3)


def test_restart_reset_covariance_and_the_controller_interface():
    """The published lane interface: restart at (theta, P), reset P(0), offsets of the spec."""
    est = make_estimator("KF-D-RLS", 2, p0=10.0, process_noise=0.01)
    u, y = data(T=50)
    est.run(u, y)
    theta = np.array([0.1, 0.2, 0.3, 0.4])
    P = np.diag([1.0, 2.0, 3.0, 4.0])
    x = est.x_hat
    est.restart(theta, P)
    np.testing.assert_array_equal(est.theta, theta)
    np.testing.assert_allclose(est.P, P, rtol=1e-14)
    np.testing.assert_array_equal(est.x_hat, x)
    with pytest.raises(ValueError, match="not symmetric positive definite"):
        est.restart(theta, -np.eye(4))
    np.testing.assert_array_equal(est.theta, theta)
    est.reset_covariance()
    np.testing.assert_allclose(est.P, 10.0 * np.eye(4), rtol=1e-14)
    spec = est.spec
    state = spec.make_state(3)  # a caller's lane state of its own, lane 2 of it
    set_lanes(state, 2, spec.initial_state())
    status = np.zeros(3, dtype=np.int64)
    y, u = np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 0.5])
    update_lanes(state, spec.make_work(3), spec.config, y, status)
    predict_lanes(state, spec.make_work(3), spec.config, u, status)
    ref = make_estimator("KF-D-RLS", 2, p0=10.0, process_noise=0.01)
    ref.update(1.0)
    ref.predict(0.5)
    assert status[2] == 0
    for field, ref_field in zip(state, ref.state, strict=True):
        np.testing.assert_array_equal(field[2], ref_field[0])
    np.testing.assert_array_equal(state.theta[2], ref.theta)


def test_callable_observer_gain_runs_per_lane():
    gain = lambda a, b: -a  # noqa: E731  (dead-beat gain of the observer form)
    single = make_estimator("CO-RLS", 2, observer_gain=gain, theta0=np.r_[A_TRUE, B_TRUE])
    batch = make_estimator(
        "CO-RLS", 2, observer_gain=gain, theta0=np.r_[A_TRUE, B_TRUE], num_envs=2
    )
    u, y = data(T=30)
    out = single.run(u, y)
    outb = batch.run(np.c_[u, u], np.c_[y, y])
    np.testing.assert_array_equal(outb[:, 1], out)


def test_frozen_signal_on_a_collapsed_covariance():
    """A frozen wrong model (P collapsed, large innovation) raises the flag and a warning; the
    same data with p0 = 100 does not."""
    u2, y = data(T=3000, seed=1)
    est = make_estimator("O-RLS", 2, theta0=[0.5, 0.5, -1.0, 0.0], p0=100.0)
    est.enabled = False
    est.run(u2[:10], y[:10])
    est.enabled = True
    est.restart([0.5, 0.5, -1.0, 0.0], 1e-12 * np.eye(4))  # a collapsed P on a wrong model
    with pytest.warns(RuntimeWarning, match="frozen on a wrong model"):
        est.run(u2[10:], y[10:])
    assert est.health["frozen"] and est.frozen
    good = make_estimator("O-RLS", 2, p0=100.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        good.run(u2, y)
    assert not good.health["frozen"]
