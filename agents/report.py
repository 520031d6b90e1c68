"""``report.md`` of a bench run: tables and one-line conclusions computed from the numbers."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from stcgym.agents.evaluate import default_windows, summarize

__all__ = ["aggregate", "conclusions", "write_report"]

_STATS_COLUMNS = (
    "cost",
    "cost_start",
    "cost_steady",
    "cost_post_jump",
    "reconverge_steps",
    "effort",
    "data_steps",
    "train_wall_s",
    "step_us",
)


def _g(x: float, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    if math.isinf(x):
        return "inf"
    if abs(x) >= 10 ** (digits + 2):
        return f"{x:.2e}"
    return f"{x:.{digits}g}"


def aggregate(rows: Sequence[dict[str, Any]]) -> dict[tuple[str, str], dict[str, Any]]:
    """``(scenario, controller) -> {column: summarize(...)} plus failure counts``."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault((row["scenario"], row["controller"]), []).append(row)
    out = {}
    for key, rs in groups.items():
        failed = [not int(r["bounded"]) for r in rs]
        stats = {c: summarize([float(r[c]) for r in rs], failed) for c in _STATS_COLUMNS}
        stats["runs"] = len(rs)
        stats["failures"] = int(sum(failed))
        stats["family"] = rs[0]["family"]
        out[key] = stats
    return out


def _med(stats: dict[str, Any], col: str) -> float:
    return stats[col]["median"]


def conclusions(agg: dict[tuple[str, str], dict[str, Any]], scenarios: Sequence[str]) -> list[str]:
    """Plain statements read off the medians (whole-episode cost and steady-state cost)."""
    lines = []
    wins = losses = 0
    for sc in scenarios:
        ctrls = {c: s for (name, c), s in agg.items() if name == sc}
        if not ctrls:
            continue
        ranked = sorted(ctrls, key=lambda c: _med(ctrls[c], "cost"))
        best = ranked[0]
        parts = [f"best median episode cost: **{best}** ({_g(_med(ctrls[best], 'cost'))})"]
        if "stc" in ctrls:
            stc = _med(ctrls["stc"], "cost")
            parts.append(
                f"stc {_g(stc)}"
                + (
                    f" ({_g(stc / _med(ctrls[best], 'cost'), 2)}x best)"
                    if best != "stc" and _med(ctrls[best], "cost") > 0
                    else ""
                )
            )
            rl = [c for c in ctrls if ctrls[c]["family"] == "rl"]
            better = [c for c in rl if _med(ctrls[c], "cost") < stc]
            worse = [c for c in rl if c not in better]
            wins += len(worse)
            losses += len(better)
            if better:
                parts.append(f"{', '.join(better)} beat{'s' if len(better) == 1 else ''} stc")
            if worse:
                parts.append(f"stc beats {', '.join(worse)}")
            steady_rl = [
                c for c in rl if _med(ctrls[c], "cost_steady") < _med(ctrls["stc"], "cost_steady")
            ]
            if steady_rl:
                parts.append(f"in steady state {', '.join(steady_rl)} beat stc")
        fails = [
            f"{c} {ctrls[c]['failures']}/{ctrls[c]['runs']}" for c in ranked if ctrls[c]["failures"]
        ]
        if fails:
            parts.append("diverged: " + ", ".join(fails))
        lines.append(f"- `{sc}`: " + "; ".join(parts) + ".")
    if wins + losses:
        lines.append(
            f"- Overall the self-tuning controller has the lower median episode cost in {wins} of "
            f"{wins + losses} (RL agent, scenario) pairs."
        )
    return lines


def _main_table(agg, scenarios: Sequence[str], controllers: Sequence[str]) -> list[str]:
    head = "| controller | " + " | ".join(f"`{s}`" for s in scenarios) + " |"
    lines = [head, "|" + "---|" * (len(scenarios) + 1)]
    for c in controllers:
        cells = []
        for s in scenarios:
            st = agg.get((s, c))
            if st is None:
                cells.append("")
                continue
            cell = f"{_g(st['cost']['median'])} [{_g(st['cost']['iqr'], 2)}]"
            if st["failures"]:
                cell += f" ({st['failures']}/{st['runs']} div.)"
            cells.append(cell)
        lines.append(f"| {c} | " + " | ".join(cells) + " |")
    return lines


