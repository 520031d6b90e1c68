"""The benchmark's protocol piece by piece: paired statistics, rows scored against the yardstick,
the action bound, batched episodes, the RL agents' vector window and reward, the figure style."""

from __future__ import annotations

import math
from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest

import stcgym.envs  # noqa: F401  (registers the ids)
from stcgym.agents.benchmark.headline import headline, scenario_tables
from stcgym.agents.benchmark.rows import Yardstick, episode_rows, rl_steps_to_target
from stcgym.agents.evaluation.bounds import round_up
from stcgym.agents.evaluation.env_spec import EnvSpec
from stcgym.agents.evaluation.episodes import EpisodeSet, run_episodes
from stcgym.agents.evaluation.statistics import (
    _bootstrap_mean,
    _counts,
    paired_comparison,
    rate_estimate,
)

FAMILY_TEST = dict(family="siso2-v1", split="test", jump_probability=0.0, steps=150)


# ------------------------------------------------------------------------------ statistics
def test_paired_comparison_by_hand():
    # X: 2 runs, Y: 1 run, on 2 plants x 2 episodes
    x = np.array([[[1.0, 3.0], [2.0, 2.0]], [[4.0, 1.0], [1.0, 8.0]]])
    y = np.array([[[2.0, 2.0], [2.0, 4.0]]])
    c = paired_comparison(x, y, reps=300)
    wins = [1, 0, 0.5, 1, 0, 1, 1, 0]  # every (run, plant, episode) pair, ties one half
    assert c.probability.value == pytest.approx(np.mean(wins))
    logs = np.log(np.array([1, 3, 2, 2, 4, 1, 1, 8]) / np.array([2, 2, 2, 4] * 2))
    assert c.ratio.value == pytest.approx(math.exp(np.mean(logs)))
    assert c.probability.low <= c.probability.value <= c.probability.high
    # a controller against itself: a tie everywhere, a ratio of 1 exactly
    same = paired_comparison(y, y, reps=100)
    assert (same.probability.low, same.probability.high) == (0.5, 0.5)
    assert same.ratio.value == pytest.approx(1.0) and same.ratio.high == pytest.approx(1.0)
    with pytest.raises(ValueError, match="same"):
        paired_comparison(x, y[:, :1])
    with pytest.raises(ValueError, match="finite"):
        paired_comparison(x * np.inf, y)


def test_bootstrap_counts_equal_an_explicit_resample():
    # the weighted mean with multinomial counts is the mean over the resampled indices
    rng = np.random.default_rng(3)
    table = rng.random((3, 2, 5))
    draws = np.random.default_rng(7)
    wx, wy, wp = _counts(draws, 1, 3)[0], _counts(draws, 1, 2)[0], _counts(draws, 1, 5)[0]
    ix, iy, ip = (np.repeat(np.arange(len(w)), w.astype(int)) for w in (wx, wy, wp))
    explicit = table[np.ix_(ix, iy, ip)].mean()
    weighted = np.einsum("i,j,p,ijp->", wx, wy, wp, table) / (3 * 2 * 5)
    assert weighted == pytest.approx(explicit)
    assert _counts(draws, 4, 1).tolist() == [[1.0]] * 4  # one item: always drawn once


def test_paired_intervals_cover_the_true_ratio():
    # X costs exp(0.2 + noise) times Y's on each plant; the paired ratio's interval should
    # cover exp(0.2) in most of 40 independent experiments (nominal 95 %)
    rng = np.random.default_rng(11)
    covered = 0
    for k in range(40):
        y = rng.lognormal(0.0, 1.0, (1, 30, 2))
        x = y * np.exp(0.2 + rng.normal(0.0, 0.3, (4, 30, 2)))
        c = paired_comparison(x, y, reps=400, seed=k)
        covered += c.ratio.low <= math.exp(0.2) <= c.ratio.high
    assert covered >= 33


