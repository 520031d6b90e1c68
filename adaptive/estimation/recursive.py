"""Recursive (online) joint state and parameter estimators of Ding & Ma (2014), sections 1-3,
for either canonical form, for one plant or a batch of ``B`` plants.

:func:`make_estimator` (:mod:`stcgym.adaptive.estimation.factory`) maps each paper name
(``"O-SG"`` ... ``"KF-D-MILS"``, case-insensitive; ``"CO-..."`` for the closed-loop observer) to
one :class:`RecursiveEstimator`. There is one implementation: the lane functions of
:mod:`stcgym.adaptive.estimation.estimator` (parameter rules in
:mod:`~stcgym.adaptive.estimation.least_squares`, state estimators and regressors in
:mod:`~stcgym.adaptive.estimation.state_estimation`). The estimator's state is an
:class:`~stcgym.adaptive.estimation.estimator_spec.EstimatorState` of batched arrays, one row per
lane (``B = 1`` for a single plant); ``make_estimator(..., num_envs=B)`` returns the *same*
class stepping ``B`` lanes with a batch loop over the same lane function, so a single estimator
equals lane ``i`` of a batch bit for bit.

* parameter rule: SG (12)-(15), MISG (16)-(22), RLS (32)-(36), MILS (37)-(44), each optionally
  model-decomposed (``D-``: separate ``a`` and ``b`` sub-updates sharing one innovation,
  (96)-(145));
* state estimator: open-loop observer ``O`` (46)-(49), closed-loop observer with a user gain
  ``CO`` (50)-(53), Kalman filter ``KF`` (66)-(72);
* regressor per canonical form: observer form (9)/(57)
  ``phi_hat(t) = [-x1_hat(t-1), ..., -x1_hat(t-n), u(t-1), ..., u(t-n)]``; observability form
  (153) ``[-x_n_hat(t-n), ..., -x_1_hat(t-n), u(t-1), ..., u(t-n)]``.

Time convention (paper): ``t = 1, 2, ...``; every signal, state estimate and regressor is zero
for ``t <= 0``, also inside the stacked MISG/MILS windows. Defaults: ``theta_hat(0) = 1/p0``,
``P(0) = p0 I``, ``x_hat(1) = 1/p0``, ``P1(1) = I``, ``r(0) = 1``, ``p0 = 1e6``. One step
(O-RLS (54)-(62), KF-MILS (73)-(86)) is split in two so that a controller can act in between::

    theta = est.update(y_t)   # phi_hat(t), Phi(p, t), Y(p, t); theta_hat(t), P(t)
    u_t = controller(theta, est.x_hat)
    est.predict(u_t)          # A_hat(t), b_hat(t) from theta_hat(t); x_hat(t+1)

``update`` twice without ``predict`` (or ``predict`` first) raises :class:`RuntimeError`.
Batched: ``update(y (B,)) -> theta (B, 2n)``, ``predict(u (B,)) -> x_hat (B, n)``.

Numerical health and the "frozen on a wrong model" signal:
:mod:`stcgym.adaptive.estimation.health`; the
attributes and the warnings of a step:
:class:`~stcgym.adaptive.estimation.estimator_views.EstimatorViews`;
the measured behaviour of the paper's algorithms: the design notes of the documentation.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.estimation import estimator as _k
from stcgym.adaptive.estimation import estimator_lanes as _lanes
from stcgym.adaptive.estimation.estimator_spec import (
    EstimatorSpec,
    EstimatorState,
)
from stcgym.adaptive.estimation.estimator_views import EstimatorViews
from stcgym.adaptive.estimation.state_estimation import is_schur_stable as _schur_lane
from stcgym.envs.lanes import lane_rows, per_lane
from stcgym.lanes.compiled import FixedTypes, set_lanes
from stcgym.lanes.validation import (
    finite_vector,
    lane_indices,
    lane_vector,
    real_number,
    vector_pair,
)

__all__ = ["RecursiveEstimator", "is_schur_stable"]


def is_schur_stable(a: ArrayLike) -> bool:
    """True when ``z^n + a1 z^{n-1} + ... + an`` has all roots strictly inside the unit circle
    (Schur-Cohn step-down recursion; the lane function the estimator's projection uses)."""
    arr = np.asarray(a, dtype=float).reshape(-1)
    return bool(_schur_lane(arr, arr.size, np.empty(arr.size)))


# the steps of every lane (one for a single plant), their compiled version looked up once
_update_lanes = FixedTypes(_lanes.update_lanes)
_predict_lanes = FixedTypes(_lanes.predict_lanes)


def _scalar(value: Any, name: str) -> float:
    """A finite real scalar: a number, or a 0-d or one-element array of one (``y(t)``, ``u(t)``)."""
    kind = type(value)
    if kind is float and math.isfinite(value):  # every step's call: no more work than this
        return value
    if (kind is np.ndarray or kind is list or kind is tuple) and np.size(value) == 1:
        value = np.asarray(value).reshape(())
    return real_number(value, name)


class RecursiveEstimator(EstimatorViews):
    """Joint recursive parameter and state estimator for one plant or ``B`` plants.

    Build it with :func:`make_estimator`. For a single plant (``num_envs=None``) every array
    below has the shape given; a batch prepends the lane axis ``B`` (``theta`` ``(B, 2n)``,
    ``t`` ``(B,)``, ...). The attributes are read-only unless stated.

    Parameters
    ----------
    spec : EstimatorSpec
        The validated configuration (:func:`make_estimator` builds it from keywords).
    num_envs : int or None, default None
        Number of lanes ``B``; ``None``: one plant.
    lane_theta0 : ndarray, shape (B, 2n), optional
        Per-lane ``theta_hat(0)``, overriding the spec's.
    lane_P0 : ndarray, shape (B, 2n, 2n), optional
        Per-lane ``P(0)``, overriding the spec's.

    Attributes
    ----------
    spec : EstimatorSpec
        The validated configuration (lane-state shapes, configuration, initial values).
    name, n, p, form, num_envs : the algorithm name (upper case), order, innovation length,
        canonical form, number of lanes (``None`` for a single plant).
    theta, a, b : ndarray
        ``theta_hat(t) = [a_hat; b_hat]`` (copies).
    x_hat : ndarray
        ``x_hat(t)`` after ``update``, ``x_hat(t+1)`` after ``predict``.
    P : ndarray or None
        ``P(t)`` of RLS/MILS rules (block-diagonal ``diag(P_a, P_b)`` for D- rules).
    r : ndarray or None
        ``[r(t)]`` (plain) or ``[r1(t), r2(t)]`` (D-) of SG/MISG rules.
    P1, L1, Q, R : Kalman covariance ``P1(t+1)``, gain ``L1(t)``, process-noise covariance
        (settable between steps, e.g. adaptively) and measurement-noise variance (KF only).
    innovation, e : ``E(p, t)`` and its first entry ``e(t)``.
    phi, Phi : ``phi_hat(t)`` and ``Phi(p, t)`` (``2n x p``, column ``j`` = ``phi_hat(t-j)``).
    t : int
        Time of the last measurement update (0 before the first).
    enabled : bool (settable; per lane for a batch)
        ``False`` freezes ``theta`` and ``P`` (the innovation is still computed, the state
        still propagated, stacked windows keep sliding, the finite-history buffer does not).
    n_resets, health : numerical-health events (see :mod:`stcgym.adaptive.estimation.health`).
    flops_per_step, flops_parameters, flops_state : int
        Paper conventions: ``O-RLS`` = table 1, ``KF-MILS`` = table 2, D-RLS / D-MILS
        ``flops_parameters`` = tables 3 / 4 (:mod:`stcgym.adaptive.estimation.flops`).

    Examples
    --------
    O-RLS on recorded data of the plant ``y(t) = 1.2 y(t-1) - 0.5 y(t-2) + u(t-1) + 0.4 u(t-2)``
    (``theta = [a1, a2, b1, b2] = [-1.2, 0.5, 1, 0.4]``), with the measurement-corrected
    regressor:

    >>> import numpy as np
    >>> from scipy.signal import lfilter
    >>> from stcgym.adaptive import make_estimator
    >>> u = np.random.default_rng(0).standard_normal(50)
    >>> y = lfilter([0.0, 1.0, 0.4], [1.0, -1.2, 0.5], u)
    >>> est = make_estimator("O-RLS", 2, p0=100.0, regressor="filtered")
    >>> thetas = est.run(u, y)
    >>> thetas.shape, est.t
    ((50, 4), 50)
    >>> np.round(est.theta, 2)
    array([-1.2,  0.5,  1. ,  0.4])

    Step by step, as a controller uses it (:meth:`update` with ``y(t)``, then :meth:`predict`
    with ``u(t)``):

    >>> est.reset()
    >>> for u_t, y_t in zip(u, y):
    ...     theta = est.update(y_t)
    ...     x_next = est.predict(u_t)
    >>> np.allclose(theta, thetas[-1])
    True
    """

    def __init__(
        self,
        spec: EstimatorSpec,
        num_envs: int | None = None,
        *,
        lane_theta0: NDArray | None = None,
        lane_P0: NDArray | None = None,
    ) -> None:
        self.spec = spec
        self.name, self.n, self.p, self.form = spec.name, spec.n, spec.p, spec.form
        self.num_envs = num_envs
        B = 1 if num_envs is None else int(num_envs)
        init = spec.make_state(B)
        if lane_theta0 is None and lane_P0 is None:
            set_lanes(init, slice(None), spec.initial_state())
        else:
            for i in range(B):
                th0 = None if lane_theta0 is None else lane_theta0[i]
                P0 = None if lane_P0 is None else lane_P0[i]
                set_lanes(init, i, spec.initial_state(th0, P0))
        self._init = init
        self._state = EstimatorState(*(field.copy() for field in init))
        self._work = spec.make_work(B)
        self._status = np.zeros(B, dtype=np.int64)
        self._signal = np.zeros(B)  # y(t) or u(t) of a single plant's step
        self._last_event: str | None = None
        self._frozen_warned = False  # the frozen signal warns once (until reset)
        self._flops = spec.variant.flops(spec.n, spec.p, spec.stacked_r)
        self._gain_fn = callable(spec.observer_gain)

    # ---- lifecycle ----------------------------------------------------------------------------

    def reset(self, lanes: Any = None) -> None:
        """Back to the initial conditions (``t = 0``) for all lanes or the given ``lanes``
        (indices or a boolean mask of length ``B``); ``enabled`` is kept.

        Parameters
        ----------
        lanes : array_like of int or bool, optional
            Lane indices or a boolean mask of length ``B`` (default all lanes).

        Raises
        ------
        ValueError
            An index out of range or a mask of the wrong length.
        """
        idx = lane_indices(lanes, self._B)
        enabled = self._state.enabled[idx].copy()
        set_lanes(self._state, idx, self._init, idx)
        self._state.enabled[idx] = enabled
        if lanes is None:
            self._last_event = None
            self._frozen_warned = False

    def reset_covariance(self, lanes: Any = None) -> None:
        """``P <- P(0)`` (``r <- r(0)``) and an empty finite-history window; ``theta_hat`` and
        the state estimate are kept (the documented safe action, also on a change alarm).

        Parameters
        ----------
        lanes : array_like of int or bool, optional
            Lane indices or a boolean mask of length ``B`` (default all lanes).

        Raises
        ------
        ValueError
            An index out of range or a mask of the wrong length.
        """
        for i in lane_indices(lanes, self._B):
            _k.reset_covariance(self._state, i, self.spec.config)

    def restart(self, theta: ArrayLike, P: ArrayLike | None = None, lanes: Any = None) -> None:
        """Restart the parameter estimate at ``theta`` with covariance ``P`` (RLS/MILS; only
        its diagonal blocks for D- rules) keeping the state estimate; SG/MISG restart ``r``.

        Parameters
        ----------
        theta : array_like, shape (2n,) or (lanes, 2n)
            The new ``theta_hat``, finite (one row for every lane restarted, or one for all).
        P : array_like, shape (2n, 2n) or (lanes, 2n, 2n), optional
            Symmetric positive definite covariance; required by the RLS/MILS rules, ignored by
            SG/MISG.
        lanes : array_like of int or bool, optional
            The lanes to restart (default all).

        Raises
        ------
        ValueError
            ``theta`` or ``P`` malformed, ``P`` missing for RLS/MILS, or not positive definite
            on some lane; nothing changed.
        """
        idx = lane_indices(lanes, self._B)
        d = 2 * self.n
        th = per_lane(theta, idx.size, (d,), "theta")
        if self.spec.least_squares:
            if P is None:
                raise ValueError("P (2n x 2n covariance) is needed to restart an RLS/MILS rule")
            Pm = per_lane(P, idx.size, (d, d), "P")
        else:
            Pm = np.zeros((idx.size, d, d))
        saved = self._snapshot()
        for j, i in enumerate(idx):
            ok = _k.estimator_restart(
                self._state,
                self._work,
                i,
                self.spec.config,
                np.ascontiguousarray(th[j]),
                Pm[j].copy(),
            )
            if not ok:
                self._restore(saved)
                raise ValueError(f"P of lane {int(i)} is not symmetric positive definite")

    # ---- the two half-steps -------------------------------------------------------------------

    def _lane_signal(self, value: ArrayLike, name: str) -> NDArray:
        """``y(t)`` or ``u(t)`` of every lane, validated, as the lane functions take it (one
        plant's value in the reused buffer ``_signal``)."""
        if self.num_envs is not None:
            return lane_vector(value, self._B, name)
        self._signal[0] = _scalar(value, name)
        return self._signal

    def _check_phase(self, expected: bool, what: str) -> None:
        phase = self._state.phase
        if (phase[0] != expected) if self.num_envs is None else np.any(phase != expected):
            t = self._scalar_field("t")
            if what == "update":
                raise RuntimeError(
                    f"{self.name}: update() called twice without predict(u(t)) in between "
                    f"(t = {t}); the order is update(y(t)) -> compute u(t) -> predict(u(t))"
                )
            raise RuntimeError(
                f"{self.name}: predict() must follow update(y(t)) (t = {t}); the order is "
                f"update(y(t)) -> compute u(t) -> predict(u(t))"
            )

    def update(self, y_t: ArrayLike) -> NDArray:
        """Measurement step at time ``t``: build ``phi_hat(t)``, ``Phi(p, t)``, ``Y(p, t)`` and
        update ``theta_hat(t)`` (and ``P(t)`` / ``r(t)``); returns a copy of ``theta_hat(t)``.

        The regressor is (9)/(57) in the observer form, (153) in the observability form; the
        parameter rule SG (12)-(15), MISG (16)-(22), RLS (32)-(36) or MILS (37)-(44) of Ding &
        Ma (2014) (a whole O-RLS step, this and :meth:`predict`, is (54)-(62); KF-MILS's
        (73)-(86)).

        Parameters
        ----------
        y_t : float or array_like of shape (B,)
            The measured output ``y(t)``, finite.

        Returns
        -------
        ndarray, shape (2n,) or (B, 2n)
            ``theta_hat(t) = [a_hat(t); b_hat(t)]``.

        Raises
        ------
        RuntimeError
            ``update`` twice without :meth:`predict` in between.
        ValueError
            ``y_t`` not finite or of the wrong shape; nothing changed.
        NumericalHealthError
            With ``on_failure="raise"``, a covariance or normaliser that lost positive
            definiteness or overflowed; the estimator is left as before the call.
        """
        self._check_phase(False, "update")
        y = self._lane_signal(y_t, "y(t)")
        snapshot = self._snapshot() if self.spec.on_failure == "raise" else None
        _update_lanes(self._state, self._work, self.spec.config, y, self._status)
        if self._status.any():
            self._report(self._status, snapshot)
        return self._out(self._state.theta)

    def predict(self, u_t: ArrayLike, *, x_next: ArrayLike | None = None) -> NDArray:
        """State step: ``x_hat(t+1)`` from ``x_hat(t)``, ``u(t)``, ``y(t)`` and ``A_hat(t)``,
        ``b_hat(t)`` built from ``theta_hat(t)``; returns a copy of ``x_hat(t+1)``.

        Parameters
        ----------
        u_t : float (array (B,) for a batch)
            The input ``u(t)`` applied at time ``t``.
        x_next : array_like, shape (n,) or (B, n), optional
            A known (measured) ``x(t+1)`` that replaces the estimate: the regressors then use
            the true states (which lets the rules be checked against batch least squares).

        Returns
        -------
        ndarray, shape (n,) or (B, n)
            ``x_hat(t+1)``: the open-loop observer (46)-(49), the closed-loop observer (50)-(53)
            or the Kalman filter (66)-(72) on ``A_hat(t)``, ``b_hat(t)`` ((47) or (146)).

        Raises
        ------
        RuntimeError
            ``predict`` before :meth:`update`.
        ValueError
            ``u_t`` or ``x_next`` not finite or of the wrong shape; nothing changed.
        NumericalHealthError
            With ``on_failure="raise"``, a non-finite state estimate or Kalman covariance.
        """
        self._check_phase(True, "predict")
        spec = self.spec
        B = self._B
        u = self._lane_signal(u_t, "u(t)")
        known = None
        if x_next is not None:
            if self.num_envs is None:
                known = finite_vector(x_next, "x_next", length=self.n)[None, :]
            else:
                known = lane_rows(np.asarray(x_next, dtype=float), B, self.n, "x_next")
        gains = self._observer_gains() if self._gain_fn else None
        snapshot = self._snapshot() if spec.on_failure == "raise" else None
        if gains is not None:
            self._state.K[...] = gains
        _predict_lanes(self._state, self._work, spec.config, u, self._status)
        if known is not None:
            self._state.x_hat[...] = known
        if self._status.any():
            self._report(self._status, snapshot)
        return self._out(self._state.x_hat)

    def _observer_gains(self) -> NDArray:
        """Evaluate a callable observer gain ``K(a_hat, b_hat)`` for every lane (50)."""
        fn: Callable[[NDArray, NDArray], ArrayLike] = self.spec.observer_gain
        theta = self._field("theta")
        n = self.n
        out = np.empty((self._B, n))
        for i in range(self._B):
            K = np.asarray(fn(theta[i, :n].copy(), theta[i, n:].copy()), dtype=float)
            if K.shape != (n,) or not np.all(np.isfinite(K)):
                raise ValueError(f"observer_gain callable must return a finite ({n},) vector")
            out[i] = K
        return out

    def run(self, u: ArrayLike, y: ArrayLike) -> NDArray:
        """Open-loop pass over recorded data: ``u[k], y[k]`` are ``u(t), y(t)`` for
        ``t = k + 1`` (continuing from the current time).

        Parameters
        ----------
        u, y : array_like, shape (T,) or (T, B)
            Inputs and measured outputs, finite, of equal length.

        Returns
        -------
        ndarray, shape (T, 2n) or (T, B, 2n)
            ``theta_hat(t)`` for ``t = 1..T`` (fewer rows when ``on_failure="raise"`` stopped
            the pass).

        Raises
        ------
        RuntimeError
            Called between :meth:`update` and :meth:`predict`.
        ValueError
            ``u`` and ``y`` malformed or of different lengths.
        NumericalHealthError
            With ``on_failure="raise"``, as for :meth:`update`.
        """
        if self.num_envs is not None or callable(self.spec.observer_gain):
            return self._run_steps(u, y)
        u_arr, y_arr = vector_pair(u, y, ("u", "y"), " (u[k], y[k] = u(t), y(t), t = k + 1)")
        if self._state.phase[0]:
            raise RuntimeError(f"{self.name}: run() called between update() and predict()")
        T = u_arr.size
        thetas = np.empty((T, 2 * self.n))
        status = np.zeros(T, dtype=np.int64)
        raising = self.spec.on_failure == "raise"
        snapshot = self._snapshot() if raising else None
        stop = (_k.ST_RESET | _k.ST_STATE_RESET) if raising else 0
        done = _lanes.run_lane(
            self._state, self._work, 0, self.spec.config, u_arr, y_arr, thetas, status, stop
        )
        events = status[:done]
        if events.any():
            self._report(events, snapshot, times=True)
        return thetas[:done]

    def _run_steps(self, u: ArrayLike, y: ArrayLike) -> NDArray:
        u_arr = np.asarray(u, dtype=float)
        y_arr = np.asarray(y, dtype=float)
        if self.num_envs is None:
            u_arr, y_arr = finite_vector(u, "u"), finite_vector(y, "y")
        if u_arr.shape != y_arr.shape or u_arr.ndim != (1 if self.num_envs is None else 2):
            raise ValueError(
                f"u and y must have the same shape ((T,) single, (T, B) batch), got "
                f"{u_arr.shape} and {y_arr.shape}"
            )
        if np.any(self._state.phase):
            raise RuntimeError(f"{self.name}: run() called between update() and predict()")
        out = []
        for k in range(u_arr.shape[0]):
            out.append(self.update(y_arr[k]))
            self.predict(u_arr[k])
        return np.array(out).reshape((u_arr.shape[0], *np.shape(self.theta)))

    def __repr__(self) -> str:
        lanes = "" if self.num_envs is None else f", num_envs={self.num_envs}"
        return (
            f"RecursiveEstimator({self.name!r}, n={self.n}, p={self.p}, form={self.form!r}"
            f"{lanes}, t={self.t if self.num_envs is None else 'per lane'})"
        )
