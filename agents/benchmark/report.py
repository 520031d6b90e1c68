"""``report.md`` of a bench run: the headline with confidence intervals, then the details.

The headline answers three questions per scenario, each as a point estimate with a 95 %
stratified-bootstrap interval (:mod:`stcgym.agents.benchmark.statistics`, i.e. ``rliable``):

1. where does each controller end up: steady-state cost / the oracle's on the same episode
   (interquartile mean, IQM);
2. how much data does it need: environment steps until its cost stays within 1.2x of the
   oracle's (training steps for RL, read off the learning curve; adaptation steps within the
   episode for the self-tuning controller; median, with the share of runs that got there);
3. what happens after a change (``jump:*``): post-jump cost / the oracle's, and the steps until
   the cost stays within 1.2x of the oracle told the new parameters (``inf``, shown as "never",
   when it does not; median with the share of runs that recovered).

Whole-episode cost stays as a column, and the probability that each self-tuning controller
of the scenario (``stc``, ``stc_lq``, ``stc_kfmils``; ``stc_mimo`` on a MIMO plant) has the
lower cost (rliable's probability of improvement) is given against every other controller.

Next to each RL agent's figures the report says how its training ended, per training seed:
at the plateau of its learning curve or at the cap (:mod:`stcgym.agents.rl.stopping`), and at
which step its cost last improved by more than the rule's minimum. A conclusion that a
self-tuning controller beats an RL agent names, in the same sentence, the seeds of that agent
that reached the cap before a plateau.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from stcgym.agents.benchmark.evaluate import default_windows
from stcgym.agents.benchmark.headline import (
    SELF_TUNING,
    aggregate,
    headline,
    training_stops,
)
from stcgym.agents.benchmark.statistics import Estimate
from stcgym.agents.controllers import CONTROLLERS

__all__ = ["aggregate", "headline", "training_stops", "write_report"]

#: How the conclusions name the self-tuning controllers other than ``stc``.
_VARIANTS = {
    "stc_lq": "self-tuning LQ (stc_lq)",
    "stc_kfmils": "the self-tuning controller on the paper's KF-MILS estimator (stc_kfmils)",
    "stc_mimo": "the multivariable self-tuning LQ controller (stc_mimo)",
}


def _g(x: float | None, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    if abs(x) >= 10 ** (digits + 2):
        return f"{x:.2e}"
    return f"{x:.{digits}g}"


# ---------------------------------------------------------------------------------- headline
def _steps_range(values: Sequence[float]) -> str:
    v = [x for x in values if math.isfinite(x)]
    if not v:
        return "-"
    lo, hi = _k(min(v)), _k(max(v))
    return lo if lo == hi else f"{lo}-{hi}"


def _k(x: float) -> str:
    return f"{x / 1000:.3g}k" if x >= 1000 else f"{x:.0f}"


def _training_cell(res: dict[str, Any]) -> str:
    """``"plateau 2/3, cap 1/3; last gain at 40k-100k"`` (``-`` for a classical controller)."""
    t = res.get("training")
    if t is None:
        return "-"
    parts = [f"{k} {t[k]}/{t['seeds']}" for k in ("plateau", "cap") if t[k]]
    return f"{', '.join(parts) or '-'}; last gain at {_steps_range(t['last_improvement'])}"


def _still_improving(hl: dict[str, dict[str, Any]], agents: Sequence[str]) -> str:
    """``" (at the training cap before a plateau: sac in 3/3 seeds)"`` or ``""``: the seeds
    that the cap stopped before the plateau rule could (an agent that may still improve)."""
    capped = [
        f"{c} in {hl[c]['training']['cap']}/{hl[c]['training']['seeds']} seeds"
        for c in agents
        if hl[c].get("training", {}).get("cap")
    ]
    if not capped:
        return ""
    return f" (at the training cap before a plateau: {', '.join(capped)})"


def _converged(res: dict[str, Any]) -> str:
    """``" (trained to its plateau in 3/3 seeds)"`` when every seed stopped at its plateau."""
    t = res.get("training")
    if not t or t["plateau"] != t["seeds"]:
        return ""
    return f" (trained to its plateau in {t['plateau']}/{t['seeds']} seeds)"


def _cell(res: dict[str, Any], key: str, stat: str = "iqm") -> str:
    if key not in res:
        return "-"
    e: Estimate = res[key][stat]
    if key in ("steps_to_oracle", "reconverge_steps"):
        reached, cap = res[f"{key}_reached"], res[f"{key}_cap"]
        if reached == 0:
            return f"never (0/{res['runs']})"
        if 2 * reached <= res["runs"]:  # the median is (or averages in) a run that never did
            return f"> {_g(cap)} in half the runs or more ({reached}/{res['runs']})"
        return f"{e.format(3)} ({reached}/{res['runs']})"
    return e.format(3)


def _headline_table(hl: dict[str, dict[str, Any]], jump: bool) -> list[str]:
    cols = [
        "controller",
        "runs (div.)",
        "steady / oracle, IQM",
        "env steps to <= 1.2x oracle, median (reached)",
    ]
    if jump:
        cols += ["post-jump / oracle, IQM", "re-converge steps, median (recovered)"]
    tuners = [name for name in SELF_TUNING if name in hl]  # those of this scenario
    cols += ["episode cost, IQM", *(f"P({name} cost lower)" for name in tuners)]
    cols.append("RL training: stop (seeds); last > min. gain")
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for c, res in hl.items():
        div = f" ({res['failures']})" if res["failures"] else ""
        cells = [
            c,
            f"{res['runs']}{div}",
            _cell(res, "steady_ratio"),
            _cell(res, "steps_to_oracle", "median"),
        ]
        if jump:
            cells += [_cell(res, "post_jump_ratio"), _cell(res, "reconverge_steps", "median")]
        cells.append(_cell(res, "cost"))
        for key in (SELF_TUNING[name] for name in tuners):
            p = res.get(key)
            cells.append(p.format(2) if p is not None else "-")
        cells.append(_training_cell(res))
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _reach(res: dict[str, Any], key: str, verb: str, unit: str = "steps") -> str:
    """``"gets within 1.2x after 16 steps (median; 5/5 runs)"`` or ``"never gets ..."``."""
    reached, runs = res[f"{key}_reached"], res["runs"]
    if reached == 0:
        return f"never {verb} (0/{runs} runs)"
    med = res[key]["median"].value
    if 2 * reached <= runs:  # the median is (or averages in) a censored value
        return f"{verb} in no more than half of the runs ({reached}/{runs})"
    return f"{verb} after {_g(med)} {unit} (median; {reached}/{runs} runs)"


def _sentences(name: str, hl: dict[str, dict[str, Any]], jump: bool) -> str:
    parts = []
    stc = hl.get("stc")
    if stc is not None and "steady_ratio" in stc:
        parts.append(
            f"stc ends at {_g(stc['steady_ratio']['iqm'].value)}x the oracle's steady cost and "
            + _reach(stc, "steps_to_oracle", "gets within 1.2x", "adaptation steps")
        )
    variants = [ctl for ctl in _VARIANTS if ctl in hl]
    for ctl in variants:
        res = hl[ctl]
        if "steady_ratio" in res:
            parts.append(
                f"{_VARIANTS[ctl]} ends at {_g(res['steady_ratio']['iqm'].value)}x and "
                + _reach(res, "steps_to_oracle", "gets within 1.2x", "adaptation steps")
            )
    rl = {
        c: r
        for c, r in hl.items()
        if c not in CONTROLLERS and "steady_ratio" in r and "steps_to_oracle" in r
    }
    if rl:
        best = min(rl, key=lambda c: rl[c]["steady_ratio"]["iqm"].value)
        r = rl[best]
        parts.append(
            f"the best RL agent ({best}) ends at {_g(r['steady_ratio']['iqm'].value)}x and "
            + _reach(r, "steps_to_oracle", "gets within 1.2x", "training steps")
            + (_still_improving(hl, [best]) or _converged(r))
        )
    if jump and stc is not None and "post_jump_ratio" in stc:
        parts.append(
            f"after the jump stc runs at {_g(stc['post_jump_ratio']['iqm'].value)}x the "
            "informed oracle and " + _reach(stc, "reconverge_steps", "re-converges")
        )
    better = [c for c, r in hl.items() if r.get("poi") is not None and r["poi"].value > 0.5]
    if better:
        parts.append(
            f"stc has the lower episode cost more often than not against {', '.join(better)}"
            + _still_improving(hl, better)
        )
    # and where RL wins, said as plainly
    rl_wins = [
        c
        for c, r in hl.items()
        if "training" in r and r.get("poi") is not None and r["poi"].value < 0.5
    ]
    if rl_wins:
        trained = [c for c in rl_wins if _converged(hl[c])]
        parts.append(
            f"{', '.join(rl_wins)} {'has' if len(rl_wins) == 1 else 'have'} the lower episode "
            "cost than stc more often than not"
            + (f" ({', '.join(trained)} trained to the plateau in every seed)" if trained else "")
        )
    for ctl in variants:
        # against the RL agents only: a classical controller is never counted as one
        key = SELF_TUNING[ctl]
        rivals = [c for c, r in hl.items() if c not in CONTROLLERS and r.get(key) is not None]
        wins = [c for c in rivals if hl[c][key].value > 0.5]
        losses = [c for c in rivals if c not in wins]
        if rivals:
            parts.append(
                f"{ctl} has the lower episode cost more often than not against "
                f"{', '.join(wins) or 'no RL agent'}"
                + _still_improving(hl, wins)
                + (f", not against {', '.join(losses)}" if losses else "")
            )
    return f"- `{name}`: " + "; ".join(parts) + "." if parts else ""


# ---------------------------------------------------------------------------------- details
def _detail_table(agg, scenario: str, controllers: Sequence[str]) -> list[str]:
    cols = [
        "controller",
        "episode cost median [IQR]",
        "CVaR25",
        "start",
        "steady",
        "effort u^2",
        "bounded",
        "data steps",
        "train s",
        "us/step",
    ]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for c in controllers:
        st = agg.get((scenario, c))
        if st is None:
            continue
        lines.append(
            "| "
            + " | ".join(
                [
                    c,
                    f"{_g(st['cost']['median'])} [{_g(st['cost']['iqr'], 2)}]",
                    _g(st["cost"]["cvar25"]),
                    _g(st["cost_start"]["median"]),
                    _g(st["cost_steady"]["median"]),
                    _g(st["effort"]["median"]),
                    f"{st['runs'] - st['failures']}/{st['runs']}",
                    _g(st["data_steps"]["median"], 4),
                    _g(st["train_wall_s"]["median"], 3),
                    _g(st["step_us"]["median"], 3),
                ]
            )
            + " |"
        )
    return lines


def _step_table(agg, names: Sequence[str], controllers: Sequence[str]) -> list[str]:
    lines = [
        "| scenario | controller | overshoot % | settling steps | start-up settling steps |",
        "|---|---|---|---|---|",
    ]
    for s in names:
        for c in controllers:
            st = agg.get((s, c))
            if st is None:
                continue
            lines.append(
                f"| `{s}` | {c} | {_g(st['overshoot_pct']['median'], 3)} | "
                f"{_g(st['settling_steps']['median'])} | "
                f"{_g(st['startup_settling_steps']['median'])} |"
            )
    return lines


def _stop_text(stop: dict[str, Any] | None) -> str:
    if not stop:
        return "-"
    where = "plateau at" if stop["status"] == "plateau" else "cap"
    last = stop.get("last_improvement_step")
    gain = "-" if last is None else _k(float(last))
    return f"{where} {_k(float(stop['steps']))} (last gain {gain})"


def _curve_table(
    curves: Sequence[dict[str, Any]],
    lines_ref: dict[str, dict[str, float]],
    stops: dict[tuple[str, str, Any], dict[str, Any]],
):
    if not curves:
        return []
    out = [
        "| training env | agent | final curve cost / oracle, per training seed | "
        "training stop, per training seed | classical on the same episodes |",
        "|---|---|---|---|---|",
    ]
    for env, algo in sorted({(c["train_env"], c["algo"]) for c in curves}):
        final: dict[Any, float] = {}
        for c in curves:
            if c["train_env"] == env and c["algo"] == algo:
                final[c["train_seed"]] = c["cost_to_oracle"]  # rows in step order: keep last
        ref = lines_ref.get(env, {})
        oracle = ref.get("oracle")
        refs = ", ".join(f"{k} {_g(v / oracle) if oracle else _g(v)}" for k, v in ref.items())
        seeds = ", ".join(_g(final[s]) for s in sorted(final))
        ended = ", ".join(_stop_text(stops.get((env, algo, s))) for s in sorted(final))
        out.append(f"| `{env}` | {algo} | {seeds} | {ended} | {refs} |")
    return out


def _caps(cfg: Any) -> str:
    family = getattr(cfg, "family_train_steps", {}) or {}
    mimo = getattr(cfg, "mimo_train_steps", {}) if "mimo" in cfg.scenarios else {}
    caps = []
    for a, n in cfg.train_steps.items():
        f, m = family.get(a, n), mimo.get(a, n)
        where = ([f"on the family {f}"] if f != n else []) + ([f"on MIMO {m}"] if m != n else [])
        caps.append(f"{a} {n}" + (f" ({', '.join(where)})" if where else ""))
    return ", ".join(caps) or "-"


def _rule(cfg: Any) -> str:
    intervals = ", ".join(
        f"{a} {c.get('eval_interval')}" for a, c in getattr(cfg, "algo_configs", {}).items()
    )
    rule = cfg.plateau
    return rule.describe("eval_interval") + f" (eval_interval: {intervals or '-'})"


def write_report(
    run_dir: Path,
    cfg: Any,
    scenarios: Sequence[Any],
    rows: Sequence[dict[str, Any]],
    data: Any,
    wall_s: float,
    *,
    interrupted: bool = False,
    sessions: int = 1,
) -> Path:
    """Write ``report.md`` from the metric rows (also a partial one after an interrupt);
    ``wall_s`` is the run's wall time over its ``sessions`` (the first and each ``--resume``)."""
    from stcgym.agents.executors import write_atomic

    agg = aggregate(rows)
    names = [s.name for s in scenarios if any(r["scenario"] == s.name for r in rows)]
    controllers = [c for c in cfg.agents if any(r["controller"] == c for r in rows)]
    T = cfg.episode_steps
    w = default_windows(T)
    wj = default_windows(T, T // 2)
    budgets = _caps(cfg)
    out = [f"# stcgym bench: `{cfg.run}`", ""]
    if interrupted:
        out += ["**INTERRUPTED: partial results (the rows finished before the interrupt).**", ""]
    out += [
        f"Mode `{cfg.mode}`; {cfg.seeds} evaluation seeds (from {cfg.first_seed}) x "
        f"{cfg.train_seeds} training seeds per RL agent; episodes of {T} steps; output noise "
        f"std {cfg.noise_std}; cost per step `(y - r)^2 + {cfg.control_cost} u^2` "
        f"(the environments' reward); RL training caps (env steps): {budgets}. Wall time "
        f"{wall_s:.0f} s on {cfg.jobs} worker(s)"
        f"{f' over {sessions} sessions (resumed)' if sessions > 1 else ''}. Exact "
        "configuration: `config.json`; per-run numbers: `metrics.csv`.",
        "",
        "## Headline",
        "",
        "Each cell: point estimate [95 % confidence interval]. A run is one (training seed, "
        "evaluation seed) pair for an RL agent and one evaluation seed for the other "
        "controllers, so the intervals cover both training and evaluation variation; they are "
        f"rliable's stratified bootstrap ({cfg.bootstrap_reps} replications). IQM: mean of "
        "the middle 50 % of runs. All "
        "ratios are to the known-model oracle on the same episode (seed, noise, reference). "
        "Env steps to <= 1.2x: training steps for RL (learning curve), adaptation steps "
        "within the episode for the self-tuning controllers, 0 for a controller that starts "
        "there. P(stc cost lower), P(stc_lq cost lower), P(stc_kfmils cost lower), "
        "P(stc_mimo cost lower): probability that `stc` (the self-tuning controller with its "
        "defaults), `stc_lq` (self-tuning LQ), `stc_kfmils` (the self-tuning controller on the "
        "paper's KF-MILS estimator) or `stc_mimo` (multivariable self-tuning LQ, `mimo:*`) "
        "has the lower episode cost than that controller on a random pair of runs. "
        f"RL training: every agent trains until {_rule(cfg)}; the column says how many "
        "training seeds stopped at the plateau and how many at the cap (before a plateau), and "
        "at which training step the cost last gained more than the minimum.",
        "",
    ]
    sentences = []
    for name in names:
        jump = name.startswith("jump:")
        hl = headline(rows, name, controllers, jump=jump, reps=cfg.bootstrap_reps)
        out += [f"### `{name}`", "", *_headline_table(hl, jump), ""]
        line = _sentences(name, hl, jump)
        if line:
            sentences.append(line)
    out += ["## Conclusions", "", *sentences, ""]
    out += [
        "## Step response",
        "",
        "Medians over episodes (and training seeds) at the reference steps of the steady "
        "window; start-up: the first reference step. Settling: steps until |y - r| stays "
        "within 5 % of the step.",
        "",
        *_step_table(agg, names, controllers),
        "",
        "## Details per scenario",
        "",
    ]
    for name in names:
        out += [f"### `{name}`", "", *_detail_table(agg, name, controllers), ""]
    ct = _curve_table(data.curves, data.reference_lines, getattr(data, "stops", {}))
    if ct:
        out += [
            "## Learning curves",
            "",
            f"Deterministic policy at {cfg.curve_points} log-spaced points up to the first "
            "evaluation interval, then at every interval (the evaluations of the plateau "
            f"rule), on {cfg.curve_seeds} fixed episodes per training plant of "
            f"{cfg.train_episode_steps} steps (`learning_curves.csv`, `data_efficiency.png`). "
            "Training stop: where training ended (at the plateau or the cap) and the step of "
            "the last gain above the rule's minimum.",
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
        "- Steps to <= 1.2x and re-converge: the first step from which on the cost over every "
        "following reference period stays within 1.2x of the oracle's on the same episode "
        "(`stcgym.agents.benchmark.response.settling_step`); never reaching it reads `never`, "
        "not 0.",
        "- CVaR25: mean episode cost of the worst quarter of runs. `div.`: diverged runs "
        "(charged their last cost until the end).",
        "- Data steps: environment steps of RL training plus the steps an online learner adapts "
        "on (the self-tuning controller learns during the episode; the oracles know the model).",
        "- Window agents in `jump:*` are those trained on the pre-jump plant; recurrent agents "
        "(rppo) are trained on the family "
        f"({', '.join(cfg.family_train)}); the oracle is told the new parameters at the jump "
        "(lqg is not); in `family:*` the plant is held out.",
        "- `mimo:*`: a MIMO plant with measured state (`stcgym/StateSpace-v0`), cost "
        f"`||x - r||^2 + {cfg.control_cost} ||u||^2`; the oracle is LQR on the true (A, B); "
        "the SISO-only controllers and the recurrent agents do not run there.",
        "- RL training recipe: observation = window of past y, r, u (no plant state); training "
        "reward = compressed cost `log(1 + cost)`, a diverged episode charged until its end"
        + (f" (training bound |y| > {cfg.train_y_bound:g})" if cfg.train_y_bound else "")
        + "; the checkpoint with the lowest learning-curve cost (validation seeds, disjoint "
        "from the evaluation seeds) is kept.",
        "",
    ]
    path = Path(run_dir) / "report.md"
    write_atomic(path, "\n".join(out))
    return path
