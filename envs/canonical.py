"""Canonical state-space forms of a SISO plant with parameter vector ``theta = [a; b]``.

Both forms of the seed paper (Ding & Ma 2014, sections 2 and 6) share
``theta = [a1..an, b1..bn]`` and the output row ``c = [1, 0, ..., 0]``:

* observer canonical form, eq. (1)-(5): ``A`` has ``-a`` in its first column and an identity
  above the diagonal; its transfer function is
  ``(b1 z^{n-1} + ... + bn) / (z^n + a1 z^{n-1} + ... + an)``;
* observability canonical form, eq. (146)-(147): ``A`` is a shift with last row
  ``[-a_n, ..., -a_1]``; here ``b1..bn`` are the first ``n`` Markov parameters (impulse
  response samples) rather than the numerator coefficients.

The helpers validate their input and never return non-finite matrices.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.lanes.validation import finite_vector as as_finite_vector
from stcgym.lanes.validation import vector_pair

Form = Literal["observer", "observability"]
FORMS: tuple[str, ...] = ("observer", "observability")


def check_form(form: str) -> str:
    """Return the canonical-form name in lower case or raise ``ValueError``."""
    f = str(form).lower()
    if f not in FORMS:
        raise ValueError(f"form must be one of {FORMS}, got {form!r}")
    return f


def split_theta(theta: ArrayLike) -> tuple[NDArray, NDArray]:
    """Split ``theta = [a; b]`` (length ``2n``) into ``a`` and ``b``."""
    th = as_finite_vector(theta, "theta")
    if th.size % 2:
        raise ValueError(f"theta must have even length 2n (theta = [a; b]), got {th.size}")
    n = th.size // 2
    return th[:n].copy(), th[n:].copy()


def check_ab(a: ArrayLike, b: ArrayLike) -> tuple[NDArray, NDArray]:
    """Validate the parameter pair ``(a, b)``: finite, non-empty, equal lengths ``n``."""
    return vector_pair(a, b, ("a", "b"), " n (theta = [a1..an, b1..bn])")


def companion_A(a: NDArray, form: str = "observer") -> NDArray:
    """System matrix ``A`` of the canonical form for the denominator coefficients ``a``.

    Observer form, eq. (1): first column ``-a``, ones on the superdiagonal.
    Observability form, eq. (146): ones on the superdiagonal, last row ``[-a_n .. -a_1]``.

    This is the numpy face used by every module outside the lane functions; compiled code
    fills the same matrix with ``stcgym.adaptive.estimation.state_estimation.companion_into`` or
    applies it without forming it (``stcgym.envs.dynamics.shift_transition``).

    Parameters
    ----------
    a : array_like, shape (n,)
        Denominator coefficients ``[a1, ..., an]`` of ``z^n + a1 z^{n-1} + ... + an``. Taken as
        given (converted to float, not checked for finiteness): :func:`canonical_matrices` is
        the validating entry point.
    form : {"observer", "observability"}, default "observer"
        The canonical form (case-insensitive).

    Returns
    -------
    A : ndarray, shape (n, n)
        A new float array.

    Raises
    ------
    ValueError
        ``form`` is not one of the two names.

    Examples
    --------
    >>> from stcgym.envs import companion_A
    >>> companion_A([-1.5, 0.7])
    array([[ 1.5,  1. ],
           [-0.7,  0. ]])
    >>> companion_A([-1.5, 0.7], form="observability")
    array([[ 0. ,  1. ],
           [-0.7,  1.5]])
    """
    a = np.asarray(a, dtype=float)
    n = a.size
    A = np.eye(n, k=1)
    if check_form(form) == "observer":
        A[:, 0] = -a
    else:
        A[-1, :] = -a[::-1]
    return A


def canonical_matrices(
    a: ArrayLike, b: ArrayLike, form: str = "observer"
) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Return ``(A, B, C, D)`` of the SISO canonical plant with parameters ``a``, ``b``.

    ``A`` is :func:`companion_A` of ``a``, ``B`` the column ``b``, ``C = [1, 0, ..., 0]`` and
    ``D = 0``: the observer canonical form of Ding & Ma (2014) eq. (1)-(2), or the
    observability canonical form eq. (146)-(147).

    Parameters
    ----------
    a, b : array_like, shape (n,)
        ``theta = [a1..an, b1..bn]``: denominator coefficients, and the numerator coefficients
        (observer form) or the first ``n`` Markov parameters (observability form). Finite,
        non-empty, equal lengths.
    form : {"observer", "observability"}, default "observer"
        The canonical form (case-insensitive).

    Returns
    -------
    A : ndarray, shape (n, n)
    B : ndarray, shape (n, 1)
    C : ndarray, shape (1, n)
    D : ndarray, shape (1, 1)
        New float arrays.

    Raises
    ------
    ValueError
        ``a`` or ``b`` empty, not finite, not one-dimensional or of different lengths (the
        message names the argument); ``form`` unknown.

    Examples
    --------
    >>> from stcgym.envs import canonical_matrices
    >>> A, B, C, D = canonical_matrices([-1.5, 0.7], [1.0, 0.5])
    >>> A
    array([[ 1.5,  1. ],
           [-0.7,  0. ]])
    >>> B.ravel(), C, D
    (array([1. , 0.5]), array([[1., 0.]]), array([[0.]]))
    """
    a_arr, b_arr = check_ab(a, b)
    n = a_arr.size
    A = companion_A(a_arr, form)
    B = b_arr.reshape(n, 1).copy()
    C = np.zeros((1, n))
    C[0, 0] = 1.0
    D = np.zeros((1, 1))
    return A, B, C, D


