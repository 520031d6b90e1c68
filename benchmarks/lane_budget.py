"""Where the time of one closed-loop lane step goes, against the throughput budget.

Run from the repository root::

    python benchmarks/lane_budget.py            # about 50 s (3 min the first time: compiles)
    python benchmarks/lane_budget.py --steps 100000

The targets are ``>= 5e6`` plant-steps/s through the public batched route and ``>= 1e7``
through the compiled rollout (n = 2, KF-MILS p = 5). With every lane an independent scalar
computation (the :mod:`stcgym.lanes.compiled` convention), ``c`` cores give at most
``c / t_lane`` plant-steps/s, so the budget is ``c / target`` of one core per lane-step. This
script prints that budget next to the measured cost of each part of a lane step, every part
timed in a compiled loop over one lane (no Python in the timing; the best of 20 short runs,
which catches the quiet moments of a shared machine):

* the canonical plant step (:func:`stcgym.envs.dynamics.canonical_plant_step`);
* the KF-MILS estimator (``estimator_update`` + ``estimator_predict``, p = 5, through the
  estimator's own ``run_lane``) on the plant's open-loop data;
* its core, the multi-innovation least-squares increment (``least_squares_increment``, d = 4,
  p = 5), compiled twice from **the same source**: as shipped (the sizes are run-time values
  read from the configuration, as in every lane function) and with the sizes as compile-time
  constants (the function inlined into a driver that passes literal sizes, so LLVM unrolls its
  loops). The ratio is what size specialisation would buy on the estimator's core;
* the pole-placement design (``place_design``, order 2 + integrator), the same two ways;
* a **layout experiment** for a storage decision left open: the same MILS increment on
  blocks of ``W`` lanes stored as a structure of arrays (every scalar of the lane function
  becomes a loop over the block's lanes, innermost), against the shipped lane function run
  over the same ``B`` lanes one by one. The block version repeats the shipped function's
  operations in the same order, and the script checks that both give the same bits. It is a
  measurement, not part of the package. The block width is a run-time value on purpose: with a
  compile-time width LLVM unrolls the lane loops and then does not vectorise them (numba cannot
  promise that the record's fields do not alias), with a run-time width its loop vectoriser
  does, behind a run-time overlap check;
* the whole controller step with the plant step, KF-MILS p = 5 and the default ELS: the
  compiled rollout of ``benchmarks/perf.py`` (``rollout_rate``) with one lane, best of 5;
* the same rollout with ``B = 1e4`` lanes on all threads: plant-steps/s, and the thread
  scaling it implies.

Every figure is a measurement of this run; the machine is shared, so the ratios are more
stable than the absolute numbers.
"""

from __future__ import annotations

import argparse
import math
import time

import numba
import numpy as np
from perf import rollout_rate

from stcgym.adaptive import SelfTuningController
from stcgym.adaptive.control.placement import place_design
from stcgym.adaptive.control.safe_set import DesignConfig, design_work
from stcgym.adaptive.estimation.estimator_lanes import run_lane
from stcgym.adaptive.estimation.estimator_spec import EstimatorSpec
from stcgym.adaptive.estimation.least_squares import least_squares_increment
from stcgym.envs import PLANTS
from stcgym.envs.dynamics import canonical_plant_step

TARGETS = {"public batched route": 5e6, "compiled rollout": 1e7}

# The shipped lane functions' source, compiled so that a caller's literal sizes reach its loops.
_increment_const = numba.njit(inline="always")(least_squares_increment.py_func)
_place_const = numba.njit(inline="always")(place_design.py_func)


@numba.njit
def _plant_loop(x, theta, u, z, r, steps, y_out):  # type: ignore[no-untyped-def]
    """``steps`` plant steps under the input ``u``; ``y_out[k]`` the measured ``y(k + 1)``."""
    none = z[0:0]
    for k in range(steps):
        _, _, _, _, _, y_out[k] = canonical_plant_step(
            x, theta, u[k], 10.0, 0.0, none, 0.05, z[k + 1], r[k], 0.01, 1e9, 0
        )


