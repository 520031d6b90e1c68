"""Parameter-update rules of the recursive estimators: SG, MISG, RLS, MILS and their
model-decomposition (D-) variants (Ding & Ma 2014, ``shared/docs/algorithms.md`` §3 and §5).

A rule updates ``theta = [a; b]`` from the stacked regressors ``Phi(p, t)`` (``2n x p``, column
``j`` is ``phi_hat(t - j)``) and outputs ``Y(p, t)``. It is made of one or two *cores*: a plain
rule has one core over the whole ``theta``; a D- rule has one core for ``a`` (regressor rows
``0..n-1``, i.e. ``phi_a``) and one for ``b`` (rows ``n..2n-1``, i.e. ``psi``). Every core sees the
same innovation ``E(p, t) = Y(p, t) - Phi(p, t)^T theta(t-1)`` computed once with
``theta(t-1)``, as in (96)-(97), (104)-(106), (124)/(127) and (134)-(135) — the two sub-updates
are "Jacobi" style, never "Gauss-Seidel".

Cores
-----
* gradient core (SG (12)-(15), MISG (16)-(22), D-SG (96)-(103), D-MISG (104)-(117))::

      r(t) = lambda r(t-1) + ||phi_hat(t)||^2      (or + ||Phi(p, t)||^2, remark 1 / (116)-(117))
      delta = Phi(p, t) E(p, t) / r(t)

  ``lambda = 1`` is the paper; ``lambda < 1`` is the forgetting-gradient variant that keeps the
  step size from vanishing (tracking of time-varying plants).
* least-squares core (RLS (32)-(36), MILS (37)-(44), D-RLS (124)-(133), D-MILS (134)-(145)) with
  exponential forgetting ``lambda`` (``lambda = 1`` is the paper)::

      zeta = P(t-1) Phi,   S = lambda I_p + Phi^T zeta,   L(t) = zeta S^{-1}
      P(t) = [P(t-1) - L(t) zeta^T] / lambda,        delta = L(t) E(p, t)

  i.e. ``P^{-1}(t) = lambda P^{-1}(t-1) + Phi Phi^T``. With ``p = 1`` the scalar path
  (33)-(34) is used (no matrix solve). ``P`` stays exactly symmetric on the scalar path
  (``zeta zeta^T / s`` is computed symmetrically) and is symmetrised after every block update.

Finite history (``window = W``)
-------------------------------
For the least-squares rules the estimate can be restricted to the last ``W`` data blocks
(MATLAB's "finite history"): after adding block ``t`` the block ``t - W`` is removed by an exact
downdate ``P^{-1} <- P^{-1} - Phi Phi^T`` (``G = P Phi (I_p - Phi^T P Phi)^{-1}``,
``P <- P + G zeta^T``, ``theta <- theta - G E_old`` with ``E_old = Y_old - Phi_old^T theta``). For
a plain RLS rule this is the exact regularised least-squares estimate over the last ``W`` samples
``(H_W^T H_W + P0^{-1})^{-1} (H_W^T Y_W + P0^{-1} theta(0))``; for MILS the same over the last
``W`` stacked blocks; for D- rules each sub-estimator is windowed the same way (the hierarchical
approximation itself is kept). Window and forgetting are mutually exclusive.

Numerical health
----------------
A core raises :class:`HealthError` (internal) when a denominator or ``S`` is not positive, when
``P`` or ``r`` is not finite, or (in :meth:`ParameterRule.check_full`) when a Cholesky
factorisation of ``P`` fails. :class:`~stcgym.adaptive.recursive.RecursiveEstimator` turns this
into its documented safe action.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "HealthError",
    "GradientCore",
    "LeastSquaresCore",
    "ParameterRule",
    "innovation",
    "gradient_r",
    "ls_gain",
    "ls_covariance",
    "rls_gain",
    "rls_covariance",
    "is_spd",
]


class HealthError(FloatingPointError):
    """A rule's covariance or normaliser lost positive definiteness or became non-finite."""


# --------------------------------------------------------------------------------------------
# Formulas (short functions so that a batched version can reuse them)
# --------------------------------------------------------------------------------------------


def innovation(theta: NDArray, Phi: NDArray, Y: NDArray) -> NDArray:
    """Innovation vector ``E(p, t) = Y(p, t) - Phi(p, t)^T theta(t-1)``, eq. (17), (38).

    For ``p = 1`` it is the scalar innovation ``e(t)`` of (12), (32) as a length-1 array.
    """
    return Y - theta @ Phi


