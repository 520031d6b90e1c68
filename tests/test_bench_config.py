"""``build_config``: the bench's settings by the names of ``BenchConfig``'s fields, from
Python and from the command line alike."""

from __future__ import annotations

import pytest

import stcgym.agents.benchmark as benchmark
from stcgym.agents.benchmark import BenchConfig, BenchInputError, build_config
from stcgym.agents.benchmark.tiers import MODES
from stcgym.agents.cli import main


def test_settings_are_the_fields_list_ones_as_strings_or_sequences():
    a = build_config(run="c", agents="PPO, stc", scenarios="nominal", train_seeds=2)
    b = build_config(run="c", agents=["ppo", "stc"], scenarios=("nominal",), train_seeds=2)
    assert a == b
    assert a.agents == ["ppo", "stc", "lqg", "zero"]  # the yardstick and zero input joined
    assert a.scenarios == ["nominal"] and a.train_seeds == 2


def test_none_or_absent_keeps_the_presets_value():
    preset = MODES["standard"]
    cfg = build_config(run="s", mode="standard", train_seeds=None, test_plants=None)
    assert cfg.train_seeds == preset["train_seeds"]
    assert cfg.test_plants == preset["test_plants"]
    assert cfg.patience == BenchConfig.patience  # a field no preset sets: its default


@pytest.mark.parametrize(
    "name", ["no_such_setting", "tuned", "action_bounds", "family_train_steps"]
)
def test_unknown_or_derived_settings_are_refused_by_name(name):
    with pytest.raises(TypeError, match=rf"\['{name}'\].*BenchConfig's fields"):
        build_config(run="x", **{name: {}})


def test_bad_values_name_the_setting():
    with pytest.raises(BenchInputError, match="mode must be one of"):
        build_config(mode="huge")
    with pytest.raises(BenchInputError, match="positive integer"):
        build_config(run="x", train_seeds=0)


def test_the_command_line_sets_the_same_fields(monkeypatch):
    seen = {}

    def fake_run(cfg, **kwargs):
        seen["cfg"] = cfg
        raise KeyboardInterrupt  # stop before any work

    monkeypatch.setattr(benchmark, "run_bench", fake_run)
    argv = ["bench", "--run", "c", "--out", "/nonexistent-never-written", "--agents", "ppo,stc"]
    argv += ["--scenarios", "nominal", "--noise", "0.1", "--hp", "ppo.n_epochs=5"]
    argv += ["--no-plots", "--train-seeds", "2", "--train-steps", "ppo=40960", "--jobs", "1"]
    assert main(argv) == 130
    expected = build_config(
        run="c",
        out="/nonexistent-never-written",
        agents="ppo,stc",
        scenarios="nominal",
        noise_std=0.1,
        overrides=["ppo.n_epochs=5"],
        plots=False,
        train_seeds=2,
        train_steps="ppo=40960",
        jobs=1,
    )
    cfg = seen["cfg"]
    assert cfg.noise_std == 0.1 and cfg.overrides == ["ppo.n_epochs=5"] and not cfg.plots
    assert cfg.train_steps["ppo"] == 40960
    assert cfg.algo_configs["ppo"]["hyperparams"]["n_epochs"] == 5
    assert cfg == expected
