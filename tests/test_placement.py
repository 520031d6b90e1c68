"""Pole placement and LQ gains (stcgym.adaptive.control.placement) against python-control."""

from __future__ import annotations

import control
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stcgym.adaptive.control.placement import (
    UncontrollableError,
    ackermann,
    augment_integral,
    characteristic_coefficients,
    check_poles,
    controllability_matrix,
    lq_gain,
    place_poles,
    steady_state_gains,
)
from stcgym.envs.canonical import companion_A, observer_to_observability_b

FORMS = ("observer", "observability")


def _random_pair(rng: np.random.Generator, n: int, form: str) -> tuple[np.ndarray, np.ndarray]:
    """A random canonical pair, well controllable (rcond > 1e-4)."""
    while True:
        a = rng.uniform(-1.5, 1.5, n)
        b = rng.uniform(-1.0, 1.0, n)
        A = companion_A(a, form)
        C = controllability_matrix(A, b)
        if np.linalg.cond(C / np.linalg.norm(C, axis=0)) < 1e4:
            return A, b


def _distinct_poles(rng: np.random.Generator, m: int) -> np.ndarray:
    """``m`` well separated poles inside the unit circle, complex ones in conjugate pairs."""
    poles: list[complex] = []
    while len(poles) < m:
        if m - len(poles) >= 2 and rng.random() < 0.5:
            rad, ang = rng.uniform(0.1, 0.9), rng.uniform(0.3, 2.5)
            cand = [rad * np.exp(1j * ang), rad * np.exp(-1j * ang)]
        else:
            cand = [complex(rng.uniform(-0.9, 0.9))]
        if all(abs(c - p) > 0.15 for c in cand for p in poles):
            poles.extend(cand)
    return np.array(poles)


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("n", [1, 2, 3, 4, 5])
def test_matches_control_place(form: str, n: int) -> None:
    rng = np.random.default_rng(100 + n)
    for _ in range(5):
        A, b = _random_pair(rng, n, form)
        poles = _distinct_poles(rng, n)
        K = place_poles(A, b, poles)
        K_ref = np.asarray(control.place(A, b.reshape(-1, 1), poles)).ravel()
        np.testing.assert_allclose(K, K_ref, rtol=1e-6, atol=1e-8)
        eig = np.linalg.eigvals(A - np.outer(b, K))
        np.testing.assert_allclose(np.sort_complex(eig), np.sort_complex(poles), atol=1e-6)


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("n", [1, 2, 4])
def test_matches_control_acker_with_repeated_poles(form: str, n: int) -> None:
    rng = np.random.default_rng(7 + n)
    A, b = _random_pair(rng, n, form)
    Aa, ba = augment_integral(A, b)
    K = place_poles(Aa, ba, 0.5)  # n + 1 poles, all at 0.5 (place() refuses this)
    K_ref = np.asarray(control.acker(Aa, ba.reshape(-1, 1), [0.5] * (n + 1))).ravel()
    np.testing.assert_allclose(K, K_ref, rtol=1e-6, atol=1e-8)
    # Repeated poles are ill-conditioned eigenvalues: test the characteristic polynomial.
    char = np.poly(Aa - np.outer(ba, K))
    np.testing.assert_allclose(char, np.poly([0.5] * (n + 1)), atol=1e-8)


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(1, 4),
    seed=st.integers(0, 2**31 - 1),
    form=st.sampled_from(FORMS),
    integral=st.booleans(),
)
def test_placed_characteristic_polynomial(n: int, seed: int, form: str, integral: bool) -> None:
    rng = np.random.default_rng(seed)
    A, b = _random_pair(rng, n, form)
    if integral:
        A, b = augment_integral(A, b)
    m = A.shape[0]
    poles = _distinct_poles(rng, m)
    K, rcond = ackermann(A, b, characteristic_coefficients(poles))
    assert rcond > 0
    np.testing.assert_allclose(np.poly(A - np.outer(b, K)), np.poly(poles), atol=1e-7)


