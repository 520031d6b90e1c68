"""The difficulty ladder in the bench: one scenario per rung, its RL agents trained on the rung,
the report's table across rungs; and the tuning studies a run plans."""

from __future__ import annotations

import pytest

from stcgym.agents.benchmark import build_config
from stcgym.agents.benchmark.config import BenchInputError
from stcgym.agents.benchmark.ladder_report import ladder_table
from stcgym.agents.benchmark.plan import describe_plan, rl_tasks, tuning_seconds
from stcgym.agents.benchmark.scenarios import make_scenarios, training_envs
from stcgym.agents.evaluation.statistics import Estimate
from stcgym.envs.families import LADDER, get_family


def _ladder_config(**kw):
    kw = {"scenarios": "family,ladder", "agents": "ppo,sac,oracle_ppo,stc", **kw}
    return build_config(run="l", train_seeds=2, test_plants=4, **kw)


def test_each_rung_is_a_scenario_on_its_own_test_split_and_training_key():
    cfg = _ladder_config(ladder="ladder-l1-v1,ladder-l3-v1")
    by_name = {sc.name: sc for sc in make_scenarios(cfg)}
    assert list(by_name) == ["family:test", "ladder-l1-v1:test", "ladder-l3-v1:test"]
    for rung in ("ladder-l1-v1", "ladder-l3-v1"):
        sc = by_name[f"{rung}:test"]
        assert sc.kind == "ladder" and sc.train_key == f"family:{rung}"
        assert sc.env.family == rung and sc.env.split == "test"
        first = get_family(rung).split_indices("test")[0]
        assert sc.episodes.plants == tuple(f"{rung}/test/{first + i}" for i in range(4))
    envs = training_envs(cfg, list(by_name.values()))
    assert set(envs) == {"family", "family:ladder-l1-v1", "family:ladder-l3-v1"}
    rung = envs["family:ladder-l1-v1"]
    assert (rung.train.family, rung.train.split) == ("ladder-l1-v1", "train")
    assert (rung.curve.family, rung.curve.split) == ("ladder-l1-v1", "validation")


def test_only_the_ladder_agents_train_on_the_rungs_and_each_is_scored_on_its_own_rung():
    cfg = _ladder_config(ladder="ladder-l2-v1", ladder_agents="ppo,oracle_ppo")
    scenarios = make_scenarios(cfg)
    tasks = rl_tasks(cfg, scenarios, training_envs(cfg, scenarios), {})
    jobs = {(t.train_key, t.algo) for t in tasks}
    assert jobs == {
        ("family", "ppo"),
        ("family", "sac"),
        ("family", "oracle_ppo"),
        ("family:ladder-l2-v1", "ppo"),
        ("family:ladder-l2-v1", "oracle_ppo"),
    }
    for t in tasks:
        wanted = "family:test" if t.train_key == "family" else "ladder-l2-v1:test"
        assert [e.scenario for e in t.evaluations] == [wanted]
        assert t.steps == cfg.family_train_steps[t.algo]  # a rung is a family: its cap
    assert sum(t.name.startswith("family-ladder-l2-v1_ppo_s") for t in tasks) == 2


def test_the_ladder_alone_trains_the_agents_that_need_a_family():
    cfg = _ladder_config(scenarios="ladder", ladder="ladder-l1-v1", agents="oracle_ppo,stc")
    assert [sc.name for sc in make_scenarios(cfg)] == ["ladder-l1-v1:test"]
    with pytest.raises(BenchInputError, match="train on the plant family"):
        _ladder_config(scenarios="ladder", ladder_agents="ppo", agents="oracle_ppo,stc")


@pytest.mark.parametrize(
    ("kw", "message"),
    [
        ({"ladder": ""}, "at least one rung"),
        ({"ladder": "ladder-l1-v1,ladder-l1-v1"}, "lists a rung twice"),
        ({"ladder": "ladder-l9-v1"}, "--ladder"),
        ({"ladder_agents": "ppo,dqn"}, "--ladder-agents: unknown RL agent"),
        ({"tune_agents": "ppo,dqn", "tune_trials": 2}, "--tune-agents: unknown RL agent"),
    ],
)
def test_bad_ladder_or_tuning_input_names_the_option(kw, message):
    with pytest.raises(BenchInputError, match=message):
        _ladder_config(**kw)


