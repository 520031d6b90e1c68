"""Fast self-tuning regulator: one generated kernel per closed-loop step.

:class:`FastBatchedSelfTuningController` (``BatchedSelfTuningController(..., mode="fast")``) and
the single-plant :class:`FastLoop` run the step of
:class:`~stcgym.adaptive.controller.SelfTuningController` as straight-line code produced by
:mod:`stcgym.adaptive.batched_codegen`: the estimator of :mod:`stcgym.adaptive.batched_kernels`,
the bootstrap least squares, the Ackermann design with its safe set (controllability matrix,
Gauss-Jordan inverses with partial pivoting for the 1-norm condition numbers), the tracking law,
the PRBS (a 9-bit LFSR in exact float arithmetic) and the adaptive Kalman process noise.

The common step is one *nominal* kernel call per chunk of lanes (one scalar call for
:class:`FastLoop`). Rare events are guards: the bootstrap hand-over, a covariance reset (both
rebuild the estimator and replay the stored window), and estimator health failures. A chunk in
which a guard fires is recomputed phase by phase (measurement/bootstrap, estimator update and
change detection, design/control/state step) with the general kernels, the rebuilds done by the
driver in between, exactly where the single controller does them.

The equations are the single controller's; only the evaluation order differs (structure of the
canonical matrices exploited, no BLAS/LAPACK), so lanes agree with the single controller to
rounding amplified by the conditioning of the loop (about 1e-12 on the catalogue plants; see the
tests), and :class:`FastLoop` is bit-for-bit equal to a lane of the batched fast controller.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.batched_codegen import (
    Kernel,
    Tracer,
    Value,
    absolute,
    all_of,
    compile_kernel,
    dot,
    floor,
    guard,
    isfinite,
    logical_and,
    logical_not,
    logical_or,
    maximum,
    sqrt,
    to_float,
    where,
)
from stcgym.adaptive.batched_controller import (
    REJECTION_REASONS,
    ControllerConfig,
    restart_covariance,
)
from stcgym.adaptive.batched_kernels import (
    EstimatorTrace,
    LaneState,
    Layout,
    Program,
    estimator_layout,
    estimator_programs,
)
from stcgym.adaptive.policy import BatchedPolicy

__all__ = ["FastBatchedSelfTuningController", "FastLoop", "controller_layout"]

_NREJ = len(REJECTION_REASONS)


# --------------------------------------------------------------------------------------------
# Layout
# --------------------------------------------------------------------------------------------
def controller_layout(cfg: ControllerConfig) -> Layout:
    """Estimator rows first (so that they are an estimator layout of their own), then the
    controller's."""
    lay = estimator_layout(cfg.est)
    d, m = cfg.d, cfg.m
    lay.add("boot_theta", (d,))
    lay.add("boot_P", (d, d), "sym")
    lay.add("boot_phi", (d,))
    lay.add("booting", ())  # set by phase A, read by phase C (general path)
    lay.add("K", (m,))
    for name in ("N", "has_gain", "rcond", "xi", "saturated", "u_unsat", "prbs", "ct"):
        lay.add(name)
    for name in ("exc_end", "n_aborts", "n_handovers", "open_loop", "design_ok", "n_rejected"):
        lay.add(name)
    lay.add("rej", (_NREJ,))
    for name in ("n_cov_resets", "n_saturated", "ewma_s", "ewma_l", "last_reset_t", "closed_t"):
        lay.add(name)
    return lay


# --------------------------------------------------------------------------------------------
# Traced pieces
# --------------------------------------------------------------------------------------------
def _inverse(M: list[list[Value]]) -> tuple[list[list[Value]], Value]:
    """Inverse and an "exactly singular" flag.

    Up to 3 x 3 by the adjugate (singular: determinant exactly zero); larger by Gauss-Jordan
    with partial pivoting (first largest pivot, as LAPACK's ``getrf``; singular: a pivot exactly
    zero). Both are the inverse ``numpy.linalg.inv`` computes, in another evaluation order.
    """
    m = len(M)
    if m <= 3:
        return _adjugate_inverse(M)
    return _gauss_jordan(M)


def _adjugate_inverse(M: list[list[Value]]) -> tuple[list[list[Value]], Value]:
    m = len(M)
    if m == 1:
        det = M[0][0]
        adj: list[list[Value]] = [[1.0]]
    elif m == 2:
        (a, b), (c, d) = M
        det = a * d - b * c
        adj = [[d, -b], [-c, a]]  # type: ignore[list-item, operator]
    else:
        cof = [[0.0] * 3 for _ in range(3)]
        for i in range(3):
            for j in range(3):
                r0, r1 = [k for k in range(3) if k != i]
                c0, c1 = [k for k in range(3) if k != j]
                minor = M[r0][c0] * M[r1][c1] - M[r0][c1] * M[r1][c0]
                cof[i][j] = minor if (i + j) % 2 == 0 else -minor  # type: ignore[operator]
        det = M[0][0] * cof[0][0] + M[0][1] * cof[0][1] + M[0][2] * cof[0][2]
        adj = [[cof[j][i] for j in range(3)] for i in range(3)]
    singular = det.eq(0.0) if not isinstance(det, float) else det == 0.0
    rdet = 1.0 / det
    return [[v * rdet for v in row] for row in adj], singular


