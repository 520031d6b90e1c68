"""Certainty-equivalence design lane functions (placement, lq, safe_set, law of
stcgym.adaptive.control).

References: python-control's ``acker`` / ``dlqr`` on the integral-augmented canonical model, the
steady-state equations solved with numpy, and the tracking law written out by hand.
"""

from __future__ import annotations

import math

import control
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from lane_call import call

from stcgym.adaptive.control import law, lq
from stcgym.adaptive.control import placement as pp
from stcgym.adaptive.control import safe_set as ss
from stcgym.adaptive.control.placement import augment_integral, controllability_matrix
from stcgym.adaptive.estimation import state_estimation as se
from stcgym.envs.canonical import companion_A
from stcgym.envs.dynamics import FORM_CODES, OBSERVER

FORMS = FORM_CODES


def _K(gain: ss.Gain, integral: bool, lane: int = 0) -> np.ndarray:
    """The state-feedback gain ``[K_x, k_i]`` (``K_x`` alone without integral action)."""
    return np.r_[gain.K_x[lane], gain.k_i[lane]] if integral else gain.K_x[lane].copy()


def _flat(gain: ss.Gain, lane: int = 0) -> np.ndarray:
    """Every field of one lane of a gain, ``[K_x, k_i, N, rcond]``: to compare two gains."""
    return np.r_[gain.K_x[lane], gain.k_i[lane], gain.N[lane], gain.rcond[lane]]


def _gain_of(K_x: np.ndarray, k_i: float, N: float) -> ss.Gain:
    """A one-lane gain with the given fields (``rcond`` 0.5: any accepted design's)."""
    gain = ss.make_gain(K_x.size, 1)
    gain.K_x[0] = K_x
    gain.k_i[0], gain.N[0], gain.rcond[0] = k_i, N, 0.5
    return gain


