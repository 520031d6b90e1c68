"""End-to-end ``stcgym bench`` on a tiny budget, reproducibility, bad input, interruption."""

from __future__ import annotations

import contextlib
import csv
import io
import json

import pytest

import stcgym.agents.benchmark as benchmark
from stcgym.agents.benchmark import METRIC_COLUMNS, BenchConfig, build_config, make_scenarios
from stcgym.agents.benchmark import runner as runner_mod
from stcgym.agents.benchmark.config import FULL, QUICK
from stcgym.agents.benchmark.plan import (
    WORKER_START_SECONDS,
    curve_evaluations,
    job_weights,
    rl_tasks,
    schedule,
)
from stcgym.agents.cli import main
from stcgym.agents.controllers import CONTROLLERS, ControllerInfo

# A few hundred training steps, 2 training seeds, short episodes: the whole pipeline in seconds
# (the SISO scenarios; tests/test_bench_mimo.py runs the mimo one).
TINY = [
    "--scenarios",
    "nominal,family,jump",
    "--train-steps",
    "300",
    "--eval-interval",
    "100",
    "--train-seeds",
    "2",
    "--seeds",
    "2",
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
    "sac.learning_starts=250",
    "--hp",
    "rppo.n_steps=32",
    "--hp",
    "rppo.batch_size=64",
    "--hp",
    "rppo.n_envs=2",
    "--hp",
    "ppo.n_epochs=2",
    "--hp",
    "rppo.n_epochs=2",
    "--agents",
    "ppo,rppo,stc,stc_lq,stc_kfmils,oracle,lqg",
    "--bootstrap-reps",
    "100",
    "--jobs",
    "1",
    "--no-progress",
]


def _rows(path):
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        return reader.fieldnames, list(reader)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = main(
            [
                "bench",
                *TINY,
                "--out",
                str(out),
                "--run",
                "tiny",
                "--tensorboard-log",
                str(out / "tb"),
            ]
        )
    assert rc == 0, err.getvalue()
    return out / "tiny", err.getvalue(), out / "tb"


