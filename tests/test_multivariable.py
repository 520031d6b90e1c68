"""Tests of the multivariable self-tuning LQ controller, its oracle and the MIMO plants.

Independent references: python-control's ``dlqr`` for the LQ gain, ``numpy.linalg.lstsq`` /
``pinv`` for the ``[A B]`` estimator, the constrained least-squares equilibrium solved on the
null space of ``[A - I, B]`` (``scipy.linalg.null_space``) for the feed-forward, and the
oracle's closed-loop cost on the same episode.
"""

from __future__ import annotations

import pickle

import control
import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from lane_call import call
from scipy.linalg import null_space

import stcgym.envs  # noqa: F401  (registers the envs)
from stcgym.adaptive import LQRController, MultivariableSelfTuningController
from stcgym.adaptive.multivariable import mimo_lq
from stcgym.adaptive.multivariable.multichannel import StateMatrixEstimator
from stcgym.adaptive.multivariable.state_matrix import make_state_matrix, state_matrix_update
from stcgym.envs import MIMO_PLANTS, Jumps, get_mimo_plant

# ------------------------------------------------------------------ plants


def test_catalogue_table_matches_the_matrices():
    expected = {  # the module docstring's table: pole magnitudes, stability
        "quadruple_tank": ([0.805, 0.846, 0.923, 0.946], True),
        "quadruple_tank_nmp": ([0.880, 0.915, 0.924, 0.946], True),
        "he1": ([0.813, 0.977, 1.028, 1.028], False),
        "ac1": ([0.925, 0.925, 0.998, 0.998, 1.0], False),
    }
    assert set(MIMO_PLANTS) == set(expected)
    for name, (mags, stable) in expected.items():
        spec = get_mimo_plant(name)
        np.testing.assert_allclose(np.sort(np.abs(spec.poles)), mags, atol=6e-4)
        assert spec.stable == stable
        A, B = spec.discrete()
        assert np.linalg.matrix_rank(control.ctrb(A, B)) == spec.n_states


def test_state_space_env_takes_a_catalogue_name():
    env = gym.make("stcgym/StateSpace-v0", plant="he1")
    A, B = get_mimo_plant("he1").discrete()
    np.testing.assert_array_equal(env.unwrapped.A, A)
    np.testing.assert_array_equal(env.unwrapped.C, np.eye(4))
    assert env.unwrapped.dt == 0.1
    sysd = control.sample_system(
        control.ss(np.array(MIMO_PLANTS["he1"].A_c), np.array(MIMO_PLANTS["he1"].B_c),
                   np.eye(4), 0), 0.1)  # fmt: skip
    np.testing.assert_allclose(A, sysd.A, rtol=1e-12)
    with pytest.raises(ValueError, match="plant must be one of"):
        gym.make("stcgym/StateSpace-v0", plant="nope")
    with pytest.raises(ValueError, match="either plant"):
        gym.make("stcgym/StateSpace-v0", plant="he1", A=np.eye(4), B=np.ones((4, 2)))


# ------------------------------------------------------------------ estimator kernel


def _estimator(n, m):
    """One lane of the estimator's state and scratch."""
    return make_state_matrix(n, m, 1)


def _feed(est, work, X, U, lam=1.0):
    for k in range(len(U)):
        est.z[0] = np.concatenate((X[k], U[k]))
        call(state_matrix_update, est, work, 0, np.ascontiguousarray(X[k + 1]), lam, 1e-9, 100.0)
    return est.theta[0].T  # C = [A B]


@pytest.mark.parametrize("forgetting", [1.0, 0.98])
def test_estimator_equals_batch_least_squares(forgetting):
    rng = np.random.default_rng(3)
    n, m, T = 3, 2, 40
    A = 0.5 * rng.standard_normal((n, n))
    B = rng.standard_normal((n, m))
    U = rng.standard_normal((T, m))
    X = np.zeros((T + 1, n))
    for k in range(T):
        X[k + 1] = A @ X[k] + B @ U[k] + 0.05 * rng.standard_normal(n)
    est, work = _estimator(n, m)
    # minimum-norm phase: C = X Z^+ (Kunik et al. (10)) and the Python estimator
    q = n + m
    Z = np.hstack((X[:-1], U))
    C_mn = _feed(est, work, X[: q - 1], U[: q - 2])
    ref = StateMatrixEstimator(n, m)
    for k in range(q - 2):
        ref.update(X[k], U[k], X[k + 1])
    np.testing.assert_allclose(C_mn, X[1 : q - 1].T @ np.linalg.pinv(Z[: q - 2].T), atol=1e-10)
    np.testing.assert_allclose(C_mn, ref.C, atol=1e-10)
    # the whole record: weighted batch least squares
    est, work = _estimator(n, m)
    C = _feed(est, work, X, U, forgetting)
    w = np.sqrt(forgetting ** np.arange(T - 1, -1, -1))[:, None]
    expected = np.linalg.lstsq(w * Z, w * X[1:], rcond=None)[0].T
    np.testing.assert_allclose(C, expected, rtol=1e-8, atol=1e-10)
    assert est.rank[0] == q


