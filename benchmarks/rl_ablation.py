"""The RL recipe ablation: PPO's update settings, discount and training reward on the ladder.

Each run trains one agent (``stcgym.agents.rl.sb3.train_agent``, a fixed budget, no plateau
stop, the last policy kept) on the training split of a rung and scores it on 100 validation
plants (one episode each, seeds from 10 000) as the bench does: the median over episodes of
the mean cost per step over LQG's on the same episode. It appends one JSON line per run to
``--out``: the settings, the learning curve, the final and best median ratio, the final
policy's divergences and median ratio over the bounded episodes, and the median and 10-90 %
range of each update diagnostic (approx_kl, clip_fraction, explained_variance, entropy).

Recipes (``--recipe``): ``zoo``, the RL Zoo's Pendulum-v1 PPO entry as the bench ran it
(4 envs x 1024 steps, 10 epochs of batch 64, lr 1e-3); ``healthy``, 16 envs x 256 steps
(16 plants per update), 10 epochs of batch 256, lr 3e-4, ``target_kl`` 0.03;
``healthy_wide``, the same with networks of 256 x 256. For SAC:
``sac_zoo``, the Zoo's one gradient step per env step; ``sac_every4``, one every fourth step;
``sac_vec8``, 8 envs and 2 gradient steps per vector step (the bench's). The reward is
``--reward`` (``lqg_ratio`` or ``cost``).

Usage: one run appends one line to ``--out``::

    nice python benchmarks/rl_ablation.py --family ladder-l1-v1 --recipe healthy \
        --gamma 0.9 --seed 0 --steps 100000 --out ablation/runs.jsonl

``benchmarks/rl_ablation_runs.jsonl`` holds these runs, each for seeds 0, 1 and 2 (two
processes side by side on the shared 2-core machine, about 40 s per 10^5 steps each):

- ``--recipe healthy --gamma G --steps 100000`` for G in 0.9, 0.95, 0.99 on ``ladder-l1-v1``
  and ``ladder-l4-v1``;
- ``--recipe zoo --gamma 0.99 --steps 100000`` on ``ladder-l1-v1``;
- ``--recipe healthy --reward cost --gamma 0.9 --steps 100000`` on ``ladder-l1-v1`` and
  ``ladder-l4-v1``;
- ``--recipe healthy --gamma G --steps 300000`` on ``ladder-l1-v1`` for G in 0.9, 0.95, 0.99,
  and ``--agent oracle_ppo`` with G 0.9;
- ``--recipe healthy --gamma 0.9 --steps 200000`` on ``ladder-l2-v1``, ``ladder-l3-v1``,
  ``ladder-l4-v1``;
- ``--recipe healthy --gamma 0.9 --steps 1000000`` on ``ladder-l1-v1``, for ``ppo`` and
  ``oracle_ppo``;
- ``--agent oracle_ppo --recipe healthy --steps 3000000`` on ``ladder-l1-v1``: ``--gamma 0.9``
  seeds 0 and 1, ``--gamma 0.95`` and ``--gamma 0.99`` seed 0;
- ``--recipe healthy_wide --gamma 0.9 --steps 1000000``: ``ppo`` and ``oracle_ppo`` on
  ``ladder-l1-v1``, seeds 0 and 1; ``oracle_ppo`` on ``ladder-l2-v1`` and ``ppo`` on
  ``ladder-l4-v1``, seed 0 (the last eight beside one other run, as pairs);
- ``--agent oracle_ppo --recipe healthy_wide --gamma 0.9``: ``--steps 3000000`` on
  ``ladder-l2-v1`` seeds 0 and 1, on ``ladder-l1-v1`` and ``ladder-l3-v1`` seed 0;
  ``--steps 10000000`` on ``ladder-l1-v1`` and ``ladder-l2-v1`` seed 2 (as pairs, on the
  otherwise idle machine);
- ``--agent rppo --recipe healthy --gamma 0.9 --steps 100000`` on ``ladder-l1-v1``, seed 0
  only;
- ``--agent sac --recipe R --gamma 0.9 --steps 100000`` on ``ladder-l1-v1`` for R in
  ``sac_zoo`` and ``sac_vec8``, seeds 0 and 1; ``sac_vec8`` with ``--gamma 0.99`` and with
  ``--zero-start``, and ``sac_vec8_lowent``, seed 0 (these ran beside other jobs: their wall
  times are no throughput figures).

The references (deterministic, one line each per rung)::

    python benchmarks/rl_ablation.py --family ladder-l1-v1 --reference zero lqg fixed_pi stc \
        --out ablation/references.jsonl

and the summary: ``python benchmarks/rl_ablation.py --summarise ablation/runs.jsonl
ablation/references.jsonl --out benchmarks/rl_ablation_summary.json`` (prints the table).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from stcgym.agents.controllers import CONTROLLERS
from stcgym.agents.evaluation.bounds import BOUND_SEED, lqg_action_bound
from stcgym.agents.evaluation.env_spec import EnvSpec
from stcgym.agents.evaluation.episodes import EpisodeSet, run_episodes
from stcgym.agents.rl.configs import default_config
from stcgym.agents.rl.learning_curve import CurveOptions, summarise_updates

VALIDATION_SEED = 10_000
#: What every recipe shares (the bench's PPO before this ablation, but for the discount).
BASE: dict[str, Any] = {
    "gae_lambda": 0.95,
    "clip_range": 0.2,
    "ent_coef": 0.0,
    "use_sde": True,
    "sde_sample_freq": 4,
    "policy_kwargs": {"net_arch": [64, 64], "log_std_init": -5.0},
}
RECIPES: dict[str, dict[str, Any]] = {
    "zoo": {"n_envs": 4, "n_steps": 1024, "batch_size": 64, "n_epochs": 10,
            "learning_rate": 1e-3, "target_kl": None},
    "healthy": {"n_envs": 16, "n_steps": 256, "batch_size": 256, "n_epochs": 10,
                "learning_rate": 3e-4, "target_kl": 0.03},
    # ... with networks of 256 x 256 (the capacity question: is a wider policy closer to LQG?)
    "healthy_wide": {"n_envs": 16, "n_steps": 256, "batch_size": 256, "n_epochs": 10,
                     "learning_rate": 3e-4, "target_kl": 0.03, "net_arch": [256, 256]},
    # SAC: the Zoo's Pendulum-v1 entry (one gradient step per env step), and two that take a
    # quarter of the gradient steps: every fourth step of one env, or two steps per step of 8
    "sac_zoo": {"n_envs": 1, "train_freq": 1, "gradient_steps": 1},
    "sac_every4": {"n_envs": 1, "train_freq": 4, "gradient_steps": 1},
    "sac_vec8": {"n_envs": 8, "train_freq": 1, "gradient_steps": 2},
    # ... and its exploration held to a small input: the entropy target of a pre-squash
    # standard deviation of about 0.005 (0.1 of a typical LQG input in units of the bound)
    "sac_vec8_lowent": {"n_envs": 8, "train_freq": 1, "gradient_steps": 2,
                        "target_entropy": -4.0},
}  # fmt: skip


def specs(family: str, bound_episodes: int = 200) -> tuple[EnvSpec, EnvSpec, EpisodeSet]:
    """The rung's training and validation specs (the family's episode settings, as the bench's)
    under its LQG-measured action bound, and the validation episodes."""
    from stcgym.envs.families import get_family

    fam = get_family(family)
    settings = {k: fam[k] for k in ("steps", "noise_std", "control_cost", "y_bound", "reference",
                                    "initial_state_std")}  # fmt: skip
    train = EnvSpec(family=family, split="train", **settings)
    eps = EpisodeSet.of(train, 1, BOUND_SEED, bound_episodes)
    bound, _ = lqg_action_bound(train, eps)
    train = replace(train, action_bound=bound)
    val = replace(train, split="validation")
    return train, val, EpisodeSet.of(val, 1, VALIDATION_SEED)


def controller_costs(name: str, spec: EnvSpec, episodes: EpisodeSet, **kw: Any) -> Any:
    info = CONTROLLERS[name]
    builder = info.build(SimpleNamespace(tuned={}), SimpleNamespace(env=spec, **kw))
    return run_episodes(builder, spec, episodes, informed=info.informed)


def scores(batch: Any, lqg: np.ndarray) -> dict[str, float]:
    """Median cost / LQG over all episodes, and over the bounded ones, the divergence rate."""
    ratio = batch.cost.mean(axis=1) / lqg
    bounded = ratio[~batch.diverged]
    return {
        "median_ratio": float(np.median(ratio)),
        "median_ratio_bounded": float(np.median(bounded)) if bounded.size else float("nan"),
        "diverged": float(np.mean(batch.diverged)),
    }


def _zero_started_models() -> None:
    """Make every model this process builds start with its mean action at zero (the
    untrained policy is zero input), as the residual agents' do: the ``--zero-start`` arm."""
    from stcgym.agents.rl import sb3

    build = sb3.build_model

    def zero_started(*args: Any, **kw: Any) -> Any:
        model = build(*args, **kw)
        sb3._zero_mean_action(model.policy)
        return model

    sb3.build_model = zero_started


