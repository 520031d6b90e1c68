"""Bad input, numerical trouble and lifecycle of the environments (single and vector).

Every malformed argument raises ``ValueError`` or ``TypeError`` naming the argument, before any
state changes; every accepted input gives finite observations and rewards; every env pickles
and deep-copies with an identical continuation.
"""

from __future__ import annotations

import copy
import pickle
import warnings

import control
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import stcgym.envs  # noqa: F401  (registers the ids)
from stcgym.envs.dynamics import REWARD_FLOOR
from stcgym.envs.signals import PRBS, RandomWalk
from stcgym.envs.vector import ObserverCanonicalVectorEnv, StateSpaceVectorEnv

OC = "stcgym/ObserverCanonical-v0"
OB = "stcgym/ObservabilityCanonical-v0"
SS = "stcgym/StateSpace-v0"
MC = "stcgym/MultichannelStatic-v0"
IDS = [OC, OB, SS, MC]


def _state(env):
    u = env.unwrapped
    return (u.t, np.array(u.x, copy=True), np.array(u.params, copy=True), u.n_clipped)


def _same_state(a, b):
    assert a[0] == b[0] and a[3] == b[3]
    np.testing.assert_array_equal(a[1], b[1])
    np.testing.assert_array_equal(a[2], b[2])


# ----------------------------------------------------------------------------- named cases
@pytest.mark.parametrize(
    ("env_id", "kwargs", "error", "name"),
    [
        (OC, {"noise_std": "big"}, TypeError, "noise_std"),
        (OC, {"noise_std": [0.1]}, TypeError, "noise_std"),
        (OC, {"control_cost": 10**400}, ValueError, "control_cost"),
        (OC, {"reference": object()}, TypeError, "reference"),
        (OC, {"reference": {"kind": "square", "periodd": 3}}, TypeError, "reference"),
        (OC, {"plant": 5}, TypeError, "plant"),
        (OC, {"plant": ["stable2", 5]}, TypeError, "plant"),
        (OC, {"a": [0.5 + 1j], "b": [1.0]}, ValueError, "a must"),
        (OC, {"y_bound": 0}, ValueError, "y_bound"),
        (OC, {"y_bound": -1.0}, ValueError, "y_bound"),
        (OC, {"schedule": 3}, TypeError, "schedule"),
        (SS, {"A": np.eye(2), "B": np.zeros((2, 0))}, ValueError, "B must have at least one"),
        (SS, {"A": np.zeros((0, 0)), "B": np.zeros((0, 1))}, ValueError, "A must have"),
        (SS, {"A": np.eye(2)}, ValueError, "A and B"),
        (SS, {"sys": "not a system"}, TypeError, "sys"),
        (MC, {"theta": [[1, 2], [3]]}, ValueError, "theta"),
        (MC, {"theta": np.zeros((0, 0))}, ValueError, "theta"),
        (MC, {"theta": [[1.0, 2.0j]]}, ValueError, "theta"),
    ],
)
def test_bad_constructor_arguments_raise_naming_them(env_id, kwargs, error, name):
    with pytest.raises(error, match=name):
        gym.make(env_id, **kwargs)


@pytest.mark.parametrize(
    ("env_id", "action", "name"),
    [
        (OC, "abc", "action"),
        (OC, np.array([1 + 1j]), "action must be real"),
        (OC, [np.inf], "action must be finite"),
        (OC, None, "action"),
        (MC, [[1.0, 2.0], [3.0]], "action"),
        (SS, {"u": 1}, "action"),
    ],
)
def test_bad_actions_raise_and_leave_the_env_unchanged(env_id, action, name):
    env = gym.make(env_id, noise_std=0.1)
    env.reset(seed=0)
    env.step(np.full(env.action_space.shape, 0.3))
    before = _state(env)
    with pytest.raises(ValueError, match=name):
        env.step(action)
    _same_state(before, _state(env))


def test_reference_callable_returning_garbage_raises_before_the_step():
    answers = iter(["abc"])
    env = gym.make(OC, reference=lambda k: 0.5 if k == 0 else next(answers))
    env.reset(seed=0)
    before = _state(env)
    with pytest.raises(ValueError, match="reference callable"):
        env.step(np.array([0.1]))
    _same_state(before, _state(env))
    env = gym.make(OC, reference=lambda k: np.nan)
    with pytest.raises(ValueError, match="non-finite"):
        env.reset(seed=0)


