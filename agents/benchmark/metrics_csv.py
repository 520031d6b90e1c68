"""``metrics.csv`` of a ``stcgym bench`` run: its columns, the writer (a run's rows at a time,
flushed), and the cost ratio every row is scored by."""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path
from typing import Any

__all__ = ["METRIC_COLUMNS", "TOLERANCE", "MetricsWriter", "format_value", "ratio"]

#: Columns of ``metrics.csv``, in order: one row per scenario, controller, run and episode.
METRIC_COLUMNS = [
    "scenario",
    "kind",
    "plant",
    "controller",
    "family",
    "run",
    "seed",
    "jump_step",
    "cost",
    "cost_ratio",
    "score",
    "cost_start",
    "cost_steady",
    "steady_ratio",
    "cost_post_jump",
    "post_jump_ratio",
    "reconverge_steps",
    "steps_to_target",
    "effort",
    "bounded",
    "steps_run",
    "clip_frac",
    "overshoot_pct",
    "settling_steps",
    "startup_settling_steps",
    "track_rms_1",
    "track_rms_2",
    "cross_peak",
    "data_steps",
    "train_steps",
    "train_cap",
    "train_stop",
    "train_last_improvement",
    "train_kept_step",
    "train_wall_s",
    "step_us",
]

#: Allowed cost ratio to the yardstick in ``steps_to_target`` and ``reconverge_steps``.
TOLERANCE = 1.2


class MetricsWriter:
    """Append rows to ``metrics.csv``, flushed to disk one by one."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.rows: list[dict[str, Any]] = []
        new = not path.exists() or path.stat().st_size == 0
        self._fh = open(path, "a", newline="")  # noqa: SIM115  (kept open for the whole run)
        self._csv = csv.DictWriter(self._fh, METRIC_COLUMNS, extrasaction="ignore")
        if new:
            self._csv.writeheader()
            self._flush()

    def _flush(self) -> None:
        self._fh.flush()
        os.fsync(self._fh.fileno())

    def write(self, rows: list[dict[str, Any]]) -> None:
        """Append ``rows`` (one controller run's episodes) and flush them to disk."""
        for row in rows:
            self._csv.writerow({k: format_value(row.get(k, "")) for k in METRIC_COLUMNS})
        self._flush()
        self.rows.extend(rows)

    def close(self) -> None:
        self._fh.close()


def format_value(v: Any) -> Any:
    """A CSV cell: floats with 6 significant digits, ``nan`` as an empty cell."""
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v:.6g}"
    return v


def ratio(x: float, ref: float | None) -> float:
    """``x / ref``; ``nan`` without a reference, ``inf`` for a diverged ``x`` or a zero ``ref``."""
    if ref is None or not math.isfinite(x) or not ref > 0:
        return math.nan if ref is None or math.isnan(x) or math.isnan(ref) else math.inf
    return x / ref
