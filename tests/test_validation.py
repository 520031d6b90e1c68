"""The shared argument checks (stcgym.lanes.validation): what they accept, and exceptions that
name the argument and the expected form."""

from __future__ import annotations

import numpy as np
import pytest

from stcgym.lanes import validation as v


@pytest.mark.parametrize("value", [3, np.int64(3), np.uint8(3)])
def test_integer_accepts_python_and_numpy_integers(value):
    assert v.integer(value, "n") == 3 and type(v.integer(value, "n")) is int


@pytest.mark.parametrize("value", [0, -1, True, 2.0, "2", None, [2], np.array(2)])
def test_integer_rejects_everything_else_naming_the_argument(value):
    with pytest.raises(ValueError, match=r"^n must be an integer >= 1, got"):
        v.integer(value, "n")


@pytest.mark.parametrize("value", [1.5, -2, np.float32(0.25), np.array(3.0)])
def test_real_number_accepts_finite_real_scalars(value):
    assert v.real_number(value, "x") == float(value)


@pytest.mark.parametrize("value", ["1", None, [1.0], True, np.bool_(True), 1j, np.ones(2)])
def test_a_scalar_of_the_wrong_kind_is_a_type_error(value):
    with pytest.raises(TypeError, match=r"^x must be a finite real number"):
        v.real_number(value, "x")


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf, 10**400])
def test_a_non_finite_scalar_is_a_value_error(value):
    with pytest.raises(ValueError, match=r"^x must be a finite real number"):
        v.real_number(value, "x")


def test_sign_checks():
    assert v.non_negative(0.0, "s") == 0.0 and v.positive(1e-300, "s") == 1e-300
    with pytest.raises(ValueError, match="s must be a finite number >= 0"):
        v.non_negative(-1e-300, "s")
    with pytest.raises(ValueError, match="s must be a finite number > 0"):
        v.positive(0.0, "s")


@pytest.mark.parametrize("value", [0.0, -0.1, 1.0000001, np.nan, True, "0.9"])
def test_forgetting_factor_lies_in_the_half_open_unit_interval(value):
    with pytest.raises(ValueError, match=r"lam must lie in \(0, 1\]"):
        v.forgetting_factor(value, "lam")
    assert v.forgetting_factor(1, "lam") == 1.0


@pytest.mark.parametrize(
    ("value", "match"),
    [
        ([[1.0], [1.0, 2.0]], "u must be a rectangular array"),
        ([1.0, 2j], "u must be real"),
        (["a"], "u must be an array of real numbers"),
        ([[1.0, 2.0]], "u must be one-dimensional"),
        ([], "u must not be empty"),
        ([1.0, 2.0], "u must have length 3"),
        ([1.0, np.nan, 0.0], "u must be finite"),
    ],
)
def test_finite_vector_names_what_is_wrong(value, match):
    with pytest.raises(ValueError, match=match):
        v.finite_vector(value, "u", length=3)


def test_finite_vector_returns_a_new_float_array():
    src = np.array([1, 2, 3])
    out = v.finite_vector(src, "u")
    assert out.dtype == np.float64 and not np.shares_memory(out, src)
    np.testing.assert_array_equal(v.finite_vector(2.5, "u"), [2.5])


def test_matrices():
    np.testing.assert_array_equal(v.matrix([1.0, 2.0], "b", (2, 1)), [[1.0], [2.0]])
    with pytest.raises(ValueError, match=r"B must have 2 rows \(shape \(2, any\)\)"):
        v.matrix(np.ones((3, 1)), "B", (2, None))
    with pytest.raises(ValueError, match="C must have at least one of its rows"):
        v.matrix(np.ones((0, 2)), "C", (None, 2))
    for bad in (np.ones((2, 3)), np.ones(3), np.ones((0, 0))):
        with pytest.raises(ValueError, match="A must be a non-empty square matrix"):
            v.square_matrix(bad, "A")
    with pytest.raises(ValueError, match="A must be finite"):
        v.square_matrix([[1.0, np.inf], [0.0, 1.0]], "A")


def test_lane_selections():
    np.testing.assert_array_equal(v.lane_indices(None, 3), [0, 1, 2])
    np.testing.assert_array_equal(v.lane_indices([True, False, True], 3), [0, 2])
    np.testing.assert_array_equal(v.lane_indices(np.int64(2), 3), [2])
    with pytest.raises(ValueError, match=r"lanes must be integers in \[0, 3\)"):
        v.lane_indices([3], 3)
    with pytest.raises(ValueError, match=r"lanes as a boolean mask must have shape \(3,\)"):
        v.lane_indices([True], 3)
    with pytest.raises(ValueError, match="lanes must be lane indices"):
        v.lane_indices([0.5], 3)
    np.testing.assert_array_equal(v.lane_vector(2.0, 3, "y"), [2.0, 2.0, 2.0])
    np.testing.assert_array_equal(v.lane_vector([[1.0], [2.0]], 2, "y"), [1.0, 2.0])
    with pytest.raises(ValueError, match=r"y must be finite; lanes \[1\] are not"):
        v.lane_vector([0.0, np.nan], 2, "y")
    with pytest.raises(ValueError, match=r"y must have shape \(2,\)"):
        v.lane_vector([0.0, 1.0, 2.0], 2, "y")


