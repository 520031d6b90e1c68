"""Recursive (online) joint state and parameter estimators of Ding & Ma 2014, sections 1-3
(``shared/docs/algorithms.md`` §1-§5), for either canonical form.

An estimator is composed of three parts, wired by :class:`RecursiveEstimator`:

* a parameter-update rule (:mod:`stcgym.adaptive.rules`): SG, MISG, RLS, MILS, each optionally
  model-decomposed (``D-``: separate ``a`` and ``b`` sub-updates sharing one innovation);
* a state estimator (:mod:`stcgym.adaptive.state_estimators`): open-loop observer ``O``
  (46)-(49), closed-loop observer with a user gain ``CO`` (50)-(53), Kalman filter ``KF``
  (66)-(72);
* a regressor builder per canonical form: observer form ``phi_hat(t)`` (9)/(57)
  ``[-x1_hat(t-1), ..., -x1_hat(t-n), u(t-1), ..., u(t-n)]``; observability form (153)
  ``[-x_n_hat(t-n), ..., -x_1_hat(t-n), u(t-1), ..., u(t-n)]`` (needs the full ``x_hat(t-n)``).

:func:`make_estimator` maps each paper name (``"O-SG"`` ... ``"KF-D-MILS"``, case-insensitive;
``"CO-..."`` for the closed-loop observer) to its parts.

Time convention (paper)
-----------------------
``t = 1, 2, ...``; every signal, state estimate and regressor is zero for ``t <= 0``, also inside
the stacked MISG/MILS windows (columns ``phi_hat(t - j)`` with ``t - j <= 0`` are zero, and so are
the matching entries of ``Y(p, t)``). Defaults: ``theta_hat(0) = 1/p0``, ``P(0) = p0 I``,
``x_hat(1) = 1/p0``, ``P1(1) = I``, ``r(0) = 1``, ``p0 = 1e6``.

One step (O-RLS (54)-(62), KF-MILS (73)-(86)) is split in two so that a controller can act in
between::

    theta = est.update(y_t)   # build phi_hat(t), Phi(p, t), Y(p, t); update theta_hat(t), P(t)
    u_t = controller(theta, est.x_hat)
    est.predict(u_t)          # A_hat(t), b_hat(t) from theta_hat(t); x_hat(t+1)

``update`` twice without ``predict`` (or ``predict`` first) raises :class:`RuntimeError`.

Numerical health
----------------
``P`` is propagated in square-root form, so it cannot lose symmetry or positive definiteness
through cancellation; after every update ``P`` (through its trace), ``r`` and the gain
denominators are checked for overflow / NaN, and every ``pd_check_every`` steps (default 100)
the factor of ``P`` is checked for lost rank (singular values). On a failure the default
``on_failure="reset"`` resets ``P`` to ``P(0)`` (``r`` to ``r(0)``, the finite-history buffer is
emptied), keeps the last finite ``theta_hat``, counts the event in :attr:`n_resets` /
:attr:`health` and emits a :class:`RuntimeWarning`; ``on_failure="raise"`` raises
:class:`NumericalHealthError` instead. A non-finite state estimate is reset to ``x_hat(1)`` the
same way (counted in ``health["n_state_resets"]``); a non-finite Kalman covariance is reset to
``P1(1)``. No NaN is returned silently.

Measured behaviour of the paper's algorithms (``tests/test_recursive.py``, 2nd-order plant,
white input, 20 seeds)
-------------------------------------------------------------------------------------------
* ``p0 = 1e6``: the RLS/MILS family freezes at a wrong estimate on roughly one run in four
  (observer form; fewer in the observability form): an early unstable ``A_hat(t)`` makes the
  open-loop observer's ``x_hat`` huge, the huge ``phi_hat`` entries collapse ``P`` before
  ``theta`` is right, and with ``lambda = 1`` it never recovers. ``p0 = 10 .. 100`` avoids it;
  ``project_stable=True`` (not in the paper) reduces it.
* D-RLS / D-MILS with a huge ``P(0)``: on the first informative step each half (``a`` and ``b``)
  absorbs the whole innovation, so the prediction overshoots by ``e(t)`` and early estimates can
  diverge. Use ``p0 <= 100``.
* D- rules converge slowly in the observer form, where ``phi_a(t) = -x1(t-1..t-n)`` is correlated
  with ``psi(t) = u(t-1..t-n)``; in the observability form ``phi_a(t) = -x(t-n)`` is uncorrelated
  with ``psi(t)`` for a white input and the hierarchical split loses almost nothing.
* With the default Kalman filter (``Q = 0``) and ``theta_hat(0) ~ 0`` (``A_hat`` nilpotent) the
  gain vanishes after ``n`` steps, so ``KF-*`` and ``O-*`` give practically the same estimates.
* Lightly damped plants (e.g. poles ``0.8 +- 0.4i``) can make the observer-form estimators
  converge to biased values: this is a pseudo-linear regression, whose convergence needs a
  positive-real-type condition on ``1 / A(z)``.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from numbers import Integral, Real
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive import flops as _flops
from stcgym.adaptive.rules import NumericalHealthError, ParameterRule, innovation
from stcgym.adaptive.state_estimators import (
    ClosedLoopObserver,
    KalmanFilter,
    ModelMatrices,
    OpenLoopObserver,
    is_schur_stable,
)
from stcgym.envs.canonical import as_finite_vector, check_form

if TYPE_CHECKING:
    from stcgym.adaptive.batched_estimators import BatchedEstimatorBase

__all__ = [
    "ALGORITHMS",
    "RULES",
    "STATE_ESTIMATORS",
    "NumericalHealthError",
    "RecursiveEstimator",
    "make_estimator",
    "parse_name",
]

RULES: tuple[str, ...] = ("SG", "MISG", "RLS", "MILS")
STATE_ESTIMATORS: tuple[str, ...] = ("O", "KF", "CO")
#: The 16 algorithms of the paper (``CO-...`` variants are accepted as well).
ALGORITHMS: tuple[str, ...] = tuple(
    f"{s}-{d}{r}" for d in ("", "D-") for r in RULES for s in ("O", "KF")
)


# --------------------------------------------------------------------------------------------
# Validation helpers
# --------------------------------------------------------------------------------------------


def _int(value: Any, name: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, Integral) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def _positive_real(value: Any, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, Real):
        raise ValueError(f"{name} must be a finite positive real number, got {value!r}")
    v = float(value)
    if not (math.isfinite(v) and v > 0.0):
        raise ValueError(f"{name} must be a finite positive real number, got {value!r}")
    return v


def _scalar(value: Any, name: str) -> float:
    """A finite real scalar (Python number, numpy scalar, 0-d or 1-element array)."""
    if type(value) is float or type(value) is int:
        v = float(value)
    else:
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{name} must be a finite real scalar, got {value!r}") from exc
        if arr.size != 1:
            raise ValueError(f"{name} must be a finite real scalar, got shape {arr.shape}")
        v = float(arr.reshape(-1)[0])
    if not math.isfinite(v):
        raise ValueError(f"{name} must be a finite real scalar, got {value!r}")
    return v


def _covariance(value: Any, dim: int, name: str, *, allow_singular: bool = False) -> NDArray:
    """A ``dim x dim`` covariance from a scalar, a vector (diagonal) or a matrix."""
    expected = (
        f"{name} must be a positive {'or zero ' if allow_singular else ''}scalar, a vector of "
        f"length {dim} or a symmetric positive {'semi' if allow_singular else ''}definite "
        f"{dim}x{dim} matrix"
    )
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{expected}, got {value!r}") from exc
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{expected}; it is not finite: {value!r}")
    if arr.ndim == 0 or (arr.ndim == 1 and arr.size == dim):
        diag = np.broadcast_to(arr, (dim,))
        if np.any(diag < 0) or (not allow_singular and np.any(diag <= 0)):
            raise ValueError(f"{expected}, got {value!r}")
        return np.diag(diag).astype(float)
    if arr.shape != (dim, dim):
        raise ValueError(f"{expected}, got shape {arr.shape}")
    scale = max(float(np.abs(arr).max()), 1e-300)
    if not np.allclose(arr, arr.T, rtol=0.0, atol=1e-12 * scale):
        raise ValueError(f"{expected}; it is not symmetric")
    M = 0.5 * (arr + arr.T)
    lam_min = float(np.linalg.eigvalsh(M).min())
    if lam_min < -1e-12 * scale or (not allow_singular and lam_min <= 0.0):
        raise ValueError(f"{expected}; its smallest eigenvalue is {lam_min:g}")
    return M


def parse_name(name: str) -> tuple[str, bool, str]:
    """Split a paper name into ``(state estimator, decomposed, rule)``.

    ``"KF-D-MILS" -> ("KF", True, "MILS")``; case-insensitive; the state estimator is one of
    ``O``, ``KF``, ``CO`` (closed-loop observer, needs ``observer_gain``).
    """
    if not isinstance(name, str):
        raise ValueError(f"name must be a string such as 'KF-D-MILS', got {name!r}")
    parts = name.strip().upper().split("-")
    ok = (
        len(parts) in (2, 3)
        and parts[0] in STATE_ESTIMATORS
        and parts[-1] in RULES
        and (len(parts) == 2 or parts[1] == "D")
    )
    if not ok:
        raise ValueError(
            f"unknown algorithm {name!r}; expected '<state>-[D-]<rule>' with state in "
            f"{STATE_ESTIMATORS} and rule in {RULES}, e.g. one of {ALGORITHMS}"
        )
    return parts[0], len(parts) == 3, parts[-1]


# --------------------------------------------------------------------------------------------
# Regressor builders
# --------------------------------------------------------------------------------------------


class ObserverFormRegressor:
    """``phi_hat(t) = [-x1_hat(t-1), ..., -x1_hat(t-n), u(t-1), ..., u(t-n)]``, eq. (9)/(57)."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.phi = np.zeros(2 * n)

    def reset(self) -> None:
        """``phi_hat(1) = 0`` (everything before t = 1 is zero)."""
        self.phi[:] = 0.0

    def advance(self, x_t: NDArray, u_t: float) -> None:
        """Turn ``phi_hat(t)`` into ``phi_hat(t+1)`` with ``x_hat(t)`` and ``u(t)``."""
        n, phi = self.n, self.phi
        phi[1:n] = phi[: n - 1]
        phi[0] = -x_t[0]
        phi[n + 1 :] = phi[n:-1]
        phi[n] = u_t


