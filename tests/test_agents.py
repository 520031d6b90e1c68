"""RL observation wrapper, SB3 adapter, configs and the evaluation loop."""

from __future__ import annotations

import math
import re

import gymnasium as gym
import numpy as np
import pytest

import stcgym.envs  # noqa: F401  (registers the env ids)
from stcgym.agents.evaluation.evaluate import (
    EnvSpec,
    default_windows,
    evaluate,
    run_episode,
    summarize,
)
from stcgym.agents.rl.configs import DEFAULT_CONFIGS, default_config
from stcgym.agents.rl.overrides import apply_overrides, parse_override
from stcgym.agents.rl.wrappers import HistoryBuffer, HistoryWindow, TrainingReward, WindowConfig


class LinearFeedback:
    """A fixed proportional controller with a feed-forward, written against the protocol."""

    def __init__(self, kp: float = 0.1, kff: float = 0.13) -> None:
        self.kp, self.kff, self.seen = kp, kff, []

    def reset(self) -> None:
        self.seen = []

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        self.seen.append(np.array(obs))
        y, r = obs
        return np.array([self.kff * r + self.kp * (r - y)]), state


class FakeModel:
    """Stands in for an SB3 model: a fixed nonlinear function of the window features."""

    def __init__(self) -> None:
        self.seen: list[np.ndarray] = []

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        obs = np.asarray(obs, dtype=np.float32)
        self.seen.append(obs.copy())
        w = np.linspace(-0.05, 0.05, obs.shape[-1])
        return np.tanh(obs @ w)[..., None].astype(np.float32), state


def _env(plant: str = "stable2", steps: int = 100, **kw) -> gym.Env:
    return gym.make(
        "stcgym/ObserverCanonical-v0", plant=plant, max_episode_steps=steps, noise_std=0.05, **kw
    )


# ------------------------------------------------------------------------------ wrapper
def test_window_config_validates():
    assert WindowConfig(window=4).n_features == 17  # y, r, u, e windows and the integral
    assert WindowConfig(window=4, include_integral=False).n_features == 16
    assert WindowConfig(window=4, include_error=False).n_features == 13
    assert WindowConfig(window=4).features_for(3, 2) == 4 * (3 * 3 + 2) + 3
    bad_values = (
        dict(window=0), dict(window=2.5), dict(y_scale=0), dict(obs_clip=-1),
        dict(integral_gain=0.0), dict(integral_gain=float("nan")),
    )  # fmt: skip
    for bad in bad_values:
        with pytest.raises(ValueError):
            WindowConfig(**bad)


def test_integral_feature_is_the_clipped_running_sum_of_the_error():
    # by hand: z(k) = clip(z(k-1) + g (r(k) - y(k)) / y_scale, -clip, clip)
    g, scale, clip = 0.5, 2.0, 1.5
    config = WindowConfig(window=1, include_error=False, y_scale=scale, integral_gain=g,
                          obs_clip=clip)  # fmt: skip
    buf = HistoryBuffer(config, action_bound=1.0, batch=2)
    obs = [
        np.array([[0.0, 1.0], [0.0, -1.0]]),
        np.array([[0.5, 1.0], [-2.0, -1.0]]),
        np.array([[0.0, 4.0], [0.0, -1.0]]),
        np.array([[0.0, 4.0], [0.0, -1.0]]),
    ]
    buf.start(obs[0])
    z = np.zeros(2)
    expected = []
    for k, o in enumerate(obs):
        if k:
            buf.push_action([0.0, 0.0])
            buf.push_obs(o)
        z = np.clip(z + g * (o[:, 1] - o[:, 0]) / scale, -clip, clip)
        expected.append(z.copy())
        np.testing.assert_allclose(buf.features()[:, -1], z, rtol=1e-6)
    assert expected[-1][0] == clip  # anti-windup: the integral stops at the clip
    # a new episode on lane 1 only restarts its integral
    buf.start(np.array([[0.0, 0.0], [1.0, 1.0]]), lanes=[False, True])
    np.testing.assert_allclose(buf.features()[:, -1], [clip, 0.0], rtol=1e-6)