def test_unknown_reset_options_raise_before_anything_changes():
    env = gym.make(OC)
    env.reset(seed=4)
    env.step(np.array([1.0]))
    before = _state(env)
    rng_state = env.unwrapped.np_random.bit_generator.state
    for options in ({"intial_state": [5, 5]}, {"A": np.eye(2)}, {"theta": [1.0, 2.0, 3.0]}):
        with pytest.raises(ValueError, match="intial_state|'A'|theta"):
            env.reset(seed=1, options=options)
        _same_state(before, _state(env))
        assert env.unwrapped.np_random.bit_generator.state == rng_state
    with pytest.raises(ValueError, match="initial_state"):
        gym.make(MC).reset(options={"initial_state": []})
    venv = ObserverCanonicalVectorEnv(num_envs=2)
    venv.reset(seed=0)
    with pytest.raises(ValueError, match="intial_state"):
        venv.reset(options={"intial_state": [5, 5]})


def test_vector_env_bad_actions_and_seeds_raise_naming_them():
    venv = ObserverCanonicalVectorEnv(num_envs=2)
    venv.reset(seed=0)
    x = venv.x.copy()
    for actions, match in (("ab", "actions"), (np.array([[1j], [0.0]]), "actions must be real")):
        with pytest.raises(ValueError, match=match):
            venv.step(actions)
    np.testing.assert_array_equal(venv.x, x)
    with pytest.raises(ValueError, match="num_envs=2"):
        venv.reset(seed=[1, 2, 3])
    with pytest.raises(ValueError, match="seed"):
        venv.reset(seed=[1, "a"])
    with pytest.raises(TypeError, match="num_envs"):
        ObserverCanonicalVectorEnv(num_envs=2.5)


def test_reward_overflow_terminates_with_a_finite_reward():
    """Documented safe behaviour: a reward that overflows ends the episode (diverged) with
    reward REWARD_FLOOR, the most negative finite float."""
    cases = [
        dict(reference={"kind": "step", "amplitude": 1e200}),
        dict(control_cost=1e308, reference="zero"),
        dict(a=[-3.0], b=[1.0], y_bound=1e300, reference="zero"),
    ]
    for kwargs in cases:
        env = gym.make(OC, max_episode_steps=None, **kwargs)
        env.reset(seed=0)
        for _ in range(1000):
            obs, reward, terminated, _, info = env.step(np.array([5.0]))
            assert np.isfinite(reward) and np.all(np.isfinite(obs))
            if terminated:
                break
        assert terminated and info["diverged"] and reward == REWARD_FLOOR, kwargs


def test_per_lane_options_reverting_on_autoreset_warn():
    venv = ObserverCanonicalVectorEnv(num_envs=2, max_episode_steps=2)
    a = np.array([[-1.2, 0.52], [-1.5, 0.7]])
    venv.reset(seed=0, options={"a": a, "b": np.ones((2, 2))})
    venv.step(np.zeros((2, 1)))
    venv.step(np.zeros((2, 1)))
    with pytest.warns(UserWarning, match="constructor's plant"):
        venv.step(np.zeros((2, 1)))
    np.testing.assert_array_equal(venv.theta[0], stcgym.envs.PLANTS["stable2"].theta)