class ObservabilityFormRegressor:
    """``phi_hat(t) = [-x_n_hat(t-n), ..., -x_1_hat(t-n), u(t-1), ..., u(t-n)]``, eq. (153)."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.phi = np.zeros(2 * n)
        self._xs = np.zeros((n, n))  # the last n state estimates, ring buffer
        self._k = 0

    def reset(self) -> None:
        """``phi_hat(1) = 0`` and an all-zero state history."""
        self.phi[:] = 0.0
        self._xs[...] = 0.0
        self._k = 0

    def advance(self, x_t: NDArray, u_t: float) -> None:
        """Store ``x_hat(t)`` and form ``phi_hat(t+1)`` (uses ``x_hat(t+1-n)``)."""
        n, phi = self.n, self.phi
        self._xs[self._k] = x_t
        self._k = (self._k + 1) % n  # now the oldest stored estimate, x_hat(t+1-n)
        np.negative(self._xs[self._k, ::-1], out=phi[:n])
        phi[n + 1 :] = phi[n:-1]
        phi[n] = u_t


# --------------------------------------------------------------------------------------------
# The estimator
# --------------------------------------------------------------------------------------------


class RecursiveEstimator:
    """Joint recursive parameter and state estimator (build it with :func:`make_estimator`).

    Attributes (read-only unless stated)
    ------------------------------------
    name, n, p, form : the algorithm name (upper case), order, innovation length, canonical form.
    theta, a, b : ndarray
        ``theta_hat(t) = [a_hat; b_hat]`` (copies).
    x_hat : ndarray
        Latest state estimate: ``x_hat(t)`` after ``update``, ``x_hat(t+1)`` after ``predict``.
    P : ndarray or None
        ``P(t)`` of RLS/MILS rules (block-diagonal ``diag(P_a, P_b)`` for D- rules).
    r : ndarray or None
        ``[r(t)]`` (plain) or ``[r1(t), r2(t)]`` (D-) of SG/MISG rules.
    P1, L1 : ndarray or None
        Kalman covariance ``P1(t+1)`` and gain ``L1(t)`` (KF only).
    innovation : ndarray, shape (p,)
        ``E(p, t) = Y(p, t) - Phi(p, t)^T theta_hat(t-1)``; ``e`` is its first entry ``e(t)``.
    phi, Phi : ndarray
        ``phi_hat(t)`` and ``Phi(p, t)`` used by the last update.
    t : int
        Time of the last measurement update (0 before the first).
    enabled : bool (settable)
        ``False`` freezes ``theta`` and ``P`` (the innovation is still computed and the state
        estimate still propagated with the frozen parameters; stacked windows keep sliding, the
        finite-history buffer does not).
    n_resets, health : int, dict
        Numerical-health events (see the module docstring).
    flops_per_step, flops_parameters, flops_state : int
        Flops per step (paper conventions, ``lambda = 1``, no finite history):
        parameter update + state estimate. ``O-RLS`` = table 1, ``KF-MILS`` = table 2; for
        ``*-D-RLS`` / ``*-D-MILS`` ``flops_parameters`` = tables 3 / 4 (which count the parameter
        update only). See :mod:`stcgym.adaptive.flops`.
    """

    def __init__(
        self,
        name: str,
        n: int,
        p: int,
        form: str,
        rule: ParameterRule,
        state_estimator: OpenLoopObserver | ClosedLoopObserver | KalmanFilter,
        theta0: NDArray,
        x_init: NDArray,
        *,
        enabled: bool = True,
        on_failure: str = "reset",
        pd_check_every: int = 100,
        project_stable: bool = False,
        flops: tuple[int, int] = (0, 0),
    ) -> None:
        self.name = name
        self.n = n
        self.p = p
        self.form = form
        self.rule = rule
        self.state_estimator = state_estimator
        self.regressor = (
            ObserverFormRegressor(n) if form == "observer" else ObservabilityFormRegressor(n)
        )
        self._model = ModelMatrices(n, form)
        self._theta0 = np.array(theta0, dtype=float)
        self._x_init = np.array(x_init, dtype=float)
        self._enabled = bool(enabled)
        self._on_failure = on_failure
        self._check_every = pd_check_every
        self._project = bool(project_stable)
        self._flops = flops
        self._theta = self._theta0.copy()
        self._Phi = np.zeros((2 * n, p))
        self._Y = np.zeros(p)
        self.reset()

    # ---- lifecycle ------------------------------------------------------------------------

    def reset(self) -> None:
        """Back to the initial conditions (``t = 0``); ``enabled`` is kept."""
        self._theta[:] = self._theta0
        self._theta_prev = self._theta0.copy()
        self._n_projections = 0
        self.rule.reset()
        self.state_estimator.reset()
        self.regressor.reset()
        self._x = self._x_init.copy()
        self._Phi[...] = 0.0
        self._Y[...] = 0.0
        self._E = np.zeros(self.p)
        self._y = 0.0
        self._t = 0
        self._awaiting_predict = False
        self._n_resets = 0
        self._n_state_resets = 0
        self._last_event: str | None = None
        if isinstance(self.state_estimator, KalmanFilter):
            self.state_estimator.n_resets = 0

    def update(self, y_t: float) -> NDArray:
        """Measurement step at time ``t``: build ``phi_hat(t)``, ``Phi(p, t)``, ``Y(p, t)`` and
        update ``theta_hat(t)`` (and ``P(t)`` / ``r(t)``); returns a copy of ``theta_hat(t)``.

        Parameters
        ----------
        y_t : float
            The measured output ``y(t)``.
        """
        if self._awaiting_predict:
            raise RuntimeError(
                f"{self.name}: update() called twice without predict(u(t)) in between (t = "
                f"{self._t}); the order is update(y(t)) -> compute u(t) -> predict(u(t))"
            )
        y = _scalar(y_t, "y(t)")
        Phi, Y = self._Phi, self._Y
        if self.p > 1:  # slide the stacked window: column j is phi_hat(t - j)
            Phi[:, 1:] = Phi[:, :-1]
            Y[1:] = Y[:-1]
        Phi[:, 0] = self.regressor.phi
        Y[0] = y
        t = self._t + 1
        self._t = t
        if self._enabled:
            if self._project:
                self._theta_prev[:] = self._theta
            try:
                self._E = self.rule.step(self._theta, Phi, Y)
                if self._project and not is_schur_stable(self._theta[: self.n].tolist()):
                    # Projection: reject an update whose A_hat(t) is unstable (P is kept).
                    self._theta[:] = self._theta_prev
                    self._n_projections += 1
                if self._check_every and t % self._check_every == 0:
                    self.rule.check_full()
            except NumericalHealthError as exc:
                self._rule_failure(str(exc))
                self._E = innovation(self._theta, Phi, Y)
        else:
            self._E = innovation(self._theta, Phi, Y)
        self._y = y
        self._awaiting_predict = True
        return self._theta.copy()

    def predict(self, u_t: float, *, x_next: ArrayLike | None = None) -> NDArray:
        """State step: ``x_hat(t+1)`` from ``x_hat(t)``, ``u(t)``, ``y(t)`` and ``A_hat(t)``,
        ``b_hat(t)`` built from ``theta_hat(t)``; returns a copy of ``x_hat(t+1)``.

        Parameters
        ----------
        u_t : float
            The input ``u(t)`` applied at time ``t``.
        x_next : array_like, shape (n,), optional
            A known (measured) ``x(t+1)`` that replaces the estimate: the regressors then use
            the true states, which also lets the parameter rules be checked against batch least
            squares. The Kalman covariance is propagated as usual.
        """
        if not self._awaiting_predict:
            raise RuntimeError(
                f"{self.name}: predict() must follow update(y(t)) (t = {self._t}); the order is "
                f"update(y(t)) -> compute u(t) -> predict(u(t))"
            )
        u = _scalar(u_t, "u(t)")
        if x_next is not None:
            x_known = as_finite_vector(x_next, "x_next", length=self.n)
        model = self._model
        model.set(self._theta)
        x = self._x
        xn = self.state_estimator.propagate(model, x, u, self._y)
        self.regressor.advance(x, u)
        if x_next is not None:
            xn = x_known.copy()
        elif not math.isfinite(float(xn.sum())):
            self._state_failure()
            xn = self._x_init.copy()
        self._x = xn
        self._awaiting_predict = False
        return xn.copy()

    def run(self, u: ArrayLike, y: ArrayLike) -> NDArray:
        """Open-loop pass over recorded data: ``u[k], y[k]`` are ``u(t), y(t)`` for
        ``t = k + 1`` (continuing from the current time if the estimator was used before).

        Returns
        -------
        ndarray, shape (T, 2n)
            ``theta_hat(t)`` for ``t = 1..T`` (relative to the current time).
        """
        u_arr = as_finite_vector(u, "u")
        y_arr = as_finite_vector(y, "y")
        if u_arr.size != y_arr.size:
            raise ValueError(
                f"u and y must have the same length (u[k], y[k] = u(t), y(t), t = k + 1), "
                f"got len(u)={u_arr.size}, len(y)={y_arr.size}"
            )
        if self._awaiting_predict:
            raise RuntimeError(f"{self.name}: run() called between update() and predict()")
        out = np.empty((u_arr.size, 2 * self.n))
        update, predict = self.update, self.predict
        for k in range(u_arr.size):
            out[k] = update(float(y_arr[k]))
            predict(float(u_arr[k]))
        return out

    # ---- health ---------------------------------------------------------------------------

    def _rule_failure(self, reason: str) -> None:
        msg = f"{self.name} at t={self._t}: {reason}"
        if self._on_failure == "raise":
            raise NumericalHealthError(msg)
        self.rule.reset()
        self._n_resets += 1
        self._last_event = msg
        warnings.warn(
            f"{msg}; P reset to P(0) (r to r(0)), theta_hat kept at its last finite value",
            RuntimeWarning,
            stacklevel=3,
        )

    def _state_failure(self) -> None:
        msg = f"{self.name} at t={self._t}: state estimate x_hat(t+1) is not finite"
        if self._on_failure == "raise":
            raise NumericalHealthError(msg)
        self._n_state_resets += 1
        self._last_event = msg
        warnings.warn(f"{msg}; reset to x_hat(1)", RuntimeWarning, stacklevel=3)

    # ---- read-only views ------------------------------------------------------------------

    @property
    def theta(self) -> NDArray:
        """``theta_hat(t) = [a_hat(t); b_hat(t)]`` (copy)."""
        return self._theta.copy()

    @property
    def a(self) -> NDArray:
        """``a_hat(t)`` (copy)."""
        return self._theta[: self.n].copy()

    @property
    def b(self) -> NDArray:
        """``b_hat(t)`` (copy)."""
        return self._theta[self.n :].copy()

    @property
    def x_hat(self) -> NDArray:
        """Latest state estimate (copy): ``x_hat(t)`` after update, ``x_hat(t+1)`` after
        predict."""
        return self._x.copy()

    @property
    def P(self) -> NDArray | None:
        """``P(t)`` (RLS/MILS; block-diagonal for D- rules), else ``None``."""
        return self.rule.P

    @property
    def r(self) -> NDArray | None:
        """``[r(t)]`` or ``[r1(t), r2(t)]`` (SG/MISG), else ``None``."""
        return self.rule.r

    @property
    def P1(self) -> NDArray | None:
        """Kalman covariance (KF only), else ``None``."""
        se = self.state_estimator
        return se.P1.copy() if isinstance(se, KalmanFilter) else None

    @property
    def L1(self) -> NDArray | None:
        """Last Kalman gain ``L1(t)`` (KF only), else ``None``."""
        se = self.state_estimator
        return se.L1.copy() if isinstance(se, KalmanFilter) else None

    @property
    def innovation(self) -> NDArray:
        """``E(p, t)`` of the last update (length ``p``; ``e(t)`` for SG/RLS)."""
        return np.array(self._E, dtype=float)

    @property
    def e(self) -> float:
        """Scalar innovation ``e(t) = y(t) - phi_hat(t)^T theta_hat(t-1)``."""
        return float(self._E[0])

    @property
    def phi(self) -> NDArray:
        """``phi_hat(t)`` of the last update (copy)."""
        return self._Phi[:, 0].copy()

    @property
    def Phi(self) -> NDArray:
        """``Phi(p, t)`` of the last update (copy)."""
        return self._Phi.copy()

    @property
    def t(self) -> int:
        """Time of the last measurement update (0 before the first)."""
        return self._t

    @property
    def enabled(self) -> bool:
        """Adaptation switch: ``False`` freezes ``theta`` and ``P``/``r``."""
        return self._enabled

    @enabled.setter
    def enabled(self, value: bool) -> None:
        self._enabled = bool(value)

    @property
    def n_resets(self) -> int:
        """Number of covariance / normaliser resets (numerical-health events)."""
        return self._n_resets

    @property
    def health(self) -> dict[str, Any]:
        """Counters of numerical events and the last one's description.

        ``n_resets`` (covariance resets), ``n_state_resets`` (non-finite ``x_hat``),
        ``n_kf_resets`` (non-finite ``P1``), ``n_projections`` (updates rejected by
        ``project_stable``), ``n_window_recomputes`` (ill-conditioned finite-history downdates
        replaced by an exact recomputation), ``last_event``.
        """
        se = self.state_estimator
        return {
            "n_resets": self._n_resets,
            "n_state_resets": self._n_state_resets,
            "n_kf_resets": se.n_resets if isinstance(se, KalmanFilter) else 0,
            "n_projections": self._n_projections,
            "n_window_recomputes": self.rule.n_recomputes,
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

    def __repr__(self) -> str:
        return (
            f"RecursiveEstimator({self.name!r}, n={self.n}, p={self.p}, form={self.form!r}, "
            f"t={self._t}, enabled={self._enabled})"
        )


# --------------------------------------------------------------------------------------------
# Factory
# --------------------------------------------------------------------------------------------


def make_estimator(
    name: str,
    n: int,
    *,
    p: int = 1,
    p0: float = 1e6,
    form: str = "observer",
    forgetting: float = 1.0,
    window: int | None = None,
    theta0: ArrayLike | None = None,
    P0: ArrayLike | None = None,
    r0: float | None = None,
    stacked_r: bool = False,
    x_init: ArrayLike | None = None,
    P1_init: ArrayLike | None = None,
    process_noise: ArrayLike | None = None,
    measurement_noise: float | None = None,
    observer_gain: ArrayLike | Callable[[NDArray, NDArray], NDArray] | None = None,
    enabled: bool = True,
    on_failure: str = "reset",
    pd_check_every: int = 100,
    project_stable: bool = False,
    num_envs: int | None = None,
    mode: str = "exact",
) -> RecursiveEstimator | BatchedEstimatorBase:
    """Build one of the paper's recursive estimators by name.

    Parameters
    ----------
    name : str
        ``"<state>-[D-]<rule>"``, case-insensitive: state ``O`` (open-loop observer (46)),
        ``KF`` (Kalman filter (66)) or ``CO`` (closed-loop observer (50), needs
        ``observer_gain``); rule ``SG``, ``MISG``, ``RLS``, ``MILS``; ``D-`` for model
        decomposition. The 16 paper names are in :data:`ALGORITHMS`. ``O-...`` together with
        ``observer_gain`` also gives the closed-loop observer.
    n : int
        Plant order (``theta`` has ``2n`` entries), ``n >= 1``.
    p : int
        Innovation length ``p >= 1`` (MISG/MILS; must be 1 for SG/RLS).
    p0 : float
        The paper's large number: ``theta_hat(0) = 1/p0``, ``P(0) = p0 I``, ``x_hat(1) = 1/p0``.
    form : {"observer", "observability"}
        Canonical form of the plant (regressor (9) or (153), ``A_hat`` (47) or (146)).
    forgetting : float
        ``lambda`` in ``(0, 1]``. RLS/MILS: exponential forgetting
        ``P^{-1}(t) = lambda P^{-1}(t-1) + Phi Phi^T``. SG/MISG: forgetting-gradient
        ``r(t) = lambda r(t-1) + ||phi||^2`` (keeps the step from vanishing).
    window : int, optional
        Finite history of ``W`` samples (RLS/MILS only, exclusive with ``forgetting < 1``):
        exact regularised least squares over the last ``W`` data blocks by downdating.
    theta0 : array_like, shape (2n,), optional
        ``theta_hat(0)`` (default ``1/p0``).
    P0 : float, array_like (2n,) or (2n, 2n), optional
        ``P(0)`` as a scalar (times ``I``), a diagonal or a matrix (RLS/MILS only; block-diagonal
        for D- rules). Default ``p0 I``.
    r0 : float, optional
        ``r(0)`` of SG/MISG rules (default 1).
    stacked_r : bool
        MISG: ``r(t) = r(t-1) + ||Phi(p, t)||^2`` (remark 1, (116)-(117)) instead of
        ``+ ||phi_hat(t)||^2``.
    x_init : array_like, shape (n,), optional
        ``x_hat(1)`` (default ``1/p0``).
    P1_init, process_noise, measurement_noise :
        Kalman filter only: ``P1(1)`` (default ``I``), process-noise covariance ``Q`` (default
        0), measurement-noise variance ``R`` (default 1) — the paper's filter. With ``Q = 0`` the
        gain dies out after a few tens of steps (the filter becomes the open-loop observer).
    observer_gain : array_like (n,) or callable ``(a_hat, b_hat) -> (n,)``, optional
        Gain ``K`` of the closed-loop observer (50) (``CO-...`` names, or ``O-...``).
    enabled : bool
        Initial adaptation switch (see :attr:`RecursiveEstimator.enabled`).
    on_failure : {"reset", "raise"}
        Action on loss of positive definiteness / overflow (see the module docstring).
    pd_check_every : int
        Rank test of the factor of ``P`` every this many steps (``0``: only the per-step
        overflow checks; an SVD costs ~5 us).
    project_stable : bool
        Not in the paper (default ``False``): reject a parameter update whose ``A_hat(t)`` is not
        Schur stable (keep ``theta_hat(t-1)``, ``P(t)`` as updated) — the projection of
        output-error / pseudo-linear-regression methods (Ljung & Soderstrom 1983). Without it an
        early unstable estimate can make the open-loop observer blow up; the huge ``phi_hat``
        entries then collapse ``P`` and ``a_hat`` stays wrong for thousands of steps.
    num_envs : int, optional
        Build ``num_envs`` lanes of this estimator stepped together on arrays instead
        (:func:`~stcgym.adaptive.batched.make_batched_estimator`; ``theta0``/``P0`` may then
        carry a leading lane axis).
    mode : {"exact", "fast"}
        Batched lanes only: ``"exact"`` repeats the BLAS/LAPACK calls of ``num_envs`` single
        estimators on stacked arrays (equal to rounding), ``"fast"`` uses generated kernels
        (same equations, different rounding).

    Returns
    -------
    RecursiveEstimator
        Or a batched estimator when ``num_envs`` is given.
    """
    if num_envs is not None:
        # Every argument but the batching ones goes through unchanged; the batched factory
        # validates them with this very function (num_envs=None) on lane 0.
        kwargs = {k: v for k, v in locals().items() if k not in ("name", "n", "num_envs", "mode")}
        from stcgym.adaptive.batched import make_batched_estimator

        return make_batched_estimator(name, n, num_envs=num_envs, mode=mode, **kwargs)
    if mode != "exact":
        raise ValueError(f"mode={mode!r} applies to batched estimators (num_envs=...) only")
    state_name, decomposed, rule_name = parse_name(name)
    n = _int(n, "n", 1)
    p = _int(p, "p", 1)
    if rule_name in ("SG", "RLS") and p != 1:
        raise ValueError(
            f"p (innovation length) applies to MISG/MILS; {rule_name} has p = 1, got p={p}"
        )
    p0 = _positive_real(p0, "p0")
    form = check_form(form)
    lam = forgetting
    if isinstance(lam, bool) or not isinstance(lam, Real) or not (0.0 < float(lam) <= 1.0):
        raise ValueError(f"forgetting (lambda) must be a real number in (0, 1], got {lam!r}")
    lam = float(lam)
    least_squares = rule_name in ("RLS", "MILS")
    if window is not None:
        window = _int(window, "window", 1)
        if not least_squares:
            raise ValueError("window (finite history) applies to RLS/MILS rules only")
        if lam != 1.0:
            raise ValueError("window and forgetting < 1 are mutually exclusive")
    d = 2 * n
    theta0_arr = (
        np.full(d, 1.0 / p0) if theta0 is None else as_finite_vector(theta0, "theta0", length=d)
    )
    if P0 is not None and not least_squares:
        raise ValueError(f"P0 applies to RLS/MILS rules only, not {rule_name}")
    if r0 is not None and least_squares:
        raise ValueError(f"r0 applies to SG/MISG rules only, not {rule_name}")
    if stacked_r and least_squares:
        raise ValueError(f"stacked_r applies to SG/MISG rules only, not {rule_name}")
    P0_mat = None
    if least_squares:
        P0_mat = p0 * np.eye(d) if P0 is None else _covariance(P0, d, "P0")
        if decomposed and (np.any(P0_mat[:n, n:] != 0.0) or np.any(P0_mat[n:, :n] != 0.0)):
            raise ValueError(
                "P0 must be block-diagonal diag(P_a, P_b) for D- rules (separate a and b "
                "covariances)"
            )
    r0_val = 1.0 if r0 is None else _positive_real(r0, "r0")
    rule = ParameterRule(
        rule_name,
        n,
        p,
        decomposed=decomposed,
        P0=P0_mat,
        r0=r0_val,
        forgetting=lam,
        stacked_r=bool(stacked_r),
        window=window,
        theta0=theta0_arr,
    )

    x_init_arr = (
        np.full(n, 1.0 / p0) if x_init is None else as_finite_vector(x_init, "x_init", length=n)
    )
    kf_opts = {
        "P1_init": P1_init,
        "process_noise": process_noise,
        "measurement_noise": measurement_noise,
    }
    if state_name == "KF":
        if observer_gain is not None:
            raise ValueError("observer_gain applies to O/CO state estimators, not KF")
        P1 = np.eye(n) if P1_init is None else _covariance(P1_init, n, "P1_init")
        Q = (
            np.zeros((n, n))
            if process_noise is None
            else _covariance(process_noise, n, "process_noise", allow_singular=True)
        )
        R = (
            1.0
            if measurement_noise is None
            else _positive_real(measurement_noise, "measurement_noise")
        )
        state: OpenLoopObserver | ClosedLoopObserver | KalmanFilter = KalmanFilter(n, P1, Q, R)
    else:
        given = [k for k, v in kf_opts.items() if v is not None]
        if given:
            raise ValueError(f"{', '.join(given)} apply to KF state estimators only")
        if state_name == "CO" and observer_gain is None:
            raise ValueError("CO (closed-loop observer) needs observer_gain=K (or a callable)")
        if observer_gain is not None:
            state_name = "CO"
            state = ClosedLoopObserver(n, observer_gain)
        else:
            state = OpenLoopObserver(n)

    if on_failure not in ("reset", "raise"):
        raise ValueError(f"on_failure must be 'reset' or 'raise', got {on_failure!r}")
    pd_check_every = _int(pd_check_every, "pd_check_every", 0)

    canonical = f"{state_name}-{'D-' if decomposed else ''}{rule_name}"
    fl = _flops.recursive_parts(canonical, n, p, stacked_r=bool(stacked_r))
    return RecursiveEstimator(
        canonical,
        n,
        p,
        form,
        rule,
        state,
        theta0_arr,
        x_init_arr,
        enabled=enabled,
        on_failure=on_failure,
        pd_check_every=pd_check_every,
        project_stable=project_stable,
        flops=fl,
    )
