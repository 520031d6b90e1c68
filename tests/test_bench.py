"""End-to-end ``stcgym bench`` on a tiny budget, reproducibility, bad input, interruption."""

from __future__ import annotations

import contextlib
import csv
import io
import json
import re
import types

import numpy as np
import pytest

import stcgym.agents.benchmark as benchmark
from stcgym.agents.benchmark import METRIC_COLUMNS, BenchConfig, build_config, make_scenarios
from stcgym.agents.benchmark import runner as runner_mod
from stcgym.agents.benchmark.config import EVALUATIONS_PER_CAP
from stcgym.agents.benchmark.plan import (
    WORKER_START_SECONDS,
    curve_evaluations,
    job_weights,
    rl_tasks,
    schedule,
)
from stcgym.agents.benchmark.scenarios import training_envs
from stcgym.agents.benchmark.store import ResultsStore
from stcgym.agents.benchmark.tiers import FULL, QUICK
from stcgym.agents.cli import main
from stcgym.agents.controllers import CONTROLLERS, ControllerInfo

# A few hundred training steps, 2 runs, short episodes on a few test plants: the whole pipeline
# in seconds (the SISO scenarios; tests/test_bench_mimo.py runs the mimo one).
TINY = [
    "--scenarios",
    "nominal,family,ood,jump",
    "--train-steps",
    "300",
    "--eval-interval",
    "100",
    "--train-seeds",
    "2",
    "--test-plants",
    "4",
    "--nominal-episodes",
    "3",
    "--curve-episodes",
    "3",
    "--bound-plants",
    "10",
    "--episode-steps",
    "120",
    "--curve-points",
    "2",
    "--hp",
    "ppo.n_steps=64",
    "--hp",
    "ppo.n_envs=2",
    "--hp",
    "ppo.batch_size=64",
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
SCENARIOS = {
    "nominal:stable2": 3,
    "family:test": 4,
    "family:ood_near_zero": 4,
    "family:ood_order3": 4,
    "jump:test": 4,
}


def _rows(path):
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        return reader.fieldnames, list(reader)


def _in_process_config(tmp_path, run, **settings):
    """A quick-tier config small enough for ``runner_mod.run_bench`` in this process: 2 test
    plants per family split, 2 nominal episodes, 2 episodes per learning-curve point, 5 plants
    for the action bound, no plots, a small bootstrap; ``settings``: the scenarios, agents,
    episode length, ..."""
    small = dict(test_plants=2, nominal_episodes=2, bound_plants=5, curve_episodes=2)
    return build_config(
        quick=True, run=run, out=str(tmp_path), plots=False, bootstrap_reps=50, **small, **settings
    )


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
        "adaptation.png",
        "theta_jump_test.png",
        "traces_jump_test.png",
        "traces_nominal_stable2.png",
    } <= pngs

    header, rows = _rows(run / "metrics.csv")
    assert header == METRIC_COLUMNS
    per = {}
    for r in rows:
        per.setdefault((r["scenario"], r["controller"]), []).append(r)
    assert {s for s, _ in per} == set(SCENARIOS)
    for s, episodes in SCENARIOS.items():
        # every controller meets the same episodes: the same (plant, seed) pairs
        units = {(r["plant"], r["seed"]) for r in per[(s, "lqg")]}
        assert len(units) == episodes
        for c in ("stc", "stc_lq", "stc_kfmils", "oracle", "lqg", "zero", "ppo", "rppo"):
            if c == "rppo" and s.startswith("nominal"):
                assert (s, c) not in per  # the recurrent agent trains on the family only
                continue
            runs = 2 if c in ("stc", "stc_lq", "stc_kfmils", "ppo", "rppo") else 1
            assert len(per[(s, c)]) == runs * episodes, (s, c)
            assert {(r["plant"], r["seed"]) for r in per[(s, c)]} == units
            assert {r["run"] for r in per[(s, c)]} == {str(k) for k in range(runs)}
        for r in per[(s, "lqg")]:
            assert float(r["cost_ratio"]) == 1.0
            assert r["score"] == "" or float(r["score"]) == 1.0
        for r in per[(s, "zero")]:
            assert r["score"] == "" or float(r["score"]) == 0.0
    for r in rows:
        assert float(r["cost"]) >= 0 and r["bounded"] in ("0", "1")
        assert r["cost_ratio"] != ""
        if r["kind"] == "jump":  # the jump comes at a random time inside the episode
            assert 0 < int(r["jump_step"]) < 120 and r["post_jump_ratio"] != ""
        else:
            assert r["jump_step"] == "" and r["post_jump_ratio"] == ""
        if r["family"] == "rl":
            assert int(r["train_steps"]) >= 300 and float(r["train_wall_s"]) > 0
            assert int(r["data_steps"]) == int(r["train_steps"])
            if r["kind"] == "ood":  # the validation curve does not speak for another distribution
                assert r["steps_to_target"] == ""
        elif r["controller"] in ("stc", "stc_lq", "stc_kfmils"):
            assert r["family"] == "adaptive"
            assert int(r["data_steps"]) == int(float(r["steps_run"]))
            assert r["steps_to_target"] != ""
    # the same episode gives the same LQG cost in every scenario that holds it (family:test and
    # jump:test draw the same plants and seeds; only the jump differs)
    family = {(r["plant"], r["seed"]): r for r in per[("family:test", "lqg")]}
    jump = {(r["plant"], r["seed"]): r for r in per[("jump:test", "lqg")]}
    assert family.keys() == jump.keys()
    for key, r in jump.items():
        J = int(r["jump_step"])
        assert float(r["cost_start"]) == pytest.approx(float(family[key]["cost_start"])) or J < 12

    header, curves = _rows(run / "learning_curves.csv")
    assert header == ["train_env", "algo", "train_seed", "steps", "score"]
    keys = {(c["train_env"], c["algo"]) for c in curves}
    assert keys == {("nominal:stable2", "ppo"), ("family", "ppo"), ("family", "rppo")}

    config = json.loads((run / "config.json").read_text())
    bench = config["bench"]
    assert bench["train_steps"] == {"ppo": 300, "rppo": 300}
    assert bench["algo_configs"]["ppo"]["hyperparams"]["n_steps"] == 64
    assert set(bench["action_bounds"]) == {"nominal:stable2", "family"}
    assert set(bench["action_units"]) == {"nominal:stable2", "family"}
    assert "versions" in config and config["argv"][0] == "bench"
    # one action bound per training distribution, for every scenario that uses it
    for sc in config["scenarios"]:
        assert sc["env"]["action_bound"] == bench["action_bounds"][sc["train_env"]]

    report = (run / "report.md").read_text()
    for section in (
        "## Protocol",
        "## What each controller knows",
        "## Headline",
        "## Conclusions",
        "## RL training",
        "## Details per scenario",
    ):
        assert section in report
    assert "| self-tuning | RL agent | P(self-tuning cost lower) |" in report
    assert "Departures from the RL Zoo's settings" in report
    assert "fixed before the test split was drawn" in report
    assert "| ppo | 2 x 3 |" in report  # runs x episodes of nominal:stable2
    assert "has not improved on its best by more than 5 % in 3 consecutive" in report
    # every training run's kept checkpoint, as the training callback kept it (agent.json)
    training = report.split("## RL training")[1].split("Departures")[0]
    header = "| kept step | updates: approx KL, clip fraction, explained variance, entropy |"
    assert header in training
    for meta_file in (run / "models").glob("*/agent.json"):
        meta = json.loads(meta_file.read_text())
        suffix = f"_{meta['algo']}_s{meta['seed']}"
        key = meta_file.parent.name.removesuffix(suffix).replace("-", ":")
        kept = int(meta["best_step"])
        row = next(line for line in training.splitlines()
                   if line.startswith(f"| {key} | {meta['algo']} | {meta['seed']} |"))  # fmt: skip
        assert row.split(" | ")[7] == (f"{kept / 1000:.3g}k" if kept >= 1000 else str(kept))
        if kept == 0:
            assert f"{meta['algo']} on {key} (run" in training
    # 300 steps are 3 evaluations of the rule, one too few for a plateau: every run reached its
    # cap, and a conclusion that names an RL agent says so
    assert {r["train_stop"] for r in rows if r["family"] == "rl"} == {"cap"}
    conclusions = report.split("## Conclusions")[1].split("## RL training")[0]
    for line in conclusions.splitlines():
        if "lower cost more often than" in line or "neither" in line:
            # every run the estimates count (runs kept at step 0 are left out of them)
            assert re.search(r"reached its training cap before a plateau in (\d)/\1 runs", line)

    # progress over the whole run, and the learning curve through SB3's logger
    assert "job 1/" in log and "ETA" in log and "action bound of family" in log
    events = list(tb.rglob("events.out.tfevents.*"))
    assert len(events) == 6  # one TensorBoard run per training job
    assert any(b"eval/curve_score" in e.read_bytes() for e in events)