def _augmented(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``[[A, 0], [-c, 1]]``, ``[b; 0]`` written out with ``np.block`` (the reference)."""
    n = A.shape[0]
    return np.block([[A, np.zeros((n, 1))], [-np.eye(1, n), np.ones((1, 1))]]), np.r_[b, 0.0]


def test_integral_augmentation_is_the_block_model() -> None:
    rng = np.random.default_rng(3)
    for n in (1, 2, 5):
        A, b = rng.standard_normal((n, n)), rng.standard_normal(n)
        for got, ref in zip(augment_integral(A, b), _augmented(A, b), strict=True):
            np.testing.assert_array_equal(got, ref)


def _plant(rng: np.random.Generator, n: int, form: str) -> tuple[np.ndarray, np.ndarray]:
    """Random ``theta = [a; b]`` whose augmented model is well controllable, and its ``A``."""
    while True:
        theta = np.r_[rng.uniform(-1.2, 1.2, n), rng.uniform(-1.0, 1.0, n)]
        A = companion_A(theta[:n], form)
        Aa, ba = _augmented(A, theta[n:])
        C = controllability_matrix(Aa, ba)
        if np.linalg.cond(C / np.linalg.norm(C, axis=0)) < 1e5:
            return theta, A


def _models(theta: np.ndarray, form: str, integral: bool) -> tuple[np.ndarray, ...]:
    n = theta.size // 2
    A = companion_A(theta[:n], form)
    b = theta[n:].copy()
    Ad, bd = _augmented(A, b) if integral else (A, b)
    return A, b, Ad, bd


def _lq_config(form: int, integral: bool) -> ss.DesignConfig:
    """The settings of an LQ design with feed-forward and no safe set (no poles)."""
    return ss.DesignConfig(form, integral, True, ss.safe_set(), np.zeros(0))


def _alpha(poles: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.real(np.poly(poles))[1:])


def _dc_reference(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    """``x_ss``, ``u_ss`` for ``y = 1`` by numpy's solver (the independent reference)."""
    n = A.shape[0]
    M = np.block([[A - np.eye(n), b[:, None]], [np.eye(1, n), np.zeros((1, 1))]])
    sol = np.linalg.solve(M, np.r_[np.zeros(n), 1.0])
    return sol[:n], sol[n]


# ------------------------------------------------------------------------------ pole placement
@pytest.mark.parametrize("form", list(FORMS))
@pytest.mark.parametrize("n", [1, 2, 3, 5, 8])
@pytest.mark.parametrize(("integral", "feedforward"), [(True, True), (False, True), (True, False)])
def test_place_design_matches_acker(form: str, n: int, integral: bool, feedforward: bool) -> None:
    rng = np.random.default_rng(10 * n + integral)
    theta, _ = _plant(rng, n, form)
    A, b, Ad, bd = _models(theta, form, integral)
    m = Ad.shape[0]
    poles = np.linspace(0.2, 0.7, m)
    gain = ss.make_gain(n, 1)
    cfg = ss.DesignConfig(FORMS[form], integral, feedforward, ss.safe_set(), _alpha(poles))
    status = pp.place_design(theta, cfg, gain, ss.design_work(n, integral), 0)
    assert status == ss.OK
    K_ref = np.ravel(control.acker(Ad, bd[:, None], poles))
    K = _K(gain, integral)
    np.testing.assert_allclose(K, K_ref, rtol=1e-6, atol=1e-9 * np.abs(K_ref).max())
    assert gain.rcond[0] > 0.0  # the reciprocal condition of the accepted design
    if integral is False:
        assert gain.k_i[0] == 0.0
    if feedforward:
        # N = u_ss + K_x x_ss: on the exact model the loop rests at y = r with xi = 0
        x_ss, u_ss = _dc_reference(A, b)
        assert gain.N[0] == pytest.approx(u_ss + K_ref[:n] @ x_ss, rel=1e-8, abs=1e-10)
        x_cl = np.linalg.solve(np.eye(n) - (A - np.outer(b, K_ref[:n])), b * gain.N[0])
        assert x_cl[0] == pytest.approx(1.0, rel=1e-7)
    else:
        assert gain.N[0] == 0.0


@settings(max_examples=50, deadline=None)
@given(
    n=st.integers(1, 8),
    seed=st.integers(0, 2**31 - 1),
    form=st.sampled_from(list(FORMS)),
    radius=st.floats(0.0, 0.95),
)
def test_place_design_characteristic_polynomial(
    n: int, seed: int, form: str, radius: float
) -> None:
    """Property: the augmented closed loop has the requested characteristic polynomial."""
    rng = np.random.default_rng(seed)
    theta, _ = _plant(rng, n, form)
    _, _, Ad, bd = _models(theta, form, True)
    m = n + 1
    half = radius * np.exp(1j * np.pi * rng.uniform(0, 1, m // 2))
    poles = np.r_[half, half.conj(), radius * rng.uniform(-1, 1, m % 2)]
    alpha = _alpha(poles)
    gain = ss.make_gain(n, 1)
    cfg = ss.DesignConfig(FORMS[form], True, True, ss.safe_set(), alpha)
    assert pp.place_design(theta, cfg, gain, ss.design_work(n, True), 0) == ss.OK
    K = _K(gain, True)
    char = np.poly(Ad - np.outer(bd, K))
    scale = max(1.0, np.abs(K).max() * np.abs(bd).max())
    np.testing.assert_allclose(char[1:], alpha, atol=1e-8 * scale)


# ------------------------------------------------------------------------------ safe set
def _status(theta: np.ndarray, safe: np.ndarray, gain: ss.Gain, **kw: object) -> int:
    n = theta.size // 2
    integral = kw.get("integral", True)
    cfg = ss.DesignConfig(
        kw.get("form", OBSERVER), integral, kw.get("feedforward", True), safe,
        _alpha(np.full(n + 1, 0.5)),
    )  # fmt: skip
    return pp.place_design(theta, cfg, gain, ss.design_work(n, integral), 0)


def test_safe_set_status_codes_and_last_good_gain_kept() -> None:
    good = np.array([-1.5, 0.7, 1.0, 0.5])  # stable2
    gain = ss.make_gain(2, 1)
    assert _status(good, ss.safe_set(), gain) == ss.OK
    kept = _flat(gain)
    cases = {
        ss.NONFINITE: (np.array([-1.5, np.nan, 1.0, 0.5]), ss.safe_set()),
        ss.B_SMALL: (np.array([-1.5, 0.7, 1e-3, 1e-3]), ss.safe_set(b_min=0.01)),
        # (z - 0.5) cancels: a(z) = (z - 0.5)(z - 0.8), b(z) = z - 0.5
        ss.UNCONTROLLABLE: (np.r_[np.poly([0.5, 0.8])[1:], 1.0, -0.5], ss.safe_set()),
        ss.GAIN_LARGE: (good, ss.safe_set(gain_max=0.5)),
    }
    for code, (theta, safe) in cases.items():
        assert _status(theta, safe, gain) == code, ss.STATUS_NAMES[code]
        np.testing.assert_array_equal(_flat(gain), kept)
    near = np.r_[np.poly([0.5, 0.8])[1:], 1.0, -0.5 + 1e-6]
    assert _status(near, ss.safe_set(), gain) == ss.OK
    assert _status(near, ss.safe_set(rcond_min=1e-3), gain) == ss.UNCONTROLLABLE
    # b(z) = z - 1: a zero at z = 1 (with integral action the integrator would cancel it and
    # the model be uncontrollable, so without)
    zero_at_one = np.array([-1.5, 0.7, 1.0, -1.0])
    assert _status(zero_at_one, ss.safe_set(), gain, integral=False) == ss.DC_SINGULAR
    assert _status(zero_at_one, ss.safe_set(), gain, integral=False, feedforward=False) == ss.OK
    assert [ss.STATUS_NAMES[c] for c in range(8)] == [
        "ok", "nonfinite", "b_small", "uncontrollable", "dc_singular", "gain_large",
        "not_stabilisable", "not_converged",
    ]  # fmt: skip


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"gain_max": 0.0}, "gain_max"),
        ({"gain_max": -1.0}, "gain_max"),
        ({"gain_max": float("nan")}, "gain_max"),
        ({"b_min": -1.0}, "b_min"),
        ({"b_min": "big"}, "b_min"),
        ({"rcond_min": 1.5}, "rcond_min"),
        ({"dc_rcond_min": -0.1}, "dc_rcond_min"),
    ],
)
def test_safe_set_rejects_nonsense(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        ss.safe_set(**kwargs)


@pytest.mark.parametrize(("n", "integral"), [(1, True), (2, False), (3, True)])
def test_scratch_of_another_order_is_an_error_not_garbage(n: int, integral: bool) -> None:
    theta = np.array([-1.5, 0.7, 1.0, 0.5])
    with pytest.raises(ValueError, match="scratch"):
        pp.place_design(
            theta, ss.DesignConfig(OBSERVER, True, True, ss.safe_set(), _alpha(np.full(3, 0.5))),
            ss.make_gain(2, 1), ss.design_work(n, integral), 0,
        )  # fmt: skip


# ------------------------------------------------------------------------------ LQ
@pytest.mark.parametrize("form", list(FORMS))
@pytest.mark.parametrize("n", [1, 2, 4, 8])
@pytest.mark.parametrize("integral", [True, False])
def test_lq_solve_and_riccati_iteration_match_dlqr(form: str, n: int, integral: bool) -> None:
    rng = np.random.default_rng(50 + n)
    theta, _ = _plant(rng, n, form)
    A, b, Ad, bd = _models(theta, form, integral)
    m = Ad.shape[0]
    weights = np.array([1.0, 0.05, 0.02])
    Q = np.zeros((m, m))
    Q[0, 0] = weights[0]
    if integral:
        Q[n, n] = weights[1]
    K_ref, P_ref, _ = control.dlqr(Ad, bd[:, None], Q, [[weights[2]]])
    K_ref = np.ravel(K_ref)
    gain = ss.make_gain(n, 1)
    P = np.zeros((m, m))
    cfg = _lq_config(FORMS[form], integral)
    status = lq.lq_solve(
        theta, cfg, weights, P, gain, lq.lq_work(n, integral, solve=True), 0, 1e-12, 64
    )
    assert status == ss.OK
    K = _K(gain, integral)
    np.testing.assert_allclose(K, K_ref, rtol=1e-7, atol=1e-10 * np.abs(K_ref).max())
    np.testing.assert_allclose(P, P_ref, rtol=1e-7, atol=1e-10 * np.abs(P_ref).max())
    x_ss, u_ss = _dc_reference(A, b)
    assert gain.N[0] == pytest.approx(u_ss + K_ref[:n] @ x_ss, rel=1e-7, abs=1e-10)
    # one Riccati iteration per call from the cold start P = Q converges to the same gain
    P_it = lq.lq_initial_P(n, integral, weights)
    np.testing.assert_array_equal(P_it, Q)
    g_it = ss.make_gain(n, 1)
    work = lq.lq_work(n, integral)
    for _ in range(3000):
        assert lq.lq_design(theta, cfg, weights, P_it, g_it, work, 0) == ss.OK
    expected = _flat(gain)
    np.testing.assert_allclose(_flat(g_it), expected, rtol=1e-6, atol=1e-9 * np.abs(expected).max())


def test_lq_riccati_iteration_is_the_riccati_difference_equation() -> None:
    """One call = one step of P <- Q + A'PA - A'Pb (rho + b'Pb)^-1 b'PA (numpy by hand)."""
    theta = np.array([-1.1, 0.3, 0.8, 0.4])
    weights = np.array([1.0, 0.01, 0.01])
    _, _, Ad, bd = _models(theta, "observer", True)
    rng = np.random.default_rng(0)
    L = rng.normal(size=(3, 3))
    P = L @ L.T
    P_ref = P.copy()
    gain = ss.make_gain(2, 1)
    cfg = _lq_config(OBSERVER, True)
    assert lq.lq_design(theta, cfg, weights, P, gain, lq.lq_work(2, True), 0) == ss.OK
    Q = np.diag([1.0, 0.0, 0.01])
    rho = 0.01
    s = rho + bd @ P_ref @ bd
    P_next = Q + Ad.T @ P_ref @ Ad - np.outer(Ad.T @ P_ref @ bd, bd @ P_ref @ Ad) / s
    np.testing.assert_allclose(P, P_next, rtol=1e-10)
    K = (bd @ P_next @ Ad) / (rho + bd @ P_next @ bd)
    np.testing.assert_allclose(_K(gain, True), K, rtol=1e-10)


def test_lq_not_stabilisable_plant() -> None:
    # a(z) = (z - 1)(z - 2), b(z) = z - 2: the unstable pole at 2 is cancelled
    theta = np.array([-3.0, 2.0, 1.0, -2.0 + 1e-9])
    weights = np.array(lq.DEFAULT_LQ_WEIGHTS)
    gain = ss.make_gain(2, 1)
    P = np.zeros((3, 3))
    cfg = _lq_config(OBSERVER, True)
    status = lq.lq_solve(
        theta, cfg, weights, P, gain, lq.lq_work(2, True, solve=True), 0, 1e-12, 64
    )
    assert status == ss.NOT_STABILISABLE
    assert not _flat(gain).any() and not P.any()
    # the per-step iteration blows up and restarts from Q with NOT_STABILISABLE
    P = lq.lq_initial_P(2, True, weights)
    codes = set()
    for _ in range(200):
        codes.add(lq.lq_design(theta, cfg, weights, P, gain, lq.lq_work(2, True), 0))
        assert np.all(np.isfinite(P)) and np.abs(P).max() <= lq.P_MAX
    assert ss.NOT_STABILISABLE in codes


def test_lq_solve_ill_conditioned_but_stabilisable() -> None:
    """A near cancellation of an unstable pole: huge but valid gain (python-control agrees)."""
    theta = np.array([-3.0, 2.0, 1.0, -2.0 + 1e-3])
    weights = np.array(lq.DEFAULT_LQ_WEIGHTS)
    _, _, Ad, bd = _models(theta, "observer", True)
    q_y, q_i, rho = weights
    K_ref, _, E = control.dlqr(Ad, bd[:, None], np.diag([q_y, 0.0, q_i]), [[rho]])
    assert np.abs(E).max() < 1
    gain = ss.make_gain(2, 1)
    P = np.zeros((3, 3))
    cfg = _lq_config(OBSERVER, True)
    work = lq.lq_work(2, True, solve=True)
    assert lq.lq_solve(theta, cfg, weights, P, gain, work, 0, 1e-12, 64) == ss.OK
    np.testing.assert_allclose(_K(gain, True), np.ravel(K_ref), rtol=1e-5)


# ------------------------------------------------------------------------------ tracking law
def _law_by_hand(K, ki, N, xi, x, y, r, e, bound, integral, anti_windup):
    u = N * r - K @ x - ki * xi + e
    u_sat = float(np.clip(u, -bound, bound))
    sat = u_sat != u
    if integral and not (anti_windup and sat and (-ki * (r - y)) * u > 0):
        xi = xi + (r - y)
    return u_sat, xi, sat, u


@settings(max_examples=200, deadline=None)
@given(
    vals=st.lists(st.floats(-5, 5), min_size=8, max_size=8),
    bound=st.sampled_from([0.5, 3.0, math.inf]),
    integral=st.booleans(),
    anti_windup=st.booleans(),
)
def test_track_matches_the_law_by_hand(vals, bound, integral, anti_windup) -> None:
    K = np.array(vals[:2])
    ki, N, xi, y, r, e = vals[2], vals[3], vals[4], vals[5], vals[6], vals[7]
    x = np.array([0.3, -0.7])
    gain = _gain_of(K, ki if integral else 0.0, N)
    u, xi_next, saturated, u_unsat = call(
        law.track, gain, 0, True, xi, x, y, r, e, bound, integral, anti_windup
    )
    u_ref, xi_ref, sat_ref, u_unsat_ref = _law_by_hand(
        K, ki if integral else 0.0, N, xi, x, y, r, e, bound, integral, anti_windup
    )
    assert u == pytest.approx(u_ref, rel=1e-12, abs=1e-12)
    assert xi_next == pytest.approx(xi_ref, rel=1e-12, abs=1e-12)
    assert saturated == sat_ref
    assert u_unsat == pytest.approx(u_unsat_ref, rel=1e-12, abs=1e-12)


def test_track_without_gain_applies_only_the_excitation() -> None:
    gain = ss.make_gain(2, 1)
    gain.K_x[0] = [5.0, 5.0]  # never used without a gain
    u, xi, saturated, _ = call(
        law.track, gain, 0, False, 0.7, np.ones(2), 0.0, 1.0, 0.25, 10.0, True, True
    )
    assert (u, saturated) == (0.25, False)
    assert xi == 0.7  # the integrator waits for a gain
    u, _, saturated, _ = call(
        law.track, gain, 0, False, 0.7, np.ones(2), 0.0, 1.0, 30.0, 10.0, True, True
    )
    assert (u, saturated) == (10.0, True)


# ------------------------------------------------------------------------------ Kalman filter
def test_filtered_state_is_the_kalman_correction() -> None:
    x = np.array([0.2, -0.4, 1.0])
    L = np.random.default_rng(1).normal(size=(3, 3))
    P = L @ L.T
    xf = np.empty(3)
    innov = se.filtered_state(x, P, 0.3, 1.5, xf)
    c = np.eye(1, 3)
    gain_ref = P @ c.T / (0.3 + (c @ P @ c.T).item())
    np.testing.assert_allclose(xf, x + gain_ref.ravel() * (1.5 - 0.2), rtol=1e-13)
    assert innov == pytest.approx(1.3)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"q_y": 0.0}, "q_y"),
        ({"rho": -1.0}, "rho"),
        ({"rho": float("inf")}, "rho"),
        ({"q_i": 0.0}, "q_i"),
        ({"q_i": "x"}, "q_i"),
    ],
)
def test_lq_weights_reject_nonsense(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        lq.lq_weights(**kwargs)


def test_lq_weights_defaults_and_no_integral() -> None:
    np.testing.assert_array_equal(lq.lq_weights(), lq.DEFAULT_LQ_WEIGHTS)
    np.testing.assert_array_equal(lq.lq_weights(q_i=0.0, integral=False), [1.0, 0.0, 1e-2])


def test_batch_loops_equal_the_lane_functions() -> None:
    """The batch loops run the same compiled lane function per row: equal bit for bit."""
    rng = np.random.default_rng(11)
    thetas = np.array([_plant(rng, 3, "observer")[0] for _ in range(6)])
    thetas[2, 4] = np.nan  # one lane outside the safe set
    alpha = _alpha(np.full(4, 0.4))
    gains = ss.make_gain(3, 6)
    status = np.zeros(6, dtype=np.int64)
    work = ss.design_work(3, True, 6)
    cfg = ss.DesignConfig(OBSERVER, True, True, ss.safe_set(), alpha)
    pp.place_design_lanes(thetas, cfg, gains, status, work)
    weights = lq.lq_weights()
    Ps = np.zeros((6, 4, 4))
    gains_lq = ss.make_gain(3, 6)
    status_lq = np.zeros(6, dtype=np.int64)
    work_lq = lq.lq_work(3, True, 6, solve=True)
    lq.lq_solve_lanes(thetas, cfg, weights, Ps, gains_lq, status_lq, work_lq, 1e-12, 64)
    for i in range(6):
        g = ss.make_gain(3, 1)
        work = lq.lq_work(3, True, solve=True)  # every design reads only its own fields
        st_i = pp.place_design(thetas[i], cfg, g, work, 0)
        assert status[i] == st_i
        np.testing.assert_array_equal(_flat(gains, i), _flat(g))
        P = np.zeros((4, 4))
        g_lq = ss.make_gain(3, 1)
        st_lq = lq.lq_solve(thetas[i], cfg, weights, P, g_lq, work, 0, 1e-12, 64)
        assert status_lq[i] == st_lq
        np.testing.assert_array_equal(_flat(gains_lq, i), _flat(g_lq))
        np.testing.assert_array_equal(Ps[i], P)
    assert status[2] == ss.NONFINITE and status_lq[2] == ss.NONFINITE


@pytest.mark.parametrize("form", list(FORMS))
def test_kalman_covariance_lanes_match_dlqe(form: str) -> None:
    rng = np.random.default_rng(12)
    thetas = np.array([_plant(rng, 3, form)[0] for _ in range(3)])
    W = np.stack([1e-4 * np.outer(t[3:], t[3:]) + 1e-6 * np.eye(3) for t in thetas])
    Ps = np.zeros((3, 3, 3))
    status = np.zeros(3, dtype=np.int64)
    work = lq.dare_work(3, 3)
    lq.kalman_covariance_lanes(thetas, FORMS[form], W, 0.05**2, Ps, status, work, 1e-12, 64)
    assert not status.any()
    for t, Wi, P in zip(thetas, W, Ps, strict=True):
        A = companion_A(t[:3], form)
        _, P_ref, _ = control.dlqe(A, np.eye(3), np.eye(1, 3), Wi, [[0.05**2]])
        np.testing.assert_allclose(P, P_ref, rtol=1e-7, atol=1e-12)


def test_the_safe_set_and_weight_vectors_are_read_by_name() -> None:
    """The one accessor of each vector gives its entries under the names the designs use."""
    from stcgym.adaptive.control.lq import weight_fields
    from stcgym.adaptive.control.safe_set import safe_bounds

    safe = ss.safe_set(b_min=0.1, rcond_min=0.2, dc_rcond_min=0.3, gain_max=4.0)
    assert call(safe_bounds, safe) == ss.SafeSetBounds(b_min=0.1, rcond_min=0.2, dc_rcond_min=0.3,
                                                gain_max=4.0)  # fmt: skip
    weights = lq.lq_weights(2.0, 0.5, 0.25)
    assert call(weight_fields, weights) == lq.LQWeights(q_y=2.0, q_i=0.5, rho=0.25)
