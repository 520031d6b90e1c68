"""``report.md`` of a bench run: the protocol, what each controller knows, the headline per
scenario with intervals, paired comparisons, RL training, details.

The headline (:mod:`stcgym.agents.benchmark.headline`) gives per scenario and controller the
cost ratio to the LQG yardstick on the same episode and the normalised score (IQM over runs and
test plants, rliable's stratified bootstrap over runs), the divergence rate with its interval,
the steps to get within 1.2x of LQG, and after a jump the post-jump ratio and re-convergence;
then every self-tuning controller against every RL agent on the same (plant, episode): the
probability of the lower cost and the paired cost ratio, with intervals. Next to each RL agent's
figures the report says how its training runs ended (plateau or cap). The conclusions are
generated from those numbers, whichever way they fall.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from stcgym.agents.benchmark.attribution import identification_or_design
from stcgym.agents.benchmark.cells import number, percent, thousands
from stcgym.agents.benchmark.headline import (
    SELF_TUNING,
    aggregate,
    as_float,
    headline,
    paired,
    scenario_tables,
    training_stops,
    untrained_runs,
)
from stcgym.agents.benchmark.ladder_report import ladder_table, strata_section
from stcgym.agents.controllers import CONTROLLERS, YARDSTICK
from stcgym.agents.evaluation.statistics import Estimate
from stcgym.agents.rl.interfaces import InterfaceSpec

__all__ = ["write_report"]

#: Reference rows: compared with, not ranked.
_REFERENCES = (YARDSTICK, "zero", "oracle")


def _steps(res: dict[str, Any]) -> str:
    """``"2.3k (4/5)"``: median steps and how many got there; ``never`` when none did."""
    n, reached = res["n"], res["reached"]
    if n == 0:
        return "-"
    if reached == 0:
        return f"never (0/{n})"
    if 2 * reached <= n:  # the median is a "never"
        return f"never in half or more ({reached}/{n})"
    return f"{thousands(res['median'])} ({reached}/{n})"


def _training_cell(res: dict[str, Any] | None) -> str:
    """``"plateau 2/3, cap 1/3"`` (``-`` for a classical controller)."""
    if res is None:
        return "-"
    parts = [f"{k} {res[k]}/{res['seeds']}" for k in ("plateau", "cap") if res[k]]
    return ", ".join(parts) or "-"


def _settings(params: dict[str, Any]) -> str:
    return ", ".join(f"{k}={number(v) if isinstance(v, float) else v}" for k, v in params.items())


def _knowledge_table(cfg: Any) -> list[str]:
    from stcgym.agents.rl.configs import agent_knowledge

    lines = [
        "| controller | plant order | integral action | model | data before the episode |",
        "|---|---|---|---|---|",
    ]
    for name in cfg.agents:
        if name in CONTROLLERS:
            k = CONTROLLERS[name].knows
            data = k.get("data", "-")
            lines.append(
                f"| {name} | {k.get('order', '-')} | {k.get('integral', '-')} | "
                f"{k.get('model', '-')} | {data} |"
            )
            continue
        k = agent_knowledge(name, cfg.algo_configs[name])
        lines.append(f"| {name} | {k['order']} | {k['integral']} | {k['model']} | {k['data']} |")
    lines += [
        "",
        "Every controller gets the same observation `[y(k), r(k)]` and the same action bound "
        "per training distribution; nobody sees the plant state.",
    ]
    return lines


def _protocol(cfg: Any, scenarios: Sequence[Any], data: Any) -> list[str]:
    from stcgym.envs.families import get_family

    fam = get_family(cfg.family)
    splits = ", ".join(f"{k} {len(fam.split_indices(k))}" for k in fam.splits)
    bounds = "; ".join(f"`{k}` {number(v)}" for k, v in cfg.action_bounds.items())
    units = "; ".join(f"`{k}` {number(v)}" for k, v in cfg.action_units.items())
    peaks = "; ".join(
        f"`{k}`: median {number(b['peak_median'])}, max {number(b['peak_max'])} over "
        f"{b['episodes']}"
        for k, b in data.bounds.items()
    )
    kinds = {sc.kind for sc in scenarios}
    tested = []
    if kinds & {"family", "ood", "jump"}:
        on_test = f"its test split ({cfg.episodes_per_plant} episode(s) per plant"
        on_test += f", the first {cfg.test_plants} plants)" if cfg.test_plants else ")"
        tested.append(on_test)
    if "ood" in kinds:
        tested.append(f"the held-out variants {', '.join(f'`{v}`' for v in cfg.ood)}")
    plants = (
        f"the family `{cfg.family}` (`stcgym.envs.families`; splits by plant index: {splits})"
        + (f"; scenarios test on {' and on '.join(tested)}" if tested else "")
    )
    if "nominal" in kinds:
        plants += f"; `nominal:*` on one catalogue plant ({cfg.nominal_episodes} episodes)"
    if kinds & {"mimo", "mimo_switch", "mimo_family"}:
        plants += f"; the MIMO scenarios on {', '.join(f'`{p}`' for p in cfg.mimo_plants)}"
    lines = [
        "## Protocol",
        "",
        f"- **Plants**: {plants}. Every controller meets the same episodes (the same plants, "
        "seeds, noise, reference and initial state).",
        "- **Episodes differ**: random initial state, a random-steps reference, output noise"
        + (
            ", and in `jump:test` a parameter jump at a random time in every episode"
            if "jump" in kinds
            else ""
        )
        + ". RL trains on episodes drawn the same way, of the same length, with the jump in a "
        "share of them.",
        "- **Score**: the environments' per-step cost `(y - r)^2 + rho u^2`, undiscounted over "
        "the episode; a diverged episode is charged its last cost for every step it did not "
        f"live. {_rl_objective(cfg)}",
        f"- **One action bound per training distribution** for every controller: {bounds} "
        f"(1.5 x the 99th percentile of LQG's input peak per training episode; peaks: "
        f"{peaks or 'read back from config.json'}). The Gaussian-policy RL agents (PPO and "
        "the agents built on it, RecurrentPPO) act in units of a typical input, "
        f"{units or '-'} (the 99th percentile of LQG's inputs over every training step), "
        "in a box widened to the whole bound: "
        "in units of the bound their optimiser's steps were large inputs and they got worse "
        "as they trained.",
        "- **Yardstick**: LQG on the true model with the scored cost, told the new "
        "parameters at a jump (the best a linear controller that knows the plant does); every "
        "ratio is a controller's episode cost over LQG's on the same episode. Pole placement "
        "on the true model (`oracle`) stays as a reference row. Normalised score: "
        "`(C_zero - C) / (C_zero - C_LQG)` where zero input stays bounded and costs more than "
        "LQG (1: as good as LQG, 0: as good as doing nothing).",
        "- **The self-tuning controllers' options are the library defaults**, fixed before the "
        "test split was drawn; none was tuned on it.",
        f"- **Runs**: {cfg.train_seeds} per controller with random parts (RL training seeds; "
        "self-tuning controller seeds), one for the deterministic ones. Intervals bootstrap "
        f"the runs and the test plants ({cfg.bootstrap_reps} replications)"
        + (
            "; with one run per controller they show the spread over plants only."
            if cfg.train_seeds == 1
            else "."
        ),
        f"- **RL training**: until {cfg.plateau.describe()} (the learning curve: median cost "
        f"ratio to LQG on {cfg.curve_episodes} fixed validation episodes); the checkpoint with "
        "the best validation score is kept.",
        "",
    ]
    return lines


def _rl_objective(cfg: Any) -> str:
    """What the run's RL agents were trained on, read from their configs."""
    if not cfg.algo_configs:
        return ""
    by_reward: dict[tuple[str, str, Any], list[str]] = {}
    for algo, c in cfg.algo_configs.items():
        gamma = f"{c['hyperparams'].get('gamma', 0.99):g}"
        key = (c.get("reward", "lqg_ratio"), gamma, c.get("cost_cap"))
        by_reward.setdefault(key, []).append(algo)
    parts = []
    for (reward, gamma, cap), algos in by_reward.items():
        what = (
            "the per-step cost over the LQG cost of the episode's own plant, capped at "
            f"{cap} (the score's unit; that LQG cost is privileged information, in the "
            "reward only)"
            if reward == "lqg_ratio"
            else "the raw per-step cost"
        )
        parts.append(f"{', '.join(f'`{a}`' for a in algos)}: {what}, gamma {gamma}")
    return (
        "RL's reward, with SB3's running reward scale, normalised observations and the "
        "integral of the tracking error among its inputs: " + "; ".join(parts) + "."
    )


