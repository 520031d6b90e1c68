"""The multi-input multi-output plants: any state-space system (matrices, a python-control
system or a MIMO catalogue name) and the multichannel static object of Voevoda & Troshina (2017),
on the common :class:`~stcgym.envs.linear_plant.LinearPlantEnv` (timing, reward, termination,
randomness: see :mod:`stcgym.envs.linear_plant`)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from gymnasium import spaces
from numpy.typing import ArrayLike, NDArray

from stcgym.envs import dynamics
from stcgym.envs.linear_plant import _EMPTY, LinearPlantEnv
from stcgym.envs.mimo_plants import get_mimo_plant
from stcgym.lanes.validation import matrix, positive, real_array

__all__ = ["DEFAULT_STATE_SPACE", "MultichannelStaticEnv", "StateSpaceEnv"]

#: The plant of ``gym.make("stcgym/StateSpace-v0")`` without matrices: a stable, coupled
#: two-state, two-input plant (eigenvalues 0.9 and 0.8) with measured state (``C = I``, ``D = 0``).
DEFAULT_STATE_SPACE = {
    "A": ((0.9, 0.1), (0.0, 0.8)),
    "B": ((1.0, 0.0), (0.5, 1.0)),
}


class StateSpaceEnv(LinearPlantEnv):
    """MIMO discrete plant ``x(k+1) = A x + B u + w``, ``y = C x + D u + v``.

    ``reset(options=...)`` accepts ``"A"`` and ``"B"`` to override this episode's matrices.
    ``info`` carries ``"x"``, ``"y_clean"``, ``"params"`` (``[A B]`` in force) and ``"t"``.
    ``env.unwrapped.sys`` is the discrete python-control system of the nominal plant (built on
    request: the env itself holds only arrays, so it pickles). Registered as
    ``stcgym/StateSpace-v0``.

    Parameters
    ----------
    A, B, C, D : array_like, optional
        Matrices, finite: ``A`` square ``(n, n)``, ``B`` ``(n, m)``, ``C`` ``(p, n)``, ``D``
        ``(p, m)``. ``C`` defaults to the identity (the measured-state plant of Kunik et al.
        2001), ``D`` to zero. Or give ``sys`` instead. With neither, the documented default
        plant :data:`DEFAULT_STATE_SPACE` (two states, two inputs, measured state).
    plant : str, optional
        A name of the MIMO catalogue (:data:`stcgym.envs.mimo_plants.MIMO_PLANTS`: its
        zero-order-hold ``A``, ``B``, measured state; ``dt`` its sample time), instead of the
        matrices or ``sys``.
    sys : python-control system, optional
        Any python-control ``StateSpace`` or ``TransferFunction`` (or anything ``control.ss``
        accepts). A continuous system is discretised with ``control.sample_system(sys, dt,
        "zoh")``, so ``dt`` is then required.
    dt : float, optional
        Sample time (``> 0``) for discretising a continuous ``sys``; with matrices, recorded in
        :attr:`sys` (default ``True``: discrete, unspecified sample time).
    canonical : {None, "reachable", "observable", "modal"}, default None
        A python-control canonical form, applied with ``control.canonical_form`` after
        discretisation (SISO plants only).
    schedule : schedule spec, optional
        Acts on the stacked matrix ``[A B]`` (shape ``(n, n + m)``).
    C_z, D_z : array_like, optional
        A performance output ``z = C_z x + D_z u`` (``(p_z, n)``, ``(p_z, m)``; ``D_z``
        default zero). With it the reference has ``p_z`` channels, the observation is
        ``[y(k), r(k)]`` of length ``p + p_z``, and the reward of step ``k`` is the LQ stage
        cost at the state the input acts on,
        ``-(||C_z x(k) + D_z u(k) - r(k)||^2 + rho ||u(k)||^2)`` (weights ``Q = C_z' C_z``,
        ``R = D_z' D_z + rho I``, cross weight ``N = C_z' D_z``), instead of the tracking cost
        of the output ``y(k+1)``.
    noise_input : array_like, optional
        ``G`` (``(n, d)``, ``d <= n``): the process noise is ``w = process_noise_std G z``,
        ``z ~ N(0, I_d)`` (default ``G = I``: independent noise on each state).
    reference_in : {"output", "state"}, default "output"
        With a performance output and measured state: ``"state"`` observes the reference as
        the state ``r_x = C_z^+ r(k)`` (``n`` values, ``C_z r_x = r`` for ``C_z`` of full row
        rank), so that a state-feedback design for ``Q = C_z' C_z`` tracking ``r_x`` tracks
        ``r``: ``(x - r_x)' Q (x - r_x) = ||C_z x - r||^2``.
    input_range : pair of array_like, optional
        ``(low, high)``, one value per input (``low < high``): the inputs are clipped to
        ``[max(low, -action_bound), min(high, action_bound)]``, the action space's bounds (an
        asymmetric range around an operating point).
    cost : {"tracking", "performance"}, default "tracking"
        With ``plant``: ``"performance"`` takes ``C_z``, ``D_z``, the noise input ``B1`` and the
        input range from the catalogue entry (:class:`~stcgym.envs.mimo_plants.MimoPlantSpec`).
    measured : {"state", "output"}, default "state"
        With ``plant``: ``"output"`` measures the entry's ``C_y x`` instead of the state.
    **kwargs
        Other keyword arguments as in :class:`LinearPlantEnv`; ``reference`` may be one spec
        for every output or a list with one per output.

    Raises
    ------
    ValueError
        Matrices of wrong or inconsistent shapes or not finite (naming the matrix); ``sys``
        together with matrices; only one of ``A``, ``B``; a continuous ``sys`` without ``dt``;
        ``dt <= 0``; an unknown ``canonical``, or one python-control cannot apply to this plant;
        any value :class:`LinearPlantEnv` rejects.
    TypeError
        ``sys`` that ``control.ss`` does not accept; a value of the wrong kind.

    Examples
    --------
    The default plant (measured state, square-wave reference on both outputs):

    >>> import gymnasium as gym
    >>> import numpy as np
    >>> import stcgym.envs
    >>> env = gym.make("stcgym/StateSpace-v0")
    >>> obs, info = env.reset(seed=0)
    >>> obs  # [y(0), r(0)], two outputs each
    array([0., 0., 1., 1.])
    >>> obs, reward, *_ = env.step(np.array([1.0, 0.0]))
    >>> obs  # y(1) = C x(1) = B u(0)
    array([1. , 0.5, 1. , 1. ])

    The quadruple tank at its minimum-phase operating point, its cost on the two lower levels
    (reference and cost in ``z = C_z x``, the state measured), pumps within their voltage range:

    >>> env = gym.make("stcgym/StateSpace-v0", plant="quadruple_tank", cost="performance",
    ...                reference="zero")
    >>> env.observation_space.shape  # [x(k), r(k)]: four levels, two references
    (6,)
    >>> env.action_space.low, env.action_space.high
    (array([-3., -3.]), array([7., 7.]))

    A continuous first-order lag ``1 / (s + 1)`` from python-control, sampled at ``dt = 0.1``:

    >>> import control
    >>> env = gym.make("stcgym/StateSpace-v0", sys=control.tf([1.0], [1.0, 1.0]), dt=0.1)
    >>> np.round(env.unwrapped.A, 6), np.round(env.unwrapped.B, 6)
    (array([[0.904837]]), array([[0.095163]]))
    """

    reset_options = LinearPlantEnv.reset_options | {"A", "B"}

    def __init__(
        self,
        A: ArrayLike | None = None,
        B: ArrayLike | None = None,
        C: ArrayLike | None = None,
        D: ArrayLike | None = None,
        *,
        plant: str | None = None,
        sys: Any = None,
        dt: float | None = None,
        canonical: str | None = None,
        C_z: ArrayLike | None = None,
        D_z: ArrayLike | None = None,
        noise_input: ArrayLike | None = None,
        input_range: Any = None,
        reference_in: str = "output",
        cost: str | None = None,
        measured: str | None = None,
        **kwargs: Any,
    ) -> None:
        import control

        if dt is not None:
            dt = positive(dt, "dt")
        if canonical is not None and canonical not in ("reachable", "observable", "modal"):
            raise ValueError(
                f"canonical must be None, 'reachable', 'observable' or 'modal', got {canonical!r}"
            )
        self.mimo_plant = None if plant is None else get_mimo_plant(plant)
        if self.mimo_plant is not None:
            if sys is not None or any(v is not None for v in (A, B, C, D, dt)):
                raise ValueError("give either plant (a MIMO catalogue name) or A, B (C, D), sys")
            A, B = self.mimo_plant.discrete()
            dt = self.mimo_plant.dt
            C_z, D_z, noise_input, input_range, C = _catalogue_settings(
                self.mimo_plant, cost, measured, C_z, D_z, noise_input, input_range
            )
        elif cost is not None or measured is not None:
            raise ValueError(
                "cost and measured select a MIMO catalogue plant's settings: give plant"
            )
        if sys is not None:
            if A is not None or B is not None or C is not None or D is not None:
                raise ValueError("give either sys or the matrices A, B (C, D), not both")
            try:
                sysd = control.ss(sys)
            except Exception as exc:  # python-control raises many types for a bad system
                raise TypeError(
                    f"sys must be a python-control system (StateSpace, TransferFunction) or "
                    f"anything control.ss accepts, got {sys!r}"
                ) from exc
            if sysd.isctime(strict=True):
                if dt is None:
                    raise ValueError("dt (> 0) is required to discretise a continuous sys")
                sysd = control.sample_system(sysd, dt, method="zoh")
            if canonical is not None:
                sysd = _canonical_form(sysd, canonical)
            A_, B_ = np.asarray(sysd.A, float), np.asarray(sysd.B, float)
            C_, D_ = np.asarray(sysd.C, float), np.asarray(sysd.D, float)
            self.dt = sysd.dt
            A_, B_ = matrix(A_, "sys.A", (None, None)), matrix(B_, "sys.B", (A_.shape[0], None))
        else:
            if A is None and B is None:
                A, B = DEFAULT_STATE_SPACE["A"], DEFAULT_STATE_SPACE["B"]
            if A is None or B is None:
                raise ValueError("StateSpaceEnv needs both matrices A and B (or sys=...)")
            A_ = matrix(A, "A", (None, None))
            if A_.shape[0] != A_.shape[1]:
                raise ValueError(f"A must be square (n x n), got shape {A_.shape}")
            n = A_.shape[0]
            B_ = matrix(B, "B", (n, None))
            C_ = np.eye(n) if C is None else matrix(C, "C", (None, n))
            D_ = (
                np.zeros((C_.shape[0], B_.shape[1]))
                if D is None
                else matrix(D, "D", (C_.shape[0], B_.shape[1]))
            )
            self.dt = True if dt is None else dt
            if canonical is not None:
                sysd = _canonical_form(control.ss(A_, B_, C_, D_, self.dt), canonical)
                A_, B_ = np.asarray(sysd.A, float), np.asarray(sysd.B, float)
                C_, D_ = np.asarray(sysd.C, float), np.asarray(sysd.D, float)
        self.A_nominal, self.B_nominal = np.ascontiguousarray(A_), np.ascontiguousarray(B_)
        self.C, self.D = np.ascontiguousarray(C_), np.ascontiguousarray(D_)
        n, m = self.B_nominal.shape
        self._tmp = np.zeros(n)
        self._performance_settings(C_z, D_z, reference_in, noise_input)
        p_r = None if self.C_z is None else self.C_z.shape[0]
        super().__init__(
            n_states=n, n_inputs=m, n_outputs=self.C.shape[0], n_references=p_r, **kwargs
        )
        self.input_range = _input_range(input_range, m, self.action_bound)
        if self.input_range is not None:
            self.action_space = spaces.Box(*self.input_range, dtype=np.float64)
        self._no_reference = np.zeros(self.C.shape[0])
        self._z_w = np.zeros(n)
        self._set_params(np.hstack((self.A_nominal, self.B_nominal)))

    def _performance_settings(
        self, C_z: Any, D_z: Any, reference_in: str, noise_input: Any
    ) -> None:
        """``C_z``, ``D_z``, the observed reference's map and the noise input, checked."""
        n, m = self.B_nominal.shape
        self.C_z, self.D_z = _performance_output(C_z, D_z, n, m)
        if reference_in not in ("output", "state"):
            raise ValueError(f"reference_in must be 'output' or 'state', got {reference_in!r}")
        if reference_in == "state" and (self.C_z is None or not np.array_equal(self.C, np.eye(n))):
            raise ValueError("reference_in='state' needs a performance output and measured state")
        self.reference_in = reference_in
        # r_x = C_z^+ r: a state whose performance output is r (C_z of full row rank)
        self._to_state = None if reference_in == "output" else np.linalg.pinv(self.C_z).T
        self.noise_input = _noise_input(noise_input, n)

    @property
    def sys(self) -> Any:
        """The discrete python-control system of the nominal plant (a new object per call).

        Examples
        --------
        >>> import gymnasium as gym
        >>> import stcgym.envs
        >>> sys = gym.make("stcgym/StateSpace-v0").unwrapped.sys
        >>> sys.nstates, sys.ninputs, sys.noutputs, sys.isdtime()
        (2, 2, 2, True)
        """
        import control

        return control.ss(self.A_nominal, self.B_nominal, self.C, self.D, self.dt)

    def _parse_options(self, options: dict[str, Any]) -> NDArray | None:
        if "A" not in options and "B" not in options:
            return None
        n, m = self.B_nominal.shape
        A = matrix(options["A"], "options['A']", (n, n)) if "A" in options else self.A_nominal
        B = matrix(options["B"], "options['B']", (n, m)) if "B" in options else self.B_nominal
        return np.hstack((A, B))

    def _nominal_params(self, parsed: NDArray | None, rng: np.random.Generator) -> NDArray:
        return np.hstack((self.A_nominal, self.B_nominal)) if parsed is None else parsed

    def _matrices(self, params: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        n = self.n_states
        return params[:, :n], params[:, n:], self.C, self.D

    def _plant_step(
        self, u_raw: NDArray, z_w: NDArray, z_v: NDArray, r: NDArray
    ) -> tuple[float, bool, bool]:
        clipped = False
        if self.input_range is not None or self.C_z is not None:
            u_raw, clipped = _clip(u_raw, *self._bounds())
        if self.noise_input is not None and z_w.size:
            dynamics.matvec(self.noise_input, z_w, self._z_w)
            z_w = self._z_w
        if self.C_z is not None:  # the LQ stage cost at x(k), before the step moves it
            cost = dynamics.performance_reward(
                self._x, u_raw, self._r(self.t), self.C_z, self.D_z, self.control_cost
            )
            r = self._no_reference
        reward, kernel_clipped, diverged = dynamics.state_space_plant_step(
            self._x, self.params, self.C, self.D, u_raw, self.action_bound,
            self.process_noise_std, z_w, self.noise_std, z_v, r, self.control_cost,
            self.y_bound, self._u, self._y_clean, self._y, self._tmp,
        )  # fmt: skip
        if self.C_z is not None:
            reward = cost
        return reward, clipped or kernel_clipped, diverged

    def _observed_reference(self, r: NDArray) -> NDArray:
        return r if self._to_state is None else r @ self._to_state

    def _bounds(self) -> tuple[Any, Any]:
        """The input bounds ``(low, high)`` (arrays with an input range, else floats)."""
        if self.input_range is not None:
            return self.input_range
        return -self.action_bound, self.action_bound

    def _reset_output(self) -> None:
        dynamics.matvec(self.C, self._x, self._y_clean)

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        spec = state.get("spec")
        if spec is not None and "sys" in spec.kwargs:
            # gym.make keeps its kwargs in env.spec; a python-control system holds a lambda.
            # Re-specify the same plant by its discrete matrices.
            kwargs = {k: v for k, v in spec.kwargs.items() if k not in ("sys", "canonical")}
            kwargs.update(A=self.A_nominal, B=self.B_nominal, C=self.C, D=self.D, dt=self.dt)
            state["spec"] = dataclasses.replace(spec, kwargs=kwargs)
        return state


def _clip(u_raw: NDArray, low: Any, high: Any) -> tuple[NDArray, bool]:
    u = np.clip(u_raw, low, high)
    return u, bool(np.any(u != u_raw))


def _catalogue_settings(
    plant: Any, cost: str | None, measured: str | None, C_z: Any, D_z: Any, G: Any, bounds: Any
) -> tuple[Any, Any, Any, Any, Any]:
    """``(C_z, D_z, noise_input, input_range, C)`` of a catalogue plant for ``cost`` and
    ``measured`` (values given explicitly win)."""
    if cost not in (None, "tracking", "performance"):
        raise ValueError(f"cost must be 'tracking' or 'performance', got {cost!r}")
    if measured not in (None, "state", "output"):
        raise ValueError(f"measured must be 'state' or 'output', got {measured!r}")
    if cost == "performance":
        Cz, Dz = plant.performance_output()
        C_z = Cz if C_z is None else C_z
        D_z = Dz if D_z is None else D_z
        G = (plant.noise_input() if plant.B1_c is not None else None) if G is None else G
        bounds = plant.input_range if bounds is None else bounds
    C = None
    if measured == "output":
        if plant.C_y is None:
            raise ValueError(f"plant {plant.name!r} has no measured output C_y (measured='state')")
        C = np.array(plant.C_y, dtype=float)
    return C_z, D_z, G, bounds, C


def _performance_output(C_z: Any, D_z: Any, n: int, m: int) -> tuple[Any, Any]:
    if C_z is None:
        if D_z is not None:
            raise ValueError("D_z needs C_z (the performance output z = C_z x + D_z u)")
        return None, None
    Cz = matrix(C_z, "C_z", (None, n))
    Dz = np.zeros((Cz.shape[0], m)) if D_z is None else matrix(D_z, "D_z", (Cz.shape[0], m))
    return Cz, np.ascontiguousarray(Dz)


def _noise_input(G: Any, n: int) -> NDArray | None:
    """``G`` padded with zero columns to ``(n, n)`` (the noise stream draws ``n`` normals)."""
    if G is None:
        return None
    Gm = matrix(G, "noise_input", (n, None))
    if Gm.shape[1] > n:
        raise ValueError(f"noise_input must have at most n = {n} columns, got {Gm.shape[1]}")
    return np.ascontiguousarray(np.hstack((Gm, np.zeros((n, n - Gm.shape[1])))))


def _input_range(bounds: Any, m: int, bound: float) -> tuple[NDArray, NDArray] | None:
    if bounds is None:
        return None
    try:
        low, high = (real_array(v, "input_range").reshape(-1) for v in bounds)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"input_range must be a pair (low, high), got {bounds!r}") from exc
    if low.shape != (m,) or high.shape != (m,) or not np.all(low < high):
        raise ValueError(
            f"input_range must be (low, high) with {m} values each and low < high, got {bounds!r}"
        )
    low, high = np.maximum(low, -bound), np.minimum(high, bound)
    if not np.all(low < high):
        raise ValueError(f"input_range {bounds!r} lies outside [-action_bound, action_bound]")
    return np.ascontiguousarray(low), np.ascontiguousarray(high)


