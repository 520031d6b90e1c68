"""What an RL agent observes besides its window, and how its action becomes the plant input.

Every agent of the bench sees the window of :class:`~stcgym.agents.rl.wrappers.HistoryBuffer`
(past outputs, references, inputs, errors and the integral of the tracking error). An
:class:`InterfaceSpec` adds what a classical part running on the same data knows:

``"window"`` (:class:`WindowInterface`)
    The window alone; the action ``a`` in ``[-L, L]`` is the input ``u = a s``, with ``s`` the
    action unit and ``L = u_max / s`` (default ``s = u_max``: ``a`` in ``[-1, 1]``).
``"estimate"`` (:class:`EstimateInterface`): the estimate-conditioned agent
    The window, then the online estimate of an estimator running on the same ``y(t)`` and
    applied ``u(t)``, batched over the lanes::

        [ window | theta_hat(t) (2n) | log10 diag P(t) (2n) | e(t) / y_scale ]

    ``theta_hat(t)`` after the measurement update with ``y(t)`` (eq. (32)-(36) of Ding & Ma
    (2014) for RLS), ``P(t)`` its covariance, ``e(t) = y(t) - phi_hat(t)^T theta_hat(t-1)``
    the innovation: identification is the estimator's, control is learned (the universal
    policy with online system identification of Yu et al., RSS 2017). ``estimator`` is

    * one of the paper's recursive estimators, run standalone
      (:func:`stcgym.adaptive.make_estimator`, :class:`EstimateInterface`) with the settings
      the self-tuning controller gives it in closed loop
      (:class:`~stcgym.adaptive.EstimatorOptions`); the default ``O-RLS``: the
      measurement-corrected regressor ``"filtered"``, the output injection ``injection``
      after ``injection_warmup`` steps, ``P(0) = 300 I``, ``theta_hat(0) = 0``, no
      forgetting. The ``KF-`` estimators take their process noise ``Q(t)`` from the
      controller at every step, so standalone they are another estimator than the
      controller's. These have no change detection (the controller's, not the
      estimator's): after a parameter jump the innovation is the agent's signal;
    * ``"ELS"``, the self-tuning controller's own extended least squares
      (:class:`ControllerEstimateInterface`): a :class:`~stcgym.adaptive.
      SelfTuningController` with its defaults runs beside the agent,
      :meth:`~stcgym.adaptive.SelfTuningController.propose` with each observation (its
      design, filter and law run too; their input is never applied) and ``commit`` with the
      input the agent applies; the features are its ``[a; b]`` of ``[a; b; c]``, their
      variances in its ``P`` (inflated by its change detection on an alarm) and its
      innovation.

    Measured on the benchmark family's test episodes (``benchmarks/estimate_choice.py``: 200
    plants, 1000 steps, both on the same data), ELS's estimate is the closer (or as close)
    from about step 50 on, whichever inputs the agent applies: the median relative error
    ``||theta_hat - theta|| / ||theta||`` at the last step, O-RLS against ELS, is 0.074 /
    0.042 under the self-tuning controller's inputs, 0.16 / 0.058 under LQG's, 0.093 / 0.047
    under white noise of a tenth of the action unit, 0.42 / 0.25 under a trained
    ``theta_ppo``'s, and 0.005 for both under white noise of a whole unit; in the first 10 to
    25 steps O-RLS is the closer (ELS fits the noise model ``c`` too). The table is in the
    RL-baselines page of the documentation.
``"true"`` (:class:`TrueParameterInterface`): the universal policy with the true parameters
    The window, then the true parameters of the lane's plant, ``[a_1 .. a_n | b_1 .. b_n]``
    (observer form, Ding & Ma (2014) eq. (1)-(5)), updated at a parameter jump: privileged
    information, the "universal policy" half of UP-OSI (Yu et al., RSS 2017) with the
    identification given. How far it stays from LQG is how far RL's design is from the
    optimal controller when identification is free. Training reads the parameters from the
    vector env; evaluation is told them (the plants the lanes start on, and
    ``SB3Policy.set_model`` at a jump, as the known-model oracles are).
``"residual"`` (:class:`ResidualInterface`): residual RL on the self-tuning controller
    A :class:`~stcgym.adaptive.SelfTuningController` with its defaults, told the order ``n``,
    runs on the same observations; the agent sees the window and the controller's input
    ``u_stc(t) / u_max`` and its action ``a`` is a bounded correction::

        u(t) = clip(u_stc(t) + s a(t), -u_max, u_max),   |a(t)| <= fraction * u_max / s

    (default ``s = fraction * u_max``: ``a`` in ``[-1, 1]``)

    (Johannink et al., ICRA 2019; Silver et al., 2018). The policy's mean action starts at
    exactly zero (:func:`stcgym.agents.rl.sb3.build_model` zeroes its last layer), so the
    deterministic agent starts as the controller. The controller identifies from the input
    the plant is given, correction included (:meth:`~stcgym.adaptive.SelfTuningController.
    propose` chooses ``u_stc(t)``, :meth:`~stcgym.adaptive.SelfTuningController.commit` hands
    it the applied ``u(t)``), so the correction never biases its estimate. Lane
    ``i`` seeds the controller's probe with ``seeds[i]``; the bench passes
    :func:`~stcgym.agents.controllers.controller_seeds` of the episode seeds and the training
    run, the seeds its ``stc`` rows use, so a zero residual reproduces them exactly.

**The action unit** ``s`` (``action_unit``) is the input one unit of the action stands for.
Stable-Baselines3's Gaussian policies (PPO, A2C, RecurrentPPO) start with a mean action near 0
and an exploration noise set in action units, and their optimiser moves the mean by steps of
about the learning rate in the same units; where the useful inputs are a small fraction of
the bound (on the benchmark family the LQG controller's median input is 1 % of it) each step
of the mean is a large input and the policy gets worse as it trains (measured: PPO on
``stable2`` with the bound 27 instead of 2.9, 7.2x LQG after 1.5e5 steps instead of 1.8x;
with the bound 27 and a unit of 2.9, 2.2x). A unit of the typical input, with the box widened
to keep the whole bound reachable, is the usual normalisation of RL actions without taking
authority from the agent. The bench sets it from the LQG controller's inputs on the training
episodes (``"lqg"``: :func:`stcgym.agents.evaluation.bounds.lqg_action_unit`). Squashed
policies (SAC's) span their box whatever its width, so a unit would change nothing for them.

One object serves training (:class:`~stcgym.agents.rl.vec_env.VecHistoryWindow`, over the lanes
of a vector env) and evaluation (:class:`~stcgym.agents.rl.policy.SB3Policy`, from raw ``[y, r]``
observations), so the two build the same features: per step, :meth:`WindowInterface.observe`
takes the observation of every lane (``starts`` marks the lanes whose episode starts with it),
:meth:`~WindowInterface.features` gives the network input and :meth:`~WindowInterface.to_input`
turns the network's action into the input applied (and records it).
"""

