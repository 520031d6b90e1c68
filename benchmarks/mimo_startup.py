"""Multivariable self-tuning LQ start-up on ``he1`` in controlgym's formulation, against LQR.

Usage::

    python benchmarks/mimo_startup.py [--seeds 10] [--steps 1000] [--commit-grid] [--out FILE.json]

Setting (controlgym 1.0.0's linear-control task, Zhang et al. 2023, on COMPleib's HE1):
``x(k+1) = A x(k) + B u(k) + B1 w(k)`` with ``(A, B)`` stcgym's ``he1`` (zero-order hold at
0.1 s), ``B1`` COMPleib's disturbance matrix discretised with it, ``w(k) ~ N(0, 0.1 I)``,
``x(0) ~ N(0, 0.1 I)``, regulation (``r = 0``), the state measured without noise, no input
bound, and the stage cost ``||C1 x + D12 u||^2``, i.e. ``Q = C1' C1``, ``R = D12' D12``,
``N = C1' D12`` (python-control's ``dlqr(A, B, Q, R, N)``) for both controllers. Episodes of
``--steps`` samples; seed ``s`` draws the initial state and the noise of episode ``s`` (the
same for every controller) and the self-tuning controller's probe seed.

Rows: ``lqr`` (:class:`~stcgym.adaptive.LQRController` on the true ``(A, B)``),
``stc`` (:class:`~stcgym.adaptive.MultivariableSelfTuningController` with the same weights and
default options), ``stc_no_cross`` (the same without ``N``, for comparison), ``zero``
(no input) and ``bound``: what identification costs at the least. ``[A B]`` has ``n + m``
unknown columns, so no estimate exists before ``n + m`` regressors ``[x; u]``: the bound row
applies the self-tuning controller's own probe for those ``n + m`` samples (open loop, as any
controller without a model must) and then LQR with the *true* gain, i.e. a controller that
identifies the model exactly from the fewest samples with the smallest excitation.

An episode whose state leaves ``|x_i| < 1e6`` is charged ``inf`` (zero input on this unstable
plant). Figures: whole-episode cost of each row per seed, its ratio to LQR's, the median over the
seeds, and ``stc`` over ``bound``: per seed, its median, 90th percentile and largest value, the
share of seeds within 1.2x, and the pooled ratio (total cost over total cost, with a 95 %
bootstrap interval over the seeds: the per-seed ratios are heavy-tailed, so the pooled one needs
hundreds of seeds). Target: ``stc`` within 1.5x of LQR (median), or within 1.2x of the bound
where that bound exceeds 1.5x.

``--commit-grid`` adds what the first estimates are worth without adaptation
(explore-then-commit): a probe of ``k`` samples with the self-tuning controller's probe amplitude
times ``scale`` (random signs), then the LQ gain of the batch least-squares estimate of those
``k`` samples (python-control's ``dlqr``), held for the rest of the episode; for every
``(k, scale)`` of the grid the median ratio to the bound and the share of episodes that diverge.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from typing import Any

import control
import numpy as np
from numpy.typing import NDArray

from stcgym.adaptive import LQRController, MultivariableSelfTuningController
from stcgym.envs import get_mimo_plant

#: COMPleib HE1 (Leibfritz 2004, as shipped by controlgym 1.0.0): disturbance input ``B1``
#: (continuous), performance output ``z = C1 x + D12 u``.
_S = float(np.sqrt(0.5))
HE1_B1 = np.array([[0.04678, 0.0], [0.04572, 0.00988], [0.04369, 0.00111], [-0.02179, 0.0]])
HE1_C1 = np.array([[2 * _S, 0.0, 0.0, 0.0], [0.0, _S, 0.0, 0.0]])
HE1_D12 = np.array([[_S, 0.0], [0.0, _S]])
#: controlgym's defaults: noise covariance and initial-state covariance ``0.1 I``.
NOISE_COV = 0.1


def he1_problem() -> dict[str, NDArray]:
    """``A, B, B1`` (discrete) and ``Q, R, N`` of he1 in controlgym's formulation."""
    spec = get_mimo_plant("he1")
    n, m = spec.n_states, spec.n_inputs
    Bc = np.hstack((np.array(spec.B_c), HE1_B1))
    sysd = control.sample_system(
        control.ss(np.array(spec.A_c), Bc, np.eye(n), np.zeros((n, Bc.shape[1]))), spec.dt
    )
    A, B = spec.discrete()
    B1 = np.asarray(sysd.B)[:, m:]
    return {
        "A": A,
        "B": B,
        "B1": B1,
        "C1": HE1_C1,
        "D12": HE1_D12,
        "Q": HE1_C1.T @ HE1_C1,
        "R": HE1_D12.T @ HE1_D12,
        "N": HE1_C1.T @ HE1_D12,
    }


