"""Known-model controllers used as scoring oracles for the self-tuning regulator.

Both see only what the envs observe, ``[y(t), r(t)]``, and estimate the state with a Kalman
filter on the *true* model; they differ from :class:`~stcgym.adaptive.controller.
SelfTuningController` only in knowing ``(a, b)``:

* :class:`KnownModelController` runs exactly the regulator's tracking law
  (:class:`~stcgym.adaptive.controller.TrackingLaw`: the same poles, integral action,
  feed-forward, saturation and anti-windup) on the known ``(A, b)``, with the regulator's kind of
  state estimate (the seed paper's Kalman filter, ``shared/docs/algorithms.md`` §4
  eq. (66)-(72), corrected by the current sample). With the paper's ``Q = 0`` the filter is
  optimal for the envs' noise model (output noise only), so the oracle's state estimate
  converges to the true state: the ratio of the regulator's cost to this oracle's is the price
  of not knowing the parameters.
* :class:`LQGController` is the optimal linear design for the env's own cost
  ``(y - r)^2 + rho u^2``: ``control.dlqr`` on the (optionally integral-augmented) model with
  ``Q = c^T c``, ``R = rho``, a steady-state Kalman predictor from ``control.dlqe`` and the
  reference feed-forward of the steady state ``(x_ss, u_ss)``.

Both implement the SB3 policy protocol (:mod:`stcgym.adaptive.policy`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.placement import augment_integral, steady_state_gains
from stcgym.adaptive.policy import StatefulPolicy
from stcgym.envs.canonical import check_ab, check_form, companion_A

__all__ = ["KalmanObserver", "KnownModelController", "LQGController"]


class KalmanObserver:
    """Time-varying Kalman filter for ``x(t+1) = A x + b u + w``, ``y = x_1 + v``.

    The seed paper's filter (eq. (66)-(72)) is the case ``Q = 0``, ``R = 1``, ``P1(1) = I``:

        L1(t)   = A P1(t) c^T / (R + c P1(t) c^T)
        P1(t+1) = A P1(t) A^T - L1(t) c P1(t) A^T + Q
        x(t+1)  = A x(t) + b u(t) + L1(t) [y(t) - c x(t)]

    The step is split like the recursive estimators: :meth:`correct` takes ``y(t)`` and returns
    the filtered estimate ``x(t|t)``; :meth:`predict` takes ``u(t)`` and forms ``x(t+1|t)``.
    ``A`` and ``b`` may be replaced between steps (:meth:`set_model`).
    """

    def __init__(
        self,
        A: NDArray,
        b: NDArray,
        *,
        process_noise: float | NDArray = 0.0,
        measurement_noise: float = 1.0,
        P0: float = 1.0,
    ) -> None:
        self.n = A.shape[0]
        self.set_model(A, b)
        q = np.asarray(process_noise, dtype=float)
        self.Q = q * np.eye(self.n) if q.ndim == 0 else q.copy()
        self.R = float(measurement_noise)
        if self.R <= 0:
            raise ValueError(f"measurement_noise must be > 0, got {measurement_noise}")
        self.P0 = float(P0)
        self.reset()

    def set_model(self, A: NDArray, b: NDArray) -> None:
        self.A = np.asarray(A, dtype=float)
        self.b = np.asarray(b, dtype=float).reshape(-1)

    def reset(self) -> None:
        self.x = np.zeros(self.n)  # x(t|t-1)
        self.P = self.P0 * np.eye(self.n)
        self.x_filt = self.x.copy()
        self._innov = 0.0

    def correct(self, y: float) -> NDArray:
        """Measurement update with ``y(t)``; returns ``x(t|t)``."""
        Pc = self.P[:, 0]
        s = self.R + Pc[0]
        self._innov = y - self.x[0]
        self._gain = Pc / s
        self.x_filt = self.x + self._gain * self._innov
        return self.x_filt

    def predict(self, u: float) -> NDArray:
        """Time update with the applied ``u(t)``; returns ``x(t+1|t)`` (eq. (72))."""
        A = self.A
        # x(t+1|t) = A x(t|t) + b u  ==  A x + b u + L1 (y - c x) with L1 = A P c^T / s.
        self.x = A @ self.x_filt + self.b * u
        Pf = self.P - np.outer(self._gain, self.P[0, :])  # P(t|t)
        self.P = A @ Pf @ A.T + self.Q
        self.P = 0.5 * (self.P + self.P.T)
        return self.x


class KnownModelController(StatefulPolicy):
    """The self-tuning regulator's design applied to the known parameters ``(a, b)``.

    Parameters
    ----------
    a, b
        True plant parameters ``theta = [a; b]`` in the canonical ``form``.
    poles, integral, feedforward, action_bound, anti_windup
        As for :class:`~stcgym.adaptive.controller.SelfTuningController`, whose defaults they
        share (poles all at 0.5, integral action and feed-forward on, ``action_bound`` 10 as the
        envs); pass the regulator's values to compare like with like.
    form
        ``"observer"`` (default) or ``"observability"``.
    filtered
        Control on ``x(t|t)`` (default, as the regulator) instead of ``x(t|t-1)``.
    process_noise, measurement_noise, P0
        Kalman filter tuning; the defaults are the paper's filter (``Q = 0``, ``R = 1``,
        ``P1(1) = I``).
    """

    def __init__(
        self,
        a: ArrayLike,
        b: ArrayLike,
        *,
        poles: ArrayLike | None = None,
        integral: bool = True,
        feedforward: bool = True,
        action_bound: float | None = 10.0,
        anti_windup: bool = True,
        form: str = "observer",
        filtered: bool = True,
        process_noise: float = 0.0,
        measurement_noise: float = 1.0,
        P0: float = 1.0,
    ) -> None:
        from stcgym.adaptive.controller import DEFAULT_POLE, TrackingLaw

        super().__init__()
        a_arr, b_arr = check_ab(a, b)
        self.n = a_arr.size
        self.form = check_form(form)
        self.law = TrackingLaw(
            self.n,
            poles=DEFAULT_POLE if poles is None else poles,
            integral=integral,
            feedforward=feedforward,
            action_bound=action_bound,
            anti_windup=anti_windup,
            form=self.form,
        )
        self.filtered = bool(filtered)
        self.kf = KalmanObserver(
            companion_A(a_arr, self.form),
            b_arr,
            process_noise=process_noise,
            measurement_noise=measurement_noise,
            P0=P0,
        )
        self.set_model(a_arr, b_arr)
        self._initial_model = (a_arr.copy(), b_arr.copy())
        self._reset_state()

    @property
    def poles(self) -> NDArray:
        return self.law.poles

    @property
    def K(self) -> NDArray:
        """Current gain ``[K_x, k_i]`` (``k_i`` only with integral action)."""
        return self.law.K.copy()

    def set_model(self, a: ArrayLike, b: ArrayLike) -> None:
        """Switch to new true parameters (e.g. at a scheduled jump); the state estimate is kept."""
        a_arr, b_arr = check_ab(a, b)
        if a_arr.size != self.n:
            raise ValueError(f"new parameters must have order {self.n}, got {a_arr.size}")
        A = companion_A(a_arr, self.form)
        self.kf.set_model(A, b_arr)
        ok, reason = self.law.design(A, b_arr)
        if not ok:
            raise ValueError(f"cannot place the poles on the given model: {reason}")
        self.a, self.b = a_arr, b_arr

    def _reset_state(self) -> None:
        if hasattr(self, "_initial_model"):
            self.set_model(*self._initial_model)
        self.kf.reset()
        self.law.reset()
        self.t = 0

    def _act(self, obs: NDArray) -> float:
        y, r = float(obs[0]), float(obs[1])
        xf = self.kf.correct(y)
        x = xf if self.filtered else self.kf.x
        u = self.law.control(x, y, r)
        self.kf.predict(u)
        self.t += 1
        return u


class LQGController(StatefulPolicy):
    """LQG tracking controller on the known model (``control.dlqr`` + ``control.dlqe``).

    Minimises ``sum (y - r)^2 + rho u^2`` for a constant reference: ``u = u_ss r - K (x - x_ss r)``
    with ``K`` from ``dlqr(A, b, c^T c, rho)``; with ``integral=True`` the integral of ``r - y``
    is added to the state with weight ``integral_weight``. The state comes from the steady-state
    Kalman filter of ``dlqe`` for process noise ``input_noise_std^2 b b^T + process_noise_floor I``
    (a small input-disturbance model keeps the filter alive on stable plants) and measurement
    variance ``noise_std^2``, used as a current estimator ``x(t|t)``.

    Parameters
    ----------
    a, b
        True parameters. ``form`` as elsewhere.
    control_cost
        ``rho``, the weight of ``u^2`` (match the env's ``control_cost``); must be > 0.
    noise_std, input_noise_std, process_noise_floor
        Noise model of the Kalman filter (output noise std, input-disturbance std, floor).
    integral, integral_weight
        Optional integral state and its weight in the LQ cost (off by default: the oracle knows
        the model, so the feed-forward is exact).
    action_bound
        Saturation (default 10 as the envs), with conditional integration as anti-windup.
    """

    def __init__(
        self,
        a: ArrayLike,
        b: ArrayLike,
        *,
        control_cost: float = 1e-2,
        noise_std: float = 0.05,
        input_noise_std: float = 0.01,
        process_noise_floor: float = 1e-8,
        integral: bool = False,
        integral_weight: float = 1e-2,
        action_bound: float | None = 10.0,
        form: str = "observer",
    ) -> None:
        import control

        super().__init__()
        a_arr, b_arr = check_ab(a, b)
        self.n = n = a_arr.size
        self.form = check_form(form)
        if not control_cost > 0:
            raise ValueError(f"control_cost (rho) must be > 0, got {control_cost}")
        if not noise_std > 0:
            raise ValueError(f"noise_std must be > 0, got {noise_std}")
        if action_bound is not None and not action_bound > 0:
            raise ValueError(f"action_bound must be > 0 or None, got {action_bound}")
        self.action_bound = action_bound
        self.A = companion_A(a_arr, self.form)
        self.b = b_arr
        self.integral = bool(integral)
        x_ss, u_ss, rc = steady_state_gains(self.A, self.b)
        if rc < 1e-10:
            raise ValueError(
                "the model has a zero (or pole/zero cancellation) at z = 1: no tracking"
            )
        self.x_ss, self.u_ss = x_ss, u_ss
        if self.integral:
            Aa, ba = augment_integral(self.A, self.b)
            Q = np.zeros((n + 1, n + 1))
            Q[0, 0] = 1.0
            Q[n, n] = float(integral_weight)
            K, _, _ = control.dlqr(Aa, ba.reshape(-1, 1), Q, [[control_cost]])
        else:
            Q = np.zeros((n, n))
            Q[0, 0] = 1.0
            K, _, _ = control.dlqr(self.A, self.b.reshape(-1, 1), Q, [[control_cost]])
        self.K = np.asarray(K, dtype=float).reshape(-1)
        W = input_noise_std**2 * np.outer(self.b, self.b) + process_noise_floor * np.eye(n)
        C = np.zeros((1, n))
        C[0, 0] = 1.0
        # dlqe gives the predictor gain L = A M c^T(...)^-1 and the (a priori) covariance P.
        _, P, _ = control.dlqe(self.A, np.eye(n), C, W, [[noise_std**2]])
        P = np.asarray(P, dtype=float)
        self.M = P[:, 0] / (P[0, 0] + noise_std**2)  # current-estimator gain
        self._reset_state()

    def _reset_state(self) -> None:
        self.x = np.zeros(self.n)
        self.xi = 0.0
        self.t = 0

    def _act(self, obs: NDArray) -> float:
        y, r = float(obs[0]), float(obs[1])
        xf = self.x + self.M * (y - self.x[0])
        n = self.n
        u = self.u_ss * r - self.K[:n] @ (xf - self.x_ss * r)
        if self.integral:
            u -= self.K[n] * self.xi
        bound = self.action_bound
        u_sat = u if bound is None else min(max(u, -bound), bound)
        # Conditional integration (anti-windup): d u / d xi = -K[n]; freeze xi while saturated
        # when the error would push u further past the bound.
        if self.integral and not (u_sat != u and (-self.K[n] * (r - y)) * u > 0.0):
            self.xi += r - y
        self.x = self.A @ xf + self.b * u_sat
        self.t += 1
        return float(u_sat)
