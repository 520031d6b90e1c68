"""Multichannel least-squares estimators: matrix RLS and ``[A B]`` from measured states.

Two recursive estimators of a matrix of parameters:

* :class:`MatrixRLS` -- Voevoda & Troshina (2017), appendix 2: the static object
  ``y^T = x^T Theta + v`` with an ``n_inputs``-vector ``x``, an ``n_outputs``-vector ``y`` and an
  ``n_inputs x n_outputs`` matrix ``Theta``. One gain vector ``K`` serves every output channel,
  because all channels share the regressor ``x``.
* :class:`StateMatrixEstimator` -- Kunik, Kovalenko & Al Sadi (2001): ``x(t+1) = A x(t) + B u(t)``
  with measured state; ``C = [A B]`` is estimated from ``z(t) = [x(t); u(t)]``. While the
  regressors collected so far do not span ``R^{m+N}`` the minimum-norm recursion (17)-(18) gives
  ``C = X Z^+``; afterwards ordinary RLS (20)-(21).

Numerical health: ``P`` is kept symmetric (Joseph-form update) and checked for finiteness and
positive definiteness (Cholesky) after every update. Joseph form keeps ``P`` positive definite
under round-off as long as its condition number stays well below ``1/eps ~ 1e16``; strong
covariance wind-up (``lambda < 1`` without excitation for hundreds of steps, ``P`` growing like
``lambda^-t``) can exceed that, and is then detected. A failed check either raises
:class:`NumericalHealthError` (default) or, with ``on_unhealthy="reset"``, discards the offending
sample and resets ``P`` to its initial value (covariance resetting) with a ``RuntimeWarning``.
Updates are atomic: when an exception is raised the estimator state is unchanged.
"""

from __future__ import annotations

import warnings
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.recursive import NumericalHealthError

__all__ = ["MatrixRLS", "NumericalHealthError", "StateMatrixEstimator"]

OnUnhealthy = Literal["raise", "reset"]


def _positive_int(value: int, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    return int(value)


def _forgetting(value: float) -> float:
    try:
        lam = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"forgetting must be a real number in (0, 1], got {value!r}") from exc
    if not (0.0 < lam <= 1.0):  # also rejects NaN
        raise ValueError(f"forgetting must lie in (0, 1], got {value!r}")
    return lam


def _on_unhealthy(value: str) -> OnUnhealthy:
    if value not in ("raise", "reset"):
        raise ValueError(f"on_unhealthy must be 'raise' or 'reset', got {value!r}")
    return value  # type: ignore[return-value]


def _vector(value: ArrayLike, name: str, length: int) -> NDArray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a real vector of length {length}, got {value!r}") from exc
    arr = np.atleast_1d(arr)
    if arr.ndim != 1 or arr.size != length:
        raise ValueError(f"{name} must be a vector of length {length}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr}")
    return arr


def _matrix(value: ArrayLike, name: str, shape: tuple[int, int]) -> NDArray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a real {shape[0]}x{shape[1]} matrix") from exc
    if arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


def _is_spd(P: NDArray) -> bool:
    try:
        np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        return False
    return True