def test_action_bound_is_the_lqg_input_range_on_training_episodes(tiny_run):
    from stcgym.agents.benchmark.scenarios import training_envs
    from stcgym.agents.evaluation.bounds import lqg_action_bound, lqg_inputs, round_up

    run = tiny_run[0]
    cfg = BenchConfig.from_dict(json.loads((run / "config.json").read_text())["bench"])
    for key, env in training_envs(cfg, make_scenarios(cfg)).items():
        bound, peaks = lqg_action_bound(env.train, env.bound_episodes)
        assert bound == cfg.action_bounds[key] == round_up(1.5 * np.quantile(peaks, 0.99))
        assert len(peaks) == 10 and env.train.action_bound == bound == env.curve.action_bound
        # the Gaussian agents' action unit: LQG's input on all but 1 % of the steps
        inputs = lqg_inputs(env.train, env.bound_episodes)
        assert np.array_equal(inputs.max(axis=(1, 2)), peaks)
        assert cfg.action_units[key] == round_up(float(np.quantile(inputs, 0.99))) < bound


def test_gaussian_agents_act_in_the_measured_unit_with_the_whole_bound(tiny_run):
    from stcgym.agents.benchmark.plan import agent_config
    from stcgym.agents.rl.sb3 import load_agent

    run = tiny_run[0]
    cfg = BenchConfig.from_dict(json.loads((run / "config.json").read_text())["bench"])
    meta = json.loads((run / "models" / "family_ppo_s0" / "agent.json").read_text())
    unit = cfg.action_units["family"]
    assert meta["config"]["interface"]["action_unit"] == unit
    assert agent_config(cfg, "ppo", "family").interface["action_unit"] == unit
    agent = load_agent(run / "models" / "family_ppo_s0")
    box = agent.policy.model.action_space
    assert np.allclose(box.high, cfg.action_bounds["family"] / unit) and np.allclose(
        box.low, -box.high
    )


