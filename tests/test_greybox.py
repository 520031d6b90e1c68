"""Tests of the grey-box regression builder (Voevoda & Troshina 2016, eq. (5)-(8)).

Independent references: python-control's transfer function of the same matrices (input-output
coefficients), the paper's regression (7)-(8) written out by hand, a plain numpy simulation of
the state equation from a random initial state, and ``numpy.linalg.lstsq`` on the built rows.
"""

from __future__ import annotations

import control
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stcgym.adaptive.regression.greybox import (
    AffineStateSpace,
    NotLinearInParameters,
    io_coefficients,
)

PAPER = {
    "Phi0": [[0.0, 1.0], [-0.3, 0.0]],
    "Gamma0": [0.0, 1.0],
    "H": [1.0, 0.0],
    "Phi_terms": [[[0.0, 0.0], [0.0, 1.0]]],
}


def simulate(Phi, Gamma, H, u, x0):
    """``x(k+1) = Phi x(k) + Gamma u(k)``, ``y(k) = H x(k)``, k = 0..T-1 (plain numpy)."""
    x = np.array(x0, dtype=float)
    y = []
    for u_k in u:
        y.append(H @ x)
        x = Phi @ x + Gamma @ np.atleast_1d(u_k)
    return np.array(y)


def observer_form(n):
    """Observer canonical form with ``theta = [a_1..a_n, b_1..b_n]`` (affine input-output map)."""
    Phi0 = np.eye(n, k=1)
    Phi_terms = np.zeros((2 * n, n, n))
    Gamma_terms = np.zeros((2 * n, n, 1))
    for i in range(n):
        Phi_terms[i, i, 0] = -1.0
        Gamma_terms[n + i, i, 0] = 1.0
    H = np.eye(1, n)
    return AffineStateSpace(Phi0, np.zeros((n, 1)), H, Phi_terms, Gamma_terms)


# ------------------------------------------------------------------ the paper's structure


