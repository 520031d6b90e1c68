"""The estimates behind ``report.md``: per-scenario headline figures with stratified-bootstrap
intervals (:func:`headline`), per-column summaries (:func:`aggregate`) and how each RL agent's
training ended (:func:`training_stops`). :mod:`stcgym.agents.benchmark.report` writes them out.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from stcgym.agents.benchmark.evaluate import summarize
from stcgym.agents.benchmark.statistics import interval_estimates, probability_of_improvement

__all__ = ["DETAIL_COLUMNS", "SELF_TUNING", "aggregate", "headline", "training_stops"]

#: Columns summarised per (scenario, controller) in the report's details.
DETAIL_COLUMNS = (
    "cost",
    "cost_start",
    "cost_steady",
    "effort",
    "data_steps",
    "train_wall_s",
    "step_us",
    "overshoot_pct",
    "settling_steps",
    "startup_settling_steps",
)

#: The self-tuning controllers given against every other controller, each with the key of its
#: probability of the lower episode cost in :func:`headline` (and a column of the headline).
SELF_TUNING = {name: "poi" + name[3:] for name in ("stc", "stc_lq", "stc_kfmils", "stc_mimo")}


def _float(v: Any) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def _groups(rows: Sequence[dict[str, Any]]) -> dict[tuple[str, str], list[dict[str, Any]]]:
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault((row["scenario"], row["controller"]), []).append(row)
    return groups


def aggregate(rows: Sequence[dict[str, Any]]) -> dict[tuple[str, str], dict[str, Any]]:
    """``(scenario, controller) -> {column: summarize(...)} plus run and failure counts``."""
    out = {}
    for key, rs in _groups(rows).items():
        failed = [not int(r["bounded"]) for r in rs]
        stats = {c: summarize([_float(r.get(c)) for r in rs], failed) for c in DETAIL_COLUMNS}
        stats["runs"] = len(rs)
        stats["failures"] = int(sum(failed))
        stats["family"] = rs[0]["family"]
        out[key] = stats
    return out


def _censor(values: np.ndarray, cap: float) -> np.ndarray:
    # "never" (inf) counts as the largest possible value: order statistics stay right and the
    # bootstrap gets finite numbers.
    return np.where(np.isfinite(values), values, cap)


def headline(
    rows: Sequence[dict[str, Any]],
    scenario: str,
    controllers: Sequence[str],
    *,
    jump: bool,
    reps: int,
) -> dict[str, dict[str, Any]]:
    """Estimates of one scenario: ``controller -> {metric: Estimate, ...}`` (see the module).

    Step counts that never reach the tolerance (``inf``) are censored at the largest value
    that could have been observed (the episode part or the training budget); the count of
    runs that did reach it is reported next to them.
    """
    groups = _groups(rows)
    cols = ["steady_ratio", "cost", "steps_to_oracle"] + (
        ["post_jump_ratio", "reconverge_steps"] if jump else []
    )
    data: dict[str, np.ndarray] = {}
    extra: dict[str, dict[str, Any]] = {}
    for c in controllers:
        rs = groups.get((scenario, c))
        if not rs:
            continue
        table = np.array([[_float(r.get(k)) for k in cols] for r in rs])
        info: dict[str, Any] = {"runs": len(rs), "failures": sum(not int(r["bounded"]) for r in rs)}
        if rs[0]["family"] == "rl":
            info["training"] = training_stops(rs)
        for j, k in enumerate(cols):
            v = table[:, j]
            if k in ("steps_to_oracle", "reconverge_steps"):
                cap = _step_cap(rs, k)
                info[f"{k}_reached"] = int(np.sum(np.isfinite(v)))
                info[f"{k}_cap"] = cap
                table[:, j] = _censor(v, cap)
            else:
                # a diverged run has an infinite ratio at worst: the largest finite one stands in
                finite = v[np.isfinite(v)]
                table[:, j] = np.where(np.isfinite(v), v, finite.max() if finite.size else math.nan)
        keep = np.all(np.isfinite(table), axis=0)
        info["cols"] = [k for k, ok in zip(cols, keep, strict=True) if ok]
        data[c] = table[:, keep]
        extra[c] = info
    est = interval_estimates(data, reps=reps) if data else {}
    costs = {
        c: data[c][:, extra[c]["cols"].index("cost")] for c in data if "cost" in extra[c]["cols"]
    }
    # probability that each self-tuning controller has the lower episode cost than every other
    poi = {
        name: probability_of_improvement(costs, name, reps=reps)
        if name in costs and len(costs) > 1
        else {}
        for name in SELF_TUNING
    }
    out = {}
    for c, info in extra.items():
        res = dict(info)
        for j, k in enumerate(info["cols"]):
            res[k] = {"iqm": est[c]["iqm"][j], "median": est[c]["median"][j]}
        for name, key in SELF_TUNING.items():
            res[key] = poi[name].get(c)
        out[c] = res
    return out


def training_stops(rs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """How the training runs behind the rows ``rs`` (one RL agent) ended, one per train seed:
    ``{"seeds", "plateau", "cap", "steps", "last_improvement"}`` (step lists by seed)."""
    per_seed = {r["train_seed"]: r for r in rs}
    runs = [per_seed[k] for k in sorted(per_seed, key=str)]
    status = [str(r.get("train_stop", "")) for r in runs]
    return {
        "seeds": len(runs),
        "plateau": status.count("plateau"),
        "cap": status.count("cap"),
        "steps": [_float(r["train_steps"]) for r in runs],
        "last_improvement": [_float(r.get("train_last_improvement")) for r in runs],
    }


def _step_cap(rs: Sequence[dict[str, Any]], key: str) -> float:
    if key == "steps_to_oracle" and rs[0]["family"] == "rl":
        return max(_float(r["train_steps"]) for r in rs)
    T = max(_float(r["steps_run"]) for r in rs)
    if key == "reconverge_steps":
        return float(T // 2)  # the jump is at T/2
    return float(T if rs[0]["kind"] != "jump" else T // 2)
