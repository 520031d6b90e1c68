"""Start-up benchmark of the self-tuning controller (issue: close the loop from the first samples).

Usage::

    python benchmarks/startup.py [--seeds 20] [--plants 1000] [--steps 1000] [--out FILE.json]

Setting: ``stcgym/ObserverCanonical-v0``, square-wave reference of period 100, output noise std
0.05, ``action_bound`` 10, ``control_cost`` 0.01. Cost of step ``k`` is the env's ``-reward``;
episode cost is the sum over the episode, start included; a diverged episode (``|y| > 100``)
counts as unbounded. Every episode and every lane gets its own controller seed.

Sections
--------
Costs come from the compiled rollout (:func:`stcgym.adaptive.rollout.rollout`, the env's own
plant step) for the controller and from the oracles stepped on the same plant and noise.

* **catalogue**: per plant, the ratio of the seed-averaged episode cost of
  ``SelfTuningController(n)`` (defaults) to :class:`KnownModelController` (same poles), the start
  window (steps 0-100) ratio, the steps to settle (first ``k`` from which the 100-step window
  cost is within 1.2x the oracle's), and the same ratio for every estimator name and for
  ``design="lq"`` against :class:`LQGController`; for ``timevarying2`` the post-jump window
  (1000-1500 of a 1500-step episode) against the oracle that switches to the new parameters.
* **random family**: ``--plants`` second-order plants, poles up to magnitude 1.15 (real or
  complex), ``|b_i|`` in ``[0.1, 4]``, no zero within 0.1 of a pole; bounded fraction among the
  plants the oracle holds, median and 90th percentile of the episode ratio, the plants lost
  (poles, zeros, DC gain), false alarms of the change detector (alarms on these
  time-invariant plants).

Targets (issue 11): catalogue every ratio <= 1.5, geometric mean <= 1.3; random family bounded
on >= 99.5 % of the plants the oracle holds, median <= 1.15, p90 <= 1.5; LQ <= 1.3x LQG.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import warnings
from typing import Any

import gymnasium as gym
import numpy as np

import stcgym.envs  # noqa: F401  (registers the envs)
from stcgym.adaptive import ALGORITHMS, KnownModelController, LQGController, SelfTuningController
from stcgym.adaptive.rollout import rollout
from stcgym.envs import PLANTS
from stcgym.envs.canonical import companion_A

NOISE = 0.05
BOUND = 10.0
CATALOGUE = ("stable2", "lightly_damped2", "unstable2", "nonminphase2", "integrator2", "stable4")


NDArray = np.ndarray
SQUARE = np.array([1.0 if (k % 100) < 50 else -1.0 for k in range(100_001)])


def oracle_costs(
    oracles: list[Any],
    thetas: NDArray,
    z: NDArray,
    steps: int,
    jump: tuple[int, NDArray] | None = None,
) -> NDArray:
    """Per-step costs ``(B, steps)`` of one known-model oracle per lane on the env's plant step
    (numpy), output noise ``NOISE * z``; ``inf`` from a divergence on. With ``jump`` the plant
    and the oracles switch to the new parameters at that step."""
    B, n = thetas.shape[0], thetas.shape[1] // 2
    A = np.array([companion_A(th[:n]) for th in thetas])
    b = thetas[:, n:].copy()
    for o in oracles:
        o.reset()
    x = np.zeros((B, n))
    cost = np.zeros((B, steps))
    alive = np.ones(B, dtype=bool)
    for k in range(steps):
        if jump is not None and k == jump[0]:
            th2 = np.broadcast_to(jump[1], thetas.shape)
            A = np.array([companion_A(th[:n]) for th in th2])
            b = th2[:, n:].copy()
            for o, th in zip(oracles, th2, strict=True):
                o.set_model(th[:n], th[n:])
        y = x[:, 0] + NOISE * z[:, k]
        u = np.array([o.predict(np.array([yi, SQUARE[k]]))[0][0] if ok else 0.0
                      for o, yi, ok in zip(oracles, y, alive, strict=True)])  # fmt: skip
        u = np.clip(u, -BOUND, BOUND)
        x = np.einsum("bij,bj->bi", A, x) + b * u[:, None]
        x[~alive] = 0.0
        alive &= np.abs(x[:, 0] + NOISE * z[:, k + 1]) <= 100.0
        c = (x[:, 0] - SQUARE[k + 1]) ** 2 + 0.01 * u**2
        cost[:, k] = np.where(alive, c, np.inf)
    return cost


def stc_costs(thetas: NDArray, z: NDArray, steps: int, seed0: int, jump=None, **kw: Any) -> tuple:
    """Per-step costs of ``SelfTuningController`` (compiled rollout, one lane per plant)."""
    B, n = thetas.shape[0], thetas.shape[1] // 2
    ctl = SelfTuningController(n, num_envs=B, seed=seed0 + np.arange(B), action_bound=BOUND, **kw)
    res = rollout(
        ctl, thetas, steps, reference=SQUARE[: steps + 1], noise_std=NOISE, z=z, window=1,
        jump=jump,
    )  # fmt: skip
    cost = res.cost.copy()
    for i in np.flatnonzero(res.diverged):
        cost[i, res.steps_run[i] - 1 :] = np.inf
    return cost, ctl


def settle_step(c: NDArray, o: NDArray, window: int = 100, tol: float = 1.2) -> int:
    """First ``k`` (step 10) from which every ``window``-step cost is within ``tol`` x oracle."""
    ks = list(range(0, len(c) - window + 1, 10))
    ok = [c[k : k + window].sum() <= tol * o[k : k + window].sum() for k in ks]
    for i in range(len(ks)):
        if all(ok[i:]):
            return ks[i]
    return len(c)


def _ratio(c: NDArray, o: NDArray) -> float:
    """Ratio of seed-averaged episode costs (``inf`` when a lane the oracle holds diverged)."""
    held = np.isfinite(o).all(1)
    return float(c[held].sum(1).mean() / o[held].sum(1).mean())


def catalogue(seeds: int, steps: int) -> dict[str, Any]:
    rows: dict[str, Any] = {}
    for j, plant in enumerate(CATALOGUE):
        spec = PLANTS[plant]
        th = np.tile(spec.theta, (seeds, 1))
        z = np.random.default_rng(100 + j).standard_normal((seeds, steps + 1))
        orc = oracle_costs(
            [KnownModelController(spec.a, spec.b) for _ in range(seeds)], th, z, steps
        )
        lqg = oracle_costs(
            [LQGController(spec.a, spec.b, noise_std=NOISE) for _ in range(seeds)], th, z, steps
        )
        row: dict[str, Any] = {}
        for name, kw, ref in (
            ("default", {}, orc),
            ("lq", {"design": "lq"}, lqg),
            *[(est, {"estimator": est}, orc) for est in ALGORITHMS],
        ):
            c, _ = stc_costs(th, z, steps, 1000 * j, **kw)
            entry = {"ratio": _ratio(c, ref), "bounded": float(np.isfinite(c).all(1).mean())}
            if name in ("default", "lq"):
                entry["start_ratio"] = float(c[:, :100].sum(1).mean() / ref[:, :100].sum(1).mean())
                entry["steady_ratio"] = _ratio(c[:, 100:], ref[:, 100:])
                entry["settle"] = settle_step(c.mean(0), ref.mean(0))
            row[name] = entry
        rows[plant] = row
        d = row["default"]
        print(
            f"{plant:16s} ratio {d['ratio']:6.2f} start(0-100) {d['start_ratio']:6.2f} "
            f"after(100-) {d['steady_ratio']:5.2f} settle {d['settle']:4d}  "
            f"lq/LQG {row['lq']['ratio']:5.2f} (start {row['lq']['start_ratio']:.2f}, "
            f"after {row['lq']['steady_ratio']:.2f})",
            flush=True,
        )
        print(
            "    paper estimators (ratio, bounded): "
            + ", ".join(f"{e} {row[e]['ratio']:.3g}/{row[e]['bounded']:.2f}" for e in ALGORITHMS),
            flush=True,
        )
    r = [rows[p]["default"]["ratio"] for p in CATALOGUE]
    rows["geometric_mean"] = float(np.exp(np.mean(np.log(r))))
    rows["max"] = float(np.max(r))
    print(f"catalogue: max {rows['max']:.3f}  geometric mean {rows['geometric_mean']:.3f}")
    return rows


def jump(seeds: int) -> dict[str, float]:
    """``timevarying2`` (jump at 1000): window 1000-1500 against the oracle that knows it."""
    spec = PLANTS["timevarying2"]
    th = np.tile(spec.theta, (seeds, 1))
    env = gym.make("stcgym/ObserverCanonical-v0", plant="timevarying2", max_episode_steps=1002)
    env.reset(seed=0)
    for _ in range(1001):
        *_, info = env.step(np.zeros(1))
    after = np.asarray(info["theta"], dtype=float)
    z = np.random.default_rng(7).standard_normal((seeds, 1501))
    c, ctl = stc_costs(th, z, 1500, 0, jump=(1000, after))
    o = oracle_costs(
        [KnownModelController(spec.a, spec.b) for _ in range(seeds)], th, z, 1500, (1000, after)
    )
    w = slice(1000, 1500)
    out = {
        "post_jump_ratio": float(c[:, w].sum(1).mean() / o[:, w].sum(1).mean()),
        "alarms_per_lane": float(np.mean(ctl.diagnostics["n_alarms"])),
    }
    print(
        f"timevarying2 post-jump ratio {out['post_jump_ratio']:.3f} "
        f"(alarms per lane {out['alarms_per_lane']:.2f})"
    )
    return out


def random_plants(count: int, rng: np.random.Generator) -> list[tuple[NDArray, NDArray]]:
    plants = []
    while len(plants) < count:
        if rng.random() < 0.5:
            poles = rng.uniform(-1.15, 1.15, 2)
        else:
            rad, ang = rng.uniform(0.0, 1.15), rng.uniform(0.0, np.pi)
            poles = np.array([rad * np.exp(1j * ang), rad * np.exp(-1j * ang)])
        a = np.real(np.poly(poles))[1:]
        b = rng.uniform(0.1, 4.0, 2) * rng.choice([-1.0, 1.0], 2)
        zero = -b[1] / b[0]
        if np.min(np.abs(poles - zero)) < 0.1:
            continue
        plants.append((a, b))
    return plants


def family(count: int, steps: int, seed: int = 0) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    plants = random_plants(count, rng)
    th = np.array([np.r_[a, b] for a, b in plants])
    z = rng.standard_normal((count, steps + 1))
    c_stc, ctl = stc_costs(th, z, steps, 10_000)
    c_orc = oracle_costs([KnownModelController(a, b) for a, b in plants], th, z, steps)
    held = np.isfinite(c_orc).all(1)
    ok = np.isfinite(c_stc).all(1)
    ratio = c_stc.sum(1)[held & ok] / c_orc.sum(1)[held & ok]
    after = c_stc[:, 100:].sum(1)[held & ok] / c_orc[:, 100:].sum(1)[held & ok]
    lost_rows = []
    for i in np.flatnonzero(held & ~ok):
        a, b = plants[i]
        den = 1.0 + a.sum()
        lost_rows.append(
            {
                "poles": np.roots(np.r_[1.0, a]).round(3).astype(str).tolist(),
                "zero": round(float(-b[1] / b[0]), 3),
                "dc_gain": float(b.sum() / den) if abs(den) > 1e-12 else float("inf"),
            }
        )
    out = {
        "plants": count,
        "oracle_held": int(held.sum()),
        "bounded_fraction_of_held": float((held & ok).sum() / max(held.sum(), 1)),
        "median_ratio": float(np.median(ratio)),
        "p90_ratio": float(np.percentile(ratio, 90)),
        "p90_ratio_after_100": float(np.percentile(after, 90)),
        "lanes_with_alarm": int((ctl.diagnostics["n_alarms"] > 0).sum()),
        "diverged_after_alarm": int(((ctl.diagnostics["n_alarms"] > 0) & held & ~ok).sum()),
        "lost": lost_rows,
    }
    print(
        f"random family: {count} plants, oracle holds {out['oracle_held']}, stc bounded on "
        f"{100 * out['bounded_fraction_of_held']:.2f} % of those, median ratio "
        f"{out['median_ratio']:.3f}, p90 {out['p90_ratio']:.3f} (steps 100- alone: p90 "
        f"{out['p90_ratio_after_100']:.3f}); false alarms on "
        f"{out['lanes_with_alarm']} lanes ({out['diverged_after_alarm']} of them lost); "
        f"lost {len(lost_rows)}"
    )
    for row in lost_rows:
        print("  lost:", row)
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--plants", type=int, default=1000)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--skip-catalogue", action="store_true")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore", RuntimeWarning)
    result: dict[str, Any] = {}
    if args.plants:
        result["family"] = family(args.plants, args.steps)
    if not args.skip_catalogue:
        result["jump"] = jump(args.seeds)
        result["catalogue"] = catalogue(args.seeds, args.steps)
    if args.out:
        d = os.path.dirname(os.path.abspath(args.out))
        with tempfile.NamedTemporaryFile("w", dir=d, delete=False, suffix=".tmp") as fh:
            json.dump(result, fh, indent=1)
        os.replace(fh.name, args.out)


if __name__ == "__main__":
    main()