# ----------------------------------------------------------------------------- defaults
def test_state_space_makes_with_no_arguments_a_mimo_plant():
    env = gym.make(SS)
    assert env.action_space.shape == (2,) and env.observation_space.shape == (4,)
    A = env.unwrapped.A
    assert np.all(np.abs(np.linalg.eigvals(A)) < 1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        check_env(env.unwrapped, skip_render_check=True)


@pytest.mark.parametrize("env_id", IDS)
def test_matrices_and_parameters_exist_before_the_first_reset(env_id):
    env = gym.make(env_id).unwrapped
    assert env.A.shape[0] == env.B.shape[0] == env.n_states
    assert env.C.shape == (env.n_outputs, env.n_states)
    assert env.D.shape == (env.n_outputs, env.n_inputs)
    theta = env.theta
    env.reset(seed=0)
    np.testing.assert_array_equal(theta, env.theta)
    assert env_id in (OC, OB) or env.plant is None


@pytest.mark.parametrize("env_id", IDS)
def test_sb3_check_env_passes(env_id):
    pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.env_checker import check_env

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        check_env(gym.make(env_id).unwrapped, warn=False)


# ----------------------------------------------------------------------------- lifecycle
COPY_CASES = [
    (OC, dict(plant=["stable2", "unstable2"], noise_std=0.1, reference="prbs")),
    (OB, dict(plant="stable4", process_noise_std=0.01, schedule=RandomWalk(0.001))),
    (SS, dict(sys=control.tf([1.0], [1.0, 0.5, 1.0]), dt=0.2, noise_std=0.1)),
    (SS, dict(sys=control.tf([1.0, 0.2], [1.0, -0.5, 0.1], True), canonical="reachable")),
    (MC, dict(reference="sine")),
]


def _continuations(env, other, steps=30, vector=False):
    rng = np.random.default_rng(0)
    for _ in range(steps):
        a = rng.uniform(-2, 2, size=env.action_space.shape)
        out1, out2 = env.step(a), other.step(a)
        for v1, v2 in zip(out1[:4], out2[:4], strict=True):
            np.testing.assert_array_equal(v1, v2)


def _clones_continue_like_the_original(env, steps=30):
    """Each clone (pickled, deep-copied) made from ``env`` as it is then steps like ``env``."""
    for make_clone in (lambda e: pickle.loads(pickle.dumps(e)), copy.deepcopy):
        _continuations(env, make_clone(env), steps=steps)


@pytest.mark.parametrize(("env_id", "kwargs"), COPY_CASES)
def test_single_envs_pickle_and_deepcopy_with_identical_continuation(env_id, kwargs):
    env = gym.make(env_id, **kwargs)
    env.reset(seed=2)
    for _ in range(7):
        env.step(env.action_space.sample())
    _clones_continue_like_the_original(env)
    clone = copy.deepcopy(env)
    _, info = clone.reset(seed=5)
    _, info2 = env.reset(seed=5)
    np.testing.assert_array_equal(info["x"], info2["x"])


@pytest.mark.parametrize(
    ("vcls", "kwargs"),
    [
        (ObserverCanonicalVectorEnv, dict(plant=["stable2", "timevarying2"], reference=PRBS())),
        (StateSpaceVectorEnv, dict(sys=control.tf([1.0], [1.0, 0.5, 1.0]), dt=0.2)),
    ],
)
def test_vector_envs_pickle_and_deepcopy_with_identical_continuation(vcls, kwargs):
    venv = vcls(num_envs=3, max_episode_steps=5, noise_std=0.1, **kwargs)
    venv.reset(seed=0)
    for _ in range(3):
        venv.step(venv.action_space.sample())
    _clones_continue_like_the_original(venv, steps=12)


def test_the_copy_check_catches_a_copy_that_loses_the_state(monkeypatch):
    """A copy that restarts its plant from x = 0 (the same for every copy) must be caught."""
    env = gym.make(OC, plant="stable2", noise_std=0.1)
    env.reset(seed=2)
    for _ in range(7):
        env.step(np.array([1.0]))
    cls = type(env.unwrapped)

    def lossy_setstate(self, state):
        self.__dict__.update(state)
        self.__dict__["_x"] = np.zeros_like(state["_x"])

    monkeypatch.setattr(cls, "__setstate__", lossy_setstate, raising=False)
    with pytest.raises(AssertionError):
        _clones_continue_like_the_original(env)


def test_make_vec_state_space_from_sys_pickles():
    venv = gym.make_vec(SS, num_envs=2, sys=control.ss([[0.5]], [[1.0]], [[1.0]], [[0.0]], True))
    venv.reset(seed=0)
    clone = pickle.loads(pickle.dumps(venv))
    np.testing.assert_array_equal(clone.step(np.ones((2, 1)))[0], venv.step(np.ones((2, 1)))[0])


# ----------------------------------------------------------------------------- property test
_MALFORMED = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(10**400), max_value=10**400),
    st.floats(allow_nan=True, allow_infinity=True),
    st.complex_numbers(allow_nan=False, max_magnitude=1e3),
    st.text(max_size=4),
    st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=4),
    st.lists(st.lists(st.floats(-1e3, 1e3), max_size=3), max_size=3),
    st.just(object()),
    st.dictionaries(st.text(max_size=3), st.integers(), max_size=2),
)

