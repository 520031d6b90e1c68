"""Environment tests: conformance, trajectories against python-control, seeding, bad input."""

from __future__ import annotations

import copy
import warnings

import control
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import stcgym.envs  # noqa: F401  (registers the ids)
from stcgym.envs import (
    PLANTS,
    PRBS,
    Jumps,
    Ramp,
    RandomJump,
    RandomWalk,
    SquareWave,
    canonical_matrices,
    make_reference,
    observer_to_observability_b,
    transfer_function_coefficients,
)

CANONICAL_IDS = ["stcgym/ObserverCanonical-v0", "stcgym/ObservabilityCanonical-v0"]

CHECK_CASES = [
    ("stcgym/ObserverCanonical-v0", {}),
    ("stcgym/ObserverCanonical-v0", {"plant": "unstable2", "noise_std": 0.05}),
    ("stcgym/ObserverCanonical-v0", {"a": [0.5], "b": [1.0], "reference": "prbs"}),
    ("stcgym/ObserverCanonical-v0", {"plant": ["stable2", "unstable2"], "process_noise_std": 0.01}),
    ("stcgym/ObservabilityCanonical-v0", {"plant": "timevarying2", "noise_std": 0.1}),
    ("stcgym/ObservabilityCanonical-v0", {"plant": "stable4", "reference": "sine"}),
    ("stcgym/StateSpace-v0", {"A": [[0.9, 0.1], [0.0, 0.8]], "B": [[0.0], [1.0]]}),
    ("stcgym/StateSpace-v0", {"sys": control.tf([1.0], [1.0, 1.0]), "dt": 0.1}),
    ("stcgym/MultichannelStatic-v0", {}),
    ("stcgym/MultichannelStatic-v0", {"theta": [[1.0, 0.5, 0.0]], "reference": 0.5}),
]


@pytest.mark.parametrize(("env_id", "kwargs"), CHECK_CASES)
def test_check_env_passes(env_id, kwargs):
    env = gym.make(env_id, **kwargs)
    with warnings.catch_warnings():
        # The checker recommends [-1, 1] actions and bounded observations: physical units and an
        # unbounded output are deliberate here (the RL wrapper normalises actions).
        warnings.simplefilter("ignore", UserWarning)
        check_env(env.unwrapped, skip_render_check=True)


def _rollout(env, u, seed=0, options=None):
    obs, info = env.reset(seed=seed, options=options)
    ys, infos = [obs], [info]
    for uk in u:
        obs, reward, terminated, truncated, info = env.step(np.atleast_1d(uk))
        ys.append(obs)
        infos.append(info)
        assert not terminated
    return np.array(ys), infos


@pytest.mark.parametrize("env_id", CANONICAL_IDS)
@pytest.mark.parametrize("plant", ["stable2", "nonminphase2", "stable4"])
def test_noise_free_output_equals_forced_response(env_id, plant):
    rng = np.random.default_rng(3)
    u = rng.uniform(-1, 1, 60)
    x0 = rng.normal(size=PLANTS[plant].n)
    env = gym.make(env_id, plant=plant, reference="zero")
    obs, _ = _rollout(env, u, options={"initial_state": x0})
    A, B, C, D = env.unwrapped.A, env.unwrapped.B, env.unwrapped.C, env.unwrapped.D
    sys = control.ss(A, B, C, D, 1)
    # Env step k applies u(k) and returns y(k+1): the same as forced_response's y[k+1].
    resp = control.forced_response(sys, T=np.arange(61), U=np.append(u, 0.0), X0=x0)
    np.testing.assert_allclose(obs[:, 0], resp.outputs, rtol=1e-12, atol=1e-12)


def test_both_canonical_forms_are_the_same_plant():
    u = np.random.default_rng(0).normal(size=80)
    outs = []
    for env_id in CANONICAL_IDS:
        env = gym.make(env_id, plant="stable4", noise_std=0.1)
        obs, _ = _rollout(env, u, seed=5)
        outs.append(obs[:, 0])
    np.testing.assert_allclose(outs[0], outs[1], rtol=1e-9, atol=1e-9)