def test_end_to_end_writes_every_file(tiny_run):
    run, log, tb = tiny_run
    names = {p.name for p in run.iterdir()}
    assert {"metrics.csv", "report.md", "config.json", "learning_curves.csv", "models"} <= names
    pngs = {n for n in names if n.endswith(".png")}
    assert {
        "data_efficiency.png",
        "theta_jump_timevarying2.png",
        "jump_cost_jump_timevarying2.png",
        "traces_nominal_stable2.png",
        "traces_family_nonminphase2.png",
    } <= pngs

    header, rows = _rows(run / "metrics.csv")
    assert header == METRIC_COLUMNS
    per = {}
    for r in rows:
        per.setdefault((r["scenario"], r["controller"]), []).append(r)
    scenarios = {
        "nominal:stable2",
        "family:lightly_damped2",
        "family:nonminphase2",
        "jump:timevarying2",
    }
    assert {s for s, _ in per} == scenarios
    for s in scenarios:
        for c in ("stc", "stc_lq", "stc_kfmils", "oracle", "lqg"):
            assert len(per[(s, c)]) == 2  # evaluation seeds
        assert len(per[(s, "ppo")]) == 4  # training seeds x evaluation seeds
        # the recurrent agent is trained on the family: held-out plants and the jump only
        assert len(per.get((s, "rppo"), [])) == (0 if s.startswith("nominal") else 4)
    for r in rows:
        assert float(r["cost"]) >= 0 and r["bounded"] in ("0", "1")
        assert r["steady_ratio"] != "" and r["steps_to_oracle"] != ""
        if r["kind"] == "jump":
            assert r["post_jump_ratio"] != "" and r["reconverge_steps"] != ""
        if r["controller"] == "oracle":
            assert float(r["steady_ratio"]) == 1.0 and float(r["steps_to_oracle"]) == 0.0
        if r["family"] == "rl":
            assert int(r["train_steps"]) >= 300 and float(r["train_wall_s"]) > 0
            assert int(r["data_steps"]) == int(r["train_steps"])
        elif r["controller"] in ("stc", "stc_lq", "stc_kfmils"):
            assert r["family"] == "adaptive"
            assert int(r["data_steps"]) == int(r["steps_run"])
            assert r["controller_seed"] == r["seed"]  # every episode its own controller seed

    header, curves = _rows(run / "learning_curves.csv")
    assert header == ["train_env", "algo", "train_seed", "steps", "cost", "cost_to_oracle"]
    keys = {(c["train_env"], c["algo"]) for c in curves}
    assert keys == {("nominal:stable2", "ppo"), ("family", "ppo"), ("family", "rppo")}

    config = json.loads((run / "config.json").read_text())
    assert config["bench"]["train_steps"] == {"ppo": 300, "rppo": 300}
    assert config["bench"]["algo_configs"]["ppo"]["hyperparams"]["n_steps"] == 64
    assert "versions" in config and config["argv"][0] == "bench"

    report = (run / "report.md").read_text()
    for section in ("## Headline", "## Conclusions", "## Step response", "## Learning curves"):
        assert section in report
    assert "P(stc cost lower)" in report and "re-converge steps" in report
    # the self-tuning LQ controller is reported against the RL agents, never counted as one
    assert "P(stc_lq cost lower)" in report and "self-tuning LQ (stc_lq) ends at" in report
    assert "stc_lq has the lower episode cost more often than not against" in report
    assert "the best RL agent (stc_lq)" not in report
    # and so is the self-tuning controller on the paper's KF-MILS estimator
    assert "P(stc_kfmils cost lower)" in report
    assert "self-tuning controller on the paper's KF-MILS estimator (stc_kfmils) ends at" in report
    assert "stc_kfmils has the lower episode cost more often than not against" in report
    assert "the best RL agent (stc_kfmils)" not in report
    assert "training seed, evaluation seed" in report  # what the intervals cover

    # how each RL agent's training ended, next to its figures: 300 steps are 3 evaluations
    # of the rule, one too few for a plateau, so every run reached its cap
    assert {r["train_stop"] for r in rows if r["family"] == "rl"} == {"cap"}
    assert all(int(r["train_cap"]) == 300 for r in rows if r["family"] == "rl")
    assert "RL training: stop (seeds); last > min. gain" in report
    assert "| ppo | 4 |" in report and "cap 2/2; last gain at" in report
    assert "has not improved on its best by more than 5 % in 3 consecutive" in report
    # no win over an RL agent without saying, in the same sentence, that it was still improving
    claims = [
        part
        for line in report.split("## Conclusions")[1].split("## Step response")[0].splitlines()
        for part in line.split("; ")
        if "more often than not against" in part
        and any(f" {a}" in part.split(", not against")[0] for a in ("ppo", "rppo"))
    ]
    assert claims and all("at the training cap before a plateau" in c for c in claims)

    # progress over the whole run, and the learning curve through SB3's logger
    assert "job 1/" in log and "ETA" in log
    events = list(tb.rglob("events.out.tfevents.*"))
    assert len(events) == 6  # one TensorBoard run per training job
    assert any(b"eval/curve_cost" in e.read_bytes() for e in events)


def test_saved_model_reloads_for_evaluation(tiny_run, capsys):
    model = tiny_run[0] / "models" / "nominal-stable2_ppo_s0"
    assert (model / "agent.json").is_file()
    assert main(["eval", str(model), "--seeds", "2", "--episode-steps", "50"]) == 0
    assert "ppo (seed 0" in capsys.readouterr().out


def test_eval_reproduces_the_bench_numbers_of_a_saved_agent(tiny_run, capsys):
    run = tiny_run[0]
    _, rows = _rows(run / "metrics.csv")
    bench = {
        r["seed"]: float(r["cost"])
        for r in rows
        if (r["scenario"], r["controller"], r["train_seed"]) == ("nominal:stable2", "ppo", "0")
    }
    assert len(bench) == 2
    model = run / "models" / "nominal-stable2_ppo_s0"
    assert main(["eval", str(model), "--seeds", "2", "--episode-steps", "120"]) == 0
    out = capsys.readouterr().out
    for seed, cost in bench.items():
        assert f"seed {seed}: cost {cost:.4g} " in out


def _sorted_numbers(path):
    key = lambda r: (r["scenario"], r["controller"], r["seed"], r["train_seed"])  # noqa: E731
    return sorted(_numbers(path), key=key)