def test_rate_estimate():
    flags = np.zeros((2, 10, 1))
    flags[0, :3] = 1
    est = rate_estimate(flags, reps=300)
    assert est.value == pytest.approx(3 / 20)
    assert 0.0 <= est.low < est.value < est.high <= 1.0
    assert rate_estimate(np.zeros((3, 4)), reps=50).high == 0.0
    t = np.arange(24.0).reshape(2, 3, 4)
    assert _bootstrap_mean(t, 50, 0.95, 0)[0] == pytest.approx(t.mean())


# ------------------------------------------------------------------------------ rows
class _Scenario:
    name, kind = "family:test", "jump"

    class env:
        span = 2

    class episodes:
        plants = ("p0", "p1")
        seeds = (5, 6)


def test_rows_are_scored_against_the_yardstick_on_the_same_episode():
    T = 8
    lqg = np.ones((2, T))
    yard = Yardstick(lqg, np.array([-1, 4]), np.array([5.0, 0.5]), np.array([True, True]))
    cost = np.vstack([np.full(T, 2.0), np.r_[np.ones(4), np.full(4, 3.0)]])
    resp = {"steps_run": np.array([8.0, 8.0]), "bounded": np.array([1.0, 1.0])}
    rows = episode_rows(_Scenario, "stc", "adaptive", 0, cost, resp, yard, online=True)
    a, b = rows
    assert (a["plant"], a["seed"], b["seed"]) == ("p0", 5, 6)
    assert a["cost_ratio"] == pytest.approx(2.0) and b["cost_ratio"] == pytest.approx(2.0)
    # (C_zero - C) / (C_zero - C_LQG) = (5 - 2) / (5 - 1); undefined where zero input costs
    # less than LQG (episode b)
    assert a["score"] == pytest.approx(0.75) and math.isnan(b["score"])
    assert a["jump_step"] == "" and b["jump_step"] == 4
    # episode b: steady = [J/2, J) = [2, 4), post-jump = [4, 8): ratios 1 and 3
    assert b["steady_ratio"] == pytest.approx(1.0) and b["post_jump_ratio"] == pytest.approx(3.0)
    assert math.isnan(a["post_jump_ratio"]) and math.isnan(a["reconverge_steps"])
    assert b["reconverge_steps"] == math.inf  # 3x LQG to the end: never back within 1.2x
    assert a["steps_to_target"] == math.inf and b["steps_to_target"] == 0.0
    assert a["data_steps"] == 8


def test_rl_steps_to_target_never_claims_what_the_test_episodes_deny():
    # the learning curve (validation) reaches 1.2x of LQG at 20 500 steps, but on the test
    # episodes of the scenario the agent runs at 50x: it did not get there
    curve = [(0, 80.0), (5000, 3.0), (20_500, 1.15), (30_000, 1.1)]
    assert rl_steps_to_target(curve, np.full(10, 50.0), True) == math.inf
    assert rl_steps_to_target(curve, np.full(10, 1.05), True) == 20_500
    # held-out distributions: the validation curve does not speak for them
    assert math.isnan(rl_steps_to_target(curve, np.full(10, 1.05), False))
    assert rl_steps_to_target([(0, 9.0), (10, 2.0)], np.full(3, 1.0), True) == math.inf


def test_headline_arranges_runs_plants_and_episodes():
    rows = []
    rng = np.random.default_rng(0)
    ratios = rng.lognormal(0.0, 0.3, (3, 4, 2))
    for run in range(3):
        for p in range(4):
            for e in range(2):
                r = float(ratios[run, p, e])
                rows.append(
                    dict(
                        scenario="s",
                        controller="x",
                        family="adaptive",
                        run=run,
                        plant=f"p{p}",
                        seed=10 * p + e,
                        cost=r,
                        cost_ratio=r,
                        steady_ratio=r,
                        score=1.0,
                        post_jump_ratio="",
                        steps_to_target=5.0,
                        reconverge_steps="",
                        bounded=1,
                    )  # fmt: skip
                )
    tables = scenario_tables(rows, "s", (4, 2))
    np.testing.assert_allclose(tables["x"]["cost_ratio"], ratios)
    from rliable import metrics

    hl = headline(tables, reps=100)["x"]
    assert hl["ratio"].value == pytest.approx(metrics.aggregate_iqm(ratios.mean(axis=2)))
    assert hl["runs"] == 3 and hl["episodes"] == 8 and hl["diverged"].value == 0.0
    assert hl["to_target"] == {"median": 5.0, "reached": 24, "n": 24}
    # a run with a missing episode (an interrupted run) is left out
    assert scenario_tables(rows[:-1], "s", (4, 2))["x"]["runs"] == 2