def test_the_ladder_table_puts_the_rungs_side_by_side_with_the_family_last():
    cfg = _ladder_config(ladder=",".join(LADDER[:2]))
    scenarios = make_scenarios(cfg)

    def res(ratio, diverged):
        return {"ratio": Estimate(ratio, ratio * 0.9, ratio * 1.1),
                "diverged": Estimate(diverged, 0.0, diverged)}  # fmt: skip

    statistics = {
        "ladder-l1-v1:test": {"ppo": res(2.5, 0.0), "stc": res(1.8, 0.0)},
        "ladder-l2-v1:test": {
            "ppo": {"family": "rl", "runs": 0, "untrained_runs": 2},
            "stc": res(1.9, 0.0),
        },  # fmt: skip
        "family:test": {
            "ppo": {**res(7.0, 0.25), "runs": 2, "untrained_runs": 3},
            "stc": res(2.2, 0.01),
        },
    }
    lines = ladder_table(cfg, scenarios, statistics)
    assert lines[0] == ("| controller | ladder-l1-v1 | ladder-l2-v1 | ladder-l4-v1 (family:test) |")
    assert lines[2] == (
        "| ppo | 2.5 [2.25, 2.75] | no improvement over initialisation "
        "| 7 [6.3, 7.7]; 25 % div.; 3 of 5 runs untrained |"
    )
    assert lines[3] == "| stc | 1.8 [1.62, 1.98] | 1.9 [1.71, 2.09] | 2.2 [1.98, 2.42]; 1 % div. |"
    # another family is not the last rung: the rungs alone
    other = _ladder_config(ladder="ladder-l1-v1", family="ladder-l2-v1", ood="ood_order3")
    assert "family:test" not in ladder_table(other, make_scenarios(other), statistics)[0]


def test_a_tuning_run_plans_its_studies_and_tunes_only_the_agents_named():
    plain = build_config(run="t", mode="standard", tune_trials=0, agents="ppo,sac,stc")
    assert plain.tuned_rl_agents == [] and "tuning" not in describe_plan(plain)
    cfg = build_config(
        run="t", mode="standard", agents="ppo,sac,stc,stc_tuned", tune_trials=4,
        tune_agents="ppo",
    )  # fmt: skip
    assert cfg.tuned_rl_agents == ["ppo"]
    envs = training_envs(cfg, make_scenarios(cfg))
    alone = tuning_seconds(cfg, envs)
    assert alone > 0 and "4 Optuna trials each for ppo, stc" in describe_plan(cfg)
    both = build_config(
        run="t", mode="standard", agents="ppo,sac,stc,stc_tuned", tune_trials=4,
        tune_agents="ppo,sac",
    )  # fmt: skip
    assert tuning_seconds(both, envs) > alone  # SAC's study on the other worker is longer


def test_plant_strata_follow_the_ladder_features_of_each_plant():
    from stcgym.agents.benchmark.headline import plant_strata
    from stcgym.envs.families import draw_plant

    l1 = [f"ladder-l1-v1/test/{i}" for i in range(1100, 1120)]
    assert (plant_strata(l1) == 0).all()  # L1 has its own features only
    names = [f"siso2-v1/test/{i}" for i in range(1100, 1300)]
    strata = plant_strata(names)
    fam = get_family("siso2-v1")
    for name, k in zip(names, strata, strict=True):
        p = draw_plant(fam, int(name.rsplit("/", 1)[1]))
        unstable = abs(p.poles).max() >= 1
        nmp = p.zeros.size > 0 and abs(p.zeros).max() >= 1
        want = 3 if unstable else 2 if nmp else 1 if p.dc_gain < 0 else 0
        assert k == want, name
    assert set(strata) == {0, 1, 2, 3}  # the family's test split has every stratum


def test_by_stratum_takes_the_median_and_divergences_of_each_strata_plants():
    import numpy as np

    from stcgym.agents.benchmark.headline import by_stratum

    ratio = np.array([[[1.0], [2.0], [3.0], [10.0]], [[1.5], [2.5], [3.5], [20.0]]])
    bounded = np.ones_like(ratio)
    bounded[1, 3, 0] = 0.0  # run 1 diverged on plant 3
    tables = {"c": {"cost_ratio": ratio, "bounded": bounded}}
    strata = np.array([0, 0, 3, 3])
    cells = by_stratum(tables, strata, reps=200)["c"]
    assert cells[1] is None and cells[2] is None
    # the lower median of the (run, plant) cells: the statistics' weighted median
    assert cells[0]["plants"] == 2 and cells[0]["ratio"].value == 1.5
    assert cells[3]["ratio"].value == 3.5  # of 3.0, 3.5 and 10: the bounded cells only
    assert cells[3]["diverged"].value == 0.25 and cells[0]["diverged"].value == 0.0