@numba.njit
def _increment_generic(S, Phi, E, p, delta, K, w, steps):  # type: ignore[no-untyped-def]
    d = S.shape[0]
    acc = 0.0
    for _ in range(steps):
        acc += least_squares_increment(S, 0, d, Phi, E, p, 0.99, False, delta, K, w)
        for i in range(d):  # keep the factor from shrinking to zero over the loop
            S[i, i] *= 1.005
    return acc


@numba.njit
def _increment_specialised(S, Phi, E, p, delta, K, w, steps):  # type: ignore[no-untyped-def]
    acc = 0.0
    for _ in range(steps):
        acc += _increment_const(S, 0, 4, Phi, E, 5, 0.99, False, delta, K, w)
        for i in range(4):
            S[i, i] *= 1.005
    return acc


@numba.njit
def _increment_lanes(S, Phi, E, lam, delta, K, w):  # type: ignore[no-untyped-def]
    """The shipped lane function over ``B`` lanes, one after the other (``S`` ``(B, d, d)``)."""
    d, p = S.shape[1], Phi.shape[1]
    for i in range(S.shape[0]):
        least_squares_increment(S[i], 0, d, Phi[i], E[i], p, lam, False, delta[i], K, w)


@numba.njit(error_model="numpy")
def _increment_lane_blocks(S, Phi, E, lam, delta, K, g, alpha, f, b, c):  # type: ignore[no-untyped-def]
    """``least_squares_increment`` (MILS branch, eq. (39)-(41)) on blocks of ``W`` lanes.

    Structure of arrays: ``S`` ``(NB, d, d, W)``, ``Phi`` ``(NB, p, d, W)``, ``E`` ``(NB, p, W)``,
    ``delta`` ``(NB, d, W)``; scratch ``K``, ``g`` ``(d, W)``, ``alpha``, ``f``, ``b``, ``c``
    ``(W,)``. Same operations in the same order as the lane function, lane loop innermost.
    """
    d, p, W = S.shape[1], Phi.shape[1], S.shape[3]
    inv_sqrt_lam = 1.0 / math.sqrt(lam) if lam != 1.0 else 1.0
    for blk in range(S.shape[0]):
        Sb, Pb, Eb, Db = S[blk], Phi[blk], E[blk], delta[blk]
        for k in range(p):  # p Carlson updates, the first with alpha_0 = lam
            for lane in range(W):
                alpha[lane] = lam if k == 0 else 1.0
            for i in range(d):
                for lane in range(W):
                    K[i, lane] = 0.0
            for j in range(d):
                for lane in range(W):
                    f[lane] = 0.0
                for i in range(j + 1):
                    for lane in range(W):
                        f[lane] += Sb[i, j, lane] * Pb[k, i, lane]
                for lane in range(W):
                    alpha_new = alpha[lane] + f[lane] * f[lane]
                    inv_r = 1.0 / math.sqrt(alpha[lane] * alpha_new)
                    b[lane] = alpha[lane] * inv_r
                    c[lane] = f[lane] * inv_r
                    alpha[lane] = alpha_new
                for i in range(j + 1):
                    for lane in range(W):
                        sij = Sb[i, j, lane]
                        Sb[i, j, lane] = b[lane] * sij - c[lane] * K[i, lane]
                        K[i, lane] += f[lane] * sij
            if k == 0 and lam != 1.0:
                for j in range(d):
                    for i in range(j + 1):
                        for lane in range(W):
                            Sb[i, j, lane] *= inv_sqrt_lam
        for i in range(d):  # K = Phi^T E, then delta = S S^T K
            for lane in range(W):
                K[i, lane] = 0.0
            for k in range(p):
                for lane in range(W):
                    K[i, lane] += Pb[k, i, lane] * Eb[k, lane]
        for j in range(d):
            for lane in range(W):
                g[j, lane] = 0.0
            for i in range(j + 1):
                for lane in range(W):
                    g[j, lane] += Sb[i, j, lane] * K[i, lane]
        for i in range(d):
            for lane in range(W):
                Db[i, lane] = 0.0
            for j in range(i, d):
                for lane in range(W):
                    Db[i, lane] += Sb[i, j, lane] * g[j, lane]