# ------------------------------------------------------------------------------ bound
def test_round_up():
    assert [round_up(x) for x in (3.4501, 3.4, 0.0123, 120.0, 99.1)] == [
        3.5,
        3.4,
        0.013,
        120.0,
        100.0,
    ]
    with pytest.raises(ValueError):
        round_up(0.0)


# ------------------------------------------------------------------------------ episodes
@pytest.mark.equality
def test_a_batch_of_episodes_equals_its_episodes_one_by_one():
    from stcgym.adaptive import SelfTuningController
    from stcgym.agents.evaluation.evaluate import run_episode

    spec = EnvSpec(action_bound=10.0, **FAMILY_TEST)
    eps = EpisodeSet.of(spec, per_plant=2, first_seed=40, max_plants=3)

    def lanes(plants, seeds):
        return SelfTuningController(2, num_envs=len(plants), seed=seeds, action_bound=10.0)

    batch = run_episodes(lanes, spec, eps, max_lanes=4)  # two blocks of lanes
    assert batch.cost.shape == (6, 150) and batch.plants == list(eps.plants)
    for i, (plant, seed) in enumerate(zip(eps.plants, eps.seeds, strict=True)):
        single = SelfTuningController(2, seed=seed, action_bound=10.0)
        ep = run_episode(single, spec, seed, plant=plant)
        np.testing.assert_array_equal(batch.cost[i], ep.cost)
        np.testing.assert_array_equal(batch.y[i], ep.y)


def test_informed_controllers_are_told_the_jump_when_it_happens():
    from stcgym.adaptive import LQGController
    from stcgym.agents.controllers import CONTROLLERS

    spec = EnvSpec(action_bound=10.0, **{**FAMILY_TEST, "jump_probability": 1.0})
    eps = EpisodeSet.of(spec, per_plant=1, first_seed=7, max_plants=3)
    sc = type("S", (), {"env": spec, "controller_order": 2})
    batch = run_episodes(CONTROLLERS["lqg"].build(None, sc), spec, eps, informed=True)
    assert np.all((batch.jump_step > 0) & (batch.jump_step < 150))
    # the same LQG on one episode, told the new parameters by hand at the env's jump
    law = CONTROLLERS["lqg"].build(None, sc)
    env = spec.make()
    obs, info = env.reset(seed=eps.seeds[1], options={"plant": eps.plants[1]})
    ctl = law([env.unwrapped.plant], [0])
    assert isinstance(ctl, LQGController)
    ctl.reset()
    cost, theta = [], info["theta"]
    for k in range(150):
        if k == batch.jump_step[1]:
            ctl.set_model(env.unwrapped.a[None], env.unwrapped.b[None])
        assert np.array_equal(env.unwrapped.theta, theta) == (k < batch.jump_step[1])
        u, _ = ctl.predict(obs[None])
        obs, reward, *_ = env.step(u[0])
        cost.append(-reward)
    np.testing.assert_allclose(batch.cost[1], cost, rtol=1e-9, atol=1e-12)