def test_vector_pairs_must_have_the_same_length():
    u, y = v.vector_pair([1, 2], [3.0, 4.0], ("u", "y"))
    np.testing.assert_array_equal(np.c_[u, y], [[1.0, 3.0], [2.0, 4.0]])
    with pytest.raises(ValueError, match=r"u and y must have the same length L, got len\(u\)=2"):
        v.vector_pair([1, 2], [3.0], ("u", "y"), " L")
    with pytest.raises(ValueError, match="y must be finite"):
        v.vector_pair([1, 2], [3.0, np.nan], ("u", "y"))


@pytest.mark.parametrize(
    ("value", "kwargs", "ok"),
    [
        (0.0, {"lo": 0.0}, True),
        (0.0, {"lo": 0.0, "lo_open": True}, False),
        (1.0, {"hi": 1.0}, True),
        (1.0, {"hi": 1.0, "hi_open": True}, False),
        (np.inf, {"lo": 0.0}, True),  # [0, inf]: inf switches the setting off
        (np.inf, {"lo": 0.0, "hi_open": True}, False),
        (-np.inf, {}, False),
        (np.nan, {}, False),
        (np.float32(0.5), {"lo": 0.0, "hi": 1.0}, True),
        (3, {"lo": 1.0}, True),
    ],
)
def test_real_in_checks_each_end_of_the_interval(value, kwargs, ok):
    if ok:
        assert v.real_in(value, "s", **kwargs) == float(value)
    else:
        with pytest.raises(ValueError, match=r"^s must lie in [\[(]"):
            v.real_in(value, "s", **kwargs)


@pytest.mark.parametrize("value", ["1", None, [1.0], True, np.bool_(False), 1j, 10**400])
def test_real_in_rejects_every_other_kind_as_a_value_error(value):
    with pytest.raises(ValueError, match=r"^gain_max must lie in \(0, inf\], got"):
        v.real_in(value, "gain_max", 0.0, lo_open=True)


def test_one_of_names_the_choices():
    assert v.one_of("raise", "on_failure", ("reset", "raise")) == "raise"
    for bad in ("Raise", None, ["reset"], 1):
        with pytest.raises(ValueError, match=r"on_failure must be one of \('reset', 'raise'\)"):
            v.one_of(bad, "on_failure", ("reset", "raise"))


def test_covariance_from_a_scalar_a_diagonal_or_a_matrix():
    np.testing.assert_array_equal(v.covariance(2.0, 3, "P0"), 2.0 * np.eye(3))
    np.testing.assert_array_equal(v.covariance([1.0, 2.0], 2, "P0"), np.diag([1.0, 2.0]))
    M = np.array([[2.0, 0.5], [0.5, 1.0]])
    M_rounded = M + np.array([[0.0, 1e-14], [0.0, 0.0]])  # symmetric to rounding
    np.testing.assert_allclose(v.covariance(M_rounded, 2, "P0"), 0.5 * (M_rounded + M_rounded.T))
    assert np.linalg.eigvalsh(v.covariance(M_rounded, 2, "P0")).min() > 0.0
    expected = r"P0 must be a positive scalar, a vector of length 2 or a symmetric positive"
    singular = [[1.0, 1.0], [1.0, 1.0]]
    for bad in (0.0, [1.0, 0.0], [[1.0, 0.5], [0.0, 1.0]], singular, "x", [1.0] * 3):
        with pytest.raises(ValueError, match=expected):
            v.covariance(bad, 2, "P0")
    with pytest.raises(ValueError, match="it is not finite"):
        v.covariance([[1.0, np.nan], [np.nan, 1.0]], 2, "P0")
    # a singular covariance only where allowed (a process noise, not an initial P)
    np.testing.assert_array_equal(v.covariance([1.0, 0.0], 2, "Q", allow_singular=True),
                                  np.diag([1.0, 0.0]))  # fmt: skip
    np.testing.assert_array_equal(
        v.covariance([[1.0, 1.0], [1.0, 1.0]], 2, "Q", allow_singular=True), np.ones((2, 2))
    )
    with pytest.raises(ValueError, match="Q must be a positive or zero scalar"):
        v.covariance(-1.0, 2, "Q", allow_singular=True)


def test_flag_takes_only_bools():
    assert v.flag(np.bool_(True), "integral") is True and v.flag(False, "integral") is False
    for bad in (1, 0, "yes", None, np.array([True])):
        with pytest.raises(ValueError, match="integral must be a bool, got"):
            v.flag(bad, "integral")
