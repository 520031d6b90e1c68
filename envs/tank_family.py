"""Quadruple tanks drawn from their valve settings: ``stcgym/QuadrupleTankFamily-v0``.

K. H. Johansson, "The quadruple-tank process: a multivariable laboratory process with an
adjustable zero", IEEE Trans. Control Systems Technology 8(3), 2000. The valve settings
``gamma1, gamma2`` (the share of each pump's flow into its lower tank) move the plant's
transmission zero: minimum phase for ``gamma1 + gamma2 > 1``, a zero in the right half plane
for ``gamma1 + gamma2 < 1`` (Section III). The family :data:`TANK_FAMILY` draws the settings,
and each setting is linearised physically:

1. the steady levels of eq. (1) at the pump voltages ``v0`` (Johansson's ``P-``: 3.0 V each,
   ``k = (3.33, 3.35)`` cm^3/Vs; Table I's outlet areas ``a = (0.071, 0.057, 0.071, 0.057)``
   cm^2 and ``g = 981`` cm/s^2): ``a3 sqrt(2 g h3) = (1 - gamma2) k2 v2``,
   ``a4 sqrt(2 g h4) = (1 - gamma1) k1 v1``,
   ``a1 sqrt(2 g h1) = gamma1 k1 v1 + (1 - gamma2) k2 v2``,
   ``a2 sqrt(2 g h2) = gamma2 k2 v2 + (1 - gamma1) k1 v1``;
2. the time constants ``T_i = (A_i / a_i) sqrt(2 h_i / g)`` and eq. (2)
   (:func:`~stcgym.envs.mimo_plants.quadruple_tank_spec`), sampled at 5 s by zero-order hold.

===============  ==========================================================================
draw             ``gamma1, gamma2 ~ U[0.2, 0.8]``, redrawn while
                 ``|gamma1 + gamma2 - 1| < 0.15`` (near 1 the zero nears the origin and the
                 steady-state gain is nearly singular: two independent level references
                 become unreachable within the pump range); member ``i`` is drawn from
                 ``numpy.random.default_rng([seed, i])``, so it does not depend on the
                 split sizes
splits           ``train`` indices 0-199, ``validation`` 200-249, ``test`` 250-349 (disjoint)
plants           named ``"quadruple_tank-v1/<split>/<i>"``, each a
                 :class:`~stcgym.envs.mimo_plants.MimoPlantSpec` (measured state, the two
                 lower levels as performance output, pumps in ``[0, 10]`` V around ``v0``)
===============  ==========================================================================

Both phases occur in every split (about half of the settings each; Johansson's ``P-`` and
``P+`` settings lie inside the range).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Hashable
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stcgym.envs.mimo_plants import MimoPlantSpec, quadruple_tank_spec
from stcgym.envs.plants import StateSpaceEnv
from stcgym.envs.vector import StateSpaceVectorEnv
from stcgym.envs.vector_base import USER_SCHEDULE

__all__ = [
    "TANK_FAMILY",
    "QuadrupleTankFamilyEnv",
    "QuadrupleTankFamilyVectorEnv",
    "TankFamily",
    "tank_at",
    "tank_levels",
]

#: Johansson (2000), Table I: outlet areas (cm^2) and the acceleration of gravity (cm/s^2).
OUTLET_AREAS = (0.071, 0.057, 0.071, 0.057)
GRAVITY = 981.0
#: Johansson (2000), Table II, ``P-``: pump gains (cm^3/Vs) and voltages (V) of every member.
PUMP_GAINS = (3.33, 3.35)
PUMP_VOLTAGES = (3.0, 3.0)


def tank_levels(gamma: tuple[float, float]) -> tuple[float, float, float, float]:
    """Steady levels ``h0`` (cm) of Johansson (2000) eq. (1) at the valve settings ``gamma``
    and the pump voltages :data:`PUMP_VOLTAGES`."""
    (k1, k2), (v1, v2), (g1, g2) = PUMP_GAINS, PUMP_VOLTAGES, gamma
    a1, a2, a3, a4 = OUTLET_AREAS
    flows = (
        (g1 * k1 * v1 + (1 - g2) * k2 * v2) / a1,
        (g2 * k2 * v2 + (1 - g1) * k1 * v1) / a2,
        (1 - g2) * k2 * v2 / a3,
        (1 - g1) * k1 * v1 / a4,
    )  # sqrt(2 g h_i)
    return tuple(q * q / (2 * GRAVITY) for q in flows)  # type: ignore[return-value]


def tank_at(gamma: tuple[float, float], name: str = "quadruple_tank") -> MimoPlantSpec:
    """The quadruple tank linearised at the valve settings ``gamma`` (see the module
    docstring): steady levels, time constants ``T_i = (A_i / a_i) sqrt(2 h_i / g)``, eq. (2).

    Examples
    --------
    Johansson's ``P-`` settings give his Table II time constants (62, 90, 23, 30) s to within
    his measurement:

    >>> from stcgym.envs.tank_family import tank_at
    >>> [round(-1 / tank_at((0.70, 0.60)).A_c[i][i], 1) for i in range(4)]
    [62.4, 90.6, 22.8, 30.1]
    """
    from stcgym.envs.mimo_plants import _TANK_AREAS

    g1, g2 = (float(g) for g in gamma)
    for g, label in ((g1, "gamma1"), (g2, "gamma2")):
        if not 0.0 < g < 1.0:
            raise ValueError(f"{label} must lie in (0, 1), got {g!r}")
    h = tank_levels((g1, g2))
    T = tuple(
        A / a * math.sqrt(2 * hi / GRAVITY)
        for A, a, hi in zip(_TANK_AREAS, OUTLET_AREAS, h, strict=True)
    )
    description = f"Johansson's quadruple tank at gamma = ({g1:.4f}, {g2:.4f})."
    return quadruple_tank_spec(name, T, PUMP_GAINS, (g1, g2), PUMP_VOLTAGES, description)


@dataclass(frozen=True)
class TankFamily:
    """A family of quadruple tanks drawn from their valve settings, split by index.

    Attributes
    ----------
    key : str
        The family's name, the prefix of its plants' names.
    seed : int
        Member ``i``'s settings come from ``numpy.random.default_rng([seed, i])``.
    gamma_range : tuple of float
        Each ``gamma_i`` uniform on this interval.
    gap : float
        Settings with ``|gamma1 + gamma2 - 1| < gap`` are redrawn.
    splits : tuple of (str, int, int)
        ``(name, first index, stop index)`` of each split.

    Examples
    --------
    >>> from stcgym.envs.tank_family import TANK_FAMILY
    >>> TANK_FAMILY.indices("test")
    range(250, 350)
    >>> g1, g2 = TANK_FAMILY.gamma(250)
    >>> 0.2 <= g1 <= 0.8 and abs(g1 + g2 - 1) >= 0.15
    True
    >>> TANK_FAMILY.members("test")[0].name
    'quadruple_tank-v1/test/250'
    """

    key: str
    seed: int
    gamma_range: tuple[float, float]
    gap: float
    splits: tuple[tuple[str, int, int], ...]

    @property
    def split_names(self) -> list[str]:
        """The splits' names."""
        return [s[0] for s in self.splits]

    def indices(self, split: str) -> range:
        """The member indices of ``split``."""
        for name, first, stop in self.splits:
            if name == split:
                return range(first, stop)
        raise ValueError(f"split must be one of {self.split_names} of {self.key!r}, got {split!r}")

    def gamma(self, i: int) -> tuple[float, float]:
        """The valve settings of member ``i``."""
        rng = np.random.default_rng([self.seed, int(i)])
        low, high = self.gamma_range
        while True:
            g1, g2 = (float(g) for g in rng.uniform(low, high, 2))
            if abs(g1 + g2 - 1.0) >= self.gap:
                return g1, g2

    def members(self, split: str) -> list[MimoPlantSpec]:
        """The plants of ``split`` in index order."""
        return list(_members(self, split))


