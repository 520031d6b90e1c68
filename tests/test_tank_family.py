"""The quadruple tanks drawn from their valve settings (``stcgym.envs.tank_family``) and the
``mimo_family:test`` scenario of ``stcgym bench``: the linearisation against Johansson's
nonlinear model by finite differences and a matrix exponential, the splits, a lane against the
single env, and a tiny bench run."""

from __future__ import annotations

import contextlib
import csv
import io
import json

import control
import gymnasium as gym
import numpy as np
import pytest
from scipy.linalg import expm

import stcgym.envs  # noqa: F401  (registers the envs)
from stcgym.adaptive import LQRController
from stcgym.agents.benchmark import build_config, make_scenarios
from stcgym.agents.benchmark.plan import rl_tasks
from stcgym.agents.benchmark.scenarios import training_envs
from stcgym.agents.cli import main
from stcgym.agents.evaluation.env_spec import EnvSpec
from stcgym.agents.evaluation.mimo import TANK_REFERENCE, MimoEnvSpec
from stcgym.envs import get_mimo_plant
from stcgym.envs.tank_family import (
    GRAVITY,
    OUTLET_AREAS,
    PUMP_GAINS,
    PUMP_VOLTAGES,
    TANK_FAMILY,
    TankFamily,
    tank_at,
    tank_levels,
)

AREAS = (28.0, 32.0, 28.0, 32.0)  # Johansson (2000), Table I


def _levels_rate(h, v, gamma):
    """Johansson (2000) eq. (1): dh/dt of the nonlinear tanks, written out by hand."""
    (a1, a2, a3, a4), (A1, A2, A3, A4) = OUTLET_AREAS, AREAS
    (k1, k2), (g1, g2), g = PUMP_GAINS, gamma, GRAVITY
    q = [a * np.sqrt(2 * g * hi) for a, hi in zip((a1, a2, a3, a4), h, strict=True)]
    return np.array(
        [
            (-q[0] + q[2] + g1 * k1 * v[0]) / A1,
            (-q[1] + q[3] + g2 * k2 * v[1]) / A2,
            (-q[2] + (1 - g2) * k2 * v[1]) / A3,
            (-q[3] + (1 - g1) * k1 * v[0]) / A4,
        ]
    )


@pytest.mark.parametrize("gamma", [(0.7, 0.6), (0.43, 0.34), (0.31, 0.77)])
def test_linearisation_is_the_jacobian_of_the_nonlinear_tanks_at_their_steady_levels(gamma):
    h0, v0 = np.array(tank_levels(gamma)), np.array(PUMP_VOLTAGES)
    np.testing.assert_allclose(_levels_rate(h0, v0, gamma), 0.0, atol=1e-12)  # steady
    eps = 1e-6
    A_fd = np.column_stack(
        [
            (_levels_rate(h0 + eps * e, v0, gamma) - _levels_rate(h0 - eps * e, v0, gamma))
            / (2 * eps)
            for e in np.eye(4)
        ]
    )
    B_fd = np.column_stack(
        [
            (_levels_rate(h0, v0 + eps * e, gamma) - _levels_rate(h0, v0 - eps * e, gamma))
            / (2 * eps)
            for e in np.eye(2)
        ]
    )
    spec = tank_at(gamma)
    np.testing.assert_allclose(np.array(spec.A_c), A_fd, rtol=1e-6, atol=1e-10)
    np.testing.assert_allclose(np.array(spec.B_c), B_fd, rtol=1e-6, atol=1e-10)
    # zero-order hold at 5 s by the block matrix exponential
    M = expm(np.block([[A_fd, B_fd], [np.zeros((2, 6))]]) * 5.0)
    A, B = spec.discrete()
    np.testing.assert_allclose(A, M[:4, :4], rtol=1e-6, atol=1e-10)
    np.testing.assert_allclose(B, M[:4, 4:], rtol=1e-6, atol=1e-10)


def test_johanssons_minimum_phase_setting_gives_the_catalogue_tank():
    # Table II's time constants are measured; the physical ones agree within 1.5 %
    drawn, table = tank_at((0.70, 0.60)), get_mimo_plant("quadruple_tank")
    np.testing.assert_allclose(np.diag(drawn.A_c), np.diag(table.A_c), rtol=0.015)
    np.testing.assert_allclose(np.array(drawn.B_c), np.array(table.B_c), rtol=1e-12)
    assert drawn.input_range == table.input_range and drawn.C_z == table.C_z


def test_the_zero_is_in_the_right_half_plane_exactly_when_gamma1_plus_gamma2_is_below_one():
    for spec in TANK_FAMILY.members("validation"):
        g1, g2 = (float(s) for s in spec.description.split("(")[1].split(")")[0].split(","))
        sys = control.ss(np.array(spec.A_c), np.array(spec.B_c), np.eye(2, 4), np.zeros((2, 2)))
        rhp = np.any(np.real(control.zeros(sys)) > 0)
        assert rhp == (g1 + g2 < 1)
        assert 0.2 <= min(g1, g2) and max(g1, g2) <= 0.8 and abs(g1 + g2 - 1) >= 0.15


