"""PNG plots of a bench run (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["write_plots"]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _slug(name: str) -> str:
    return "".join(ch if ch.isalnum() else "_" for ch in name)


def plot_traces(path: Path, scenario: Any, episodes: dict[str, Any]) -> None:
    """y and r (top), u (bottom) of every controller on one seed."""
    plt = _plt()
    fig, (ax_y, ax_u) = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    ref_drawn = False
    for name, ep in episodes.items():
        k = np.arange(len(ep.y))
        if not ref_drawn:
            ax_y.plot(k, ep.r, "k--", lw=1, label="r")
            ref_drawn = True
        ax_y.plot(k, ep.y, lw=1, label=name)
        ax_u.plot(np.arange(len(ep.u)), ep.u, lw=1, label=name)
    if scenario.env.jump_step is not None:
        for ax in (ax_y, ax_u):
            ax.axvline(scenario.env.jump_step, color="grey", ls=":", lw=1)
    seed = next(iter(episodes.values())).seed
    ax_y.set_title(f"{scenario.name}, seed {seed}")
    ax_y.set_ylabel("y (noise-free), r")
    ax_u.set_ylabel("u")
    ax_u.set_xlabel("step")
    # Keep divergent traces from squashing the others.
    ylim = 3 * max(1.0, float(np.nanmax(np.abs(next(iter(episodes.values())).r))))
    ax_y.set_ylim(-ylim, ylim)
    ax_y.legend(loc="upper right", fontsize=8, ncol=3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_learning_curves(
    path: Path, curves: Sequence[dict[str, Any]], reference_lines: dict[str, dict[str, float]]
) -> None:
    """Cost vs training steps, one panel per training environment, classical as lines."""
    plt = _plt()
    envs = list(dict.fromkeys(c["train_env"] for c in curves))
    fig, axes = plt.subplots(1, len(envs), figsize=(5 * len(envs), 4), squeeze=False)
    for ax, env in zip(axes[0], envs, strict=True):
        algos = list(dict.fromkeys(c["algo"] for c in curves if c["train_env"] == env))
        for i, algo in enumerate(algos):
            seeds = sorted(
                {c["train_seed"] for c in curves if c["train_env"] == env and c["algo"] == algo}
            )
            for s in seeds:
                pts = [
                    (c["steps"], c["cost"])
                    for c in curves
                    if c["train_env"] == env and c["algo"] == algo and c["train_seed"] == s
                ]
                x, y = np.array(pts).T
                ax.plot(
                    x,
                    y,
                    "o-",
                    ms=3,
                    color=f"C{i}",
                    alpha=1.0 if s == seeds[0] else 0.4,
                    label=algo if s == seeds[0] else None,
                )
        for j, (name, level) in enumerate(reference_lines.get(env, {}).items()):
            ax.axhline(level, color=f"C{len(algos) + j}", ls="--", label=name)
        ax.set_yscale("log")
        ax.set_title(f"trained on {env}")
        ax.set_xlabel("training env steps")
        ax.set_ylabel("mean cost per step")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_jump_cost(path: Path, scenario: Any, costs: dict[str, list[np.ndarray]]) -> None:
    """Mean cost per reference period around the jump, median over seeds."""
    plt = _plt()
    period = scenario.env.period
    fig, ax = plt.subplots(figsize=(10, 4))
    for name, runs in costs.items():
        c = np.median(np.vstack(runs), axis=0)
        kernel = np.ones(period) / period
        smooth = np.convolve(c, kernel, mode="valid")  # forward window starting at each step
        ax.plot(np.arange(len(smooth)), smooth, lw=1.2, label=name)
    J = scenario.env.jump_step
    ax.axvline(J, color="grey", ls=":", lw=1)
    ax.set_yscale("log")
    ax.set_xlim(max(0, J - 2 * period), None)
    ax.set_title(f"{scenario.name}: cost per reference period after the jump (median over seeds)")
    ax.set_xlabel("step (start of the period window)")
    ax.set_ylabel("mean cost per step")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write_plots(
    run_dir: Path,
    cfg: Any,
    scenarios: Sequence[Any],
    traces: dict[tuple[str, str], Any],
    jump_costs: dict[tuple[str, str], list[np.ndarray]],
    curves: Sequence[dict[str, Any]],
    reference_lines: dict[str, dict[str, float]],
) -> list[Path]:
    """Write every plot; returns the paths."""
    paths = []
    order = list(cfg.agents)
    for sc in scenarios:
        eps = {c: traces[(sc.name, c)] for c in order if (sc.name, c) in traces}
        if eps:
            p = Path(run_dir) / f"traces_{_slug(sc.name)}.png"
            plot_traces(p, sc, eps)
            paths.append(p)
        jc = {c: jump_costs[(sc.name, c)] for c in order if (sc.name, c) in jump_costs}
        if jc:
            p = Path(run_dir) / f"jump_cost_{_slug(sc.name)}.png"
            plot_jump_cost(p, sc, jc)
            paths.append(p)
    if curves:
        p = Path(run_dir) / "learning_curves.png"
        plot_learning_curves(p, curves, reference_lines)
        paths.append(p)
    return paths
