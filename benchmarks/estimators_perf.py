"""Speed of the recursive estimators (compiled lane functions) and the frozen-signal measurement.

Run from the repository root::

    python benchmarks/estimators_perf.py            # speed table (about 1 minute once compiled)
    python benchmarks/estimators_perf.py --frozen   # the frozen-estimator measurement (~2 min)

Speed: O-RLS (n = 2) and KF-MILS (n = 2, p = 5), one ``update(y)`` + ``predict(u)`` pair per
step. Rows: the public single estimator (``make_estimator``), the bare lane functions on a
record (what a compiled controller step pays), the public batched estimator at ``B = 1e4``
(``make_estimator(..., num_envs=B)``), and the dense-numpy reference of the paper's formulas
(``stcgym.adaptive.estimation.reference``: explicit ``P``, numpy calls) as the baseline of the
ratios
(the former numpy ``RecursiveEstimator`` is gone; it ran O-RLS at about 49 us per step on the
development machine). Everything in the same run: ratios are meaningful on a loaded machine,
absolute numbers are not. First-call compile time (or the on-disk cache load) is reported
separately.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

CASES = {"O-RLS": {}, "KF-MILS": {"p": 5, "process_noise": 1e-4}}


def _best(fn, repeats: int = 3) -> float:
    """Best wall time of ``fn()`` over ``repeats`` runs."""
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def speed(T: int, B: int) -> None:
    rng = np.random.default_rng(0)
    u, y = rng.standard_normal(T), rng.standard_normal(T)
    U, Y = rng.standard_normal((20, B)), rng.standard_normal((20, B))
    print(f"{'estimator':9s} {'route':44s} {'us/step':>9s} {'lane-steps/s':>13s} {'x ref':>7s}")
    for name, kw in CASES.items():
        _measure(name, kw, u, y, U, Y)


def _measure(
    name: str, kw: dict, u: np.ndarray, y: np.ndarray, U: np.ndarray, Y: np.ndarray
) -> None:
    """One estimator's rows of the table (closures bind this call's objects)."""
    from stcgym.adaptive import make_estimator
    from stcgym.adaptive.estimation.estimator_lanes import predict_lanes, run_lane, update_lanes
    from stcgym.adaptive.estimation.estimator_spec import EstimatorSpec
    from stcgym.adaptive.estimation.reference import ReferenceEstimator

    T, B = u.size, U.shape[1]
    t0 = time.perf_counter()
    est = make_estimator(name, 2, **kw)
    est.update(1.0)
    est.predict(0.0)
    batch = make_estimator(name, 2, num_envs=B, **kw)
    batch.update(Y[0])
    batch.predict(U[0])
    compile_s = time.perf_counter() - t0

    ref = ReferenceEstimator(EstimatorSpec.build(name, 2, **kw))
    Tr = max(T // 10, 100)

    def ref_loop() -> None:
        for k in range(Tr):
            ref.update(y[k])
            ref.predict(u[k])

    t_ref = _best(ref_loop) / Tr

    def single_loop() -> None:
        for k in range(T):
            est.update(y[k])
            est.predict(u[k])

    t_single = _best(single_loop) / T
    state, work, cfg = est.spec.initial_state(), est.spec.make_work(1), est.spec.config
    one, lane_status = np.zeros(1), np.zeros(1, dtype=np.int64)

    def lane_loop() -> None:
        for k in range(T):
            one[0] = y[k]
            update_lanes(state, work, cfg, one, lane_status)
            one[0] = u[k]
            predict_lanes(state, work, cfg, one, lane_status)

    t_lane = _best(lane_loop) / T
    thetas = np.empty((T, 4))
    status = np.zeros(T, dtype=np.int64)
    state2 = est.spec.initial_state()
    t_run = _best(lambda: run_lane(state2, work, 0, cfg, u, y, thetas, status, 0)) / T

    def batch_loop() -> None:
        for k in range(20):
            batch.update(Y[k])
            batch.predict(U[k])

    t_batch = _best(batch_loop) / (20 * B)
    rows = [
        ("dense-numpy reference (baseline)", t_ref),
        ("make_estimator: update + predict", t_single),
        ("lane loops update_lanes/predict_lanes, B = 1", t_lane),
        ("compiled T-step loop (run_lane, est.run)", t_run),
        (f"make_estimator(num_envs={B:.0e}), per lane", t_batch),
    ]
    for route, t in rows:
        print(f"{name:9s} {route:44s} {t * 1e6:9.3f} {1.0 / t:13.3g} {t_ref / t:7.1f}")
    print(f"{name:9s} first-call compile (or cache load): {compile_s:.1f} s")


def frozen(T: int, seeds: int) -> None:
    """How well ``health["frozen"]`` marks wrong estimates (see
    stcgym.adaptive.estimation.health)."""
    from stcgym.adaptive import make_estimator
    from stcgym.envs.canonical import canonical_matrices

    plants = {
        "zero at 4.64": ([-1.5, 0.6994], [1.0, -4.64]),
        "stable2": ([-1.5, 0.6994], [1.0, 0.5]),
        "poles 0.3+-0.33j": ([-0.6, 0.2], [0.5, 1.0]),
    }
    print(f"T = {T}, white input, observer form, names O-RLS O-MILS O-D-RLS KF-RLS O-D-MILS")
    for noise in (0.1, 1.0):
        rows = []
        for a, b in plants.values():
            theta = np.r_[a, b]
            A, Bm, _, _ = canonical_matrices(a, b, "observer")
            for seed in range(seeds):
                rng = np.random.default_rng(seed)
                u = rng.standard_normal(T)
                x = np.zeros(2)
                y = np.empty(T)
                for k in range(T):
                    y[k] = x[0] + noise * rng.standard_normal()
                    x = A @ x + Bm[:, 0] * u[k]
                for name in ("O-RLS", "O-MILS", "O-D-RLS", "KF-RLS", "O-D-MILS"):
                    for p0 in (1e6, 100.0):
                        est = make_estimator(name, 2, p0=p0, p=3 if "MI" in name else 1)
                        with warnings.catch_warnings(record=True) as caught:
                            warnings.simplefilter("always")
                            th = est.run(u, y)[-1]
                        ever = any("frozen" in str(w.message) for w in caught)
                        err = np.linalg.norm(th - theta) / np.linalg.norm(theta)
                        rows.append((err, est.frozen, ever))
        r = np.array(rows, dtype=float)
        for thr in (0.05, 0.1):
            bad = r[:, 0] > thr
            print(
                f"noise std {noise}: error > {thr:.0%}: {int(bad.sum())} runs, flagged at the end "
                f"{int(r[bad, 1].sum())}; error <= {thr:.0%}: {int((~bad).sum())} runs, flagged "
                f"at the end {int(r[~bad, 1].sum())}, at some time {int(r[~bad, 2].sum())}"
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frozen", action="store_true", help="run the frozen-signal measurement")
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--lanes", type=int, default=10000)
    args = ap.parse_args()
    if args.frozen:
        frozen(200_000, 3)
    else:
        speed(args.steps, args.lanes)


if __name__ == "__main__":
    main()
