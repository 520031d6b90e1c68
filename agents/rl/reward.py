"""The RL agents' training objective: the score, per step.

The bench scores a controller on an episode by its mean per-step cost divided by the LQG
yardstick's on the same episode. The default training reward (``reward = "lqg_ratio"``) is that
quantity per step,

    r(k) = -min( c(k) / c_LQG(plant), cost_cap ),

with ``c(k)`` the environment's scored per-step cost and ``c_LQG(plant)`` the LQG controller's
mean per-step cost on the episode's own plant (:func:`plant_lqg_costs`), and a diverged
episode charged its last (capped) step for every step it did not live
(:func:`~stcgym.agents.rl.wrappers.training_reward`). ``c_LQG`` is privileged information,
the true plant's optimal cost, used in the reward only, never in the observation: the
asymmetric actor-critic pattern (Pinto et al., RSS 2018), where training may use what the
deployed policy cannot see. Without it every plant's reward has its own scale (on the
training split of ``ladder-l4-v1`` LQG's cost per step has a 5-95 % range of 0.08-0.52), and
a return is dominated by the plants with the largest costs.

The cap bounds what one step (and so a divergence, at most ``cost_cap`` per step not lived)
can cost in LQG units. The raw cost (``reward = "cost"``, optionally with ``cost_squash``)
remains as the ablation it was: a diverged family episode under zero input returned a median
of -382,811, a bounded one -340.

``c_LQG(plant)`` is measured, not modelled: the bench's LQG controller (``CONTROLLERS["lqg"]``,
told the true parameters and every jump) runs :data:`LQG_COST_EPISODES` episodes of each plant
of the training distribution, without an input bound (as the action bound's measurement runs it:
:mod:`stcgym.agents.evaluation.bounds`), with the fixed seeds from :data:`LQG_COST_SEED`, all
plants as lanes of one compiled batch (about 5 s for the family's 1000 training plants); the
mean per-step cost of those episodes is the plant's. It is cached per spec within a process.
Two episodes of one plant differ by about 1-2 % in their mean cost (the noise and the random
reference), far below the spread across plants.
"""

from __future__ import annotations

import functools
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from stcgym.agents.evaluation.env_spec import EnvSpec
from stcgym.agents.evaluation.episodes import EpisodeSet, run_episodes
from stcgym.agents.evaluation.scenario import Scenario

__all__ = [
    "DEFAULT_COST_CAP",
    "LQG_COST_EPISODES",
    "LQG_COST_SEED",
    "REWARDS",
    "plant_lqg_costs",
]

#: The training rewards: ``"lqg_ratio"`` (the score per step, the default) and ``"cost"``
#: (the raw per-step cost, an ablation; ``cost_squash`` applies to it).
REWARDS: tuple[str, ...] = ("lqg_ratio", "cost")
#: The largest per-step cost of the ``lqg_ratio`` reward, in units of the plant's LQG cost: the
#: charge per step of a diverged episode's remainder. Zero input costs a median 17-19x LQG on
#: the family's plants that stay bounded, so the cap leaves every bounded policy its gradient.
DEFAULT_COST_CAP = 100.0
#: Episodes of each plant that measure its LQG cost, and their first seed (apart from the
#: bench's test, validation and bound episodes).
LQG_COST_EPISODES = 2
LQG_COST_SEED = 30_000
#: LQG's input bound while it measures (none in practice).
_UNBOUNDED = 1e9


@functools.lru_cache(maxsize=16)
def plant_lqg_costs(spec: EnvSpec, episodes: int = LQG_COST_EPISODES) -> NDArray:
    """LQG's mean per-step cost on each plant of ``spec`` (module docstring).

    Parameters
    ----------
    spec : EnvSpec
        The training distribution: catalogue plants, or a family's split.
    episodes : int
        Episodes per plant (seeds ``LQG_COST_SEED, LQG_COST_SEED + 1, ...`` plant-major).

    Returns
    -------
    ndarray, shape (plants,)
        In the order of ``spec.plant_names()`` (the vector env's ``plant_index``); read-only.

    Raises
    ------
    RuntimeError
        LQG diverged on some episode even without an input bound (no linear controller holds
        that plant at this noise: a family spec to fix).
    """
    from stcgym.agents.controllers import CONTROLLERS, YARDSTICK

    free = replace(spec, action_bound=_UNBOUNDED)
    eps = EpisodeSet.of(free, int(episodes), LQG_COST_SEED)
    builder = CONTROLLERS[YARDSTICK].build(None, Scenario.of("reward", free, eps))
    batch = run_episodes(builder, free, eps, informed=True)
    if batch.diverged.any():
        bad = [eps.plants[i] for i in np.flatnonzero(batch.diverged)][:5]
        raise RuntimeError(f"LQG on the true model diverged without an input bound on {bad}")
    costs = batch.cost.mean(axis=1).reshape(-1, int(episodes)).mean(axis=1)
    costs.setflags(write=False)
    return costs
