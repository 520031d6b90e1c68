"""The ``mimo`` scenario of ``stcgym bench``: MIMO plants, ``stc_mimo`` against the LQR yardstick
and the window RL agents, the SISO-only controllers left out."""

from __future__ import annotations

import contextlib
import csv
import io
from dataclasses import replace

import gymnasium as gym
import numpy as np
import pytest

import stcgym.envs  # noqa: F401  (registers the envs)
from stcgym.adaptive import LQRController, MultivariableSelfTuningController
from stcgym.agents.benchmark import build_config, make_scenarios
from stcgym.agents.benchmark.plan import rl_tasks
from stcgym.agents.benchmark.tiers import FULL, QUICK
from stcgym.agents.cli import main
from stcgym.agents.controllers import controllers_for
from stcgym.agents.evaluation.env_spec import EnvSpec
from stcgym.agents.evaluation.episodes import EpisodeSet
from stcgym.agents.evaluation.evaluate import run_episode
from stcgym.agents.evaluation.mimo import TANK_REFERENCE, MimoEnvSpec
from stcgym.agents.rl.wrappers import HistoryBuffer, HistoryWindow, WindowConfig
from stcgym.envs import get_mimo_plant, mimo_plant_names

# RL in seconds: a couple of PPO rollouts of 64 steps on 2 envs
TINY = (
    "--train-steps 200 --eval-interval 100 --train-seeds 1 --nominal-episodes 2 "
    "--curve-episodes 2 --bound-plants 3 --episode-steps 120 --curve-points 2 "
    "--hp ppo.n_steps=64 --hp ppo.n_envs=2 --hp ppo.n_epochs=2 --bootstrap-reps 100 --jobs 1 "
    "--no-progress"
).split()


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _bench(out, *args):
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = main(["bench", *args, "--out", str(out)])
    assert rc == 0, err.getvalue()


@pytest.fixture(scope="module")
def mimo_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    _bench(
        out,
        *TINY,
        "--scenarios",
        "nominal,mimo",
        "--agents",
        "ppo,stc,stc_mimo,lqg",
        "--run",
        "mimo",
    )
    return out / "mimo"


def test_mimo_rows_and_report_next_to_the_siso_scenario(mimo_run):
    rows = _rows(mimo_run / "metrics.csv")
    by = {}
    for r in rows:
        by.setdefault(r["scenario"], set()).add(r["controller"])
    # the SISO-only controllers are left out of the MIMO scenario, stc_mimo out of the SISO one
    assert by == {
        "nominal:stable2": {"ppo", "stc", "lqg", "zero"},
        "mimo:quadruple_tank": {"ppo", "stc_mimo", "lqg", "zero"},
    }
    mimo = [r for r in rows if r["scenario"] == "mimo:quadruple_tank"]
    assert {r["kind"] for r in mimo} == {"mimo"} and len(mimo) == 4 * 2
    lqr = {r["seed"]: float(r["cost"]) for r in mimo if r["controller"] == "lqg"}
    for r in mimo:
        assert float(r["cost_ratio"]) == pytest.approx(float(r["cost"]) / lqr[r["seed"]], 1e-5)
        assert r["overshoot_pct"] == ""  # no step-response figures for several outputs
        assert float(r["track_rms_1"]) >= 0 and float(r["track_rms_2"]) >= 0  # per channel
    report = (mimo_run / "report.md").read_text()
    assert "### `mimo:quadruple_tank`" in report
    section = report.split("### `mimo:quadruple_tank`")[1].split("###")[0]
    assert "| stc_mimo | ppo |" in section and "| stc | ppo |" not in section
    assert "| controller | RMS error z1 | RMS error z2 | cross-channel peak |" in section
    names = {p.name for p in mimo_run.iterdir()}
    assert "traces_mimo_quadruple_tank.png" in names
    assert (mimo_run / "models" / "mimo-quadruple_tank_ppo_s0" / "agent.json").is_file()


