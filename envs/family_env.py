"""The plant-family environment: every episode a plant drawn from one split of a family.

``gym.make("stcgym/PlantFamily-v0", family="siso2-v1", split="train")`` gives any RL library
the plant distribution the benchmark scores on (``family="ladder-l1-v1"`` ... ``"ladder-l4-v1"``:
the rungs of the difficulty ladder, :data:`~stcgym.envs.families.LADDER`, without jumps unless
``jump_probability`` asks for them): a :class:`~stcgym.envs.families.FamilySpec`
(:data:`~stcgym.envs.families.FAMILIES`), one of its splits (or variants), and the family's
noise, reference, cost, bounds, random initial state, episode length and random jumps.
``gym.make_vec("stcgym/PlantFamily-v0", num_envs=B, ...)`` builds the native vector env
:class:`PlantFamilyVectorEnv`, whose lane ``i`` reproduces the single env reset with seed
``s + i`` bit for bit, across autoresets and jumps.
"""

from __future__ import annotations

import functools
import json
import numbers
from collections.abc import Hashable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.envs.canonical_plants import ObserverCanonicalEnv
from stcgym.envs.catalogue import PlantSpec
from stcgym.envs.families import FamilySpec, draw_plant, get_family
from stcgym.envs.schedules import RandomJump, RandomWalk, Schedule
from stcgym.envs.vector import ObserverCanonicalVectorEnv
from stcgym.lanes.validation import integer, real_in

__all__ = ["PlantFamilyEnv", "PlantFamilyVectorEnv"]

#: Schedule key of the family's own jump (or drift) in the vector env: one object, every lane.
FAMILY_SCHEDULE = "family schedule"