def _gauss_jordan(M: list[list[Value]]) -> tuple[list[list[Value]], Value]:
    m = len(M)
    A = [list(row) for row in M]
    X: list[list[Value]] = [[1.0 if i == j else 0.0 for j in range(m)] for i in range(m)]
    singular: Value = False
    for k in range(m):
        for i in range(k + 1, m):
            swap = absolute(A[i][k]) > absolute(A[k][k])
            for j in range(k, m):
                A[k][j], A[i][j] = where(swap, A[i][j], A[k][j]), where(swap, A[k][j], A[i][j])
            for j in range(m):
                X[k][j], X[i][j] = where(swap, X[i][j], X[k][j]), where(swap, X[k][j], X[i][j])
        piv = A[k][k]
        singular = logical_or(singular, piv.eq(0.0) if not isinstance(piv, float) else piv == 0.0)
        rp = 1.0 / piv
        for j in range(k + 1, m):
            A[k][j] = A[k][j] * rp
        X[k] = [v * rp for v in X[k]]
        for i in range(m):
            if i == k:
                continue
            f = A[i][k]
            for j in range(k + 1, m):
                A[i][j] = A[i][j] - f * A[k][j]
            X[i] = [X[i][j] - f * X[k][j] for j in range(m)]
    return X, singular


def _norm1_rcond(M: list[list[Value]], Minv: list[list[Value]]) -> Value:
    """``1 / (max column sum |M| * max column sum |Minv|)`` (NaN-propagating maxima)."""
    m = len(M)

    def colmax(X: list[list[Value]]) -> Value:
        best: Value = None  # type: ignore[assignment]
        for j in range(m):
            s: Value = 0.0
            for i in range(m):
                s = s + absolute(X[i][j])
            best = s if best is None else maximum(best, s)
        return best

    return 1.0 / (colmax(M) * colmax(Minv))


