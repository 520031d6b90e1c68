"""Run independent tasks on a local process pool or on Ray, resumably; only the driver writes.

This is the one executor of stcgym: ``stcgym sweep`` (one task per chunk of plants) and the RL
part of ``stcgym bench`` (one task per training env x agent x seed) both go through it.

API
---
``run_tasks(fn, tasks, *, executor="local", jobs=None, address=None, done=(), ...)``
    Call ``fn(task)`` for every task and yield a :class:`TaskOutcome`
    ``(index, task, result, error, seconds)`` as each one completes (not in input order;
    ``index`` is the task's position in ``tasks``). A task that raises does not stop the others:
    its outcome has ``result=None`` and ``error`` = the traceback text (the driver reports it
    with ``task``, the config). ``done`` is a collection of :func:`task_id` values to skip
    (resume); ``progress`` is updated after every task; ``admit(task)`` decides, as each worker
    frees up, whether a task may still start (a time limit). ``fn`` must be a module-level
    function and ``tasks`` and results picklable (they travel to worker processes or Ray
    workers); results should be small (rows, not traces).

    * ``executor="local"`` (default, no extra dependency): ``jobs`` worker processes
      (``concurrent.futures.ProcessPoolExecutor``, spawn start method so that numba's threads
      and Ray never meet a forked copy of themselves); ``jobs=1`` runs the tasks one after the
      other in the calling process (debuggable with pdb). Default ``jobs``: the number of CPUs.
    * ``executor="ray"``: the same tasks as Ray remote calls (``pip install stcgym[ray]``);
      ``address=None`` reuses an initialised Ray or starts a local one, ``address="auto"``
      joins the cluster started by ``ray start --head``. ``jobs`` caps the tasks in flight.

    Tasks are the unit of parallelism: each runs numba with ``threads`` threads (default 1; a
    Ray task holds one CPU). A closed loop opens a short parallel region every step, and with
    more threads than free cores each region waits for a descheduled thread: a 50-lane chunk
    ran 20-40x slower with 2 threads than with 1 on the loaded 2-core development machine.
``connect_ray(address=None, jobs=None)``
    Initialise Ray (or reuse it) before any work: ``ConnectionError`` when no cluster answers.
``task_id(task) -> str``
    A stable id of a JSON-able task (SHA-1 of its canonical JSON): the same config gives the
    same id in every process and run, which is what resuming is keyed by.
``ResultStore(folder)``
    The driver's journal of finished tasks: ``store.done()`` the ids already saved,
    ``store.save(task_id, result)`` writes ``folder/<id>.json`` atomically (temp file +
    ``os.replace``), ``store.load(task_id)``. Results must be JSON data (floats round-trip
    exactly, ``nan``/``inf`` included), so a resumed run rebuilds exactly the table of an
    uninterrupted one. A task is either saved completely or not at all: a kill at any moment
    repeats or loses none.
``Progress(total, done=0, stream=sys.stderr)``
    Prints ``task k/N, ETA 1m23s`` lines; ``Progress.update(outcome)``; ``done`` counts tasks
    finished by an earlier run (the ETA extrapolates this run's rate only).

Example::

    store = ResultStore(run_dir / "tasks")
    for out in run_tasks(simulate, tasks, jobs=2, done=store.done(), progress=Progress(len(tasks))):
        if out.error is None:
            store.save(task_id(out.task), out.result)
        else:
            print(f"task {out.index} failed: {out.task}\\n{out.error}")
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Collection, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import Any, TextIO

__all__ = [
    "EXECUTORS",
    "Progress",
    "ResultStore",
    "TaskOutcome",
    "connect_ray",
    "run_tasks",
    "task_id",
    "write_atomic",
]

EXECUTORS: tuple[str, ...] = ("local", "ray")


@dataclass(frozen=True)
class TaskOutcome:
    """One finished task: its position, config, result (or ``None``), error text, wall seconds."""

    index: int
    task: Any
    result: Any
    error: str | None
    seconds: float

    @property
    def ok(self) -> bool:
        return self.error is None


def task_id(task: Any) -> str:
    """Stable id of a JSON-able task: SHA-1 (16 hex digits) of its canonical JSON."""
    try:
        text = json.dumps(task, sort_keys=True, separators=(",", ":"), allow_nan=True)
    except TypeError as exc:
        raise TypeError(f"task must be JSON data (dicts, lists, numbers, strings): {exc}") from exc
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def write_atomic(path: str | os.PathLike, data: bytes | str) -> None:
    """Write ``data`` to ``path`` via a temp file in the same folder and ``os.replace``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    raw = data.encode() if isinstance(data, str) else data
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.fchmod(fd, 0o666 & ~umask)  # mkstemp makes 0600; results are ordinary files
        with os.fdopen(fd, "wb") as fh:
            fh.write(raw)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


