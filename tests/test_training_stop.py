"""The plateau rule: its bookkeeping, its wiring into SB3's training loop, its bad input."""

from __future__ import annotations

import re

import pytest

from stcgym.agents.evaluation.env_spec import EnvSpec
from stcgym.agents.rl import sb3 as sb3_mod
from stcgym.agents.rl.configs import default_config
from stcgym.agents.rl.learning_curve import CurveOptions
from stcgym.agents.rl.sb3 import curve_checkpoints, train_agent
from stcgym.agents.rl.stopping import PlateauRule, PlateauTracker


def _expected_stop(costs, min_improvement, patience, first=0):
    """The rule written out by hand: (index of the stopping evaluation or None, index of the
    last evaluation that improved); evaluations before index ``first`` (those before the
    minimum fraction of the cap) move the reference but do not count towards ``patience``."""
    reference, last, quiet = None, None, 0
    for i, c in enumerate(costs):
        if reference is None or c < reference * (1 - min_improvement):
            reference, last = c, i
            quiet = 0
        elif i >= first:
            quiet += 1
            if quiet == patience:
                return i, last
    return None, last


# 9.6 is a 4 % gain on 10 (not enough), 9.4 a 6 % gain (enough); 9.0 is 4.3 % below 9.4, 8.9
# 5.3 %; then 8.8, 8.7, 8.6 are three evaluations without a 5 % gain.
COSTS = [10.0, 9.6, 9.4, 9.0, 8.9, 8.8, 8.7, 8.6, 1.0]


def test_hand_worked_sequence():
    assert _expected_stop(COSTS, 0.05, 3) == (7, 4)


def test_tracker_moves_the_reference_only_on_a_gain_above_the_minimum():
    tracker = PlateauTracker(PlateauRule(0.05, 3))
    gains = [tracker.observe(100 * (i + 1), c) for i, c in enumerate(COSTS[:8])]
    assert gains == [True, False, True, False, True, False, False, False]
    assert tracker.reference_cost == 8.9 and tracker.last_improvement_step == 500
    assert tracker.best_mean_reward == -8.9  # what SB3's StopTrainingOnNoModelImprovement reads
    assert tracker.evaluations == 8