# ------------------------------------------------------------------------------ RL side
def test_vec_window_equals_the_single_env_wrappers_through_ends_and_divergence():
    from stable_baselines3.common.vec_env import VecMonitor

    from stcgym.agents import HistoryWindow, TrainingReward, WindowConfig
    from stcgym.agents.rl.vec_env import SB3VecEnv, VecHistoryWindow

    config = WindowConfig(window=3)
    kw = dict(plant="unstable2", noise_std=0.1, y_bound=4.0)
    lanes = gym.make_vec("stcgym/ObserverCanonical-v0", num_envs=3, max_episode_steps=12, **kw)
    venv = VecHistoryWindow(VecMonitor(SB3VecEnv(lanes)), config, horizon=12)
    venv.seed(5)
    obs = venv.reset()
    singles = []
    for i in range(3):
        env = HistoryWindow(gym.make("stcgym/ObserverCanonical-v0", max_episode_steps=12, **kw),
                            config)  # fmt: skip
        env = TrainingReward(env, horizon=12)
        o, _ = env.reset(seed=5 + i)
        np.testing.assert_array_equal(obs[i], o)
        singles.append(env)
    rng = np.random.default_rng(0)
    ended = np.zeros(3, dtype=int)
    for _ in range(40):
        a = rng.uniform(-1, 1, (3, 1)).astype(np.float32)
        a[0] = 1.0  # lane 0 drives the unstable plant out of its bound: divergence
        venv.step_async(a)
        obs, rewards, dones, infos = venv.step_wait()
        for i, env in enumerate(singles):
            o, r, term, trunc, _ = env.step(a[i])
            assert rewards[i] == pytest.approx(r, rel=1e-6)
            assert dones[i] == (term or trunc)
            if term or trunc:
                ended[i] += 1
                np.testing.assert_array_equal(infos[i]["terminal_observation"], o)
                o, _ = env.reset()  # the lane's next episode, from its own generator
            np.testing.assert_array_equal(obs[i], o)
    assert ended[0] >= 2 and ended[1:].min() >= 2  # divergences and time limits both met


def test_obs_norm_is_vec_normalize():
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from stcgym.agents import HistoryWindow
    from stcgym.agents.rl.policy import ObsNorm

    def make():
        return HistoryWindow(gym.make("stcgym/ObserverCanonical-v0", noise_std=0.1))

    vec = VecNormalize(DummyVecEnv([make, make]), norm_reward=False)
    vec.reset()
    for _ in range(50):
        vec.step(np.random.default_rng(1).uniform(-1, 1, (2, 1)))
    raw = vec.get_original_obs()
    norm = ObsNorm.of(vec)
    np.testing.assert_allclose(norm.apply(raw), vec.normalize_obs(raw), rtol=1e-6)
    assert ObsNorm.from_dict(norm.to_dict()) == norm


def test_rl_trains_on_the_scored_cost_by_default():
    from stcgym.agents import TrainingReward, default_config
    from stcgym.agents.rl.configs import ABLATIONS, DEFAULT_CONFIGS
    from stcgym.agents.rl.zoo_departures import ZOO_DEPARTURES

    env = TrainingReward(gym.make("stcgym/ObserverCanonical-v0", plant="stable2"), horizon=50)
    raw = gym.make("stcgym/ObserverCanonical-v0", plant="stable2")
    env.reset(seed=3)
    raw.reset(seed=3)
    for u in (0.3, -0.2, 1.0):
        assert env.step(np.array([u]))[1] == raw.step(np.array([u]))[1]
    for algo in DEFAULT_CONFIGS:
        cfg = default_config(algo)
        assert cfg.cost_squash is None and cfg.normalize_obs
        # the PPO-family update's discount was chosen by the ablation of the RL-baselines page
        ppo_family = cfg.hyperparams.get("target_kl") is not None
        assert cfg.hyperparams["gamma"] == (0.9 if ppo_family else 0.99)
        assert cfg.reward == "lqg_ratio"
        # the integral of the tracking error is an input, but in its ablation
        assert cfg.window.get("include_integral", True) == (algo not in ABLATIONS)
        if algo in ABLATIONS:  # an ablation is its agent with one thing changed
            base = default_config(ABLATIONS[algo][0])
            assert cfg.hyperparams == base.hyperparams and cfg.algo == algo
            assert {**cfg.window, "include_integral": True} == {
                **base.window,
                "include_integral": True,
            }
        # every departure from the Zoo is listed with a reason
        for _setting, zoo, ours, why in ZOO_DEPARTURES.get(algo, []):
            assert why and zoo != ours
    assert default_config("rppo").hyperparams["policy_kwargs"]["lstm_hidden_size"] == 128


