"""A drawn plant of a family as the single environment a test steps by hand (shared by the
tests that compare the compiled lanes with single episodes)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym

import stcgym.envs  # noqa: F401  (registers the ids)


def single_family_env(fam: Any, plant: Any, steps: int, **extra: Any) -> gym.Env:
    """``stcgym/ObserverCanonical-v0`` with ``plant``'s ``a``, ``b`` and the family's noise,
    cost, bounds and reference, truncated after ``steps``; ``extra``: e.g. a ``schedule``."""
    return gym.make(
        "stcgym/ObserverCanonical-v0",
        a=plant.a,
        b=plant.b,
        **fam.env_settings,
        max_episode_steps=steps,
        **extra,
    )
