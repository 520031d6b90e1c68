"""Closed-loop throughput of the self-tuning controller (the README's performance table).

Run from the repository root::

    python benchmarks/perf.py            # full table, B up to 1e6 (a few minutes on 2 cores)
    python benchmarks/perf.py --quick    # fewer steps, B up to 1e4
    python benchmarks/perf.py --threads  # plant and controller batch steps: 1 thread vs all

Every row is measured in this run; ratios are to the naive loop of the same run, so they stay
meaningful on a loaded machine (absolute numbers do not).

* ``naive``: ``gym.make`` env step + :func:`~stcgym.adaptive.make_estimator`
  KF-MILS (p = 5) + ``control.place`` on the integral-augmented estimated model every step;
* ``predict``: ``SelfTuningController(2).predict(obs)`` through the Python API (one call per
  step, plant in numpy);
* ``rollout``: :func:`stcgym.adaptive.control.rollout.rollout`, plant + controller fused in one
  compiled call, ``B`` lanes in one batch loop;
* ``vector env``: the public batched route, ``gym.make_vec(..., num_envs=B)`` +
  ``SelfTuningController(2, num_envs=B)``, one ``predict`` and one ``step`` per sample;
* memory: bytes of controller lane records per plant; import time and first-call compile time
  in fresh processes (the compile with an empty numba cache directory).

Estimators: the default (``ELS``) and ``KF-MILS`` with ``p = 5``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

WARMUP = 30
SQUARE = np.array([1.0 if (k % 100) < 50 else -1.0 for k in range(100_001)])
PLANT_OF = {2: "stable2", 4: "stable4", 8: None}


def _theta(n: int) -> np.ndarray:
    from stcgym.envs import PLANTS

    if PLANT_OF[n] is not None:
        return PLANTS[PLANT_OF[n]].theta
    poles = 0.6 * np.exp(1j * np.linspace(0.3, 2.5, n // 2))
    a = np.real(np.poly(np.r_[poles, poles.conj()]))[1:]
    return np.r_[a, 0.1 * np.ones(n)]


def _naive(steps: int) -> float:
    """Plant-steps per second of the naive loop (python-control ``place`` every step)."""
    import control
    import gymnasium as gym

    import stcgym.envs  # noqa: F401 - registers the envs
    from stcgym.adaptive import make_estimator
    from stcgym.adaptive.control.placement import augment_integral
    from stcgym.envs.canonical import companion_A

    env = gym.make("stcgym/ObserverCanonical-v0", plant="stable2", noise_std=0.1)
    est = make_estimator("KF-MILS", 2, p=5, process_noise=1e-4)
    poles = [0.5, 0.45, 0.4]  # distinct: place() needs them for a single input
    obs, _ = env.reset(seed=0)
    K = np.zeros(3)
    xi = 0.0
    rng = np.random.default_rng(0)
    t0 = 0.0
    for k in range(25 + steps):
        if k == 25:
            t0 = time.perf_counter()
        y, r = float(obs[0]), float(obs[1])
        theta = est.update(y)
        Aa, ba = augment_integral(companion_A(theta[:2]), theta[2:])
        try:
            K = np.asarray(control.place(Aa, ba[:, None], poles)).ravel()
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


def _predict_us(steps: int, estimator: str) -> float:
    from stcgym.adaptive import SelfTuningController
    from stcgym.envs.canonical import companion_A

    th = _theta(2)
    A, b = companion_A(th[:2]), th[2:]
    ctl = SelfTuningController(2, estimator=estimator, estimator_options={"p": 5})
    x = np.zeros(2)
    obs = np.zeros(2)
    total = 0.0
    for k in range(WARMUP + steps):
        obs[0], obs[1] = x[0], SQUARE[k]
        t0 = time.perf_counter()
        u = ctl.predict(obs)[0][0]
        if k >= WARMUP:
            total += time.perf_counter() - t0
        x = A @ x + b * u
    return total / steps * 1e6


def rollout_rate(n: int, B: int, steps: int, estimator: str) -> float:
    """Plant-steps/s of one :func:`~stcgym.adaptive.control.rollout.rollout` call (``B`` lanes,
    ``steps``
    steps, the order-``n`` test plant, the square-wave reference); also used by
    ``lane_budget.py``."""
    from stcgym.adaptive import SelfTuningController
    from stcgym.adaptive.control.rollout import rollout

    ctl = SelfTuningController(
        n, num_envs=None if B == 1 else B, estimator=estimator, estimator_options={"p": 5}
    )
    rollout(ctl, _theta(n), 2, reference=SQUARE[:3])  # compile outside the timing
    ctl.reset()
    t0 = time.perf_counter()
    res = rollout(ctl, _theta(n), steps, reference=SQUARE[: steps + 1])
    # a diverged lane stops early: count the steps actually run
    return float(res.steps_run.sum()) / (time.perf_counter() - t0)


def _vector_rate(B: int, steps: int, estimator: str) -> float:
    import gymnasium as gym

    import stcgym.envs  # noqa: F401
    from stcgym.adaptive import SelfTuningController

    venv = gym.make_vec(
        "stcgym/ObserverCanonical-v0", num_envs=B, plant="stable2", noise_std=0.05,
        max_episode_steps=100_000,
    )  # fmt: skip
    ctl = SelfTuningController(
        2, num_envs=B, env=venv, estimator=estimator, estimator_options={"p": 5}
    )
    obs, _ = venv.reset(seed=0)
    t0 = 0.0
    for k in range(WARMUP + steps):
        if k == WARMUP:
            t0 = time.perf_counter()
        action, _ = ctl.predict(obs)
        obs, *_ = venv.step(action)
    return B * steps / (time.perf_counter() - t0)


def _blocks_ns(loop, args: tuple, B: int, threads: int, steps: int, warmup: int = 1) -> float:
    """Nanoseconds per lane of ``loop(*args, first, last)`` over ``B`` lanes in blocks on
    ``threads`` threads (whatever the loop's own threshold), best of 5: the least disturbed by
    other processes."""
    import numba

    from stcgym.lanes.compiled import run_blocks

    saved = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        for _ in range(warmup):
            run_blocks(loop, args, min_lanes=1)
        best = np.inf
        for _ in range(5):
            t0 = time.perf_counter()
            for _ in range(steps):
                run_blocks(loop, args, min_lanes=1)
            best = min(best, (time.perf_counter() - t0) / steps)
    finally:
        numba.set_num_threads(saved)
    return best / B * 1e9


def plant_batch_ns(B: int, threads: int, steps: int, n: int = 2) -> float:
    """Nanoseconds per lane of one noisy canonical plant batch step (the vector env's compiled
    loop, :func:`stcgym.envs.dynamics.canonical_plants_step`, through numba's dispatcher) on
    ``threads`` threads."""
    from stcgym.envs import dynamics

    rng = np.random.default_rng(0)
    X = np.zeros((B, n))
    Theta = np.tile(_theta(n), (B, 1))
    U_raw, R = rng.uniform(-1, 1, B), np.zeros(B)
    Z_w, Z_v = rng.standard_normal((B, n)), rng.standard_normal(B)
    U, Y_clean, Y, reward = np.zeros(B), np.zeros(B), np.zeros(B), np.zeros(B)
    clipped, diverged = np.zeros(B, bool), np.zeros(B, bool)
    args = (X, Theta, U_raw, 10.0, 0.01, Z_w, 0.1, Z_v, R, 0.0, 1e6, 0)
    outs = (U, Y_clean, Y, reward, clipped, diverged)
    return _blocks_ns(dynamics.canonical_plants_step.dispatcher, (*args, *outs), B, threads, steps)


def controller_batch_ns(B: int, threads: int, steps: int) -> float:
    """Nanoseconds per lane of one batch step of ``SelfTuningController(2, num_envs=B)`` (the
    compiled loop :func:`stcgym.adaptive.control.controller_step.controllers_step`) on ``threads``
    threads, after 200 steps (the loop closed on every lane)."""
    import numba

    from stcgym.adaptive import SelfTuningController
    from stcgym.adaptive.control import controller_step as kc

    c = SelfTuningController(2, num_envs=B)
    u, y, r = np.zeros(B), np.full(B, 0.1), np.ones(B)
    args = (*c.compiled_args, y, r, u)
    types = tuple(numba.typeof(a) for a in args) + (numba.int64, numba.int64)
    loop = kc.controllers_step.dispatcher.compile(types)
    return _blocks_ns(loop, args, B, threads, steps, warmup=200)


def threads_table() -> None:
    """One thread against all cores for two batch loops, the plant step and the controller
    step: the basis of :data:`stcgym.envs.dynamics.PARALLEL_MIN_LANES` and
    :data:`stcgym.lanes.compiled.DEFAULT_MIN_LANES`."""
    import numba

    cores = numba.config.NUMBA_NUM_THREADS
    for name, ns, sizes, work in (
        ("plant batch step, n=2", plant_batch_ns, (1024, 16384, 65536, 262144), 2_000_000),
        ("controller batch step, n=2, ELS", controller_batch_ns, (16, 64, 256, 1024), 20_000),
    ):
        print(f"{name}, ns per lane (best of 5), 1 thread vs {cores} threads")
        print(f"{'B':>8s} {'1 thread':>10s} {f'{cores} threads':>11s} {'speed-up':>9s}")
        for B in sizes:
            steps = max(20, work // B)
            one, many = ns(B, 1, steps), ns(B, cores, steps)
            print(f"{B:8d} {one:10.1f} {many:11.1f} {one / many:8.2f}x", flush=True)


def _fresh_process(code: str, cache_dir: str | None = None) -> float:
    env = dict(os.environ)
    if cache_dir is not None:
        env["NUMBA_CACHE_DIR"] = cache_dir
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], check=True, env=env)
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description="closed-loop throughput table")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument(
        "--threads",
        action="store_true",
        help="only the plant and controller batch steps, one thread against all cores",
    )
    args = ap.parse_args(argv)
    if args.threads:
        threads_table()
        return
    q = args.quick
    rows: list[tuple[str, str, str]] = []

    def row(name: str, value: str, ratio: float | None) -> None:
        r = "" if ratio is None else f"{ratio:10.0f}x"
        rows.append((name, value, r))
        print(f"{name:58s} {value:>22s} {r:>12s}", flush=True)

    print(f"{'configuration':58s} {'measured':>22s} {'vs naive':>12s}")
    naive = _naive(100 if q else 400)
    row("naive loop (gym.make + KF-MILS + control.place), n=2", f"{naive:.3g} steps/s", 1.0)
    for est in ("ELS", "KF-MILS"):
        us = _predict_us(500 if q else 3000, est)
        row(f"SelfTuningController(2).predict, {est}", f"{us:.2f} us/call", 1e6 / us / naive)
    for n in (2, 4, 8):
        rate = rollout_rate(n, 1, 2000 if q else 20000, "ELS")
        row(f"compiled rollout, B=1, n={n}, ELS", f"{1e6 / rate:.2f} us/step", rate / naive)
    rate = rollout_rate(2, 1, 2000 if q else 20000, "KF-MILS")
    row("compiled rollout, B=1, n=2, KF-MILS p=5", f"{1e6 / rate:.2f} us/step", rate / naive)
    for est in ("ELS", "KF-MILS"):
        for B in (1000, 10_000):
            rate = _vector_rate(B, 20 if q else 100, est)
            row(f"gym.make_vec + SelfTuningController(2, num_envs={B}), {est}",
                f"{rate:.3g} steps/s", rate / naive)  # fmt: skip
    sizes = (1, 100, 10_000) if q else (1, 100, 10_000, 100_000, 1_000_000)
    for n in (2, 4, 8):
        for B in sizes:
            if n > 2 and B > 100_000:
                continue
            steps = max(10, min(2000, 2_000_000 // (B * n)))
            rate = rollout_rate(n, B, steps, "ELS")
            row(f"compiled rollout, B={B}, n={n}, ELS", f"{rate:.3g} steps/s", rate / naive)
    rate = rollout_rate(2, 10_000, 50 if q else 200, "KF-MILS")
    row("compiled rollout, B=10000, n=2, KF-MILS p=5", f"{rate:.3g} steps/s", rate / naive)
    from stcgym.adaptive import SelfTuningController

    for n in (2, 4, 8):
        for est in ("ELS", "KF-MILS"):
            mem = SelfTuningController(
                n, num_envs=2, estimator=est, estimator_options={"p": 5}
            ).nbytes_per_lane
            row(f"memory per plant, n={n}, {est}", f"{mem} bytes", None)
    imp = _fresh_process("import stcgym.adaptive, stcgym.envs")
    row("import stcgym.adaptive + stcgym.envs (fresh process)", f"{imp:.2f} s", None)
    with tempfile.TemporaryDirectory() as cache:
        code = (
            "import numpy as np; from stcgym.adaptive import SelfTuningController as S; "
            "S(2).predict(np.array([0.1, 1.0]))"
        )
        cold = _fresh_process(code, cache)
        warm = _fresh_process(code, cache)
    row("first predict, empty numba cache (compile)", f"{cold:.1f} s", None)
    row("first predict, warm numba cache", f"{warm:.1f} s", None)


if __name__ == "__main__":
    main()
