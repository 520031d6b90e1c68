"""Named benchmark plants (observer-canonical parameters ``a``, ``b``; sample time 1).

Each plant is the transfer function ``(b1 z^{n-1} + ... + bn) / (z^n + a1 z^{n-1} + ... + an)``.
Select one by name in any canonical environment, e.g.
``gym.make("stcgym/ObserverCanonical-v0", plant="unstable2")``. In the observability
canonical environment the same name gives the same transfer function (``b`` converted to Markov
parameters), so both forms describe one plant.

=================  =====================================  ================  =========
name               poles                                  zeros             DC gain
=================  =====================================  ================  =========
stable2            0.75 +- 0.371j (abs 0.837)             -0.5              7.5
lightly_damped2    0.908 +- 0.281j (abs 0.95, zeta 0.05)  -0.8              1.03
unstable2          1.1, 0.6                               -0.6              (unstable)
nonminphase2       0.75 +- 0.371j                         2.0               2.5
integrator2        1.0, 0.6                               -0.5              (infinite)
stable4            0.8 +- 0.3j, 0.5 +- 0.4j               -0.606, -0.07+-0.64j   0.94
timevarying2       stable2, jumping at step 1000 to poles 0.6 +- 0.4j, zero -0.33, DC 3.75
=================  =====================================  ================  =========

The table is checked against the coefficients by the tests.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from stcgym.envs.signals import Jumps, Schedule

__all__ = ["PlantSpec", "PLANTS", "get_plant", "plant_names"]


@dataclass(frozen=True)
class PlantSpec:
    """A catalogue plant: observer-form ``a``, ``b`` and an optional parameter schedule.

    The plant is ``(b1 z^{n-1} + ... + bn) / (z^n + a1 z^{n-1} + ... + an)``, sample time 1,
    with ``theta = [a; b]`` of the observer canonical form, Ding & Ma (2014) eq. (1)-(5).
    Instances are frozen (hashable, comparable by value; ``schedule`` is left out of the
    comparison). The fields are stored as given, without checks: build plants of your own with
    finite tuples of equal length ``n``.

    Parameters
    ----------
    name : str
        The catalogue key (lower case).
    a : tuple of float, length n
        Denominator coefficients ``[a1, ..., an]``.
    b : tuple of float, length n
        Numerator coefficients ``[b1, ..., bn]``.
    description : str
        One sentence for listings.
    schedule : callable () -> Schedule, optional
        Builds a fresh copy of the plant's own parameter schedule (acting on observer-form
        ``theta``); ``None`` (default) for a time-invariant plant. A module-level function, so
        that environments holding the spec pickle.

    See Also
    --------
    get_plant, plant_names, PLANTS

    Examples
    --------
    >>> import numpy as np
    >>> from stcgym.envs import get_plant
    >>> plant = get_plant("unstable2")
    >>> plant.a, plant.b, plant.n
    ((-1.7, 0.66), (0.5, 0.3), 2)
    >>> np.round(plant.poles, 3), plant.stable, plant.minimum_phase
    (array([1.1, 0.6]), False, True)

    A plant of your own, for the ``a``/``b`` arguments of an environment:

    >>> from stcgym.envs import PlantSpec
    >>> first_order = PlantSpec("first_order", a=(-0.5,), b=(1.0,), description="lag")
    >>> first_order.theta, first_order.dc_gain
    (array([-0.5,  1. ]), 2.0)
    """

    name: str
    a: tuple[float, ...]
    b: tuple[float, ...]
    description: str
    schedule: Callable[[], Schedule] | None = field(default=None, compare=False)

    @property
    def n(self) -> int:
        """Plant order ``n = len(a)``."""
        return len(self.a)

    @property
    def theta(self) -> NDArray:
        """``[a1, ..., an, b1, ..., bn]`` as a float array."""
        return np.array(self.a + self.b, dtype=float)

    @property
    def poles(self) -> NDArray:
        """Poles: the roots of the polynomial ``[1, a1, ..., an]`` (highest power first)."""
        return np.roots(np.concatenate(([1.0], self.a)))

    @property
    def zeros(self) -> NDArray:
        """Zeros: the roots of the polynomial ``[b1, ..., bn]`` (highest power first)."""
        return np.roots(np.array(self.b, dtype=float))

    @property
    def stable(self) -> bool:
        """Every pole strictly inside the unit circle."""
        return bool(np.all(np.abs(self.poles) < 1.0))

    @property
    def minimum_phase(self) -> bool:
        """Every zero strictly inside the unit circle."""
        return bool(np.all(np.abs(self.zeros) < 1.0))

    @property
    def dc_gain(self) -> float:
        """Steady-state gain ``B(1) / A(1) = sum(b) / (1 + sum(a))``; ``inf`` for a pole at
        ``z = 1`` (``|1 + sum(a)| <= 1e-12``).

        Examples
        --------
        >>> from stcgym.envs import get_plant
        >>> round(get_plant("stable2").dc_gain, 6), get_plant("integrator2").dc_gain
        (7.5, inf)
        """
        den = 1.0 + sum(self.a)
        return float(sum(self.b) / den) if abs(den) > 1e-12 else float("inf")


_STABLE2_A, _STABLE2_B = (-1.5, 0.7), (1.0, 0.5)
#: Parameters of ``timevarying2`` after its jump at step 1000.
TIMEVARYING2_JUMP_STEP = 1000
TIMEVARYING2_AFTER = ((-1.2, 0.52), (0.9, 0.3))


def _timevarying2_schedule() -> Schedule:
    # A module-level function, not a lambda: envs holding the spec must pickle.
    return Jumps({TIMEVARYING2_JUMP_STEP: np.array(TIMEVARYING2_AFTER[0] + TIMEVARYING2_AFTER[1])})


#: The catalogue: :class:`PlantSpec` by name (see the table above); :func:`get_plant` looks a
#: name up case-insensitively with a clear error.
PLANTS: dict[str, PlantSpec] = {
    p.name: p
    for p in (
        PlantSpec(
            "stable2",
            _STABLE2_A,
            _STABLE2_B,
            "Astrom's classic stable, well-damped second-order plant.",
        ),
        PlantSpec(
            "lightly_damped2",
            (-1.815, 0.9025),
            (0.05, 0.04),
            "Resonant plant, damping ratio about 0.05 (poles at radius 0.95).",
        ),
        PlantSpec(
            "unstable2",
            (-1.7, 0.66),
            (0.5, 0.3),
            "Open-loop unstable: one real pole at 1.1.",
        ),
        PlantSpec(
            "nonminphase2",
            _STABLE2_A,
            (-0.5, 1.0),
            "Non-minimum phase: zero at 2, so the step response starts the wrong way.",
        ),
        PlantSpec(
            "integrator2",
            (-1.6, 0.6),
            (0.2, 0.1),
            "Integrating plant: a pole at z = 1.",
        ),
        PlantSpec(
            "stable4",
            (-2.6, 2.74, -1.386, 0.2993),
            (0.02, 0.015, 0.01, 0.005),
            "Fourth order, two oscillatory pole pairs.",
        ),
        PlantSpec(
            "timevarying2",
            _STABLE2_A,
            _STABLE2_B,
            "stable2 whose parameters jump at step 1000 (to a=(-1.2, 0.52), b=(0.9, 0.3)).",
            schedule=_timevarying2_schedule,
        ),
    )
}


def plant_names() -> list[str]:
    """Names of the catalogue plants, in catalogue order.

    Returns
    -------
    list of str
        A new list (the keys of :data:`PLANTS`).

    Examples
    --------
    >>> from stcgym.envs import plant_names
    >>> plant_names()
    ['stable2', 'lightly_damped2', 'unstable2', 'nonminphase2', 'integrator2', 'stable4',
     'timevarying2']
    """
    return list(PLANTS)


def get_plant(name: str) -> PlantSpec:
    """Look a catalogue plant up by name.

    Parameters
    ----------
    name : str
        A catalogue name (case-insensitive), one of :func:`plant_names`.

    Returns
    -------
    PlantSpec
        The catalogue entry (shared and frozen).

    Raises
    ------
    TypeError
        ``name`` is not a string.
    ValueError
        ``name`` is not in the catalogue; the message lists the valid names.

    Examples
    --------
    >>> from stcgym.envs import get_plant
    >>> plant = get_plant("Stable2")
    >>> plant.name, plant.theta
    ('stable2', array([-1.5,  0.7,  1. ,  0.5]))
    >>> get_plant("stable3")
    Traceback (most recent call last):
        ...
    ValueError: plant must be one of ['stable2', ...], got 'stable3'
    """
    if not isinstance(name, str):
        raise TypeError(f"plant must be a catalogue name (one of {plant_names()}), got {name!r}")
    key = name.lower()
    if key not in PLANTS:
        raise ValueError(f"plant must be one of {plant_names()}, got {name!r}")
    return PLANTS[key]
