"""Tests of the multichannel estimators (Voevoda & Troshina 2017; Kunik et al. 2001).

References are independent: regularised normal equations solved with ``numpy.linalg.solve``,
minimum-norm solutions from ``numpy.linalg.pinv``/``lstsq``, a hand-worked scalar case and the
numbers printed in the papers.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stcgym.adaptive.multivariable.multichannel import (
    MatrixRLS,
    NumericalHealthError,
    StateMatrixEstimator,
)

# ------------------------------------------------------------------ MatrixRLS


def test_hand_worked_scalar_case():
    # P0 = 0.5; (x, y) = (1, 2): K = 0.5 / 1.5 = 1/3, theta = 2/3, P = 0.5 - 0.25/1.5 = 1/3;
    # (x, y) = (2, 2): K = (2/3) / (7/3) = 2/7, theta = 2/3 + 2/7 (2 - 4/3) = 6/7, P = 1/7
    est = MatrixRLS(1, 1, P0=0.5)
    np.testing.assert_allclose(est.update([1.0], 2.0), [[2 / 3]])
    np.testing.assert_allclose([est.K[0], est.P[0, 0]], [1 / 3, 1 / 3])
    np.testing.assert_allclose(est.update([2.0], [2.0]), [[6 / 7]])
    np.testing.assert_allclose([est.K[0], est.P[0, 0]], [2 / 7, 1 / 7])
    assert est.t == 2


@pytest.mark.parametrize("forgetting", [1.0, 0.97])
def test_matrix_rls_equals_regularised_batch_least_squares(forgetting):
    rng = np.random.default_rng(0)
    n_in, n_out, N = 3, 2, 60
    X = rng.standard_normal((N, n_in))
    Y = X @ rng.standard_normal((n_in, n_out)) + 0.1 * rng.standard_normal((N, n_out))
    P0 = np.array([[2.0, 0.3, 0.0], [0.3, 1.0, 0.1], [0.0, 0.1, 0.5]])
    theta0 = rng.standard_normal((n_in, n_out))
    est = MatrixRLS(n_in, n_out, P0=P0, theta0=theta0, forgetting=forgetting)
    for k in range(N):
        est.update(X[k], Y[k])
    w = forgetting ** np.arange(N - 1, -1, -1)
    prior = forgetting**N * np.linalg.inv(P0)
    info = prior + X.T @ (w[:, None] * X)
    expected = np.linalg.solve(info, prior @ theta0 + X.T @ (w[:, None] * Y))
    np.testing.assert_allclose(est.theta, expected, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(est.P, np.linalg.inv(info), rtol=1e-9, atol=1e-14)


def test_one_gain_vector_serves_every_output_channel():
    rng = np.random.default_rng(1)
    X, Y = rng.standard_normal((30, 2)), rng.standard_normal((30, 3))
    joint = MatrixRLS(2, 3, P0=10.0)
    singles = [MatrixRLS(2, 1, P0=10.0) for _ in range(3)]
    for x, y in zip(X, Y, strict=True):
        joint.update(x, y)
        for j, s in enumerate(singles):
            s.update(x, y[j])
            np.testing.assert_allclose(s.K, joint.K, rtol=1e-12)
    np.testing.assert_allclose(joint.theta, np.hstack([s.theta for s in singles]), rtol=1e-12)


def test_non_symmetric_p0_is_used_as_printed():
    P0 = np.array([[0.5, 0.4], [0.5, 1.0]])  # Voevoda & Troshina's value
    rng = np.random.default_rng(2)
    X, Y = rng.choice([-1.0, 1.0], size=(25, 2)), rng.standard_normal((25, 2))
    est = MatrixRLS(2, 2, P0=P0)
    assert not est.symmetric
    for x, y in zip(X, Y, strict=True):
        est.update(x, y)
    # Sherman-Morrison holds for any invertible P0: P_N = (P0^{-1} + X^T X)^{-1}
    info = np.linalg.inv(P0) + X.T @ X
    np.testing.assert_allclose(est.P, np.linalg.inv(info), rtol=1e-10)
    np.testing.assert_allclose(est.theta, np.linalg.solve(info, X.T @ Y), rtol=1e-10)
    assert not np.allclose(est.P, est.P.T)  # the asymmetry persists, as the paper prints it


def square_wave(period: int, N: int) -> np.ndarray:
    """Unit-amplitude meander: +1 for the first half period, then -1 (sample k = 0, 1, ...)."""
    return np.where(np.arange(N) % period < period / 2, 1.0, -1.0)


VT_THETA = np.array([[1.0, 2.0], [0.0, 1.0]])
VT_P0 = np.array([[0.5, 0.4], [0.5, 1.0]])
VT_PAPER = {
    100: np.array([0.9505, 1.935, 0.02, 1.034]),
    200: np.array([0.9791, 1.962, 0.01646, 1.025]),
}


def voevoda_troshina_runs(P0, seeds=range(100), N=200):
    """Estimates (theta11, theta12, theta21, theta22) at N = 100 and N = 200 for each seed."""
    X = np.column_stack([square_wave(6, N), square_wave(4, N)])
    out = {100: [], 200: []}
    gains = None
    for seed in seeds:
        noise = np.random.default_rng(seed).normal(0.0, 0.1, size=(N, 2))  # variance 0.01
        est = MatrixRLS(2, 2, P0=P0)
        for k in range(N):
            est.update(X[k], X[k] @ VT_THETA + noise[k])
            if k + 1 in out:
                out[k + 1].append(est.theta.ravel())
            if k + 1 == 100:
                gains = est.K.copy()  # independent of the noise
    return {N_: np.array(v) for N_, v in out.items()}, gains


def test_voevoda_troshina_example():
    """Voevoda & Troshina (2017), section 2: 2x2 static object, meanders of periods 6 and 4.

    Set-up (seed 000): ``y^T = x^T Theta + v`` with ``Theta = [[1, 2], [0, 1]]`` read as printed
    in the recursion's row form (reading the example as ``y = Theta x`` instead puts the paper's
    values 5-8 standard deviations away), inputs the unit-amplitude square waves starting at +1,
    ``v ~ N(0, 0.01 I)``, ``Theta0 = 0`` and ``P0 = [[0.5, 0.4], [0.5, 1]]`` as printed.

    The paper reports a single run, so the relevant spread is that of single-run estimates. Over
    100 seeds, for each of the 8 reported numbers: ``|paper - mean| <= 3 std`` (std of the 100
    single-run estimates; 3 sigma keeps the familywise false-alarm rate near 2 %), and the paper's
    deviation from the truth has the sign of the mean deviation (the deviations are the
    shrinkage of the small ``P0`` prior towards ``Theta0 = 0``; see the next test). The gain at
    N = 100, which does not depend on the noise, must match the printed
    ``K = [-0.01028, -0.01047]`` in sign and within 10 %.
    """
    est, K100 = voevoda_troshina_runs(VT_P0)
    truth = VT_THETA.ravel()
    for N, paper in VT_PAPER.items():
        mean, std = est[N].mean(axis=0), est[N].std(axis=0, ddof=1)
        assert np.all(np.abs(paper - mean) <= 3 * std), (N, mean, std, paper)
        assert np.all(np.sign(paper - truth) == np.sign(mean - truth)), (N, mean, paper)
    np.testing.assert_allclose(K100, [-0.01028, -0.01047], rtol=0.10)


def test_voevoda_troshina_deviation_is_the_prior_not_noise():
    """With an uninformative ``P0 = 1e6 I`` the estimates are unbiased and the paper's numbers
    fall outside the 3-sigma band, i.e. the test above can fail and discriminates the set-up."""
    est, _ = voevoda_troshina_runs(1e6 * np.eye(2), seeds=range(50))
    mean, std = est[100].mean(axis=0), est[100].std(axis=0, ddof=1)
    assert np.any(np.abs(VT_PAPER[100] - mean) > 3 * std)


def test_matrix_rls_bad_input():
    with pytest.raises(ValueError, match="n_inputs"):
        MatrixRLS(0, 1)
    with pytest.raises(ValueError, match="n_outputs"):
        MatrixRLS(2, True)
    for lam in (0.0, -0.5, 1.5, float("nan")):
        with pytest.raises(ValueError, match="forgetting"):
            MatrixRLS(2, 2, forgetting=lam)
    with pytest.raises(ValueError, match=r"P0 must have 2 rows \(shape \(2, 2\)\)"):
        MatrixRLS(2, 2, P0=np.eye(3))
    with pytest.raises(ValueError, match="P0 must be finite"):
        MatrixRLS(2, 2, P0=[[1.0, np.nan], [np.nan, 1.0]])
    with pytest.raises(ValueError, match="symmetric positive definite"):
        MatrixRLS(2, 2, P0=[[1.0, 2.0], [2.0, 1.0]])
    with pytest.raises(ValueError, match="symmetric part"):
        MatrixRLS(2, 2, P0=[[1.0, 3.0], [0.0, -1.0]])
    with pytest.raises(ValueError, match="P0 must be a finite number > 0"):
        MatrixRLS(2, 2, P0=-1.0)
    with pytest.raises(ValueError, match=r"theta0 must have 2 columns \(shape \(2, 2\)\)"):
        MatrixRLS(2, 2, theta0=np.zeros((2, 3)))
    with pytest.raises(ValueError, match="on_failure"):
        MatrixRLS(2, 2, on_failure="ignore")
    est = MatrixRLS(2, 2)
    with pytest.raises(ValueError, match="x must have length 2"):
        est.update([1.0, 2.0, 3.0], [0.0, 0.0])
    with pytest.raises(ValueError, match="y must be finite"):
        est.update([1.0, 2.0], [0.0, np.inf])
    assert est.t == 0


def test_overflow_is_detected_and_state_left_unchanged():
    est = MatrixRLS(2, 1, P0=1.0, on_failure="raise")
    est.update([1.0, 0.0], [1.0])
    P, theta = est.P.copy(), est.theta.copy()
    with pytest.raises(NumericalHealthError, match="MatrixRLS update 2"):
        est.update([1e200, 1e200], [1e300])
    np.testing.assert_array_equal(est.P, P)
    np.testing.assert_array_equal(est.theta, theta)


def test_reset_is_the_default_and_restores_p0():
    est = MatrixRLS(2, 1, P0=3.0)
    est.update([1.0, 0.0], [1.0])
    theta = est.theta.copy()
    with pytest.warns(RuntimeWarning, match="reset to P0"):
        est.update([1e200, 1e200], [1e300])
    np.testing.assert_allclose(est.P, 3.0 * np.eye(2), rtol=1e-15, atol=0.0)
    np.testing.assert_array_equal(est.theta, theta)
    assert est.n_resets == 1 and est.t == 2


def test_forgetting_windup_overflow_is_reported():
    # no excitation with lambda < 1: P grows like lambda^-t until it overflows
    est = MatrixRLS(1, 1, P0=1e300, forgetting=0.5, on_failure="raise")
    with pytest.raises(NumericalHealthError, match="overflow"):
        for _ in range(100):
            est.update([0.0], [0.0])
    assert np.all(np.isfinite(est.P))


@settings(max_examples=40, deadline=None, derandomize=True)
@given(
    n=st.integers(1, 4),
    forgetting=st.floats(0.9, 1.0),
    p0=st.floats(1e-3, 1e6),
    steps=st.integers(200, 500),
    seed=st.integers(0, 2**32 - 1),
    kind=st.sampled_from(["gauss", "sparse", "collinear", "large"]),
)
def test_p_stays_symmetric_positive_definite(n, forgetting, p0, steps, seed, kind):
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((steps, n))
    if kind == "sparse":  # long stretches without excitation (wind-up with lambda < 1)
        X *= rng.random(steps)[:, None] < 0.05
    elif kind == "collinear":  # regressors confined to one direction most of the time
        X = np.where(rng.random(steps)[:, None] < 0.9, rng.standard_normal((steps, 1)), X)
    elif kind == "large":
        X *= 10.0 ** rng.uniform(-3, 3, size=(steps, 1))
    Y = X @ rng.standard_normal((n, 2)) + rng.standard_normal((steps, 2))
    est = MatrixRLS(n, 2, P0=p0, forgetting=forgetting)
    for x, y in zip(X, Y, strict=True):
        est.update(x, y)
        P = est.P
        assert np.all(np.isfinite(P)) and np.all(np.isfinite(est.theta))
        np.testing.assert_array_equal(P, P.T)
        assert np.linalg.eigvalsh(P)[0] > 0


# ------------------------------------------------------------------ StateMatrixEstimator


def random_plant(m, N, rng):
    A = rng.standard_normal((m, m))
    A *= 0.9 / max(1.0, np.max(np.abs(np.linalg.eigvals(A))))
    return A, rng.standard_normal((m, N))


def test_minimum_norm_phase_then_exact():
    rng = np.random.default_rng(3)
    m, N = 3, 2
    A, B = random_plant(m, N, rng)
    est = StateMatrixEstimator(m, N)
    Z, Xn = [], []
    x = rng.standard_normal(m)
    for t in range(1, m + N + 4):
        u = rng.standard_normal(N)
        x_next = A @ x + B @ u
        C = est.update(x, u, x_next)
        Z.append(np.r_[x, u])
        Xn.append(x_next)
        Zm, Xm = np.array(Z).T, np.array(Xn).T  # columns are samples, as in (6)-(8)
        if t < m + N:
            assert est.phase == "minimum_norm" and est.P is None
            np.testing.assert_allclose(C, Xm @ np.linalg.pinv(Zm), atol=1e-10)  # (10)
        else:
            assert est.phase == "rls"
            np.testing.assert_allclose(C, np.hstack([A, B]), atol=1e-9)  # exact
        x = x_next
    np.testing.assert_allclose(est.A, A, atol=1e-9)
    np.testing.assert_allclose(est.B, B, atol=1e-9)


def drive(est, A, B, rng, T, noise_std):
    """Feed ``est`` ``T`` samples of ``x+ = A x + B u + w`` (white ``u``, ``w`` of std
    ``noise_std``); returns the regressors ``[x; u]`` and the next states, one row per sample."""
    m, N = B.shape
    Z, Xn = [], []
    x = rng.standard_normal(m)
    for _ in range(T):
        u = rng.standard_normal(N)
        x_next = A @ x + B @ u + noise_std * rng.standard_normal(m)
        est.update(x, u, x_next)
        Z.append(np.r_[x, u])
        Xn.append(x_next)
        x = x_next
    return np.array(Z), np.array(Xn)


def test_rls_phase_equals_batch_least_squares_with_noise():
    rng = np.random.default_rng(4)
    m, N, T = 2, 1, 80
    A, B = random_plant(m, N, rng)
    est = StateMatrixEstimator(m, N)
    Z, Xn = drive(est, A, B, rng, T, 0.05)
    C_ls = np.linalg.lstsq(Z, Xn, rcond=None)[0].T  # (11)
    np.testing.assert_allclose(est.C, C_ls, atol=1e-9)
    assert np.all(np.linalg.eigvalsh(est.P) > 0)


def test_dependent_samples_in_minimum_norm_phase():
    rng = np.random.default_rng(5)
    m, N = 2, 2
    A, B = random_plant(m, N, rng)
    z1, z2 = rng.standard_normal(4), rng.standard_normal(4)
    zs = [z1, z2, 2.0 * z1 - z2, z1, np.zeros(4)]  # the last three are dependent
    targets = [A @ z[:m] + B @ z[m:] + 0.1 * rng.standard_normal(m) for z in zs]
    est = StateMatrixEstimator(m, N)
    for k, (z, xn) in enumerate(zip(zs, targets, strict=True)):
        est.update(z[:m], z[m:], xn)
        Zm, Xm = np.array(zs[: k + 1]).T, np.array(targets[: k + 1]).T
        np.testing.assert_allclose(est.C, Xm @ np.linalg.pinv(Zm), atol=1e-9)
    assert est.rank == 2 and est.phase == "minimum_norm"


def test_state_estimator_forgetting_is_weighted_least_squares():
    rng = np.random.default_rng(6)
    m, N, T, lam = 2, 1, 50, 0.9
    A, B = random_plant(m, N, rng)
    est = StateMatrixEstimator(m, N, forgetting=lam)
    Z, Xn = drive(est, A, B, rng, T, 0.1)
    w = np.sqrt(lam ** np.arange(T - 1, -1, -1))[:, None]
    C_wls = np.linalg.lstsq(w * Z, w * Xn, rcond=None)[0].T
    np.testing.assert_allclose(est.C, C_wls, atol=1e-8)


def test_state_estimator_bad_input():
    with pytest.raises(ValueError, match="m must be"):
        StateMatrixEstimator(0, 1)
    with pytest.raises(ValueError, match="N"):
        StateMatrixEstimator(2, -1)
    with pytest.raises(ValueError, match="forgetting"):
        StateMatrixEstimator(2, 1, forgetting=0.0)
    with pytest.raises(ValueError, match=r"C0 must have 3 columns \(shape \(2, 3\)\)"):
        StateMatrixEstimator(2, 1, C0=np.zeros((2, 2)))
    est = StateMatrixEstimator(2, 1)
    with pytest.raises(ValueError, match="u_t must have length 1"):
        est.update([0.0, 1.0], [1.0, 2.0], [0.0, 0.0])
    with pytest.raises(ValueError, match="x_next must be finite"):
        est.update([0.0, 1.0], [1.0], [np.nan, 0.0])
    assert est.t == 0
    # N = 0 estimates A alone
    a_only = StateMatrixEstimator(1, 0)
    a_only.update([2.0], [], [1.0])
    np.testing.assert_allclose(a_only.A, [[0.5]])
    with pytest.raises(ValueError, match="u_t must be empty"):
        a_only.update([2.0], [1.0], [1.0])
    assert a_only.B.shape == (1, 0)


@settings(max_examples=20, deadline=None, derandomize=True)
@given(
    m=st.integers(1, 3),
    N=st.integers(0, 2),
    forgetting=st.floats(0.9, 1.0),
    seed=st.integers(0, 2**32 - 1),
)
def test_state_estimator_long_runs_stay_healthy(m, N, forgetting, seed):
    rng = np.random.default_rng(seed)
    A, B = random_plant(m, N, rng)
    est = StateMatrixEstimator(m, N, forgetting=forgetting)
    x = rng.standard_normal(m)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for _ in range(300):
            u = rng.standard_normal(N) * (rng.random() < 0.5)
            x_next = A @ x + B @ u + 0.01 * rng.standard_normal(m)
            est.update(x, u, x_next)
            assert np.all(np.isfinite(est.C))
            if est.P is not None:
                P = est.P
                np.testing.assert_array_equal(P, P.T)
                assert np.all(np.isfinite(P)) and np.linalg.eigvalsh(P)[0] > 0
            x = x_next
