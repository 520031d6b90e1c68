"""PNG plots of a bench run (matplotlib, Agg backend: no display needed), in the shared style
of :mod:`stcgym.agents.benchmark.style` (800 px wide, one colour per controller everywhere).

* ``data_efficiency.png``: two panels, offline and online samples on separate axes. Left: the
  RL learning curves, median cost / LQG on the validation episodes against training env steps
  (median over runs, the band between the best and worst run), one row of panels per training
  distribution. Right: what the online learners do with the samples of one episode: cost / LQG
  over each window of the reference's shortest hold against the step within the episode
  (median over the episodes of each run of the in-distribution test scenario, median over
  the runs).
* ``adaptation.png``: cumulative cost above LQG against the time within the episode, median
  over episodes with the interquartile band (median over runs of each run's median, mean of
  its quartiles): on the test split (from step 0) and in the jump scenario (from the jump on),
  for the self-tuning controllers and every RL agent.

Both read the runs' adaptation summaries of the results store
(:mod:`~stcgym.agents.benchmark.adaptation`), not per-step costs.
* ``traces_<scenario>.png``: small multiples, one row per controller on the same axes: y and r
  over the first episode, and the input u.
* ``theta_<scenario>.png``: a self-tuning controller's estimates against the true parameters
  over the first episode of the jump scenario.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from stcgym.agents.benchmark.adaptation import combine
from stcgym.agents.benchmark.style import DPI, WIDTH, color, pyplot
from stcgym.agents.controllers import CONTROLLERS, YARDSTICK

__all__ = [
    "plot_adaptation",
    "plot_data_efficiency",
    "plot_theta",
    "plot_traces",
    "write_plots",
]


def _slug(name: str) -> str:
    return "".join(ch if ch.isalnum() else "_" for ch in name)


def _save(fig: Any, path: Path) -> None:
    if fig.get_layout_engine() is None:
        fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    pyplot().close(fig)


def _shared_legend(fig: Any, axes: Any) -> None:
    """One legend for every panel, below them (never over data), each name once."""
    entries: dict[str, Any] = {}
    for ax in np.ravel(axes):
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            entries.setdefault(label, handle)
    if entries:
        fig.legend(list(entries.values()), list(entries), loc="outside lower center",
                   ncol=min(5, len(entries)))  # fmt: skip


def _learners(data: Any, scenario: str) -> list[str]:
    """The controllers of a scenario that learn: online learners and RL agents."""
    out = []
    for sc, name in data.adaptation:
        if sc != scenario or name in out:
            continue
        info = CONTROLLERS.get(name)
        if info is None or info.online:
            out.append(name)
    return out


def plot_data_efficiency(
    path: Path, curves: Sequence[dict[str, Any]], data: Any, scenario: Any | None
) -> None:
    plt = pyplot()
    keys = list(dict.fromkeys(c["train_env"] for c in curves))
    rows = max(1, len(keys))
    fig, axes = plt.subplots(
        rows, 2, figsize=(WIDTH, 3.2 * rows + 0.8), squeeze=False, layout="constrained"
    )
    for ax, key in zip(axes[:, 0], keys or [None], strict=True):
        if key is None:
            ax.set_axis_off()
            continue
        first = np.inf  # the first evaluation after step 0, over this panel's agents
        for algo in dict.fromkeys(c["algo"] for c in curves if c["train_env"] == key):
            runs: dict[int, list[tuple[float, float]]] = {}
            for c in curves:
                if c["train_env"] == key and c["algo"] == algo:
                    runs.setdefault(c["train_seed"], []).append((c["steps"], c["score"]))
            # step 0 is the untrained policy: the checkpoint kept when training never beats it
            grid = np.unique([s for pts in runs.values() for s, _ in pts])
            if grid.size == 0:
                continue
            if np.any(grid > 0):
                first = min(first, float(grid[grid > 0].min()))
            # each run's curve held at its last point (a run stopped at its plateau)
            table = np.array(
                [np.interp(grid, *zip(*sorted(pts), strict=True)) for pts in runs.values()]
            )
            ax.plot(grid, np.median(table, axis=0), color=color(algo), lw=2, label=algo)
            ax.fill_between(grid, table.min(axis=0), table.max(axis=0), color=color(algo),
                            alpha=0.2, lw=0)  # fmt: skip
        ax.axhline(1.0, color=color(YARDSTICK), lw=1, ls="--", label="LQG")
        # linear from step 0 to the first evaluation, logarithmic after it
        ax.set_xscale("symlog", linthresh=first if np.isfinite(first) else 1.0)
        ax.set_xlim(left=0)
        ax.set(yscale="log", xlabel="training env steps (offline)",
               ylabel="validation cost / LQG", title=f"RL learning curves: {key}")  # fmt: skip
    ax = axes[0, 1]
    if scenario is None:
        ax.set_axis_off()
    else:
        for name in _learners(data, scenario.name):
            runs = combine(data.adaptation[(scenario.name, name)])
            ax.plot(runs["window_ends"], runs["window"], color=color(name), lw=2, label=name)
        ax.axhline(1.0, color=color(YARDSTICK), lw=1, ls="--", label="LQG")
        ax.set(xscale="log", yscale="log", xlabel="step within the episode (online)",
               ylabel="window cost / LQG", title=f"within an episode: {scenario.name}")  # fmt: skip
    for ax in axes[1:, 1]:
        ax.set_axis_off()
    _shared_legend(fig, axes)
    _save(fig, path)


def plot_adaptation(path: Path, data: Any, panels: Sequence[Any]) -> None:
    plt = pyplot()
    fig, axes = plt.subplots(
        1, len(panels), figsize=(WIDTH, 4.2), squeeze=False, layout="constrained"
    )
    for ax, sc in zip(axes[0], panels, strict=True):
        align = sc.kind == "jump"
        lowest = 0.0
        for name in _learners(data, sc.name):
            runs = combine(data.adaptation[(sc.name, name)])
            if "steps" not in runs:
                continue
            steps = runs["steps"]
            ax.plot(steps, runs["excess_q50"], color=color(name), lw=2, label=name)
            ax.fill_between(steps, runs["excess_q25"], runs["excess_q75"], color=color(name),
                            alpha=0.15, lw=0)  # fmt: skip
            lowest = min(lowest, float(np.nanmin(runs["excess_q25"])))
        ax.axhline(0.0, color=color(YARDSTICK), lw=1, ls="--", label="LQG")
        ax.set_yscale("symlog", linthresh=1.0)  # below LQG only as far as some band goes
        ax.set_ylim(bottom=lowest)
        ax.set(xscale="log",
               xlabel="steps after the jump" if align else "step within the episode",
               ylabel="cumulative cost above LQG", title=sc.name)  # fmt: skip
    _shared_legend(fig, axes)
    _save(fig, path)


def plot_traces(path: Path, scenario: Any, data: Any, controllers: Sequence[str]) -> None:
    plt = pyplot()
    names = [c for c in controllers if (scenario.name, c) in data.traces]
    if not names:
        return
    fig, axes = plt.subplots(
        len(names), 2, figsize=(WIDTH, 1.6 * len(names) + 0.8), sharex=True, squeeze=False
    )
    for row, name in zip(axes, names, strict=True):
        tr = data.traces[(scenario.name, name)]
        y, r, u = (np.asarray(tr[k])[0] for k in ("y", "r", "u"))
        t = np.arange(len(y))
        row[0].plot(t, r, color="0.5", lw=1, label="r")
        row[0].plot(t, y, color=color(name), lw=1.2, label="y")
        row[0].set_ylabel(name)
        row[1].plot(np.arange(len(u)), u, color=color(name), lw=1)
        row[1].set_ylabel("u")
    axes[0, 0].legend(loc="upper right", ncol=2)
    axes[0, 0].set_title(f"{scenario.name}: output and reference (first episode)")
    axes[0, 1].set_title("input")
    axes[-1, 0].set_xlabel("step")
    axes[-1, 1].set_xlabel("step")
    _save(fig, path)


def plot_theta(path: Path, scenario: Any, data: Any, name: str) -> None:
    tr = data.traces.get((scenario.name, name))
    if tr is None or "theta" not in tr:
        return
    plt = pyplot()
    theta, est = np.asarray(tr["theta"])[0], np.asarray(tr["theta_hat"])[0]
    k = theta.shape[1]
    n = k // 2
    fig, axes = plt.subplots(2, n, figsize=(WIDTH, 4.4), sharex=True, squeeze=False)
    for j in range(k):
        ax = axes[j // n, j % n]
        label = f"{'ab'[j // n]}{j % n + 1}"
        ax.plot(theta[:, j], color="0.3", lw=1.5, label="true")
        ax.plot(np.arange(1, len(est) + 1), est[:, j], color=color(name), lw=1.2,
                label=f"{name} estimate")  # fmt: skip
        ax.set_title(label)
    axes[0, 0].legend(loc="best")
    for ax in axes[-1]:
        ax.set_xlabel("step")
    fig.suptitle(f"{scenario.name}: {name}'s parameter estimates (first episode)")
    _save(fig, path)


def write_plots(
    run_dir: Path, cfg: Any, scenarios: Sequence[Any], rows: Sequence[dict], data: Any
) -> list[Path]:
    """Write every figure of the module docstring into ``run_dir``; returns their paths."""
    run_dir = Path(run_dir)
    written = []
    test = next((sc for sc in scenarios if sc.kind == "family"), None)
    test = test or next((sc for sc in scenarios if sc.in_distribution), None)
    path = run_dir / "data_efficiency.png"
    plot_data_efficiency(path, data.curves, data, test)
    written.append(path)
    panels = [sc for sc in scenarios if sc.adaptation]
    if panels:
        path = run_dir / "adaptation.png"
        plot_adaptation(path, data, panels)
        written.append(path)
    order = [c for c in cfg.agents if c != "zero"]
    for sc in scenarios:
        if sc.kind in ("nominal", "jump", "mimo", "mimo_switch"):
            path = run_dir / f"traces_{_slug(sc.name)}.png"
            plot_traces(path, sc, data, order)
            written.append(path)
        if sc.kind == "jump":
            tuner = next((c for c in ("stc", "stc_lq", "stc_kfmils") if c in cfg.agents), None)
            if tuner is not None:
                path = run_dir / f"theta_{_slug(sc.name)}.png"
                plot_theta(path, sc, data, tuner)
                written.append(path)
    return [p for p in written if p.exists()]
