"""The environment of a benchmark scenario as data: :class:`EnvSpec`.

An :class:`EnvSpec` names the plants (catalogue plants, or a split of a registered plant
family, :mod:`stcgym.envs.families`), the episode (length, output noise, reference, random
initial state, parameter jump) and the scoring settings (control cost, action bound, divergence
bound). It is hashable and JSON-able, so it travels in the bench's tasks and ``config.json``,
and it builds the single environment (:meth:`EnvSpec.make`) and the native vector environment
(:meth:`EnvSpec.make_vec`) of the same episodes: lane ``i`` of ``make_vec`` reset with seed ``s``
is ``make()`` reset with seed ``s``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np

from stcgym.envs.catalogue import get_plant

__all__ = ["ENV_ID", "FAMILY_ENV_ID", "EnvSpec", "freeze", "thaw"]

ENV_ID = "stcgym/ObserverCanonical-v0"
FAMILY_ENV_ID = "stcgym/PlantFamily-v0"


def freeze(value: Any) -> Any:
    """A JSON value as a hashable one: dicts become sorted ``(key, value)`` tuples, lists
    tuples (:func:`thaw` is the inverse)."""
    if isinstance(value, Mapping):
        return tuple(sorted((str(k), freeze(v)) for k, v in value.items()))
    if isinstance(value, (list, tuple)):
        return tuple(freeze(v) for v in value)
    return value


def thaw(value: Any) -> Any:
    """The JSON value of :func:`freeze`'s output (a reference spec as a dict)."""
    if (
        isinstance(value, tuple)
        and value
        and all(isinstance(v, tuple) and len(v) == 2 and isinstance(v[0], str) for v in value)
    ):
        return {k: thaw(v) for k, v in value}
    if isinstance(value, tuple):
        return [thaw(v) for v in value]
    return value