@cache
def _members(family: TankFamily, split: str) -> tuple[MimoPlantSpec, ...]:
    return tuple(
        tank_at(family.gamma(i), f"{family.key}/{split}/{i}") for i in family.indices(split)
    )


#: The quadruple-tank family of the benchmark (see the module docstring).
TANK_FAMILY = TankFamily(
    "quadruple_tank-v1",
    seed=35,
    gamma_range=(0.2, 0.8),
    gap=0.15,
    splits=(("train", 0, 200), ("validation", 200, 250), ("test", 250, 350)),
)


class QuadrupleTankFamilyEnv(StateSpaceEnv):
    """One split of :data:`TANK_FAMILY` as an environment (``stcgym/QuadrupleTankFamily-v0``).

    Each reset draws a member of the split uniformly (from the reset's draw stream) unless
    ``options={"plant": ...}`` names one (its name or index ``i``); the episode runs that
    member's ``[A B]`` as :class:`~stcgym.envs.plants.StateSpaceEnv` with the catalogue's
    quadruple-tank settings: measured state, the cost of the two lower levels (``C_z``),
    pumps clipped to their voltage range. ``env.unwrapped.mimo_plant`` is the member's
    :class:`~stcgym.envs.mimo_plants.MimoPlantSpec`, ``info["plant"]`` its name.

    Parameters
    ----------
    split : str, default "train"
        ``"train"``, ``"validation"`` or ``"test"``.
    **kwargs
        The other arguments of :class:`~stcgym.envs.plants.StateSpaceEnv` (``reference``,
        ``reference_in``, ``noise_std``, ...); not the plant's (``plant``, ``A``, ``B``, ``C``,
        ``D``, ``sys``, ``dt``, ``C_z``, ``D_z``, ``input_range``, ``cost``, ``measured``).

    Raises
    ------
    ValueError
        An unknown split (the message lists them), a bad ``plant`` option.
    TypeError
        A plant argument given.

    Examples
    --------
    >>> import gymnasium as gym
    >>> import stcgym.envs
    >>> env = gym.make("stcgym/QuadrupleTankFamily-v0", split="test", reference="zero")
    >>> obs, info = env.reset(seed=0)
    >>> info["plant"], obs.shape
    ('quadruple_tank-v1/test/291', (6,))
    >>> _, info = env.reset(seed=0, options={"plant": 250})
    >>> info["plant"]
    'quadruple_tank-v1/test/250'
    """

    reset_options = StateSpaceEnv.reset_options | {"plant"}
    _PLANT_ARGS = ("plant", "A", "B", "C", "D", "sys", "dt", "C_z", "D_z", "input_range")

    def __init__(self, split: str = "train", **kwargs: Any) -> None:
        given = sorted({*self._PLANT_ARGS, "cost", "measured"} & set(kwargs))
        if given:
            raise TypeError(f"QuadrupleTankFamilyEnv draws its plants from its split; got {given}")
        self.family, self.split = TANK_FAMILY, split
        self.indices = TANK_FAMILY.indices(split)
        self.members = TANK_FAMILY.members(split)
        first = self.members[0]
        A, B = first.discrete()
        C_z, _ = first.performance_output()
        super().__init__(A, B, dt=first.dt, C_z=C_z, input_range=first.input_range, **kwargs)
        self.mimo_plant = first

    def member_index(self, plant: Any, name: str = "options['plant']") -> int:
        """Position in :attr:`members` of ``plant`` (a member's name or index ``i``)."""
        if isinstance(plant, numbers.Integral) and not isinstance(plant, bool):
            if int(plant) in self.indices:
                return int(plant) - self.indices.start
        elif isinstance(plant, str) and plant.startswith(f"{self.family.key}/{self.split}/"):
            tail = plant.rsplit("/", 1)[1]
            if tail.isdigit() and int(tail) in self.indices:
                return int(tail) - self.indices.start
        raise ValueError(
            f"{name} must be a plant of split {self.split!r} (an index in {self.indices} or "
            f"its name '{self.family.key}/{self.split}/<i>'), got {plant!r}"
        )

    def _parse_options(self, options: dict[str, Any]) -> Any:
        if "plant" in options:
            if "A" in options or "B" in options:
                raise ValueError("give options 'plant' or 'A'/'B', not both")
            return ("plant", self.member_index(options["plant"]))
        return super()._parse_options(options)

    def _nominal_params(self, parsed: Any, rng: np.random.Generator) -> NDArray:
        if isinstance(parsed, tuple):
            j = parsed[1]
        elif parsed is None:
            j = int(rng.integers(len(self.members)))
        else:  # matrices given
            self.mimo_plant = None
            return parsed
        self.mimo_plant = self.members[j]
        return np.hstack(self.mimo_plant.discrete())

    def _info(self) -> dict[str, Any]:
        info = super()._info()
        info["plant"] = None if self.mimo_plant is None else self.mimo_plant.name
        return info


