"""Multivariable self-tuning LQ against the known-model LQR: catalogue and random family.

Usage::

    python benchmarks/mimo.py [--family 300] [--seeds 10] [--steps 1000] [--noise 0.02]
                              [--out FILE.json]

Setting: ``stcgym/StateSpace-v0`` with measured state (``C = I``), square-wave reference of
period 100 and amplitude 1 on every state, measurement noise std ``--noise``, ``action_bound``
10, ``control_cost`` 0.01 (LQ weights ``Q = I``, ``R = 0.01 I``, the env's cost, for both
controllers). Cost of step ``k`` is the env's ``-reward``; a diverged lane (``|x_i| > 100``) is
flagged and charged its last per-step cost for every step it did not live (the divergence rule
of :func:`stcgym.adaptive.control.rollout.charge_divergence`, through
:func:`stcgym.agents.closed_loop.run_closed_loop`). The controller and the oracle
(:class:`~stcgym.adaptive.LQRController` on the true ``(A, B)``) run on the same plants, noise
and references (the same reset seed); every lane gets its own probe seed.

Plants: every MIMO catalogue plant (``--seeds`` episodes each), and ``--family`` random plants
with 2, 3 or 4 states and 2 inputs, drawn from ``SeedSequence([0, i])``: ``A`` a Gaussian
matrix scaled to spectral radius in ``[0.3, 0.98]`` (a quarter of them in ``[1.02, 1.15]``:
open-loop unstable), ``B`` Gaussian, kept when ``(A, B)`` is controllable.

Figures: bounded fraction of the lanes the oracle holds; episode cost over the oracle's (median,
90th percentile); the steady window (the second half of the episode) over the oracle's
(median, p90); the samples until within 1.2x (the first step from which every later 50-step
window costs at most 1.2x the oracle's; median, p90); start-up: the first 100 steps over the
oracle's (median) and the extra cost they add (median, in units of the oracle's cost per
step). Targets: bounded >= 99 %, median episode ratio <= 1.3, median steady ratio <= 1.05.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
import warnings
from typing import Any

import control
import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

import stcgym.envs  # noqa: F401  (registers the envs)
from stcgym.adaptive import LQRController, MultivariableSelfTuningController
from stcgym.agents.closed_loop import run_closed_loop
from stcgym.envs import MIMO_PLANTS

WINDOW = 50
START = 100
UNSTABLE_SHARE = 0.25
INPUTS = 2


def random_plant(i: int) -> tuple[NDArray, NDArray]:
    """Plant ``i`` of the family (module docstring)."""
    rng = np.random.default_rng(np.random.SeedSequence([0, i]))
    n = int(rng.integers(2, 5))
    unstable = rng.random() < UNSTABLE_SHARE
    while True:
        A = rng.standard_normal((n, n))
        radius = rng.uniform(1.02, 1.15) if unstable else rng.uniform(0.3, 0.98)
        A *= radius / np.max(np.abs(np.linalg.eigvals(A)))
        B = rng.standard_normal((n, INPUTS))
        if np.linalg.matrix_rank(control.ctrb(A, B)) == n:
            return A, B


def run_group(
    As: NDArray, Bs: NDArray, steps: int, noise: float, seed: int, probe_seed: int
) -> dict[str, NDArray]:
    """Controller and oracle on lanes with matrices ``As``, ``Bs`` (one vector env)."""
    lanes, n, _ = As.shape
    venv = gym.make_vec(
        "stcgym/StateSpace-v0", num_envs=lanes, A=As[0], B=Bs[0], noise_std=noise,
        max_episode_steps=steps + 1,
    )  # fmt: skip
    options = {"A": As, "B": Bs}
    out: dict[str, Any] = {}
    for name, policy in (
        ("stc", MultivariableSelfTuningController(env=venv, seed=probe_seed)),
        ("oracle", LQRController(As, Bs, env=venv)),
    ):
        obs, _ = venv.reset(seed=seed, options=options)
        t0 = time.perf_counter()
        with warnings.catch_warnings():  # a diverged lane's autoreset is never scored
            warnings.filterwarnings("ignore", message="autoreset: lanes whose parameters")
            res = run_closed_loop(policy, venv, obs, steps)
        out[name] = res
        out[name + "_s"] = time.perf_counter() - t0
    venv.close()
    return out


def lane_figures(stc: NDArray, oracle: NDArray) -> dict[str, NDArray]:
    """Per-lane ratios of the costs ``(B, T)`` (module docstring)."""
    T = stc.shape[1]
    half = T // 2
    ratio = stc.sum(axis=1) / oracle.sum(axis=1)
    steady = stc[:, half:].sum(axis=1) / oracle[:, half:].sum(axis=1)
    start = stc[:, :START].sum(axis=1) / oracle[:, :START].sum(axis=1)
    per_step = oracle.sum(axis=1) / T
    extra = (stc[:, :START].sum(axis=1) - oracle[:, :START].sum(axis=1)) / per_step
    w = T // WINDOW
    ws = stc[:, : w * WINDOW].reshape(len(stc), w, WINDOW).sum(axis=2)
    wo = oracle[:, : w * WINDOW].reshape(len(stc), w, WINDOW).sum(axis=2)
    bad = ws > 1.2 * wo
    settle = np.full(len(stc), np.inf)
    for i in range(len(stc)):
        idx = np.flatnonzero(bad[i])
        last_bad = -1 if idx.size == 0 else idx[-1]
        if last_bad < w - 1:
            settle[i] = (last_bad + 1) * WINDOW
    return {"ratio": ratio, "steady": steady, "start": start, "extra": extra, "settle": settle}


def summary(fig: dict[str, NDArray], bounded: NDArray, held: NDArray) -> dict[str, Any]:
    keep = held & bounded
    pct = lambda v, q: float(np.percentile(v[keep], q)) if keep.any() else float("nan")  # noqa: E731
    return {
        "held_by_oracle": int(held.sum()),
        "bounded_pct": 100.0 * float(bounded[held].mean()) if held.any() else float("nan"),
        "lost": int((held & ~bounded).sum()),
        "median": pct(fig["ratio"], 50),
        "p90": pct(fig["ratio"], 90),
        "steady_median": pct(fig["steady"], 50),
        "steady_p90": pct(fig["steady"], 90),
        "settle_median": pct(fig["settle"], 50),
        "settle_p90": pct(fig["settle"], 90),
        "never_within_1.2x": int(np.isinf(fig["settle"][keep]).sum()),
        "start_median": pct(fig["start"], 50),
        "start_extra_median": pct(fig["extra"], 50),
    }


def evaluate(As: NDArray, Bs: NDArray, args: argparse.Namespace, seed: int) -> dict[str, Any]:
    res = run_group(As, Bs, args.steps, args.noise, seed, probe_seed=1000 * seed)
    stc, oracle = res["stc"], res["oracle"]
    fig = lane_figures(stc.cost, oracle.cost)
    return {"fig": fig, "bounded": ~stc.diverged, "held": ~oracle.diverged, "wall": res}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--family", type=int, default=300)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--noise", type=float, default=0.02)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    t_start = time.perf_counter()
    report: dict[str, Any] = {"args": vars(args), "catalogue": {}, "family": {}}
    print(f"python benchmarks/mimo.py --family {args.family} --seeds {args.seeds} "
          f"--steps {args.steps} --noise {args.noise}")  # fmt: skip
    hdr = (f"{'plant':<16}{'bounded %':>10}{'median':>8}{'p90':>8}{'steady':>8}"
           f"{'settle':>8}{'start':>8}{'extra':>8}")  # fmt: skip
    print(hdr)

    def row(name: str, s: dict[str, Any]) -> None:
        print(f"{name:<16}{s['bounded_pct']:>10.1f}{s['median']:>8.3f}{s['p90']:>8.3f}"
              f"{s['steady_median']:>8.3f}{s['settle_median']:>8.0f}{s['start_median']:>8.2f}"
              f"{s['start_extra_median']:>8.1f}")  # fmt: skip

    for name, spec in MIMO_PLANTS.items():
        A, B = spec.discrete()
        As = np.repeat(A[None], args.seeds, axis=0)
        Bs = np.repeat(B[None], args.seeds, axis=0)
        ev = evaluate(As, Bs, args, seed=1)
        s = summary(ev["fig"], ev["bounded"], ev["held"])
        report["catalogue"][name] = s
        row(name, s)
    plants = [random_plant(i) for i in range(args.family)]
    figs: list[dict[str, NDArray]] = []
    bounded, held, unstable = [], [], []
    for n in (2, 3, 4):
        idx = [i for i, (A, _) in enumerate(plants) if A.shape[0] == n]
        if not idx:
            continue
        As = np.stack([plants[i][0] for i in idx])
        Bs = np.stack([plants[i][1] for i in idx])
        ev = evaluate(As, Bs, args, seed=2)
        figs.append(ev["fig"])
        bounded.append(ev["bounded"])
        held.append(ev["held"])
        unstable.append(np.max(np.abs(np.linalg.eigvals(As)), axis=1) > 1.0)
    fig = {k: np.concatenate([f[k] for f in figs]) for k in figs[0]}
    b, h, u = np.concatenate(bounded), np.concatenate(held), np.concatenate(unstable)
    s = summary(fig, b, h)
    s["open_loop_unstable"] = int(u.sum())
    s["lost_unstable"] = int((h & ~b & u).sum())
    report["family"] = s
    row(f"family ({len(b)})", s)
    print(f"family: {s['held_by_oracle']} held by the oracle ({s['open_loop_unstable']} "
          f"open-loop unstable); lost {s['lost']} ({s['lost_unstable']} unstable); p90 "
          f"{s['p90']:.3f}, steady p90 {s['steady_p90']:.3f}, settle p90 {s['settle_p90']:.0f}, "
          f"never within 1.2x {s['never_within_1.2x']}")  # fmt: skip
    report["wall_s"] = time.perf_counter() - t_start
    print(f"wall time {report['wall_s']:.1f} s")
    print(
        "columns: episode cost / oracle (median, p90), steady = second half / oracle "
        "(median), settle = samples until every later 50-step window <= 1.2x the oracle's "
        "(median), start = steps 0-100 / oracle (median), extra = cost those steps add, in "
        "oracle steps (median)"
    )
    if args.out:
        directory = os.path.dirname(os.path.abspath(args.out))
        with tempfile.NamedTemporaryFile("w", dir=directory, delete=False) as fh:
            json.dump(report, fh, indent=1, default=float)
        os.replace(fh.name, args.out)
    return report


if __name__ == "__main__":
    main()
