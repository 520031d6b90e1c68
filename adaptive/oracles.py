"""Known-model controllers used as scoring oracles for the self-tuning regulator.

Both see only what the envs observe, ``[y(t), r(t)]``, and estimate the state with a Kalman
filter on the *true* model; they differ from :class:`~stcgym.adaptive.controller.
SelfTuningController` only in knowing ``(a, b)``. Both run the same compiled lane step
(:func:`~stcgym.adaptive.kernels.design.known_model_propose`: the Kalman correction, the
regulator's tracking law :func:`~stcgym.adaptive.kernels.design.track`, the Kalman time update
``kalman_step``) and differ in their design and filter tuning:

* :class:`KnownModelController` places the regulator's poles on the known ``(A, b)``
  (:func:`~stcgym.adaptive.kernels.design.place_design`: the same integral action, feed-forward,
  saturation and anti-windup), with the regulator's kind of state estimate: the seed paper's
  time-varying Kalman filter (Ding & Ma 2014, eq. (66)-(72): ``Q = 0``, ``R = 1``,
  ``P1(1) = I``), corrected by the current sample. With ``Q = 0`` the filter is optimal for the
  envs' noise model (output noise only), so the oracle's state estimate converges to the true
  state: the ratio of the regulator's cost to this oracle's is the price of not knowing the
  parameters.
* :class:`LQGController` is the optimal linear design for the env's own cost
  ``(y - r)^2 + rho u^2``: the LQ gain of the (optionally integral-augmented) model solved to
  convergence (:func:`~stcgym.adaptive.kernels.design.lq_solve`, ``Q = c^T c``, ``R = rho``),
  the reference feed-forward of the steady state, and the steady-state Kalman filter (the same
  Riccati solver on the dual problem) used as a current estimator ``x(t|t)``.

Both implement the SB3 policy protocol (:mod:`stcgym.adaptive.policy`) for one plant
(``num_envs=None``; a batch of observations then runs freshly reset copies, one per row) or for
``num_envs=B`` plants with their own true parameters (``a``, ``b`` of shape ``(B, n)``), stepped
together by a ``prange`` over lanes. A lane record holds all the state, so the oracles pickle
and deep-copy with identical continuation, and a step whose result would not be finite is
rejected as a whole: no lane changes.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.kernels import design as _design
from stcgym.adaptive.kernels.state_estimation import kalman_step
from stcgym.adaptive.placement import characteristic_coefficients, check_poles
from stcgym.adaptive.policy import episode_starts, validate_observation
from stcgym.envs.canonical import as_finite_vector, check_form
from stcgym.envs.compiled import FixedTypes, Layout

__all__ = ["KalmanObserver", "KnownModelController", "LQGController"]

# the single-plant step with its argument types looked up once (see FixedTypes)
_known_model_propose = FixedTypes(_design.known_model_propose)
_known_model_commit = FixedTypes(_design.known_model_commit)

#: Default closed-loop pole of the known-model controller (as the regulator's).
DEFAULT_POLE = 0.5
#: Largest accepted noise level, weight or covariance scale: squares and products of settings
#: beyond it overflow in the filter and design, so such a value is an input error, not a setting.
MAX_SETTING = 1e100


def _check_positive(
    value: Any, name: str, *, allow_none: bool = False, limit: float = MAX_SETTING
) -> float | None:
    """A number in ``[1 / limit, limit]`` (``None`` passes when allowed)."""
    if value is None and allow_none:
        return None
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a positive number, got {value!r}") from exc
    if not (1.0 / limit <= v <= limit):
        raise ValueError(f"{name} must be a number in [{1.0 / limit:g}, {limit:g}], got {value!r}")
    return v


def _check_nonnegative(value: Any, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a number >= 0, got {value!r}") from exc
    if not (0 <= v <= MAX_SETTING):
        raise ValueError(f"{name} must be a number in [0, {MAX_SETTING:g}], got {value!r}")
    return v


def _check_num_envs(num_envs: Any) -> int | None:
    if num_envs is None:
        return None
    if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
        raise ValueError(f"num_envs must be None or a positive integer, got {num_envs!r}")
    return int(num_envs)


def _lane_parameters(
    a: ArrayLike, b: ArrayLike, num_lanes: int, *, batched: bool = True
) -> tuple[NDArray, NDArray]:  # (lanes, n) each
    """``a``, ``b`` as ``(num_lanes, n)``: one vector for every lane or one row per lane
    (``batched=False``: a single plant, vectors only)."""
    rows = []
    for name, value in (("a", a), ("b", b)):
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{name} must be a sequence of real numbers, got {value!r}") from exc
        if arr.ndim <= 1:
            arr = as_finite_vector(arr, name)[None, :]
        elif not batched:
            raise ValueError(
                f"{name} must be one-dimensional (n,) when num_envs is None, got shape {arr.shape}"
            )
        elif arr.ndim != 2 or arr.shape[0] != num_lanes or arr.shape[1] == 0:
            raise ValueError(
                f"{name} must have shape (n,) or (num_envs, n) = ({num_lanes}, n), "
                f"got shape {arr.shape}"
            )
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} must be finite")
        rows.append(np.broadcast_to(arr, (num_lanes, arr.shape[1])).copy())
    a_l, b_l = rows
    if a_l.shape[1] != b_l.shape[1]:
        raise ValueError(
            f"a and b must have the same length n (theta = [a1..an, b1..bn]), "
            f"got len(a)={a_l.shape[1]}, len(b)={b_l.shape[1]}"
        )
    return a_l, b_l


class _KnownModelLoop(ABC):
    """Lane records and the SB3-style ``predict`` shared by the two oracles.

    Subclasses set ``n``, ``form``, the flags and call :meth:`_build` with per-lane models,
    designs and filter settings; the state lives in ``self._F`` (``(lanes, size)``, one row per
    plant) and, for ``num_envs=None``, in ``self._rows`` (the copies serving a batch of
    observations).
    """

    #: Length of one observation: the envs observe ``[y(t), r(t)]``.
    obs_dim: int = 2

    def _build(self, num_envs: int | None, a: NDArray, b: NDArray) -> None:
        n = self.n
        lay = Layout()
        for name, shape in (
            ("A", (n, n)),
            ("b", (n,)),
            ("Q", (n, n)),
            ("R", ()),
            ("x", (n,)),
            ("x_filt", (n,)),
            ("P", (n, n)),
            ("innov", ()),
            ("gain", (_design.gain_size(n),)),
            ("law", (_design.LAW_SIZE,)),
            ("t", ()),
            # initial values restored by reset()
            ("A0", (n, n)),
            ("b0", (n,)),
            ("P0", (n, n)),
            ("gain0", (_design.gain_size(n),)),
        ):
            lay.add(name, shape)
        self._layout = lay
        self._at = lay.record(_design.OracleRecord)
        self.num_envs = num_envs
        lanes_ = a.shape[0]
        F = lay.empty(lanes_)
        self._F = F
        lay.view(F, "R")[:] = self.R
        lay.view(F, "Q")[:] = self._process_noise(b)
        gains = self._design_lanes(a, b, "a, b")
        A = self._model_matrices(a, b)
        lay.view(F, "A0")[:] = A
        lay.view(F, "b0")[:] = b
        lay.view(F, "gain0")[:] = gains
        lay.view(F, "P0")[:] = self._initial_covariance(a, b)
        self._a, self._b = a.copy(), b.copy()
        self._a0, self._b0 = a.copy(), b.copy()
        self._rows: NDArray | None = None
        self._reset_records(F)

    # -- hooks -----------------------------------------------------------------------------
    @abstractmethod
    def _design_batch(self, thetas: NDArray, gains: NDArray, status: NDArray) -> None:
        """Design every lane of ``thetas`` ``(lanes, 2n)`` into ``gains``, codes into ``status``."""

    @abstractmethod
    def _process_noise(self, b: NDArray) -> NDArray:
        """Kalman filter process-noise covariance ``Q`` (``(n, n)`` or per lane)."""

    @abstractmethod
    def _initial_covariance(self, a: NDArray, b: NDArray) -> NDArray:
        """Kalman filter covariance ``P1`` at reset, per lane (``a``, ``b``: ``(lanes, n)``)."""

    # -- records ---------------------------------------------------------------------------
    @property
    def _form_code(self) -> int:
        return _design.OBSERVER if self.form == "observer" else _design.OBSERVABILITY

    def _model_matrices(self, a: NDArray, b: NDArray) -> NDArray:
        """Canonical ``A`` of every lane, ``(lanes, n, n)`` (lane function ``model_matrices``)."""
        A = np.empty((a.shape[0], self.n, self.n))
        thetas = np.hstack((a, b))
        if a.shape[0] == 1:  # one plant: the lane function itself (no parallel compile)
            _design.model_matrices(thetas[0], self._form_code, A[0], b[0].copy())
        else:
            _design.model_matrices_lanes(thetas, self._form_code, A, b.copy())
        return A

    def _design_lanes(self, a: NDArray, b: NDArray, name: str) -> NDArray:
        """Gain records for every lane's model; ``ValueError`` (nothing changed) if one fails."""
        gains = np.zeros((a.shape[0], _design.gain_size(self.n)))
        status = np.zeros(a.shape[0], dtype=np.int64)
        self._design_batch(np.hstack((a, b)), gains, status)
        bad = np.flatnonzero(status)
        if bad.size:
            i = int(bad[0])
            lane = "" if a.shape[0] == 1 else f" (lane {i}; {bad.size} lanes fail)"
            raise ValueError(f"{name}{lane}: {self._failure(int(status[i]))}")
        return gains

    def _failure(self, status: int) -> str:
        return f"no design on the given model: {_design.STATUS_NAMES[status]}"

    def _reset_records(self, F: NDArray, rows: NDArray | slice = slice(None)) -> None:
        lay = self._layout
        for src, dst in (("A0", "A"), ("b0", "b"), ("P0", "P"), ("gain0", "gain")):
            lay.view(F, dst)[rows] = lay.view(F, src)[rows]
        for name in ("x", "x_filt", "innov", "law", "t"):
            lay.view(F, name)[rows] = 0.0

    # -- public state ----------------------------------------------------------------------
    def _lane0(self, value: NDArray) -> NDArray:
        return value[0].copy() if self.num_envs is None else value.copy()

    @property
    def a(self) -> NDArray:
        """True ``a`` in force (``(n,)``, or ``(num_envs, n)`` when batched)."""
        return self._lane0(self._a)

    @property
    def b(self) -> NDArray:
        """True ``b`` in force (``(n,)``, or ``(num_envs, n)`` when batched)."""
        return self._lane0(self._b)

    @property
    def t(self) -> int | NDArray:
        """Steps taken since the last reset (per lane when batched)."""
        t = self._layout.view(self._F, "t").astype(np.int64)
        return int(t[0]) if self.num_envs is None else t

    @property
    def xi(self) -> float | NDArray:
        """Integral of the tracking error ``xi(t)`` (per lane when batched)."""
        xi = self._layout.view(self._F, "law")[:, _design.LAW.xi].copy()
        return float(xi[0]) if self.num_envs is None else xi

    @property
    def x_hat(self) -> NDArray:
        """State estimate ``x(t|t-1)`` of the Kalman filter (per lane when batched)."""
        return self._lane0(self._layout.view(self._F, "x"))

    @property
    def K(self) -> NDArray:
        """State-feedback gain ``[K_x, k_i]`` (``k_i`` only with integral action)."""
        m = self.n + int(self.integral)
        return self._lane0(self._layout.view(self._F, "gain")[:, :m])

    @property
    def N(self) -> float | NDArray:
        """Reference feed-forward gain ``N``."""
        N = self._layout.view(self._F, "gain")[:, self.n + 1].copy()
        return float(N[0]) if self.num_envs is None else N

    def set_model(self, a: ArrayLike, b: ArrayLike, lanes: ArrayLike | None = None) -> None:
        """Switch to new true parameters (e.g. at a scheduled jump); the state estimate is kept.

        ``a``, ``b``: shape ``(n,)`` for every selected lane, or one row per selected lane.
        ``lanes`` (batched only): a boolean mask of ``num_envs`` entries or lane indices.
        Raises ``ValueError`` (nothing changed) when a model cannot be designed on.
        """
        idx = self._lane_index(lanes)
        a_l, b_l = _lane_parameters(a, b, idx.size)
        if a_l.shape[1] != self.n:
            raise ValueError(f"new parameters must have order {self.n}, got {a_l.shape[1]}")
        # everything is computed before the first assignment: a failure changes nothing
        new = {
            "A": self._model_matrices(a_l, b_l),
            "b": b_l,
            "gain": self._design_lanes(a_l, b_l, "set_model"),
        }
        new.update(self._model_extras(a_l, b_l))
        targets = [(self._F, idx)]
        if self._rows is not None:  # the copies serving a batch of observations
            targets.append((self._rows, slice(None)))
        for F, rows in targets:
            for name, value in new.items():
                self._layout.view(F, name)[rows] = value
        self._a[idx], self._b[idx] = a_l, b_l

    def _model_extras(self, a: NDArray, b: NDArray) -> dict[str, NDArray]:
        """Hook: other record fields a new model changes (the LQG filter's noise and P)."""
        return {}

    def _lane_index(self, lanes: ArrayLike | None) -> NDArray:
        B = self._F.shape[0]
        if lanes is None:
            return np.arange(B)
        if self.num_envs is None:
            raise ValueError("lanes is only for batched oracles (num_envs=B)")
        arr = np.asarray(lanes)
        if arr.dtype == bool:
            if arr.shape != (B,):
                raise ValueError(
                    f"lanes as a mask must have one bool per lane ({B}), got shape {arr.shape}"
                )
            return np.flatnonzero(arr)
        if arr.ndim > 1 or not np.issubdtype(arr.dtype, np.integer):
            raise ValueError(f"lanes must be a boolean mask or integer lane indices, got {lanes!r}")
        arr = arr.reshape(-1).astype(np.int64)
        if arr.size and (arr.min() < 0 or arr.max() >= B):
            raise ValueError(f"lanes must lie in [0, {B}), got {arr.tolist()}")
        return arr

    # -- protocol --------------------------------------------------------------------------
    def reset(self, lanes: ArrayLike | None = None) -> None:
        """Forget the episode (initial model restored, filter and integrator zeroed).

        ``lanes`` (batched only): reset just those lanes (mask or indices).
        """
        idx = self._lane_index(lanes)
        self._reset_records(self._F, idx)
        if lanes is None:
            self._rows = None
            self._a[:], self._b[:] = self._a0, self._b0
        else:
            self._a[idx], self._b[idx] = self._a0[idx], self._b0[idx]

    def predict(
        self,
        observation: ArrayLike,
        state: Any = None,
        episode_start: ArrayLike | bool | None = None,
        deterministic: bool = True,
    ) -> tuple[NDArray, Any]:
        """SB3-style step: ``(actions, state)``; actions ``(1,)`` for one observation
        ``[y, r]``, ``(B, 1)`` for ``B`` observations. ``episode_start`` (a bool or one per
        observation) resets those lanes first. Everything is validated, and the whole step
        computed, before any state changes: a rejected call leaves the oracle as it was.
        """
        obs, single = validate_observation(observation, self.obs_dim)
        batch = obs.shape[0]
        if self.num_envs is not None and batch != self.num_envs:
            raise ValueError(
                f"observation must have one row per lane: expected {self.num_envs} "
                f"observations, got {batch}"
            )
        starts = episode_starts(episode_start, batch)
        if self.num_envs is None and not single:
            if self._rows is None or self._rows.shape[0] != batch:
                # one freshly reset copy of the single plant's record per observation row
                fresh = self._F.copy()
                self._reset_records(fresh)
                self._rows = np.repeat(fresh, batch, axis=0)
            F = self._rows
        else:
            F = self._F
        saved = F[starts].copy() if starts.any() else None
        if saved is not None:
            self._reset_records(F, np.flatnonzero(starts))
        u = self._step(F, obs[:, 0].copy(), obs[:, 1].copy())
        if u is None:
            if saved is not None:
                F[starts] = saved
            raise ValueError(
                "observation drives the oracle's state estimate to non-finite values "
                f"(got {obs[0] if single else obs}); the state was left unchanged"
            )
        return (u if single else u[:, None]), state

    def _step(self, F: NDArray, y: NDArray, r: NDArray) -> NDArray | None:
        """Propose the step of every lane, commit only if all are finite (else ``None``)."""
        B, n = F.shape[0], self.n
        S = np.empty((B, _design.oracle_scratch_size(n)))
        bound = math.inf if self.action_bound is None else self.action_bound
        flags = (bool(self.filtered), bool(self.integral), bool(self.anti_windup), float(bound))
        u = np.empty(B)
        if B == 1:  # one plant: the lane function itself (no thread-pool start-up)
            if _known_model_propose(F[0], self._at, n, S[0], float(y[0]), float(r[0]), *flags):
                return None
            u[0] = _known_model_commit(F[0], self._at, n, S[0])
            return u
        status = np.zeros(B, dtype=np.int64)
        _design.known_model_propose_lanes(F, self._at, n, S, y, r, *flags, status)
        if status.any():
            return None
        _design.known_model_commit_lanes(F, self._at, n, S, u)
        return u