def episode(
    prob: dict[str, NDArray],
    policy: Any,
    seed: int,
    steps: int,
    probe: NDArray | None = None,
) -> float:
    """Whole-episode cost ``sum ||C1 x + D12 u||^2`` of ``policy`` (``None``: zero input);
    with ``probe`` (``(k, m)``) the first ``k`` inputs are the probe's instead (the bound
    row)."""
    A, B, B1, C1, D12 = (prob[k] for k in ("A", "B", "B1", "C1", "D12"))
    n, m = B.shape
    rng = np.random.default_rng(np.random.SeedSequence([35, seed]))
    x = rng.normal(0.0, np.sqrt(NOISE_COV), n)
    W = rng.normal(0.0, np.sqrt(NOISE_COV), (steps, B1.shape[1]))
    r = np.zeros(n)
    cost = 0.0
    for k in range(steps):
        u = np.zeros(m) if policy is None else policy.predict(np.concatenate([x, r]))[0]
        if probe is not None and k < len(probe):
            u = probe[k]
        z = C1 @ x + D12 @ u
        cost += float(z @ z)
        x = A @ x + B @ u + B1 @ W[k]
        if not np.all(np.abs(x) < 1e6):
            return float("inf")
    return cost


class FirstInputs:
    """``policy`` as it is, keeping its first ``count`` inputs: on the self-tuning controller's
    episode, its own probe's first ``n + m`` samples, the fewest regressors ``[x; u]`` that
    determine ``[A B]`` (the bound row applies them)."""

    def __init__(self, policy: Any, count: int) -> None:
        self.policy, self.count = policy, count
        self.inputs: list[NDArray] = []

    def predict(self, observation: NDArray) -> tuple[NDArray, Any]:
        u, state = self.policy.predict(observation)
        if len(self.inputs) < self.count:
            self.inputs.append(np.array(u, dtype=float))
        return u, state


class ExploreThenCommit:
    """Explore-then-commit as a policy for :func:`episode`: ``k`` probe samples ``+-amplitude``
    (random signs from ``seed``), then ``u = -K x`` with ``K`` the LQ gain (python-control's
    ``dlqr`` with the problem's ``Q, R, N``) of the batch least-squares ``[A B]`` of the probe's
    samples, held for the rest of the episode (zero when ``dlqr`` finds no stabilising
    solution)."""

    def __init__(self, prob: dict[str, NDArray], seed: int, k: int, amplitude: float) -> None:
        self.prob = prob
        self.n, self.m = prob["B"].shape
        rng = np.random.default_rng(np.random.SeedSequence([35, seed, k]))
        self.probe = amplitude * rng.choice([-1.0, 1.0], (k, self.m))
        self.x: list[NDArray] = []  # x(0), ..., x(k): the probe's regressors and targets
        self.K: NDArray | None = None

    def predict(self, observation: NDArray) -> tuple[NDArray, None]:
        k, n = len(self.probe), self.n
        x = observation[:n]
        if len(self.x) < k:
            self.x.append(x.copy())
            return self.probe[len(self.x) - 1], None
        if self.K is None:
            self.x.append(x.copy())
            X = np.array(self.x)
            theta = np.linalg.lstsq(np.hstack((X[:-1], self.probe)), X[1:], rcond=None)[0]
            p = self.prob
            try:
                self.K = control.dlqr(theta[:n].T, theta[n:].T, p["Q"], p["R"], p["N"])[0]
            except (ValueError, np.linalg.LinAlgError, control.ControlArgument):
                self.K = np.zeros((self.m, n))
        return -self.K @ x, None


def _ratio_summary(stc: NDArray, bound: NDArray, resamples: int = 4000) -> dict[str, float]:
    """``stc`` over ``bound`` per seed (median, 90th percentile, largest, share within 1.2x) and
    pooled (total over total) with its 95 % bootstrap interval over the seeds."""
    ratio = stc / bound
    rng = np.random.default_rng(0)
    idx = rng.integers(0, len(ratio), (resamples, len(ratio)))
    boot = stc[idx].sum(axis=1) / bound[idx].sum(axis=1)
    return {
        "median": float(np.median(ratio)),
        "p90": float(np.percentile(ratio, 90)),
        "max": float(np.max(ratio)),
        "within_1.2": float(np.mean(ratio <= 1.2)),
        "pooled": float(stc.sum() / bound.sum()),
        "pooled_low": float(np.percentile(boot, 2.5)),
        "pooled_high": float(np.percentile(boot, 97.5)),
    }


