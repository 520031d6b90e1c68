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

Numerical health: the RLS recursion is the shared square-root least-squares step of
:mod:`stcgym.adaptive.estimation.least_squares` (Carlson's update of ``P = S S^T``), so ``P`` stays
symmetric positive definite by construction, with the one health check of that module plus a
finite ``trace(P)`` (covariance wind-up under ``lambda < 1`` without excitation). The policy is
the estimators' common one: ``on_failure="reset"`` (default) discards the sample, resets ``P``
to ``P0``, keeps the last ``Theta``, counts the event in ``n_resets`` and warns;
``on_failure="raise"`` raises :class:`NumericalHealthError` and leaves the estimator unchanged.
"""

from __future__ import annotations

import math
import warnings
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.estimation.health import NumericalHealthError
from stcgym.adaptive.estimation.least_squares import (
    FAIL_COVARIANCE,
    OK,
    block_trace_is_finite,
    factor_is_healthy,
    least_squares_increment,
    least_squares_work,
    upper_factor,
)
from stcgym.lanes.compiled import lane
from stcgym.lanes.validation import (
    finite_vector,
    forgetting_factor,
    integer,
    matrix,
    one_of,
    positive,
    real_in,
)

__all__ = ["MatrixRLS", "NumericalHealthError", "StateMatrixEstimator"]

OnFailure = Literal["reset", "raise"]


def _is_spd(P: NDArray) -> bool:
    try:
        np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        return False
    return True


@lane(entry=True, inline=True)
def matrix_rls_step(theta, S, x, y, lam, w, lane_i):
    """One step of appendix 2's recursion (P.6)-(P.8) on ``P = S S^T``; returns a status.

    ``theta`` ``(d, q)``, ``S`` ``(d, d)`` upper triangular, ``x`` ``(1, d)`` the regressor,
    ``y`` ``(q,)``; scratch: lane ``lane_i`` of a
    :class:`~stcgym.adaptive.estimation.least_squares.LeastSquaresWork` for ``d`` parameters and
    ``q`` outputs. Every output channel ``j`` shares the gain ``K = P x / (lam + x^T P x)``
    (``w.gain[lane_i]`` on return) and the factor update, so ``theta[:, j] += K e_j`` with the
    innovation ``e = y - theta^T x`` (``w.E[lane_i]``). Returns ``OK``, or ``FAIL_COVARIANCE``
    (``theta`` untouched, ``S`` to be reset by the caller) when the factor is unhealthy,
    ``trace(P)`` or an increment is not finite.
    """
    d, q = theta.shape
    K = w.gain[lane_i]
    delta = w.delta[lane_i]
    E = w.E[lane_i]
    for j in range(q):
        acc = y[j]
        for i in range(d):
            acc -= x[0, i] * theta[i, j]
        E[j] = acc
    denom = least_squares_increment(S, 0, d, x, E, 1, lam, True, delta, K, w.factor_work[lane_i])
    healthy = factor_is_healthy(S, 0, d) and block_trace_is_finite(S, 0, d)
    if not (denom > 0.0 and math.isfinite(denom) and healthy):
        return FAIL_COVARIANCE
    for i in range(d):
        K[i] /= denom
        for j in range(q):
            if not math.isfinite(K[i] * E[j]):
                return FAIL_COVARIANCE
    for i in range(d):
        for j in range(q):
            theta[i, j] += K[i] * E[j]
    return OK


class MatrixRLS:
    r"""Matrix recursive least squares for ``y^T = x^T Theta + v`` (Voevoda & Troshina 2017).

    Voevoda & Troshina (2017), appendix 2, with exponential forgetting ``lambda``::

        K(N+1)     = P(N) x / (lambda + x^T P(N) x)
        Theta(N+1) = Theta(N) + K(N+1) (y^T - x^T Theta(N))
        P(N+1)     = (I - K(N+1) x^T) P(N) / lambda

    ``lambda = 1`` is the paper's algorithm. The estimate after ``N`` samples is the regularised
    least-squares solution of the normal equation
    ``(lambda^N P0^{-1} + sum_i lambda^{N-i} x_i x_i^T) Theta = lambda^N P0^{-1} Theta0
    + sum_i lambda^{N-i} x_i y_i^T``, ``P(N)`` the inverse of its matrix.

    Parameters
    ----------
    n_inputs, n_outputs
        Dimensions of ``x`` and ``y`` (``Theta`` is ``n_inputs x n_outputs``).
    P0
        Initial covariance: ``None`` gives ``p0 * I``; a positive scalar ``s`` gives ``s * I``;
        or an ``n_inputs x n_inputs`` matrix. A symmetric matrix must be positive definite. A
        *non-symmetric* matrix is accepted "as printed" so that the paper's example
        ``P0 = [[0.5, 0.4], [0.5, 1]]`` can be reproduced; its symmetric part must be positive
        definite (so ``1 + x^T P0 x > 0``). By the Sherman-Morrison identity (valid for any
        invertible matrix) the paper's recursion still gives the normal equation above, with a
        non-symmetric prior weight ``M0 = P0^{-1}`` that corresponds to no quadratic criterion
        (its influence decays like ``1/N``). The recursion runs on the symmetric part ``Ms`` of
        ``M0`` (square-root step from ``Ps(0) = Ms^{-1}``); ``Theta`` and ``P`` add the skew part
        ``Mk`` back in closed form: ``P = (I + lambda^N Ps Mk)^{-1} Ps`` and
        ``Theta = (I + lambda^N Ps Mk)^{-1} (Theta_s + lambda^N Ps Mk Theta0)``.
    theta0
        Initial estimate (default zeros), shape ``(n_inputs, n_outputs)``.
    forgetting
        ``lambda`` in ``(0, 1]``.
    p0
        Scale of the default ``P0`` (paper convention ``p0 = 1e6``).
    on_failure
        ``"reset"`` (default): when ``P`` loses positive definiteness or ``P``, the gain or
        ``Theta`` overflows, discard that sample, reset ``P`` to ``P0``, keep ``Theta`` and warn.
        ``"raise"``: raise :class:`NumericalHealthError`, the estimator unchanged.

    Attributes
    ----------
    theta : ndarray, shape (n_inputs, n_outputs)
    P : ndarray, shape (n_inputs, n_inputs)
    K : ndarray, shape (n_inputs,) -- gain of the last update (zeros before the first).
    t : int -- number of samples processed (including discarded ones).
    n_resets : int -- number of covariance resets performed.
    symmetric : bool -- whether ``P`` is symmetric (False only for a non-symmetric ``P0``).

    Raises
    ------
    ValueError
        On construction: ``n_inputs`` or ``n_outputs`` not a positive integer, ``p0`` or a
        scalar ``P0`` not positive, a matrix ``P0`` not ``n_inputs x n_inputs``, not positive
        definite (a symmetric one) or with a symmetric part that is not (a non-symmetric
        one), ``theta0`` of the wrong shape, ``forgetting`` outside ``(0, 1]``, an unknown
        ``on_failure``.

    Examples
    --------
    Three inputs, two outputs, slightly noisy data: with the paper's ``p0 = 1e6`` the
    estimate is the batch least-squares one:

    >>> import numpy as np
    >>> from stcgym.adaptive import MatrixRLS
    >>> rng = np.random.default_rng(0)
    >>> Theta = np.array([[1.0, -0.5], [2.0, 0.3], [0.0, 1.5]])
    >>> X = rng.standard_normal((20, 3))
    >>> Y = X @ Theta + 0.01 * rng.standard_normal((20, 2))
    >>> est = MatrixRLS(3, 2)
    >>> for x, y in zip(X, Y):
    ...     theta = est.update(x, y)
    >>> np.round(theta, 2)
    array([[ 1.  , -0.5 ],
           [ 2.  ,  0.3 ],
           [ 0.  ,  1.51]])
    >>> np.allclose(theta, np.linalg.lstsq(X, Y, rcond=None)[0], atol=1e-4)
    True
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
        on_failure: OnFailure = "reset",
    ) -> None:
        self.n_inputs = integer(n_inputs, "n_inputs")
        self.n_outputs = integer(n_outputs, "n_outputs")
        self.forgetting = forgetting_factor(forgetting)
        self.on_failure = one_of(on_failure, "on_failure", ("reset", "raise"))  # type: ignore[assignment]
        n = self.n_inputs
        if P0 is None or np.ndim(P0) == 0:
            scale = positive(p0, "p0") if P0 is None else positive(P0, "P0")
            P = scale * np.eye(n)
        else:
            P = matrix(P0, "P0", (n, n))
        self.symmetric = bool(np.allclose(P, P.T, rtol=1e-12, atol=0.0))
        if self.symmetric:
            P_s = 0.5 * (P + P.T)
            self._skew = np.zeros((n, n))
        elif not _is_spd(0.5 * (P + P.T)):
            raise ValueError("the symmetric part of a non-symmetric P0 must be positive definite")
        else:
            M0 = np.linalg.inv(P)
            self._skew = 0.5 * (M0 - M0.T)
            P_s = np.linalg.inv(0.5 * (M0 + M0.T))
            P_s = 0.5 * (P_s + P_s.T)
        self._S0 = np.zeros((n, n))
        if not upper_factor(np.ascontiguousarray(P_s), self._S0):
            raise ValueError("P0 must be symmetric positive definite")
        self._S = self._S0.copy()
        shape = (n, self.n_outputs)
        theta = np.zeros(shape) if theta0 is None else matrix(theta0, "theta0", shape)
        self._theta_s = np.ascontiguousarray(theta, dtype=float)
        self._prior = self._theta_s.copy()  # Theta0, moved to the kept estimate by a reset
        self._decay = 1.0  # lambda^N since the start or the last reset
        self._work = least_squares_work(n, self.n_outputs)
        self.K = np.zeros(n)
        self.t = 0
        self.n_resets = 0

    # ------------------------------------------------------------------ estimate
    def _skew_correction(self) -> tuple[NDArray, NDArray]:
        """``(I + lambda^N Ps Mk, lambda^N Ps Mk)`` for a non-symmetric ``P0``."""
        Ps = self._S @ self._S.T
        PsMk = self._decay * (Ps @ self._skew)
        return np.eye(self.n_inputs) + PsMk, PsMk

    @property
    def P(self) -> NDArray:
        """``P(N)``, shape ``(n_inputs, n_inputs)`` (a copy)."""
        Ps = self._S @ self._S.T
        Ps = 0.5 * Ps + 0.5 * Ps.T  # (Ps + Ps.T) / 2 could overflow near the float limit
        if self.symmetric:
            return Ps
        M, _ = self._skew_correction()
        return np.linalg.solve(M, Ps)

    @property
    def theta(self) -> NDArray:
        """``Theta(N)``, shape ``(n_inputs, n_outputs)`` (a copy)."""
        if self.symmetric:
            return self._theta_s.copy()
        M, PsMk = self._skew_correction()
        return np.linalg.solve(M, self._theta_s + PsMk @ self._prior)

    def predict(self, x: ArrayLike) -> NDArray:
        """Model output ``x^T Theta`` (shape ``(n_outputs,)``).

        Parameters
        ----------
        x : array_like, shape (n_inputs,)
            Finite regressor.

        Returns
        -------
        ndarray, shape (n_outputs,)

        Raises
        ------
        ValueError
            ``x`` not finite or of the wrong length.
        """
        return finite_vector(x, "x", length=self.n_inputs) @ self.theta

    def update(self, x: ArrayLike, y: ArrayLike) -> NDArray:
        """Process one sample ``(x, y)`` and return a copy of the new ``Theta``.

        Parameters
        ----------
        x : array_like, shape (n_inputs,)
        y : array_like, shape (n_outputs,) -- a scalar is accepted when ``n_outputs == 1``.
        """
        x = finite_vector(x, "x", length=self.n_inputs)
        y = finite_vector(y, "y", length=self.n_outputs)
        t = self.t + 1
        lam = self.forgetting
        if not self.symmetric:  # the paper's gain, with its non-symmetric P(N)
            with np.errstate(over="ignore", invalid="ignore"):
                Px = self.P @ x
                K = Px / (lam + x @ Px)
        saved_S = self._S.copy()
        status = matrix_rls_step(self._theta_s, self._S, x[None, :], y, lam, self._work, 0)
        self.t = t
        if status == OK:
            self._decay *= lam
            self.K = self._work.gain[0].copy() if self.symmetric else K
            return self.theta
        problem = "P lost positive definiteness or P, the gain or Theta overflowed"
        self._S[...] = saved_S  # Theta as before this sample
        if self.on_failure == "raise":
            self.t = t - 1
            raise NumericalHealthError(f"MatrixRLS update {t}: {problem}; state left unchanged")
        kept = self.theta  # then the restart at P0
        self._S[...] = self._S0
        self._theta_s[...] = kept
        self._prior[...] = kept
        self._decay = 1.0
        self.n_resets += 1
        warnings.warn(
            f"MatrixRLS update {t}: {problem}; sample discarded and P reset to P0, Theta kept",
            RuntimeWarning,
            stacklevel=2,
        )
        return kept.copy()


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
    on_failure
        As for :class:`MatrixRLS`, in the RLS phase. The minimum-norm phase has no covariance to
        reset: an overflow there raises :class:`NumericalHealthError` (estimator unchanged).

    Raises
    ------
    ValueError
        On construction: ``m`` not a positive integer, ``N`` not a non-negative one,
        ``forgetting`` outside ``(0, 1]``, ``C0`` not ``m x (m + N)``, ``dependence_tol``
        outside ``(0, 1)``, an unknown ``on_failure``.

    Examples
    --------
    Two states, one input: three independent regressors ``z = [x; u]`` determine
    ``[A B]`` exactly, and the estimator then switches to RLS:

    >>> import numpy as np
    >>> from stcgym.adaptive import StateMatrixEstimator
    >>> A = np.array([[0.9, 0.2], [0.0, 0.8]])
    >>> B = np.array([[0.0], [1.0]])
    >>> est = StateMatrixEstimator(2, 1)
    >>> x = np.array([1.0, 0.0])
    >>> for u in ([0.5], [-1.0], [0.3]):
    ...     x_next = A @ x + B @ u
    ...     C = est.update(x, u, x_next)
    ...     print(est.phase, est.rank)
    ...     x = x_next
    minimum_norm 1
    minimum_norm 2
    rls 3
    >>> np.allclose(est.A, A), np.allclose(est.B, B)
    (True, True)
    """

    def __init__(
        self,
        m: int,
        N: int,
        *,
        forgetting: float = 1.0,
        C0: ArrayLike | None = None,
        dependence_tol: float = 1e-9,
        on_failure: OnFailure = "reset",
    ) -> None:
        self.m = integer(m, "m")
        self.N = integer(N, "N (number of inputs)", 0)
        self.forgetting = forgetting_factor(forgetting)
        self.on_failure = one_of(on_failure, "on_failure", ("reset", "raise"))  # type: ignore[assignment]
        self.dependence_tol = real_in(dependence_tol, "dependence_tol", 0.0, 1.0,
                                      lo_open=True, hi_open=True)  # fmt: skip
        q = self.m + self.N
        self._C = np.zeros((self.m, q)) if C0 is None else matrix(C0, "C0", (self.m, q))
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
        """Process ``(x(t), u(t), x(t+1))`` and return the new ``C = [A B]``.

        Minimum-norm step (17)-(18) while the regressors do not span ``R^{m+N}``, RLS
        (20)-(21) afterwards (Kunik, Kovalenko & Al Sadi 2001).

        Parameters
        ----------
        x_t : array_like, shape (m,)
            The state ``x(t)``.
        u_t : array_like, shape (N,)
            The input ``u(t)`` (empty when ``N = 0``).
        x_next : array_like, shape (m,)
            The next state ``x(t+1)``.

        Returns
        -------
        ndarray, shape (m, m + N)
            A copy of ``C = [A B]``.

        Raises
        ------
        ValueError
            A vector not finite or of the wrong length (a non-empty ``u_t`` with ``N = 0``).
        NumericalHealthError
            The minimum-norm phase overflowed (estimator unchanged), or in the RLS phase with
            ``on_failure="raise"``.
        """
        x_t = finite_vector(x_t, "x_t", length=self.m)
        if self.N:
            u_t = finite_vector(u_t, "u_t", length=self.N)
        elif np.size(u_t):
            raise ValueError(f"u_t must be empty when N = 0, got {u_t!r}")
        else:
            u_t = np.zeros(0)
        x_next = finite_vector(x_next, "x_next", length=self.m)
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
            on_failure=self.on_failure,
        )
        self.R = None
