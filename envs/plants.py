"""Gymnasium environments for linear discrete-time plants (defined in
:mod:`stcgym.envs.linear_plant`, :mod:`stcgym.envs.canonical_plants` and
:mod:`stcgym.envs.state_space_plants`, re-exported here).

Timing convention (the same in every environment)
--------------------------------------------------
Steps are counted ``k = 0, 1, 2, ...`` from ``reset`` (``k`` is the seed paper's ``t - 1``). At
step ``k`` the agent observes ``y(k)`` and ``r(k)``, applies ``u(k)``; the environment computes
``x(k+1) = A(k) x(k) + B(k) u(k) + w(k)`` and returns ``y(k+1) = C x(k+1) + D u(k) + v(k+1)``
and ``r(k+1)``. The feedthrough term uses the input still held from the last step (zero-order
hold, sampled before the next input is chosen), so the observation never depends on an action not
yet taken. The state starts at zero unless set, and every signal is zero before the first step,
so ``y(0) = C x(0) + v(0)``.

The reward of step ``k`` is ``-(||y_clean(k+1) - r(k+1)||^2 + rho ||u(k)||^2)``, scored on the
noise-free output (the controller's quality, not the sensor's), with ``rho = control_cost``.

Episodes end with ``terminated=True`` (and ``info["diverged"] = True``) when an output leaves
``[-y_bound, y_bound]``, the state stops being finite, or the reward overflows (then the reward
is :data:`~stcgym.envs.dynamics.REWARD_FLOOR`, the most negative finite float: rewards and
observations are always finite); the time limit (``max_episode_steps`` in the registration or
``gym.make``) gives ``truncated=True``.

The plant step itself is the compiled lane function of :mod:`stcgym.envs.dynamics`, the same
one the vector envs of :mod:`stcgym.envs.vector` run for each lane, so a single env equals the
matching lane of a vector env bit for bit.

Randomness: ``reset(seed=...)`` seeds ``np_random``; each episode then draws independent child
streams for output noise, process noise, the reference, the parameter schedule and the initial
state / parameter draws, so an episode is reproducible from its seed whatever happened before.

Bad input raises before any state changes: ``ValueError`` for a wrong value or shape,
``TypeError`` for a wrong kind of object, each naming the argument and the expected form.
Every env pickles and deep-copies; the copy continues exactly like the original.
"""

from __future__ import annotations

from stcgym.envs.canonical_plants import (
    CanonicalPlantEnv,
    ObservabilityCanonicalEnv,
    ObserverCanonicalEnv,
)
from stcgym.envs.linear_plant import LinearPlantEnv
from stcgym.envs.state_space_plants import (
    DEFAULT_STATE_SPACE,
    MultichannelStaticEnv,
    StateSpaceEnv,
)

__all__ = [
    "LinearPlantEnv",
    "CanonicalPlantEnv",
    "ObserverCanonicalEnv",
    "ObservabilityCanonicalEnv",
    "StateSpaceEnv",
    "MultichannelStaticEnv",
    "DEFAULT_STATE_SPACE",
]
