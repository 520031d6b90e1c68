"""The estimate-conditioned interfaces: the window and an online estimate's ``theta_hat``,
``log10 diag P`` and innovation, from one of the paper's estimators run standalone
(:class:`EstimateInterface`) or from the self-tuning controller's own extended least squares
(:class:`ControllerEstimateInterface`); :mod:`stcgym.agents.rl.interfaces` says what each
gives and which is the closer estimate."""

from __future__ import annotations

import copy
import warnings
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.agents.rl.window_interface import WindowInterface
from stcgym.agents.rl.wrappers import WindowConfig

if TYPE_CHECKING:
    from stcgym.agents.rl.interfaces import InterfaceSpec

__all__ = [
    "ControllerEstimateInterface",
    "EstimateInterface",
    "closed_loop_estimator",
    "estimate_features",
]


class _EstimateFeatures(WindowInterface):
    """The window and an online estimate's ``theta_hat``, ``log10 diag P`` and innovation: the
    machinery the two estimate interfaces share. A subclass says what makes the estimate
    (:meth:`_new_source`), its measurement step with ``y(t)`` (:meth:`_measure`), its step with
    the input applied (:meth:`_apply`) and the features it gives (:meth:`_estimate`)."""

    def __init__(
        self, window: WindowConfig, action_bound: float, batch: int, spec: InterfaceSpec
    ) -> None:
        super().__init__(window, action_bound, batch, action_unit=spec.action_unit)
        self.spec = spec
        self._source = self._new_source()

    def _new_source(self) -> Any:
        raise NotImplementedError

    def _measure(self, source: Any, obs: ArrayLike, starts: NDArray | None) -> None:
        raise NotImplementedError

    def _apply(self, u: NDArray) -> None:
        raise NotImplementedError

    def _estimate(self, source: Any) -> NDArray:
        raise NotImplementedError

    @property
    def n_features(self) -> int:
        return super().n_features + self.spec.extra_features

    @property
    def theta_hat(self) -> NDArray:
        """The estimate among the features, ``[a | b]`` of every lane, ``(B, 2n)``."""
        return self._source.theta

    def observe(self, obs: ArrayLike, starts: NDArray | None = None) -> None:
        super().observe(obs, starts)
        self._measure(self._source, obs, starts)

    def terminal_features(self, last: NDArray, lanes: NDArray) -> NDArray:
        window = super().terminal_features(last, lanes)
        ahead = copy.deepcopy(self._source)  # the lanes restart: the real one stays
        self._measure(ahead, last, None)
        return self._with_extra(window, self._estimate(ahead))

    def features(self) -> NDArray:
        return self._with_extra(super().features(), self._estimate(self._source))

    def to_input(self, action: ArrayLike) -> NDArray:
        u = super().to_input(action)
        self._apply(u)
        return u


class EstimateInterface(_EstimateFeatures):
    """The window and an estimator's ``theta_hat``, ``log10 diag P`` and innovation (module
    docstring), the estimator batched over the lanes.

    Examples
    --------
    The estimate in the features is the estimator's own, run on the same data:

    >>> import numpy as np
    >>> from stcgym.agents import WindowConfig
    >>> from stcgym.agents.rl.interfaces import InterfaceSpec
    >>> spec = InterfaceSpec("estimate", order=2)
    >>> lanes = spec.build(WindowConfig(window=2), action_bound=5.0, batch=3)
    >>> lanes.observe(np.array([[0.1, 1.0]] * 3), starts=np.ones(3, bool))
    >>> u = lanes.to_input(np.array([[0.2], [0.0], [-0.4]]))
    >>> lanes.observe(np.array([[0.3, 1.0], [0.0, 1.0], [-0.2, 1.0]]))
    >>> f = lanes.features()
    >>> f.shape, bool(np.allclose(f[:, 9:13], lanes.estimator.theta.astype(np.float32)))
    ((3, 18), True)
    """

    def _new_source(self) -> Any:
        return closed_loop_estimator(self.spec.estimator, self.spec._order(), self.batch)

    @property
    def estimator(self) -> Any:
        """The estimator (read-only use)."""
        return self._source

    def _measure(self, estimator: Any, obs: ArrayLike, starts: NDArray | None) -> None:
        if starts is not None and starts.any():
            estimator.reset(lanes=starts)
        y = np.asarray(obs, dtype=float).reshape(self.batch, 2)[:, 0]
        with warnings.catch_warnings():  # its health events: documented safe actions
            warnings.simplefilter("ignore")
            estimator.update(y)

    def _apply(self, u: NDArray) -> None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            self._source.predict(u[:, 0])

    def _estimate(self, estimator: Any) -> NDArray:
        return estimate_features(self.spec, self.window, estimator.theta, estimator.S, estimator.e)