def gradient_r(r: float, Phi: NDArray, lam: float, stacked: bool) -> float:
    """Step normaliser ``r(t) = lambda r(t-1) + ||phi_hat(t)||^2``, eq. (13), (18), (98)-(99).

    With ``stacked`` the increment is ``||Phi(p, t)||^2`` (remark 1, (116)-(117)).
    """
    if stacked:
        inc = float(np.vdot(Phi, Phi))
    else:
        phi = Phi[:, 0]
        inc = float(phi @ phi)
    return lam * r + inc


def rls_gain(P: NDArray, phi: NDArray, lam: float) -> tuple[NDArray, NDArray, float]:
    """RLS gain ``L(t) = P(t-1) phi / (lambda + phi^T P(t-1) phi)``, eq. (33) / (55).

    Returns ``(L, zeta, s)`` with ``zeta = P(t-1) phi`` and ``s`` the scalar denominator.
    """
    zeta = P @ phi
    s = lam + float(phi @ zeta)
    return zeta / s, zeta, s


def rls_covariance(P: NDArray, zeta: NDArray, s: float, lam: float) -> None:
    """In place ``P(t) = [P(t-1) - zeta zeta^T / s] / lambda``, eq. (34) / (56).

    ``zeta zeta^T`` is formed before the division so that ``P`` stays exactly symmetric.
    """
    P -= np.multiply.outer(zeta, zeta) * (1.0 / s)
    if lam != 1.0:
        P *= 1.0 / lam


def ls_gain(P: NDArray, Phi: NDArray, lam: float) -> tuple[NDArray, NDArray]:
    """MILS gain ``L(t) = P(t-1) Phi [lambda I_p + Phi^T P(t-1) Phi]^{-1}``, eq. (39) / (75).

    Returns ``(L, zeta)`` with ``zeta = P(t-1) Phi``. Raises :class:`HealthError` when
    ``lambda I_p + Phi^T P Phi`` is not positive definite (then ``P`` is not).
    """
    zeta = P @ Phi
    S = Phi.T @ zeta
    S.flat[:: S.shape[0] + 1] += lam
    try:
        C = np.linalg.cholesky(S)
    except np.linalg.LinAlgError as exc:
        raise HealthError("I_p + Phi^T P Phi is not positive definite") from exc
    # L^T = S^{-1} zeta^T through the Cholesky factor (S symmetric positive definite).
    Lt = np.linalg.solve(C.T, np.linalg.solve(C, zeta.T))
    return Lt.T, zeta


def ls_covariance(P: NDArray, L: NDArray, zeta: NDArray, lam: float, work: NDArray) -> None:
    """In place ``P(t) = [P(t-1) - L(t) zeta^T] / lambda``, eq. (40) / (76), symmetrised."""
    P -= L @ zeta.T
    np.add(P, P.T, out=work)
    np.multiply(work, 0.5 / lam, out=P)


def is_spd(P: NDArray) -> bool:
    """True when ``P`` is finite and symmetric positive definite (Cholesky succeeds)."""
    try:
        C = np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        return False
    # A NaN or inf anywhere in (the lower triangle of) P reaches the factor's diagonal.
    return math.isfinite(float(C.trace()))


# --------------------------------------------------------------------------------------------
# Cores: one parameter block each
# --------------------------------------------------------------------------------------------


