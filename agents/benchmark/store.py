"""The results store of a ``stcgym bench`` run: one compact record per finished job, as data.

A run's outcome is what its report, tables and figures are rendered from, and nothing else:

* one :class:`JobRecord` per finished job (a classical controller's run on a scenario, or an RL
  training run with its evaluations), kept in ``<run>/store/`` as gzip-compressed JSON under
  an id of the settings that shape it (:func:`record_path`). A record holds, per scenario it
  was scored on, the ``metrics.csv`` rows of its episodes (columnar; a column that is the same
  on every row is kept once), the compact adaptation summary the figures draw
  (:mod:`~stcgym.agents.benchmark.adaptation`), the first episode's signals (run 0 only),
  and for an RL run its learning curve, update diagnostics and how training stopped;
* ``config.json`` beside it: the settings and the run plan's measured values (action bounds
  and units).

A record is written atomically when its job finishes, so a run cut at any moment leaves a
readable store; ``stcgym bench --resume`` reads the records whose ids the plan asks for and
runs the rest, and ``stcgym report`` renders a store without training. Per-step cost arrays
and trained models are not part of the store (they stay in the run folder's ``models/``,
optional). A whole standard run's store is a few MB, small enough to commit.

The format is plain JSON: numbers (floats to 6 significant digits, as in ``metrics.csv``),
strings, ``null`` for a missing value (``nan``) and the strings ``"inf"`` / ``"-inf"``.
"""

from __future__ import annotations

import gzip
import json
import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import quote

import numpy as np

__all__ = [
    "SCHEMA",
    "STORE_FOLDER",
    "JobRecord",
    "ResultsStore",
    "ScenarioResult",
    "decode_rows",
    "encode_rows",
    "record_path",
]

#: The store's folder inside a run folder.
STORE_FOLDER = "store"
#: The version of the record format; a record of another version is not read (run again).
SCHEMA = 1
#: Significant digits kept of a float (those of ``metrics.csv``).
DIGITS = 6


def _value(v: Any) -> Any:
    """One value as JSON data: floats rounded, ``nan`` as ``None``, infinities as strings."""
    if isinstance(v, (np.integer, bool, np.bool_)):
        return int(v) if not isinstance(v, (bool, np.bool_)) else bool(v)
    if isinstance(v, (float, np.floating)):
        x = float(v)
        if math.isnan(x):
            return None
        if math.isinf(x):
            return "inf" if x > 0 else "-inf"
        return float(f"{x:.{DIGITS}g}")
    if isinstance(v, np.ndarray):
        return [_value(x) for x in v.tolist()]
    if isinstance(v, (list, tuple)):
        return [_value(x) for x in v]
    if isinstance(v, Mapping):
        return {str(k): _value(x) for k, x in v.items()}
    return v


def _float(v: Any) -> float:
    """The inverse of :func:`_value` for a number."""
    if v is None:
        return math.nan
    if v == "inf":
        return math.inf
    if v == "-inf":
        return -math.inf
    return float(v)


#: Columns whose cells are numbers (read back as floats; ``""`` in ``metrics.csv`` is ``nan``).
_TEXT_COLUMNS = ("scenario", "kind", "plant", "controller", "family", "train_stop")


def encode_rows(rows: Sequence[Mapping[str, Any]], columns: Sequence[str]) -> dict[str, Any]:
    """``rows`` (dicts of one job on one scenario) as columns: ``{"n": rows, "const": {column:
    value}, "cols": {column: [values]}}``, a column equal on every row kept once."""
    const: dict[str, Any] = {}
    cols: dict[str, list[Any]] = {}
    for c in columns:
        values = [_value(r.get(c, "")) for r in rows]
        if values and all(v == values[0] for v in values):
            const[c] = values[0]
        else:
            cols[c] = values
    return {"n": len(rows), "const": const, "cols": cols}


def _cell(column: str, v: Any) -> Any:
    """A decoded cell: text as it is, ``None`` and the infinities back to floats."""
    if column in _TEXT_COLUMNS or v == "":
        return v
    if v is None or v in ("inf", "-inf"):
        return _float(v)
    return v


