"""``stcgym sweep``: the same table on every executor, resume after a kill, the loop by hand."""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from family_envs import single_family_env

import stcgym.agents.sweeps.chunk as chunk
import stcgym.envs  # noqa: F401
from stcgym.adaptive import KnownModelController, LawOptions, LQGController
from stcgym.adaptive.control.options import cost_weights
from stcgym.agents.sweeps import SweepConfig, SweepError, run_sweep
from stcgym.agents.sweeps.chunk import closed_loop
from stcgym.agents.sweeps.cli import main, parse_controller
from stcgym.envs.families import draw_plant, load_family, plant_features
from stcgym.envs.signals import Jumps, RandomWalk

FAMILY = {
    "name": "tiny",
    "seed": 3,
    "count": 3,
    "order": 2,
    "poles": {"unstable_share": 0.3, "complex_share": 0.5},
    "zeros": {"nonminimum_phase_share": 0.3},
    "steps": 120,
    "reference": {"kind": "square", "period": 20},
    "jump": {"at": 0.5, "magnitude_scale": [0.8, 1.0], "dc_gain_scale": [0.5, 2.0]},
}
CONTROLLERS = {"stc": {}, "oracle": {}, "lqg": {}}


def tiny_config(**family):
    return SweepConfig.build({**FAMILY, **family}, CONTROLLERS, seeds=2, chunk_size=2)


@pytest.fixture(scope="module")
def reference_run(tmp_path_factory):
    """The uninterrupted sweep on one process: 6 lanes in 3 tasks."""
    out = tmp_path_factory.mktemp("sweep")
    return run_sweep(tiny_config(), out=out, run="jobs1", jobs=1, progress=False)


def test_table_has_one_row_per_plant_controller_and_seed(reference_run):
    df = reference_run.table
    assert len(df) == 3 * 2 * 3
    assert not df.duplicated(["plant", "seed", "controller"]).any()
    assert set(df["controller"]) == {"stc", "oracle", "lqg"}
    oracle = df[df["controller"] == "oracle"]
    np.testing.assert_array_equal(oracle["ratio"], 1.0)
    assert set(df["bounded"]) <= {0, 1}
    fam = load_family(FAMILY)
    for row in df.itertuples():
        feats = plant_features(draw_plant(fam, row.plant))
        assert row.pole_mag_max == feats["pole_mag_max"]
        assert row.abs_dc_gain == feats["abs_dc_gain"]
    merged = df.merge(oracle[["plant", "seed", "cost"]], on=["plant", "seed"], suffixes=("", "_o"))
    np.testing.assert_allclose(merged["ratio"], merged["cost"] / merged["cost_o"], rtol=1e-12)
    # Settling is measured against the oracle on the same lane: the oracle itself reads 0,
    # the others a step count inside the scored part of the episode, or inf.
    bounded_oracle = oracle[oracle["bounded"] == 1]
    assert (bounded_oracle["adapt_steps"] == 0).all()
    assert (bounded_oracle["reconverge_steps"] == 0).all()
    J = load_family(FAMILY).jump_step
    for col, limit in (("adapt_steps", J), ("reconverge_steps", 120 - J)):
        v = df[col].to_numpy()
        assert np.all(((v >= 0) & (v < limit)) | (v == math.inf))
    assert reference_run.plot_path is not None
    assert reference_run.plot_path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not (reference_run.run_dir / "failures.json").exists()


def test_jobs_2_and_ray_give_identical_tables(reference_run, tmp_path):
    expected = reference_run.table_path.read_bytes()
    two = run_sweep(tiny_config(), out=tmp_path, run="jobs2", jobs=2, progress=False, plot=False)
    assert two.table_path.read_bytes() == expected
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False)
    try:
        on_ray = run_sweep(
            tiny_config(), out=tmp_path, run="ray", executor="ray", progress=False, plot=False
        )
    finally:
        ray.shutdown()
    assert on_ray.table_path.read_bytes() == expected


