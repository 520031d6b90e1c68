"""Batched estimators and self-tuning regulator: one import for everything with ``num_envs``.

* ``make_batched_estimator(name, n, num_envs=B, mode=...)``: ``B`` lanes of
  :func:`~stcgym.adaptive.recursive.make_estimator`; ``update(y (B,)) -> theta (B, 2n)``,
  ``predict(u (B,))``.
* ``BatchedSelfTuningController(n, num_envs=B, mode=...)``: ``B`` lanes of
  :class:`~stcgym.adaptive.controller.SelfTuningController`;
  ``predict(obs (B, 2)) -> (actions (B, 1), None)``.
* ``FastLoop(controller=..., **env_kwargs)``: one plant and one regulator in scalar generated
  code (the single-plant fast path).

Modes: ``"exact"`` repeats the single implementation's numpy/BLAS/LAPACK calls on stacked
arrays and equals ``B`` independent single runs to rounding (OpenBLAS may pick another kernel
for a stacked product, by CPU); ``"fast"`` runs
generated straight-line kernels (structure of the canonical matrices exploited, no BLAS), the
same equations in another evaluation order: equal to rounding amplified by the conditioning
(about 1e-13 relative with a moderate ``P(0)``, about 1e-9 with the paper's ``p0 = 1e6``
during the first updates). The single-plant :class:`FastLoop` is bit-for-bit a lane of the
fast batched controller. Pair them with the vector envs of :mod:`stcgym.envs.vector`
(``exact=True`` there makes the whole closed loop equal to single runs to rounding).
"""

from __future__ import annotations

from stcgym.adaptive.batched_controller import (
    REJECTION_REASONS,
    BatchedSelfTuningController,
)
from stcgym.adaptive.batched_estimators import (
    BatchedRecursiveEstimator,
    make_batched_estimator,
)
from stcgym.adaptive.batched_fast import FastBatchedSelfTuningController, FastLoop
from stcgym.adaptive.batched_kernels import FastBatchedEstimator

__all__ = [
    "REJECTION_REASONS",
    "BatchedRecursiveEstimator",
    "BatchedSelfTuningController",
    "FastBatchedEstimator",
    "FastBatchedSelfTuningController",
    "FastLoop",
    "make_batched_estimator",
]
