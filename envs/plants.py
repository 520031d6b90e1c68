"""Gymnasium environments for linear discrete-time plants: re-exports the base
:class:`~stcgym.envs.linear_plant.LinearPlantEnv` (its module docstring states the timing
convention, reward, termination and randomness every env shares), the SISO canonical forms
(:mod:`stcgym.envs.canonical_plants`) and the state-space and multichannel plants
(:mod:`stcgym.envs.state_space_plants`)."""

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
