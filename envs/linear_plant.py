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

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import ArrayLike, NDArray

from stcgym.envs import dynamics
from stcgym.envs.catalogue import PlantSpec
from stcgym.envs.signals import Reference, Schedule, make_references, make_schedule
from stcgym.lanes.validation import non_negative, positive, real_array

__all__ = ["LinearPlantEnv"]

_NOISE_BLOCK = 512  # standard normals drawn per refill: one generator call per 512 steps
_EMPTY = np.zeros(0)


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
    initial_state_std : float, default 0.0
        ``> 0``: each episode draws ``x(0) ~ N(0, std^2 I)`` (as the reset option of that name
        does, from the episode's draw stream) unless ``reset`` options say otherwise; not with
        ``initial_state``.
    render_mode : {None, "rgb_array"}, default None
        ``"rgb_array"``: :meth:`render` draws the episode's traces (needs matplotlib).
    n_references : int, optional
        Reference channels ``p_r`` (set by a subclass whose cost weighs a performance output;
        default ``n_outputs``): the observation is then ``[y(k), r(k)]`` of length
        ``p + p_r`` (or ``p`` plus what the subclass's :meth:`_observed_reference` makes of
        ``r(k)``).

    Raises
    ------
    ValueError
        A number out of range or not finite, an unknown ``render_mode``, an ``initial_state``
        of the wrong length or not finite, ``initial_state`` with ``initial_state_std > 0``, a
        reference or schedule spec that is rejected.
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
        initial_state_std: float = 0.0,
        render_mode: str | None = None,
        n_references: int | None = None,
    ) -> None:
        super().__init__()
        self.n_states, self.n_inputs, self.n_outputs = n_states, n_inputs, n_outputs
        self.n_references = n_outputs if n_references is None else int(n_references)
        self.noise_std = non_negative(noise_std, "noise_std")
        self.process_noise_std = non_negative(process_noise_std, "process_noise_std")
        self.control_cost = non_negative(control_cost, "control_cost")
        self.action_bound = positive(action_bound, "action_bound")
        self.y_bound = positive(y_bound, "y_bound")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self.reference: list[Reference] = make_references(reference, self.n_references)
        self.schedule: Schedule = make_schedule(schedule)
        self.initial_state = (
            None if initial_state is None else self._check_state(initial_state, "initial_state")
        )
        self.initial_state_std = non_negative(initial_state_std, "initial_state_std")
        if self.initial_state is not None and self.initial_state_std > 0:
            raise ValueError("give initial_state or initial_state_std > 0, not both")
        self.action_space = spaces.Box(
            -self.action_bound, self.action_bound, shape=(n_inputs,), dtype=np.float64
        )
        width = self._observed_reference(np.zeros((1, self.n_references))).shape[1]
        self.observation_space = spaces.Box(
            -np.inf, np.inf, shape=(n_outputs + width,), dtype=np.float64
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

    def _observed_reference(self, r: NDArray) -> NDArray:
        """What the observation carries of the references ``r`` (rows ``(lanes, p_r)``):
        ``r`` itself unless a subclass says otherwise."""
        return r

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
        elif self.initial_state_std > 0:
            self._x = self.initial_state_std * rng_draw.standard_normal(self.n_states)
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
        return np.concatenate((self._y, self._observed_reference(r[None])[0])), self._info()

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
        obs = np.concatenate((y, self._observed_reference(r[None])[0]))
        return obs, float(reward), self._diverged, False, self._info()

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