def test_augmented_model_structure() -> None:
    A = companion_A(np.array([-1.5, 0.7]), "observer")
    b = np.array([1.0, 0.5])
    Aa, ba = augment_integral(A, b)
    np.testing.assert_array_equal(Aa[:2, :2], A)
    np.testing.assert_array_equal(Aa[2], [-1.0, 0.0, 1.0])
    np.testing.assert_array_equal(ba, [1.0, 0.5, 0.0])


def test_uncontrollable_pair_is_rejected() -> None:
    # (z - 0.5) cancels: a(z) = (z - 0.5)(z - 0.8), B(z) = z - 0.5.
    a = np.poly([0.5, 0.8])[1:]
    A = companion_A(a, "observer")
    b = np.array([1.0, -0.5])
    with pytest.raises(UncontrollableError):
        place_poles(A, b, [0.1, 0.2])
    # Nearly cancelling: still placeable, but refused once rcond_min is asked for.
    b_near = np.array([1.0, -0.5 + 1e-7])
    place_poles(A, b_near, [0.1, 0.2])
    with pytest.raises(UncontrollableError, match="uncontrollable"):
        place_poles(A, b_near, [0.1, 0.2], rcond_min=1e-4)
    with pytest.raises(UncontrollableError):
        place_poles(A, np.zeros(2), [0.1, 0.2])


