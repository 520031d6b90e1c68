"""Batched self-tuning regulator: ``B`` copies of
:class:`~stcgym.adaptive.controller.SelfTuningController` driven by a vector env.

``BatchedSelfTuningController(n, num_envs=B, **kwargs)`` takes the keyword arguments of the
single controller and behaves like ``B`` independent single controllers, lane ``i`` seeing row
``i`` of the vector env's observations: ``predict(obs)`` takes ``(B, 2)`` observations
``[y(t), r(t)]`` and returns ``(B, 1)`` actions (SB3's ``predict`` signature; ``episode_start``
resets lanes). ``seed`` may be one value or one per lane.

``mode="exact"`` (default) repeats every operation of the single controller on stacked arrays:
the same numpy/BLAS/LAPACK calls per stack element, so lane ``i`` equals the single
controller to rounding (OpenBLAS may pick other kernels for stacked calls, by CPU), with
:class:`~stcgym.adaptive.batched_estimators.BatchedRecursiveEstimator`
underneath. Branches of the single code (safe-set rejections, saturation, bootstrap hand-over,
covariance resets) become per-lane masks; the rare restarts replay the stored window on the
affected lanes only.

``mode="fast"`` runs one generated kernel per step (:mod:`stcgym.adaptive.batched_fast`): the
same equations with structure-exploiting arithmetic, bit-for-bit equal to the scalar single-plant
fast path :class:`~stcgym.adaptive.batched_fast.FastLoop`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.batched_estimators import (
    BatchedRecursiveEstimator,
    EstimatorConfig,
    _mv,
    _vm,
    _vv,
    stacked_lanes,
)
from stcgym.adaptive.policy import BatchedPolicy

__all__ = [
    "REJECTION_REASONS",
    "BatchedSelfTuningController",
    "ControllerConfig",
    "restart_covariance",
]

#: Safe-set rejection reasons, in the order of ``TrackingLaw.design`` (``rejections`` columns).
REJECTION_REASONS = (
    "bootstrap",
    "nonfinite",
    "b_small",
    "uncontrollable",
    "dc_singular",
    "gain_large",
)


class ControllerConfig:
    """Settings of a :class:`~stcgym.adaptive.controller.SelfTuningController`, read from a
    prototype built with the same arguments (so validation and defaults are the single one's)."""

    def __init__(self, proto: Any, num_envs: int) -> None:
        if not proto._factory:
            raise NotImplementedError("batched controllers need an estimator name, not an object")
        if proto.record:
            raise NotImplementedError("record=True is not batched; use a single controller")
        law = proto.law
        self.proto = proto
        self.num_envs = int(num_envs)
        self.n = n = proto.n
        self.form = proto.form
        self.integral, self.feedforward = law.integral, law.feedforward
        self.m = law.m
        self.alpha = np.array(law.alpha, dtype=float)
        self.action_bound = law.action_bound
        self.anti_windup = law.anti_windup
        self.b_min, self.rcond_min = law.b_min, law.rcond_min
        self.dc_rcond_min, self.gain_max = law.dc_rcond_min, law.gain_max
        self.excitation_steps = proto.excitation_steps
        self.excitation_amplitude = proto.excitation_amplitude
        self.excitation_limit = proto.excitation_limit
        self.dither = proto.dither
        self.covariance_reset = proto.covariance_reset
        self.reset_threshold = proto.reset_threshold
        self.reset_holdoff = proto.reset_holdoff
        self.reset_inflation = proto.reset_inflation
        self.filtered = proto.filtered
        self.bootstrap = proto.bootstrap
        self.bootstrap_window = proto.bootstrap_window
        self.handover_inflation = proto.handover_inflation
        self.boot_p0 = proto._boot.p0
        self.hist_len = proto._hist_len
        self.adaptive_q = proto._adaptive_q
        self.q_floor = np.array(proto._q_floor, dtype=float)
        self.process_noise_gain = float(getattr(proto, "process_noise_gain", 1.0))
        self.estimator_name = proto.estimator_name
        self.rule = self.estimator_name.split("-")[-1]
        self.decomposed = "-D-" in self.estimator_name
        self.est = EstimatorConfig(proto.estimator, num_envs)
        self.est.lane_theta0 = None
        self.est.lane_P0 = None
        self.kalman = self.est.kalman
        self.d = 2 * n


def _lfsr(state: NDArray) -> tuple[NDArray, NDArray]:
    """``_PRBS.__call__`` on all lanes: ``(value, new_state)``."""
    bit = ((state >> 8) ^ (state >> 4)) & 1
    return np.where(bit == 1, 1.0, -1.0), ((state << 1) | bit) & 0x1FF


class BatchedSelfTuningController(BatchedPolicy):
    """``num_envs`` lanes of :class:`~stcgym.adaptive.controller.SelfTuningController`.

    Parameters
    ----------
    n, kwargs
        As the single controller (``estimator`` must be a name; ``record`` is not batched).
    num_envs
        Number of lanes ``B``.
    seed
        PRBS seed: one int for all lanes (like copies of one controller) or one per lane.
    mode
        ``"exact"`` (the single controller to rounding) or ``"fast"`` (generated kernels).
    """

    def __new__(cls, n: int, *, num_envs: int, mode: str = "exact", **kwargs: Any) -> Any:
        if mode == "fast":
            from stcgym.adaptive.batched_fast import FastBatchedSelfTuningController

            return FastBatchedSelfTuningController(n, num_envs=num_envs, **kwargs)
        if mode != "exact":
            raise ValueError(f"mode must be 'exact' or 'fast', got {mode!r}")
        return super().__new__(cls)

    def __init__(
        self,
        n: int,
        *,
        num_envs: int,
        mode: str = "exact",
        seed: int | ArrayLike = 0,
        **kwargs: Any,
    ) -> None:
        from stcgym.adaptive.controller import SelfTuningController

        if isinstance(num_envs, bool) or int(num_envs) != num_envs or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        B = self.num_envs = int(num_envs)
        seeds = np.broadcast_to(np.asarray(seed), (B,)).astype(np.int64)
        proto = SelfTuningController(n, seed=int(seeds[0]), **kwargs)
        self.cfg = cfg = ControllerConfig(proto, B)
        self.n = cfg.n
        self.mode = "exact"
        self._prbs0 = (seeds % 511) + 1
        d, m, L = cfg.d, cfg.m, cfg.hist_len
        self.est = BatchedRecursiveEstimator(cfg.est)
        self._boot_theta = np.zeros((B, d))
        self._boot_P = np.tile(cfg.boot_p0 * np.eye(d), (B, 1, 1))
        self._boot_phi = np.zeros((B, d))
        self.K = np.zeros((B, m))
        self.N = np.zeros(B)
        self.has_gain = np.zeros(B, dtype=bool)
        self.rcond = np.zeros(B)
        self.xi = np.zeros(B)
        self.saturated = np.zeros(B, dtype=bool)
        self.u_unsat = np.zeros(B)
        self._prbs = self._prbs0.copy()
        self.t = np.zeros(B, dtype=np.int64)
        self.open_loop = np.ones(B, dtype=bool)
        self.design_ok = np.zeros(B, dtype=bool)
        self.n_rejected = np.zeros(B, dtype=np.int64)
        self.rejections = np.zeros((B, len(REJECTION_REASONS)), dtype=np.int64)
        self.n_covariance_resets = np.zeros(B, dtype=np.int64)
        self.n_handovers = np.zeros(B, dtype=np.int64)
        self.n_saturated = np.zeros(B, dtype=np.int64)
        self.n_excitation_aborts = np.zeros(B, dtype=np.int64)
        self._excitation_end = np.full(B, cfg.excitation_steps, dtype=np.int64)
        self._ewma_short = np.zeros(B)
        self._ewma_long = np.zeros(B)
        self._last_reset_t = np.zeros(B, dtype=np.int64)
        self._closed_t = np.full(B, -1, dtype=np.int64)
        self._u_hist = np.zeros((B, L))
        self._y_hist = np.zeros((B, L))
        self.reset()

    # ------------------------------------------------------------------------ lanes
    def reset(self, lanes: ArrayLike | None = None) -> None:
        """Forget the episode in all lanes (or a boolean mask / index array)."""
        B, cfg = self.num_envs, self.cfg
        idx = np.arange(B) if lanes is None else np.asarray(lanes)
        if idx.dtype == bool:
            idx = np.flatnonzero(idx)
        if idx.size == 0:
            return
        k = idx.size
        self.est.reinit(idx, np.broadcast_to(cfg.est.theta0, (k, cfg.d)))
        self.est._enabled[idx] = cfg.est.enabled
        if lanes is None:
            self.est._awaiting_predict = False
        self._boot_theta[idx] = 0.0
        self._boot_P[idx] = cfg.boot_p0 * np.eye(cfg.d)
        self._boot_phi[idx] = 0.0
        self.K[idx] = 0.0
        self.N[idx] = 0.0
        self.has_gain[idx] = False
        self.rcond[idx] = 0.0
        self.xi[idx] = 0.0
        self.saturated[idx] = False
        self.u_unsat[idx] = 0.0
        self._prbs[idx] = self._prbs0[idx]
        self.t[idx] = 0
        self.open_loop[idx] = True
        self.design_ok[idx] = False
        for arr in (
            self.n_rejected,
            self.rejections,
            self.n_covariance_resets,
            self.n_handovers,
            self.n_saturated,
            self.n_excitation_aborts,
            self._last_reset_t,
        ):
            arr[idx] = 0
        self._excitation_end[idx] = cfg.excitation_steps
        self._ewma_short[idx] = 0.0
        self._ewma_long[idx] = 0.0
        self._closed_t[idx] = -1
        self._u_hist[idx] = 0.0
        self._y_hist[idx] = 0.0

    # ------------------------------------------------------------------------ the step
    def act(self, y: NDArray, r: NDArray) -> NDArray:
        """One step of every lane from ``y(t)``, ``r(t)`` (shape ``(B,)``); returns ``u(t)``."""
        cfg, est, n = self.cfg, self.est, self.n
        t = self.t.copy()
        # -- 0. excitation phase and bootstrap
        if cfg.excitation_limit is not None:
            abort = (t < self._excitation_end) & (np.abs(y) > cfg.excitation_limit)
            self._excitation_end[abort] = t[abort]
            self.n_excitation_aborts += abort
        booting = np.zeros(self.num_envs, dtype=bool)
        if cfg.bootstrap:
            booting = self.n_handovers == 0
            if booting.any():
                self._boot_update(booting, y)
                due = booting & (t >= np.maximum(self._excitation_end, cfg.bootstrap_window))
                if due.any():
                    self._handover(np.flatnonzero(due))
        theta = est.update(y)
        reset_now = self._detect_change(t, y)
        if reset_now.any():
            theta = est.theta
        # -- 1. model and design
        A = np.tile(np.eye(n, k=1), (self.num_envs, 1, 1))
        if cfg.form == "observer":
            A[:, :, 0] = -theta[:, :n]
        else:
            A[:, -1, :] = -theta[:, n - 1 :: -1]
        if cfg.bootstrap:
            still = self.n_handovers == 0
            self.design_ok = np.zeros(self.num_envs, dtype=bool)
            reason = np.where(still, 0, -1)
            todo = ~still
        else:
            reason = np.full(self.num_envs, -1)
            todo = np.ones(self.num_envs, dtype=bool)
        if todo.any():
            lanes = np.flatnonzero(todo)
            ok, why = self._design(A[lanes], theta[lanes, n:], lanes)
            reason[lanes] = why
        self.design_ok = reason < 0
        rejected = ~self.design_ok
        self.n_rejected += rejected
        lanes = np.flatnonzero(rejected)
        np.add.at(self.rejections, (lanes, reason[lanes]), 1)
        # -- 2. control
        self.open_loop = (t < self._excitation_end) | ~self.has_gain
        u = np.zeros(self.num_envs)
        ol = self.open_loop
        bound = cfg.action_bound
        if ol.any():
            val, new = _lfsr(self._prbs)
            self._prbs = np.where(ol, new, self._prbs)
            uo = cfg.excitation_amplitude * val
            if bound is not None:
                uo = np.where(np.abs(uo) > bound, np.copysign(bound, uo), uo)
            u = np.where(ol, uo, u)
            self.saturated = np.where(ol, False, self.saturated)
        cl = ~ol
        if cl.any():
            self._closed_t = np.where(cl & (self._closed_t < 0), t, self._closed_t)
            x = est.x_hat
            if cfg.filtered and cfg.kalman:
                P1c = est._P1[:, :, 0]
                x = x + P1c * ((y - x[:, 0]) / (cfg.est.R + P1c[:, 0]))[:, None]
            exc = np.zeros(self.num_envs)
            if cfg.dither > 0:
                val, new = _lfsr(self._prbs)
                self._prbs = np.where(cl, new, self._prbs)
                exc = cfg.dither * val
            uc = self._control(x, y, r, exc, cl)
            u = np.where(cl, uc, u)
            self.n_saturated += cl & self.saturated
        # -- 3. state step with the applied input
        if cfg.adaptive_q and cfg.kalman and cfg.est.least_squares:
            self._set_process_noise(y, u)
        est.predict(u)
        if booting.any():
            self._boot_push(booting, y, u)
        i = t % cfg.hist_len
        rows = np.arange(self.num_envs)
        self._u_hist[rows, i] = u
        self._y_hist[rows, i] = y
        self.t = t + 1
        return u

    # -- pieces --------------------------------------------------------------------------------
    def _boot_update(self, lanes: NDArray, y: NDArray) -> None:
        """``_EquationErrorRLS.update`` on the masked lanes."""
        idx = np.flatnonzero(lanes)
        P, phi, th = self._boot_P[idx], self._boot_phi[idx], self._boot_theta[idx]
        Pphi = _mv(P, phi)
        s = 1.0 + _vv(phi, Pphi)
        ok = (s > 0.0) & np.isfinite(s)
        th_new = th + Pphi * ((y[idx] - _vv(phi, th)) / s)[:, None]
        P_new = P - np.multiply(Pphi[:, :, None], Pphi[:, None, :]) * (1.0 / s)[:, None, None]
        self._boot_theta[idx] = np.where(ok[:, None], th_new, th)
        self._boot_P[idx] = np.where(ok[:, None, None], P_new, P)

    def _boot_push(self, lanes: NDArray, y: NDArray, u: NDArray) -> None:
        n, phi = self.n, self._boot_phi
        new = phi.copy()
        new[:, 1:n] = phi[:, : n - 1]
        new[:, 0] = -y
        new[:, n + 1 :] = phi[:, n:-1]
        new[:, n] = u
        self._boot_phi = np.where(lanes[:, None], new, phi)

    def _handover(self, lanes: NDArray) -> None:
        from stcgym.envs.canonical import observer_to_observability_b

        cfg, n = self.cfg, self.n
        th = self._boot_theta[lanes].copy()
        if cfg.form == "observability":
            for j in range(len(lanes)):
                th[j, n:] = observer_to_observability_b(th[j, :n], th[j, n:])
        self.n_handovers[lanes] += 1
        fine = np.isfinite(th).all(axis=1)
        lanes, th = lanes[fine], th[fine]
        if lanes.size == 0:
            return
        P0 = None
        if cfg.rule in ("RLS", "MILS"):
            Pb = self._boot_P[lanes]
            P0 = 0.5 * (Pb + Pb.transpose(0, 2, 1)) * cfg.handover_inflation
        self._restart(lanes, th, P0, None)

    def _restart(
        self, lanes: NDArray, theta0: NDArray, P0: NDArray | None, y: NDArray | None
    ) -> None:
        """``SelfTuningController._restart`` for ``lanes`` (rebuild, replay, optional update)."""
        cfg, n, est = self.cfg, self.n, self.est
        if P0 is not None:
            P0 = restart_covariance(P0, n, cfg.decomposed)
        t = self.t[lanes]
        for tv in np.unique(t):
            grp = np.flatnonzero(t == tv)
            sub_lanes = lanes[grp]
            k = int(min(tv, cfg.hist_len))
            P1_init = None
            if k < tv and cfg.kalman:
                P1_init = np.broadcast_to(1e4 * np.eye(n), (grp.size, n, n))
            est.reinit(sub_lanes, theta0[grp], None if P0 is None else P0[grp], P1_init)
            sub = est.subset(sub_lanes)
            sub._awaiting_predict = False
            if k:
                idx = np.arange(tv - k, tv) % cfg.hist_len
                enabled = sub._enabled.copy()
                sub._enabled[:] = False
                sub.run(self._u_hist[sub_lanes][:, idx], self._y_hist[sub_lanes][:, idx])
                sub._enabled[:] = enabled
            if y is not None:
                sub.update(y[sub_lanes])
            est.copy_lanes_from(sub, sub_lanes)

    def _detect_change(self, t: NDArray, y: NDArray) -> NDArray:
        cfg, est = self.cfg, self.est
        e = est._E[:, 0]
        e2 = e * e
        long_prev = self._ewma_long.copy()
        self._ewma_short = self._ewma_short + 0.1 * (e2 - self._ewma_short)
        self._ewma_long = self._ewma_long + 0.01 * (e2 - self._ewma_long)
        if not cfg.covariance_reset:
            return np.zeros(self.num_envs, dtype=bool)
        alarm = (
            (self._closed_t >= 0)
            & (t - self._closed_t > cfg.reset_holdoff)
            & (t - self._last_reset_t > cfg.reset_holdoff)
            & (self._ewma_short > cfg.reset_threshold * long_prev)
        )
        lanes = np.flatnonzero(alarm)
        if lanes.size:
            self._last_reset_t[lanes] = t[lanes]
            self.n_covariance_resets[lanes] += 1
            if cfg.est.least_squares:
                P = est.P[lanes]
                self._restart(lanes, est._theta[lanes].copy(), cfg.reset_inflation * P, y)
            else:
                est._reset_rules(lanes)
        return alarm

    def _set_process_noise(self, y: NDArray, u: NDArray) -> None:
        cfg, n, est = self.cfg, self.n, self.est
        P = est.P
        Pab = P[:, :n, n:]
        Q = (
            (y * y)[:, None, None] * P[:, :n, :n]
            + (u * u)[:, None, None] * P[:, n:, n:]
            - (y * u)[:, None, None] * (Pab + Pab.transpose(0, 2, 1))
        )
        Q *= cfg.est.R * cfg.process_noise_gain
        Q += cfg.q_floor
        est._Q[...] = Q

    def _control(self, x: NDArray, y: NDArray, r: NDArray, exc: NDArray, lanes: NDArray) -> NDArray:
        """``TrackingLaw.control`` on all lanes; state changes only where ``lanes``."""
        cfg, n = self.cfg, self.n
        hg = self.has_gain
        Kx = self.K[:, :n]
        ki = self.K[:, n] if cfg.integral else np.zeros(self.num_envs)
        u = np.where(hg, self.N * r - _vv(np.ascontiguousarray(Kx), x) - ki * self.xi + exc, exc)
        self.u_unsat = np.where(lanes, u, self.u_unsat)
        bound = cfg.action_bound
        if bound is not None:
            sat = np.abs(u) > bound
            u_sat = np.where(sat, np.copysign(bound, u), u)
        else:
            sat = np.zeros(self.num_envs, dtype=bool)
            u_sat = u
        self.saturated = np.where(lanes, sat, self.saturated)
        if cfg.integral:
            err = r - y
            frozen = cfg.anti_windup & sat & ((-ki * err) * u > 0.0)
            step = lanes & hg & ~frozen
            self.xi = np.where(step, self.xi + err, self.xi)
        return u_sat

    def _design(self, A: NDArray, b: NDArray, lanes: NDArray) -> tuple[NDArray, NDArray]:
        """``TrackingLaw.design`` for the given lanes; returns ``(ok, reason index or -1)``."""
        cfg, n, m = self.cfg, self.n, self.cfg.m
        k = A.shape[0]
        reason = np.full(k, -1)

        def reject(mask: NDArray, code: int) -> None:
            reason[mask & (reason < 0)] = code

        finite = np.isfinite(A).all(axis=(1, 2)) & np.isfinite(b).all(axis=1)
        reject(~finite, 1)
        reject(np.abs(b).max(axis=1) < cfg.b_min, 2)
        if cfg.integral:
            Ad = np.zeros((k, n + 1, n + 1))
            Ad[:, :n, :n] = A
            Ad[:, n, 0] = -1.0
            Ad[:, n, n] = 1.0
            bd = np.zeros((k, n + 1))
            bd[:, :n] = b
        else:
            Ad, bd = A, b
        live = reason < 0
        K = np.zeros((k, m))
        rcond = np.zeros(k)
        if live.any():
            idx = np.flatnonzero(live)
            Kl, rc, fail = self._ackermann(Ad[idx], bd[idx])
            K[idx], rcond[idx] = Kl, rc
            reject(np.isin(np.arange(k), idx[fail]), 3)
        N = np.zeros(k)
        if cfg.feedforward:
            live = reason < 0
            if live.any():
                idx = np.flatnonzero(live)
                x_ss, u_ss, dc = self._steady_state(A[idx], b[idx])
                bad = dc < max(cfg.dc_rcond_min, 1e-13)
                N[idx] = u_ss + _vv(np.ascontiguousarray(K[idx, :n]), x_ss)
                reject(np.isin(np.arange(k), idx[bad]), 4)
        live = reason < 0
        big = ~((np.abs(K).max(axis=1) <= cfg.gain_max) & (np.abs(N) <= cfg.gain_max))
        reject(live & big, 5)
        ok = reason < 0
        g = lanes[ok]
        self.K[g] = K[ok]
        self.N[g] = N[ok]
        self.rcond[g] = rcond[ok]
        self.has_gain[g] = True
        return ok, reason

    def _ackermann(self, A: NDArray, b: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        """``placement.ackermann`` on stacked models: ``(K, rcond, failed)``."""
        cfg, m = self.cfg, self.cfg.m
        k = A.shape[0]
        C = np.empty((k, m, m))
        v = b.copy()
        for j in range(m):
            C[:, :, j] = v
            v = _mv(A, v)
        norms = np.sqrt(np.einsum("bij,bij->bj", C, C))
        fail = ~np.isfinite(norms).all(axis=1) | (norms == 0.0).any(axis=1)
        K = np.zeros((k, m))
        rcond = np.zeros(k)
        idx = np.flatnonzero(~fail)
        if idx.size == 0:
            return K, rcond, fail
        Cn = C[idx] / norms[idx][:, None, :]
        Cinv, ok = stacked_lanes(np.linalg.inv, Cn)
        rc = np.zeros(idx.size)
        with np.errstate(all="ignore"):
            rc[ok] = 1.0 / (
                np.abs(Cn[ok]).sum(axis=1).max(axis=1) * np.abs(Cinv[ok]).sum(axis=1).max(axis=1)
            )
        good = ok & (rc > max(cfg.rcond_min, 1e-14))
        fail[idx[~good]] = True
        alpha = cfg.alpha
        w = Cinv[:, m - 1] / norms[idx, m - 1][:, None]
        Kg = alpha[m - 1] * w
        vv = w
        Ag = A[idx]
        for j in range(1, m + 1):
            vv = _vm(vv, Ag)
            Kg = Kg + (alpha[m - 1 - j] if j < m else 1.0) * vv
        K[idx[good]] = Kg[good]
        rcond[idx] = rc
        return K, rcond, fail

    def _steady_state(self, A: NDArray, b: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        """``placement.steady_state_gains`` on stacked models."""
        n = self.n
        k = A.shape[0]
        M = np.zeros((k, n + 1, n + 1))
        M[:, :n, :n] = A - np.eye(n)
        M[:, :n, n] = b
        M[:, n, 0] = 1.0
        Minv, ok = stacked_lanes(np.linalg.inv, M)
        ok &= np.isfinite(Minv).all(axis=(1, 2))
        x_ss = np.zeros((k, n))
        u_ss = np.zeros(k)
        rc = np.zeros(k)
        if ok.any():
            sol = Minv[ok][:, :, n]
            x_ss[ok] = sol[:, :n]
            u_ss[ok] = sol[:, n]
            rc[ok] = 1.0 / (
                np.abs(M[ok]).sum(axis=1).max(axis=1) * np.abs(Minv[ok]).sum(axis=1).max(axis=1)
            )
        return x_ss, u_ss, rc

    # ------------------------------------------------------------------------ views
    @property
    def theta(self) -> NDArray:
        return self.est.theta

    @property
    def x_hat(self) -> NDArray:
        return self.est.x_hat

    @property
    def rejection_counts(self) -> dict[str, NDArray]:
        return {r: self.rejections[:, j].copy() for j, r in enumerate(REJECTION_REASONS)}


def restart_covariance(P0: NDArray, n: int, decomposed: bool) -> NDArray:
    """``P(0)`` of a restart, per lane, as ``SelfTuningController._restart`` builds it.

    Symmetrised, the a/b cross blocks zeroed for D- rules, ``1e-2 I`` for lanes that are not
    finite and positive definite; then symmetrised once more, as ``make_estimator``'s
    validation does in the single controller (a no-op in exact arithmetic, not in rounding).
    """
    P0 = 0.5 * (P0 + P0.transpose(0, 2, 1))
    if decomposed:
        P0[:, :n, n:] = 0.0
        P0[:, n:, :n] = 0.0
    bad = ~np.isfinite(P0).all(axis=(1, 2))
    good = np.flatnonzero(~bad)
    if good.size:
        bad[good[np.linalg.eigvalsh(P0[good]).min(axis=1) <= 0.0]] = True
    P0[bad] = 1e-2 * np.eye(2 * n)
    return 0.5 * (P0 + P0.transpose(0, 2, 1))