def test_observer_form_transfer_function_matches_control_tf():
    rng = np.random.default_rng(1)
    for n in (1, 2, 3, 5):
        a, b = rng.normal(size=n), rng.normal(size=n)
        A, B, C, D = canonical_matrices(a, b, "observer")
        got = control.ss2tf(control.ss(A, B, C, D, 1))
        want = control.tf(b, np.concatenate(([1.0], a)), 1)
        for z in (0.3 + 0.2j, -1.7, 2.5j):
            assert got(z) == pytest.approx(want(z), rel=1e-9)
        # python-control's "observable" canonical form is the paper's observer form.
        ref, _ = control.canonical_form(control.ss(want), "observable")
        np.testing.assert_allclose(A, ref.A, atol=1e-9)


def test_observability_form_b_are_markov_parameters():
    rng = np.random.default_rng(2)
    for n in (1, 2, 4):
        a, b = rng.normal(size=n) * 0.3, rng.normal(size=n)
        A, B, C, D = canonical_matrices(a, b, "observability")
        markov = [(C @ np.linalg.matrix_power(A, k) @ B).item() for k in range(n)]
        np.testing.assert_allclose(markov, b, atol=1e-12)
        num, den = transfer_function_coefficients(a, b, "observability")
        got = control.ss2tf(control.ss(A, B, C, D, 1))
        want = control.tf(num, den, 1)
        for z in (0.5 + 0.5j, 3.0):
            assert got(z) == pytest.approx(want(z), rel=1e-9)
        np.testing.assert_allclose(observer_to_observability_b(a, num), b, atol=1e-12)


def test_state_space_env_matches_forced_response_with_feedthrough():
    rng = np.random.default_rng(4)
    A = np.array([[0.8, 0.2, 0.0], [-0.1, 0.7, 0.3], [0.0, 0.0, 0.5]])
    B, C, D = rng.normal(size=(3, 2)), rng.normal(size=(2, 3)), rng.normal(size=(2, 2))
    u = rng.normal(size=(40, 2))
    env = gym.make("stcgym/StateSpace-v0", A=A, B=B, C=C, D=D, reference="zero")
    obs, _ = _rollout(env, u)
    resp = control.forced_response(
        control.ss(A, B, C, D, 1), T=np.arange(41), U=np.vstack((u, np.zeros((1, 2)))).T
    )
    # y(k+1) = C x(k+1) + D u(k): the input held from the last step (see envs.plants docstring).
    u_held = np.vstack((np.zeros((1, 2)), u))
    u_next = np.vstack((u, np.zeros((1, 2))))
    expected = resp.outputs.T - u_next @ D.T + u_held @ D.T
    np.testing.assert_allclose(obs[:, :2], expected, rtol=1e-10, atol=1e-10)


def test_state_space_env_discretises_continuous_sys_with_zoh():
    sys_c = control.tf([2.0], [1.0, 3.0, 2.0])
    env = gym.make("stcgym/StateSpace-v0", sys=sys_c, dt=0.2, reference="zero")
    u = np.sin(np.arange(30) * 0.4)
    obs, _ = _rollout(env, u)
    sys_d = control.sample_system(control.ss(sys_c), 0.2, method="zoh")
    resp = control.forced_response(sys_d, T=np.arange(31) * 0.2, U=np.append(u, 0.0))
    np.testing.assert_allclose(obs[:, 0], resp.outputs, atol=1e-10)
    with pytest.raises(ValueError, match="dt"):
        gym.make("stcgym/StateSpace-v0", sys=sys_c)


def test_multichannel_static_output():
    theta = np.array([[1.0, 2.0], [0.0, 1.0]])
    env = gym.make("stcgym/MultichannelStatic-v0", theta=theta, noise_std=0.0)
    env.reset(seed=0)
    u = np.array([0.3, -0.7])
    obs, reward, *_ = env.step(u)
    np.testing.assert_allclose(obs[:2], u @ theta)
    assert reward == pytest.approx(-(np.sum((u @ theta - 1.0) ** 2) + 0.01 * u @ u))


