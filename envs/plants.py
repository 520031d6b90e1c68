"""Gymnasium environments for linear discrete-time plants.

Timing convention (the same in every environment)
--------------------------------------------------
Steps are counted ``k = 0, 1, 2, ...`` from ``reset`` (``k`` is the seed paper's ``t - 1``). At
step ``k`` the agent observes ``y(k)`` and ``r(k)``, applies ``u(k)``; the environment computes
``x(k+1) = A(k) x(k) + B(k) u(k) + w(k)`` and returns ``y(k+1) = C x(k+1) + D u(k) + v(k+1)``
and ``r(k+1)``. The feedthrough term uses the input still held from the last step (zero-order
hold, sampled before the next input is chosen), so the observation never depends on an action not
yet taken. The state starts at zero unless set, and every signal is zero before the first step,
so ``y(0) = C x(0) + v(0)``.

The reward of step ``k`` is ``-(||y_clean(k+1) - r(k+1)||^2 + rho ||u(k)||^2)``, scored on the
noise-free output (the controller's quality, not the sensor's), with ``rho = control_cost``.

Episodes end with ``terminated=True`` (and ``info["diverged"] = True``) when an output leaves
``[-y_bound, y_bound]`` or the state stops being finite; the time limit (``max_episode_steps`` in
the registration or ``gym.make``) gives ``truncated=True``.

Randomness: ``reset(seed=...)`` seeds ``np_random``; each episode then draws independent child
streams for output noise, process noise, the reference, the parameter schedule and the initial
state / parameter draws, so an episode is reproducible from its seed whatever happened before.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import ArrayLike, NDArray

from stcgym.envs.canonical import (
    canonical_matrices,
    check_ab,
    check_form,
    observer_to_observability_b,
    split_theta,
)
from stcgym.envs.catalogue import PlantSpec, get_plant
from stcgym.envs.signals import Jumps, Reference, Schedule, make_references, make_schedule

__all__ = [
    "LinearPlantEnv",
    "CanonicalPlantEnv",
    "ObserverCanonicalEnv",
    "ObservabilityCanonicalEnv",
    "StateSpaceEnv",
    "MultichannelStaticEnv",
]

_NOISE_BLOCK = 512  # standard normals drawn per refill: one generator call per 512 steps


def _non_negative(value: float, name: str) -> float:
    v = float(value)
    if not np.isfinite(v) or v < 0:
        raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
    return v


def _matrix(value: ArrayLike, name: str, shape: tuple[int | None, int | None]) -> NDArray:
    """2-D finite float matrix with the given shape (``None`` = any size)."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 1 and shape[1] == 1:
        arr = arr.reshape(-1, 1)
    if arr.ndim != 2:
        raise ValueError(f"{name} must be a 2-D matrix, got shape {arr.shape}")
    for got, want, what in zip(arr.shape, shape, ("rows", "columns"), strict=True):
        if want is not None and got != want:
            raise ValueError(f"{name} must have {want} {what} (shape {shape}), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


class _NormalStream:
    """Standard normals of a fixed width, drawn from one generator in blocks (cheap per step)."""

    def __init__(self, rng: np.random.Generator, width: int) -> None:
        self._rng, self._width = rng, width
        self._block = np.empty((0, width))
        self._i = 0

    def next(self) -> NDArray:
        if self._i >= self._block.shape[0]:
            self._block = self._rng.standard_normal((_NOISE_BLOCK, self._width))
            self._i = 0
        self._i += 1
        return self._block[self._i - 1]


class LinearPlantEnv(gym.Env):
    """Base class: a discrete linear plant ``(A(k), B(k), C, D)`` driven by a parameter array.

    Subclasses provide the nominal parameter array of an episode and map a parameter array to
    the matrices (:meth:`_matrices`). See the module docstring for timing, reward and
    termination. Public attributes of ``env.unwrapped``: ``A``, ``B``, ``C``, ``D`` (matrices in
    force now), ``params`` (the scheduled parameter array), ``x`` (true state), ``t`` (step
    index), ``reference`` (list of per-output :class:`~stcgym.envs.signals.Reference`),
    ``schedule``.

    Observation: ``[y(k) (p values), r(k) (p values)]``, a flat float64 ``Box``. Action: ``u(k)``
    (``m`` values) in ``[-action_bound, action_bound]``; larger actions are clipped and counted
    (``info["clipped"]``, ``info["n_clipped"]``); non-finite or wrongly shaped actions raise.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(
        self,
        *,
        n_states: int,
        n_inputs: int,
        n_outputs: int,
        reference: Any = "square",
        schedule: Any = None,
        noise_std: float = 0.0,
        process_noise_std: float = 0.0,
        action_bound: float = 10.0,
        control_cost: float = 0.01,
        y_bound: float = 100.0,
        initial_state: ArrayLike | None = None,
        render_mode: str | None = None,
    ) -> None:
        super().__init__()
        self.n_states, self.n_inputs, self.n_outputs = n_states, n_inputs, n_outputs
        self.noise_std = _non_negative(noise_std, "noise_std")
        self.process_noise_std = _non_negative(process_noise_std, "process_noise_std")
        self.control_cost = _non_negative(control_cost, "control_cost")
        self.action_bound = _non_negative(action_bound, "action_bound")
        if self.action_bound == 0:
            raise ValueError("action_bound must be positive")
        self.y_bound = _non_negative(y_bound, "y_bound")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self.reference: list[Reference] = make_references(reference, n_outputs)
        self.schedule: Schedule = make_schedule(schedule)
        self._initial_state = (
            None if initial_state is None else self._check_state(initial_state, "initial_state")
        )
        self.action_space = spaces.Box(
            -self.action_bound, self.action_bound, shape=(n_inputs,), dtype=np.float64
        )
        self.observation_space = spaces.Box(
            -np.inf, np.inf, shape=(2 * n_outputs,), dtype=np.float64
        )
        self.t = 0
        self.x = np.zeros(n_states)
        self.n_clipped = 0
        self._trace: dict[str, list] = {"y": [], "r": [], "u": []}

    # ---------------------------------------------------------------- subclass hooks
    def _nominal_params(self, options: dict[str, Any], rng: np.random.Generator) -> NDArray:
        """The parameter array of this episode (before the schedule acts)."""
        raise NotImplementedError

    def _matrices(self, params: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        """``(A, B, C, D)`` for a parameter array."""
        raise NotImplementedError

    # ---------------------------------------------------------------- helpers
    def _check_state(self, value: ArrayLike, name: str) -> NDArray:
        x = np.asarray(value, dtype=float).ravel()
        if x.shape != (self.n_states,) or not np.all(np.isfinite(x)):
            raise ValueError(f"{name} must be a finite vector of length {self.n_states}")
        return x

    def _set_params(self, params: NDArray) -> None:
        self.params = params
        self.A, self.B, self.C, self.D = self._matrices(params)

    def _r(self, k: int) -> NDArray:
        return np.array([ref(k) for ref in self.reference])

    def _info(self) -> dict[str, Any]:
        return {
            "t": self.t,
            "x": self.x.copy(),
            "y_clean": self._y_clean.copy(),
            "params": np.array(self.params, copy=True),
            "clipped": self._clipped,
            "n_clipped": self.n_clipped,
            "diverged": self._diverged,
        }

    # ---------------------------------------------------------------- gymnasium API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray, dict[str, Any]]:
        """Start an episode.

        ``options`` (all optional): ``"initial_state"`` (vector), ``"initial_state_std"`` (draw
        ``x(0) ~ N(0, std^2 I)``), and parameter overrides documented by each subclass.
        """
        super().reset(seed=seed)
        options = dict(options or {})
        children = np.random.SeedSequence(int(self.np_random.integers(2**63))).spawn(5)
        rng_v, rng_w, rng_ref, rng_sched, rng_draw = (np.random.default_rng(s) for s in children)
        self._v = _NormalStream(rng_v, self.n_outputs)
        self._w = _NormalStream(rng_w, self.n_states)
        for ref, child in zip(self.reference, rng_ref.spawn(len(self.reference)), strict=True):
            ref.reset(child)
        nominal = self._nominal_params(options, rng_draw)  # may swap in a plant's schedule
        self.schedule.reset(nominal, rng_sched)

        if "initial_state" in options:
            self.x = self._check_state(options["initial_state"], "options['initial_state']")
        elif "initial_state_std" in options:
            std = _non_negative(options["initial_state_std"], "options['initial_state_std']")
            self.x = std * rng_draw.standard_normal(self.n_states)
        elif self._initial_state is not None:
            self.x = self._initial_state.copy()
        else:
            self.x = np.zeros(self.n_states)

        self.t = 0
        self.n_clipped = 0
        self._clipped = False
        self._diverged = False
        self._set_params(self.schedule(0))
        self._y_clean = self.C @ self.x
        y = self._y_clean + self.noise_std * self._v.next()
        r = self._r(0)
        self._trace = {"y": [y], "r": [r], "u": []}
        return np.concatenate((y, r)), self._info()

    def _action(self, action: ArrayLike) -> NDArray:
        u = np.asarray(action, dtype=float)
        if u.size != self.n_inputs or u.ndim > 1 and u.shape != (self.n_inputs,):
            raise ValueError(
                f"action must have shape ({self.n_inputs},) (a scalar is accepted when there is "
                f"one input), got shape {u.shape}"
            )
        u = u.reshape(self.n_inputs)
        if not np.all(np.isfinite(u)):
            raise ValueError(f"action must be finite, got {u}")
        clipped = np.clip(u, -self.action_bound, self.action_bound)
        self._clipped = bool(np.any(clipped != u))
        self.n_clipped += self._clipped
        return clipped

    def step(self, action: ArrayLike) -> tuple[NDArray, float, bool, bool, dict[str, Any]]:
        u = self._action(action)
        x_next = self.A @ self.x + self.B @ u
        if self.process_noise_std:
            x_next = x_next + self.process_noise_std * self._w.next()
        self.x = x_next
        self.t += 1
        if self.schedule.time_varying:
            self._set_params(self.schedule(self.t))
        # y(k+1) uses D u(k): the input is still held when the next sample is taken.
        self._y_clean = self.C @ self.x + self.D @ u
        y = self._y_clean + self.noise_std * self._v.next()
        r = self._r(self.t)

        finite = bool(np.all(np.isfinite(self.x)) and np.all(np.isfinite(y)))
        self._diverged = not finite or bool(np.any(np.abs(y) > self.y_bound))
        if not finite:
            # Keep observation and reward finite: a diverged loop must end, not overflow.
            y = np.clip(
                np.nan_to_num(y, posinf=self.y_bound, neginf=-self.y_bound),
                -self.y_bound,
                self.y_bound,
            )
            self._y_clean = y.copy()
        e = np.clip(self._y_clean, -self.y_bound, self.y_bound) - r
        reward = -float(e @ e + self.control_cost * (u @ u))
        if self.render_mode is not None:
            self._trace["y"].append(y)
            self._trace["r"].append(r)
            self._trace["u"].append(u)
        return np.concatenate((y, r)), reward, self._diverged, False, self._info()

    def render(self) -> NDArray | None:
        """``rgb_array``: a picture of the episode so far (y, r and u traces)."""
        if self.render_mode is None:
            gym.logger.warn("render() called without render_mode='rgb_array'; returning None")
            return None
        from stcgym.envs.render import render_traces

        return render_traces(self._trace, title=type(self).__name__)


class CanonicalPlantEnv(LinearPlantEnv):
    """SISO plant in a canonical form with parameters ``theta = [a1..an, b1..bn]``.

    Parameters
    ----------
    plant
        Catalogue name (see :mod:`stcgym.envs.catalogue`), or a list of names to draw one per
        episode (plant-family training). Default ``"stable2"`` when neither ``plant`` nor
        ``a``/``b`` is given.
    a, b
        Parameters of this env's canonical form (equal lengths ``n``). In the observability form
        ``b`` holds Markov parameters; catalogue plants are converted automatically.
    noise_std
        Standard deviation of the white Gaussian output noise ``v``.
    process_noise_std
        Standard deviation of the white Gaussian process noise ``w`` (each state).
    action_bound
        Actions are clipped to ``[-action_bound, action_bound]``.
    control_cost
        ``rho`` in the reward ``-((y - r)^2 + rho u^2)``.
    reference
        See :func:`stcgym.envs.signals.make_reference`; default a unit square wave of period 100.
    schedule
        Parameter schedule acting on ``theta`` (this form's parameters): ``None``,
        :class:`~stcgym.envs.signals.Jumps`, :class:`~stcgym.envs.signals.Ramp`,
        :class:`~stcgym.envs.signals.RandomWalk` or ``{step: theta}``. Catalogue plants with a
        schedule of their own (``timevarying2``) use it unless one is given.
    y_bound
        Divergence bound on ``|y|`` (terminates the episode).
    initial_state
        ``x(0)``; zero by default.
    render_mode
        ``None`` or ``"rgb_array"``.

    ``reset(options=...)`` also accepts ``"plant"`` (a catalogue name), ``"a"`` and ``"b"``, or
    ``"theta"`` to set this episode's parameters. ``info`` carries the true state ``"x"``, the
    noise-free output ``"y_clean"``, the true parameters in force ``"theta"`` (also ``"a"``,
    ``"b"``) and the step ``"t"``. ``env.unwrapped.plant`` is the current
    :class:`~stcgym.envs.catalogue.PlantSpec` (``None`` for user parameters).
    """

    form = "observer"

    def __init__(
        self,
        plant: str | Sequence[str] | None = None,
        *,
        a: ArrayLike | None = None,
        b: ArrayLike | None = None,
        schedule: Any = None,
        **kwargs: Any,
    ) -> None:
        check_form(self.form)
        if plant is not None and (a is not None or b is not None):
            raise ValueError("give either plant (a catalogue name) or a and b, not both")
        if (a is None) != (b is None):
            raise ValueError("a and b must be given together (theta = [a; b])")
        if a is not None:
            self._family: list[PlantSpec] = []
            self._user_theta = np.concatenate(check_ab(a, b))
        else:
            names = ["stable2"] if plant is None else [plant] if isinstance(plant, str) else plant
            if len(names) == 0:
                raise ValueError("plant must be a catalogue name or a non-empty list of names")
            self._family = [get_plant(name) for name in names]
            if len({spec.n for spec in self._family}) > 1:
                raise ValueError(
                    f"plant family must share one order n, got {[s.name for s in self._family]}"
                )
            self._user_theta = None
        self._user_schedule = schedule is not None
        self.plant: PlantSpec | None = None if self._family == [] else self._family[0]
        n = self._family[0].n if self._family else self._user_theta.size // 2
        super().__init__(n_states=n, n_inputs=1, n_outputs=1, schedule=schedule, **kwargs)

    # -------------------------------------------------------------- parameters
    def _theta_of(self, spec: PlantSpec) -> NDArray:
        a, b = np.array(spec.a), np.array(spec.b)
        if self.form == "observability":
            b = observer_to_observability_b(a, b)
        return np.concatenate((a, b))

    def _catalogue_schedule(self, spec: PlantSpec) -> Schedule | None:
        if spec.schedule is None:
            return None
        sched = spec.schedule()
        if self.form == "observability" and isinstance(sched, Jumps):
            sched = Jumps([(k, self._theta_of(_spec_from_theta(v))) for k, v in sched.changes])
        return sched

    def _nominal_params(self, options: dict[str, Any], rng: np.random.Generator) -> NDArray:
        spec: PlantSpec | None = None
        if "theta" in options:
            theta = np.concatenate(split_theta(options["theta"]))
        elif "a" in options or "b" in options:
            theta = np.concatenate(check_ab(options.get("a"), options.get("b")))
        elif "plant" in options:
            spec = get_plant(options["plant"])
            theta = self._theta_of(spec)
        elif self._family:
            spec = (
                self._family[int(rng.integers(len(self._family)))]
                if len(self._family) > 1
                else self._family[0]
            )
            theta = self._theta_of(spec)
        else:
            theta = self._user_theta.copy()
        if theta.size != 2 * self.n_states:
            raise ValueError(
                f"episode parameters must have order n={self.n_states} like the env "
                f"(theta of length {2 * self.n_states}), got length {theta.size}"
            )
        self.plant = spec
        if not self._user_schedule:
            self.schedule = (self._catalogue_schedule(spec) if spec else None) or make_schedule(
                None
            )
        return theta

    def _matrices(self, params: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        n = self.n_states
        return canonical_matrices(params[:n], params[n:], self.form)

    @property
    def theta(self) -> NDArray:
        """True parameters ``[a; b]`` in force now (this env's canonical form)."""
        return np.array(self.params, copy=True)

    @property
    def a(self) -> NDArray:
        return self.params[: self.n_states].copy()

    @property
    def b(self) -> NDArray:
        return self.params[self.n_states :].copy()

    def _info(self) -> dict[str, Any]:
        info = super()._info()
        theta = info.pop("params")
        info["theta"] = theta
        info["a"], info["b"] = theta[: self.n_states], theta[self.n_states :]
        info["y_clean"] = float(info["y_clean"][0])
        return info


def _spec_from_theta(theta: NDArray) -> PlantSpec:
    n = theta.size // 2
    return PlantSpec("jumped", tuple(theta[:n]), tuple(theta[n:]), "")


class ObserverCanonicalEnv(CanonicalPlantEnv):
    """SISO plant in observer canonical form, seed paper eq. (1)-(5) (digest §2).

    ``A`` has ``-a`` in its first column and ones on the superdiagonal, ``B = b``,
    ``C = [1, 0, ..., 0]``; transfer function ``(b1 z^{n-1} + ... + bn) / (z^n + a1 z^{n-1} + ...
    + an)``. See :class:`CanonicalPlantEnv` for the parameters.
    """

    form = "observer"


class ObservabilityCanonicalEnv(CanonicalPlantEnv):
    """SISO plant in observability canonical form, seed paper eq. (146)-(147) (digest §6).

    ``A`` is a shift with last row ``[-a_n, ..., -a_1]``, ``B = b`` (the first ``n`` Markov
    parameters), ``C = [1, 0, ..., 0]``. See :class:`CanonicalPlantEnv` for the parameters.
    """

    form = "observability"


class StateSpaceEnv(LinearPlantEnv):
    """MIMO discrete plant ``x(k+1) = A x + B u + w``, ``y = C x + D u + v``.

    Parameters
    ----------
    A, B, C, D
        Matrices (``C`` defaults to the identity: the measured-state plant of Kunik et al.
        2001; ``D`` to zero). Or give ``sys`` instead.
    sys
        Any python-control ``StateSpace`` or ``TransferFunction`` (or anything ``control.ss``
        accepts). A continuous system is discretised with ``control.sample_system(sys, dt,
        "zoh")``, so ``dt`` is then required.
    dt
        Sample time for discretising a continuous ``sys``.
    canonical
        ``None`` or a python-control canonical form name (``"reachable"``, ``"observable"``,
        ``"modal"``), applied with ``control.canonical_form`` after discretisation.
    schedule
        Acts on the stacked matrix ``[A B]`` (shape ``(n, n + m)``).

    Other keyword arguments as in :class:`LinearPlantEnv`; ``reference`` may be one spec for
    every output or a list with one per output. ``reset(options=...)`` accepts ``"A"`` and
    ``"B"`` to override this episode's matrices. ``env.unwrapped.sys`` is the discrete
    python-control system of the nominal plant.
    """

    def __init__(
        self,
        A: ArrayLike | None = None,
        B: ArrayLike | None = None,
        C: ArrayLike | None = None,
        D: ArrayLike | None = None,
        *,
        sys: Any = None,
        dt: float | None = None,
        canonical: str | None = None,
        **kwargs: Any,
    ) -> None:
        import control

        if sys is not None:
            if A is not None or B is not None or C is not None or D is not None:
                raise ValueError("give either sys or the matrices A, B (C, D), not both")
            sysd = control.ss(sys)
            if sysd.isctime(strict=True):
                if dt is None or not dt > 0:
                    raise ValueError("dt (> 0) is required to discretise a continuous sys")
                sysd = control.sample_system(sysd, dt, method="zoh")
        else:
            if A is None or B is None:
                raise ValueError("StateSpaceEnv needs the matrices A and B (or sys=...)")
            A_ = _matrix(A, "A", (None, None))
            if A_.shape[0] != A_.shape[1]:
                raise ValueError(f"A must be square (n x n), got shape {A_.shape}")
            n = A_.shape[0]
            B_ = _matrix(B, "B", (n, None))
            C_ = np.eye(n) if C is None else _matrix(C, "C", (None, n))
            D_ = (
                np.zeros((C_.shape[0], B_.shape[1]))
                if D is None
                else _matrix(D, "D", (C_.shape[0], B_.shape[1]))
            )
            sysd = control.ss(A_, B_, C_, D_, True if dt is None else dt)
        if canonical is not None:
            sysd, _ = control.canonical_form(sysd, canonical)
        self.sys = sysd
        self._A0, self._B0 = np.asarray(sysd.A, float), np.asarray(sysd.B, float)
        self._C, self._D = np.asarray(sysd.C, float), np.asarray(sysd.D, float)
        n, m = self._B0.shape
        super().__init__(n_states=n, n_inputs=m, n_outputs=self._C.shape[0], **kwargs)

    def _nominal_params(self, options: dict[str, Any], rng: np.random.Generator) -> NDArray:
        n, m = self._B0.shape
        A = _matrix(options["A"], "options['A']", (n, n)) if "A" in options else self._A0
        B = _matrix(options["B"], "options['B']", (n, m)) if "B" in options else self._B0
        return np.hstack((A, B))

    def _matrices(self, params: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        n = self.n_states
        return params[:, :n], params[:, n:], self._C, self._D


class MultichannelStaticEnv(LinearPlantEnv):
    """Static multichannel object ``y^T = u^T Theta + v^T`` (Voevoda & Troshina 2017, digest §8).

    The action ``u(k)`` (``n_inputs`` values) produces ``y(k+1) = Theta^T u(k) + v(k+1)``; it is
    the state-space plant with no state and ``D = Theta^T``, so the timing convention of the
    module holds. Default ``Theta = [[1, 2], [0, 1]]`` and ``noise_std = 0.1`` (variance 0.01), the
    seed's worked example. ``schedule`` acts on ``Theta``; ``reset(options={"theta": ...})``
    overrides it for one episode. The reward tracks the vector reference.
    """

    def __init__(
        self, theta: ArrayLike = ((1.0, 2.0), (0.0, 1.0)), *, noise_std: float = 0.1, **kwargs: Any
    ) -> None:
        self._theta0 = _matrix(theta, "theta", (None, None))
        n_in, n_out = self._theta0.shape
        if "process_noise_std" in kwargs or "initial_state" in kwargs:
            raise ValueError("a static object has no state: no process noise or initial state")
        super().__init__(n_states=0, n_inputs=n_in, n_outputs=n_out, noise_std=noise_std, **kwargs)

    def _nominal_params(self, options: dict[str, Any], rng: np.random.Generator) -> NDArray:
        if "theta" in options:
            return _matrix(options["theta"], "options['theta']", self._theta0.shape)
        return self._theta0.copy()

    def _matrices(self, params: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        n_in, n_out = params.shape
        return np.zeros((0, 0)), np.zeros((0, n_in)), np.zeros((n_out, 0)), params.T

    @property
    def theta(self) -> NDArray:
        """The true ``Theta`` (``n_inputs x n_outputs``) in force now."""
        return np.array(self.params, copy=True)

    def _info(self) -> dict[str, Any]:
        info = super()._info()
        info["theta"] = info.pop("params")
        return info
