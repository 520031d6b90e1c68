"""Argument checks shared by every stcgym module: each names the argument and the expected form.

A public function validates its input with these before it changes any state, so a bad call
leaves everything as it was. The convention:

* a scalar that is not a real number at all (text, ``None``, a sequence, a bool) is a
  :class:`TypeError`; a real number out of range or not finite is a :class:`ValueError`;
* an integer argument rejects every non-integer (bool and ``2.0`` included) with a
  :class:`ValueError` saying ``"<name> must be an integer >= <minimum>"``;
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
    "real_number",
    "non_negative",
    "positive",
    "forgetting_factor",
    "real_array",
    "finite_array",
    "finite_vector",
    "vector_pair",
    "matrix",
    "square_matrix",
    "lane_indices",
    "lane_vector",
]


# ----------------------------------------------------------------------------------- scalars
def integer(value: Any, name: str, minimum: int = 1) -> int:
    """``value`` as an ``int >= minimum`` (Python or numpy integer; bools and floats rejected)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def real_number(value: Any, name: str) -> float:
    """``value`` as a finite float: a Python or numpy real number, or a 0-d array of one.

    Raises
    ------
    TypeError
        Not a real number (text, bool, ``None``, a sequence, a complex number).
    ValueError
        Not finite (NaN, inf, an integer beyond the float range).
    """
    kind = type(value)
    if kind is not float and kind is not np.float64 and kind is not int:  # not the common case
        if kind is np.ndarray and value.shape == ():
            value = value[()]
        if isinstance(value, (str, bytes, bool, np.bool_)) or not isinstance(value, numbers.Real):
            raise TypeError(f"{name} must be a finite real number, got {value!r}")
    try:
        v = float(value)
    except OverflowError as exc:
        raise ValueError(f"{name} must be a finite real number, got {value!r}") from exc
    if not math.isfinite(v):
        raise ValueError(f"{name} must be a finite real number, got {value!r}")
    return v


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


def forgetting_factor(value: Any, name: str = "forgetting") -> float:
    """A forgetting factor ``lambda`` in ``(0, 1]`` (a real number; bools rejected)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must lie in (0, 1] (a real number), got {value!r}")
    lam = float(value)
    if not 0.0 < lam <= 1.0:  # also rejects NaN
        raise ValueError(f"{name} must lie in (0, 1] (a real number), got {value!r}")
    return lam