class PlantFamilyEnv(ObserverCanonicalEnv):
    """One split of a plant family as a Gymnasium environment (``stcgym/PlantFamily-v0``).

    Each reset draws one plant of the split uniformly (from the reset's draw stream) unless
    ``options={"plant": ...}`` names one; the plant is an observer-canonical SISO plant,
    Ding & Ma (2014) eq. (1)-(5), with the family's order ``n``. The split's plants are
    :class:`~stcgym.envs.catalogue.PlantSpec` objects named ``"<family>-v<version>/<split>/<i>"``
    (``i``: the plant's index in the family, or in the variant), in :attr:`members`.

    Observation: ``[y(k), r(k)]`` (a ``Box`` of two float64). Action: ``u(k)`` in
    ``[-action_bound, action_bound]`` (clipped beyond). Reward: ``-((y_clean(k+1) -
    r(k+1))^2 + control_cost * u(k)^2)`` on the noise-free output. Starting state: ``x(0) ~
    N(0, initial_state_std^2 I)``. Episode end: ``terminated`` when ``|y|`` leaves
    ``y_bound`` (``info["diverged"]``); ``truncated`` when the env itself reaches ``steps``
    (the id is registered without a ``TimeLimit``; ``gym.make(..., max_episode_steps=T)``
    adds one). With the family's ``jump``, an episode has the jump with probability
    ``jump_probability``, at a step drawn uniformly from the family's ``jump.at`` range
    (fractions of ``steps``); from that step on the plant is the drawn after-jump plant
    (:class:`~stcgym.envs.schedules.RandomJump`). A family ``drift`` becomes a
    :class:`~stcgym.envs.schedules.RandomWalk` of the parameters.

    ``reset(options=...)`` takes the canonical envs' options; ``"plant"`` may also be a plant's
    index ``i`` in the split. ``info`` carries ``"plant"`` (the plant's name; ``None`` for
    parameters given as ``theta``/``a``/``b``), ``"theta"``, ``"a"``, ``"b"``, ``"x"``,
    ``"y_clean"``, ``"t"``; ``env.unwrapped.plant`` is the plant's ``PlantSpec``.

    Parameters
    ----------
    family : str, path-like, dict or FamilySpec, default "siso2-v1"
        What :func:`~stcgym.envs.families.get_family` accepts.
    split : str, default "train"
        A split or a variant of the family (a variant: all its plants).
    jump_probability : float, optional
        The chance that an episode has the jump, in ``[0, 1]``; ``None``: the family's
        (``0.0``: never, ``1.0``: always; above 0 only for a family with a jump).
    steps : int, optional
        Episode length (``>= 2``); default the family's ``steps``.
    noise_std, control_cost, action_bound, y_bound, initial_state_std : float, optional
        Default the family's values.
    reference : reference spec, optional
        Default the family's (``"zero"`` for regulation); see
        :func:`~stcgym.envs.signals.make_reference`.
    **kwargs
        Other arguments of :class:`~stcgym.envs.plants.CanonicalPlantEnv` (``process_noise_std``,
        ``schedule``: replaces the family's jump, ``render_mode``); not ``plant``, ``a``, ``b``.

    Attributes
    ----------
    family : FamilySpec
        The family (as given, not the variant).
    split : str
        The split or variant name.
    indices : range
        The plant indices of the split (of the variant's plants for a variant).
    steps : int
        Episode length.
    jump_probability : float
        Chance of the jump per episode (0 without one).
    jump_range : tuple of int or None
        The steps ``(low, high)`` an episode's jump is drawn from; ``None`` without a jump.

    Raises
    ------
    ValueError
        An unknown family name; a split that is neither a split nor a variant (the message
        lists them); ``jump_probability`` outside ``[0, 1]`` or above 0 for a family without a
        jump; ``steps`` too short for the family's jump range; any value the canonical env
        rejects.
    TypeError
        ``plant``, ``a`` or ``b`` given; a value of the wrong kind.

    Examples
    --------
    >>> import gymnasium as gym
    >>> import stcgym.envs
    >>> env = gym.make("stcgym/PlantFamily-v0", family="siso2-v1", split="test")
    >>> obs, info = env.reset(seed=0)
    >>> info["plant"]
    'siso2-v1/test/1182'
    >>> env.unwrapped.split, env.unwrapped.indices, env.unwrapped.steps
    ('test', range(1100, 1300), 1000)
    >>> _, info = env.reset(seed=0, options={"plant": 1200})
    >>> info["plant"], env.unwrapped.plant.n
    ('siso2-v1/test/1200', 2)
    >>> gym.make("stcgym/PlantFamily-v0", split="ood_order3").unwrapped.n_states
    3
    """

    def __init__(
        self,
        family: Any = "siso2-v1",
        split: str = "train",
        *,
        jump_probability: float | None = None,
        steps: int | None = None,
        noise_std: float | None = None,
        reference: Any = None,
        control_cost: float | None = None,
        action_bound: float | None = None,
        y_bound: float | None = None,
        initial_state_std: float | None = None,
        **kwargs: Any,
    ) -> None:
        given = sorted({"plant", "a", "b"} & set(kwargs))
        if given:
            raise TypeError(f"PlantFamilyEnv draws its plants from the family; got {given}")
        spec = get_family(family)
        source, indices = spec.members(split)
        self.family, self.split, self.indices = spec, split, indices
        self.steps = source.steps if steps is None else integer(steps, "steps", 2)
        self.jump_range = None if source["jump"] is None else source.jump_range(self.steps)
        if jump_probability is None:
            self.jump_probability = source.jump_probability
        else:
            self.jump_probability = real_in(jump_probability, "jump_probability", 0.0, 1.0)
            if self.jump_probability > 0 and self.jump_range is None:
                raise ValueError(
                    f"jump_probability must be 0 or None: split {split!r} of family "
                    f"{spec.key!r} has no jump"
                )
        members, self._after = _members(
            json.dumps(source.data, sort_keys=True),
            f"{spec.key}/{split}",
            indices,
            self.jump_range,
            self.jump_probability,
        )
        self._prefix = f"{spec.key}/{split}/"
        defaults = {
            "noise_std": (noise_std, source["noise_std"]),
            "reference": (reference, source["reference"]),
            "control_cost": (control_cost, source["control_cost"]),
            "action_bound": (action_bound, source["action_bound"]),
            "y_bound": (y_bound, source["y_bound"]),
            "initial_state_std": (initial_state_std, source["initial_state_std"]),
        }
        chosen = {key: own if own is not None else fam for key, (own, fam) in defaults.items()}
        super().__init__(plant=list(members), **chosen, **kwargs)

    def _find_plant(self, plant: Any, name: str = "options['plant']") -> PlantSpec:
        """As the canonical env's, and an index ``i`` of the split names its plant ``i``."""
        if isinstance(plant, numbers.Integral) and not isinstance(plant, bool):
            key = f"{self._prefix}{int(plant)}"
            if key not in self._member_index:
                raise ValueError(
                    f"{name} as an index must be one of the split's plant indices "
                    f"{self.indices}, got {plant!r}"
                )
            return self.members[self._member_index[key]]
        return super()._find_plant(plant, name)

    def step(self, action: ArrayLike) -> tuple[NDArray, float, bool, bool, dict[str, Any]]:
        """As :meth:`LinearPlantEnv.step <stcgym.envs.plants.LinearPlantEnv.step>`, and
        ``truncated`` once the episode has reached :attr:`steps` steps."""
        obs, reward, terminated, _, info = super().step(action)
        return obs, reward, terminated, self.t >= self.steps, info

    def _info(self) -> dict[str, Any]:
        info = super()._info()
        info["plant"] = None if self.plant is None else self.plant.name
        return info