def train_run(args: argparse.Namespace) -> dict[str, Any]:
    from stcgym.agents.rl.sb3 import train_agent

    if args.zero_start:
        _zero_started_models()

    train, val, episodes = specs(args.family)
    lqg = controller_costs("lqg", val, episodes).cost.mean(axis=1)
    config = default_config(args.agent)
    recipe = dict(RECIPES[args.recipe])
    config.n_envs = recipe.pop("n_envs")
    net_arch = recipe.pop("net_arch", BASE["policy_kwargs"]["net_arch"])
    # the PPO family shares BASE; SAC keeps its own settings but for the recipe's
    on_policy = not args.recipe.startswith("sac")
    shared = {k: v for k, v in BASE.items() if k != "policy_kwargs"} if on_policy else {}
    config.hyperparams = {**config.hyperparams, **shared, **recipe, "gamma": args.gamma}
    if args.agent in ("ppo", "oracle_ppo", "theta_ppo"):
        config.hyperparams["policy_kwargs"] = {**BASE["policy_kwargs"], "net_arch": net_arch}
    config.normalize_reward, config.normalize_obs = True, True
    config.reward = args.reward
    t0 = time.perf_counter()
    agent = train_agent(
        args.agent, config, train, args.steps, args.seed,
        curve=CurveOptions(val, episodes, 4, lqg.tolist(), keep_best=False), progress=False,
        tensorboard_log=None if args.tensorboard is None else str(args.tensorboard),
        tb_log_name=f"{args.family}_{args.agent}_{args.recipe}_g{args.gamma}_s{args.seed}",
    )  # fmt: skip
    final = run_episodes(
        lambda plants, seeds: agent.policy.with_lanes(len(plants), seeds, plants),
        val,
        episodes,
        informed=agent.policy.informed,
    )
    curve = [[int(s), float(c)] for s, c in agent.curve]
    return {
        "family": args.family, "agent": args.agent, "recipe": args.recipe,
        "zero_start": args.zero_start,
        "reward": args.reward, "gamma": args.gamma, "seed": args.seed, "steps": agent.steps,
        "action_bound": train.action_bound, "wall_s": time.perf_counter() - t0,
        "final": scores(final, lqg), "best_curve": min(c for _, c in curve),
        "curve": curve, "updates": summarise_updates(agent.updates),
    }  # fmt: skip


