"""The SISO canonical-form plants: the observer form, eq. (1)-(5), and the observability form,
eq. (146)-(147), of Ding & Ma (2014), on the common
:class:`~stcgym.envs.linear_plant.LinearPlantEnv` (timing, reward, termination, randomness: see
:mod:`stcgym.envs.linear_plant`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
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
from stcgym.envs.linear_plant import LinearPlantEnv
from stcgym.envs.signals import Jumps, RandomJump, Schedule, make_schedule

__all__ = ["CanonicalPlantEnv", "ObservabilityCanonicalEnv", "ObserverCanonicalEnv"]


class CanonicalPlantEnv(LinearPlantEnv):
    """SISO plant in a canonical form with parameters ``theta = [a1..an, b1..bn]``.

    The base of :class:`ObserverCanonicalEnv` (Ding & Ma 2014, eq. (1)-(5)) and
    :class:`ObservabilityCanonicalEnv` (eq. (146)-(147)), which fix ``form``; the matrices are
    :func:`~stcgym.envs.canonical.canonical_matrices` of the parameters in force.

    ``reset(options=...)`` also accepts ``"plant"`` (the name of one of this env's plants, a
    catalogue name or a ``PlantSpec``), ``"a"`` and ``"b"``, or ``"theta"`` to set this
    episode's parameters (of the env's order ``n``). ``info`` carries the
    true state ``"x"``, the noise-free output ``"y_clean"``, the true parameters in force
    ``"theta"`` (also ``"a"``, ``"b"``) and the step ``"t"``. ``env.unwrapped.plant`` is the
    current :class:`~stcgym.envs.catalogue.PlantSpec` (``None`` for user parameters).

    Parameters
    ----------
    plant : str, PlantSpec or list of them, optional
        Catalogue name (see :mod:`stcgym.envs.catalogue`) or a
        :class:`~stcgym.envs.catalogue.PlantSpec` of your own, or a list of them to draw one
        per episode (plant-family training; one order ``n``, one plant per name). Default
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
    initial_state_std : float, default 0.0
        ``> 0``: ``x(0) ~ N(0, std^2 I)`` each episode (see :class:`LinearPlantEnv`).
    render_mode : {None, "rgb_array"}, default None
        See :class:`LinearPlantEnv`.

    Raises
    ------
    ValueError
        ``plant`` with ``a``/``b``; ``a`` without ``b``; an unknown catalogue name; a family of
        plants of different orders or two plants of one name; ``a``, ``b`` empty, not finite
        or of unequal lengths; any value :class:`LinearPlantEnv` rejects.
    TypeError
        ``plant`` neither a name, a ``PlantSpec`` nor a list of them; a value of the wrong
        kind.

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
        plant: str | PlantSpec | Sequence[str | PlantSpec] | None = None,
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
            self.members: list[PlantSpec] = []
            self.user_theta = np.concatenate(check_ab(a, b))
        else:
            if plant is None:
                entries: list[Any] = ["stable2"]
            elif isinstance(plant, (str, PlantSpec)):
                entries = [plant]
            elif isinstance(plant, (list, tuple)):
                entries = list(plant)
            else:
                raise TypeError(
                    f"plant must be a catalogue name, a PlantSpec or a list of them, got {plant!r}"
                )
            if len(entries) == 0:
                raise ValueError("plant must be a catalogue name, a PlantSpec or a non-empty list")
            self.members = [_plant_spec(entry, "plant") for entry in entries]
            if len({spec.n for spec in self.members}) > 1:
                raise ValueError(
                    f"plant family must share one order n, got {[s.name for s in self.members]}"
                )
            self.user_theta = None
        # One plant per name, so that reset(options={"plant": name}) is unambiguous.
        self._member_index: dict[str, int] = {}
        for j, spec in enumerate(self.members):
            first = self._member_index.setdefault(spec.name, j)
            if self.members[first] != spec:
                raise ValueError(f"plant: two different plants are named {spec.name!r}")
        self.has_user_schedule = schedule is not None
        self.plant: PlantSpec | None = None if self.members == [] else self.members[0]
        n = self.members[0].n if self.members else self.user_theta.size // 2
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
        elif self.form == "observability" and isinstance(sched, RandomJump):
            after = self.theta_of(_spec_from_theta(sched.after))
            sched = RandomJump(after, sched.at, sched.probability)
        return sched

    def _find_plant(self, plant: Any, name: str = "options['plant']") -> PlantSpec:
        """A plant given by name (this env's own plants first, then the catalogue) or as a
        ``PlantSpec``; ``ValueError``/``TypeError`` naming ``name`` otherwise."""
        if isinstance(plant, str) and plant in self._member_index:
            return self.members[self._member_index[plant]]
        try:
            return _plant_spec(plant, name)
        except ValueError as exc:
            if not self.members:
                raise
            raise ValueError(
                f"{name} must name one of this env's {len(self.members)} plants (e.g. "
                f"{self.members[0].name!r}) or a catalogue plant: {exc}"
            ) from exc

    def _parse_options(self, options: dict[str, Any]) -> tuple[NDArray | None, PlantSpec | None]:
        theta, spec = None, None
        if ("a" in options) != ("b" in options):
            raise ValueError("options 'a' and 'b' must be given together (theta = [a; b])")
        if "theta" in options:
            theta = np.concatenate(split_theta(options["theta"]))
        elif "a" in options or "b" in options:
            theta = np.concatenate(check_ab(options.get("a"), options.get("b")))
        elif "plant" in options:
            spec = self._find_plant(options["plant"])
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
            if self.members:
                spec = (
                    self.members[int(rng.integers(len(self.members)))]
                    if len(self.members) > 1
                    else self.members[0]
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


def _plant_spec(plant: Any, name: str) -> PlantSpec:
    """A catalogue plant by name, or a ``PlantSpec`` of finite ``a``, ``b`` of one length."""
    if isinstance(plant, PlantSpec):
        check_ab(plant.a, plant.b)
        return plant
    if isinstance(plant, str):
        return get_plant(plant)
    raise TypeError(f"{name} must be a plant name or a PlantSpec, got {plant!r}")


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
    >>> # y(1) = b1 u(0); reward -((y - r)^2 + 0.01 u^2)
    >>> obs, round(reward, 6), terminated, truncated
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
    >>> kwargs = dict(plant="stable2", reference="zero")
    >>> env = gym.make("stcgym/ObservabilityCanonical-v0", **kwargs)
    >>> twin = gym.make("stcgym/ObserverCanonical-v0", **kwargs)
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