from __future__ import annotations

import copy
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.agents.rl.estimate_interfaces import (
    ControllerEstimateInterface,
    EstimateInterface,
)
from stcgym.agents.rl.window_interface import WindowInterface
from stcgym.agents.rl.wrappers import WindowConfig
from stcgym.lanes.validation import positive

__all__ = [
    "ESTIMATORS",
    "KINDS",
    "MEASURED_UNIT",
    "ControllerEstimateInterface",
    "EstimateInterface",
    "InterfaceSpec",
    "ResidualInterface",
    "TrueParameterInterface",
    "WindowInterface",
]

#: Interface kinds (see the module docstring).
KINDS = ("window", "estimate", "residual", "true")
#: ``action_unit`` value that asks the bench to measure the unit (module docstring).
MEASURED_UNIT = "lqg"
#: Estimators of the estimate-conditioned agents: the paper's least-squares rules that hold a
#: closed loop with the self-tuning controller's settings (its warning names the others), run
#: standalone, and ``"ELS"``, the self-tuning controller's own extended least squares.
ESTIMATORS = ("O-RLS", "O-MILS", "KF-RLS", "KF-MILS", "ELS")


@dataclass(frozen=True)
class InterfaceSpec:
    """The interface of an agent (JSON-able; ``AlgoConfig.interface`` holds its fields).

    Parameters
    ----------
    kind : {"window", "estimate", "residual", "true"}
        See the module docstring.
    estimator : str, default "O-RLS"
        ``"estimate"``: one of :data:`ESTIMATORS` (case-insensitive): a paper estimator run
        standalone with the self-tuning controller's closed-loop settings for it, or
        ``"ELS"``, the extended least squares inside a self-tuning controller
        (:class:`ControllerEstimateInterface`).
    log_p, innovation : bool, default True
        ``"estimate"``: append ``log10 diag P(t)`` and the innovation ``e(t)``.
    fraction : float, default 0.25
        ``"residual"``: the bound of the correction as a fraction of the action bound, in
        ``[0, 1]`` (0: the controller alone).
    order : int or None
        The plant order ``n`` the estimator or controller is told (the training
        distribution's; set by :func:`~stcgym.agents.rl.sb3.train_agent`).
    run : int, default 0
        The training run (its seed): with the episode seeds it gives the controller seeds.
    action_unit : float, "lqg" or None, default None
        The input one unit of the action stands for (module docstring); ``None``: the action
        bound (``"residual"``: ``fraction`` times it), so the action box is ``[-1, 1]``.
        ``"lqg"`` asks the bench (or :func:`~stcgym.agents.rl.sb3.train_agent`) to set it
        from the LQG controller's inputs on the training episodes; an interface is built only
        with a number or ``None``.

    Raises
    ------
    ValueError
        On construction, naming the field out of range.

    Examples
    --------
    >>> from stcgym.agents.rl.interfaces import InterfaceSpec
    >>> from stcgym.agents import WindowConfig
    >>> spec = InterfaceSpec("estimate", order=2)
    >>> spec.n_features(WindowConfig(window=3))  # 13 window values, 4 + 4 + 1 of the estimate
    22
    >>> InterfaceSpec("residual", fraction=1.5)
    Traceback (most recent call last):
    ...
    ValueError: interface.fraction must be a number in [0, 1], got 1.5
    """

    kind: str = "window"
    estimator: str = "O-RLS"
    log_p: bool = True
    innovation: bool = True
    fraction: float = 0.25
    order: int | None = None
    run: int = 0
    action_unit: float | str | None = None

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"interface.kind must be one of {KINDS}, got {self.kind!r}")
        name = str(self.estimator).upper()
        if name not in ESTIMATORS:
            raise ValueError(
                f"interface.estimator must be one of {ESTIMATORS}, got {self.estimator!r}"
            )
        object.__setattr__(self, "estimator", name)
        for key in ("log_p", "innovation"):
            if not isinstance(getattr(self, key), bool):
                raise ValueError(f"interface.{key} must be True or False")
        f = self.fraction
        if isinstance(f, bool) or not isinstance(f, (int, float)) or not 0 <= f <= 1:
            raise ValueError(f"interface.fraction must be a number in [0, 1], got {f!r}")
        n = self.order
        if n is not None and (isinstance(n, bool) or not isinstance(n, int) or n < 1):
            raise ValueError(f"interface.order must be None or an integer >= 1, got {n!r}")
        if isinstance(self.run, bool) or not isinstance(self.run, int):
            raise ValueError(f"interface.run must be an integer, got {self.run!r}")
        s = self.action_unit
        if s is not None and s != MEASURED_UNIT:
            try:
                positive(s, "interface.action_unit")
            except (TypeError, ValueError):
                raise ValueError(
                    f"interface.action_unit must be a positive number, {MEASURED_UNIT!r} or "
                    f"None, got {s!r}"
                ) from None

    @classmethod
    def of(cls, data: dict[str, Any] | None, order: int | None = None, run: int = 0):
        """The spec of an ``AlgoConfig.interface`` dict (``{}``: the window alone), told the
        plant ``order`` and the training ``run``."""
        return cls(**{**(data or {}), "order": order, "run": int(run)})

    @property
    def extra_features(self) -> int:
        """Features after the window's."""
        if self.kind == "estimate":
            d = 2 * self._order()
            return d + (d if self.log_p else 0) + int(self.innovation)
        if self.kind == "true":
            return 2 * self._order()
        return 1 if self.kind == "residual" else 0

    def n_features(self, window: WindowConfig, channels: tuple[int, int] = (1, 1)) -> int:
        """Length of the observation with ``window`` on a plant of ``channels``."""
        return window.features_for(*channels) + self.extra_features

    def _order(self) -> int:
        if self.order is None:
            raise ValueError(f"the {self.kind!r} interface needs the plant order (order=n)")
        return self.order

    def build(
        self,
        window: WindowConfig,
        action_bound: float,
        batch: int = 1,
        channels: tuple[int, int] = (1, 1),
        seeds: ArrayLike | None = None,
    ) -> WindowInterface:
        """The interface for ``batch`` lanes; ``seeds``: the residual controller's seed per
        lane (default: :func:`~stcgym.agents.controllers.controller_seeds` of the lane
        indices and :attr:`run`).

        Raises
        ------
        ValueError
            ``action_unit`` still ``"lqg"`` (not measured yet), or a multichannel plant for an
            interface other than ``"window"``.
        """
        if self.action_unit == MEASURED_UNIT:
            raise ValueError(
                f"interface.action_unit {MEASURED_UNIT!r} is measured by the bench (from the LQG "
                "controller's inputs on the training episodes); give a number or None to build "
                "the interface outside it"
            )
        unit = self.action_unit
        if self.kind == "window":
            return WindowInterface(window, action_bound, batch, channels, action_unit=unit)
        if tuple(channels) != (1, 1):
            raise ValueError(f"the {self.kind!r} interface runs on SISO plants, got {channels}")
        if self.kind == "estimate" and self.estimator == "ELS":
            return ControllerEstimateInterface(window, action_bound, batch, self)
        if self.kind == "estimate":
            return EstimateInterface(window, action_bound, batch, self)
        if self.kind == "true":
            return TrueParameterInterface(window, action_bound, batch, self)
        if seeds is None:
            from stcgym.agents.controllers import controller_seeds

            seeds = controller_seeds(range(batch), self.run)
        return ResidualInterface(window, action_bound, batch, self, seeds)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> InterfaceSpec:
        return cls(**(data or {}))


