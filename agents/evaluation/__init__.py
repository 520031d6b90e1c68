"""Evaluation shared by the RL agents and the benchmark: episodes, closed-loop metrics, bounds.

Both :mod:`stcgym.agents.rl` (learning curves, the action unit) and
:mod:`stcgym.agents.benchmark` (the bench's jobs and report) score a controller the same way,
so the code that does it lives here, and neither of those two packages imports the other at
module level:

- :mod:`~stcgym.agents.evaluation.env_spec`: :class:`EnvSpec`, the episode settings of a
  benchmark scenario and how to build its environments;
- :mod:`~stcgym.agents.evaluation.episodes`: :class:`EpisodeSet` and :func:`run_episodes`, one
  episode runner for every controller (classical, oracle or RL);
- :mod:`~stcgym.agents.evaluation.evaluate`: :func:`evaluate` and the per-episode metrics;
- :mod:`~stcgym.agents.evaluation.response`: step-response figures (settling, overshoot);
- :mod:`~stcgym.agents.evaluation.statistics`: bootstrap intervals, IQM;
- :mod:`~stcgym.agents.evaluation.bounds`: the action bound and unit measured from LQG;
- :mod:`~stcgym.agents.evaluation.mimo`: the MIMO plants' environments (:class:`MimoEnvSpec`)
  and their known-model yardsticks.
"""
