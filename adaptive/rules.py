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

      L(t) = P(t-1) Phi [lambda I_p + Phi^T P(t-1) Phi]^{-1}
      P(t) = [P(t-1) - L(t) Phi^T P(t-1)] / lambda,        delta = L(t) E(p, t)

  i.e. ``P^{-1}(t) = lambda P^{-1}(t-1) + Phi Phi^T``. It is computed in square-root form
  (``P = S S^T``; Potter's rank-one update or a Cholesky block update, see
  :class:`LeastSquaresCore`): the same numbers in exact arithmetic, but ``P`` cannot lose
  symmetry or positive definiteness through cancellation.

Finite history (``window = W``)
-------------------------------
For the least-squares rules the estimate can be restricted to the last ``W`` data blocks
(MATLAB's "finite history"): after adding block ``t`` the block ``t - W`` is removed by an exact
downdate ``P^{-1} <- P^{-1} - Phi Phi^T`` (square-root form, column by column) and
``theta <- theta - P Phi E_old`` with ``E_old = Y_old - Phi_old^T theta``. Downdating cancels
digits when the removed block dominates; if ``1 - phi^T P phi <= DOWNDATE_TOL`` the estimate is
recomputed exactly from the stored window instead (counted in ``ParameterRule.n_recomputes``). For
a plain RLS rule this is the exact regularised least-squares estimate over the last ``W`` samples
``(H_W^T H_W + P0^{-1})^{-1} (H_W^T Y_W + P0^{-1} theta(0))``; for MILS the same over the last
``W`` stacked blocks; for D- rules each sub-estimator is windowed the same way (the hierarchical
approximation itself is kept). Window and forgetting are mutually exclusive.

Numerical health
----------------
A core raises :class:`NumericalHealthError` when a denominator is not positive, when ``P`` or
``r`` is not finite (checked every step), or (in :meth:`ParameterRule.check_full`, run every
``pd_check_every`` steps by the estimator) when the factor of ``P`` lost rank.
:class:`~stcgym.adaptive.recursive.RecursiveEstimator` turns this into its documented safe
action.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "DOWNDATE_TOL",
    "IllConditionedDowndate",
    "NumericalHealthError",
    "GradientCore",
    "LeastSquaresCore",
    "ParameterRule",
    "innovation",
    "gradient_r",
    "potter_update",
    "block_update",
    "potter_downdate",
]


_EPS = float(np.finfo(float).eps)

#: Smallest acceptable pivot (squared) of ``I_p - Phi^T P Phi`` in a finite-history downdate.
DOWNDATE_TOL = 1e-8


class NumericalHealthError(FloatingPointError):
    """A covariance or normaliser lost positive definiteness or became non-finite.

    Raised by the estimators when ``on_failure="raise"``; with the default ``"reset"`` they
    recover instead and emit a :class:`RuntimeWarning`.
    """


class IllConditionedDowndate(NumericalHealthError):
    """A finite-history downdate would be inaccurate; the rule recomputes from its buffer."""


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


def potter_update(S: NDArray, phi: NDArray, lam: float) -> tuple[NDArray, float]:
    """Square-root form of the RLS covariance update (33)-(34) with forgetting, in place.

    With ``P(t-1) = S S^T``, ``f = S^T phi``, ``s = lambda + f^T f`` (the denominator of (33)),
    ``S <- [S - beta (S f) f^T] / sqrt(lambda)``, ``beta = 1 / (s (1 + sqrt(lambda / s)))``,
    gives ``S S^T = [P - P phi phi^T P / s] / lambda = P(t)`` exactly (Potter). Returns
    ``(P(t-1) phi, s)`` so that the gain (33) is ``L(t) = P(t-1) phi / s``.
    """
    f = phi @ S  # S^T phi
    s = lam + float(f @ f)
    Sf = S @ f  # P(t-1) phi
    beta = 1.0 / (s * (1.0 + math.sqrt(lam / s)))
    S -= np.multiply.outer(Sf * beta, f)
    if lam != 1.0:
        S *= 1.0 / math.sqrt(lam)
    return Sf, s