@settings(max_examples=30, deadline=None)
@given(
    n=st.integers(1, 4),
    m=st.integers(1, 3),
    extra=st.integers(0, 30),
    forgetting=st.sampled_from([1.0, 0.99, 0.9]),
    seed=st.integers(0, 2**31),
)
def test_estimator_property_batch_least_squares(n, m, extra, forgetting, seed):
    # any dimensions, any record length past the switch: the weighted batch estimate
    rng = np.random.default_rng(seed)
    T = n + m + extra
    X = rng.standard_normal((T + 1, n))
    U = rng.standard_normal((T, m))
    est, work = _estimator(n, m)
    C = _feed(est, work, X, U, forgetting)
    Z = np.hstack((X[:-1], U))
    w = np.sqrt(forgetting ** np.arange(T - 1, -1, -1))[:, None]
    expected = np.linalg.lstsq(w * Z, w * X[1:], rcond=None)[0].T
    np.testing.assert_allclose(C, expected, rtol=1e-7, atol=1e-8)


def test_estimator_counts_dependent_regressors_in_the_switch():
    # a repeated regressor in the minimum-norm phase leaves C, but enters the batch estimate
    rng = np.random.default_rng(4)
    n, m = 2, 1
    Z = rng.standard_normal((4, 3))
    Z[1] = 2.0 * Z[0]
    Y = rng.standard_normal((4, 2))
    est, work = _estimator(n, m)
    for k in range(4):
        est.z[0] = Z[k]
        status = call(state_matrix_update, est, work, 0, Y[k].copy(), 1.0, 1e-9, 100.0)
        assert status == (1 if k == 1 else 0)
    expected = np.linalg.lstsq(Z, Y, rcond=None)[0].T
    np.testing.assert_allclose(est.theta[0].T, expected, atol=1e-10)


# ------------------------------------------------------------------ design kernels


def _random_plant(rng, n, m, unstable=False):
    while True:
        A = rng.standard_normal((n, n))
        radius = rng.uniform(1.02, 1.2) if unstable else rng.uniform(0.3, 0.95)
        A *= radius / np.max(np.abs(np.linalg.eigvals(A)))
        B = rng.standard_normal((n, m))
        if np.linalg.matrix_rank(control.ctrb(A, B)) == n:
            return A, B