def test_a_non_finite_cost_never_improves():
    tracker = PlateauTracker(PlateauRule())
    assert not tracker.observe(1, float("nan"))
    assert tracker.observe(2, 5.0) and not tracker.observe(3, float("inf"))


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"patience": 0}, "--patience must be an integer >= 1"),
        ({"patience": -2}, "--patience must be an integer >= 1"),
        ({"patience": 2.5}, "--patience must be an integer >= 1"),
        ({"min_improvement": 1.0}, "--min-improvement must be a number in [0, 1)"),
        ({"min_improvement": -0.1}, "--min-improvement must be a number in [0, 1)"),
        ({"min_improvement": float("nan")}, "--min-improvement must be a number in [0, 1)"),
        ({"min_fraction": 1.5}, "--min-train-fraction must be a number in [0, 1]"),
        ({"min_fraction": -0.1}, "--min-train-fraction must be a number in [0, 1]"),
    ],
)
def test_rule_rejects_values_it_cannot_meet(kwargs, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        PlateauRule(**kwargs)


def test_curve_checkpoints_log_spaced_then_every_interval():
    marks = curve_checkpoints(1000, 3, 200)
    assert marks[-5:] == [200, 400, 600, 800, 1000]
    assert marks[0] < marks[1] < 200  # log-spaced points below the first interval
    assert curve_checkpoints(1000, 3) == sorted(set(curve_checkpoints(1000, 3)))
    assert curve_checkpoints(1000, 3)[-1] == 1000


# PPO with 2 envs x 64 steps: one rollout = 128 env steps = one evaluation interval, so every
# evaluation of the rule happens exactly at a multiple of 128.
ROLLOUT = 128


def _scripted(monkeypatch, costs):
    """Replace the learning-curve cost by COSTS[k - 1] at evaluation k (step k x ROLLOUT)."""

    def fake_curve_cost(policy, spec, episodes, reference=None):
        step = policy.model.num_timesteps
        return 50.0 if step == 0 else costs[min(step // ROLLOUT, len(costs)) - 1]

    monkeypatch.setattr(sb3_mod, "curve_cost", fake_curve_cost)


def _train(cap, rule):
    config = default_config("ppo")
    config.n_envs = 2
    config.hyperparams.update(n_steps=64, batch_size=64, n_epochs=1)
    spec = EnvSpec(("stable2",), steps=60)
    curve = CurveOptions(points=1, plateau=rule, interval=ROLLOUT)
    return train_agent("ppo", config, spec, cap, 0, curve=curve)


def test_min_evals_hand_worked():
    # a quarter of 30 intervals is 7.5: the evaluations at 1..7 intervals do not count
    assert PlateauRule(0.05, 3, 0.25).min_evals(30 * 128, 128) == 7
    assert PlateauRule(0.05, 3, 0.25).min_evals(32 * 128, 128) == 7  # 8 intervals: from the 8th
    assert PlateauRule(0.05, 3, 0.0).min_evals(30 * 128, 128) == 0


# A flat start (the untrained policy's cost for four evaluations), then learning, then a
# plateau at 2.0: without the floor the flat start is taken for a plateau.
FLAT_START = [50.0, 50.0, 50.0, 50.0, 20.0, 8.0, 3.0, 2.0, 2.0, 2.0, 2.0, 2.0]


def test_a_flat_start_is_not_a_plateau_once_a_fraction_of_the_cap_must_be_trained(monkeypatch):
    _scripted(monkeypatch, FLAT_START)
    assert _expected_stop(FLAT_START, 0.05, 3) == (3, 0)
    early = _train(16 * ROLLOUT, PlateauRule(0.05, 3, 0.0))
    assert early.stop.status == "plateau" and early.stop.evaluations == 4
    # a quarter of 16 intervals: evaluations count from the 4th interval on (index 3)
    rule = PlateauRule(0.05, 3, 0.25)
    first = rule.min_evals(16 * ROLLOUT, ROLLOUT)
    stop_index, last = _expected_stop(FLAT_START, 0.05, 3, first)
    assert (first, stop_index, last) == (3, 10, 7)
    agent = _train(16 * ROLLOUT, rule)
    assert agent.stop.status == "plateau" and agent.stop.evaluations == stop_index + 1
    assert agent.stop.last_improvement_step == (last + 1) * ROLLOUT
    assert "25 % of the cap" in agent.stop.rule


def test_training_stops_at_the_plateau_through_sb3(monkeypatch):
    _scripted(monkeypatch, COSTS)
    agent = _train(30 * ROLLOUT, PlateauRule(0.05, 3, 0.0))
    stop_index, last = _expected_stop(COSTS, 0.05, 3)
    stop = agent.stop
    assert stop.status == "plateau"
    assert stop.evaluations == stop_index + 1
    assert stop.last_improvement_step == (last + 1) * ROLLOUT
    assert stop.reference_cost == COSTS[last]
    # the last evaluation is the one that stopped training; SB3 stops on the next env step
    assert agent.curve[-1][0] == (stop_index + 1) * ROLLOUT
    assert agent.steps == (stop_index + 1) * ROLLOUT + 2
    assert stop.cap == 30 * ROLLOUT and "5 %" in stop.rule and "3 consecutive" in stop.rule


def test_training_that_still_improves_runs_to_the_cap(monkeypatch):
    _scripted(monkeypatch, COSTS)
    agent = _train(5 * ROLLOUT, PlateauRule(0.05, 3))
    assert agent.stop.status == "cap"
    assert agent.steps >= 5 * ROLLOUT
    assert agent.stop.evaluations == 5
    assert agent.stop.last_improvement_step == 5 * ROLLOUT


def test_a_run_kept_at_step_0_says_it_did_not_improve(monkeypatch):
    """Every evaluation worse than the untrained policy's 50: the kept checkpoint is step 0 and
    the stop summary says so; one that learned says it improved."""
    _scripted(monkeypatch, [60.0] * 8)
    agent = _train(8 * ROLLOUT, PlateauRule(0.05, 3))
    assert agent.best_step == 0 and agent.stop.best_step == 0
    assert agent.stop.improved is False
    assert agent.stop.to_dict()["improved"] is False
    _scripted(monkeypatch, FLAT_START)
    learned = _train(8 * ROLLOUT, PlateauRule(0.05, 3))
    assert learned.stop.improved is True and learned.stop.best_step == 8 * ROLLOUT


def test_the_default_rule_never_stops_before_half_the_cap(monkeypatch):
    """A curve flat from the start: with the default rule the first stop comes once half the
    cap is trained, and not before."""
    _scripted(monkeypatch, [50.0] * 40)
    rule = PlateauRule()
    assert rule.min_fraction == 0.5
    agent = _train(20 * ROLLOUT, rule)
    assert agent.stop.status == "plateau"
    assert 10 * ROLLOUT <= agent.curve[-1][0] < 20 * ROLLOUT
    assert "50 % of the cap" in agent.stop.rule


def test_curve_options_check_what_they_are_given():
    with pytest.raises(ValueError, match="interval must be a positive integer with a plateau"):
        CurveOptions(plateau=PlateauRule())
    with pytest.raises(ValueError, match="interval must be a positive integer"):
        CurveOptions(plateau=PlateauRule(), interval=0.5)
    with pytest.raises(ValueError, match="points must be a positive integer"):
        CurveOptions(points=0)
    assert CurveOptions(plateau=PlateauRule(), interval=128.0).interval == 128
    assert CurveOptions(interval=None).plateau is None  # no rule: no interval needed


def test_cap_below_one_interval_is_refused():
    with pytest.raises(ValueError, match="below one evaluation interval"):
        train_agent(
            "ppo",
            default_config("ppo"),
            EnvSpec(("stable2",), steps=60),
            100,
            0,
            curve=CurveOptions(plateau=PlateauRule(), interval=ROLLOUT),
        )


def _rl_rows(stops):
    """metrics.csv rows of one RL agent: two episodes per training run."""
    return [
        {
            "run": ts,
            "train_stop": status,
            "train_steps": steps,
            "train_last_improvement": last,
        }
        for ts, (status, steps, last) in enumerate(stops)
        for _ in range(2)
    ]


def test_report_says_how_training_ended():
    from stcgym.agents.benchmark import report
    from stcgym.agents.benchmark.headline import training_stops

    mixed = training_stops(_rl_rows([("plateau", 51_200, 20_480), ("cap", 100_000, 92_160)]))
    assert (mixed["seeds"], mixed["plateau"], mixed["cap"]) == (2, 1, 1)
    assert mixed["last_improvement"] == [20_480, 92_160]
    assert report._training_cell(mixed) == "plateau 1/2, cap 1/2"
    converged = training_stops(_rl_rows([("plateau", 40_960, 10_240)] * 3))
    assert report._training_cell(converged) == "plateau 3/3"
    assert report._training_cell(None) == "-"


def test_conclusions_say_where_rl_wins_and_qualify_wins_over_capped_agents():
    from stcgym.agents.benchmark import report
    from stcgym.agents.benchmark.headline import training_stops
    from stcgym.agents.evaluation.statistics import Estimate

    capped = training_stops(_rl_rows([("cap", 100_000, 92_160)] * 2))
    zero = Estimate(0.0, 0.0, 0.0)

    def res(family, ratio):
        return {"family": family, "ratio": Estimate(ratio, ratio * 0.9, ratio * 1.1),
                "diverged": zero}  # fmt: skip

    hl = {"ppo": res("rl", 2.0), "stc": res("adaptive", 1.5), "lqg": res("oracle", 1.0)}
    pairs = [("stc", "ppo", {"probability": Estimate(0.9, 0.8, 1.0),
                             "ratio": Estimate(0.7, 0.6, 0.8)})]  # fmt: skip
    line = report._conclusion("family:test", hl, pairs, {"ppo": capped})
    assert line.startswith("`family:test`: the lowest cost / LQG is stc's, 1.5 [1.35, 1.65]")
    assert "stc has the lower cost more often than ppo: P = 0.9 [0.8, 1]" in line
    assert "(ppo reached its training cap before a plateau in 2/2 runs)" in line
    # where RL wins, the sentence says so, whichever way the numbers fall
    hl["ppo"] = res("rl", 1.2)
    pairs = [("stc", "ppo", {"probability": Estimate(0.2, 0.1, 0.3),
                             "ratio": Estimate(1.3, 1.1, 1.5)})]  # fmt: skip
    line = report._conclusion("family:test", hl, pairs, {})
    assert "lowest cost / LQG is ppo's" in line
    assert "ppo has the lower cost more often than stc" in line and "cap" not in line
    # an interval across one half decides nothing
    pairs = [("stc", "ppo", {"probability": Estimate(0.5, 0.3, 0.7),
                             "ratio": Estimate(1.0, 0.8, 1.2)})]  # fmt: skip
    assert "neither stc nor ppo" in report._conclusion("family:test", hl, pairs, {})
    # an agent that diverged on every episode has no ratio and is not ranked first
    nan = float("nan")
    hl["ppo"] = {"family": "rl", "ratio": Estimate(nan, nan, nan), "diverged": Estimate(1, 1, 1)}
    line = report._conclusion("family:ood", hl, pairs, {})
    assert line.startswith("`family:ood`: the lowest cost / LQG is stc's, 1.5")
    assert "ppo 100.0 %" in line
    hl["stc"] = hl["ppo"]
    assert report._conclusion("family:ood", hl, pairs, {}).startswith(
        "`family:ood`: no controller stayed bounded on any episode"
    )
