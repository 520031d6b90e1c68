"""Named multi-input plants with measured state for ``stcgym/StateSpace-v0``.

Each entry is a continuous-time model ``dx/dt = A_c x + B_c u`` from a published source,
discretised by zero-order hold (``control.sample_system``) with the sample time ``dt`` stated
below, and measured state (``C = I``). Select one with
``gym.make("stcgym/StateSpace-v0", plant="he1")``.

=================  ======  ======  =====  ==========================================  ==========
name               states  inputs  dt     discrete poles (magnitude)                  stability
=================  ======  ======  =====  ==========================================  ==========
``quadruple_tank`` 4       2       5 s    0.923, 0.946, 0.805, 0.846                  stable
``he1``            4       2       0.1 s  1.028 (complex pair), 0.977, 0.813          unstable
``ac1``            5       3       0.1 s  1.0, 0.998 (complex pair), 0.925 (pair)     integrator
=================  ======  ======  =====  ==========================================  ==========

Sources
-------
``quadruple_tank``
    K. H. Johansson, "The quadruple-tank process: a multivariable laboratory process with an
    adjustable zero", IEEE Trans. Control Systems Technology 8(3), 2000, eq. (2) linearised at
    the minimum-phase operating point P- of Table I/II (``A1 = A3 = 28``, ``A2 = A4 = 32`` cm^2,
    ``T = (62, 90, 23, 30)`` s, ``k1 = 3.33``, ``k2 = 3.35`` cm^3/Vs, ``gamma = (0.70, 0.60)``);
    the states are the four level deviations (cm), the inputs the two pump voltages (V).
``he1``, ``ac1``
    COMPleib (F. Leibfritz, "COMPleib: constraint matrix optimization problem library", 2004):
    ``A`` and the control matrix ``B2`` of HE1 (helicopter, Keel et al. 1988) and AC1 (aircraft,
    Hung & MacFarlane 1982), as shipped by controlgym 1.0.0 (Zhang et al. 2023,
    ``linear_control_src/he1.mat``, ``ac1.mat``), which discretises them with the same sample
    time 0.1 s.

The table is checked against the matrices by the tests.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np
from numpy.typing import NDArray

__all__ = ["MIMO_PLANTS", "MimoPlantSpec", "get_mimo_plant", "mimo_plant_names"]


@dataclass(frozen=True)
class MimoPlantSpec:
    """A MIMO catalogue plant: continuous ``(A_c, B_c)``, its sample time and source.

    ``gym.make("stcgym/StateSpace-v0", plant=name)`` runs its zero-order-hold discretisation
    (:meth:`discrete`) with measured state (``C = I``).

    Examples
    --------
    >>> from stcgym.envs import get_mimo_plant
    >>> plant = get_mimo_plant("he1")
    >>> plant.n_states, plant.n_inputs, plant.dt, plant.stable
    (4, 2, 0.1, False)
    >>> A, B = plant.discrete()
    >>> A.shape, B.shape
    ((4, 4), (4, 2))
    """

    name: str
    A_c: tuple[tuple[float, ...], ...]
    B_c: tuple[tuple[float, ...], ...]
    dt: float
    description: str

    @property
    def n_states(self) -> int:
        """Number of states ``n``."""
        return len(self.A_c)

    @property
    def n_inputs(self) -> int:
        """Number of inputs ``m``."""
        return len(self.B_c[0])

    def discrete(self) -> tuple[NDArray, NDArray]:
        """``(A, B)`` of the zero-order-hold discretisation with ``dt`` (copies)."""
        A, B = _discretise(self.name)
        return A.copy(), B.copy()

    @property
    def poles(self) -> NDArray:
        """Eigenvalues of the discrete ``A``."""
        return np.linalg.eigvals(self.discrete()[0])

    @property
    def stable(self) -> bool:
        """Every eigenvalue of the discrete ``A`` strictly inside the unit circle."""
        return bool(np.all(np.abs(self.poles) < 1.0))


@cache
def _discretise(name: str) -> tuple[NDArray, NDArray]:
    import control

    spec = MIMO_PLANTS[name]
    n, m = spec.n_states, spec.n_inputs
    sys = control.ss(np.array(spec.A_c), np.array(spec.B_c), np.eye(n), np.zeros((n, m)))
    sysd = control.sample_system(sys, spec.dt, method="zoh")
    A = np.ascontiguousarray(sysd.A, dtype=float)
    B = np.ascontiguousarray(sysd.B, dtype=float)
    A.setflags(write=False)
    B.setflags(write=False)
    return A, B


def _quadruple_tank() -> MimoPlantSpec:
    A1, A2, A3, A4 = 28.0, 32.0, 28.0, 32.0
    T1, T2, T3, T4 = 62.0, 90.0, 23.0, 30.0
    k1, k2, g1, g2 = 3.33, 3.35, 0.70, 0.60
    A_c = (
        (-1 / T1, 0.0, A3 / (A1 * T3), 0.0),
        (0.0, -1 / T2, 0.0, A4 / (A2 * T4)),
        (0.0, 0.0, -1 / T3, 0.0),
        (0.0, 0.0, 0.0, -1 / T4),
    )
    B_c = (
        (g1 * k1 / A1, 0.0),
        (0.0, g2 * k2 / A2),
        (0.0, (1 - g2) * k2 / A3),
        ((1 - g1) * k1 / A4, 0.0),
    )
    return MimoPlantSpec(
        "quadruple_tank", A_c, B_c, 5.0, "Johansson's quadruple-tank process, minimum phase (P-)."
    )


MIMO_PLANTS: dict[str, MimoPlantSpec] = {
    p.name: p
    for p in (
        _quadruple_tank(),
        MimoPlantSpec(
            "he1",
            (
                (-0.0366, 0.0271, 0.0188, -0.4555),
                (0.0482, -1.01, 0.0024, -4.0208),
                (0.1002, 0.3681, -0.707, 1.42),
                (0.0, 0.0, 1.0, 0.0),
            ),
            ((0.4422, 0.1761), (3.5446, -7.5922), (-5.52, 4.49), (0.0, 0.0)),
            0.1,
            "COMPleib HE1: helicopter, open-loop unstable.",
        ),
        MimoPlantSpec(
            "ac1",
            (
                (0.0, 0.0, 1.132, 0.0, -1.0),
                (0.0, -0.0538, -0.1712, 0.0, 0.0705),
                (0.0, 0.0, 0.0, 1.0, 0.0),
                (0.0, 0.0485, 0.0, -0.8556, -1.013),
                (0.0, -0.2909, 0.0, 1.0532, -0.6859),
            ),
            (
                (0.0, 0.0, 0.0),
                (-0.12, 1.0, 0.0),
                (0.0, 0.0, 0.0),
                (4.419, 0.0, -1.665),
                (1.575, 0.0, -0.0732),
            ),
            0.1,
            "COMPleib AC1: aircraft, an integrator and lightly damped modes.",
        ),
    )
}


def mimo_plant_names() -> list[str]:
    """Names of the MIMO catalogue plants.

    Examples
    --------
    >>> from stcgym.envs import mimo_plant_names
    >>> mimo_plant_names()
    ['quadruple_tank', 'he1', 'ac1']
    """
    return list(MIMO_PLANTS)


def get_mimo_plant(name: str) -> MimoPlantSpec:
    """The MIMO catalogue plant ``name`` (case-insensitive).

    Raises
    ------
    TypeError
        ``name`` is not a string.
    ValueError
        An unknown name; the message lists the valid ones.

    Examples
    --------
    >>> from stcgym.envs import get_mimo_plant
    >>> get_mimo_plant("quadruple_tank").n_inputs
    2
    """
    if not isinstance(name, str):
        raise TypeError(
            f"plant must be a MIMO catalogue name (one of {mimo_plant_names()}), got {name!r}"
        )
    key = name.lower()
    if key not in MIMO_PLANTS:
        raise ValueError(f"plant must be one of {mimo_plant_names()}, got {name!r}")
    return MIMO_PLANTS[key]