@pytest.mark.parametrize("seed", range(6))
def test_lq_gain_equals_dlqr(seed):
    rng = np.random.default_rng(seed)
    n, m = 2 + seed % 3, 1 + seed % 2
    A, B = _random_plant(rng, n, m, unstable=seed % 2 == 0)
    Q = np.diag(rng.uniform(0.5, 2.0, n))
    R = np.diag(rng.uniform(0.01, 1.0, m))
    K_ref, P_ref, _ = control.dlqr(A, B, Q, R)
    oracle = LQRController(A, B, Q=Q, R=R)
    np.testing.assert_allclose(oracle.K, K_ref, rtol=1e-8, atol=1e-10)
    # the per-sample Riccati iteration converges to the same solution
    P = Q.copy()
    K = np.zeros((m, n))
    work = mimo_lq.mimo_design_work(n, m)
    problem = mimo_lq.LQProblem(Q, R, np.zeros((n, m)), 1e-12, 64)
    for _ in range(3000):
        call(mimo_lq.riccati_step, A, B, problem, P, K, work, 0)
    mimo_lq.lq_gain(A, B, problem, P, K, work, 0)
    np.testing.assert_allclose(P, P_ref, rtol=1e-7)
    np.testing.assert_allclose(K, K_ref, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("seed", range(4))
def test_feedforward_reaches_the_cheapest_equilibrium(seed):
    rng = np.random.default_rng(10 + seed)
    n, m = 3, 1 + seed % 3
    A, B = _random_plant(rng, n, m)
    Q, R = np.eye(n), 0.05 * np.eye(m)
    oracle = LQRController(A, B, Q=Q, R=R, action_bound=np.inf)
    r = rng.standard_normal(n)
    # equilibrium of the closed loop u = -K x + F r
    K, F = oracle.K, oracle.F
    x_cl = np.linalg.solve(np.eye(n) - A + B @ K, B @ F @ r)
    u_cl = -K @ x_cl + F @ r
    # independent: minimise |x - r|^2 + 0.05 |u|^2 on the null space of [A - I, B]
    N = null_space(np.hstack((A - np.eye(n), B)))
    W = np.sqrt(np.diag(np.concatenate((np.ones(n), 0.05 * np.ones(m)))))
    target = np.concatenate((r, np.zeros(m)))
    c = np.linalg.lstsq(W @ N, W @ target, rcond=None)[0]
    np.testing.assert_allclose(np.concatenate((x_cl, u_cl)), N @ c, rtol=1e-8, atol=1e-10)


def test_oracle_lanes_take_their_own_matrices():
    rng = np.random.default_rng(7)
    plants = [_random_plant(rng, 3, 2, unstable=i == 1) for i in range(3)]
    As = np.stack([A for A, _ in plants])
    Bs = np.stack([B for _, B in plants])
    batch = LQRController(As, Bs, num_envs=3)
    obs = rng.standard_normal((3, 6))
    u = batch.predict(obs)[0]
    assert u.shape == (3, 2) and batch.K.shape == (3, 2, 3)
    for i, (A, B) in enumerate(plants):
        single = LQRController(A, B)
        np.testing.assert_array_equal(single.K, batch.K[i])
        expected = np.clip(-single.K @ obs[i, :3] + single.F @ obs[i, 3:], -10, 10)
        np.testing.assert_allclose(single.predict(obs[i])[0], expected, rtol=1e-12)
        np.testing.assert_allclose(u[i], expected, rtol=1e-12)
    with pytest.raises(ValueError, match="per-lane A and B"):
        LQRController(As, Bs, num_envs=2)


def test_stability_test_by_squaring():
    work = mimo_lq.mimo_design_work(2, 1)
    assert call(mimo_lq.schur_stable, np.array([[0.999, 1e3], [0.0, 0.5]]), work, 0)
    assert not call(mimo_lq.schur_stable, np.array([[1.001, 0.0], [0.0, 0.1]]), work, 0)
    assert not call(mimo_lq.schur_stable, np.array([[1.0, 1.0], [0.0, 1.0]]), work, 0)
    assert not call(mimo_lq.schur_stable, np.array([[np.nan, 0.0], [0.0, 0.1]]), work, 0)


# ------------------------------------------------------------------ closed loop


def _episode(env, policy, seed, steps):
    obs, _ = env.reset(seed=seed)
    costs = []
    for _ in range(steps):
        action, _ = policy.predict(obs)
        obs, reward, terminated, truncated, _ = env.step(action)
        costs.append(-reward)
        if terminated or truncated:
            break
    return np.array(costs), terminated


@pytest.mark.parametrize(("plant", "estimate_tol"), [("quadruple_tank", 0.15), ("he1", 0.02)])
def test_closed_loop_cost_near_the_oracle(plant, estimate_tol):
    # in closed loop only the feedback's excitation identifies [A B]: the slow quadruple tank's
    # estimate stays off by up to 0.1 in some entries, its loop costs the oracle's all the same
    env = gym.make("stcgym/StateSpace-v0", plant=plant, noise_std=0.01, max_episode_steps=600)
    A, B = env.unwrapped.A, env.unwrapped.B
    ctl = MultivariableSelfTuningController(env=env, seed=1)
    stc, lost = _episode(env, ctl, 0, 600)
    oracle, _ = _episode(env, LQRController(A, B, env=env), 0, 600)
    assert not lost and len(stc) == 600
    assert stc.sum() / oracle.sum() < 1.1
    assert stc[300:].sum() / oracle[300:].sum() < 1.02
    np.testing.assert_allclose(ctl.theta, np.hstack((A, B)), atol=estimate_tol)
    # one Riccati iteration per sample trails the still-moving estimate a little
    K_ref = control.dlqr(ctl.A_hat, ctl.B_hat, ctl.Q, ctl.R)[0]
    np.testing.assert_allclose(ctl.K, K_ref, rtol=2e-3, atol=1e-5)
    assert ctl.diagnostics["has_gain"] and ctl.diagnostics["n_alarms"] == 0


def test_lagging_iteration_on_a_settled_model_is_solved_to_convergence():
    # noise-free: the estimate is exact once it has full rank, so the model stops moving; a
    # Riccati matrix far from the fixed point then makes the next design a full solve, whose
    # gain is the model's LQ gain (one warm-started step from 10 P would not be)
    plant = get_mimo_plant("he1")
    A, B = plant.discrete()
    n, m = B.shape
    ctl = MultivariableSelfTuningController(n, m, seed=3)
    x = np.full(n, 0.1)
    for _ in range(40):
        u = ctl.predict(np.concatenate([x, np.zeros(n)]))[0]
        x = A @ x + B @ u
    np.testing.assert_allclose(ctl.theta, np.hstack((A, B)), atol=1e-9)
    K_ref = control.dlqr(A, B, ctl.Q, ctl.R)[0]
    np.testing.assert_allclose(ctl.K, K_ref, rtol=1e-6, atol=1e-9)
    before = ctl.diagnostics["n_catch_up"]
    ctl._state.P_lq[0] *= 10.0
    ctl._state.K[0] = 0.0
    ctl.predict(np.concatenate([x, np.zeros(n)]))
    assert ctl.diagnostics["n_catch_up"] == before + 1
    np.testing.assert_allclose(ctl.K, K_ref, rtol=1e-8, atol=1e-10)
    # a moving model is filtered by the warm start instead: no full solve
    ctl._state.P_lq[0] *= 10.0
    ctl._state.A[0] += 0.1
    ctl.predict(np.concatenate([x, np.zeros(n)]))
    assert ctl.diagnostics["n_catch_up"] == before + 1
    assert np.max(np.abs(ctl.K - K_ref)) > 1e-3


@pytest.mark.equality
def test_single_equals_its_lane_bit_for_bit_and_pickles():
    B = 3
    venv = gym.make_vec("stcgym/StateSpace-v0", num_envs=B, plant="he1", noise_std=0.02)
    batch = MultivariableSelfTuningController(env=venv, seed=5)
    singles = [MultivariableSelfTuningController(4, 2, seed=5 + i) for i in range(B)]
    strided = MultivariableSelfTuningController(4, 2, seed=5)  # fed a non-contiguous view
    obs, _ = venv.reset(seed=0)
    seen, actions = [], []
    for t in range(80):
        u = batch.predict(obs)[0]
        assert u.shape == (B, 2)
        for i, s in enumerate(singles):
            np.testing.assert_array_equal(s.predict(obs[i])[0], u[i])
        column = np.zeros((obs.shape[1], 2))
        column[:, 0] = obs[0]
        np.testing.assert_array_equal(strided.predict(column[:, 0])[0], u[0])
        if t == 39:
            copy = pickle.loads(pickle.dumps(batch))
        if t >= 40:
            seen.append(obs)
            actions.append(u)
        obs, *_ = venv.step(u)
    assert batch.K.shape == (B, 2, 4) and singles[0].K.shape == (2, 4)
    np.testing.assert_array_equal(batch.K[1], singles[1].K)
    # the copy taken after step 39 continues like the original on the same observations
    for o, u in zip(seen, actions, strict=True):
        np.testing.assert_array_equal(copy.predict(o)[0], u)


def test_pickled_controller_continues_identically():
    env = gym.make("stcgym/StateSpace-v0", plant="quadruple_tank", noise_std=0.01)
    ctl = MultivariableSelfTuningController(env=env, seed=2)
    obs, _ = env.reset(seed=1)
    for _ in range(30):
        obs, *_ = env.step(ctl.predict(obs)[0])
    copy = pickle.loads(pickle.dumps(ctl))
    for _ in range(30):
        u = ctl.predict(obs)[0]
        np.testing.assert_array_equal(copy.predict(obs)[0], u)
        obs, *_ = env.step(u)


def test_reset_starts_a_new_probe_sequence():
    ctl = MultivariableSelfTuningController(2, 2, seed=0)
    obs = np.zeros(4)
    first = np.array([ctl.predict(obs)[0] for _ in range(4)])
    ctl.reset()
    second = np.array([ctl.predict(obs)[0] for _ in range(4)])
    assert np.all(np.abs(first) == 0.5) and not np.array_equal(first, second)
    assert ctl.t == 4 and ctl.diagnostics["episode"] == 1


def _jump_costs(change_detection):
    A0, B0 = np.array([[0.9, 0.1], [0.0, 0.8]]), np.array([[1.0, 0.0], [0.5, 1.0]])
    A1, B1 = np.array([[1.05, 0.1], [0.0, 0.8]]), np.array([[0.4, 0.0], [0.5, 1.0]])
    env = gym.make("stcgym/StateSpace-v0", A=A0, B=B0, noise_std=0.02, max_episode_steps=1000,
                   schedule=Jumps({500: np.hstack((A1, B1))}))  # fmt: skip
    ctl = MultivariableSelfTuningController(env=env, seed=3, change_detection=change_detection)
    before, after = LQRController(A0, B0, env=env), LQRController(A1, B1, env=env)
    costs = {}
    for name in ("stc", "informed"):
        obs, _ = env.reset(seed=0)
        c = []
        for k in range(1000):
            policy = ctl if name == "stc" else (before if k < 500 else after)
            obs, reward, terminated, *_ = env.step(policy.predict(obs)[0])
            c.append(-reward)
            assert not terminated
        costs[name] = np.array(c)
    return costs["stc"][700:].sum() / costs["informed"][700:].sum(), ctl.diagnostics["n_alarms"]


def test_change_detection_follows_a_jump():
    # [A B] jumps at step 500 (the plant becomes open-loop unstable, one input weaker); the
    # informed oracle switches to the LQR of the new plant at the jump
    ratio, alarms = _jump_costs(None)
    assert alarms >= 1 and ratio < 1.03
    ratio_off, alarms_off = _jump_costs({"enabled": False})
    assert alarms_off == 0 and ratio_off > 1.05


# ------------------------------------------------------------------ bad input


def test_bad_input_is_a_clear_error():
    with pytest.raises(ValueError, match="measured state"):
        MultivariableSelfTuningController(
            env=gym.make("stcgym/StateSpace-v0", C=[[1.0, 0.0]]),
        )
    env = gym.make("stcgym/StateSpace-v0")  # 2 states, 2 inputs
    with pytest.raises(ValueError, match="do not match"):
        MultivariableSelfTuningController(3, 2, env=env)
    with pytest.raises(ValueError, match="num_envs"):
        MultivariableSelfTuningController(env=gym.make_vec("stcgym/StateSpace-v0", 2), num_envs=3)
    with pytest.raises(ValueError, match="R must be"):
        MultivariableSelfTuningController(env=env, R=[[1.0, 0.0], [0.0, -1.0]])
    with pytest.raises(ValueError, match="Q must be"):
        MultivariableSelfTuningController(env=env, Q=np.ones((3, 3)))
    with pytest.raises(ValueError, match="give env"):
        MultivariableSelfTuningController(2)
    ctl = MultivariableSelfTuningController(env=env)
    with pytest.raises(ValueError, match="observation must have shape"):
        ctl.predict(np.zeros(3))
    with pytest.raises(ValueError, match="no stabilising LQ gain"):
        LQRController(np.diag([1.2, 0.5]), [[0.0], [1.0]])
    with pytest.raises(ValueError, match="A and B must be"):
        LQRController(np.eye(2), np.ones(2))


def test_unstabilisable_plant_keeps_the_bounded_probe():
    # the unstable mode 1.05 is not reachable from the input: no estimate is ever stabilisable
    A, B = np.diag([1.05, 0.5]), np.array([[0.0], [1.0]])
    env = gym.make("stcgym/StateSpace-v0", A=A, B=B, initial_state=[0.1, 0.0],
                   reference="zero", max_episode_steps=300)  # fmt: skip
    ctl = MultivariableSelfTuningController(env=env, seed=0)
    obs, _ = env.reset(seed=0)
    for _ in range(60):
        u = ctl.predict(obs)[0]
        assert np.abs(u).max() <= 0.5
        obs, *_ = env.step(u)
    diag = ctl.diagnostics
    assert not diag["has_gain"] and diag["n_rejected"] > 0
    # rounding leaves a tiny coupling in B_hat: a huge gain or a diverging Riccati iterate
    assert diag["last_rejection"] in ("not_stabilisable", "gain_large")
    np.testing.assert_array_equal(ctl.K, np.zeros((1, 2)))


# ------------------------------------------------------------------ any Gymnasium env


class _TwoTanks(gym.Env):
    """A hand-written plant that knows nothing of stcgym: ``x+ = A x + B u + w``, the state
    observed, inputs within ``[-2, 3]``, cost ``|x|^2 + 0.01 |u|^2``."""

    A = np.array([[1.02, 0.1], [0.0, 0.95]])
    B = np.array([[0.1, 0.0], [0.05, 0.2]])

    def __init__(self, with_reference: bool = False):
        size = 4 if with_reference else 2
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (size,), dtype=np.float64)
        self.action_space = gym.spaces.Box(-2.0, 3.0, (2,), dtype=np.float64)
        self.with_reference = with_reference

    def _obs(self):
        return np.concatenate([self.x, np.zeros(2)]) if self.with_reference else self.x.copy()

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x = self.np_random.normal(0.0, 1.0, 2)
        return self._obs(), {}

    def step(self, action):
        u = np.clip(action, self.action_space.low, self.action_space.high)
        cost = float(self.x @ self.x + 0.01 * u @ u)
        self.x = self.A @ self.x + self.B @ u + self.np_random.normal(0.0, 1e-3, 2)
        return self._obs(), -cost, False, False, {}