class MatrixRLS:
    r"""Matrix recursive least squares for ``y^T = x^T Theta + v`` (Voevoda & Troshina 2017).

    Voevoda & Troshina (2017), appendix 2, with exponential forgetting ``lambda``::

        K(N+1)     = P(N) x / (lambda + x^T P(N) x)
        Theta(N+1) = Theta(N) + K(N+1) (y^T - x^T Theta(N))
        P(N+1)     = (I - K(N+1) x^T) P(N) / lambda

    ``lambda = 1`` is the paper's algorithm. With a symmetric ``P0`` the estimate after ``N``
    samples is the regularised least-squares solution
    ``(lambda^N P0^{-1} + sum_i lambda^{N-i} x_i x_i^T) Theta = lambda^N P0^{-1} Theta0
    + sum_i lambda^{N-i} x_i y_i^T``.

    Parameters
    ----------
    n_inputs, n_outputs
        Dimensions of ``x`` and ``y`` (``Theta`` is ``n_inputs x n_outputs``).
    P0
        Initial covariance: ``None`` gives ``p0 * I``; a positive scalar ``s`` gives ``s * I``;
        or an ``n_inputs x n_inputs`` matrix. A symmetric matrix must be positive definite. A
        *non-symmetric* matrix is accepted "as printed" so that the paper's example
        ``P0 = [[0.5, 0.4], [0.5, 1]]`` can be reproduced: the recursion is then run exactly in
        the paper's form (no symmetrisation, no Joseph form). By the Sherman-Morrison identity
        (valid for any invertible matrix) ``P(N) = (P0^{-1} + X^T X)^{-1}`` still holds, and so
        does the regularised normal equation above, but a non-symmetric prior weight
        ``P0^{-1}`` does not correspond to any quadratic criterion; its influence decays like
        ``1/N``. Its symmetric part must be positive definite (so ``1 + x^T P0 x > 0``).
    theta0
        Initial estimate (default zeros), shape ``(n_inputs, n_outputs)``.
    forgetting
        ``lambda`` in ``(0, 1]``.
    p0
        Scale of the default ``P0`` (paper convention ``p0 = 1e6``).
    on_unhealthy
        ``"raise"`` (default): raise :class:`NumericalHealthError` when ``P`` or ``Theta`` becomes
        non-finite or ``P`` loses positive definiteness. ``"reset"``: discard that sample, reset
        ``P`` to ``P0`` and warn.

    Attributes
    ----------
    theta : ndarray, shape (n_inputs, n_outputs)
    P : ndarray, shape (n_inputs, n_inputs)
    K : ndarray, shape (n_inputs,) -- gain of the last update (zeros before the first).
    t : int -- number of samples processed (including discarded ones).
    n_resets : int -- number of covariance resets performed.
    symmetric : bool -- whether ``P`` is kept symmetric (False only for a non-symmetric ``P0``).
    """

    def __init__(
        self,
        n_inputs: int,
        n_outputs: int,
        *,
        P0: ArrayLike | float | None = None,
        theta0: ArrayLike | None = None,
        forgetting: float = 1.0,
        p0: float = 1e6,
        on_unhealthy: OnUnhealthy = "raise",
    ) -> None:
        self.n_inputs = _positive_int(n_inputs, "n_inputs")
        self.n_outputs = _positive_int(n_outputs, "n_outputs")
        self.forgetting = _forgetting(forgetting)
        self.on_unhealthy = _on_unhealthy(on_unhealthy)
        n = self.n_inputs
        if P0 is None or np.ndim(P0) == 0:
            scale = float(p0 if P0 is None else P0)  # type: ignore[arg-type]
            label = "p0" if P0 is None else "P0"
            if not np.isfinite(scale) or scale <= 0:
                raise ValueError(f"{label} must be a positive finite number, got {scale!r}")
            P = scale * np.eye(n)
        else:
            P = _matrix(P0, "P0", (n, n))
        self.symmetric = bool(np.allclose(P, P.T, rtol=1e-12, atol=0.0))
        if self.symmetric:
            P = 0.5 * (P + P.T)
            if not _is_spd(P):
                raise ValueError("P0 must be symmetric positive definite")
        else:
            if not _is_spd(0.5 * (P + P.T)):
                raise ValueError(
                    "the symmetric part of a non-symmetric P0 must be positive definite"
                )
        self._P0 = P.copy()
        self.P = P
        if theta0 is None:
            self.theta = np.zeros((n, self.n_outputs))
        else:
            self.theta = _matrix(theta0, "theta0", (n, self.n_outputs))
        self.K = np.zeros(n)
        self.t = 0
        self.n_resets = 0

    def predict(self, x: ArrayLike) -> NDArray:
        """Model output ``x^T Theta`` (shape ``(n_outputs,)``)."""
        return _vector(x, "x", self.n_inputs) @ self.theta

    def update(self, x: ArrayLike, y: ArrayLike) -> NDArray:
        """Process one sample ``(x, y)`` and return a copy of the new ``Theta``.

        Parameters
        ----------
        x : array_like, shape (n_inputs,)
        y : array_like, shape (n_outputs,) -- a scalar is accepted when ``n_outputs == 1``.
        """
        x = _vector(x, "x", self.n_inputs)
        y = _vector(y, "y", self.n_outputs)
        t = self.t + 1
        lam = self.forgetting
        P = self.P
        with np.errstate(over="ignore", invalid="ignore"):
            Px = P @ x
            den = lam + x @ Px
            K = Px / den
            e = y - x @ self.theta  # innovation row vector, one entry per output channel
            theta = self.theta + np.outer(K, e)
            if self.symmetric:
                # Joseph form: algebraically equal to (I - K x^T) P / lambda but a sum of two
                # symmetric PSD terms, so round-off cannot make P indefinite.
                M = np.eye(self.n_inputs) - np.outer(K, x)
                P_new = (M @ P @ M.T + lam * np.outer(K, K)) / lam
                P_new = 0.5 * (P_new + P_new.T)
            else:
                # the paper's form (P.8) exactly, to reproduce its non-symmetric example
                P_new = (P - np.outer(K, x @ P)) / lam
        problem = self._check(den, P_new, theta)
        if problem is not None and self.on_unhealthy == "raise":
            raise NumericalHealthError(f"MatrixRLS update {t}: {problem}; state left unchanged")
        self.t = t
        if problem is None:
            self.P, self.theta, self.K = P_new, theta, K
        else:
            self.P = self._P0.copy()
            self.n_resets += 1
            warnings.warn(
                f"MatrixRLS update {self.t}: {problem}; sample discarded and P reset to P0",
                RuntimeWarning,
                stacklevel=2,
            )
        return self.theta.copy()

    def _check(self, den: float, P_new: NDArray, theta: NDArray) -> str | None:
        if not np.isfinite(den) or den <= 0:
            return f"gain denominator lambda + x^T P x = {den!r} is not positive"
        if not np.all(np.isfinite(P_new)):
            return "P overflowed (non-finite entries)"
        if not np.all(np.isfinite(theta)):
            return "Theta overflowed (non-finite entries)"
        S = P_new if self.symmetric else 0.5 * (P_new + P_new.T)
        if not _is_spd(S):
            return "P lost positive definiteness"
        return None


