"""The ``mimo`` scenario of ``stcgym bench``: multi-input plants with measured state.

Each plant of ``--mimo-plants`` (the MIMO catalogue, :data:`stcgym.envs.MIMO_PLANTS`) is one
scenario ``mimo:<plant>`` on ``stcgym/StateSpace-v0``: ``x(k+1) = A x(k) + B u(k)``, observation
``[x(k) + v(k), r(k)]``, the bench's square-wave reference on every state, its output noise,
cost ``||x - r||^2 + control_cost ||u||^2`` and an action bound set from the yardstick's input
range (:mod:`stcgym.agents.benchmark.bounds`). The controllers that declare ``"mimo"`` among
their plants (:class:`~stcgym.agents.controllers.ControllerInfo`) run there: the multivariable
self-tuning LQ controller (``stc_mimo``), and as the yardstick ``lqg`` the LQR on the true
``(A, B)`` with the same weights and tracking law; the window RL agents are trained on the
plant itself (their observation window then holds every state, reference and input). The
SISO-only controllers and the recurrent agents (trained on the SISO family) are left out.

:class:`MimoEnvSpec` is the scenario's environment, an :class:`~stcgym.agents.benchmark.
evaluate.EnvSpec` whose plant is a MIMO catalogue name, so the bench's evaluation loop, RL
training and JSON tasks take it as they take a SISO spec.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

import gymnasium as gym
import numpy as np

from stcgym.agents.benchmark.env_spec import EnvSpec
from stcgym.envs.mimo_plants import MimoPlantSpec, get_mimo_plant, mimo_plant_names

if TYPE_CHECKING:
    from stcgym.agents.benchmark.config import BenchConfig
    from stcgym.agents.benchmark.scenarios import Scenario

__all__ = [
    "MIMO_ENV_ID",
    "MimoEnvSpec",
    "check_mimo_plants",
    "estimate_error",
    "mimo_scenarios",
]

MIMO_ENV_ID = "stcgym/StateSpace-v0"


class MimoEnvSpec(EnvSpec):
    """The environment of a ``mimo`` scenario: one MIMO catalogue plant, measured state.

    The fields are :class:`~stcgym.agents.benchmark.evaluate.EnvSpec`'s; ``plants`` holds one
    name of :data:`stcgym.envs.MIMO_PLANTS` and there is no parameter jump.

    Raises
    ------
    ValueError
        On construction: not exactly one plant, an unknown MIMO plant (the message lists the
        catalogue), ``steps`` not a positive integer, or a jump.

    Examples
    --------
    >>> from stcgym.agents.benchmark.mimo import MimoEnvSpec
    >>> spec = MimoEnvSpec("quadruple_tank", steps=200)
    >>> spec.channels, spec.order
    ((4, 2), 4)
    >>> obs, info = spec.make().reset(seed=0)
    >>> obs.shape  # [x(0) + v(0), r(0)]
    (8,)
    >>> EnvSpec.from_dict(spec.to_dict()) == spec
    True
    """

    plant_kind: ClassVar[str] = "mimo"

    def __post_init__(self) -> None:
        plants = (self.plants,) if isinstance(self.plants, str) else tuple(self.plants)
        if len(plants) != 1:
            raise ValueError(f"a MIMO scenario runs on one MIMO plant, got {list(plants)}")
        object.__setattr__(self, "plants", (get_mimo_plant(plants[0]).name,))
        if int(self.steps) != self.steps or self.steps < 1:
            raise ValueError(f"episode steps must be a positive integer, got {self.steps!r}")
        if self.jump_step is not None or self.jump_to is not None:
            raise ValueError("a MIMO scenario has no parameter jump (jump_step, jump_to)")
        if self.family is not None or self.reference is not None:
            raise ValueError("a MIMO scenario has one plant and a square-wave reference")

    @property
    def plant(self) -> MimoPlantSpec:
        """The catalogue entry of the plant."""
        return get_mimo_plant(self.plants[0])

    @property
    def order(self) -> int:
        """Number of states ``n``."""
        return self.plant.n_states

    @property
    def channels(self) -> tuple[int, int]:
        """``(outputs, inputs)``: the ``n`` measured states and the ``m`` inputs."""
        return self.plant.n_states, self.plant.n_inputs

    def plant_names(self) -> list[str]:
        return list(self.plants)

    def _kwargs(self) -> tuple[str, dict[str, Any]]:
        from stcgym.envs.signals import SquareWave

        return MIMO_ENV_ID, dict(
            plant=self.plants[0],
            noise_std=self.noise_std,
            control_cost=self.control_cost,
            action_bound=self.action_bound,
            y_bound=self.y_bound,
            reference=SquareWave(period=self.period, amplitude=self.amplitude),
        )

    def reset_episode(self, env: gym.Env, seed: int, plant: str | None) -> tuple[Any, Any, Any]:
        """``(obs, info, plant_spec)`` of ``env.reset(seed=seed)``; ``plant`` may only name the
        spec's own plant."""
        if plant is not None and plant.lower() != self.plants[0]:
            raise ValueError(f"plant must be {self.plants[0]!r} (the spec's), got {plant!r}")
        obs, info = env.reset(seed=int(seed))
        return obs, info, env.unwrapped.mimo_plant

    def reset_lanes(
        self, env: Any, seeds: list[int], plants: list[str] | None
    ) -> tuple[np.ndarray, list[Any]]:
        obs, _ = env.reset(seed=[int(s) for s in seeds])
        return obs, [self.plant] * len(seeds)

    def to_dict(self) -> dict[str, Any]:
        """The spec as JSON data, marked ``kind: "mimo"`` (``EnvSpec.from_dict`` reads it)."""
        return {**super().to_dict(), "kind": "mimo"}