@pytest.mark.parametrize("with_reference", [False, True])
def test_controller_runs_on_any_gymnasium_env(with_reference):
    env = _TwoTanks(with_reference)
    n_states = 2 if with_reference else None
    ctl = MultivariableSelfTuningController(n_states, env=env, seed=3)
    assert (ctl.n_states, ctl.n_inputs, ctl.action_bound) == (2, 2, 2.0)
    stc, _ = _episode(env, ctl, 0, 300)
    ref = LQRController(env.A, env.B, env=env)
    lqr, _ = _episode(env, ref, 0, 300)
    assert np.all(np.abs(ctl.B_hat - env.B) < 0.02)
    assert stc[100:].sum() / lqr[100:].sum() < 1.1
    # a vector env of the same plant: one lane each
    venv = gym.vector.SyncVectorEnv([lambda: _TwoTanks(with_reference)] * 2)
    batch = MultivariableSelfTuningController(n_states, env=venv, seed=3)
    obs, _ = venv.reset(seed=0)
    u, _ = batch.predict(obs)
    assert u.shape == (2, 2) and np.all(np.abs(u) <= 2.0)


def test_gymnasium_env_with_the_wrong_spaces_is_refused():
    env = _TwoTanks()
    with pytest.raises(ValueError, match="observation has 2 entries"):
        MultivariableSelfTuningController(3, env=env)
    env.action_space = gym.spaces.Discrete(3)
    with pytest.raises(ValueError, match="1-D Box action space"):
        MultivariableSelfTuningController(env=env)
    env = _TwoTanks()
    env.action_space = gym.spaces.Box(0.0, 1.0, (2,))
    with pytest.raises(ValueError, match="symmetric box around 0"):
        MultivariableSelfTuningController(env=env)