def test_killed_sweep_resumes_to_the_uninterrupted_table(tmp_path):
    # 8 tasks of one lane each; kill the sweep once two of them are saved.
    spec = {**FAMILY, "count": 4, "steps": 200, "jump": None}
    (tmp_path / "fam.json").write_text(json.dumps(spec))
    args = ["--seeds", "2", "--chunk", "1", "--jobs", "1", "--no-plot", "--quiet"]
    cmd = [sys.executable, "-m", "stcgym.agents.sweeps.cli", str(tmp_path / "fam.json"), *args]
    proc = subprocess.Popen([*cmd, "--out", str(tmp_path), "--run", "killed"])
    tasks = tmp_path / "killed" / "tasks"
    deadline = time.monotonic() + 600  # a cold numba cache compiles first
    while proc.poll() is None and time.monotonic() < deadline:
        if tasks.is_dir() and len(list(tasks.glob("*.json"))) >= 2:
            proc.send_signal(signal.SIGKILL)
            break
        time.sleep(0.01)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL
    saved = len(list(tasks.glob("*.json")))
    assert 2 <= saved < 8
    assert not (tmp_path / "killed" / "metrics.csv").exists()

    resumed = run_sweep(resume=tmp_path / "killed", progress=False, plot=False)
    full = run_sweep(
        SweepConfig.build(spec, ["stc", "oracle", "lqg"], seeds=2, chunk_size=1),
        out=tmp_path,
        run="full",
        jobs=1,
        progress=False,
        plot=False,
    )
    assert resumed.table_path.read_bytes() == full.table_path.read_bytes()
    assert len(list(tasks.glob("*.json"))) == 8


def test_a_failed_task_keeps_the_others_and_resume_retries_it(reference_run, tmp_path, monkeypatch):
    real = chunk.closed_loop

    def flaky(kw, family, plants, lane_seeds):
        if any(p.index == 1 for p in plants):
            raise RuntimeError("simulated crash on plant 1")
        return real(kw, family, plants, lane_seeds)

    monkeypatch.setattr(chunk, "closed_loop", flaky)
    part = run_sweep(tiny_config(), out=tmp_path, run="r", jobs=1, progress=False, plot=False)
    assert len(part.failures) == 1 and part.failures[0]["lanes"] == [2, 4]
    assert "simulated crash on plant 1" in part.failures[0]["error"]
    assert json.loads((part.run_dir / "failures.json").read_text()) == part.failures
    assert sorted(set(part.table["plant"])) == [0, 2]

    monkeypatch.setattr(chunk, "closed_loop", real)
    again = run_sweep(resume=part.run_dir, progress=False, plot=False)
    assert not again.failures and not (part.run_dir / "failures.json").exists()
    assert again.table_path.read_bytes() == reference_run.table_path.read_bytes()


