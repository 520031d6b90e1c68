"""Plant families live in :mod:`stcgym.envs.families`; this module re-exports them so that
``from stcgym.agents.sweeps.families import ...`` keeps working."""

from __future__ import annotations

from stcgym.envs.families import (
    DEFAULT_FAMILY,
    FamilySpec,
    FamilySpecError,
    Plant,
    draw_plant,
    draw_plants,
    load_family,
    plant_features,
)

__all__ = [
    "DEFAULT_FAMILY",
    "FamilySpec",
    "FamilySpecError",
    "Plant",
    "draw_plant",
    "draw_plants",
    "load_family",
    "plant_features",
]