def test_history_window_spaces_and_contents():
    env = HistoryWindow(_env(), WindowConfig(window=3, include_integral=False))
    assert env.action_space.low[0] == -1 and env.action_space.high[0] == 1
    assert env.observation_space.shape == (12,) and env.observation_space.dtype == np.float32
    obs, _ = env.reset(seed=0)
    assert obs.dtype == np.float32 and obs.shape == (12,)
    raw = env.unwrapped
    us = []
    for a in [0.05, -0.025, 0.01, 0.02]:
        obs, *_, info = env.step(np.array([a], dtype=np.float32))
        us.append(info["u"])
    np.testing.assert_allclose(us, [0.5, -0.25, 0.1, 0.2], rtol=1e-6)
    # Window of 3: u(k-3..k-1) normalised by the bound; y, r, e the last three samples.
    np.testing.assert_allclose(obs[6:9], np.array(us[-3:]) / 10.0, rtol=1e-6)
    y, r = obs[0:3], obs[3:6]
    np.testing.assert_allclose(obs[9:12], r - y, rtol=1e-5, atol=1e-6)
    assert r[-1] == pytest.approx(raw._r(raw.t)[0])
    # Actions beyond [-1, 1] are clipped to the bound; features are clipped to obs_clip.
    for _ in range(3):
        obs, *_, info = env.step(np.array([2.0], dtype=np.float32))
        assert info["u"] == 10.0
    assert np.max(np.abs(obs)) == pytest.approx(10.0)


def test_history_window_rejects_a_discrete_action_space():
    env = gym.make("CartPole-v1")
    with pytest.raises(ValueError, match="action box"):
        HistoryWindow(env)


def test_history_window_with_make_vec_and_sb3_vec_env():
    venv = gym.make_vec(
        "stcgym/ObserverCanonical-v0",
        num_envs=2,
        vectorization_mode="sync",
        wrappers=[lambda e: HistoryWindow(e, WindowConfig(window=5))],
    )
    obs, _ = venv.reset(seed=0)
    assert obs.shape == (2, 21)
    obs, rew, *_ = venv.step(np.zeros((2, 1), dtype=np.float32))
    assert obs.shape == (2, 21) and rew.shape == (2,)
    venv.close()

    from stable_baselines3.common.env_util import make_vec_env

    vec = make_vec_env(lambda: _env(), n_envs=2, seed=0, wrapper_class=HistoryWindow)
    assert vec.reset().shape == (2, 41)
    vec.close()


def test_training_reward_charges_divergence_and_squashes():
    # Full positive feedback on the unstable plant diverges quickly.
    env = TrainingReward(_env("unstable2", 200, y_bound=5.0), horizon=200, cost_squash=None)
    env.reset(seed=0)
    total, k = 0.0, 0
    while True:
        obs, rew, term, trunc, info = env.step(np.array([10.0]))
        k += 1
        if term or trunc:
            break
        total += rew
    assert term and info["diverged"] and k < 200
    raw_last = -((np.clip(info["y_clean"], -5.0, 5.0) - obs[1]) ** 2 + 0.01 * 100.0)
    assert rew == pytest.approx(raw_last * (1 + 200 - k))
    # Squash: identity for small costs, logarithmic for large ones.
    env = TrainingReward(_env(), horizon=100, cost_squash=1.0)
    env.reset(seed=0)
    obs, rew, *_, info = env.step(np.array([10.0]))
    cost = (info["y_clean"] - obs[1]) ** 2 + 0.01 * 100.0
    assert cost > 50 and rew == pytest.approx(-math.log1p(cost))
    obs, rew, *_, info = env.step(np.array([-3.5]))
    cost = (info["y_clean"] - obs[1]) ** 2 + 0.01 * 3.5**2
    assert rew == pytest.approx(-math.log1p(cost))


# ------------------------------------------------------------------------------ adapter
def test_sb3_adapter_rebuilds_the_training_features():
    """The adapter, fed raw [y, r], gives the model exactly what HistoryWindow gave it."""
    from stcgym.agents.rl.policy import SB3Policy

    cfg = WindowConfig(window=4)
    model_w, model_a = FakeModel(), FakeModel()
    env = HistoryWindow(_env(steps=30), cfg)
    obs, _ = env.reset(seed=3)
    wrapped_u = []
    for _ in range(30):
        a, _ = model_w.predict(obs)
        obs, _, term, trunc, info = env.step(a)
        wrapped_u.append(info["u"])
        if term or trunc:
            break
    policy = SB3Policy(model_a, cfg, action_bound=10.0)
    ep = run_episode(policy, EnvSpec(("stable2",), steps=30), seed=3)
    np.testing.assert_allclose(np.vstack(model_a.seen), np.vstack(model_w.seen))
    np.testing.assert_allclose(ep.u, wrapped_u)


