"""The ``stcgym`` command.

``stcgym bench --quick``
    The README's main job: the self-tuning controller, the known-model and LQG oracles and PPO,
    SAC and TD3 (trained on the spot) on the nominal, plant-family and parameter-jump
    scenarios; about 5-10 minutes on 2 CPU cores. ``stcgym bench`` (or ``--full``) is the full
    version: more plants, A2C, 3 training seeds, 20 evaluation seeds, 10x budgets (hours).
``stcgym eval MODEL_DIR``
    Re-evaluate a saved RL agent (a ``models/*`` folder of a bench run).

Every input is checked before anything is trained; errors print one line and exit with
status 2. Ctrl-C keeps the finished rows of ``metrics.csv`` (exit status 130).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

__all__ = ["main", "build_parser"]


def _bench_parser(sub: argparse._SubParsersAction) -> None:
    from stcgym.agents.configs import ALGORITHMS
    from stcgym.envs.catalogue import plant_names

    p = sub.add_parser(
        "bench",
        help="benchmark the self-tuning controller against RL agents",
        description="Benchmark the self-tuning controller against RL agents and known-model "
        "oracles; writes results/<run>/ (metrics.csv, report.md, PNG plots, config.json).",
    )
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--quick", action="store_true", help="~5-10 min on 2 CPU cores")
    mode.add_argument(
        "--full", action="store_true", help="all plants and agents, long budgets (the default)"
    )
    p.add_argument("--scenarios", help="comma list of nominal,family,jump (default: all)")
    p.add_argument(
        "--plants", help=f"nominal-scenario plants (catalogue: {','.join(plant_names())})"
    )
    p.add_argument("--family-train", help="plants RL trains on in the family scenario")
    p.add_argument("--family-test", help="held-out plants of the family scenario")
    p.add_argument(
        "--jump",
        action="append",
        dest="jumps",
        help="jump scenario: 'timevarying2' or BEFORE:AFTER plant names (repeatable)",
    )
    p.add_argument(
        "--agents",
        help=f"comma list of {','.join(ALGORITHMS)},stc,oracle,lqg "
        "(quick default: ppo,sac,td3,stc,oracle)",
    )
    p.add_argument(
        "--train-steps",
        help="RL training budget in env steps: N for every agent, or ppo=N,sac=M",
    )
    p.add_argument("--train-seeds", type=int, help="RL training seeds per agent")
    p.add_argument("--seeds", type=int, help="evaluation episodes (seeds) per scenario")
    p.add_argument("--first-seed", type=int, default=1000, help="first evaluation seed")
    p.add_argument("--episode-steps", type=int, help="evaluation episode length")
    p.add_argument("--train-episode-steps", type=int, help="RL training episode length")
    p.add_argument("--noise", type=float, default=0.05, help="output noise std (default 0.05)")
    p.add_argument(
        "--train-y-bound",
        type=float,
        help="end RL training episodes once |y| exceeds this (x reference amplitude); "
        "default: the environment's bound",
    )
    p.add_argument(
        "--hp",
        action="append",
        default=[],
        metavar="ALGO.KEY=VALUE",
        help="override a hyperparameter, e.g. ppo.learning_rate=3e-4 (repeatable)",
    )
    p.add_argument("--curve-points", type=int, default=10, help="learning-curve points")
    p.add_argument("--out", default="results", help="output folder (default results/)")
    p.add_argument("--run", help="run name (default: timestamp and mode)")
    p.add_argument("--overwrite", action="store_true", help="reuse an existing run folder")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    bar = p.add_mutually_exclusive_group()
    bar.add_argument(
        "--progress",
        dest="progress",
        action="store_true",
        default=None,
        help="SB3 progress bar (default: when stderr is a terminal)",
    )
    bar.add_argument("--no-progress", dest="progress", action="store_false")


def _eval_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("eval", help="evaluate a saved RL agent (a bench models/ folder)")
    p.add_argument("model_dir", help="folder holding agent.json and model.zip")
    p.add_argument("--plant", help="catalogue plant (default: the first training plant)")
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--first-seed", type=int, default=1000)
    p.add_argument("--episode-steps", type=int, default=1000)
    p.add_argument("--noise", type=float, default=None, help="default: as in training")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="stcgym", description="stcgym: self-tuning control vs RL benchmark"
    )
    sub = parser.add_subparsers(dest="command", required=True)
    _bench_parser(sub)
    _eval_parser(sub)
    return parser


def _run_bench(args: argparse.Namespace, argv: Sequence[str]) -> int:
    from stcgym.agents.bench import build_config, run_bench

    cfg = build_config(
        quick=args.quick,
        run=args.run,
        out=args.out,
        scenarios=args.scenarios,
        plants=args.plants,
        family_train=args.family_train,
        family_test=args.family_test,
        jumps=args.jumps,
        agents=args.agents,
        train_steps=args.train_steps,
        train_seeds=args.train_seeds,
        seeds=args.seeds,
        first_seed=args.first_seed,
        episode_steps=args.episode_steps,
        train_episode_steps=args.train_episode_steps,
        noise_std=args.noise,
        train_y_bound=args.train_y_bound,
        hp=args.hp,
        curve_points=args.curve_points,
        plots=not args.no_plots,
        progress=args.progress,
    )
    result = run_bench(cfg, overwrite=args.overwrite, argv=list(argv))
    print(result.run_dir / "report.md")
    return 0


def _run_eval(args: argparse.Namespace) -> int:
    from dataclasses import asdict

    from stcgym.agents.bench import BenchInputError
    from stcgym.agents.evaluate import EnvSpec, evaluate, summarize
    from stcgym.agents.sb3 import load_agent

    if args.seeds < 1 or args.episode_steps < 1:
        raise BenchInputError("--seeds and --episode-steps must be >= 1")
    agent = load_agent(args.model_dir)
    spec = agent.train_spec
    plant = args.plant or spec.plants[0]
    fields = {**asdict(spec), "plants": (plant,), "steps": args.episode_steps}
    if args.noise is not None:
        fields["noise_std"] = args.noise
    env = EnvSpec(**fields)
    seeds = [args.first_seed + i for i in range(args.seeds)]
    res = evaluate(agent.policy, env, seeds, plant=plant)
    costs = [m["cost"] for m in res.metrics]
    s = summarize(costs, [not m["bounded"] for m in res.metrics])
    print(
        f"{agent.algo} (seed {agent.seed}, {agent.steps} steps) on {plant}: median cost "
        f"{s['median']:.4g} [IQR {s['iqr']:.3g}], CVaR25 {s['cvar25']:.4g}, failure rate "
        f"{s['failure_rate']:.2f}"
    )
    for seed, m in zip(seeds, res.metrics, strict=True):
        print(f"  seed {seed}: cost {m['cost']:.4g} steady {m['cost_steady']:.4g}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``stcgym`` console script; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    from stcgym.agents.bench import BenchInputError

    try:
        if args.command == "bench":
            return _run_bench(args, argv)
        return _run_eval(args)
    except (BenchInputError, FileNotFoundError) as exc:
        print(f"stcgym {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("stcgym: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