def _headline_table(
    hl: dict[str, dict[str, Any]], jump: bool, stops: dict, untrained: dict[str, tuple[int, int]]
) -> list[str]:
    cols = [
        "controller",
        "runs x episodes",
        "cost / LQG, IQM (bounded)",
        "cost / LQG, median (bounded)",
        "steady / LQG, IQM (bounded)",
        "score, IQM (bounded)",
        "diverged",
        "steps to <= 1.2x LQG (reached)",
    ]
    if jump:
        cols += ["post-jump cost / LQG, IQM", "re-converge steps (recovered)"]
    cols.append("RL training stop")
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for c, res in hl.items():
        left_out = untrained.get(c, (0, 0))[0]
        cells = [
            c + (f" ({left_out} untrained run{'s' * (left_out > 1)} left out)" if left_out else ""),
            f"{res['runs']} x {res['episodes']}",
            res["ratio"].format(3),
            res["ratio_median"].format(3),
            res["steady"].format(3),
            res["score"].format(3),
            percent(res["diverged"]),
            _steps(res["to_target"]),
        ]
        if jump:
            post = res["post_jump"]
            cells += ["-" if post is None else post.format(3), _steps(res["reconverge"])]
        cells.append(_training_cell(stops.get(c)))
        lines.append("| " + " | ".join(cells) + " |")
    for c, (n, runs) in untrained.items():
        if c not in hl and n:  # every run kept its untrained network
            blank = ["-"] * (len(cols) - 2)
            cells = [c, f"no improvement over initialisation ({n}/{runs} runs)", *blank]
            lines.append("| " + " | ".join(cells) + " |")
    return lines


