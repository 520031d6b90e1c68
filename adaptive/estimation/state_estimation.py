"""State estimators driven by the current parameter estimates, as lane functions (Ding & Ma 2014,
section 2), and the regressor shifts of both canonical forms.

Published interface (signatures fixed; the model ``A_hat(t)``, ``b_hat(t)`` of ``theta_hat(t)``
comes from :func:`stcgym.adaptive.kernels.canonical.companion_into`):

``observer_step(A, b, x, u, y, K, closed, x_next) -> None``
    Open-loop observer (46)/(58): ``x_hat(t+1) = A x_hat(t) + b u(t)``; with ``closed`` the
    closed-loop observer (50) adds ``K [y(t) - c x_hat(t)]``, ``c = [1, 0, ..., 0]``.
``kalman_step(A, b, P1, Q, R, x, u, y, x_next, L1, AP, P_upd) -> int``
    Kalman filter (66)-(72) / (80)-(82) on the model ``(A, b, c = e_1)`` with process-noise
    covariance ``Q`` (n, n) and measurement-noise variance ``R`` (the paper: ``Q = 0``,
    ``R = 1``)::

        g = A P1 c^T,  s = R + c P1 c^T,  L1 = g / s                      (67)/(81)
        x_hat(t+1) = A x_hat + b u + L1 [y - c x_hat]                     (66)/(80)
        P1(t+1) = A P1 A^T - g g^T / s + Q    (symmetrised)               (68)/(82)

    ``AP`` and ``P_upd`` (n, n) are its scratch: ``A P1`` and ``P1(t+1)`` until it is
    accepted. Returns 0, or 1 when ``s <= 0`` or ``P1(t+1)`` is not
    finite: then ``P1`` and ``L1`` are untouched, ``x_next = A x + b u`` and the caller resets
    ``P1`` (the estimator resets it to ``P1(1)``). Any dense ``A`` works (the LQG oracle).
``filtered_state(x, P1, R, y, x_filt) -> float``
    The filtered estimate ``x(t|t) = x(t|t-1) + P1 c^T (y - c x(t|t-1)) / (R + c P1 c^T)`` of
    the same filter; returns the innovation ``y - c x(t|t-1)``.
``advance_regressor(phi, xs, x, u, n, observability) -> None``
    ``phi_hat(t) -> phi_hat(t+1)`` with ``x_hat(t)``, ``u(t)``: observer form (9)/(57)
    ``[-x1_hat(t), ..., -x1_hat(t-n+1), u(t), ..., u(t-n+1)]``; observability form (153)
    ``[-x_n_hat(t+1-n), ..., -x_1_hat(t+1-n), u(t), ...]`` from the last ``n`` estimates
    ``xs`` (row ``j`` is ``x_hat(t - j)``; zero before ``t = 1``).
``is_schur_stable(a, n, c) -> bool``
    ``z^n + a_1 z^{n-1} + ... + a_n`` has every root strictly inside the unit circle
    (Schur-Cohn step-down recursion, ``O(n^2)``, no eigenvalue solver).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from stcgym.lanes.compiled import lane
from stcgym.lanes.linalg import copy_matrix, copy_vector, matmul

__all__ = [
    "advance_regressor",
    "filtered_state",
    "is_schur_stable",
    "kalman_step",
    "observer_step",
]


@lane(inline=True)
def observer_step(
    A: NDArray,
    b: NDArray,
    x: NDArray,
    u: float,
    y: float,
    K: NDArray,
    closed: bool,
    x_next: NDArray,
) -> None:
    """Open-loop (46) or closed-loop (50) observer; ``x_next`` must not alias ``x``."""
    n = x.shape[0]
    innov = y - x[0]
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += A[i, j] * x[j]
        acc += b[i] * u
        if closed:
            acc += K[i] * innov
        x_next[i] = acc


@lane(inline=True, entry=True)
def kalman_step(
    A: NDArray,
    b: NDArray,
    P1: NDArray,
    Q: NDArray,
    R: float,
    x: NDArray,
    u: float,
    y: float,
    x_next: NDArray,
    L1: NDArray,
    AP: NDArray,
    P_upd: NDArray,
) -> int:
    """Kalman filter step (66)-(68); see the module docstring. ``x_next`` must not alias ``x``;
    ``AP``, ``P_upd``: ``(n, n)`` scratch."""
    n = x.shape[0]
    matmul(A, P1, AP)  # g = A P1 c^T = AP[:, 0]                                      (67)/(81)
    s = R + P1[0, 0]  # s = R + c P1 c^T                                              (67)/(81)
    innov = y - x[0]
    for i in range(n):  # A x_hat + b u, the prediction part of                      (66)/(80)
        acc = 0.0
        for j in range(n):
            acc += A[i, j] * x[j]
        x_next[i] = acc + b[i] * u
    finite = s > 0.0 and math.isfinite(s)
    inv_s = 1.0 / s
    # P1(t+1) = A P1 A^T - g g^T / s + Q                                              (68)/(82)
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for k in range(n):
                acc += AP[i, k] * A[j, k]
            P_upd[i, j] = acc - AP[i, 0] * AP[j, 0] * inv_s + Q[i, j]
    for i in range(n):
        for j in range(i + 1):
            v = 0.5 * (P_upd[i, j] + P_upd[j, i])
            P_upd[i, j] = v
            P_upd[j, i] = v
            finite = finite and math.isfinite(v)
    if not finite:
        return 1
    for i in range(n):
        L1[i] = AP[i, 0] * inv_s  # L1 = g / s                                        (67)/(81)
        x_next[i] += L1[i] * innov  # + L1 [y - c x_hat]                               (66)/(80)
    copy_matrix(P_upd, P1)
    return 0


@lane(inline=True, entry=True)
def filtered_state(x, P1, R, y, x_filt):
    """The current estimate ``x(t|t) = x(t|t-1) + P1 c^T (y - c x(t|t-1)) / (R + c P1 c^T)`` of
    the seed paper's Kalman filter (eq. (66)-(72), ``c = e_1``); returns the innovation. The
    time update is :func:`kalman_step`, whose
    prediction ``A x + b u + L1 (y - c x)`` equals ``A x(t|t) + b u``."""
    n = x.size
    s = R + P1[0, 0]
    innov = y - x[0]
    for i in range(n):
        x_filt[i] = x[i] + P1[i, 0] / s * innov
    return innov


@lane(inline=True)
def advance_regressor(
    phi: NDArray, xs: NDArray, x: NDArray, u: float, n: int, observability: bool
) -> None:
    """``phi_hat(t) -> phi_hat(t+1)``; see the module docstring."""
    for i in range(2 * n - 1, n, -1):
        phi[i] = phi[i - 1]
    phi[n] = u
    if observability:
        for j in range(n - 1, 0, -1):
            for i in range(n):
                xs[j, i] = xs[j - 1, i]
        copy_vector(x, xs[0])
        for i in range(n):  # -x_hat(t+1-n) in reverse order
            phi[i] = -xs[n - 1, n - 1 - i]
    else:
        for i in range(n - 1, 0, -1):
            phi[i] = phi[i - 1]
        phi[0] = -x[0]


@lane(inline=True, entry=True)
def is_schur_stable(a: NDArray, n: int, c: NDArray) -> bool:
    """Schur-Cohn / Jury step-down test of ``z^n + a_1 z^{n-1} + ... + a_n``: stable iff every
    reflection coefficient ``k_m`` satisfies ``|k_m| < 1`` (False for NaN).

    ``c`` (at least ``n`` floats) is scratch that receives the step-down coefficients; it may be
    ``a`` itself when ``a`` need not survive. The step-down ``c_i <- (c_i - k c_{m-2-i}) / (1 -
    k^2)`` is done in place pairwise (``i`` with ``m-2-i``), so the test allocates nothing."""
    copy_vector(a[:n], c)
    m = n
    while m > 0:
        k = c[m - 1]
        if not (-1.0 < k < 1.0):
            return False
        den = 1.0 - k * k
        for i in range(m // 2):  # the ceil((m - 1) / 2) pairs of the m - 1 new coefficients
            j = m - 2 - i
            ci, cj = c[i], c[j]
            c[i] = (ci - k * cj) / den
            c[j] = (cj - k * ci) / den
        m -= 1
    return True


@lane(allocates=True, entry=True)
def state_trajectory(
    A: NDArray,
    b: NDArray,
    u: NDArray,
    y: NDArray,
    x1: NDArray,
    kalman: bool,
    P1: NDArray,
    Q: NDArray,
    R: float,
    xs: NDArray,
) -> None:
    """Re-estimate all states ``x_hat(1..L)`` of a batch with a fixed model: ``xs[t - 1]`` is
    ``x_hat(t)``, ``x_hat(1) = x1``; open-loop observer (238)-(241) or, with ``kalman``, the
    Kalman filter (258)-(263) from ``P1(1) = P1`` (updated in place). The iterative GI/LSI
    estimators call it once per iteration. Values are not checked: the caller rejects states
    beyond its limit (a diverging model gives inf, never a silent reset here)."""
    n = x1.shape[0]
    x = x1.copy()
    x_next = np.empty(n)
    L1 = np.empty(n)
    AP = np.empty((n, n))
    P_upd = np.empty((n, n))
    K = np.zeros(n)
    for t in range(u.shape[0]):
        copy_vector(x, xs[t])
        if kalman:
            if kalman_step(A, b, P1, Q, R, x, u[t], y[t], x_next, L1, AP, P_upd) != 0:
                # P1 overflowed: propagate the open-loop prediction; the caller's limit trips
                observer_step(A, b, x, u[t], y[t], K, False, x_next)
        else:
            observer_step(A, b, x, u[t], y[t], K, False, x_next)
        copy_vector(x_next, x)