def block_update(S: NDArray, Phi: NDArray, lam: float) -> None:
    """Square-root form of the MILS covariance update (39)-(40) with forgetting, in place.

    ``P(t) = [lambda P^{-1}(t-1) + Phi Phi^T]^{-1} = S M^{-1} S^T`` with
    ``M = lambda I + S^T Phi Phi^T S = G G^T`` (Cholesky; ``M >= lambda I``, so it cannot fail
    for finite data), hence ``S <- S G^{-T}``.
    """
    F = Phi.T @ S  # (S^T Phi)^T, p x dim
    M = F.T @ F
    M.flat[:: M.shape[0] + 1] += lam
    G = np.linalg.cholesky(M)
    S[...] = np.linalg.solve(G, S.T).T


def potter_downdate(S: NDArray, phi: NDArray) -> float:
    """Square-root downdate ``P <- (P^{-1} - phi phi^T)^{-1}``, in place; returns ``1 - q``.

    ``f = S^T phi``, ``q = f^T f`` (must be < 1), ``S <- S + beta (S f) f^T`` with
    ``beta = 1 / (sqrt(1 - q) (1 + sqrt(1 - q)))``. ``S`` is left untouched when
    ``1 - q <= DOWNDATE_TOL`` (the subtraction would cancel most digits).
    """
    f = phi @ S
    g = 1.0 - float(f @ f)
    if not g > DOWNDATE_TOL:
        return g
    r = math.sqrt(g)
    S += np.multiply.outer((S @ f) * (1.0 / (r * (1.0 + r))), f)
    return g


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
            raise NumericalHealthError(f"r(t) = {r} is not finite and positive")
        self.r = r
        return Phi @ (E * (1.0 / r))

    def downdate(self, Phi: NDArray, E: NDArray) -> NDArray:  # pragma: no cover - guarded
        raise NotImplementedError("finite history is defined for least-squares rules only")

    def check_full(self) -> None:
        """Health check of the normaliser."""
        if not (self.r > 0.0 and math.isfinite(self.r)):
            raise NumericalHealthError(f"r(t) = {self.r} is not finite and positive")