def test_paper_structure_is_equations_7_8():
    obj = AffineStateSpace(**PAPER)
    reg = obj.regression()
    assert reg.method == "output" and reg.order == 2 and reg.num_params == 1
    assert reg.equations() == "z(k) = y(k+2) + 0.3 y(k) - u(k)\nphi[theta[0]](k) = y(k+1)"
    rng = np.random.default_rng(0)
    u, y = rng.standard_normal(50), rng.standard_normal(50)  # any data: a pure formula check
    phi, z = reg.build(u, y)
    np.testing.assert_allclose(z, y[2:] + 0.3 * y[:-2] - u[:-2], rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(phi[:, 0], y[1:-1], rtol=0, atol=0)
    assert phi.shape == (48, 1) and z.shape == (48,)


def test_paper_structure_recovers_theta_from_noise_free_data():
    obj = AffineStateSpace(**PAPER)
    u = np.where(np.arange(200) % 6 < 3, 1.0, -1.0)  # meander of period 6
    Phi, Gamma = obj.matrices([-0.5])
    y = simulate(Phi, Gamma, obj.H, u, x0=[0.7, -1.2])[:, 0]
    phi, z = obj.regression().build(u, y)
    theta, *_ = np.linalg.lstsq(phi, z, rcond=None)
    np.testing.assert_allclose(theta, [-0.5], rtol=1e-12)


# ------------------------------------------------------------------ input-output coefficients


def test_io_coefficients_equal_python_control_transfer_functions():
    rng = np.random.default_rng(1)
    A, B, C = rng.standard_normal((3, 3)), rng.standard_normal((3, 2)), rng.standard_normal((2, 3))
    c, beta = io_coefficients(A, B, C)
    for r in range(2):
        for s in range(2):
            tf = control.ss2tf(control.ss(A, B[:, [s]], C[[r]], 0, True))
            num, den = np.ravel(tf.num[0][0]), np.ravel(tf.den[0][0])
            np.testing.assert_allclose(c, den[::-1] / den[0], rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(beta[:, r, s], num[::-1] / den[0], rtol=1e-10, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(1, 3),
    seed=st.integers(0, 2**32 - 1),
)
def test_output_route_holds_for_any_initial_state(n, seed):
    """Cayley-Hamilton: the rows are exact on every noise-free trajectory (any x(0))."""
    rng = np.random.default_rng(seed)
    obj = observer_form(n)
    theta = rng.uniform(-0.6, 0.6, 2 * n) / n
    Phi, Gamma = obj.matrices(theta)
    u = rng.standard_normal(12 * n)
    y = simulate(Phi, Gamma, obj.H, u, x0=rng.standard_normal(n))
    phi, z = obj.regression().build(u, y)
    scale = 1.0 + np.abs(z).max()
    np.testing.assert_allclose(phi @ theta, z, rtol=0, atol=1e-10 * scale)
    est, *_ = np.linalg.lstsq(phi, z, rcond=None)
    np.testing.assert_allclose(est, theta, rtol=0, atol=1e-7)


def test_output_route_with_two_outputs():
    """Parameters only in Gamma: the input-output map is affine for any Phi0 and H (p = 2)."""
    rng = np.random.default_rng(3)
    Phi0 = 0.5 * rng.standard_normal((3, 3))
    Gamma_terms = rng.standard_normal((2, 3, 1))
    H = rng.standard_normal((2, 3))
    obj = AffineStateSpace(Phi0, rng.standard_normal(3), H, Gamma_terms=Gamma_terms)
    reg = obj.regression()
    assert reg.method == "output" and reg.num_outputs == 2
    theta = np.array([0.4, -1.1])
    u = rng.standard_normal(40)
    y = simulate(*obj.matrices(theta), H, u, x0=rng.standard_normal(3))
    phi, z = reg.build(u, y)
    assert phi.shape == (37, 2, 2) and z.shape == (37, 2)
    np.testing.assert_allclose(phi @ theta, z, atol=1e-10)
    est, *_ = np.linalg.lstsq(phi.reshape(-1, 2), z.reshape(-1), rcond=None)
    np.testing.assert_allclose(est, theta, atol=1e-9)


# ------------------------------------------------------------------ the state route


def test_state_route_recovers_a_generic_structure():
    """A generic affine structure with the state measured: linear whatever the products."""
    rng = np.random.default_rng(4)
    n, m, q = 3, 2, 4
    obj = AffineStateSpace(
        0.3 * rng.standard_normal((n, n)),
        rng.standard_normal((n, m)),
        rng.standard_normal((n, n)) + 2 * np.eye(n),
        0.1 * rng.standard_normal((q, n, n)),
        rng.standard_normal((q, n, m)),
    )
    reg = obj.regression()
    assert reg.method == "state" and reg.num_outputs == n
    theta = rng.standard_normal(q)
    u = rng.standard_normal((30, m))
    y = simulate(*obj.matrices(theta), obj.H, u, x0=rng.standard_normal(n))
    phi, z = reg.build(u, y)
    assert phi.shape == (29, n, q)
    est, *_ = np.linalg.lstsq(phi.reshape(-1, q), z.reshape(-1), rcond=None)
    np.testing.assert_allclose(est, theta, atol=1e-9)
    # the same structure seen through y alone is bilinear in theta
    with pytest.raises(NotLinearInParameters, match=r"theta\[\d\]\*theta\[\d\]|\^2"):
        obj.regression("output")


# ------------------------------------------------------------------ structures that fail


def test_squared_parameter_is_named():
    obj = AffineStateSpace([[0, 1], [0, 0]], [0, 1], [1, 0], [np.eye(2)], names=["a"])
    with pytest.raises(NotLinearInParameters, match=r"c_0, the coefficient of y\(k\).*a\^2"):
        obj.regression()


def test_bilinear_parameters_are_named():
    Phi_terms = [[[1, 0], [0, 0]], [[0, 0], [0, 1]]]
    obj = AffineStateSpace([[0, 0], [1, 0]], [1, 0], [0, 1], Phi_terms, names=["p", "q"])
    with pytest.raises(NotLinearInParameters, match=r"p\*q term"):
        obj.regression()


def test_from_functions_equals_explicit_terms_and_rejects_non_affine():
    obj = AffineStateSpace.from_functions(
        lambda th: [[0, 1], [-0.3, th[0]]], [[0], [1]], [[1, 0]], num_params=1
    )
    np.testing.assert_array_equal(obj.Phi0, PAPER["Phi0"])
    np.testing.assert_array_equal(obj.Phi_terms, PAPER["Phi_terms"])
    with pytest.raises(NotLinearInParameters, match="Phi is not affine"):
        AffineStateSpace.from_functions(
            lambda th: [[0, 1], [-0.3, th[0] ** 2]], [[0], [1]], [[1, 0]], num_params=1
        )
    with pytest.raises(NotLinearInParameters, match="Gamma is not affine"):
        AffineStateSpace.from_functions(
            lambda th: [[0, 1], [-0.3, th[0]]],
            lambda th: [[0], [np.sin(th[0])]],
            [[1, 0]],
            num_params=1,
        )


def test_parameter_outside_the_observed_part_is_not_identifiable():
    # x2 never reaches y = x1: theta (the pole of x2) does not enter the input-output equation
    obj = AffineStateSpace([[0.5, 0], [0, 0]], [1, 1], [1, 0], [[[0, 0], [0, 1]]])
    with pytest.raises(ValueError, match=r"theta\[0\] does not change the transfer function"):
        obj.regression()


def test_parameters_in_a_fixed_combination_are_not_identifiable():
    term = [[0, 0], [0, 1]]
    obj = AffineStateSpace(PAPER["Phi0"], PAPER["Gamma0"], PAPER["H"], [term, term])
    with pytest.raises(ValueError, match="fixed combinations"):
        obj.regression()


# ------------------------------------------------------------------ bad input


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"Phi0": [[0, 1, 2], [0, 0, 1]]}, "Phi0 must be square"),
        ({"Phi0": [[0, np.nan], [0, 0]]}, "Phi0 must be finite"),
        ({"Gamma0": [0, 1, 2]}, r"Gamma0 must have 2 rows \(shape \(2, any\)\)"),
        ({"H": [1, 0, 0]}, "H must have 2 columns"),
        ({"Phi_terms": [[[0, 1, 0], [0, 0, 1]]]}, r"Phi_terms must have shape \(q, 2, 2\)"),
        ({"Phi_terms": [[0, 0], [0, 1]]}, "Phi_terms must be a sequence of matrices"),
        ({"Phi_terms": None}, "give Phi_terms or Gamma_terms"),
        ({"Gamma_terms": [[0, 1], [1, 0]]}, "Phi_terms and Gamma_terms must have one matrix"),
        ({"Phi_terms": [[[0, 0], [0, 0]]]}, r"Phi_terms\[0\] and Gamma_terms\[0\] are both zero"),
        ({"names": ["a", "b"]}, "names must hold 1 names"),
    ],
)
def test_bad_structures_name_the_argument(kwargs, match):
    with pytest.raises(ValueError, match=match):
        AffineStateSpace(**{**PAPER, **kwargs})


