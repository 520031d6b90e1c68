"""Certainty-equivalence design for single-input models: the numpy face of the lane functions.

The self-tuning regulator re-designs its state feedback at every step on the estimated model
``(A_hat(t), b_hat(t))`` built from ``theta_hat(t)`` (Ding & Ma 2014, eq. (59)-(60) for O-RLS,
the same matrices for every estimator). The algorithms live once, as compiled lane functions in
:mod:`.pole_placement`, :mod:`.lq` and :mod:`.safe_set`; this module validates numpy input,
calls them, and turns their status codes into exceptions:

* :func:`ackermann` / :func:`place_poles`: Ackermann's formula

      K = e_m^T  Ctrb(A, b)^{-1}  phi_d(A),      Ctrb = [b, A b, ..., A^{m-1} b],

  with ``phi_d`` the desired characteristic polynomial, so that ``eig(A - b K)`` are the desired
  poles. ``phi_d(A)`` is never formed (``K = sum_k alpha_{m-k} w^T A^k`` with ``w^T`` the last
  row of ``Ctrb^{-1}``), and one inverse of the column-normalised controllability matrix gives
  both the solve and a reciprocal (1-norm) condition number; a model whose ``rcond`` falls
  below a threshold is reported as (nearly) uncontrollable instead of returning a huge,
  meaningless gain. Equivalent to python-control's ``acker`` (and ``place`` for distinct poles).
* :func:`lq_gain`: the infinite-horizon LQ gain and stabilising Riccati solution (python-control's
  ``dlqr`` / ``dare`` for a single input), by structured doubling.
* :func:`augment_integral`, :func:`steady_state_gains`: the integral-action augmentation used
  for offset-free tracking and the steady-state (feed-forward) solution of a model.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.control import pole_placement, safe_set
from stcgym.adaptive.kernels import canonical as _canonical
from stcgym.adaptive.multivariable import mimo_lq as _mimo_lq
from stcgym.adaptive.multivariable.lqr import lq_failure_reason
from stcgym.lanes.validation import finite_vector, matrix, positive, square_matrix

__all__ = [
    "UncontrollableError",
    "check_poles",
    "characteristic_coefficients",
    "controllability_matrix",
    "ackermann",
    "lq_gain",
    "place_poles",
    "augment_integral",
    "steady_state_gains",
]


class UncontrollableError(np.linalg.LinAlgError):
    """Raised when ``(A, b)`` is uncontrollable or too close to it for a meaningful gain.

    A subclass of :class:`numpy.linalg.LinAlgError`, raised by :func:`ackermann`,
    :func:`place_poles` and :func:`lq_gain`; the message gives the reciprocal condition number
    or the Riccati solver's status.

    Parameters
    ----------
    *args
        The message, as for any exception.

    Examples
    --------
    Two identical integrators driven by the same input cannot be placed independently:

    >>> import numpy as np
    >>> from stcgym.adaptive import UncontrollableError, place_poles
    >>> try:
    ...     place_poles(np.eye(2), [1.0, 1.0], 0.5)
    ... except UncontrollableError as exc:
    ...     print(exc)
    (A, b) is (nearly) uncontrollable: rcond of the controllability matrix 0
    """


def _single_input_model(A: ArrayLike, b: ArrayLike) -> tuple[NDArray, NDArray]:
    """``(A, b)`` as a finite square ``m x m`` matrix and a finite vector of length ``m``.

    The compiled loops index ``A`` by ``b``'s length, so a non-square ``A`` must stop here.
    """
    A = square_matrix(A, "A")
    m = A.shape[0]
    b = finite_vector(np.reshape(b, -1), "b", length=m)
    return A, b


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
    A: ArrayLike, b: ArrayLike, alpha: ArrayLike, *, rcond_min: float = 0.0
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
    ValueError
        ``A`` not a finite square matrix, ``b`` or ``alpha`` not finite of length ``m``.
    UncontrollableError
        ``rcond < rcond_min`` or the controllability matrix is exactly singular / non-finite.

    Examples
    --------
    Both poles of a second-order model at ``z = 0.5``, ``phi_d(z) = z^2 - z + 0.25``:

    >>> import numpy as np
    >>> from stcgym.adaptive import ackermann
    >>> A = np.array([[1.5, 1.0], [-0.7, 0.0]])
    >>> b = np.array([1.0, 0.5])
    >>> K, rcond = ackermann(A, b, [-1.0, 0.25])
    >>> np.round(K, 4), round(rcond, 4)
    (array([0.2941, 0.4118]), 0.291)
    >>> np.round(np.linalg.eigvals(A - np.outer(b, K)), 6)
    array([0.5, 0.5])
    """
    A, b = _single_input_model(A, b)
    m = A.shape[0]
    alpha = finite_vector(np.reshape(alpha, -1), "alpha", length=m)
    K = np.zeros(m)
    rcond = float(pole_placement.ackermann_gain(A, b, alpha, K, safe_set.design_work(m, False), 0))
    if not rcond > max(rcond_min, safe_set.RCOND_FLOOR):
        raise UncontrollableError(
            f"(A, b) is (nearly) uncontrollable: rcond of the controllability matrix {rcond:.3g}"
        )
    return K, rcond


