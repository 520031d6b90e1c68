"""IQM, median and probability of improvement with rliable's bootstrap, on hand-worked cases."""

from __future__ import annotations

import numpy as np
import pytest

from stcgym.agents.evaluation.statistics import interval_estimates, probability_of_improvement


def test_iqm_and_median_by_hand():
    # 8 runs: the IQM drops the 2 lowest and 2 highest, mean(3, 4, 5, 6) = 4.5 (not the
    # mean 13.0 that the outlier 80 drags up)
    est = interval_estimates({"a": [1, 2, 3, 4, 5, 6, 7, 80.0]}, reps=300)["a"]
    assert est["iqm"][0].value == pytest.approx(4.5)
    assert est["median"][0].value == pytest.approx(4.5)
    lo, hi = est["iqm"][0].low, est["iqm"][0].high
    assert 1.0 <= lo < 4.5 < hi <= 80.0
    # constant runs: the interval collapses onto the value
    c = interval_estimates({"c": [2.0, 2.0, 2.0]}, reps=100)["c"]["iqm"][0]
    assert (c.value, c.low, c.high) == (2.0, 2.0, 2.0)


def test_columns_are_separate_metrics_and_match_rliable():
    from rliable import metrics

    rng = np.random.default_rng(1)
    x = rng.random((15, 3))
    est = interval_estimates({"x": x}, reps=100)["x"]
    for j in range(3):
        assert est["iqm"][j].value == pytest.approx(metrics.aggregate_iqm(x[:, [j]]))
        assert est["median"][j].value == pytest.approx(np.median(x[:, j]))
    pooled = interval_estimates({"x": x}, pool_tasks=True, reps=100)["x"]
    assert pooled["iqm"][0].value == pytest.approx(metrics.aggregate_iqm(x))


def test_intervals_are_reproducible_and_shrink_with_more_runs():
    rng = np.random.default_rng(2)
    few, many = rng.normal(size=6), rng.normal(size=600)
    a = interval_estimates({"f": few, "m": many}, reps=300, seed=3)
    b = interval_estimates({"f": few, "m": many}, reps=300, seed=3)
    assert a == b
    width = {k: a[k]["iqm"][0].high - a[k]["iqm"][0].low for k in a}
    assert width["m"] < width["f"]


def test_probability_of_improvement_by_hand():
    # x = [1, 3] vs y = [2, 4]: pairs (1<2), (1<4), (3<4) lower, (3>2) not: 3/4
    p = probability_of_improvement({"x": [1.0, 3.0], "y": [2.0, 4.0], "z": [5.0, 6.0]}, "x")
    assert p["y"].value == pytest.approx(0.75)
    assert p["z"].value == pytest.approx(1.0) and p["z"].low == pytest.approx(1.0)
    # ties count one half
    tie = probability_of_improvement({"x": [1.0, 2.0], "y": [2.0, 3.0]}, "x")["y"]
    assert tie.value == pytest.approx((1 + 1 + 0.5 + 1) / 4)
    assert set(p) == {"y", "z"}


def test_bad_scores_are_rejected():
    with pytest.raises(ValueError, match="finite"):
        interval_estimates({"a": [1.0, np.inf]})
    nan = interval_estimates({"a": []})["a"]["iqm"][0]
    assert np.isnan(nan.value)


def test_improvement_statistic_is_rliables():
    from rliable import metrics

    from stcgym.agents.evaluation.statistics import _improvement

    rng = np.random.default_rng(4)
    for nx, ny, tasks in ((3, 5, 1), (15, 5, 2), (4, 4, 3)):
        x = rng.integers(0, 5, (nx, tasks)).astype(float)  # integers: ties happen
        y = rng.integers(0, 5, (ny, tasks)).astype(float)
        assert _improvement(x, y) == pytest.approx(metrics.probability_of_improvement(x, y))