def test_bad_data_and_methods_name_the_argument():
    obj = AffineStateSpace(**PAPER)
    reg = obj.regression()
    with pytest.raises(ValueError, match="same number of samples"):
        reg.build(np.zeros(10), np.zeros(11))
    with pytest.raises(ValueError, match="y must be finite"):
        reg.build(np.zeros(10), np.r_[np.zeros(9), np.inf])
    with pytest.raises(ValueError, match="u must have shape"):
        reg.build(np.zeros((10, 2)), np.zeros(10))
    with pytest.raises(ValueError, match="y needs more than 2 samples"):
        reg.build(np.zeros(2), np.zeros(2))
    with pytest.raises(ValueError, match="method must be"):
        obj.regression("batch")
    with pytest.raises(ValueError, match="method='state' needs the whole state measured"):
        obj.regression("state")
    with pytest.raises(ValueError, match="theta must hold 1 values"):
        obj.matrices([1.0, 2.0])


# ------------------------------------------------------------------ the paper's example


def _script():
    """``benchmarks/voevoda_troshina_2016.py`` as a module: the tested numbers are its numbers."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "voevoda_troshina_2016.py"
    spec = importlib.util.spec_from_file_location("voevoda_troshina_2016", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def vt2016():
    return _script()


def test_paper_env_record_satisfies_equations_7_8(vt2016):
    """The StateSpace env with the paper's matrices obeys the eliminated equation exactly."""
    u, y, y_clean = vt2016.record(0)
    assert y.shape == (502,) and np.array_equal(y, y_clean)
    np.testing.assert_array_equal(u[:8], [1, 1, 1, -1, -1, -1, 1, 1])  # meander, period 6
    z = y[2:] + 0.3 * y[:-2] - u[:-2]
    np.testing.assert_allclose(z, -0.5 * y[1:-1], rtol=0, atol=1e-12)


def test_paper_noise_free_estimate_and_convergence(vt2016):
    history, clean = vt2016.estimate([0])
    phi = clean[0]
    S = np.cumsum(phi**2)
    # RLS from theta0 = 0 with P0 = 0.5 on noise-free data: -0.5 S / (1/P0 + S), exactly
    np.testing.assert_allclose(history[0], -0.5 * S / (2.0 + S), rtol=1e-12)
    assert abs(history[0, -1] - vt2016.PAPER_NOISE_FREE) < 0.005  # paper: -0.5008
    assert 40 <= vt2016.steps_to_within(history[0], -0.5, 0.05) <= 80  # paper: 50-60
    big, _ = vt2016.estimate([0], P0=1e6)
    np.testing.assert_allclose(big[0, -1], -0.5, rtol=1e-7)
    frozen, _ = vt2016.estimate([0], P0=0.0)
    np.testing.assert_array_equal(frozen, 0.0)  # P0 = 0: never moves


def test_paper_noisy_estimate_is_the_errors_in_variables_bias(vt2016):
    seeds = range(30)
    history, clean = vt2016.estimate(seeds, noise_var=0.025)
    final = history[:, -1]
    predicted = vt2016.eiv_prediction(clean, 0.025)
    sem = final.std(ddof=1) / np.sqrt(final.size)
    assert abs(final.mean() - predicted) < 4 * sem  # the bias is what the formula says
    assert final.mean() - 4 * sem > -0.5  # ... and it is a bias, not noise
    # the paper's single run lies within the spread of single runs (2 sd for v only)
    assert abs(vt2016.PAPER_NOISY - final.mean()) < 3 * final.std(ddof=1)
