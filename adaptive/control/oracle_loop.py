"""The closed loop the known-model oracles share: a Kalman filter on the true model, the
regulator's tracking law and a compiled lane step, for one plant or ``num_envs`` lanes
(:class:`_KnownModelLoop`, the base of
:class:`~stcgym.adaptive.control.oracles.KnownModelController`
and :class:`~stcgym.adaptive.control.oracles.LQGController`; see
:mod:`stcgym.adaptive.control.oracles`).
"""

from __future__ import annotations

from abc import abstractmethod
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.control import known_model, safe_set
from stcgym.adaptive.control.options import LawOptions, option_group
from stcgym.adaptive.kernels import canonical
from stcgym.adaptive.policy import LanePolicy
from stcgym.envs.canonical import as_finite_vector
from stcgym.envs.dynamics import FORM_CODES
from stcgym.envs.env_settings import plant_settings
from stcgym.lanes.compiled import FixedTypes, set_lanes, state_arrays
from stcgym.lanes.validation import integer, lane_indices, real_in

__all__ = ["MAX_SETTING"]

# the single-plant step with its argument types looked up once (see FixedTypes)
_known_model_propose = FixedTypes(known_model.known_model_propose)
_known_model_commit = FixedTypes(known_model.known_model_commit)

#: The oracles know the model: no safe set, only the design's numerical floors reject it.
_NO_SAFE_SET = safe_set.safe_set()
#: Largest accepted noise level, weight or covariance scale: squares and products of settings
#: beyond it overflow in the filter and design, so such a value is an input error, not a setting.
MAX_SETTING = 1e100


def _setting(
    value: Any, name: str, *, lo: float = 1.0 / MAX_SETTING, hi: float = MAX_SETTING
) -> float:
    """A noise level, weight or covariance scale in ``[lo, hi]`` (see :data:`MAX_SETTING`)."""
    return real_in(value, name, lo, hi)


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