def test_saved_model_reloads_for_evaluation(tiny_run, capsys):
    model = tiny_run[0] / "models" / "nominal-stable2_ppo_s0"
    assert (model / "agent.json").is_file()
    meta = json.loads((model / "agent.json").read_text())
    assert len(meta["obs_norm"]["mean"]) == meta["config"]["window"].get("window", 10) * 4 + 1
    assert main(["eval", str(model), "--seeds", "2", "--episode-steps", "50"]) == 0
    assert "ppo (seed 0" in capsys.readouterr().out
    family = tiny_run[0] / "models" / "family_rppo_s1"
    assert main(["eval", str(family), "--seeds", "2", "--episode-steps", "50"]) == 0
    assert "on siso2-v1 test" in capsys.readouterr().out


def test_eval_reproduces_the_bench_numbers_of_a_saved_agent(tiny_run, capsys):
    run = tiny_run[0]
    _, rows = _rows(run / "metrics.csv")
    bench = {
        r["seed"]: float(r["cost"])
        for r in rows
        if (r["scenario"], r["controller"], r["run"]) == ("nominal:stable2", "ppo", "0")
    }
    assert len(bench) == 3
    model = run / "models" / "nominal-stable2_ppo_s0"
    assert main(["eval", str(model), "--seeds", "3", "--episode-steps", "120"]) == 0
    out = capsys.readouterr().out
    for seed, cost in bench.items():
        assert f"seed {seed}: cost {cost:.4g}" in out


def _classical_runs(path):
    """The (scenario, controller, run) triples of the classical rows of a metrics.csv."""
    _, rows = _rows(path)
    classical = (r for r in rows if r["controller"] in CONTROLLERS)
    return {(r["scenario"], r["controller"], r["run"]) for r in classical}


def _rl_records(store):
    """The RL jobs' record files of a store (a classical record's label names its run)."""
    return sorted(p for p in store.glob("*.json.gz") if ".run" not in p.name)


def _sorted_numbers(path):
    key = lambda r: (r["scenario"], r["controller"], r["seed"], r["run"])  # noqa: E731
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
    store = run / "store"
    rl_records = _rl_records(store)
    assert len(rl_records) == 6  # every RL training job kept its record
    rl_records[0].unlink()  # as if the run had been killed before this job finished
    kept = [
        p for p in store.glob("*.run*.json.gz")
        if ".lqg.run" not in p.name and ".zero.run" not in p.name
    ]  # fmt: skip
    assert len(kept) == sum(1 for _ in _classical_runs(source / "metrics.csv")) - 2 * len(SCENARIOS)
    kept[0].unlink()  # nor had this classical evaluation
    # the store alone: no trained model nor per-step cost array is needed to resume
    shutil.rmtree(run / "models")
    shutil.rmtree(run / "jobs", ignore_errors=True)
    (run / "report.md").unlink()
    trained, evaluated = [], []
    real = training.train_and_evaluate
    real_evaluate = runner_mod._RunState._evaluate

    def counting(task):
        trained.append(task.name)
        return real(task)

    def counting_evaluations(self, sc, name, run):
        if name not in ("lqg", "zero"):  # the yardstick and zero input are always evaluated
            evaluated.append((sc.name, name, run))
        return real_evaluate(self, sc, name, run)

    monkeypatch.setattr(training, "train_and_evaluate", counting)
    monkeypatch.setattr(runner_mod._RunState, "_evaluate", counting_evaluations)
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main(["bench", "--resume", str(run), "--no-plots"]) == 0
    assert len(trained) == 1  # the finished jobs were not trained again
    assert "5 finished RL jobs read back" in err.getvalue()
    assert len(evaluated) == 1  # nor the classical evaluations but the one removed
    assert f"{len(kept) - 1} classical evaluations read back" in err.getvalue()
    assert "action bound of" not in err.getvalue()  # the bounds were read back, not measured
    # the same table as the uninterrupted run (the retrained job reproduces its numbers)
    assert _sorted_numbers(run / "metrics.csv") == _sorted_numbers(source / "metrics.csv")
    assert (run / "report.md").is_file() and len(_rl_records(store)) == 6
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
        (["--test-plants", "3"], "drop --test-plants"),
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
    for name in ("nominal-stable2_ppo_s0", "family_ppo_s0"):
        assert main(["eval", str(tiny_run[0] / "models" / name), *extra]) == 2
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
        "ppo,stc",
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
    # lqg and zero (1 run), stc and ppo (2 runs each), on 3 episodes
    assert len(a) == (1 + 1 + 2 + 2) * 3
    # the rows of the yardstick and of zero input (every ratio and score needs them) come first
    assert [r["controller"] for r in b][:6] == ["lqg"] * 3 + ["zero"] * 3
    key = lambda r: (r["scenario"], r["controller"], r["seed"], r["run"])  # noqa: E731
    assert sorted(a, key=key) == sorted(b, key=key)


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--plants", "stable2,nosuchplant"], "unknown plant"),
        (["--plants", "timevarying2"], "time-invariant"),
        (["--agents", "ppo,dqn"], "unknown agent"),
        (["--train-steps", "0"], "positive integer"),
        (["--train-steps", "ppo=100,sac=0"], "positive integer"),
        (["--test-plants", "0"], "positive integer"),
        (["--curve-episodes", "0"], "positive integer"),
        (["--first-seed", "-5"], "--first-seed"),
        (["--noise", "-1"], "--noise"),
        (["--family", "no-such-family"], "--family"),
        (["--ood", "ood_nope"], "unknown --ood variant"),
        (["--hp", "ppo.no_such_knob=1"], "no_such_knob"),
        (["--hp", "sac.batch_size=0"], "batch_size"),
        (["--hp", "ppo.learning_rate=abc"], "learning_rate"),
        (["--hp", "ppo.learning_rate=-1"], "learning_rate"),
        (["--hp", "ppo.tensorboard_log=tb"], "--tensorboard-log"),
        (["--hp", "ppo.policy_kwargs.bogus=1"], "SB3 rejects"),
        (["--scenarios", "nominal,weird"], "scenarios"),
        (["--scenarios", "nominal", "--agents", "rppo,stc"], "family, ood or jump"),
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
    monkeypatch.setattr(runner_mod, "run_episodes", no_work)
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


