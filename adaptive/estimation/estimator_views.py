"""The read-only views and the health reporting of :class:`~stcgym.adaptive.RecursiveEstimator`.

The estimator's whole state is one lane state of ``B`` lanes (``B = 1`` for a single plant,
:class:`~stcgym.adaptive.estimation.estimator_spec.EstimatorState`); :class:`EstimatorViews` reads
its named fields (``theta_hat``, ``P = S S^T``,
``x_hat``, the Kalman covariance, the innovation, the counters of numerical-health events) as
copies, without the lane axis for a single plant, and turns the status bits of a step into the
warnings or the :class:`~stcgym.adaptive.estimation.health.NumericalHealthError` that
:mod:`stcgym.adaptive.estimation.health` describes.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.estimation import estimator as _k
from stcgym.adaptive.estimation.estimator_spec import EstimatorSpec, EstimatorState
from stcgym.adaptive.estimation.health import describe_events, health_error
from stcgym.lanes.compiled import set_lanes

__all__ = ["EstimatorViews"]


class EstimatorViews:
    """The attributes of a recursive estimator read from its lane state.

    A base of :class:`~stcgym.adaptive.RecursiveEstimator`, which sets ``spec``, ``n``,
    ``name``, ``num_envs``, the lane state ``_state``, the flop counts ``_flops`` and the
    health bookkeeping ``_last_event`` / ``_frozen_warned``.
    """

    spec: EstimatorSpec
    name: str
    n: int
    num_envs: int | None
    _state: EstimatorState
    _flops: tuple[int, int]
    _last_event: str | None
    _frozen_warned: bool

    # ---- state access -------------------------------------------------------------------------
    @property
    def _B(self) -> int:
        return self._state.theta.shape[0]

    def _field(self, name: str) -> NDArray:
        return getattr(self._state, name)

    def _out(self, arr: NDArray) -> NDArray:
        """A copy, without the lane axis for a single plant."""
        return (arr[0] if self.num_envs is None else arr).copy()

    def _scalar_field(self, name: str, dtype: type = int) -> Any:
        v = self._field(name)
        if self.num_envs is None:
            return dtype(v[0])
        return v.astype(dtype)

    @property
    def state(self) -> EstimatorState:
        """The lane state (read-only views of every field, one row a lane)."""
        views = []
        for field in self._state:
            view = field.view()
            view.setflags(write=False)
            views.append(view)
        return EstimatorState(*views)

    def _snapshot(self) -> EstimatorState:
        return EstimatorState(*(field.copy() for field in self._state))

    def _restore(self, snapshot: EstimatorState) -> None:
        set_lanes(self._state, slice(None), snapshot, slice(None))

    # ---- health -------------------------------------------------------------------------------

    def _report(
        self, status: NDArray, snapshot: EstimatorState | None, times: bool = False
    ) -> None:
        """Turn status bits into warnings / errors (``status`` per lane, or per step)."""
        t = int(self._state.t[0])
        single = self.num_envs is None

        def describe(mask: int) -> str | None:
            return describe_events(self.name, t, status, mask, times=times, single=single)

        rule = describe(_k.ST_RESET)
        state = describe(_k.ST_STATE_RESET)
        if snapshot is not None and (rule or state):
            self._restore(snapshot)
            raise health_error(status, rule, state)
        if rule:
            self._event(
                f"{rule}: covariance reset",
                f"{rule}: P reset to P(0) (r to r(0)), theta_hat kept at its last finite value",
            )
        if state:
            self._event(
                f"{state}: state estimate reset",
                f"{state}: state estimate x_hat(t+1) is not finite; reset to x_hat(1)",
            )
        frozen = describe(_k.ST_FROZEN)
        if frozen and not self._frozen_warned:
            self._frozen_warned = True
            self._event(
                f"{frozen}: frozen",
                f"{frozen}: the estimator looks frozen on a wrong model (P has collapsed while "
                f"the innovation stays large); with p0 = 1e6 use p0 = 10..100, forgetting < 1 "
                f"or project_stable=True",
            )

    def _event(self, last_event: str, message: str) -> None:
        """Record ``last_event`` and warn with ``message`` at the caller of the public step."""
        self._last_event = last_event
        warnings.warn(message, RuntimeWarning, stacklevel=4)

    # ---- read-only views ----------------------------------------------------------------------

    @property
    def theta(self) -> NDArray:
        """``theta_hat(t) = [a_hat(t); b_hat(t)]`` (copy)."""
        return self._out(self._field("theta"))

    @property
    def a(self) -> NDArray:
        """``a_hat(t)`` (copy)."""
        return self._out(self._field("theta")[:, : self.n])

    @property
    def b(self) -> NDArray:
        """``b_hat(t)`` (copy)."""
        return self._out(self._field("theta")[:, self.n :])

    @property
    def x_hat(self) -> NDArray:
        """Latest state estimate (copy)."""
        return self._out(self._field("x_hat"))

    @property
    def P(self) -> NDArray | None:
        """``P(t) = S S^T`` (RLS/MILS; block-diagonal for D- rules), else ``None``."""
        if not self.spec.least_squares:
            return None
        S = self._field("S")
        P = S @ np.swapaxes(S, -1, -2)
        return self._out(0.5 * P + 0.5 * np.swapaxes(P, -1, -2))

    @property
    def S(self) -> NDArray | None:
        """Upper-triangular factor ``S`` of ``P = S S^T`` (copy), else ``None``."""
        return self._out(self._field("S")) if self.spec.least_squares else None

    @property
    def r(self) -> NDArray | None:
        """``[r(t)]`` or ``[r1(t), r2(t)]`` (SG/MISG), else ``None``."""
        if not self.spec.normaliser:
            return None
        r = self._field("r")
        return self._out(r[:, :2] if self.spec.decomposed else r[:, :1])

    @property
    def P1(self) -> NDArray | None:
        """Kalman covariance ``P1(t+1)`` (KF only), else ``None``."""
        return self._out(self._field("P1")) if self.spec.variant.state.kalman else None

    @property
    def L1(self) -> NDArray | None:
        """Last Kalman gain ``L1(t)`` (KF only), else ``None``."""
        return self._out(self._field("L1")) if self.spec.variant.state.kalman else None

    @property
    def R(self) -> float | None:
        """Measurement-noise variance of the Kalman filter (KF only), else ``None``."""
        return self.spec.R if self.spec.variant.state.kalman else None

    @property
    def Q(self) -> NDArray | None:
        """Process-noise covariance of the Kalman filter (KF only); settable between steps
        (shape ``(n, n)``, or ``(B, n, n)`` per lane)."""
        return self._out(self._field("Q")) if self.spec.variant.state.kalman else None

    @Q.setter
    def Q(self, value: ArrayLike) -> None:
        if self.spec.state != "KF":
            raise ValueError("Q (process-noise covariance) applies to KF state estimators only")
        n, B = self.n, self._B
        Qm = np.array(value, dtype=float)
        ok_shape = Qm.shape == (n, n) or (self.num_envs is not None and Qm.shape == (B, n, n))
        if not ok_shape or not np.all(np.isfinite(Qm)):
            expected = f"({n}, {n})" + (f" or ({B}, {n}, {n})" if self.num_envs else "")
            raise ValueError(
                f"Q (process-noise covariance) must be finite with shape {expected}, got "
                f"shape {Qm.shape}"
            )
        self._field("Q")[...] = Qm

    @property
    def innovation(self) -> NDArray:
        """``E(p, t)`` of the last update (length ``p``; ``e(t)`` for SG/RLS)."""
        return self._out(self._field("E"))

    @property
    def e(self) -> Any:
        """Scalar innovation ``e(t) = y(t) - phi_hat(t)^T theta_hat(t-1)``."""
        e = self._field("E")[:, 0]
        return float(e[0]) if self.num_envs is None else e.copy()

    @property
    def phi(self) -> NDArray:
        """``phi_hat(t)`` of the last update (copy)."""
        return self._out(self._field("Phi")[:, 0, :])

    @property
    def Phi(self) -> NDArray:
        """``Phi(p, t)`` of the last update, ``2n x p`` (column ``j`` is ``phi_hat(t-j)``)."""
        return self._out(np.swapaxes(self._field("Phi"), -1, -2))

    @property
    def t(self) -> Any:
        """Time of the last measurement update (0 before the first)."""
        return self._scalar_field("t")

    @property
    def enabled(self) -> Any:
        """Adaptation switch: ``False`` freezes ``theta`` and ``P``/``r`` (per lane)."""
        return self._scalar_field("enabled", bool)

    @enabled.setter
    def enabled(self, value: Any) -> None:
        if self.num_envs is None:
            self._state.enabled[0] = bool(value)
            return
        arr = np.asarray(value)
        if arr.ndim == 0:
            arr = np.full(self._B, bool(arr))
        if arr.shape != (self._B,):
            raise ValueError(
                f"enabled must be a bool or one flag per lane, shape ({self._B},), got "
                f"shape {arr.shape}"
            )
        self._state.enabled[:] = arr.astype(bool)

    @property
    def n_resets(self) -> Any:
        """Number of covariance / normaliser resets (numerical-health events)."""
        return self._scalar_field("n_resets")

    @property
    def frozen(self) -> Any:
        """The "frozen on a wrong model" signal (see :mod:`stcgym.adaptive.estimation.health`)."""
        return self._scalar_field("frozen", bool)

    @property
    def health(self) -> dict[str, Any]:
        """Counters of numerical events, the frozen signal and the last event's description.

        ``n_resets`` (covariance resets), ``n_state_resets`` (non-finite ``x_hat``),
        ``n_kf_resets`` (non-finite ``P1``), ``n_projections`` (updates rejected by
        ``project_stable``), ``n_window_recomputes`` (ill-conditioned finite-history downdates
        replaced by an exact recomputation), ``frozen``, ``last_event``.
        """
        counters = ("n_resets", "n_state_resets", "n_kf_resets", "n_projections")
        return {
            **{name: self._scalar_field(name) for name in (*counters, "n_window_recomputes")},
            "frozen": self._scalar_field("frozen", bool),
            "last_event": self._last_event,
        }

    @property
    def flops_parameters(self) -> int:
        """Flops of the parameter update per step (tables 3 / 4 for D-RLS / D-MILS)."""
        return self._flops[0]

    @property
    def flops_state(self) -> int:
        """Flops of the state estimate per step."""
        return self._flops[1]

    @property
    def flops_per_step(self) -> int:
        """Total flops per step (table 1 for O-RLS, table 2 for KF-MILS)."""
        return self._flops[0] + self._flops[1]

    @property
    def nbytes_per_lane(self) -> int:
        """Memory of one lane's state and scratch in bytes."""
        return self.spec.nbytes_per_lane
