"""Known-model oracles (stcgym.adaptive.control.oracles): against a dense numpy loop written from
the
equations with python-control's gains, batched lanes against single plants, lifecycle and bad
input."""

from __future__ import annotations

import copy
import pickle

import control
import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import stcgym.envs  # noqa: F401  (registers the envs)
from stcgym.adaptive.control.controller import SelfTuningController
from stcgym.adaptive.control.options import LawOptions
from stcgym.adaptive.control.oracles import KalmanObserver, KnownModelController, LQGController
from stcgym.adaptive.policy import Policy
from stcgym.envs.canonical import companion_A, observer_to_observability_b
from stcgym.envs.env_settings import DEFAULT_ACTION_BOUND

A_S2, B_S2 = (-1.5, 0.7), (1.0, 0.5)  # stable2
A_U2, B_U2 = (-1.7, 0.66), (1.0, 0.6)  # unstable2 (poles 1.1, 0.6)


def _observations(steps: int, seed: int, lanes: int | None = None) -> np.ndarray:
    """Synthetic ``[y, r]`` sequences: a noisy response-like signal and a square reference."""
    rng = np.random.default_rng(seed)
    shape = (steps,) if lanes is None else (steps, lanes)
    r = np.where((np.arange(steps) // 25) % 2 == 0, 1.0, -1.0)
    r = r if lanes is None else r[:, None] * np.ones(lanes)
    y = 0.8 * r + 0.3 * rng.standard_normal(shape)
    return np.stack([y, r], axis=-1)


def _reference_loop(A, b, K, N, ki, Q, R, P0, obs, bound, integral=True, filtered=True):
    """Dense numpy known-model loop: Kalman correction, tracking law, Kalman prediction."""
    n = A.shape[0]
    x, P, xi = np.zeros(n), P0.copy(), 0.0
    out = []
    for y, r in obs:
        s = R + P[0, 0]
        g = P[:, 0] / s
        xf = x + g * (y - x[0])
        u = N * r - K @ (xf if filtered else x) - ki * xi
        u_sat = float(np.clip(u, -bound, bound))
        if integral and not (u_sat != u and (-ki * (r - y)) * u > 0):
            xi += r - y
        x = A @ xf + b * u_sat
        P = A @ (P - np.outer(g, P[0])) @ A.T + Q
        out.append(u_sat)
    return np.array(out)


def _steady_state(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    n = A.shape[0]
    M = np.block([[A - np.eye(n), b[:, None]], [np.eye(1, n), np.zeros((1, 1))]])
    sol = np.linalg.solve(M, np.r_[np.zeros(n), 1.0])
    return sol[:n], sol[n]


# ------------------------------------------------------------------------------ against numpy
@pytest.mark.parametrize(
    ("form", "filtered"), [("observer", True), ("observability", True), ("observer", False)]
)
@pytest.mark.parametrize(("a", "b"), [(A_S2, B_S2), (A_U2, B_U2)])
def test_known_model_controller_matches_numpy_loop(
    form: str, filtered: bool, a: tuple, b: tuple
) -> None:
    if form == "observability":  # the same plant: b as Markov parameters
        b = tuple(observer_to_observability_b(a, b))
    orc = KnownModelController(
        a, b, poles=[0.3, 0.5, 0.6], action_bound=2.0, form=form,
        law=LawOptions(filtered=filtered),
    )  # fmt: skip
    A, bv = companion_A(np.array(a), form), np.array(b)
    Aa = np.block([[A, np.zeros((2, 1))], [np.array([[-1.0, 0.0, 1.0]])]])
    K = np.ravel(control.acker(Aa, np.r_[bv, 0.0][:, None], [0.3, 0.5, 0.6]))
    x_ss, u_ss = _steady_state(A, bv)
    N = u_ss + K[:2] @ x_ss
    np.testing.assert_allclose(orc.K, K, rtol=1e-9)
    assert orc.N == pytest.approx(N, rel=1e-9)
    obs = _observations(300, 0)
    ref = _reference_loop(
        A, bv, K[:2], N, K[2], np.zeros((2, 2)), 1.0, np.eye(2), obs, 2.0, filtered=filtered
    )
    got = np.array([orc.predict(o)[0][0] for o in obs])
    np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-11)
    assert orc.t == 300


@pytest.mark.parametrize("integral", [False, True])
def test_lqg_controller_matches_dlqr_dlqe_loop(integral: bool) -> None:
    rho, noise, w_in, floor, q_i = 0.02, 0.05, 0.01, 1e-8, 0.03
    law = LawOptions(integral=integral, lq_weights=(1.0, q_i, rho))
    orc = LQGController(A_U2, B_U2, law=law, noise_std=noise, action_bound=3.0)
    A, b = companion_A(np.array(A_U2)), np.array(B_U2)
    if integral:
        Aa = np.block([[A, np.zeros((2, 1))], [np.array([[-1.0, 0.0, 1.0]])]])
        K, _, _ = control.dlqr(Aa, np.r_[b, 0.0][:, None], np.diag([1.0, 0.0, q_i]), [[rho]])
    else:
        K, _, _ = control.dlqr(A, b[:, None], np.diag([1.0, 0.0]), [[rho]])
    K = np.ravel(K)
    np.testing.assert_allclose(orc.K, K, rtol=1e-8)
    W = w_in**2 * np.outer(b, b) + floor * np.eye(2)
    _, P, _ = control.dlqe(A, np.eye(2), np.eye(1, 2), W, [[noise**2]])
    x_ss, u_ss = _steady_state(A, b)
    np.testing.assert_allclose(orc.x_ss, x_ss, rtol=1e-10)
    assert orc.u_ss == pytest.approx(u_ss, rel=1e-10)
    N = u_ss + K[:2] @ x_ss
    obs = _observations(300, 1)
    ref = _reference_loop(
        A, b, K[:2], N, K[2] if integral else 0.0, W, noise**2, np.asarray(P), obs, 3.0, integral
    )
    got = np.array([orc.predict(o)[0][0] for o in obs])
    np.testing.assert_allclose(got, ref, rtol=1e-7, atol=1e-9)


def test_lqg_plant_that_cannot_be_stabilised_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match="cannot be stabilised"):
        LQGController([-3, 2], [1, -2])  # the pole at 2 is cancelled by the zero at 2
    with pytest.raises(ValueError, match="z = 1"):
        LQGController([-1.5, 0.7], [1.0, -1.0])  # a zero at z = 1: no steady state
    with pytest.raises(ValueError, match="cannot place the poles"):
        KnownModelController([-3, 2], [1, -2])


# ------------------------------------------------------------------------------ batched lanes
@pytest.mark.parametrize("cls", [KnownModelController, LQGController])
def test_batched_lanes_equal_single_plants(cls: type) -> None:
    rng = np.random.default_rng(3)
    B = 4
    a = np.array([A_S2, A_U2, (-1.6, 0.6), (-1.2, 0.5)]) + rng.uniform(-0.01, 0.01, (B, 2))
    b = np.array([B_S2, B_U2, (0.2, 0.1), (1.0, -0.3)])
    batch = cls(a, b, num_envs=B)
    assert isinstance(batch, cls) and isinstance(batch, Policy)
    singles = [cls(a[i], b[i]) for i in range(B)]
    obs = _observations(200, 2, lanes=B)
    for k, o in enumerate(obs):
        start = np.zeros(B, dtype=bool)
        start[k % B] = k == 120  # one lane restarts its episode mid-run
        u_b = batch.predict(o, episode_start=start)[0]
        assert u_b.shape == (B, 1)
        for i, s in enumerate(singles):
            u_s = s.predict(o[i], episode_start=bool(start[i]))[0]
            assert u_b[i, 0] == u_s[0]  # the same compiled lane function: bit for bit
    np.testing.assert_array_equal(batch.t, [s.t for s in singles])
    np.testing.assert_array_equal(batch.K, np.stack([s.K for s in singles]))


@pytest.mark.parametrize("cls", [KnownModelController, LQGController])
def test_single_oracle_rejects_a_batch_of_observations(cls: type) -> None:
    orc = cls(A_S2, B_S2)
    orc.predict(np.array([0.3, 1.0]))
    before = _state(orc)
    with pytest.raises(ValueError, match=r"observation must have shape \(2,\) for num_envs=None"):
        orc.predict(_observations(1, 4, lanes=3)[0])
    assert _state(orc) == before
    assert orc.t == 1


def test_set_model_per_lane_and_reset_restores_the_initial_model() -> None:
    orc = KnownModelController([A_S2, A_S2, A_S2], [B_S2, B_S2, B_S2], num_envs=3)
    orc.predict(_observations(1, 0, lanes=3)[0])
    K0 = orc.K
    orc.set_model(A_U2, B_U2, lanes=[False, True, False])
    np.testing.assert_array_equal(orc.a[[0, 2]], [A_S2, A_S2])
    np.testing.assert_array_equal(orc.a[1], A_U2)
    np.testing.assert_array_equal(orc.K[[0, 2]], K0[[0, 2]])
    assert np.abs(orc.K[1] - K0[1]).max() > 1e-3
    before = pickle.dumps(orc)
    with pytest.raises(ValueError, match="cannot place the poles"):
        orc.set_model([[-1.5, 0.7], [-3.0, 2.0]], [[1.0, 0.5], [1.0, -2.0]], lanes=[0, 2])
    assert pickle.dumps(orc) == before  # a failed redesign changes nothing
    orc.reset(lanes=[1])
    np.testing.assert_array_equal(orc.a[1], A_S2)
    np.testing.assert_array_equal(orc.K, np.stack([K0[0]] * 3))
    assert orc.t.tolist() == [1, 0, 1]


def test_lqg_set_model_redesigns_filter_and_gain() -> None:
    orc = LQGController(A_S2, B_S2)
    orc.set_model(A_U2, B_U2)
    ref = LQGController(A_U2, B_U2)
    np.testing.assert_allclose(orc.K, ref.K, rtol=1e-12)
    obs = _observations(30, 5)
    np.testing.assert_allclose(
        [orc.predict(o)[0][0] for o in obs], [ref.predict(o)[0][0] for o in obs], rtol=1e-12
    )


@pytest.mark.parametrize("restart", ["reset", "episode_start"])
def test_lqg_reset_after_set_model_restores_the_initial_filter(restart: str) -> None:
    # set_model writes the new model's process noise Q (input noise along the new b); a new
    # episode restores the initial model, so it must restore the initial Q with it
    orc = LQGController([A_S2, A_S2], [B_S2, B_S2], num_envs=2)
    fresh = LQGController(A_S2, B_S2)
    obs = _observations(40, 8, lanes=2)
    orc.predict(obs[0])
    orc.set_model(A_U2, B_U2, lanes=[1])
    if restart == "reset":
        orc.reset(lanes=[1])
        starts = [False, False]
    else:
        starts = [False, True]
    got = [orc.predict(o, episode_start=starts if k == 0 else None)[0][1, 0]
           for k, o in enumerate(obs)]  # fmt: skip
    np.testing.assert_array_equal(got, [fresh.predict(o[1])[0][0] for o in obs])
    np.testing.assert_array_equal(orc.a[1], A_S2)


def test_oracles_share_the_controllers_settings_and_defaults() -> None:
    env = gym.make("stcgym/ObservabilityCanonical-v0", plant="stable2", action_bound=4.0)
    a, b = env.unwrapped.a, env.unwrapped.b
    ctl = SelfTuningController(2, env=env)
    for orc in (KnownModelController(a, b, env=env), LQGController(a, b, env=env)):
        assert orc.law == ctl.law == LawOptions()
        assert orc.action_bound == ctl.action_bound == 4.0
        assert orc.form == ctl.form == "observability"
        assert orc.K.shape == (3,)  # integral action on, as the controller's
    np.testing.assert_array_equal(KnownModelController(a, b, env=env).poles, ctl.poles)
    plain = (KnownModelController(A_S2, B_S2), LQGController(A_S2, B_S2), SelfTuningController(2))
    assert {p.action_bound for p in plain} == {DEFAULT_ACTION_BOUND}
    assert {p.form for p in plain} == {"observer"}
    with pytest.raises(ValueError, match="exceeds the env's action_bound"):
        KnownModelController(a, b, env=env, action_bound=5.0)
    venv = gym.make_vec("stcgym/ObserverCanonical-v0", num_envs=3, plant="stable2")
    with pytest.raises(ValueError, match="num_envs"):
        LQGController([A_S2, A_S2], [B_S2, B_S2], num_envs=2, env=venv)
    venv.close()
    with pytest.raises(ValueError, match="plant order"):
        KnownModelController([-0.5], [1.0], env=env)
    env.close()


# ------------------------------------------------------------------------------ lifecycle
@pytest.mark.parametrize(
    "make",
    [
        lambda: KnownModelController(A_S2, B_S2),
        lambda: LQGController(A_U2, B_U2),
        lambda: KnownModelController([A_S2, A_U2], [B_S2, B_U2], num_envs=2),
        lambda: LQGController([A_S2, A_U2], [B_S2, B_U2], num_envs=2, law={"integral": False}),
    ],
)
@pytest.mark.parametrize("clone", [pickle.loads, copy.deepcopy])
def test_pickle_and_deepcopy_continue_identically(make, clone) -> None:
    orc = make()
    lanes = orc.num_envs
    obs = _observations(80, 6, lanes=lanes)
    for o in obs[:40]:
        orc.predict(o)
    twin = clone(pickle.dumps(orc)) if clone is pickle.loads else clone(orc)
    for o in obs[40:]:
        np.testing.assert_array_equal(orc.predict(o)[0], twin.predict(o)[0])
    orc.reset()
    twin.reset()
    np.testing.assert_array_equal(orc.predict(obs[0])[0], twin.predict(obs[0])[0])


def _state(orc) -> bytes:
    return pickle.dumps((orc._state, orc._a, orc._b))


@pytest.mark.parametrize(
    ("bad", "match"),
    [
        ([np.nan, 1.0], "observation"),
        ([0.0, np.inf], "observation"),
        ([0.0, 1.0, 2.0], "observation"),
        ("ab", "observation"),
    ],
)
def test_rejected_predict_leaves_the_state_unchanged(bad, match: str) -> None:
    orc = KnownModelController(A_U2, B_U2)
    for o in _observations(20, 7):
        orc.predict(o)
    before = _state(orc)
    with pytest.raises(ValueError, match=match):
        orc.predict(bad)
    assert _state(orc) == before
    orc.predict(np.array([0.0, 1.0]))


def test_overflowing_observation_is_rejected_atomically() -> None:
    orc = LQGController([A_S2, A_U2], [B_S2, B_U2], num_envs=2)
    ok = np.array([[0.1, 1.0], [0.2, 1.0]])
    orc.predict(ok)
    huge = np.array([[0.1, 1.0], [1.7e308, 0.0]])
    raised = False
    for _ in range(5):
        before = _state(orc)
        try:
            u = orc.predict(huge, episode_start=[True, False])[0]
        except ValueError as exc:
            assert "non-finite" in str(exc) and "unchanged" in str(exc)
            assert _state(orc) == before  # also lane 0, which alone would have been fine
            raised = True
            break
        assert np.all(np.isfinite(u))
    assert raised
    assert np.all(np.isfinite(orc.predict(ok)[0]))


def test_batched_bad_input_names_the_argument() -> None:
    orc = KnownModelController([A_S2, A_U2, A_S2], [B_S2, B_U2, B_S2], num_envs=3)
    obs = _observations(1, 0, lanes=3)[0]
    before = _state(orc)
    with pytest.raises(ValueError, match="episode_start"):
        orc.predict(obs, episode_start=[True, False])
    with pytest.raises(ValueError, match="observation"):
        orc.predict(obs[:2])
    with pytest.raises(ValueError, match="lanes"):
        orc.reset(lanes=[7])
    with pytest.raises(ValueError, match="lanes"):
        orc.reset(lanes=[True, False])
    with pytest.raises(ValueError, match="lanes"):
        orc.set_model(A_S2, B_S2, lanes=[-1])
    assert _state(orc) == before
    with pytest.raises(ValueError, match="lanes"):
        KnownModelController(A_S2, B_S2).reset(lanes=[1])


@pytest.mark.parametrize(
    ("cls", "kwargs", "match"),
    [
        (KnownModelController, {"poles": [0.5, 0.5, 1.0]}, "unit circle"),
        (KnownModelController, {"action_bound": -1.0}, "action_bound"),
        (KnownModelController, {"action_bound": "big"}, "action_bound"),
        (KnownModelController, {"P0": 0.0}, "P0"),
        (KnownModelController, {"measurement_noise": 0.0}, "measurement_noise"),
        (KnownModelController, {"process_noise": -1.0}, "process_noise"),
        (KnownModelController, {"form": "diagonal"}, "form"),
        (KnownModelController, {"num_envs": 0}, "num_envs"),
        (KnownModelController, {"num_envs": 1.5}, "num_envs"),
        (KnownModelController, {"num_envs": True}, "num_envs"),
        (LQGController, {"law": {"lq_weights": (1.0, 1e-4, 0.0)}}, "rho"),
        (LQGController, {"noise_std": -0.1}, "noise_std"),
        (LQGController, {"input_noise_std": np.nan}, "input_noise_std"),
        (LQGController, {"law": {"lq_weights": (1.0, 0.0, 0.01)}}, "q_i"),
        (KnownModelController, {"law": {"integral": 1}}, "integral"),
        (KnownModelController, {"law": "pid"}, "law"),
        (LQGController, {"action_bound": 0.0}, "action_bound"),
    ],
)
def test_bad_construction(cls: type, kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        cls(A_S2, B_S2, **kwargs)


def test_bad_parameters() -> None:
    with pytest.raises(ValueError, match="same length"):
        KnownModelController([-1.5, 0.7], [1.0])
    with pytest.raises(ValueError, match="one-dimensional"):
        KnownModelController([A_S2, A_S2], [B_S2, B_S2])
    with pytest.raises(ValueError, match=r"\(num_envs, n\) = \(2, n\)"):
        LQGController([A_S2, A_S2, A_S2], B_S2, num_envs=2)
    with pytest.raises(ValueError, match="a must"):
        KnownModelController("ab", B_S2)
    with pytest.raises(ValueError, match="order 2"):
        KnownModelController(A_S2, B_S2).set_model([0.1], [1.0])


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    value=st.one_of(
        st.floats(allow_nan=True, allow_infinity=True),
        st.integers(-5, 5),
        st.text(max_size=3),
        st.none(),
        st.lists(st.floats(-2, 2), max_size=3),
    ),
    key=st.sampled_from(
        [
            "poles",
            "action_bound",
            "P0",
            "measurement_noise",
            "process_noise",
            "law",
            "noise_std",
            "num_envs",
            "a",
            "b",
        ]
    ),  # fmt: skip
)
def test_malformed_settings_raise_value_error_or_work(value, key: str) -> None:
    """Property: a malformed setting is a ValueError naming it, or a working oracle."""
    cls = LQGController if key in ("law", "noise_std") else KnownModelController
    kwargs: dict = {}
    args = {"a": A_S2, "b": B_S2}
    if key in args:
        args[key] = value
    else:
        kwargs[key] = value
    try:
        orc = cls(args["a"], args["b"], **kwargs)
    except ValueError as exc:
        name = key.split("_")[0] if key in ("a", "b") else key
        assert name in str(exc) or "same length" in str(exc) or "poles" in str(exc)
        return
    n_obs = orc.num_envs
    u = orc.predict(_observations(1, 0, lanes=n_obs)[0])[0]
    assert np.all(np.isfinite(u))


def test_kalman_observer_matches_the_equations() -> None:
    A = companion_A(np.array(A_U2))
    b = np.array(B_U2)
    kf = KalmanObserver(A, b, process_noise=0.01, measurement_noise=0.5, P0=2.0)
    x, P = np.zeros(2), 2.0 * np.eye(2)
    for y, u in [(0.3, 1.0), (-0.2, 0.5), (1.1, -0.7)]:
        xf = kf.correct(y)
        g = P[:, 0] / (0.5 + P[0, 0])
        np.testing.assert_allclose(xf, x + g * (y - x[0]), rtol=1e-13)
        x = A @ (x + g * (y - x[0])) + b * u
        P = A @ (P - np.outer(g, P[0])) @ A.T + 0.01 * np.eye(2)
        np.testing.assert_allclose(kf.predict(u), x, rtol=1e-12)
        np.testing.assert_allclose(kf.P, P, rtol=1e-12)
    with pytest.raises(ValueError, match="measurement_noise"):
        KalmanObserver(A, b, measurement_noise=0.0)
