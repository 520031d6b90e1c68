"""Closed-loop throughput of the self-tuning regulator: naive loop, fast path, batched loop.

Run from the repository root::

    python benchmarks/perf.py            # full table (about 2-3 minutes on 2 cores)
    python benchmarks/perf.py --quick    # fewer steps, B up to 1e4 (about 30 s)

Every row is one closed-loop configuration measured in this run; ratios are to the naive loop
of the same run, so they stay meaningful on a loaded machine (absolute numbers do not).

* ``naive``: ``gym.make`` env step + :func:`~stcgym.adaptive.recursive.make_estimator`
  KF-MILS (p = 5) + ``control.place`` on the integral-augmented estimated model every step.
* ``fast path``: :class:`~stcgym.adaptive.batched_fast.FastLoop`, one plant, scalar generated
  code: plant + the full :class:`~stcgym.adaptive.controller.SelfTuningController` step
  (KF-MILS p = 5, bootstrap, Ackermann pole placement with its safe set, adaptive Kalman noise).
* ``batched fast``: the vector env
  (:class:`~stcgym.envs.vector.ObserverCanonicalVectorEnv`) and
  ``BatchedSelfTuningController(mode="fast")`` with ``B`` plants, one kernel call per chunk.
* ``batched exact``: ``mode="exact"``, the single controller's calls stacked (equal to rounding).
* ``batched fast, 2 procs``: the lanes split over two worker processes (both CPU cores).

Throughput is measured after a warm-up past the bootstrap hand-over (step 100), i.e. in the
closed-loop regime; memory is bytes of lane state per plant (env + controller arrays, and with
``tracemalloc`` everything allocated, Python objects included).
"""

from __future__ import annotations

import argparse
import gc
import math
import multiprocessing as mp
import time
import tracemalloc
import warnings
from typing import Any

import numpy as np

PLANTS = {2: "stable2", 4: "stable4"}
WARMUP = 110  # past the bootstrap hand-over at t = 100


