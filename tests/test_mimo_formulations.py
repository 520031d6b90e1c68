"""MIMO plants posed as their literature poses them: the quadruple tank at both operating
points (Johansson 2000) with its performance output, input range and valve switch, and he1 /
ac1 in controlgym's formulation (performance output with feed-through, noise input ``B1``),
checked against the equations by hand and python-control."""

from __future__ import annotations

import math

import control
import gymnasium as gym
import numpy as np
import pytest
from scipy.linalg import expm

import stcgym.envs  # noqa: F401  (registers the envs)
from stcgym.envs import Jumps, get_mimo_plant

# Johansson (2000), Table I and II, typed in again here: areas, outlet areas, g, operating points
AREAS = (28.0, 32.0, 28.0, 32.0)
OUTLETS = (0.071, 0.057, 0.071, 0.057)
POINTS = {
    "quadruple_tank": dict(h0=(12.4, 12.7, 1.8, 1.4), k=(3.33, 3.35), g=(0.70, 0.60), v0=3.00),
    "quadruple_tank_nmp": dict(h0=(12.6, 13.0, 4.8, 4.9), k=(3.14, 3.29), g=(0.43, 0.34), v0=3.15),
}


def _tank_by_hand(name):
    """eq. (2) of the paper from the physical constants, ``T_i = A_i / a_i sqrt(2 h_i0 / g)``."""
    p = POINTS[name]
    T = [A / a * math.sqrt(2 * h / 981.0) for A, a, h in zip(AREAS, OUTLETS, p["h0"], strict=True)]
    (A1, A2, A3, A4), (k1, k2), (g1, g2) = AREAS, p["k"], p["g"]
    A = np.diag([-1 / t for t in T])
    A[0, 2], A[1, 3] = A3 / (A1 * T[2]), A4 / (A2 * T[3])
    B = np.array([[g1 * k1 / A1, 0], [0, g2 * k2 / A2], [0, (1 - g2) * k2 / A3],
                  [(1 - g1) * k1 / A4, 0]])  # fmt: skip
    return A, B


@pytest.mark.parametrize("name", list(POINTS))
def test_tank_is_johanssons_linearisation_at_its_operating_point(name):
    spec = get_mimo_plant(name)
    A_hand, B_hand = _tank_by_hand(name)
    # the catalogue holds Table II's time constants: within 5 % of the physics (h0 rounded)
    np.testing.assert_allclose(np.array(spec.A_c), A_hand, rtol=0.05, atol=1e-12)
    np.testing.assert_allclose(np.array(spec.B_c), B_hand, rtol=1e-12)
    # zero-order hold by the matrix exponential of [[A, B], [0, 0]] dt
    n, m = 4, 2
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = np.array(spec.A_c), np.array(spec.B_c)
    E = expm(M * spec.dt)
    A, B = spec.discrete()
    np.testing.assert_allclose(A, E[:n, :n], rtol=1e-12)
    np.testing.assert_allclose(B, E[:n, n:], rtol=1e-12)
    # performance output: the two lower levels; pumps between 0 and 10 V around v0
    C_z, D_z = spec.performance_output()
    np.testing.assert_array_equal(C_z, np.eye(4)[:2])
    np.testing.assert_array_equal(D_z, 0.0)
    v0 = POINTS[name]["v0"]
    np.testing.assert_allclose(spec.input_range, ((-v0, -v0), (10 - v0, 10 - v0)))


def test_p_minus_is_minimum_phase_and_p_plus_has_its_right_half_plane_zero():
    zeros = {}
    for name in POINTS:
        spec = get_mimo_plant(name)
        sys = control.ss(np.array(spec.A_c), np.array(spec.B_c), spec.performance_output()[0], 0)
        zeros[name] = np.sort(np.real(control.zeros(sys)))
    # the paper's Section III: P- zeros -0.060 and -0.018, P+ zeros -0.057 and 0.013 (rad/s)
    np.testing.assert_allclose(zeros["quadruple_tank"], [-0.060, -0.018], atol=2e-3)
    np.testing.assert_allclose(zeros["quadruple_tank_nmp"], [-0.057, 0.013], atol=2e-3)