def test_reward_uses_noise_free_output_and_control_cost():
    env = gym.make(
        "stcgym/ObserverCanonical-v0",
        a=[0.5],
        b=[2.0],
        control_cost=0.1,
        reference=0.25,
        noise_std=1.0,
    )
    env.reset(seed=0)
    obs, reward, _, _, info = env.step(np.array([0.5]))
    assert info["y_clean"] == pytest.approx(1.0)  # x(1) = 2 * 0.5
    assert reward == pytest.approx(-((1.0 - 0.25) ** 2 + 0.1 * 0.25))
    assert obs[1] == 0.25 and obs[0] != pytest.approx(1.0)


def test_same_seed_same_episode_whatever_came_before():
    env = gym.make(
        "stcgym/ObserverCanonical-v0", noise_std=0.1, reference="prbs", schedule=RandomWalk(0.001)
    )
    u = np.full(50, 0.05)
    first, infos1 = _rollout(env, u, seed=11)
    _rollout(env, u, seed=3)
    env.reset()  # advance np_random
    again, infos2 = _rollout(env, u, seed=11)
    np.testing.assert_array_equal(first, again)
    np.testing.assert_array_equal(infos1[-1]["theta"], infos2[-1]["theta"])
    other, _ = _rollout(env, u, seed=12)
    assert not np.allclose(first[:, 0], other[:, 0])
    # A fresh env with the same seed gives the same episode too.
    fresh = gym.make(
        "stcgym/ObserverCanonical-v0", noise_std=0.1, reference="prbs", schedule=RandomWalk(0.001)
    )
    np.testing.assert_array_equal(first, _rollout(fresh, u, seed=11)[0])


def test_noise_statistics():
    env = gym.make(
        "stcgym/ObserverCanonical-v0",
        a=[0.0],
        b=[0.0],
        noise_std=0.3,
        reference="zero",
        max_episode_steps=None,
    )
    obs, _ = _rollout(env, np.zeros(4000), seed=1)
    assert np.std(obs[:, 0]) == pytest.approx(0.3, rel=0.05)
    assert abs(np.mean(obs[:, 0])) < 0.03


def test_parameter_jump_is_in_info_and_in_dynamics():
    new = np.array([-1.2, 0.52, 0.9, 0.3])
    env = gym.make("stcgym/ObserverCanonical-v0", plant="stable2", schedule=Jumps({10: new}))
    _, infos = _rollout(env, np.ones(15))
    assert np.allclose(infos[9]["theta"], PLANTS["stable2"].theta)
    assert np.allclose(infos[10]["theta"], new)
    np.testing.assert_allclose(env.unwrapped.a, new[:2])
    # timevarying2 carries its own jump at step 1000, in either form.
    env = gym.make("stcgym/ObservabilityCanonical-v0", plant="timevarying2", max_episode_steps=2000)
    _, infos = _rollout(env, np.zeros(1001))
    a_after, b_after = np.array([-1.2, 0.52]), np.array([0.9, 0.3])
    np.testing.assert_allclose(infos[1000]["a"], a_after)
    np.testing.assert_allclose(infos[1000]["b"], observer_to_observability_b(a_after, b_after))
    assert not np.allclose(infos[999]["a"], a_after)


def test_ramp_and_random_walk():
    ramp = Ramp(target=[1.0, 3.0], start=10, stop=20)
    ramp.reset(np.array([0.0, 1.0]), np.random.default_rng(0))
    np.testing.assert_allclose(ramp(5), [0.0, 1.0])
    np.testing.assert_allclose(ramp(15), [0.5, 2.0])
    np.testing.assert_allclose(ramp(30), [1.0, 3.0])
    walk = RandomWalk(0.1, mask=[True, False])
    walk.reset(np.zeros(2), np.random.default_rng(1))
    values = np.array([walk(k) for k in range(2000)])
    assert np.all(values[:, 1] == 0.0)
    assert np.std(np.diff(values[:, 0])) == pytest.approx(0.1, rel=0.1)