class ControllerTrace:
    """The traced step of the self-tuning regulator, split in phases A, B, C."""

    def __init__(self, cfg: ControllerConfig, booted: bool = False) -> None:
        self.cfg = cfg
        self.et = EstimatorTrace(cfg.est)
        # booted: specialise for lanes past the bootstrap (its least squares folded away);
        # a lane still booting fires a guard.
        self.booted = booted

    # -- phase A: excitation abort and bootstrap ---------------------------------------------
    def phase_a(self, st: dict[str, Any], y: Value) -> Value:
        cfg = self.cfg
        t = st["ct"]
        if cfg.excitation_limit is not None:
            abort = logical_and(t < st["exc_end"], absolute(y) > cfg.excitation_limit)
            st["exc_end"] = where(abort, t, st["exc_end"])
            st["n_aborts"] = st["n_aborts"] + to_float(abort)
        due: Value = False
        booting: Value = False
        if cfg.bootstrap and self.booted:
            guard(st["n_handovers"].eq(0.0))
        elif cfg.bootstrap:
            booting = st["n_handovers"].eq(0.0)
            self._boot_update(st, y, booting)
            end = st["exc_end"]
            w = float(cfg.bootstrap_window)
            due = logical_and(booting, t >= where(end > w, end, w))
            st["n_handovers"] = st["n_handovers"] + to_float(due)
        st["booting"] = to_float(booting)
        return guard(due)

    def _boot_update(self, st: dict[str, Any], y: Value, booting: Value) -> None:
        d = self.cfg.d
        P, phi, th = st["boot_P"], st["boot_phi"], st["boot_theta"]
        Pphi = [dot(P[i], phi) for i in range(d)]
        s = 1.0 + dot(phi, Pphi)
        ok = logical_and(booting, logical_and(s > 0.0, isfinite(s)))
        g = (y - dot(phi, th)) / s
        st["boot_theta"] = [where(ok, th[i] + Pphi[i] * g, th[i]) for i in range(d)]
        inv_s = 1.0 / s
        Pn: list[list[Value]] = [[0.0] * d for _ in range(d)]
        for i in range(d):
            for j in range(i, d):
                Pn[i][j] = Pn[j][i] = where(ok, P[i][j] - (Pphi[i] * Pphi[j]) * inv_s, P[i][j])
        st["boot_P"] = Pn

    # -- phase B: estimator measurement step and change detection -----------------------------
    def phase_b(self, st: dict[str, Any], y: Value) -> Value:
        cfg = self.cfg
        self.et.update(st, y)
        e = st["E"][0]
        e2 = e * e
        long_prev = st["ewma_l"]
        st["ewma_s"] = st["ewma_s"] + 0.1 * (e2 - st["ewma_s"])
        st["ewma_l"] = long_prev + 0.01 * (e2 - long_prev)
        if not cfg.covariance_reset:
            return False
        t = st["ct"]
        hold = float(cfg.reset_holdoff)
        alarm = all_of(
            [
                st["closed_t"] >= 0.0,
                (t - st["closed_t"]) > hold,
                (t - st["last_reset_t"]) > hold,
                st["ewma_s"] > cfg.reset_threshold * long_prev,
            ]
        )
        alarm = guard(alarm)
        st["last_reset_t"] = where(alarm, t, st["last_reset_t"])
        st["n_cov_resets"] = st["n_cov_resets"] + to_float(alarm)
        if not cfg.est.least_squares:  # gradient rules: back to r(0) in place
            for k in range(len(cfg.est.blocks)):
                st[f"rc{k}"] = where(alarm, st[f"rinit{k}"], st[f"rc{k}"])
        return alarm

    # -- phase C: design, control, state step -------------------------------------------------
    def phase_c(self, st: dict[str, Any], y: Value, r: Value) -> Value:
        cfg = self.cfg
        n = cfg.n
        t = st["ct"]
        theta = st["theta"]
        A, b = self.et.model(theta)
        if cfg.bootstrap and not self.booted:
            still = st["n_handovers"].eq(0.0)
        else:
            still = False
        ok, code, K_new, N_new, rc_new = self._design(A, b)
        ok = logical_and(logical_not(still), ok)
        code = where(still, 0.0, code)
        st["K"] = [where(ok, a_, b_) for a_, b_ in zip(K_new, st["K"], strict=True)]
        st["N"] = where(ok, N_new, st["N"])
        st["rcond"] = where(ok, rc_new, st["rcond"])
        st["has_gain"] = where(ok, 1.0, st["has_gain"])
        st["design_ok"] = to_float(ok)
        st["n_rejected"] = st["n_rejected"] + to_float(logical_not(ok))
        st["rej"] = [st["rej"][c] + to_float(code.eq(float(c))) for c in range(_NREJ)]
        hg = st["has_gain"].ne(0.0)
        # -- control
        ol = logical_or(t < st["exc_end"], logical_not(hg))
        cl = logical_not(ol)
        st["open_loop"] = to_float(ol)
        bound = cfg.action_bound
        consumed = ol if cfg.dither <= 0 else True
        val, new_state = self._lfsr(st["prbs"])
        st["prbs"] = where(consumed, new_state, st["prbs"])
        uo = cfg.excitation_amplitude * val
        if bound is not None:
            uo = where(absolute(uo) > bound, where(uo > 0.0, bound, -bound), uo)
        st["closed_t"] = where(logical_and(cl, st["closed_t"] < 0.0), t, st["closed_t"])
        x = st["x"]
        if cfg.filtered and cfg.kalman:
            P1 = st["P1"]
            gain = (y - x[0]) / (cfg.est.R + P1[0][0])
            x = [x[i] + P1[i][0] * gain for i in range(n)]
        exc: Value = cfg.dither * val if cfg.dither > 0 else 0.0
        uc, sat, xi_new, u_unsat = self._law(st, x, y, r, exc, hg)
        u = where(ol, uo, uc)
        st["saturated"] = where(ol, 0.0, to_float(sat))
        st["xi"] = where(cl, xi_new, st["xi"])
        st["u_unsat"] = where(cl, u_unsat, st["u_unsat"])
        st["n_saturated"] = st["n_saturated"] + to_float(logical_and(cl, sat))
        # -- state step with the applied input
        Q = None
        if cfg.adaptive_q and cfg.kalman and cfg.est.least_squares:
            Q = self._process_noise(st, y, u)
        self.et.predict(st, u, Q)
        if cfg.bootstrap and not self.booted:
            booting = st["booting"].ne(0.0)
            phi = st["boot_phi"]
            new_phi = [-y] + phi[: n - 1] + [u] + phi[n : 2 * n - 1]  # type: ignore[operator]
            st["boot_phi"] = [where(booting, a_, b_) for a_, b_ in zip(new_phi, phi, strict=True)]
        st["ct"] = t + 1.0
        return u

    @staticmethod
    def _lfsr(s: Value) -> tuple[Value, Value]:
        """``_PRBS.__call__`` in exact float arithmetic: ``(value, new state)``."""
        b8 = floor(s * (1.0 / 256.0))
        b4 = floor(s * (1.0 / 16.0)) - 2.0 * floor(s * (1.0 / 32.0))
        bit = b8 + b4 - 2.0 * (b8 * b4)
        s2 = 2.0 * s + bit
        return 2.0 * bit - 1.0, s2 - 512.0 * floor(s2 * (1.0 / 512.0))

    def _law(
        self, st: dict[str, Any], x: list[Value], y: Value, r: Value, exc: Value, hg: Value
    ) -> tuple[Value, Value, Value, Value]:
        """``TrackingLaw.control``: ``(u_sat, saturated, xi(t+1), u_unsat)``."""
        cfg, n = self.cfg, self.cfg.n
        K = st["K"]
        ki = K[n] if cfg.integral else 0.0
        xi = st["xi"]
        u = where(hg, st["N"] * r - dot(K[:n], x) - ki * xi + exc, exc)
        bound = cfg.action_bound
        if bound is not None:
            sat = absolute(u) > bound
            u_sat = where(sat, where(u > 0.0, bound, -bound), u)
        else:
            sat, u_sat = False, u
        xi_new = xi
        if cfg.integral:
            err = r - y
            frozen = logical_and(sat, ((-ki) * err) * u > 0.0) if cfg.anti_windup else False
            xi_new = where(logical_and(hg, logical_not(frozen)), xi + err, xi)
        return u_sat, sat, xi_new, u

    def _process_noise(self, st: dict[str, Any], y: Value, u: Value) -> list[list[Value]]:
        """Adaptive Kalman process noise from ``P = S S^T`` (``_set_process_noise``)."""
        cfg, n = self.cfg, self.cfg.n
        cores = [self.et.covariance(st[f"Sc{k}"]) for k in range(len(cfg.est.blocks))]

        def P(i: int, j: int) -> Value:
            if len(cores) == 1:
                return cores[0][i][j]
            if (i < n) != (j < n):
                return 0.0
            return cores[0][i][j] if i < n else cores[1][i - n][j - n]

        yy, uu, yu = y * y, u * u, y * u
        scale = cfg.est.R * cfg.process_noise_gain
        Q: list[list[Value]] = [[0.0] * n for _ in range(n)]
        for i in range(n):
            for j in range(i, n):
                v = yy * P(i, j) + uu * P(n + i, n + j) - yu * (P(i, n + j) + P(j, n + i))
                Q[i][j] = Q[j][i] = v * scale + float(cfg.q_floor[i, j])
        return Q

    def _design(
        self, A: list[list[Value]], b: list[Value]
    ) -> tuple[Value, Value, list[Value], Value, Value]:
        """``TrackingLaw.design``: ``(ok, reason code or -1, K, N, rcond)``."""
        cfg, n, m = self.cfg, self.cfg.n, self.cfg.m
        code: Value = -1.0

        def reject(cond: Value, c: int) -> None:
            nonlocal code
            code = where(
                logical_and(code.eq(-1.0) if not isinstance(code, float) else code == -1.0, cond),
                float(c),
                code,
            )

        finite = all_of(
            [isfinite(v) for row in A for v in row if not isinstance(v, float)]
            + [isfinite(v) for v in b]
        )
        reject(logical_not(finite), 1)
        reject(all_of([absolute(v) < cfg.b_min for v in b]), 2)
        if cfg.integral:
            Ad: list[list[Value]] = [list(row) + [0.0] for row in A]
            Ad.append([-1.0] + [0.0] * (n - 1) + [1.0])
            bd = list(b) + [0.0]
        else:
            Ad, bd = [list(row) for row in A], list(b)
        # Ackermann (placement.ackermann): controllability matrix, normalised columns.
        cols = [bd]
        for _ in range(m - 1):
            v = cols[-1]
            cols.append([dot(Ad[i], v) for i in range(m)])
        norms = [sqrt(dot(c, c)) for c in cols]
        bad_norm = logical_not(all_of([logical_and(isfinite(v), v.ne(0.0)) for v in norms]))  # type: ignore[union-attr]
        Cn = [[cols[j][i] / norms[j] for j in range(m)] for i in range(m)]
        Cinv, singular = _inverse(Cn)
        rc = _norm1_rcond(Cn, Cinv)
        thr = max(cfg.rcond_min, 1e-14)
        unc = logical_or(logical_or(bad_norm, singular), logical_not(rc > thr))
        reject(unc, 3)
        alpha = [float(a) for a in cfg.alpha]
        w = [Cinv[m - 1][j] / norms[m - 1] for j in range(m)]
        K = [alpha[m - 1] * v for v in w]
        vv = w
        for k in range(1, m + 1):
            vv = [dot(vv, [Ad[i][j] for i in range(m)]) for j in range(m)]
            c = alpha[m - 1 - k] if k < m else 1.0
            K = [K[j] + c * vv[j] for j in range(m)]
        N: Value = 0.0
        if cfg.feedforward:
            M: list[list[Value]] = [[0.0] * (n + 1) for _ in range(n + 1)]
            for i in range(n):
                for j in range(n):
                    M[i][j] = A[i][j] - (1.0 if i == j else 0.0)
                M[i][n] = b[i]
            M[n][0] = 1.0
            Minv, sing2 = _inverse(M)
            fin2 = all_of([isfinite(v) for row in Minv for v in row if not isinstance(v, float)])
            dc_ok = logical_and(logical_not(sing2), fin2)
            rc2 = where(dc_ok, _norm1_rcond(M, Minv), 0.0)
            x_ss = [where(dc_ok, Minv[i][n], 0.0) for i in range(n)]
            u_ss = where(dc_ok, Minv[n][n], 0.0)
            reject(rc2 < max(cfg.dc_rcond_min, 1e-13), 4)
            N = u_ss + dot(K[:n], x_ss)
        small = all_of([absolute(v) <= cfg.gain_max for v in K] + [absolute(N) <= cfg.gain_max])
        reject(logical_not(small), 5)
        ok = code.eq(-1.0) if not isinstance(code, float) else code == -1.0
        return ok, code, K, N, rc