def _scenario_table(agg, scenario: str, controllers: Sequence[str], jump: bool) -> list[str]:
    cols = [
        "controller",
        "cost median [IQR]",
        "CVaR25",
        "start",
        "steady",
    ]
    if jump:
        cols += ["post-jump", "re-converge (steps)"]
    cols += ["effort u^2", "bounded", "data steps", "train s", "us/step"]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for c in controllers:
        st = agg.get((scenario, c))
        if st is None:
            continue
        cells = [
            c,
            f"{_g(_med(st, 'cost'))} [{_g(st['cost']['iqr'], 2)}]",
            _g(st["cost"]["cvar25"]),
            _g(_med(st, "cost_start")),
            _g(_med(st, "cost_steady")),
        ]
        if jump:
            cells += [_g(_med(st, "cost_post_jump")), _g(_med(st, "reconverge_steps"))]
        cells += [
            _g(_med(st, "effort")),
            f"{st['runs'] - st['failures']}/{st['runs']}",
            _g(_med(st, "data_steps"), 4),
            _g(_med(st, "train_wall_s"), 3),
            _g(_med(st, "step_us"), 3),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _curve_table(curves: Sequence[dict[str, Any]], lines_ref: dict[str, dict[str, float]]):
    if not curves:
        return []
    out = [
        "| training env | agent | final curve cost (median over seeds) | classical on the same "
        "episodes |",
        "|---|---|---|---|",
    ]
    keys = sorted({(c["train_env"], c["algo"]) for c in curves})
    for env, algo in keys:
        final = {}
        for c in curves:
            if c["train_env"] == env and c["algo"] == algo:
                final[c["train_seed"]] = c["cost"]  # rows are in step order: keep the last
        ref = ", ".join(f"{k} {_g(v)}" for k, v in lines_ref.get(env, {}).items())
        out.append(f"| `{env}` | {algo} | {_g(float(np.median(list(final.values()))))} | {ref} |")
    return out


def write_report(
    run_dir: Path,
    cfg: Any,
    scenarios: Sequence[Any],
    rows: Sequence[dict[str, Any]],
    curves: Sequence[dict[str, Any]],
    reference_lines: dict[str, dict[str, float]],
    wall_s: float,
    *,
    interrupted: bool = False,
) -> Path:
    """Write ``report.md`` from the metric rows (also a partial one after an interrupt)."""
    agg = aggregate(rows)
    names = [s.name for s in scenarios if any(r["scenario"] == s.name for r in rows)]
    controllers = list(dict.fromkeys([a for a in cfg.agents]))
    controllers = [c for c in controllers if any(r["controller"] == c for r in rows)]
    T = cfg.episode_steps
    w = default_windows(T)
    wj = default_windows(T, T // 2)
    budgets = ", ".join(f"{a} {n}" for a, n in cfg.train_steps.items()) or "-"
    out = [f"# stcgym bench: `{cfg.run}`", ""]
    if interrupted:
        out += ["**INTERRUPTED: partial results (the rows finished before the interrupt).**", ""]
    out += [
        f"Mode `{cfg.mode}`; {cfg.seeds} evaluation seeds (from {cfg.first_seed}), "
        f"{cfg.train_seeds} training seed(s) per RL agent; episodes of {T} steps; output noise "
        f"std {cfg.noise_std}; cost per step `(y - r)^2 + {cfg.control_cost} u^2` "
        f"(the environments' reward); RL training budgets (env steps): {budgets}. Wall time "
        f"{wall_s:.0f} s. Exact configuration: `config.json`; per-run numbers: `metrics.csv`.",
        "",
        "## Median episode cost [IQR]",
        "",
        "Mean cost per step over the whole episode, median over seeds (and RL training seeds); "
        "lower is better. `div.`: runs that diverged (charged their last cost until the end).",
        "",
        *_main_table(agg, names, controllers),
        "",
        "## Conclusions",
        "",
        *conclusions(agg, names),
        "",
    ]
    for name in names:
        jump = name.startswith("jump:")
        out += [f"### `{name}`", "", *_scenario_table(agg, name, controllers, jump), ""]
    ct = _curve_table(curves, reference_lines)
    if ct:
        out += [
            "## Learning curves",
            "",
            f"Deterministic policy every 1/{cfg.curve_points} of the budget on "
            f"{cfg.curve_seeds} fixed episodes per training plant of {cfg.train_episode_steps} "
            "steps (`learning_curves.csv`, `learning_curves.png`).",
            "",
            *ct,
            "",
        ]
    out += [
        "## Definitions",
        "",
        f"- Windows (steps): start {w.start[0]}-{w.start[1]}, steady {w.steady[0]}-{w.steady[1]}; "
        f"with the jump at {wj.jump_step}: steady (pre-jump) {wj.steady[0]}-{wj.steady[1]}, "
        f"post-jump {wj.post_jump[0]}-{wj.post_jump[1]}.",
        "- CVaR25: mean episode cost of the worst quarter of runs.",
        "- Re-converge: steps after the jump until the mean cost of every following reference "
        "period stays below 1.1 x max(pre-jump steady cost, final post-jump cost).",
        "- Data steps: environment steps of RL training plus the steps an online learner adapts "
        "on (the self-tuning controller learns during the episode; the oracles know the model).",
        "- us/step: wall time of one `predict` call; train s: RL training wall time.",
        "- RL agents in `jump:*` are those trained on the pre-jump plant; the oracle is told the "
        "new parameters at the jump (lqg is not); in `family:*` RL was trained on "
        f"{', '.join(cfg.family_train)} and the plant is held out.",
        "- RL training recipe: observation = window of past y, r, u (no plant state); training "
        "reward = compressed cost `log(1 + cost)`, a diverged episode charged until its end"
        + (f" (training bound |y| > {cfg.train_y_bound:g})" if cfg.train_y_bound else "")
        + "; the checkpoint with the lowest learning-curve cost (validation seeds, disjoint "
        "from the evaluation seeds) is kept.",
        "",
    ]
    path = Path(run_dir) / "report.md"
    path.write_text("\n".join(out))
    return path