def test_references():
    sq = SquareWave(period=6, amplitude=2.0)
    assert [sq(k) for k in range(7)] == [2, 2, 2, -2, -2, -2, 2]
    prbs = PRBS(hold=3)
    prbs.reset(np.random.default_rng(0))
    bits = [prbs(k) for k in range(300)]
    assert set(bits) == {-1.0, 1.0}
    assert all(bits[3 * j] == bits[3 * j + 1] == bits[3 * j + 2] for j in range(100))
    assert make_reference(0.5)(100) == 0.5
    assert make_reference([1.0, 2.0])(10) == 2.0
    assert make_reference(lambda k: k / 2)(3) == 1.5
    assert make_reference({"kind": "step", "amplitude": 3, "at": 2})(1) == 0.0
    with pytest.raises(ValueError, match="reference"):
        make_reference("triangle")


def test_divergence_terminates_with_flag_and_truncation_is_separate():
    env = gym.make(
        "stcgym/ObserverCanonical-v0",
        a=[-2.0],
        b=[1.0],
        y_bound=50.0,
        reference="zero",
        max_episode_steps=100,
    )
    env.reset(seed=0)
    for k in range(100):  # noqa: B007 (k is read after the loop)
        obs, reward, terminated, truncated, info = env.step(np.array([1.0]))
        assert np.isfinite(obs).all() and np.isfinite(reward)
        if terminated:
            break
    assert terminated and not truncated and info["diverged"] and k < 10
    env = gym.make("stcgym/ObserverCanonical-v0", max_episode_steps=5)
    env.reset(seed=0)
    flags = [env.step(np.zeros(1))[2:4] for _ in range(5)]
    assert flags[-1] == (False, True) and all(f == (False, False) for f in flags[:-1])


def test_action_clipping_is_counted():
    env = gym.make("stcgym/ObserverCanonical-v0", action_bound=2.0)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([5.0]))
    assert info["clipped"] and info["n_clipped"] == 1
    np.testing.assert_allclose(info["x"], 2.0 * np.array(PLANTS["stable2"].b))
    _, _, _, _, info = env.step(np.array([1.0]))
    assert not info["clipped"] and info["n_clipped"] == 1


def test_plant_family_and_reset_options():
    env = gym.make("stcgym/ObserverCanonical-v0", plant=["stable2", "unstable2", "nonminphase2"])
    drawn = {env.reset(seed=s)[1]["theta"].tobytes() for s in range(20)}
    assert len(drawn) == 3
    _, info = env.reset(options={"plant": "integrator2"})
    np.testing.assert_allclose(info["theta"], PLANTS["integrator2"].theta)
    assert env.unwrapped.plant.name == "integrator2"
    _, info = env.reset(options={"a": [0.1, 0.2], "b": [1.0, 0.0], "initial_state": [1.0, 2.0]})
    np.testing.assert_allclose(info["x"], [1.0, 2.0])
    np.testing.assert_allclose(env.unwrapped.A, [[-0.1, 1.0], [-0.2, 0.0]])


def test_catalogue_documentation_is_true():
    p = PLANTS
    assert p["stable2"].stable and p["stable2"].dc_gain == pytest.approx(7.5)
    assert np.allclose(np.abs(p["lightly_damped2"].poles), 0.95, atol=1e-3)
    assert max(np.abs(p["unstable2"].poles)) == pytest.approx(1.1)
    assert not p["nonminphase2"].minimum_phase and p["nonminphase2"].zeros[0] == pytest.approx(2)
    assert max(np.abs(p["integrator2"].poles)) == pytest.approx(1.0)
    assert p["stable4"].n == 4 and p["stable4"].stable
    assert p["stable4"].dc_gain == pytest.approx(0.938, abs=1e-3)