def test_saved_mimo_agent_reproduces_its_bench_numbers(mimo_run, capsys):
    rows = _rows(mimo_run / "metrics.csv")
    bench = {
        r["seed"]: float(r["cost"])
        for r in rows
        if (r["scenario"], r["controller"]) == ("mimo:quadruple_tank", "ppo")
    }
    model = mimo_run / "models" / "mimo-quadruple_tank_ppo_s0"
    assert main(["eval", str(model), "--seeds", "2", "--episode-steps", "120"]) == 0
    out = capsys.readouterr().out
    for seed, cost in bench.items():
        assert f"seed {seed}: cost {cost:.4g}" in out
    assert main(["eval", str(model), "--plant", "he1"]) == 2
    assert "MIMO plant quadruple_tank" in capsys.readouterr().err


def _direct_costs(policy, seed, steps, bound):
    """Per-step env costs of ``policy`` on the bench's quadruple-tank episode, by a plain loop."""
    env = gym.make(
        "stcgym/StateSpace-v0",
        plant="quadruple_tank",
        cost="performance",
        reference_in="state",
        noise_std=0.05,
        control_cost=0.01,
        action_bound=bound,
        y_bound=100.0,
        reference=TANK_REFERENCE,
        max_episode_steps=steps,
    )
    obs, _ = env.reset(seed=seed)
    policy.reset()  # a new episode, as the bench starts every episode (the probe's counter)
    costs = []
    for _ in range(steps):
        action, _ = policy.predict(obs)
        obs, reward, terminated, truncated, _ = env.step(action)
        costs.append(-reward)
        assert not terminated
    return np.array(costs)


def test_stc_mimo_is_within_a_ratio_of_the_lqr_yardstick_on_the_quadruple_tank(tmp_path):
    import json

    from stcgym.agents.benchmark.runner import _lane_seeds

    _bench(
        tmp_path,
        "--scenarios",
        "mimo",
        "--agents",
        "stc_mimo,lqg",
        "--nominal-episodes",
        "3",
        "--bound-plants",
        "3",
        "--train-seeds",
        "1",
        "--episode-steps",
        "600",
        "--bootstrap-reps",
        "100",
        "--no-plots",
        "--run",
        "r",
    )
    rows = _rows(tmp_path / "r" / "metrics.csv")
    bound = json.loads((tmp_path / "r" / "config.json").read_text())["bench"]["action_bounds"]
    bound = bound["mimo:quadruple_tank"]
    cost = {(r["controller"], int(r["seed"])): float(r["cost"]) for r in rows}
    plant = get_mimo_plant("quadruple_tank")
    A, B = plant.discrete()
    Q, R, _ = plant.lq_weights(0.01)  # the cost of the two lower levels
    seeds = (1000, 1001, 1002)
    for seed, controller_seed in zip(seeds, _lane_seeds(seeds, 0), strict=True):
        stc = MultivariableSelfTuningController(4, 2, Q=Q, R=R, seed=controller_seed,
                                                action_bound=bound,
                                                input_range=plant.input_range)  # fmt: skip
        lqr = LQRController(A, B, Q=Q, R=R, action_bound=bound)
        direct_stc = _direct_costs(stc, seed, 600, bound)
        direct_lqr = _direct_costs(lqr, seed, 600, bound)
        assert cost[("stc_mimo", seed)] == pytest.approx(direct_stc.mean(), rel=1e-5)
        assert cost[("lqg", seed)] == pytest.approx(direct_lqr.mean(), rel=1e-5)
        # the self-tuning controller pays for its start-up: after it, within 15 % of LQR
        assert direct_stc.mean() >= direct_lqr.mean()
        assert direct_stc[300:].mean() <= 1.15 * direct_lqr[300:].mean()