def test_an_agent_told_the_true_parameters_skips_plants_of_another_order():
    cfg = build_config(
        run="o", scenarios="family,ood", ood="ood_order3,ood_near_zero",
        agents="oracle_ppo,ppo,stc", train_seeds=1, test_plants=4,
    )  # fmt: skip
    scenarios = make_scenarios(cfg)
    tasks = {t.algo: t for t in rl_tasks(cfg, scenarios, training_envs(cfg, scenarios), {})}
    every = ["family:test", "family:ood_order3", "family:ood_near_zero"]
    assert [e.scenario for e in tasks["ppo"].evaluations] == every
    # (a, b) of a second-order plant are its input: a third-order plant has none to give
    assert [e.scenario for e in tasks["oracle_ppo"].evaluations] == [every[0], every[2]]


def test_a_page_opens_a_runs_tables_with_the_ladder_across_its_rungs():
    from stcgym.agents.benchmark.render import page_tables

    def est(value, low, high):
        return {"value": value, "low": low, "high": high}

    statistics = {
        "family:test": {"ppo": {"ratio": est(9.0, 8.0, 10.0), "diverged": est(0.3, 0.2, 0.4)}},
        "ladder-l1-v1:test": {
            "ppo": {"ratio": est(2.5, 2.0, 3.0), "diverged": est(0.0, 0.0, 0.0)},
            "fixed_pi": {"ratio": est(4.0, 4.0, 4.0), "diverged": est(0.0, 0.0, 0.0)},
        },
    }
    lines = page_tables("r", statistics).splitlines()
    assert lines[4:8] == [
        "| controller | `ladder-l1-v1:test` | `family:test` |",
        "|---|---|---|",
        "| `ppo` | 2.5 [2, 3] | 9 [8, 10]; 30 % div. |",
        "| `fixed_pi` | 4 | - |",
    ]
    # without rungs, the per-scenario tables alone
    plain = page_tables("r", {"family:test": statistics["family:test"]}).splitlines()
    assert plain[2].startswith("`family:test`: cost / LQG")


def test_a_pages_headline_of_a_run_is_its_first_table_and_update_page_renders_every_block(
    tmp_path,
):
    import json

    from stcgym.agents.benchmark.render import page_blocks, page_headline, update_page

    def est(value):
        return {"value": value, "low": value, "high": value}

    statistics = {
        "nominal:stable2": {"ppo": {"ratio": est(3.0), "diverged": est(0.0)}},
        "ladder-l1-v1:test": {"ppo": {"ratio": est(2.5), "diverged": est(0.0)}},
    }
    head = page_headline("r", statistics).splitlines()
    assert head[0].startswith("<!-- headline of results/r") and head[-1].endswith("results/r -->")
    assert "| `ppo` | 2.5 |" in head and not any("stable2" in line for line in head)
    # without rungs, the first scenario's table
    plain = page_headline("r", {"nominal:stable2": statistics["nominal:stable2"]})
    assert "`nominal:stable2`: cost / LQG" in plain
    run = tmp_path / "r"
    run.mkdir()
    (run / "statistics.json").write_text(json.dumps(statistics))
    page = tmp_path / "page.md"
    stale = "<!-- headline of results/r: rendered by `stcgym report`, do not edit -->\nold\n"
    stale += "<!-- end of the headline of results/r -->\n\ntext\n\n"
    stale += "<!-- tables of results/r: rendered by `stcgym report`, do not edit -->\nold\n"
    stale += "<!-- end of the tables of results/r -->\n"
    page.write_text(stale)
    assert update_page(page, run) and not update_page(page, run)  # a second pass changes nothing
    blocks = page_blocks(page.read_text(), "r")
    assert set(blocks) == {"headline", "tables"} and "old" not in page.read_text()
    assert (
        blocks["headline"] == page_headline("r", statistics) and "\n\ntext\n\n" in page.read_text()
    )
    page.write_text("no block\n")
    with pytest.raises(ValueError, match="has no block for r"):
        update_page(page, run)