def place_poles(A: ArrayLike, b: ArrayLike, poles: ArrayLike, *, rcond_min: float = 0.0) -> NDArray:
    """Validate ``poles`` and return the Ackermann gain ``K`` (1-D) with ``eig(A - b K) = poles``.

    Equivalent to ``control.acker(A, b, poles)`` (and to ``control.place`` for distinct poles),
    closed-form (the lane function :func:`stcgym.adaptive.control.pole_placement.ackermann_gain`).

    Parameters
    ----------
    A : array_like, shape (m, m)
        Finite system matrix.
    b : array_like, shape (m,) or (m, 1)
        Finite input vector.
    poles : complex or array_like of m complex
        Desired closed-loop poles, strictly inside the unit circle; a scalar puts every pole
        there; complex poles in conjugate pairs (see :func:`check_poles`).
    rcond_min : float, default 0.0
        Reject the model below this reciprocal condition number (see :func:`ackermann`).

    Returns
    -------
    K : ndarray, shape (m,)
        The state-feedback gain of ``u = -K x``.

    Raises
    ------
    ValueError
        Malformed ``A``, ``b`` or ``poles`` (see :func:`check_poles`).
    UncontrollableError
        ``(A, b)`` uncontrollable or too close to it.

    Examples
    --------
    >>> import numpy as np
    >>> from stcgym.adaptive import place_poles
    >>> A = np.array([[1.5, 1.0], [-0.7, 0.0]])
    >>> b = np.array([1.0, 0.5])
    >>> K = place_poles(A, b, [0.4, 0.6])
    >>> np.sort(np.round(np.linalg.eigvals(A - np.outer(b, K)), 6))
    array([0.4, 0.6])
    """
    A, b = _single_input_model(A, b)
    p = check_poles(poles, A.shape[0])
    K, _ = ackermann(A, b, characteristic_coefficients(p), rcond_min=rcond_min)
    return K


def augment_integral(A: ArrayLike, b: ArrayLike) -> tuple[NDArray, NDArray]:
    """Model augmented with the integral of the tracking error, for ``c = [1, 0, ..., 0]``.

    ``xi(t+1) = xi(t) + r(t) - y(t)`` with ``y = c x``, so ``z = [x; xi]`` obeys
    ``z(t+1) = [[A, 0], [-c, 1]] z(t) + [b; 0] u(t) + [0; 1] r(t)``. Placing the ``n + 1``
    eigenvalues of ``A_aug - b_aug K_aug`` gives zero steady-state error to constant references
    (and input disturbances) whatever the model error, as long as the true loop stays stable.

    Parameters
    ----------
    A : array_like, shape (n, n)
        Finite system matrix.
    b : array_like, shape (n,) or (n, 1)
        Finite input vector.

    Returns
    -------
    A_aug : ndarray, shape (n + 1, n + 1)
        ``[[A, 0], [-c, 1]]``.
    b_aug : ndarray, shape (n + 1,)
        ``[b; 0]``.

    Raises
    ------
    ValueError
        ``A`` not a finite square matrix or ``b`` not finite of length ``n``.

    Examples
    --------
    >>> import numpy as np
    >>> from stcgym.adaptive import augment_integral
    >>> A_aug, b_aug = augment_integral([[1.5, 1.0], [-0.7, 0.0]], [1.0, 0.5])
    >>> A_aug
    array([[ 1.5,  1. ,  0. ],
           [-0.7,  0. ,  0. ],
           [-1. ,  0. ,  1. ]])
    >>> b_aug
    array([1. , 0.5, 0. ])
    """
    A, b = _single_input_model(A, b)
    n = A.shape[0]
    Aa = np.empty((n + 1, n + 1))
    ba = np.empty(n + 1)
    _canonical.augment_integral(np.ascontiguousarray(A), np.ascontiguousarray(b), True, Aa, ba)
    return Aa, ba


