"""The classical episodes a bench run keeps for ``--resume``: a faithful round trip, an id that
changes with every setting that shapes the episodes, and a damaged file evaluated again."""

from __future__ import annotations

import numpy as np

from stcgym.agents.benchmark import build_config
from stcgym.agents.benchmark.classical_store import ClassicalEpisodes, ClassicalStore, classical_id


def _episodes(rng):
    return ClassicalEpisodes(
        cost=rng.random((3, 7)),
        jump_step=np.array([-1, 4, 2]),
        metrics={"effort": rng.random(3), "overshoot_pct": np.array([np.nan, 1.0, 2.0])},
        trace={"y": rng.random((2, 8)), "theta_hat": rng.random((2, 7, 4))},
    )


def test_kept_episodes_read_back_equal(tmp_path):
    rng = np.random.default_rng(0)
    episodes = _episodes(rng)
    store = ClassicalStore(tmp_path / "classical")
    assert store.load("family:test.stc.run0", "abc") is None
    store.save("family:test.stc.run0", "abc", episodes)
    back = store.load("family:test.stc.run0", "abc")
    np.testing.assert_array_equal(back.cost, episodes.cost)
    np.testing.assert_array_equal(back.jump_step, episodes.jump_step)
    assert back.metrics.keys() == episodes.metrics.keys()
    assert back.trace.keys() == {"y", "theta_hat"}
    for k in episodes.metrics:
        np.testing.assert_array_equal(back.metrics[k], episodes.metrics[k])  # NaN included
    np.testing.assert_array_equal(back.trace["theta_hat"], episodes.trace["theta_hat"])
    assert store.load("family:test.stc.run0", "abd") is None  # another id is another result
    # no pickles: the file is plain arrays
    (path,) = (tmp_path / "classical").glob("*.npz")
    with np.load(path, allow_pickle=False) as data:
        assert sorted(data.files)[:2] == ["cost", "jump_step"]
    store.clear()
    assert not list((tmp_path / "classical").glob("*.npz"))


def test_a_damaged_file_is_evaluated_again(tmp_path):
    store = ClassicalStore(tmp_path)
    store.save("x", "1", _episodes(np.random.default_rng(1)))
    (path,) = tmp_path.glob("*.npz")
    path.write_bytes(path.read_bytes()[:50])  # as if the machine had died mid-write elsewhere
    assert store.load("x", "1") is None


def test_the_id_follows_what_shapes_the_episodes(tmp_path):
    cfg = build_config(mode="quick", out=str(tmp_path), run="a").to_dict()
    scenario = {"name": "family:test", "env": {"plant": "stable2"}, "episodes": {"seeds": [1, 2]}}
    base = classical_id(cfg, scenario, "stc", 0)
    # where it is written and how it is executed do not matter ...
    elsewhere = cfg | {"run": "b", "out": "/elsewhere", "jobs": 7, "plots": False}
    assert classical_id(elsewhere, scenario, "stc", 0) == base
    # nor how the RL agents are trained
    retrained = cfg | {
        "algo_configs": {},
        "family_train_steps": 1,
        "patience": 9,
        "action_units": {"family": 3.0},
    }
    assert classical_id(retrained, scenario, "stc", 0) == base
    # ... the settings, the scenario, the controller and the run do
    assert classical_id(cfg | {"first_seed": 1}, scenario, "stc", 0) != base
    assert classical_id(cfg | {"action_bounds": {"family": 2.0}}, scenario, "stc", 0) != base
    assert classical_id(cfg, scenario | {"episodes": {"seeds": [1, 3]}}, "stc", 0) != base
    assert classical_id(cfg, scenario, "stc_lq", 0) != base
    assert classical_id(cfg, scenario, "stc", 1) != base