@pytest.mark.parametrize("change", ["none", "jump", "drift", "initial_state"])
@pytest.mark.parametrize("kind", ["oracle", "lqg"])
def test_closed_loop_lanes_equal_single_episodes_run_by_hand(kind, change):
    """Each lane against a single env stepped by hand (the envs' own ``Jumps``/``RandomWalk``;
    the family's random initial state)."""
    jump = FAMILY["jump"] if change == "jump" else None
    drift = {"std": 0.002} if change == "drift" else None
    x0_std = 0.5 if change == "initial_state" else 0.0
    fam = load_family(
        {**FAMILY, "jump": jump, "drift": drift, "count": 4, "initial_state_std": x0_std}
    )
    plants = [draw_plant(fam, i) for i in range(4)]
    seeds = [11, 12, 13, 14]
    res = closed_loop({"kind": kind}, fam, plants, seeds)
    T, J = fam.steps, fam.jump_step
    for lane, (p, seed) in enumerate(zip(plants, seeds, strict=True)):
        extra = {}
        if J is not None:
            extra["schedule"] = Jumps({J: np.r_[p.a_after, p.b_after]})
        if drift is not None:
            extra["schedule"] = RandomWalk(drift["std"])
        env = single_family_env(fam, p, T, **extra)
        if kind == "oracle":
            ctl = KnownModelController(p.a, p.b, action_bound=fam["action_bound"])
        else:
            law = LawOptions(integral=False, lq_weights=cost_weights(fam["control_cost"]))
            ctl = LQGController(p.a, p.b, law=law, noise_std=fam["noise_std"])
        obs, info = env.reset(seed=seed)
        cost, diverged = [], False
        for k in range(T):
            if k == J and kind == "oracle":
                ctl.set_model(p.a_after, p.b_after)
            if drift is not None and k > 0 and kind == "oracle":  # told the drifted plant
                ctl.set_model(info["theta"][:2], info["theta"][2:])
            obs, reward, terminated, _, info = env.step(ctl.predict(obs)[0])
            cost.append(-reward)
            if terminated:
                diverged = True
                break
        cost += [cost[-1]] * (T - len(cost))  # the charge of a diverged run
        np.testing.assert_allclose(res.cost[lane], cost, rtol=1e-9, atol=1e-12)
        assert res.diverged[lane] == diverged
        assert res.steps_run[lane] == (k + 1 if diverged else T)


def test_parse_controller():
    assert parse_controller("stc") == ("stc", {"kind": "stc"})
    text = "rls=stc:estimator=KF-RLS,estimator_options.p0=100,poles=[0.6,0.6,0.6]"
    assert parse_controller(text) == (
        "rls",
        {
            "kind": "stc",
            "estimator": "KF-RLS",
            "estimator_options": {"p0": 100},
            "poles": [0.6, 0.6, 0.6],
        },
    )
    with pytest.raises(SweepError, match="KEY=VALUE"):
        parse_controller("stc:p0")


@pytest.mark.parametrize(
    ("family", "extra", "message"),
    [
        ({**FAMILY, "count": -1}, [], "count must be an integer >= 1"),
        ({**FAMILY, "shape": 1}, [], "unknown key"),
        ({**FAMILY, "poles": {"magnitude": [0.9, 0.2]}}, [], "poles.magnitude"),
        ({**FAMILY, "jump": {"at": [0.3, 0.7]}}, [], "a sweep needs a fixed jump"),
        ({**FAMILY, "jump": {"at": 0.5, "probability": 0.5}}, [], "a sweep needs a fixed jump"),
        (FAMILY, ["--controller", "stc:estimatr=KF-RLS"], "controller 'stc'"),
        (FAMILY, ["--controller", "x=pid"], "kind must be one of"),
        (FAMILY, ["--seeds", "0"], "seeds"),
        (FAMILY, ["--chunk", "0"], "chunk_size"),
        (FAMILY, ["--features", "pole_mag_max,colour"], "features must be two of"),
    ],
)
def test_bad_input_is_one_line_before_any_work(tmp_path, capsys, family, extra, message):
    (tmp_path / "fam.json").write_text(json.dumps(family))
    status = main([str(tmp_path / "fam.json"), "--out", str(tmp_path / "out"), *extra])
    assert status == 2
    err = capsys.readouterr().err
    assert err.startswith("stcgym sweep: error:") and message in err
    assert not (tmp_path / "out").exists()


def test_a_run_folder_is_not_overwritten_and_resume_checks_it(reference_run, tmp_path):
    with pytest.raises(SweepError, match="already holds a sweep"):
        run_sweep(tiny_config(), out=reference_run.run_dir.parent, run="jobs1")
    with pytest.raises(SweepError, match="no config.json"):
        run_sweep(resume=tmp_path)
    with pytest.raises(SweepError, match="differs"):
        run_sweep(tiny_config(seed=4), resume=reference_run.run_dir)
