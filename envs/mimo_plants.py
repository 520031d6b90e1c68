"""Named multi-input plants with measured state for ``stcgym/StateSpace-v0``.

Each entry is a continuous-time model ``dx/dt = A_c x + B_c u (+ B1_c w)`` from a published
source, discretised by zero-order hold (``control.sample_system``) with the sample time ``dt``
stated below, and measured state (``C = I``). Select one with
``gym.make("stcgym/StateSpace-v0", plant="he1")``. The plants (``quadruple_tank``,
``quadruple_tank_nmp``, ``he1``, ``ac1``), their sizes, sample times and discrete poles are
tabled in the Multivariable plants page of the documentation (the tests check the poles).

Besides ``(A_c, B_c)`` an entry may carry its source's performance output ``z = C_z x + D_z u``
(the quantities the cost weighs), measured output ``y = C_y x``, process-noise input ``B1_c``
and the physical input range around the operating point (:class:`MimoPlantSpec`);
``gym.make("stcgym/StateSpace-v0", plant=name, cost="performance")`` uses them.

Sources
-------
``quadruple_tank``, ``quadruple_tank_nmp``
    K. H. Johansson, "The quadruple-tank process: a multivariable laboratory process with an
    adjustable zero", IEEE Trans. Control Systems Technology 8(3), 2000, eq. (2) linearised at
    the operating points of Table I/II, sampled at 5 s: ``P-`` (``quadruple_tank``, minimum phase:
    ``T = (62, 90, 23, 30)`` s, ``k = (3.33, 3.35)`` cm^3/Vs, ``gamma = (0.70, 0.60)``, pump
    voltages ``v0 = (3.00, 3.00)`` V) and ``P+`` (``quadruple_tank_nmp``, a transmission zero in
    the right half plane: ``T = (63, 91, 39, 56)`` s, ``k = (3.14, 3.29)``,
    ``gamma = (0.43, 0.34)``, ``v0 = (3.15, 3.15)`` V), with ``A1 = A3 = 28``,
    ``A2 = A4 = 32`` cm^2. States: the four level deviations (cm); inputs: the two pump voltage
    deviations (V); performance output: the two lower levels (``C_z = [I 0]``, cm, the outputs
    ``y1, y2`` of the paper without the sensor gain ``k_c``); input range: pump voltages in
    ``[0, 10]`` V (a laboratory pump amplifier's range, stcgym's choice), so
    ``u in [-v0, 10 - v0]``.
``he1``, ``ac1``
    COMPleib (F. Leibfritz, "COMPleib: constraint matrix optimization problem library", 2004):
    ``A``, the control matrix ``B2``, the disturbance matrix ``B1``, the measured output ``C``
    and the performance output ``C1``, ``D12`` of HE1 (helicopter, Keel et al. 1988) and AC1
    (aircraft, Hung & MacFarlane 1982), as shipped by controlgym 1.0.0 (Zhang et al. 2023,
    ``linear_control_src/he1.mat``, ``ac1.mat``), which discretises them with the same sample
    time 0.1 s. For ``ac1`` controlgym weighs the inputs with ``R = 0.5 I`` instead of
    ``D12' D12 = diag(0.5, 0.5, 0)``; the entry's ``D_z`` has a third row
    ``[0, 0, sqrt(0.5)]`` (``C_z`` a zero row) so that ``||C_z x + D_z u||^2`` is controlgym's
    stage cost ``x' Q x + u' R u + 2 x' S u`` exactly.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "MIMO_PLANTS",
    "MimoPlantSpec",
    "get_mimo_plant",
    "mimo_plant_names",
    "quadruple_tank_spec",
]


Matrix = tuple[tuple[float, ...], ...]


@dataclass(frozen=True)
class MimoPlantSpec:
    """A MIMO catalogue plant: continuous ``(A_c, B_c)``, its sample time and source.

    ``gym.make("stcgym/StateSpace-v0", plant=name)`` runs its zero-order-hold discretisation
    (:meth:`discrete`) with measured state (``C = I``); with ``cost="performance"`` the env
    also uses the optional fields below.

    Attributes
    ----------
    C_z, D_z : tuple of tuples or None
        Performance output ``z = C_z x + D_z u`` (``(p_z, n)``, ``(p_z, m)``; ``D_z`` ``None``
        for zero): what the source's cost weighs (``||z - r||^2``).
    C_y : tuple of tuples or None
        The source's measured output ``y = C_y x`` (``None``: the state).
    B1_c : tuple of tuples or None
        Continuous process-noise input: ``dx/dt = A_c x + B_c u + B1_c w``, discretised with
        ``(A_c, B_c)`` (:meth:`noise_input`).
    input_range : tuple of two tuples or None
        ``(low, high)`` per input: the physical input range around the operating point.

    Examples
    --------
    >>> from stcgym.envs import get_mimo_plant
    >>> plant = get_mimo_plant("he1")
    >>> plant.n_states, plant.n_inputs, plant.dt, plant.stable
    (4, 2, 0.1, False)
    >>> A, B = plant.discrete()
    >>> A.shape, B.shape
    ((4, 4), (4, 2))
    >>> get_mimo_plant("quadruple_tank").input_range
    ((-3.0, -3.0), (7.0, 7.0))
    """

    name: str
    A_c: Matrix
    B_c: Matrix
    dt: float
    description: str
    C_z: Matrix | None = None
    D_z: Matrix | None = None
    C_y: Matrix | None = None
    B1_c: Matrix | None = None
    input_range: tuple[tuple[float, ...], tuple[float, ...]] | None = None

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
        A, B, _ = _discretise(self)
        return A.copy(), B.copy()

    def noise_input(self) -> NDArray:
        """``B1`` of the zero-order-hold discretisation (``(n, d)``; the identity without
        ``B1_c``): ``x(k+1) = A x + B u + B1 w``."""
        return _discretise(self)[2].copy()

    def performance_output(self) -> tuple[NDArray, NDArray]:
        """``(C_z, D_z)`` as arrays (``C_z = I``, ``D_z = 0`` when the entry has none)."""
        n, m = self.n_states, self.n_inputs
        C_z = np.eye(n) if self.C_z is None else np.array(self.C_z, dtype=float)
        D_z = np.zeros((len(C_z), m)) if self.D_z is None else np.array(self.D_z, dtype=float)
        return C_z, D_z

    def lq_weights(self, control_cost: float = 0.0) -> tuple[NDArray, NDArray, NDArray]:
        """``(Q, R, N)`` of the stage cost ``||C_z x + D_z u||^2 + control_cost ||u||^2``:
        ``Q = C_z' C_z``, ``R = D_z' D_z + control_cost I``, ``N = C_z' D_z`` (the weights of
        python-control's ``dlqr(A, B, Q, R, N)``).

        Examples
        --------
        >>> from stcgym.envs import get_mimo_plant
        >>> Q, R, N = get_mimo_plant("quadruple_tank").lq_weights(0.01)
        >>> np.diag(Q), np.diag(R), float(np.abs(N).max())
        (array([1., 1., 0., 0.]), array([0.01, 0.01]), 0.0)
        """
        C_z, D_z = self.performance_output()
        R = D_z.T @ D_z + float(control_cost) * np.eye(self.n_inputs)
        return C_z.T @ C_z, R, C_z.T @ D_z

    @property
    def poles(self) -> NDArray:
        """Eigenvalues of the discrete ``A``."""
        return np.linalg.eigvals(self.discrete()[0])

    @property
    def stable(self) -> bool:
        """Every eigenvalue of the discrete ``A`` strictly inside the unit circle."""
        return bool(np.all(np.abs(self.poles) < 1.0))


@cache
def _discretise(spec: MimoPlantSpec) -> tuple[NDArray, NDArray, NDArray]:
    import control

    n, m = spec.n_states, spec.n_inputs
    B1 = np.eye(n) if spec.B1_c is None else np.array(spec.B1_c, dtype=float)
    d = B1.shape[1]
    B_all = np.hstack((np.array(spec.B_c, dtype=float), B1))
    sys = control.ss(np.array(spec.A_c), B_all, np.eye(n), np.zeros((n, m + d)))
    sysd = control.sample_system(sys, spec.dt, method="zoh")
    A = np.ascontiguousarray(sysd.A, dtype=float)
    B = np.ascontiguousarray(sysd.B[:, :m], dtype=float)
    B1d = np.eye(n) if spec.B1_c is None else np.ascontiguousarray(sysd.B[:, m:], dtype=float)
    for M in (A, B, B1d):
        M.setflags(write=False)
    return A, B, B1d


#: Johansson (2000), Table I: tank areas (cm^2).
_TANK_AREAS = (28.0, 32.0, 28.0, 32.0)
#: Johansson (2000), Table II: the two operating points.
_TANK_POINTS = {
    "P-": dict(T=(62.0, 90.0, 23.0, 30.0), k=(3.33, 3.35), gamma=(0.70, 0.60), v0=(3.00, 3.00)),
    "P+": dict(T=(63.0, 91.0, 39.0, 56.0), k=(3.14, 3.29), gamma=(0.43, 0.34), v0=(3.15, 3.15)),
}
#: Pump voltage range (V).
PUMP_VOLTAGE_MAX = 10.0


def _quadruple_tank(name: str, point: str, description: str) -> MimoPlantSpec:
    """Johansson (2000), eq. (2): the linearised tanks at the operating point ``point``."""
    p = _TANK_POINTS[point]
    return quadruple_tank_spec(name, p["T"], p["k"], p["gamma"], p["v0"], description)


def quadruple_tank_spec(
    name: str,
    T: tuple[float, ...],
    k: tuple[float, float],
    gamma: tuple[float, float],
    v0: tuple[float, float],
    description: str,
) -> MimoPlantSpec:
    """Johansson (2000), eq. (2): the quadruple tank linearised at an operating point with
    time constants ``T`` (s), pump gains ``k`` (cm^3/Vs), valve settings ``gamma`` and pump
    voltages ``v0`` (V); performance output the two lower levels, pumps within
    ``[0, PUMP_VOLTAGE_MAX]`` V, sampled at 5 s."""
    A1, A2, A3, A4 = _TANK_AREAS
    T1, T2, T3, T4 = T
    (k1, k2), (g1, g2) = k, gamma
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
        name,
        A_c,
        B_c,
        5.0,
        description,
        C_z=((1.0, 0.0, 0.0, 0.0), (0.0, 1.0, 0.0, 0.0)),
        input_range=(tuple(-v for v in v0), tuple(PUMP_VOLTAGE_MAX - v for v in v0)),
    )


_S = float(np.sqrt(0.5))  # controlgym's COMPleib entries hold sqrt(1/2) to 5 digits

MIMO_PLANTS: dict[str, MimoPlantSpec] = {
    p.name: p
    for p in (
        _quadruple_tank(
            "quadruple_tank", "P-", "Johansson's quadruple-tank process, minimum phase (P-)."
        ),
        _quadruple_tank(
            "quadruple_tank_nmp",
            "P+",
            "Johansson's quadruple-tank process, a right-half-plane transmission zero (P+).",
        ),
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
            C_z=((2 * _S, 0.0, 0.0, 0.0), (0.0, _S, 0.0, 0.0)),
            D_z=((_S, 0.0), (0.0, _S)),
            C_y=((0.0, 1.0, 0.0, 0.0),),
            B1_c=(
                (0.04678, 0.0),
                (0.04572, 0.00988),
                (0.04369, 0.00111),
                (-0.02179, 0.0),
            ),
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
            C_z=((0.0, _S, 0.0, 0.0, 0.0), (0.0, 0.0, _S, 0.0, 0.0), (0.0,) * 5),
            D_z=((_S, 0.0, 0.0), (0.0, _S, 0.0), (0.0, 0.0, _S)),
            C_y=((1.0, 0.0, 0.0, 0.0, 0.0), (0.0, 1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0, 0.0)),
            B1_c=(
                (0.03593, 0.0, 0.01672),
                (0.0, 0.00989, 0.0),
                (0.0, -0.07548, 0.0),
                (0.0, 0.0, 0.05635),
                (0.00145, 0.0, 0.06743),
            ),
        ),
    )
}


def mimo_plant_names() -> list[str]:
    """Names of the MIMO catalogue plants.

    Examples
    --------
    >>> from stcgym.envs import mimo_plant_names
    >>> mimo_plant_names()
    ['quadruple_tank', 'quadruple_tank_nmp', 'he1', 'ac1']
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