class ResultStore:
    """Finished tasks' JSON results, one file per task id (see the module docstring)."""

    def __init__(self, folder: str | os.PathLike) -> None:
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)

    def _path(self, tid: str) -> Path:
        return self.folder / f"{tid}.json"

    def done(self) -> set[str]:
        """Ids of the tasks saved so far (temp files of an interrupted save are not counted)."""
        return {p.stem for p in self.folder.glob("*.json")}

    def save(self, tid: str, result: Any) -> None:
        write_atomic(self._path(tid), json.dumps(result, allow_nan=True))

    def load(self, tid: str) -> Any:
        return json.loads(self._path(tid).read_text())


class Progress:
    """``task k/N, ETA ...`` lines on ``stream``; the ETA extrapolates the mean task rate."""

    def __init__(
        self,
        total: int,
        *,
        done: int = 0,
        stream: TextIO | None = None,
        label: str = "task",
    ) -> None:
        """``total`` tasks of which ``done`` finished in an earlier run (resume)."""
        self.total, self.count, self.first, self.label = int(total), int(done), int(done), label
        self.stream = sys.stderr if stream is None else stream
        self.t0 = time.perf_counter()

    def update(self, outcome: TaskOutcome | None = None) -> str:
        self.count += 1
        elapsed = time.perf_counter() - self.t0
        left = self.total - self.count
        eta = elapsed / (self.count - self.first) * left
        status = "" if outcome is None or outcome.ok else " (FAILED)"
        line = f"{self.label} {self.count}/{self.total}{status}, ETA {_duration(eta)}"
        print(line, file=self.stream, flush=True)
        return line