@functools.lru_cache(maxsize=8)
def _members(
    data: str,
    prefix: str,
    indices: range,
    jump_range: tuple[int, int] | None,
    probability: float,
) -> tuple[tuple[PlantSpec, ...], NDArray | None]:
    """The plants ``indices`` of the family ``data`` (JSON) as ``PlantSpec`` objects, and the
    after-jump parameters of each (``None`` without a jump); cached, so that many envs of one
    split draw the plants once (``PlantSpec`` objects are frozen)."""
    family = FamilySpec(json.loads(data))
    drift = family["drift"]
    specs, after = [], []
    for i in indices:
        plant = draw_plant(family, i)
        schedule = None
        if jump_range is not None and probability > 0:
            theta_after = tuple(float(v) for v in np.concatenate((plant.a_after, plant.b_after)))
            after.append(theta_after)
            schedule = functools.partial(RandomJump, theta_after, jump_range, probability)
        elif drift is not None and drift["std"] > 0:
            schedule = functools.partial(RandomWalk, drift["std"])
        specs.append(
            PlantSpec(
                f"{prefix}/{i}",
                tuple(float(v) for v in plant.a),
                tuple(float(v) for v in plant.b),
                f"plant {i} of family {prefix.split('/')[0]}",
                schedule=schedule,
            )
        )
    table = np.array(after) if after else None
    if table is not None:
        table.setflags(write=False)  # shared by every env of the split
    return tuple(specs), table


class _MemberJumps(RandomJump):
    """The family's jump for every lane of the vector env: lane ``i`` jumps to the after-jump
    parameters of its plant (``table[lane_member[i]]``), drawing the step and whether it jumps
    exactly as the single env's :class:`RandomJump` of that plant does."""

    def __init__(
        self, table: NDArray, lane_member: NDArray, at: tuple[int, int], probability: float
    ) -> None:
        super().__init__(table[0], at, probability)
        self.table, self.lane_member = table, lane_member

    def _targets(self, lanes: NDArray, nominal: NDArray) -> NDArray:
        return self.table[self.lane_member[lanes]]


class PlantFamilyVectorEnv(ObserverCanonicalVectorEnv):
    """Vector version of :class:`PlantFamilyEnv`: ``num_envs`` lanes, each drawing its plants.

    What ``gym.make_vec("stcgym/PlantFamily-v0", num_envs=B, **kwargs)`` builds. Lane ``i``
    reset with ``seed=s`` reproduces the single env reset with ``s + i`` bit for bit, across
    autoresets and jumps. Every lane truncates at the family's ``steps`` (or at
    ``max_episode_steps`` when that is shorter). ``reset(options={"plant": [...]})`` takes one
    plant (name or index) per lane; ``infos["plant"]`` holds each lane's plant name.

    Parameters
    ----------
    num_envs, max_episode_steps, autoreset_mode, noise_buffer_bytes, info_keys
        As :class:`~stcgym.envs.vector.LinearPlantVectorEnv`.
    **kwargs
        The arguments of :class:`PlantFamilyEnv`.

    Examples
    --------
    >>> import gymnasium as gym
    >>> import numpy as np
    >>> import stcgym.envs
    >>> envs = gym.make_vec("stcgym/PlantFamily-v0", num_envs=3, split="validation")
    >>> single = gym.make("stcgym/PlantFamily-v0", split="validation")
    >>> obs, infos = envs.reset(seed=10)
    >>> obs_2, info_2 = single.reset(seed=12)
    >>> bool(np.array_equal(obs[2], obs_2)), infos["plant"][2] == info_2["plant"]
    (True, True)
    >>> envs.max_episode_steps
    1000
    """

    single_cls = PlantFamilyEnv

    def __init__(self, num_envs: int = 1, *, max_episode_steps: int | None = None, **kwargs: Any):
        super().__init__(num_envs, max_episode_steps=max_episode_steps, **kwargs)
        proto: PlantFamilyEnv = self._proto  # type: ignore[assignment]
        if self.max_episode_steps is None or self.max_episode_steps > proto.steps:
            self.max_episode_steps = proto.steps
        self.family, self.split = proto.family, proto.split

    def _init_params(self) -> None:
        super()._init_params()
        names = [None if s is None else s.name for s in self._lane_plants]
        self._plant_names = np.array(names, dtype=object)

    def _nominal(
        self, idx: NDArray, parsed: Any, draw: list[np.random.Generator | None]
    ) -> tuple[NDArray, list[Hashable | None]]:
        theta, keys = super()._nominal(idx, parsed, draw)
        for i in idx:
            spec = self._lane_plants[i]
            self._plant_names[i] = None if spec is None else spec.name
        if self._proto.has_user_schedule:
            return theta, keys
        # The split's plants share one schedule object (a catalogue plant keeps its own).
        member = self.plant_index[idx] >= 0
        shared = zip(member, keys, strict=True)
        return theta, [FAMILY_SCHEDULE if m and key is not None else key for m, key in shared]

    def _make_schedule(self, key: Hashable) -> Schedule:
        if key != FAMILY_SCHEDULE:
            return super()._make_schedule(key)
        proto: PlantFamilyEnv = self._proto  # type: ignore[assignment]
        if proto._after is not None:
            return _MemberJumps(
                proto._after, self.plant_index, proto.jump_range, proto.jump_probability
            )
        return proto.members[0].schedule()  # the family's drift, the same for every plant

    def _param_infos(self, infos: dict[str, Any], mask: NDArray) -> None:
        super()._param_infos(infos, mask)
        infos["plant"] = self._plant_names.copy()