def test_resume_reads_finished_jobs_back_and_trains_only_the_rest(tiny_run, tmp_path, monkeypatch):
    import shutil

    from stcgym.agents.rl import training

    source = tiny_run[0]
    run = tmp_path / "tiny"
    shutil.copytree(source, run)
    config = json.loads((run / "config.json").read_text())
    config["bench"]["tensorboard_log"] = str(tmp_path / "tb")  # keep the fixture's logs apart
    (run / "config.json").write_text(json.dumps(config))
    jobs = sorted((run / "jobs").glob("*.json"))
    assert len(jobs) == 6  # every RL training job kept its result
    jobs[0].unlink()  # as if the run had been killed before this job finished
    (run / "report.md").unlink()
    trained = []
    real = training.train_and_evaluate

    def counting(task):
        trained.append(task["name"])
        return real(task)

    monkeypatch.setattr(training, "train_and_evaluate", counting)
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main(["bench", "--resume", str(run), "--no-plots"]) == 0
    assert len(trained) == 1  # the finished jobs were not trained again
    assert "5 finished RL jobs read back" in err.getvalue()
    # the same table as the uninterrupted run (the retrained job reproduces its numbers)
    assert _sorted_numbers(run / "metrics.csv") == _sorted_numbers(source / "metrics.csv")
    assert (run / "report.md").is_file() and len(list((run / "jobs").glob("*.json"))) == 6
    assert len(list((tmp_path / "tb").rglob("events.out.tfevents.*"))) == 1
    resumed = json.loads((run / "config.json").read_text())
    assert resumed["argv"] == config["argv"] and resumed["resumed"][0][:2] == ["bench", "--resume"]
    # the report's wall time counts the first session too, not only the resumed one
    assert resumed["sessions"] == 2 and resumed["wall_s"] > config["wall_s"] > 0
    report = (run / "report.md").read_text()
    assert f"Wall time {resumed['wall_s']:.0f} s on " in report and "over 2 sessions" in report


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--seeds", "3"], "drop --seeds"),
        (["--standard"], "drop --standard"),
        (["--jobs", "0"], "--jobs must be a positive integer"),
    ],
)
def test_resume_takes_the_run_settings(tiny_run, tmp_path, capsys, extra, message):
    assert main(["bench", "--resume", str(tiny_run[0]), *extra]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err
    assert main(["bench", "--resume", str(tmp_path / "none")]) == 2
    assert "holds no config.json" in capsys.readouterr().err


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--plant", "bogus"], "catalogue plant"),
        (["--plant", "stable4"], "order-2"),
        (["--noise", "-1"], "--noise"),
        (["--seeds", "0"], "--seeds"),
        (["--first-seed", "-5"], "--first-seed"),
        (["--episode-steps", "3"], "--episode-steps"),
    ],
)
def test_eval_options_are_checked(tiny_run, capsys, extra, message):
    model = tiny_run[0] / "models" / "nominal-stable2_ppo_s0"
    assert main(["eval", str(model), *extra]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err


def _numbers(path):
    _, rows = _rows(path)
    timing = {"step_us", "train_wall_s"}
    return [{k: v for k, v in r.items() if k not in timing} for r in rows]


def test_identical_seeds_give_identical_numbers_in_process_and_in_the_pool(tmp_path):
    args = [
        *TINY,
        "--agents",
        "ppo,oracle",
        "--scenarios",
        "nominal",
        "--train-seeds",
        "2",
        "--out",
        str(tmp_path),
    ]
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main(["bench", *args, "--run", "a", "--no-plots"]) == 0
        # two workers train while the driver evaluates the classical controllers in a thread
        # and, at the end, draws the plots in a process of their own next to the report
        assert main(["bench", *args, "--run", "b", "--jobs", "2"]) == 0
    assert "plots written" in err.getvalue()
    assert (tmp_path / "b" / "traces_nominal_stable2.png").is_file()
    a, b = _numbers(tmp_path / "a" / "metrics.csv"), _numbers(tmp_path / "b" / "metrics.csv")
    assert len(a) == 2 + 2 * 2  # the oracle on 2 seeds, 2 agents on 2 seeds
    # the rows of the classical controllers (the oracle's: every ratio needs them) come first
    assert [r["controller"] for r in b][:2] == ["oracle", "oracle"]
    key = lambda r: (r["scenario"], r["controller"], r["seed"], r["train_seed"])  # noqa: E731
    assert sorted(a, key=key) == sorted(b, key=key)


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--plants", "stable2,nosuchplant"], "unknown plant"),
        (["--agents", "ppo,dqn"], "unknown agent"),
        (["--train-steps", "0"], "positive integer"),
        (["--train-steps", "ppo=100,sac=0"], "positive integer"),
        (["--seeds", "0"], "positive integer"),
        (["--first-seed", "-5"], "--first-seed"),
        (["--noise", "-1"], "--noise"),
        (["--hp", "ppo.no_such_knob=1"], "no_such_knob"),
        (["--hp", "sac.batch_size=0"], "batch_size"),
        (["--hp", "ppo.learning_rate=abc"], "learning_rate"),
        (["--hp", "ppo.learning_rate=-1"], "learning_rate"),
        (["--hp", "ppo.tensorboard_log=tb"], "--tensorboard-log"),
        (["--hp", "ppo.policy_kwargs.bogus=1"], "SB3 rejects"),
        (["--family-test", "stable2"], "held-out"),
        (["--jump", "stable2:stable4"], "same order"),
        # a jump is checked even when the jump scenario is not run
        (
            ["--scenarios", "nominal", "--agents", "stc", "--jump", "stable2:stable4"],
            "--jump 'stable2:stable4'",
        ),
        (["--scenarios", "nominal", "--agents", "stc", "--jump", "stable2:"], "BEFORE:AFTER"),
        (["--jump", "stable2:"], "BEFORE:AFTER"),
        (["--jump", ":stable2"], "BEFORE:AFTER"),
        (["--jump", "stable2:bogus"], "--jump 'stable2:bogus'"),
        (["--scenarios", "nominal,weird"], "scenarios"),
        (["--scenarios", "nominal", "--agents", "rppo,stc"], "family and jump"),
        (["--jobs", "0"], "--jobs"),
        (["--executor", "slurm"], "--executor"),
        # a stopping rule that cannot be met
        (["--train-steps", "99"], "below one evaluation interval"),
        (["--eval-interval", "400"], "below one evaluation interval"),
        (["--train-steps", "ppo=300,rppo=50"], "the rppo cap of 50 env steps is below"),
        (["--hp", "ppo.eval_interval=1000"], "ppo.eval_interval = 1000"),
        (["--hp", "ppo.eval_interval=0"], "ppo.eval_interval must be an integer >= 1"),
        (["--eval-interval", "0"], "--eval-interval"),
        (["--patience", "-1"], "--patience must be an integer >= 1"),
        (["--patience", "0"], "--patience must be an integer >= 1"),
        (["--min-train-fraction", "1.5"], "--min-train-fraction must be a number in [0, 1]"),
        (["--min-improvement", "1.5"], "--min-improvement must be a number in [0, 1)"),
        (["--min-improvement", "-0.05"], "--min-improvement"),
        (["--min-improvement", "nan"], "--min-improvement"),
    ],
)
def test_bad_input_fails_before_any_work(tmp_path, monkeypatch, capsys, extra, message):
    def no_work(*args, **kwargs):  # pragma: no cover - must not be reached
        raise AssertionError("work started")

    monkeypatch.setattr("stcgym.agents.rl.sb3.train_agent", no_work)
    monkeypatch.setattr(runner_mod, "evaluate", no_work)
    rc = main(["bench", *TINY, "--out", str(tmp_path), "--run", "bad", *extra])
    assert rc == 2
    err = capsys.readouterr().err
    assert err.startswith("stcgym bench: error:") and err.count("\n") == 1 and message in err
    assert not (tmp_path / "bad").exists()