@dataclass(frozen=True)
class EnvSpec:
    """Everything needed to build the environment of one scenario (hashable, JSON-able).

    Parameters
    ----------
    plants
        One catalogue name, or several (one drawn per episode). Empty with ``family``.
    steps
        Episode length ``T`` (time limit).
    noise_std
        Output noise standard deviation.
    control_cost
        ``rho`` in the cost ``(y - r)^2 + rho u^2``.
    action_bound
        Actions are clipped to ``[-action_bound, action_bound]``.
    y_bound
        Divergence bound on ``|y|``.
    period, amplitude
        The square-wave reference used when ``reference`` is ``None``.
    jump_step, jump_to
        Catalogue plants only: from step ``jump_step`` on the plant has the observer-form
        parameters ``jump_to = (a1..an, b1..bn)``.
    family, split
        A registered plant family (:func:`stcgym.envs.families.get_family`) and one of its
        splits or variants: each episode draws a member (``stcgym/PlantFamily-v0``).
    jump_probability
        With ``family``: the chance that an episode has the family's parameter jump (``None``:
        the family's own).
    reference
        A reference spec (:func:`stcgym.envs.signals.make_reference`, e.g. ``{"kind":
        "random_steps", "amplitude": 1.0, "hold": [25, 75]}``), stored frozen; ``None``: the
        square wave of ``period`` and ``amplitude``.
    initial_state_std
        ``x(0) ~ N(0, initial_state_std^2 I)`` in every episode (0: the zero state).

    Raises
    ------
    ValueError
        On construction: neither or both of ``plants`` and ``family``, an unknown catalogue
        name or family split, plants of mixed orders, ``steps`` not a positive integer, only
        one of ``jump_step`` and ``jump_to`` (or a jump with a family), a jump outside the
        episode or ``jump_to`` not of length ``2n``.

    Examples
    --------
    >>> from stcgym.agents import EnvSpec
    >>> spec = EnvSpec("unstable2", steps=200, jump_step=100, jump_to=(-1.5, 0.56, 0.5, 0.3))
    >>> spec.plants, spec.order
    (('unstable2',), 2)
    >>> EnvSpec.from_dict(spec.to_dict()) == spec
    True
    >>> env = spec.make()
    >>> obs, info = env.reset(seed=0)
    >>> info["theta"]
    array([-1.7 ,  0.66,  0.5 ,  0.3 ])
    >>> EnvSpec("unstable2", steps=100, jump_step=150, jump_to=(-1.5, 0.56, 0.5, 0.3))
    Traceback (most recent call last):
    ...
    ValueError: jump_step must lie inside the episode (0, 100), got 150

    The test split of the benchmark's plant family, with random steps as the reference:

    >>> test = EnvSpec(family="siso2-v1", split="test", jump_probability=0.0,
    ...                reference={"kind": "random_steps", "amplitude": 1.0, "hold": [25, 75]})
    >>> test.order, len(test.plant_names()), test.plant_names()[0]
    (2, 200, 'siso2-v1/test/1100')
    """

    plants: tuple[str, ...] = ()
    steps: int = 1000
    noise_std: float = 0.05
    control_cost: float = 0.01
    action_bound: float = 10.0
    y_bound: float = 100.0
    period: int = 100
    amplitude: float = 1.0
    jump_step: int | None = None
    jump_to: tuple[float, ...] | None = None
    family: str | None = None
    split: str | None = None
    jump_probability: float | None = None
    reference: Any = None
    initial_state_std: float = 0.0
    #: the plants' kind, matched against a controller's ``ControllerInfo.plants``
    plant_kind: ClassVar[str] = "siso"

    def __post_init__(self) -> None:
        plants = (self.plants,) if isinstance(self.plants, str) else tuple(self.plants)
        object.__setattr__(self, "plants", plants)
        object.__setattr__(self, "reference", freeze(self.reference))
        if int(self.steps) != self.steps or self.steps < 1:
            raise ValueError(f"episode steps must be a positive integer, got {self.steps!r}")
        if float(self.initial_state_std) < 0:
            raise ValueError(f"initial_state_std must be >= 0, got {self.initial_state_std!r}")
        if (self.jump_step is None) != (self.jump_to is None):
            raise ValueError("jump_step and jump_to go together")
        if self.family is not None:
            self._check_family(plants)
            return
        if not plants:
            raise ValueError("EnvSpec needs at least one plant (or a family and a split)")
        if self.split is not None or self.jump_probability is not None:
            raise ValueError("split and jump_probability need a family")
        specs = [get_plant(p) for p in plants]  # raises on unknown names
        if len({s.n for s in specs}) > 1:
            raise ValueError(f"a plant family must share one order, got {list(plants)}")
        if self.jump_step is not None:
            if not 0 < self.jump_step < self.steps:
                raise ValueError(
                    f"jump_step must lie inside the episode (0, {self.steps}), got {self.jump_step}"
                )
            object.__setattr__(self, "jump_to", tuple(float(v) for v in self.jump_to))
            if len(self.jump_to) != 2 * specs[0].n:
                raise ValueError(f"jump_to must have {2 * specs[0].n} parameters")

    def _check_family(self, plants: tuple[str, ...]) -> None:
        if plants:
            raise ValueError("give plants or a family, not both")
        if self.jump_step is not None:
            raise ValueError("a family's jumps come from its spec (jump_probability), not jump_to")
        if self.split is None:
            raise ValueError(f"a family needs a split; {self.family!r} has {self.split_names()}")
        if self.split not in self.split_names():
            raise ValueError(
                f"split must be one of {self.split_names()} of family {self.family!r}, "
                f"got {self.split!r}"
            )
        p = self.jump_probability
        if p is not None and not 0.0 <= float(p) <= 1.0:
            raise ValueError(f"jump_probability must be in [0, 1], got {p!r}")

    # -- the plants ------------------------------------------------------------------------
    def family_spec(self) -> Any:
        """The :class:`~stcgym.envs.families.FamilySpec` of the split (a variant's own spec)."""
        from stcgym.envs.families import get_family

        return get_family(self.family).members(self.split)[0]

    def split_names(self) -> list[str]:
        """The family's splits and variants."""
        from stcgym.envs.families import get_family

        return get_family(self.family).split_names

    def plant_names(self) -> list[str]:
        """The names of the plants episodes are drawn from (catalogue names, or the members
        of the family's split in index order)."""
        if self.family is None:
            return list(self.plants)
        from stcgym.envs.families import get_family

        base = get_family(self.family)
        return [f"{base.key}/{self.split}/{i}" for i in base.members(self.split)[1]]

    @property
    def order(self) -> int:
        """Plant order ``n`` (of the first plant: a family has one order)."""
        if self.family is not None:
            return self.family_spec().order
        return get_plant(self.plants[0]).n

    @property
    def channels(self) -> tuple[int, int]:
        """``(outputs, inputs)`` of the plants: ``(1, 1)``."""
        return 1, 1

    # -- the episode -----------------------------------------------------------------------
    def reference_spec(self) -> dict[str, Any]:
        """The reference as a :func:`~stcgym.envs.signals.make_reference` spec."""
        if self.reference is None:
            return {"kind": "square", "period": self.period, "amplitude": self.amplitude}
        return thaw(self.reference)

    @property
    def span(self) -> int:
        """Steps between two reference changes at the least (the window of the adaptation
        metrics): half a square wave's period, a random step's shortest hold."""
        ref = self.reference_spec()
        if ref.get("kind") == "random_steps":
            return int(min(ref["hold"]))
        return max(1, int(ref.get("period", self.period)) // 2)

    @property
    def reference_amplitude(self) -> float:
        """The reference's amplitude (1 when the spec has none)."""
        return float(self.reference_spec().get("amplitude", 1.0))

    def _common_kwargs(self) -> dict[str, Any]:
        """The keyword arguments every env of a spec takes (SISO or MIMO): noise, cost, bounds,
        reference and the initial state's spread."""
        kwargs: dict[str, Any] = dict(
            noise_std=self.noise_std,
            control_cost=self.control_cost,
            action_bound=self.action_bound,
            y_bound=self.y_bound,
            reference=self.reference_spec(),
        )
        if self.initial_state_std:
            kwargs["initial_state_std"] = float(self.initial_state_std)
        return kwargs

    def _kwargs(self) -> tuple[str, dict[str, Any]]:
        """The env id and the keyword arguments of ``gym.make`` and ``gym.make_vec``."""
        kwargs = self._common_kwargs()
        if self.family is not None:
            kwargs.update(family=self.family, split=self.split, steps=self.steps)
            if self.jump_probability is not None:
                kwargs["jump_probability"] = float(self.jump_probability)
            return FAMILY_ENV_ID, kwargs
        kwargs["plant"] = list(self.plants) if len(self.plants) > 1 else self.plants[0]
        if self.jump_step is not None:
            from stcgym.envs.signals import Jumps

            kwargs["schedule"] = Jumps({self.jump_step: np.array(self.jump_to)})
        return ENV_ID, kwargs

    def make(self, **overrides: Any) -> gym.Env:
        """A fresh environment (time limit ``steps``); ``overrides`` replace spec fields.

        Parameters
        ----------
        **overrides
            Fields of :class:`EnvSpec` to replace (validated as on construction).

        Returns
        -------
        gymnasium.Env
            ``stcgym/ObserverCanonical-v0`` (catalogue plants) or ``stcgym/PlantFamily-v0``
            (a family's split) with the spec's noise, cost, bounds, reference, initial state
            and parameter jump.

        Raises
        ------
        ValueError
            An override out of range; ``TypeError`` for an unknown field.
        """
        import stcgym.envs  # noqa: F401  (registers the ids)

        spec = replace(self, **overrides) if overrides else self
        env_id, kwargs = spec._kwargs()
        return gym.make(env_id, max_episode_steps=spec.steps, **kwargs)

    def make_vec(self, num_envs: int, **kwargs: Any) -> Any:
        """The native vector environment of ``num_envs`` lanes of this spec (time limit
        ``steps``); ``kwargs`` go to the vector env (e.g. ``info_keys=()``)."""
        import stcgym.envs  # noqa: F401  (registers the ids)

        env_id, env_kwargs = self._kwargs()
        return gym.make_vec(
            env_id,
            num_envs=int(num_envs),
            vectorization_mode="vector_entry_point",
            max_episode_steps=self.steps,
            **env_kwargs,
            **kwargs,
        ).unwrapped

    def reset_episode(self, env: gym.Env, seed: int, plant: str | None) -> tuple[Any, Any, Any]:
        """``(obs, info, plant_spec)`` of ``env.reset(seed=seed)`` on the member ``plant``
        (default: the environment's draw)."""
        options = None if plant is None else {"plant": plant}
        obs, info = env.reset(seed=int(seed), options=options)
        return obs, info, env.unwrapped.plant

    def reset_lanes(
        self, env: Any, seeds: list[int], plants: list[str] | None
    ) -> tuple[np.ndarray, list[Any]]:
        """Reset every lane of ``env`` (:meth:`make_vec`): lane ``i`` with ``seeds[i]`` on the
        member ``plants[i]`` (default: each lane's draw). Returns the observations and each
        lane's plant spec."""
        options = None if plants is None else {"plant": list(plants)}
        obs, _ = env.reset(seed=[int(s) for s in seeds], options=options)
        return obs, list(env.plants)

    # -- data ------------------------------------------------------------------------------
    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> EnvSpec:
        """Inverse of :meth:`to_dict` (JSON data back to a spec; ``kind: "mimo"`` gives a
        :class:`~stcgym.agents.evaluation.mimo.MimoEnvSpec`).

        Parameters
        ----------
        data : dict
            The fields, lists where the spec holds tuples.

        Returns
        -------
        EnvSpec

        Raises
        ------
        ValueError
            A field out of range (as on construction).
        """
        d = dict(data)
        if d.pop("kind", "siso") == "mimo":
            from stcgym.agents.evaluation.mimo import MimoEnvSpec

            return MimoEnvSpec(**{**d, "plants": tuple(d["plants"])})
        d["plants"] = tuple(d.get("plants", ()))
        if d.get("jump_to") is not None:
            d["jump_to"] = tuple(d["jump_to"])
        return cls(**d)

    def to_dict(self) -> dict[str, Any]:
        """The spec as JSON data (:meth:`from_dict` reads it back)."""
        d = asdict(self)
        d["plants"] = list(self.plants)
        d["jump_to"] = None if self.jump_to is None else list(self.jump_to)
        d["reference"] = None if self.reference is None else thaw(self.reference)
        return d
