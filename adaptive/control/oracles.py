"""Known-model controllers used as scoring oracles for the self-tuning regulator.

Both see only what the envs observe, ``[y(t), r(t)]``, and estimate the state with a Kalman
filter on the *true* model; they differ from :class:`~stcgym.adaptive.control.controller.
SelfTuningController` only in knowing ``(a, b)``. Both run the same compiled lane step
(:func:`~stcgym.adaptive.control.known_model.known_model_propose`: the Kalman correction, the
regulator's tracking law :func:`~stcgym.adaptive.control.law.track`, the Kalman time update
``kalman_step``) and differ in their design and filter tuning:

* :class:`KnownModelController` places the regulator's poles on the known ``(A, b)``
  (:func:`~stcgym.adaptive.control.placement.place_design`: the same integral action,
  feed-forward, saturation and anti-windup), with the regulator's kind of state estimate: the
  seed paper's time-varying Kalman filter (Ding & Ma 2014, eq. (66)-(72): ``Q = 0``, ``R = 1``,
  ``P1(1) = I``), corrected by the current sample. With ``Q = 0`` the filter is optimal for the
  envs' noise model (output noise only), so the oracle's state estimate converges to the true
  state: the ratio of the regulator's cost to this oracle's is the price of not knowing the
  parameters.
* :class:`LQGController` is the optimal linear design for the env's own cost
  ``(y - r)^2 + rho u^2``: the LQ gain of the (optionally integral-augmented) model solved to
  convergence (:func:`~stcgym.adaptive.control.lq.lq_solve`, ``Q = c^T c``, ``R = rho``),
  the reference feed-forward of the steady state, and the steady-state Kalman filter (the same
  Riccati solver on the dual problem) used as a current estimator ``x(t|t)``.

Both take the regulator's common settings with the same names and defaults (``law``, a
:class:`~stcgym.adaptive.control.options.LawOptions`: integral action, feed-forward, anti-windup,
filtered state, LQ weights; ``action_bound``, ``form``, ``num_envs``, ``env``; ``poles`` for the
pole-placement oracle). They apply no safe set: they know the model, so only the design's
numerical floors (an uncontrollable model, a zero at ``z = 1``) reject it, with a
``ValueError``.

Both are :class:`~stcgym.adaptive.policy.LanePolicy` policies (SB3's ``predict``) for one plant
(``num_envs=None``) or for ``num_envs=B`` plants with their own true parameters (``a``, ``b`` of
shape ``(B, n)``), stepped together by a batch loop over lanes. Their lane state (named arrays,
a row a plant) is all their state, so the oracles pickle and deep-copy with identical
continuation, and a step whose result would not be finite is rejected as a whole: no lane
changes.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.control import lq, placement, safe_set
from stcgym.adaptive.control.options import DEFAULT_POLE, LawOptions
from stcgym.adaptive.control.oracle_loop import (
    MAX_SETTING,
    _KnownModelLoop,
    _setting,
)
from stcgym.adaptive.control.placement import characteristic_coefficients, check_poles
from stcgym.adaptive.estimation import state_estimation
from stcgym.adaptive.estimation.state_estimation import kalman_step
from stcgym.lanes.validation import square_matrix

__all__ = ["KalmanObserver", "KnownModelController", "LQGController"]


class KnownModelController(_KnownModelLoop):
    """The self-tuning regulator's design applied to the known parameters ``(a, b)``.

    Parameters
    ----------
    a, b
        True plant parameters ``theta = [a; b]`` in the canonical ``form``: shape ``(n,)``, or
        ``(num_envs, n)`` for one plant per lane.
    poles, law, action_bound, form, num_envs, env
        As for :class:`~stcgym.adaptive.control.controller.SelfTuningController`, with the same
        defaults: poles all at 0.5, ``LawOptions()`` (integral action, feed-forward, anti-windup,
        control on ``x(t|t)``; its LQ weights are not used), the env's ``action_bound`` else 10,
        the env's ``form`` else ``"observer"``. Pass the regulator's values to compare like with
        like.
    process_noise, measurement_noise, P0
        Kalman filter tuning; the defaults are the paper's filter (``Q = 0``, ``R = 1``,
        ``P1(1) = I``).

    Raises
    ------
    ValueError
        Malformed settings, or a model the poles cannot be placed on (uncontrollable, a zero at
        ``z = 1`` with feed-forward on).

    Examples
    --------
    The oracle of ``unstable2`` tracking a constant reference: with integral action the three
    closed-loop poles are at 0.5, and the output settles on ``r = 1``:

    >>> import gymnasium as gym
    >>> import numpy as np
    >>> import stcgym.envs
    >>> from stcgym.adaptive import KnownModelController, augment_integral
    >>> env = gym.make("stcgym/ObserverCanonical-v0", plant="unstable2", reference=1.0)
    >>> obs, info = env.reset(seed=0)
    >>> a, b = info["theta"][:2], info["theta"][2:]
    >>> oracle = KnownModelController(a, b, env=env)
    >>> for t in range(40):
    ...     u, _ = oracle.predict(obs)
    ...     obs, reward, terminated, truncated, info = env.step(u)
    >>> np.round(obs, 3)  # [y(40), r(40)]
    array([1., 1.])
    >>> A_aug, b_aug = augment_integral([[1.7, 1.0], [-0.66, 0.0]], b)
    >>> np.allclose(np.linalg.eigvals(A_aug - np.outer(b_aug, oracle.K)), 0.5, atol=1e-4)
    True
    """

    def __init__(
        self,
        a: ArrayLike,
        b: ArrayLike,
        *,
        poles: ArrayLike = DEFAULT_POLE,
        law: LawOptions | dict | None = None,
        action_bound: float | None = None,
        form: str | None = None,
        num_envs: int | None = None,
        env: Any = None,
        process_noise: float = 0.0,
        measurement_noise: float = 1.0,
        P0: float = 1.0,
    ) -> None:
        a_l, b_l = self._settings(a, b, num_envs, action_bound, form, env, law)
        self.poles = check_poles(poles, self.n + int(self.law.integral))
        self._char_poly = characteristic_coefficients(self.poles)
        self._q = _setting(process_noise, "process_noise", lo=0.0)
        self.R = _setting(measurement_noise, "measurement_noise")
        self._P0 = _setting(P0, "P0")
        self._build(a_l, b_l)

    def _design_batch(self, thetas: NDArray, gains: safe_set.Gain, status: NDArray) -> None:
        cfg = self._design_config(self._char_poly)
        work = safe_set.design_work(self.n, cfg.integral, thetas.shape[0])
        if thetas.shape[0] == 1:
            status[0] = placement.place_design(thetas[0], cfg, gains, work, 0)
        else:
            placement.place_design_lanes(thetas, cfg, gains, status, work)

    def _failure(self, status: int) -> str:
        return f"cannot place the poles on the given model: {safe_set.STATUS_NAMES[status]}"

    def _process_noise(self, b: NDArray) -> NDArray:
        return self._q * np.eye(self.n)

    def _initial_covariance(self, a: NDArray, b: NDArray) -> NDArray:
        return self._P0 * np.eye(self.n)


class LQGController(_KnownModelLoop):
    """LQG tracking controller on the known model.

    Minimises ``sum q_y (y - r)^2 + rho u^2`` for a constant reference:
    ``u = N r - K_x x(t|t) - k_i xi`` with ``N = u_ss + K_x x_ss`` (the model's steady state for a
    unit output) and ``K`` the LQ gain for ``Q = q_y c^T c``, ``R = rho``; with integral action
    the integral of ``r - y`` joins the state with weight ``q_i``. ``[q_y, q_i, rho]`` are
    ``law.lq_weights`` (default the envs' cost with ``control_cost = 0.01`` and ``q_i = 1e-4``;
    :func:`~stcgym.adaptive.control.options.cost_weights` gives them for another ``control_cost``).
    Both
    gains come from :func:`~stcgym.adaptive.control.lq.lq_solve` (doubling to convergence;
    tested against python-control's ``dlqr``). The state comes from the steady-state Kalman
    filter for process noise ``input_noise_std^2 b b^T + process_noise_floor I`` (a small
    input-disturbance model keeps the filter alive on stable plants) and measurement variance
    ``noise_std^2``, used as a current estimator ``x(t|t)``: the filter starts at (and stays on)
    the stabilising solution of the dual Riccati equation.

    Parameters
    ----------
    a, b
        True parameters, ``(n,)`` or ``(num_envs, n)``.
    law, action_bound, form, num_envs, env
        As for :class:`~stcgym.adaptive.control.controller.SelfTuningController`, with the same
        defaults (``LawOptions()``: integral action with ``q_i = 1e-4``, feed-forward,
        anti-windup, control on ``x(t|t)``; the env's ``action_bound`` else 10). Without
        integral action (``law=LawOptions(integral=False)``) this is the optimal linear
        controller for the env's cost: the oracle knows the model, so the feed-forward is exact.
    noise_std, input_noise_std, process_noise_floor
        Noise model of the Kalman filter (output noise std > 0, input-disturbance std and floor
        >= 0).

    Raises
    ------
    ValueError
        Malformed settings, or a plant without a stabilising LQ design (an unstable mode the
        input cannot reach, e.g. ``LQGController([-3, 2], [1, -2])``: the pole at 2 is cancelled
        by a zero) or without a steady state for a constant reference (a zero at ``z = 1``).

    Examples
    --------
    >>> import gymnasium as gym
    >>> import numpy as np
    >>> import stcgym.envs
    >>> from stcgym.adaptive import LQGController
    >>> env = gym.make("stcgym/ObserverCanonical-v0", plant="unstable2", reference=1.0)
    >>> obs, info = env.reset(seed=0)
    >>> oracle = LQGController(info["theta"][:2], info["theta"][2:], env=env)
    >>> for t in range(40):
    ...     u, _ = oracle.predict(obs)
    ...     obs, reward, terminated, truncated, info = env.step(u)
    >>> np.round(obs, 3)  # [y(40), r(40)]: the slow integrator removes the last 0.7 %
    array([1.007, 1.   ])
    >>> LQGController([-3, 2], [1, -2])
    Traceback (most recent call last):
    ...
    ValueError: a, b: the plant cannot be stabilised by an LQ design (uncontrollable: ...
    """

    def __init__(
        self,
        a: ArrayLike,
        b: ArrayLike,
        *,
        law: LawOptions | dict | None = None,
        action_bound: float | None = None,
        form: str | None = None,
        num_envs: int | None = None,
        env: Any = None,
        noise_std: float = 0.05,
        input_noise_std: float = 0.01,
        process_noise_floor: float = 1e-8,
    ) -> None:
        a_l, b_l = self._settings(a, b, num_envs, action_bound, form, env, law)
        # their squares are covariances of the filter: keep those in range too
        root = math.sqrt(MAX_SETTING)
        self.noise_std = _setting(noise_std, "noise_std", lo=1.0 / root, hi=root)
        self.input_noise_std = _setting(input_noise_std, "input_noise_std", lo=0.0, hi=root)
        self.process_noise_floor = _setting(process_noise_floor, "process_noise_floor", lo=0.0)
        self.R = self.noise_std**2
        self._weights = np.array(self.law.lq_weights, dtype=float)
        self._build(a_l, b_l)

    def _design_batch(self, thetas: NDArray, gains: safe_set.Gain, status: NDArray) -> None:
        cfg = self._design_config(np.zeros(0))
        m = self.n + int(cfg.integral)
        Ps = np.zeros((thetas.shape[0], m, m))
        work = lq.lq_work(self.n, cfg.integral, thetas.shape[0], solve=True)
        w = self._weights
        if thetas.shape[0] == 1:
            status[0] = lq.lq_solve(thetas[0], cfg, w, Ps[0], gains, work, 0, 1e-12, 64)
        else:
            lq.lq_solve_lanes(thetas, cfg, w, Ps, gains, status, work, 1e-12, 64)

    def _failure(self, status: int) -> str:
        if status in (safe_set.UNCONTROLLABLE, safe_set.NOT_STABILISABLE, safe_set.NOT_CONVERGED):
            return (
                f"the plant cannot be stabilised by an LQ design ({safe_set.STATUS_NAMES[status]}: "
                "a mode the input cannot reach, e.g. a pole cancelled by a zero, or with "
                "integral action a zero at z = 1)"
            )
        if status == safe_set.DC_SINGULAR:
            return "the model has a zero (or pole/zero cancellation) at z = 1: no tracking"
        return f"no LQ design on the given model: {safe_set.STATUS_NAMES[status]}"

    def _process_noise(self, b: NDArray) -> NDArray:
        bb = np.einsum("li,lj->lij", b, b)  # b b^T of every lane
        return self.input_noise_std**2 * bb + self.process_noise_floor * np.eye(self.n)

    def _initial_covariance(self, a: NDArray, b: NDArray) -> NDArray:
        """A-priori covariance of the steady-state Kalman filter: the dual Riccati equation."""
        P = np.zeros((a.shape[0], self.n, self.n))
        status = np.zeros(a.shape[0], dtype=np.int64)
        W = np.ascontiguousarray(self._process_noise(b))
        thetas = np.hstack((a, b))
        work = lq.dare_work(self.n, a.shape[0])
        if a.shape[0] == 1:
            status[0] = lq.kalman_covariance(
                thetas[0], self._form_code, W[0], self.R, P[0], work, 0, 1e-12, 64
            )
        else:
            lq.kalman_covariance_lanes(
                thetas, self._form_code, W, self.R, P, status, work, 1e-12, 64
            )
        bad = np.flatnonzero(status)
        if bad.size:
            raise ValueError(
                f"no steady-state Kalman filter for the model (lane {int(bad[0])}): "
                f"{safe_set.STATUS_NAMES[int(status[bad[0]])]}"
            )
        return P

    def _model_extras(self, a: NDArray, b: NDArray) -> dict[str, NDArray]:
        return {"Q": self._process_noise(b), "P": self._initial_covariance(a, b)}

    @property
    def x_ss(self) -> NDArray:
        """Steady state per unit output of the model in force."""
        return self._lanes_out(self._steady()[0])

    @property
    def u_ss(self) -> float | NDArray:
        """Steady-state input per unit output of the model in force."""
        return self._lanes_out(self._steady()[1], float)

    def _steady(self) -> tuple[NDArray, NDArray]:
        A, b = self._state.A, self._state.b
        u_ss = np.zeros(A.shape[0])
        work = safe_set.design_work(self.n, False, A.shape[0])
        for i in range(A.shape[0]):
            u_ss[i], _ = safe_set.steady_state(A[i], b[i], work, i)
        return work.x_ss, u_ss


class KalmanObserver:
    """Time-varying Kalman filter for ``x(t+1) = A x + b u + w``, ``y = x_1 + v``.

    The seed paper's filter (Ding & Ma 2014, eq. (66)-(72)) is the case ``Q = 0``, ``R = 1``,
    ``P1(1) = I``:

        L1(t)   = A P1(t) c^T / (R + c P1(t) c^T)
        P1(t+1) = A P1(t) A^T - L1(t) c P1(t) A^T + Q
        x(t+1)  = A x(t) + b u(t) + L1(t) [y(t) - c x(t)]

    The step is split like the recursive estimators: :meth:`correct` takes ``y(t)`` and returns
    the filtered estimate ``x(t|t)`` (lane function
    :func:`~stcgym.adaptive.estimation.state_estimation.filtered_state`); :meth:`predict` takes
    ``u(t)`` and forms ``x(t+1|t)`` (lane function ``kalman_step`` of
    :mod:`stcgym.adaptive.estimation.state_estimation`). When the covariance update is not finite,
    ``P`` is kept, the state advances open loop and ``n_failures`` counts it. ``A`` and ``b`` may
    be replaced between steps (:meth:`set_model`).

    Parameters
    ----------
    A : array_like, shape (n, n)
        Finite, non-empty square system matrix.
    b : array_like, shape (n,)
        Finite input vector.
    process_noise : float or array_like (n, n), default 0.0
        ``Q``: a number gives ``Q I``; finite.
    measurement_noise : float, default 1.0
        ``R``, in ``[1e-100, 1e100]`` (:data:`MAX_SETTING`).
    P0 : float, default 1.0
        ``P1(1) = P0 I``, in ``[1e-100, 1e100]``.

    Raises
    ------
    ValueError
        Any of the above malformed, before the filter is built.

    Examples
    --------
    The paper's filter on the noise-free ``unstable2`` model, started at ``x = 0`` while the
    plant starts at ``[1, -0.5]``:

    >>> import numpy as np
    >>> from stcgym.adaptive import KalmanObserver
    >>> A = np.array([[1.7, 1.0], [-0.66, 0.0]])
    >>> b = np.array([0.5, 0.3])
    >>> kf = KalmanObserver(A, b)
    >>> x, rng = np.array([1.0, -0.5]), np.random.default_rng(0)
    >>> for t in range(30):
    ...     x_filt = kf.correct(x[0])
    ...     u = rng.standard_normal()
    ...     x_pred = kf.predict(u)
    ...     x = A @ x + b * u
    >>> round(float(np.linalg.norm(x_pred - x)), 3), kf.n_failures
    (0.008, 0)
    """

    def __init__(
        self,
        A: ArrayLike,
        b: ArrayLike,
        *,
        process_noise: float | ArrayLike = 0.0,
        measurement_noise: float = 1.0,
        P0: float = 1.0,
    ) -> None:
        A_arr = square_matrix(A, "A")
        self.n = A_arr.shape[0]
        self.set_model(A_arr, b)
        q = np.asarray(process_noise, dtype=float)
        Q = q * np.eye(self.n) if q.ndim == 0 else q.copy()
        if Q.shape != (self.n, self.n) or not np.all(np.isfinite(Q)):
            raise ValueError(
                f"process_noise must be a finite number or an ({self.n}, {self.n}) matrix"
            )
        self.Q = np.ascontiguousarray(Q)
        self.R = _setting(measurement_noise, "measurement_noise")
        self.P0 = _setting(P0, "P0")
        self.reset()

    def set_model(self, A: ArrayLike, b: ArrayLike) -> None:
        """Filter with a new model ``A`` ``(n, n)``, ``b`` ``(n,)``; the estimate and ``P`` stay.

        Parameters
        ----------
        A : array_like, shape (n, n)
            Finite system matrix.
        b : array_like, shape (n,)
            Finite input vector.

        Raises
        ------
        ValueError
            Wrong shapes or non-finite entries, before anything changes.
        """
        A_arr = np.ascontiguousarray(A, dtype=float)
        b_arr = np.ascontiguousarray(b, dtype=float).reshape(-1)
        if A_arr.shape != (self.n, self.n) or b_arr.size != self.n:
            raise ValueError(f"A must be ({self.n}, {self.n}) and b of length {self.n}")
        if not (np.all(np.isfinite(A_arr)) and np.all(np.isfinite(b_arr))):
            raise ValueError("A and b must be finite")
        self.A, self.b = A_arr, b_arr

    def reset(self) -> None:
        """Restart at ``x(1|0) = 0`` with ``P = P0 I``."""
        self.x = np.zeros(self.n)  # x(t|t-1)
        self.P = self.P0 * np.eye(self.n)
        self.x_filt = self.x.copy()
        self.L1 = np.zeros(self.n)
        self._y = 0.0
        self._innov = 0.0
        self.n_failures = 0
        self._AP = np.zeros((self.n, self.n))  # the Kalman step's scratch
        self._P_upd = np.zeros((self.n, self.n))

    def correct(self, y: float) -> NDArray:
        """Measurement update with ``y(t)``; returns ``x(t|t)``.

        Parameters
        ----------
        y : float
            The measured output ``y(t)``.

        Returns
        -------
        ndarray, shape (n,)
            The filtered estimate ``x(t|t) = x(t|t-1) + g [y(t) - c x(t|t-1)]``,
            ``g = P1 c^T / (R + c P1 c^T)`` (the object itself: copy it to keep it).
        """
        self._y = float(y)
        self._innov = state_estimation.filtered_state(self.x, self.P, self.R, self._y, self.x_filt)
        return self.x_filt

    def predict(self, u: float) -> NDArray:
        """Time update with the applied ``u(t)``; returns ``x(t+1|t)`` (eq. (72)).

        Parameters
        ----------
        u : float
            The input ``u(t)`` applied after :meth:`correct`.

        Returns
        -------
        ndarray, shape (n,)
            ``x(t+1|t)``, with ``P1(t+1)`` and ``L1(t)`` of (66)-(72) updated; a non-finite
            covariance update keeps ``P`` and counts in ``n_failures``.
        """
        x_next = np.empty(self.n)
        status = kalman_step(
            self.A, self.b, self.P, self.Q, self.R, self.x, float(u), self._y, x_next, self.L1,
            self._AP, self._P_upd,
        )  # fmt: skip
        self.n_failures += int(status != 0)
        self.x = x_next
        return self.x
