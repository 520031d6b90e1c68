"""``stcgym sweep``: classical controllers over a plant family, on a process pool or Ray, resumable.

Python API::

    from stcgym.agents.sweeps import SweepConfig, run_sweep
    cfg = SweepConfig.build("family.yaml", controllers={"stc": {}, "rls": {"kind": "stc",
                            "estimator": "KF-RLS", "estimator_options": {"p0": 100}}},
                            seeds=2)
    result = run_sweep(cfg, out="results", jobs=2)          # or executor="ray", address="auto"
    result.table  # pandas DataFrame, one row per (plant, controller, seed)

Command line (``stcgym sweep --help``)::

    stcgym sweep family.yaml --controller stc \\
        --controller rls=stc:estimator=KF-RLS,estimator_options.p0=100 \\
        --seeds 2 --jobs 2
    stcgym sweep --resume results/<run>          # continue a killed sweep

Controllers
-----------
``kind`` is ``stc`` (:class:`~stcgym.adaptive.SelfTuningController`, any estimator and setting
as keywords), ``oracle`` (:class:`~stcgym.adaptive.KnownModelController`: the regulator's
design on the true parameters, told the new ones at a jump and, under drift, every step) or
``lqg`` (:class:`~stcgym.adaptive.LQGController` for the family's cost on the true *initial*
parameters, as in ``stcgym bench``). ``action_bound`` defaults to the family's; LQG's
``noise_std`` to the family's and its ``law`` to no integral action with the family's cost as
LQ weights (``law.integral``, ``law.lq_weights`` override them). A controller named
``oracle`` (kind oracle, defaults) is always run: the ratios are to it. Every controller is
built once on plant 0 before any work starts, so bad keywords fail at once.

Tasks and lanes
---------------
Lane ``k`` is plant ``k // S`` with seed ``seeds[k % S]`` (``S`` seeds); a task is a run of
``chunk_size`` (default 10^4) consecutive lanes, simulated together on the batched closed loop
(:func:`stcgym.agents.sweeps.chunk.closed_loop`) for every controller. Lane noise comes from
``SeedSequence([family seed, plant, seed])``, so a lane's numbers do not depend on the chunking,
the executor or the number of workers. Tasks go through :mod:`stcgym.agents.executors`; each
finished task's rows are saved atomically as ``tasks/<task id>.json`` by the driver, and the
table is rebuilt from those files, so a resumed run writes exactly the table of an
uninterrupted one.

Outputs (``<out>/<run>/``)
--------------------------
``metrics.csv`` (``metrics.parquet`` with pyarrow; pandas reads both): one row per (plant,
controller, seed) with the plant features of
:func:`~stcgym.envs.families.plant_features` and its coefficients ``a1..an, b1..bn``, then

* ``bounded`` (1: ``|y|`` stayed below ``y_bound``), ``steps_run``;
* ``cost`` (mean of ``(y - r)^2 + rho u^2`` over the episode), ``cost_start``,
  ``cost_steady``, ``cost_post_jump`` over the windows of
  :func:`stcgym.agents.evaluation.evaluate.default_windows`; a diverged run is charged its
  last cost for the steps it did not live (the rule of
  :func:`stcgym.agents.closed_loop.run_closed_loop`, as in ``stcgym bench``);
* ``ratio`` = ``cost`` / the oracle's ``cost`` on the same plant and seed, ``steady_ratio`` the
  same for ``cost_steady``;
* ``adapt_steps``: steps from the start until the cost over every following window of one
  reference period stays within :data:`RECONVERGE_TOL` x the oracle's cost over the same window
  (:func:`stcgym.agents.evaluation.response.settling_step`, up to the jump if there is one);
  ``reconverge_steps``: the same from the jump step ``J`` on, against the oracle told the new
  parameters. ``inf`` if that never happens (or the run diverged), so a controller that does
  not recover cannot read 0.

``robustness.png``: bounded % and median cost ratio over two plant features (default largest
pole magnitude x |DC gain|), one column of panels per controller. ``config.json``: the sweep;
``failures.json``: failed tasks with their lanes and traceback (the other tasks' rows are
kept; ``--resume`` retries them).
"""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stcgym.agents.executors import (
    EXECUTORS,
    Progress,
    ResultStore,
    connect_ray,
    run_tasks,
    task_id,
    write_atomic,
)
from stcgym.agents.sweeps.chunk import simulate_chunk
from stcgym.agents.sweeps.config import SweepConfig, SweepError
from stcgym.envs.families import FamilySpec, draw_plant, plant_features

__all__ = ["SweepResult", "read_table", "robustness_map", "run_sweep"]


@dataclass
class SweepResult:
    """A finished (or partly failed) sweep: its folder, table path and failed tasks."""

    run_dir: Path
    table_path: Path
    failures: list[dict[str, Any]] = field(default_factory=list)
    plot_path: Path | None = None

    @property
    def table(self) -> Any:
        return read_table(self.table_path)