class QuadrupleTankFamilyVectorEnv(StateSpaceVectorEnv):
    """Vector version of :class:`QuadrupleTankFamilyEnv`: each lane draws its member at every
    reset, autoresets included, from its own draw stream, so lane ``i`` reset with ``seed=s``
    is the single env reset with ``s + i``. ``reset(options={"plant": ...})`` takes one member
    (name or index) for every lane or a list of one per lane; :attr:`plants` holds each lane's
    member, ``infos["plant"]`` its name.

    Examples
    --------
    >>> import gymnasium as gym
    >>> import numpy as np
    >>> import stcgym.envs
    >>> envs = gym.make_vec("stcgym/QuadrupleTankFamily-v0", num_envs=3, split="validation")
    >>> single = gym.make("stcgym/QuadrupleTankFamily-v0", split="validation")
    >>> obs, infos = envs.reset(seed=10)
    >>> obs_2, info_2 = single.reset(seed=12)
    >>> bool(np.array_equal(obs[2], obs_2)), infos["plant"][2] == info_2["plant"]
    (True, True)
    """

    single_cls = QuadrupleTankFamilyEnv

    def _init_params(self) -> None:
        super()._init_params()
        proto: QuadrupleTankFamilyEnv = self._proto  # type: ignore[assignment]
        self.members = proto.members
        self._members_AB = np.array([np.hstack(p.discrete()) for p in self.members])
        self._lane_plants: list[MimoPlantSpec | None] = [self.members[0]] * self.num_envs

    @property
    def plants(self) -> list[MimoPlantSpec | None]:
        """Each lane's member of this episode (``None`` for matrices given as options)."""
        return list(self._lane_plants)

    def _parse_options(self, options: dict[str, Any]) -> Any:
        if "plant" not in options:
            return super()._parse_options(options)
        if "A" in options or "B" in options:
            raise ValueError("give options 'plant' or 'A'/'B', not both")
        proto: QuadrupleTankFamilyEnv = self._proto  # type: ignore[assignment]
        plant, B = options["plant"], self.num_envs
        if isinstance(plant, (list, tuple, np.ndarray)):
            if len(plant) != B:
                raise ValueError(
                    f"options['plant'] must be one plant or a list of num_envs={B} plants, "
                    f"got {len(plant)}"
                )
            entries = [p.item() if isinstance(p, np.generic) else p for p in plant]
            index = np.array([proto.member_index(p) for p in entries], dtype=np.int64)
        else:
            index = np.full(B, proto.member_index(plant), dtype=np.int64)
        return ("plant", index)

    def _needs_draw_rng(self, parsed: Any) -> bool:
        return parsed is None

    def _nominal(
        self, idx: NDArray, parsed: Any, draw: list[np.random.Generator | None]
    ) -> tuple[NDArray, list[Hashable | None]]:
        k = len(idx)
        if isinstance(parsed, tuple):
            index = parsed[1][idx]
        elif parsed is None:
            index = np.array([g.integers(len(self.members)) for g in draw], dtype=np.int64)
        else:
            for i in idx:
                self._lane_plants[i] = None
            return super()._nominal(idx, parsed, draw)
        for i, j in zip(idx, index, strict=True):
            self._lane_plants[i] = self.members[j]
        keys = [USER_SCHEDULE if self._proto.schedule.time_varying else None] * k
        return self._members_AB[index], keys

    def _param_infos(self, infos: dict[str, Any], mask: NDArray) -> None:
        super()._param_infos(infos, mask)
        names = [None if p is None else p.name for p in self._lane_plants]
        infos["plant"] = np.array(names, dtype=object)