def test_splits_are_disjoint_reproducible_and_hold_both_phases():
    names = {s: [p.name for p in TANK_FAMILY.members(s)] for s in TANK_FAMILY.split_names}
    assert [len(names[s]) for s in ("train", "validation", "test")] == [200, 50, 100]
    settings = {s: {TANK_FAMILY.gamma(i) for i in TANK_FAMILY.indices(s)} for s in names}
    assert not settings["train"] & settings["test"]
    assert not settings["train"] & settings["validation"]
    assert not settings["validation"] & settings["test"]
    # member i depends on the seed and i only, not on the split sizes
    other = TankFamily("x", 35, (0.2, 0.8), 0.15, (("all", 0, 400),))
    assert [other.gamma(i) for i in range(250, 350)] == [
        TANK_FAMILY.gamma(i) for i in TANK_FAMILY.indices("test")
    ]
    for split in names:
        sums = [sum(TANK_FAMILY.gamma(i)) for i in TANK_FAMILY.indices(split)]
        assert 0.2 < np.mean(np.array(sums) < 1) < 0.8  # both phases in every split
    with pytest.raises(ValueError, match="split must be one of"):
        TANK_FAMILY.indices("ood")


def _kwargs():
    return dict(
        split="test",
        reference_in="state",
        reference=TANK_REFERENCE,
        noise_std=0.05,
        control_cost=0.01,
    )


@pytest.mark.equality
def test_each_lane_is_the_single_env_across_autoresets():
    B, T, steps = 3, 40, 130  # three episodes and a bit per lane
    envs = gym.make_vec(
        "stcgym/QuadrupleTankFamily-v0", num_envs=B, max_episode_steps=T, **_kwargs()
    )
    singles = [
        gym.make("stcgym/QuadrupleTankFamily-v0", max_episode_steps=T, **_kwargs())
        for _ in range(B)
    ]
    obs, infos = envs.reset(seed=7)
    single_obs = [env.reset(seed=7 + i) for i, env in enumerate(singles)]
    for i in range(B):
        np.testing.assert_array_equal(obs[i], single_obs[i][0])
        assert infos["plant"][i] == single_obs[i][1]["plant"]
    rng = np.random.default_rng(0)
    done = [False] * B
    seen = [{infos["plant"][i]} for i in range(B)]
    for _ in range(steps):
        u = rng.uniform(-2, 2, (B, 2))
        obs, reward, term, trunc, infos = envs.step(u)
        for i, env in enumerate(singles):
            if done[i]:  # NEXT_STEP autoreset: this step starts the lane's next episode
                o, info = env.reset()
                r_i, end = 0.0, False
            else:
                o, r_i, te, tr, info = env.step(u[i])
                end = te or tr
            np.testing.assert_array_equal(obs[i], o)
            assert reward[i] == r_i and infos["plant"][i] == info["plant"]
            seen[i].add(info["plant"])
            done[i] = end
            assert (term[i] or trunc[i]) == end
    # every lane drew a new member at its autoresets
    assert all(len(s) > 1 for s in seen)


@pytest.mark.equality
def test_a_member_is_the_state_space_env_with_its_matrices():
    family = gym.make("stcgym/QuadrupleTankFamily-v0", max_episode_steps=60, **_kwargs())
    obs, info = family.reset(seed=3, options={"plant": 300})
    plant = family.unwrapped.mimo_plant
    assert info["plant"] == plant.name == "quadruple_tank-v1/test/300"
    A, B = plant.discrete()
    kw = {k: v for k, v in _kwargs().items() if k != "split"}
    single = gym.make(
        "stcgym/StateSpace-v0",
        A=A,
        B=B,
        C_z=np.eye(2, 4),
        input_range=plant.input_range,
        max_episode_steps=60,
        **kw,
    )
    ref, _ = single.reset(seed=3)
    np.testing.assert_array_equal(obs, ref)
    for u in np.random.default_rng(1).uniform(-3, 7, (60, 2)):
        a = family.step(u)
        b = single.step(u)
        np.testing.assert_array_equal(a[0], b[0])
        assert a[1:4] == b[1:4]


def test_bad_plant_options_name_the_split():
    env = gym.make("stcgym/QuadrupleTankFamily-v0", split="validation")
    with pytest.raises(ValueError, match=r"options\['plant'\] must be a plant of split"):
        env.reset(options={"plant": 250})  # a test plant
    with pytest.raises(TypeError, match="draws its plants"):
        gym.make("stcgym/QuadrupleTankFamily-v0", plant="quadruple_tank")
    envs = gym.make_vec("stcgym/QuadrupleTankFamily-v0", num_envs=2, split="validation")
    with pytest.raises(ValueError, match="num_envs=2"):
        envs.reset(options={"plant": [200]})
    _, infos = envs.reset(seed=0, options={"plant": [201, "quadruple_tank-v1/validation/249"]})
    assert list(infos["plant"]) == [
        "quadruple_tank-v1/validation/201",
        "quadruple_tank-v1/validation/249",
    ]


