"""The RL ablation's committed records and what the RL-baselines page prints from them."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RUNS = ROOT / "benchmarks" / "rl_ablation_runs.jsonl"


def _ablation_script():
    path = ROOT / "benchmarks" / "rl_ablation.py"
    spec = importlib.util.spec_from_file_location("rl_ablation_script", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_summary_and_the_pages_table_are_the_committed_runs():
    script = _ablation_script()
    table = script.summarise([RUNS])
    committed = json.loads((ROOT / "benchmarks" / "rl_ablation_summary.json").read_text())
    assert table == committed
    page = (ROOT / "docs" / "rl_baselines.md").read_text()
    marker = "<!-- ablation table: benchmarks/rl_ablation.py --summarise -->\n"
    printed = page.split(marker, 1)[1].split("\n\n", 1)[0]
    assert printed == script.markdown(table)


def test_every_run_records_its_settings_and_scores():
    rows = [json.loads(line) for line in RUNS.read_text().splitlines() if line.strip()]
    assert rows
    for row in rows:
        assert {"family", "agent", "final"} <= set(row)
        final = row["final"]
        assert 0.0 <= final["diverged"] <= 1.0 and final["median_ratio"] > 0
        if "steps" in row:  # a trained run: its curve ends where its training did
            assert row["curve"][0][0] == 0 and row["curve"][-1][0] == row["steps"]