def _canonical_form(sys: Any, form: str) -> Any:
    import control

    try:
        return control.canonical_form(sys, form)[0]
    except control.ControlNotImplemented as exc:
        raise ValueError(f"canonical={form!r} needs a SISO plant (python-control): {exc}") from exc


class MultichannelStaticEnv(LinearPlantEnv):
    """Static multichannel object ``y^T = u^T Theta + v^T`` (Voevoda & Troshina 2017).

    The action ``u(k)`` (``n_inputs`` values) produces ``y(k+1) = Theta^T u(k) + v(k+1)``; it is
    the state-space plant with no state and ``D = Theta^T``, so the timing convention of the
    module holds. Default ``Theta = [[1, 2], [0, 1]]`` and ``noise_std = 0.1`` (variance 0.01), the
    paper's worked example. ``schedule`` acts on ``Theta``; ``reset(options={"theta": ...})``
    overrides it for one episode. The reward tracks the vector reference. Registered as
    ``stcgym/MultichannelStatic-v0`` (no vector env).

    ``info`` carries ``"theta"`` (``Theta`` in force), ``"y_clean"``, ``"t"`` and an empty
    ``"x"``.

    Parameters
    ----------
    theta : array_like, shape (n_inputs, n_outputs), default ((1, 2), (0, 1))
        ``Theta``, finite; row ``i`` holds input ``i``'s gains to every output.
    noise_std : float, default 0.1
        Standard deviation of the white Gaussian output noise ``v`` (``>= 0``).
    **kwargs
        ``reference``, ``schedule``, ``action_bound``, ``control_cost``, ``y_bound``,
        ``render_mode`` as in :class:`LinearPlantEnv`; ``reference`` may be a list with one
        spec per output.

    Raises
    ------
    ValueError
        ``theta`` not a finite 2-D matrix; ``process_noise_std`` or ``initial_state`` given (the
        object has no state); any value :class:`LinearPlantEnv` rejects.
    TypeError
        A value of the wrong kind.

    Examples
    --------
    >>> import gymnasium as gym
    >>> import numpy as np
    >>> import stcgym.envs
    >>> env = gym.make("stcgym/MultichannelStatic-v0", noise_std=0.0, reference="zero")
    >>> obs, info = env.reset(seed=0)
    >>> obs, reward, terminated, truncated, info = env.step(np.array([1.0, 1.0]))
    >>> obs  # [y(1), r(1)] with y(1) = Theta^T u(0)
    array([1., 3., 0., 0.])
    >>> info["theta"]
    array([[1., 2.],
           [0., 1.]])
    """

    reset_options = frozenset({"theta"})

    def __init__(
        self, theta: ArrayLike = ((1.0, 2.0), (0.0, 1.0)), *, noise_std: float = 0.1, **kwargs: Any
    ) -> None:
        self._theta0 = matrix(theta, "theta", (None, None))
        n_in, n_out = self._theta0.shape
        if {"process_noise_std", "initial_state", "initial_state_std"} & set(kwargs):
            raise ValueError("a static object has no state: no process noise or initial state")
        super().__init__(n_states=0, n_inputs=n_in, n_outputs=n_out, noise_std=noise_std, **kwargs)
        self._set_params(self._theta0.copy())

    def _parse_options(self, options: dict[str, Any]) -> NDArray | None:
        if "theta" in options:
            return matrix(options["theta"], "options['theta']", self._theta0.shape)
        return None

    def _nominal_params(self, parsed: NDArray | None, rng: np.random.Generator) -> NDArray:
        return self._theta0.copy() if parsed is None else parsed

    def _matrices(self, params: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        n_in, n_out = params.shape
        return np.zeros((0, 0)), np.zeros((0, n_in)), np.zeros((n_out, 0)), params.T

    def _plant_step(
        self, u_raw: NDArray, z_w: NDArray, z_v: NDArray, r: NDArray
    ) -> tuple[float, bool, bool]:
        # y(k+1) = Theta(k+1)^T u(k): the output is sampled after the parameters move on.
        if self.schedule.time_varying:
            self._set_params(self.schedule(self.t + 1))
        return dynamics.static_plant_step(
            self.params, u_raw, self.action_bound, self.noise_std, z_v, r, self.control_cost,
            self.y_bound, self._u, self._y_clean, self._y, _EMPTY,
        )  # fmt: skip

    def _reset_output(self) -> None:
        self._y_clean[:] = 0.0

    def _info(self) -> dict[str, Any]:
        info = super()._info()
        info["theta"] = info.pop("params")
        return info