def _performance_env(**kw):
    return gym.make("stcgym/StateSpace-v0", cost="performance", **kw)


def test_performance_reward_is_the_lq_stage_cost_by_hand():
    env = _performance_env(plant="quadruple_tank", reference=[0.5, -1.0], control_cost=0.1)
    obs, info = env.reset(seed=0, options={"initial_state": [1.0, 2.0, 3.0, 4.0]})
    assert obs.shape == (6,)
    np.testing.assert_array_equal(obs, [1.0, 2.0, 3.0, 4.0, 0.5, -1.0])  # [x(0), r_z(0)]
    u = np.array([2.0, -1.0])
    obs, reward, *_ = env.step(u)
    # z(0) = C_z x(0) = (1, 2) against r = (0.5, -1): the cost of the state u(0) acts on
    assert reward == pytest.approx(-((1 - 0.5) ** 2 + (2 + 1) ** 2 + 0.1 * (4 + 1)), rel=1e-14)
    A, B = get_mimo_plant("quadruple_tank").discrete()
    np.testing.assert_allclose(obs[:4], A @ [1.0, 2.0, 3.0, 4.0] + B @ u, rtol=1e-14)


def test_pumps_are_clipped_to_their_voltage_range():
    env = _performance_env(plant="quadruple_tank_nmp", reference="zero")
    space = env.action_space
    np.testing.assert_allclose(space.low, [-3.15, -3.15])
    np.testing.assert_allclose(space.high, [6.85, 6.85])
    env.reset(seed=0)
    _, reward, _, _, info = env.step(np.array([-5.0, 8.0]))
    assert info["clipped"]
    u = np.array([-3.15, 6.85])
    assert reward == pytest.approx(-0.01 * float(u @ u), rel=1e-14)
    A, B = get_mimo_plant("quadruple_tank_nmp").discrete()
    np.testing.assert_allclose(info["x"], B @ u, rtol=1e-14)
    # a tighter action bound wins over the physical range
    env = _performance_env(plant="quadruple_tank", action_bound=2.0)
    np.testing.assert_allclose(env.action_space.low, -2.0)
    np.testing.assert_allclose(env.action_space.high, 2.0)
    with pytest.raises(ValueError, match="input_range must be"):
        gym.make("stcgym/StateSpace-v0", A=np.eye(2), B=np.eye(2), input_range=(1.0, 0.0))
    with pytest.raises(ValueError, match="give plant"):
        gym.make("stcgym/StateSpace-v0", cost="performance")


@pytest.mark.equality
def test_vector_lanes_equal_the_single_env_with_performance_cost_noise_input_and_range():
    rng = np.random.default_rng(1)
    for kw in (
        dict(plant="quadruple_tank", noise_std=0.05, process_noise_std=0.1,
             reference={"kind": "random_steps", "amplitude": 2.0, "hold": [5, 9]}),
        dict(plant="he1", reference="zero", control_cost=0.0, process_noise_std=0.3,
             initial_state_std=0.3),
    ):  # fmt: skip
        env = _performance_env(**kw)
        venv = gym.make_vec("stcgym/StateSpace-v0", num_envs=3, cost="performance",
                            vectorization_mode="vector_entry_point", **kw)  # fmt: skip
        obs, _ = env.reset(seed=5)
        obs_v, _ = venv.reset(seed=[4, 5, 6])
        np.testing.assert_array_equal(obs, obs_v[1])
        for _ in range(40):
            u = 4.0 * rng.standard_normal(2)
            obs, reward, *_ = env.step(u)
            obs_v, rewards, *_ = venv.step(np.stack([-u, u, 2 * u]))
            np.testing.assert_array_equal(obs, obs_v[1])
            assert reward == rewards[1]


def test_valve_switch_is_a_parameter_jump_from_p_minus_to_p_plus():
    A2, B2 = get_mimo_plant("quadruple_tank_nmp").discrete()
    env = _performance_env(plant="quadruple_tank", schedule=Jumps({3: np.hstack((A2, B2))}))
    env.reset(seed=0)
    x, u = np.zeros(4), np.array([1.0, 0.5])
    A1, B1 = get_mimo_plant("quadruple_tank").discrete()
    for k in range(6):
        _, _, _, _, info = env.step(u)
        A, B = (A1, B1) if k < 3 else (A2, B2)
        x = A @ x + B @ u
        np.testing.assert_allclose(info["x"], x, rtol=1e-13)


