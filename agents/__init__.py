"""Everything around the controllers: RL baselines, the benchmark, sweeps and the command.

* :mod:`stcgym.agents.rl`: RL agents: the observation window and training reward
  (:mod:`~stcgym.agents.rl.wrappers`), one hyperparameter config per algorithm
  (:mod:`~stcgym.agents.rl.configs`), training, saving/loading and :class:`SB3Policy`
  (:mod:`~stcgym.agents.rl.sb3`), one training job as a task (:mod:`~stcgym.agents.rl.training`)
  and the Stable-Baselines3 ``VecEnv`` adapter of the native vector envs
  (:mod:`~stcgym.agents.rl.vec_env`);
* :mod:`stcgym.agents.benchmark`: ``stcgym bench``: the evaluation harness and its metrics
  (:mod:`~stcgym.agents.evaluation.evaluate`, :mod:`~stcgym.agents.evaluation.response`), the
  run (config, scenarios, plan, runner), interval statistics, report and plots;
* :mod:`stcgym.agents.sweeps`: ``stcgym sweep``: random plant families
  (:mod:`~stcgym.envs.families`) and the classical controllers swept over them;
* :mod:`stcgym.agents.closed_loop`: the one closed-loop driver behind every cost the benchmark
  and the sweeps report (the compiled rollout where it applies, ``predict`` otherwise) and its
  divergence rule;
* :mod:`stcgym.agents.controllers`: the registry of classical controllers (self-tuning
  variants, oracles) the benchmark runs;
* :mod:`stcgym.agents.executors`: the task executor (local processes or Ray) that runs the
  bench's RL jobs and the sweeps' chunks, resumable;
* :mod:`stcgym.agents.cli`: the ``stcgym`` command (``bench``, ``eval``, ``sweep``).

Stable-Baselines3 and torch are imported only when an agent is trained or loaded.
"""

from stcgym.agents.evaluation.evaluate import (
    EnvSpec,
    Episode,
    EvalResult,
    evaluate,
    run_episode,
    summarize,
)
from stcgym.agents.rl.configs import AlgoConfig, default_config
from stcgym.agents.rl.learning_curve import CurveOptions
from stcgym.agents.rl.overrides import apply_overrides
from stcgym.agents.rl.wrappers import HistoryBuffer, HistoryWindow, TrainingReward, WindowConfig

__all__ = [
    "AlgoConfig",
    "EnvSpec",
    "CurveOptions",
    "Episode",
    "EvalResult",
    "HistoryBuffer",
    "HistoryWindow",
    "SB3Policy",
    "TrainingReward",
    "WindowConfig",
    "apply_overrides",
    "default_config",
    "evaluate",
    "load_agent",
    "run_episode",
    "summarize",
    "train_agent",
]


def __getattr__(name: str):
    # SB3 pulls torch in (seconds); load it only when asked for.
    if name in ("load_agent", "train_agent"):
        from stcgym.agents.rl import sb3

        return getattr(sb3, name)
    if name == "SB3Policy":
        from stcgym.agents.rl.policy import SB3Policy

        return SB3Policy
    raise AttributeError(f"module 'stcgym.agents' has no attribute {name!r}")
