"""Closed-form pole placement for single-input models, fast enough for a per-step loop.

The self-tuning regulator re-designs its state feedback at every step on the estimated model
``(A_hat(t), b_hat(t))`` built from ``theta_hat(t)`` (``shared/docs/algorithms.md`` §4,
eq. (59)-(60) for O-RLS, the same matrices for every estimator). python-control's ``place`` /
``acker`` are general but cost tens to hundreds of microseconds per call, so the hot path uses
Ackermann's formula in plain numpy:

    K = e_m^T  Ctrb(A, b)^{-1}  phi_d(A),      Ctrb = [b, A b, ..., A^{m-1} b],

with ``phi_d(z) = z^m + alpha_1 z^{m-1} + ... + alpha_m`` the desired characteristic polynomial,
so that ``eig(A - b K)`` are the desired poles.  Two things keep it cheap and honest:

* ``phi_d(A)`` is never formed: with the row ``w^T = e_m^T Ctrb^{-1}`` the gain is
  ``K = sum_k alpha_{m-k} w^T A^k``, i.e. ``m`` row-vector/matrix products (``O(m^3)`` in all,
  against ``O(m^4)`` for Horner on matrices; ``m = n + 1 <= 5`` on the benchmark plants).
* one inverse of the column-normalised controllability matrix gives both the solve and a
  reciprocal (1-norm) condition number; a model whose ``rcond`` falls below a threshold is
  reported as (nearly) uncontrollable instead of returning a huge, meaningless gain.

The module also builds the integral-action augmentation used for offset-free tracking and the
steady-state (feed-forward) solution of a model.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "UncontrollableError",
    "check_poles",
    "characteristic_coefficients",
    "controllability_matrix",
    "ackermann",
    "place_poles",
    "augment_integral",
    "steady_state_gains",
]


class UncontrollableError(np.linalg.LinAlgError):
    """Raised when ``(A, b)`` is uncontrollable or too close to it for a meaningful gain."""


def check_poles(poles: ArrayLike, m: int, *, name: str = "poles") -> NDArray:
    """Validate desired closed-loop poles and return them as a complex array of length ``m``.

    Parameters
    ----------
    poles
        A scalar (every pole at that location) or a sequence of exactly ``m`` numbers, real or
        complex. Complex poles must come in conjugate pairs so that the gain is real.
    m
        Number of poles the design needs (``n``, or ``n + 1`` with integral action).
    name
        Name used in error messages.

    Raises
    ------
    ValueError
        Wrong count, non-finite values, a pole on or outside the unit circle (the design would
        not be stable), or complex poles without their conjugates.
    """
    try:
        arr = np.asarray(poles, dtype=complex)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"{name} must be a number or a sequence of numbers, got {poles!r}"
        ) from exc
    if arr.ndim == 0:
        arr = np.full(m, arr.item(), dtype=complex)
    if arr.ndim != 1 or arr.size != m:
        raise ValueError(
            f"{name} must be a scalar or have exactly {m} entries (the closed-loop order), "
            f"got shape {np.shape(poles)}"
        )
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr}")
    if np.any(np.abs(arr) >= 1.0):
        raise ValueError(
            f"{name} must lie strictly inside the unit circle (|p| < 1) for a stable discrete-time "
            f"closed loop, got moduli {np.round(np.abs(arr), 6)}"
        )
    if not np.allclose(np.sort_complex(arr), np.sort_complex(arr.conj()), atol=1e-9):
        raise ValueError(f"complex {name} must come in conjugate pairs, got {arr}")
    return arr


def characteristic_coefficients(poles: ArrayLike) -> NDArray:
    """Real coefficients ``[alpha_1, ..., alpha_m]`` of ``prod (z - p_i)`` (leading 1 dropped)."""
    c = np.poly(np.asarray(poles, dtype=complex))
    return np.ascontiguousarray(np.real(c[1:]), dtype=float)


def controllability_matrix(A: NDArray, b: NDArray) -> NDArray:
    """``[b, A b, ..., A^{m-1} b]`` by repeated matrix-vector products."""
    m = A.shape[0]
    C = np.empty((m, m))
    v = np.asarray(b, dtype=float).reshape(m)
    for k in range(m):
        C[:, k] = v
        v = A @ v
    return C


def ackermann(
    A: NDArray, b: NDArray, alpha: NDArray, *, rcond_min: float = 0.0
) -> tuple[NDArray, float]:
    """State-feedback gain ``K`` (1-D, length ``m``) with ``eig(A - b K)`` = roots of ``alpha``.

    Parameters
    ----------
    A, b
        ``m x m`` system matrix and input vector (any state coordinates).
    alpha
        ``[alpha_1, ..., alpha_m]``, the desired monic characteristic polynomial without its
        leading one (see :func:`characteristic_coefficients`).
    rcond_min
        Reject the model when the reciprocal 1-norm condition number of the column-normalised
        controllability matrix is below this value. Normalising the columns makes the test
        insensitive to the size of ``b`` and to the decay of ``A^k b``; what remains measures how
        close the Krylov directions are to linear dependence, i.e. to a pole/zero cancellation.

    Returns
    -------
    K, rcond
        The gain and the reciprocal condition number that was tested.

    Raises
    ------
    UncontrollableError
        ``rcond < rcond_min`` or the controllability matrix is exactly singular / non-finite.
    """
    m = A.shape[0]
    C = controllability_matrix(A, b)
    norms = np.sqrt(np.einsum("ij,ij->j", C, C))
    if not np.all(np.isfinite(norms)) or np.any(norms == 0.0):
        raise UncontrollableError("controllability matrix has a zero or non-finite column")
    Cn = C / norms
    try:
        Cinv = np.linalg.inv(Cn)
    except np.linalg.LinAlgError as exc:
        raise UncontrollableError("controllability matrix is singular") from exc
    # 1-norm reciprocal condition number (within a factor m of the 2-norm one, far cheaper
    # than an SVD in the per-step loop).
    rcond = float(1.0 / (np.abs(Cn).sum(axis=0).max() * np.abs(Cinv).sum(axis=0).max()))
    if not rcond > max(rcond_min, 1e-14):
        raise UncontrollableError(
            f"(A, b) is (nearly) uncontrollable: rcond of the controllability matrix {rcond:.3g}"
        )
    # w^T = e_m^T Ctrb^{-1} = e_m^T diag(1/norms) Cn^{-1}: the last row of Cn^{-1}, scaled.
    w = Cinv[m - 1] / norms[m - 1]
    # K = w^T phi_d(A) = sum_{k=0}^{m} alpha_{m-k} w^T A^k  (alpha_0 = 1).
    K = alpha[m - 1] * w
    v = w
    for k in range(1, m + 1):
        v = v @ A
        K = K + (alpha[m - 1 - k] if k < m else 1.0) * v
    return K, rcond


def place_poles(A: ArrayLike, b: ArrayLike, poles: ArrayLike, *, rcond_min: float = 0.0) -> NDArray:
    """Convenience wrapper: validate ``poles`` and return the Ackermann gain ``K`` (1-D).

    Equivalent to ``control.acker(A, b, poles)`` (and to ``control.place`` for distinct poles),
    but closed-form numpy; raises :class:`UncontrollableError` for an uncontrollable pair.
    """
    A = np.asarray(A, dtype=float)
    if A.ndim != 2 or A.shape[0] != A.shape[1]:
        raise ValueError(f"A must be square, got shape {A.shape}")
    m = A.shape[0]
    b = np.asarray(b, dtype=float).reshape(-1)
    if b.size != m:
        raise ValueError(f"b must have {m} entries (single input), got {b.size}")
    p = check_poles(poles, m)
    K, _ = ackermann(A, b, characteristic_coefficients(p), rcond_min=rcond_min)
    return K


def augment_integral(A: NDArray, b: NDArray) -> tuple[NDArray, NDArray]:
    """Model augmented with the integral of the tracking error, for ``c = [1, 0, ..., 0]``.

    ``xi(t+1) = xi(t) + r(t) - y(t)`` with ``y = c x``, so ``z = [x; xi]`` obeys
    ``z(t+1) = [[A, 0], [-c, 1]] z(t) + [b; 0] u(t) + [0; 1] r(t)``. Placing the ``n + 1``
    eigenvalues of ``A_aug - b_aug K_aug`` gives zero steady-state error to constant references
    (and input disturbances) whatever the model error, as long as the true loop stays stable.
    """
    n = A.shape[0]
    Aa = np.zeros((n + 1, n + 1))
    Aa[:n, :n] = A
    Aa[n, 0] = -1.0
    Aa[n, n] = 1.0
    ba = np.zeros(n + 1)
    ba[:n] = b
    return Aa, ba


def steady_state_gains(A: NDArray, b: NDArray) -> tuple[NDArray, float, float]:
    """Steady state of ``x = A x + b u``, ``y = x_1`` for a unit output: ``x_ss``, ``u_ss``.

    Solves the Rosenbrock system ``[[A - I, b], [c, 0]] [x_ss; u_ss] = [0; 1]``, which is regular
    exactly when the model has no zero at ``z = 1`` and no pole/zero cancellation there; unlike
    ``u_ss = 1 / G(1)`` it also works for plants with an integrator (``A`` with eigenvalue 1).

    Returns
    -------
    x_ss, u_ss, rcond
        Steady state per unit reference and the reciprocal 1-norm condition estimate of the
        Rosenbrock matrix (small means the DC gain is nearly zero: no feed-forward possible).
    """
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = A - np.eye(n)
    M[:n, n] = b
    M[n, 0] = 1.0
    try:
        Minv = np.linalg.inv(M)
    except np.linalg.LinAlgError:
        return np.zeros(n), 0.0, 0.0
    if not np.all(np.isfinite(Minv)):
        return np.zeros(n), 0.0, 0.0
    sol = Minv[:, n]  # = Minv @ [0, ..., 0, 1]
    rcond = float(1.0 / (np.abs(M).sum(axis=0).max() * np.abs(Minv).sum(axis=0).max()))
    return sol[:n].copy(), float(sol[n]), rcond
