"""End-to-end ``stcgym bench`` on a tiny budget, reproducibility, bad input, interruption."""

from __future__ import annotations

import csv
import json

import pytest

from stcgym.agents import bench as bench_mod
from stcgym.agents.bench import CONTROLLERS, METRIC_COLUMNS, ControllerInfo, build_config
from stcgym.agents.cli import main

# A few hundred training steps, one seed, short episodes: the whole pipeline in seconds.
TINY = [
    "--quick",
    "--train-steps",
    "300",
    "--seeds",
    "1",
    "--episode-steps",
    "120",
    "--train-episode-steps",
    "60",
    "--curve-points",
    "2",
    "--hp",
    "ppo.n_steps=64",
    "--hp",
    "ppo.n_envs=2",
    "--hp",
    "sac.learning_starts=100",
    "--hp",
    "td3.learning_starts=100",
    "--no-progress",
]


def _rows(path):
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        return reader.fieldnames, list(reader)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    rc = main(["bench", *TINY, "--out", str(out), "--run", "tiny"])
    assert rc == 0
    return out / "tiny"


def test_end_to_end_writes_every_file(tiny_run):
    names = {p.name for p in tiny_run.iterdir()}
    assert {"metrics.csv", "report.md", "config.json", "learning_curves.csv"} <= names
    pngs = {n for n in names if n.endswith(".png")}
    assert "learning_curves.png" in pngs
    assert {f"traces_{s}.png" for s in ("nominal_stable2", "family_nonminphase2")} <= pngs
    assert "jump_cost_jump_timevarying2.png" in pngs

    header, rows = _rows(tiny_run / "metrics.csv")
    assert header == METRIC_COLUMNS
    scenarios = {r["scenario"] for r in rows}
    assert scenarios == {
        "nominal:stable2",
        "nominal:unstable2",
        "family:lightly_damped2",
        "family:nonminphase2",
        "jump:timevarying2",
    }
    controllers = {r["controller"] for r in rows}
    assert controllers == {"ppo", "sac", "td3", "stc", "oracle", "lqg"}
    assert len(rows) == len(scenarios) * len(controllers)  # one seed, one training seed
    for r in rows:
        assert float(r["cost"]) >= 0 and r["bounded"] in ("0", "1")
        if r["kind"] == "jump":
            assert r["cost_post_jump"] != "" and r["reconverge_steps"] != ""
        if r["family"] == "rl":
            assert int(r["train_steps"]) >= 300 and float(r["train_wall_s"]) > 0
            assert int(r["data_steps"]) == int(r["train_steps"])
        elif r["controller"] == "stc":
            assert int(r["data_steps"]) == int(r["steps_run"])

    header, curves = _rows(tiny_run / "learning_curves.csv")
    assert header == ["train_env", "algo", "train_seed", "steps", "cost"]
    assert {c["train_env"] for c in curves} == {"nominal:stable2", "nominal:unstable2", "family"}

    config = json.loads((tiny_run / "config.json").read_text())
    assert config["bench"]["train_steps"] == {"ppo": 300, "sac": 300, "td3": 300}
    assert config["bench"]["algo_configs"]["ppo"]["hyperparams"]["n_steps"] == 64
    assert "versions" in config and config["argv"][:2] == ["bench", "--quick"]

    report = (tiny_run / "report.md").read_text()
    assert "## Median episode cost" in report and "## Conclusions" in report
    assert "| stc |" in report and "`jump:timevarying2`" in report


def test_saved_model_reloads_for_evaluation(tiny_run, capsys):
    model = tiny_run / "models" / "nominal-stable2_ppo_s0"
    assert (model / "agent.json").is_file()
    assert main(["eval", str(model), "--seeds", "2", "--episode-steps", "50"]) == 0
    assert "ppo (seed 0" in capsys.readouterr().out


def _numbers(path):
    _, rows = _rows(path)
    timing = {"step_us", "train_wall_s"}
    return [{k: v for k, v in r.items() if k not in timing} for r in rows]