def test_sb3_adapter_batch_lanes_are_independent():
    from stcgym.agents.rl.policy import SB3Policy

    cfg = WindowConfig(window=3)
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(5, 2, 2))
    batch = SB3Policy(FakeModel(), cfg, 10.0, num_envs=2)
    singles = [SB3Policy(FakeModel(), cfg, 10.0) for _ in range(2)]
    for k in range(5):
        ub, _ = batch.predict(obs[k], episode_start=np.array([k == 0, k in (0, 3)]))
        for i, pol in enumerate(singles):
            start = k == 0 or (i == 1 and k == 3)
            us, _ = pol.predict(obs[k, i], episode_start=start)
            assert us.shape == (1,)
            assert ub[i, 0] == pytest.approx(us[0])
    with pytest.raises(ValueError, match="finite"):
        batch.predict(np.array([np.nan, 0.0]))


def test_train_save_load_roundtrip(tmp_path):
    from stcgym.agents.rl.learning_curve import CurveOptions
    from stcgym.agents.rl.sb3 import load_agent, train_agent

    cfg = default_config("ppo")
    apply_overrides({"ppo": cfg}, ["ppo.n_steps=32", "ppo.batch_size=32", "ppo.n_envs=2"])
    spec = EnvSpec(("stable2",), steps=40)
    agent = train_agent(
        "ppo",
        cfg,
        spec,
        64,
        seed=1,
        curve=CurveOptions(points=2),
        out_dir=tmp_path,
        progress=False,
    )
    assert agent.steps == 64 and agent.curve[0][0] == 0 and agent.curve[-1][0] == 64
    assert (tmp_path / "model.zip").is_file() and (tmp_path / "agent.json").is_file()
    again = load_agent(tmp_path)
    assert again.algo == "ppo" and again.seed == 1 and again.config == agent.config
    # the action unit the config asked for was measured: LQG's inputs on 20 training episodes
    from stcgym.agents.evaluation.bounds import lqg_action_unit, lqg_inputs
    from stcgym.agents.evaluation.episodes import EpisodeSet
    from stcgym.agents.rl.configs import with_action_unit

    inputs = lqg_inputs(spec, EpisodeSet(("stable2",) * 20, tuple(range(20_000, 20_020))))
    assert agent.config == with_action_unit(cfg, lqg_action_unit(inputs))
    assert cfg.interface["action_unit"] == "lqg"  # the caller's config is left alone
    assert again.train_spec == spec and again.curve == agent.curve
    a = run_episode(agent.policy, spec, 7)
    b = run_episode(again.policy, spec, 7)
    np.testing.assert_array_equal(a.u, b.u)
    with pytest.raises(FileNotFoundError):
        load_agent(tmp_path / "nothing")


# ------------------------------------------------------------------------------ configs
def test_configs_are_valid_constructor_arguments():
    from stcgym.agents.rl.configs import algorithm_class

    env = HistoryWindow(_env())
    for algo, cfg in DEFAULT_CONFIGS.items():
        kwargs = dict(cfg.hyperparams)
        if "buffer_size" in kwargs:
            kwargs["buffer_size"] = 1000  # construction only: keep the replay buffer small
        model = algorithm_class(algo)(cfg.policy, env, device="cpu", **kwargs)
        assert model.gamma == cfg.hyperparams["gamma"]


def test_parse_and_apply_overrides():
    assert parse_override("ppo.learning_rate=3e-4") == ("ppo", ["learning_rate"], 3e-4)
    assert parse_override("sac.policy_kwargs.net_arch=[32, 32]")[2] == [32, 32]
    assert parse_override("td3.policy=MlpPolicy")[2] == "MlpPolicy"
    cfgs = {"ppo": default_config("ppo")}
    apply_overrides(
        cfgs,
        [
            "ppo.learning_rate=1e-4",
            "ppo.n_envs=2",
            "ppo.policy_kwargs.net_arch=[32]",
            "ppo.hyperparams.gamma=0.9",
            "sac.batch_size=128",
        ],
    )
    assert cfgs["ppo"].hyperparams["learning_rate"] == 1e-4 and cfgs["ppo"].n_envs == 2
    assert cfgs["ppo"].hyperparams["policy_kwargs"]["net_arch"] == [32]
    assert cfgs["ppo"].hyperparams["gamma"] == 0.9
    assert cfgs["sac"].hyperparams["batch_size"] == 128
    assert DEFAULT_CONFIGS["ppo"].hyperparams["learning_rate"] == 3e-4  # defaults untouched
    for bad in ("ppo.no_such_arg=1", "dqn.learning_rate=1", "ppo=1", "learning_rate=1"):
        with pytest.raises(ValueError):
            apply_overrides({}, [bad])
    with pytest.raises(ValueError, match=r"ppo\.n_envs is not a dict"):
        apply_overrides({}, ["ppo.n_envs.x=1"])
    with pytest.raises(ValueError, match="'seed' is not a hyperparameter"):
        apply_overrides({}, ["ppo.hyperparams.seed=1"])
    with pytest.raises(ValueError, match="'seed' is not a hyperparameter"):
        apply_overrides({}, ["ppo.seed=1"])


