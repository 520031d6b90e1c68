"""Batch loops (``@lanes``): every lane once, in blocks of rows on threads, same numbers."""

from __future__ import annotations

import threading

import numba
import numpy as np
import pytest

from stcgym.lanes import compiled
from stcgym.lanes.compiled import FixedTypes, LaneLoop, lane, lanes, run_blocks


@lane(entry=True)
def _square_step(x, scale):
    return x * x * scale


@lanes(min_lanes=1)
def _squares(X, scale, out, visits, first, last):
    for i in range(first, last):
        out[i] = _square_step(X[i], scale)
        visits[i] += 1


@lanes(min_lanes=1)
def _fails_on_negative(X, first, last):
    for i in range(first, last):
        if X[i] < 0.0:
            raise ValueError("negative lane")


def _run(B: int, threads: int) -> tuple[np.ndarray, np.ndarray]:
    X = np.linspace(-2.0, 3.0, B)
    out, visits = np.zeros(B), np.zeros(B, dtype=np.int64)
    saved = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        _squares(X, 0.5, out, visits)
    finally:
        numba.set_num_threads(saved)
    return out, visits


@pytest.mark.parametrize("B", [1, 2, 3, 7, 64])
def test_every_lane_runs_once_and_equals_the_lane_function(B):
    """Whatever the blocks, each row is visited exactly once and holds the lane function's
    value computed on its own (the same compiled code: equal bit for bit)."""
    threads = numba.config.NUMBA_NUM_THREADS
    out, visits = _run(B, threads)
    np.testing.assert_array_equal(visits, np.ones(B, dtype=np.int64))
    X = np.linspace(-2.0, 3.0, B)
    np.testing.assert_array_equal(out, [_square_step(x, 0.5) for x in X])
    np.testing.assert_array_equal(out, _run(B, 1)[0])


def test_blocks_follow_the_thread_setting_and_the_minimum_per_thread(monkeypatch):
    monkeypatch.setattr(numba, "get_num_threads", lambda: 4)
    assert compiled._blocks(1000, 128) == 4
    assert compiled._blocks(300, 128) == 2  # each block at least 128 lanes
    assert compiled._blocks(255, 128) == 1
    assert compiled._blocks(5, 1) == 4
    monkeypatch.setattr(numba, "get_num_threads", lambda: 1)
    assert compiled._blocks(10**6, 1) == 1


def test_blocks_run_on_other_threads_too(monkeypatch):
    """With two blocks, the second runs on the pool while the first runs on the caller."""
    monkeypatch.setattr(numba, "get_num_threads", lambda: 2)
    seen = []

    def loop(X, first, last):
        seen.append((threading.get_ident(), first, last))

    run_blocks(loop, (np.zeros(10),), min_lanes=1)
    assert sorted((f, l) for _, f, l in seen) == [(0, 5), (5, 10)]
    assert {t for t, f, _ in seen if f == 0} == {threading.get_ident()}
    assert {t for t, f, _ in seen if f == 5} != {threading.get_ident()}


def test_an_error_in_any_block_is_raised_after_all_blocks(monkeypatch):
    monkeypatch.setattr(numba, "get_num_threads", lambda: 2)
    X = np.ones(8)
    X[6] = -1.0  # in the second block, which runs on the pool
    with pytest.raises(ValueError, match="negative lane"):
        _fails_on_negative(X)
    X[6], X[1] = 1.0, -1.0  # in the first block, on the calling thread
    with pytest.raises(ValueError, match="negative lane"):
        _fails_on_negative(X)


def test_fixed_types_runs_the_loop_compiled_for_the_first_call():
    assert isinstance(_squares, LaneLoop)
    X = np.arange(5.0)
    out, visits = np.zeros(5), np.zeros(5, dtype=np.int64)
    fixed = FixedTypes(_squares)
    fixed(X, 2.0, out, visits)
    fixed(X, 2.0, out, visits)
    np.testing.assert_array_equal(out, 2.0 * X * X)
    np.testing.assert_array_equal(visits, np.full(5, 2))


def test_a_batch_loop_pickles_by_reference():
    import pickle

    from stcgym.adaptive.control import controller_step as controller

    assert pickle.loads(pickle.dumps(controller.controllers_step)) is controller.controllers_step
