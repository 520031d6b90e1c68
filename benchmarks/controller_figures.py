"""Figures of the self-tuning regulator against the known-model oracles.

Usage::

    python benchmarks/controller_figures.py [--seeds 20] [--steps 2000] [--jobs 2]

Setting: catalogue plants in ``stcgym/ObserverCanonical-v0``, unit square-wave
reference of period 100, output noise std 0.05, ``action_bound`` 10, ``control_cost`` 0.01,
2000 steps, seeds ``0 .. seeds-1`` (env seed = controller probe seed). Cost of step ``k`` is the
env's ``-reward = (y_clean(k+1) - r(k+1))^2 + rho u(k)^2``.

Columns (ratios are of the seed-averaged window costs; ``max`` is the worst single seed):

* ``bounded``: episodes that never left ``|y| <= 100`` (the env's divergence bound);
* ``steady``: cost over steps 1000-2000, regulator / :class:`KnownModelController` (same poles,
  same law, Kalman filter on the true model);
* ``start``: cost over steps 0-200 (the start-up: a seeded probe for ``2n`` steps, then the
  loop is closed; see ``benchmarks/startup.py`` for the full start-up figures);
* ``LQ/LQG``: ``design="lq"`` against :class:`LQGController`, steady window and start;
* ``O-RLS steady``: the same steady ratio with ``estimator="O-RLS"``;
* ``oracle``: the oracle's steady cost; ``LQG/PP``: LQG oracle cost / pole-placement oracle cost
  (constant plants only);
* for ``timevarying2`` the ``post-jump`` ratio is over steps 1300-1600 against the oracle that
  switches to the new parameters at the jump (step 1000).

Then the cost of one controller step (``predict`` on one observation, median over steps
500-3000 of a closed loop with a plain numpy plant) for O-RLS and KF-MILS at n = 2 and 4.
"""

from __future__ import annotations

import argparse
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import gymnasium as gym
import numpy as np

import stcgym.envs  # noqa: F401  (registers the envs)
from stcgym.adaptive.control.controller import SelfTuningController
from stcgym.adaptive.control.options import LawOptions
from stcgym.adaptive.control.oracles import KnownModelController, LQGController
from stcgym.agents.closed_loop import run_closed_loop
from stcgym.envs import PLANTS
from stcgym.envs.canonical import canonical_matrices

PLANT_ORDER = (
    "stable2",
    "lightly_damped2",
    "stable4",
    "unstable2",
    "nonminphase2",
    "integrator2",
    "timevarying2",
)
NOISE_STD = 0.05
ACTION_BOUND = 10.0
#: LQG without integral action, the optimal linear controller for the envs' cost on the known
#: model (the README's ``design="lq"`` / LQG column is measured against it)
LQG_LAW = LawOptions(integral=False)


def run_episode(policy: Any, plant: str, seed: int, steps: int, oracle: bool = False) -> dict:
    """One closed-loop episode (the closed-loop driver); per-step costs, diverged runs charged
    by its rule, and whether it stayed bounded."""
    env = gym.make(
        "stcgym/ObserverCanonical-v0",
        plant=plant,
        noise_std=NOISE_STD,
        action_bound=ACTION_BOUND,
        max_episode_steps=steps,
    )
    obs, info = env.reset(seed=seed)
    latest = [info]

    def tell_oracle(k: int) -> None:
        info = latest[0]
        if not np.allclose(info["theta"], np.r_[policy.a, policy.b]):
            policy.set_model(info["a"], info["b"])  # the oracle knows the new parameters

    def keep_info(k: int, action: Any, obs: Any, info: dict) -> None:
        latest[0] = info

    loop = run_closed_loop(
        policy, env, obs, steps, before_step=tell_oracle if oracle else None, on_step=keep_info
    )
    return {"bounded": not loop.diverged[0], "cost": loop.cost[0]}


def _one_seed(plant: str, seed: int, steps: int) -> dict[str, Any]:
    spec = PLANTS[plant]
    out: dict[str, Any] = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for key, kw in (
            ("stc", {}),
            ("lq", {"design": "lq"}),
            ("orls", {"estimator": "O-RLS"}),
        ):
            ctl = SelfTuningController(spec.n, seed=seed, action_bound=ACTION_BOUND, **kw)
            out[key] = run_episode(ctl, plant, seed, steps)
    out["oracle"] = run_episode(
        KnownModelController(spec.a, spec.b, action_bound=ACTION_BOUND), plant, seed, steps, True
    )
    out["lqg"] = run_episode(
        LQGController(spec.a, spec.b, law=LQG_LAW, action_bound=ACTION_BOUND, noise_std=NOISE_STD),
        plant,
        seed,
        steps,
    )
    return out