# ------------------------------------------------------------------------------ evaluation
def _same(m1: dict, m2: dict) -> bool:
    """Equal metrics, wall time aside (nan == nan)."""
    return all(
        m1[k] == m2[k] or (math.isnan(m1[k]) and math.isnan(m2[k])) for k in m1 if k != "step_us"
    )


def test_evaluate_is_reproducible_and_seed_dependent():
    spec = EnvSpec(("stable2",), steps=300)
    a = evaluate(lambda plant, seed: LinearFeedback(), spec, [1, 2, 1])
    b = evaluate(LinearFeedback(), spec, [1, 2, 1])
    assert all(_same(m1, m2) for m1, m2 in zip(a.metrics, b.metrics, strict=True))
    assert _same(a.metrics[0], a.metrics[2])
    np.testing.assert_array_equal(a.episodes[0].cost, a.episodes[2].cost)
    assert not np.array_equal(a.episodes[0].y, a.episodes[1].y)  # different noise


def test_every_controller_meets_the_same_episode():
    spec = EnvSpec(("stable2",), steps=200, noise_std=0.1)
    p1, p2 = LinearFeedback(0.1), LinearFeedback(0.2)
    e1, e2 = run_episode(p1, spec, 5), run_episode(p2, spec, 5)
    np.testing.assert_array_equal(e1.r, e2.r)
    np.testing.assert_array_equal(p1.seen[0], p2.seen[0])  # same first noisy measurement
    assert p1.seen[0][0] != 0.0


def test_self_tuning_controller_and_oracle_through_the_harness():
    from stcgym.adaptive.control.controller import SelfTuningController
    from stcgym.adaptive.control.oracles import KnownModelController

    spec = EnvSpec(("stable2",), steps=400)
    stc = evaluate(lambda p, s: SelfTuningController(p.n, action_bound=10.0), spec, [0, 0])
    oracle = evaluate(lambda p, s: KnownModelController(p.a, p.b, action_bound=10.0), spec, [0])
    assert stc.metrics[0]["cost"] == stc.metrics[1]["cost"]
    assert all(m["bounded"] for m in stc.metrics + oracle.metrics)
    assert oracle.metrics[0]["cost_steady"] < 0.5


def test_diverged_run_is_charged_until_the_end():
    spec = EnvSpec(("unstable2",), steps=300, y_bound=20.0)
    ep = run_episode(LinearFeedback(kp=-5.0, kff=0.0), spec, 0)
    assert ep.diverged and ep.steps_run < 300
    assert np.all(ep.cost[ep.steps_run - 1 :] == ep.cost[ep.steps_run - 1])
    m = evaluate(LinearFeedback(kp=-5.0, kff=0.0), spec, [0]).metrics[0]
    assert m["bounded"] == 0 and math.isfinite(m["cost"]) and m["cost"] > 1.0


def test_jump_scenario_windows_and_theta_record():
    w = default_windows(2000, 1000)
    assert (w.start, w.steady, w.post_jump) == ((0, 200), (500, 1000), (1300, 1600))
    assert default_windows(2000).steady == (1000, 2000)
    theta = (-1.2, 0.52, 0.9, 0.3)
    spec = EnvSpec(("stable2",), steps=400, jump_step=200, jump_to=theta)
    res = evaluate(LinearFeedback(), spec, [0], record_theta=True)
    m, ep = res.metrics[0], res.episodes[0]
    assert math.isfinite(m["cost_post_jump"])
    # the true parameters in force: stable2 before the jump, theta from step J + 1 on
    np.testing.assert_allclose(ep.theta[0], ep.theta[150])
    assert not np.allclose(ep.theta[0], theta)
    np.testing.assert_allclose(ep.theta[-1], theta)
    assert np.all(np.isnan(ep.theta_hat))  # LinearFeedback estimates nothing
    assert EnvSpec.from_dict(spec.to_dict()) == spec
    with pytest.raises(ValueError):
        EnvSpec(("stable2",), steps=100, jump_step=200, jump_to=theta)
    with pytest.raises(ValueError):
        EnvSpec(("nope",))


