"""Named lane state and the no-allocation rule of lane functions (stcgym.lanes.compiled)."""

from __future__ import annotations

import warnings
from typing import Any, NamedTuple

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from lane_call import call

from stcgym.adaptive.estimation.state_estimation import is_schur_stable
from stcgym.lanes.compiled import FixedTypes, lane, lane_state, set_lanes, state_arrays
from stcgym.lanes.linalg import copy_matrix, copy_vector


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
    S: np.ndarray
    theta: np.ndarray


@lane(entry=True)
def _read_by_name(s, lane):
    """``sum(theta) + 100 * S[d - 1, d - 1]`` of lane ``lane``, read by the fields' names."""
    theta = s.theta[lane]
    S = s.S[lane]
    d = theta.size
    acc = 0.0
    for i in range(d):
        acc += theta[i]
    return acc + 100.0 * S[d - 1, d - 1]


def test_lane_state_rows_are_read_by_name():
    s = lane_state(_Pair, {"theta": (3,), "S": (3, 3)}, 2)
    s.theta[1] = [1.0, 2.0, 4.0]
    s.S[1] = np.diag([7.0, 8.0, 9.0])
    assert _read_by_name(s, 1) == 907.0
    assert _read_by_name(s, 0) == 0.0
    with pytest.raises(ValueError, match="exactly the fields of _Pair"):
        lane_state(_Pair, {"S": (1, 1)}, 1)


class _Outer(NamedTuple):
    pair: Any
    t: Any


def test_nested_lane_states_are_built_reset_and_listed_field_by_field():
    inner = lane_state(_Pair, {"theta": (2,), "S": (2, 2)}, 3)
    s = lane_state(_Outer, {"t": ()}, 3, {"t": np.int64}, nested={"pair": inner})
    assert s.pair is inner and s.t.shape == (3,) and s.t.dtype == np.int64
    init = lane_state(
        _Outer, {"t": ()}, 1, nested={"pair": lane_state(_Pair, {"theta": (2,), "S": (2, 2)}, 1)}
    )
    init.pair.theta[0] = [1.0, 2.0]
    init.pair.S[0] = np.eye(2)
    init.t[0] = 7
    set_lanes(s, [0, 2], init)
    np.testing.assert_array_equal(s.pair.theta, [[1.0, 2.0], [0.0, 0.0], [1.0, 2.0]])
    np.testing.assert_array_equal(s.pair.S[1], np.zeros((2, 2)))
    np.testing.assert_array_equal(s.t, [7, 0, 7])
    assert [a.shape for a in state_arrays(s)] == [(3, 2, 2), (3, 2), (3,)]  # S, theta, t
    with pytest.raises(ValueError, match="each once"):
        lane_state(_Outer, {"t": (), "pair": ()}, 3, nested={"pair": inner})


def test_fixed_types_calls_the_same_compiled_code():
    s = lane_state(_Pair, {"theta": (2,), "S": (2, 2)}, 1)
    s.theta[0] = [0.0, 1.0]
    s.S[0] = [[2.0, 3.0], [4.0, 5.0]]
    step = FixedTypes(_read_by_name)
    assert step.entry is None
    assert step(s, 0) == _read_by_name(s, 0) == 0.0 + 1.0 + 100.0 * 5.0
    assert step.entry is not None
    s.theta[0, 1] = 7.0  # the looked-up overload reads the current values
    assert step(s, 0) == 507.0


def test_a_lane_helper_called_from_python_raises_and_runs_through_a_compiled_caller() -> None:
    """Helpers have no CPython wrapper: a Python call is a clear error, before and after the
    helper was compiled for a lane function, never a jump to a null address."""
    from stcgym.lanes.linalg import norm1

    M = np.array([[1.0, -2.0], [3.0, 0.5]])
    with pytest.raises(TypeError, match="lane helper"):
        norm1(M)
    assert call(norm1, M) == 4.0  # max column sum of |M|
    with pytest.raises(TypeError, match=r"@lane\(entry=True\)"):
        norm1(M)
