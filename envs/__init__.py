"""Linear plants as Gymnasium environments, registered under the ``stcgym`` namespace.

``import stcgym.envs`` registers:

==================================  =============================================================
id                                  plant
==================================  =============================================================
``stcgym/ObserverCanonical-v0``      SISO observer canonical form, Ding & Ma (2014) eq. (1)-(5)
``stcgym/ObservabilityCanonical-v0`` SISO observability canonical form, Ding & Ma (2014) (146)-(147)
``stcgym/StateSpace-v0``             MIMO ``(A, B, C, D)`` or any python-control system
``stcgym/MultichannelStatic-v0``     static ``y^T = u^T Theta + v``, Voevoda & Troshina (2017)
``stcgym/PlantFamily-v0``            one split of a plant family, a plant drawn per episode
``stcgym/QuadrupleTankFamily-v0``    quadruple tanks drawn from their valve settings, one split
==================================  =============================================================

All but the static object also have a native vector env (:mod:`stcgym.envs.vector`,
:class:`~stcgym.envs.family_env.PlantFamilyVectorEnv`), the default of
``gym.make_vec(id, num_envs=B, **kwargs)``. Every env, single or vector, steps its plant with the
compiled lane functions of :mod:`stcgym.envs.dynamics` (the plant step, written once), so a
single env equals the matching lane of a vector env bit for bit. ``gym.make(id)`` works for
every id with its defaults (``StateSpace-v0``: :data:`~stcgym.envs.plants.DEFAULT_STATE_SPACE`).
"""

from __future__ import annotations

import gymnasium as gym

from stcgym.envs import catalogue as _catalogue
from stcgym.envs import families as _families
from stcgym.envs import mimo_plants as _mimo_plants
from stcgym.envs import plants as _plants
from stcgym.envs.canonical import (
    canonical_matrices,
    companion_A,
    observer_to_observability_b,
    transfer_function_coefficients,
)
from stcgym.envs.catalogue import PlantSpec, get_plant, plant_names
from stcgym.envs.families import (
    FamilySpec,
    FamilySpecError,
    Plant,
    draw_plant,
    get_family,
    load_family,
)
from stcgym.envs.family_env import PlantFamilyEnv
from stcgym.envs.mimo_plants import MimoPlantSpec, get_mimo_plant, mimo_plant_names
from stcgym.envs.plants import (
    CanonicalPlantEnv,
    LinearPlantEnv,
    MultichannelStaticEnv,
    ObservabilityCanonicalEnv,
    ObserverCanonicalEnv,
    StateSpaceEnv,
)
from stcgym.envs.signals import (
    PRBS,
    ArrayReference,
    CallableReference,
    Constant,
    Jumps,
    Ramp,
    RandomJump,
    RandomSteps,
    RandomWalk,
    Reference,
    Schedule,
    Sine,
    SquareWave,
    Step,
    Zero,
    make_reference,
    make_schedule,
)

# The public data names are bound here with their doc comments: the API reference reads a data
# name's text from the module that exports it.

#: The catalogue plants, :class:`PlantSpec` by name (``stable2``, ``lightly_damped2``,
#: ``unstable2``, ``nonminphase2``, ``integrator2``, ``stable4``, ``timevarying2``; see
#: :mod:`stcgym.envs.catalogue` for their poles, zeros and gains). :func:`get_plant` looks a name
#: up case-insensitively with a clear error.
PLANTS: dict[str, PlantSpec] = _catalogue.PLANTS

#: The named plant families, spec dict by ``"<name>-v<version>"`` (see
#: :data:`stcgym.envs.families.FAMILIES`; ``"siso2-v1"`` is the benchmark's default family);
#: :func:`get_family` looks a name up.
FAMILIES: dict[str, dict] = _families.FAMILIES
#: The MIMO catalogue plants, :class:`MimoPlantSpec` by name (``quadruple_tank``, ``he1``,
#: ``ac1``: continuous-time models with measured state, discretised by zero-order hold; see
#: :mod:`stcgym.envs.mimo_plants` for their sources, sample times and poles). Select one with
#: ``gym.make("stcgym/StateSpace-v0", plant=name)``; :func:`get_mimo_plant` looks a name up.
MIMO_PLANTS: dict[str, MimoPlantSpec] = _mimo_plants.MIMO_PLANTS

