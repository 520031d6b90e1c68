"""``stcgym sweep``: classical controllers over a plant family, on a process pool or Ray, resumable.

Python API::

    from stcgym.agents.sweep import SweepConfig, run_sweep
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
(:func:`closed_loop`) for every controller. Lane noise comes from
``SeedSequence([family seed, plant, seed])``, so a lane's numbers do not depend on the chunking,
the executor or the number of workers. Tasks go through :mod:`stcgym.agents.executors`; each
finished task's rows are saved atomically as ``tasks/<task id>.json`` by the driver, and the
table is rebuilt from those files, so a resumed run writes exactly the table of an
uninterrupted one.

Outputs (``<out>/<run>/``)
--------------------------
``metrics.csv`` (``metrics.parquet`` with pyarrow; pandas reads both): one row per (plant,
controller, seed) with the plant features of :func:`~stcgym.agents.families.plant_features` and
its coefficients ``a1..an, b1..bn``, then

* ``bounded`` (1: ``|y|`` stayed below ``y_bound``), ``steps_run``;
* ``cost`` (mean of ``(y - r)^2 + rho u^2`` over the episode), ``cost_start``,
  ``cost_steady``, ``cost_post_jump`` over the windows of
  :func:`stcgym.agents.evaluate.default_windows`; a diverged run is charged its last cost for
  the steps it did not live, as in ``stcgym bench``;
* ``ratio`` = ``cost`` / the oracle's ``cost`` on the same plant and seed, ``steady_ratio`` the
  same for ``cost_steady``;
* ``adapt_steps``: steps from the start until the cost over every following window of one
  reference period stays within :data:`RECONVERGE_TOL` x the oracle's cost over the same window
  (:func:`stcgym.agents.response.settling_step`, up to the jump if there is one);
  ``reconverge_steps``: the same from the jump step ``J`` on, against the oracle told the new
  parameters. ``inf`` if that never happens (or the run diverged), so a controller that does
  not recover cannot read 0.

``robustness.png``: bounded % and median cost ratio over two plant features (default largest
pole magnitude x |DC gain|), one column of panels per controller. ``config.json``: the sweep;
``failures.json``: failed tasks with their lanes and traceback (the other tasks' rows are
kept; ``--resume`` retries them).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.agents.executors import (
    EXECUTORS,
    Progress,
    ResultStore,
    connect_ray,
    run_tasks,
    task_id,
    write_atomic,
)
from stcgym.agents.families import (
    FamilySpec,
    FamilySpecError,
    Plant,
    draw_plant,
    load_family,
    plant_features,
)
from stcgym.envs.signals import NEVER, Schedule

__all__ = [
    "CONTROLLER_KINDS",
    "LaneJumps",
    "RECONVERGE_TOL",
    "SweepConfig",
    "SweepError",
    "SweepResult",
    "add_sweep_subcommand",
    "closed_loop",
    "robustness_map",
    "run_sweep",
    "run_sweep_command",
    "simulate_chunk",
]

CONTROLLER_KINDS: tuple[str, ...] = ("stc", "oracle", "lqg")
#: A window counts as adapted / re-converged when its cost is within this factor of the oracle's.
RECONVERGE_TOL = 1.2
DEFAULT_CHUNK = 10_000
ENV_ID = "stcgym/ObserverCanonical-v0"


class SweepError(ValueError):
    """Bad sweep input (controllers, seeds, chunk size, run folder), raised before any work."""


# --------------------------------------------------------------------------------------------
# Configuration
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SweepConfig:
    """A validated sweep: the family, named controllers, episode seeds and the chunk size."""

    family: FamilySpec
    controllers: dict[str, dict[str, Any]]
    seeds: tuple[int, ...]
    chunk_size: int = DEFAULT_CHUNK

    @classmethod
    def build(
        cls,
        family: FamilySpec | Mapping[str, Any] | str | os.PathLike,
        controllers: Mapping[str, Mapping[str, Any]] | Sequence[str] | None = None,
        seeds: int | Sequence[int] = 1,
        chunk_size: int = DEFAULT_CHUNK,
    ) -> SweepConfig:
        """Validate everything (building each controller once) before any work starts.

        ``controllers``: names of the default kinds (``["stc", "oracle", "lqg"]``, the
        default) or ``{name: {"kind": kind, **keywords}}`` (``kind`` defaults to the name).
        ``seeds``: a count ``S`` (seeds ``0..S-1``) or the list of episode seeds.
        """
        fam = family if isinstance(family, FamilySpec) else load_family(family)
        if controllers is None:
            controllers = list(CONTROLLER_KINDS)
        if not isinstance(controllers, Mapping):
            controllers = {str(name): {} for name in controllers}
        ctl = {str(k): dict(v or {}) for k, v in controllers.items()}
        if not ctl:
            raise SweepError("controllers: give at least one controller")
        ctl.setdefault("oracle", {"kind": "oracle"})
        for name, kw in ctl.items():
            kind = str(kw.setdefault("kind", name)).lower()
            kw["kind"] = kind
            if kind not in CONTROLLER_KINDS:
                raise SweepError(
                    f"controller {name!r}: kind must be one of {list(CONTROLLER_KINDS)}, "
                    f"got {kind!r}"
                )
        if ctl["oracle"]["kind"] != "oracle":
            raise SweepError("the controller named 'oracle' must be of kind oracle")
        if isinstance(seeds, bool) or (isinstance(seeds, int) and seeds < 1):
            raise SweepError(f"seeds must be a count >= 1 or a list of seeds, got {seeds!r}")
        seed_list = list(range(seeds)) if isinstance(seeds, int) else list(seeds)
        if not seed_list or any(
            isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0 for s in seed_list
        ):
            raise SweepError(f"seeds must be non-negative integers, got {seeds!r}")
        if len(set(seed_list)) != len(seed_list):
            raise SweepError(f"seeds must be distinct, got {seed_list}")
        if isinstance(chunk_size, bool) or int(chunk_size) != chunk_size or chunk_size < 1:
            raise SweepError(f"chunk_size must be a positive integer, got {chunk_size!r}")
        cfg = cls(fam, ctl, tuple(int(s) for s in seed_list), int(chunk_size))
        plant = draw_plant(fam, 0)
        for name, kw in ctl.items():
            try:
                _make_controller(kw, fam, [plant], batched=False)
            except (TypeError, ValueError) as exc:
                raise SweepError(f"controller {name!r} ({_describe(kw)}): {exc}") from exc
        return cfg

    @property
    def num_lanes(self) -> int:
        return self.family.count * len(self.seeds)

    def tasks(self) -> list[dict[str, Any]]:
        """One JSON task per chunk of lanes (its :func:`task_id` keys resuming)."""
        base = {
            "family": self.family.to_dict(),
            "controllers": self.controllers,
            "seeds": list(self.seeds),
        }
        return [
            {**base, "lanes": [lo, min(lo + self.chunk_size, self.num_lanes)]}
            for lo in range(0, self.num_lanes, self.chunk_size)
        ]

    def to_dict(self) -> dict[str, Any]:
        return {
            "family": self.family.to_dict(),
            "controllers": self.controllers,
            "seeds": list(self.seeds),
            "chunk_size": self.chunk_size,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> SweepConfig:
        return cls.build(d["family"], d["controllers"], list(d["seeds"]), d["chunk_size"])


def _describe(kw: Mapping[str, Any]) -> str:
    return ", ".join(f"{k}={v!r}" for k, v in kw.items())


# --------------------------------------------------------------------------------------------
# One chunk: the batched closed loop
# --------------------------------------------------------------------------------------------
@dataclass
class LoopResult:
    """Per-lane cost trace ``(B, T)`` (diverged lanes charged their last cost) and outcome."""

    cost: NDArray
    diverged: NDArray
    steps_run: NDArray


def _make_controller(
    kw: Mapping[str, Any], family: FamilySpec, plants: Sequence[Plant], *, batched: bool = True
) -> Any:
    """The batched controller of ``kw`` for the lanes ``plants`` (the oracles get each lane's
    true parameters); ``batched=False``: one controller on ``plants[0]``, to check keywords."""
    from stcgym.adaptive import (
        KnownModelController,
        LawOptions,
        LQGController,
        SelfTuningController,
    )
    from stcgym.adaptive.options import cost_weights

    opts = {k: v for k, v in kw.items() if k != "kind"}
    opts.setdefault("action_bound", family["action_bound"])
    lanes: dict[str, Any] = {"num_envs": len(plants)} if batched else {}
    if kw["kind"] == "stc":
        return SelfTuningController(family.order, **lanes, **opts)
    a = np.array([p.a for p in plants]) if batched else plants[0].a
    b = np.array([p.b for p in plants]) if batched else plants[0].b
    if kw["kind"] == "oracle":
        return KnownModelController(a, b, **lanes, **opts)
    # as in stcgym bench: no integral action, the family's cost as the LQ weights
    if not isinstance(opts.get("law"), LawOptions):
        law = dict(opts.get("law") or {})
        law.setdefault("integral", False)
        law.setdefault("lq_weights", cost_weights(family["control_cost"] or 1e-6))
        opts["law"] = law
    if family["noise_std"] <= 0 and "noise_std" not in opts:
        raise ValueError("the lqg oracle needs noise_std > 0 in the family (its Kalman filter)")
    opts.setdefault("noise_std", family["noise_std"])
    return LQGController(a, b, **lanes, **opts)


def _actions(ctl: Any, obs: NDArray) -> NDArray:
    action, _ = ctl.predict(obs)
    return np.asarray(action, dtype=float).reshape(-1, 1)


class LaneJumps(Schedule):
    """Per-lane parameter jump: from step ``step`` on, lane ``i`` has the parameters
    ``after[i]`` (shape ``(B, 2n)``; a :class:`~stcgym.envs.signals.Schedule` for a vector env
    of ``B`` lanes, or for one env with ``after`` of one row)."""

    def __init__(self, step: int, after: ArrayLike) -> None:
        self.step, self.after = int(step), np.asarray(after, dtype=float)

    def values(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        lanes = np.arange(self.num_lanes) if lanes is None else np.asarray(lanes)
        out = self._nominal[lanes].copy()
        jumped = np.asarray(k) >= self.step
        out[jumped] = self.after[lanes[jumped]]
        return out

    def next_change(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        return np.where(np.asarray(k) < self.step, self.step, NEVER).astype(np.int64)


def _vector_env(family: FamilySpec, plants: Sequence[Plant]) -> Any:
    """The native vector env of ``plants``: per-lane ``a``, ``b`` and the family's jump or drift."""
    import gymnasium as gym

    import stcgym.envs  # noqa: F401  (registers the ids)
    from stcgym.envs.signals import RandomWalk

    kwargs: dict[str, Any] = dict(
        num_envs=len(plants),
        a=np.array([p.a for p in plants]),
        b=np.array([p.b for p in plants]),
        noise_std=family["noise_std"],
        control_cost=family["control_cost"],
        action_bound=family["action_bound"],
        y_bound=family["y_bound"],
        reference=family["reference"],
        info_keys=(),
    )
    if family.jump_step is not None:
        after = np.array([np.concatenate((p.a_after, p.b_after)) for p in plants])
        kwargs["schedule"] = LaneJumps(family.jump_step, after)
    elif family["drift"] is not None and family["drift"]["std"] > 0:
        kwargs["schedule"] = RandomWalk(family["drift"]["std"])
    return gym.make_vec(ENV_ID, **kwargs).unwrapped