class LeastSquaresCore:
    """Least-squares increment for one parameter block (RLS / MILS family).

    ``P`` is kept as a square-root factor ``S`` (``P = S S^T``): RLS uses Potter's rank-one
    update (:func:`potter_update`) and the gain (33); MILS uses the block update
    (:func:`block_update`) of ``P^{-1}(t) = lambda P^{-1}(t-1) + Phi Phi^T`` and the increment
    ``L(t) E(p, t) = P(t) Phi(p, t) E(p, t)`` (since ``L(t) = P(t) Phi(p, t)``). This is the
    paper's RLS/MILS in exact arithmetic, but ``P`` stays symmetric positive semidefinite by
    construction: the textbook update ``P - L zeta^T`` cancels catastrophically when
    ``phi^T P phi`` is large (``p0 = 1e6`` with signals of size 100 loses positive definiteness
    within ~10 steps).

    Parameters
    ----------
    P0 : ndarray, shape (dim, dim)
        ``P(0)``, symmetric positive definite (paper: ``p0 I``).
    forgetting : float
        ``lambda`` in ``P^{-1}(t) = lambda P^{-1}(t-1) + Phi Phi^T``.
    p : int
        Innovation length.
    scalar : bool
        Use the RLS form (33) ``L(t) = P(t-1) phi / s`` (only with ``p = 1``); otherwise the
        MILS form ``L(t) = P(t) Phi``, so that "MILS with p = 1 equals RLS" is a real check.
    """

    has_covariance = True

    def __init__(self, P0: NDArray, forgetting: float, p: int, scalar: bool = True) -> None:
        self.P0 = np.array(P0, dtype=float)
        self.dim = self.P0.shape[0]
        self.lam = float(forgetting)
        self.p = int(p)
        self.scalar = bool(scalar) and self.p == 1
        self.S0 = np.linalg.cholesky(self.P0)
        self.S = self.S0.copy()

    def reset(self) -> None:
        """Back to ``P(0)``."""
        self.S[...] = self.S0

    @property
    def P(self) -> NDArray:
        """``P(t) = S S^T`` (a new symmetric array)."""
        P = self.S @ self.S.T
        return 0.5 * P + 0.5 * P.T

    def increment(self, Phi: NDArray, E: NDArray) -> NDArray:
        """``L(t) E(p, t)`` after updating ``P``, eq. (32)-(34) or (37)-(40)."""
        S = self.S
        if self.scalar:
            Sf, s = potter_update(S, Phi[:, 0], self.lam)
            # trace(P) = ||S||_F^2 bounds every entry of P; NaN propagates into it.
            if not (s > 0.0 and math.isfinite(s) and math.isfinite(float(np.vdot(S, S)))):
                raise NumericalHealthError(f"lambda + phi^T P phi = {s}: P(t) overflowed")
            return Sf * (E[0] / s)  # L(t) e(t), L(t) = P(t-1) phi / s, eq. (33)
        try:
            block_update(S, Phi, self.lam)
        except np.linalg.LinAlgError as exc:
            raise NumericalHealthError("P(t) is not finite") from exc
        delta = S @ ((Phi @ E) @ S)  # L(t) E(p, t) = P(t) Phi E
        if not math.isfinite(float(np.vdot(S, S))):
            raise NumericalHealthError("P(t) overflowed")
        return delta

    def downdate(self, Phi: NDArray, E: NDArray) -> NDArray:
        """Remove a data block, ``P^{-1} <- P^{-1} - Phi Phi^T``; returns ``-P_new Phi E``.

        ``E`` must be the innovation of the removed block at the current ``theta``
        (``theta_new = P_new (P^{-1} theta - Phi Y) = theta - P_new Phi E``). Raises
        :class:`IllConditionedDowndate` (``P`` restored) when a column cannot be removed
        accurately.
        """
        S = self.S
        saved = S.copy()
        for j in range(Phi.shape[1]):
            g = potter_downdate(S, Phi[:, j])
            if not g > DOWNDATE_TOL:
                S[...] = saved
                raise IllConditionedDowndate(f"1 - phi^T P phi = {g:.3g} in a downdate")
        if not math.isfinite(float(np.vdot(S, S))):
            S[...] = saved
            raise IllConditionedDowndate("downdate overflowed")
        return -(S @ ((Phi @ E) @ S))

    def recompute(self, Phis: NDArray, theta0: NDArray | None, Ys: NDArray | None) -> NDArray:
        """Exact finite-history estimate from stored blocks (fallback of :meth:`downdate`).

        ``P = (P0^{-1} + sum_k Phi_k Phi_k^T)^{-1} = S S^T`` with ``S = C^{-T}``, ``C`` the
        Cholesky factor of the information matrix; with ``theta0`` and ``Ys`` also returns
        ``theta = P (P0^{-1} theta0 + sum_k Phi_k Y_k)``.
        """
        P0_inv = np.linalg.inv(self.P0)
        J = P0_inv + np.einsum("kip,kjp->ij", Phis, Phis)
        try:
            C = np.linalg.cholesky(0.5 * (J + J.T))
        except np.linalg.LinAlgError as exc:
            msg = "window information matrix is not positive definite"
            raise NumericalHealthError(msg) from exc
        self.S[...] = np.linalg.solve(C, np.eye(self.dim)).T
        if theta0 is None or Ys is None:
            return np.zeros(self.dim)
        return self.P @ (P0_inv @ theta0 + np.einsum("kip,kp->i", Phis, Ys))

    def check_full(self) -> None:
        """``P = S S^T`` is symmetric positive definite iff the factor ``S`` is finite and
        nonsingular: fail when its singular values are not finite or the smallest is below
        ``dim * eps`` times the largest (rank lost). A Cholesky test of ``P`` itself would
        wrongly fail whenever ``cond(P) > 1e16``, which data spanning many decades can
        legitimately produce."""
        try:
            sv = np.linalg.svd(self.S, compute_uv=False)
        except np.linalg.LinAlgError as exc:
            raise NumericalHealthError("P(t) is not finite") from exc
        if not (math.isfinite(float(sv[0])) and sv[-1] > sv[0] * self.dim * _EPS):
            raise NumericalHealthError("P(t) is not symmetric positive definite (rank lost)")


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
    theta0 : ndarray, shape (2n,), optional
        ``theta(0)``: the prior of the finite-history estimate when it is recomputed.
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
        theta0: NDArray | None = None,
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
                cores.append(LeastSquaresCore(P0[blk, blk], forgetting, p, kind == "RLS"))
            else:
                cores.append(GradientCore(blk.stop - blk.start, r0, forgetting, stacked_r))
        self.blocks = blocks
        self.cores = cores
        self.window = window
        self._delta = np.zeros(d)
        self._down = np.zeros(d)
        self.theta0 = np.zeros(d) if theta0 is None else np.array(theta0, dtype=float)
        self.n_recomputes = 0
        if window is not None:
            self._hist_Phi = np.zeros((window, d, p))
            self._hist_Y = np.zeros((window, p))
        self._count = 0

    def reset(self) -> None:
        """Back to ``P(0)`` / ``r(0)`` and an empty finite-history buffer."""
        for core in self.cores:
            core.reset()
        self._count = 0
        self.n_recomputes = 0
        if self.window is not None:
            self._hist_Phi[...] = 0.0
            self._hist_Y[...] = 0.0

    def step(self, theta: NDArray, Phi: NDArray, Y: NDArray) -> NDArray:
        """Update ``theta`` in place from ``Phi(p, t)``, ``Y(p, t)``; return ``E(p, t)``.

        ``theta`` is left untouched when a :class:`NumericalHealthError` is raised.
        """
        E = innovation(theta, Phi, Y)
        if self.decomposed:  # both halves use E computed with theta(t-1)
            delta = self._delta
            for blk, core in zip(self.blocks, self.cores, strict=True):
                delta[blk] = core.increment(Phi[blk], E)
        else:
            delta = self.cores[0].increment(Phi, E)
        if self.window is not None:
            self._slide(theta, Phi, Y, delta)
        if not math.isfinite(float(delta.sum())):
            raise NumericalHealthError("theta(t) would not be finite")
        theta += delta
        return E

    def _slide(self, theta: NDArray, Phi: NDArray, Y: NDArray, delta: NDArray) -> None:
        """Finite history: store block t, remove block t - W.

        The removal is the exact rank-p downdate; when it is ill-conditioned the window
        estimate is recomputed from the stored blocks instead (plain rules: ``P`` and ``theta``
        exactly; D- rules: each block's ``P``, ``theta`` keeps the hierarchical update).
        """
        W = self.window
        k = self._count % W
        self._count += 1
        if self._count <= W:
            self._hist_Phi[k] = Phi
            self._hist_Y[k] = Y
            return
        Phi_old = self._hist_Phi[k].copy()
        Y_old = self._hist_Y[k].copy()
        self._hist_Phi[k] = Phi
        self._hist_Y[k] = Y
        E_old = innovation(theta + delta, Phi_old, Y_old)
        down = self._down
        try:
            for blk, core in zip(self.blocks, self.cores, strict=True):
                down[blk] = core.downdate(Phi_old[blk], E_old)
        except IllConditionedDowndate:
            self.n_recomputes += 1
            for blk, core in zip(self.blocks, self.cores, strict=True):
                Phis = self._hist_Phi[:, blk, :]
                if self.decomposed:
                    core.recompute(Phis, None, None)
                else:
                    th = core.recompute(Phis, self.theta0, self._hist_Y)
                    delta[blk] = th - theta[blk]
            return
        delta += down

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