#: The plant of ``gym.make("stcgym/StateSpace-v0")`` without matrices: a stable, coupled
#: two-state, two-input plant (eigenvalues 0.9 and 0.8) with measured state (``C = I``, ``D = 0``).
DEFAULT_STATE_SPACE: dict[str, tuple] = _plants.DEFAULT_STATE_SPACE

#: ``max_episode_steps`` of every registered id (``gym.make(..., max_episode_steps=T)`` overrides)
#: but ``stcgym/PlantFamily-v0``, which truncates by itself at its family's episode length.
DEFAULT_MAX_EPISODE_STEPS = 1000

#: The registered environment ids and their entry points (``"module:Class"``).
ENV_IDS = {
    "stcgym/ObserverCanonical-v0": "stcgym.envs.plants:ObserverCanonicalEnv",
    "stcgym/ObservabilityCanonical-v0": "stcgym.envs.plants:ObservabilityCanonicalEnv",
    "stcgym/StateSpace-v0": "stcgym.envs.plants:StateSpaceEnv",
    "stcgym/MultichannelStatic-v0": "stcgym.envs.plants:MultichannelStaticEnv",
    "stcgym/PlantFamily-v0": "stcgym.envs.family_env:PlantFamilyEnv",
    "stcgym/QuadrupleTankFamily-v0": "stcgym.envs.tank_family:QuadrupleTankFamilyEnv",
}

#: The native vector envs: ``gym.make_vec(id, num_envs=B)`` builds these by default (also with
#: ``vectorization_mode="vector_entry_point"``): all lanes in numpy arrays, stepped by one
#: compiled loop (the multichannel static object has none).
VECTOR_ENTRY_POINTS = {
    "stcgym/ObserverCanonical-v0": "stcgym.envs.vector:ObserverCanonicalVectorEnv",
    "stcgym/ObservabilityCanonical-v0": "stcgym.envs.vector:ObservabilityCanonicalVectorEnv",
    "stcgym/StateSpace-v0": "stcgym.envs.vector:StateSpaceVectorEnv",
    "stcgym/PlantFamily-v0": "stcgym.envs.family_env:PlantFamilyVectorEnv",
    "stcgym/QuadrupleTankFamily-v0": "stcgym.envs.tank_family:QuadrupleTankFamilyVectorEnv",
}
#: Ids that truncate their episodes themselves (registered without a ``TimeLimit``).
_SELF_TRUNCATING = frozenset({"stcgym/PlantFamily-v0"})


def _register() -> None:
    for env_id, entry_point in ENV_IDS.items():
        if env_id not in gym.registry:
            gym.register(
                id=env_id,
                entry_point=entry_point,
                vector_entry_point=VECTOR_ENTRY_POINTS.get(env_id),
                max_episode_steps=(
                    None if env_id in _SELF_TRUNCATING else DEFAULT_MAX_EPISODE_STEPS
                ),
            )


_register()

__all__ = [
    "DEFAULT_STATE_SPACE",
    "ENV_IDS",
    "FAMILIES",
    "FamilySpec",
    "FamilySpecError",
    "Plant",
    "PlantFamilyEnv",
    "draw_plant",
    "get_family",
    "load_family",
    "VECTOR_ENTRY_POINTS",
    "PLANTS",
    "PRBS",
    "ArrayReference",
    "CallableReference",
    "CanonicalPlantEnv",
    "Constant",
    "Jumps",
    "LinearPlantEnv",
    "MIMO_PLANTS",
    "MimoPlantSpec",
    "MultichannelStaticEnv",
    "ObservabilityCanonicalEnv",
    "ObserverCanonicalEnv",
    "PlantSpec",
    "Ramp",
    "RandomJump",
    "RandomSteps",
    "RandomWalk",
    "Reference",
    "Schedule",
    "Sine",
    "SquareWave",
    "StateSpaceEnv",
    "Step",
    "Zero",
    "canonical_matrices",
    "companion_A",
    "get_mimo_plant",
    "get_plant",
    "make_reference",
    "make_schedule",
    "observer_to_observability_b",
    "mimo_plant_names",
    "plant_names",
    "transfer_function_coefficients",
]
