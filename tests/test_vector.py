"""Native vector envs: equal to independent single envs, Gymnasium and SB3 plumbing."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import stcgym.envs  # noqa: F401 - registers the single envs
from stcgym.envs.signals import Jumps, Ramp, RandomJump, RandomWalk
from stcgym.envs.vector import (
    ObservabilityCanonicalVectorEnv,
    ObserverCanonicalVectorEnv,
    StateSpaceVectorEnv,
)

SINGLE_IDS = {
    ObserverCanonicalVectorEnv: "stcgym/ObserverCanonical-v0",
    ObservabilityCanonicalVectorEnv: "stcgym/ObservabilityCanonical-v0",
    StateSpaceVectorEnv: "stcgym/StateSpace-v0",
}

CASES = [
    (ObserverCanonicalVectorEnv, dict(noise_std=0.1), None),
    (
        ObserverCanonicalVectorEnv,
        dict(plant="stable4", schedule=RandomWalk(0.002), process_noise_std=0.01, reference=0.5),
        {"initial_state": [0.1, 0.0, -0.1, 0.2]},
    ),
    (
        ObserverCanonicalVectorEnv,
        dict(a=[-1.5, 0.7], b=[1.0, 0.5], schedule=Ramp([-1.2, 0.52, 0.9, 0.3], 20, 60)),
        None,
    ),
    (
        ObserverCanonicalVectorEnv,
        dict(
            plant=["stable2", "unstable2", "timevarying2", "nonminphase2"],
            noise_std=0.1,
            process_noise_std=0.05,
            reference="prbs",
        ),
        None,
    ),
    (ObservabilityCanonicalVectorEnv, dict(plant="stable4", noise_std=0.2, reference="sine"), None),
    (
        ObserverCanonicalVectorEnv,
        dict(
            plant=["stable2", "unstable2"],
            noise_std=0.1,
            reference={"kind": "random_steps", "hold": [2, 9]},
            schedule=RandomJump([-1.2, 0.52, 0.9, 0.3], at=(10, 60), probability=0.5),
            initial_state_std=0.5,
        ),
        None,
    ),
    (
        ObservabilityCanonicalVectorEnv,
        dict(plant=["timevarying2", "unstable2"], noise_std=0.2, reference="step"),
        {"initial_state_std": 1.0},
    ),
    (
        StateSpaceVectorEnv,
        dict(A=[[0.9, 0.1], [0.0, 0.8]], B=[[1.0, 0.0], [0.0, 1.0]], noise_std=0.1),
        None,
    ),
    (
        StateSpaceVectorEnv,
        dict(
            C=[[1.0, -0.5]],
            D=[[0.2, 0.1]],
            process_noise_std=0.02,
            schedule=Jumps({30: [[0.5, 0.2, 1.0, 0.0], [0.1, 0.6, 0.0, 1.0]]}),
            reference=[{"kind": "sine", "period": 17}],
        ),
        {"A": [[0.7, 0.1], [0.0, 0.9]]},
    ),
    (StateSpaceVectorEnv, dict(reference=["prbs", "step"], noise_std=0.05), None),
]


def _run_pair(vcls, kwargs, options, *, B=4, T=260, mes=90, seed=7):
    """Step a vector env and B single envs (NEXT_STEP autoreset by hand) with one action
    sequence; yield both results per step."""
    seeds = [seed + 3 * i for i in range(B)]
    venv = vcls(num_envs=B, max_episode_steps=mes, **kwargs)
    envs = [gym.make(SINGLE_IDS[vcls], max_episode_steps=mes, **kwargs) for _ in range(B)]
    vo, vi = venv.reset(seed=seeds, options=options)
    singles = [e.reset(seed=s, options=options) for e, s in zip(envs, seeds, strict=True)]
    yield vo, vi, [o for o, _ in singles], [i for _, i in singles], None, None, None
    rng = np.random.default_rng(seed)
    ended = np.zeros(B, dtype=bool)
    for _ in range(T):
        a = rng.uniform(-3, 3, size=(B, venv.n_inputs))
        vout = venv.step(a)
        souts = []
        for i, e in enumerate(envs):
            if ended[i]:
                o, info = e.reset()
                souts.append((o, 0.0, False, False, info))
            else:
                souts.append(e.step(a[i]))
            ended[i] = souts[-1][2] or souts[-1][3]
        yield vout[0], vout[4], [s[0] for s in souts], [s[4] for s in souts], vout, souts, a


@pytest.mark.equality
@pytest.mark.filterwarnings("ignore:autoreset")  # options A: reverts on autoreset, as singles do
@pytest.mark.parametrize(("vcls", "kwargs", "options"), CASES)
def test_vector_env_equals_single_envs(vcls, kwargs, options):
    """Lane i reproduces gym.make(...) reset with seed s_i bit for bit: observations, rewards,
    flags and info, across autoresets. Both run the same compiled lane function of
    stcgym.envs.dynamics (no BLAS) on the same numbers, and references and schedules give a
    lane the values a single env gets."""
    for vo, vi, so, si, vout, souts, _ in _run_pair(vcls, kwargs, options):
        for i, (o, info) in enumerate(zip(so, si, strict=True)):
            np.testing.assert_array_equal(vo[i], o)
            for key, val in info.items():
                assert vi["_" + key][i]
                np.testing.assert_array_equal(np.asarray(vi[key][i], float), np.asarray(val, float))
        if vout is not None:
            np.testing.assert_array_equal(vout[1], [s[1] for s in souts])
            assert np.array_equal(vout[2], [s[2] for s in souts])
            assert np.array_equal(vout[3], [s[3] for s in souts])


def test_per_lane_parameters_and_options():
    a = np.array([[-1.5, 0.7], [-1.2, 0.52], [-1.7, 0.66]])
    b = np.array([[1.0, 0.5], [0.9, 0.3], [0.5, 0.3]])
    venv = ObserverCanonicalVectorEnv(num_envs=3, a=a, b=b)
    venv.reset(seed=1)
    np.testing.assert_array_equal(venv.theta, np.hstack((a, b)))
    theta = np.array([[-1.0, 0.3, 1.0, 0.0]] * 3)
    _, info = venv.reset(seed=1, options={"theta": theta, "initial_state": [[1.0, 0.0]] * 3})
    np.testing.assert_array_equal(info["theta"], theta)
    np.testing.assert_array_equal(info["x"], [[1.0, 0.0]] * 3)
    single = gym.make("stcgym/ObserverCanonical-v0", a=a[1], b=b[1])
    o1, _ = single.reset(seed=2)
    venv2 = ObserverCanonicalVectorEnv(num_envs=3, a=a, b=b)
    vo, _ = venv2.reset(seed=[0, 2, 4])
    np.testing.assert_array_equal(vo[1], o1)


def test_autoreset_modes_and_validation():
    venv = ObserverCanonicalVectorEnv(
        num_envs=2, max_episode_steps=3, autoreset_mode=AutoresetMode.SAME_STEP
    )
    assert venv.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    venv.reset(seed=0)
    for _ in range(2):
        _, _, _, trunc, infos = venv.step(np.zeros((2, 1)))
        assert not trunc.any()
    obs, rew, term, trunc, infos = venv.step(np.zeros((2, 1)))
    assert trunc.all() and infos["_final_obs"].all()
    assert infos["final_info"]["t"].tolist() == [3, 3] and infos["t"].tolist() == [0, 0]
    # DISABLED: stepping an ended lane is an error until it is reset by mask.
    venv = ObserverCanonicalVectorEnv(num_envs=2, max_episode_steps=1, autoreset_mode="Disabled")
    venv.reset(seed=0)
    venv.step(np.zeros((2, 1)))
    with pytest.raises(RuntimeError):
        venv.step(np.zeros((2, 1)))
    venv.reset(options={"reset_mask": np.array([True, True])})
    venv.step(np.zeros((2, 1)))
    # Validation: shapes, non-finite actions, clipping counted like the single env.
    venv = ObserverCanonicalVectorEnv(num_envs=2, action_bound=1.0)
    with pytest.raises(RuntimeError):
        venv.step(np.zeros((2, 1)))
    venv.reset(seed=0)
    with pytest.raises(ValueError):
        venv.step(np.zeros((3, 1)))
    with pytest.raises(ValueError):
        venv.step(np.array([[np.nan], [0.0]]))
    _, _, _, _, info = venv.step(np.array([[5.0], [0.5]]))
    assert info["clipped"].tolist() == [True, False] and info["n_clipped"].tolist() == [1, 0]
    assert (
        venv.step(np.zeros(2))[4] and ObserverCanonicalVectorEnv(2, info_keys=()).reset()[1] == {}
    )


def test_make_vec_uses_the_vector_entry_point():
    """The registered ids default to the numpy vector env in ``gym.make_vec``."""
    env_id = "stcgym/ObserverCanonical-v0"
    envs = gym.make_vec(
        env_id,
        num_envs=8,
        plant=["stable2", "lightly_damped2"],
        noise_std=0.1,
        max_episode_steps=50,
    )
    assert isinstance(envs.unwrapped, ObserverCanonicalVectorEnv)
    assert envs.num_envs == 8 and envs.unwrapped.max_episode_steps == 50
    obs, _ = envs.reset(seed=3)
    assert obs.shape == (8, 2) and envs.observation_space.shape == (8, 2)
    assert envs.single_action_space.shape == (1,)
    for _ in range(50):
        obs, rew, term, trunc, _ = envs.step(envs.action_space.sample())
    assert trunc.all()
    envs.close()
    for env_id, vcls, kw in (
        ("stcgym/ObservabilityCanonical-v0", ObservabilityCanonicalVectorEnv, {}),
        ("stcgym/StateSpace-v0", StateSpaceVectorEnv, dict(A=[[0.5]], B=[[1.0]])),
    ):
        envs = gym.make_vec(env_id, num_envs=2, **kw)
        assert type(envs) is vcls and envs.max_episode_steps == 1000


@pytest.mark.equality
def test_make_vec_vector_entry_point_equals_sync_vector_env():
    """Same seeds and actions: the native vector env and gymnasium's SyncVectorEnv of single
    envs give identical observations, rewards and autoresets (bit for bit)."""
    kw = dict(plant="unstable2", noise_std=0.1, max_episode_steps=30)
    ours = gym.make_vec("stcgym/ObserverCanonical-v0", num_envs=3, **kw)
    sync = gym.make_vec("stcgym/ObserverCanonical-v0", num_envs=3, vectorization_mode="sync", **kw)
    assert isinstance(sync, gym.vector.SyncVectorEnv)
    o1, _ = ours.reset(seed=[4, 5, 6])
    o2, _ = sync.reset(seed=[4, 5, 6])
    rng = np.random.default_rng(0)
    for _ in range(70):
        np.testing.assert_array_equal(o1, o2)
        a = rng.uniform(-1, 1, size=(3, 1))
        o1, r1, te1, tr1, _ = ours.step(a)
        o2, r2, te2, tr2, _ = sync.step(a)
        np.testing.assert_array_equal(r1, r2)
        np.testing.assert_array_equal(te1 | tr1, te2 | tr2)


def test_sb3_adapter_trains_ppo():
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecEnv

    from stcgym.agents.rl.vec_env import SB3VecEnv

    venv = ObserverCanonicalVectorEnv(num_envs=8, max_episode_steps=40, noise_std=0.05)
    vec = SB3VecEnv(venv)
    assert isinstance(vec, VecEnv) and vec.num_envs == 8
    vec.seed(5)
    obs = vec.reset()
    assert obs.shape == (8, 2)
    _, _, dones, infos = vec.step(np.zeros((8, 1), dtype=np.float32))
    assert dones.shape == (8,) and len(infos) == 8
    for _ in range(39):
        _, _, dones, infos = vec.step(np.zeros((8, 1), dtype=np.float32))
    assert dones.all() and infos[0]["TimeLimit.truncated"]
    assert infos[0]["terminal_observation"].shape == (2,)
    model = PPO("MlpPolicy", vec, n_steps=32, batch_size=64, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=512)
    action, _ = model.predict(vec.reset(), deterministic=True)
    assert action.shape == (8, 1)


@pytest.mark.equality
@pytest.mark.parametrize(
    "kwargs",
    [
        dict(plant=["stable2", "timevarying2"], noise_std=0.1, reference="prbs"),
        dict(plant="stable4", process_noise_std=0.05, schedule=RandomWalk(0.001)),
    ],
)
def test_lookahead_feeds_a_compiled_rollout_equal_to_the_env(kwargs):
    """lookahead(T) (references, parameters, noise of the next T steps) leaves the env as it
    was, and T calls of the published lane function on them reproduce T env steps exactly."""
    from stcgym.envs import dynamics

    B, T = 3, 40
    venv = ObserverCanonicalVectorEnv(num_envs=B, max_episode_steps=None, **kwargs)
    venv.reset(seed=[3, 4, 5])
    for _ in range(5):
        venv.step(np.full((B, 1), 0.1))
    plan = venv.lookahead(T)
    x, theta = venv.x.copy(), venv.params.copy()
    u_seq = np.random.default_rng(1).uniform(-1, 1, (T, B, 1))
    form = dynamics.FORM_CODES[venv.form]
    for j in range(T):
        obs, rew, *_ = venv.step(u_seq[j])
        if plan["params"] is not None:
            theta = np.ascontiguousarray(plan["params"][:, j])
        for i in range(B):
            reward, _, _, _, _, y = dynamics.canonical_plant_step(
                x[i], theta[i], u_seq[j, i, 0], venv.action_bound, venv.process_noise_std,
                plan["z_w"][i, j], venv.noise_std, plan["z_v"][i, j, 0], plan["r"][i, j, 0],
                venv.control_cost, venv.y_bound, form,
            )  # fmt: skip
            assert reward == rew[i] and y == obs[i, 0] and plan["r"][i, j, 0] == obs[i, 1]
        np.testing.assert_array_equal(x, venv.x)