_ARGS = {
    OC: ["noise_std", "process_noise_std", "action_bound", "control_cost", "y_bound", "reference",
         "plant", "a", "initial_state", "schedule"],
    OB: ["noise_std", "y_bound", "reference", "plant", "b", "initial_state"],
    SS: ["A", "B", "C", "D", "noise_std", "reference", "initial_state", "dt"],
    MC: ["theta", "noise_std", "action_bound", "reference", "control_cost"],
}  # fmt: skip


def _names(exc: Exception, arg: str) -> bool:
    """Whether the message names ``arg`` (one-letter names only as ``'A'``, ``A must``, ...)."""
    msg = str(exc)
    if len(arg) > 1:
        return arg in msg
    return any(p in msg for p in (f"'{arg}'", f"{arg} must", f"{arg} and", f"and {arg} "))


def _finite_episode(env, actions) -> None:
    obs, _ = env.reset(seed=0)
    assert np.all(np.isfinite(obs))
    for a in actions:
        try:
            obs, reward, terminated, truncated, _ = env.step(a)
        except (ValueError, TypeError) as exc:
            assert "action" in str(exc), exc
            continue
        assert np.all(np.isfinite(obs)) and np.isfinite(reward)
        if terminated or truncated:
            obs, _ = env.reset()


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    env_id=st.sampled_from(IDS),
    data=st.data(),
    value=_MALFORMED,
    actions=st.lists(_MALFORMED, min_size=1, max_size=4),
)
def test_malformed_input_is_a_clear_error_or_finite(env_id, data, value, actions):
    """Any malformed constructor argument or action: a ValueError/TypeError naming the
    argument, or an env whose observations and rewards stay finite; never a raw numpy/scipy
    error, never NaN/inf."""
    arg = data.draw(st.sampled_from(_ARGS[env_id]))
    kwargs = {arg: value}
    if arg in ("a", "b"):
        kwargs = {"a": value, "b": value}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        try:
            env = gym.make(env_id, max_episode_steps=20, **kwargs)
        except (ValueError, TypeError) as exc:
            pair = arg in ("a", "b") and (_names(exc, "a") or _names(exc, "b"))
            assert pair or _names(exc, arg), f"{arg}={value!r}: {exc}"
            return
        try:
            env.reset(seed=0)
        except (ValueError, TypeError) as exc:  # a reference or schedule checked at reset
            assert _names(exc, arg) or "reference" in str(exc) or "parameters" in str(exc), exc
            return
        shape = env.action_space.shape
        good = [np.full(shape, 0.5), np.full(shape, 1e6)]
        _finite_episode(env, good + list(actions))
        key = data.draw(st.sampled_from(sorted(env.unwrapped.reset_options) + ["intial_state"]))
        before = _state(env)
        try:
            obs, _ = env.reset(options={key: value})
        except (ValueError, TypeError) as exc:
            assert _names(exc, key), exc
            _same_state(before, _state(env))
        else:
            assert np.all(np.isfinite(obs))


@settings(max_examples=60, deadline=None)
@given(actions=st.lists(_MALFORMED, min_size=1, max_size=4), key=st.sampled_from(
    ["initial_state", "initial_state_std", "theta", "a", "plant", "reset_mask", "intial_state"]
))  # fmt: skip
def test_vector_env_malformed_steps_and_options(actions, key):
    venv = ObserverCanonicalVectorEnv(num_envs=2, max_episode_steps=5)
    venv.reset(seed=0)
    for value in actions:
        x = venv.x.copy()
        try:
            obs, reward, *_ = venv.step(value)
        except (ValueError, TypeError) as exc:
            assert "actions" in str(exc), exc
            np.testing.assert_array_equal(venv.x, x)
        else:
            assert np.all(np.isfinite(obs)) and np.all(np.isfinite(reward))
        try:
            obs, _ = venv.reset(options={key: value})
        except (ValueError, TypeError) as exc:
            assert _names(exc, key), exc
        else:
            assert np.all(np.isfinite(obs))