# --------------------------------------------------------------------------------------------
# Compilation
# --------------------------------------------------------------------------------------------
_CACHE: dict[Any, Any] = {}


def _compile_phase(
    cfg: ControllerConfig, phases: str, nominal: bool, booted: bool = False
) -> Kernel:
    lay = controller_layout(cfg)
    tr = Tracer(nominal=nominal)
    st = lay.load(tr)
    ct = ControllerTrace(cfg, booted=booted)
    y, r = tr.input("I", 0), tr.input("I", 1)
    outs: list[Value] = []
    if "A" in phases:
        outs.append(to_float(ct.phase_a(st, y)))
    if "B" in phases:
        outs.append(to_float(ct.phase_b(st, y)))
    if "C" in phases:
        outs.append(ct.phase_c(st, y, r))
    if nominal:
        outs = outs[-1:]  # the fused kernel reports u; guards cover the rest
    name = f"stc_{phases}{'_booted' if booted else ''}"
    return compile_kernel(tr, lay._syms, lay.store(st), outs, lay._consts, name=name)


def _key(cfg: ControllerConfig) -> tuple:
    proto = cfg.proto
    items = sorted(
        (k, repr(v))
        for k, v in vars(proto).items()
        if isinstance(v, (int, float, str, bool, type(None))) and k not in ("seed", "t")
    )
    law = sorted((k, repr(v)) for k, v in vars(proto.law).items() if not k.startswith(("K", "x")))
    return (tuple(items), tuple(law), repr(cfg.alpha.tolist()), cfg.est.name, cfg.est.p)