def closed_loop(
    kw: Mapping[str, Any], family: FamilySpec, plants: Sequence[Plant], lane_seeds: Sequence[int]
) -> LoopResult:
    """Run controller ``kw`` on lanes ``plants`` (noise seeds ``lane_seeds``) for one episode.

    The public route: the native vector env (per-lane ``a``, ``b``, the family's jump as a
    per-lane schedule, reset with one seed per lane) and the batched controller
    (``num_envs=B``). Lane ``i`` is the single env with the same plant and schedule reset with
    ``seed=lane_seeds[i]``, driven by the single controller. The oracle is told the new
    parameters at the jump (under drift: every step).
    """
    B, T, J = len(plants), family.steps, family.jump_step
    ctl = _make_controller(kw, family, plants)
    env = _vector_env(family, plants)
    obs, _ = env.reset(seed=[int(s) for s in lane_seeds])
    cost = np.zeros((B, T))
    alive = np.ones(B, dtype=bool)
    steps_run = np.full(B, T, dtype=np.int64)
    oracle = kw["kind"] == "oracle"
    drift = family["drift"] is not None and family["drift"]["std"] > 0
    for k in range(T):
        if oracle and k == J:
            ctl.set_model(np.array([p.a_after for p in plants]), [p.b_after for p in plants])
        elif oracle and drift and k > 0:
            _tell_oracles(ctl, env.params)
        obs, reward, terminated, _, _ = env.step(_actions(ctl, obs))
        # A diverged lane is charged its last cost for the steps it did not live (its env
        # lane restarts; what it does next is not scored).
        cost[:, k] = np.where(alive, -reward, cost[:, k - 1] if k else 0.0)
        died = alive & terminated
        steps_run[died] = k + 1
        alive &= ~terminated
    env.close()
    return LoopResult(cost, ~alive, steps_run)


