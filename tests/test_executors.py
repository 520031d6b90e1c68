"""The task executor: local pool and Ray run the same tasks, failures are reported, resume skips."""

from __future__ import annotations

import io
import math

import pytest

from stcgym.agents.executors import (
    Progress,
    ResultStore,
    run_tasks,
    task_id,
    write_atomic,
)

# ``math.sqrt`` is picklable by reference everywhere (spawned processes, Ray workers) and fails
# on a negative number: a task function with a known answer and a known error.
TASKS = [4.0, 9.0, -1.0, 16.0, 2.25]


def _by_index(outcomes):
    return {o.index: o for o in outcomes}


def _check_outcomes(outcomes, skipped=()):
    got = _by_index(outcomes)
    expected = [i for i in range(len(TASKS)) if i not in skipped]
    assert sorted(got) == expected  # every task exactly once
    for i in expected:
        o = got[i]
        assert o.task == TASKS[i]
        if TASKS[i] < 0:
            assert not o.ok and o.result is None
            assert "ValueError" in o.error and "math domain error" in o.error
        else:
            assert o.ok and o.result == math.sqrt(TASKS[i]) and o.seconds >= 0


@pytest.mark.parametrize("jobs", [1, 2])
def test_local_pool_runs_every_task_and_reports_the_failure(jobs):
    _check_outcomes(list(run_tasks(math.sqrt, TASKS, jobs=jobs)))


def test_done_tasks_are_skipped():
    done = {task_id(TASKS[1]), task_id(TASKS[3])}
    _check_outcomes(list(run_tasks(math.sqrt, TASKS, jobs=1, done=done)), skipped=(1, 3))


@pytest.mark.parametrize("jobs", [1, 2])
def test_admit_is_asked_as_workers_free_up_and_refused_tasks_never_run(jobs):
    # a budget of 3 starts: each admitted task uses one, so the rest are refused
    budget = {"left": 3}
    asked = []

    def admit(task):
        asked.append(task)
        if task == 16.0 or budget["left"] == 0:
            return False
        budget["left"] -= 1
        return True

    got = _by_index(run_tasks(math.sqrt, TASKS, jobs=jobs, admit=admit))
    assert sorted(got) == [0, 1, 2]  # in order, 4.0, 9.0, -1.0; the rest never started
    assert 16.0 in asked and 2.25 in asked
    # without the budget, the refused task is skipped and the one after it starts
    got = _by_index(run_tasks(math.sqrt, TASKS, jobs=jobs, admit=lambda t: t != 16.0))
    assert sorted(got) == [0, 1, 2, 4]


def test_ray_runs_the_same_tasks():
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False)
    try:
        _check_outcomes(list(run_tasks(math.sqrt, TASKS, executor="ray", jobs=2)))
    finally:
        ray.shutdown()


def test_task_id_is_canonical():
    a = {"family": {"count": 3, "seed": 1}, "lanes": [0, 10]}
    b = {"lanes": [0, 10], "family": {"seed": 1, "count": 3}}
    assert task_id(a) == task_id(b)
    assert task_id(a) != task_id({**a, "lanes": [0, 11]})
    assert len(task_id(a)) == 16
    with pytest.raises(TypeError, match="JSON"):
        task_id({"f": object()})


def test_result_store_round_trips_floats_exactly(tmp_path):
    store = ResultStore(tmp_path / "tasks")
    rows = [{"x": 0.1 + 0.2, "big": 1e300, "nan": math.nan, "inf": math.inf, "i": 3}]
    store.save("abc", rows)
    (tmp_path / "tasks" / ".abc.json.123.tmp").write_text("half a fil")  # an interrupted save
    assert store.done() == {"abc"}
    back = store.load("abc")
    assert back[0]["x"] == 0.1 + 0.2 and back[0]["big"] == 1e300 and back[0]["i"] == 3
    assert math.isnan(back[0]["nan"]) and back[0]["inf"] == math.inf


def test_write_atomic_replaces_and_leaves_no_temp_files(tmp_path):
    path = tmp_path / "sub" / "table.csv"
    write_atomic(path, "a\n")
    write_atomic(path, b"b\n")
    assert path.read_text() == "b\n"
    assert sorted(p.name for p in path.parent.iterdir()) == ["table.csv"]


def test_progress_lines_count_earlier_tasks():
    out = io.StringIO()
    bar = Progress(5, done=2, stream=out)
    bar.update()
    bar.update()
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("task 3/5, ETA ") and lines[1].startswith("task 4/5, ETA ")


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"executor": "dask"}, "executor"), ({"jobs": 0}, "jobs"), ({"jobs": 1.5}, "jobs")],
)
def test_bad_arguments_fail_before_any_task(kwargs, match):
    ran = []
    with pytest.raises(ValueError, match=match):
        list(run_tasks(ran.append, [1, 2], **kwargs))
    assert ran == []


def test_result_store_refuses_what_json_cannot_hold(tmp_path):
    store = ResultStore(tmp_path)
    with pytest.raises(TypeError):
        store.save("x", {"x": object()})
    assert store.done() == set()
