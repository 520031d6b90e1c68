"""Where the iterative estimators converge: the LSI family from random iteration-0 states.

Usage::

    python benchmarks/iterative_convergence.py [--starts 10] [--samples 300]

Noise-free data (``L`` samples of a random +-1 input from rest) of a well-damped plant (poles
0.25 +- 0.37j, the plant of ``tests/test_iterative.py``) and of three catalogue plants, in both
canonical forms; every LSI-family name of Ding & Ma (2014), section 5, runs 200 iterations from
``--starts`` random iteration-0 state sequences (``seed = 0, 1, ...``). Printed per plant, form
and name: how many starts converged to the true parameters (error below ``1e-6``), how many
stopped elsewhere or overflowed (``NumericalHealthError``), and the median error.
"""

from __future__ import annotations

import argparse
import warnings

import control as ct
import numpy as np

from stcgym.adaptive import NumericalHealthError, fit_iterative
from stcgym.envs import PLANTS
from stcgym.envs.canonical import canonical_matrices, observer_to_observability_b

NAMES = ("O-LSI", "KF-LSI", "O-D-LSI", "KF-D-LSI")
WELL_DAMPED = ((-0.5, 0.2), (1.0, 0.5))
CATALOGUE = ("stable2", "lightly_damped2", "nonminphase2")


def record(a: np.ndarray, b: np.ndarray, form: str, samples: int) -> tuple[np.ndarray, ...]:
    """``u``, ``y`` of the plant in ``form`` (``b`` in that form's convention) from rest."""
    A, B, C, D = canonical_matrices(a, b, form)
    u = np.random.default_rng(1).choice([-1.0, 1.0], size=samples)
    res = ct.forced_response(ct.ss(A, B, C, D, dt=1), T=np.arange(samples), U=u)
    return u, np.asarray(res.outputs).ravel()


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--starts", type=int, default=10)
    ap.add_argument("--samples", type=int, default=300)
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore", RuntimeWarning)
    plants = {"well_damped": WELL_DAMPED}  # every plant is second order
    plants.update({k: (PLANTS[k].a, PLANTS[k].b) for k in CATALOGUE})
    print("| plant | form | name | converged | elsewhere | overflowed | median error |")
    print("|---|---|---|---:|---:|---:|---:|")
    for plant, (a, b) in plants.items():
        a, b = np.asarray(a, float), np.asarray(b, float)
        for form in ("observability", "observer"):
            b_form = observer_to_observability_b(a, b) if form == "observability" else b
            theta = np.concatenate([a, b_form])
            u, y = record(a, b_form, form, args.samples)
            for name in NAMES:
                errors, overflowed = [], 0
                for seed in range(args.starts):
                    try:
                        res = fit_iterative(name, u, y, 2, form=form, iterations=200, seed=seed)
                    except NumericalHealthError:
                        overflowed += 1
                        continue
                    errors.append(float(np.linalg.norm(res.theta - theta)))
                ok = sum(e < 1e-6 for e in errors)
                med = f"{np.median(errors):.2g}" if errors else "-"
                print(
                    f"| {plant} | {form} | {name} | {ok} | {len(errors) - ok} | {overflowed} | "
                    f"{med} |"
                )


if __name__ == "__main__":
    main()
