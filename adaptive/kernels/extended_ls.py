"""Extended least squares on the ARMAX form: the closed-loop-consistent estimator of the controller.

Model (Astrom & Wittenmark, *Adaptive Control*, 2nd ed., sec. 2.2-2.3 and 3.3): the observer
canonical plant with output noise, ``y = B(z)/A(z) u + v``, is the ARMAX model

    A(q) y(t) = B(q) u(t) + C(q) e(t),   C = A for white output noise,

and with ``theta = [a_1..a_n, b_1..b_n, c_1..c_n]``,

    phi(t) = [-y(t-1), ..., -y(t-n), u(t-1), ..., u(t-n), eps(t-1), ..., eps(t-n)],
    e(t)   = y(t) - phi(t)^T theta(t-1)                 (innovation, prior residual)
    L(t)   = P(t-1) phi(t) / (lambda + phi(t)^T P(t-1) phi(t))
    theta(t) = theta(t-1) + L(t) e(t)
    P(t)   = (P(t-1) - L(t) phi(t)^T P(t-1)) / lambda
    eps(t) = y(t) - phi(t)^T theta(t)                   (posterior residual, ELS)

The regressor is built from *measured* outputs and inputs (plus the residuals standing in for
the unmeasured noise), so unlike the seed paper's estimators, whose regressors are state
estimates that are only as good as the current parameters, it needs no good initial model and
stays consistent when ``u`` is a feedback of ``y``. ``with_c = 0`` drops the ``c`` block: plain
equation-error RLS (ARX), biased by output noise.

The lane record (:func:`extended_ls_layout`): ``theta`` (``d``), ``P`` (``d x d``), ``phi``
(``d``) and ``scratch`` (``d``), ``d = 2n`` or ``3n``; the estimate is always in the observer
canonical form (the controller designs on it; it converts to the env's form for display).
"""

from __future__ import annotations

import numpy as np

from stcgym.envs.compiled import Layout, lane

__all__ = ["extended_ls_layout", "extended_ls_reset", "extended_ls_update", "extended_ls_push"]

# offsets array indices
THETA, P, PHI, SCRATCH = 0, 1, 2, 3


def extended_ls_layout(n: int, with_c: bool) -> Layout:
    """Record of one lane: ``theta``, ``P``, ``phi``, ``scratch``; ``d = 3n`` (``2n`` without c)."""
    d = (3 if with_c else 2) * n
    lay = Layout()
    lay.add("theta", (d,))
    lay.add("P", (d, d))
    lay.add("phi", (d,))
    lay.add("scratch", (d,))
    return lay


@lane
def extended_ls_reset(f, off, d, p0):
    """``theta(0) = 0``, ``P(0) = p0 I``, ``phi(1) = 0`` (every signal zero before t = 1)."""
    for i in range(d):
        f[off[THETA] + i] = 0.0
        f[off[PHI] + i] = 0.0
    P0 = off[P]
    for i in range(d * d):
        f[P0 + i] = 0.0
    for i in range(d):
        f[P0 + i * d + i] = p0


@lane
def extended_ls_update(f, off, d, y, lam, p0):
    """Measurement step with ``y(t)``: ``theta(t)``, ``P(t)``; returns ``(e(t), eps(t))``.

    A non-positive or non-finite denominator, or a non-finite update, restarts ``P`` at
    ``p0 I`` and keeps ``theta`` (returns the prior residual for both).
    """
    th = off[THETA]
    Pk = off[P]
    ph = off[PHI]
    g = off[SCRATCH]
    e = y
    for i in range(d):
        e -= f[ph + i] * f[th + i]
    s = lam
    for i in range(d):
        acc = 0.0
        for j in range(d):
            acc += f[Pk + i * d + j] * f[ph + j]
        f[g + i] = acc
        s += f[ph + i] * acc
    if not (s > 0.0 and np.isfinite(s) and np.isfinite(e)):
        extended_ls_restart(f, off, d, p0)
        return e, e
    inv_s = 1.0 / s
    inv_lam = 1.0 / lam
    for i in range(d):
        f[th + i] += f[g + i] * inv_s * e
    for i in range(d):
        gi = f[g + i] * inv_s
        for j in range(i, d):
            v = (f[Pk + i * d + j] - gi * f[g + j]) * inv_lam
            f[Pk + i * d + j] = v
            f[Pk + j * d + i] = v
    eps = y
    ok = True
    for i in range(d):
        eps -= f[ph + i] * f[th + i]
        if not np.isfinite(f[th + i]):
            ok = False
    if not ok:
        extended_ls_restart(f, off, d, p0)
        return e, e
    return e, eps


@lane
def extended_ls_restart(f, off, d, p0):
    """``P = p0 I`` (numerical trouble); a non-finite ``theta`` goes back to zero."""
    Pk = off[P]
    for i in range(d):
        if not np.isfinite(f[off[THETA] + i]):
            f[off[THETA] + i] = 0.0
        for j in range(d):
            f[Pk + i * d + j] = p0 if i == j else 0.0


@lane
def extended_ls_push(f, off, n, d, y, u, eps):
    """Shift ``y(t)``, ``u(t)``, ``eps(t)`` into the regressor: it becomes ``phi(t+1)``."""
    ph = off[PHI]
    for k in range(n - 1, 0, -1):
        f[ph + k] = f[ph + k - 1]
        f[ph + n + k] = f[ph + n + k - 1]
    f[ph] = -y
    f[ph + n] = u
    if d > 2 * n:
        for k in range(n - 1, 0, -1):
            f[ph + 2 * n + k] = f[ph + 2 * n + k - 1]
        f[ph + 2 * n] = eps
