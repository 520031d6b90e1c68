"""The folder of a ``stcgym bench`` run and the checks before any work: output folder,
dependencies, every agent's model built once by SB3, the ids finished RL jobs are kept under."""

from __future__ import annotations

import platform
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stcgym.agents.benchmark.config import BenchConfig, BenchInputError, is_family_key
from stcgym.agents.benchmark.scenarios import TrainingEnv, make_scenarios, training_envs
from stcgym.agents.rl.configs import FAMILY_ALGORITHMS, RECURRENT_ALGORITHMS, AlgoConfig

if TYPE_CHECKING:
    from stcgym.agents.rl.training import TrainingTask

__all__ = [
    "check_runnable",
    "classical_id",
    "classical_key",
    "job_id",
    "prepare_run_dir",
    "read_run_config",
    "versions",
]

#: Task keys that do not shape an RL job's result: where its files go, the progress bar, and
#: the yardstick's costs on the validation episodes (derived from the other keys, and BLAS
#: may change their last digits from one machine to the next).
_NOT_RESULT = ("progress", "model_dir", "tensorboard_log", "curve_reference")


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


def _check_output(cfg: BenchConfig) -> None:
    for path, what in ((Path(cfg.out), "--out"), (cfg.run_dir, "the run folder")):
        if path.exists() and not path.is_dir():
            raise BenchInputError(f"{what} {path} is a file; a folder is expected (it is "
                                  "created when missing)")  # fmt: skip


def check_runnable(cfg: BenchConfig) -> None:
    """The checks that need more than the config: the output folder, dependencies, and every
    agent's model built once by SB3 itself. Raises :class:`BenchInputError`."""
    _check_output(cfg)
    _check_dependencies(cfg)
    if cfg.rl_agents:
        _check_trainable(cfg, training_envs(cfg, make_scenarios(cfg)))


def _check_trainable(cfg: BenchConfig, envs: dict[str, TrainingEnv]) -> None:
    """Build every agent's model once (and drop it): SB3's own checks run before any work."""
    from stcgym.agents.rl.sb3 import check_trainable

    for algo in cfg.rl_agents:
        keys = [
            k
            for k in envs
            if cfg.trains_on(algo, k) and (algo not in FAMILY_ALGORITHMS or is_family_key(k))
        ]
        if not keys:  # (validation refuses an agent with nothing to train on)
            continue
        key = keys[0]
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

    ``overwrite`` starts the run afresh (the store emptied); ``resume`` keeps the store and the
    trained agents, and renders the tables and the report again.
    """
    run_dir = cfg.run_dir
    _check_writable(Path(cfg.out))
    if resume and not (run_dir / "config.json").is_file():
        raise BenchInputError(f"--resume: {run_dir} holds no config.json (not a bench run)")
    if (run_dir / "config.json").exists() and not (overwrite or resume):
        raise BenchInputError(
            f"{run_dir} already holds a run; pick another --run, pass --overwrite, or "
            f"--resume {run_dir}"
        )
    _check_writable(run_dir)
    if overwrite or resume:
        for name in ("metrics.csv", "learning_curves.csv", "report.md"):
            (run_dir / name).unlink(missing_ok=True)
    if overwrite:
        from stcgym.agents.benchmark.metrics_csv import METRIC_COLUMNS
        from stcgym.agents.benchmark.store import STORE_FOLDER, ResultsStore

        ResultsStore(run_dir / STORE_FOLDER, METRIC_COLUMNS).clear()
    return run_dir


def classical_id(scenario: dict, controller: str, run: int, tuned: Any = None) -> str:
    """The id a classical controller's run on a scenario is kept under: what shapes its
    episodes and nothing else: the scenario (its env, with the action bound, and its episodes,
    with their seeds, as dicts), the controller's name, the run and, for a controller built
    from a tuning study, that study's result. So a run that adds agents, scenarios or rungs, or
    trains its RL agents otherwise, keeps the classical records it has."""
    from stcgym.agents.executors import task_id

    key = {"scenario": scenario, "controller": controller, "run": run}
    if tuned is not None:
        key["tuned"] = tuned
    return task_id(key)


def classical_key(cfg: BenchConfig, sc: Any, name: str, run: int) -> tuple[str, str]:
    """The label and id the store keeps run ``run`` of the classical controller ``name`` on
    ``sc`` under (:func:`~stcgym.agents.benchmark.rundir.classical_id`)."""
    from stcgym.agents.controllers import CONTROLLERS

    scenario = {
        "name": sc.name,
        "env": sc.env.to_dict(),
        "episodes": sc.episodes.to_dict(),
        "controller_order": sc.controller_order,
    }
    study = CONTROLLERS[name].tuned
    tuned = None if study is None else cfg.tuned.get(study)
    return f"{sc.name}.{name}.run{run}", classical_id(scenario, name, run, tuned)


def read_run_config(run_dir: Path) -> tuple[BenchConfig, dict[str, Any]]:
    """A run folder's config (placed in that folder: ``out`` and ``run`` follow the folder,
    wherever the run was made) and its whole ``config.json``; :class:`BenchInputError` when
    the folder holds no readable one."""
    import json
    from dataclasses import replace

    doc_file = Path(run_dir) / "config.json"
    if not doc_file.is_file():
        raise BenchInputError(f"{run_dir} holds no config.json (not a bench run folder)")
    try:
        doc = json.loads(doc_file.read_text())
        cfg = BenchConfig.from_dict(doc["bench"])
    except (ValueError, KeyError, TypeError) as exc:
        raise BenchInputError(f"{doc_file} is not a readable bench config: {exc}") from None
    return replace(cfg, out=str(Path(run_dir).parent), run=Path(run_dir).name), doc


def job_id(task: TrainingTask | dict[str, Any]) -> str:
    """The id a finished RL job is kept under: everything that shapes its result (not where
    its files go, nor the progress bar), so a resumed run finds it under another --jobs."""
    from stcgym.agents.executors import task_id

    data = task if isinstance(task, dict) else task.to_dict()
    return task_id({k: v for k, v in data.items() if k not in _NOT_RESULT})