def reference_runs(args: argparse.Namespace) -> list[dict[str, Any]]:
    train, val, episodes = specs(args.family)
    lqg = controller_costs("lqg", val, episodes).cost.mean(axis=1)
    out = []
    for name in args.reference:
        t0 = time.perf_counter()
        batch = controller_costs(name, val, episodes, train_env=train, controller_order=2)
        out.append({"family": args.family, "agent": name, "action_bound": train.action_bound,
                    "wall_s": time.perf_counter() - t0, "final": scores(batch, lqg)})  # fmt: skip
    return out


def summarise(paths: list[Path]) -> dict[str, Any]:
    """Per (family, agent, recipe, reward, gamma, budget): the seeds' final median ratios,
    their median and range, and the medians of the runs' update diagnostics."""
    rows = [
        json.loads(line) for path in paths for line in path.read_text().splitlines() if line.strip()
    ]
    groups: dict[str, list[dict[str, Any]]] = {}
    for row in rows:
        budget = f"{round(row['steps'], -4):.0e}" if "steps" in row else "-"
        fields = [str(row.get(k, "-")) for k in ("family", "agent", "recipe", "reward", "gamma")]
        if row.get("zero_start"):  # the --zero-start arm
            fields[2] += "+zero_start"
        groups.setdefault("/".join([*fields, budget]), []).append(row)
    table = {}
    for key, runs in sorted(groups.items()):
        final = [r["final"]["median_ratio"] for r in runs]
        entry = {
            "runs": len(runs),
            "seeds": [r.get("seed") for r in runs],
            "final_median_ratio": final,
            "median": float(np.median(final)),
            "min": float(np.min(final)),
            "max": float(np.max(final)),
            "diverged": [r["final"]["diverged"] for r in runs],
            "median_ratio_bounded": [r["final"]["median_ratio_bounded"] for r in runs],
        }
        if "best_curve" in runs[0]:
            entry["best_curve"] = [r["best_curve"] for r in runs]
        for name in ("approx_kl", "clip_fraction", "explained_variance", "entropy_loss", "std"):
            values = [r["updates"][name]["median"] for r in runs if name in r.get("updates", {})]
            if values:
                entry[name] = float(np.median(values))
        table[key] = entry
    return table


