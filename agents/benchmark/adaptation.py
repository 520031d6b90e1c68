"""How a controller's cost approaches the yardstick's within an episode, summarised per run.

The figures of a bench run (``data_efficiency.png``, right; ``adaptation.png``) show online
learning against the step within the episode. Per-step costs of every episode are too large to
keep in the results store (200 episodes x 1000 steps per run and scenario), so each run keeps
this summary of them instead, computed once when the run's episodes are scored:

* ``window``: the window cost ratio to LQG on the same episode, over consecutive windows of
  the reference's shortest hold (``span`` steps), median over the episodes;
* ``steps`` and ``excess_q25`` / ``excess_q50`` / ``excess_q75``: the cumulative cost above
  LQG's (from the episode's start, or from its jump when ``align``), quartiles over the
  episodes, at about 64 steps spaced logarithmically (the figures' axis is logarithmic).

The figures combine the runs of a controller with :func:`combine`: the median over runs of
each run's median, and the mean over runs of its quartiles for the band.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["GRID_POINTS", "combine", "log_grid", "summarize_adaptation", "window_ratio"]

#: Steps kept of the cumulative excess (spaced logarithmically from 1 to the episode's length).
GRID_POINTS = 64


def log_grid(length: int, points: int = GRID_POINTS) -> NDArray:
    """About ``points`` distinct steps ``1 .. length``, spaced logarithmically (1-based)."""
    if length < 1:
        return np.zeros(0, dtype=int)
    return np.unique(np.round(np.geomspace(1, length, points)).astype(int))


def window_ratio(cost: NDArray, ref: NDArray, span: int) -> tuple[NDArray, NDArray]:
    """Cost / reference over consecutive windows of ``span`` steps: (window ends, ratios)."""
    T = cost.shape[1]
    ends = np.arange(span, T + 1, span)
    c = np.add.reduceat(cost[:, : ends[-1]], np.arange(0, ends[-1], span), axis=1)
    r = np.add.reduceat(ref[:, : ends[-1]], np.arange(0, ends[-1], span), axis=1)
    return ends, c / np.maximum(r, 1e-12)


def _excess(cost: NDArray, ref: NDArray, jump_step: NDArray, align: bool) -> NDArray:
    """Cumulative cost above the reference per episode, ``(episodes, steps)``; from each
    episode's jump on with ``align`` (``nan`` past the episode's end, episodes without a jump
    left out)."""
    excess = cost - ref
    if not align:
        return np.cumsum(excess, axis=1)
    T = excess.shape[1]
    rows = []
    for i, J in enumerate(jump_step):
        if J >= 1:
            row = np.full(T, np.nan)
            row[: T - J] = np.cumsum(excess[i, J:])
            rows.append(row)
    return np.array(rows) if rows else np.zeros((0, T))


def summarize_adaptation(
    cost: NDArray, ref: NDArray, jump_step: NDArray, span: int, *, align: bool
) -> dict[str, Any]:
    """The summary of one run's per-step costs ``(episodes, steps)`` against the yardstick's
    (see the module docstring)."""
    cost, ref = np.asarray(cost, dtype=float), np.asarray(ref, dtype=float)
    _, ratios = window_ratio(cost, ref, span)
    ex = _excess(cost, ref, np.asarray(jump_step), align)
    live = ~np.all(np.isnan(ex), axis=0) if ex.size else np.zeros(0, dtype=bool)
    length = int(np.count_nonzero(live))
    steps = log_grid(length)
    out: dict[str, Any] = {"span": int(span), "window": np.median(ratios, axis=0).tolist()}
    out["steps"] = steps.tolist()
    if steps.size:
        q = np.nanpercentile(ex[:, steps - 1], [25, 50, 75], axis=0)
        out |= {f"excess_q{p}": q[i].tolist() for i, p in enumerate((25, 50, 75))}
    return out


def combine(summaries: Sequence[Mapping[str, Any]]) -> dict[str, NDArray]:
    """The runs of one controller together: ``window_ends``, ``window`` (median over runs),
    ``steps``, ``excess_q50`` (median over runs), ``excess_q25`` / ``excess_q75`` (means)."""
    runs = [s for s in summaries if s]
    if not runs:
        return {}
    span = int(runs[0]["span"])
    window = np.array([s["window"] for s in runs], dtype=float)
    out = {
        "window_ends": span * np.arange(1, window.shape[1] + 1),
        "window": np.median(window, axis=0),
    }
    with_excess = [s for s in runs if s.get("steps") and "excess_q50" in s]
    if with_excess:
        n = min(len(s["steps"]) for s in with_excess)  # the same grid unless lengths differ
        pick = lambda key: np.array([s[key][:n] for s in with_excess], dtype=float)  # noqa: E731
        out |= {
            "steps": np.asarray(with_excess[0]["steps"][:n]),
            "excess_q50": np.median(pick("excess_q50"), axis=0),
            "excess_q25": np.mean(pick("excess_q25"), axis=0),
            "excess_q75": np.mean(pick("excess_q75"), axis=0),
        }
    return out
