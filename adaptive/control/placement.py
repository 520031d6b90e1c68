"""Certainty-equivalence design for single-input models: pole placement and the numpy face.

The self-tuning regulator re-designs its state feedback at every step on the estimated model
``(A_hat(t), b_hat(t))`` built from ``theta_hat(t)`` (Ding & Ma 2014, eq. (59)-(60) for O-RLS,
the same matrices for every estimator). The algorithms live once, as compiled lane functions:
Ackermann's formula here (below), the LQ designs in :mod:`.lq`, the model, the safe set and the
steady state in :mod:`.safe_set`. The numpy functions validate their input, call them, and turn
their status codes into exceptions:

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

The lane functions of Ackermann's formula on the (integral-augmented) model:

``place_design(theta, cfg, gain, w, lane_i) -> int``
    Ackermann pole placement of the ``m`` poles with monic characteristic polynomial
    ``z^m + char_poly[0] z^{m-1} + ... + char_poly[m-1]`` (``cfg.char_poly``, length ``m``) on
    the (augmented) model of ``theta``; ``N = u_ss + K_x x_ss`` from the steady state. ``cfg``:
    a :class:`.safe_set.DesignConfig` (form, integral action, feed-forward, safe set); ``w`` is
    a :data:`.safe_set.DesignWork` (:func:`.safe_set.design_work`), of which lane ``lane_i`` is
    used. Returns the status code of :mod:`.safe_set`; ``gain`` is written only on success.
``ackermann_gain(A, b, char_poly, K, w, lane_i) -> rcond``
    The same formula on a general pair (``rcond <= 0``: singular; ``K`` written only when
    ``rcond > 0``; ``w`` with the fields of :class:`.safe_set.ControllabilityWork`), used by
    the numpy helpers of this module.
``place_design_lanes(thetas, cfg, gains, status, w)``
    The batch loop (``w`` a :data:`.safe_set.DesignWork` with a row a lane).

:data:`COMPILED_DESIGN` is the self-tuning controller's pole placement (its compiled argument
:class:`Placement` is empty: the poles are the controller's ``cfg.char_poly``; it keeps no lane
state).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.control import safe_set
from stcgym.adaptive.control.safe_set import OK, controllability, design_start, design_work, finish
from stcgym.adaptive.kernels import canonical as _canonical
from stcgym.adaptive.multivariable import mimo_lq as _mimo_lq
from stcgym.adaptive.multivariable.lqr import lq_failure_reason
from stcgym.adaptive.variants import CompiledDesign
from stcgym.lanes.compiled import lane, lanes
from stcgym.lanes.validation import finite_vector, matrix, positive, square_matrix

__all__ = [
    "COMPILED_DESIGN",
    "Placement",
    "UncontrollableError",
    "ackermann_gain",
    "place_design",
    "place_design_lanes",
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
    rcond = float(ackermann_gain(A, b, alpha, K, design_work(m, False), 0))
    if not rcond > max(rcond_min, safe_set.RCOND_FLOOR):
        raise UncontrollableError(
            f"(A, b) is (nearly) uncontrollable: rcond of the controllability matrix {rcond:.3g}"
        )
    return K, rcond


def place_poles(A: ArrayLike, b: ArrayLike, poles: ArrayLike, *, rcond_min: float = 0.0) -> NDArray:
    """Validate ``poles`` and return the Ackermann gain ``K`` (1-D) with ``eig(A - b K) = poles``.

    Equivalent to ``control.acker(A, b, poles)`` (and to ``control.place`` for distinct poles),
    closed-form (the lane function :func:`ackermann_gain`).

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
    work = design_work(n, False)
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
    if status != OK:
        raise UncontrollableError(
            "no stabilising LQ solution: " + lq_failure_reason(A, B, Q, R_mat, N, status)
        )
    return K[0].copy(), P


# ---- the lane functions ---------------------------------------------------------------------


