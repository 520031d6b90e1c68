"""Lane-record views and the no-allocation rule of lane functions (stcgym.envs.compiled)."""

from __future__ import annotations

import warnings
from typing import NamedTuple

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from lane_call import call

from stcgym.adaptive.estimation.state_estimation import is_schur_stable
from stcgym.adaptive.kernels.records import copy_matrix, copy_vector, view2d, view3d
from stcgym.envs.compiled import FixedTypes, Layout, lane


@lane(entry=True)
def _write_through_views(a, offset, count, rows, cols):
    """Write k * 1000 + i * 10 + j through view3d and read it back through view2d."""
    M = view3d(a, offset, count, rows, cols)
    for k in range(count):
        for i in range(rows):
            for j in range(cols):
                M[k, i, j] = k * 1000.0 + i * 10.0 + j
    total = 0.0
    for k in range(count):
        V = view2d(a, offset + k * rows * cols, rows, cols)
        for i in range(rows):
            for j in range(cols):
                total += V[i, j]
    return total


@settings(max_examples=30, deadline=None)
@given(
    st.integers(0, 5), st.integers(1, 3), st.integers(1, 4), st.integers(1, 4), st.integers(0, 3)
)
def test_compiled_views_are_the_numpy_reshape(offset, count, rows, cols, tail):
    size = offset + count * rows * cols + tail
    a = np.full(size, -1.0)
    total = _write_through_views(a, offset, count, rows, cols)
    expected = np.fromfunction(lambda k, i, j: k * 1000.0 + i * 10.0 + j, (count, rows, cols))
    # the compiled views wrote exactly the C-ordered block at offset, nothing around it
    np.testing.assert_array_equal(
        a[offset : offset + count * rows * cols].reshape(count, rows, cols), expected
    )
    assert np.all(a[:offset] == -1.0) and np.all(a[offset + count * rows * cols :] == -1.0)
    assert total == expected.sum()
    # the uncompiled definitions are numpy's reshape of the same block
    np.testing.assert_array_equal(view3d(a, offset, count, rows, cols), expected)


def test_copies_write_every_entry():
    src = np.arange(12.0).reshape(3, 4)
    dst = np.zeros((3, 4))
    call(copy_matrix, src, dst)
    np.testing.assert_array_equal(dst, src)
    v = np.zeros(5)
    call(copy_vector, np.arange(5.0), v)
    np.testing.assert_array_equal(v, np.arange(5.0))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-2.5, 2.5), min_size=1, max_size=6))
def test_schur_test_in_place_matches_roots(coeffs):
    a = np.array(coeffs)
    roots = np.abs(np.roots(np.r_[1.0, a]))
    if np.any(np.abs(roots - 1.0) < 1e-6):
        return  # on the unit circle: either answer is rounding
    expected = bool(np.all(roots < 1.0))
    scratch = np.empty(a.size)
    assert is_schur_stable(a, a.size, scratch) == expected
    # with the scratch being the coefficients themselves (allowed when they may be destroyed)
    assert is_schur_stable(a.copy(), a.size, a.copy()) == expected
    b = a.copy()
    assert is_schur_stable(b, b.size, b) == expected


def test_a_lane_function_that_allocates_does_not_compile():
    """Lane functions run without numba's reference counting: an allocation is a compile
    error, not a silent slowdown (``lane(allocates=True)`` is the documented opt-out)."""

    @lane(entry=True)
    def allocating(n):
        return np.zeros(n).sum()

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a typing error, never a fallback to object mode
        with pytest.raises(numba.core.errors.TypingError):
            allocating(3)

    @lane(allocates=True, entry=True)
    def allowed(n):
        return np.zeros(n).sum() + n

    assert allowed(3) == 3.0


class _Pair(NamedTuple):
    S: int
    theta: int


@lane(entry=True)
def _read_by_name(f, at, d):
    """``sum(theta) + 100 * S[d - 1, d - 1]`` read through the record's field names."""
    theta = f[at.theta : at.theta + d]
    S = view2d(f, at.S, d, d)
    acc = 0.0
    for i in range(d):
        acc += theta[i]
    return acc + 100.0 * S[d - 1, d - 1]


@pytest.mark.parametrize("base", [0, 3])
def test_named_record_reads_the_fields_the_layout_places(base):
    lay = Layout()
    lay.add("scratch", (2,))
    lay.add("theta", (3,))
    lay.add("S", (3, 3))
    at = lay.record(_Pair, base)
    assert at == _Pair(S=base + 5, theta=base + 2)
    rec = np.zeros((1, base + lay.size))
    lay.view(rec[:, base:], "theta")[0] = [1.0, 2.0, 4.0]
    lay.view(rec[:, base:], "S")[0] = np.diag([7.0, 8.0, 9.0])
    assert _read_by_name(rec[0], at, 3) == 907.0
    only_S = Layout()
    only_S.add("S", (1, 1))
    with pytest.raises(ValueError, match=r"\['theta'\] of _Pair"):
        only_S.record(_Pair)


def test_fixed_types_calls_the_same_compiled_code():
    lay = Layout()
    lay.add("theta", (2,))
    lay.add("S", (2, 2))
    at = lay.record(_Pair)
    rec = np.arange(lay.size, dtype=float)
    step = FixedTypes(_read_by_name)
    assert step.entry is None
    assert step(rec, at, 2) == _read_by_name(rec, at, 2) == 0.0 + 1.0 + 100.0 * 5.0
    assert step.entry is not None
    rec[1] = 7.0  # the looked-up overload reads the current values
    assert step(rec, at, 2) == 507.0


def test_a_lane_helper_called_from_python_raises_and_runs_through_a_compiled_caller() -> None:
    """Helpers have no CPython wrapper: a Python call is a clear error, before and after the
    helper was compiled for a lane function, never a jump to a null address."""
    from stcgym.adaptive.kernels.linalg import norm1

    M = np.array([[1.0, -2.0], [3.0, 0.5]])
    with pytest.raises(TypeError, match="lane helper"):
        norm1(M)
    assert call(norm1, M) == 4.0  # max column sum of |M|
    with pytest.raises(TypeError, match=r"@lane\(entry=True\)"):
        norm1(M)
