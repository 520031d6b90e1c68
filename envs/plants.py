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
``[-y_bound, y_bound]``, the state stops being finite, or the reward overflows (then the reward
is :data:`~stcgym.envs.dynamics.REWARD_FLOOR`, the most negative finite float: rewards and
observations are always finite); the time limit (``max_episode_steps`` in the registration or
``gym.make``) gives ``truncated=True``.

The plant step itself is the compiled lane function of :mod:`stcgym.envs.dynamics`, the same
one the vector envs of :mod:`stcgym.envs.vector` run for each lane, so a single env equals the
matching lane of a vector env bit for bit.

Randomness: ``reset(seed=...)`` seeds ``np_random``; each episode then draws independent child
streams for output noise, process noise, the reference, the parameter schedule and the initial
state / parameter draws, so an episode is reproducible from its seed whatever happened before.

Bad input raises before any state changes: ``ValueError`` for a wrong value or shape,
``TypeError`` for a wrong kind of object, each naming the argument and the expected form.
Every env pickles and deep-copies; the copy continues exactly like the original.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import ArrayLike, NDArray

from stcgym.envs import dynamics
from stcgym.envs.canonical import (
    canonical_matrices,
    check_ab,
    check_form,
    observer_to_observability_b,
    split_theta,
)
from stcgym.envs.catalogue import PlantSpec, get_plant
from stcgym.envs.mimo_plants import get_mimo_plant
from stcgym.envs.signals import Jumps, Reference, Schedule, make_references, make_schedule
from stcgym.envs.validation import matrix, non_negative, positive, real_array

__all__ = [
    "LinearPlantEnv",
    "CanonicalPlantEnv",
    "ObserverCanonicalEnv",
    "ObservabilityCanonicalEnv",
    "StateSpaceEnv",
    "MultichannelStaticEnv",
    "DEFAULT_STATE_SPACE",
]

_NOISE_BLOCK = 512  # standard normals drawn per refill: one generator call per 512 steps
_EMPTY = np.zeros(0)

