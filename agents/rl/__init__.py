"""RL agents: the observation window and training reward (:mod:`~stcgym.agents.rl.wrappers`),
what an agent observes besides it and how its action becomes the input: an estimator's
estimate, a residual on the self-tuning controller (:mod:`~stcgym.agents.rl.interfaces`),
one hyperparameter config per algorithm (:mod:`~stcgym.agents.rl.configs`), training,
saving/loading and the policy adapter (:mod:`~stcgym.agents.rl.sb3`), one training job as an
executor task (:mod:`~stcgym.agents.rl.training`) and the Stable-Baselines3 ``VecEnv`` adapter
of the native vector envs (:mod:`~stcgym.agents.rl.vec_env`).

Stable-Baselines3 and torch are imported only by ``sb3`` and ``vec_env``, when they are used.
"""
