"""Which estimate the estimate-conditioned agent should see: standalone O-RLS or the
self-tuning controller's extended least squares (ELS), on the bench's family test episodes.

Both estimators run side by side on the same episodes and the same applied inputs, as an agent
would feed them:

* ``O-RLS`` exactly as :class:`~stcgym.agents.rl.estimate_interfaces.EstimateInterface` runs it
  (:func:`~stcgym.agents.rl.estimate_interfaces.closed_loop_estimator`: ``update(y(t))``, then
  ``predict(u(t))`` with the input applied);
* ``ELS`` as a :class:`~stcgym.adaptive.SelfTuningController` with its defaults reports it when
  it is told the applied input: ``propose([y(t), r(t)])`` (its measurement step, change
  detection, design and filter), then ``commit(u(t))``; its seeds are the bench's ``stc``
  seeds of run 0.

Both estimates are read after the measurement update with ``y(t)``, the moment the agent's
features hold them. The inputs (``--drivers``) come from

``stc``
    the self-tuning controller itself (the ELS controller's own inputs: what the bench's
    ``stc`` row applies, and a residual agent's inputs with a zero correction);
``lqg``
    LQG on the true model (the inputs of an agent that controls well);
``noise``
    zero mean plus white Gaussian noise of one action unit ``s`` (``--action-unit``): an
    untrained Gaussian policy with Stable-Baselines3's default ``log_std_init = 0``;
``noise_small``
    the same with ``0.1 s``: a poorly-controlling agent that explores little;
``theta_ppo``
    a trained estimate-conditioned agent (``--agent``, a folder of ``stcgym.agents.
    save_agent``); its own O-RLS estimator is checked against the one run here, bit for bit.

Episodes: the bench's ``family:test`` scenario of the standard tier (the family's test split,
one episode per plant from seed 1000, its length, noise, reference and initial state) under the
action bound the bench measured on the family (``--action-bound``). A lane that leaves
``y_bound`` ends there (as the bench scores it); the figures at time ``t`` are over the lanes
still running at ``t``, both estimators on the same lanes.

Figures per driver: the relative parameter error ``||theta_hat(t) - theta|| / ||theta||``
(median and interquartile mean over the lanes, and the share of lanes where ELS is the closer)
at a few times, the mean squared innovation (the one-step prediction error of each estimator's
own predictor) over windows of the episode as a multiple of the noise variance (1 is the
floor), and the end-of-episode error per stratum of the plants (the bench's strata: the last
ladder feature a plant has). Last, what one step of an agent's features costs for ``B``
lanes (:class:`~stcgym.agents.rl.interfaces.InterfaceSpec` ``observe``, ``features`` and
``to_input``): the window alone, with O-RLS's estimate and with ELS's (``estimator="ELS"``),
best of interleaved repeats.

Usage::

    nice python benchmarks/estimate_choice.py \\
        --agent results/standard-v1/models/family_theta_ppo_s0 \\
        --out benchmarks/estimate_choice.json

``--drivers`` with no names measures the step costs only (``--timing-lanes``,
``--timing-repeats``); without ``--agent`` the ``theta_ppo`` driver is skipped.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stcgym.adaptive import SelfTuningController
from stcgym.agents.benchmark import build_config, make_scenarios
from stcgym.agents.benchmark.headline import STRATA, plant_strata
from stcgym.agents.controllers import CONTROLLERS, controller_seeds
from stcgym.agents.rl.estimate_interfaces import closed_loop_estimator

ESTIMATES = ("O-RLS", "ELS")
DRIVERS = ("stc", "lqg", "noise", "noise_small", "theta_ppo")
TIMES = (10, 25, 50, 100, 200, 500)
WINDOWS = ((0, 50), (50, 200), (200, None))


def family_test(action_bound: float, plants: int | None) -> tuple[Any, Any, Any]:
    """The bench's ``family:test`` scenario (standard tier) under ``action_bound``, its first
    ``plants`` episodes."""
    from dataclasses import replace

    cfg = build_config(run="estimate-choice", mode="standard", scenarios="family", agents="stc")
    sc = next(s for s in make_scenarios(cfg) if s.name == "family:test")
    env = replace(sc.env, action_bound=float(action_bound))
    sc = replace(sc, env=env)
    eps = sc.episodes
    n = len(eps.seeds) if plants is None else int(plants)
    return cfg, sc, (list(eps.plants[:n]), list(eps.seeds[:n]))


class NoiseInput:
    """Zero input plus white Gaussian noise of standard deviation ``sigma`` on every lane."""

    def __init__(self, sigma: float, lanes: int, seed: int = 0) -> None:
        self.sigma, self.lanes = float(sigma), int(lanes)
        self.rng = np.random.default_rng(seed)

    def predict(self, obs: NDArray, **_: Any) -> tuple[NDArray, None]:
        return self.sigma * self.rng.standard_normal((self.lanes, 1)), None


def driver_policy(name: str, cfg: Any, sc: Any, plants: list, seeds: list, args: Any) -> Any:
    """The policy whose inputs the run applies (``None``: the ELS controller's own)."""
    B = len(seeds)
    if name == "stc":
        return None
    if name == "lqg":
        return CONTROLLERS["lqg"].build(cfg, sc)(plants, seeds)
    if name == "noise":
        return NoiseInput(args.action_unit, B)
    if name == "noise_small":
        return NoiseInput(0.1 * args.action_unit, B)
    if name == "theta_ppo":
        import torch

        from stcgym.agents import load_agent

        torch.set_num_threads(1)  # small batches: threads only contend on a shared machine
        agent = load_agent(args.agent)
        if agent.policy.interface.kind != "estimate":
            raise ValueError(f"{args.agent} is not an estimate-conditioned agent")
        if agent.policy.interface.estimator != "O-RLS":
            raise ValueError(f"{args.agent} observes {agent.policy.interface.estimator}")
        return agent.policy.with_lanes(B, seeds=seeds)
    raise ValueError(f"driver must be one of {DRIVERS}, got {name!r}")


def run_driver(name: str, cfg: Any, sc: Any, lanes: tuple[list, list], args: Any) -> dict:
    """Both estimates at every step of the episodes under the inputs of driver ``name``."""
    plant_names, seeds = lanes
    spec, B, T, n = sc.env, len(seeds), sc.env.steps, sc.controller_order
    env = spec.make_vec(B, info_keys=())
    obs, plants = spec.reset_lanes(env, seeds, plant_names)
    theta = env.params.reshape(B, -1).copy()  # no jumps in family:test
    policy = driver_policy(name, cfg, sc, plants, seeds, args)
    ctl = SelfTuningController(
        n, num_envs=B, action_bound=spec.action_bound, seed=controller_seeds(seeds, 0)
    )
    orls = closed_loop_estimator("O-RLS", n, B)
    est = {k: np.full((B, T, 2 * n), np.nan) for k in ESTIMATES}
    innov = {k: np.full((B, T), np.nan) for k in ESTIMATES}
    u_abs = np.full((B, T), np.nan)
    alive = np.ones(B, dtype=bool)
    bound = spec.action_bound
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the estimators' health events, an autoreset's plant
        for k in range(T):
            proposal = ctl.propose(obs, episode_start=np.ones(B, bool) if k == 0 else None)
            orls.update(obs[:, 0])
            est["ELS"][alive, k] = ctl.theta[alive]
            est["O-RLS"][alive, k] = orls.theta[alive]
            innov["ELS"][alive, k] = ctl.compiled_args.s.e[alive]
            innov["O-RLS"][alive, k] = orls.e[alive]
            if policy is None:
                u = proposal
            else:
                u, _ = policy.predict(obs, deterministic=True)
            u = np.clip(np.asarray(u, dtype=float).reshape(B, 1), -bound, bound)
            if name == "theta_ppo":  # the agent's own O-RLS is the one run here
                assert np.array_equal(policy.lanes.estimator.theta, orls.theta)
            ctl.commit(u)
            orls.predict(u[:, 0])
            u_abs[alive, k] = np.abs(u[alive, 0])
            obs, _, terminated, _, _ = env.step(u)
            alive &= ~np.asarray(terminated, dtype=bool)
    env.close()
    return {"theta": theta, "estimate": est, "innovation": innov, "u_abs": u_abs}


def iqm(x: NDArray) -> float:
    """Interquartile mean (the mean of the middle half)."""
    x = np.sort(x[np.isfinite(x)])
    lo, hi = int(np.floor(0.25 * x.size)), int(np.ceil(0.75 * x.size))
    return float(x[lo:hi].mean()) if hi > lo else float("nan")


def summarise(run: dict, strata: NDArray, noise_std: float) -> dict:
    """The figures of one driver (module docstring)."""
    theta = run["theta"]
    scale = np.linalg.norm(theta, axis=1)
    err = {
        k: np.linalg.norm(run["estimate"][k] - theta[:, None, :], axis=2) / scale[:, None]
        for k in ESTIMATES
    }
    T = err["ELS"].shape[1]
    times = [t for t in TIMES if t < T] + [T - 1]
    out: dict[str, Any] = {"times": times, "lanes": [], "error": {k: [] for k in ESTIMATES}}
    out["els_closer"] = []
    for t in times:
        live = np.isfinite(err["ELS"][:, t])
        out["lanes"].append(int(live.sum()))
        for k in ESTIMATES:
            e = err[k][live, t]
            out["error"][k].append({"median": float(np.median(e)), "iqm": iqm(e)})
        out["els_closer"].append(float(np.mean(err["ELS"][live, t] < err["O-RLS"][live, t])))
    out["innovation"] = {}
    for lo, hi in WINDOWS:
        key = f"{lo}-{T if hi is None else hi}"
        window = {k: run["innovation"][k][:, lo:hi] for k in ESTIMATES}
        ran = np.isfinite(window["ELS"]).any(axis=1)  # the lanes that reached the window
        out["innovation"][key] = {
            k: float(np.median(np.nanmean(w[ran] ** 2, axis=1)) / noise_std**2)
            for k, w in window.items()
        }
    last = np.array([np.flatnonzero(np.isfinite(row))[-1] for row in err["ELS"]])
    lanes = np.arange(len(last))
    end = {k: err[k][lanes, last] for k in ESTIMATES}
    full = last == T - 1
    out["strata"] = []
    for s, label in enumerate(STRATA):
        mask = (strata == s) & full
        if mask.any():
            row = {k: float(np.median(end[k][mask])) for k in ESTIMATES}
            out["strata"].append({"stratum": label, "lanes": int(mask.sum()), **row})
    out["ended_early"] = int((~full).sum())
    out["median_abs_input"] = float(np.nanmedian(run["u_abs"]))
    return out


def print_summary(name: str, s: dict) -> None:
    print(f"\n== inputs of {name}: median |u| {s['median_abs_input']:.3g}, "
          f"{s['ended_early']} lanes left y_bound ==")  # fmt: skip
    print(f"{'t':>5} {'lanes':>5} | {'O-RLS median':>12} {'IQM':>6} | {'ELS median':>10} "
          f"{'IQM':>6} | ELS closer")  # fmt: skip
    for i, t in enumerate(s["times"]):
        o, e = s["error"]["O-RLS"][i], s["error"]["ELS"][i]
        print(f"{t:>5} {s['lanes'][i]:>5} | {o['median']:>12.3f} {o['iqm']:>6.3f} | "
              f"{e['median']:>10.3f} {e['iqm']:>6.3f} | {s['els_closer'][i]:>9.0%}")  # fmt: skip
    print("mean squared innovation / noise variance (median over lanes):")
    for window, v in s["innovation"].items():
        print(f"  steps {window:>9}: O-RLS {v['O-RLS']:8.3g}   ELS {v['ELS']:8.3g}")
    print("end-of-episode relative error by stratum (median, lanes that ran to the end):")
    for row in s["strata"]:
        print(f"  {row['stratum']:<40} {row['lanes']:>4}: O-RLS {row['O-RLS']:.3f}   "
              f"ELS {row['ELS']:.3f}")  # fmt: skip


def step_costs(n: int, batches: tuple[int, ...], steps: int, repeats: int) -> list[dict]:
    """Wall time of one agent step's features for ``B`` lanes (``observe``, ``features``,
    ``to_input``): the window alone, and the estimate interface with O-RLS and with ELS (best
    of ``repeats`` interleaved runs of ``steps`` steps on random observations and actions)."""
    from stcgym.agents.rl.interfaces import InterfaceSpec
    from stcgym.agents.rl.wrappers import WindowConfig

    specs = {
        "window": InterfaceSpec("window"),
        **{k: InterfaceSpec("estimate", estimator=k, order=n) for k in ESTIMATES},
    }
    rng = np.random.default_rng(0)
    out = []
    for B in batches:
        obs = rng.normal(0.0, 0.5, (steps, B, 2))
        actions = rng.uniform(-0.1, 0.1, (steps, B, 1))
        best = dict.fromkeys(specs, np.inf)
        for _ in range(repeats):
            for name, spec in specs.items():
                lanes = spec.build(WindowConfig(), 10.0, B)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    t0 = time.perf_counter()
                    for k in range(steps):
                        lanes.observe(obs[k], np.ones(B, bool) if k == 0 else None)
                        lanes.features()
                        lanes.to_input(actions[k])
                    best[name] = min(best[name], time.perf_counter() - t0)
        row = {"lanes": B, **{k: 1e6 * v / steps for k, v in best.items()}}
        out.append(row)
        print(f"B = {B:>4}: window {row['window']:6.1f} us a step, estimate with O-RLS "
              f"{row['O-RLS']:6.1f} us, with ELS {row['ELS']:6.1f} us "
              f"(ELS - O-RLS: {row['ELS'] - row['O-RLS']:+.1f} us)")  # fmt: skip
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--drivers", nargs="*", default=list(DRIVERS), choices=DRIVERS)
    parser.add_argument("--agent", default=None, help="a saved theta_ppo (the theta_ppo driver)")
    parser.add_argument("--plants", type=int, default=None, help="first N test episodes")
    parser.add_argument(
        "--action-bound",
        type=float,
        default=27.0,
        help="the bench's measured bound on siso2-v1 (standard tier)",
    )
    parser.add_argument(
        "--action-unit",
        type=float,
        default=3.4,
        help="the bench's measured action unit on siso2-v1",
    )
    parser.add_argument("--timing-lanes", type=int, nargs="*", default=[1, 16, 200])
    parser.add_argument("--timing-repeats", type=int, default=20)
    parser.add_argument("--out", default=None, help="write the figures as JSON here")
    args = parser.parse_args()
    drivers = [d for d in args.drivers if d != "theta_ppo" or args.agent is not None]
    cfg, sc, lanes = family_test(args.action_bound, args.plants)
    strata = plant_strata(lanes[0])
    print(f"{sc.name}: {len(lanes[1])} episodes of {sc.env.steps} steps, noise "
          f"{sc.env.noise_std}, bound {sc.env.action_bound}, order {sc.controller_order}; "
          f"strata {np.bincount(strata, minlength=len(STRATA)).tolist()}")  # fmt: skip
    result: dict[str, Any] = {
        "scenario": sc.name, "episodes": len(lanes[1]), "steps": sc.env.steps,
        "noise_std": sc.env.noise_std, "action_bound": sc.env.action_bound,
        "action_unit": args.action_unit,
        "agent": None if args.agent is None else Path(args.agent).name, "drivers": {},
    }  # fmt: skip
    for name in drivers:
        t0 = time.perf_counter()
        run = run_driver(name, cfg, sc, lanes, args)
        s = summarise(run, strata, sc.env.noise_std)
        s["wall_s"] = time.perf_counter() - t0
        result["drivers"][name] = s
        print_summary(name, s)
    if args.timing_lanes:
        repeats = args.timing_repeats
        print(f"\none step of the agent's features, best of {repeats} interleaved runs of 500 "
              "steps:")  # fmt: skip
        result["step_cost_us"] = step_costs(
            sc.controller_order, tuple(args.timing_lanes), 500, repeats
        )
    if args.out:
        Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
        print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
