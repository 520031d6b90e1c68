"""``stcgym bench``: the self-tuning controllers against RL agents on identical terms.

Modules: :mod:`~stcgym.agents.benchmark.config` (the run's settings and their checks),
:mod:`~stcgym.agents.benchmark.tiers` (the scenario kinds and each tier's preset),
:mod:`~stcgym.agents.benchmark.scenarios` (scenarios and RL training environments),
:mod:`~stcgym.agents.evaluation.env_spec` (a scenario's environment as data),
:mod:`~stcgym.agents.evaluation.episodes` (fixed evaluation episodes, run as a batch),
:mod:`~stcgym.agents.evaluation.bounds` (one action bound per training distribution, from LQG),
:mod:`~stcgym.agents.benchmark.mimo` (the MIMO scenarios;
:mod:`~stcgym.agents.evaluation.mimo`: their environments and yardsticks),
:mod:`~stcgym.agents.benchmark.plan` (the jobs, their estimates and the ETA),
:mod:`~stcgym.agents.benchmark.runner` (the run: its plan, then its jobs),
:mod:`~stcgym.agents.benchmark.rundir` (the run folder, the checks before any work, job ids),
:mod:`~stcgym.agents.benchmark.store` (the results store: one record per finished job),
:mod:`~stcgym.agents.benchmark.adaptation` (the per-run summary the adaptation figures draw),
:mod:`~stcgym.agents.benchmark.render` (report, tables and figures from the store),
:mod:`~stcgym.agents.benchmark.rows` and :mod:`~stcgym.agents.benchmark.metrics_csv`
(``metrics.csv``: one row per scenario, controller, run and episode),
:mod:`~stcgym.agents.evaluation.evaluate` (the closed-loop evaluation of one episode,
per-episode metrics), :mod:`~stcgym.agents.evaluation.response` (settling against the yardstick),
:mod:`~stcgym.agents.evaluation.statistics` and :mod:`~stcgym.agents.benchmark.headline` (interval
estimates with the run as the unit), :mod:`~stcgym.agents.benchmark.report` and
:mod:`~stcgym.agents.benchmark.attribution` (its answer to "identification or design?"),
:mod:`~stcgym.agents.benchmark.ladder_report` (the ladder across its rungs, results by stratum),
:mod:`~stcgym.agents.benchmark.plots` and :mod:`~stcgym.agents.benchmark.style` (output).

Identical terms
---------------
Every controller meets the same fixed episodes of a scenario (plants, seeds, noise, reference,
initial state, jump time), observes ``[y(k), r(k)]`` only, and is clipped at the same action
bound, set per training distribution from the LQG yardstick's input range. RL agents train on
the score per step (the scored cost over the LQG cost of the episode's own plant, capped:
:mod:`stcgym.agents.rl.reward`), on episodes drawn like the evaluation episodes (length,
noise, reference, jumps), with ``gamma 0.9``, normalised observations and the integral of the
tracking error among their inputs; the
self-tuning controllers are told the plant order of the training distribution. Every ratio is
to LQG on the true model on the same episode. The report lists what each controller knows.

Scenarios
---------
``nominal:P`` (catalogue plant ``P``; RL trains on ``P``), ``family:test`` (the test split of
the plant family; RL trains on its training split, validated on its validation split),
``family:<variant>`` (a held-out variant of the family: out of distribution for everyone),
``jump:test`` (the test split with a parameter jump at a random time in every episode) and
``mimo:P`` (a MIMO plant with measured state). Recurrent agents (``rppo``) and the agents that
know what the estimator knows (``theta_ppo``, ``theta_sac``, ``residual_ppo``) train on the
family only, with jumps in a share of their episodes.

Controllers
-----------
``ppo``, ``sac``, ``td3``, ``a2c``, ``rppo``: Stable-Baselines3 / sb3-contrib agents
(:mod:`stcgym.agents.rl.sb3`), one model per training distribution and training run;
``theta_ppo`` and ``theta_sac`` observe an estimator's online estimate besides their window,
``residual_ppo`` corrects the self-tuning controller's input
(:mod:`stcgym.agents.rl.interfaces`). The
classical controllers (``stc``, ``stc_lq``, ``stc_kfmils``, ``stc_mimo``, the yardstick
``lqg``, ``oracle`` and ``zero``) are those of :mod:`stcgym.agents.controllers`.

Statistics
----------
The unit is the run: an RL agent's training run, a self-tuning controller's seed. Cost / LQG
and the normalised score are interquartile means (and medians) over runs and test plants of
the episodes that stayed bounded, with a bootstrap over runs and plants; divergence is a rate
beside them with its own interval, never mixed into a ratio; comparisons are paired on
(plant, episode) (:mod:`~stcgym.agents.benchmark.headline`). An RL run that kept its untrained
network (no improvement over initialisation) is left out of its agent's estimates and named.

Tiers
-----
``quick`` (the default, about 4 minutes on 2 cores: 3 runs, 40 test plants, two held-out
variants, short RL caps), ``standard`` (about 8.5 hours: 5 runs, the whole test split of 200
plants, every held-out variant, RL caps of 10^6 env steps on the family for PPO and
RecurrentPPO) and ``full`` (about 38 hours: 10 runs, every MIMO plant, TD3 and A2C too). In every
tier each RL agent trains until its learning curve on the validation episodes plateaus or it
reaches its cap (:mod:`stcgym.agents.rl.stopping`), and the report says which, per run.

Execution
---------
The driver first sets the action bounds (``config.json`` keeps them), runs the yardstick and
zero input on every scenario, then hands every RL training job (training distribution x agent x
run, a JSON task of :mod:`stcgym.agents.rl.training`) to the executor of
:mod:`stcgym.agents.executors` (``jobs`` local processes, or Ray), longest first, while it
evaluates the other classical controllers in a thread, and logs ``job k/N, ETA``. Each
finished job is written at once to the results store (``store/``, a few MB for a whole
standard run, meant to be committed); ``run_bench(cfg, resume=True)`` (``stcgym bench --resume
RUN_DIR``) uses the records its plan asks for instead of running those jobs again, also from a
fresh clone without the trained models. ``metrics.csv``, the report and the figures are
rendered from the store alone (``stcgym report RUN_DIR``).

Output (``<out>/<run>/``): ``config.json`` and ``store/`` (the run's outcome, as data);
rendered from them ``metrics.csv``, ``learning_curves.csv``, ``statistics.json``, ``report.md``
and the PNG plots; and, not needed to resume or render, ``models/`` (each trained agent with its
per-step test costs).
"""

from stcgym.agents.benchmark.config import BenchConfig, BenchInputError, build_config
from stcgym.agents.benchmark.plan import estimate_seconds
from stcgym.agents.benchmark.render import render_run
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
    "render_run",
    "run_bench",
]