@pytest.mark.parametrize("name", ["quadruple_tank", "quadruple_tank_nmp"])
def test_lqr_costs_far_less_than_zero_input_on_both_operating_points(name):
    """Not floor-bound: the LQR on the true model (python-control's dlqr, the reference fed
    forward to the equilibrium with ``C_z x = r``) against zero input, by a plain loop."""
    spec = get_mimo_plant(name)
    A, B = spec.discrete()
    Q, R, _ = spec.lq_weights(0.01)
    K = control.dlqr(A, B, Q, R)[0]
    C_z = spec.performance_output()[0]
    # the equilibrium of each reference: [A - I, B; C_z, 0] [x; u] = [0; r]
    M = np.block([[A - np.eye(4), B], [C_z, np.zeros((2, 2))]])
    target = np.linalg.solve(M, np.vstack((np.zeros((4, 2)), np.eye(2))))
    costs = {}
    for policy in ("lqr", "zero"):
        env = _performance_env(plant=name, noise_std=0.05, max_episode_steps=1000,
                               reference={"kind": "random_steps", "amplitude": 2.0,
                                          "hold": [50, 150]})  # fmt: skip
        total = 0.0
        for seed in range(3):
            obs, _ = env.reset(seed=seed)
            for _ in range(1000):
                x, r = obs[:4], obs[4:]
                xu = target @ r
                u = xu[4:] - K @ (x - xu[:4]) if policy == "lqr" else np.zeros(2)
                obs, reward, *_ = env.step(u)
                total -= reward
        costs[policy] = total / 3000
    ratio = costs["lqr"] / costs["zero"]
    # measured: 0.026 at P-, 0.32 at P+ (its zero at 0.013 rad/s limits the bandwidth)
    assert ratio < {"quadruple_tank": 0.05, "quadruple_tank_nmp": 0.45}[name]
    assert costs["zero"] > 1.0


# ------------------------------------------------------------------ controlgym's he1 and ac1

S = math.sqrt(0.5)
# controlgym 1.0.0's Q = C1' C1, R = D12' D12 (ac1: max eig(D12' D12) I), S = C1' D12, from
# C1, D12 of its he1.mat / ac1.mat, typed in here
CONTROLGYM = {
    "he1": dict(C1=[[2 * S, 0, 0, 0], [0, S, 0, 0]], D12=[[S, 0], [0, S]], R=0.5 * np.eye(2)),
    "ac1": dict(C1=[[0, S, 0, 0, 0], [0, 0, S, 0, 0]], D12=[[S, 0, 0], [0, S, 0]],
                R=0.5 * np.eye(3)),
}  # fmt: skip


@pytest.mark.parametrize("name", list(CONTROLGYM))
def test_performance_output_is_controlgyms_stage_cost(name):
    cg = CONTROLGYM[name]
    C1, D12 = np.array(cg["C1"], dtype=float), np.array(cg["D12"], dtype=float)
    Q, R, N = get_mimo_plant(name).lq_weights()
    np.testing.assert_allclose(Q, C1.T @ C1, atol=1e-15)
    np.testing.assert_allclose(R, cg["R"], atol=1e-15)
    np.testing.assert_allclose(N, C1.T @ D12, atol=1e-15)
    # the env's reward is -(x'Qx + u'Ru + 2 x'Nu) at the state the input acts on
    env = _performance_env(plant=name, control_cost=0.0, reference="zero")
    rng = np.random.default_rng(0)
    x0, u = rng.standard_normal(len(Q)), rng.standard_normal(len(R))
    env.reset(seed=0, options={"initial_state": x0})
    _, reward, *_ = env.step(u)
    assert reward == pytest.approx(-(x0 @ Q @ x0 + u @ R @ u + 2 * x0 @ N @ u), rel=1e-12)


