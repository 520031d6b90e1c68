"""Tests of the multi-input LQ design (:func:`stcgym.adaptive.multivariable.mimo_lq.dare_solve`):
every positive semidefinite state weight with a stabilising solution, the cross weight ``N``,
and the cause named when no stabilising solution exists.

Independent reference: python-control's ``dlqr(A, B, Q, R, N)`` (scipy's DARE solver), the
Riccati equation itself, and the closed loop of the identified model.
"""

from __future__ import annotations

import control
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from lane_call import call

from stcgym.adaptive import LQRController, MultivariableSelfTuningController
from stcgym.adaptive.control.safe_set import OK, UNIT_CIRCLE_MODE
from stcgym.adaptive.multivariable import mimo_lq


def _solve(A, B, Q, R, N=None):
    """``(status, K, P)`` of the compiled solve."""
    B = np.asarray(B, dtype=float)
    n, m = B.shape
    N = np.zeros((n, m)) if N is None else np.asarray(N, dtype=float)
    P = np.zeros((n, n))
    K = np.zeros((m, n))
    work = mimo_lq.mimo_design_work(n, m)
    A, B, Q, R, N = (np.ascontiguousarray(M, dtype=float) for M in (A, B, Q, R, N))
    status = mimo_lq.dare_solve(A, B, mimo_lq.LQProblem(Q, R, N, 1e-12, 64), P, K, work, 0)
    return status, K, P


def _assert_close(X, X_ref, rtol):
    scale = max(1.0, float(np.max(np.abs(X_ref))))
    np.testing.assert_allclose(X, X_ref, rtol=rtol, atol=rtol * scale)


# ------------------------------------------------------------------ singular Q


def test_unweighted_unstable_scalar_mode():
    # doubling from Q = 0 stays at P = 0 (the solution that leaves the mode 2 alone)
    K_ref, P_ref, _ = control.dlqr(2.0, 1.0, 0.0, 1.0)
    oracle = LQRController(np.array([[2.0]]), np.array([[1.0]]), Q=0.0, R=1.0)
    np.testing.assert_allclose(oracle.K, K_ref, rtol=1e-12)
    np.testing.assert_allclose(oracle.K, [[1.5]], rtol=1e-12)
    status, K, P = _solve([[2.0]], [[1.0]], [[0.0]], [[1.0]])
    assert status == OK
    np.testing.assert_allclose(P, P_ref, rtol=1e-12)
    np.testing.assert_allclose(P, [[3.0]], rtol=1e-12)


def test_unweighted_unstable_mode_of_two():
    A, B, Q, R = np.diag([1.05, 0.5]), np.eye(2), np.diag([0.0, 1.0]), 0.01 * np.eye(2)
    K_ref, P_ref, _ = control.dlqr(A, B, Q, R)
    oracle = LQRController(A, B, Q=Q, R=0.01)
    _assert_close(oracle.K, K_ref, 1e-10)
    np.testing.assert_allclose(np.diag(oracle.K), [0.0976, 0.4951], atol=5e-5)
    status, K, P = _solve(A, B, Q, R)
    assert status == OK
    _assert_close(P, P_ref, 1e-10)


def _random_problem(rng, n, m, rank, cross):
    """A random ``(A, B, Q, R, N)``: ``Q - N R^-1 N^T`` of rank ``rank``, eigenvalues of ``A``
    and of ``A - B R^-1 N^T`` away from the unit circle (a stabilising solution exists)."""
    A = rng.standard_normal((n, n))
    A *= rng.uniform(0.3, 1.6) / np.max(np.abs(np.linalg.eigvals(A)))
    B = rng.standard_normal((n, m))
    C = rng.standard_normal((rank, n))
    D = rng.standard_normal((rank, m)) if cross else np.zeros((rank, m))
    # joint weight [C D]^T [C D] plus a positive definite part on the input
    R = D.T @ D + np.diag(rng.uniform(0.05, 2.0, m))
    Q = C.T @ C
    N = C.T @ D
    return A, B, Q, R, N


@settings(max_examples=100, deadline=None)
@given(
    n=st.integers(1, 4),
    m=st.integers(1, 3),
    rank_gap=st.integers(1, 4),
    cross=st.booleans(),
    seed=st.integers(0, 2**32 - 1),
)
def test_dare_equals_dlqr_with_singular_weights(n, m, rank_gap, cross, seed):
    rng = np.random.default_rng(seed)
    rank = max(0, n - rank_gap)  # singular: rank < n (zero weight included)
    A, B, Q, R, N = _random_problem(rng, n, m, rank, cross)
    RNt = np.linalg.solve(R, N.T)
    for M in (A, A - B @ RNt):
        assume(np.min(np.abs(np.abs(np.linalg.eigvals(M)) - 1.0)) > 0.05)
    # well-conditioned reachability of the modes on or outside the unit circle
    s = np.linalg.svd(control.ctrb(A, B), compute_uv=False)
    assume(s[-1] > 1e-3 * s[0])
    K_ref, P_ref, _ = control.dlqr(A, B, Q, R, N)
    status, K, P = _solve(A, B, Q, R, N)
    assert status == OK
    _assert_close(K, K_ref, 1e-8)
    _assert_close(P, P_ref, 1e-8)
    assert np.max(np.abs(np.linalg.eigvals(A - B @ K))) < 1.0


# ------------------------------------------------------------------ cross weight