class GradientCore:
    """Normalised-gradient increment for one parameter block (SG / MISG family).

    Parameters
    ----------
    dim : int
        Size of the block (``2n`` plain, ``n`` for each half of a D- rule).
    r0 : float
        ``r(0)`` (paper: 1).
    forgetting : float
        ``lambda`` in ``r(t) = lambda r(t-1) + ||phi||^2``.
    stacked : bool
        Use ``||Phi(p, t)||^2`` instead of ``||phi_hat(t)||^2`` (remark 1).
    """

    has_covariance = False

    def __init__(self, dim: int, r0: float, forgetting: float, stacked: bool) -> None:
        self.dim = dim
        self.r0 = float(r0)
        self.lam = float(forgetting)
        self.stacked = bool(stacked)
        self.r = self.r0

    def reset(self) -> None:
        """Back to ``r(0)``."""
        self.r = self.r0

    def increment(self, Phi: NDArray, E: NDArray) -> NDArray:
        """``Phi E / r(t)`` after updating ``r``, eq. (12)-(13), (16)-(18)."""
        r = gradient_r(self.r, Phi, self.lam, self.stacked)
        if not (r > 0.0 and math.isfinite(r)):
            raise HealthError(f"r(t) = {r} is not finite and positive")
        self.r = r
        return Phi @ (E * (1.0 / r))

    def downdate(self, Phi: NDArray, E: NDArray) -> NDArray:  # pragma: no cover - guarded
        raise NotImplementedError("finite history is defined for least-squares rules only")

    def check_full(self) -> None:
        """Health check of the normaliser."""
        if not (self.r > 0.0 and math.isfinite(self.r)):
            raise HealthError(f"r(t) = {self.r} is not finite and positive")


class LeastSquaresCore:
    """Least-squares increment for one parameter block (RLS / MILS family).

    Parameters
    ----------
    P0 : ndarray, shape (dim, dim)
        ``P(0)``, symmetric positive definite (paper: ``p0 I``).
    forgetting : float
        ``lambda`` in ``P^{-1}(t) = lambda P^{-1}(t-1) + Phi Phi^T``.
    p : int
        Innovation length; ``p = 1`` uses the scalar RLS path (33)-(34).
    """

    has_covariance = True

    def __init__(self, P0: NDArray, forgetting: float, p: int) -> None:
        self.P0 = np.array(P0, dtype=float)
        self.dim = self.P0.shape[0]
        self.lam = float(forgetting)
        self.p = int(p)
        self.P = self.P0.copy()
        self._work = np.empty_like(self.P0)

    def reset(self) -> None:
        """Back to ``P(0)``."""
        self.P[...] = self.P0

    def increment(self, Phi: NDArray, E: NDArray) -> NDArray:
        """``L(t) E(p, t)`` after updating ``P``, eq. (32)-(34) or (37)-(40)."""
        P = self.P
        if self.p == 1:
            L, zeta, s = rls_gain(P, Phi[:, 0], self.lam)
            # s >= lambda > 0 whenever P is positive semidefinite.
            if not (s > 0.0 and math.isfinite(s)):
                raise HealthError(f"1 + phi^T P phi = {s} is not finite and positive")
            rls_covariance(P, zeta, s, self.lam)
            d = P.diagonal()
            if not (d.min() > 0.0 and math.isfinite(float(P.sum()))):
                raise HealthError("P(t) lost positive definiteness or overflowed")
            return L * E[0]
        L, zeta = ls_gain(P, Phi, self.lam)
        ls_covariance(P, L, zeta, self.lam, self._work)
        if not (P.diagonal().min() > 0.0 and math.isfinite(float(P.sum()))):
            raise HealthError("P(t) lost positive definiteness or overflowed")
        return L @ E

    def downdate(self, Phi: NDArray, E: NDArray) -> NDArray:
        """Remove a data block: ``P^{-1} <- P^{-1} - Phi Phi^T``; returns ``-G E``.

        ``G = P Phi (I_p - Phi^T P Phi)^{-1}`` is the gain of the updated ``P`` on ``Phi``;
        ``E`` must be the innovation of the removed block at the current ``theta``.
        """
        P = self.P
        zeta = P @ Phi
        S = -(Phi.T @ zeta)
        S.flat[:: S.shape[0] + 1] += 1.0
        try:
            C = np.linalg.cholesky(S)
        except np.linalg.LinAlgError as exc:
            raise HealthError("downdate: I_p - Phi^T P Phi is not positive definite") from exc
        G = np.linalg.solve(C.T, np.linalg.solve(C, zeta.T)).T
        P += G @ zeta.T
        np.add(P, P.T, out=self._work)
        np.multiply(self._work, 0.5, out=P)
        if not (P.diagonal().min() > 0.0 and math.isfinite(float(P.sum()))):
            raise HealthError("P(t) lost positive definiteness or overflowed (downdate)")
        return -(G @ E)

    def check_full(self) -> None:
        """Cholesky test of ``P``."""
        if not is_spd(self.P):
            raise HealthError("P(t) is not symmetric positive definite")