def read_table(path: str | os.PathLike) -> Any:
    """The sweep table as a pandas DataFrame (CSV or Parquet by suffix)."""
    import pandas as pd

    path = Path(path)
    if path.suffix == ".parquet":
        return pd.read_parquet(path)
    # pandas' default float parser may be 1 ulp off; the table is exact, so read it exactly.
    return pd.read_csv(path, float_precision="round_trip")


def _check_features(family: FamilySpec, features: Sequence[str]) -> None:
    known = list(plant_features(draw_plant(family, 0)))
    if len(features) != 2 or any(f not in known for f in features):
        raise SweepError(f"features must be two of {known}, got {list(features)}")


def _table_format(fmt: str) -> str:
    if fmt not in ("auto", "csv", "parquet"):
        raise SweepError(f"table format must be auto, csv or parquet, got {fmt!r}")
    if fmt != "auto":
        return fmt
    try:
        import pyarrow  # noqa: F401
    except ImportError:
        return "csv"
    return "parquet"


def _write_table(parts: list[dict[str, list]], path: Path) -> None:
    """The task results in task order as one table, written atomically."""
    import io

    import pandas as pd

    frames = [pd.DataFrame(p["rows"], columns=p["columns"]) for p in parts if p["rows"]]
    df = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
    if path.suffix == ".parquet":
        buf = io.BytesIO()
        df.to_parquet(buf, index=False)
        write_atomic(path, buf.getvalue())
    else:
        write_atomic(path, df.to_csv(index=False))


def run_sweep(
    config: SweepConfig | None = None,
    *,
    out: str | os.PathLike = "results",
    run: str | None = None,
    resume: str | os.PathLike | None = None,
    executor: str = "local",
    jobs: int | None = None,
    address: str | None = None,
    table_format: str = "auto",
    plot: bool = True,
    features: tuple[str, str] = ("pole_mag_max", "abs_dc_gain"),
    progress: bool = True,
) -> SweepResult:
    """Run (or, with ``resume``, continue) a sweep; only this process writes files.

    ``resume`` is a run folder of an earlier call (or its name under ``out``): its
    ``config.json`` is the sweep (``config``, if given, must equal it), finished tasks are
    skipped. Otherwise ``out/run`` (``run``
    defaults to a timestamp) must not hold a sweep yet.
    """
    if executor not in EXECUTORS:
        raise SweepError(f"executor must be one of {list(EXECUTORS)}, got {executor!r}")
    if jobs is not None and (isinstance(jobs, bool) or int(jobs) != jobs or jobs < 1):
        raise SweepError(f"jobs must be a positive integer, got {jobs!r}")
    fmt = _table_format(table_format)
    if resume is None and config is None:
        raise SweepError("give a sweep config (or resume a run folder)")
    if config is not None and plot:
        _check_features(config.family, features)
    if executor == "ray":  # a wrong --address fails here, before the run folder exists
        connect_ray(address, jobs)
    if resume is not None:
        run_dir = Path(resume)
        if not run_dir.is_dir() and (Path(out) / run_dir).is_dir():  # a run name under ``out``
            run_dir = Path(out) / run_dir
        saved = run_dir / "config.json"
        if not saved.is_file():
            raise SweepError(f"--resume {run_dir}: no config.json there (not a sweep run folder)")
        stored = SweepConfig.from_dict(json.loads(saved.read_text()))
        if config is not None and config.to_dict() != stored.to_dict():
            raise SweepError(f"--resume {run_dir}: the given sweep differs from its config.json")
        config = stored
        if plot:
            _check_features(config.family, features)
    else:
        name = run or datetime.now(timezone.utc).strftime("%Y%m%d-%H%M%S-sweep")
        run_dir = Path(out) / name
        if (run_dir / "config.json").exists():
            raise SweepError(f"{run_dir} already holds a sweep; use --resume {run_dir}")
        run_dir.mkdir(parents=True, exist_ok=True)
        write_atomic(run_dir / "config.json", json.dumps(config.to_dict(), indent=2))

    tasks = config.tasks()
    ids = [task_id(t) for t in tasks]
    store = ResultStore(run_dir / "tasks")
    done = store.done() & set(ids)
    stream = sys.stderr if progress else open(os.devnull, "w")  # noqa: SIM115
    if done:
        print(f"resuming {run_dir}: {len(done)} of {len(tasks)} tasks already done", file=stream)
    bar = Progress(len(tasks), done=len(done), stream=stream)
    failures = []
    for outcome in run_tasks(
        simulate_chunk,
        tasks,
        executor=executor,
        jobs=jobs,
        address=address,
        done=done,
        progress=bar,
    ):
        if outcome.ok:
            store.save(ids[outcome.index], outcome.result)
            continue
        lanes = outcome.task["lanes"]
        failures.append({"task": outcome.index, "lanes": lanes, "error": outcome.error})
        last = outcome.error.strip().splitlines()[-1] if outcome.error else "?"
        print(
            f"task {outcome.index + 1} (lanes {lanes[0]}..{lanes[1] - 1}, controllers "
            f"{list(config.controllers)}) failed: {last}",
            file=sys.stderr,
        )
    if not progress:
        stream.close()
    if failures:
        write_atomic(run_dir / "failures.json", json.dumps(failures, indent=2))
    else:
        (run_dir / "failures.json").unlink(missing_ok=True)
    finished = store.done()
    parts = [store.load(tid) for tid in ids if tid in finished]
    table_path = run_dir / f"metrics.{fmt}"
    _write_table(parts, table_path)
    rows = sum(len(part["rows"]) for part in parts)
    result = SweepResult(run_dir, table_path, failures)
    if plot and rows:
        result.plot_path = robustness_map(
            read_table(table_path), run_dir / "robustness.png", *features
        )
    return result