def _duration(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "?"
    s = int(round(seconds))
    return f"{s // 60}m{s % 60:02d}s" if s >= 60 else f"{s}s"


def _call(
    fn: Callable[[Any], Any], task: Any, threads: int | None
) -> tuple[Any, str | None, float]:
    """Run one task: ``(result, error, seconds)``; exceptions become error text. numba runs
    ``threads`` threads during the task (the caller's setting is restored afterwards)."""
    import numba

    before = numba.get_num_threads()
    numba.set_num_threads(max(1, min(int(threads or 1), numba.config.NUMBA_NUM_THREADS)))
    t0 = time.perf_counter()
    try:
        return fn(task), None, time.perf_counter() - t0
    except Exception:  # noqa: BLE001  (every task error is reported, none stops the sweep)
        return None, traceback.format_exc(), time.perf_counter() - t0
    finally:
        numba.set_num_threads(before)


def _check(executor: str, jobs: int | None) -> None:
    if executor not in EXECUTORS:
        raise ValueError(f"executor must be one of {EXECUTORS}, got {executor!r}")
    if jobs is not None and (int(jobs) != jobs or jobs < 1):
        raise ValueError(f"jobs must be a positive integer, got {jobs!r}")


def run_tasks(
    fn: Callable[[Any], Any],
    tasks: Sequence[Any],
    *,
    executor: str = "local",
    jobs: int | None = None,
    address: str | None = None,
    done: Collection[str] = (),
    progress: Progress | None = None,
    threads: int | None = None,
    admit: Callable[[Any], bool] | None = None,
) -> Iterator[TaskOutcome]:
    """Run ``fn`` on every task not in ``done`` and yield outcomes as they complete.

    Parameters
    ----------
    fn
        Module-level function ``fn(task) -> result`` (picklable).
    tasks
        Task configs; JSON data if ``done`` is used (ids by :func:`task_id`).
    executor
        ``"local"`` (process pool, default) or ``"ray"``.
    jobs
        Local worker processes (default: CPU count; 1 = in this process), or the cap on Ray
        tasks in flight (default: no cap).
    address
        Ray cluster address (``"auto"`` for the one started by ``ray start --head``).
    done
        Task ids to skip (they are neither run nor yielded).
    progress
        Updated after every task.
    threads
        numba threads per task (default 1, see the module docstring).
    admit
        Asked, each time a worker is free, of the tasks not started yet in their order: the
        first it admits starts. A task it refuses is asked again at the next free worker;
        when no task is running and it admits none of those left, the call ends without
        them (they are neither run nor yielded). For a time limit: admit a task while its
        estimated duration fits in the time left. Default: every task, in order.
    """
    _check(executor, jobs)
    skip = set(done)
    todo = [(i, t) for i, t in enumerate(tasks) if not skip or task_id(t) not in skip]
    threads = 1 if threads is None else int(threads)
    admit = admit or (lambda task: True)
    if executor == "ray":
        yield from _run_ray(fn, todo, jobs, address, progress, threads, admit)
        return
    jobs = int(jobs or os.cpu_count() or 1)
    if jobs == 1 or len(todo) <= 1:
        while (nxt := _next_admitted(todo, admit)) is not None:
            i, task = nxt
            out = TaskOutcome(i, task, *_call(fn, task, threads))
            _tick(progress, out)
            yield out
        return
    yield from _run_pool(fn, todo, jobs, progress, threads, admit)


def _next_admitted(queue: list[tuple[int, Any]], admit: Callable[[Any], bool]) -> Any:
    """Take the first task of ``queue`` that ``admit`` admits out of it (``None``: none)."""
    for k, (_, task) in enumerate(queue):
        if admit(task):
            return queue.pop(k)
    return None


def _tick(progress: Progress | None, out: TaskOutcome) -> None:
    if progress is not None:
        progress.update(out)


def _run_pool(
    fn: Callable[[Any], Any],
    todo: list[tuple[int, Any]],
    jobs: int,
    progress: Progress | None,
    threads: int,
    admit: Callable[[Any], bool],
) -> Iterator[TaskOutcome]:
    ctx = get_context("spawn")
    queue = list(todo)
    workers = min(jobs, len(todo))
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
        # one task per free worker, each admitted when it starts (not all submitted at once)
        futures: dict[Future, tuple[int, Any]] = {}
        try:
            while True:
                while len(futures) < workers and (nxt := _next_admitted(queue, admit)):
                    futures[pool.submit(_call, fn, nxt[1], threads)] = nxt
                if not futures:
                    return
                finished, _ = wait(futures, return_when=FIRST_COMPLETED)
                for fut in finished:
                    i, task = futures.pop(fut)
                    try:
                        out = TaskOutcome(i, task, *fut.result())
                    except BrokenProcessPool as exc:  # a worker died (killed, out of memory)
                        out = TaskOutcome(i, task, None, f"worker process died: {exc!r}", 0.0)
                    _tick(progress, out)
                    yield out
        finally:  # the consumer stopped early (or Ctrl-C): drop what has not started
            for fut in futures:
                fut.cancel()


def connect_ray(address: str | None = None, jobs: int | None = None) -> Any:
    """Import Ray and initialise it unless it is already: ``address=None`` starts a local Ray
    with ``jobs`` CPUs (default: all), ``"auto"`` joins the cluster of ``ray start --head``.

    Raises ``ImportError`` without Ray and ``ConnectionError`` when no cluster answers; a driver
    calls it before writing anything, so a wrong address fails before any work starts.
    """
    try:
        import ray
    except ImportError as exc:  # pragma: no cover  (ray is in the test extra)
        raise ImportError("executor='ray' needs Ray: pip install 'stcgym[ray]'") from exc
    if not ray.is_initialized():
        cpus = None if address is not None or jobs is None else int(jobs)
        ray.init(address=address, num_cpus=cpus, include_dashboard=False, log_to_driver=False)
    return ray


def _run_ray(
    fn: Callable[[Any], Any],
    todo: list[tuple[int, Any]],
    jobs: int | None,
    address: str | None,
    progress: Progress | None,
    threads: int,
    admit: Callable[[Any], bool],
) -> Iterator[TaskOutcome]:
    ray = connect_ray(address, jobs)
    remote = ray.remote(num_cpus=1, max_retries=0)(_call)
    fn_ref = ray.put(fn)
    queue = list(todo)
    running: dict[Any, tuple[int, Any]] = {}
    cap = len(todo) if jobs is None else int(jobs)
    try:
        while True:
            while len(running) < cap and (nxt := _next_admitted(queue, admit)):
                running[remote.remote(fn_ref, nxt[1], threads)] = nxt
            if not running:
                return
            ready, _ = ray.wait(list(running), num_returns=1)
            for ref in ready:
                i, task = running.pop(ref)
                try:
                    out = TaskOutcome(i, task, *ray.get(ref))
                except Exception as exc:  # noqa: BLE001  (worker crash, node lost)
                    out = TaskOutcome(i, task, None, f"ray task failed: {exc!r}", 0.0)
                _tick(progress, out)
                yield out
    finally:
        for ref in running:
            ray.cancel(ref, force=True)
