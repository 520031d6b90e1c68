"""PNG plots of a bench run (matplotlib, Agg backend: no display needed).

* ``data_efficiency.png``: cost / oracle cost against environment steps (log x): RL learning
  curves (training steps; median over training seeds, one thin line per seed) and the
  self-tuning controller's (``stc``; ``stc_mimo`` on a MIMO plant: the first online controller
  of the run's agents) cost per reference half-period against its adaptation steps
  (median and quartiles over episodes), on the same axes; the oracle (1) and LQG as lines.
  Each training seed's curve ends in a marker: a dot where the plateau rule stopped it, a
  cross where it reached its cap before a plateau.
* ``theta_<scenario>.png``: the self-tuning controller's estimates theta_hat(t) against the
  true theta(t), one panel per parameter, jump marked (the first online controller of the
  run's agents with an estimate); in a ``mimo`` scenario the relative error of the estimate
  ``[A_hat B_hat]`` instead (:func:`plot_estimate_error`).
* ``traces_<scenario>.png``: small multiples, one row per controller on the same axes: y and r
  over the episode, y and r over the first 100 steps, u over the first 100 steps (one line per
  output and input of a MIMO plant).
* ``jump_cost_<scenario>.png``: cost per reference period (trailing window, so nothing moves
  before the jump) around the jump, median over seeds.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from stcgym.agents.controllers import CONTROLLERS

__all__ = [
    "plot_data_efficiency",
    "plot_estimate_error",
    "plot_jump_cost",
    "plot_theta",
    "plot_traces",
    "write_plots",
]

ZOOM = 100  # steps shown in the start-up panels


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _slug(name: str) -> str:
    return "".join(ch if ch.isalnum() else "_" for ch in name)


def _save(fig: Any, path: Path) -> None:
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    _plt().close(fig)


def plot_traces(path: Path, scenario: Any, episodes: dict[str, Any]) -> None:
    """Small multiples: one row per controller, same axes in every row."""
    plt = _plt()
    names = list(episodes)
    fig, axes = plt.subplots(
        len(names),
        3,
        figsize=(13, 1.9 * len(names) + 0.6),
        sharex="col",
        sharey="col",
        squeeze=False,
        gridspec_kw={"width_ratios": [3, 1.3, 1.3]},
    )
    r0 = next(iter(episodes.values())).r
    amp = max(1.0, float(np.nanmax(np.abs(r0))))
    umax = max(float(np.nanmax(np.abs(ep.u[:ZOOM]))) for ep in episodes.values())
    for row, name in zip(axes, names, strict=True):
        ep = episodes[name]
        k = np.arange(len(ep.y))
        for ax, stop in ((row[0], len(k)), (row[1], ZOOM + 1)):
            ax.plot(k[:stop], ep.r[:stop], "k--", lw=0.8)
            ax.plot(k[:stop], ep.y[:stop], lw=0.9, color="C0")
            ax.set_ylim(-2.5 * amp, 2.5 * amp)
            if scenario.env.jump_step is not None and stop > scenario.env.jump_step:
                ax.axvline(scenario.env.jump_step, color="grey", ls=":", lw=1)
        row[2].plot(np.arange(min(ZOOM, len(ep.u))), ep.u[:ZOOM], lw=0.9, color="C3")
        row[2].set_ylim(-1.1 * umax - 1e-9, 1.1 * umax + 1e-9)
        row[0].set_ylabel(name, rotation=0, ha="right", va="center", fontsize=10)
        if ep.diverged:
            row[0].text(0.01, 0.85, "diverged", transform=row[0].transAxes, color="red")
    axes[0, 0].set_title(f"{scenario.name}, seed {next(iter(episodes.values())).seed}: y, r")
    axes[0, 1].set_title(f"y, r: first {ZOOM} steps")
    axes[0, 2].set_title(f"u: first {ZOOM} steps")
    for ax in axes[-1]:
        ax.set_xlabel("step")
    _save(fig, path)


def plot_data_efficiency(
    path: Path,
    curves: Sequence[dict[str, Any]],
    adaptation: dict[str, tuple[np.ndarray, np.ndarray, str]],
    reference_lines: dict[str, dict[str, float]],
    stops: dict[tuple[str, str, Any], dict[str, Any]] | None = None,
) -> None:
    """Cost / oracle against env steps, one panel per training environment (module doc);
    ``stops``: ``(train_env, algo, train_seed) -> {"status": "plateau" | "cap", ...}``."""
    stops = stops or {}
    marker = {"plateau": "o", "cap": "x"}
    plt = _plt()
    envs = list(dict.fromkeys([*adaptation, *(c["train_env"] for c in curves)]))
    # one colour per algorithm in every panel
    colour = {a: f"C{i}" for i, a in enumerate(dict.fromkeys(c["algo"] for c in curves))}
    fig, axes = plt.subplots(1, len(envs), figsize=(6 * len(envs), 4.5), squeeze=False)
    for ax, env in zip(axes[0], envs, strict=True):
        algos = list(dict.fromkeys(c["algo"] for c in curves if c["train_env"] == env))
        for algo in algos:
            pts = [c for c in curves if c["train_env"] == env and c["algo"] == algo]
            seeds = sorted({c["train_seed"] for c in pts})
            per_seed = []
            for s in seeds:
                xy = np.array(
                    [(c["steps"], c["cost_to_oracle"]) for c in pts if c["train_seed"] == s]
                )
                xy = xy[xy[:, 0] > 0]  # step 0 has no place on a log axis
                ax.plot(xy[:, 0], xy[:, 1], color=colour[algo], lw=0.6, alpha=0.35)
                status = stops.get((env, algo, s), {}).get("status")
                if status in marker and len(xy):
                    ax.plot(*xy[-1], marker[status], color=colour[algo], ms=6, alpha=0.8)
                per_seed.append(xy)
            n = min(len(xy) for xy in per_seed)
            if n:
                steps = np.median([xy[:n, 0] for xy in per_seed], axis=0)
                med = np.median([xy[:n, 1] for xy in per_seed], axis=0)
                ax.plot(
                    steps, med, "o-", ms=3, color=colour[algo], label=f"{algo} (training steps)"
                )
        if env in adaptation:
            ends, ratios, learner = adaptation[env]
            q25, med, q75 = np.nanpercentile(ratios, [25, 50, 75], axis=0)
            ax.plot(ends, med, "s-", ms=3, color="k", label=f"{learner} (adaptation steps)")
            ax.fill_between(ends, q25, q75, color="k", alpha=0.15, lw=0)
        if any(k[0] == env for k in stops):
            ax.plot([], [], "o", color="grey", label="seed stopped at its plateau")
            ax.plot([], [], "x", color="grey", label="seed at its cap, before a plateau")
        ax.axhline(1.0, color="grey", lw=1.2, label="oracle")
        ax.axhline(1.2, color="grey", lw=0.8, ls=":", label="1.2x oracle")
        ref = reference_lines.get(env, {})
        if "lqg" in ref and ref.get("oracle"):
            ax.axhline(ref["lqg"] / ref["oracle"], color="C9", ls="--", lw=1.2, label="LQG")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"{env}: cost / oracle cost vs data")
        ax.set_xlabel("environment steps (log)")
        ax.set_ylabel("cost / oracle cost (same episodes)")
        ax.legend(fontsize=7)
    _save(fig, path)


def plot_theta(path: Path, scenario: Any, episode: Any) -> None:
    """theta_hat(t) (self-tuning controller) against the true theta(t)."""
    plt = _plt()
    theta, theta_hat = episode.theta, episode.theta_hat
    m = theta.shape[1]
    n = m // 2
    labels = [f"a{i + 1}" for i in range(n)] + [f"b{i + 1}" for i in range(n)]
    fig, axes = plt.subplots(n, 2, figsize=(11, 2.4 * n + 0.5), sharex=True, squeeze=False)
    for j in range(m):
        ax = axes[j % n, j // n]
        ax.plot(np.arange(len(theta)), theta[:, j], "k-", lw=1.4, label="true")
        ax.plot(np.arange(1, len(theta_hat) + 1), theta_hat[:, j], "C1", lw=1, label="estimate")
        lo, hi = np.nanmin(theta[:, j]), np.nanmax(theta[:, j])
        pad = max(0.5 * (hi - lo), 0.5 * max(abs(lo), abs(hi)), 0.2)
        ax.set_ylim(lo - pad, hi + pad)
        ax.set_ylabel(labels[j])
        if scenario.env.jump_step is not None:
            ax.axvline(scenario.env.jump_step, color="grey", ls=":", lw=1)
    axes[0, 0].legend(fontsize=8)
    axes[0, 0].set_title(f"{scenario.name}, seed {episode.seed}: theta_hat(t) vs theta(t)")
    for ax in axes[-1]:
        ax.set_xlabel("step")
    _save(fig, path)


def plot_estimate_error(path: Path, scenario: Any, episode: Any) -> None:
    """``||[A_hat B_hat] - [A B]||_F / ||[A B]||_F`` against the step (log y)."""
    from stcgym.agents.benchmark.mimo import estimate_error

    plt = _plt()
    err = estimate_error(episode.theta, episode.theta_hat)
    fig, ax = plt.subplots(figsize=(10, 3.5))
    ax.plot(np.arange(1, len(err) + 1), err, "C1", lw=1)
    ax.set_yscale("log")
    ax.set_title(f"{scenario.name}, seed {episode.seed}: relative error of [A_hat B_hat]")
    ax.set_xlabel("step")
    ax.set_ylabel("||estimate - true||_F / ||true||_F")
    _save(fig, path)


def plot_jump_cost(path: Path, scenario: Any, costs: dict[str, list[np.ndarray]]) -> None:
    """Mean cost over the trailing reference period, median over seeds, around the jump."""
    plt = _plt()
    period = scenario.env.period
    fig, ax = plt.subplots(figsize=(10, 4))
    for name, runs in costs.items():
        c = np.median(np.vstack(runs), axis=0)
        cs = np.concatenate(([0.0], np.cumsum(c)))
        trailing = (cs[period:] - cs[:-period]) / period  # window ending at each step
        ax.plot(np.arange(period, len(c) + 1), trailing, lw=1.2, label=name)
    J = scenario.env.jump_step
    ax.axvline(J, color="grey", ls=":", lw=1)
    ax.set_yscale("log")
    ax.set_xlim(max(0, J - 2 * period), None)
    ax.set_title(f"{scenario.name}: cost over the last reference period (median over seeds)")
    ax.set_xlabel("step (end of the window)")
    ax.set_ylabel("mean cost per step")
    ax.legend(fontsize=8)
    _save(fig, path)


def write_plots(
    run_dir: Path,
    cfg: Any,
    scenarios: Sequence[Any],
    rows: Sequence[dict[str, Any]],
    data: Any,
) -> list[Path]:
    """Write every plot; returns the paths."""
    paths = []
    order = list(cfg.agents)
    for sc in scenarios:
        eps = {c: data.traces[(sc.name, c)] for c in order if (sc.name, c) in data.traces}
        if eps:
            p = Path(run_dir) / f"traces_{_slug(sc.name)}.png"
            plot_traces(p, sc, eps)
            paths.append(p)
        online = [c for c in order if c in CONTROLLERS and CONTROLLERS[c].online]
        learner = [data.traces[(sc.name, c)] for c in online if (sc.name, c) in data.traces]
        if learner and learner[0].theta is not None:
            p = Path(run_dir) / f"theta_{_slug(sc.name)}.png"
            plot = plot_estimate_error if sc.kind == "mimo" else plot_theta
            plot(p, sc, learner[0])
            paths.append(p)
        if sc.env.jump_step is not None:
            jc = {c: data.costs[(sc.name, c)] for c in order if (sc.name, c) in data.costs}
            if jc:
                p = Path(run_dir) / f"jump_cost_{_slug(sc.name)}.png"
                plot_jump_cost(p, sc, jc)
                paths.append(p)
    if data.curves or data.adaptation:
        p = Path(run_dir) / "data_efficiency.png"
        plot_data_efficiency(
            p, data.curves, data.adaptation, data.reference_lines, getattr(data, "stops", {})
        )
        paths.append(p)
    return paths