def check_mimo_plants(names: list[str]) -> None:
    """Raise ``ValueError`` naming ``--mimo-plants`` for names outside the MIMO catalogue."""
    bad = [p for p in names if p not in mimo_plant_names()]
    if bad:
        raise ValueError(
            f"unknown MIMO plant(s) {bad} in --mimo-plants; MIMO catalogue: {mimo_plant_names()}"
        )
    if len(set(names)) != len(names):
        raise ValueError(f"--mimo-plants lists a plant twice: {names}")


def mimo_spec(cfg: BenchConfig, plant: str) -> MimoEnvSpec:
    """The environment of ``mimo:<plant>`` (the bench's noise, cost and the plant's bound)."""
    from stcgym.agents.benchmark.scenarios import _episode_settings

    settings = _episode_settings(cfg)
    return MimoEnvSpec(
        (plant,),
        steps=settings["steps"],
        noise_std=settings["noise_std"],
        control_cost=settings["control_cost"],
        action_bound=float(cfg.action_bounds.get(f"mimo:{plant}", 10.0)),
    )


def mimo_scenarios(cfg: BenchConfig) -> list[Scenario]:
    """One ``mimo:<plant>`` scenario per plant of ``cfg.mimo_plants``; its RL agents train on
    the plant itself (training key ``mimo:<plant>``)."""
    from stcgym.agents.benchmark.episodes import EpisodeSet
    from stcgym.agents.benchmark.scenarios import Scenario

    out = []
    n = cfg.nominal_episodes
    for p in cfg.mimo_plants:
        env = mimo_spec(cfg, p)
        eps = EpisodeSet((env.plants[0],) * n, tuple(range(cfg.first_seed, cfg.first_seed + n)))
        out.append(Scenario(f"mimo:{p}", "mimo", env, eps, f"mimo:{p}", env.order))
    return out


def estimate_error(theta: np.ndarray, theta_hat: np.ndarray) -> np.ndarray:
    """Relative error ``||[A_hat B_hat] - [A B]||_F / ||[A B]||_F`` after each step (``nan``
    where there is no estimate); ``theta`` ``(T + 1, n (n + m))``, ``theta_hat`` ``(T, ...)``."""
    true = theta[1:]
    return np.linalg.norm(theta_hat - true, axis=1) / np.linalg.norm(true, axis=1)
