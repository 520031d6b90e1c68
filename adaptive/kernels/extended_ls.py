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
:func:`~stcgym.adaptive.kernels.least_squares.least_squares_step` (square-root form ``P = S
S^T``, Carlson's update; Ding & Ma 2014 eq. (32)-(36) on this regressor): ELS differs from the
paper's RLS only in its regressor.

The regressor is built from *measured* outputs and inputs (plus the residuals standing in for
the unmeasured noise), so unlike the seed paper's estimators, whose regressors are state
estimates that are only as good as the current parameters, it needs no good initial model and
stays consistent when ``u`` is a feedback of ``y``. ``with_c = 0`` drops the ``c`` block: plain
equation-error RLS (ARX), biased by output noise.

The lane record (:class:`ExtendedLSRecord`, :func:`extended_ls_layout`): ``theta`` (``d``),
``S`` (``d x d``, the upper factor of ``P``), ``phi`` (``d``) and ``scratch`` (``3 d + 2``),
``d = 2n`` or ``3n``; the estimate is always in the observer canonical form (the controller
designs on it; it converts to the env's form for display).
"""

from __future__ import annotations

import math
from typing import NamedTuple

from stcgym.adaptive.kernels.least_squares import OK, least_squares_step
from stcgym.adaptive.kernels.records import view2d
from stcgym.envs.compiled import Layout, lane

__all__ = [
    "ExtendedLSRecord",
    "extended_ls_layout",
    "extended_ls_push",
    "extended_ls_reset",
    "extended_ls_update",
]


class ExtendedLSRecord(NamedTuple):
    """Fields of the ELS lane record. The lane functions read any record ``at`` with these
    fields (the controller's record locates them inside its own)."""

    theta: int  # [a; b; c] (d)
    S: int  # upper-triangular factor of P = S S^T (d, d)
    phi: int  # regressor phi(t) (d)
    scratch: int  # least_squares_step's work (3 d + 1) and y(t)


def extended_ls_layout(n: int, with_c: bool) -> Layout:
    """Record of one lane: ``theta``, ``S``, ``phi``, ``scratch``; ``d = 3n`` (``2n`` without c)."""
    d = (3 if with_c else 2) * n
    lay = Layout()
    lay.add("theta", (d,))
    lay.add("S", (d, d))
    lay.add("phi", (d,))
    lay.add("scratch", (3 * d + 2,))  # least_squares_step's work (p = 1) and y(t)
    return lay


@lane(inline=True)
def extended_ls_reset(f, at, d, p0):
    """``theta(0) = 0``, ``P(0) = p0 I`` (``S = sqrt(p0) I``), ``phi(1) = 0`` (every signal zero
    before t = 1)."""
    for i in range(d):
        f[at.theta + i] = 0.0
        f[at.phi + i] = 0.0
    extended_ls_restart(f, at, d, p0)


@lane(inline=True)
def extended_ls_update(f, at, d, y, lam, p0):
    """Measurement step with ``y(t)``: ``theta(t)``, ``P(t)``; returns ``(e(t), eps(t))``.

    A failed least-squares step (non-positive or non-finite denominator, unhealthy factor,
    non-finite update: ``least_squares_step`` leaves ``theta`` untouched) or a non-finite
    innovation restarts ``P`` at ``p0 I`` and keeps ``theta`` (returns the prior residual for
    both).
    """
    theta = f[at.theta : at.theta + d]
    S = view2d(f, at.S, d, d)
    Phi = view2d(f, at.phi, 1, d)  # the regressor as the one row of Phi (p = 1)
    work = f[at.scratch : at.scratch + 3 * d + 1]
    Y = f[at.scratch + 3 * d + 1 : at.scratch + 3 * d + 2]  # y(t) as a 1-block, after it
    Y[0] = y
    if not math.isfinite(y) or least_squares_step(theta, S, Phi, Y, lam, work) != OK:
        e = y
        for i in range(d):
            e -= Phi[0, i] * theta[i]
        extended_ls_restart(f, at, d, p0)
        return e, e
    e = work[2 * d]  # the innovation E(1, t) with theta(t-1), left there by the step
    eps = y
    for i in range(d):
        eps -= Phi[0, i] * theta[i]
    return e, eps


@lane(inline=True)
def extended_ls_restart(f, at, d, p0):
    """``P = p0 I`` (numerical trouble; ``S = sqrt(p0) I``); a non-finite ``theta`` goes back to
    zero."""
    theta = f[at.theta : at.theta + d]
    S = view2d(f, at.S, d, d)
    root = math.sqrt(p0)
    for i in range(d):
        if not math.isfinite(theta[i]):
            theta[i] = 0.0
        for j in range(d):
            S[i, j] = root if i == j else 0.0


@lane(inline=True)
def extended_ls_push(f, at, n, d, y, u, eps):
    """Shift ``y(t)``, ``u(t)``, ``eps(t)`` into the regressor: it becomes ``phi(t+1)``."""
    phi = f[at.phi : at.phi + d]
    for k in range(n - 1, 0, -1):
        phi[k] = phi[k - 1]
        phi[n + k] = phi[n + k - 1]
    phi[0] = -y
    phi[n] = u
    if d > 2 * n:
        for k in range(n - 1, 0, -1):
            phi[2 * n + k] = phi[2 * n + k - 1]
        phi[2 * n] = eps