def test_summarize():
    s = summarize([1.0, 2.0, 3.0, 4.0, 100.0], [False] * 4 + [True])
    assert s["median"] == 3.0 and s["iqr"] == 2.0 and s["cvar25"] == pytest.approx(52.0)
    assert s["failure_rate"] == pytest.approx(0.2)
    s = summarize([1.0, math.inf, 2.0, math.nan])
    assert s["n"] == 3 and s["median"] == 2.0 and math.isinf(s["cvar25"])
    assert math.isnan(summarize([math.nan])["median"])


def test_history_buffer_start_mask():
    config = WindowConfig(window=2, include_error=False, include_integral=False)
    buf = HistoryBuffer(config, 10.0, batch=2)
    buf.start(np.array([[1.0, 2.0], [3.0, 4.0]]))
    buf.push_action([5.0, 10.0])
    buf.push_obs(np.array([[6.0, 7.0], [8.0, 9.0]]))
    buf.start(np.array([[0.5, 0.5], [0.5, 0.5]]), lanes=[False, True])
    f = buf.features()
    np.testing.assert_allclose(f[0], [1, 6, 2, 7, 0, 0.5])
    np.testing.assert_allclose(f[1], [0, 0.5, 0, 0.5, 0, 0])


# ------------------------------------------------------------------------------ hyperparameters
@pytest.mark.parametrize(
    "override, message",
    [
        ("sac.batch_size=0", "batch_size must be an integer >= 1"),
        ("ppo.learning_rate=abc", "learning_rate must be a positive number"),
        ("ppo.learning_rate=-1", "learning_rate must be a positive number"),
        ("ppo.gamma=1.5", "gamma must be a number in (0, 1]"),
        ("td3.train_freq=[1, 'hour']", "train_freq"),
        ("ppo.batch_size=1", "batch_size must be > 1"),
        ("ppo.n_envs=0", "n_envs must be an integer >= 1"),
        ("ppo.n_steps=1", None),  # 1 x 4 envs > 1: allowed by SB3
        ("rppo.policy=MlpPolicy", "MlpLstmPolicy"),
        ("ppo.tensorboard_log=tb", "--tensorboard-log"),
        ("sac.seed=3", "--train-seeds"),
        ("ppo.ent_coef=auto", "ent_coef"),
        ("sac.ent_coef=auto_0.1", None),
        ("ppo.window={'width': 3}", "window"),
        ("ppo.use_sde=1", "True or False"),
    ],
)
def test_hyperparameter_values_are_checked(override, message):
    if message is None:
        apply_overrides({}, [override])
        return
    with pytest.raises(ValueError, match=re.escape(message)):
        apply_overrides({}, [override])


def test_sb3_rejects_what_the_rules_cannot_see():
    from stcgym.agents.rl.sb3 import check_trainable

    cfg = default_config("ppo")
    apply_overrides({"ppo": cfg}, ["ppo.policy_kwargs.no_such_kwarg=1"])
    with pytest.raises(ValueError, match="SB3 rejects"):
        check_trainable("ppo", cfg, EnvSpec(("stable2",), steps=40))
    check_trainable("sac", default_config("sac"), EnvSpec(("stable2",), steps=40))


def test_recurrent_agent_carries_its_state_and_reloads(tmp_path):
    from stcgym.agents.rl.learning_curve import CurveOptions
    from stcgym.agents.rl.sb3 import load_agent, train_agent

    cfg = default_config("rppo")
    apply_overrides({"rppo": cfg}, ["rppo.n_steps=16", "rppo.batch_size=32", "rppo.n_envs=2"])
    spec = EnvSpec(("stable2", "unstable2"), steps=40)
    agent = train_agent(
        "rppo",
        cfg,
        spec,
        32,
        seed=0,
        curve=CurveOptions(points=1),
        out_dir=tmp_path,
        progress=False,
    )
    assert agent.policy.recurrent
    a = run_episode(agent.policy, spec, 3)
    assert agent.policy._lstm is not None  # the LSTM state was carried along
    b = run_episode(load_agent(tmp_path).policy, spec, 3)
    np.testing.assert_array_equal(a.u, b.u)
    # The memory matters: the same last observation window after different histories can
    # give different actions, which a window policy could not do.
    assert a.u.std() > 0