def test_mimo_switch_tells_the_yardstick_the_new_valve_setting():
    from stcgym.agents.controllers import CONTROLLERS
    from stcgym.agents.evaluation.episodes import run_episodes

    cfg = build_config(run="s", mode="standard", scenarios="mimo_switch", agents="lqg")
    (sc,) = make_scenarios(cfg)
    assert sc.name == "mimo_switch" and sc.kind == "mimo_switch" and sc.adaptation
    assert sc.env.switch_to == "quadruple_tank_nmp" and sc.env.jump_step == sc.env.steps // 2
    assert EnvSpec.from_dict(sc.env.to_dict()) == sc.env
    short = replace(sc.env, steps=200, jump_step=100)
    eps = EpisodeSet(("quadruple_tank",) * 2, (1, 2))
    batch = run_episodes(CONTROLLERS["lqg"].build(cfg, replace(sc, env=short)), short, eps,
                         informed=True)  # fmt: skip
    assert batch.jump_step.tolist() == [100, 100]
    # after the switch the yardstick is P+'s LQR: the same inputs by a plain loop
    plant = get_mimo_plant("quadruple_tank")
    Q, R, _ = plant.lq_weights(short.control_cost)
    env = short.make()
    obs, _ = env.reset(seed=1)
    before = LQRController(*plant.discrete(), Q=Q, R=R, action_bound=short.action_bound)
    after = LQRController(*get_mimo_plant("quadruple_tank_nmp").discrete(), Q=Q, R=R,
                          action_bound=short.action_bound)  # fmt: skip
    for k in range(200):
        u, _ = (before if k < 100 else after).predict(obs)
        np.testing.assert_allclose(batch.u[0, k], np.clip(u, env.action_space.low,
                                   env.action_space.high), rtol=1e-9, atol=1e-12)  # fmt: skip
        obs, *_ = env.step(u)


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--scenarios", "mimo", "--mimo-plants", "nosuch"], "unknown MIMO plant(s) ['nosuch']"),
        (["--scenarios", "mimo", "--mimo-plants", "stable2"], "catalogue: ['quadruple_tank'"),
        (["--scenarios", "mimo", "--mimo-plants", "he1,he1"], "twice"),
        (["--scenarios", "mimo", "--mimo-plants", ","], "needs at least one plant"),
    ],
)
def test_bad_mimo_input_is_one_line_before_any_work(tmp_path, capsys, extra, message):
    rc = main(["bench", "--agents", "stc_mimo,lqg", "--out", str(tmp_path), *extra])
    assert rc == 2
    err = capsys.readouterr().err
    assert err.startswith("stcgym bench: error:") and err.count("\n") == 1 and message in err
    assert "--mimo-plants" in err
    assert not any(tmp_path.iterdir())


def test_controllers_run_only_on_the_plants_they_declare():
    names = ["stc", "stc_lq", "stc_kfmils", "oracle", "lqg", "zero", "stc_mimo"]
    assert controllers_for(names, MimoEnvSpec("he1")) == ["lqg", "zero", "stc_mimo"]
    assert controllers_for(names, EnvSpec("stable2")) == names[:6]


def test_every_tier_runs_mimo():
    from stcgym.agents.benchmark.scenarios import training_envs

    quick = build_config(run="q")
    assert "mimo" in quick.scenarios == QUICK["scenarios"]
    assert quick.mimo_plants == ["quadruple_tank"]
    # RL on a MIMO plant at the quick tier: PPO two evaluation intervals, SAC one
    assert quick.mimo_train_steps == {"ppo": 2 * 20_480, "sac": 2000}
    # the RL agents meet the episodes of the classical controllers: same env and episodes
    scenarios = make_scenarios(quick)
    mimo = next(s for s in scenarios if s.kind == "mimo")
    envs = training_envs(quick, scenarios)
    tasks = [t for t in rl_tasks(quick, scenarios, envs, {}) if t.train_key == mimo.train_key]
    assert sorted((t.algo, t.seed) for t in tasks) == [
        (a, s) for a in ("ppo", "sac") for s in range(quick.train_seeds)
    ]
    for t in tasks:
        (ev,) = t.evaluations
        assert ev.env == mimo.env and ev.episodes == mimo.episodes
    assert {"stc_mimo", "lqg", "zero"} == set(controllers_for(quick.classical, mimo.env))
    assert "mimo_switch" not in quick.scenarios  # the quick tier stays within its minutes
    standard = build_config(mode="standard", run="s")
    assert "mimo" in standard.scenarios and "mimo_switch" in standard.scenarios
    assert standard.mimo_plants == ["quadruple_tank", "quadruple_tank_nmp"]
    assert [s.name for s in make_scenarios(standard) if s.kind.startswith("mimo")] == [
        "mimo:quadruple_tank",
        "mimo:quadruple_tank_nmp",
        "mimo_switch",
        "mimo_family:test",
    ]
    assert standard.mimo_train_steps == {"ppo": 200_000, "sac": 50_000}  # single-plant caps
    full = build_config(mode="full", run="f")
    # every MIMO plant with a yardstick for its cost (ac1 has none for controlgym's)
    assert full.mimo_plants == [p for p in mimo_plant_names() if p != "ac1"] == FULL["mimo_plants"]
    assert [s.name for s in make_scenarios(full) if s.kind == "mimo"] == [
        f"mimo:{p}" for p in full.mimo_plants
    ]
    # every tier's default agents include the multivariable controller the scenario is for
    for cfg in (quick, standard, full):
        assert "stc_mimo" in cfg.agents