class _Programs:
    """Layout, nominal fused kernel and the three general phase kernels of a configuration."""

    def __init__(self, cfg: ControllerConfig) -> None:
        key = _key(cfg)
        if key not in _CACHE:
            _CACHE[key] = (
                controller_layout(cfg),
                _compile_phase(cfg, "ABC", True),
                _compile_phase(cfg, "ABC", True, booted=True) if cfg.bootstrap else None,
                _compile_phase(cfg, "A", False),
                _compile_phase(cfg, "B", False),
                _compile_phase(cfg, "C", False),
            )
        self.layout, self.nominal, self.booted, self.A, self.B, self.C = _CACHE[key]
        if self.booted is None:
            self.booted = self.nominal


# --------------------------------------------------------------------------------------------
# The numpy driver
# --------------------------------------------------------------------------------------------
class FastBatchedSelfTuningController(BatchedPolicy):
    """``BatchedSelfTuningController(..., mode="fast")``: see the module docstring.

    ``chunk`` sets the lanes per kernel call (a few thousand keep the scratch in L2).
    """

    def __init__(
        self,
        n: int,
        *,
        num_envs: int,
        seed: int | ArrayLike = 0,
        chunk: int = 16384,
        **kwargs: Any,
    ) -> None:
        from stcgym.adaptive.controller import SelfTuningController

        if isinstance(num_envs, bool) or int(num_envs) != num_envs or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        B = self.num_envs = int(num_envs)
        kwargs.pop("mode", None)
        seeds = np.broadcast_to(np.asarray(seed), (B,)).astype(np.int64)
        proto = SelfTuningController(n, seed=int(seeds[0]), **kwargs)
        self.cfg = cfg = ControllerConfig(proto, B)
        self.n = cfg.n
        self.mode = "fast"
        self._prbs0 = ((seeds % 511) + 1).astype(float)
        progs = _Programs(cfg)
        self.layout = progs.layout
        self._progs = progs
        self.chunk = int(chunk)
        self._scratch: dict[int, tuple[NDArray, NDArray]] = {}
        _, self._est_update, self._est_predict = estimator_programs(cfg.est, chunk=self.chunk)
        self.state = LaneState(self.layout, B)
        self._nh_row = self.layout.rows("n_handovers")
        self._out = np.zeros((2, B))
        self._I = np.zeros((2, B))
        L = cfg.hist_len
        self._u_hist = np.zeros((L, B))
        self._y_hist = np.zeros((L, B))
        st = self.state
        if cfg.est.least_squares:
            for k, P0 in enumerate(cfg.est.P0):
                st.set(f"Sinit{k}", slice(None), np.linalg.cholesky(P0))
        else:
            for k, r0 in enumerate(cfg.est.r0):
                st.set(f"rinit{k}", slice(None), r0)
        if cfg.kalman:
            st.set("P1init", slice(None), cfg.est.P1_init)
        self.n_slow_steps = 0
        self.reset()

    # ------------------------------------------------------------------------ lanes
    def reset(self, lanes: ArrayLike | None = None) -> None:
        """Forget the episode in all lanes (or a boolean mask / index array)."""
        cfg, st = self.cfg, self.state
        idx = np.arange(self.num_envs) if lanes is None else np.asarray(lanes)
        if idx.dtype == bool:
            idx = np.flatnonzero(idx)
        if idx.size == 0:
            return
        for name in self.layout.groups:
            if not self.layout.is_const(name):
                st.set(name, idx, 0.0)
        self._estimator_fresh(idx, np.broadcast_to(cfg.est.theta0, (idx.size, cfg.d)), None, None)
        st.set("boot_P", idx, cfg.boot_p0 * np.eye(cfg.d))
        st.set("prbs", idx, self._prbs0[idx])
        st.set("open_loop", idx, 1.0)
        st.set("exc_end", idx, float(cfg.excitation_steps))
        st.set("closed_t", idx, -1.0)
        self._u_hist[:, idx] = 0.0
        self._y_hist[:, idx] = 0.0

    def _estimator_fresh(
        self, lanes: NDArray, theta0: NDArray, P0: NDArray | None, P1_init: NDArray | None
    ) -> None:
        """Estimator rows of ``lanes`` as a newly built estimator (``make_estimator``)."""
        cfg, st = self.cfg.est, self.state
        for name in estimator_layout(cfg).groups:
            if not self.layout.is_const(name):
                st.set(name, lanes, 0.0)
        st.set("theta", lanes, theta0)
        if cfg.least_squares:
            for k, blk in enumerate(cfg.blocks):
                if P0 is None:
                    S0 = np.broadcast_to(
                        np.linalg.cholesky(cfg.P0[k]), (len(lanes), *cfg.P0[k].shape)
                    )
                else:
                    S0 = np.linalg.cholesky(np.ascontiguousarray(P0[:, blk, blk]))
                st.set(f"Sinit{k}", lanes, S0)
                st.set(f"Sc{k}", lanes, S0)
        else:
            for k, r0 in enumerate(cfg.r0):
                st.set(f"rinit{k}", lanes, r0)
                st.set(f"rc{k}", lanes, r0)
        st.set("x", lanes, cfg.x_init)
        st.set("enabled", lanes, float(cfg.enabled))
        if cfg.kalman:
            P1i = cfg.P1_init if P1_init is None else P1_init
            st.set("P1init", lanes, P1i)
            st.set("P1", lanes, P1i)

    # ------------------------------------------------------------------------ the step
    #: Up to this many lanes the scalar kernel is run lane by lane (faster than numpy calls).
    scalar_lanes = 48

    def act(self, y: NDArray, r: NDArray) -> NDArray:
        """One step of every lane from ``y(t)``, ``r(t)`` (shape ``(B,)``); returns ``u(t)``."""
        st, I, O = self.state, self._I, self._out
        I[0], I[1] = y, r
        t = st.S[self.layout.rows("ct")].copy()
        B = self.num_envs
        if B <= self.scalar_lanes:
            self._act_scalar()
            st.swap()
            u = O[0].copy()
            self._record(t, u, y)
            return u
        c = min(self.chunk, B)
        F, G = self.scratch(c)
        boot_k, run_k = self._progs.nominal.numpy, self._progs.booted.numpy
        nh = st.S[self._nh_row]
        with np.errstate(all="ignore"):
            for s in range(0, B, c):
                e = min(B, s + c)
                w = e - s
                Fc, Gc = (F, G) if w == c else (F[:, :w], G[:, :w])
                Oc = O[:, s:e]
                nom = boot_k if (nh[s:e] == 0.0).any() else run_k
                nom(st.S[:, s:e], st.N[:, s:e], st.K[:, s:e], I[:, s:e], Oc, Fc, Gc)
                if Oc[-1].any():
                    self._slow_chunk(s, e, Fc, Gc)
        st.swap()
        u = O[0].copy()
        self._record(t, u, y)
        return u

    def _act_scalar(self) -> None:
        """Few lanes: the scalar kernels lane by lane (bit-for-bit the numpy kernels)."""
        st, I, O, p = self.state, self._I, self._out, self._progs
        F, G = self.scratch(1)
        for i in range(self.num_envs):
            S = tuple(st.S[:, i].tolist())
            kern = p.nominal.scalar if S[self._nh_row] == 0.0 else p.booted.scalar
            try:
                new, out = kern(S, tuple(st.K[:, i].tolist()), (float(I[0, i]), float(I[1, i])))
                if not out[-1]:
                    st.N[:, i] = new
                    O[0, i] = out[0]
                    continue
            except (ZeroDivisionError, ValueError, OverflowError):
                pass
            with np.errstate(all="ignore"):
                self._slow_chunk(i, i + 1, F, G)

    def scratch(self, c: int) -> tuple[NDArray, NDArray]:
        """Scratch rows for chunks of ``c`` lanes, enough for every kernel of the step."""
        if c not in self._scratch:
            p = self._progs
            ks = (p.nominal, p.booted, p.A, p.B, p.C)
            nf = max(max(k.n_float for k in ks), 1)
            nb = max(max(k.n_bool for k in ks), 1)
            self._scratch[c] = (np.empty((nf, c)), np.empty((nb, c), dtype=bool))
        return self._scratch[c]

    def _record(self, t: NDArray, u: NDArray, y: NDArray) -> None:
        L = self.cfg.hist_len
        i = (t % L).astype(np.intp)
        if (i == i[0]).all():
            self._u_hist[i[0]] = u
            self._y_hist[i[0]] = y
        else:
            cols = np.arange(self.num_envs)
            self._u_hist[i, cols] = u
            self._y_hist[i, cols] = y

    # ------------------------------------------------------------------------ the slow path
    def _slow_chunk(self, s: int, e: int, F: NDArray, G: NDArray) -> None:
        """Recompute lanes ``s:e`` phase by phase (hand-overs, restarts, health recovery)."""
        self.n_slow_steps += 1
        st, I, O, progs = self.state, self._I, self._out, self._progs
        sl = slice(s, e)
        Oc = O[:, sl]
        before = self._health_counts(st.S, sl)
        # A: S -> N
        progs.A.numpy(st.S[:, sl], st.N[:, sl], st.K[:, sl], I[:, sl], Oc[:1], F, G)
        due = np.flatnonzero(Oc[0] != 0) + s
        if due.size:
            self._handover(due, st.N)
        # B: N -> S (the old state of this chunk is not needed any more)
        progs.B.numpy(st.N[:, sl], st.S[:, sl], st.K[:, sl], I[:, sl], Oc[:1], F, G)
        alarm = np.flatnonzero(Oc[0] != 0) + s
        if alarm.size and self.cfg.est.least_squares:
            self._restart(alarm, st.S, I[0])
        # C: S -> N
        progs.C.numpy(st.S[:, sl], st.N[:, sl], st.K[:, sl], I[:, sl], Oc[:1], F, G)
        events = self._health_counts(st.N, sl) > before
        for what, lanes in zip(
            (
                "P(t) lost positive definiteness or overflowed",
                "state estimate not finite",
                "Kalman covariance not finite",
            ),
            events,
            strict=False,
        ):
            if lanes.any():
                warnings.warn(
                    f"{self.cfg.estimator_name}: {what} in lane(s) "
                    f"{(np.flatnonzero(lanes) + s)[:8].tolist()}; reset as the single estimator "
                    "does",
                    RuntimeWarning,
                    stacklevel=4,
                )

    def _health_counts(self, arr: NDArray, sl: slice) -> NDArray:
        """Estimator health counters of a chunk, one row per kind."""
        names = ["n_resets", "n_state_resets"] + (["n_kf_resets"] if self.cfg.kalman else [])
        return np.array([arr[self.layout.rows(nm), sl] for nm in names])

    def _rows(self, arr: NDArray, name: str, lanes: NDArray) -> NDArray:
        kind, shape, rows, const = self.layout.groups[name]
        if not shape:
            return arr[rows, lanes]
        return np.moveaxis(arr[np.array(rows)][..., lanes], -1, 0)

    def _handover(self, lanes: NDArray, S: NDArray) -> None:
        from stcgym.envs.canonical import observer_to_observability_b

        cfg, n = self.cfg, self.n
        th = self._rows(S, "boot_theta", lanes).copy()
        if cfg.form == "observability":
            for j in range(len(lanes)):
                th[j, n:] = observer_to_observability_b(th[j, :n], th[j, n:])
        fine = np.isfinite(th).all(axis=1)
        lanes, th = lanes[fine], th[fine]
        if lanes.size == 0:
            return
        P0 = None
        if cfg.rule in ("RLS", "MILS"):
            Pb = self._rows(S, "boot_P", lanes)
            P0 = 0.5 * (Pb + Pb.transpose(0, 2, 1)) * cfg.handover_inflation
        self._restart_lanes(lanes, th, P0, None, S)

    def _restart(self, lanes: NDArray, S: NDArray, y: NDArray) -> None:
        cfg = self.cfg
        theta = self._rows(S, "theta", lanes).copy()
        Ss = [self._rows(S, f"Sc{k}", lanes) for k in range(len(cfg.est.blocks))]
        d = cfg.d
        P = np.zeros((len(lanes), d, d))
        for blk, Sk in zip(cfg.est.blocks, Ss, strict=True):
            Pk = Sk @ Sk.transpose(0, 2, 1)
            P[:, blk, blk] = 0.5 * Pk + 0.5 * Pk.transpose(0, 2, 1)
        self._restart_lanes(lanes, theta, cfg.reset_inflation * P, y, S)

    def _restart_lanes(
        self, lanes: NDArray, theta0: NDArray, P0: NDArray | None, y: NDArray | None, S: NDArray
    ) -> None:
        """``SelfTuningController._restart`` on the estimator rows of ``lanes`` in ``S``."""
        cfg, n = self.cfg, self.n
        if P0 is not None:
            P0 = restart_covariance(P0, n, cfg.decomposed)
        t = self._rows(S, "ct", lanes).astype(np.int64)
        elay = self._est_update_layout()
        for tv in np.unique(t):
            grp = np.flatnonzero(t == tv)
            gl = lanes[grp]
            k = int(min(tv, cfg.hist_len))
            P1_init = None
            if k < tv and cfg.kalman:
                P1_init = np.broadcast_to(1e4 * np.eye(n), (grp.size, n, n))
            # Build the fresh estimator in a scratch lane state, replay, copy back.
            sub = LaneState(elay, grp.size)
            saved, self.state = self.state, sub
            try:
                self._estimator_fresh(
                    np.arange(grp.size), theta0[grp], None if P0 is None else P0[grp], P1_init
                )
            finally:
                self.state = saved
            if k:
                idx = np.arange(tv - k, tv) % cfg.hist_len
                en = sub.get("enabled")
                sub.set("enabled", slice(None), 0.0)
                for j in idx:
                    self._est_run(self._est_update, sub, self._y_hist[j, gl])
                    self._est_run(self._est_predict, sub, self._u_hist[j, gl])
                sub.set("enabled", slice(None), en)
            if y is not None:
                self._est_run(self._est_update, sub, y[gl])
            S[: elay.size, gl] = sub.S
            self.state.K[: elay.n_const, gl] = sub.K[: elay.n_const]

    def _est_update_layout(self) -> Layout:
        return estimator_layout(self.cfg.est)

    @staticmethod
    def _est_run(prog: Program, sub: LaneState, values: NDArray) -> None:
        out = np.zeros((2, sub.S.shape[1]))
        prog(sub.S, sub.N, sub.K, values[None, :], out)
        sub.swap()

    # ------------------------------------------------------------------------ views
    def _get(self, name: str) -> NDArray:
        return self.state.get(name)

    @property
    def theta(self) -> NDArray:
        return self._get("theta")

    @property
    def x_hat(self) -> NDArray:
        return self._get("x")

    @property
    def K(self) -> NDArray:
        return self._get("K")

    @property
    def N(self) -> NDArray:
        return self._get("N")

    @property
    def xi(self) -> NDArray:
        return self._get("xi")

    @property
    def t(self) -> NDArray:
        return self._get("ct").astype(np.int64)

    @property
    def has_gain(self) -> NDArray:
        return self._get("has_gain") != 0

    @property
    def n_handovers(self) -> NDArray:
        return self._get("n_handovers").astype(np.int64)

    @property
    def n_covariance_resets(self) -> NDArray:
        return self._get("n_cov_resets").astype(np.int64)

    @property
    def n_rejected(self) -> NDArray:
        return self._get("n_rejected").astype(np.int64)

    @property
    def rejection_counts(self) -> dict[str, NDArray]:
        rej = self._get("rej").astype(np.int64)
        return {r: rej[:, j] for j, r in enumerate(REJECTION_REASONS)}

    @property
    def memory_per_lane(self) -> int:
        """Bytes of state per lane (double-buffered rows, constants, replay history)."""
        st = self.state
        return (st.S.shape[0] * 2 + st.K.shape[0] + 2 * self.cfg.hist_len) * 8