def _stc(prob: dict[str, NDArray], seed: int, cross: bool) -> MultivariableSelfTuningController:
    n, m = prob["B"].shape
    return MultivariableSelfTuningController(
        n,
        m,
        Q=prob["Q"],
        R=prob["R"],
        N=prob["N"] if cross else None,
        action_bound=np.inf,
        seed=seed,
    )


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument(
        "--commit-grid",
        action="store_true",
        help="add explore-then-commit over probe lengths and amplitudes",
    )
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    prob = he1_problem()
    n, m = prob["B"].shape
    lqr = LQRController(prob["A"], prob["B"], Q=prob["Q"], R=prob["R"], N=prob["N"],
                        action_bound=np.inf)  # fmt: skip
    K_ref = control.dlqr(prob["A"], prob["B"], prob["Q"], prob["R"], prob["N"])[0]
    print(f"LQR gain against control.dlqr: max |dK| = {np.max(np.abs(lqr.K - K_ref)):.2e}")
    rows: dict[str, list[float]] = {k: [] for k in ("lqr", "stc", "stc_no_cross", "zero", "bound")}
    probes = []  # the self-tuning controller's probe on every episode
    for s in range(args.seeds):
        rows["lqr"].append(episode(prob, lqr, s, args.steps))
        stc = FirstInputs(_stc(prob, s, True), n + m)
        rows["stc"].append(episode(prob, stc, s, args.steps))
        probes.append(np.array(stc.inputs))
        rows["stc_no_cross"].append(episode(prob, _stc(prob, s, False), s, args.steps))
        rows["zero"].append(episode(prob, None, s, args.steps))
        rows["bound"].append(episode(prob, lqr, s, args.steps, probe=probes[-1]))
    lqr_cost = np.array(rows["lqr"])
    print(f"he1 (controlgym formulation), {args.steps} steps, {args.seeds} seeds")
    print(f"{'seed':>4} {'lqr':>9} " + " ".join(f"{k + '/lqr':>16}" for k in rows if k != "lqr"))
    for s in range(args.seeds):
        ratios = " ".join(f"{rows[k][s] / lqr_cost[s]:16.3f}" for k in rows if k != "lqr")
        print(f"{s:4d} {lqr_cost[s]:9.3f} {ratios}")
    medians = {k: float(np.median(np.array(v) / lqr_cost)) for k, v in rows.items()}
    print("median " + " ".join(f"{k}/lqr={v:.3f}" for k, v in medians.items() if k != "lqr"))
    to_bound = np.array(rows["stc"]) / np.array(rows["bound"])
    medians["stc/bound"] = float(np.median(to_bound))
    if args.seeds <= 20:
        print(f"stc/bound per seed {np.round(to_bound, 3).tolist()}")
    summary = _ratio_summary(np.array(rows["stc"]), np.array(rows["bound"]))
    print(
        f"stc/bound: median {summary['median']:.3f}, p90 {summary['p90']:.2f}, "
        f"max {summary['max']:.2f}, {100 * summary['within_1.2']:.0f} % of seeds within 1.2x; "
        f"pooled {summary['pooled']:.3f} [{summary['pooled_low']:.3f}, "
        f"{summary['pooled_high']:.3f}]"
    )
    result = {
        "steps": args.steps,
        "seeds": args.seeds,
        "costs": rows,
        "median_ratio": medians,
        "stc_over_bound": summary,
    }
    if args.commit_grid:
        bound = np.array(rows["bound"])
        amplitude = [float(np.max(np.abs(p))) for p in probes]
        grid: dict[str, Any] = {}
        best_cost: dict[str, NDArray] = {}
        print("explore-then-commit: probe k samples at scale x the controller's amplitude")
        for k in (n + m, n + m + 2, 2 * (n + m), 3 * (n + m), 5 * (n + m)):
            for scale in (1.0, 3.0, 10.0, 30.0):
                policies = [ExploreThenCommit(prob, s, k, scale * amplitude[s])
                            for s in range(args.seeds)]  # fmt: skip
                cost = np.array([episode(prob, p, s, args.steps) for s, p in enumerate(policies)])
                med = float(np.median(cost / bound))
                diverged = float(np.mean(~np.isfinite(cost)))
                cell = f"k={k},scale={scale:g}"
                grid[cell] = {"median_over_bound": med, "diverged": diverged}
                best_cost[cell] = cost
                print(f"  k={k:3d} scale={scale:4g}: median / bound {med:10.3g}, "
                      f"diverged {100 * diverged:.0f} %")  # fmt: skip
        best = min(grid, key=lambda key: grid[key]["median_over_bound"])
        to_best = np.array(rows["stc"]) / best_cost[best]
        result["commit_best"] = {
            "cell": best,
            "stc_over_it_median": float(np.median(to_best)),
            "stc_cheaper": float(np.mean(to_best < 1.0)),
        }
        print(
            f"stc / explore-then-commit's best cell ({best}): median {np.median(to_best):.3f}, "
            f"stc cheaper on {100 * np.mean(to_best < 1.0):.0f} % of the seeds"
        )
        result["commit_grid"] = grid
    if args.out:
        fd, tmp = tempfile.mkstemp(dir=os.path.dirname(os.path.abspath(args.out)) or ".")
        with os.fdopen(fd, "w") as fh:
            json.dump(result, fh, indent=1)
        os.replace(tmp, args.out)
    return result


if __name__ == "__main__":
    main()
