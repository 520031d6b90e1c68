"""State estimators driven by the current parameter estimates (Ding & Ma 2014, section 2,
``shared/docs/algorithms.md`` §4), for either canonical form.

``A_hat(t)``, ``b_hat(t)`` are built from ``theta_hat(t)`` in place (:class:`ModelMatrices`), and
every estimator computes ``x_hat(t+1)`` from ``x_hat(t)``, ``u(t)`` and ``y(t)``:

* :class:`OpenLoopObserver` ``"O"``, eq. (46)-(49):
  ``x_hat(t+1) = A_hat(t) x_hat(t) + b_hat(t) u(t)``;
* :class:`ClosedLoopObserver` ``"CO"``, eq. (50)-(53): adds ``K(t) [y(t) - c x_hat(t)]`` with a
  user gain ``K`` (a fixed vector, or a callable ``K(a_hat, b_hat) -> (n,)`` evaluated every step;
  e.g. ``lambda a, b: -a`` is the dead-beat gain of the observer form, ``A_hat - K c`` nilpotent);
* :class:`KalmanFilter` ``"KF"``, eq. (66)-(72), generalised with a process-noise covariance
  ``Q`` and a measurement-noise variance ``R``::

      g = A_hat P1(t) c^T,   s = R + c P1(t) c^T,   L1(t) = g / s
      P1(t+1) = A_hat P1(t) A_hat^T - g g^T / s + Q
      x_hat(t+1) = A_hat x_hat(t) + b_hat u(t) + L1(t) [y(t) - c x_hat(t)]

  The paper's filter is ``Q = 0``, ``R = 1``, ``P1(1) = I``. With ``Q = 0`` the filter treats
  the state as deterministic, so for a stable (or merely detectable) ``A_hat`` the covariance
  ``P1`` and hence the gain ``L1`` die out within a few tens of steps and the filter becomes the
  open-loop observer (46). Give ``process_noise > 0`` to keep a persistent correction.

All flop counts follow the paper's conventions (structure of ``A_hat`` exploited; they are the
same for both canonical forms): tables 1 and 2.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive import flops as _flops

__all__ = [
    "is_schur_stable",
    "ModelMatrices",
    "OpenLoopObserver",
    "ClosedLoopObserver",
    "KalmanFilter",
]


def is_schur_stable(a: NDArray | list[float]) -> bool:
    """True when ``z^n + a1 z^{n-1} + ... + an`` has all roots strictly inside the unit circle.

    Schur-Cohn / Jury test by the step-down (reflection-coefficient) recursion: the polynomial
    is stable iff every reflection coefficient ``k_m`` satisfies ``|k_m| < 1``. ``O(n^2)``
    scalar operations, no eigenvalue solver (cheap enough for every step).
    """
    c = [float(v) for v in a]
    m = len(c)
    while m:
        k = c[m - 1]
        if not -1.0 < k < 1.0:  # also False for NaN
            return False
        d = 1.0 - k * k
        c = [(c[i] - k * c[m - 2 - i]) / d for i in range(m - 1)]
        m -= 1
    return True


class ModelMatrices:
    """``A_hat(t)`` and ``b_hat(t)`` of a canonical form, rebuilt in place from ``theta``.

    Observer form (47): first column ``-a``; observability form (146)/(239): last row
    ``[-a_n, ..., -a_1]``. Only the parameter-dependent entries are written each step.
    """

    def __init__(self, n: int, form: str) -> None:
        self.n = n
        self.observer = form == "observer"
        self.A = np.eye(n, k=1)
        self.a = np.zeros(n)
        self.b = np.zeros(n)

    def set(self, theta: NDArray) -> None:
        """Write ``a_hat``, ``b_hat`` of ``theta`` into ``A``, ``b``."""
        n = self.n
        a = self.a
        a[:] = theta[:n]
        if self.observer:
            np.negative(a, out=self.A[:, 0])
        else:
            np.negative(a[::-1], out=self.A[-1, :])
        self.b[:] = theta[n:]


class OpenLoopObserver:
    """Open-loop observer (46)-(49): ``x_hat(t+1) = A_hat x_hat(t) + b_hat u(t)``."""

    name = "O"

    def __init__(self, n: int) -> None:
        self.n = n

    def reset(self) -> None:
        """Nothing to reset (memoryless apart from ``x_hat``)."""

    def propagate(self, model: ModelMatrices, x: NDArray, u: float, y: float) -> NDArray:
        """Return ``x_hat(t+1)``."""
        return model.A @ x + model.b * u

    @property
    def flops(self) -> int:
        """``4n - 1`` (table 1, row ``x_hat(t+1)``)."""
        return _flops.open_loop_observer(self.n)


class ClosedLoopObserver:
    """Closed-loop observer (50)-(53) with a user gain ``K``.

    Parameters
    ----------
    n : int
    gain : array_like, shape (n,), or callable ``(a_hat, b_hat) -> array (n,)``
        ``K`` such that ``A_hat - K c`` is stable; a callable is evaluated every step.
    """

    name = "CO"

    def __init__(self, n: int, gain: NDArray | Callable[[NDArray, NDArray], NDArray]) -> None:
        self.n = n
        self._gain_fn: Callable[[NDArray, NDArray], NDArray] | None = None
        if callable(gain):
            self._gain_fn = gain
            self.K = np.zeros(n)
        else:
            K = np.asarray(gain, dtype=float)
            if K.shape != (n,) or not np.all(np.isfinite(K)):
                raise ValueError(
                    f"observer_gain must be a finite vector of length n={n} or a callable "
                    f"(a_hat, b_hat) -> K, got {gain!r}"
                )
            self.K = K.copy()

    def reset(self) -> None:
        """Nothing to reset."""

    def propagate(self, model: ModelMatrices, x: NDArray, u: float, y: float) -> NDArray:
        """Return ``x_hat(t+1) = A_hat x_hat + b_hat u + K [y - c x_hat]``."""
        if self._gain_fn is not None:
            n = self.n
            K = np.asarray(self._gain_fn(model.a.copy(), model.b.copy()), dtype=float)
            if K.shape != (n,) or not np.all(np.isfinite(K)):
                raise ValueError(f"observer_gain callable must return a finite ({n},) vector")
            self.K = K
        return model.A @ x + model.b * u + self.K * (y - x[0])

    @property
    def flops(self) -> int:
        """``6n``: the open-loop observer plus ``K [y - c x_hat]`` (gain evaluation excluded)."""
        return _flops.closed_loop_observer(self.n)


class KalmanFilter:
    """Kalman filter with the current parameter estimates, eq. (66)-(72).

    Parameters
    ----------
    n : int
    P1_init : ndarray, shape (n, n)
        ``P1(1)`` (paper: ``I_n``).
    Q : ndarray, shape (n, n)
        Process-noise covariance (paper: 0).
    R : float
        Measurement-noise variance (paper: 1).
    """

    name = "KF"

    def __init__(self, n: int, P1_init: NDArray, Q: NDArray, R: float) -> None:
        self.n = n
        self.P1_init = np.array(P1_init, dtype=float)
        self.Q = Q
        self.R = float(R)
        self.P1 = self.P1_init.copy()
        self.L1 = np.zeros(n)
        self.n_resets = 0

    @property
    def Q(self) -> NDArray:
        """Process-noise covariance; may be replaced between steps (adaptive process noise)."""
        return self._Q

    @Q.setter
    def Q(self, Q: ArrayLike) -> None:
        Q = np.array(Q, dtype=float)
        if Q.shape != (self.n, self.n) or not np.all(np.isfinite(Q)):
            raise ValueError(
                f"Q (process-noise covariance) must be finite, shape ({self.n}, {self.n})"
            )
        self._Q = Q
        # The paper's filter has Q = 0; skipping the addition keeps it bit-for-bit the paper's.
        self.has_Q = bool(np.any(Q != 0.0))

    def reset(self) -> None:
        """Back to ``P1(1)``."""
        self.P1[...] = self.P1_init
        self.L1[...] = 0.0

    def propagate(self, model: ModelMatrices, x: NDArray, u: float, y: float) -> NDArray:
        """Return ``x_hat(t+1)`` and advance ``P1``, eq. (66)-(68) / (80)-(82)."""
        A = model.A
        P1 = self.P1
        AP = A @ P1
        g = AP[:, 0]  # A_hat P1 c^T
        s = self.R + P1[0, 0]
        L1 = g / s
        x_next = A @ x + model.b * u + L1 * (y - x[0])
        # P1(t+1) = A P1 A^T - L1 c P1 A^T; c P1 A^T = g^T, and g g^T keeps P1 symmetric.
        P1_next = AP @ A.T
        P1_next -= np.multiply.outer(g, L1)
        if self.has_Q:
            P1_next += self.Q
        # Symmetrise (A P1 A^T is not bit-symmetric) and guard against overflow.
        P1_next += P1_next.T
        P1_next *= 0.5
        if not (s > 0.0 and math.isfinite(float(P1_next.sum()))):
            self.n_resets += 1
            self.P1[...] = self.P1_init
            self.L1[...] = 0.0
            return model.A @ x + model.b * u
        self.P1 = P1_next
        self.L1 = L1
        return x_next

    @property
    def flops(self) -> int:
        """``4n^2 + 10n - 1`` (table 2, rows ``x_hat``, ``L1``, ``P1``, ``zeta1``)."""
        return _flops.kalman_filter(self.n)