class TrueParameterInterface(WindowInterface):
    """The window and the true parameters ``[a | b]`` of each lane's plant (module docstring):
    :meth:`set_model` tells them (zero until told).

    Examples
    --------
    >>> import numpy as np
    >>> from stcgym.agents import WindowConfig
    >>> from stcgym.agents.rl.interfaces import InterfaceSpec
    >>> lanes = InterfaceSpec("true", order=2).build(WindowConfig(window=2), 5.0, batch=2)
    >>> lanes.set_model(np.array([[-1.5, 0.7]]), np.array([[1.0, 0.5]]), lanes=[1])
    >>> lanes.observe(np.array([[0.1, 1.0], [0.2, 1.0]]), starts=np.ones(2, bool))
    >>> lanes.features()[:, -4:]
    array([[ 0. ,  0. ,  0. ,  0. ],
           [-1.5,  0.7,  1. ,  0.5]], dtype=float32)
    """

    def __init__(
        self, window: WindowConfig, action_bound: float, batch: int, spec: InterfaceSpec
    ) -> None:
        super().__init__(window, action_bound, batch, action_unit=spec.action_unit)
        self.spec = spec
        self.theta = np.zeros((self.batch, 2 * spec._order()))

    @property
    def n_features(self) -> int:
        return super().n_features + self.spec.extra_features

    def set_model(self, a: ArrayLike, b: ArrayLike, lanes: ArrayLike | None = None) -> None:
        """The true ``a``, ``b`` (one row per selected lane) of the lanes ``lanes`` (a boolean
        mask or indices; default all), as the known-model oracles are told them."""
        idx = np.arange(self.batch) if lanes is None else np.arange(self.batch)[lanes]
        n = self.spec._order()
        rows = np.concatenate([np.reshape(a, (idx.size, n)), np.reshape(b, (idx.size, n))], axis=1)
        self.theta[idx] = rows

    def terminal_features(self, last: NDArray, lanes: NDArray) -> NDArray:
        return self._with_extra(super().terminal_features(last, lanes), self.theta)

    def features(self) -> NDArray:
        return self._with_extra(super().features(), self.theta)


