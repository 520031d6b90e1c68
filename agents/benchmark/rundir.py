"""The folder of a ``stcgym bench`` run and the checks before any work: output folder,
dependencies, every agent's model built once by SB3, the ids finished RL jobs are kept under."""

from __future__ import annotations

import platform
from pathlib import Path
from typing import Any

from stcgym.agents.benchmark.config import BenchConfig, BenchInputError
from stcgym.agents.benchmark.scenarios import TrainingEnv, make_scenarios, training_envs
from stcgym.agents.rl.configs import FAMILY_ALGORITHMS, RECURRENT_ALGORITHMS, AlgoConfig

__all__ = ["JOBS_FOLDER", "check_runnable", "job_id", "prepare_run_dir", "versions"]

#: Where each finished RL job's result is kept (what ``--resume`` reuses).
JOBS_FOLDER = "jobs"
#: Task keys that do not shape an RL job's result (where its files go, the progress bar).
_NOT_RESULT = ("progress", "model_dir", "tensorboard_log")


def _check_writable(folder: Path) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / ".write-test"
        probe.write_text("ok")
        probe.unlink()
    except OSError as exc:
        raise BenchInputError(f"output folder {folder} cannot be written: {exc}") from exc


def _check_dependencies(cfg: BenchConfig) -> None:
    missing = []
    if cfg.rl_agents:
        mods = ["stable_baselines3", "torch", "rliable"]
        if any(a in RECURRENT_ALGORITHMS for a in cfg.rl_agents):
            mods.append("sb3_contrib")
        if cfg.tensorboard_log:
            mods.append("tensorboard")
        if cfg.progress:
            mods += ["tqdm", "rich"]
        for mod in mods:
            try:
                __import__(mod)
            except ImportError:
                missing.append(f"{mod} (pip install 'stcgym[rl]')")
    else:
        try:
            __import__("rliable")
        except ImportError:
            missing.append("rliable for the confidence intervals (pip install 'stcgym[rl]')")
    if cfg.executor == "ray":
        try:
            __import__("ray")
        except ImportError:
            missing.append("ray for --executor ray (pip install 'stcgym[ray]')")
    if cfg.plots:
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            missing.append("matplotlib for the plots (pip install 'stcgym[plot]' or --no-plots)")
    if missing:
        raise BenchInputError("missing dependencies: " + "; ".join(missing))


def check_runnable(cfg: BenchConfig) -> None:
    """The checks that need more than the config: dependencies, and every agent's model built
    once by SB3 itself. Raises :class:`BenchInputError`."""
    _check_dependencies(cfg)
    if cfg.rl_agents:
        _check_trainable(cfg, training_envs(cfg, make_scenarios(cfg)))


def _check_trainable(cfg: BenchConfig, envs: dict[str, TrainingEnv]) -> None:
    """Build every agent's model once (and drop it): SB3's own checks run before any work."""
    from stcgym.agents.rl.sb3 import check_trainable

    for algo in cfg.rl_agents:
        key = "family" if algo in FAMILY_ALGORITHMS else next(iter(envs))
        try:
            check_trainable(algo, AlgoConfig.from_dict(cfg.algo_configs[algo]), envs[key].train)
        except ValueError as exc:
            raise BenchInputError(str(exc)) from exc


def versions() -> dict[str, str]:
    """Python, platform and the versions of the packages a run's numbers depend on."""
    out = {"python": platform.python_version(), "platform": platform.platform()}
    for mod in ("numpy", "gymnasium", "control", "stable_baselines3", "torch"):
        try:
            out[mod] = __import__(mod).__version__
        except ImportError:
            pass
    return out


def prepare_run_dir(cfg: BenchConfig, overwrite: bool = False, resume: bool = False) -> Path:
    """Create ``<out>/<run>``; refuse to mix two runs in one folder.

    ``overwrite`` starts the run afresh; ``resume`` keeps the finished RL jobs (``jobs/``), the
    classical controllers' episodes (``jobs/classical/``) and the trained agents, and rebuilds
    the tables and the report.
    """
    run_dir = cfg.run_dir
    _check_writable(Path(cfg.out))
    if resume and not (run_dir / "config.json").is_file():
        raise BenchInputError(f"--resume: {run_dir} holds no config.json (not a bench run)")
    if (run_dir / "metrics.csv").exists() and not (overwrite or resume):
        raise BenchInputError(
            f"{run_dir} already holds a run; pick another --run, pass --overwrite, or "
            f"--resume {run_dir}"
        )
    _check_writable(run_dir)
    if overwrite or resume:
        for name in ("metrics.csv", "learning_curves.csv", "report.md"):
            (run_dir / name).unlink(missing_ok=True)
    if overwrite:
        from stcgym.agents.benchmark.classical_store import CLASSICAL_FOLDER, ClassicalStore

        for old in (run_dir / JOBS_FOLDER).glob("*.json"):
            old.unlink()
        ClassicalStore(run_dir / JOBS_FOLDER / CLASSICAL_FOLDER).clear()
    return run_dir


def job_id(task: dict[str, Any]) -> str:
    """The id a finished RL job is kept under: everything that shapes its result (not where
    its files go, nor the progress bar), so a resumed run finds it under another --jobs."""
    from stcgym.agents.executors import task_id

    return task_id({k: v for k, v in task.items() if k not in _NOT_RESULT})