def _window_ratio(
    runs: list[dict], key: str, window: slice, ref: str = "oracle"
) -> tuple[float, float]:
    """Ratio of seed-averaged window costs (bounded runs only) and the worst per-seed ratio."""
    ok = [r for r in runs if r[key]["bounded"] and r[ref]["bounded"]]
    if not ok:
        return float("nan"), float("nan")
    num = np.array([r[key]["cost"][window].mean() for r in ok])
    den = np.array([r[ref]["cost"][window].mean() for r in ok])
    return float(num.mean() / den.mean()), float(np.max(num / den))


def plant_figures(plant: str, seeds: int, steps: int, jobs: int) -> dict[str, Any]:
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        runs = list(pool.map(_one_seed, [plant] * seeds, range(seeds), [steps] * seeds))
    steady = slice(steps // 2, steps)
    start = slice(0, min(200, steps))
    row: dict[str, Any] = {"plant": plant}
    row["bounded"] = 100.0 * np.mean([r["stc"]["bounded"] for r in runs])
    row["bounded_lq"] = 100.0 * np.mean([r["lq"]["bounded"] for r in runs])
    row["bounded_orls"] = 100.0 * np.mean([r["orls"]["bounded"] for r in runs])
    row["steady"] = _window_ratio(runs, "stc", steady)
    row["start"] = _window_ratio(runs, "stc", start)
    row["start_lq"] = _window_ratio(runs, "lq", start, "lqg")
    row["steady_lq"] = _window_ratio(runs, "lq", steady, "lqg")
    row["orls"] = _window_ratio(runs, "orls", steady)
    row["oracle"] = float(np.mean([r["oracle"]["cost"][steady].mean() for r in runs]))
    lqg = [r["lqg"]["cost"][steady].mean() for r in runs if r["lqg"]["bounded"]]
    # The LQG oracle is built once on the initial parameters: meaningless after a jump.
    constant = PLANTS[plant].schedule is None
    row["lqg_pp"] = float(np.mean(lqg) / row["oracle"]) if lqg and constant else float("nan")
    if plant == "timevarying2":
        row["post_jump"] = _window_ratio(runs, "stc", slice(1300, 1600))
    return row


def step_cost_us(estimator: str, plant: str, steps: int = 3000) -> float:
    """Median wall time of one ``predict`` call in a closed loop (numpy plant, no env)."""
    spec = PLANTS[plant]
    A, B, _, _ = canonical_matrices(spec.a, spec.b)
    ctl = SelfTuningController(spec.n, estimator=estimator)
    rng = np.random.default_rng(0)
    x = np.zeros(spec.n)
    times = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for k in range(steps):
            obs = np.array([x[0] + NOISE_STD * rng.standard_normal(), 1.0 if k % 100 < 50 else -1])
            t0 = time.perf_counter()
            action, _ = ctl.predict(obs)
            times.append(time.perf_counter() - t0)
            x = A @ x + B[:, 0] * action[0]
    return float(np.median(times[500:]) * 1e6)


def _fmt(pair: tuple[float, float]) -> str:
    return f"{pair[0]:.3f} ({pair[1]:.2f})"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--plants", default=",".join(PLANT_ORDER))
    args = parser.parse_args(argv)

    print(
        f"Self-tuning regulator (defaults: ELS, pole placement) vs known-model pole placement; "
        f"{args.seeds} seeds x {args.steps} steps, noise std {NOISE_STD}, square wave period 100."
    )
    print("Ratios: seed-averaged cost / oracle cost (worst seed in brackets).\n")
    head = (
        "| plant | bounded % (LQ, O-RLS) | steady 1000-2000 | start 0-200 | "
        "LQ/LQG start 0-200 | LQ/LQG steady | O-RLS steady | oracle cost | LQG/PP | post-jump |"
    )
    print(head)
    print("|---" * (head.count("|") - 1) + "|")
    for plant in args.plants.split(","):
        row = plant_figures(plant, args.seeds, args.steps, args.jobs)
        post = _fmt(row["post_jump"]) if "post_jump" in row else ""
        print(
            f"| {plant} | {row['bounded']:.0f} ({row['bounded_lq']:.0f}, "
            f"{row['bounded_orls']:.0f}) | {_fmt(row['steady'])} | {_fmt(row['start'])} | "
            f"{_fmt(row['start_lq'])} | {_fmt(row['steady_lq'])} | {_fmt(row['orls'])} | "
            f"{row['oracle']:.3f} | {row['lqg_pp']:.2f} | {post} |",
            flush=True,
        )
    print("\nCost of one controller step (predict on one observation, median):\n")
    print("| estimator | n = 2 (stable2) | n = 4 (stable4) |")
    print("|---|---|---|")
    for est in ("ELS", "O-RLS", "KF-MILS"):
        print(
            f"| {est} | {step_cost_us(est, 'stable2'):.0f} us | "
            f"{step_cost_us(est, 'stable4'):.0f} us |"
        )


if __name__ == "__main__":
    main()
