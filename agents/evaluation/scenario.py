"""A scenario: a set of test episodes on an environment, as every controller is scored on it.

The bench (:mod:`stcgym.agents.benchmark.scenarios`) makes its scenarios from a configuration;
the controllers' builders (:data:`stcgym.agents.controllers.CONTROLLERS`) read a scenario's
environment and the plant order its self-tuning controllers are told.
"""

from __future__ import annotations

from dataclasses import dataclass

from stcgym.agents.evaluation.env_spec import EnvSpec
from stcgym.agents.evaluation.episodes import EpisodeSet

__all__ = ["Scenario"]


@dataclass(frozen=True)
class Scenario:
    """One evaluation setting: its environment, episodes, and the RL training env it uses.

    ``controller_order`` is the plant order the self-tuning controllers are told (the training
    distribution's); ``in_distribution`` marks a scenario drawn from the distribution the
    validation curves are measured on; ``adaptation`` one whose per-step costs are kept (the
    adaptation figure, re-convergence after a jump).
    """

    name: str
    kind: str
    env: EnvSpec
    episodes: EpisodeSet
    train_key: str
    controller_order: int
    in_distribution: bool = True
    adaptation: bool = False

    @classmethod
    def of(cls, name: str, env: EnvSpec, episodes: EpisodeSet) -> Scenario:
        """``env``'s ``episodes`` as a scenario of kind ``name``, with no training key: what a
        controller is built on outside the bench's scenarios (the action bound's and the
        reward's LQG runs, the fixed PI law's tuning)."""
        return cls(name, name, env, episodes, train_key="", controller_order=env.order)

    @property
    def plant(self) -> str:
        """The plant label of the scenario's rows (a catalogue name or the family split)."""
        return self.name.split(":", 1)[1]

    def train_key_for(self, algo: str) -> str | None:
        """The training environment of ``algo``'s agents evaluated here (``None``: not here)."""
        from stcgym.agents.rl.configs import FAMILY_ALGORITHMS, TRUE_PARAMETER_ALGORITHMS

        if algo in TRUE_PARAMETER_ALGORITHMS and self.env.order != self.controller_order:
            return None  # told (a, b) of the training order: another order has no such input
        if algo in FAMILY_ALGORITHMS:  # trained on a plant family only (or a ladder's rung)
            family = self.train_key == "family" or self.train_key.startswith("family:")
            return self.train_key if family else None
        return self.train_key