def test_mimo_env_spec_round_trips_and_rejects_what_it_cannot_run():
    spec = MimoEnvSpec("AC1", steps=50)
    assert spec.plants == ("ac1",) and spec.channels == (5, 3)
    assert EnvSpec.from_dict(spec.to_dict()) == spec
    with pytest.raises(ValueError, match="plant must be one of"):
        MimoEnvSpec("stable2")
    with pytest.raises(ValueError, match="switch_to"):
        MimoEnvSpec("he1", steps=50, jump_step=10, jump_to=(0.0,))
    with pytest.raises(ValueError, match="other dimensions"):
        MimoEnvSpec("he1", steps=50, jump_step=10, switch_to="ac1")
    with pytest.raises(ValueError, match="one MIMO plant"):
        MimoEnvSpec(("he1", "ac1"))
    ep = run_episode(lambda plant, seed: LQRController(*plant.discrete()), spec, seed=3)
    # the traces hold the performance output z (three channels of ac1's cost)
    assert ep.plant == "ac1" and ep.y.shape == (51, 3) and ep.u.shape == (50, 3)


def test_history_window_of_a_mimo_plant_holds_every_channel():
    env = gym.make("stcgym/StateSpace-v0", plant="quadruple_tank", noise_std=0.0)
    config = WindowConfig(window=2, include_error=False, include_integral=False)
    wrapped = HistoryWindow(env, config)
    assert wrapped.observation_space.shape == (2 * (4 + 4 + 2),)
    assert wrapped.action_space.shape == (2,)
    obs0, _ = wrapped.reset(seed=0)
    obs1, _, _, _, info = wrapped.step(np.array([0.5, -0.25]))
    x1 = info["x"]
    np.testing.assert_allclose(info["u"], [5.0, -2.5])
    A, B = get_mimo_plant("quadruple_tank").discrete()
    np.testing.assert_allclose(x1, B @ np.array([5.0, -2.5]))  # from x(0) = 0
    # blocks: y window (4 channels x 2 samples), r window (4 x 2), u window (2 x 2)
    y_rows, r_rows = obs1[:8].reshape(4, 2), obs1[8:16].reshape(4, 2)
    np.testing.assert_allclose(y_rows[:, 0], 0.0)
    np.testing.assert_allclose(y_rows[:, 1], x1, rtol=1e-6)
    np.testing.assert_allclose(r_rows, 1.0)  # the square wave's first half-period
    np.testing.assert_allclose(obs0[8:16].reshape(4, 2), [[0.0, 1.0]] * 4)
    u_rows = obs1[16:].reshape(2, 2)
    np.testing.assert_allclose(u_rows, [[0.0, 0.5], [0.0, -0.25]])
    # the one-channel buffer is the SISO one
    buf = HistoryBuffer(config, 10.0, 1, 4, 2)
    buf.start(np.concatenate([np.zeros(4), np.ones(4)]))
    assert buf.features().shape == (1, 20)