class ControllerEstimateInterface(_EstimateFeatures):
    """The window and the self-tuning controller's own estimate (``estimator="ELS"``, module
    docstring): ``theta_hat``, ``log10 diag P`` and the innovation of the extended least squares
    inside ``controller``, a :class:`~stcgym.adaptive.SelfTuningController` with its defaults
    for the lanes, told the input applied.

    Each step :meth:`observe` runs the controller's
    :meth:`~stcgym.adaptive.SelfTuningController.propose` (the estimator's measurement step
    with ``y(t)``; the design, filter and law too, whose proposal is not applied) and
    :meth:`to_input` its :meth:`~stcgym.adaptive.SelfTuningController.commit` with the input
    the agent applies. The controller's seed only signs its start-up probe, which is never
    applied here, so the estimate does not depend on it.

    Examples
    --------
    The estimate in the features is that of a controller told the same inputs:

    >>> import numpy as np
    >>> from stcgym.adaptive import SelfTuningController
    >>> from stcgym.agents import WindowConfig
    >>> from stcgym.agents.rl.interfaces import InterfaceSpec
    >>> spec = InterfaceSpec("estimate", estimator="ELS", order=2)
    >>> lanes = spec.build(WindowConfig(window=2), action_bound=5.0, batch=2)
    >>> alone = SelfTuningController(2, num_envs=2, action_bound=5.0)
    >>> for k, y in enumerate([0.1, 0.4, -0.2]):
    ...     obs = np.array([[y, 1.0], [-y, 1.0]])
    ...     lanes.observe(obs, starts=np.ones(2, bool) if k == 0 else None)
    ...     _ = alone.propose(obs, episode_start=k == 0)
    ...     alone.commit(lanes.to_input(np.array([[0.2], [-0.3]])))
    >>> lanes.observe(np.array([[0.3, 1.0], [0.1, 1.0]]))
    >>> _ = alone.propose(np.array([[0.3, 1.0], [0.1, 1.0]]))
    >>> bool(np.array_equal(lanes.features()[:, 9:13], alone.theta.astype(np.float32)))
    True
    """

    def _new_source(self) -> Any:
        from stcgym.adaptive import SelfTuningController

        return SelfTuningController(
            self.spec._order(), num_envs=self.batch, action_bound=self.action_bound
        )

    @property
    def controller(self) -> Any:
        """The self-tuning controller whose estimate the features hold (read-only use)."""
        return self._source

    def _measure(self, controller: Any, obs: ArrayLike, starts: NDArray | None) -> None:
        # the sample stays open until to_input commits the input applied
        controller.propose(obs, episode_start=starts)

    def _apply(self, u: NDArray) -> None:
        # the estimator's regressor holds the input the plant got, not the controller's own
        self._source.commit(u)

    def _estimate(self, controller: Any) -> NDArray:
        state = controller.compiled_args
        d = 2 * self.spec._order()
        # the estimate is over [a; b; c]: the factor's rows of a and b give their variances
        S = state.est.S[:, :d]
        return estimate_features(self.spec, self.window, controller.theta, S, state.s.e)


def estimate_features(
    spec: InterfaceSpec, window: WindowConfig, theta: NDArray, S: NDArray, e: NDArray
) -> NDArray:
    """``[theta_hat | log10 diag P | e / y_scale]`` of every lane (the parts ``spec`` asks
    for), from ``theta_hat`` ``(B, 2n)``, the rows of ``[a; b]`` in the factor ``S`` of
    ``P = S S^T`` ``(B, 2n, d)`` and the innovation ``e`` ``(B,)``."""
    parts = [theta]
    if spec.log_p:  # diag P = row sums of S^2
        parts.append(np.log10(np.maximum(np.sum(S * S, axis=2), 1e-300)))
    if spec.innovation:
        parts.append(e[:, None] / window.y_scale)
    return np.concatenate(parts, axis=1)


def closed_loop_estimator(name: str, n: int, batch: int) -> Any:
    """The estimator ``name`` (one of :data:`~stcgym.agents.rl.interfaces.ESTIMATORS` but
    ``"ELS"``, which runs inside the controller: :class:`ControllerEstimateInterface`) for
    ``batch`` lanes with the settings
    :class:`~stcgym.adaptive.SelfTuningController` gives it in closed loop
    (:class:`~stcgym.adaptive.EstimatorOptions`'s defaults), ``theta_hat(0) = 0``."""
    from stcgym.adaptive import EstimatorOptions, make_estimator

    eo = EstimatorOptions()
    kw: dict[str, Any] = {
        "p0": eo.initial_covariance(name), "forgetting": eo.forgetting,
        "theta0": np.zeros(2 * n), "regressor": eo.regressor,
    }  # fmt: skip
    if name.endswith("MILS"):
        kw["p"] = eo.p
    if name.startswith("O-"):
        kw.update(injection=eo.injection, injection_warmup=eo.injection_warmup)
    else:
        kw.update(
            process_noise=eo.process_noise_floor * np.eye(n),
            measurement_noise=eo.kf_measurement_noise,
        )
    return make_estimator(name, n, num_envs=batch, **kw)
