"""The last stage of a bench run: tables, report and figures rendered from the results store.

:func:`render_run` reads a run folder's ``config.json`` and the records of its ``store/``
(:mod:`~stcgym.agents.benchmark.store`) that the run's plan asks for, and writes
``metrics.csv``, ``learning_curves.csv``, ``statistics.json`` (the estimates the report shows),
``report.md`` and, on request, the figures. It evaluates and trains nothing, so it also serves
``stcgym report <run folder>`` on a store committed to a repository, and renders a partial
report of a run cut short (the jobs of the plan with no record are listed as missing).
"""

from __future__ import annotations

import csv
import io
import json
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from stcgym.agents.benchmark.cells import percent
from stcgym.agents.benchmark.config import BenchConfig
from stcgym.agents.benchmark.ladder_report import ladder_rows
from stcgym.agents.benchmark.metrics_csv import METRIC_COLUMNS, format_value
from stcgym.agents.benchmark.rundir import classical_key, job_id, read_run_config
from stcgym.agents.benchmark.scenarios import make_scenarios, training_envs
from stcgym.agents.benchmark.store import STORE_FOLDER, JobRecord, ResultsStore
from stcgym.agents.controllers import YARDSTICK, controllers_for
from stcgym.agents.evaluation.statistics import Estimate

__all__ = [
    "HEADLINE_END",
    "HEADLINE_START",
    "PAGE_BLOCKS",
    "PAGE_END",
    "PAGE_START",
    "RunData",
    "Rendered",
    "load_run",
    "page_blocks",
    "page_headline",
    "page_tables",
    "planned_records",
    "prune_store",
    "render_run",
    "update_page",
]


@dataclass
class RunData:
    """What the report and the figures read besides the rows, all from the store."""

    #: (scenario, controller) -> the first episode's signals of run 0
    traces: dict[tuple[str, str], dict[str, Any]] = field(default_factory=dict)
    #: (scenario, controller) -> each run's adaptation summary
    adaptation: dict[tuple[str, str], list[dict[str, Any]]] = field(default_factory=dict)
    #: learning-curve rows (train_env, algo, train_seed, steps, score)
    curves: list[dict[str, Any]] = field(default_factory=list)
    #: (train_env, algo, train_seed) -> how training ended, with ``kept_step``
    stops: dict[tuple[str, str, int], dict[str, Any]] = field(default_factory=dict)
    #: (train_env, algo, train_seed) -> SB3's update statistics at each evaluation
    diagnostics: dict[tuple[str, str, int], list[dict[str, Any]]] = field(default_factory=dict)
    #: train_env -> the action bound and the LQG input peaks it was set from
    bounds: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: the command line of the run (its first session's)
    argv: list[str] | None = None
    #: agent -> the RL Zoo departures its runs trained with (``config.json``; ``None``: a run
    #: that did not record them, reported with this version's)
    departures: dict[str, list[list[str]]] | None = None


@dataclass
class Rendered:
    """A run read from its store: the config, scenarios, rows in order, the rest, and the
    planned jobs that have no record yet."""

    cfg: BenchConfig
    scenarios: list[Any]
    rows: list[dict[str, Any]]
    data: RunData
    missing: list[str]
    doc: dict[str, Any]

    @property
    def curves(self) -> list[dict[str, Any]]:
        return self.data.curves


def planned_records(cfg: BenchConfig, scenarios: list[Any], run_dir: Path) -> list[tuple]:
    """The records the plan of ``cfg`` asks for, in the report's order: ``(kind, label, id)``
    of every classical controller's run on every scenario, then of every RL job."""
    out = []
    for sc in scenarios:
        for name in controllers_for(cfg.classical, sc.env):
            runs = cfg.runs_of(name)
            out += [("classical", *classical_key(cfg, sc, name, run)) for run in range(runs)]
    if cfg.rl_agents:
        from stcgym.agents.benchmark.plan import rl_tasks

        tasks = rl_tasks(cfg, scenarios, training_envs(cfg, scenarios), {}, run_dir)
        out += [("rl", t.name, job_id(t)) for t in tasks]
    return out


def prune_store(run_dir: str | Path) -> list[Path]:
    """Delete the records of a run folder's store that its plan does not ask for (left by a
    run whose settings changed since: a store about to be committed keeps only what it
    renders); returns the files deleted."""
    run_dir = Path(run_dir)
    cfg, _ = read_run_config(run_dir)
    wanted = {rid for _k, _l, rid in planned_records(cfg, make_scenarios(cfg), run_dir)}
    return ResultsStore(run_dir / STORE_FOLDER, METRIC_COLUMNS).prune(wanted)


def _add(record: JobRecord, data: RunData) -> None:
    for sc_name, result in record.scenarios.items():
        name = record.algo if record.kind == "rl" else result.rows[0]["controller"]
        data.adaptation.setdefault((sc_name, name), []).append(result.adaptation)
        if result.trace:
            data.traces[(sc_name, name)] = result.trace
    if record.kind == "rl":
        job = (record.train_key, record.algo, record.seed)
        data.stops[job] = {**record.stop, "wall_s": record.wall_s}
        data.diagnostics[job] = record.diagnostics
        data.curves += [
            {"train_env": job[0], "algo": job[1], "train_seed": job[2], "steps": s, "score": c}
            for s, c in record.curve
        ]


def load_run(run_dir: str | Path) -> Rendered:
    """Read a run folder: its config, scenarios and the store's records the plan asks for."""
    run_dir = Path(run_dir)
    cfg, doc = read_run_config(run_dir)
    scenarios = make_scenarios(cfg)
    store = ResultsStore(run_dir / STORE_FOLDER, METRIC_COLUMNS)
    data = RunData(
        bounds=dict(doc.get("bound_measurements", {})),
        argv=doc.get("argv"),
        departures=doc.get("zoo_departures"),
    )
    records, missing = [], []
    for _kind, label, rid in planned_records(cfg, scenarios, run_dir):
        record = store.load(label, rid)
        if record is None:
            missing.append(label)
        else:
            records.append(record)
            _add(record, data)
    # the yardstick and zero input first (every ratio and score is read against them), then
    # the controllers in the run's order
    names = [YARDSTICK, "zero", *(a for a in cfg.agents if a not in (YARDSTICK, "zero"))]
    order = {name: i for i, name in enumerate(names)}
    rows = []
    for sc in scenarios:  # scenario by scenario, controllers in that order, runs in order
        found = [(r.scenarios[sc.name].rows, r) for r in records if sc.name in r.scenarios]
        found.sort(key=lambda fr: (order.get(fr[0][0]["controller"], len(order)), fr[0][0]["run"]))
        for rs, _ in found:
            rows += rs
    data.curves.sort(key=lambda c: (c["train_env"], c["algo"], c["train_seed"], c["steps"]))
    return Rendered(cfg, scenarios, rows, data, missing, doc)


def _csv(rows: list[dict[str, Any]], columns: list[str]) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, columns, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: format_value(row.get(k, "")) for k in columns})
    return buffer.getvalue()


