"""RL agents, the evaluation harness and the ``stcgym bench`` command.

* :mod:`stcgym.agents.wrappers`: the RL observation (a window of past ``y``, ``r``, ``u``) and
  the training reward;
* :mod:`stcgym.agents.configs`: one hyperparameter config per algorithm (PPO, SAC, TD3, A2C,
  RecurrentPPO) and the rules every value is checked against;
* :mod:`stcgym.agents.sb3`: training, saving/loading, and :class:`SB3Policy`, the adapter that
  puts a trained model (recurrent ones included) behind the shared policy protocol;
* :mod:`stcgym.agents.evaluate`: one evaluation loop for every controller, and the metrics;
* :mod:`stcgym.agents.response`: settling to the oracle's cost, re-convergence after a jump,
  step-response figures;
* :mod:`stcgym.agents.statistics`: IQM, median and probability of improvement with
  stratified-bootstrap intervals (rliable);
* :mod:`stcgym.agents.training`: one RL training job as a picklable task for the executor;
* :mod:`stcgym.agents.bench` / :mod:`stcgym.agents.report` / :mod:`stcgym.agents.plots` /
  :mod:`stcgym.agents.cli`: ``stcgym bench``.

Stable-Baselines3 and torch are imported only when an agent is trained or loaded.
"""

from stcgym.agents.configs import AlgoConfig, apply_overrides, default_config
from stcgym.agents.evaluate import EnvSpec, Episode, EvalResult, evaluate, run_episode, summarize
from stcgym.agents.wrappers import HistoryBuffer, HistoryWindow, TrainingReward, WindowConfig

__all__ = [
    "AlgoConfig",
    "EnvSpec",
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
    if name in ("SB3Policy", "load_agent", "train_agent"):
        from stcgym.agents import sb3

        return getattr(sb3, name)
    raise AttributeError(f"module 'stcgym.agents' has no attribute {name!r}")