# --------------------------------------------------------------------------------------------
# Robustness map
# --------------------------------------------------------------------------------------------
def _edges(values: NDArray, bins: int) -> tuple[NDArray, bool]:
    lo, hi = float(np.min(values)), float(np.max(values))
    if hi <= lo:
        hi = lo + 1e-9
    if lo > 0 and hi / lo > 10:
        return np.geomspace(lo, hi * (1 + 1e-9), bins + 1), True
    return np.linspace(lo, hi + 1e-9 * max(1.0, abs(hi)), bins + 1), False


def robustness_map(
    table: Any,
    path: str | os.PathLike,
    x: str = "pole_mag_max",
    y: str = "abs_dc_gain",
    *,
    bins: int = 8,
) -> Path:
    """Bounded % (top row) and median cost ratio to the oracle (bottom row) over features
    ``x`` and ``y``, one column per controller (the oracle itself left out); saved atomically.

    In the shared figure style (:mod:`stcgym.agents.benchmark.style`): 4 inches per column at
    ``style.DPI``, so up to two controllers fit the 800 px of a page with text of 10 pt.
    """
    import io

    from matplotlib.colors import LogNorm

    from stcgym.agents.benchmark import style

    plt = style.pyplot()

    for feat in (x, y):
        if feat not in table.columns:
            raise SweepError(f"feature {feat!r} is not a column of the table")
    names = [c for c in dict.fromkeys(table["controller"]) if c != "oracle"] or ["oracle"]
    xe, xlog = _edges(table[x].to_numpy(float), bins)
    ye, ylog = _edges(table[y].to_numpy(float), bins)
    ratios = table.loc[table["controller"].isin(names), "ratio"].to_numpy(float)
    ratios = ratios[np.isfinite(ratios) & (ratios > 0)]
    # One colour scale for every panel, so that controllers compare at a glance.
    norm = (
        LogNorm(vmin=max(min(ratios.min(), 1.0), 1e-3), vmax=max(ratios.max(), 10.0))
        if ratios.size
        else None
    )
    fig, axes = plt.subplots(
        2, len(names), figsize=(4.0 * len(names), 6.4), squeeze=False, layout="constrained"
    )
    for j, name in enumerate(names):
        sub = table[table["controller"] == name]
        ix = np.clip(np.searchsorted(xe, sub[x].to_numpy(float), side="right") - 1, 0, bins - 1)
        iy = np.clip(np.searchsorted(ye, sub[y].to_numpy(float), side="right") - 1, 0, bins - 1)
        bounded = np.full((bins, bins), np.nan)
        ratio = np.full((bins, bins), np.nan)
        b_vals, r_vals = sub["bounded"].to_numpy(float), sub["ratio"].to_numpy(float)
        for cx in range(bins):
            for cy in range(bins):
                m = (ix == cx) & (iy == cy)
                if m.any():
                    bounded[cy, cx] = 100.0 * b_vals[m].mean()
                    ratio[cy, cx] = np.median(r_vals[m])
        top = axes[0, j].pcolormesh(xe, ye, bounded, vmin=0, vmax=100, cmap="RdYlGn")
        bottom = axes[1, j].pcolormesh(xe, ye, ratio, norm=norm, cmap="viridis_r")
        axes[0, j].set_title(f"{name}: bounded %")
        axes[1, j].set_title(f"{name}: median cost / oracle")
        for ax in axes[:, j]:
            ax.grid(False)  # the style's grid would hatch the cells
            ax.set_xlabel(x)
            ax.set_ylabel(y)
            if xlog:
                ax.set_xscale("log")
            if ylog:
                ax.set_yscale("log")
        fig.colorbar(top, ax=axes[0, j])
        fig.colorbar(bottom, ax=axes[1, j])
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=style.DPI)
    plt.close(fig)
    path = Path(path)
    write_atomic(path, buf.getvalue())
    return path
