"""The classical controllers' episodes of a ``stcgym bench`` run, kept for ``--resume``.

A classical controller is deterministic given the run's settings, so a resumed run could
evaluate it again; on the multivariable scenarios that costs about an hour of one core per
session (the self-tuning LQ controller solves a Riccati equation every step), taken from the
RL workers. Each evaluated (scenario, controller, run) is therefore kept in
``jobs/classical/`` as a NumPy ``.npz`` file (plain arrays, read with ``allow_pickle=False``)
under an id of everything that shapes it, and read back instead of evaluated again.
"""

from __future__ import annotations

import io
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import quote

import numpy as np
from numpy.typing import NDArray

__all__ = ["CLASSICAL_FOLDER", "ClassicalEpisodes", "ClassicalStore", "classical_id"]

#: The sub-folder of the run's ``jobs/`` folder that holds the classical controllers' episodes.
CLASSICAL_FOLDER = "classical"
#: Settings of a run that do not shape a classical controller's episodes: where it is written,
#: how it is executed, and how the RL agents are trained (their recipes, budgets, learning
#: curves and stopping rule), so that a run whose RL settings change keeps them.
_NOT_RESULT = (
    "run",
    "out",
    "plots",
    "progress",
    "jobs",
    "executor",
    "address",
    "tensorboard_log",
    "bootstrap_reps",
    "algo_configs",
    "action_units",
    "train_steps",
    "family_train_steps",
    "mimo_train_steps",
    "eval_interval",
    "curve_episodes",
    "curve_points",
    "patience",
    "min_improvement",
    "min_train_fraction",
)


@dataclass
class ClassicalEpisodes:
    """What the report needs of one run of a classical controller on a scenario's episodes.

    ``cost``: per-step costs ``(B, T)``; ``jump_step``: each episode's jump step (``-1``: none);
    ``metrics``: the per-episode columns of
    :func:`~stcgym.agents.evaluation.evaluate.response_metrics`; ``trace``: the first episodes'
    signals (``y``, ``r``, ``u`` and, for an adaptive controller, ``theta``, ``theta_hat``),
    kept for run 0 only (empty otherwise).
    """

    cost: NDArray
    jump_step: NDArray
    metrics: dict[str, NDArray]
    trace: dict[str, NDArray] = field(default_factory=dict)

    def to_bytes(self) -> bytes:
        arrays = {"cost": self.cost, "jump_step": self.jump_step}
        arrays |= {f"metrics/{k}": np.asarray(v) for k, v in self.metrics.items()}
        arrays |= {f"trace/{k}": np.asarray(v) for k, v in self.trace.items()}
        buffer = io.BytesIO()
        np.savez(buffer, **arrays)
        return buffer.getvalue()

    @classmethod
    def from_file(cls, path: Path) -> ClassicalEpisodes:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
        part = lambda prefix: {  # noqa: E731
            k.split("/", 1)[1]: v for k, v in arrays.items() if k.startswith(prefix + "/")
        }
        return cls(arrays["cost"], arrays["jump_step"], part("metrics"), part("trace"))


def classical_id(settings: dict, scenario: dict, controller: str, run: int) -> str:
    """The id a classical controller's episodes are kept under: the run's settings (without
    those in ``_NOT_RESULT``), the scenario (its env and episodes as dicts), the controller's
    name and the run."""
    from stcgym.agents.executors import task_id

    shaping = {k: v for k, v in settings.items() if k not in _NOT_RESULT}
    return task_id({"bench": shaping, "scenario": scenario, "controller": controller, "run": run})


class ClassicalStore:
    """The ``.npz`` files of one run's classical episodes, one per :func:`classical_id`."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)

    def _path(self, label: str, tid: str) -> Path:
        return self.folder / f"{quote(label, safe='')}.{tid}.npz"

    def load(self, label: str, tid: str) -> ClassicalEpisodes | None:
        """The episodes kept under ``tid``, or ``None`` when none are (or the file is unreadable:
        they are evaluated again)."""
        path = self._path(label, tid)
        if not path.is_file():
            return None
        try:
            return ClassicalEpisodes.from_file(path)
        except (OSError, ValueError, KeyError, zipfile.BadZipFile):
            return None

    def save(self, label: str, tid: str, episodes: ClassicalEpisodes) -> None:
        from stcgym.agents.executors import write_atomic

        write_atomic(self._path(label, tid), episodes.to_bytes())

    def clear(self) -> None:
        """Remove every kept file (a run started afresh with ``--overwrite``)."""
        for old in self.folder.glob("*.npz"):
            old.unlink()