#: The plant of ``gym.make("stcgym/StateSpace-v0")`` without matrices: a stable, coupled
#: two-state, two-input plant (eigenvalues 0.9 and 0.8) with measured state (``C = I``, ``D = 0``).
DEFAULT_STATE_SPACE = {
    "A": ((0.9, 0.1), (0.0, 0.8)),
    "B": ((1.0, 0.0), (0.5, 1.0)),
}


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

    Subclasses provide the nominal parameter array of an episode, map a parameter array to the
    matrices (:meth:`_matrices`) and call their lane function of :mod:`stcgym.envs.dynamics`
    (:meth:`_plant_step`). See the module docstring for timing, reward and termination. Public
    attributes of ``env.unwrapped`` (all present from construction on): ``A``, ``B``, ``C``,
    ``D`` (matrices in force now), ``params`` (the scheduled parameter array), ``x`` (true
    state), ``t`` (step index), ``reference`` (list of per-output
    :class:`~stcgym.envs.signals.Reference`), ``schedule``.

    Observation: ``[y(k) (p values), r(k) (p values)]``, a flat float64 ``Box``. Action: ``u(k)``
    (``m`` real values) in ``[-action_bound, action_bound]``; larger actions are clipped and
    counted (``info["clipped"]``, ``info["n_clipped"]``); non-finite, complex, non-numeric or
    wrongly shaped actions raise ``ValueError`` and leave the env as it was.

    Parameters
    ----------
    n_states, n_inputs, n_outputs : int
        Dimensions ``n``, ``m``, ``p`` (set by the subclass from its plant).
    reference : reference spec, default "square"
        What :func:`~stcgym.envs.signals.make_reference` accepts (a name, a number, an array, a
        callable ``k -> r``, a dict, a :class:`~stcgym.envs.signals.Reference`), used for every
        output; or a list with one spec per output. Default a unit square wave of period 100.
    schedule : schedule spec, optional
        What :func:`~stcgym.envs.signals.make_schedule` accepts; acts on the subclass's
        parameter array. ``None``: time-invariant.
    noise_std : float, default 0.0
        Standard deviation of the white Gaussian output noise ``v`` (``>= 0``).
    process_noise_std : float, default 0.0
        Standard deviation of the white Gaussian process noise ``w``, each state (``>= 0``).
    action_bound : float, default 10.0
        Actions are clipped to ``[-action_bound, action_bound]`` (``> 0``).
    control_cost : float, default 0.01
        ``rho`` in the reward (``>= 0``).
    y_bound : float, default 100.0
        Divergence bound on ``|y|`` (``> 0``): an output beyond it terminates the episode.
    initial_state : array_like, shape (n,), optional
        ``x(0)`` of every episode unless ``reset`` options say otherwise; zero by default.
    render_mode : {None, "rgb_array"}, default None
        ``"rgb_array"``: :meth:`render` draws the episode's traces (needs matplotlib).

    Raises
    ------
    ValueError
        A number out of range or not finite, an unknown ``render_mode``, an ``initial_state``
        of the wrong length or not finite, a reference or schedule spec that is rejected.
    TypeError
        A number that is not a real number; a reference or schedule of an unknown kind.

    Examples
    --------
    Every stcgym env is a ``LinearPlantEnv``; the reset options of the base class set the
    initial state:

    >>> import gymnasium as gym
    >>> import stcgym.envs
    >>> from stcgym.envs import LinearPlantEnv
    >>> env = gym.make("stcgym/ObserverCanonical-v0", plant="stable2")
    >>> isinstance(env.unwrapped, LinearPlantEnv)
    True
    >>> obs, info = env.reset(seed=0, options={"initial_state": [1.0, 0.0]})
    >>> obs, info["x"]  # [y(0), r(0)] with y(0) = C x(0)
    (array([1., 1.]), array([1., 0.]))
    >>> env.reset(options={"intial_state": [1.0, 0.0]})
    Traceback (most recent call last):
        ...
    ValueError: unknown reset option(s) ['intial_state'] for ObserverCanonicalEnv; ...
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}
    #: ``reset(options=...)`` keys this env understands (subclasses extend it).
    reset_options: frozenset[str] = frozenset({"initial_state", "initial_state_std"})

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
        self.noise_std = non_negative(noise_std, "noise_std")
        self.process_noise_std = non_negative(process_noise_std, "process_noise_std")
        self.control_cost = non_negative(control_cost, "control_cost")
        self.action_bound = positive(action_bound, "action_bound")
        self.y_bound = positive(y_bound, "y_bound")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self.reference: list[Reference] = make_references(reference, n_outputs)
        self.schedule: Schedule = make_schedule(schedule)
        self.initial_state = (
            None if initial_state is None else self._check_state(initial_state, "initial_state")
        )
        self.action_space = spaces.Box(
            -self.action_bound, self.action_bound, shape=(n_inputs,), dtype=np.float64
        )
        self.observation_space = spaces.Box(
            -np.inf, np.inf, shape=(2 * n_outputs,), dtype=np.float64
        )
        self.t = 0
        self._x = np.zeros(n_states)
        self._u = np.zeros(n_inputs)
        self._y = np.zeros(n_outputs)
        self._y_clean = np.zeros(n_outputs)
        self.n_clipped = 0
        self._clipped = False
        self._diverged = False
        self._trace: dict[str, list] = {"y": [], "r": [], "u": []}

    # ---------------------------------------------------------------- subclass hooks
    def _parse_options(self, options: dict[str, Any]) -> Any:
        """Validate this subclass's parameter options (no randomness, no state change)."""
        return None

    def _nominal_params(self, parsed: Any, rng: np.random.Generator) -> NDArray:
        """The parameter array of this episode (before the schedule acts)."""
        raise NotImplementedError

    def _matrices(self, params: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        """``(A, B, C, D)`` for a parameter array."""
        raise NotImplementedError

    def _plant_step(
        self, u_raw: NDArray, z_w: NDArray, z_v: NDArray, r: NDArray
    ) -> tuple[float, bool, bool]:
        """One call of this plant's lane function: ``(reward, clipped, diverged)``."""
        raise NotImplementedError

    def _reset_output(self) -> None:
        """``y_clean(0) = C x(0)`` into ``self._y_clean``."""
        raise NotImplementedError

    #: The catalogue plant of this episode (canonical envs; ``None`` otherwise).
    plant: PlantSpec | None = None

    @property
    def theta(self) -> NDArray:
        """The parameter array in force now (a copy): ``[a; b]``, ``[A B]`` or ``Theta``.

        Examples
        --------
        >>> import gymnasium as gym
        >>> import stcgym.envs
        >>> env = gym.make("stcgym/ObserverCanonical-v0", plant="unstable2")
        >>> env.unwrapped.theta
        array([-1.7 ,  0.66,  0.5 ,  0.3 ])
        """
        return np.array(self.params, copy=True)

    # ---------------------------------------------------------------- helpers
    @property
    def x(self) -> NDArray:
        """True state ``x(k)``, shape ``(n_states,)``.

        Settable between steps (a finite vector of length ``n_states``, copied; anything else
        raises ``ValueError`` and leaves the state as it was).
        """
        return self._x

    @x.setter
    def x(self, value: ArrayLike) -> None:
        self._x = self._check_state(value, "x")

    def _check_state(self, value: ArrayLike, name: str) -> NDArray:
        x = real_array(value, name).ravel()
        if x.shape != (self.n_states,) or not np.all(np.isfinite(x)):
            raise ValueError(f"{name} must be a finite vector of length {self.n_states}")
        return np.ascontiguousarray(x)

    def _set_params(self, params: NDArray) -> None:
        self.params = np.ascontiguousarray(params, dtype=float)
        self.A, self.B, self.C, self.D = self._matrices(self.params)

    def _r(self, k: int) -> NDArray:
        kk = np.array([k], dtype=np.int64)
        return np.array([float(ref.values(kk, _LANE0)[0]) for ref in self.reference])

    def _info(self) -> dict[str, Any]:
        return {
            "t": self.t,
            "x": self._x.copy(),
            "y_clean": self._y_clean.copy(),
            "params": np.array(self.params, copy=True),
            "clipped": self._clipped,
            "n_clipped": self.n_clipped,
            "diverged": self._diverged,
        }

    def _check_option_keys(self, options: dict[str, Any]) -> None:
        unknown = sorted(set(options) - self.reset_options)
        if unknown:
            raise ValueError(
                f"unknown reset option(s) {unknown} for {type(self).__name__}; expected keys "
                f"from {sorted(self.reset_options)}"
            )

    # ---------------------------------------------------------------- gymnasium API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray, dict[str, Any]]:
        """Start an episode.

        ``options`` (all optional): ``"initial_state"`` (vector), ``"initial_state_std"`` (draw
        ``x(0) ~ N(0, std^2 I)``), and parameter overrides documented by each subclass. Unknown
        keys (a typo such as ``"intial_state"``) raise ``ValueError`` before anything changes.

        Parameters
        ----------
        seed : int, optional
            Seeds ``np_random``; the episode's noise, reference, schedule and draws come from
            independent child streams of it. ``None`` continues the current generator.
        options : dict, optional
            Keys from :attr:`reset_options`; they apply to this episode only.

        Returns
        -------
        observation : ndarray
            ``[y(0), r(0)]``.
        info : dict
            As :meth:`step` returns it, for step 0.

        Raises
        ------
        TypeError
            ``options`` is not a dict.
        ValueError
            An unknown key, or a value the key does not accept (naming the key).
        """
        if options is not None and not isinstance(options, dict):
            raise TypeError(f"options must be a dict or None, got {options!r}")
        options = dict(options or {})
        self._check_option_keys(options)
        parsed = self._parse_options(options)
        x0 = None
        if "initial_state" in options:
            x0 = self._check_state(options["initial_state"], "options['initial_state']")
        elif "initial_state_std" in options:
            std = non_negative(options["initial_state_std"], "options['initial_state_std']")

        super().reset(seed=seed)
        children = np.random.SeedSequence(int(self.np_random.integers(2**63))).spawn(5)
        rng_v, rng_w, rng_ref, rng_sched, rng_draw = (np.random.default_rng(s) for s in children)
        self._v = _NormalStream(rng_v, self.n_outputs)
        self._w = _NormalStream(rng_w, self.n_states)
        for ref, child in zip(self.reference, rng_ref.spawn(len(self.reference)), strict=True):
            ref.reset(child)
        nominal = self._nominal_params(parsed, rng_draw)  # may swap in a plant's schedule
        self.schedule.reset(nominal, rng_sched)

        if x0 is not None:
            self._x = x0
        elif "initial_state_std" in options:
            self._x = std * rng_draw.standard_normal(self.n_states)
        elif self.initial_state is not None:
            self._x = self.initial_state.copy()
        else:
            self._x = np.zeros(self.n_states)

        self.t = 0
        self.n_clipped = 0
        self._clipped = False
        self._diverged = False
        self._set_params(self.schedule(0))
        self._reset_output()
        self._y = self._y_clean.copy()
        dynamics.add_noise(self._y, self.noise_std, self._v.next())
        r = self._r(0)
        self._trace = {"y": [self._y.copy()], "r": [r], "u": []}
        return np.concatenate((self._y, r)), self._info()

    def _action(self, action: ArrayLike) -> NDArray:
        u = real_array(action, "action")
        if u.size != self.n_inputs or u.ndim > 1 and u.shape != (self.n_inputs,):
            raise ValueError(
                f"action must have shape ({self.n_inputs},) (a scalar is accepted when there is "
                f"one input), got shape {u.shape}"
            )
        u = np.ascontiguousarray(u.reshape(self.n_inputs))
        if not np.all(np.isfinite(u)):
            raise ValueError(f"action must be finite, got {u}")
        return u

    def step(self, action: ArrayLike) -> tuple[NDArray, float, bool, bool, dict[str, Any]]:
        """Apply ``u(k) = action`` (clipped to ``action_bound``) and advance to ``k + 1``.

        Parameters
        ----------
        action : array_like, shape (n_inputs,)
            ``u(k)``, finite real numbers (a scalar when there is one input).

        Returns
        -------
        observation, reward, terminated, truncated, info
            ``[y(k+1), r(k+1)]``; ``-(||y_clean - r||^2 + rho ||u||^2)``; ``True`` when
            ``|y|`` left ``y_bound`` (``info["diverged"]``); always ``False`` (the time limit
            is the ``TimeLimit`` wrapper's); the true state ``x``, ``y_clean``, the parameters
            in force and ``t``.

        Raises
        ------
        ValueError
            A malformed action, before anything changes.
        RuntimeError
            ``step`` before ``reset``.
        """
        if not hasattr(self, "_v"):
            raise RuntimeError("call reset() before step()")
        u_raw = self._action(action)
        r = self._r(self.t + 1)  # a user reference may raise: before any state change
        z_w = self._w.next() if self.process_noise_std else _EMPTY
        z_v = self._v.next()
        reward, clipped, diverged = self._plant_step(u_raw, z_w, z_v, r)
        self._clipped, self._diverged = bool(clipped), bool(diverged)
        self.n_clipped += self._clipped
        self.t += 1
        if self.schedule.time_varying:
            self._set_params(self.schedule(self.t))
        y = self._y.copy()
        if self.render_mode is not None:
            self._trace["y"].append(y)
            self._trace["r"].append(r)
            self._trace["u"].append(self._u.copy())
        return np.concatenate((y, r)), float(reward), self._diverged, False, self._info()

    def render(self) -> NDArray | None:
        """A picture of the episode so far (``y``, ``r`` and ``u`` traces), needs matplotlib.

        Returns
        -------
        ndarray of uint8, shape (height, width, 3) or None
            The RGB image with ``render_mode="rgb_array"``; ``None`` (and a logged warning)
            without a render mode.
        """
        if self.render_mode is None:
            gym.logger.warn("render() called without render_mode='rgb_array'; returning None")
            return None
        from stcgym.envs.render import render_traces

        return render_traces(self._trace, title=type(self).__name__)


_LANE0 = np.zeros(1, dtype=np.int64)


class CanonicalPlantEnv(LinearPlantEnv):
    """SISO plant in a canonical form with parameters ``theta = [a1..an, b1..bn]``.

    The base of :class:`ObserverCanonicalEnv` (Ding & Ma 2014, eq. (1)-(5)) and
    :class:`ObservabilityCanonicalEnv` (eq. (146)-(147)), which fix ``form``; the matrices are
    :func:`~stcgym.envs.canonical.canonical_matrices` of the parameters in force.

    Parameters
    ----------
    plant : str or list of str, optional
        Catalogue name (see :mod:`stcgym.envs.catalogue`), or a list of names to draw one per
        episode (plant-family training; the names must share one order ``n``). Default
        ``"stable2"`` when neither ``plant`` nor ``a``/``b`` is given.
    a, b : array_like, shape (n,), optional
        Parameters of this env's canonical form (finite, equal lengths ``n``; both or neither,
        and not with ``plant``). In the observability form ``b`` holds Markov parameters;
        catalogue plants are converted automatically.
    noise_std : float, default 0.0
        Standard deviation of the white Gaussian output noise ``v`` (``>= 0``).
    process_noise_std : float, default 0.0
        Standard deviation of the white Gaussian process noise ``w`` (each state, ``>= 0``).
    action_bound : float, default 10.0
        Actions are clipped to ``[-action_bound, action_bound]`` (``> 0``).
    control_cost : float, default 0.01
        ``rho`` in the reward ``-((y - r)^2 + rho u^2)`` (``>= 0``).
    reference : reference spec, default "square"
        See :func:`stcgym.envs.signals.make_reference`; default a unit square wave of period 100.
    schedule : schedule spec, optional
        Parameter schedule acting on ``theta`` (this form's parameters): ``None``,
        :class:`~stcgym.envs.signals.Jumps`, :class:`~stcgym.envs.signals.Ramp`,
        :class:`~stcgym.envs.signals.RandomWalk` or ``{step: theta}``. Catalogue plants with a
        schedule of their own (``timevarying2``) use it unless one is given.
    y_bound : float, default 100.0
        Divergence bound on ``|y|`` (``> 0``; terminates the episode).
    initial_state : array_like, shape (n,), optional
        ``x(0)``; zero by default.
    render_mode : {None, "rgb_array"}, default None
        See :class:`LinearPlantEnv`.

    ``reset(options=...)`` also accepts ``"plant"`` (a catalogue name), ``"a"`` and ``"b"``, or
    ``"theta"`` to set this episode's parameters (of the env's order ``n``). ``info`` carries the
    true state ``"x"``, the noise-free output ``"y_clean"``, the true parameters in force
    ``"theta"`` (also ``"a"``, ``"b"``) and the step ``"t"``. ``env.unwrapped.plant`` is the
    current :class:`~stcgym.envs.catalogue.PlantSpec` (``None`` for user parameters).

    Raises
    ------
    ValueError
        ``plant`` with ``a``/``b``; ``a`` without ``b``; an unknown catalogue name; a family of
        plants of different orders; ``a``, ``b`` empty, not finite or of unequal lengths; any
        value :class:`LinearPlantEnv` rejects.
    TypeError
        ``plant`` neither a name nor a list of names; a value of the wrong kind.

    Examples
    --------
    A family of two catalogue plants, one drawn per episode from the reset's seed:

    >>> import gymnasium as gym
    >>> import stcgym.envs
    >>> env = gym.make("stcgym/ObserverCanonical-v0", plant=["stable2", "unstable2"])
    >>> [env.reset(seed=seed)[1]["theta"].tolist() for seed in (0, 1)]
    [[-1.5, 0.7, 1.0, 0.5], [-1.7, 0.66, 0.5, 0.3]]
    >>> env.unwrapped.plant.name
    'unstable2'

    Parameters of your own, and a change of plant for one episode:

    >>> env = gym.make("stcgym/ObserverCanonical-v0", a=[-0.9], b=[1.0])
    >>> env.reset(seed=0, options={"theta": [-0.5, 2.0]})[1]["theta"]
    array([-0.5,  2. ])
    """

    form = "observer"
    reset_options = LinearPlantEnv.reset_options | {"plant", "a", "b", "theta"}

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
        self.form_code = dynamics.FORM_CODES[self.form]
        if plant is not None and (a is not None or b is not None):
            raise ValueError("give either plant (a catalogue name) or a and b, not both")
        if (a is None) != (b is None):
            raise ValueError("a and b must be given together (theta = [a; b])")
        if a is not None:
            self.family: list[PlantSpec] = []
            self.user_theta = np.concatenate(check_ab(a, b))
        else:
            if plant is None:
                names: list[Any] = ["stable2"]
            elif isinstance(plant, str):
                names = [plant]
            elif isinstance(plant, (list, tuple)):
                names = list(plant)
            else:
                raise TypeError(f"plant must be a catalogue name or a list of names, got {plant!r}")
            if len(names) == 0:
                raise ValueError("plant must be a catalogue name or a non-empty list of names")
            self.family = [get_plant(name) for name in names]
            if len({spec.n for spec in self.family}) > 1:
                raise ValueError(
                    f"plant family must share one order n, got {[s.name for s in self.family]}"
                )
            self.user_theta = None
        self.has_user_schedule = schedule is not None
        self.plant: PlantSpec | None = None if self.family == [] else self.family[0]
        n = self.family[0].n if self.family else self.user_theta.size // 2
        super().__init__(n_states=n, n_inputs=1, n_outputs=1, schedule=schedule, **kwargs)
        # The constructor's plant is in force until the first reset (A, B, C, D, theta exist).
        self._set_params(self.theta_of(self.plant) if self.plant else self.user_theta)

    # -------------------------------------------------------------- parameters
    def theta_of(self, spec: PlantSpec) -> NDArray:
        """``theta = [a; b]`` of a catalogue plant in this env's canonical form.

        Parameters
        ----------
        spec : PlantSpec
            A catalogue plant (observer-form ``a``, ``b``).

        Returns
        -------
        ndarray, shape (2n,)
            ``[a; b]`` with ``b`` converted to Markov parameters in the observability form
            (:func:`~stcgym.envs.canonical.observer_to_observability_b`).

        Examples
        --------
        >>> import gymnasium as gym
        >>> import stcgym.envs
        >>> from stcgym.envs import get_plant
        >>> env = gym.make("stcgym/ObservabilityCanonical-v0")
        >>> env.unwrapped.theta_of(get_plant("stable2"))
        array([-1.5,  0.7,  1. ,  2. ])
        """
        a, b = np.array(spec.a), np.array(spec.b)
        if self.form == "observability":
            b = observer_to_observability_b(a, b)
        return np.concatenate((a, b))

    def catalogue_schedule(self, spec: PlantSpec) -> Schedule | None:
        """A fresh copy of a catalogue plant's own parameter schedule in this env's form.

        Parameters
        ----------
        spec : PlantSpec
            A catalogue plant.

        Returns
        -------
        Schedule or None
            The plant's schedule with its parameter arrays in this env's form (a
            :class:`~stcgym.envs.signals.Jumps` is converted to Markov parameters in the
            observability form); ``None`` for a time-invariant plant.

        Examples
        --------
        >>> import gymnasium as gym
        >>> import stcgym.envs
        >>> from stcgym.envs import get_plant
        >>> env = gym.make("stcgym/ObserverCanonical-v0")
        >>> env.unwrapped.catalogue_schedule(get_plant("timevarying2"))
        Jumps(changes=[(1000, array([-1.2 ,  0.52,  0.9 ,  0.3 ]))])
        >>> env.unwrapped.catalogue_schedule(get_plant("stable2")) is None
        True
        """
        if spec.schedule is None:
            return None
        sched = spec.schedule()
        if self.form == "observability" and isinstance(sched, Jumps):
            sched = Jumps([(k, self.theta_of(_spec_from_theta(v))) for k, v in sched.changes])
        return sched

    def _parse_options(self, options: dict[str, Any]) -> tuple[NDArray | None, PlantSpec | None]:
        theta, spec = None, None
        if ("a" in options) != ("b" in options):
            raise ValueError("options 'a' and 'b' must be given together (theta = [a; b])")
        if "theta" in options:
            theta = np.concatenate(split_theta(options["theta"]))
        elif "a" in options or "b" in options:
            theta = np.concatenate(check_ab(options.get("a"), options.get("b")))
        elif "plant" in options:
            spec = get_plant(options["plant"])
            theta = self.theta_of(spec)
        if theta is not None and theta.size != 2 * self.n_states:
            raise ValueError(
                f"episode parameters must have order n={self.n_states} like the env "
                f"(theta of length {2 * self.n_states}), got length {theta.size}"
            )
        return theta, spec

    def _nominal_params(
        self, parsed: tuple[NDArray | None, PlantSpec | None], rng: np.random.Generator
    ) -> NDArray:
        theta, spec = parsed
        if theta is None:
            if self.family:
                spec = (
                    self.family[int(rng.integers(len(self.family)))]
                    if len(self.family) > 1
                    else self.family[0]
                )
                theta = self.theta_of(spec)
            else:
                theta = self.user_theta.copy()
        self.plant = spec
        if not self.has_user_schedule:
            self.schedule = (self.catalogue_schedule(spec) if spec else None) or make_schedule(None)
        return theta

    def _matrices(self, params: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        n = self.n_states
        return canonical_matrices(params[:n], params[n:], self.form)

    def _plant_step(
        self, u_raw: NDArray, z_w: NDArray, z_v: NDArray, r: NDArray
    ) -> tuple[float, bool, bool]:
        reward, clipped, diverged, u, y_clean, y = dynamics.canonical_plant_step(
            self._x, self.params, u_raw[0], self.action_bound, self.process_noise_std, z_w,
            self.noise_std, z_v[0], r[0], self.control_cost, self.y_bound, self.form_code,
        )  # fmt: skip
        self._u[0], self._y_clean[0], self._y[0] = u, y_clean, y
        return reward, clipped, diverged

    def _reset_output(self) -> None:
        self._y_clean[0] = dynamics.canonical_output(self._x)

    @property
    def a(self) -> NDArray:
        """The plant's ``[a1, ..., an]`` in force (a copy), eq. (1)-(5) or (146)-(147)."""
        return self.params[: self.n_states].copy()

    @property
    def b(self) -> NDArray:
        """The plant's ``[b1, ..., bn]`` in force (a copy): observer-form numerator
        coefficients, or Markov parameters in the observability form (146)-(147)."""
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
    """SISO plant in observer canonical form, Ding & Ma (2014) eq. (1)-(5).

    ``A`` has ``-a`` in its first column and ones on the superdiagonal, ``B = b``,
    ``C = [1, 0, ..., 0]``; transfer function ``(b1 z^{n-1} + ... + bn) / (z^n + a1 z^{n-1} + ...
    + an)``. See :class:`CanonicalPlantEnv` for the parameters, ``reset`` options and ``info``.
    Registered as ``stcgym/ObserverCanonical-v0``.

    Parameters
    ----------
    plant, a, b, schedule, **kwargs
        As :class:`CanonicalPlantEnv`; ``b`` holds the numerator coefficients.

    Raises
    ------
    ValueError, TypeError
        As :class:`CanonicalPlantEnv`.

    Examples
    --------
    >>> import gymnasium as gym
    >>> import numpy as np
    >>> import stcgym.envs
    >>> env = gym.make("stcgym/ObserverCanonical-v0", plant="unstable2")
    >>> env.observation_space, env.action_space
    (Box(-inf, inf, (2,), float64), Box(-10.0, 10.0, (1,), float64))
    >>> obs, info = env.reset(seed=0)
    >>> obs  # [y(0), r(0)]: zero state, square-wave reference
    array([0., 1.])
    >>> obs, reward, terminated, truncated, info = env.step(np.array([1.0]))
    >>> obs, round(reward, 6), terminated, truncated  # y(1) = b1 u(0); -((y - r)^2 + 0.01 u^2)
    (array([0.5, 1. ]), -0.26, False, False)
    >>> info["theta"], info["x"]
    (array([-1.7 ,  0.66,  0.5 ,  0.3 ]), array([0.5, 0.3]))
    """

    form = "observer"


class ObservabilityCanonicalEnv(CanonicalPlantEnv):
    """SISO plant in observability canonical form, Ding & Ma (2014) eq. (146)-(147).

    ``A`` is a shift with last row ``[-a_n, ..., -a_1]``, ``B = b`` (the first ``n`` Markov
    parameters), ``C = [1, 0, ..., 0]``. See :class:`CanonicalPlantEnv` for the parameters,
    ``reset`` options and ``info``. Registered as ``stcgym/ObservabilityCanonical-v0``.

    Parameters
    ----------
    plant, a, b, schedule, **kwargs
        As :class:`CanonicalPlantEnv`; ``b`` holds the Markov parameters ``h_1..h_n`` (a
        catalogue ``plant`` is converted).

    Raises
    ------
    ValueError, TypeError
        As :class:`CanonicalPlantEnv`.

    Examples
    --------
    A catalogue name gives the same transfer function in both forms: ``b`` becomes the Markov
    parameters, and the outputs agree.

    >>> import gymnasium as gym
    >>> import numpy as np
    >>> import stcgym.envs
    >>> env = gym.make("stcgym/ObservabilityCanonical-v0", plant="stable2", reference="zero")
    >>> twin = gym.make("stcgym/ObserverCanonical-v0", plant="stable2", reference="zero")
    >>> env.unwrapped.b, twin.unwrapped.b
    (array([1., 2.]), array([1. , 0.5]))
    >>> _, _ = env.reset(seed=0), twin.reset(seed=0)
    >>> y, y_twin = [], []
    >>> for u in (1.0, 0.0, -1.0, 0.5):
    ...     y.append(env.step(np.array([u]))[0][0])
    ...     y_twin.append(twin.step(np.array([u]))[0][0])
    >>> np.round(y, 6), bool(np.allclose(y, y_twin))
    (array([1.  , 2.  , 1.3 , 0.55]), True)
    """

    form = "observability"


class StateSpaceEnv(LinearPlantEnv):
    """MIMO discrete plant ``x(k+1) = A x + B u + w``, ``y = C x + D u + v``.

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
    **kwargs
        Other keyword arguments as in :class:`LinearPlantEnv`; ``reference`` may be one spec
        for every output or a list with one per output.

    ``reset(options=...)`` accepts ``"A"`` and ``"B"`` to override this episode's matrices.
    ``info`` carries ``"x"``, ``"y_clean"``, ``"params"`` (``[A B]`` in force) and ``"t"``.
    ``env.unwrapped.sys`` is the discrete python-control system of the nominal plant (built on
    request: the env itself holds only arrays, so it pickles). Registered as
    ``stcgym/StateSpace-v0``.

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
        super().__init__(n_states=n, n_inputs=m, n_outputs=self.C.shape[0], **kwargs)
        self._set_params(np.hstack((self.A_nominal, self.B_nominal)))

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
        return dynamics.state_space_plant_step(
            self._x, self.params, self.C, self.D, u_raw, self.action_bound,
            self.process_noise_std, z_w, self.noise_std, z_v, r, self.control_cost,
            self.y_bound, self._u, self._y_clean, self._y, self._tmp,
        )  # fmt: skip

    def _reset_output(self) -> None:
        dynamics.state_output(self._x, self.C, self._y_clean)

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
    seed's worked example. ``schedule`` acts on ``Theta``; ``reset(options={"theta": ...})``
    overrides it for one episode. The reward tracks the vector reference. Registered as
    ``stcgym/MultichannelStatic-v0`` (no vector env).

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

    ``info`` carries ``"theta"`` (``Theta`` in force), ``"y_clean"``, ``"t"`` and an empty
    ``"x"``.

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
        if "process_noise_std" in kwargs or "initial_state" in kwargs:
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