def test_make_vec_and_render():
    envs = gym.make_vec(
        "stcgym/ObserverCanonical-v0", num_envs=3, vectorization_mode="sync", noise_std=0.1
    )
    obs, _ = envs.reset(seed=[1, 2, 3])
    assert obs.shape == (3, 2)
    obs, rewards, terms, truncs, _ = envs.step(np.zeros((3, 1)))
    assert obs.shape == (3, 2) and rewards.shape == (3,)
    assert len({o.tobytes() for o in obs}) == 3
    envs.close()
    env = gym.make("stcgym/ObserverCanonical-v0", render_mode="rgb_array")
    env.reset(seed=0)
    for _ in range(20):
        env.step(np.array([0.1]))
    frame = env.render()
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8
    assert frame.std() > 0


BAD = [
    ({"a": [0.1, 0.2], "b": [1.0]}, "same length"),
    ({"a": [], "b": []}, "empty"),
    ({"a": [np.nan], "b": [1.0]}, "finite"),
    ({"a": [0.1]}, "together"),
    ({"plant": "nope"}, "plant must be one of"),
    ({"noise_std": -0.1}, "noise_std"),
    ({"action_bound": 0.0}, "action_bound"),
    ({"reference": "triangle"}, "reference"),
    ({"plant": ["stable2", "stable4"]}, "order"),
    ({"plant": "stable2", "a": [0.1], "b": [0.1]}, "either"),
]