def _paired_table(pairs: list[tuple[str, str, dict[str, Estimate]]]) -> list[str]:
    lines = [
        "| self-tuning | RL agent | P(self-tuning cost lower) | paired cost ratio "
        "(self-tuning / RL) |",
        "|---|---|---|---|",
    ]
    for a, b, p in pairs:
        lines.append(f"| {a} | {b} | {p['probability'].format(3)} | {p['ratio'].format(3)} |")
    return lines


def _channel_table(
    rows: Sequence[dict[str, Any]], scenario: str, order: Sequence[str]
) -> list[str]:
    """Per controller, the mean over its rows of the tracking error of each performance
    channel and of the cross-channel disturbance (a MIMO scenario's columns)."""
    cols = ("track_rms_1", "track_rms_2", "cross_peak")
    lines = [
        "| controller | RMS error z1 | RMS error z2 | cross-channel peak |",
        "|---|---|---|---|",
    ]
    for c in order:
        mine = [r for r in rows if r["scenario"] == scenario and r["controller"] == c]
        if not mine:
            continue
        cells = []
        for col in cols:
            vals = [float(r[col]) for r in mine if r.get(col) not in (None, "")]
            vals = [v for v in vals if math.isfinite(v)]
            cells.append(number(float(np.mean(vals))) if vals else "-")
        lines.append(f"| {c} | " + " | ".join(cells) + " |")
    return lines if len(lines) > 2 else []


def _best(hl: dict[str, dict[str, Any]], names: Sequence[str]) -> str | None:
    """The controller of ``names`` with the lowest cost / LQG; one whose every episode
    diverged has no ratio (nothing bounded to average) and is not ranked."""
    present = [n for n in names if n in hl and _finite(hl[n]["ratio"].value)]
    return min(present, key=lambda n: hl[n]["ratio"].value) if present else None