def test_bare_bench_runs_the_quick_preset_that_help_describes(monkeypatch, capsys):
    seen = {}

    def fake_run(cfg, **kwargs):
        seen["cfg"] = cfg
        raise KeyboardInterrupt  # stop right there

    monkeypatch.setattr(benchmark, "run_bench", fake_run)
    assert main(["bench", "--out", "/nonexistent-never-written"]) == 130
    cfg = seen["cfg"]
    assert cfg.mode == "quick" and cfg.train_seeds >= 3
    assert cfg.agents == QUICK["agents"]
    with pytest.raises(SystemExit):
        main(["bench", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert f"quick default: {', '.join(QUICK['agents'])}" in help_text
    assert "estimate is printed first" in help_text  # --full announces its time
    # the stopping rule is stated in --help
    assert "has not improved on its best by more than 5 % in 3 consecutive" in help_text


def test_standard_tier_is_quick_with_zoo_caps_and_family_caps(monkeypatch):
    seen = {}

    def fake_run(cfg, **kwargs):
        seen["cfg"] = cfg
        raise KeyboardInterrupt

    monkeypatch.setattr(benchmark, "run_bench", fake_run)
    assert main(["bench", "--standard", "--out", "/nonexistent-never-written"]) == 130
    std, quick = seen["cfg"], build_config(run="q")
    assert std.mode == "standard"
    same = ("plants", "family_train", "family_test", "jumps", "agents", "seeds")
    for name in (*same, "train_seeds", "first_seed", "episode_steps"):
        assert getattr(std, name) == getattr(quick, name), name
    # quick measures its learning curves at fewer points, on one episode per plant
    assert (quick.curve_points, quick.curve_seeds) == (5, 1)
    assert (std.curve_points, std.curve_seeds) == (10, 2)
    assert std.scenarios == quick.scenarios == ["nominal", "family", "jump", "mimo"]
    # the RL Zoo's Pendulum-v1 n_timesteps as single-plant caps, 1e5-3e5 on the family
    assert std.train_steps == {"ppo": 100_000, "sac": 20_000, "rppo": 100_000}
    assert std.family_train_steps == {"ppo": 300_000, "sac": 100_000, "rppo": 100_000}
    assert (std.patience, std.min_improvement, std.min_train_fraction) == (3, 0.05, 0.25)
    # each cap is bigger than the quick one, and a whole number of evaluation intervals
    for algo, cap in std.train_steps.items():
        assert cap > quick.train_steps[algo]
    tasks = rl_tasks(std, make_scenarios(std), {}, {})
    assert {(t["train_key"], t["algo"]): t["steps"] for t in tasks} == {
        ("nominal:stable2", "ppo"): 100_000,
        ("nominal:stable2", "sac"): 20_000,
        ("mimo:quadruple_tank", "ppo"): 100_000,
        ("mimo:quadruple_tank", "sac"): 20_000,
        ("family", "ppo"): 300_000,
        ("family", "sac"): 100_000,
        ("family", "rppo"): 100_000,
    }
    rule = {"min_improvement": 0.05, "patience": 3, "min_fraction": 0.25}
    assert all(t["plateau"] == rule for t in tasks)
    # about an hour on 2 cores at the caps, the quick tier under its 10 minutes
    assert 45 * 60 <= benchmark.estimate_seconds(std) <= 75 * 60
    assert 6 * 60 <= benchmark.estimate_seconds(quick) <= 10 * 60


def test_stc_kfmils_is_stc_on_the_kf_mils_estimator_in_every_scenario(tmp_path):
    from stcgym.adaptive import SelfTuningController
    from stcgym.envs.catalogue import get_plant

    for agents in (QUICK["agents"], FULL["agents"], BenchConfig(run="x").agents):
        assert "stc_kfmils" in agents
    info = CONTROLLERS["stc_kfmils"]
    assert info.kind == "adaptive" and info.online
    cfg = build_config(
        quick=True,
        run="kf",
        out=str(tmp_path),
        scenarios="nominal,family,jump",  # stc_kfmils is SISO-only
        agents="stc,stc_lq,stc_kfmils,oracle,lqg",
        seeds=2,
        episode_steps=120,
        plots=False,
        bootstrap_reps=50,
    )
    for sc in make_scenarios(cfg):
        plant = get_plant(sc.plant)
        ctl = info.build(cfg, sc)(plant, 7)
        ref = CONTROLLERS["stc"].build(cfg, sc)(plant, 7)
        assert isinstance(ctl, SelfTuningController) and ctl.estimator == "KF-MILS"
        assert ref.estimator == "ELS"  # otherwise built as stc: same design, bound and seed
        assert (ctl.n, ctl.design, ctl.action_bound) == (ref.n, ref.design, ref.action_bound)
        assert list(ctl.seeds) == list(ref.seeds) == [7]
        assert list(ctl.poles) == list(ref.poles)

    runner_mod.run_bench(cfg, log=lambda msg: None)
    _, rows = _rows(tmp_path / "kf" / "metrics.csv")
    scenarios = {r["scenario"] for r in rows}
    assert len(scenarios) == 4
    for s in scenarios:
        ours = [r for r in rows if r["scenario"] == s and r["controller"] == "stc_kfmils"]
        assert len(ours) == 2 and all(r["family"] == "adaptive" for r in ours)
    report = (tmp_path / "kf" / "report.md").read_text()
    assert "| P(stc cost lower) | P(stc_lq cost lower) | P(stc_kfmils cost lower) |" in report
    assert "self-tuning controller on the paper's KF-MILS estimator (stc_kfmils) ends at" in report
    # no RL agent in this run: the classical controllers are not rivals, nor the best RL agent
    for name in ("stc_lq", "stc_kfmils"):
        assert f"{name} has the lower episode cost" not in report
    assert "the best RL agent" not in report


def test_unwritable_output_folder(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    rc = main(["bench", *TINY, "--agents", "oracle", "--out", str(blocker / "sub"), "--run", "x"])
    assert rc == 2 and "cannot be written" in capsys.readouterr().err


def test_existing_run_is_not_overwritten(tmp_path, capsys):
    args = ["bench", *TINY, "--agents", "oracle", "--no-plots", "--out", str(tmp_path)]
    assert main([*args, "--run", "r", "--scenarios", "nominal"]) == 0
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
    info = ControllerInfo("oracle", lambda cfg, sc: lambda plant, seed: _Exploding())
    monkeypatch.setitem(CONTROLLERS, "boom", info)
    _Exploding.episodes = 0
    cfg = build_config(
        quick=True,
        run="int",
        out=str(tmp_path),
        agents="oracle,boom",
        scenarios="nominal,family",
        seeds=2,
        episode_steps=50,
        plots=False,
        bootstrap_reps=50,
    )
    with pytest.raises(KeyboardInterrupt):
        runner_mod.run_bench(cfg, log=lambda msg: None)
    header, rows = _rows(tmp_path / "int" / "metrics.csv")
    assert header == METRIC_COLUMNS
    # Scenario 1: oracle and boom on 2 seeds; scenario 2: oracle, then boom blows up.
    assert [r["controller"] for r in rows] == ["oracle", "oracle", "boom", "boom"] + ["oracle"] * 2
    assert [r["scenario"] for r in rows] == ["nominal:stable2"] * 4 + ["family:lightly_damped2"] * 2
    assert all(r["cost"] for r in rows)
    assert "INTERRUPTED" in (tmp_path / "int" / "report.md").read_text()


def test_curve_evaluations_count_the_points_each_training_measured(tiny_run):
    run = tiny_run[0]
    cfg = BenchConfig.from_dict(json.loads((run / "config.json").read_text())["bench"])
    _, curves = _rows(run / "learning_curves.csv")
    measured = {}
    for r in curves:
        key = (r["train_env"], r["algo"], int(r["train_seed"]))
        measured[key] = measured.get(key, 0) + 1
    tasks = rl_tasks(cfg, make_scenarios(cfg), {}, {})
    assert {(t["train_key"], t["algo"], t["seed"]): curve_evaluations(t) for t in tasks} == measured


def test_schedule_gives_each_job_to_the_first_free_worker():
    # jobs in the order given: 5 -> A, 4 -> B, 3 -> B (B free first), 3 -> A, 3 -> B
    s = WORKER_START_SECONDS
    assert schedule([5, 4, 3, 3, 3], 2) == [s + 5 + 3, s + 4 + 3 + 3]
    assert schedule([7], 2) == [s + 7] and schedule([], 2) == []
    # longest first: the quick tier's RL jobs end within one short job of each other
    cfg = build_config(run="q")
    tasks = rl_tasks(cfg, make_scenarios(cfg), {}, {})
    weights = job_weights(cfg, [], tasks)
    cost = [weights[("rl", t["name"])] for t in tasks]
    assert cost == sorted(cost, reverse=True)
    busy = schedule(cost, 2)
    assert max(busy) - min(busy) <= min(cost)