@pytest.mark.parametrize(("kwargs", "match"), BAD)
def test_bad_canonical_input_raises(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make("stcgym/ObserverCanonical-v0", **kwargs)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"A": [[1.0, 0.0]], "B": [[1.0]]}, "A must be square"),
        ({"A": np.eye(2), "B": np.ones((3, 1))}, "B must have 2 rows"),
        ({"A": np.eye(2), "B": np.ones((2, 1)), "C": np.ones((1, 3))}, "C must have 2 columns"),
        ({"A": np.eye(2), "B": np.ones((2, 1)), "D": np.ones((2, 2))}, "D must have"),
        ({"A": [[np.inf]], "B": [[1.0]]}, "A must be finite"),
    ],
)
def test_bad_state_space_input_raises(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make("stcgym/StateSpace-v0", **kwargs)


def test_bad_actions_raise():
    env = gym.make("stcgym/ObserverCanonical-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action must be finite"):
        env.step(np.array([np.nan]))
    with pytest.raises(ValueError, match=r"action must have shape \(1,\)"):
        env.step(np.array([1.0, 2.0]))
    mimo = gym.make("stcgym/MultichannelStatic-v0")
    mimo.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(2,\)"):
        mimo.step(np.array([1.0]))
    with pytest.raises(ValueError, match="initial_state"):
        env.reset(options={"initial_state": [1.0]})


LANE_REFERENCES = [
    SquareWave(period=7, amplitude=2.0, offset=0.5),
    PRBS(hold=3),
    make_reference({"kind": "random_steps", "amplitude": 2.0, "hold": [1, 4], "offset": 0.5}),
    make_reference({"kind": "sine", "period": 11.5, "phase": 0.3}),
    make_reference({"kind": "step", "at": 4, "initial": -1.0}),
    make_reference([0.1, 0.2, 0.3]),
    make_reference(lambda k: 0.1 * k),
    make_reference("zero"),
]


@pytest.mark.parametrize("ref", LANE_REFERENCES, ids=lambda r: type(r).__name__)
def test_references_give_each_lane_its_single_lane_values(ref):
    """values(k, lanes) on B lanes (each at its own step) equals B one-lane references reset
    with the same generators: the vector env needs no type switch over reference classes."""
    B, T = 4, 40
    seeds = np.random.SeedSequence(5).spawn(B)
    batch = copy.deepcopy(ref)
    batch.allocate(B)
    batch.reset_lanes(np.arange(B), [np.random.default_rng(s) for s in seeds])
    singles = [copy.deepcopy(ref) for _ in range(B)]
    for single, s in zip(singles, seeds, strict=True):
        single.reset(np.random.default_rng(s))
    offsets = np.array([0, 3, 9, 1])
    for k in range(T):
        got = batch.values(k + offsets)
        want = [single(int(k + o)) for single, o in zip(singles, offsets, strict=True)]
        np.testing.assert_array_equal(got, want)
    lanes = np.array([2, 0])
    np.testing.assert_array_equal(
        batch.values(np.array([T + 9, T]), lanes), [singles[2](T + 9), singles[0](T)]
    )


@pytest.mark.parametrize(
    "schedule",
    [
        Jumps({5: [0.0, 1.0], 12: [2.0, 2.0]}),
        Ramp([1.0, -1.0], 3, 15),
        RandomWalk(0.1, start=2),
        RandomJump([0.0, 1.0], at=(2, 20), probability=0.7),
    ],
    ids=lambda s: type(s).__name__,
)
def test_schedules_give_each_lane_its_single_lane_values(schedule):
    B, T = 3, 25
    nominal = np.array([[0.5, 0.5], [1.0, 0.0], [-1.0, 3.0]])
    seeds = np.random.SeedSequence(2).spawn(B)
    batch = copy.deepcopy(schedule)
    batch.allocate(B)
    batch.reset_lanes(np.arange(B), nominal, [np.random.default_rng(s) for s in seeds])
    singles = [copy.deepcopy(schedule) for _ in range(B)]
    for single, nom, s in zip(singles, nominal, seeds, strict=True):
        single.reset(nom, np.random.default_rng(s))
    k = np.zeros(B, dtype=np.int64)
    for _ in range(T):
        want = np.array([single(int(kk)) for single, kk in zip(singles, k, strict=True)])
        np.testing.assert_array_equal(batch.values(k), want)
        # next_change never skips a change: values are constant strictly before it.
        nxt = batch.next_change(k)
        for i in range(B):
            if nxt[i] > k[i] + 1 and nxt[i] < k[i] + 50:
                np.testing.assert_array_equal(singles[i](int(nxt[i]) - 1), want[i])
        k = k + np.array([1, 2, 1])


# ------------------------------------------------------------------- threaded batch loops
@pytest.mark.equality
@pytest.mark.parametrize(
    ("env_id", "kwargs"),
    [
        ("stcgym/ObserverCanonical-v0", {"plant": ["stable2", "unstable2"], "noise_std": 0.1}),
        ("stcgym/ObservabilityCanonical-v0", {"plant": "stable4", "process_noise_std": 0.02}),
        ("stcgym/StateSpace-v0", {"noise_std": 0.1, "process_noise_std": 0.01}),
    ],
)
def test_a_batch_above_the_parallel_threshold_equals_the_single_envs(monkeypatch, env_id, kwargs):
    """Batches of at least 2 * PARALLEL_MIN_LANES lanes run in blocks on several threads: each
    lane must still be its single env bit for bit (the threshold lowered to 1 to get there)."""
    import numba

    from stcgym.envs import dynamics

    loops = ("canonical_plants_step", "state_space_plants_step", "canonical_outputs")
    for name in (*loops, "state_outputs"):
        monkeypatch.setattr(getattr(dynamics, name), "min_lanes", 1)
    if numba.get_num_threads() < 2:
        pytest.skip("one thread: no blocks to compare")
    B, seeds = 5, [11, 12, 13, 14, 15]
    venv = gym.make_vec(env_id, num_envs=B, vectorization_mode="vector_entry_point", **kwargs)
    envs = [gym.make(env_id, **kwargs) for _ in range(B)]
    obs, _ = venv.reset(seed=seeds)
    for i, (env, seed) in enumerate(zip(envs, seeds, strict=True)):
        np.testing.assert_array_equal(obs[i], env.reset(seed=seed)[0])
    rng = np.random.default_rng(0)
    ended = np.zeros(B, dtype=bool)
    for _ in range(40):
        actions = rng.uniform(-2, 2, size=(B, *envs[0].action_space.shape))
        obs, reward, terminated, truncated, _ = venv.step(actions)
        for i, env in enumerate(envs):
            if ended[i]:  # the vector env resets an ended lane on its next step
                o, r, term, trunc = env.reset()[0], 0.0, False, False
            else:
                o, r, term, trunc, _ = env.step(actions[i])
            np.testing.assert_array_equal(obs[i], o)
            assert reward[i] == r and terminated[i] == term
            ended[i] = term or trunc