class _KnownModelLoop(LanePolicy):
    """The lane state and the lane step shared by the two oracles.

    Subclasses call :meth:`_settings` (the common settings and the true parameters), set their
    own, then :meth:`_build` with the per-lane models; the state lives in ``self._state``
    (an :class:`~stcgym.adaptive.control.known_model.OracleState`, one row per plant).
    """

    def _settings(
        self, a: ArrayLike, b: ArrayLike, num_envs: Any, action_bound: Any, form: Any, env: Any,
        law: Any,
    ) -> tuple[NDArray, NDArray]:  # fmt: skip
        """Set ``n``, ``num_envs``, ``action_bound``, ``form`` and ``law``; return ``a``, ``b``
        as ``(lanes, n)``."""
        num = None if num_envs is None else integer(num_envs, "num_envs", 1)
        a_l, b_l = _lane_parameters(a, b, 1 if num is None else num, batched=num is not None)
        self.n = a_l.shape[1]
        self.num_envs, self.action_bound, self.form = plant_settings(
            self.n, num_envs=num, action_bound=action_bound, form=form, env=env
        )
        self.law = option_group(law, LawOptions, "law")
        return a_l, b_l

    def _build(self, a: NDArray, b: NDArray) -> None:
        state, self._proposal = known_model.make_oracle_state(self.n, a.shape[0])
        self._state = state
        state.R[:] = self.R
        state.Q0[:] = self._process_noise(b)
        self._gain0 = self._design_lanes(a, b, "a, b")  # the design a reset restores
        state.A0[:] = self._model_matrices(a, b)
        state.b0[:] = b
        state.P0[:] = self._initial_covariance(a, b)
        self._a, self._b = a.copy(), b.copy()
        self._a0, self._b0 = a.copy(), b.copy()
        self._reset_state()

    # -- hooks -----------------------------------------------------------------------------
    @abstractmethod
    def _design_batch(self, thetas: NDArray, gains: safe_set.Gain, status: NDArray) -> None:
        """Design every lane of ``thetas`` ``(lanes, 2n)`` into ``gains``, codes into ``status``."""

    @abstractmethod
    def _process_noise(self, b: NDArray) -> NDArray:
        """Kalman filter process-noise covariance ``Q`` (``(n, n)`` or per lane)."""

    @abstractmethod
    def _initial_covariance(self, a: NDArray, b: NDArray) -> NDArray:
        """Kalman filter covariance ``P1`` at reset, per lane (``a``, ``b``: ``(lanes, n)``)."""

    # -- lane state -------------------------------------------------------------------------
    @property
    def _form_code(self) -> int:
        return FORM_CODES[self.form]

    def _model_matrices(self, a: NDArray, b: NDArray) -> NDArray:
        """Canonical ``A`` of every lane, ``(lanes, n, n)`` (lane function ``model_matrices``)."""
        A = np.empty((a.shape[0], self.n, self.n))
        thetas = np.hstack((a, b))
        if a.shape[0] == 1:  # one plant: the lane function itself (no parallel compile)
            canonical.model_matrices(thetas[0], self._form_code, A[0], b[0].copy())
        else:
            canonical.model_matrices_lanes(thetas, self._form_code, A, b.copy())
        return A

    def _design_config(self, char_poly: NDArray) -> safe_set.DesignConfig:
        """The design's settings: the law's integral action and feed-forward, no safe set."""
        law = self.law
        return safe_set.DesignConfig(
            self._form_code, bool(law.integral), bool(law.feedforward), _NO_SAFE_SET, char_poly
        )

    def _design_lanes(self, a: NDArray, b: NDArray, name: str) -> safe_set.Gain:
        """The design of every lane's model; ``ValueError`` (nothing changed) if one fails."""
        gains = safe_set.make_gain(self.n, a.shape[0])
        status = np.zeros(a.shape[0], dtype=np.int64)
        self._design_batch(np.hstack((a, b)), gains, status)
        bad = np.flatnonzero(status)
        if bad.size:
            i = int(bad[0])
            lane = "" if a.shape[0] == 1 else f" (lane {i}; {bad.size} lanes fail)"
            raise ValueError(f"{name}{lane}: {self._failure(int(status[i]))}")
        return gains

    def _failure(self, status: int) -> str:
        return f"no design on the given model: {safe_set.STATUS_NAMES[status]}"

    def _reset_state(self, rows: NDArray | slice = slice(None)) -> None:
        s = self._state
        for src, dst in ((s.A0, s.A), (s.b0, s.b), (s.Q0, s.Q), (s.P0, s.P)):
            dst[rows] = src[rows]
        set_lanes(s.gain, rows, self._gain0, rows)
        for field in (s.x, s.x_filt, s.innov, s.xi, s.saturated, s.u_unsat, s.t):
            field[rows] = 0

    # -- public state ----------------------------------------------------------------------
    @property
    def a(self) -> NDArray:
        """True ``a`` in force (``(n,)``, or ``(num_envs, n)`` when batched)."""
        return self._lanes_out(self._a)

    @property
    def b(self) -> NDArray:
        """True ``b`` in force (``(n,)``, or ``(num_envs, n)`` when batched)."""
        return self._lanes_out(self._b)

    @property
    def t(self) -> int | NDArray:
        """Steps taken since the last reset (per lane when batched)."""
        return self._lanes_out(self._state.t, int)

    @property
    def xi(self) -> float | NDArray:
        """Integral of the tracking error ``xi(t)`` (per lane when batched)."""
        return self._lanes_out(self._state.xi, float)

    @property
    def x_hat(self) -> NDArray:
        """State estimate ``x(t|t-1)`` of the Kalman filter (per lane when batched)."""
        return self._lanes_out(self._state.x)

    @property
    def K(self) -> NDArray:
        """State-feedback gain ``[K_x, k_i]`` (``k_i`` only with integral action)."""
        return self._lanes_out(safe_set.feedback_gain(self._state.gain, self.law.integral))

    @property
    def N(self) -> float | NDArray:
        """Reference feed-forward gain ``N``."""
        return self._lanes_out(self._state.gain.N, float)

    def set_model(self, a: ArrayLike, b: ArrayLike, lanes: ArrayLike | None = None) -> None:
        """Switch to new true parameters (e.g. at a scheduled jump); the state estimate is kept.

        ``a``, ``b``: shape ``(n,)`` for every selected lane, or one row per selected lane.
        ``lanes``: a boolean mask of one entry per lane or lane indices (default all). A reset
        restores the initial model. Raises ``ValueError`` (nothing changed) when a model cannot
        be designed on.
        """
        idx = lane_indices(lanes, self.num_lanes)
        a_l, b_l = _lane_parameters(a, b, idx.size)
        if a_l.shape[1] != self.n:
            raise ValueError(f"new parameters must have order {self.n}, got {a_l.shape[1]}")
        # everything is computed before the first assignment: a failure changes nothing
        gains = self._design_lanes(a_l, b_l, "set_model")
        new = {"A": self._model_matrices(a_l, b_l), "b": b_l}
        new.update(self._model_extras(a_l, b_l))
        for name, value in new.items():
            getattr(self._state, name)[idx] = value
        set_lanes(self._state.gain, idx, gains, slice(None))
        self._a[idx], self._b[idx] = a_l, b_l

    def _model_extras(self, a: NDArray, b: NDArray) -> dict[str, NDArray]:
        """Hook: other state fields a new model changes (the LQG filter's noise and P)."""
        return {}

    # -- the policy's hooks ----------------------------------------------------------------
    def _reset_lanes(self, idx: NDArray) -> None:
        """Forget the episode on the lanes ``idx``: initial model restored (``A``, ``b``, the
        filter's ``Q`` and ``P``, the gain), state estimate and integrator zeroed."""
        self._reset_state(idx)
        self._a[idx], self._b[idx] = self._a0[idx], self._b0[idx]

    def _act(self, obs: NDArray, starts: NDArray | None, deterministic: bool) -> NDArray:
        """The whole step is computed before anything is committed: a step whose state would
        not be finite raises ``ValueError`` and leaves every lane (episode starts included) as
        it was."""
        saved = None
        if starts is not None:
            idx = np.flatnonzero(starts)
            fields = (*state_arrays(self._state), self._a, self._b)
            saved = [field[idx].copy() for field in fields]
            self._reset_lanes(idx)
        u = self._step(obs[:, 0].copy(), obs[:, 1].copy())
        if u is None:
            if saved is not None:
                for field, rows in zip(fields, saved, strict=True):
                    field[idx] = rows
            raise ValueError(
                "observation drives the oracle's state estimate to non-finite values "
                f"(got {obs}); the state was left unchanged"
            )
        return u

    def _step(self, y: NDArray, r: NDArray) -> NDArray | None:
        """Propose the step of every lane, commit only if all are finite (else ``None``)."""
        s, p = self._state, self._proposal
        B = y.shape[0]
        law = self.law
        flags = (
            bool(law.filtered),
            bool(law.integral),
            bool(law.anti_windup),
            float(self.action_bound),
        )
        u = np.empty(B)
        if B == 1:  # one plant: the lane function itself (no thread-pool start-up)
            if _known_model_propose(s, p, 0, float(y[0]), float(r[0]), *flags):
                return None
            u[0] = _known_model_commit(s, p, 0)
            return u
        status = np.zeros(B, dtype=np.int64)
        known_model.known_model_propose_lanes(s, p, y, r, *flags, status)
        if status.any():
            return None
        known_model.known_model_commit_lanes(s, p, u)
        return u
