"""The report's view of the difficulty ladder: every controller across the rungs, and the
family's test plants by stratum (the last ladder feature each plant has)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

from stcgym.agents.benchmark.headline import STRATA, by_stratum, plant_strata

__all__ = ["diverged_share", "ladder_rows", "ladder_table", "strata_section"]


def diverged_share(share: float) -> str:
    """``"3 % div."``: a diverged share as a table cell prints it (one decimal below 1 %,
    so that a rare divergence does not read as none)."""
    percent = 100 * share
    return f"{percent:.0f} % div." if percent >= 1 else f"{percent:.1f} % div."


def ladder_table(cfg: Any, scenarios: Sequence[Any], statistics: dict[str, Any]) -> list[str]:
    """The difficulty ladder at a glance: each controller's cost / LQG (IQM over the bounded
    episodes, with its interval) and divergence rate (where not 0) on every rung's test
    split, the family's test split last when the family is the last rung's distribution."""
    from stcgym.envs.families import LADDER

    rungs = [(sc.name, sc.name.split(":")[0]) for sc in scenarios if sc.kind == "ladder"]
    if not rungs:
        return []
    if cfg.family in ("siso2-v1", LADDER[-1]) and "family:test" in statistics:
        rungs.append(("family:test", f"{LADDER[-1]} (family:test)"))
    rungs = [(name, label) for name, label in rungs if name in statistics]
    lines = [
        "| controller | " + " | ".join(label for _, label in rungs) + " |",
        "|---|" + "---|" * len(rungs),
    ]
    rows = ladder_rows(
        statistics, [name for name, _ in rungs],
        ratio=lambda est: est.format(3), diverged=lambda res: res["diverged"].value,
    )  # fmt: skip
    return lines + [f"| {c} | " + " | ".join(cells) + " |" for c, cells in rows]


def ladder_rows(
    statistics: dict[str, Any],
    columns: Sequence[str],
    *,
    ratio: Callable[[Any], str],
    diverged: Callable[[dict[str, Any]], float],
) -> list[tuple[str, list[str]]]:
    """``[(controller, cells)]`` of the ladder table over the scenarios ``columns``, every
    controller of any of them in order of appearance: ``-`` where it did not run, "no
    improvement over initialisation" where every run kept its untrained network, else its
    cost / LQG (``ratio`` writes the estimate), the diverged share where any and how many runs
    kept their untrained network (left out of the estimate) where any. ``ratio``
    and ``diverged`` read the statistics as the report holds them (estimates) or as
    ``statistics.json`` does (dicts)."""
    names = list(dict.fromkeys(c for s in columns for c in statistics[s]))
    rows = []
    for name in names:
        cells = []
        for s in columns:
            res = statistics[s].get(name)
            if res is None:
                cells.append("-")
            elif "ratio" not in res:
                cells.append("no improvement over initialisation")
            else:
                div, untrained = diverged(res), res.get("untrained_runs", 0)
                cells.append(
                    ratio(res["ratio"])
                    + (f"; {diverged_share(div)}" if div else "")
                    + (
                        f"; {untrained} of {res['runs'] + untrained} runs untrained"
                        if untrained
                        else ""
                    )
                )
        rows.append((name, cells))
    return rows


def strata_section(sc: Any, tables: dict[str, Any], reps: int) -> list[str]:
    """Cost / LQG and divergences by stratum of the family's plants (:data:`STRATA`), where
    the scenario's plants fall in more than one."""
    strata = plant_strata(sc.episodes.plants[:: sc.episodes.units[1]])
    present = [k for k in range(len(STRATA)) if (strata == k).any()]
    if len(present) < 2:
        return []
    cells = by_stratum(tables, strata, reps=reps)
    counts = [int((strata == k).sum()) for k in present]
    head = [f"{STRATA[k]} ({n} plant{'s' * (n > 1)})" for k, n in zip(present, counts, strict=True)]
    lines = [
        "By stratum of the test plants, each plant under the last ladder feature it has: "
        "cost / LQG, median over the bounded episodes [95 % interval], and the diverged share "
        "where any.",
        "",
        "| controller | " + " | ".join(head) + " |",
        "|---|" + "---|" * len(present),
    ]
    for c, per in cells.items():
        row = []
        for k in present:
            ratio, div = per[k]["ratio"], per[k]["diverged"].value
            diverged = diverged_share(div)
            if math.isnan(ratio.value):  # every episode of the stratum diverged
                row.append(diverged)
            else:
                row.append(ratio.format(3) + (f"; {diverged}" if div else ""))
        lines.append(f"| {c} | " + " | ".join(row) + " |")
    return [*lines, ""]