@pytest.mark.parametrize(
    ("poles", "m", "match"),
    [
        ([0.5, 1.2], 2, "unit circle"),
        ([0.5, -1.0], 2, "unit circle"),
        ([0.5, 0.5, 0.5], 2, "exactly 2"),
        ([0.5], 2, "exactly 2"),
        ([0.3 + 0.2j, 0.3 + 0.2j], 2, "conjugate"),
        ([0.5, np.nan], 2, "finite"),
        ("fast", 2, "number"),
    ],
)
def test_check_poles_rejects(poles: object, m: int, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        check_poles(poles, m)


def test_check_poles_scalar_broadcast() -> None:
    np.testing.assert_array_equal(check_poles(0.4, 3), [0.4, 0.4, 0.4])
    np.testing.assert_allclose(characteristic_coefficients([0.5, 0.5]), [-1.0, 0.25])


@pytest.mark.parametrize("form", FORMS)
def test_steady_state_gains(form: str) -> None:
    a = np.array([-1.5, 0.7])
    A = companion_A(a, form)
    # The same plant (numerator z + 0.5) in both forms; b = Markov parameters when observability.
    b = np.array([1.0, 0.5]) if form == "observer" else observer_to_observability_b(a, [1.0, 0.5])
    x_ss, u_ss, rcond = steady_state_gains(A, b)
    assert rcond > 1e-3
    np.testing.assert_allclose(A @ x_ss + b * u_ss, x_ss, atol=1e-12)
    assert x_ss[0] == pytest.approx(1.0)
    assert u_ss == pytest.approx((1 - 1.5 + 0.7) / 1.5)  # 1 / G(1)


def test_steady_state_gains_integrator_and_zero_at_one() -> None:
    A = companion_A(np.array([-1.6, 0.6]), "observer")  # pole at z = 1
    x_ss, u_ss, rcond = steady_state_gains(A, np.array([0.2, 0.1]))
    assert rcond > 1e-3 and u_ss == pytest.approx(0.0, abs=1e-12) and x_ss[0] == 1.0
    _, _, rcond0 = steady_state_gains(A, np.array([1.0, -1.0]))  # zero at z = 1
    assert rcond0 < 1e-12


@pytest.mark.parametrize(
    "design",
    [
        lambda A, b: ackermann(A, b, np.zeros(b.size)),
        lambda A, b: steady_state_gains(A, b),
        lambda A, b: augment_integral(A, b),
        lambda A, b: place_poles(A, b, 0.5),
    ],
    ids=["ackermann", "steady_state_gains", "augment_integral", "place_poles"],
)
@pytest.mark.parametrize("shape", [(2, 3), (3, 2), (1, 4), (4,)])
def test_a_non_square_A_is_rejected_naming_A(design, shape) -> None:
    """The compiled loops size everything from b: a non-square A would be read out of bounds."""
    A = np.full(shape, 0.1)
    b = np.ones(min(shape))
    with pytest.raises(ValueError, match="A must be a non-empty square matrix"):
        design(A, b)


def test_a_b_of_the_wrong_length_is_rejected_naming_b() -> None:
    A = companion_A(np.array([-1.5, 0.7]))
    with pytest.raises(ValueError, match="b must have length 2"):
        ackermann(A, np.ones(3), np.zeros(2))
    with pytest.raises(ValueError, match="b must have length 2"):
        steady_state_gains(A, np.ones(1))


# ----------------------------------------------------------------------------- LQ (lq_gain)
def _output_weight(m: int, n: int, q_i: float = 0.0) -> np.ndarray:
    Q = np.zeros((m, m))
    Q[0, 0] = 1.0
    if m > n:
        Q[n, n] = q_i
    return Q


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("n", [1, 2, 4, 8])
@pytest.mark.parametrize("integral", [False, True])
def test_lq_gain_matches_control_dlqr(form: str, n: int, integral: bool) -> None:
    rng = np.random.default_rng(300 + n)
    A, b = _random_pair(rng, n, form)
    if integral:
        A, b = augment_integral(A, b)
    Q = _output_weight(A.shape[0], n, 1e-2)
    K, P = lq_gain(A, b, Q, 1e-2)
    K_ref, P_ref, _ = control.dlqr(A, b.reshape(-1, 1), Q, [[1e-2]])
    np.testing.assert_allclose(K, np.ravel(K_ref), rtol=1e-7, atol=1e-9 * np.abs(K_ref).max())
    np.testing.assert_allclose(P, P_ref, rtol=1e-7, atol=1e-9 * np.abs(P_ref).max())
    assert np.max(np.abs(np.linalg.eigvals(A - np.outer(b, K)))) < 1.0


def test_lq_gain_matches_control_dare_with_full_weights() -> None:
    rng = np.random.default_rng(5)
    A, b = _random_pair(rng, 3, "observer")
    L = rng.normal(size=(3, 3))
    Q = L @ L.T
    K, P = lq_gain(A, b, Q, 0.7)
    X, _, G = control.dare(A, b.reshape(-1, 1), Q, [[0.7]])
    np.testing.assert_allclose(P, X, rtol=1e-8)
    np.testing.assert_allclose(K, np.ravel(G), rtol=1e-8)


def test_lq_gain_rejects_unstabilisable_and_bad_input() -> None:
    # pole at 2 cancelled by the zero of b(z) = z - 2: (A, b) is not stabilisable
    A = companion_A(np.array([-3.0, 2.0]), "observer")
    with pytest.raises(UncontrollableError, match="stabilis"):
        lq_gain(A, np.array([1.0, -2.0]), np.diag([1.0, 0.0]), 0.01)
    # stable cancelled pole: stabilisable, the DARE has a solution (python-control agrees)
    A_s = companion_A(np.poly([0.5, 0.8])[1:], "observer")
    K, P = lq_gain(A_s, np.array([1.0, -0.5]), np.diag([1.0, 0.0]), 0.01)
    K_ref, P_ref, _ = control.dlqr(A_s, np.array([[1.0], [-0.5]]), np.diag([1.0, 0.0]), [[0.01]])
    np.testing.assert_allclose(K, np.ravel(K_ref), rtol=1e-7)
    with pytest.raises(ValueError, match="R"):
        lq_gain(A, np.array([1.0, 0.5]), np.eye(2), 0.0)
    with pytest.raises(ValueError, match="Q"):
        lq_gain(A, np.array([1.0, 0.5]), -np.eye(2), 1.0)
    with pytest.raises(ValueError, match=r"Q must have 2 rows \(shape \(2, 2\)\)"):
        lq_gain(A, np.array([1.0, 0.5]), np.eye(3), 1.0)
    with pytest.raises(ValueError, match="b must have length 2"):
        lq_gain(A, np.array([1.0]), np.eye(2), 1.0)


def test_lq_gain_accepts_a_weight_that_leaves_an_unstable_mode_unweighted() -> None:
    """A positive semidefinite ``Q`` blind to an unstable mode still has a stabilising DARE
    solution (it mirrors that mode into the unit circle): ``control.dlqr`` gives it and so
    must ``lq_gain``; only a mode on the unit circle that ``Q`` does not see has none."""
    K, P = lq_gain(np.array([[2.0]]), np.array([1.0]), np.array([[0.0]]), 1.0)
    np.testing.assert_allclose(K, [1.5], rtol=1e-12)
    np.testing.assert_allclose(P, [[3.0]], rtol=1e-12)
    A, b, Q = np.diag([1.05, 0.5]), np.array([1.0, 1.0]), np.diag([0.0, 1.0])
    K, P = lq_gain(A, b, Q, 0.01)
    K_ref, P_ref, _ = control.dlqr(A, b.reshape(-1, 1), Q, [[0.01]])
    np.testing.assert_allclose(K, np.ravel(K_ref), rtol=1e-8)
    np.testing.assert_allclose(P, P_ref, rtol=1e-8)
    with pytest.raises(UncontrollableError, match=r"mode\(s\) 1 of A on the unit circle"):
        lq_gain(np.array([[1.0]]), np.array([1.0]), np.array([[0.0]]), 1.0)


@settings(max_examples=30, deadline=None)
@given(n=st.integers(1, 4), seed=st.integers(0, 2**31 - 1), form=st.sampled_from(FORMS))
def test_lq_gain_equals_dlqr_with_singular_weights(n: int, seed: int, form: str) -> None:
    """Property: with a random rank-deficient ``Q`` (and the model's unstable modes often
    unweighted) ``lq_gain`` equals python-control's ``dlqr`` to 1e-8."""
    rng = np.random.default_rng(seed)
    A, b = _random_pair(rng, n, form)
    L = rng.normal(size=(n, rng.integers(0, n)))
    Q = L @ L.T
    R = float(rng.uniform(1e-2, 10.0))
    try:
        K_ref, P_ref, _ = control.dlqr(A, b.reshape(-1, 1), Q, [[R]])
    except (ValueError, np.linalg.LinAlgError):
        return  # no stabilising solution (a mode on the unit circle): nothing to compare
    K, P = lq_gain(A, b, Q, R)
    scale = max(1.0, np.abs(P_ref).max())
    np.testing.assert_allclose(P, P_ref, rtol=1e-8, atol=1e-8 * scale)
    np.testing.assert_allclose(
        K, np.ravel(K_ref), rtol=1e-8, atol=1e-8 * max(1.0, np.abs(K_ref).max())
    )


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 5), seed=st.integers(0, 2**31 - 1), form=st.sampled_from(FORMS))
def test_lq_gain_solves_the_riccati_equation(n: int, seed: int, form: str) -> None:
    """Property: the returned P satisfies the DARE and K = (R + b'Pb)^-1 b'PA, loop stable."""
    rng = np.random.default_rng(seed)
    A, b = _random_pair(rng, n, form)
    A, b = augment_integral(A, b)
    Q = _output_weight(n + 1, n, rng.uniform(1e-3, 1.0))
    R = float(rng.uniform(1e-3, 10.0))
    K, P = lq_gain(A, b, Q, R)
    s = R + b @ P @ b
    np.testing.assert_allclose(K, (b @ P @ A) / s, rtol=1e-9, atol=1e-12 * np.abs(K).max())
    residual = Q + A.T @ P @ A - np.outer(A.T @ P @ b, b @ P @ A) / s - P
    assert np.abs(residual).max() <= 1e-7 * max(1.0, np.abs(P).max())
    assert np.max(np.abs(np.linalg.eigvals(A - np.outer(b, K)))) < 1.0