def decode_rows(data: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The rows :func:`encode_rows` encoded."""
    n = int(data["n"])
    rows = [dict() for _ in range(n)]
    for c, v in data["const"].items():
        cell = _cell(c, v)
        for row in rows:
            row[c] = cell
    for c, values in data["cols"].items():
        for row, v in zip(rows, values, strict=True):
            row[c] = _cell(c, v)
    return rows


@dataclass
class ScenarioResult:
    """One job's outcome on one scenario.

    ``rows``: the ``metrics.csv`` rows of its episodes; ``adaptation``: the summary of its
    per-step costs against the yardstick's (:func:`~stcgym.agents.benchmark.adaptation.
    summarize_adaptation`); ``trace``: the first episode's ``y``, ``r``, ``u`` (and ``theta``,
    ``theta_hat`` for a self-tuning controller), kept for run 0 only.
    """

    rows: list[dict[str, Any]]
    adaptation: dict[str, Any] = field(default_factory=dict)
    trace: dict[str, Any] = field(default_factory=dict)

    def to_dict(self, columns: Sequence[str]) -> dict[str, Any]:
        return {
            "rows": encode_rows(self.rows, columns),
            "adaptation": _value(self.adaptation),
            "trace": _value(self.trace),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ScenarioResult:
        return cls(decode_rows(data["rows"]), dict(data["adaptation"]), dict(data["trace"]))


@dataclass
class JobRecord:
    """A finished job of a bench run, as the store keeps it.

    ``kind``: ``"classical"`` or ``"rl"``; ``label``: a readable name (``"family:test.stc.run0"``,
    ``"family_ppo_s0"``); ``id``: the hash of ``settings``, everything that shapes the result;
    ``scenarios``: scenario name -> :class:`ScenarioResult`. RL runs also carry ``curve``
    (``[(step, validation score), ...]``), ``diagnostics`` (SB3's update statistics at each
    evaluation, where recorded), ``stop`` (how training ended, with ``kept_step``: the step of
    the checkpoint kept, 0 for the untrained policy), ``train_key``, ``algo``, ``seed`` and
    ``wall_s``.
    """

    kind: str
    label: str
    id: str
    settings: dict[str, Any]
    scenarios: dict[str, ScenarioResult]
    curve: list[tuple[int, float]] = field(default_factory=list)
    diagnostics: list[dict[str, Any]] = field(default_factory=list)
    stop: dict[str, Any] = field(default_factory=dict)
    train_key: str = ""
    algo: str = ""
    seed: int = 0
    wall_s: float = 0.0

    def to_dict(self, columns: Sequence[str]) -> dict[str, Any]:
        return {
            "schema": SCHEMA,
            "kind": self.kind,
            "label": self.label,
            "id": self.id,
            "settings": self.settings,
            "scenarios": {k: v.to_dict(columns) for k, v in self.scenarios.items()},
            "curve": [[int(s), _value(c)] for s, c in self.curve],
            "diagnostics": _value(self.diagnostics),
            "stop": _value(self.stop),
            "train_key": self.train_key,
            "algo": self.algo,
            "seed": int(self.seed),
            "wall_s": _value(self.wall_s),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> JobRecord:
        if data.get("schema") != SCHEMA:
            raise ValueError(f"record schema {data.get('schema')!r}, this version reads {SCHEMA}")
        return cls(
            kind=data["kind"],
            label=data["label"],
            id=data["id"],
            settings=dict(data["settings"]),
            scenarios={k: ScenarioResult.from_dict(v) for k, v in data["scenarios"].items()},
            curve=[(int(s), _float(c)) for s, c in data["curve"]],
            diagnostics=list(data["diagnostics"]),
            stop=dict(data["stop"]),
            train_key=data["train_key"],
            algo=data["algo"],
            seed=int(data["seed"]),
            wall_s=_float(data["wall_s"]),
        )


def _id_of(path: Path) -> str:
    """The id in a record's file name (:func:`record_path`)."""
    return path.name.split(".")[-3]


def _read(path: Path) -> JobRecord | None:
    """The record in ``path``, or ``None`` when it is unreadable (damaged, or another schema)."""
    try:
        return JobRecord.from_dict(json.loads(gzip.decompress(path.read_bytes())))
    except (OSError, ValueError, KeyError, TypeError, EOFError):
        return None


def record_path(folder: Path, label: str, rid: str) -> Path:
    """Where the record ``rid`` of job ``label`` is kept."""
    return Path(folder) / f"{quote(label, safe='')}.{rid}.json.gz"


class ResultsStore:
    """The records of one run folder's ``store/``.

    Parameters
    ----------
    folder : path
        The store's folder (``<run>/store``); created on the first :meth:`save`.
    columns : sequence of str
        The row columns a record keeps (``metrics.csv``'s).
    """

    def __init__(self, folder: str | Path, columns: Sequence[str]) -> None:
        self.folder = Path(folder)
        self.columns = list(columns)

    def load(self, label: str, rid: str) -> JobRecord | None:
        """The record kept under ``rid``, or ``None`` (none, or unreadable: run again)."""
        path = record_path(self.folder, label, rid)
        return _read(path) if path.is_file() else None

    def save(self, record: JobRecord) -> Path:
        """Write ``record`` atomically (gzip with no time stamp: the same record, the same
        bytes)."""
        from stcgym.agents.executors import write_atomic

        text = json.dumps(record.to_dict(self.columns), separators=(",", ":"), allow_nan=False)
        path = record_path(self.folder, record.label, record.id)
        write_atomic(path, gzip.compress(text.encode(), compresslevel=9, mtime=0))
        return path

    def ids(self) -> set[str]:
        """The ids of every record kept (whatever its settings)."""
        return {_id_of(p) for p in self.folder.glob("*.json.gz")}

    def records(self) -> Iterator[JobRecord]:
        """Every readable record, in file-name order."""
        for path in sorted(self.folder.glob("*.json.gz")):
            record = _read(path)
            if record is not None:
                yield record

    def prune(self, keep: set[str]) -> list[Path]:
        """Delete every record whose id is not in ``keep``; returns the files deleted."""
        stale = [p for p in self.folder.glob("*.json.gz") if _id_of(p) not in keep]
        for path in stale:
            path.unlink()
        return stale

    def clear(self) -> None:
        """Remove every record (a run started afresh with ``--overwrite``)."""
        for old in self.folder.glob("*.json.gz"):
            old.unlink()
