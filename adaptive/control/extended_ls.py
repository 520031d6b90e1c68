"""Extended least squares on the ARMAX form: the closed-loop-consistent estimator of the controller.

Model (Astrom & Wittenmark, *Adaptive Control*, 2nd ed., sec. 2.2-2.3 and 3.3): the observer
canonical plant with output noise, ``y = B(z)/A(z) u + v``, is the ARMAX model

    A(q) y(t) = B(q) u(t) + C(q) e(t),   C = A for white output noise,

and with ``theta = [a_1..a_n, b_1..b_n, c_1..c_n]``,

    phi(t) = [-y(t-1), ..., -y(t-n), u(t-1), ..., u(t-n), eps(t-1), ..., eps(t-n)],
    e(t)   = y(t) - phi(t)^T theta(t-1)                 (innovation, prior residual)
    theta(t), P(t): one recursive least-squares step on (phi(t), y(t)) with forgetting lambda
    eps(t) = y(t) - phi(t)^T theta(t)                   (posterior residual, ELS)

The least-squares step is the project's one implementation of RLS,
:func:`~stcgym.adaptive.estimation.least_squares.least_squares_step` (square-root form ``P = S
S^T``, Carlson's update; Ding & Ma 2014 eq. (32)-(36) on this regressor): ELS differs from the
paper's RLS only in its regressor.

The regressor is built from *measured* outputs and inputs (plus the residuals standing in for
the unmeasured noise), so unlike the seed paper's estimators, whose regressors are state
estimates that are only as good as the current parameters, it needs no good initial model and
stays consistent when ``u`` is a feedback of ``y``. ``with_c = 0`` drops the ``c`` block: plain
equation-error RLS (ARX), biased by output noise.

The lane state (:class:`ExtendedLSState`) holds ``theta`` (``d``), ``S`` (``d x d``, the upper
factor of ``P``) and the regressor ``Phi`` (``1 x d``, the one row of the least-squares block);
its scratch (:class:`ExtendedLSWork`) the least-squares step's work and ``y(t)`` as a 1-block.
``d = 2n`` or ``3n`` (:func:`extended_ls_shapes`); the estimate is always in the observer
canonical form (the controller designs on it; it converts to the env's form for display).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from stcgym.adaptive.estimation.least_squares import (
    OK,
    LeastSquaresWork,
    least_squares_shapes,
    least_squares_step,
)
from stcgym.lanes.compiled import fields_of, lane, lane_state, make_work

__all__ = [
    "ExtendedLSConfig",
    "ExtendedLSState",
    "ExtendedLSWork",
    "extended_ls_push",
    "extended_ls_shapes",
    "extended_ls_update",
    "make_extended_ls",
]


class ExtendedLSState(NamedTuple):
    """The ELS lane state: field ``f`` of lane ``i`` is ``state.f[i]`` (shapes in
    :func:`extended_ls_shapes`)."""

    theta: NDArray  # [a; b; c] (d)
    S: NDArray  # upper-triangular factor of P = S S^T (d, d)
    Phi: NDArray  # the regressor phi(t) as the one row of the block Phi(1, t) (1, d)


class ExtendedLSConfig(NamedTuple):
    """Configuration of the ELS lane functions."""

    forgetting: float  # lambda
    p0: float  # P(0) = p0 I, and P after numerical trouble


class ExtendedLSStepWork(NamedTuple):
    """The ELS step's own scratch."""

    Y: NDArray  # y(t) as the one entry of the block Y(1, t) (1)


#: The ELS scratch, one row a lane (its content is irrelevant between calls): the fields of
#: :class:`ExtendedLSStepWork` and of the least-squares step's
#: :class:`~stcgym.adaptive.estimation.least_squares.LeastSquaresWork`.
ExtendedLSWork = NamedTuple(  # type: ignore[misc]
    "ExtendedLSWork", fields_of(ExtendedLSStepWork, LeastSquaresWork)
)


def extended_ls_shapes(
    n: int, with_c: bool = True
) -> tuple[dict[str, tuple[int, ...]], dict[str, tuple[int, ...]]]:
    """The shapes of one lane's :class:`ExtendedLSState` and :class:`ExtendedLSWork` fields,
    ``d = 3n`` (``2n`` without ``c``): the one place they are declared."""
    d = (3 if with_c else 2) * int(n)
    state = {"theta": (d,), "S": (d, d), "Phi": (1, d)}
    work = {"Y": (1,), **least_squares_shapes(d, 1)}
    return state, work


def make_extended_ls(
    n: int, num_lanes: int, p0: float, with_c: bool = True
) -> tuple[ExtendedLSState, Any]:
    """The state of ``num_lanes`` lanes at ``t = 0`` and their scratch: ``theta(0) = 0``,
    ``P(0) = p0 I`` (``S = sqrt(p0) I``), ``phi(1) = 0`` (every signal zero before t = 1)."""
    shapes, work_shapes = extended_ls_shapes(n, with_c)
    state = lane_state(ExtendedLSState, shapes, num_lanes)
    state.S[:] = np.sqrt(p0) * np.eye(shapes["S"][0])
    return state, make_work(ExtendedLSWork, work_shapes, num_lanes)


@lane(inline=True)
def extended_ls_update(els, work, lane_i, y, lam, p0):
    """Measurement step with ``y(t)``: ``theta(t)``, ``P(t)``; returns ``(e(t), eps(t))``.

    A failed least-squares step (non-positive or non-finite denominator, unhealthy factor,
    non-finite update: ``least_squares_step`` leaves ``theta`` untouched) or a non-finite
    innovation restarts ``P`` at ``p0 I`` and keeps ``theta`` (returns the prior residual for
    both).
    """
    theta = els.theta[lane_i]
    S = els.S[lane_i]
    Phi = els.Phi[lane_i]
    Y = work.Y[lane_i]
    d = theta.size
    Y[0] = y
    if not math.isfinite(y) or least_squares_step(theta, S, Phi, Y, lam, work, lane_i) != OK:
        e = y
        for i in range(d):
            e -= Phi[0, i] * theta[i]
        extended_ls_restart(theta, S, p0)
        return e, e
    e = work.E[lane_i][0]  # the innovation E(1, t) with theta(t-1), left there by the step
    eps = y
    for i in range(d):
        eps -= Phi[0, i] * theta[i]
    return e, eps


@lane(inline=True)
def extended_ls_restart(theta, S, p0):
    """``P = p0 I`` (numerical trouble; ``S = sqrt(p0) I``); a non-finite ``theta`` goes back to
    zero."""
    d = theta.size
    root = math.sqrt(p0)
    for i in range(d):
        if not math.isfinite(theta[i]):
            theta[i] = 0.0
        for j in range(d):
            S[i, j] = root if i == j else 0.0


@lane(inline=True)
def extended_ls_push(els, lane_i, n, y, u, eps):
    """Shift ``y(t)``, ``u(t)``, ``eps(t)`` into the regressor: it becomes ``phi(t+1)``."""
    phi = els.Phi[lane_i, 0]
    d = phi.size
    for k in range(n - 1, 0, -1):
        phi[k] = phi[k - 1]
        phi[n + k] = phi[n + k - 1]
    phi[0] = -y
    phi[n] = u
    if d > 2 * n:
        for k in range(n - 1, 0, -1):
            phi[2 * n + k] = phi[2 * n + k - 1]
        phi[2 * n] = eps