def test_inputs_stay_in_an_asymmetric_range_and_identify_the_plant():
    # a plant whose inputs are clipped to [-0.2, 1] (pumps around an operating point): the
    # controller clips to the same range, so its regressor holds the input the plant received
    # and noise-free data give the true [A B] (an input clipped by the plant alone would not)
    A, B = get_mimo_plant("quadruple_tank").discrete()
    low, high = np.array([-0.2, -0.2]), np.array([1.0, 1.0])
    ctl = MultivariableSelfTuningController(4, 2, input_range=(low, high), seed=3)
    x, r = np.zeros(4), np.array([4.0, 3.0, 0.0, 0.0])  # needs more than the range allows
    inputs = []
    for _ in range(80):
        u, _ = ctl.predict(np.concatenate([x, r]))
        inputs.append(u)
        x = A @ x + B @ np.clip(u, low, high)
    inputs = np.array(inputs)
    assert np.all(inputs >= low) and np.all(inputs <= high)
    assert np.any(inputs == high)  # the range was reached
    np.testing.assert_allclose(ctl.theta, np.hstack((A, B)), atol=1e-6)
    env = gym.make("stcgym/StateSpace-v0", plant="quadruple_tank", input_range=((-3, -2), (7, 7)))
    ctl = MultivariableSelfTuningController(env=env)  # the env's range is the default
    np.testing.assert_array_equal(ctl.input_low, env.unwrapped.input_range[0])
    np.testing.assert_array_equal(ctl.input_high, env.unwrapped.input_range[1])
    with pytest.raises(ValueError, match="input_range must hold u = 0"):
        MultivariableSelfTuningController(4, 2, input_range=(0.0, 1.0))
    with pytest.raises(ValueError, match="input_range must be a pair"):
        MultivariableSelfTuningController(4, 2, input_range=(0.0, 1.0, 2.0))