def test_scenario_trains_on_the_training_split_and_is_scored_on_the_test_split():
    spec = MimoEnvSpec(family="quadruple_tank-v1", split="test", steps=50)
    assert EnvSpec.from_dict(spec.to_dict()) == spec
    with pytest.raises(ValueError, match="split must be one of"):
        MimoEnvSpec(family="quadruple_tank-v1", split="ood", steps=50)
    with pytest.raises(ValueError, match="MIMO family must be"):
        MimoEnvSpec(family="siso2-v1", split="test", steps=50)
    quick = build_config(run="q")
    assert "mimo_family" not in quick.scenarios  # the quick tier stays within its minutes
    for mode in ("standard", "full"):
        cfg = build_config(mode=mode, run=mode)
        assert "mimo_family" in cfg.scenarios
    cfg = build_config(run="s", mode="standard", scenarios="mimo_family", agents="ppo,stc_mimo")
    (sc,) = make_scenarios(cfg)
    assert sc.name == "mimo_family:test" and sc.train_key == "mimo_family"
    assert sc.episodes.plants == tuple(p.name for p in TANK_FAMILY.members("test"))
    envs = training_envs(cfg, [sc])
    tasks = rl_tasks(cfg, [sc], envs, {})
    assert {t.algo for t in tasks} == {"ppo"}
    for t in tasks:
        assert t.train_env.split == "train" and t.curve_env.split == "validation"
        assert all("/validation/" in p for p in t.curve_episodes.plants)
        (ev,) = t.evaluations
        assert ev.env == sc.env and ev.episodes == sc.episodes


def test_tiny_bench_run_scores_every_controller_on_the_test_plants(tmp_path, capsys):
    args = (
        "--train-steps 200 --eval-interval 100 --train-seeds 1 --test-plants 3 "
        "--curve-episodes 2 --bound-plants 3 --episode-steps 120 --curve-points 2 "
        "--hp ppo.n_steps=64 --hp ppo.n_envs=2 --hp ppo.n_epochs=2 --bootstrap-reps 100 "
        "--jobs 1 --no-progress --scenarios mimo_family --agents ppo,stc_mimo,lqg --run t"
    ).split()
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = main(["bench", *args, "--out", str(tmp_path)])
    assert rc == 0, err.getvalue()
    with open(tmp_path / "t" / "metrics.csv", newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["scenario"] == "mimo_family:test"]
    test_plants = [p.name for p in TANK_FAMILY.members("test")[:3]]
    assert {r["controller"] for r in rows} == {"ppo", "stc_mimo", "lqg", "zero"}
    for name in ("ppo", "stc_mimo", "lqg", "zero"):
        assert [r["plant"] for r in rows if r["controller"] == name] == test_plants
    # the yardstick of each lane is the LQR of that lane's plant: a plain loop agrees
    from stcgym.agents.benchmark.config import BenchConfig

    config = json.loads((tmp_path / "t" / "config.json").read_text())
    (sc,) = make_scenarios(BenchConfig.from_dict(config["bench"]))
    row = next(r for r in rows if r["controller"] == "lqg" and r["plant"] == test_plants[1])
    env = sc.env.make()
    obs, _ = env.reset(seed=int(row["seed"]), options={"plant": test_plants[1]})
    plant = env.unwrapped.mimo_plant
    Q, R, _ = plant.lq_weights(sc.env.control_cost)
    lqr = LQRController(*plant.discrete(), Q=Q, R=R, action_bound=sc.env.action_bound)
    costs = []
    for _ in range(sc.env.steps):
        u, _ = lqr.predict(obs)
        obs, reward, *_ = env.step(u)
        costs.append(-reward)
    assert sc.env.steps == 120
    assert np.mean(costs) == pytest.approx(float(row["cost"]), rel=1e-4)
    # the saved agent reproduces its bench numbers on the test members, and runs on P+
    capsys.readouterr()
    model = str(tmp_path / "t" / "models" / "mimo_family_ppo_s0")
    assert main(["eval", model, "--seeds", "3", "--episode-steps", "120"]) == 0
    out = capsys.readouterr().out
    for r in rows:
        if r["controller"] == "ppo":
            assert f"{r['plant']} seed {r['seed']}: cost {float(r['cost']):.4g}" in out
    assert main(["eval", model, "--seeds", "1", "--plant", "quadruple_tank_nmp"]) == 0
    assert main(["eval", model, "--plant", "he1"]) == 2
    assert "quadruple tanks of quadruple_tank-v1" in capsys.readouterr().err


def test_gymnasium_and_sb3_checkers_pass():
    import warnings

    from gymnasium.utils.env_checker import check_env

    pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        check_env(gym.make("stcgym/QuadrupleTankFamily-v0").unwrapped, skip_render_check=True)
        sb3_check_env(gym.make("stcgym/QuadrupleTankFamily-v0").unwrapped, warn=False)