def markdown(table: dict[str, Any]) -> str:
    """The summary as a Markdown table: the seeds' median (range) of the final median cost /
    LQG, the divergence rate and the update diagnostics' medians."""

    def num(entry: dict[str, Any], key: str) -> str:
        return f"{entry[key]:.3g}" if key in entry else "-"

    lines = [
        "| family / agent / recipe / reward / gamma / steps | runs | cost / LQG: median (range) "
        "| diverged | approx_kl | clip_fraction | explained var. |",
        "|---|---|---|---|---|---|---|",
    ]
    for key, e in table.items():
        div = float(np.median(e["diverged"]))
        lines.append(
            f"| {key} | {e['runs']} | {e['median']:.2f} ({e['min']:.2f}-{e['max']:.2f}) "
            f"| {div:.2f} | {num(e, 'approx_kl')} | {num(e, 'clip_fraction')} "
            f"| {num(e, 'explained_variance')} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--family", default="ladder-l1-v1")
    parser.add_argument("--agent", default="ppo")
    parser.add_argument("--recipe", default="healthy", choices=sorted(RECIPES))
    parser.add_argument("--reward", default="lqg_ratio", choices=("lqg_ratio", "cost"))
    parser.add_argument("--gamma", type=float, default=0.95)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--zero-start",
        action="store_true",
        help="start every policy's mean action at zero (zero input)",
    )
    parser.add_argument("--steps", type=int, default=100_000)
    parser.add_argument("--out", type=Path, default=Path("ablation/runs.jsonl"))
    parser.add_argument("--tensorboard", type=Path, default=None)
    parser.add_argument("--reference", nargs="*", default=None)
    parser.add_argument("--summarise", type=Path, nargs="+", default=None)
    args = parser.parse_args()
    if args.summarise is not None:
        table = summarise(args.summarise)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        tmp = args.out.with_suffix(".tmp")
        tmp.write_text(json.dumps(table, indent=1) + "\n")
        os.replace(tmp, args.out)
        print(markdown(table))
        return
    rows = reference_runs(args) if args.reference else [train_run(args)]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with args.out.open("a") as f:
        for row in rows:
            f.write(json.dumps(row) + "\n")
            print(json.dumps({k: v for k, v in row.items() if k not in ("curve", "updates")}))


if __name__ == "__main__":
    main()