def _finite(value: Any) -> bool:
    return value is not None and math.isfinite(float(value))


def _conclusion(name: str, hl: dict[str, dict[str, Any]], pairs: list, stops: dict) -> str:
    """One sentence per scenario, from the numbers."""
    rl = [c for c, r in hl.items() if r["family"] == "rl"]
    tuners = [c for c in SELF_TUNING if c in hl]
    ranked = [c for c in hl if c not in _REFERENCES]
    if not ranked:
        return ""
    best = _best(hl, ranked)
    if best is None:  # every controller diverged on every episode
        parts = [f"`{name}`: no controller stayed bounded on any episode"]
    else:
        parts = [f"`{name}`: the lowest cost / LQG is {best}'s, {hl[best]['ratio'].format(3)}"]
    best_rl, best_tuner = _best(hl, rl), _best(hl, tuners)
    if best_rl and best_tuner:
        p = next((q for a, b, q in pairs if a == best_tuner and b == best_rl), None)
        if p is not None:
            prob, ratio = p["probability"], p["ratio"]
            if prob.low > 0.5:
                verdict = f"{best_tuner} has the lower cost more often than {best_rl}"
            elif prob.high < 0.5:
                verdict = f"{best_rl} has the lower cost more often than {best_tuner}"
            else:
                verdict = f"neither {best_tuner} nor {best_rl} has the lower cost reliably"
            capped = stops.get(best_rl, {}).get("cap", 0)
            caveat = (
                f" ({best_rl} reached its training cap before a plateau in "
                f"{capped}/{stops[best_rl]['seeds']} runs)"
                if capped
                else ""
            )
            parts.append(
                f"{verdict}: P = {prob.format(3)}, paired cost ratio {ratio.format(3)}{caveat}"
            )
    div = [f"{c} {percent(r['diverged'])}" for c, r in hl.items() if r["diverged"].value > 0]
    if div:
        parts.append("diverged: " + ", ".join(div))
    return "; ".join(parts) + "."