# --------------------------------------------------------------------------------------------
# Single-plant fast path
# --------------------------------------------------------------------------------------------
class FastLoop:
    """One plant and one self-tuning regulator stepped by scalar generated code.

    The controller is bit-for-bit a lane of :class:`FastBatchedSelfTuningController`; the
    plant is the observer-canonical environment (``stcgym/ObserverCanonical-v0`` with the
    given keyword arguments, noise streams reproduced from ``seed``), stepped in scalar Python.
    Rare controller events fall back to the numpy kernels on one lane.

    >>> loop = FastLoop(plant="stable2", controller=dict(n=2, p=5), seed=0)  # doctest: +SKIP
    >>> y, r, u = loop.run(1000)  # doctest: +SKIP
    """

    def __init__(
        self,
        *,
        controller: dict[str, Any] | None = None,
        seed: int = 0,
        **env_kwargs: Any,
    ) -> None:
        from stcgym.envs.plants import ObserverCanonicalEnv

        ckw = dict(controller or {})
        env = ObserverCanonicalEnv(**env_kwargs)
        self.env = env
        n = ckw.pop("n", env.n_states)
        self.ctl = FastBatchedSelfTuningController(n, num_envs=1, form="observer", **ckw)
        progs = self.ctl._progs
        self._boot_kernel = progs.nominal.scalar
        self._run_kernel = progs.booted.scalar
        self._nh = self.ctl._nh_row
        self.seed = seed
        self.n_slow_steps = 0
        self.reset(seed)

    def reset(self, seed: int | None = None) -> tuple[float, float]:
        """New episode of the plant (``env.reset(seed=...)``) and a fresh controller; returns
        ``(y(0), r(0))``."""
        env = self.env
        obs, _ = env.reset(seed=seed)
        self.ctl.reset()
        self._S = tuple(self.ctl.state.S[:, 0].tolist())
        self._K = tuple(self.ctl.state.K[:, 0].tolist())
        n = env.n_states
        self._a = [float(v) for v in env.params[:n]]
        self._b = [float(v) for v in env.params[n:]]
        self._x = [float(v) for v in env.x]
        self._y, self._r0 = float(obs[0]), float(obs[1])
        self._k = 0
        return self._y, self._r0

    def step_controller(self, y: float, r: float) -> float:
        """``u(t)`` for ``y(t)``, ``r(t)`` (scalar kernel; numpy fallback for rare events)."""
        S = self._S
        kernel = self._boot_kernel if S[self._nh] == 0.0 else self._run_kernel
        try:
            new, out = kernel(S, self._K, (y, r))
            if not out[-1]:
                self._S = new
                u = out[0]
                self._record(y, u)
                return u
        except (ZeroDivisionError, ValueError, OverflowError):
            pass
        self.n_slow_steps += 1
        ctl = self.ctl
        ctl.state.S[:, 0] = self._S
        ctl.state.K[:, 0] = self._K
        u = float(ctl.act(np.array([y]), np.array([r]))[0])
        self._S = tuple(ctl.state.S[:, 0].tolist())
        self._K = tuple(ctl.state.K[:, 0].tolist())
        return u

    def _record(self, y: float, u: float) -> None:
        ctl = self.ctl
        i = int(self._S[ctl.layout.rows("ct")] - 1.0) % ctl.cfg.hist_len
        ctl._u_hist[i, 0] = u
        ctl._y_hist[i, 0] = y

    def run(self, steps: int) -> tuple[NDArray, NDArray, NDArray]:
        """Run ``steps`` closed-loop steps; returns ``y(t)``, ``r(t)``, ``u(t)`` as arrays.

        The plant is the env's observer-canonical recursion in scalar form, with its noise
        streams (and parameter schedule, if any); episodes do not end (no time limit), and the
        run stops early if the output leaves ``[-y_bound, y_bound]`` (the env would terminate).
        """
        env = self.env
        n = env.n_states
        a, b, x = self._a, self._b, self._x
        bound = env.action_bound
        ref = env.reference[0]
        sigma, sigma_w = env.noise_std, env.process_noise_std
        v, w = env._v, env._w
        tv = env.schedule.time_varying
        yb = env.y_bound
        ys = np.empty(steps)
        rs = np.empty(steps)
        us = np.empty(steps)
        y = self._y
        k = self._k
        step = self.step_controller
        j = 0
        for j in range(steps):
            r = ref(k)
            u = step(y, r)
            ys[j], rs[j], us[j] = y, r, u
            uc = bound if u > bound else -bound if u < -bound else u
            x0 = x[0]
            xn = [(-a[i] * x0 + x[i + 1]) + b[i] * uc for i in range(n - 1)]
            xn.append(-a[n - 1] * x0 + b[n - 1] * uc)
            if sigma_w:
                wk = w.next()
                xn = [xn[i] + sigma_w * float(wk[i]) for i in range(n)]
            x = xn
            k += 1
            if tv:
                p = env.schedule(k)
                a, b = [float(q) for q in p[:n]], [float(q) for q in p[n:]]
            y = x[0] + sigma * float(v.next()[0])
            if not (-yb <= y <= yb):
                j += 1
                break
        else:
            j = steps
        self._a, self._b, self._x, self._y, self._k = a, b, x, y, k
        return ys[:j], rs[:j], us[:j]

    @property
    def state(self) -> tuple[float, ...]:
        return self._S
