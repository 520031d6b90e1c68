"""The ``stcgym`` command.

``stcgym bench`` (= ``stcgym bench --quick``, ``make bench``)
    The self-tuning controllers, PPO, SAC and estimate-conditioned PPO (3 runs each, trained on
    the spot through the task executor), pole placement on the true model and zero input, all
    scored against LQG on the true model, on the same episodes of the nominal, plant-family
    (test split and held-out variants), parameter-jump and MIMO scenarios; about 4 minutes on
    2 CPU cores.
    ``stcgym bench --standard`` (about 2 hours with every RL agent at its cap) has 5 runs,
    the whole test split, every held-out variant and rung of the difficulty ladder, and RL
    caps of 10^6 steps on the family;
    ``stcgym bench --full`` is the long version (10 runs, every MIMO plant, TD3 and A2C too,
    longer caps: about 23 hours).
    Every tier trains each RL agent until its learning curve plateaus or it reaches its cap,
    and announces its estimated time. ``stcgym bench --resume results/<run>`` continues an
    interrupted run without retraining its finished jobs; ``--time-limit 2h45m`` starts only
    the jobs estimated to end in time and leaves the rest for ``--resume``.
``stcgym eval MODEL_DIR``
    Re-evaluate a saved RL agent (a ``models/*`` folder of a bench run).
``stcgym sweep FAMILY``
    Classical controllers over a random plant family (:mod:`stcgym.agents.sweeps`).

Every option is checked before any work starts (hyperparameters against each algorithm's
rules and SB3's own constructor); errors print one line and exit with status 2. Ctrl-C keeps
the finished rows of ``metrics.csv`` (exit status 130).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

__all__ = ["main", "build_parser"]


def _bench_parser(sub: argparse._SubParsersAction) -> None:
    from stcgym.agents.benchmark.config import QUICK_MIMO_INTERVALS, BenchConfig
    from stcgym.agents.benchmark.tiers import FULL, QUICK, SCENARIO_KINDS, STANDARD
    from stcgym.agents.controllers import CONTROLLERS
    from stcgym.agents.executors import EXECUTORS
    from stcgym.agents.rl.configs import ALGORITHMS, DEFAULT_CONFIGS
    from stcgym.agents.rl.stopping import PlateauRule
    from stcgym.envs.catalogue import plant_names
    from stcgym.envs.families import FAMILIES
    from stcgym.envs.mimo_plants import mimo_plant_names

    p = sub.add_parser(
        "bench",
        help="benchmark the self-tuning controller against RL agents",
        description="Benchmark the self-tuning controller against RL agents and known-model "
        "oracles; writes results/<run>/ (metrics.csv, report.md, PNG plots, config.json). "
        "Without --standard or --full it runs the quick preset.",
    )
    mode = p.add_mutually_exclusive_group()
    mode.add_argument(
        "--smoke",
        action="store_true",
        help="a one-minute end-to-end check: PPO and the self-tuning controllers on a few short "
        "episodes of one plant and of the family, one run, PPO for one evaluation interval",
    )
    mode.add_argument(
        "--quick", action="store_true", help="the default: about 4 min on 2 CPU cores"
    )
    mode.add_argument(
        "--standard",
        action="store_true",
        help="5 runs per controller, the whole test split, every held-out variant and rung of "
        "the difficulty ladder, RL trained to the plateau with caps of 1e6 env steps on the "
        "family for PPO and RecurrentPPO (2e5 for SAC): about 2 hours on 2 CPU cores at the "
        "caps (the estimate is printed first; the plateau rule stops most agents earlier)",
    )
    mode.add_argument(
        "--full",
        action="store_true",
        help="10 runs, every MIMO plant, TD3 and A2C too, longer caps (about 23 hours; the "
        "estimate is printed first)",
    )
    p.add_argument(
        "--resume",
        metavar="RUN_DIR",
        help="continue the run in RUN_DIR (after Ctrl-C or a kill) with its config.json: "
        "finished RL jobs and classical evaluations are read back, not run again; takes "
        "--jobs, --executor, --address, --time-limit, --no-plots and --progress only",
    )
    p.add_argument(
        "--scenarios",
        help=f"comma list of {','.join(SCENARIO_KINDS)} (default: all)",
    )
    p.add_argument(
        "--plants",
        help=f"nominal-scenario plants (quick default: {','.join(QUICK['plants'])}; "
        f"catalogue: {','.join(plant_names())})",
    )
    defaults = BenchConfig(run="-")
    p.add_argument(
        "--family",
        help=f"the plant family (default {defaults.family}; registered: "
        f"{','.join(FAMILIES)}; or a YAML/JSON spec file with train, validation and test "
        "splits)",
    )
    p.add_argument(
        "--ood",
        help="held-out variants of the family tested (quick default: "
        f"{','.join(QUICK['ood'])}; standard and full: {','.join(STANDARD['ood'])})",
    )
    p.add_argument(
        "--ladder",
        help="rungs of the difficulty ladder tested by the ladder scenarios (default: "
        f"{','.join(defaults.ladder)}; the last rung, ladder-l4-v1, has siso2-v1's plants)",
    )
    p.add_argument(
        "--ladder-agents",
        help="the RL agents of --agents trained on each rung (default: "
        f"{','.join(defaults.ladder_agents)}); the classical controllers run on every rung",
    )
    p.add_argument(
        "--mimo-plants",
        help="MIMO plants of the mimo scenario (measured state; default: "
        f"{','.join(defaults.mimo_plants)}; full: {','.join(FULL['mimo_plants'])}; MIMO "
        f"catalogue: {','.join(mimo_plant_names())})",
    )
    p.add_argument(
        "--agents",
        # ", " so that argparse can wrap the lists between names
        help=f"comma list of {', '.join([*ALGORITHMS, *CONTROLLERS])} (quick default: "
        f"{', '.join(QUICK['agents'])}; standard: {', '.join(STANDARD['agents'])}; full: "
        f"{', '.join(FULL['agents'])}); lqg (the yardstick) and zero are always evaluated",
    )
    rule = PlateauRule()
    p.add_argument(
        "--train-steps",
        help="RL training cap in env steps: N for every agent, or ppo=N,sac=M (defaults: "
        "each algorithm's quick_steps, standard_steps / standard_family_steps or full_steps "
        "in agents/rl/configs.py; on a MIMO plant in quick mode "
        f"{', '.join(f'{a} {n}' for a, n in QUICK_MIMO_INTERVALS.items())} evaluation "
        "intervals, at most quick_steps); at least one evaluation interval",
    )
    p.add_argument(
        "--patience",
        type=int,
        default=rule.patience,
        # (argparse %-formats help texts)
        help=f"plateau rule: {rule.describe('--eval-interval').replace('%', '%%')}; this is "
        "the number of "
        f"evaluations (>= 1, default {rule.patience})",
    )
    p.add_argument(
        "--min-improvement",
        type=float,
        default=rule.min_improvement,
        help="plateau rule: the relative gain on the best cost an evaluation must make, in "
        f"[0, 1) (default {rule.min_improvement})",
    )
    p.add_argument(
        "--min-train-fraction",
        type=float,
        default=rule.min_fraction,
        help="plateau rule: the fraction of the cap trained before evaluations count towards "
        f"--patience, in [0, 1] (default {rule.min_fraction})",
    )
    p.add_argument(
        "--eval-interval",
        type=int,
        help="env steps between the evaluations of the plateau rule, for every algorithm "
        "(default: each algorithm's eval_interval: "
        + ", ".join(f"{a} {c.eval_interval}" for a, c in DEFAULT_CONFIGS.items())
        + ")",
    )
    p.add_argument(
        "--train-seeds",
        type=int,
        help="runs per controller with random parts: RL training seeds, self-tuning "
        f"controller seeds (quick {QUICK['train_seeds']}, standard {STANDARD['train_seeds']}, "
        f"full {FULL['train_seeds']})",
    )
    p.add_argument(
        "--test-plants",
        type=int,
        help=f"test plants per family split (quick {QUICK['test_plants']}; standard and full: "
        "the whole split)",
    )
    p.add_argument(
        "--episodes-per-plant",
        type=int,
        help="episodes on each test plant (quick and standard 1, full "
        f"{FULL['episodes_per_plant']})",
    )
    p.add_argument(
        "--nominal-episodes",
        type=int,
        help=f"episodes of a nominal or MIMO scenario (quick {QUICK['nominal_episodes']}, "
        f"standard {STANDARD['nominal_episodes']})",
    )
    p.add_argument(
        "--curve-episodes",
        type=int,
        help=f"validation episodes per learning-curve point (quick {QUICK['curve_episodes']}, "
        f"standard {STANDARD['curve_episodes']}, full {FULL['curve_episodes']})",
    )
    p.add_argument(
        "--bound-plants",
        type=int,
        help=f"training episodes that set the action bound (default {defaults.bound_plants})",
    )
    p.add_argument(
        "--tune-trials",
        type=int,
        help="Optuna trials per tuned RL agent and for the self-tuning controller (stc_tuned) "
        f"on the family's validation split (standard default {STANDARD['tune_trials']}, full "
        f"{FULL['tune_trials']}; quick none)",
    )
    p.add_argument(
        "--tune-agents",
        help="the RL agents tuned with --tune-trials (standard default: "
        f"{','.join(STANDARD['tune_agents'])}; full: every RL agent)",
    )
    p.add_argument("--first-seed", type=int, default=1000, help="first test episode seed (>= 0)")
    p.add_argument(
        "--episode-steps",
        type=int,
        help="episode length, >= 20 (default: the family's, 1000); RL trains on the same",
    )
    p.add_argument("--noise", type=float, help="output noise std (default: the family's)")
    p.add_argument(
        "--hp",
        action="append",
        default=[],
        metavar="ALGO.KEY=VALUE",
        help="override a hyperparameter, e.g. ppo.learning_rate=3e-4 (repeatable; checked "
        "against the algorithm's rules)",
    )
    p.add_argument(
        "--curve-points",
        type=int,
        help="log-spaced learning-curve points before the first evaluation interval (quick "
        f"default: {QUICK['curve_points']}; standard and full: 10)",
    )
    p.add_argument(
        "--jobs",
        type=int,
        help="RL training jobs in parallel (local processes; default: min(2, CPUs))",
    )
    p.add_argument("--executor", default="local", help=f"task executor: {' or '.join(EXECUTORS)}")
    p.add_argument("--address", help="Ray cluster address (with --executor ray), e.g. auto")
    p.add_argument(
        "--time-limit",
        metavar="DURATION",
        help="wall-time limit of this session, e.g. 2h45m, 90m or 3600 (seconds): no job starts "
        "that is not estimated to end in time; what is left is for --resume (a partial "
        "report is written, exit status 0)",
    )
    p.add_argument(
        "--tensorboard-log",
        metavar="DIR",
        help="write TensorBoard logs of every RL training to DIR/<run>/ (learning curve "
        "included: eval/curve_score); view with tensorboard --logdir DIR",
    )
    p.add_argument(
        "--bootstrap-reps",
        type=int,
        default=None,
        help="bootstrap replications of the confidence intervals "
        f"(default {BenchConfig.bootstrap_reps})",
    )
    p.add_argument("--out", default="results", help="output folder (default results/)")
    p.add_argument("--run", help="run name (default: timestamp and mode)")
    p.add_argument("--overwrite", action="store_true", help="reuse an existing run folder")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument(
        "--plan",
        action="store_true",
        help="print the run's jobs and its estimated time, and stop (nothing is run or written)",
    )
    bar = p.add_mutually_exclusive_group()
    bar.add_argument(
        "--progress",
        dest="progress",
        action="store_true",
        default=None,
        help="SB3's per-job progress bar with --jobs 1 (default: when stderr is a terminal)",
    )
    bar.add_argument("--no-progress", dest="progress", action="store_false")


def _eval_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("eval", help="evaluate a saved RL agent (a bench models/ folder)")
    p.add_argument("model_dir", help="folder holding agent.json and model.zip")
    p.add_argument(
        "--plant",
        help="catalogue plant of the training order (default: the training plant, or the test "
        "split of the training family; an agent of the quadruple-tank family also runs on "
        "quadruple_tank or quadruple_tank_nmp)",
    )
    p.add_argument("--seeds", type=int, default=5, help="evaluation episodes (default 5)")
    p.add_argument("--first-seed", type=int, default=1000, help="first seed (>= 0)")
    p.add_argument("--episode-steps", type=int, default=1000, help="episode length (>= 20)")
    p.add_argument(
        "--noise", type=float, default=None, help="output noise std (default: as trained)"
    )


def _report_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "report",
        help="render a bench run's report, tables and figures from its results store",
        description="Render report.md, metrics.csv, learning_curves.csv, statistics.json and "
        "the figures of a bench run folder from its config.json and store/, without evaluating "
        "or training anything (e.g. a store committed to a repository).",
    )
    p.add_argument("run_dir", help="the run folder (holding config.json and store/)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument(
        "--prune",
        action="store_true",
        help="first delete the store's records the run's plan does not ask for (left by "
        "settings changed since), e.g. before committing the store",
    )
    p.add_argument(
        "--page",
        metavar="FILE",
        help="also write the run's headline tables into the Markdown FILE, between its two "
        "marker lines for this run",
    )


def build_parser() -> argparse.ArgumentParser:
    from stcgym.agents.sweeps.cli import add_sweep_subcommand

    parser = argparse.ArgumentParser(
        prog="stcgym", description="stcgym: self-tuning control vs RL benchmark"
    )
    sub = parser.add_subparsers(dest="command", required=True)
    _bench_parser(sub)
    _report_parser(sub)
    _eval_parser(sub)
    add_sweep_subcommand(sub)
    return parser


def _run_bench(args: argparse.Namespace, argv: Sequence[str]) -> int:
    from dataclasses import fields

    from stcgym.agents.benchmark import build_config, check_runnable, estimate_seconds, run_bench
    from stcgym.agents.benchmark.config import BenchConfig
    from stcgym.agents.benchmark.plan import format_duration, parse_duration

    if args.resume is not None:
        cfg = _resumed_config(args)
    else:
        # the bench options are named as the config's fields, but for these three
        named = {"noise_std": args.noise, "overrides": args.hp, "plots": not args.no_plots}
        cfg = build_config(
            mode=next((m for m in ("smoke", "standard", "full") if getattr(args, m)), "quick"),
            **{f.name: getattr(args, f.name) for f in fields(BenchConfig) if f.name in vars(args)},
            **named,
        )
    time_limit = None if args.time_limit is None else parse_duration(args.time_limit)
    if args.plan:
        from stcgym.agents.benchmark.plan import describe_plan

        print(describe_plan(cfg))
        return 0
    check_runnable(cfg)
    print(
        f"stcgym bench: {cfg.mode} mode, estimated {format_duration(estimate_seconds(cfg))} on "
        f"{cfg.jobs} worker(s) (every RL agent to its cap; the plateau rule can stop it "
        f"earlier); results in {cfg.run_dir}",
        file=sys.stderr,
    )
    result = run_bench(
        cfg,
        overwrite=args.overwrite,
        argv=list(argv),
        checked=True,
        resume=args.resume is not None,
        time_limit=time_limit,
    )
    print(result.run_dir / "report.md")
    return 0


#: The options ``--resume`` takes next to the run folder (the rest come from config.json).
_RESUME_OPTIONS = ("jobs", "executor", "address", "no_plots", "progress", "time_limit", "plan")


def _resumed_config(args: argparse.Namespace):
    """The config of the run to resume: its ``config.json`` and the options it takes."""
    from dataclasses import replace
    from pathlib import Path

    from stcgym.agents.benchmark.config import BenchInputError
    from stcgym.agents.benchmark.rundir import read_run_config
    from stcgym.agents.executors import EXECUTORS

    defaults = vars(build_parser().parse_args(["bench"]))
    given = [
        k
        for k, v in vars(args).items()
        if k not in ("resume", *_RESUME_OPTIONS) and v != defaults.get(k)
    ]
    if given:
        names = ", ".join("--" + k.replace("_", "-") for k in given)
        raise BenchInputError(f"--resume takes the settings of the run's config.json; drop {names}")
    try:
        cfg, _ = read_run_config(Path(args.resume))
    except BenchInputError as exc:
        raise BenchInputError(f"--resume: {exc}") from None
    jobs = cfg.jobs
    if args.jobs is not None:
        if args.jobs < 1:
            raise BenchInputError(f"--jobs must be a positive integer, got {args.jobs}")
        jobs = args.jobs
    if args.executor not in EXECUTORS:
        raise BenchInputError(f"--executor must be one of {EXECUTORS}, got {args.executor!r}")
    if args.address is not None and args.executor != "ray":
        raise BenchInputError("--address needs --executor ray")
    return replace(
        cfg,
        jobs=jobs,
        executor=args.executor,
        address=args.address,
        plots=cfg.plots and not args.no_plots,
        progress=cfg.progress if args.progress is None else args.progress,
    )


def _check_eval_args(args: argparse.Namespace) -> dict:
    """Validate every ``stcgym eval`` option (and read ``agent.json``) before loading SB3."""
    import json
    import math
    from pathlib import Path

    from stcgym.agents.benchmark.config import BenchInputError
    from stcgym.envs.catalogue import get_plant, plant_names

    if args.seeds < 1:
        raise BenchInputError(f"--seeds must be >= 1, got {args.seeds}")
    if args.first_seed < 0:
        raise BenchInputError(f"--first-seed must be >= 0, got {args.first_seed}")
    if args.episode_steps < 20:
        raise BenchInputError(f"--episode-steps must be >= 20, got {args.episode_steps}")
    if args.noise is not None and not (math.isfinite(args.noise) and args.noise >= 0):
        raise BenchInputError(f"--noise must be a finite number >= 0, got {args.noise}")
    meta_file = Path(args.model_dir) / "agent.json"
    if not meta_file.is_file():
        raise BenchInputError(f"{args.model_dir} holds no agent.json (not a saved stcgym agent)")
    try:
        meta = json.loads(meta_file.read_text())
        spec = meta["train_spec"]
        trained = spec.get("plants") or []
        mimo = spec.get("kind") == "mimo"
        order = get_plant(trained[0]).n if trained and not mimo else None
    except (ValueError, KeyError, TypeError, IndexError) as exc:
        raise BenchInputError(f"{meta_file} is not a readable agent description: {exc}") from None
    if args.plant is not None and mimo and spec.get("family") is not None:
        from stcgym.agents.evaluation.mimo import SWITCH

        if args.plant not in SWITCH:  # the quadruple tank at P- and P+
            raise BenchInputError(
                f"--plant {args.plant}: the agent was trained on the quadruple tanks of "
                f"{spec['family']} and runs on them or on {' or '.join(SWITCH)} only"
            )
    elif args.plant is not None and mimo:
        if args.plant != trained[0]:
            raise BenchInputError(
                f"--plant {args.plant}: the agent was trained on the MIMO plant {trained[0]} "
                "and runs on it only"
            )
    elif args.plant is not None:
        if args.plant not in plant_names():
            raise BenchInputError(
                f"--plant must be a catalogue plant ({', '.join(plant_names())}), "
                f"got {args.plant!r}"
            )
        if order is None:
            from stcgym.agents.evaluation.env_spec import EnvSpec

            order = EnvSpec.from_dict(spec).order
        if get_plant(args.plant).n != order:
            raise BenchInputError(
                f"--plant {args.plant}: the agent was trained on order-{order} plants"
            )
    return meta


def _run_report(args: argparse.Namespace) -> int:
    from pathlib import Path

    from stcgym.agents.benchmark.config import BenchInputError
    from stcgym.agents.benchmark.render import prune_store, render_run, update_page

    if args.page is not None and not Path(args.page).is_file():
        raise BenchInputError(f"--page {args.page}: no such file")
    if args.prune:
        stale = prune_store(args.run_dir)
        print(f"{len(stale)} records no longer in the plan deleted", file=sys.stderr)
    run = render_run(Path(args.run_dir), plots=not args.no_plots)
    if args.page is not None:
        try:
            changed = update_page(args.page, args.run_dir)
        except ValueError as exc:
            raise BenchInputError(f"--page: {exc}") from None
        print(f"{args.page}: {'tables updated' if changed else 'tables unchanged'}",
              file=sys.stderr)  # fmt: skip
    if run.missing:
        print(f"partial: {len(run.missing)} of the plan's jobs have no record yet; "
              f"stcgym bench --resume {args.run_dir} runs them", file=sys.stderr)  # fmt: skip
    print(Path(args.run_dir) / "report.md")
    return 0


def _run_eval(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from stcgym.agents.evaluation.episodes import EpisodeSet, run_episodes
    from stcgym.agents.evaluation.evaluate import summarize

    _check_eval_args(args)
    from stcgym.agents.rl.sb3 import load_agent

    agent = load_agent(args.model_dir)
    spec = replace(agent.train_spec, steps=args.episode_steps)
    if args.noise is not None:
        spec = replace(spec, noise_std=args.noise)
    if args.plant is not None and spec.family is not None:
        spec = replace(spec, family=None, split=None, jump_probability=None, plants=(args.plant,))
    elif args.plant is not None:
        spec = replace(spec, plants=(args.plant,))
    elif spec.family is not None:
        spec = replace(spec, split="test", jump_probability=0.0)
    names = spec.plant_names()
    plants = tuple(names[i % len(names)] for i in range(args.seeds))
    episodes = EpisodeSet(plants, tuple(args.first_seed + i for i in range(args.seeds)))
    batch = run_episodes(  # (an agent told the true parameters gets them: oracle_ppo)
        lambda lanes, seeds: agent.policy.with_lanes(len(lanes), seeds, lanes),
        spec,
        episodes,
        informed=agent.policy.informed,
    )
    costs = batch.cost.mean(axis=1)
    s = summarize(costs, batch.diverged)
    where = spec.plants[0] if spec.family is None else f"{spec.family} {spec.split}"
    print(
        f"{agent.algo} (seed {agent.seed}, {agent.steps} steps) on {where}: median cost "
        f"{s['median']:.4g} [IQR {s['iqr']:.3g}], CVaR25 {s['cvar25']:.4g}, failure rate "
        f"{s['failure_rate']:.2f}"
    )
    for plant, seed, c in zip(plants, episodes.seeds, costs, strict=True):
        print(f"  {plant} seed {seed}: cost {c:.4g}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``stcgym`` console script; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    if args.command == "sweep":
        return args.handler(args)
    from stcgym.agents.benchmark.config import BenchInputError

    try:
        if args.command == "bench":
            return _run_bench(args, argv)
        if args.command == "report":
            return _run_report(args)
        return _run_eval(args)
    except (BenchInputError, FileNotFoundError) as exc:
        print(f"stcgym {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("stcgym: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
