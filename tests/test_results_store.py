"""The results store of a bench run: records read back as written (rows with missing values,
infinities and text), the same record as the same bytes, a damaged file run again, ids that
follow what shapes a result, and the adaptation summary against a direct computation."""

from __future__ import annotations

import gzip
import json
import math
from dataclasses import replace

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from stcgym.agents.benchmark import build_config
from stcgym.agents.benchmark.adaptation import (
    combine,
    log_grid,
    summarize_adaptation,
    window_ratio,
)
from stcgym.agents.benchmark.metrics_csv import METRIC_COLUMNS
from stcgym.agents.benchmark.rundir import classical_key, job_id
from stcgym.agents.benchmark.scenarios import make_scenarios
from stcgym.agents.benchmark.store import (
    JobRecord,
    ResultsStore,
    ScenarioResult,
    decode_rows,
    encode_rows,
)


def _rows(n: int, rng: np.random.Generator) -> list[dict]:
    return [
        {
            "scenario": "family:test",
            "kind": "family",
            "plant": f"siso2-v1:{1100 + i}",
            "controller": "stc",
            "family": "adaptive",
            "run": 1,
            "seed": 1000 + i,
            "jump_step": "" if i % 2 else 400 + i,
            "cost": float(rng.random()),
            "cost_ratio": math.inf if i == 0 else float(rng.random() * 3),
            "post_jump_ratio": math.nan,
            "bounded": int(i != 0),
            "train_stop": "",
        }
        for i in range(n)
    ]


