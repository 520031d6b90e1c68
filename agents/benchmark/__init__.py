"""``stcgym bench``: the self-tuning controller against RL agents and known-model oracles.

Modules: :mod:`~stcgym.agents.benchmark.config` (the run's settings and their checks),
:mod:`~stcgym.agents.benchmark.scenarios` (scenarios and RL training environments),
:mod:`~stcgym.agents.benchmark.mimo` (the MIMO scenario and its environment),
:mod:`~stcgym.agents.benchmark.plan` (the RL jobs and the ETA),
:mod:`~stcgym.agents.benchmark.runner` (the run),
:mod:`~stcgym.agents.benchmark.rundir` (the run folder, the checks before any work),
:mod:`~stcgym.agents.benchmark.metrics_csv` (``metrics.csv``),
:mod:`~stcgym.agents.benchmark.evaluate` (closed-loop evaluation, per-episode metrics),
:mod:`~stcgym.agents.benchmark.response` (metrics relative to the oracle),
:mod:`~stcgym.agents.benchmark.statistics` (interval estimates),
:mod:`~stcgym.agents.benchmark.headline` (the report's estimates),
:mod:`~stcgym.agents.benchmark.report` and :mod:`~stcgym.agents.benchmark.plots` (output).

Scenarios
---------
``nominal:P``
    Plant ``P``. RL agents are trained on ``P`` and evaluated on ``P``.
``family:P``
    RL agents are trained on episodes drawn at random from the training family
    (``family_train``) and evaluated on the held-out plant ``P`` (``family_test``); the
    self-tuning controller meets ``P`` for the first time, as in every episode.
``jump:SPEC``
    The plant's parameters jump in the middle of the episode (step ``T/2``). ``SPEC`` is
    ``timevarying2`` (the catalogue's jump: ``stable2`` to ``TIMEVARYING2_AFTER``) or
    ``A:B`` (plant ``A`` jumping to plant ``B``). Window agents are the ones trained on the
    pre-jump plant (``nominal:A``): the jump is as new to them as to the self-tuning
    controller. The known-model oracle is told the new parameters at the jump.
``mimo:P``
    The MIMO catalogue plant ``P`` (``mimo_plants``) with measured state: the multivariable
    self-tuning LQ controller against the LQR oracle on the true ``(A, B)`` and the window
    agents trained on ``P``; the SISO-only controllers are left out. Part of every tier.

Recurrent agents (``rppo``, sb3-contrib's RecurrentPPO: the adaptive-RL baseline) are trained on
the plant family only and evaluated on the ``family`` and ``jump`` scenarios.

Every controller meets the same episodes: evaluation seed ``s`` means ``env.reset(seed=s)``
(same noise, same reference) for all of them, and the controller's own random parts (the
self-tuning controller's probe) are seeded with ``s`` too, so every episode and every lane has
its own controller seed. The loop and the per-episode metrics are those of
:mod:`stcgym.agents.benchmark.evaluate`; the metrics relative to the oracle on the same
episode (cost ratios, steps to get within 1.2x, re-convergence after the jump) are those of
:mod:`stcgym.agents.benchmark.response`, computed by the runner from the per-step costs.

Controllers
-----------
``ppo``, ``sac``, ``td3``, ``a2c``, ``rppo``: Stable-Baselines3 / sb3-contrib agents
(:mod:`stcgym.agents.rl.sb3`), one model per training environment and training seed. ``stc``:
:class:`~stcgym.adaptive.SelfTuningController` with its defaults; ``stc_lq`` and
``stc_kfmils``: the same with the self-tuning LQ design and on the paper's KF-MILS estimator
(:mod:`stcgym.agents.controllers`). ``oracle``:
:class:`~stcgym.adaptive.KnownModelController`, the same design on the true parameters (always
evaluated: every ratio is taken to it). ``lqg``: :class:`~stcgym.adaptive.LQGController`, the
optimal linear controller for the bench's cost on the true (pre-jump) parameters.
``stc_mimo``: :class:`~stcgym.adaptive.MultivariableSelfTuningController` (``mimo`` scenarios
only; ``oracle`` is :class:`~stcgym.adaptive.LQRController` there).

Tiers
-----
``quick`` (the default, under 10 minutes on 2 cores), ``standard`` (the same scenarios, seeds
and statistics with the RL Zoo's tuned budgets as caps: about an hour) and ``full`` (every
plant and agent, more seeds, long caps: about a day). In every tier each RL agent trains until
its learning curve plateaus or it reaches its cap (:mod:`stcgym.agents.rl.stopping`), and the
report says which, per scenario, agent and training seed.

Execution
---------
Every RL training job (training env x agent x seed) is a JSON task
(:mod:`stcgym.agents.rl.training`) run by the executor of :mod:`stcgym.agents.executors`
(``jobs`` local processes, or Ray), longest first by its estimated cost
(:mod:`~stcgym.agents.benchmark.plan`); meanwhile the driver evaluates the classical
controllers in a thread (when the jobs run in this process, it does so first). The driver
writes every result as the jobs finish (the RL rows once the oracle's are in) and logs
``job k/N, ETA`` for the whole run; the plots are drawn in a process of their own while the
driver writes the report. Each
finished job's result is kept in ``jobs/<id>.json``: ``run_bench(cfg, resume=True)``
(``stcgym bench --resume RUN_DIR``) reads those back instead of training them again.

Output (``<out>/<run>/``): ``config.json`` (written first), ``metrics.csv`` (one row per
controller x scenario x seed x training seed, appended and flushed row by row, so an
interrupted run keeps every finished row), ``learning_curves.csv``, ``report.md``, PNG plots,
``models/`` and ``jobs/``.
"""

from stcgym.agents.benchmark.config import BenchConfig, BenchInputError, build_config
from stcgym.agents.benchmark.plan import estimate_seconds
from stcgym.agents.benchmark.runner import (
    METRIC_COLUMNS,
    BenchResult,
    check_runnable,
    run_bench,
)
from stcgym.agents.benchmark.scenarios import Scenario, make_scenarios

__all__ = [
    "METRIC_COLUMNS",
    "BenchConfig",
    "BenchInputError",
    "BenchResult",
    "Scenario",
    "build_config",
    "check_runnable",
    "estimate_seconds",
    "make_scenarios",
    "run_bench",
]