def _naive(steps: int) -> float:
    """Plant-steps per second of the naive loop (python-control ``place`` every step)."""
    import control
    import gymnasium as gym

    import stcgym.envs  # noqa: F401 - registers the envs
    from stcgym.adaptive.recursive import make_estimator

    env = gym.make("stcgym/ObserverCanonical-v0", plant="stable2", noise_std=0.1)
    est = make_estimator("KF-MILS", 2, p=5, process_noise=1e-4)
    poles = [0.5, 0.45, 0.4]  # distinct: place() needs them for a single input
    obs, _ = env.reset(seed=0)
    K = np.zeros(3)
    xi = 0.0
    rng = np.random.default_rng(0)
    t0 = 0.0
    for k in range(WARMUP // 4 + steps):
        if k == WARMUP // 4:
            t0 = time.perf_counter()
        y, r = float(obs[0]), float(obs[1])
        theta = est.update(y)
        A = np.array([[-theta[0], 1.0], [-theta[1], 0.0]])
        Aa = np.zeros((3, 3))
        Aa[:2, :2] = A
        Aa[2, 0], Aa[2, 2] = -1.0, 1.0
        ba = np.array([[theta[2]], [theta[3]], [0.0]])
        try:
            K = np.asarray(control.place(Aa, ba, poles)).ravel()
        except Exception:  # noqa: BLE001 - an unplaceable model keeps the last gain
            pass
        x = est.x_hat
        if k < 20:
            u = float(rng.choice([-1.0, 1.0]))
        else:
            u = float(np.clip(-(K[:2] @ x) - K[2] * xi, -10.0, 10.0))
            xi += r - y
        est.predict(u)
        obs, *_ = env.step(np.array([u]))
    return steps / (time.perf_counter() - t0)


def _fast_path(steps: int, n: int = 2) -> float:
    from stcgym.adaptive.batched_fast import FastLoop

    loop = FastLoop(plant=PLANTS[n], noise_std=0.1, controller=dict(n=n, p=5), seed=0)
    loop.run(WARMUP)
    best = math.inf
    chunk = max(steps // 5, 20)
    for _ in range(5):
        t0 = time.perf_counter()
        loop.run(chunk)
        best = min(best, (time.perf_counter() - t0) / chunk)
    return 1.0 / best


def _batched(B: int, n: int, steps: int, mode: str = "fast", seed: int = 0) -> tuple[float, dict]:
    """Plant-steps per second of vector env + batched controller, and memory figures."""
    from stcgym.adaptive.batched_controller import BatchedSelfTuningController
    from stcgym.envs.vector import ObserverCanonicalVectorEnv

    venv = ObserverCanonicalVectorEnv(
        num_envs=B, plant=PLANTS[n], noise_std=0.1, max_episode_steps=10**9, info_keys=()
    )
    ctl = BatchedSelfTuningController(n, num_envs=B, p=5, mode=mode)
    obs, _ = venv.reset(seed=seed)
    for _ in range(WARMUP):
        a, _ = ctl.predict(obs)
        obs, *_ = venv.step(a)
    t0 = time.perf_counter()
    for _ in range(steps):
        a, _ = ctl.predict(obs)
        obs, *_ = venv.step(a)
    dt = time.perf_counter() - t0
    mem = {"env": venv.memory_per_lane, "ctl": getattr(ctl, "memory_per_lane", float("nan"))}
    return B * steps / dt, mem


def _traced_memory(B: int, n: int) -> float:
    """Bytes per plant of everything a vector env + fast controller allocate (tracemalloc)."""
    from stcgym.adaptive.batched_controller import BatchedSelfTuningController
    from stcgym.envs.vector import ObserverCanonicalVectorEnv

    BatchedSelfTuningController(n, num_envs=1, p=5, mode="fast")  # compile outside the trace
    gc.collect()
    tracemalloc.start()
    base = tracemalloc.get_traced_memory()[0]
    venv = ObserverCanonicalVectorEnv(num_envs=B, plant=PLANTS[n], noise_std=0.1, info_keys=())
    ctl = BatchedSelfTuningController(n, num_envs=B, p=5, mode="fast")
    obs, _ = venv.reset(seed=0)
    a, _ = ctl.predict(obs)
    venv.step(a)
    used = tracemalloc.get_traced_memory()[0] - base
    tracemalloc.stop()
    del venv, ctl
    return used / B


def _worker(args: tuple[int, int, int, int, Any]) -> float:
    B, n, steps, seed, barrier = args
    from stcgym.adaptive.batched_controller import BatchedSelfTuningController
    from stcgym.envs.vector import ObserverCanonicalVectorEnv

    warnings.simplefilter("ignore")
    venv = ObserverCanonicalVectorEnv(
        num_envs=B, plant=PLANTS[n], noise_std=0.1, max_episode_steps=10**9, info_keys=()
    )
    ctl = BatchedSelfTuningController(n, num_envs=B, p=5, mode="fast")
    obs, _ = venv.reset(seed=seed)
    for _ in range(WARMUP):
        a, _ = ctl.predict(obs)
        obs, *_ = venv.step(a)
    barrier.wait()
    t0 = time.perf_counter()
    for _ in range(steps):
        a, _ = ctl.predict(obs)
        obs, *_ = venv.step(a)
    return time.perf_counter() - t0


def _processes(B: int, n: int, steps: int, workers: int) -> float:
    ctx = mp.get_context("fork")
    with ctx.Manager() as manager:
        barrier = manager.Barrier(workers)
        with ctx.Pool(workers) as pool:
            jobs = [(B // workers, n, steps, 1000 * i, barrier) for i in range(workers)]
            times = pool.map(_worker, jobs)
    return (B // workers) * workers * steps / max(times)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer steps, B up to 1e4")
    ap.add_argument("--max-b", type=int, default=None, help="largest batch (default 1e5)")
    ap.add_argument("--n", type=int, nargs="+", default=[2, 4], help="plant orders")
    ap.add_argument("--workers", type=int, default=2, help="processes for the split run")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    max_b = args.max_b or (10_000 if args.quick else 100_000)
    budget = 1.5e5 if args.quick else 1.5e6  # plant-steps per batched row
    sizes = [b for b in (1, 100, 1_000, 10_000, 100_000) if b <= max_b]

    rows: list[tuple[str, int, int, float, str]] = []
    naive = _naive(100 if args.quick else 300)
    rows.append(("naive loop (python-control place)", 1, 2, naive, ""))
    rows.append(("fast path (FastLoop, scalar)", 1, 2, _fast_path(500 if args.quick else 2000), ""))
    for n in args.n:
        for B in sizes:
            steps = int(min(200, max(5, budget // B)))
            rate, mem = _batched(B, n, steps)
            rows.append(
                ("batched fast", B, n, rate, f"{mem['env'] + mem['ctl']:.0f} B/plant (arrays)")
            )
    if not args.quick:
        rate, _ = _batched(1_000, 2, 50, mode="exact")
        rows.append(("batched exact", 1_000, 2, rate, ""))
    if args.workers > 1:
        B = max_b
        steps = int(min(200, max(5, budget // B)))
        rate = _processes(B, 2, steps, args.workers)
        rows.append((f"batched fast, {args.workers} processes", B, 2, rate, ""))
    traced = _traced_memory(min(max_b, 10_000), 2)

    print(f"\nclosed-loop throughput (KF-MILS p=5 + pole placement), numpy {np.__version__}")
    head = f"{'configuration':40s} {'B':>7s} {'n':>2s} {'plant-steps/s':>14s} {'x naive':>9s}"
    print(head + "  us/plant-step  note")
    print("-" * (len(head) + 22))
    for name, B, n, rate, note in rows:
        print(
            f"{name:40s} {B:>7d} {n:>2d} {rate:>14.3g} {rate / naive:>9.1f}  "
            f"{1e6 / rate:>13.3f}  {note}"
        )
    print(
        f"\nmemory per plant (n=2, everything allocated incl. Python objects, tracemalloc): "
        f"{traced:.0f} B"
    )


if __name__ == "__main__":
    main()