def test_identical_seeds_give_identical_numbers(tmp_path):
    args = [
        *TINY,
        "--agents",
        "ppo,stc,oracle",
        "--scenarios",
        "nominal,jump",
        "--plants",
        "stable2",
        "--seeds",
        "2",
        "--no-plots",
        "--out",
        str(tmp_path),
    ]
    assert main(["bench", *args, "--run", "a"]) == 0
    assert main(["bench", *args, "--run", "b"]) == 0
    a, b = _numbers(tmp_path / "a" / "metrics.csv"), _numbers(tmp_path / "b" / "metrics.csv")
    assert len(a) == 2 * 2 * 3 and a == b


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--plants", "stable2,nosuchplant"], "unknown plant"),
        (["--agents", "ppo,dqn"], "unknown agent"),
        (["--train-steps", "0"], "positive integer"),
        (["--train-steps", "-5"], "positive integer"),
        (["--train-steps", "ppo=100,sac=0"], "positive integer"),
        (["--seeds", "0"], "positive integer"),
        (["--episode-steps", "0"], "positive integer"),
        (["--hp", "ppo.no_such_knob=1"], "no_such_knob"),
        (["--family-test", "stable2"], "held-out"),
        (["--jump", "stable2:stable4"], "same order"),
        (["--scenarios", "nominal,weird"], "scenarios"),
    ],
)
def test_bad_input_fails_before_training(tmp_path, monkeypatch, capsys, extra, message):
    def no_training(*args, **kwargs):  # pragma: no cover - must not be reached
        raise AssertionError("training started")

    monkeypatch.setattr("stcgym.agents.sb3.train_agent", no_training)
    rc = main(["bench", *TINY, "--out", str(tmp_path), "--run", "bad", *extra])
    assert rc == 2
    err = capsys.readouterr().err
    assert "error" in err and message in err
    assert not (tmp_path / "bad").exists()


def test_unwritable_output_folder(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    rc = main(["bench", *TINY, "--out", str(blocker / "sub"), "--run", "x"])
    assert rc == 2 and "cannot be written" in capsys.readouterr().err


def test_existing_run_is_not_overwritten(tmp_path, capsys):
    args = ["bench", *TINY, "--agents", "oracle", "--no-plots", "--out", str(tmp_path)]
    assert main([*args, "--run", "r", "--scenarios", "nominal", "--plants", "stable2"]) == 0
    assert main([*args, "--run", "r"]) == 2
    assert "already holds a run" in capsys.readouterr().err


class _Exploding:
    """A controller that fails on its third episode."""

    episodes = 0

    def reset(self):
        type(self).episodes += 1
        if type(self).episodes == 3:
            raise KeyboardInterrupt

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        return [0.0], state


def test_interrupted_run_keeps_finished_rows(tmp_path, monkeypatch):
    info = ControllerInfo("oracle", lambda cfg, sc: lambda plant: _Exploding())
    monkeypatch.setitem(CONTROLLERS, "boom", info)
    _Exploding.episodes = 0
    cfg = build_config(
        quick=True,
        run="int",
        out=str(tmp_path),
        agents="oracle,boom,ppo",
        seeds=2,
        episode_steps=50,
        train_steps=300,
        plots=False,
    )
    with pytest.raises(KeyboardInterrupt):
        bench_mod.run_bench(cfg, log=lambda msg: None)
    header, rows = _rows(tmp_path / "int" / "metrics.csv")
    assert header == METRIC_COLUMNS
    # Scenario 1: oracle and boom on 2 seeds; scenario 2: oracle, then boom blows up.
    assert [r["controller"] for r in rows] == [
        "oracle",
        "oracle",
        "boom",
        "boom",
        "oracle",
        "oracle",
    ]
    assert [r["scenario"] for r in rows] == ["nominal:stable2"] * 4 + ["nominal:unstable2"] * 2
    assert all(r["cost"] for r in rows)
    assert "INTERRUPTED" in (tmp_path / "int" / "report.md").read_text()

    # Through the command line the interrupt exits with 130 and keeps the rows as well.
    _Exploding.episodes = 0
    rc = main(["bench", *TINY, "--agents", "oracle,boom", "--out", str(tmp_path), "--run", "cli"])
    assert rc == 130
    _, rows = _rows(tmp_path / "cli" / "metrics.csv")
    assert [r["controller"] for r in rows] == ["oracle", "boom", "oracle", "boom", "oracle"]