def steady_state_gains(A: ArrayLike, b: ArrayLike) -> tuple[NDArray, float, float]:
    """Steady state of ``x = A x + b u``, ``y = x_1`` for a unit output: ``x_ss``, ``u_ss``.

    Solves the Rosenbrock system ``[[A - I, b], [c, 0]] [x_ss; u_ss] = [0; 1]``, which is regular
    exactly when the model has no zero at ``z = 1`` and no pole/zero cancellation there; unlike
    ``u_ss = 1 / G(1)`` it also works for plants with an integrator (``A`` with eigenvalue 1).

    Returns
    -------
    x_ss, u_ss, rcond
        Steady state per unit reference and the reciprocal 1-norm condition estimate of the
        Rosenbrock matrix (small means the DC gain is nearly zero: no feed-forward possible).

    Raises
    ------
    ValueError
        ``A`` not a finite square matrix or ``b`` not finite of length ``n``.
    """
    A, b = _single_input_model(A, b)
    n = A.shape[0]
    work = safe_set.design_work(n, False)
    u_ss, rcond = safe_set.steady_state(A, b, work, 0)
    return work.x_ss[0].copy(), float(u_ss), float(rcond)


def lq_gain(
    A: ArrayLike,
    b: ArrayLike,
    Q: ArrayLike,
    R: float,
    *,
    tol: float = 1e-12,
    max_iter: int = 64,
) -> tuple[NDArray, NDArray]:
    """Infinite-horizon LQ state feedback of the single-input pair ``(A, b)``.

    Minimises ``sum x^T Q x + R u^2`` with ``u = -K x``: ``K = (R + b^T P b)^{-1} b^T P A`` with
    ``P`` the stabilising solution of the discrete algebraic Riccati equation, computed by
    :func:`stcgym.adaptive.multivariable.mimo_lq.dare_solve` (structure-preserving doubling, with
    Newton's method where ``Q`` leaves an unstable mode unweighted; the solve of
    :class:`~stcgym.adaptive.LQRController`). Equivalent to ``control.dlqr(A, b, Q, R)[:2]``
    for every positive semidefinite ``Q`` for which the stabilising solution exists: ``(A, b)``
    stabilisable and no mode on the unit circle unobservable through ``Q``.

    Parameters
    ----------
    A : array_like, shape (m, m)
        Finite system matrix.
    b : array_like, shape (m,) or (m, 1)
        Finite input vector.
    Q : array_like, shape (m, m)
        State weight, symmetric positive semidefinite.
    R : float
        Input weight, ``> 0``.
    tol : float, default 1e-12
        Relative convergence tolerance of the doubling (and Newton) iteration.
    max_iter : int, default 64
        Most doubling (and Newton) steps.

    Returns
    -------
    K, P
        The gain (1-D, length ``m``) and the Riccati solution (``m x m``).

    Raises
    ------
    ValueError
        Malformed ``A``, ``b``, ``Q`` (not square / symmetric positive semidefinite / finite) or
        ``R <= 0``.
    UncontrollableError
        No stabilising solution, the message naming the cause: ``(A, b)`` not stabilisable
        (with the modes no input reaches), or a mode on the unit circle unobservable through
        ``Q``; or no convergence.

    Examples
    --------
    The output-only weight ``Q = c^T c`` of the envs' cost with ``R = 0.01``:

    >>> import numpy as np
    >>> from stcgym.adaptive import lq_gain
    >>> A = np.array([[1.5, 1.0], [-0.7, 0.0]])
    >>> b = np.array([1.0, 0.5])
    >>> K, P = lq_gain(A, b, np.diag([1.0, 0.0]), 0.01)
    >>> np.round(K, 4)
    array([1.4471, 0.9773])
    >>> bool(np.all(np.abs(np.linalg.eigvals(A - np.outer(b, K))) < 1))
    True
    """
    A, b = _single_input_model(A, b)
    m = A.shape[0]
    Q = matrix(Q, "Q", (m, m))
    if not np.allclose(Q, Q.T) or np.linalg.eigvalsh(0.5 * (Q + Q.T)).min() < -1e-12 * max(
        1.0, np.abs(Q).max()
    ):
        raise ValueError("Q must be symmetric positive semidefinite")
    R = positive(R, "R (input weight)")
    B = np.ascontiguousarray(b.reshape(m, 1))
    R_mat, N = np.array([[R]]), np.zeros((m, 1))
    Q = np.ascontiguousarray(Q, dtype=float)
    P = np.zeros((m, m))
    K = np.zeros((1, m))
    work = _mimo_lq.mimo_design_work(m, 1)
    problem = _mimo_lq.LQProblem(Q, R_mat, N, float(tol), int(max_iter))
    status = _mimo_lq.dare_solve(A, B, problem, P, K, work, 0)
    if status != safe_set.OK:
        raise UncontrollableError(
            "no stabilising LQ solution: " + lq_failure_reason(A, B, Q, R_mat, N, status)
        )
    return K[0].copy(), P
