"""The cost of one single-plant ``predict`` call from Python, and of the compiled step inside it.

Run from the repository root::

    python benchmarks/predict_call.py                  # ELS, KF-MILS, O-RLS, LQ
    python benchmarks/predict_call.py --calls 500 --repeats 40

A Gymnasium loop calls ``SelfTuningController(2).predict(obs)`` once a step, so the Python
around the one compiled call is a cost every step pays. For each controller this prints the
best of ``repeats`` runs of ``calls`` calls on the same observation (microseconds a call), and
the compiled rollout's cost of one controller + plant step (``rollout`` with one lane, best of
``repeats``): the difference is what the Python side costs. Public API only, so the figures of
two versions of the package compare directly (run each in its own process, alternating).

The speed of a shared machine moves by 2x between runs minutes apart, so each figure is also
given as a ratio to a baseline measured in the same run: one call from Python of a numba
function of two floats that adds them (``bare``), the cheapest call into compiled code there
is. On the idle 2-core development machine ``bare`` took 0.19-0.33 us in three runs.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numba
import numpy as np

from stcgym.adaptive import SelfTuningController
from stcgym.adaptive.control.rollout import rollout

CONTROLLERS = {
    "ELS": {},
    "KF-MILS": {"estimator": "KF-MILS"},
    "O-RLS": {"estimator": "O-RLS"},
    "ELS, design='lq'": {"design": "lq"},
}


@numba.njit(cache=True)
def _bare(y: float, r: float) -> float:
    return y + r


def predict_us(kwargs: dict, calls: int, repeats: int) -> tuple[float, float]:
    """Microseconds a ``predict`` call and a :func:`_bare` call: best of ``repeats`` rounds,
    each ``calls`` calls of one then of the other (interleaved, so both best times come from
    the machine's fastest moments)."""
    ctl = SelfTuningController(2, **kwargs)
    obs = np.array([0.1, 1.0])
    ctl.predict(obs)  # compile (or load from the cache)
    _bare(0.1, 1.0)
    best_predict = best_bare = np.inf
    for _ in range(repeats):
        ctl.reset()
        t0 = time.perf_counter()
        for _ in range(calls):
            ctl.predict(obs)
        t1 = time.perf_counter()
        for _ in range(calls):
            _bare(0.1, 1.0)
        t2 = time.perf_counter()
        best_predict = min(best_predict, t1 - t0)
        best_bare = min(best_bare, t2 - t1)
    return best_predict / calls * 1e6, best_bare / calls * 1e6


def rollout_us(kwargs: dict, steps: int, repeats: int) -> float:
    """Best of ``repeats`` compiled rollouts of one lane, microseconds a step."""
    ctl = SelfTuningController(2, **kwargs)
    theta = np.array([-1.5, 0.7, 1.0, 0.5])
    reference = np.where(np.arange(steps + 1) % 100 < 50, 1.0, -1.0)
    rollout(ctl, theta, 10, reference=reference[:11])  # compile (or load from the cache)
    best = np.inf
    for _ in range(repeats):
        ctl.reset()
        t0 = time.perf_counter()
        rollout(ctl, theta, steps, reference=reference)
        best = min(best, time.perf_counter() - t0)
    return best / steps * 1e6


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--calls", type=int, default=2000)
    ap.add_argument("--repeats", type=int, default=10)
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    print(f"{'controller':20s} {'predict us':>11s} {'rollout us/step':>16s} {'bare us':>8s} "
          f"{'predict / bare':>15s}")  # fmt: skip
    for name, kw in CONTROLLERS.items():
        p, b = predict_us(kw, args.calls, args.repeats)
        r = rollout_us(kw, args.calls, args.repeats)
        print(f"{name:20s} {p:11.2f} {r:16.2f} {b:8.3f} {p / b:15.1f}", flush=True)


if __name__ == "__main__":
    main()
