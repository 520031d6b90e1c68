"""Settling to the oracle's cost, re-convergence after a jump, step-response figures."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stcgym.agents.evaluation.response import curve_settling_step, settling_step, step_response

T, J, SPAN = 1000, 500, 100


def _reference(seed: int = 0) -> np.ndarray:
    return 0.1 + 0.05 * np.random.default_rng(seed).random(T)


def test_no_change_reads_zero():
    ref = _reference()
    assert settling_step(ref, ref, span=SPAN, start=J) == 0.0
    assert settling_step(1.1 * ref, ref, span=SPAN) == 0.0  # within tol everywhere


def test_never_recovering_reads_inf_not_zero():
    ref = _reference()
    cost = ref.copy()
    cost[J:] *= 34.0  # the td3 case: 34x the cost from the jump on, for good
    assert math.isinf(settling_step(cost, ref, span=SPAN, start=J))
    # ... even when the controller's own level after the jump is steady (the old metric's trap)
    assert math.isinf(settling_step(1.3 * ref, ref, span=SPAN, start=J))


@pytest.mark.parametrize("k", [1, 37, 60, 250])
def test_recovers_at_step_k(k):
    ref = _reference(k)
    cost = ref.copy()
    cost[J : J + k] = 1e3  # bad for k steps after the jump, then as good as the reference
    assert settling_step(cost, ref, span=SPAN, start=J) == float(k)
    # from the start of the episode, the same trace needs J + k steps
    assert settling_step(cost, ref, span=SPAN) == float(J + k)
    # the pre-jump part alone is fine
    assert settling_step(cost, ref, span=SPAN, stop=J) == 0.0


@settings(max_examples=40, deadline=None)
@given(k=st.integers(0, T - J - SPAN), scale=st.floats(1.0, 1.19))
def test_settling_is_the_last_bad_window_plus_one(k, scale):
    ref = _reference()
    cost = scale * ref
    cost[J : J + k] = 50.0
    got = settling_step(cost, ref, span=SPAN, start=J)
    # by brute force over the windows
    ratios = [cost[i : i + SPAN].sum() / ref[i : i + SPAN].sum() for i in range(J, T - SPAN + 1)]
    bad = [i - J for i, r in zip(range(J, T - SPAN + 1), ratios, strict=True) if r > 1.2]
    assert got == (0.0 if not bad else bad[-1] + 1.0)


def test_settling_input_checks():
    ref = _reference()
    with pytest.raises(ValueError):
        settling_step(ref[:10], ref, span=SPAN)
    with pytest.raises(ValueError):
        settling_step(ref, ref, span=SPAN, start=T)
    assert math.isinf(settling_step(np.full(T, np.nan), ref, span=SPAN))


def test_curve_settling_step():
    curve = [(0, 10.0), (1000, 2.0), (3000, 1.1), (10000, 1.3), (30000, 1.15), (100000, 1.0)]
    assert curve_settling_step(curve, 1.0) == 30000.0  # dips within at 3000, leaves, returns
    assert math.isinf(curve_settling_step(curve[:4], 1.0))
    assert curve_settling_step([(0, 0.5), (10, 0.9)], 1.0) == 0.0
    assert math.isnan(curve_settling_step([], 1.0))


def test_step_response_by_hand():
    # reference 0 -> 1 at k = 0 and 1 -> -1 at k = 6 (every signal is 0 before the first step)
    r = np.array([1, 1, 1, 1, 1, 1, -1, -1, -1, -1, -1, -1], dtype=float)
    y = np.array([0, 0.5, 1.3, 0.97, 1.0, 1.0, 1.0, 0.0, -1.5, -1.2, -0.99, -1.0])
    out = step_response(y, r)
    # step 1 (d = 1): overshoot 30 %, outside the 0.05 band at k = 0, 1, 2 -> settles in 3
    # step 2 (d = -2): overshoot 0.5 / 2 = 25 %, outside the 0.1 band at 6, 7, 8, 9 -> 4
    assert out["n_steps"] == 2
    assert out["overshoot_pct"] == pytest.approx(25.0)  # median of two: the lower one
    assert out["settling_steps"] == 3.0
    first = step_response(y, r, stop=6)
    assert first["overshoot_pct"] == pytest.approx(30.0) and first["settling_steps"] == 3.0
    never = step_response(np.zeros(12), r, stop=6)
    assert math.isinf(never["settling_steps"])
    assert math.isnan(step_response(y, r, start=1, stop=6)["overshoot_pct"])