@lane(inline=True)
def _ackermann_from_ctrb(A, char_poly, K, w, lane_i):
    """Ackermann's formula ``K = e_m^T Ctrb^{-1} phi_d(A)`` (Ackermann 1972; Franklin, Powell &
    Workman, *Digital Control of Dynamic Systems*, 3rd ed.) with ``phi_d(z) = z^m + c_1 z^{m-1}
    + ... + c_m`` (``c = char_poly``), as ``K = sum_k c_{m-k} v A^k`` with ``v`` the last row of
    ``Ctrb^{-1}`` (``phi_d(A)`` never formed: ``m`` row-vector/matrix products), from the
    inverse ``w.Cinv`` and column norms ``w.norms`` that :func:`.safe_set.controllability`
    left in lane ``lane_i``."""
    m = A.shape[0]
    Cinv = w.Cinv[lane_i]
    norms = w.norms[lane_i]
    v = w.v[lane_i]
    vA = w.v_next[lane_i]
    for j in range(m):  # v = e_m^T Ctrb^{-1} (the columns of Ctrb were scaled by norms)
        v[j] = Cinv[m - 1, j] / norms[m - 1]
        K[j] = char_poly[m - 1] * v[j]  # c_m v A^0
    for k in range(1, m + 1):  # + c_{m-k} v A^k, k = 1..m (c_0 = 1): K = v phi_d(A)
        coef = char_poly[m - 1 - k] if k < m else 1.0
        for j in range(m):
            acc = 0.0
            for r in range(m):
                acc += v[r] * A[r, j]
            vA[j] = acc
        for j in range(m):
            v[j] = vA[j]
            K[j] += coef * v[j]


@lane(entry=True)
def ackermann_gain(A, b, char_poly, K, w, lane_i):
    """Ackermann gain of a general pair ``(A, b)`` (``m x m``; ``w`` with the fields of
    :class:`.safe_set.ControllabilityWork` for order ``m``, lane ``lane_i`` used).

    ``eig(A - b K)`` are the roots of ``z^m + char_poly[0] z^{m-1} + ... + char_poly[m-1]``.
    Returns the reciprocal 1-norm condition of the column-normalised controllability matrix
    (``<= 0``: singular or non-finite, ``K`` untouched).
    """
    if w.C.shape[1] != A.shape[0]:
        raise ValueError("ackermann_gain: w is not the scratch of this order")
    rcond = controllability(A, b, w, lane_i)  # Ctrb = [b, A b, ..., A^{m-1} b] and its inverse
    if rcond > 0.0:
        _ackermann_from_ctrb(A, char_poly, K, w, lane_i)
    return rcond


@lane(entry=True, inline=True)
def place_design(theta, cfg, gain, w, lane_i):
    """Pole placement on the (augmented) model of ``theta``; see the module docstring.

    Returns the status code; lane ``lane_i`` of ``gain`` (a :class:`.safe_set.Gain`) is written
    only when it is ``OK`` (0).
    """
    status, rcond = design_start(theta, cfg, w, lane_i)  # model, augmentation, Ctrb^{-1}
    if status != OK:
        return status
    _ackermann_from_ctrb(w.A_aug[lane_i], cfg.char_poly, w.K[lane_i], w, lane_i)
    return finish(theta, cfg, rcond, gain, w, lane_i)  # safe set, steady state, N


@lanes(min_lanes=16)  # one design a lane
def place_design_lanes(thetas, cfg, gains, status, w, first, last):
    """:func:`place_design` for every lane (``thetas`` ``(B, 2n)``, ``gains`` a
    :class:`.safe_set.Gain` of ``B`` lanes, ``status`` ``(B,)`` int64, ``w`` a
    :data:`.safe_set.DesignWork` of ``B`` lanes)."""
    for i in range(first, last):
        status[i] = place_design(thetas[i], cfg, gains, w, i)


class Placement(NamedTuple):
    """The compiled argument of the controller's pole placement (none: the poles are the
    controller's ``cfg.char_poly``); also its lane state (it keeps none)."""


@lane(inline=True)
def controller_design(design, theta, cfg, state, gain, w, lane_i):
    """Step 3 of the self-tuning controller: :func:`place_design` (``design``, ``state``:
    empty :class:`Placement`)."""
    return place_design(theta, cfg, gain, w, lane_i)


COMPILED_DESIGN = CompiledDesign(
    argument=Placement,
    step=controller_design,
    make_argument=lambda n, law: Placement(),
    make_state=lambda n, law, num_lanes: Placement(),
    make_work=design_work,
)