def _to_blocks(a: np.ndarray, width: int) -> np.ndarray:
    """``(B, ...)`` lane-major to ``(B / width, ..., width)`` blocks (lanes innermost)."""
    blocks = a.reshape((a.shape[0] // width, width) + a.shape[1:])
    return np.ascontiguousarray(np.moveaxis(blocks, 1, -1))


def _from_blocks(a: np.ndarray) -> np.ndarray:
    return np.moveaxis(a, -1, 1).reshape((-1,) + a.shape[1:-1])


def _layout_experiment(rng: np.random.Generator, lanes: int = 8192) -> None:
    """Per-lane ns of the MILS increment (d = 4, p = 5, lam = 0.99) over ``lanes`` lanes."""
    d, p, lam = 4, 5, 0.99
    S0 = np.triu(rng.standard_normal((lanes, d, d))) + 3.0 * np.eye(d)
    Phi, E = rng.standard_normal((lanes, p, d)), rng.standard_normal((lanes, p))
    delta, K, w = np.zeros((lanes, d)), np.zeros(d), np.zeros(2 * d)
    S_ref = S0.copy()
    _increment_lanes(S_ref, Phi, E, lam, delta, K, w)  # one update from S0: the reference bits
    delta_ref = delta.copy()
    S = S0.copy()  # the timed runs keep updating the same factors
    shipped = _best_ns(lambda _: _increment_lanes(S, Phi, E, lam, delta, K, w), lanes)
    label = f"  its MILS increment, the shipped lane function over B = {lanes} lanes"
    print(f"{label:66s} {shipped:9.0f} ns")
    for width in (16, 64):
        Pb, Eb = _to_blocks(Phi, width), _to_blocks(E, width)
        Db = np.zeros((lanes // width, d, width))
        scratch = [np.zeros((d, width)), np.zeros((d, width))]
        scratch += [np.zeros(width) for _ in range(4)]
        Sb = _to_blocks(S0, width)
        _increment_lane_blocks(Sb, Pb, Eb, lam, Db, *scratch)
        same = np.array_equal(_from_blocks(Sb), S_ref)
        same = same and np.array_equal(_from_blocks(Db), delta_ref)

        def run(_: int, Sb=Sb, Pb=Pb, Eb=Eb, Db=Db, scratch=scratch) -> None:  # type: ignore[no-untyped-def]
            _increment_lane_blocks(Sb, Pb, Eb, lam, Db, *scratch)

        ns = _best_ns(run, lanes)
        label = (
            f"  the same on blocks of W = {width} lanes ({shipped / ns:.1f}x; same bits: {same})"
        )
        print(f"{label:66s} {ns:9.0f} ns")


@numba.njit
def _place_generic(buf, cfg, gain, work, steps):  # type: ignore[no-untyped-def]
    status = 0
    d = buf.shape[0]
    for _ in range(steps):
        buf[0] += 1e-12  # a new model every call, as in the controller
        status += place_design(buf[0:d], cfg, gain, work, 0)
    return status


@numba.njit
def _place_specialised(buf, cfg, gain, work, steps):  # type: ignore[no-untyped-def]
    status = 0
    for _ in range(steps):
        buf[0] += 1e-12
        status += _place_const(buf[0:4], cfg, gain, work, 0)
    return status


def _best_ns(run, steps: int, repeats: int = 20) -> float:  # type: ignore[no-untyped-def]
    """Best-of-``repeats`` wall time per step (or lane) of ``run(steps)``, in ns (compiled
    first, by a call with 10)."""
    run(10)
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        run(steps)
        best = min(best, time.perf_counter() - t0)
    return best / steps * 1e9


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description="lane-step cost against the throughput budget")
    ap.add_argument("--steps", type=int, default=20_000, help="steps per timed loop")
    steps = ap.parse_args(argv).steps
    rng = np.random.default_rng(0)
    theta = PLANTS["stable2"].theta
    square = np.where((np.arange(steps + 1) % 100) < 50, 1.0, -1.0)
    z = rng.standard_normal(steps + 1)
    u_in = rng.choice([-1.0, 1.0], size=steps)

    def row(name: str, ns: float) -> None:
        print(f"{name:66s} {ns:9.0f} ns", flush=True)

    cores = numba.get_num_threads()
    print(f"threads: {cores}")
    for name, target in TARGETS.items():
        print(f"budget, {name} >= {target:.0e} plant-steps/s: {cores / target * 1e9:.0f} ns "
              f"of one core per lane-step")  # fmt: skip
    print()
    y_next = np.zeros(steps)  # y(k + 1) of the plant under the +-1 input (open loop)

    def plant(s: int) -> None:
        _plant_loop(np.zeros(2), theta, u_in, z, square, s, y_next)

    row("plant step (canonical, n = 2)", _best_ns(plant, steps))

    # the estimator on that open-loop data (every timed run filled y_next from x = 0)
    spec = EstimatorSpec.build("KF-MILS", 2, p=5)
    y_ol = np.concatenate(([0.05 * z[0]], y_next[:-1]))  # y(k), measured before u(k)
    thetas, status = np.zeros((steps, 4)), np.zeros(steps, dtype=np.int64)

    def estimate(s: int) -> None:
        state, work = spec.initial_state(), spec.make_work(1)
        run_lane(state, work, 0, spec.config, u_in[:s], y_ol[:s], thetas, status, 0)

    row("KF-MILS estimator, update + predict (p = 5, d = 4)", _best_ns(estimate, steps))

    S = np.triu(rng.standard_normal((4, 4))) + 3.0 * np.eye(4)
    Phi, E = rng.standard_normal((5, 4)), rng.standard_normal(5)
    scratch = (np.zeros(4), np.zeros(4), np.zeros(8))
    gen = _best_ns(lambda s: _increment_generic(S.copy(), Phi, E, 5, *scratch, s), steps)
    fixed = _best_ns(lambda s: _increment_specialised(S.copy(), Phi, E, 5, *scratch, s), steps)
    row("  its MILS increment, sizes at run time (as shipped)", gen)
    row(f"  the same source, sizes compile-time constants ({gen / fixed:.1f}x)", fixed)

    _layout_experiment(rng)

    c = SelfTuningController(2).compiled_args.cfg  # the default poles and safe set
    cfg = DesignConfig(0, True, True, c.safe, c.char_poly)
    gain, work = np.zeros(6), design_work(2, True)
    gen = _best_ns(lambda s: _place_generic(theta.copy(), cfg, gain, work, s), steps)
    fixed = _best_ns(lambda s: _place_specialised(theta.copy(), cfg, gain, work, s), steps)
    row("pole-placement design (order 2 + integrator), as shipped", gen)
    row(f"  the same source, sizes compile-time constants ({gen / fixed:.1f}x)", fixed)

    # the compiled rollout (benchmarks/perf.py), best of a few calls
    lane_ns = {}
    for est in ("KF-MILS", "ELS"):
        lane_ns[est] = 1e9 / max(rollout_rate(2, 1, steps, est) for _ in range(5))
        row(f"controller step + plant step, one lane (rollout, B = 1), {est}", lane_ns[est])
    B = 10_000
    for est in ("KF-MILS", "ELS"):
        rate = max(rollout_rate(2, B, max(20, 2_000_000 // B), est) for _ in range(3))
        print(f"compiled rollout, B = {B}, {est}: {rate:.3g} plant-steps/s on {cores} threads "
              f"(= {rate * lane_ns[est] * 1e-9:.2f} lanes' worth of one-lane speed)")  # fmt: skip
    print()
    for name, target in TARGETS.items():
        budget = cores / target * 1e9
        cost = lane_ns["KF-MILS"]
        print(f"{name}: budget {budget:.0f} ns per lane-step; one KF-MILS lane step costs "
              f"{cost:.0f} ns ({cost / budget:.1f}x the budget)")  # fmt: skip


if __name__ == "__main__":
    main()