# --------------------------------------------------------------------------------------------
# Rule = one core (plain) or two cores sharing the innovation (model decomposition)
# --------------------------------------------------------------------------------------------


class ParameterRule:
    """A parameter-update rule: ``SG``, ``MISG``, ``RLS``, ``MILS``, optionally decomposed.

    Parameters
    ----------
    kind : {"SG", "MISG", "RLS", "MILS"}
    n, p : int
        Plant order and innovation length.
    decomposed : bool
        ``True`` for the D- variant: separate ``a`` and ``b`` cores, one shared innovation.
    P0 : ndarray, shape (2n, 2n), optional
        ``P(0)`` for least-squares rules (block-diagonal when ``decomposed``).
    r0, forgetting, stacked_r, window :
        See the module docstring.
    """

    def __init__(
        self,
        kind: str,
        n: int,
        p: int,
        *,
        decomposed: bool,
        P0: NDArray | None,
        r0: float,
        forgetting: float,
        stacked_r: bool,
        window: int | None,
    ) -> None:
        self.kind = kind
        self.n = n
        self.p = p
        self.decomposed = decomposed
        self.least_squares = kind in ("RLS", "MILS")
        d = 2 * n
        blocks = [slice(0, n), slice(n, d)] if decomposed else [slice(0, d)]
        cores: list[GradientCore | LeastSquaresCore] = []
        for blk in blocks:
            if self.least_squares:
                assert P0 is not None
                cores.append(LeastSquaresCore(P0[blk, blk], forgetting, p))
            else:
                cores.append(GradientCore(blk.stop - blk.start, r0, forgetting, stacked_r))
        self.blocks = blocks
        self.cores = cores
        self.window = window
        self._delta = np.zeros(d)
        if window is not None:
            self._hist_Phi = np.zeros((window, d, p))
            self._hist_Y = np.zeros((window, p))
        self._count = 0

    def reset(self) -> None:
        """Back to ``P(0)`` / ``r(0)`` and an empty finite-history buffer."""
        for core in self.cores:
            core.reset()
        self._count = 0
        if self.window is not None:
            self._hist_Phi[...] = 0.0
            self._hist_Y[...] = 0.0

    def step(self, theta: NDArray, Phi: NDArray, Y: NDArray) -> NDArray:
        """Update ``theta`` in place from ``Phi(p, t)``, ``Y(p, t)``; return ``E(p, t)``.

        ``theta`` is left untouched when a :class:`HealthError` is raised.
        """
        E = innovation(theta, Phi, Y)
        delta = self._delta
        for blk, core in zip(self.blocks, self.cores, strict=True):
            delta[blk] = core.increment(Phi[blk], E)
        if self.window is not None:
            self._slide(theta, Phi, Y, delta)
        if not math.isfinite(float(delta.sum())):
            raise HealthError("theta(t) would not be finite")
        theta += delta
        return E

    def _slide(self, theta: NDArray, Phi: NDArray, Y: NDArray, delta: NDArray) -> None:
        """Finite history: store block t, remove block t - W (exact downdate)."""
        W = self.window
        k = self._count % W
        if self._count >= W:
            Phi_old = self._hist_Phi[k]
            E_old = innovation(theta + delta, Phi_old, self._hist_Y[k])
            for blk, core in zip(self.blocks, self.cores, strict=True):
                delta[blk] += core.downdate(Phi_old[blk], E_old)
        self._hist_Phi[k] = Phi
        self._hist_Y[k] = Y
        self._count += 1

    def check_full(self) -> None:
        """Full health check (Cholesky of every ``P`` block, finiteness of ``r``)."""
        for core in self.cores:
            core.check_full()

    # ---- read-only views ------------------------------------------------------------------

    @property
    def P(self) -> NDArray | None:
        """``P(t)`` (block-diagonal ``2n x 2n`` for D- rules), ``None`` for gradient rules."""
        if not self.least_squares:
            return None
        if not self.decomposed:
            return self.cores[0].P.copy()
        d = 2 * self.n
        out = np.zeros((d, d))
        for blk, core in zip(self.blocks, self.cores, strict=True):
            out[blk, blk] = core.P
        return out

    @property
    def r(self) -> NDArray | None:
        """``[r(t)]`` or ``[r1(t), r2(t)]`` for gradient rules, ``None`` otherwise."""
        if self.least_squares:
            return None
        return np.array([core.r for core in self.cores])
