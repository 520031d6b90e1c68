"""The bench runs committed under ``results/``: each store renders, without training, to the
statistics committed beside it, and the tables the documentation prints from it are those
statistics (a page edited by hand, or a store changed without rendering the page again, fails
here). A run committed part-way (to be resumed from the repository) renders to its partial
report; a finished one is printed by a page."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from stcgym.agents.benchmark.render import PAGE_BLOCKS, page_blocks, render_run

ROOT = Path(__file__).resolve().parents[1]
RUNS = sorted(p.parent for p in (ROOT / "results").glob("*/config.json"))
PAGES = [ROOT / "docs" / "benchmark.md", ROOT / "README.md"]
#: The largest store a committed run may have (the repository carries every version of it).
MAX_STORE_BYTES = 20 * 2**20


@pytest.mark.skipif(not RUNS, reason="no committed run under results/")
@pytest.mark.parametrize("run", RUNS, ids=[p.name for p in RUNS])
def test_a_committed_store_renders_to_its_committed_statistics(run, tmp_path):
    store = run / "store"
    size = sum(p.stat().st_size for p in store.iterdir())
    assert 0 < size <= MAX_STORE_BYTES
    copy = tmp_path / run.name
    copy.mkdir()
    shutil.copy(run / "config.json", copy / "config.json")
    shutil.copytree(store, copy / "store")
    rendered = render_run(copy, plots=False, log=lambda msg: None)
    if rendered.missing:  # a run committed part-way, to be resumed: its report says so
        assert "**PARTIAL: jobs left to run" in (run / "report.md").read_text()
    assert json.loads((copy / "statistics.json").read_text()) == json.loads(
        (run / "statistics.json").read_text()
    )
    # (a partial report names its folder in the command that resumes it)
    report = (copy / "report.md").read_text().replace(str(copy), f"results/{run.name}")
    assert report == (run / "report.md").read_text()


@pytest.mark.skipif(not RUNS, reason="no committed run under results/")
@pytest.mark.parametrize("run", RUNS, ids=[p.name for p in RUNS])
def test_the_pages_print_the_tables_of_the_committed_statistics(run):
    statistics = json.loads((run / "statistics.json").read_text())
    blocks = [b for page in PAGES for b in page_blocks(page.read_text(), run.name).items()]
    if "**PARTIAL" not in (run / "report.md").read_text():  # a finished run is on a page
        assert blocks, f"no page prints the tables of results/{run.name}"
    for kind, block in blocks:
        assert block == PAGE_BLOCKS[kind][2](run.name, statistics), (kind, run.name)