def _same(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return (math.isnan(a) and math.isnan(b)) or a == b
    return a == b


def _rounded(v):
    return float(f"{v:.6g}") if isinstance(v, float) and math.isfinite(v) else v


def test_rows_read_back_as_written_with_constant_columns_kept_once():
    rows = _rows(5, np.random.default_rng(0))
    columns = list(rows[0])
    data = encode_rows(rows, columns)
    assert data["const"]["controller"] == "stc" and "controller" not in data["cols"]
    assert data["const"]["post_jump_ratio"] is None  # nan, once
    assert "cost" in data["cols"] and data["cols"]["cost_ratio"][0] == "inf"
    json.dumps(data, allow_nan=False)  # plain JSON: no NaN or Infinity literals
    back = decode_rows(json.loads(json.dumps(data)))
    for row, got in zip(rows, back, strict=True):
        assert set(got) == set(row)
        for k, v in row.items():
            assert _same(got[k], _rounded(v)), (k, v, got[k])
            assert type(got[k]) is type(v), k  # ints stay ints, text stays text


@given(
    st.lists(
        st.one_of(
            st.floats(allow_nan=True, allow_infinity=True, width=64),
            st.integers(-(10**6), 10**6),
            st.text(alphabet="abc:-_", max_size=5),
        ),
        min_size=1,
        max_size=6,
    )
)
def test_any_column_round_trips(values):
    rows = [{"x": v, "scenario": "s"} for v in values]
    back = decode_rows(json.loads(json.dumps(encode_rows(rows, ["x", "scenario"]))))
    assert [r["scenario"] for r in back] == ["s"] * len(values)
    for v, got in zip(values, back, strict=True):
        if isinstance(v, str) and v not in ("inf", "-inf"):
            assert got["x"] == v
        elif isinstance(v, float):
            assert _same(float(got["x"]), _rounded(v))
        elif isinstance(v, int):
            assert got["x"] == v


def _record(rng, rid="abc") -> JobRecord:
    result = ScenarioResult(
        _rows(4, rng),
        {"span": 25, "window": [1.5, 1.2], "steps": [1, 2], "excess_q50": [0.5, 0.7]},
        {"y": rng.random((1, 6)), "theta_hat": rng.random((1, 6, 4))},
    )
    return JobRecord(
        "rl", "family_ppo_s0", rid, {"algo": "ppo", "seed": 0}, {"family:test": result},
        curve=[(0, 20.0), (4096, 12.5)], diagnostics=[{"step": 4096, "approx_kl": 0.012}],
        stop={"status": "cap", "kept_step": 4096}, train_key="family", algo="ppo", seed=0,
        wall_s=12.0,
    )  # fmt: skip


def test_a_record_reads_back_equal_and_is_the_same_bytes_each_time(tmp_path):
    store = ResultsStore(tmp_path / "store", METRIC_COLUMNS)
    record = _record(np.random.default_rng(1))
    assert store.load("family_ppo_s0", "abc") is None
    path = store.save(record)
    first = path.read_bytes()
    store.save(record)
    assert path.read_bytes() == first  # no time stamp in the gzip header: diffs stay clean
    back = store.load("family_ppo_s0", "abc")
    assert back.curve == record.curve and back.stop == record.stop
    assert back.diagnostics == record.diagnostics and back.algo == "ppo" and back.wall_s == 12.0
    got = back.scenarios["family:test"]
    want = record.scenarios["family:test"]
    np.testing.assert_allclose(got.trace["theta_hat"], want.trace["theta_hat"], rtol=5e-6)
    assert got.adaptation == want.adaptation
    assert [r["seed"] for r in got.rows] == [r["seed"] for r in want.rows]
    assert store.load("family_ppo_s0", "abd") is None  # another id is another result
    assert store.ids() == {"abc"} and [r.id for r in store.records()] == ["abc"]
    data = json.loads(gzip.decompress(first))  # plain JSON data, no pickles
    assert data["schema"] == 1 and data["kind"] == "rl"
    store.clear()
    assert not list((tmp_path / "store").glob("*.json.gz"))


def test_a_damaged_or_foreign_record_is_run_again(tmp_path):
    store = ResultsStore(tmp_path, METRIC_COLUMNS)
    path = store.save(_record(np.random.default_rng(2), "1"))
    path.write_bytes(path.read_bytes()[:50])  # as if the machine had died mid-write elsewhere
    assert store.load("family_ppo_s0", "1") is None
    data = _record(np.random.default_rng(2), "2").to_dict(METRIC_COLUMNS) | {"schema": 99}
    foreign = tmp_path / path.name.replace(".1.", ".2.")
    foreign.write_bytes(gzip.compress(json.dumps(data).encode()))
    assert store.load("family_ppo_s0", "2") is None
    assert list(store.records()) == []


def test_the_classical_id_follows_what_shapes_the_episodes(tmp_path):
    cfg = build_config(mode="quick", out=str(tmp_path), run="a", scenarios="family")
    sc = make_scenarios(cfg)[0]
    label, base = classical_key(cfg, sc, "stc", 0)
    assert label == "family:test.stc.run0"
    # where it is written, how it is executed, the other agents and scenarios of the run and
    # how the RL agents are trained do not matter ...
    for change in (
        {"run": "b", "out": "/elsewhere", "jobs": 7, "plots": False},
        {"agents": ["ppo", "stc", "lqg", "zero"], "scenarios": ["family", "ladder"]},
        {"ladder": ["ladder-l1-v1"], "ood": ["ood_order3"], "mimo_plants": ["quadruple_tank"]},
        {"family_train_steps": {"ppo": 1}, "patience": 9, "action_units": {"family": 3.0}},
        {"tuned": {"stc": {"params": {"forgetting": 0.99}}}},  # stc is not built from it
    ):
        assert classical_key(replace(cfg, **change), sc, "stc", 0)[1] == base, change
    # ... the scenario's episodes and env, the controller, the run and its study do
    moved = make_scenarios(replace(cfg, first_seed=1))[0]
    bounded = make_scenarios(replace(cfg, action_bounds={"family": 2.0}))[0]
    assert classical_key(cfg, moved, "stc", 0)[1] != base
    assert classical_key(cfg, bounded, "stc", 0)[1] != base
    assert classical_key(cfg, sc, "stc_lq", 0)[1] != base
    assert classical_key(cfg, sc, "stc", 1)[1] != base
    study = {"stc": {"params": {"forgetting": 0.99}}}
    tuned_a = classical_key(replace(cfg, tuned=study), sc, "stc_tuned", 0)[1]
    study_b = {"stc": {"params": {"forgetting": 0.98}}}
    assert classical_key(replace(cfg, tuned=study_b), sc, "stc_tuned", 0)[1] != tuned_a


def test_an_rl_job_id_ignores_where_it_writes_and_the_yardsticks_last_digits():
    task = {
        "name": "family_ppo_s0", "algo": "ppo", "seed": 0, "steps": 4096,
        "curve_reference": [0.1234567, 0.2], "model_dir": "/a", "progress": False,
        "tensorboard_log": None,
    }  # fmt: skip
    base = job_id(task)
    moved = task | {"model_dir": "/b", "curve_reference": [0.1234568, 0.2], "progress": True}
    assert job_id(moved) == base
    assert job_id(task | {"steps": 8192}) != base
    assert job_id(task | {"seed": 1}) != base


def test_the_adaptation_summary_equals_a_direct_computation():
    rng = np.random.default_rng(3)
    T, B, span = 200, 7, 25
    ref = rng.random((B, T)) + 0.5
    cost = ref * (1 + 3 * np.exp(-np.arange(T) / 30)) + 0.01 * rng.random((B, T))
    jump = np.array([-1, 60, 120, -1, 80, 150, 199])
    s = summarize_adaptation(cost, ref, jump, span, align=False)
    # the window ratio, one window and episode at a time
    for w in range(T // span):
        sl = slice(w * span, (w + 1) * span)
        direct = np.median([cost[i, sl].sum() / ref[i, sl].sum() for i in range(B)])
        assert math.isclose(s["window"][w], direct, rel_tol=1e-12)
    ends, _ = window_ratio(cost, ref, span)
    assert list(ends) == [span * (w + 1) for w in range(T // span)]
    # the cumulative excess at the grid's steps
    steps = np.asarray(s["steps"])
    assert steps[0] == 1 and steps[-1] == T and np.all(np.diff(steps) > 0)
    excess = np.cumsum(cost - ref, axis=1)
    for k, t in enumerate(steps):
        q = np.percentile(excess[:, t - 1], [25, 50, 75])
        assert np.allclose([s["excess_q25"][k], s["excess_q50"][k], s["excess_q75"][k]], q)
    # aligned on the jump: only episodes with one, from the jump on
    a = summarize_adaptation(cost, ref, jump, span, align=True)
    assert a["steps"][-1] == T - 60  # the earliest jump leaves the longest stretch
    after = [np.cumsum((cost - ref)[i, J:])[0] for i, J in enumerate(jump) if J >= 1]
    assert math.isclose(a["excess_q50"][0], float(np.median(after)), rel_tol=1e-12)
    # runs combined: median of the runs' medians, mean of their quartiles
    b = summarize_adaptation(cost * 2, ref, jump, span, align=False)
    both = combine([s, b, s])
    assert np.allclose(both["window"], s["window"])
    assert np.allclose(both["excess_q25"], (2 * np.array(s["excess_q25"]) + b["excess_q25"]) / 3)
    assert list(log_grid(1)) == [1] and log_grid(0).size == 0


def test_prune_deletes_only_the_records_not_asked_for(tmp_path):
    store = ResultsStore(tmp_path, METRIC_COLUMNS)
    keep = store.save(_record(np.random.default_rng(4), "keep"))
    gone = store.save(_record(np.random.default_rng(5), "gone"))
    assert store.prune({"keep", "elsewhere"}) == [gone]
    assert keep.is_file() and not gone.exists() and store.ids() == {"keep"}
