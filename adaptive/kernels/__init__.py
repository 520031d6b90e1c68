"""Lane functions of the estimators and the self-tuning controller.

See :mod:`stcgym.envs.compiled` for the convention.

Each module holds the paper's equations for one plant as compiled lane functions; the public
classes in :mod:`stcgym.adaptive` own the lane state and call these for one plant or a batch.
"""