def test_standard_tier_meets_the_protocol(monkeypatch):
    seen = {}

    def fake_run(cfg, **kwargs):
        seen["cfg"] = cfg
        raise KeyboardInterrupt

    monkeypatch.setattr(benchmark, "run_bench", fake_run)
    assert main(["bench", "--standard", "--out", "/nonexistent-never-written"]) == 130
    std, quick = seen["cfg"], build_config(run="q")
    assert std.mode == "standard"
    for name in ("plants", "family", "first_seed", "episode_steps"):
        assert getattr(std, name) == getattr(quick, name), name
    assert set(quick.agents) <= set(std.agents)  # and the informed RL agents
    # the quick scenarios, the difficulty ladder, the quadruple tank's valve switch and its
    # family of valve settings
    assert quick.scenarios == ["nominal", "family", "ood", "jump", "mimo"]
    assert std.scenarios == [*quick.scenarios[:4], "ladder", "mimo", "mimo_switch", "mimo_family"]
    # every rung of the ladder: its first three, and the family's plants are the last one's
    from stcgym.envs.families import LADDER

    assert [*std.ladder, "ladder-l4-v1"] == list(LADDER) and std.family == "siso2-v1"
    assert {"ppo", "oracle_ppo"} <= set(std.ladder_agents) and "fixed_pi" in std.agents
    # the same small Optuna budget for PPO and the self-tuning controller
    assert std.tune_trials >= 10 and std.tuned_rl_agents == ["ppo"] and "stc_tuned" in std.agents
    # at least 5 training runs, every plant of the test split (200), every held-out variant
    scenarios = make_scenarios(std)
    assert std.train_seeds >= 5 and std.test_plants is None
    from stcgym.envs.families import get_family

    family = get_family(std.family)
    assert set(std.ood) == set(family.variant_names)
    test = next(sc for sc in scenarios if sc.name == "family:test")
    assert len(test.episodes.seeds) >= 200 and test.episodes.units == (200, 1)
    # PPO and RecurrentPPO get at least 1e6 env steps on the family; SAC what fits
    assert std.family_train_steps["ppo"] >= 1_000_000
    assert std.family_train_steps["rppo"] >= 1_000_000
    assert std.family_train_steps["sac"] >= 100_000
    tasks = rl_tasks(std, scenarios, training_envs(std, scenarios), {})
    # outside the quick tier at most 20 evaluations of the plateau rule per cap
    for t in tasks:
        assert t.steps // t.eval_interval <= EVALUATIONS_PER_CAP
        assert t.plateau.to_dict() == {"min_improvement": 0.05, "patience": 3, "min_fraction": 0.5}
        assert len(t.curve_episodes.seeds) >= 20
    # within 2 h 30 min on 2 cores at the caps, the quick tier a few minutes
    assert 3600 <= benchmark.estimate_seconds(std) <= 2.5 * 3600
    assert 2 * 60 <= benchmark.estimate_seconds(quick) <= 10 * 60  # measured: 1 min 53 s