# ------------------------------------------------------------------------------ figures
def test_figures_are_readable_at_page_width_with_one_colour_per_controller():
    from stcgym.agents.benchmark.style import COLORS, DPI, MIN_FONT, RC, WIDTH, color

    assert WIDTH * DPI == 800
    sizes = [v for k, v in RC.items() if k.endswith("size")]
    assert min(sizes) >= MIN_FONT >= 9
    names = ["stc", "stc_lq", "stc_kfmils", "lqg", "oracle", "zero", "ppo", "sac", "td3",
             "a2c", "rppo"]  # fmt: skip
    assert len({color(n) for n in names}) == len(names)
    assert all(color(n) == COLORS[n] for n in names) and color("new_agent") == color("new_agent")


def test_the_training_table_gives_each_run_its_wall_time_and_update_statistics():
    from stcgym.agents.benchmark.render import RunData
    from stcgym.agents.benchmark.report import _training_table

    def stop(wall):
        return {
            "status": "cap",
            "steps": 1000,
            "cap": 1000,
            "last_improvement_step": 500,
            "kept_step": 500,
            "wall_s": wall,
        }

    data = RunData(
        stops={("family", "ppo", 0): stop(222.0), ("nominal:stable2", "ppo", 0): stop(11.0)},
        diagnostics={
            ("family", "ppo", 0): [
                {"approx_kl": 0.01, "clip_fraction": 0.1, "explained_variance": 0.5},
                {"approx_kl": 0.03, "clip_fraction": 0.2, "explained_variance": 0.7},
                {"approx_kl": 0.02, "clip_fraction": 0.3, "explained_variance": float("nan")},
                {"entropy_loss": 1.5},  # the entropy of a narrow Gaussian is negative
            ]
        },
    )
    cfg = SimpleNamespace(rl_agents=[])
    table = _training_table(cfg, data)
    assert "| family | ppo | 0 | cap |" in table[2]
    assert table[2].endswith("| 0.02, 0.2, 0.6, -1.5 | 222 |")  # medians; nan is not counted
    assert "| nominal:stable2 | ppo | 0 |" in table[3] and table[3].endswith("| -, -, -, - | 11 |")


def test_table_cells_write_numbers_and_step_counts():
    from stcgym.agents.benchmark.cells import number, percent, thousands
    from stcgym.agents.evaluation.statistics import Estimate

    assert [thousands(x) for x in (999, 1000, 2345, 999_499, 999_500, 1_003_520)] == [
        "999", "1k", "2.35k", "999k", "1M", "1M",
    ]  # fmt: skip
    assert [number(x) for x in (None, math.nan, math.inf, -math.inf, 1.23456)] == [
        "-", "-", "inf", "-inf", "1.23",
    ]  # fmt: skip
    assert number(123456.0) == "1.23e+05"  # a diverged cost: the exponent form
    assert percent(Estimate(0.032, 0.012, 0.057)) == "3.2 % [1.2, 5.7]"
    # an estimate reads back from statistics.json and writes as the report wrote it
    est = Estimate(2.5, 2.25, -math.inf)
    from stcgym.agents.benchmark.report import _jsonable

    again = Estimate.from_dict(_jsonable(est))
    assert again == est and again.format() == "2.5 [2.25, -inf]"
    assert Estimate.from_dict({"value": 1.0, "low": None, "high": None}).format() == "1 [-, -]"
    assert Estimate(1.0, 1.0, 1.0).format() == "1"  # nothing resampled: the value alone
