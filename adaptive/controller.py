"""Self-tuning pole-placement regulator on the seed paper's joint state/parameter estimators.

:class:`SelfTuningController` is the indirect self-tuning regulator of the mission: each step it
updates a recursive estimator of Ding & Ma 2014 (``shared/docs/algorithms.md`` §3-§5; KF-MILS
by default, any name accepted by :func:`stcgym.adaptive.recursive.make_estimator`), builds
``(A_hat, b_hat)`` from ``theta_hat(t)`` (eq. (59)-(60)), places the closed-loop poles on it
(:mod:`stcgym.adaptive.placement`, closed-form Ackermann, no python-control in the loop) and
applies ``u(t)`` between the estimator's measurement and state steps (§4, last paragraph).

:class:`TrackingLaw` is the control law proper (integral action, feed-forward, saturation,
anti-windup, safe-set test); :class:`~stcgym.adaptive.oracles.KnownModelController` runs the same
law on the true parameters, so cost ratios between the two measure the price of estimation.

Both follow the SB3 policy protocol of :mod:`stcgym.adaptive.policy` and read only the
observation ``[y(t), r(t)]``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.placement import (
    UncontrollableError,
    ackermann,
    augment_integral,
    characteristic_coefficients,
    check_poles,
    steady_state_gains,
)
from stcgym.adaptive.policy import StatefulPolicy
from stcgym.envs.canonical import check_form, companion_A, observer_to_observability_b

#: Default location of every closed-loop pole (see :class:`SelfTuningController`).
DEFAULT_POLE = 0.5


class TrackingLaw:
    """Pole-placement tracking law shared by the regulator and the known-model oracle.

    ``u(t) = sat( -K_x x(t) - k_i xi(t) + N r(t) + e(t) )`` with

    * ``[K_x, k_i]`` the Ackermann gain placing the ``n + 1`` poles of the integral-augmented
      model (:func:`~stcgym.adaptive.placement.augment_integral`), or ``K_x`` placing ``n`` poles
      without integral action;
    * ``xi(t+1) = xi(t) + r(t) - y(t)`` the integral of the measured tracking error;
    * ``N = u_ss + K_x x_ss`` the reference feed-forward: ``(x_ss, u_ss)`` is the model's steady
      state for a unit output, so that on an exact model the integrator rests at ``xi = 0`` in
      steady state and only has to absorb model error (with the feed-forward off the reference
      enters through the integrator alone: slower, but independent of the DC-gain estimate);
    * ``e(t)`` an additive excitation supplied by the caller;
    * ``sat`` the clip to ``[-action_bound, action_bound]``, with anti-windup by conditional
      integration: ``xi`` is frozen while the input is saturated and the error would drive it
      further into saturation.

    :meth:`design` recomputes the gains from a model and keeps the previous ones when the model
    is outside the safe set (returns ``False`` and the reason).
    """

    def __init__(
        self,
        n: int,
        *,
        poles: ArrayLike = DEFAULT_POLE,
        integral: bool = True,
        feedforward: bool = True,
        action_bound: float | None = None,
        anti_windup: bool = True,
        form: str = "observer",
        b_min: float = 0.0,
        rcond_min: float = 0.0,
        dc_rcond_min: float = 0.0,
        gain_max: float = math.inf,
    ) -> None:
        self.n = int(n)
        self.integral = bool(integral)
        self.feedforward = bool(feedforward)
        self.m = self.n + int(self.integral)
        self.poles = check_poles(poles, self.m)
        self.alpha = characteristic_coefficients(self.poles)
        if action_bound is not None:
            action_bound = float(action_bound)
            if not (action_bound > 0 and math.isfinite(action_bound)):
                raise ValueError(
                    f"action_bound must be a positive number or None, got {action_bound}"
                )
        self.action_bound = action_bound
        self.anti_windup = bool(anti_windup)
        self.form = form
        self.b_min = float(b_min)
        self.rcond_min = float(rcond_min)
        self.dc_rcond_min = float(dc_rcond_min)
        self.gain_max = float(gain_max)
        self.clear_gain()
        self.reset()

    def clear_gain(self) -> None:
        """Forget the gains (no good design yet: :meth:`control` returns only the excitation)."""
        self.K = np.zeros(self.m)
        self.Kx = self.K[: self.n]
        self.ki = 0.0
        self.N = 0.0
        self.has_gain = False
        self.rcond = 0.0

    def reset(self) -> None:
        """Zero the integrator and the saturation flag (gains are kept)."""
        self.xi = 0.0
        self.saturated = False
        self.u_unsat = 0.0

    def design(self, A: NDArray, b: NDArray) -> tuple[bool, str]:
        """Place the poles on ``(A, b)``; on failure keep the last good gains.

        Safe set, tested in this order (reason strings in brackets): finite model
        (``"nonfinite"``), ``max |b| >= b_min`` (``"b_small"``), reciprocal condition of the
        column-normalised controllability matrix of the (augmented) model ``>= rcond_min``
        (``"uncontrollable"``), a regular steady-state (Rosenbrock) system with reciprocal
        condition ``>= dc_rcond_min`` when tracking needs it (``"dc_singular"``: a zero at
        ``z = 1``), and ``max |K| <= gain_max`` (``"gain_large"``).
        """
        if not (np.all(np.isfinite(A)) and np.all(np.isfinite(b))):
            return False, "nonfinite"
        if np.max(np.abs(b)) < self.b_min:
            return False, "b_small"
        if self.integral:
            Ad, bd = augment_integral(A, b)
        else:
            Ad, bd = A, b
        try:
            K, rcond = ackermann(Ad, bd, self.alpha, rcond_min=self.rcond_min)
        except UncontrollableError:
            return False, "uncontrollable"
        N = 0.0
        if self.feedforward:
            x_ss, u_ss, dc_rcond = steady_state_gains(A, b)
            if dc_rcond < max(self.dc_rcond_min, 1e-13):
                return False, "dc_singular"
            N = u_ss + float(K[: self.n] @ x_ss)
        if not (np.max(np.abs(K)) <= self.gain_max and abs(N) <= self.gain_max):
            return False, "gain_large"
        self.K = K
        self.Kx = K[: self.n]
        self.ki = float(K[self.n]) if self.integral else 0.0
        self.N = N
        self.rcond = rcond
        self.has_gain = True
        return True, ""

    def control(self, x: NDArray, y: float, r: float, excitation: float = 0.0) -> float:
        """Return the applied ``u(t)`` and advance the integrator to ``xi(t+1)``."""
        if self.has_gain:
            u = self.N * r - float(self.Kx @ x) - self.ki * self.xi + excitation
        else:
            u = excitation
        self.u_unsat = u
        bound = self.action_bound
        if bound is not None and abs(u) > bound:
            u_sat = math.copysign(bound, u)
            self.saturated = True
        else:
            u_sat = u
            self.saturated = False
        if self.integral and self.has_gain:
            err = r - y
            # d u / d xi = -k_i: freeze xi when the step would push u further past the bound.
            if not (self.anti_windup and self.saturated and (-self.ki * err) * u > 0.0):
                self.xi += err
        return u_sat


class _PRBS:
    """Maximum-length pseudo-random binary sequence (9-bit LFSR, x^9 + x^5 + 1, period 511).

    Values are +-1; the seed picks the starting register state (never zero), so different seeds
    give shifted copies of the same sequence. Deterministic and O(1) per sample.
    """

    def __init__(self, seed: int = 0) -> None:
        self.state0 = (int(seed) % 511) + 1
        self.reset()

    def reset(self) -> None:
        self.state = self.state0

    def __call__(self) -> float:
        s = self.state
        bit = ((s >> 8) ^ (s >> 4)) & 1
        self.state = ((s << 1) | bit) & 0x1FF
        return 1.0 if bit else -1.0


_DEFAULT = object()  # sentinel: "not given" for settings the env can supply


class _EquationErrorRLS:
    """Equation-error (ARX) recursive least squares on measured outputs: the bootstrap.

    ``y(t) = [-y(t-1..t-n), u(t-1..t-n)] [a; beta] + e(t)`` with the transfer-function
    coefficients ``a`` and numerator ``beta`` (observer-form ``b``). Its regressors are measured,
    so unlike the seed paper's estimators (regressors built from state estimates that are only
    as good as the current parameters) it converges in a few multiples of ``2n`` samples from
    any start. It is biased by output noise (the regressors are noisy), which is why it only
    initialises the paper's estimator and never drives the control itself.
    """

    def __init__(self, n: int, p0: float) -> None:
        self.n = n
        self.p0 = float(p0)
        self.theta = np.zeros(2 * n)
        self.P = self.p0 * np.eye(2 * n)
        self.phi = np.zeros(2 * n)

    def reset(self) -> None:
        self.theta[:] = 0.0
        self.P = self.p0 * np.eye(2 * self.n)
        self.phi[:] = 0.0

    def update(self, y: float) -> None:
        phi = self.phi
        Pphi = self.P @ phi
        s = 1.0 + float(phi @ Pphi)
        if s > 0.0 and math.isfinite(s):  # (32)-(34) on measured regressors
            self.theta += Pphi * ((y - float(phi @ self.theta)) / s)
            self.P -= np.multiply.outer(Pphi, Pphi) * (1.0 / s)

    def push(self, y: float, u: float) -> None:
        """Shift ``y(t)``, ``u(t)`` into the regressor (it becomes ``phi(t+1)``)."""
        n, phi = self.n, self.phi
        phi[1:n] = phi[: n - 1]
        phi[0] = -y
        phi[n + 1 :] = phi[n:-1]
        phi[n] = u


def _env_spec(env: Any) -> tuple[int | None, float | None, str | None]:
    """``(n, action_bound, form)`` of an stcgym canonical env (or wrapper), ``None`` if unknown."""
    base = getattr(env, "unwrapped", env)
    n_inputs = getattr(base, "n_inputs", 1)
    n_outputs = getattr(base, "n_outputs", 1)
    if n_inputs != 1 or n_outputs != 1:
        raise ValueError(
            f"the self-tuning regulator is single-input single-output; the env has "
            f"{n_inputs} inputs and {n_outputs} outputs"
        )
    n = getattr(base, "n_states", None)
    bound = getattr(base, "action_bound", None)
    form = getattr(base, "form", None)
    return (
        None if n is None else int(n),
        None if bound is None else float(bound),
        None if form is None else str(form),
    )


_LOG_KEYS = (
    "y",
    "r",
    "u",
    "theta",
    "K",
    "N",
    "poles",
    "design_ok",
    "open_loop",
    "saturated",
    "reset",
)


class SelfTuningController(StatefulPolicy):
    """Indirect self-tuning pole-placement regulator on the seed paper's joint estimators.

    Every step (``shared/docs/algorithms.md`` §4, "closed-loop control"):

    1. ``theta_hat(t) = estimator.update(y(t))`` (measurement step of O-RLS (54)-(57),
       KF-MILS (73)-(79), or any other recursive estimator by name);
    2. ``A_hat(t), b_hat(t)`` from ``theta_hat(t)`` (59)-(60); gains by Ackermann's formula on the
       integral-augmented model (:class:`TrackingLaw`), kept from the last good step when the
       model is outside the safe set;
    3. ``u(t) = sat(-K_x x(t) - k_i xi(t) + N r(t) + dither)`` with ``x(t)`` the estimator's
       state, corrected by ``y(t)`` when it is a Kalman filter (``filtered``);
    4. ``estimator.predict(u(t))`` (state step (58) / (80)-(82)) with the *applied* input.

    The controller reads only the observation ``[y(t), r(t)]``.

    Tracking
        Integral action on ``r - y`` (``n + 1`` poles) plus the feed-forward ``N r`` that puts
        the integrator at rest on an exact model: zero steady-state error to constant
        references whatever the estimation bias, and on an exact model the reference step
        response of the feed-forward design. Anti-windup by conditional integration.
    Default poles
        All ``n + 1`` at ``0.5`` (:data:`DEFAULT_POLE`): errors shrink by half per sample, about
        a 7-sample settling time, fast without needing huge gains on the catalogue plants.

    Safeguards (each switchable)
    ----------------------------
    excitation phase
        ``excitation_steps`` (default 100) of open-loop PRBS of ``excitation_amplitude``
        (default 3); it ends early when ``|y| > excitation_limit`` (default 5, ``None`` = never)
        so that an open-loop unstable plant does not run away. ``excitation_steps=0`` closes the
        loop as soon as a model exists (after ``bootstrap_window`` samples). Before the first
        good gain the input is the PRBS as well (nothing else identifies the plant).
    bootstrap (``bootstrap=True``, names only)
        The paper's estimators build their regressors from state estimates, which are only as
        good as the current parameters: started from ``theta_hat(0) = 1/p0`` they need
        thousands of samples and in closed loop they settle on wrong models (observed on every
        catalogue plant). So an equation-error least-squares estimator on the measured ``y``
        runs during the excitation phase; at its end the paper's estimator is rebuilt with
        ``theta_hat(0)`` = that estimate, ``P(0)`` = its covariance times
        ``handover_inflation`` (default 0.1: trust it, the equation-error estimate is biased but
        close), and the stored data are replayed with adaptation off to warm up its state
        estimate. From then on only the paper's estimator runs and drives the control.
    Kalman process noise (``process_noise="adaptive"``, KF estimators)
        ``Q(t) = g R [x1^2 P_aa - x1 u (P_ab + P_ba) + u^2 P_bb]`` from the parameter
        covariance: the model error a wrong ``theta_hat`` injects into each state row, times
        ``g = process_noise_gain`` (default 0.1). Large while the parameters are uncertain (the
        filter follows ``y``; needed on the unstable and integrating plants), vanishing as ``P``
        shrinks (the filter becomes the noise-free open-loop observer that keeps the estimates
        unbiased; ``g = 1`` biases the 4th-order plant badly, ``g = 0`` is the paper's
        ``Q = 0`` and fails the integrating plant). A number gives a constant ``Q = q I``.
    safe set
        ``max |b_hat| >= b_min``, reciprocal condition of the normalised controllability
        matrix ``>= rcond_min``, a regular steady-state system (no zero at ``z = 1``) and
        ``max |K|, |N| <= gain_max``; otherwise the last good gains are kept (counted in
        :attr:`n_rejected` / :attr:`rejections`).
    change detection and covariance resetting (``covariance_reset=True``)
        An EWMA of the squared innovation over ~10 samples is compared with one over ~100; when
        it exceeds ``reset_threshold`` times the long one (at most once per
        ``reset_holdoff`` steps, only in closed loop) the estimator is restarted at its current
        estimate with ``P`` multiplied by ``reset_inflation`` (default 100), which forgets the old
        data in one go. ``forgetting < 1`` (exponential forgetting) is available as well but
        off by default: it degrades the estimates of the slow 4th-order plant.
    saturation
        ``action_bound`` (default: the env's, else 10) with anti-windup.

    Parameters
    ----------
    n
        Plant order (``theta`` has ``2n`` entries); must match the env when ``env`` is given.
    num_envs, mode
        ``num_envs=B`` returns a :class:`~stcgym.adaptive.batched.BatchedSelfTuningController`
        instead: ``B`` lanes of this controller on arrays, ``mode="exact"`` (the single
        controller's BLAS/LAPACK calls, stacked: equal to rounding) or ``"fast"`` (generated
        kernels, different rounding).
    estimator
        A paper name (``"O-RLS"``, ``"KF-MILS"``, ... case-insensitive; see
        :func:`stcgym.adaptive.recursive.make_estimator`) or a ready estimator object with
        ``update/predict/reset/theta/x_hat`` (then no bootstrap or restarts).
    p, p0, forgetting, measurement_noise, estimator_kwargs
        Passed to ``make_estimator`` (``p`` only to MISG/MILS rules, noise settings only to KF).
    process_noise, process_noise_gain
        ``"adaptive"`` (default, scaled by ``process_noise_gain``) or a constant ``q >= 0``
        (KF estimators only).
    poles
        Desired closed-loop poles: a scalar (all of them) or ``n + 1`` values (``n`` without
        integral action), strictly inside the unit circle, complex ones in conjugate pairs.
    integral, feedforward, anti_windup, action_bound
        See :class:`TrackingLaw`.
    excitation_steps, excitation_amplitude, excitation_limit, dither
        Excitation phase and persistent dither (PRBS amplitude added in closed loop, default 0).
    bootstrap, bootstrap_window, handover_inflation
        Bootstrap; ``bootstrap_window`` (default ``4n``) is the least number of samples before
        the handover.
    b_min, rcond_min, gain_max
        Safe set.
    covariance_reset, reset_threshold, reset_holdoff, reset_inflation
        Change detection and covariance resetting.
    form
        Canonical form of the plant (default: the env's, else ``"observer"``).
    filtered
        Correct the Kalman prediction ``x(t|t-1)`` with ``y(t)`` before computing ``u(t)``.
    seed
        Start of the PRBS (different seeds give shifted sequences).
    record
        Keep per-step logs in :attr:`history` (costs an eigenvalue computation per step).
    env
        Optional env to check ``n``, ``form`` and ``action_bound`` against at construction.

    Raises
    ------
    ValueError
        Bad poles (count, modulus, conjugates), unknown estimator name, ``n`` or ``form``
        mismatching the env, ``action_bound`` larger than the env's, bad numeric settings.
    """

    def __new__(
        cls, *args: Any, num_envs: int | None = None, mode: str = "exact", **kwargs: Any
    ) -> Any:
        # ``num_envs`` lanes are a different object (arrays per lane, no Python loop per lane);
        # one constructor keeps the single and batched controllers configured identically.
        if num_envs is not None:
            from stcgym.adaptive.batched import BatchedSelfTuningController

            return BatchedSelfTuningController(*args, num_envs=num_envs, mode=mode, **kwargs)
        if mode != "exact":
            raise ValueError(f"mode={mode!r} applies to batched controllers (num_envs=...) only")
        return super().__new__(cls)

    def __init__(
        self,
        n: int,
        *,
        num_envs: None = None,
        mode: str = "exact",
        estimator: str | Any = "KF-MILS",
        p: int = 2,
        p0: float = 1e6,
        forgetting: float = 1.0,
        process_noise: float | str = "adaptive",
        process_noise_gain: float = 0.1,
        measurement_noise: float = 1.0,
        estimator_kwargs: dict[str, Any] | None = None,
        poles: ArrayLike = DEFAULT_POLE,
        integral: bool = True,
        feedforward: bool = True,
        anti_windup: bool = True,
        action_bound: float | None | object = _DEFAULT,
        excitation_steps: int = 100,
        excitation_amplitude: float = 3.0,
        excitation_limit: float | None = 5.0,
        dither: float = 0.0,
        bootstrap: bool = True,
        bootstrap_window: int | None = None,
        handover_inflation: float = 0.1,
        b_min: float = 1e-4,
        rcond_min: float = 1e-6,
        gain_max: float = 1e3,
        covariance_reset: bool = True,
        reset_threshold: float = 5.0,
        reset_holdoff: int = 100,
        reset_inflation: float = 100.0,
        form: str | object = _DEFAULT,
        filtered: bool = True,
        seed: int = 0,
        record: bool = False,
        env: Any = None,
    ) -> None:
        super().__init__()
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"n (plant order) must be a positive integer, got {n!r}")
        self.n = n = int(n)
        env_n, env_bound, env_form = (None, None, None) if env is None else _env_spec(env)
        if env_n is not None and env_n != n:
            raise ValueError(
                f"n={n} does not match the env's plant order n={env_n}; build the controller "
                f"with n={env_n}"
            )
        # Saturation: the env's bound unless given; a larger bound than the env's would let the
        # integrator wind up against a clip it does not know about.
        if action_bound is _DEFAULT:
            action_bound = env_bound if env_bound is not None else 10.0
        if action_bound is not None and env_bound is not None and action_bound > env_bound:
            raise ValueError(
                f"action_bound={action_bound} exceeds the env's action_bound={env_bound}"
            )
        if form is _DEFAULT:
            form = env_form or "observer"
        self.form = check_form(form)  # type: ignore[arg-type]
        if env_form is not None and env_form != self.form:
            raise ValueError(f"form={self.form!r} does not match the env's form {env_form!r}")
        self.law = TrackingLaw(
            n,
            poles=poles,
            integral=integral,
            feedforward=feedforward,
            action_bound=action_bound,  # type: ignore[arg-type]
            anti_windup=anti_windup,
            form=self.form,
            b_min=b_min,
            rcond_min=rcond_min,
            gain_max=gain_max,
        )
        for name, v in (
            ("excitation_amplitude", excitation_amplitude),
            ("dither", dither),
            ("handover_inflation", handover_inflation),
            ("reset_threshold", reset_threshold),
            ("reset_inflation", reset_inflation),
            ("process_noise_gain", process_noise_gain),
            ("b_min", b_min),
            ("rcond_min", rcond_min),
        ):
            if (
                isinstance(v, bool)
                or not isinstance(v, (int, float))
                or not (math.isfinite(v) and v >= 0)
            ):
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        if excitation_limit is not None and not excitation_limit > 0:
            raise ValueError(f"excitation_limit must be > 0 or None, got {excitation_limit!r}")
        self.excitation_steps = _nonneg_int(excitation_steps, "excitation_steps")
        self.excitation_amplitude = float(excitation_amplitude)
        self.excitation_limit = None if excitation_limit is None else float(excitation_limit)
        self.dither = float(dither)
        self.covariance_reset = bool(covariance_reset)
        self.reset_threshold = float(reset_threshold)
        self.reset_holdoff = _nonneg_int(reset_holdoff, "reset_holdoff")
        self.reset_inflation = float(reset_inflation)
        self.process_noise_gain = float(process_noise_gain)
        self.filtered = bool(filtered)
        self.seed = int(seed)
        self.record = bool(record)
        self._prbs = _PRBS(self.seed)
        # -- estimator ---------------------------------------------------------------------
        self._adaptive_q = isinstance(process_noise, str)
        if self._adaptive_q:
            if process_noise != "adaptive":
                raise ValueError(
                    f"process_noise must be a number >= 0 or 'adaptive', got {process_noise!r}"
                )
            process_noise = 1e-12  # non-zero: keeps the filter's process-noise path switched on
        self._est_args: dict[str, Any] = {
            "p": p,
            "p0": p0,
            "forgetting": forgetting,
            "process_noise": process_noise,
            "measurement_noise": measurement_noise,
            "extra": dict(estimator_kwargs or {}),
        }
        self._factory = isinstance(estimator, str)
        self.estimator_name, self.estimator = self._build_estimator(estimator)
        self.bootstrap = bool(bootstrap) and self._factory
        self.bootstrap_window = _nonneg_int(
            4 * n if bootstrap_window is None else bootstrap_window, "bootstrap_window"
        )
        if self.bootstrap and self.bootstrap_window < 2 * n:
            raise ValueError(
                f"bootstrap_window must be >= 2n = {2 * n} (one sample per parameter), got "
                f"{self.bootstrap_window}"
            )
        self.handover_inflation = float(handover_inflation)
        self._boot = _EquationErrorRLS(n, 1e4)
        # Replay buffer: the whole excitation phase, or the last 50 samples for restarts.
        self._hist_len = max(self.excitation_steps, self.bootstrap_window, 50)
        self._A = companion_A(np.zeros(n), self.form)
        self._q_floor = 1e-12 * np.eye(n)
        self._reset_state()

    # ------------------------------------------------------------------ public views
    @property
    def theta(self) -> NDArray:
        """Current estimate ``theta_hat(t) = [a_hat; b_hat]`` (this env's canonical form)."""
        return np.asarray(self.estimator.theta, dtype=float).copy()

    @property
    def x_hat(self) -> NDArray:
        """The estimator's latest state estimate."""
        return np.asarray(self.estimator.x_hat, dtype=float).copy()

    @property
    def K(self) -> NDArray:
        """Gain in use ``[K_x, k_i]`` (zeros before the first good design)."""
        return self.law.K.copy()

    @property
    def poles(self) -> NDArray:
        """Desired closed-loop poles."""
        return self.law.poles.copy()

    @property
    def diagnostics(self) -> dict[str, Any]:
        """Snapshot: estimates, gains, counters and flags of the last step (cheap)."""
        return {
            "t": self.t,
            "theta": self.theta,
            "K": self.K,
            "N": self.law.N,
            "xi": self.law.xi,
            "has_gain": self.law.has_gain,
            "design_ok": self.design_ok,
            "open_loop": self.open_loop,
            "saturated": self.law.saturated,
            "n_rejected": self.n_rejected,
            "rejections": dict(self.rejections),
            "n_saturated": self.n_saturated,
            "n_covariance_resets": self.n_covariance_resets,
            "n_handovers": self.n_handovers,
            "n_excitation_aborts": self.n_excitation_aborts,
            "excitation_end": self._excitation_end,
            "estimator": self.estimator_name,
        }

    @property
    def history(self) -> dict[str, NDArray]:
        """Per-step log as arrays (empty unless ``record=True``).

        Keys: ``y``, ``r``, ``u`` (applied), ``theta`` (``theta_hat(t)``), ``K`` (gain in use),
        ``N``, ``poles`` (sorted eigenvalues of the estimated closed loop with the gain in use;
        NaN before the first gain), ``design_ok``, ``open_loop``, ``saturated``, ``reset``.
        """
        return {k: np.asarray(v) for k, v in self._log.items()}

    # ------------------------------------------------------------------ construction helpers
    def _build_estimator(self, estimator: str | Any, **override: Any) -> tuple[str, Any]:
        n = self.n
        if not isinstance(estimator, str):
            for attr in ("update", "predict", "reset", "theta", "x_hat"):
                if not hasattr(estimator, attr):
                    raise TypeError(
                        f"estimator must be a name or an object with update/predict/reset/theta/"
                        f"x_hat; {type(estimator).__name__} has no {attr!r}"
                    )
            if np.size(estimator.theta) != 2 * n:
                raise ValueError(
                    f"estimator has {np.size(estimator.theta)} parameters, expected 2n={2 * n}"
                )
            return type(estimator).__name__, estimator
        from stcgym.adaptive.recursive import make_estimator, parse_name

        state, _, rule = parse_name(estimator)  # ValueError naming the valid algorithms
        args = self._est_args
        kwargs: dict[str, Any] = {
            "p0": args["p0"],
            "form": self.form,
            "forgetting": args["forgetting"],
        }
        if rule in ("MISG", "MILS"):
            kwargs["p"] = args["p"]
        if state == "KF":
            kwargs["process_noise"] = args["process_noise"]
            kwargs["measurement_noise"] = args["measurement_noise"]
        kwargs.update(args["extra"])
        kwargs.update(override)
        est = make_estimator(estimator, n, **kwargs)
        return est.name, est

    # ------------------------------------------------------------------ state
    def _reset_state(self) -> None:
        if self._factory:
            _, self.estimator = self._build_estimator(self.estimator_name)
        else:
            self.estimator.reset()
        self._boot.reset()
        self.law.clear_gain()
        self.law.reset()
        self._prbs.reset()
        self.t = 0
        self.open_loop = True
        self.design_ok = False
        self.n_rejected = 0
        self.rejections: dict[str, int] = {}
        self.last_rejection = ""
        self.n_covariance_resets = 0
        self.n_handovers = 0
        self.n_saturated = 0
        self.n_excitation_aborts = 0
        self._excitation_end = self.excitation_steps
        self._ewma_short = 0.0
        self._ewma_long = 0.0
        self._last_reset_t = 0
        self._closed_t = -1
        self._u_hist = np.zeros(self._hist_len)  # ring buffers of applied u and measured y
        self._y_hist = np.zeros(self._hist_len)
        self._log: dict[str, list] = {k: [] for k in _LOG_KEYS}

    def _replay_window(self, t: int) -> tuple[NDArray, NDArray]:
        """The stored ``u``, ``y`` of steps ``max(0, t - hist_len) .. t - 1`` in time order."""
        k = min(t, self._hist_len)
        idx = (np.arange(t - k, t)) % self._hist_len
        return self._u_hist[idx], self._y_hist[idx]

    def _handover(self, t: int) -> None:
        """Rebuild the paper's estimator from the bootstrap estimate (see the class docstring).

        ``theta_hat(0)`` = the equation-error estimate (numerator converted to Markov parameters
        for the observability form), ``P(0)`` = its covariance times ``handover_inflation``.
        """
        n = self.n
        boot = self._boot
        self.n_handovers += 1
        # Checked before the conversion, which rejects non-finite input with an exception.
        if not np.all(np.isfinite(boot.theta)):  # pragma: no cover - RLS on finite data
            return
        a, beta = boot.theta[:n].copy(), boot.theta[n:].copy()
        if self.form == "observability":
            beta = observer_to_observability_b(a, beta)
        theta0 = np.concatenate([a, beta])
        P0 = None
        if self.estimator_name.split("-")[-1] in ("RLS", "MILS"):
            P0 = 0.5 * (boot.P + boot.P.T) * self.handover_inflation
        self._restart(t, theta0, P0)

    def _restart(self, t: int, theta0: NDArray, P0: NDArray | None, y: float | None = None) -> None:
        """Rebuild the paper's estimator at ``theta0`` / ``P0`` and replay the stored window with
        adaptation off, so that its state estimate and regressors are consistent with the data.
        With ``y`` the restart happens after ``y(t)`` was measured: it is fed in as well."""
        n = self.n
        override: dict[str, Any] = {"theta0": theta0}
        if P0 is not None:
            P0 = 0.5 * (P0 + P0.T)
            if "-D-" in self.estimator_name:  # D- rules: separate a and b covariances
                P0[:n, n:] = 0.0
                P0[n:, :n] = 0.0
            if not np.all(np.isfinite(P0)) or np.min(np.linalg.eigvalsh(P0)) <= 0.0:
                P0 = 1e-2 * np.eye(2 * n)
            override["P0"] = P0
        u_w, y_w = self._replay_window(t)
        if u_w.size < t and self.estimator_name.startswith("KF"):
            # The window does not start at the known initial state x(0) = 0: vague prior.
            override["P1_init"] = 1e4 * np.eye(n)
        _, est = self._build_estimator(self.estimator_name, **override)
        if u_w.size:
            enabled = est.enabled
            est.enabled = False
            est.run(u_w, y_w)
            est.enabled = enabled
        if y is not None:
            est.update(y)
        self.estimator = est

    # ------------------------------------------------------------------ the step
    def _act(self, obs: NDArray) -> float:
        y, r = float(obs[0]), float(obs[1])
        t = self.t
        n = self.n
        # -- 0. excitation phase and bootstrap -----------------------------------------------
        if (
            t < self._excitation_end
            and self.excitation_limit is not None
            and abs(y) > self.excitation_limit
        ):
            self._excitation_end = t  # e.g. an unstable plant running away: stop exciting
            self.n_excitation_aborts += 1
        booting = self.bootstrap and self.n_handovers == 0
        if booting:
            self._boot.update(y)
            if t >= max(self._excitation_end, self.bootstrap_window):
                self._handover(t)
        est = self.estimator
        theta = est.update(y)
        reset_now = self._detect_change(est, t, y)
        if reset_now:
            est = self.estimator
            theta = est.theta
        # -- 1. estimated model (59)-(60) and gains ------------------------------------------
        A = self._A
        if self.form == "observer":
            A[:, 0] = -theta[:n]
        else:
            A[-1, :] = -theta[n - 1 :: -1]
        if self.bootstrap and self.n_handovers == 0:
            ok, reason = False, "bootstrap"
        else:
            ok, reason = self.law.design(A, theta[n:])
        self.design_ok = ok
        if not ok:
            self.n_rejected += 1
            self.rejections[reason] = self.rejections.get(reason, 0) + 1
            self.last_rejection = reason
        # -- 2. control ----------------------------------------------------------------------
        self.open_loop = t < self._excitation_end or not self.law.has_gain
        if self.open_loop:
            u = self.excitation_amplitude * self._prbs()
            bound = self.law.action_bound
            if bound is not None and abs(u) > bound:
                u = math.copysign(bound, u)
            self.law.saturated = False
        else:
            if self._closed_t < 0:
                self._closed_t = t
            x = est.x_hat
            kf = self._kf if self.filtered else None
            if kf is not None:
                # x(t|t) = x(t|t-1) + P1 c^T (y - c x) / (R + c P1 c^T): the Kalman prediction
                # corrected by the sample just measured (one sample less delay in the loop).
                P1c = kf.P1[:, 0]
                x = x + P1c * ((y - x[0]) / (kf.R + P1c[0]))
            exc = self.dither * self._prbs() if self.dither > 0 else 0.0
            u = self.law.control(x, y, r, exc)
            self.n_saturated += self.law.saturated
        # -- 3. state step with the applied input --------------------------------------------
        if self._adaptive_q:
            self._set_process_noise(est, y, u)
        est.predict(u)
        if booting:
            self._boot.push(y, u)
        if self._factory:
            i = t % self._hist_len
            self._u_hist[i] = u
            self._y_hist[i] = y
        self.t = t + 1
        if self.record:
            self._record(y, r, u, theta, ok, reset_now)
        return u

    def _set_process_noise(self, est: Any, y: float, u: float) -> None:
        """Kalman process noise from the parameter uncertainty (see the class docstring).

        Row ``k`` of the model error is ``w_k = -(a_k - a_hat_k) x_1 + (b_k - b_hat_k) u``; with
        ``Cov(theta - theta_hat) = R P`` (least-squares ``P`` in units of the noise variance):
        ``Q = R [x1^2 P_aa - x1 u (P_ab + P_ba) + u^2 P_bb]`` (observer form; used as a scale for
        the observability form too), with ``x_1 ~ y``.
        """
        kf = self._kf
        if kf is None:
            return
        P = est.P
        if P is None:  # gradient rules carry no covariance: keep the constant floor
            return
        n = self.n
        Pab = P[:n, n:]
        Q = (y * y) * P[:n, :n] + (u * u) * P[n:, n:] - (y * u) * (Pab + Pab.T)
        Q *= kf.R * self.process_noise_gain
        Q += self._q_floor
        kf.Q = Q

    def _detect_change(self, est: Any, t: int, y: float) -> bool:
        """Innovation-variance change detector; restarts the estimator on an alarm."""
        e = float(est.e) if hasattr(est, "e") else float(np.ravel(est.innovation)[0])
        e2 = e * e
        long_prev = self._ewma_long
        self._ewma_short += 0.1 * (e2 - self._ewma_short)
        self._ewma_long += 0.01 * (e2 - self._ewma_long)
        if not (
            self.covariance_reset
            and self._closed_t >= 0
            and t - self._closed_t > self.reset_holdoff
            and t - self._last_reset_t > self.reset_holdoff
            and self._ewma_short > self.reset_threshold * long_prev
        ):
            return False
        self._last_reset_t = t
        self.n_covariance_resets += 1
        P = getattr(est, "P", None)
        if self._factory and P is not None:
            self._restart(t, est.theta, self.reset_inflation * P, y)
        else:  # gradient rules or a user estimator: back to its own P(0) / r(0)
            rule = getattr(est, "rule", None)
            if rule is not None:
                rule.reset()
        return True

    def _record(self, y: float, r: float, u: float, theta: NDArray, ok: bool, reset: bool) -> None:
        log = self._log
        law = self.law
        log["y"].append(y)
        log["r"].append(r)
        log["u"].append(u)
        log["theta"].append(theta)
        log["K"].append(law.K.copy())
        log["N"].append(law.N)
        log["design_ok"].append(ok)
        log["open_loop"].append(self.open_loop)
        log["saturated"].append(law.saturated)
        log["reset"].append(reset)
        if law.has_gain:
            b_hat = theta[self.n :]
            Ad, bd = augment_integral(self._A, b_hat) if law.integral else (self._A, b_hat)
            poles = np.sort_complex(np.linalg.eigvals(Ad - np.outer(bd, law.K)))
        else:
            poles = np.full(law.m, np.nan + 0j)
        log["poles"].append(poles)

    @property
    def _kf(self) -> Any:
        se = getattr(self.estimator, "state_estimator", None)
        return se if (se is not None and hasattr(se, "P1") and hasattr(se, "R")) else None


def _nonneg_int(value: Any, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise ValueError(f"{name} must be a non-negative integer, got {value!r}")
    return int(value)