def test_stc_kfmils_is_stc_on_the_kf_mils_estimator_in_every_scenario(tmp_path):
    from stcgym.adaptive import SelfTuningController

    for agents in (QUICK["agents"], FULL["agents"], BenchConfig(run="x").agents):
        assert "stc_kfmils" in agents
    info = CONTROLLERS["stc_kfmils"]
    assert info.kind == "adaptive" and info.online and info.seeded
    cfg = _in_process_config(
        tmp_path,
        "kf",
        scenarios="nominal,family,ood,jump",  # stc_kfmils is SISO-only
        agents="stc,stc_lq,stc_kfmils,oracle,lqg",
        episode_steps=120,
    )
    for sc in make_scenarios(cfg):
        plants = [object(), object()]
        ctl = info.build(cfg, sc)(plants, [7, 8])
        ref = CONTROLLERS["stc"].build(cfg, sc)(plants, [7, 8])
        assert isinstance(ctl, SelfTuningController) and ctl.estimator == "KF-MILS"
        assert ref.estimator == "ELS"  # otherwise built as stc: same design, bound and seed
        assert (ctl.n, ctl.design, ctl.action_bound) == (ref.n, ref.design, ref.action_bound)
        assert ctl.n == 2  # the training distribution's order, on the order-3 variant too
        assert list(ctl.seeds) == list(ref.seeds) == [7, 8]
        assert list(ctl.poles) == list(ref.poles)

    runner_mod.run_bench(cfg, log=lambda msg: None)
    _, rows = _rows(tmp_path / "kf" / "metrics.csv")
    scenarios = {r["scenario"] for r in rows}
    assert len(scenarios) == 5
    for s in scenarios:
        ours = [r for r in rows if r["scenario"] == s and r["controller"] == "stc_kfmils"]
        assert len(ours) == 3 * 2 and all(r["family"] == "adaptive" for r in ours)
    report = (tmp_path / "kf" / "report.md").read_text()
    # no RL agent in this run: no paired comparison, no RL verdict
    assert "P(self-tuning cost lower)" not in report and "more often than" not in report


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
    """A controller that fails on its second run."""

    runs = 0

    def __init__(self, num_envs: int) -> None:
        self.num_envs = num_envs

    def reset(self):
        type(self).runs += 1
        if type(self).runs == 2:
            raise KeyboardInterrupt

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        return np.zeros((self.num_envs, 1)), state


def test_interrupted_run_keeps_finished_rows(tmp_path, monkeypatch):
    build = lambda cfg, sc: lambda plants, seeds: _Exploding(len(plants))  # noqa: E731
    monkeypatch.setitem(CONTROLLERS, "boom", ControllerInfo("oracle", build))
    _Exploding.runs = 0
    cfg = _in_process_config(
        tmp_path, "int", scenarios="nominal,family", agents="oracle,boom", episode_steps=50
    )
    with pytest.raises(KeyboardInterrupt):
        runner_mod.run_bench(cfg, log=lambda msg: None)
    header, rows = _rows(tmp_path / "int" / "metrics.csv")
    assert header == METRIC_COLUMNS
    # the records finished before boom blew up on the family, scenario by scenario: lqg and
    # zero on both, oracle and boom on nominal, oracle on the family
    order = [(r["scenario"], r["controller"]) for r in rows][::2]
    assert order == [
        ("nominal:stable2", "lqg"),
        ("nominal:stable2", "zero"),
        ("nominal:stable2", "oracle"),
        ("nominal:stable2", "boom"),
        ("family:test", "lqg"),
        ("family:test", "zero"),
        ("family:test", "oracle"),
    ]
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
    scenarios = make_scenarios(cfg)
    tasks = rl_tasks(cfg, scenarios, training_envs(cfg, scenarios), {})
    assert {(t.train_key, t.algo, t.seed): curve_evaluations(t) for t in tasks} == measured


def test_schedule_gives_each_job_to_the_first_free_worker():
    # jobs in the order given: 5 -> A, 4 -> B, 3 -> B (B free first), 3 -> A, 3 -> B
    s = WORKER_START_SECONDS
    assert schedule([5, 4, 3, 3, 3], 2) == [s + 5 + 3, s + 4 + 3 + 3]
    assert schedule([7], 2) == [s + 7] and schedule([], 2) == []
    # longest first: the quick tier's RL jobs end within one short job of each other
    cfg = build_config(run="q")
    scenarios = make_scenarios(cfg)
    tasks = rl_tasks(cfg, scenarios, training_envs(cfg, scenarios), {})
    weights = job_weights(cfg, [], tasks)
    cost = [weights[("rl", t.name)] for t in tasks]
    assert cost == sorted(cost, reverse=True)
    busy = schedule(cost, 2)
    assert max(busy) - min(busy) <= min(cost)


def test_a_study_starts_at_the_default_recipe_and_fails_trials_with_unhealthy_updates(
    monkeypatch,
):
    import optuna

    from stcgym.agents.benchmark import tuning
    from stcgym.agents.rl import sb3
    from stcgym.agents.rl.configs import default_config

    for algo in ("ppo", "sac", "rppo"):  # the first trial is the default recipe, exactly
        config = default_config(algo)
        trial = optuna.trial.FixedTrial(tuning.default_params(config, algo))
        tried = tuning.apply_rl_params(config, tuning.sample_rl(trial, algo))
        if algo == "sac":  # SB3's default tau, now written out
            assert tried.hyperparams.pop("tau") == 0.005
        assert tried == config

    def fake_training(algo, config, *args, **kw):
        lr = config.hyperparams["learning_rate"]
        # a larger step scores better early, and beyond 5e-4 its updates are too large
        kl = 0.02 if lr <= 5e-4 else 0.3
        updates = [{"approx_kl": kl, "clip_fraction": 0.15}] * 4
        return types.SimpleNamespace(curve=[(0, 20.0), (1, 1e-3 / lr)], updates=updates)

    monkeypatch.setattr(sb3, "train_agent", fake_training)
    task = tuning.TuningTask("ppo", default_config("ppo"), None, None, None, (), 8, 100)
    out = tuning.tune_rl(task)
    assert out["trials"][0] == pytest.approx(1e-3 / 3e-4)  # the defaults, tried first
    assert tuning.FAILED in out["trials"]  # some trials went beyond 5e-4 and failed
    assert out["params"]["hyperparams"]["learning_rate"] <= 5e-4
    assert out["best_value"] == min(out["trials"])