class StateMatrixEstimator:
    r"""Recursive estimate of ``C = [A B]`` from measured states (Kunik et al. 2001).

    Model ``x(t+1) = A x(t) + B u(t) = C z(t)`` with ``z(t) = [x(t); u(t)]``, ``x`` in ``R^m``,
    ``u`` in ``R^N``. Each call of :meth:`update` supplies one triple ``(x(t), u(t), x(t+1))``
    (the paper writes the target as ``x(n)``; with model (3) the target of regressor ``z(n)`` is
    the next state).

    *Minimum-norm phase* (while the regressors seen so far do not span ``R^{m+N}``; for linearly
    independent samples that is exactly the first ``m + N`` samples, the paper's ``n < m+N``),
    with ``R(0) = I`` and ``e = x(t+1) - C z``:

    * independent ``z`` (``z^T R z > tol * z^T z``), eq. (17)-(18)::

          C <- C + e z^T R / (z^T R z),      R <- R - R z z^T R / (z^T R z)

      ``R`` is the orthogonal projector onto the complement of the span of the past regressors.
    * dependent ``z`` (not covered by the paper, which assumes independence): Greville's second
      case, i.e. an RLS step restricted to the span, ``C <- C + e (G z)^T / (lambda + z^T G z)``
      with ``G`` the pseudo-inverse of the (weighted) Gram matrix ``S = sum lambda^{t-i} z z^T``.

    Starting from ``C(0) = 0`` the estimate is then ``X Z^+``, the minimum-norm least-squares
    solution (10). When the rank reaches ``m+N`` the estimator switches to RLS (20)-(21) with
    ``P = S^{-1}`` (computed once), so that from then on ``C`` is the (weighted) batch
    least-squares estimate (11); the RLS phase is a :class:`MatrixRLS` on ``C^T``.

    Parameters
    ----------
    m, N
        State and input dimensions (``N >= 0``; ``N = 0`` estimates ``A`` alone).
    forgetting
        Exponential forgetting ``lambda`` in ``(0, 1]`` (the paper's recommendation for
        time-varying objects). In the minimum-norm phase it only weights dependent samples.
    C0
        Initial estimate (default zeros). With a non-zero ``C0`` the minimum-norm phase returns
        the solution closest to ``C0`` instead of the minimum-norm one.
    dependence_tol
        Relative threshold on ``z^T R z / z^T z`` below which a regressor counts as dependent.
    on_unhealthy
        As for :class:`MatrixRLS`.
    """

    def __init__(
        self,
        m: int,
        N: int,
        *,
        forgetting: float = 1.0,
        C0: ArrayLike | None = None,
        dependence_tol: float = 1e-9,
        on_unhealthy: OnUnhealthy = "raise",
    ) -> None:
        self.m = _positive_int(m, "m")
        if isinstance(N, bool) or not isinstance(N, (int, np.integer)) or N < 0:
            raise ValueError(f"N (number of inputs) must be an integer >= 0, got {N!r}")
        self.N = int(N)
        self.forgetting = _forgetting(forgetting)
        self.on_unhealthy = _on_unhealthy(on_unhealthy)
        tol = float(dependence_tol)
        if not (0.0 < tol < 1.0):
            raise ValueError(f"dependence_tol must lie in (0, 1), got {dependence_tol!r}")
        self.dependence_tol = tol
        q = self.m + self.N
        self._C = np.zeros((self.m, q)) if C0 is None else _matrix(C0, "C0", (self.m, q))
        self.R: NDArray | None = np.eye(q)  # projector of the minimum-norm phase
        self._S = np.zeros((q, q))  # weighted Gram matrix sum lambda^{t-i} z z^T
        self.rank = 0
        self.t = 0
        self._rls: MatrixRLS | None = None

    # ------------------------------------------------------------------ properties
    @property
    def phase(self) -> str:
        """``"minimum_norm"`` before the regressors span ``R^{m+N}``, then ``"rls"``."""
        return "minimum_norm" if self._rls is None else "rls"

    @property
    def C(self) -> NDArray:
        """Current estimate of ``[A B]``, shape ``(m, m+N)`` (a copy)."""
        return (self._C if self._rls is None else self._rls.theta.T).copy()

    @property
    def A(self) -> NDArray:
        """Estimated state matrix, shape ``(m, m)``."""
        return self.C[:, : self.m]

    @property
    def B(self) -> NDArray:
        """Estimated input matrix, shape ``(m, N)``."""
        return self.C[:, self.m :]

    @property
    def P(self) -> NDArray | None:
        """RLS covariance (``None`` during the minimum-norm phase)."""
        return None if self._rls is None else self._rls.P.copy()

    # ------------------------------------------------------------------ update
    def update(self, x_t: ArrayLike, u_t: ArrayLike, x_next: ArrayLike) -> NDArray:
        """Process ``(x(t), u(t), x(t+1))`` and return the new ``C = [A B]``."""
        x_t = _vector(x_t, "x_t", self.m)
        if self.N:
            u_t = _vector(u_t, "u_t", self.N)
        elif np.size(u_t):
            raise ValueError(f"u_t must be empty when N = 0, got {u_t!r}")
        else:
            u_t = np.zeros(0)
        x_next = _vector(x_next, "x_next", self.m)
        z = np.concatenate([x_t, u_t])
        self.t += 1
        if self._rls is not None:
            self._rls.update(z, x_next)
            return self.C
        lam = self.forgetting
        assert self.R is not None
        e = x_next - self._C @ z
        Rz = self.R @ z
        gamma = float(z @ Rz)
        S_new = lam * self._S + np.outer(z, z)
        if gamma > self.dependence_tol * float(z @ z):
            # eq. (18) and (17): interpolate the new sample exactly without disturbing the fit
            # on the span of the previous regressors
            C = self._C + np.outer(e, Rz) / gamma
            R = self.R - np.outer(Rz, Rz) / gamma
            R = 0.5 * (R + R.T)
            rank = self.rank + 1
        else:
            # z lies in the span already seen: least-squares step inside that span
            Gz = np.linalg.pinv(self._S, hermitian=True) @ z
            C = self._C + np.outer(e, Gz) / (lam + z @ Gz)
            R, rank = self.R, self.rank
        if not (np.all(np.isfinite(C)) and np.all(np.isfinite(R)) and np.all(np.isfinite(S_new))):
            msg = f"StateMatrixEstimator update {self.t}: estimate overflowed"
            self.t -= 1
            raise NumericalHealthError(msg + "; state left unchanged")
        self._C, self.R, self._S, self.rank = C, R, S_new, rank
        if rank == self.m + self.N:
            self._switch_to_rls()
        return self.C

    def _switch_to_rls(self) -> None:
        # P(n) = (Z Z^T)^{-1} as in (19); C is already the batch LS estimate (10)=(11) here
        S = 0.5 * (self._S + self._S.T)
        try:
            P = np.linalg.inv(S)
        except np.linalg.LinAlgError:  # pragma: no cover - rank test guarantees invertibility
            return
        P = 0.5 * (P + P.T)
        if not (np.all(np.isfinite(P)) and _is_spd(P)):
            # numerically rank deficient despite the projector test: stay minimum-norm
            return
        self._rls = MatrixRLS(
            self.m + self.N,
            self.m,
            P0=P,
            theta0=self._C.T,
            forgetting=self.forgetting,
            on_unhealthy=self.on_unhealthy,
        )
        self.R = None
