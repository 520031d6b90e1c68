"""``stcgym sweep`` on the command line (also ``python -m stcgym.agents.sweeps.cli``)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from typing import Any

from stcgym.agents.executors import EXECUTORS
from stcgym.agents.sweeps.chunk import CONTROLLER_KINDS
from stcgym.agents.sweeps.config import DEFAULT_CHUNK, SweepConfig, SweepError
from stcgym.agents.sweeps.sweep import run_sweep
from stcgym.envs.families import FamilySpecError

__all__ = ["add_sweep_subcommand", "main", "parse_controller", "run_sweep_command"]


def _parse_value(text: str) -> Any:
    try:
        import yaml

        return yaml.safe_load(text)
    except ImportError:  # pragma: no cover
        try:
            return json.loads(text)
        except json.JSONDecodeError:
            return text


def parse_controller(text: str) -> tuple[str, dict[str, Any]]:
    """``NAME[=KIND][:KEY=VALUE,...]`` -> ``(name, {"kind": kind, key: value})``.

    Values are YAML scalars or flow collections (``poles=[0.6,0.6,0.6]``,
    ``estimator=KF-RLS``); commas inside brackets do not split. A dotted key sets an entry of
    an options group: ``estimator_options.p0=100`` -> ``{"estimator_options": {"p0": 100}}``.
    """
    head, _, rest = text.partition(":")
    name, _, kind = head.partition("=")
    name, kind = name.strip(), (kind.strip() or name.strip())
    if not name:
        raise SweepError(f"--controller {text!r}: expected NAME[=KIND][:KEY=VALUE,...]")
    opts: dict[str, Any] = {"kind": kind}
    depth, item, items = 0, "", []
    for ch in rest:
        if ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        if ch == "," and depth == 0:
            items.append(item)
            item = ""
        else:
            item += ch
    if item.strip():
        items.append(item)
    for it in items:
        key, eq, value = it.partition("=")
        if not eq or not key.strip():
            raise SweepError(f"--controller {text!r}: option {it!r} is not KEY=VALUE")
        *groups, leaf = key.strip().split(".")
        target = opts
        for g in groups:
            target = target.setdefault(g, {})
            if not isinstance(target, dict):
                raise SweepError(f"--controller {text!r}: {g!r} is set twice")
        target[leaf] = _parse_value(value.strip())
    return name, opts


def add_sweep_subcommand(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``sweep`` on the ``stcgym`` command's subparsers; returns its parser."""
    p = subparsers.add_parser(
        "sweep",
        help="classical controllers over a random plant family (process pool or Ray)",
        description="Run the self-tuning controller, the known-model oracle and LQG over a "
        "plant family (YAML/JSON spec, see stcgym.envs.families); writes <out>/<run>/ "
        "(metrics.csv or .parquet, robustness.png, config.json).",
    )
    p.add_argument("family", nargs="?", help="family spec file (.yaml/.yml/.json)")
    p.add_argument(
        "--controller",
        action="append",
        dest="controllers",
        metavar="NAME[=KIND][:KEY=VALUE,...]",
        help="a controller (repeatable; default stc, oracle, lqg), e.g. "
        "rls=stc:estimator=KF-RLS,estimator_options.p0=100; the oracle is always run",
    )
    p.add_argument("--seeds", type=int, default=1, help="episode seeds per plant (default 1)")
    p.add_argument(
        "--chunk", type=int, default=DEFAULT_CHUNK, help="lanes per task (default 10000)"
    )
    p.add_argument("--jobs", type=int, help="local worker processes (default: CPU count)")
    p.add_argument("--executor", choices=EXECUTORS, default="local", help="local (default) or ray")
    p.add_argument("--address", help="Ray cluster address, e.g. auto (after ray start --head)")
    p.add_argument("--out", default="results", help="output folder (default results/)")
    p.add_argument("--run", help="run name (default: timestamp)")
    p.add_argument("--resume", metavar="RUN", help="continue the sweep in this run folder")
    p.add_argument(
        "--format", dest="table_format", default="auto", choices=("auto", "csv", "parquet")
    )
    p.add_argument(
        "--features",
        default="pole_mag_max,abs_dc_gain",
        help="two plant features for the robustness map (default pole_mag_max,abs_dc_gain)",
    )
    p.add_argument("--no-plot", action="store_true", help="skip robustness.png")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(handler=run_sweep_command)
    return p


def run_sweep_command(args: argparse.Namespace) -> int:
    """Run ``stcgym sweep`` from parsed arguments; exit status 0, 1 (task failures) or 2."""
    try:
        features = tuple(f.strip() for f in args.features.split(","))
        if len(features) != 2:
            raise SweepError(f"--features needs two names, got {args.features!r}")
        config = None
        if args.family is not None:
            controllers = dict(parse_controller(c) for c in (args.controllers or CONTROLLER_KINDS))
            config = SweepConfig.build(args.family, controllers, args.seeds, args.chunk)
        elif args.resume is None:
            raise SweepError("give a family spec file, or --resume RUN")
        t0 = time.perf_counter()
        result = run_sweep(
            config,
            out=args.out,
            run=args.run,
            resume=args.resume,
            executor=args.executor,
            jobs=args.jobs,
            address=args.address,
            table_format=args.table_format,
            plot=not args.no_plot,
            features=features,  # type: ignore[arg-type]
            progress=not args.quiet,
        )
    except (SweepError, FamilySpecError, FileNotFoundError) as exc:
        print(f"stcgym sweep: error: {exc}", file=sys.stderr)
        return 2
    except ConnectionError as exc:  # ray.init(address=...) found no cluster
        print(
            f"stcgym sweep: error: no Ray cluster at --address {args.address} ({exc}); start "
            f"one with `ray start --head`",
            file=sys.stderr,
        )
        return 2
    except KeyboardInterrupt:
        print("stcgym sweep: interrupted; continue with --resume", file=sys.stderr)
        return 130
    print(f"{result.table_path} ({time.perf_counter() - t0:.1f} s)")
    return 1 if result.failures else 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m stcgym.agents.sweeps.cli ...`` (the same as ``stcgym sweep ...``)."""
    parser = argparse.ArgumentParser(prog="stcgym")
    add_sweep_subcommand(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["sweep", *(sys.argv[1:] if argv is None else argv)])
    return run_sweep_command(args)


if __name__ == "__main__":
    sys.exit(main())