def test_tuning_gives_rl_and_the_self_tuning_controller_one_budget(tmp_path, monkeypatch):
    from stcgym.agents.benchmark import tuning

    def small(trial, algo):  # a tiny search space: the tiny run's rollouts stay short
        lr = trial.suggest_float("learning_rate", 1e-4, 1e-3, log=True)
        return {"hyperparams": {"learning_rate": lr, "n_steps": 64}, "net_width": 16}

    monkeypatch.setattr(tuning, "sample_rl", small)
    args = ["--scenarios", "family", "--agents", "ppo,stc_tuned", "--tune-trials", "2"]
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = main(["bench", *TINY, *args, "--no-plots", "--out", str(tmp_path), "--run", "t"])
    assert rc == 0, err.getvalue()
    bench = json.loads((tmp_path / "t" / "config.json").read_text())["bench"]
    tuned = bench["tuned"]
    assert set(tuned) == {"ppo", "stc"}
    for study in tuned.values():  # the same budget: trials on the validation episodes
        assert len(study["trials"]) == 2 and study["best_value"] == min(study["trials"])
    best = tuned["ppo"]["best_params"]["learning_rate"]
    assert bench["algo_configs"]["ppo"]["hyperparams"]["learning_rate"] == best
    assert bench["algo_configs"]["ppo"]["hyperparams"]["policy_kwargs"]["net_arch"] == [16, 16]
    _, rows = _rows(tmp_path / "t" / "metrics.csv")
    ours = [r for r in rows if r["controller"] == "stc_tuned"]
    assert len(ours) == 2 * 4 and {r["family"] for r in ours} == {"adaptive"}
    assert "## Tuning" in (tmp_path / "t" / "report.md").read_text()


def test_tuned_settings_build_valid_agents_and_controllers():
    import optuna

    from stcgym.adaptive import SelfTuningController
    from stcgym.agents.benchmark.tuning import apply_rl_params, sample_rl, sample_stc, stc_options
    from stcgym.agents.rl.configs import default_config, validate_config

    for k in range(5):
        trial = optuna.trial.FixedTrial(
            {"learning_rate": 3e-4, "gamma": 0.99, "net_width": 128, "n_steps": [256, 512][k % 2],
             "gae_lambda": 0.9, "batch_size": 128, "tau": 0.01, "lstm_hidden_size": 64,
             "pole": 0.3, "forgetting": 0.99, "probe_amplitude": 0.2, "change_threshold": 4.0,
             "measurement_noise": 5.0}
        )  # fmt: skip
        for algo in ("ppo", "sac", "rppo"):
            config = apply_rl_params(default_config(algo), sample_rl(trial, algo))
            validate_config(config)
            rollout = config.hyperparams.get("n_steps", 1) * config.n_envs
            assert config.eval_interval % rollout == 0
            # the PPO agents keep the ablation's network; the others take the sampled width
            net = config.hyperparams["policy_kwargs"]["net_arch"]
            default = default_config(algo).hyperparams["policy_kwargs"]["net_arch"]
            assert (
                net == {"ppo": default, "sac": [128, 128], "rppo": {"pi": [128], "vf": [128]}}[algo]
            )
        ctl = SelfTuningController(2, **stc_options(sample_stc(trial)))
        assert list(ctl.poles) == [0.3] * 3


def test_a_time_limit_leaves_jobs_for_resume_and_the_resumed_run_is_complete(
    tiny_run, tmp_path, monkeypatch
):
    """A job estimated longer than the time left does not start; the partial report says so;
    ``--resume`` runs it and the table equals the uninterrupted run's."""
    real_weights = runner_mod.job_weights
    long_job = "family_rppo_s1"

    def weights(cfg, scenarios, tasks):
        out = real_weights(cfg, scenarios, tasks)
        if ("rl", long_job) in out:
            out[("rl", long_job)] = 1e6  # far longer than the limit below
        return out

    monkeypatch.setattr(runner_mod, "job_weights", weights)
    args = ["bench", *TINY, "--out", str(tmp_path), "--run", "tiny", "--no-plots"]
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main([*args, "--time-limit", "2h"]) == 0
    run = tmp_path / "tiny"
    log = err.getvalue()
    assert "time limit: stopped after" in log and f"1 RL job ({long_job})" in log
    assert f"stcgym bench --resume {run}" in log
    report = (run / "report.md").read_text()
    assert f"**PARTIAL: jobs left to run (1 of the plan's jobs: {long_job})" in report
    assert len(_rl_records(run / "store")) == 5  # the other RL jobs are kept
    assert not list(run.glob("*.png"))
    monkeypatch.setattr(runner_mod, "job_weights", real_weights)
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main(["bench", "--resume", str(run), "--no-plots", "--time-limit", "2h"]) == 0
    assert "5 finished RL jobs read back" in err.getvalue()
    assert "time limit" not in err.getvalue()
    assert "PARTIAL" not in (run / "report.md").read_text()
    assert _sorted_numbers(run / "metrics.csv") == _sorted_numbers(tiny_run[0] / "metrics.csv")


