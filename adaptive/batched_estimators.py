"""Batched recursive estimators: ``B`` independent copies of
:class:`~stcgym.adaptive.recursive.RecursiveEstimator` stepped together.

Two implementations share one interface (:class:`BatchedEstimatorBase`):

``mode="exact"`` (:class:`BatchedRecursiveEstimator`)
    A line-by-line transliteration of :mod:`stcgym.adaptive.recursive` and
    :mod:`stcgym.adaptive.rules` onto arrays with a leading batch axis. Every matrix product,
    Cholesky factorisation and solve is the *same* numpy/BLAS/LAPACK call on a stack of
    matrices (numpy's ``matmul`` / ``linalg`` gufuncs apply the single-matrix kernel to each
    stack element), and every elementwise operation is the same IEEE operation, so each lane
    reproduces a single estimator to rounding (not bit for bit: OpenBLAS may pick another
    kernel for a stacked product than for a single one, depending on the CPU). Cost: a few
    stacked calls per step, about 1-3 us per lane-step.

``mode="fast"`` (:class:`~stcgym.adaptive.batched_kernels.FastBatchedEstimator`)
    Straight-line kernels generated for the given ``n``, ``p`` that exploit the structure of
    the canonical matrices and the symmetry of ``P`` and apply the same equations to all lanes
    with elementwise numpy operations on lane-contiguous arrays. The same kernel also compiles
    to scalar Python for a single plant. Same equations, different rounding: see that module
    for how close it stays.

Everything (arguments, defaults, health checks and their recovery) follows
:func:`~stcgym.adaptive.recursive.make_estimator`; arrays carry a leading batch axis: ``update``
takes ``y`` of shape ``(B,)`` and returns ``theta`` of shape ``(B, 2n)``, ``predict`` takes
``u`` of shape ``(B,)``. ``enabled`` is per lane. Not batched: finite history (``window``), the
closed-loop observer (``CO-``/``observer_gain``) and ``project_stable``.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.rules import NumericalHealthError

__all__ = [
    "BatchedEstimatorBase",
    "BatchedRecursiveEstimator",
    "EstimatorConfig",
    "estimator_config",
    "make_batched_estimator",
]


# --------------------------------------------------------------------------------------------
# Configuration: validated by the single-estimator factory itself
# --------------------------------------------------------------------------------------------
class EstimatorConfig:
    """Everything a batched estimator needs, read from a prototype single estimator.

    Building the prototype with :func:`~stcgym.adaptive.recursive.make_estimator` validates the
    arguments exactly as the single estimator does and fixes every default in one place.
    """

    def __init__(self, proto: Any, num_envs: int) -> None:
        from stcgym.adaptive.state_estimators import KalmanFilter

        self.proto = proto
        self.num_envs = int(num_envs)
        self.name: str = proto.name
        self.n: int = proto.n
        self.p: int = proto.p
        self.d = 2 * proto.n
        self.form: str = proto.form
        rule = proto.rule
        if getattr(rule, "window", None) is not None:
            raise NotImplementedError("finite history (window=...) is not batched")
        if proto.state_estimator.name == "CO":
            raise NotImplementedError("the closed-loop observer (CO-/observer_gain) is not batched")
        if getattr(proto, "_project", False):
            raise NotImplementedError("project_stable=True is not batched")
        self.kind: str = rule.kind
        self.decomposed: bool = rule.decomposed
        self.least_squares: bool = rule.least_squares
        self.blocks: list[slice] = list(rule.blocks)
        cores = rule.cores
        self.lam: float = cores[0].lam
        if self.least_squares:
            self.P0 = [np.array(c.P0, dtype=float) for c in cores]
            # RLS uses the scalar (Potter) form, MILS the block square-root form (any p).
            self.scalar_ls: bool = bool(getattr(cores[0], "scalar", self.p == 1))
        else:
            self.r0 = [float(c.r0) for c in cores]
            self.stacked: bool = bool(cores[0].stacked)
        se = proto.state_estimator
        self.kalman = isinstance(se, KalmanFilter)
        if self.kalman:
            self.P1_init = np.array(se.P1_init, dtype=float)
            self.Q = np.array(se.Q, dtype=float)
            self.has_Q = bool(se.has_Q)
            self.R = float(se.R)
        self.theta0 = np.array(proto._theta0, dtype=float)
        self.x_init = np.array(proto._x_init, dtype=float)
        self.enabled = bool(proto.enabled)
        self.on_failure: str = proto._on_failure
        self.check_every: int = int(proto._check_every)
        self.flops = (proto.flops_parameters, proto.flops_state)


def estimator_config(name: str, n: int, num_envs: int, **kwargs: Any) -> EstimatorConfig:
    """Validate ``make_estimator`` arguments and return the batched configuration.

    ``theta0`` (and ``P0``) may be per lane, shape ``(num_envs, 2n)`` (``(num_envs, 2n, 2n)``);
    the prototype is then validated with lane 0 and the per-lane arrays are kept.
    """
    from stcgym.adaptive.recursive import make_estimator

    if isinstance(num_envs, bool) or int(num_envs) != num_envs or num_envs < 1:
        raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
    B = int(num_envs)
    lane_theta0 = lane_P0 = None
    kw = dict(kwargs)
    if kw.get("theta0") is not None and np.ndim(kw["theta0"]) == 2:
        lane_theta0 = np.array(kw["theta0"], dtype=float)
        if lane_theta0.shape != (B, 2 * n) or not np.all(np.isfinite(lane_theta0)):
            raise ValueError(f"per-lane theta0 must be finite with shape ({B}, {2 * n})")
        kw["theta0"] = lane_theta0[0]
    if kw.get("P0") is not None and np.ndim(kw["P0"]) == 3:
        lane_P0 = np.array(kw["P0"], dtype=float)
        if lane_P0.shape != (B, 2 * n, 2 * n):
            raise ValueError(f"per-lane P0 must have shape ({B}, {2 * n}, {2 * n})")
        kw["P0"] = lane_P0[0]
    cfg = EstimatorConfig(make_estimator(name, n, **kw), B)
    cfg.lane_theta0 = lane_theta0
    cfg.lane_P0 = None
    if lane_P0 is not None:
        # Each lane's P0 goes through the same validation as the single factory's.
        from stcgym.adaptive.recursive import _covariance

        blocks = []
        for blk in cfg.blocks:
            blocks.append(np.array([_covariance(M, 2 * n, "P0")[blk, blk] for M in lane_P0]))
        cfg.lane_P0 = blocks
    return cfg


# --------------------------------------------------------------------------------------------
# Common interface
# --------------------------------------------------------------------------------------------
def _lane_vector(value: ArrayLike, B: int, name: str) -> NDArray:
    """A finite float vector of one value per lane (a scalar is broadcast)."""
    try:
        # A private copy: the estimators keep y(t) and reset lanes in place.
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric, got {value!r}") from exc
    if arr.ndim == 0:
        arr = np.full(B, float(arr))
    arr = arr.reshape(-1) if arr.ndim == 2 and arr.shape[1] == 1 else arr
    if arr.shape != (B,):
        raise ValueError(f"{name} must have shape ({B},) (one value per lane), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = np.flatnonzero(~np.isfinite(arr))[:5]
        raise ValueError(f"{name} must be finite; lanes {bad.tolist()} are not")
    return arr


class BatchedEstimatorBase:
    """Shared driver logic: call order, validation, lane masks and health reporting."""

    cfg: EstimatorConfig

    def __init__(self, cfg: EstimatorConfig) -> None:
        self.cfg = cfg
        self.name, self.n, self.p, self.form = cfg.name, cfg.n, cfg.p, cfg.form
        self.num_envs = cfg.num_envs
        self._awaiting_predict = False

    # -- call order (the lanes step in lock-step) ---------------------------------------------
    def _begin_update(self, y_t: ArrayLike) -> NDArray:
        if self._awaiting_predict:
            raise RuntimeError(
                f"{self.name}: update() called twice without predict(u(t)) in between; the "
                "order is update(y(t)) -> compute u(t) -> predict(u(t))"
            )
        return _lane_vector(y_t, self.num_envs, "y(t)")

    def _begin_predict(self, u_t: ArrayLike) -> NDArray:
        if not self._awaiting_predict:
            raise RuntimeError(
                f"{self.name}: predict() must follow update(y(t)); the order is "
                "update(y(t)) -> compute u(t) -> predict(u(t))"
            )
        return _lane_vector(u_t, self.num_envs, "u(t)")

    def _report(self, lanes: NDArray, what: str, action: str) -> None:
        """One warning (or error) per call for all lanes that hit a health event."""
        if lanes.size == 0:
            return
        msg = f"{self.name}: {what} in {lanes.size} lane(s) {lanes[:8].tolist()}"
        if self.cfg.on_failure == "raise":
            raise NumericalHealthError(msg)
        warnings.warn(f"{msg}; {action}", RuntimeWarning, stacklevel=3)

    def run(self, u: ArrayLike, y: ArrayLike) -> NDArray:
        """Open-loop pass over recorded data of shape ``(B, T)``; returns ``(B, T, 2n)``."""
        u_arr = np.asarray(u, dtype=float)
        y_arr = np.asarray(y, dtype=float)
        if u_arr.shape != y_arr.shape or u_arr.ndim != 2 or u_arr.shape[0] != self.num_envs:
            raise ValueError(
                f"u and y must both have shape (num_envs={self.num_envs}, T), got {u_arr.shape} "
                f"and {y_arr.shape}"
            )
        if self._awaiting_predict:
            raise RuntimeError(f"{self.name}: run() called between update() and predict()")
        out = np.empty((self.num_envs, u_arr.shape[1], 2 * self.n))
        for k in range(u_arr.shape[1]):
            out[:, k] = self.update(y_arr[:, k])
            self.predict(u_arr[:, k])
        return out

    @property
    def a(self) -> NDArray:
        """``a_hat(t)`` per lane (copy)."""
        return self.theta[:, : self.n]

    @property
    def b(self) -> NDArray:
        """``b_hat(t)`` per lane (copy)."""
        return self.theta[:, self.n :]

    @property
    def e(self) -> NDArray:
        """Scalar innovation ``e(t)`` per lane."""
        return self.innovation[:, 0]

    @property
    def flops_parameters(self) -> int:
        return self.cfg.flops[0]

    @property
    def flops_state(self) -> int:
        return self.cfg.flops[1]

    @property
    def flops_per_step(self) -> int:
        """Flops per lane and step (paper conventions; table 1 / table 2)."""
        return self.cfg.flops[0] + self.cfg.flops[1]

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}({self.name!r}, n={self.n}, p={self.p}, form={self.form!r}, "
            f"num_envs={self.num_envs})"
        )


# --------------------------------------------------------------------------------------------
# Exact mode: stacked transliteration of the single estimator
# --------------------------------------------------------------------------------------------
def _mv(M: NDArray, v: NDArray) -> NDArray:
    """Stacked ``M @ v`` for 1-D ``v`` per lane (the single code's ``matrix @ vector``)."""
    return (M @ v[..., None])[..., 0]


def _vm(v: NDArray, M: NDArray) -> NDArray:
    """Stacked ``v @ M`` for 1-D ``v`` per lane."""
    return (v[:, None, :] @ M)[:, 0, :]


def _vv(v: NDArray, w: NDArray) -> NDArray:
    """Stacked ``v @ w`` of two 1-D vectors per lane."""
    return (v[:, None, :] @ w[..., None])[:, 0, 0]


def stacked_lanes(fn: Callable[[NDArray], NDArray], M: NDArray) -> tuple[NDArray, NDArray]:
    """``fn`` (``np.linalg.cholesky`` / ``inv``) on a stack of matrices, and a success mask.

    numpy raises for the whole stack when one matrix fails; the (rare) failing call is then
    repeated lane by lane, which gives the same results for the lanes that succeed (NaN for
    the others).
    """
    try:
        return fn(M), np.ones(M.shape[0], dtype=bool)
    except np.linalg.LinAlgError:
        out = np.full_like(M, np.nan)
        ok = np.zeros(M.shape[0], dtype=bool)
        for i in range(M.shape[0]):
            try:
                out[i] = fn(M[i])
                ok[i] = True
            except np.linalg.LinAlgError:
                pass
        return out, ok


class BatchedRecursiveEstimator(BatchedEstimatorBase):
    """``B`` lanes of a recursive estimator, equal to ``B`` single estimators to rounding.

    Build it with :func:`make_batched_estimator` (``mode="exact"``). State arrays have a leading
    batch axis; the public properties return copies.
    """

    def __init__(self, cfg: EstimatorConfig) -> None:
        super().__init__(cfg)
        B, n, d, p = cfg.num_envs, cfg.n, cfg.d, cfg.p
        self._theta0 = (
            np.array(cfg.lane_theta0)
            if cfg.lane_theta0 is not None
            else np.tile(cfg.theta0, (B, 1))
        )
        self._x_init = np.tile(cfg.x_init, (B, 1))
        if cfg.least_squares:
            # Square-root factors S (P = S S^T) and S(0) = cholesky(P(0)), as the reference.
            P0s = (
                [np.array(P) for P in cfg.lane_P0]
                if cfg.lane_P0 is not None
                else [np.tile(P, (B, 1, 1)) for P in cfg.P0]
            )
            self._S0 = [np.linalg.cholesky(P) for P in P0s]
            self._S = [S.copy() for S in self._S0]
        else:
            self._r0 = [np.full(B, r) for r in cfg.r0]
            self._r = [r.copy() for r in self._r0]
        self._theta = self._theta0.copy()
        self._Phi = np.zeros((B, d, p))
        self._Y = np.zeros((B, p))
        self._E = np.zeros((B, p))
        self._phi = np.zeros((B, d))  # regressor phi_hat(t+1) being built
        self._xs = np.zeros((B, n, n))  # observability form: last n state estimates, newest first
        self._x = self._x_init.copy()
        self._y = np.zeros(B)
        self._t = np.zeros(B, dtype=np.int64)
        self._enabled = np.full(B, cfg.enabled)
        self._n_resets = np.zeros(B, dtype=np.int64)
        self._n_state_resets = np.zeros(B, dtype=np.int64)
        self._n_kf_resets = np.zeros(B, dtype=np.int64)
        if cfg.kalman:
            # Per lane: a controller may rebuild lanes with another P1(1) and tune Q online.
            self._P1_init = np.tile(cfg.P1_init, (B, 1, 1))
            self._Q = np.tile(cfg.Q, (B, 1, 1))
            self._P1 = self._P1_init.copy()
            self._L1 = np.zeros((B, n))
        self._A = np.tile(np.eye(n, k=1), (B, 1, 1))
        self._a = np.zeros((B, n))
        self._b = np.zeros((B, n))

    # ------------------------------------------------------------------------ lifecycle
    def reset(self, lanes: ArrayLike | None = None) -> None:
        """Back to the initial conditions (all lanes, or a boolean mask / index array)."""
        idx = slice(None) if lanes is None else np.asarray(lanes)
        if idx is not None and not isinstance(idx, slice) and idx.dtype == bool:
            idx = np.flatnonzero(idx)
        if not isinstance(idx, slice) and idx.size == 0:
            return
        self._theta[idx] = self._theta0[idx]
        if self.cfg.least_squares:
            for S, S0 in zip(self._S, self._S0, strict=True):
                S[idx] = S0[idx]
        else:
            for r, r0 in zip(self._r, self._r0, strict=True):
                r[idx] = r0[idx]
        self._Phi[idx] = 0.0
        self._Y[idx] = 0.0
        self._E[idx] = 0.0
        self._phi[idx] = 0.0
        self._xs[idx] = 0.0
        self._x[idx] = self._x_init[idx]
        self._y[idx] = 0.0
        self._t[idx] = 0
        self._n_resets[idx] = 0
        self._n_state_resets[idx] = 0
        self._n_kf_resets[idx] = 0
        if self.cfg.kalman:
            self._P1[idx] = self._P1_init[idx]
            self._L1[idx] = 0.0
        if lanes is None:
            self._awaiting_predict = False

    def reinit(
        self,
        lanes: NDArray,
        theta0: NDArray,
        P0: NDArray | None = None,
        P1_init: NDArray | None = None,
    ) -> None:
        """Rebuild lanes as fresh estimators: what a single-run caller does with
        ``make_estimator(..., theta0=..., P0=..., P1_init=...)`` (``P0`` full ``(k, 2n, 2n)``;
        ``None`` keeps the configured value). ``Q`` returns to the configured value."""
        lanes = np.asarray(lanes)
        self._theta0[lanes] = theta0
        cfg = self.cfg
        if P0 is not None:
            for blk, S0 in zip(cfg.blocks, self._S0, strict=True):
                S0[lanes] = np.linalg.cholesky(np.ascontiguousarray(P0[:, blk, blk]))
        elif cfg.least_squares:
            for S0, P0_cfg in zip(self._S0, cfg.P0, strict=True):
                S0[lanes] = np.linalg.cholesky(P0_cfg)
        if cfg.kalman:
            self._P1_init[lanes] = cfg.P1_init if P1_init is None else P1_init
            self._Q[lanes] = cfg.Q
        self.reset(lanes)

    @property
    def Q(self) -> NDArray | None:
        """Kalman process-noise covariance per lane ``(B, n, n)`` (settable), else ``None``."""
        return self._Q.copy() if self.cfg.kalman else None

    @Q.setter
    def Q(self, value: ArrayLike) -> None:
        self._Q[...] = value

    # ------------------------------------------------------------------------ stepping
    def _innovation(self, theta: NDArray, Phi: NDArray, Y: NDArray) -> NDArray:
        return Y - _vm(theta, Phi)

    def _potter(self, S: NDArray, phi: NDArray, lam: float) -> tuple[NDArray, NDArray]:
        """``rules.potter_update`` on all lanes (in place); returns ``(S f, s)``."""
        f = _vm(phi, S)
        s = lam + _vv(f, f)
        Sf = _mv(S, f)
        beta = 1.0 / (s * (1.0 + np.sqrt(lam / s)))
        S -= np.multiply((Sf * beta[:, None])[:, :, None], f[:, None, :])
        if lam != 1.0:
            S *= 1.0 / math.sqrt(lam)
        return Sf, s

    @staticmethod
    def _sq_norm(S: NDArray) -> NDArray:
        """``vdot(S, S)`` per lane (only tested for finiteness)."""
        return np.einsum("bij,bij->b", S, S)

    def _ls_increment(self, k: int, Phi: NDArray, E: NDArray, fail: NDArray) -> NDArray:
        """``LeastSquaresCore.increment`` (square-root form) on all lanes."""
        cfg, S = self.cfg, self._S[k]
        if cfg.scalar_ls:  # RLS: Potter's update, L(t) = P(t-1) phi / s
            Sf, s = self._potter(S, Phi[:, :, 0], cfg.lam)
            fail |= ~((s > 0.0) & np.isfinite(s) & np.isfinite(self._sq_norm(S)))
            return Sf * (E[:, 0] / s)[:, None]
        # MILS: rules.block_update, S <- S G^{-T} with G G^T = lambda I + S^T Phi Phi^T S.
        F = Phi.transpose(0, 2, 1) @ S
        M = F.transpose(0, 2, 1) @ F
        diag = np.arange(M.shape[1])
        M[:, diag, diag] += cfg.lam
        G, ok = stacked_lanes(np.linalg.cholesky, M)
        fail |= ~ok
        if ok.all():
            S[...] = np.linalg.solve(G, S.transpose(0, 2, 1)).transpose(0, 2, 1)
        else:  # failed lanes are reset afterwards; solve the others only
            good = np.flatnonzero(ok)
            if good.size:
                Sg = S[good]
                S[good] = np.linalg.solve(G[good], Sg.transpose(0, 2, 1)).transpose(0, 2, 1)
        delta = _mv(S, _vm(_mv(Phi, E), S))
        fail |= ~np.isfinite(self._sq_norm(S))
        return delta

    def _gradient_increment(self, k: int, Phi: NDArray, E: NDArray, fail: NDArray) -> NDArray:
        """``GradientCore.increment`` on all lanes."""
        cfg = self.cfg
        B = Phi.shape[0]
        if cfg.stacked:
            flat = Phi.reshape(B, -1)
            inc = np.array([np.vdot(flat[i], flat[i]) for i in range(B)])
        else:
            phi = Phi[:, :, 0]
            inc = _vv(phi, phi)
        r = cfg.lam * self._r[k] + inc
        bad = ~((r > 0.0) & np.isfinite(r))
        fail |= bad
        self._r[k] = np.where(bad, self._r[k], r)
        return _mv(Phi, E * (1.0 / r)[:, None])

    def _check_full(self) -> NDArray:
        """``ParameterRule.check_full`` per lane: True where the check fails."""
        fail = np.zeros(self.num_envs, dtype=bool)
        if self.cfg.least_squares:
            for S in self._S:
                C, ok = stacked_lanes(np.linalg.cholesky, self._P_of(S))
                tr = np.trace(C, axis1=1, axis2=2)
                fail |= ~(ok & np.isfinite(tr))
        else:
            for r in self._r:
                fail |= ~((r > 0.0) & np.isfinite(r))
        return fail

    @staticmethod
    def _P_of(S: NDArray) -> NDArray:
        """``LeastSquaresCore.P``: ``S S^T`` symmetrised as ``0.5 P + 0.5 P^T``."""
        P = S @ S.transpose(0, 2, 1)
        return 0.5 * P + 0.5 * P.transpose(0, 2, 1)

    def _reset_rules(self, lanes: NDArray) -> None:
        if self.cfg.least_squares:
            for S, S0 in zip(self._S, self._S0, strict=True):
                S[lanes] = S0[lanes]
        else:
            for r, r0 in zip(self._r, self._r0, strict=True):
                r[lanes] = r0[lanes]

    def update(self, y_t: ArrayLike) -> NDArray:
        """Measurement step for every lane (``y`` of shape ``(B,)``); returns ``theta (B, 2n)``."""
        y = self._begin_update(y_t)
        cfg = self.cfg
        Phi, Y = self._Phi, self._Y
        if cfg.p > 1:
            Phi[:, :, 1:] = Phi[:, :, :-1].copy()
            Y[:, 1:] = Y[:, :-1].copy()
        Phi[:, :, 0] = self._phi
        Y[:, 0] = y
        self._t += 1
        E = self._innovation(self._theta, Phi, Y)
        en = self._enabled
        if en.any():
            lanes = np.flatnonzero(en) if not en.all() else None
            saved = None
            if lanes is not None:  # frozen lanes must keep P / r untouched
                saved = (
                    [S.copy() for S in self._S]
                    if cfg.least_squares
                    else [r.copy() for r in self._r]
                )
            fail = np.zeros(self.num_envs, dtype=bool)
            delta = np.zeros_like(self._theta)
            for k, blk in enumerate(cfg.blocks):
                before = fail.copy()
                if cfg.least_squares:
                    inc = self._ls_increment(k, Phi[:, blk], E, fail)
                else:
                    inc = self._gradient_increment(k, Phi[:, blk], E, fail)
                # A core that fails stops the rule: later cores of that lane are not run (their
                # state is reset below anyway).
                delta[:, blk] = np.where(before[:, None], 0.0, inc)
            fail |= ~np.isfinite(delta.sum(axis=1))
            if saved is not None:
                frozen = ~en
                for cur, old in zip(self._S if cfg.least_squares else self._r, saved, strict=True):
                    cur[frozen] = old[frozen]
                fail &= en
            step_ok = en & ~fail
            self._theta[step_ok] += delta[step_ok]
            check = step_ok.copy()
            if cfg.check_every:
                due = (self._t % cfg.check_every) == 0
                check &= due
                late = np.zeros(self.num_envs, dtype=bool)
                if check.any():
                    late = self._check_full() & check
                fail |= late
            failed = np.flatnonzero(fail)
            if failed.size:
                self._report(
                    failed,
                    "P(t)/r(t) lost positive definiteness or overflowed",
                    "P reset to P(0) (r to r(0)), theta_hat kept at its last finite value",
                )
                self._reset_rules(failed)
                self._n_resets[failed] += 1
                E[failed] = self._innovation(self._theta[failed], Phi[failed], Y[failed])
        self._E = E
        self._y = y
        self._awaiting_predict = True
        return self._theta.copy()

    def _set_model(self) -> None:
        n = self.n
        self._a[:] = self._theta[:, :n]
        if self.form == "observer":
            np.negative(self._a, out=self._A[:, :, 0])
        else:
            np.negative(self._a[:, ::-1], out=self._A[:, -1, :])
        self._b[:] = self._theta[:, n:]

    def predict(self, u_t: ArrayLike) -> NDArray:
        """State step for every lane (``u`` of shape ``(B,)``); returns ``x_hat(t+1)``."""
        u = self._begin_predict(u_t)
        cfg = self.cfg
        self._set_model()
        A, b, x = self._A, self._b, self._x
        open_loop = _mv(A, x) + b * u[:, None]
        if cfg.kalman:
            P1 = self._P1
            AP = A @ P1
            g = AP[:, :, 0]
            s = cfg.R + P1[:, 0, 0]
            L1 = g / s[:, None]
            xn = open_loop + L1 * (self._y - x[:, 0])[:, None]
            P1n = AP @ A.transpose(0, 2, 1)
            P1n -= np.multiply(g[:, :, None], L1[:, None, :])
            if cfg.has_Q:
                P1n += self._Q
            P1n += P1n.transpose(0, 2, 1)
            P1n *= 0.5
            bad = ~((s > 0.0) & np.isfinite(P1n.sum(axis=(1, 2))))
            if bad.any():
                self._n_kf_resets[bad] += 1
                P1n[bad] = self._P1_init[bad]
                L1[bad] = 0.0
                xn[bad] = open_loop[bad]
            self._P1, self._L1 = P1n, L1
        else:
            xn = open_loop
        self._advance_regressor(x, u)
        nonfinite = ~np.isfinite(xn.sum(axis=1))
        if nonfinite.any():
            lanes = np.flatnonzero(nonfinite)
            self._report(lanes, "state estimate x_hat(t+1) is not finite", "reset to x_hat(1)")
            self._n_state_resets[lanes] += 1
            xn[lanes] = self._x_init[lanes]
        self._x = xn
        self._awaiting_predict = False
        return xn.copy()

    def _advance_regressor(self, x: NDArray, u: NDArray) -> None:
        n, phi = self.n, self._phi
        if self.form == "observer":
            phi[:, 1:n] = phi[:, : n - 1].copy()
            phi[:, 0] = -x[:, 0]
        else:
            xs = self._xs
            xs[:, 1:] = xs[:, :-1].copy()
            xs[:, 0] = x
            np.negative(xs[:, n - 1, ::-1], out=phi[:, :n])
        phi[:, n + 1 :] = phi[:, n:-1].copy()
        phi[:, n] = u

    # ------------------------------------------------------------------------ lane transfer
    _STATE = (
        "_theta",
        "_theta0",
        "_x_init",
        "_Phi",
        "_Y",
        "_E",
        "_phi",
        "_xs",
        "_x",
        "_y",
        "_t",
        "_enabled",
        "_n_resets",
        "_n_state_resets",
        "_n_kf_resets",
    )

    def _state_arrays(self) -> dict[str, NDArray]:
        arrays = {k: getattr(self, k) for k in self._STATE}
        if self.cfg.least_squares:
            for i, (S, S0) in enumerate(zip(self._S, self._S0, strict=True)):
                arrays[f"S{i}"], arrays[f"S0{i}"] = S, S0
        else:
            for i, (r, r0) in enumerate(zip(self._r, self._r0, strict=True)):
                arrays[f"r{i}"], arrays[f"r0{i}"] = r, r0
        if self.cfg.kalman:
            arrays["_P1"], arrays["_L1"] = self._P1, self._L1
            arrays["_P1_init"], arrays["_Q"] = self._P1_init, self._Q
        return arrays

    def copy_lanes_from(self, other: BatchedRecursiveEstimator, lanes: NDArray) -> None:
        """Overwrite lanes ``lanes`` with the state of ``other`` (one lane of it per entry)."""
        mine, theirs = self._state_arrays(), other._state_arrays()
        for key, arr in mine.items():
            arr[lanes] = theirs[key]

    def subset(self, lanes: NDArray) -> BatchedRecursiveEstimator:
        """A new batched estimator holding copies of lanes ``lanes``."""
        cfg = EstimatorConfig.__new__(EstimatorConfig)
        cfg.__dict__.update(self.cfg.__dict__)
        cfg.num_envs = len(lanes)
        cfg.lane_theta0 = self._theta0[lanes]
        cfg.lane_P0 = None
        sub = BatchedRecursiveEstimator(cfg)
        for key, arr in sub._state_arrays().items():
            arr[...] = self._state_arrays()[key][lanes]
        sub._awaiting_predict = self._awaiting_predict
        return sub

    # ------------------------------------------------------------------------ views
    @property
    def theta(self) -> NDArray:
        """``theta_hat(t)`` per lane, shape ``(B, 2n)`` (copy)."""
        return self._theta.copy()

    @property
    def x_hat(self) -> NDArray:
        """Latest state estimates, shape ``(B, n)`` (copy)."""
        return self._x.copy()

    @property
    def P(self) -> NDArray | None:
        """``P(t)`` per lane ``(B, 2n, 2n)`` (block-diagonal for D- rules), else ``None``."""
        if not self.cfg.least_squares:
            return None
        if not self.cfg.decomposed:
            return self._P_of(self._S[0])
        out = np.zeros((self.num_envs, self.cfg.d, self.cfg.d))
        for blk, S in zip(self.cfg.blocks, self._S, strict=True):
            out[:, blk, blk] = self._P_of(S)
        return out

    @property
    def r(self) -> NDArray | None:
        """``r(t)`` per lane ``(B, 1)`` or ``(B, 2)`` (SG/MISG), else ``None``."""
        if self.cfg.least_squares:
            return None
        return np.stack(self._r, axis=1)

    @property
    def P1(self) -> NDArray | None:
        return self._P1.copy() if self.cfg.kalman else None

    @property
    def L1(self) -> NDArray | None:
        return self._L1.copy() if self.cfg.kalman else None

    @property
    def innovation(self) -> NDArray:
        """``E(p, t)`` per lane, shape ``(B, p)``."""
        return self._E.copy()

    @property
    def phi(self) -> NDArray:
        return self._Phi[:, :, 0].copy()

    @property
    def Phi(self) -> NDArray:
        return self._Phi.copy()

    @property
    def t(self) -> NDArray:
        return self._t.copy()

    @property
    def enabled(self) -> NDArray:
        """Per-lane adaptation switch (settable with a bool or one bool per lane)."""
        return self._enabled.copy()

    @enabled.setter
    def enabled(self, value: ArrayLike) -> None:
        self._enabled[:] = np.broadcast_to(np.asarray(value, dtype=bool), (self.num_envs,))

    @property
    def n_resets(self) -> NDArray:
        return self._n_resets.copy()

    @property
    def health(self) -> dict[str, Any]:
        return {
            "n_resets": self._n_resets.copy(),
            "n_state_resets": self._n_state_resets.copy(),
            "n_kf_resets": self._n_kf_resets.copy(),
            "n_projections": np.zeros(self.num_envs, dtype=np.int64),
        }


# --------------------------------------------------------------------------------------------
# Factory
# --------------------------------------------------------------------------------------------
def make_batched_estimator(
    name: str, n: int, *, num_envs: int, mode: str = "exact", **kwargs: Any
) -> BatchedEstimatorBase:
    """``num_envs`` lanes of ``make_estimator(name, n, **kwargs)`` stepped together.

    Parameters
    ----------
    name, n, kwargs
        As :func:`~stcgym.adaptive.recursive.make_estimator` (``theta0`` / ``P0`` may also be
        given per lane with a leading axis of length ``num_envs``).
    num_envs
        Number of lanes ``B``.
    mode
        ``"exact"``: equal to ``B`` single estimators to rounding (stacked BLAS/LAPACK calls).
        ``"fast"``: generated structure-exploiting kernels, the same equations with different
        rounding (see :mod:`stcgym.adaptive.batched_kernels`).
    """
    if mode not in ("exact", "fast"):
        raise ValueError(f"mode must be 'exact' or 'fast', got {mode!r}")
    cfg = estimator_config(name, n, num_envs, **kwargs)
    if mode == "exact":
        return BatchedRecursiveEstimator(cfg)
    from stcgym.adaptive.batched_kernels import FastBatchedEstimator

    return FastBatchedEstimator(cfg)