class ResidualInterface(WindowInterface):
    """The window and the self-tuning controller's input; the action a bounded correction of
    it (module docstring). ``controller`` is the :class:`~stcgym.adaptive.
    SelfTuningController` of the lanes (seeded ``seeds``).

    Examples
    --------
    With a zero action the input is the controller's:

    >>> import numpy as np
    >>> from stcgym.adaptive import SelfTuningController
    >>> from stcgym.agents import WindowConfig
    >>> from stcgym.agents.rl.interfaces import InterfaceSpec
    >>> lanes = InterfaceSpec("residual", order=2).build(WindowConfig(window=2), 5.0, 2,
    ...                                                  seeds=[7, 8])
    >>> alone = SelfTuningController(2, num_envs=2, action_bound=5.0, seed=[7, 8])
    >>> obs = np.array([[0.1, 1.0], [-0.3, 1.0]])
    >>> lanes.observe(obs, starts=np.ones(2, bool))
    >>> u = lanes.to_input(np.zeros((2, 1)))
    >>> alone.reset()
    >>> bool(np.array_equal(u, alone.predict(obs)[0]))
    True
    """

    def __init__(
        self,
        window: WindowConfig,
        action_bound: float,
        batch: int,
        spec: InterfaceSpec,
        seeds: ArrayLike,
    ) -> None:
        from stcgym.adaptive import SelfTuningController

        super().__init__(window, action_bound, batch)
        self.spec = spec
        # the correction's range fraction * u_max, in units of s (default: the range itself)
        span = spec.fraction * self.action_bound
        if spec.action_unit is None:
            self.action_unit, self.action_limit = span, 1.0
        else:
            self.action_unit = float(spec.action_unit)
            self.action_limit = span / self.action_unit
        self.seeds = [int(s) for s in seeds]
        self.controller = SelfTuningController(
            spec._order(), num_envs=self.batch, action_bound=self.action_bound, seed=self.seeds
        )
        self.u_base = np.zeros((self.batch, 1))

    @property
    def n_features(self) -> int:
        return super().n_features + 1

    def observe(self, obs: ArrayLike, starts: NDArray | None = None) -> None:
        super().observe(obs, starts)
        # the controller's sample stays open until to_input commits the input applied
        self.u_base = self.controller.propose(obs, episode_start=starts)

    def terminal_features(self, last: NDArray, lanes: NDArray) -> NDArray:
        window = super().terminal_features(last, lanes)
        ahead = copy.deepcopy(self.controller)  # the lanes restart: the real one stays
        return self._with_extra(window, ahead.predict(last)[0] / self.action_bound)

    def features(self) -> NDArray:
        return self._with_extra(super().features(), self.u_base / self.action_bound)

    def to_input(self, action: ArrayLike) -> NDArray:
        limit, bound = self.action_limit, self.action_bound
        a = np.clip(np.asarray(action, dtype=float).reshape(self.batch, 1), -limit, limit)
        u = np.clip(self.u_base + self.action_unit * a, -bound, bound)
        # the controller's estimator and filter get the input the plant gets, correction and
        # all: a correction they did not see would be an input disturbance to them
        self.controller.commit(u)
        return self._record(u)
