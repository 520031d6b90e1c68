"""Voevoda & Troshina (2016): recursive least squares for one parameter of a 2nd-order object.

Usage::

    python benchmarks/voevoda_troshina_2016.py [--seeds 200]

The paper (Sci. Bull. NSTU 65(4), 2016, pp. 7-18) simulates, eq. (5)-(6)::

    x(k+1) = [[0, 1], [-0.3, theta]] x(k) + [0, 1]^T u(k) + w(k),   y(k+1) = [1, 0] x(k+1) + v(k+1)

eliminates the state, eq. (7)-(8) (target ``y(k+2) + 0.3 y(k) - u(k)``, regressor ``y(k+1)``),
and runs the scalar RLS (2)-(4) with ``P0 = 0.5`` on 500 measurements of a meander input of
period 6 and amplitude 1. Reported: ``theta_hat = -0.5008`` without measurement noise and
``-0.4613`` with measurement noise of variance 0.025; convergence in about 50-70 steps;
``P0 = 0`` never converges.

Here the plant is ``stcgym/StateSpace-v0`` with those matrices, the regression comes from
:class:`stcgym.adaptive.AffineStateSpace` (which derives (7)-(8) from the structure) and the
estimator is :class:`stcgym.adaptive.RecursiveLeastSquares` (all seeds as lanes of one
estimator).

Conventions chosen where the text extraction is garbled or silent
-----------------------------------------------------------------
1. **Sign of theta.** The text calls ``0.5`` the base value, but both reported estimates are
   near ``-0.5``; with ``+0.5`` every estimate here is near ``+0.5`` (printed below), and no
   reading of the garbled (7) turns data of ``theta = +0.5`` into ``-0.5``. We take
   ``theta = -0.5`` (a minus sign lost in the extraction).
2. **Equation (7).** The extraction prints ``y(k+2) + 0.3 y(k+1) - u(k+1)``, which is not what
   (5)-(6) give; eliminating the state from (5)-(6) gives
   ``y(k+2) + 0.3 y(k) - u(k) = theta y(k+1)``, which is what we use (and what
   ``AffineStateSpace(...).regression().equations()`` prints).
3. **Input.** Meander of period 6 *samples*: ``u(k) = +1`` for ``k mod 6 < 3``, else ``-1``
   (``stcgym.envs.signals.SquareWave(6)``). A period of 12 samples (if "T = 6" were the half
   period) is shown as a sensitivity row.
4. **Noise.** The noisy case adds white measurement noise ``v`` of variance 0.025 to ``y``
   (the text: "measurement noise v ... variance 0.025"); no process noise ``w``. The paper's
   figure 1 also has a ``Noise_w`` block, so a variant with ``w`` of the same variance on both
   states is shown too.
5. **Length and start.** 500 measurements = 500 regression rows (``y(0..501)``),
   ``x(0) = 0``, ``theta0 = 0``, ``P0 = 0.5``.

What the numbers say
--------------------
* **Noise-free.** RLS from ``theta0`` on noise-free data ends at the convex combination
  ``(theta0 / P0 + theta sum phi^2) / (1 / P0 + sum phi^2)`` of ``theta0`` and the true value
  (the prior ``P0`` is one extra "observation" of ``theta0``): ``-0.4972`` here
  (``sum phi^2 = 350``), ``-0.5`` to 9 digits with ``P0 = 1e6``. The paper's ``-0.5008`` lies
  *beyond* the true value, which no ``P0 > 0`` from ``theta0 = 0`` can produce on noise-free
  data of this model; the paper's "noise-free" run presumably still had the process noise ``w``
  of its figure 1, or a different start. We do not reproduce that last 0.2 %.
* **Noisy: errors in variables.** The regressor ``y(k+1)`` is itself measured with noise, so
  least squares is biased towards zero:
  ``plim theta_hat = theta E[y_clean^2] / (E[y_clean^2] + var v)`` (plus the prior's pull),
  ``-0.480`` here. The simulation gives ``-0.480 +- 0.010`` over 200 seeds; the paper's single
  run ``-0.4613`` is 2 standard deviations closer to zero (3 % of our runs are). With process
  noise of the same variance as well, the mean is ``-0.466 +- 0.015`` and ``-0.4613`` is well
  inside the spread (39 % of the runs are closer to zero): the paper's number is consistent
  with one run of that variant. Either way the noisy estimate is
  biased (not just noisy), and more data do not remove the bias; instrumental variables or a
  joint state/parameter estimator do.
* **P0 = 0.** The gain (3) is zero, ``theta`` stays at ``theta0 = 0`` for ever (the paper's
  remark after (4)).
* **Convergence.** With ``P0 = 0.5`` the pull of the prior decays like
  ``1 / (1 + P0 sum phi^2)``: within 5 % of the true value after about 55 steps (the paper:
  "about 50-60 iterations").
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

import stcgym.envs  # noqa: F401  (registers the envs)
from stcgym.adaptive import AffineStateSpace, RecursiveLeastSquares
from stcgym.envs.signals import SquareWave

THETA_TRUE = -0.5
PAPER_NOISE_FREE = -0.5008
PAPER_NOISY = -0.4613
P0 = 0.5
NOISE_VAR = 0.025
PERIOD = 6
ROWS = 500


def paper_object() -> AffineStateSpace:
    """Eq. (5)-(6): ``Phi = [[0, 1], [-0.3, theta]]``, ``Gamma = [0, 1]^T``, ``H = [1, 0]``."""
    return AffineStateSpace(
        Phi0=[[0.0, 1.0], [-0.3, 0.0]],
        Gamma0=[0.0, 1.0],
        H=[1.0, 0.0],
        Phi_terms=[[[0.0, 0.0], [0.0, 1.0]]],
        names=["theta"],
    )


def record(
    seed: int,
    *,
    noise_var: float = 0.0,
    process_noise_var: float = 0.0,
    theta: float = THETA_TRUE,
    period: int = PERIOD,
    rows: int = ROWS,
) -> tuple[NDArray, NDArray, NDArray]:
    """One experiment in ``stcgym/StateSpace-v0``: ``(u, y, y_clean)`` for ``k = 0..rows+1``."""
    obj = paper_object()
    Phi, Gamma = obj.matrices([theta])
    steps = rows + 2
    env = gym.make(
        "stcgym/StateSpace-v0",
        A=Phi,
        B=Gamma,
        C=obj.H,
        noise_std=float(np.sqrt(noise_var)),
        process_noise_std=float(np.sqrt(process_noise_var)),
        reference="zero",
        max_episode_steps=steps,
    )
    meander = SquareWave(period, 1.0)
    u = np.array([meander(k) for k in range(steps)])
    y = np.empty(steps)
    y_clean = np.empty(steps)
    obs, info = env.reset(seed=seed)
    y[0], y_clean[0] = obs[0], info["y_clean"][0]
    for k in range(steps - 1):
        obs, _, terminated, _, info = env.step([u[k]])
        if terminated:
            raise RuntimeError(f"the plant left the env's y_bound at step {k} (seed {seed})")
        y[k + 1], y_clean[k + 1] = obs[0], info["y_clean"][0]
    env.close()
    return u, y, y_clean


def estimate(
    seeds: range | list[int], *, P0: float = P0, theta0: float = 0.0, **experiment
) -> tuple[NDArray, NDArray]:
    """RLS on the regression (7)-(8) of each seed's record, all seeds as lanes of one estimator.

    Returns the estimate histories ``(len(seeds), rows)`` and the noise-free regressors
    ``(len(seeds), rows)`` (for the errors-in-variables prediction).
    """
    reg = paper_object().regression()
    phis, zs, clean = [], [], []
    for seed in seeds:
        u, y, y_clean = record(seed, **experiment)
        phi, z = reg.build(u, y)
        phis.append(phi)
        zs.append(z)
        clean.append(reg.build(u, y_clean)[0][:, 0])
    est = RecursiveLeastSquares(1, P0=P0, theta0=[theta0], num_envs=len(phis))
    return est.run(np.array(phis), np.array(zs))[:, :, 0], np.array(clean)


def eiv_prediction(phi_clean: NDArray, noise_var: float, P0: float = P0, theta=THETA_TRUE):
    """Large-sample RLS estimate with a noisy regressor (errors in variables), from ``theta0 = 0``.

    ``sum phi z ~ theta sum phi_clean^2`` (the noise of ``z`` is uncorrelated with ``phi``),
    ``sum phi^2 ~ sum phi_clean^2 + N var v``, so
    ``theta_hat ~ theta S / (1 / P0 + S + N var v)`` with ``S = sum phi_clean^2``.
    """
    S = float(np.mean(np.sum(phi_clean**2, axis=-1)))
    N = phi_clean.shape[-1]
    return theta * S / (1.0 / P0 + S + N * noise_var)


def steps_to_within(history: NDArray, target: float, rel: float) -> int:
    """First step after which ``|theta(t) - target| <= rel |target|`` for good."""
    outside = np.flatnonzero(np.abs(history - target) > rel * abs(target))
    return int(outside[-1] + 1) if outside.size else 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=200, help="noisy runs per case")
    args = parser.parse_args()
    seeds = range(args.seeds)

    print("regression built from the structure (eq. (7)-(8)):")
    print("  " + paper_object().regression().equations().replace("\n", "\n  "))

    free, _ = estimate([0])
    free_big, _ = estimate([0], P0=1e6)
    frozen, _ = estimate([0], P0=0.0)
    plus, _ = estimate([0], theta=0.5)
    noisy, clean = estimate(seeds, noise_var=NOISE_VAR)
    both, _ = estimate(seeds, noise_var=NOISE_VAR, process_noise_var=NOISE_VAR)
    slow, _ = estimate(seeds, noise_var=NOISE_VAR, period=2 * PERIOD)
    final = noisy[:, -1]
    z = (PAPER_NOISY - final.mean()) / final.std(ddof=1)

    def row(case: str, paper: str, values: NDArray) -> None:
        v = np.atleast_1d(values)
        spread = f" +- {v.std(ddof=1):.4f} ({v.size} seeds)" if v.size > 1 else ""
        print(f"| {case} | {paper} | {v.mean():.4f}{spread} |")

    print("\n| case (theta = -0.5, P0 = 0.5, theta0 = 0, 500 rows) | paper | stcgym |")
    print("|---|---:|---:|")
    row("no noise", f"{PAPER_NOISE_FREE}", free[:, -1])
    row("no noise, P0 = 1e6", "", free_big[:, -1])
    row("v: measurement noise, variance 0.025", f"{PAPER_NOISY}", final)
    pred = eiv_prediction(clean, NOISE_VAR)
    print(f"| errors-in-variables prediction for v | | {pred:.4f} |")
    row("v and w (process noise, variance 0.025 per state)", "", both[:, -1])
    row("v, meander period 12 samples", "", slow[:, -1])
    row("no noise, theta = +0.5 (other sign)", "", plus[:, -1])
    row("P0 = 0 (never adapts)", "no convergence", frozen[:, -1])
    print(
        f"\nthe paper's noisy value is {z:.1f} standard deviations closer to zero than the mean "
        f"over seeds (v only); runs at least as close to zero: "
        f"{np.mean(final >= PAPER_NOISY):.1%} (v only), "
        f"{np.mean(both[:, -1] >= PAPER_NOISY):.1%} (v and w)"
    )
    print(
        f"convergence, no noise: within 5 % of theta after "
        f"{steps_to_within(free[0], THETA_TRUE, 0.05)} steps, within 1 % after "
        f"{steps_to_within(free[0], THETA_TRUE, 0.01)} (paper: about 50-60)"
    )


if __name__ == "__main__":
    main()