def transfer_function_coefficients(
    a: ArrayLike, b: ArrayLike, form: str = "observer"
) -> tuple[NDArray, NDArray]:
    """Numerator and denominator (highest power first) of ``c (zI - A)^{-1} b``.

    The denominator is ``[1, a1, ..., an]`` in both forms. In the observer form the numerator is
    ``[b1, ..., bn]`` (degree n-1). In the observability form ``b`` holds Markov parameters
    ``h_1..h_n`` and the numerator is ``beta = T b`` with ``T`` the lower-triangular Toeplitz
    matrix of ``[1, a1, ..., a_{n-1}]`` (from ``B(z) = A(z) H(z)`` truncated to its polynomial
    part).

    Parameters
    ----------
    a, b : array_like, shape (n,)
        The canonical form's parameters (finite, non-empty, equal lengths).
    form : {"observer", "observability"}, default "observer"
        The canonical form ``b`` belongs to.

    Returns
    -------
    num : ndarray, shape (n,)
        Numerator coefficients ``[beta_1, ..., beta_n]`` of ``beta_1 z^{n-1} + ... + beta_n``.
    den : ndarray, shape (n + 1,)
        Denominator coefficients ``[1, a1, ..., an]``.

    Raises
    ------
    ValueError
        As :func:`canonical_matrices`.

    See Also
    --------
    observer_to_observability_b : the inverse map of the observability form's numerator.

    Examples
    --------
    The observability form's Markov parameters ``[1, 2]`` of ``stable2`` give back its numerator:

    >>> from stcgym.envs import transfer_function_coefficients
    >>> transfer_function_coefficients([-1.5, 0.7], [1.0, 2.0], form="observability")
    (array([1. , 0.5]), array([ 1. , -1.5,  0.7]))
    """
    a_arr, b_arr = check_ab(a, b)
    den = np.concatenate(([1.0], a_arr))
    if check_form(form) == "observer":
        return b_arr.copy(), den
    n = a_arr.size
    col = np.concatenate(([1.0], a_arr[: n - 1]))
    T = np.zeros((n, n))
    for k in range(n):
        T[k:, k] = col[: n - k]
    return T @ b_arr, den


def observer_to_observability_b(a: ArrayLike, beta: ArrayLike) -> NDArray:
    """Markov parameters ``h_1..h_n`` of ``beta(z) / (z^n + a1 z^{n-1} + ...)``.

    Converts observer-form ``b`` (numerator coefficients, eq. (1)-(5)) into observability-form
    ``b`` (eq. (146)-(147)) for the same transfer function, by the recursion
    ``h_k = beta_k - sum_{i<k} a_i h_{k-i}``: the first ``n`` impulse-response samples.

    Parameters
    ----------
    a : array_like, shape (n,)
        Denominator coefficients ``[a1, ..., an]``.
    beta : array_like, shape (n,)
        Numerator coefficients ``[beta_1, ..., beta_n]`` (the observer form's ``b``).

    Returns
    -------
    ndarray, shape (n,)
        ``[h_1, ..., h_n]``.

    Raises
    ------
    ValueError
        ``a`` or ``beta`` empty, not finite or of different lengths.

    Examples
    --------
    >>> from stcgym.envs import observer_to_observability_b
    >>> observer_to_observability_b([-1.5, 0.7], [1.0, 0.5])
    array([1., 2.])
    """
    a_arr, beta_arr = check_ab(a, beta)
    n = a_arr.size
    h = np.zeros(n)
    for k in range(n):
        h[k] = beta_arr[k] - np.dot(a_arr[:k], h[:k][::-1])
    return h
