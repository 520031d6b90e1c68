"""The estimates behind ``report.md``, with the run as the unit.

:func:`scenario_tables` arranges a scenario's rows as arrays ``(runs, plants, episodes)`` per
controller (a run: one RL training seed, one self-tuning controller seed, the single run of a
deterministic controller) and :func:`headline` estimates, each with its 95 % interval
(:mod:`stcgym.agents.evaluation.statistics`):

* the cost ratio to the LQG yardstick on the same episode (whole episode, and the steady
  window: the second half, or before the jump) and the normalised score
  ``(C_zero - C) / (C_zero - C_LQG)``, over the episodes that stayed bounded only: the IQM
  (and for the whole episode the median) over (run, plant) of the per-plant means, with a
  bootstrap over runs and plants (:func:`~stcgym.agents.evaluation.statistics.
  bounded_estimates`);
* the divergence rate beside them, with its own interval (runs and plants resampled): a
  diverged episode's cost is the charge for leaving the bounds, not a control cost, so no
  statistic mixes the two;
* steps to get within 1.2x of LQG (RL: training steps read off the validation curve, for
  in-distribution scenarios only; online learners: adaptation steps within the episode),
  re-convergence steps after a jump, and the post-jump cost ratio: medians, with the share of
  runs or episodes that got there;
* paired comparisons (:func:`paired`) of every self-tuning controller with every RL agent on
  the same (plant, episode): the probability of the lower cost and the paired cost ratio.

:func:`aggregate` gives the plain per-column summaries of the report's details, and
:func:`training_stops` how each RL agent's training runs ended.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from stcgym.agents.evaluation.evaluate import summarize
from stcgym.agents.evaluation.statistics import (
    Estimate,
    bounded_estimates,
    paired_comparison,
    rate_estimate,
)

__all__ = [
    "DETAIL_COLUMNS",
    "SELF_TUNING",
    "aggregate",
    "as_float",
    "headline",
    "STRATA",
    "by_stratum",
    "paired",
    "plant_strata",
    "scenario_tables",
    "training_stops",
    "untrained_runs",
]

#: Columns summarised per (scenario, controller) in the report's details.
DETAIL_COLUMNS = (
    "cost",
    "cost_ratio",
    "cost_start",
    "cost_steady",
    "effort",
    "clip_frac",
    "data_steps",
    "train_wall_s",
    "step_us",
    "overshoot_pct",
    "settling_steps",
    "startup_settling_steps",
)

#: The self-tuning controllers, compared pairwise with every RL agent.
SELF_TUNING = ("stc", "stc_lq", "stc_kfmils", "stc_tuned", "stc_mimo")

_TABLE_COLUMNS = (
    "cost",
    "cost_ratio",
    "steady_ratio",
    "score",
    "post_jump_ratio",
    "steps_to_target",
    "reconverge_steps",
    "bounded",
)


def as_float(v: Any) -> float:
    """A metric cell as a number: ``nan`` where it is empty or not one."""
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def _groups(rows: Sequence[dict[str, Any]]) -> dict[tuple[str, str], list[dict[str, Any]]]:
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault((row["scenario"], row["controller"]), []).append(row)
    return groups


def scenario_tables(
    rows: Sequence[dict[str, Any]], scenario: str, units: tuple[int, int]
) -> dict[str, dict[str, Any]]:
    """``controller -> {"family", "runs", column: ndarray (runs, plants, episodes)}`` of one
    scenario; ``units`` is ``(plants, episodes per plant)`` of its episode set (rows of a run
    come in episode order, plant-major). Runs with missing episodes (an interrupted run) are
    left out."""
    P, E = units
    out: dict[str, dict[str, Any]] = {}
    for (sc, controller), rs in _groups(rows).items():
        if sc != scenario:
            continue
        by_run: dict[Any, list[dict[str, Any]]] = {}
        for r in rs:
            if not _untrained(r):  # the untrained network is no trained agent's cost
                by_run.setdefault(r["run"], []).append(r)
        runs = [k for k in sorted(by_run, key=as_float) if len(by_run[k]) == P * E]
        if not runs:
            continue
        table = {
            col: np.array(
                [[as_float(r.get(col)) for r in by_run[k]] for k in runs], dtype=float
            ).reshape(len(runs), P, E)
            for col in _TABLE_COLUMNS
        }
        out[controller] = {"family": rs[0]["family"], "runs": len(runs), "rows": by_run, **table}
    return out


def _untrained(row: dict[str, Any]) -> bool:
    """An RL run whose kept checkpoint is step 0: training never improved on the untrained
    network's validation score."""
    return row["family"] == "rl" and as_float(row.get("train_kept_step")) == 0