@pytest.mark.parametrize("limit", ["0", "2x", "-1h", "inf"])
def test_a_bad_time_limit_is_refused_before_any_work(tmp_path, capsys, limit):
    out = tmp_path / "out"
    assert main(["bench", *TINY, "--out", str(out), f"--time-limit={limit}"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--time-limit must be a positive duration" in err
    assert not out.exists()


def test_a_resume_reads_kept_classical_evaluations_back_whatever_the_time_limit(
    tiny_run, tmp_path, monkeypatch
):
    """Reading a kept evaluation back costs no time: a resumed session whose limit admits no
    new evaluation still reports every kept one (here each is estimated at 10^6 s)."""
    import shutil

    source = tiny_run[0]
    run = tmp_path / "tiny"
    shutil.copytree(source, run)
    (run / "report.md").unlink()
    kept = [
        p for p in (run / "store").glob("*.run*.json.gz")
        if ".lqg.run" not in p.name and ".zero.run" not in p.name
    ]  # fmt: skip
    monkeypatch.setattr(runner_mod, "classical_seconds", lambda *args: 1e6)
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main(["bench", "--resume", str(run), "--no-plots", "--time-limit", "1m"]) == 0
    assert f"{len(kept)} classical evaluations read back" in err.getvalue()
    assert "time limit" not in err.getvalue()  # nothing was left for another session
    assert "PARTIAL" not in (run / "report.md").read_text()
    assert _sorted_numbers(run / "metrics.csv") == _sorted_numbers(source / "metrics.csv")


def test_report_renders_the_same_files_from_the_store_alone(tiny_run, tmp_path, capsys):
    """``stcgym report`` rebuilds the run's report, tables and statistics from config.json and
    the store, with the trained models and every rendered file gone (a store committed to a
    repository): byte for byte what the run itself rendered."""
    import shutil

    source = tiny_run[0]
    run = tmp_path / "tiny"
    shutil.copytree(source, run)
    rendered = ("metrics.csv", "learning_curves.csv", "statistics.json", "report.md")
    shutil.rmtree(run / "models")
    shutil.rmtree(run / "jobs", ignore_errors=True)
    for name in rendered:
        (run / name).unlink()
    for png in run.glob("*.png"):
        png.unlink()
    assert sorted(p.name for p in run.iterdir()) == ["config.json", "store"]
    assert main(["report", str(run)]) == 0
    assert capsys.readouterr().out.strip() == str(run / "report.md")
    for name in rendered:
        assert (run / name).read_bytes() == (source / name).read_bytes(), name
    assert {p.name for p in run.glob("*.png")} == {p.name for p in source.glob("*.png")}
    stats = json.loads((run / "statistics.json").read_text())
    assert set(stats) == set(SCENARIOS) and "ratio_median" in stats["family:test"]["stc"]
    # the store is data: gzip-compressed JSON, no per-step arrays, no pickles
    assert all(p.name.endswith(".json.gz") for p in (run / "store").iterdir())


def test_plan_prints_the_jobs_and_the_estimate_and_runs_nothing(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["bench", *TINY, "--out", str(out), "--run", "p", "--plan"]) == 0
    text = capsys.readouterr().out
    assert "family_ppo_s0: cap" in text and "nominal:stable2 (3 episodes)" in text
    assert "estimated wall time on 1 worker(s), from an empty store:" in text
    assert not out.exists()  # nothing written


def test_a_resumed_plan_estimates_only_what_the_store_lacks(tiny_run, tmp_path, capsys):
    import shutil

    from stcgym.agents.benchmark.plan import estimate_seconds, job_weights, rl_tasks
    from stcgym.agents.benchmark.rundir import read_run_config
    from stcgym.agents.benchmark.scenarios import make_scenarios, training_envs
    from stcgym.agents.benchmark.store import ResultsStore

    run = tmp_path / "tiny"
    shutil.copytree(tiny_run[0], run)
    (removed,) = [p for p in (run / "store").glob("family_rppo_s1.*.json.gz")]
    removed.unlink()
    assert main(["bench", "--resume", str(run), "--plan"]) == 0
    text = capsys.readouterr().out
    assert "still to run, the store holding the rest: 1 of the 6 RL jobs, estimated" in text
    cfg, _ = read_run_config(run)
    kept = frozenset(ResultsStore(run / "store", []).ids())
    scenarios = make_scenarios(cfg)
    tasks = rl_tasks(cfg, scenarios, training_envs(cfg, scenarios), {})
    weights = job_weights(cfg, scenarios, tasks)
    left, whole = estimate_seconds(cfg, kept), estimate_seconds(cfg)
    # the one job left and what runs whatever the store holds (references, output), not more
    assert weights[("rl", "family_rppo_s1")] < left < whole - weights[("rl", "family_ppo_s0")]


def test_a_partial_store_renders_a_partial_report_that_names_the_missing_jobs(
    tiny_run, tmp_path, capsys
):
    import shutil

    run = tmp_path / "tiny"
    shutil.copytree(tiny_run[0], run)
    (removed,) = [p for p in (run / "store").glob("family_rppo_s1.*.json.gz")]
    removed.unlink()
    assert main(["report", str(run), "--no-plots"]) == 0
    assert "1 of the plan's jobs have no record yet" in capsys.readouterr().err
    report = (run / "report.md").read_text()
    assert "**PARTIAL: jobs left to run (1 of the plan's jobs: family_rppo_s1)" in report
    rows = _numbers(run / "metrics.csv")
    assert not [r for r in rows if r["controller"] == "rppo" and r["run"] == "1"]


def test_the_smoke_preset_is_one_short_run_of_every_stage():
    cfg = build_config(mode="smoke", run="s")
    assert cfg.train_seeds == 1 and cfg.scenarios == ["nominal", "family"]
    assert cfg.rl_agents == ["ppo"] and {"stc", "lqg", "zero"} <= set(cfg.agents)
    interval = cfg.algo_configs["ppo"]["eval_interval"]
    assert cfg.family_train_steps["ppo"] == cfg.train_steps["ppo"] == interval
    assert cfg.eval_interval_for("ppo", "family") == interval
    assert [sc.name for sc in make_scenarios(cfg)] == ["nominal:stable2", "family:test"]


def test_an_output_path_that_is_a_file_is_refused_before_the_estimate(tmp_path, capsys):
    out = tmp_path / "taken"
    out.write_text("not a folder")
    assert main(["bench", *TINY, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"--out {out} is a file; a folder is expected" in err
    assert "estimated" not in err


def test_report_writes_the_headline_tables_into_a_page_between_its_markers(
    tiny_run, tmp_path, capsys
):
    import shutil

    from stcgym.agents.benchmark.render import PAGE_END, PAGE_START

    run = tmp_path / "tiny"
    shutil.copytree(tiny_run[0], run)
    page = tmp_path / "page.md"
    start, end = PAGE_START.format(run="tiny"), PAGE_END.format(run="tiny")
    page.write_text(f"# Results\n\nbefore\n\n{start}\nstale\n{end}\n\nafter\n")
    assert main(["report", str(run), "--no-plots", "--page", str(page)]) == 0
    assert "tables updated" in capsys.readouterr().err
    text = page.read_text()
    assert text.startswith("# Results\n\nbefore\n\n") and text.endswith("\n\nafter\n")
    assert "stale" not in text
    stats = json.loads((run / "statistics.json").read_text())
    stc = stats["family:test"]["stc"]
    ratio = stc["ratio"]
    cell = f"{ratio['value']:.3g} [{ratio['low']:.3g}, {ratio['high']:.3g}]"
    assert f"| `stc` | {stc['runs']} | {cell} |" in text
    assert main(["report", str(run), "--no-plots", "--page", str(page)]) == 0
    assert "tables unchanged" in capsys.readouterr().err
    page.write_text("no markers\n")
    assert main(["report", str(run), "--no-plots", "--page", str(page)]) == 2
    assert "has no block for tiny" in capsys.readouterr().err


@pytest.mark.parametrize(
    "args, flag",
    [
        (
            ["--scenarios", "nominal", "--agents", "ppo,stc", "--train-steps", "4096"],
            "--train-steps",
        ),
        (["--agents", "ppo,nope"], "unknown agent(s) ['nope']"),
        (["--scenarios", "nominal,bogus"], "scenarios must be"),
        (["--plants", "nope"], "--plants"),
        (["--mimo-plants", "nope"], "--mimo-plants"),
        (["--ood", "nope"], "--ood"),
        (["--family", "nope"], "--family"),
        (["--jobs", "0"], "--jobs"),
        (["--test-plants", "0"], "--test-plants"),
        (["--executor", "slurm"], "--executor"),
        (["--time-limit", "2x"], "--time-limit"),
        (["--first-seed", "-1"], "--first-seed"),
    ],
)
def test_common_mistakes_get_one_line_naming_the_flag_before_any_work(args, flag, tmp_path, capsys):
    """What a newcomer types wrong: one line on stderr that names the option, before the
    estimate, and nothing written."""
    out = tmp_path / "out"
    assert main(["bench", *args, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and flag in err, err
    assert "estimated" not in err and not out.exists()


def test_the_ray_executor_runs_the_same_plan_to_the_same_records(tmp_path):
    """``--executor ray`` (a local Ray instance here, as on a cluster's head node) runs the
    plan the local process pool runs: the same jobs under the same ids, the same rows."""
    ray = pytest.importorskip("ray")
    small = [
        *TINY[TINY.index("--train-steps") : TINY.index("--agents")],
        "--scenarios", "family", "--agents", "ppo,stc,lqg", "--bootstrap-reps", "50",
        "--no-plots", "--out", str(tmp_path),
    ]  # fmt: skip
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main(["bench", *small, "--run", "local", "--jobs", "2"]) == 0, err.getvalue()
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
        try:
            rc = main(["bench", *small, "--run", "ray", "--executor", "ray", "--jobs", "2"])
        finally:
            ray.shutdown()
    assert rc == 0, err.getvalue()
    ids = {name: ResultsStore(tmp_path / name / "store", METRIC_COLUMNS).ids()
           for name in ("local", "ray")}  # fmt: skip
    assert ids["ray"] == ids["local"] and len(ids["local"]) == 6  # lqg, zero; stc, ppo: 2 runs
    _, local_rows = _rows(tmp_path / "local" / "metrics.csv")
    _, ray_rows = _rows(tmp_path / "ray" / "metrics.csv")
    drop = ("train_wall_s", "step_us")  # the columns of wall time
    diff = {k for a, b in zip(ray_rows, local_rows, strict=True) for k in a if a[k] != b[k]}
    assert diff <= set(drop), diff