def render_run(
    run_dir: str | Path,
    *,
    interrupted: bool = False,
    time_limited: bool = False,
    plots: bool = True,
    log: Callable[[str], None] | None = None,
) -> Rendered:
    """Write ``metrics.csv``, ``learning_curves.csv``, ``statistics.json``, ``report.md`` and
    (``plots``) the figures of a run folder from its store; returns what was read.

    A plan with jobs that have no record yet (a run cut short, or its store copied before the
    end) renders a partial report that says so; ``interrupted`` and ``time_limited`` name why.
    """
    from stcgym.agents.benchmark.report import write_report
    from stcgym.agents.executors import write_atomic

    log = log or (lambda msg: print(msg, file=sys.stderr, flush=True))
    t0 = time.perf_counter()
    run_dir = Path(run_dir)
    run = load_run(run_dir)
    write_atomic(run_dir / "metrics.csv", _csv(run.rows, METRIC_COLUMNS))
    curve_cols = ["train_env", "algo", "train_seed", "steps", "score"]
    write_atomic(run_dir / "learning_curves.csv", _csv(run.data.curves, curve_cols))
    write_report(
        run_dir,
        run.cfg,
        run.scenarios,
        run.rows,
        run.data,
        float(run.doc.get("wall_s", 0.0)),
        interrupted=interrupted,
        time_limited=time_limited or (bool(run.missing) and not interrupted),
        missing=run.missing,
        sessions=int(run.doc.get("sessions", 1)),
    )
    log(f"report written from {len(run.rows)} rows of the store "
        f"({time.perf_counter() - t0:.1f} s)")  # fmt: skip
    if plots and not run.missing and run.cfg.plots:
        from stcgym.agents.benchmark.plots import write_plots

        t0 = time.perf_counter()
        write_plots(run_dir, run.cfg, run.scenarios, run.rows, run.data)
        log(f"plots written ({time.perf_counter() - t0:.1f} s)")
    return run


#: The markers around a page's block of tables rendered from a run (``stcgym report --page``).
PAGE_START = "<!-- tables of results/{run}: rendered by `stcgym report`, do not edit -->"
PAGE_END = "<!-- end of the tables of results/{run} -->"
#: The markers around a page's headline of a run: its first table alone (a page that opens with
#: a run's result and gives every table further down).
HEADLINE_START = "<!-- headline of results/{run}: rendered by `stcgym report`, do not edit -->"
HEADLINE_END = "<!-- end of the headline of results/{run} -->"


def _cell(estimate: dict[str, Any] | None, digits: int = 3) -> str:
    """``value [low, high]`` of an estimate as ``statistics.json`` holds it."""
    return Estimate.from_dict(estimate).format(digits) if estimate else "-"