def untrained_runs(rows: Sequence[dict[str, Any]], scenario: str) -> dict[str, tuple[int, int]]:
    """``controller -> (untrained runs, runs)`` of the RL agents on ``scenario`` (runs kept at
    step 0 are left out of the estimates: "no improvement over initialisation")."""
    runs: dict[str, dict[Any, bool]] = {}
    for r in rows:
        if r["scenario"] == scenario and r["family"] == "rl":
            runs.setdefault(r["controller"], {})[r["run"]] = _untrained(r)
    return {c: (sum(flags.values()), len(flags)) for c, flags in runs.items()}


def _median_reached(values: np.ndarray) -> dict[str, Any]:
    """Median of step counts (``inf``: never) with the share that got there."""
    v = values[~np.isnan(values)]
    if v.size == 0:
        return {"median": math.nan, "reached": 0, "n": 0}
    order = np.sort(v)  # an order statistic: "never" counts as the largest value
    return {
        "median": float(order[(v.size - 1) // 2]),
        "reached": int(np.isfinite(v).sum()),
        "n": int(v.size),
    }


def _per_plant_bounded(table: dict[str, Any], col: str) -> np.ndarray:
    """``(runs, plants)``: the mean of ``col`` over each plant's bounded episodes (``nan``
    where none stayed bounded, or where the column is not defined)."""
    v = np.where(table["bounded"] > 0, table[col], np.nan)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a plant with no bounded episode
        return np.nanmean(v, axis=2)


def headline(
    tables: dict[str, dict[str, Any]], *, reps: int, seed: int = 0
) -> dict[str, dict[str, Any]]:
    """The estimates of one scenario (see the module docstring): ``controller -> {...}``.

    Keys: ``runs``, ``episodes`` (per run), ``ratio`` and ``ratio_median`` (cost / LQG over
    the bounded episodes), ``steady`` (the steady window's ratio) and ``score``
    (:class:`Estimate`, IQM over the bounded episodes), ``bounded_cells`` (the (run, plant)
    cells with a bounded episode), ``diverged`` (:class:`Estimate`), ``post_jump``
    (:class:`Estimate` or ``None``), ``to_target`` and ``reconverge``
    (:func:`_median_reached` dicts).
    """
    est = {
        c: {
            col: bounded_estimates(_per_plant_bounded(t, col), reps=reps, seed=seed)
            for col in ("cost_ratio", "steady_ratio", "score", "post_jump_ratio")
        }
        for c, t in tables.items()
    }
    out = {}
    for c, t in tables.items():
        targets = t["steps_to_target"]
        if t["family"] == "rl":
            targets = targets[:, 0, 0]  # one value per run (its training)
        out[c] = {
            "family": t["family"],
            "runs": t["runs"],
            "episodes": int(t["cost"][0].size),
            "ratio": est[c]["cost_ratio"]["iqm"],
            "ratio_median": est[c]["cost_ratio"]["median"],
            "bounded_cells": est[c]["cost_ratio"]["n"],
            "steady": est[c]["steady_ratio"]["iqm"],
            "score": est[c]["score"]["iqm"],
            "diverged": rate_estimate(1.0 - t["bounded"], reps=reps, seed=seed),
            "post_jump": post["iqm"] if (post := est[c]["post_jump_ratio"])["n"] else None,
            "to_target": _median_reached(np.ravel(targets)),
            "reconverge": _median_reached(np.ravel(t["reconverge_steps"])),
        }
    return out


#: The strata of a family's plants: the last feature of the difficulty ladder a plant has
#: (:data:`~stcgym.envs.families.LADDER`: L1's features, then a negative gain, a
#: nonminimum-phase zero, an unstable pole).
STRATA = ("L1: stable, minimum phase, gain > 0", "gain < 0", "nonminimum phase", "unstable")


def plant_strata(plants: Sequence[str]) -> np.ndarray:
    """The :data:`STRATA` index of each family plant, named ``<family>/<split>/<index>``."""
    from stcgym.envs.families import draw_plant, get_family, plant_features

    out = []
    for name in plants:
        family, _split, index = name.rsplit("/", 2)
        f = plant_features(draw_plant(get_family(family), int(index)))
        hardest = [True, f["dc_gain"] < 0, bool(f["nonminimum_phase"]), bool(f["unstable"])]
        out.append(max(i for i, has in enumerate(hardest) if has))
    return np.array(out, dtype=int)


def by_stratum(
    tables: dict[str, dict[str, Any]], strata: np.ndarray, *, reps: int, seed: int = 0
) -> dict[str, list[dict[str, Any] | None]]:
    """``controller -> [per stratum: {"ratio": Estimate (median over the bounded episodes),
    "diverged": Estimate, "plants": n} or None]`` from :func:`scenario_tables`' arrays;
    ``strata`` gives each plant's stratum (:func:`plant_strata`, the plants in table order)."""
    out: dict[str, list[dict[str, Any] | None]] = {}
    for c, t in tables.items():
        ratios = _per_plant_bounded(t, "cost_ratio")
        cells: list[dict[str, Any] | None] = []
        for k in range(len(STRATA)):
            mask = strata == k
            if not mask.any():
                cells.append(None)
                continue
            est = bounded_estimates(ratios[:, mask], reps=reps, seed=seed)
            diverged = rate_estimate(1.0 - t["bounded"][:, mask], reps=reps, seed=seed)
            cells.append({"ratio": est["median"], "diverged": diverged, "plants": int(mask.sum())})
        out[c] = cells
    return out


def paired(
    tables: dict[str, dict[str, Any]], a: str, b: str, *, reps: int, seed: int = 0
) -> dict[str, Estimate]:
    """``a`` against ``b`` on the same (plant, episode): ``{"probability", "ratio"}``."""
    comp = paired_comparison(tables[a]["cost"], tables[b]["cost"], reps=reps, seed=seed)
    return {"probability": comp.probability, "ratio": comp.ratio}


def aggregate(rows: Sequence[dict[str, Any]]) -> dict[tuple[str, str], dict[str, Any]]:
    """``(scenario, controller) -> {column: summarize(...)} plus row and failure counts``."""
    out = {}
    for key, rs in _groups(rows).items():
        failed = [not int(as_float(r["bounded"])) for r in rs]
        stats = {c: summarize([as_float(r.get(c)) for r in rs], failed) for c in DETAIL_COLUMNS}
        stats["rows"] = len(rs)
        stats["failures"] = int(sum(failed))
        stats["family"] = rs[0]["family"]
        out[key] = stats
    return out


def training_stops(rs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """How the training runs behind the rows ``rs`` (one RL agent) ended, one per run:
    ``{"seeds", "plateau", "cap", "steps", "last_improvement"}`` (step lists by run)."""
    per_run = {r["run"]: r for r in rs}
    runs = [per_run[k] for k in sorted(per_run, key=as_float)]
    status = [str(r.get("train_stop", "")) for r in runs]
    return {
        "seeds": len(runs),
        "plateau": status.count("plateau"),
        "cap": status.count("cap"),
        "steps": [as_float(r["train_steps"]) for r in runs],
        "last_improvement": [as_float(r.get("train_last_improvement")) for r in runs],
    }