def _detail_table(agg: dict, name: str, controllers: Sequence[str]) -> list[str]:
    cols = [
        ("cost", "median"),
        ("cost_ratio", "median"),
        ("cost_ratio", "cvar25"),
        ("effort", "median"),
        ("clip_frac", "mean"),
        ("overshoot_pct", "median"),
        ("settling_steps", "median"),
        ("data_steps", "median"),
        ("step_us", "median"),
    ]
    head = ["controller", "rows (div.)", *(f"{c} {s}" for c, s in cols)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for c in controllers:
        a = agg.get((name, c))
        if a is None:
            continue
        div = f" ({a['failures']})" if a["failures"] else ""
        cells = [c, f"{a['rows']}{div}", *(number(a[col][stat]) for col, stat in cols)]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _training_table(cfg: Any, data: Any) -> list[str]:
    from stcgym.agents.rl.zoo_departures import ZOO_DEPARTURES

    lines = [
        "| training env | agent | run | stop | steps (cap) | last gain at | best validation "
        "score | kept step | updates: approx KL, clip fraction, explained variance, entropy | "
        "wall s |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    untrained: dict[str, list[str]] = {}
    for (key, algo, ts), stop in sorted(data.stops.items(), key=lambda kv: str(kv[0])):
        curve = [c["score"] for c in data.curves if (c["train_env"], c["algo"], c["train_seed"])
                 == (key, algo, ts)]  # fmt: skip
        kept = stop["kept_step"]
        if kept == 0:
            untrained.setdefault(f"{algo} on {key}", []).append(str(ts))
        diagnostics = _diagnostics_cell(data.diagnostics.get((key, algo, ts), []))
        lines.append(
            f"| {key} | {algo} | {ts} | {stop['status']} | {thousands(stop['steps'])} "
            f"({thousands(stop['cap'])}) | {thousands(stop['last_improvement_step'] or 0)} | "
            f"{number(min(curve)) if curve else '-'} | {thousands(kept)} | {diagnostics} | "
            f"{number(as_float(stop.get('wall_s')), 4)} |"
        )
    if len(lines) == 2:
        return []
    if untrained:
        runs = "; ".join(f"{name} (run {', '.join(r)})" for name, r in untrained.items())
        lines += [
            "",
            "Kept at step 0, the untrained policy (training never improved its validation "
            f"score): {runs}. No improvement over initialisation: these runs are left out of "
            "the headline's estimates (their rows in `metrics.csv` are the untrained "
            "network's).",
        ]
    dep = ["| agent | setting | RL Zoo | here | why |", "|---|---|---|---|---|"]
    recorded = data.departures or {}  # the run's own, where config.json keeps them
    for agent in cfg.rl_agents:
        for setting, zoo, ours, why in recorded.get(agent, ZOO_DEPARTURES.get(agent, [])):
            dep.append(f"| {agent} | {setting} | {zoo} | {ours} | {why} |")
    return [*lines, "", "Departures from the RL Zoo's settings:", "", *dep]


#: SB3's update statistics the training table summarises, as its logger names them, with the
#: sign each is shown with: the policy's entropy is minus SB3's ``entropy_loss``.
_DIAGNOSTICS = (
    ("approx_kl", 1.0),
    ("clip_fraction", 1.0),
    ("explained_variance", 1.0),
    ("entropy_loss", -1.0),
)


def _diagnostics_cell(diagnostics: Sequence[dict[str, Any]]) -> str:
    """The median over a run's recorded updates of each of :data:`_DIAGNOSTICS` (``-`` where
    the algorithm logs none, e.g. SAC's clip fraction)."""
    cells = []
    for name, sign in _DIAGNOSTICS:
        values = [
            sign * as_float(d.get(name, d.get(f"train/{name}")))
            for d in diagnostics
        ]  # fmt: skip
        values = [v for v in values if math.isfinite(v)]
        cells.append(number(float(np.median(values)), 2) if values else "-")
    return ", ".join(cells)


def write_report(
    run_dir: Path,
    cfg: Any,
    scenarios: Sequence[Any],
    rows: Sequence[dict[str, Any]],
    data: Any,
    wall_s: float,
    *,
    interrupted: bool = False,
    time_limited: bool = False,
    missing: Sequence[str] = (),
    sessions: int = 1,
) -> Path:
    """Write ``report.md`` from the metric rows (also a partial one after an interrupt, or when
    the time limit left jobs for ``--resume``: ``time_limited``, ``missing`` naming them) and
    ``statistics.json``, the estimates its tables show; ``wall_s`` is the run's wall time over
    its ``sessions`` (the first and each ``--resume``)."""
    from stcgym.agents.executors import write_atomic

    agg = aggregate(rows)
    present = {r["scenario"] for r in rows}
    order = [c for c in cfg.agents if c not in _REFERENCES] + [c for c in _REFERENCES]
    out = [f"# stcgym bench: `{cfg.run}`", ""]
    if interrupted:
        out += ["**INTERRUPTED: partial results (the rows finished before the interrupt).**", ""]
    elif time_limited:
        left = f" ({len(missing)} of the plan's jobs: {', '.join(missing[:8])}" + (
            ", ...)" if len(missing) > 8 else ")"
        )
        out += [
            f"**PARTIAL: jobs left to run{left if missing else ''}; `stcgym bench --resume "
            f"{run_dir}` continues the run.**",
            "",
        ]
    out += [
        f"Tier `{cfg.mode}`. Wall time {wall_s:.0f} s on {cfg.jobs} worker(s)"
        f"{f' over {sessions} sessions (resumed)' if sessions > 1 else ''}. Exact "
        "configuration: `config.json`; one row per scenario, controller, run and episode: "
        "`metrics.csv`; learning curves: `learning_curves.csv`.",
        "",
        *_protocol(cfg, scenarios, data),
        "## What each controller knows",
        "",
        *_knowledge_table(cfg),
        "",
        "## Headline",
        "",
        "Each cell: point estimate [95 % interval] (a value alone: nothing to resample, e.g. "
        "one run on one plant). cost / LQG: interquartile mean (IQM) and "
        "median over runs and test plants of the per-plant mean ratio to LQG on the same "
        "episodes, over the episodes that stayed bounded only, the whole episode (start-up "
        "included) and its steady window (the second half; before the jump in `jump:test`); "
        "score: the same for the normalised score (higher is better); diverged: share of "
        "episodes, beside them (a diverged episode's cost is the charge for leaving the "
        "bounds, not a control cost, and enters no ratio). Intervals: bootstrap over runs and "
        "plants. An RL run whose kept checkpoint is step 0 (training never improved on the "
        "untrained network) is left out of its agent's estimates and counted beside its name; "
        'an agent with no other run reads "no improvement over initialisation". '
        "Steps to <= 1.2x LQG: for RL the training steps after which its validation score "
        "stays within 1.2x of LQG (in-distribution scenarios only, and only for runs within "
        "1.2x on the test episodes too), for the self-tuning controllers the adaptation steps "
        "within an episode (median, with how many got there).",
        "",
    ]
    sentences = []
    family: list[tuple[str, dict[str, Any]]] = []  # the plant family's scenarios' tables
    family_stops: dict[str, Any] = {}
    statistics: dict[str, Any] = {}
    for sc in scenarios:
        if sc.name not in present:
            continue
        tables = scenario_tables(rows, sc.name, sc.episodes.units)
        tables = {c: tables[c] for c in order if c in tables}
        hl = headline(tables, reps=cfg.bootstrap_reps)
        statistics[sc.name] = dict(hl)
        stops = {
            c: training_stops([r for rs in t["rows"].values() for r in rs[:1]])
            for c, t in tables.items()
            if t["family"] == "rl"
        }
        pairs = [
            (a, b, paired(tables, a, b, reps=cfg.bootstrap_reps))
            for a in SELF_TUNING
            if a in tables
            for b in tables
            if tables[b]["family"] == "rl"
        ]
        untrained = untrained_runs(rows, sc.name)
        for c, (n, _) in untrained.items():  # saved beside the estimates (statistics.json)
            if n and c in hl:
                hl[c]["untrained_runs"] = n
            elif n:  # every run kept its untrained network: no estimate
                statistics[sc.name][c] = {"family": "rl", "runs": 0, "untrained_runs": n}
        table = _headline_table(hl, sc.kind == "jump", stops, untrained)
        out += [f"### `{sc.name}`", "", *table, ""]
        if sc.kind in ("family", "ladder"):
            out += strata_section(sc, tables, cfg.bootstrap_reps)
        if pairs:
            out += ["Paired on the same (plant, episode):", "", *_paired_table(pairs), ""]
        channels = _channel_table(rows, sc.name, order) if sc.env.plant_kind == "mimo" else []
        if channels:
            out += [
                "Per channel of the performance output (mean over runs and episodes): the RMS "
                "tracking error of each channel and the cross-channel disturbance, how far a "
                "channel's error moves within a reference hold after another channel's step.",
                "",
                *channels,
                "",
            ]
        sentences.append(_conclusion(sc.name, hl, pairs, stops))
        if sc.kind in ("family", "ood", "jump"):
            family.append((sc.name, tables))
            family_stops = family_stops or stops
    ladder = ladder_table(cfg, scenarios, statistics)
    if ladder:
        out += [
            "## The difficulty ladder",
            "",
            "Cost / LQG (IQM over the bounded episodes [95 % interval]), the share of "
            "diverged episodes and the runs kept at step 0, left out (where any) on each "
            "rung's test split, one feature added per "
            "rung (L1 stable, minimum phase, positive gain; L2 both gain signs; L3 "
            "nonminimum-phase zeros; L4 unstable poles: `stcgym.envs.families.LADDER`). The "
            "RL agents of a rung trained on its training split; on the family's test split "
            "they trained on the family's, with its parameter jumps.",
            "",
            *ladder,
            "",
        ]
    out += ["## Conclusions", "", *(s for s in sentences if s), ""]
    theta = InterfaceSpec(**cfg.algo_configs.get("theta_ppo", {}).get("interface", {}))
    answer = identification_or_design(
        family, reps=cfg.bootstrap_reps, stops=family_stops, estimator=theta.estimator
    )
    if answer:
        out += ["## Identification or design?", "", *answer, ""]
    if cfg.tuned:
        out += [
            "## Tuning",
            "",
            f"Optuna (TPE, seeded), {cfg.tune_trials} trials per study on the family's "
            "validation episodes (median cost / LQG); an RL trial trains for "
            f"{cfg.tune_fraction:g} of the agent's family cap. The best settings train every "
            "run of the agent and configure `stc_tuned`.",
            "",
            "| study | trials | best validation score | best settings |",
            "|---|---|---|---|",
            *(
                f"| {name} | {len(t['trials'])} | {number(t['best_value'])} | "
                f"{_settings(t['best_params'])} |"
                for name, t in cfg.tuned.items()
            ),
            "",
        ]
    training = _training_table(cfg, data)
    if training:
        out += [
            "## RL training",
            "",
            "Per training run: how it ended (plateau or cap), env steps used, the step of its "
            "last gain above the rule's minimum, its best validation score (median cost / LQG "
            "on the validation episodes), the step of the checkpoint kept (the best score's; "
            "0 is the untrained policy), the median over its recorded updates of SB3's "
            "approx_kl, clip_fraction and explained_variance (healthy PPO: about 0.01-0.03, "
            "0.05-0.2 and towards 1) and of the policy's entropy (minus SB3's entropy_loss; "
            "falling as the exploration narrows), `-` where not recorded, and its wall time "
            "(`learning_curves.csv`, `data_efficiency.png`).",
            "",
            *training,
            "",
        ]
    out += ["## Details per scenario", ""]
    for sc in scenarios:
        if sc.name in present:
            out += [f"### `{sc.name}`", "", *_detail_table(agg, sc.name, order), ""]
    argv = getattr(data, "argv", None)
    made_by = f" (`stcgym {' '.join(argv)}`)" if argv else ""
    out += [
        "## Figures",
        "",
        f"Made by this run{made_by}; 800 px wide, one colour per controller in every figure.",
        "",
        "- `data_efficiency.png`: left, the RL learning curves (median cost / LQG on the "
        "validation episodes against training env steps, median over runs with the range); "
        "right, the online learners within one episode (cost / LQG per window against the step, "
        "median over the test episodes and runs). Offline and online samples on separate axes.",
        "- `adaptation.png`: cumulative cost above LQG against the step within the episode "
        "(test split) and after the jump (`jump:test`), median with the interquartile band.",
        "- `traces_<scenario>.png`: output, reference and input of the first episode, one row "
        "per controller; `theta_jump_test.png`: a self-tuning controller's estimates against "
        "the true parameters across the jump.",
        "",
        "## Definitions",
        "",
        "- Windows: start = steps `[0, T/10)`, steady = `[T/2, T)` (with a jump at J: "
        "`[J/2, J)`), post-jump = `[J, T)`.",
        "- Steps to <= 1.2x and re-converge: the first step from which on the cost over every "
        "window of the reference's shortest hold stays within 1.2x of LQG's on the same "
        "episode (`stcgym.agents.evaluation.response.settling_step`); `never` when it does not.",
        "- CVaR25: mean of the worst quarter. `div.`: diverged episodes (charged their last cost "
        "until the end). Data steps: RL training steps, or the steps an online learner adapts "
        "on within the episode.",
        "",
    ]
    path = Path(run_dir) / "report.md"
    write_atomic(path, "\n".join(out))
    write_atomic(Path(run_dir) / "statistics.json", json.dumps(_jsonable(statistics), indent=1))
    return path


def _jsonable(x: Any) -> Any:
    """The report's estimates as JSON data (an :class:`Estimate` as ``{value, low, high}``;
    ``nan`` as ``null``, infinities as strings)."""
    if isinstance(x, Estimate):
        return _jsonable(dataclasses.asdict(x))
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return None if math.isnan(v) else (("inf" if v > 0 else "-inf") if math.isinf(v) else v)
    if isinstance(x, np.integer):
        return int(x)
    return x
