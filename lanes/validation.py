"""Argument checks shared by every stcgym module: each names the argument and the expected form.

A public function validates its input with these before it changes any state, so a bad call
leaves everything as it was. The convention:

* a scalar that is not a real number at all (text, ``None``, a sequence, a bool) is a
  :class:`TypeError`; a real number out of range or not finite is a :class:`ValueError`;
* an integer argument rejects every non-integer (bool and ``2.0`` included) with a
  :class:`ValueError` saying ``"<name> must be an integer >= <minimum>"``; a setting in an
  interval (:func:`real_in`, :func:`forgetting_factor`) rejects anything else the same way;
* an array argument (ragged, complex, text, wrong shape, not finite) is a :class:`ValueError`.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "integer",
    "integer_range",
    "real_number",
    "real_in",
    "non_negative",
    "positive",
    "forgetting_factor",
    "flag",
    "one_of",
    "real_array",
    "finite_array",
    "finite_vector",
    "vector_pair",
    "matrix",
    "square_matrix",
    "covariance",
    "lane_indices",
    "lane_vector",
]


# ----------------------------------------------------------------------------------- scalars
def integer(value: Any, name: str, minimum: int = 1) -> int:
    """``value`` as an ``int >= minimum`` (Python or numpy integer; bools and floats rejected)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def integer_range(value: Any, name: str, minimum: int = 1) -> tuple[int, int]:
    """``value`` as ``(low, high)``: a pair ``[low, high]`` of integers ``>= minimum`` with
    ``low <= high``, or one integer ``v`` meaning ``(v, v)``."""
    if isinstance(value, (list, tuple, np.ndarray)):
        if len(value) != 2:
            raise ValueError(
                f"{name} must be an integer >= {minimum} or a range [low, high] of them, "
                f"got {value!r}"
            )
        low, high = (integer(v, name, minimum) for v in value)
        if low > high:
            raise ValueError(f"{name} must be a range [low, high] with low <= high, got {value!r}")
        return low, high
    v = integer(value, name, minimum)
    return v, v


def _real(value: Any, name: str) -> float:
    """``value`` as a float (possibly not finite); a :class:`TypeError` if not a real number."""
    kind = type(value)
    if kind is not float and kind is not np.float64 and kind is not int:  # not the common case
        if kind is np.ndarray and value.shape == ():
            value = value[()]
        if isinstance(value, (str, bytes, bool, np.bool_)) or not isinstance(value, numbers.Real):
            raise TypeError(f"{name} must be a finite real number, got {value!r}")
    try:
        return float(value)
    except OverflowError:  # an integer beyond the float range
        return math.nan


def real_number(value: Any, name: str) -> float:
    """``value`` as a finite float: a Python or numpy real number, or a 0-d array of one.

    Raises
    ------
    TypeError
        Not a real number (text, bool, ``None``, a sequence, a complex number).
    ValueError
        Not finite (NaN, inf, an integer beyond the float range).
    """
    v = _real(value, name)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be a finite real number, got {value!r}")
    return v


def real_in(
    value: Any,
    name: str,
    lo: float = -math.inf,
    hi: float = math.inf,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
) -> float:
    """A setting: a real number in the interval from ``lo`` to ``hi`` (ends closed unless open).

    ``math.inf`` passes only where the interval is ``[.., inf]`` (a setting that ``inf``
    switches off); NaN never passes. Like :func:`integer`, anything else, a value of the wrong
    kind included, is a ``ValueError``: ``"<name> must lie in (lo, hi], got ..."``.
    """
    try:
        v = _real(value, name)
    except TypeError:
        v = math.nan
    ok = math.isfinite(v) or (v == math.inf and hi == math.inf and not hi_open)
    if not (ok and (v > lo if lo_open else v >= lo) and (v < hi if hi_open else v <= hi)):
        interval = f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
        raise ValueError(f"{name} must lie in {interval}, got {value!r}")
    return v


def forgetting_factor(value: Any, name: str = "forgetting") -> float:
    """A forgetting factor ``lambda`` in ``(0, 1]`` (see :func:`real_in`)."""
    return real_in(value, name, 0.0, 1.0, lo_open=True)