def page_tables(run_name: str, statistics: dict[str, Any]) -> str:
    """The headline tables of a run for a documentation page, from its ``statistics.json``:
    per scenario, cost / LQG over the bounded episodes (IQM and median, 95 % intervals) and
    the divergence rate beside it, between the :data:`PAGE_START` / :data:`PAGE_END`
    markers (the ladder across its rungs first, where the run has them)."""
    lines = [PAGE_START.format(run=run_name), "", *_ladder_page_table(statistics)]
    for scenario, table in statistics.items():
        lines += _scenario_page_table(scenario, table)
    lines.append(PAGE_END.format(run=run_name))
    return "\n".join(lines)


def page_headline(run_name: str, statistics: dict[str, Any]) -> str:
    """A run's first table alone, between the :data:`HEADLINE_START` / :data:`HEADLINE_END`
    markers: the ladder across its rungs where the run has them, else the table of its first
    scenario."""
    first = next(iter(statistics.items()), None)
    table = _ladder_page_table(statistics) or (
        [] if first is None else _scenario_page_table(*first)
    )
    return "\n".join(
        [HEADLINE_START.format(run=run_name), "", *table, HEADLINE_END.format(run=run_name)]
    )


#: The blocks a page can hold of a run: their markers and what renders them.
PAGE_BLOCKS = {
    "tables": (PAGE_START, PAGE_END, page_tables),
    "headline": (HEADLINE_START, HEADLINE_END, page_headline),
}


def _scenario_page_table(scenario: str, table: dict[str, Any]) -> list[str]:
    """One scenario's rows: runs, IQM and median of cost / LQG, the diverged share."""
    lines = [
        f"`{scenario}`: cost / LQG over the bounded episodes, and the diverged share",
        "",
        "| controller | runs | IQM [95 % CI] | median [95 % CI] | diverged |",
        "|---|---|---|---|---|",
    ]
    for name, est in table.items():
        div = est.get("diverged") or {}
        pct = "-" if div.get("value") is None else percent(Estimate.from_dict(div))
        runs = f"{est.get('runs', '-')}"
        if est.get("untrained_runs"):
            runs += f" (+{est['untrained_runs']} untrained, left out)"
        lines.append(
            f"| `{name}` | {runs} | {_cell(est.get('ratio'))} | "
            f"{_cell(est.get('ratio_median'))} | {pct} |"
        )
    return [*lines, ""]


def _ladder_page_table(statistics: dict[str, Any]) -> list[str]:
    """Where the run has the ladder's rungs: cost / LQG (IQM over the bounded episodes) of
    every controller on each rung's test split, the family's (``siso2-v1``, the last rung's
    plants) last, with the divergence rate where any."""
    rungs = [s for s in statistics if s.startswith("ladder-") and s.endswith(":test")]
    if not rungs:
        return []
    columns = [*rungs, *(["family:test"] if "family:test" in statistics else [])]
    lines = [
        "The ladder: cost / LQG, IQM over the bounded episodes [95 % CI], the diverged share "
        "and the runs whose training never improved on the untrained network (left out) "
        "where any",
        "",
        "| controller | " + " | ".join(f"`{s}`" for s in columns) + " |",
        "|---|" + "---|" * len(columns),
    ]
    rows = ladder_rows(
        statistics, columns, ratio=_cell,
        diverged=lambda est: (est.get("diverged") or {}).get("value") or 0.0,
    )  # fmt: skip
    lines += [f"| `{name}` | " + " | ".join(cells) + " |" for name, cells in rows]
    return [*lines, ""]


def page_blocks(text: str, run: str) -> dict[str, str]:
    """The blocks of ``run`` that the page ``text`` holds, by kind (:data:`PAGE_BLOCKS`), each
    from its start marker to its end marker included."""
    out = {}
    for kind, (start, end, _) in PAGE_BLOCKS.items():
        start, end = start.format(run=run), end.format(run=run)
        if start in text and end in text.split(start, 1)[1]:
            out[kind] = start + text.split(start, 1)[1].split(end, 1)[0] + end
    return out


def update_page(page: str | Path, run_dir: str | Path) -> bool:
    """Replace the blocks of ``run_dir`` in the Markdown file ``page`` (its tables, its
    headline: :data:`PAGE_BLOCKS`) with blocks made from its ``statistics.json``; returns
    whether the page changed. ``ValueError`` when the page has no block for the run (add the
    two marker lines where the tables go)."""
    from stcgym.agents.executors import write_atomic

    page, run_dir = Path(page), Path(run_dir)
    text = page.read_text()
    blocks = page_blocks(text, run_dir.name)
    if not blocks:
        start, end = PAGE_START.format(run=run_dir.name), PAGE_END.format(run=run_dir.name)
        raise ValueError(f"{page} has no block for {run_dir.name}: add the lines\n{start}\n{end}")
    statistics = json.loads((run_dir / "statistics.json").read_text())
    new = text
    for kind, block in blocks.items():
        new = new.replace(block, PAGE_BLOCKS[kind][2](run_dir.name, statistics))
    if new != text:
        write_atomic(page, new)
    return new != text