def _tell_oracles(ctl: Any, params: NDArray) -> None:
    """Under drift the oracle knows the parameters in force; a lane whose drifted model cannot
    be designed on keeps its last one (``set_model`` changes nothing when it raises)."""
    n = ctl.n
    try:
        ctl.set_model(params[:, :n], params[:, n:])
    except ValueError:
        for i, th in enumerate(params):
            try:
                ctl.set_model(th[:n], th[n:], lanes=[i])
            except ValueError:
                pass


def _lane_seed(*entropy: int) -> int:
    """A 32-bit env seed from ``SeedSequence(entropy)``."""
    return int(np.random.SeedSequence(list(entropy)).generate_state(1)[0])


def simulate_chunk(task: Mapping[str, Any]) -> dict[str, list]:
    """The task function: the table rows of lanes ``task["lanes"]``, column-wise compact:
    ``{"columns": names, "rows": [values, ...]}`` (JSON data, about half the size of dicts)."""
    family = FamilySpec.from_dict(task["family"])
    seeds = list(task["seeds"])
    lanes = range(*task["lanes"])
    S = len(seeds)
    pairs = [(k // S, seeds[k % S]) for k in lanes]
    plants_by_index = {i: draw_plant(family, i) for i in sorted({i for i, _ in pairs})}
    plants = [plants_by_index[i] for i, _ in pairs]
    lane_seeds = [_lane_seed(family["seed"], i, sd) for i, sd in pairs]
    results = {
        name: closed_loop(kw, family, plants, lane_seeds)
        for name, kw in task["controllers"].items()
    }
    rows = _rows(family, task["controllers"], pairs, plants, results)
    columns = list(rows[0]) if rows else []
    return {"columns": columns, "rows": [list(r.values()) for r in rows]}


def _rows(
    family: FamilySpec,
    controllers: Mapping[str, Mapping[str, Any]],
    pairs: list[tuple[int, int]],
    plants: list[Plant],
    results: Mapping[str, LoopResult],
) -> list[dict[str, Any]]:
    from stcgym.agents.evaluate import default_windows

    T, J = family.steps, family.jump_step
    win = default_windows(T, J)
    oracle = results["oracle"]
    o_cost = oracle.cost.mean(axis=1)
    o_steady = _window(oracle.cost, win.steady)
    rows = []
    for lane, ((index, seed), plant) in enumerate(zip(pairs, plants, strict=True)):
        base: dict[str, Any] = {"family": family["name"], "plant": index, "seed": seed}
        base.update(plant_features(plant))
        base.update({f"a{j + 1}": float(v) for j, v in enumerate(plant.a)})
        base.update({f"b{j + 1}": float(v) for j, v in enumerate(plant.b)})
        for name, res in results.items():
            c = res.cost[lane]
            row = dict(base, controller=name, kind=controllers[name]["kind"])
            row.update(
                bounded=int(not res.diverged[lane]),
                steps_run=int(res.steps_run[lane]),
                cost=float(c.mean()),
                cost_start=float(c[slice(*win.start)].mean()),
                cost_steady=float(c[slice(*win.steady)].mean()),
                cost_post_jump=math.nan,
                reconverge_steps=math.nan,
            )
            row["ratio"] = _ratio(row["cost"], o_cost[lane])
            row["steady_ratio"] = _ratio(row["cost_steady"], o_steady[lane])
            row["adapt_steps"] = (
                math.inf
                if res.diverged[lane]
                else _settling(c, oracle.cost[lane], family, 0, J or T)
            )
            if J is not None:
                row["cost_post_jump"] = float(c[slice(*win.post_jump)].mean())
                row["reconverge_steps"] = (
                    math.inf
                    if res.diverged[lane]
                    else _settling(c, oracle.cost[lane], family, J, T)
                )
            rows.append(row)
    return rows


def _window(cost: NDArray, window: tuple[int, int]) -> NDArray:
    return cost[:, window[0] : window[1]].mean(axis=1)


def _ratio(x: float, ref: float) -> float:
    return float(x / ref) if ref > 0 else math.inf


def _settling(cost: NDArray, oracle: NDArray, family: FamilySpec, start: int, stop: int) -> float:
    from stcgym.agents.response import settling_step

    return settling_step(
        cost, oracle, span=family.period, start=start, stop=stop, tol=RECONVERGE_TOL
    )


# --------------------------------------------------------------------------------------------
# Driver
# --------------------------------------------------------------------------------------------
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
    ``x`` and ``y``, one column per controller (the oracle itself left out); saved atomically."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

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
        2, len(names), figsize=(3.6 * len(names) + 1, 6.4), squeeze=False, constrained_layout=True
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
            ax.set_xlabel(x)
            ax.set_ylabel(y)
            if xlog:
                ax.set_xscale("log")
            if ylog:
                ax.set_yscale("log")
        fig.colorbar(top, ax=axes[0, j])
        fig.colorbar(bottom, ax=axes[1, j])
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    path = Path(path)
    write_atomic(path, buf.getvalue())
    return path


# --------------------------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------------------------
def _parse_value(text: str) -> Any:
    try:
        import yaml

        return yaml.safe_load(text)
    except ImportError:  # pragma: no cover
        try:
            return json.loads(text)
        except json.JSONDecodeError:
            return text


def parse_controller(text: str) -> tuple[str, dict[str, Any]]:
    """``NAME[=KIND][:KEY=VALUE,...]`` -> ``(name, {"kind": kind, key: value})``.

    Values are YAML scalars or flow collections (``poles=[0.6,0.6,0.6]``,
    ``estimator=KF-RLS``); commas inside brackets do not split. A dotted key sets an entry of
    an options group: ``estimator_options.p0=100`` -> ``{"estimator_options": {"p0": 100}}``.
    """
    head, _, rest = text.partition(":")
    name, _, kind = head.partition("=")
    name, kind = name.strip(), (kind.strip() or name.strip())
    if not name:
        raise SweepError(f"--controller {text!r}: expected NAME[=KIND][:KEY=VALUE,...]")
    opts: dict[str, Any] = {"kind": kind}
    depth, item, items = 0, "", []
    for ch in rest:
        if ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        if ch == "," and depth == 0:
            items.append(item)
            item = ""
        else:
            item += ch
    if item.strip():
        items.append(item)
    for it in items:
        key, eq, value = it.partition("=")
        if not eq or not key.strip():
            raise SweepError(f"--controller {text!r}: option {it!r} is not KEY=VALUE")
        *groups, leaf = key.strip().split(".")
        target = opts
        for g in groups:
            target = target.setdefault(g, {})
            if not isinstance(target, dict):
                raise SweepError(f"--controller {text!r}: {g!r} is set twice")
        target[leaf] = _parse_value(value.strip())
    return name, opts


def add_sweep_subcommand(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``sweep`` on the ``stcgym`` command's subparsers; returns its parser."""
    p = subparsers.add_parser(
        "sweep",
        help="classical controllers over a random plant family (process pool or Ray)",
        description="Run the self-tuning controller, the known-model oracle and LQG over a "
        "plant family (YAML/JSON spec, see stcgym.agents.families); writes <out>/<run>/ "
        "(metrics.csv or .parquet, robustness.png, config.json).",
    )
    p.add_argument("family", nargs="?", help="family spec file (.yaml/.yml/.json)")
    p.add_argument(
        "--controller",
        action="append",
        dest="controllers",
        metavar="NAME[=KIND][:KEY=VALUE,...]",
        help="a controller (repeatable; default stc, oracle, lqg), e.g. "
        "rls=stc:estimator=KF-RLS,estimator_options.p0=100; the oracle is always run",
    )
    p.add_argument("--seeds", type=int, default=1, help="episode seeds per plant (default 1)")
    p.add_argument(
        "--chunk", type=int, default=DEFAULT_CHUNK, help="lanes per task (default 10000)"
    )
    p.add_argument("--jobs", type=int, help="local worker processes (default: CPU count)")
    p.add_argument("--executor", choices=EXECUTORS, default="local", help="local (default) or ray")
    p.add_argument("--address", help="Ray cluster address, e.g. auto (after ray start --head)")
    p.add_argument("--out", default="results", help="output folder (default results/)")
    p.add_argument("--run", help="run name (default: timestamp)")
    p.add_argument("--resume", metavar="RUN", help="continue the sweep in this run folder")
    p.add_argument(
        "--format", dest="table_format", default="auto", choices=("auto", "csv", "parquet")
    )
    p.add_argument(
        "--features",
        default="pole_mag_max,abs_dc_gain",
        help="two plant features for the robustness map (default pole_mag_max,abs_dc_gain)",
    )
    p.add_argument("--no-plot", action="store_true", help="skip robustness.png")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(handler=run_sweep_command)
    return p


def run_sweep_command(args: argparse.Namespace) -> int:
    """Run ``stcgym sweep`` from parsed arguments; exit status 0, 1 (task failures) or 2."""
    try:
        features = tuple(f.strip() for f in args.features.split(","))
        if len(features) != 2:
            raise SweepError(f"--features needs two names, got {args.features!r}")
        config = None
        if args.family is not None:
            controllers = dict(parse_controller(c) for c in (args.controllers or CONTROLLER_KINDS))
            config = SweepConfig.build(args.family, controllers, args.seeds, args.chunk)
        elif args.resume is None:
            raise SweepError("give a family spec file, or --resume RUN")
        t0 = time.perf_counter()
        result = run_sweep(
            config,
            out=args.out,
            run=args.run,
            resume=args.resume,
            executor=args.executor,
            jobs=args.jobs,
            address=args.address,
            table_format=args.table_format,
            plot=not args.no_plot,
            features=features,  # type: ignore[arg-type]
            progress=not args.quiet,
        )
    except (SweepError, FamilySpecError, FileNotFoundError) as exc:
        print(f"stcgym sweep: error: {exc}", file=sys.stderr)
        return 2
    except ConnectionError as exc:  # ray.init(address=...) found no cluster
        print(
            f"stcgym sweep: error: no Ray cluster at --address {args.address} ({exc}); start "
            f"one with `ray start --head`",
            file=sys.stderr,
        )
        return 2
    except KeyboardInterrupt:
        print("stcgym sweep: interrupted; continue with --resume", file=sys.stderr)
        return 130
    print(f"{result.table_path} ({time.perf_counter() - t0:.1f} s)")
    return 1 if result.failures else 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m stcgym.agents.sweep ...`` (the same as ``stcgym sweep ...``)."""
    parser = argparse.ArgumentParser(prog="stcgym")
    add_sweep_subcommand(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["sweep", *(sys.argv[1:] if argv is None else argv)])
    return run_sweep_command(args)


if __name__ == "__main__":
    sys.exit(main())