class KnownModelController(_KnownModelLoop):
    """The self-tuning regulator's design applied to the known parameters ``(a, b)``.

    Parameters
    ----------
    a, b
        True plant parameters ``theta = [a; b]`` in the canonical ``form``: shape ``(n,)``, or
        ``(num_envs, n)`` for one plant per lane.
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
    num_envs
        ``None`` (one plant) or the number of lanes ``B``.

    Raises
    ------
    ValueError
        Malformed settings, or a model the poles cannot be placed on (uncontrollable, a zero at
        ``z = 1`` with feed-forward on).
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
        num_envs: int | None = None,
    ) -> None:
        super().__init__()
        num = _check_num_envs(num_envs)
        a_l, b_l = _lane_parameters(a, b, 1 if num is None else num, batched=num is not None)
        self.n = a_l.shape[1]
        self.form = check_form(form)
        self.integral = bool(integral)
        self.feedforward = bool(feedforward)
        self.anti_windup = bool(anti_windup)
        self.filtered = bool(filtered)
        self.action_bound = _check_positive(action_bound, "action_bound", allow_none=True)
        self.poles = check_poles(DEFAULT_POLE if poles is None else poles, self.n + self.integral)
        self._alpha = characteristic_coefficients(self.poles)
        self._q = _check_nonnegative(process_noise, "process_noise")
        self.R = _check_positive(measurement_noise, "measurement_noise")
        self._P0 = _check_positive(P0, "P0")
        self._safe = _design.safe_set()
        self._build(num, a_l, b_l)

    def _design_batch(self, thetas: NDArray, gains: NDArray, status: NDArray) -> None:
        args = (self._form_code, self.integral, self.feedforward, self._alpha, self._safe)
        if thetas.shape[0] == 1:
            work = np.zeros(_design.work_size(self.n))
            status[0] = _design.place_design(thetas[0], *args, gains[0], work)
        else:
            _design.place_design_lanes(thetas, *args, gains, status)

    def _failure(self, status: int) -> str:
        return f"cannot place the poles on the given model: {_design.STATUS_NAMES[status]}"

    def _process_noise(self, b: NDArray) -> NDArray:
        return self._q * np.eye(self.n)

    def _initial_covariance(self, a: NDArray, b: NDArray) -> NDArray:
        return self._P0 * np.eye(self.n)


class LQGController(_KnownModelLoop):
    """LQG tracking controller on the known model.

    Minimises ``sum (y - r)^2 + rho u^2`` for a constant reference:
    ``u = N r - K_x x(t|t) - k_i xi`` with ``N = u_ss + K_x x_ss`` (the model's steady state for a
    unit output) and ``K`` the LQ gain for ``Q = c^T c``, ``R = rho``; with ``integral=True`` the
    integral of ``r - y`` joins the state with weight ``integral_weight``. Both gains come from
    :func:`~stcgym.adaptive.kernels.design.lq_solve` (doubling to convergence; tested against
    python-control's ``dlqr``). The state comes from the steady-state Kalman filter for process
    noise ``input_noise_std^2 b b^T + process_noise_floor I`` (a small input-disturbance model
    keeps the filter alive on stable plants) and measurement variance ``noise_std^2``, used as a
    current estimator ``x(t|t)``: the filter starts at (and stays on) the stabilising solution
    of the dual Riccati equation.

    Parameters
    ----------
    a, b
        True parameters, ``(n,)`` or ``(num_envs, n)``. ``form`` as elsewhere.
    control_cost
        ``rho``, the weight of ``u^2`` (match the env's ``control_cost``); must be > 0.
    noise_std, input_noise_std, process_noise_floor
        Noise model of the Kalman filter (output noise std > 0, input-disturbance std and floor
        >= 0).
    integral, integral_weight
        Optional integral state and its weight in the LQ cost (off by default: the oracle knows
        the model, so the feed-forward is exact).
    action_bound
        Saturation (default 10 as the envs), with conditional integration as anti-windup.
    num_envs
        ``None`` (one plant) or the number of lanes ``B``.

    Raises
    ------
    ValueError
        Malformed settings, or a plant without a stabilising LQ design (an unstable mode the
        input cannot reach, e.g. ``LQGController([-3, 2], [1, -2])``: the pole at 2 is cancelled
        by a zero) or without a steady state for a constant reference (a zero at ``z = 1``).
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
        num_envs: int | None = None,
    ) -> None:
        super().__init__()
        num = _check_num_envs(num_envs)
        a_l, b_l = _lane_parameters(a, b, 1 if num is None else num, batched=num is not None)
        self.n = a_l.shape[1]
        self.form = check_form(form)
        self.integral = bool(integral)
        self.feedforward = True
        self.anti_windup = True
        self.filtered = True
        self.control_cost = _check_positive(control_cost, "control_cost (rho)")
        # its square is the filter's measurement variance: keep that in range too
        self.noise_std = _check_positive(noise_std, "noise_std", limit=math.sqrt(MAX_SETTING))
        self.input_noise_std = _check_nonnegative(input_noise_std, "input_noise_std")
        if self.input_noise_std > math.sqrt(MAX_SETTING):
            raise ValueError(
                f"input_noise_std must be at most {math.sqrt(MAX_SETTING):g}, "
                f"got {input_noise_std!r}"
            )
        self.process_noise_floor = _check_nonnegative(process_noise_floor, "process_noise_floor")
        self.integral_weight = (
            _check_positive(integral_weight, "integral_weight") if self.integral else 0.0
        )
        self.action_bound = _check_positive(action_bound, "action_bound", allow_none=True)
        self.R = self.noise_std**2
        self._weights = np.array([1.0, self.integral_weight, self.control_cost])
        self._safe = _design.safe_set()
        self._build(num, a_l, b_l)

    def _design_batch(self, thetas: NDArray, gains: NDArray, status: NDArray) -> None:
        m = self.n + int(self.integral)
        Ps = np.zeros((thetas.shape[0], m, m))
        args = (self._form_code, self.integral, True, self._weights, self._safe)
        if thetas.shape[0] == 1:
            work = np.zeros(_design.solve_work_size(self.n))
            status[0] = _design.lq_solve(thetas[0], *args, Ps[0], gains[0], work, 1e-12, 64)
        else:
            _design.lq_solve_lanes(thetas, *args, Ps, gains, status, 1e-12, 64)

    def _failure(self, status: int) -> str:
        if status in (_design.UNCONTROLLABLE, _design.NOT_STABILISABLE, _design.NOT_CONVERGED):
            return (
                f"the plant cannot be stabilised by an LQ design ({_design.STATUS_NAMES[status]}: "
                "a mode the input cannot reach, e.g. a pole cancelled by a zero)"
            )
        if status == _design.DC_SINGULAR:
            return "the model has a zero (or pole/zero cancellation) at z = 1: no tracking"
        return f"no LQ design on the given model: {_design.STATUS_NAMES[status]}"

    def _process_noise(self, b: NDArray) -> NDArray:
        return self.input_noise_std**2 * np.einsum(
            "li,lj->lij", b, b
        ) + self.process_noise_floor * np.eye(self.n)

    def _initial_covariance(self, a: NDArray, b: NDArray) -> NDArray:
        """A-priori covariance of the steady-state Kalman filter: the dual Riccati equation."""
        P = np.zeros((a.shape[0], self.n, self.n))
        status = np.zeros(a.shape[0], dtype=np.int64)
        W = np.ascontiguousarray(self._process_noise(b))
        thetas = np.hstack((a, b))
        if a.shape[0] == 1:
            status[0] = _design.kalman_covariance(
                thetas[0], self._form_code, W[0], self.R, P[0], 1e-12, 64
            )
        else:
            _design.kalman_covariance_lanes(
                thetas, self._form_code, W, self.R, P, status, 1e-12, 64
            )
        bad = np.flatnonzero(status)
        if bad.size:
            raise ValueError(
                f"no steady-state Kalman filter for the model (lane {int(bad[0])}): "
                f"{_design.STATUS_NAMES[int(status[bad[0]])]}"
            )
        return P

    def _model_extras(self, a: NDArray, b: NDArray) -> dict[str, NDArray]:
        return {"Q": self._process_noise(b), "P": self._initial_covariance(a, b)}

    @property
    def x_ss(self) -> NDArray:
        """Steady state per unit output of the model in force."""
        return self._lane0(self._steady()[0])

    @property
    def u_ss(self) -> float | NDArray:
        """Steady-state input per unit output of the model in force."""
        u = self._steady()[1]
        return float(u[0]) if self.num_envs is None else u

    def _steady(self) -> tuple[NDArray, NDArray]:
        lay = self._layout
        A, b = lay.view(self._F, "A"), lay.view(self._F, "b")
        x_ss = np.zeros((A.shape[0], self.n))
        u_ss = np.zeros(A.shape[0])
        work = np.zeros(_design.work_size(self.n))
        for i in range(A.shape[0]):
            u_ss[i], _ = _design.steady_state(np.ascontiguousarray(A[i]), b[i], x_ss[i], work)
        return x_ss, u_ss


class KalmanObserver:
    """Time-varying Kalman filter for ``x(t+1) = A x + b u + w``, ``y = x_1 + v``.

    The seed paper's filter (Ding & Ma 2014, eq. (66)-(72)) is the case ``Q = 0``, ``R = 1``,
    ``P1(1) = I``:

        L1(t)   = A P1(t) c^T / (R + c P1(t) c^T)
        P1(t+1) = A P1(t) A^T - L1(t) c P1(t) A^T + Q
        x(t+1)  = A x(t) + b u(t) + L1(t) [y(t) - c x(t)]

    The step is split like the recursive estimators: :meth:`correct` takes ``y(t)`` and returns
    the filtered estimate ``x(t|t)`` (lane function
    :func:`~stcgym.adaptive.kernels.design.filtered_state`); :meth:`predict` takes ``u(t)`` and
    forms ``x(t+1|t)`` (lane function ``kalman_step`` of
    :mod:`stcgym.adaptive.kernels.state_estimation`). When the covariance update is not finite,
    ``P`` is kept, the state advances open loop and ``n_failures`` counts it. ``A`` and ``b`` may
    be replaced between steps (:meth:`set_model`).
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
        A_arr = np.asarray(A, dtype=float)
        if A_arr.ndim != 2 or A_arr.shape[0] != A_arr.shape[1] or A_arr.shape[0] == 0:
            raise ValueError(f"A must be a non-empty square matrix, got shape {A_arr.shape}")
        self.n = A_arr.shape[0]
        self.set_model(A_arr, b)
        q = np.asarray(process_noise, dtype=float)
        Q = q * np.eye(self.n) if q.ndim == 0 else q.copy()
        if Q.shape != (self.n, self.n) or not np.all(np.isfinite(Q)):
            raise ValueError(
                f"process_noise must be a finite number or an ({self.n}, {self.n}) matrix"
            )
        self.Q = np.ascontiguousarray(Q)
        self.R = float(_check_positive(measurement_noise, "measurement_noise"))
        self.P0 = float(_check_positive(P0, "P0"))
        self.reset()

    def set_model(self, A: ArrayLike, b: ArrayLike) -> None:
        A_arr = np.ascontiguousarray(A, dtype=float)
        b_arr = np.ascontiguousarray(b, dtype=float).reshape(-1)
        if A_arr.shape != (self.n, self.n) or b_arr.size != self.n:
            raise ValueError(f"A must be ({self.n}, {self.n}) and b of length {self.n}")
        if not (np.all(np.isfinite(A_arr)) and np.all(np.isfinite(b_arr))):
            raise ValueError("A and b must be finite")
        self.A, self.b = A_arr, b_arr

    def reset(self) -> None:
        self.x = np.zeros(self.n)  # x(t|t-1)
        self.P = self.P0 * np.eye(self.n)
        self.x_filt = self.x.copy()
        self.L1 = np.zeros(self.n)
        self._y = 0.0
        self._innov = 0.0
        self.n_failures = 0
        self._work = np.zeros(2 * self.n * self.n)

    def correct(self, y: float) -> NDArray:
        """Measurement update with ``y(t)``; returns ``x(t|t)``."""
        self._y = float(y)
        self._innov = _design.filtered_state(self.x, self.P, self.R, self._y, self.x_filt)
        return self.x_filt

    def predict(self, u: float) -> NDArray:
        """Time update with the applied ``u(t)``; returns ``x(t+1|t)`` (eq. (72))."""
        x_next = np.empty(self.n)
        status = kalman_step(
            self.A, self.b, self.P, self.Q, self.R, self.x, float(u), self._y, x_next, self.L1,
            self._work,
        )  # fmt: skip
        self.n_failures += int(status != 0)
        self.x = x_next
        return self.x