def non_negative(value: Any, name: str) -> float:
    """A finite real number ``>= 0`` (see :func:`real_number` for the exception types)."""
    v = real_number(value, name)
    if v < 0.0:
        raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
    return v


def positive(value: Any, name: str) -> float:
    """A finite real number ``> 0`` (see :func:`real_number` for the exception types)."""
    v = real_number(value, name)
    if v <= 0.0:
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return v


def flag(value: Any, name: str) -> bool:
    """A switch: a Python or numpy bool (not ``0``/``1``), else a ``ValueError`` naming ``name``."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be a bool, got {value!r}")
    return bool(value)


def one_of(value: Any, name: str, choices: tuple[str, ...]) -> str:
    """``value`` if it is one of the strings ``choices``, else a ``ValueError`` naming ``name``
    and the choices."""
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"{name} must be one of {choices}, got {value!r}")
    return value


# ------------------------------------------------------------------------------------ arrays
def real_array(value: ArrayLike, name: str) -> NDArray:
    """``value`` as a float64 array (any shape, possibly not finite).

    A ``ValueError`` naming ``name`` for ragged nesting, text, objects or complex numbers
    (numpy would drop an imaginary part with only a warning).
    """
    try:
        raw = np.asarray(value)
    except (TypeError, ValueError, OverflowError) as exc:  # ragged nested sequences
        raise ValueError(f"{name} must be a rectangular array of real numbers") from exc
    if raw.dtype.kind == "c":
        raise ValueError(f"{name} must be real, got complex values {value!r}")
    if raw.dtype.kind not in "biuf":
        raise ValueError(f"{name} must be an array of real numbers, got {value!r}")
    return raw.astype(float)


def finite_array(value: ArrayLike, name: str) -> NDArray:
    """:func:`real_array` whose every entry is finite (a new array: the caller may keep it)."""
    arr = real_array(value, name)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite (no NaN or inf)")
    return arr


def finite_vector(value: ArrayLike, name: str, *, length: int | None = None) -> NDArray:
    """A non-empty 1-D finite float array (a scalar becomes length 1), of ``length`` if given."""
    arr = np.atleast_1d(real_array(value, name))
    if arr.ndim != 1:
        raise ValueError(f"{name} must be one-dimensional, got shape {arr.shape}")
    if arr.size == 0:
        raise ValueError(f"{name} must not be empty")
    if length is not None and arr.size != length:
        raise ValueError(f"{name} must have length {length}, got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr}")
    return arr


def vector_pair(
    first: ArrayLike, second: ArrayLike, names: tuple[str, str], meaning: str = ""
) -> tuple[NDArray, NDArray]:
    """Two :func:`finite_vector` s of the same length (``meaning`` says what pairs them)."""
    x = finite_vector(first, names[0])
    y = finite_vector(second, names[1])
    if x.size != y.size:
        raise ValueError(
            f"{names[0]} and {names[1]} must have the same length{meaning}, got "
            f"len({names[0]})={x.size}, len({names[1]})={y.size}"
        )
    return x, y


def matrix(value: ArrayLike, name: str, shape: tuple[int | None, int | None]) -> NDArray:
    """A 2-D finite, C-contiguous float matrix of ``shape`` (``None``: any size, at least 1).

    A 1-D ``value`` is read as a column when ``shape`` asks for one column.
    """
    arr = real_array(value, name)
    if arr.ndim == 1 and shape[1] == 1:
        arr = arr.reshape(-1, 1)
    if arr.ndim != 2:
        raise ValueError(f"{name} must be a 2-D matrix, got shape {arr.shape}")
    expected = "(" + ", ".join("any" if w is None else str(w) for w in shape) + ")"
    for got, want, what in zip(arr.shape, shape, ("rows", "columns"), strict=True):
        if want is not None and got != want:
            raise ValueError(f"{name} must have {want} {what} (shape {expected}), got {arr.shape}")
        if want is None and got == 0:
            raise ValueError(f"{name} must have at least one of its {what}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return np.ascontiguousarray(arr)


def square_matrix(value: ArrayLike, name: str) -> NDArray:
    """A non-empty, finite, square float matrix (C-contiguous)."""
    arr = real_array(value, name)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1] or arr.shape[0] == 0:
        raise ValueError(f"{name} must be a non-empty square matrix, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return np.ascontiguousarray(arr)


def covariance(value: Any, dim: int, name: str, *, allow_singular: bool = False) -> NDArray:
    """A ``dim x dim`` covariance from a scalar, a vector (its diagonal) or a matrix.

    The matrix must be symmetric (to ``1e-12`` of its largest entry; the result is its
    symmetric part) and positive definite (semidefinite with ``allow_singular``); a scalar or
    vector must be positive (``>= 0`` with ``allow_singular``). Else a ``ValueError`` naming
    ``name`` and the expected form.
    """
    semi = "semi" if allow_singular else ""
    expected = (
        f"{name} must be a positive {'or zero ' if allow_singular else ''}scalar, a vector of "
        f"length {dim} or a symmetric positive {semi}definite {dim}x{dim} matrix"
    )
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{expected}, got {value!r}") from exc
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{expected}; it is not finite: {value!r}")
    if arr.ndim == 0 or (arr.ndim == 1 and arr.size == dim):
        diag = np.broadcast_to(arr, (dim,))
        if np.any(diag < 0) or (not allow_singular and np.any(diag <= 0)):
            raise ValueError(f"{expected}, got {value!r}")
        return np.diag(diag).astype(float)
    if arr.shape != (dim, dim):
        raise ValueError(f"{expected}, got shape {arr.shape}")
    scale = max(float(np.abs(arr).max()), 1e-300)
    if not np.allclose(arr, arr.T, rtol=0.0, atol=1e-12 * scale):
        raise ValueError(f"{expected}; it is not symmetric")
    M = 0.5 * (arr + arr.T)
    lam_min = float(np.linalg.eigvalsh(M).min())
    if lam_min < -1e-12 * scale or (not allow_singular and lam_min <= 0.0):
        raise ValueError(f"{expected}; its smallest eigenvalue is {lam_min:g}")
    return M


# ------------------------------------------------------------------------------------- lanes
def lane_indices(lanes: Any, B: int, name: str = "lanes") -> NDArray:
    """The selected lanes of a batch of ``B`` as ``int64`` indices.

    ``lanes``: ``None`` (all), integer indices in ``[0, B)`` or a boolean mask of length ``B``.
    """
    if lanes is None:
        return np.arange(B)
    arr = np.asarray(lanes)
    if arr.dtype == bool:
        if arr.shape != (B,):
            raise ValueError(
                f"{name} as a boolean mask must have shape ({B},) (one flag per lane), got "
                f"shape {arr.shape}"
            )
        return np.flatnonzero(arr)
    arr = np.atleast_1d(arr)
    if arr.ndim != 1 or (arr.size and not np.issubdtype(arr.dtype, np.integer)):
        raise ValueError(
            f"{name} must be lane indices (integers in [0, {B})) or a boolean mask of length "
            f"{B}, got {lanes!r}"
        )
    if arr.size and (arr.min() < 0 or arr.max() >= B):
        raise ValueError(f"{name} must be integers in [0, {B}), got {arr.tolist()}")
    return arr.astype(np.int64)


def lane_vector(value: Any, B: int, name: str) -> NDArray:
    """A finite float vector of one value per lane, shape ``(B,)`` (a scalar is broadcast)."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric (one value per lane), got {value!r}") from exc
    if arr.ndim == 0:
        arr = np.full(B, float(arr))
    if arr.ndim == 2 and arr.shape[1] == 1:
        arr = arr[:, 0]
    if arr.shape != (B,):
        raise ValueError(f"{name} must have shape ({B},) (one value per lane), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = np.flatnonzero(~np.isfinite(arr))[:5]
        raise ValueError(f"{name} must be finite; lanes {bad.tolist()} are not")
    return arr