@pytest.mark.parametrize("seed", range(4))
def test_cross_weight_equals_dlqr(seed):
    rng = np.random.default_rng(seed)
    n, m = 3 + seed % 2, 1 + seed % 2
    A, B, Q, R, N = _random_problem(rng, n, m, n, cross=True)
    Q += np.eye(n)
    K_ref, P_ref, _ = control.dlqr(A, B, Q, R, N)
    oracle = LQRController(A, B, Q=Q, R=R, N=N)
    _assert_close(oracle.K, K_ref, 1e-8)
    status, K, P = _solve(A, B, Q, R, N)
    assert status == OK
    _assert_close(P, P_ref, 1e-8)
    # the per-sample Riccati iteration (with N) converges to the same solution
    P_it = Q.copy()
    K_it = np.zeros((m, n))
    work = mimo_lq.mimo_design_work(n, m)
    problem = mimo_lq.LQProblem(Q, R, N, 1e-12, 64)
    for _ in range(5000):
        call(mimo_lq.riccati_step, A, B, problem, P_it, K_it, work, 0)
    _assert_close(P_it, P_ref, 1e-7)


def test_cross_weight_moves_the_equilibrium_to_the_cheapest_one():
    # the feed-forward's equilibrium minimises [x - r; u]^T W [x - r; u] on (A - I) x + B u = 0
    rng = np.random.default_rng(3)
    n, m = 3, 2
    A, B, Q, R, N = _random_problem(rng, n, m, n, cross=True)
    Q += np.eye(n)
    oracle = LQRController(A, B, Q=Q, R=R, N=N, action_bound=np.inf)
    r = rng.standard_normal(n)
    x = np.linalg.solve(np.eye(n) - A + B @ oracle.K, B @ oracle.F @ r)
    u = -oracle.K @ x + oracle.F @ r
    # independent: the KKT conditions of the constrained quadratic problem
    W = np.block([[Q, N], [N.T, R]])
    E = np.hstack((A - np.eye(n), B))
    grad = W @ np.concatenate((x - r, u))
    mu = np.linalg.lstsq(E.T, -grad, rcond=None)[0]
    np.testing.assert_allclose(E.T @ mu + grad, 0.0, atol=1e-9)
    np.testing.assert_allclose(E @ np.concatenate((x, u)), 0.0, atol=1e-10)


@pytest.mark.parametrize(
    ("N", "match"),
    [
        (np.ones((2, 2)), "N must be a finite 2 x 1"),
        (np.ones(3), "N must be a finite 2 x 1"),
        ([[np.nan], [0.0]], "N must be a finite"),
        ([[10.0], [0.0]], r"N must leave the joint weight"),
    ],
)
def test_bad_cross_weight_is_refused(N, match):
    A, B = np.array([[1.1, 0.1], [0.0, 0.9]]), np.array([[0.0], [1.0]])
    with pytest.raises(ValueError, match=match):
        LQRController(A, B, Q=1.0, R=1.0, N=N)
    with pytest.raises(ValueError, match=match):
        MultivariableSelfTuningController(2, 1, Q=1.0, R=1.0, N=N)


# ------------------------------------------------------------------ no stabilising solution


def test_unobservable_mode_on_the_unit_circle_is_named():
    A, B = np.diag([1.0, 0.5]), np.eye(2)
    status, _, _ = _solve(A, B, np.diag([0.0, 1.0]), np.eye(2))
    assert status == UNIT_CIRCLE_MODE
    with pytest.raises(ValueError, match="unobservable through the state weight"):
        LQRController(A, B, Q=np.diag([0.0, 1.0]), R=1.0)
    # a rotation on the unit circle: a complex pair unweighted
    c, s = np.cos(0.3), np.sin(0.3)
    A = np.block([[np.array([[c, -s], [s, c]]), np.zeros((2, 1))], [np.zeros((1, 2)), 0.5]])
    with pytest.raises(ValueError, match="unobservable through the state weight"):
        LQRController(A, np.eye(3)[:, :2], Q=np.diag([0.0, 0.0, 1.0]), R=1.0)


def test_unstabilisable_pair_is_named():
    with pytest.raises(ValueError, match=r"not stabilisable.*1\.2"):
        LQRController(np.diag([1.2, 0.5]), [[0.0], [1.0]])
    # not stabilisable even though Q does not see the mode
    with pytest.raises(ValueError, match="not stabilisable"):
        LQRController(np.diag([1.2, 0.5]), [[0.0], [1.0]], Q=np.diag([0.0, 1.0]))


# ------------------------------------------------------------------ self-tuning controller


@pytest.mark.parametrize("cross", [False, True])
def test_self_tuning_design_takes_singular_weights_and_cross_weight(cross):
    # without the fallback the unweighted unstable mode is never designed for: probing goes on
    A, B = np.diag([1.05, 0.5]), np.eye(2)
    Q, R = np.diag([0.0, 1.0]), 0.01 * np.eye(2)
    N = np.array([[0.0, 0.0], [0.05, 0.0]]) if cross else None
    stc = MultivariableSelfTuningController(2, 2, Q=Q, R=R, N=N, seed=0)
    x, r = np.array([0.3, -0.2]), np.zeros(2)
    for _ in range(40):
        u, _ = stc.predict(np.concatenate([x, r]))
        x = A @ x + B @ u
    assert stc.diagnostics["has_gain"]
    K_ref = control.dlqr(A, B, Q, R, np.zeros((2, 2)) if N is None else N)[0]
    _assert_close(stc.K, K_ref, 1e-8)
    # the unweighted mode is mirrored inside the unit circle (1 / 1.05), not driven to zero
    np.testing.assert_allclose(np.sort(np.abs(np.linalg.eigvals(A - B @ stc.K))).max(), 1 / 1.05)