@pytest.mark.parametrize("name", list(CONTROLGYM))
def test_noise_input_is_the_zero_order_hold_of_b1(name):
    spec = get_mimo_plant(name)
    A_c, B_c, B1_c = (np.array(M, dtype=float) for M in (spec.A_c, spec.B_c, spec.B1_c))
    n, m, d = B1_c.shape[0], B_c.shape[1], B1_c.shape[1]
    M = np.zeros((n + m + d, n + m + d))
    M[:n, :n], M[:n, n : n + m], M[:n, n + m :] = A_c, B_c, B1_c
    E = expm(M * 0.1)
    np.testing.assert_allclose(spec.discrete()[1], E[:n, n : n + m], rtol=1e-10, atol=1e-15)
    np.testing.assert_allclose(spec.noise_input(), E[:n, n + m :], rtol=1e-10, atol=1e-15)
    # measured output: controlgym's C
    assert len(spec.C_y) == {"he1": 1, "ac1": 3}[name]


def _steady_cost(env, policy, seeds=20, steps=1000, skip=100):
    """Mean per-step cost after ``skip`` steps from x(0) = 0, and its standard error."""
    costs = []
    for seed in range(seeds):
        obs, _ = env.reset(seed=seed)
        policy.reset()
        c = []
        for _ in range(steps):
            u, _ = policy.predict(obs)
            obs, reward, *_ = env.step(u)
            c.append(-reward)
        costs.append(np.mean(c[skip:]))
    return float(np.mean(costs)), float(np.std(costs) / math.sqrt(seeds))


def test_lqr_and_lqg_oracles_cost_what_the_riccati_solutions_say_on_he1():
    """LQR (state) and LQG (measured output, noise 0.1 on it) in controlgym's formulation of
    he1, driven through the env: their steady cost per step against
    ``tr(P W)`` and ``tr(P W) + tr(S_f K' (R + B'PB) K)`` from python-control's Riccati
    solutions (``S_f`` the filtered error covariance)."""
    from stcgym.adaptive import LQRController
    from stcgym.agents.evaluation.mimo import OutputLQG

    plant = get_mimo_plant("he1")
    (A, B), G, C = plant.discrete(), plant.noise_input(), np.array(plant.C_y)
    Q, R, N = plant.lq_weights()
    W, V = 0.1 * G @ G.T, 0.01 * np.eye(1)
    K, P, _ = control.dlqr(A, B, Q, R, N)
    S_pred = control.dlqe(A, np.eye(4), C, W, V)[1]
    S_f = S_pred - S_pred @ C.T @ np.linalg.inv(C @ S_pred @ C.T + V) @ C @ S_pred
    j_lqr = np.trace(P @ W)
    j_lqg = j_lqr + np.trace(S_f @ K.T @ (R + B.T @ P @ B) @ K)
    kw = dict(plant="he1", control_cost=0.0, reference="zero", process_noise_std=math.sqrt(0.1),
              action_bound=1e6)  # fmt: skip
    lqr = LQRController(A, B, Q=Q, R=R, N=N, action_bound=1e6)
    np.testing.assert_allclose(lqr.K, K, rtol=1e-8, atol=1e-10)
    cost, se = _steady_cost(_performance_env(reference_in="state", **kw), lqr)
    assert abs(cost - j_lqr) < 4 * se
    lqg = OutputLQG(A, B, C, Q, R, N, W=W, V=V, action_bound=1e6)
    cost, se = _steady_cost(_performance_env(measured="output", noise_std=0.1, **kw), lqg)
    assert abs(cost - j_lqg) < 4 * se
    assert j_lqg > 50 * j_lqr  # one measured state of four: the estimate costs most


def test_ac1_has_no_lq_yardstick_for_controlgyms_cost_and_the_bench_says_so():
    from stcgym.agents.benchmark.mimo import check_mimo_plants, has_yardstick

    # Q - N R^-1 N' = 0: the integrator x1 (eigenvalue 1) is weighted by nothing
    Q, R, N = get_mimo_plant("ac1").lq_weights()
    np.testing.assert_allclose(Q - N @ np.linalg.solve(R, N.T), 0.0, atol=1e-15)
    assert not has_yardstick("ac1") and has_yardstick("he1")
    with pytest.raises(ValueError, match="no stabilising LQ solution"):
        check_mimo_plants(["he1", "ac1"])
