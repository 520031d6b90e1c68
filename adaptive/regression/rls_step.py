"""Recursive least squares on user regressors, ``y(t) = phi(t) theta + e(t)``: the lane step.

The lane state :class:`RLSState` holds a whole estimator: ``theta``, the square-root factor
``S`` of ``P = S S^T``, the gain and the finite-history window; :class:`RLSWork` is its scratch
(named tuples of batched arrays, lane ``i``'s field ``f`` is ``state.f[i]``; shapes in
:func:`rls_shapes`), :class:`RLSConfig` the settings every lane shares.
:func:`rls_step` is one sample of the shared least-squares lane function
(:func:`stcgym.adaptive.estimation.least_squares.least_squares_step`) with forgetting, an
optional finite window (a rank-one downdate when it is accurate, else a replay of the stored
window) and the common health policy; :func:`rls_run` is a record of samples, and
:func:`rls_run_lanes` its batch loop over lanes. :class:`stcgym.adaptive.RecursiveLeastSquares`
is its Python face.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from stcgym.adaptive.estimation.least_squares import (
    DOWNDATE_TOL,
    WindowedLeastSquaresWork,
    factor_is_healthy,
    least_squares_downdate,
    least_squares_shapes,
    least_squares_step,
)
from stcgym.adaptive.estimation.least_squares import OK as LS_OK
from stcgym.lanes.compiled import fields_of, lane, lane_state, lanes, make_work
from stcgym.lanes.linalg import copy_matrix, copy_vector

__all__ = [
    "FAILED",
    "OK",
    "RECOMPUTED",
    "WINDOW_DOWNDATE_TOL",
    "RLSConfig",
    "RLSState",
    "RLSWork",
    "make_rls_state",
    "rls_run",
    "rls_run_lanes",
    "rls_shapes",
    "rls_step",
]

#: A finite-history sample is removed by a downdate only when every pivot of
#: ``I - phi P phi^T`` exceeds this (the kernels' one limit); otherwise the window is replayed.
WINDOW_DOWNDATE_TOL = DOWNDATE_TOL

# lane status codes
OK = 0
FAILED = 1  # non-finite or non-positive: P reset (or the lane left untouched)
RECOMPUTED = 2  # finite history recomputed from the stored window


# --------------------------------------------------------------------------------------------
# The estimator step on one lane (the rule itself is the shared least-squares lane
# function of :mod:`stcgym.adaptive.estimation.least_squares`)
# --------------------------------------------------------------------------------------------


class RLSState(NamedTuple):
    """A :class:`RecursiveLeastSquares` lane state: field ``f`` of lane ``i`` is ``state.f[i]``
    (shapes in :func:`rls_shapes`)."""

    theta: NDArray  # theta(t) (d,)
    S: NDArray  # upper factor of P = S S^T (d, d)
    innovation: NDArray  # e(t) (p,)
    y_hat: NDArray  # the prediction with theta(t-1) (p,)
    K: NDArray  # the gain (d, p)
    t: NDArray  # steps since the reset (int)
    n_resets: NDArray  # covariance resets (int)
    n_recomputes: NDArray  # window recomputations (int)
    count: NDArray  # samples in the window (int)
    hist_Phi: NDArray  # the window's regressors (W, p, d)
    hist_Y: NDArray  # the window's outputs (W, p)


class RLSStepWork(NamedTuple):
    """The scratch of :func:`rls_step` around the least-squares step."""

    theta_try: NDArray  # the step's candidate theta (d,)
    S_try: NDArray  # its candidate factor (d, d)
    y_pred: NDArray  # Phi theta(t-1) (p,)
    F: NDArray  # Phi S of downdate_is_accurate (p, d)
    M: NDArray  # the Cholesky factor of I - F F^T (p, p)
    saved_Phi: NDArray  # the window sample a recomputation replaces (p, d)
    saved_Y: NDArray  # (p,)


#: The scratch of :func:`rls_step`, one row a lane (its content is irrelevant between calls):
#: the fields of :class:`RLSStepWork` and of the least-squares step's and downdate's
#: :data:`~stcgym.adaptive.estimation.least_squares.WindowedLeastSquaresWork`.
RLSWork = NamedTuple(  # type: ignore[misc]
    "RLSWork", fields_of(RLSStepWork, WindowedLeastSquaresWork)
)


class RLSConfig(NamedTuple):
    """The settings every lane of a :class:`RecursiveLeastSquares` shares."""

    theta0: NDArray  # the prior theta(0) (d,)
    S0: NDArray  # the factor of P(0) (d, d)
    lam: float  # the forgetting factor
    window: int  # the finite history (0: none)
    adapt: bool  # update theta and P (else predictions only)
    reset_on_failure: bool  # a failing lane restarts at P(0) (else it is left as it was)


_COUNTERS = ("t", "n_resets", "n_recomputes", "count")


def rls_shapes(
    d: int, p: int, window: int
) -> tuple[dict[str, tuple[int, ...]], dict[str, tuple[int, ...]]]:
    """The shapes of one lane's :class:`RLSState` and :class:`RLSWork` fields for ``d``
    parameters, ``p`` outputs and a window of ``window`` samples: the one place they are
    declared."""
    d, p, W = int(d), int(p), int(window)
    state: dict[str, tuple[int, ...]] = {
        "theta": (d,),
        "S": (d, d),
        **dict.fromkeys(("innovation", "y_hat"), (p,)),
        "K": (d, p),
        **dict.fromkeys(_COUNTERS, ()),
        "hist_Phi": (W, p, d),
        "hist_Y": (W, p),
    }
    work: dict[str, tuple[int, ...]] = {
        "theta_try": (d,),
        "S_try": (d, d),
        **dict.fromkeys(("y_pred", "saved_Y"), (p,)),
        **dict.fromkeys(("F", "saved_Phi"), (p, d)),
        "M": (p, p),
        **least_squares_shapes(d, p, window=True),
    }
    return state, work


def make_rls_state(d: int, p: int, window: int, num_lanes: int) -> tuple[RLSState, Any]:
    """A zeroed :class:`RLSState` of ``num_lanes`` lanes and their scratch."""
    state, work = rls_shapes(d, p, window)
    dtypes: dict[str, Any] = dict.fromkeys(_COUNTERS, np.int64)
    return (
        lane_state(RLSState, state, num_lanes, dtypes),
        make_work(RLSWork, work, num_lanes),
    )


@lane
def replay_window(theta, S, cfg, hist_Phi, hist_Y, first, w, lane_i):  # pragma: no cover
    """Finite-history estimate recomputed by replaying the stored samples from the prior.

    ``theta <- theta0``, ``S <- S0`` (of the :class:`RLSConfig` ``cfg``), then
    :func:`least_squares_step` on every stored sample, oldest (slot ``first``) first: exactly the
    regularised estimate over the window, without the cancellation of a downdate. Returns
    ``False`` when a step fails.
    """
    W = hist_Phi.shape[0]
    copy_vector(cfg.theta0, theta)
    copy_matrix(cfg.S0, S)
    for k in range(W):
        slot = (first + k) % W
        if least_squares_step(theta, S, hist_Phi[slot], hist_Y[slot], 1.0, w, lane_i) != LS_OK:
            return False
    return True


@lane
def downdate_is_accurate(S, Phi, F, M):  # pragma: no cover - compiled
    """Removing ``Phi`` from ``P^{-1} = (S S^T)^{-1}`` keeps enough digits.

    ``True`` when every squared Cholesky pivot of ``I - Phi P Phi^T`` exceeds
    ``WINDOW_DOWNDATE_TOL`` (for one row: ``1 - phi^T P phi``; their product is
    ``det(P^{-1} - Phi^T Phi) / det(P^{-1})``). ``F`` (p, d) and ``M`` (p, p) are scratch.
    """
    p, d = Phi.shape
    for r in range(p):  # F = Phi S
        for j in range(d):
            acc = 0.0
            for i in range(j + 1):  # S upper triangular
                acc += Phi[r, i] * S[i, j]
            F[r, j] = acc
    for r in range(p):  # Cholesky I - F F^T = M M^T
        for c in range(r + 1):
            acc = 1.0 if r == c else 0.0
            for j in range(d):
                acc -= F[r, j] * F[c, j]
            for k in range(c):
                acc -= M[r, k] * M[c, k]
            if r == c:
                if not acc > WINDOW_DOWNDATE_TOL:
                    return False
                M[r, r] = math.sqrt(acc)
            else:
                M[r, c] = acc / M[c, c]
    return True


@lane(inline=True)
def _gain(K, S, Phi, g):  # pragma: no cover - compiled
    """``K(t) = P(t) Phi^T = S (S^T Phi^T)``, ``(d, p)`` (``= P(t-1) phi / alpha``, eq. (3));
    ``g`` is scratch of length ``d``."""
    p, d = Phi.shape
    for r in range(p):
        for j in range(d):
            acc = 0.0
            for i in range(d):
                acc += S[i, j] * Phi[r, i]
            g[j] = acc
        for i in range(d):
            acc = 0.0
            for j in range(d):
                acc += S[i, j] * g[j]
            K[i, r] = acc


@lane(inline=True)
def rls_step(s, w, lane_i, cfg, Phi, Y):  # pragma: no cover
    """One step of :class:`RecursiveLeastSquares` on lane ``lane_i``; returns a status code.

    ``s``/``w``: an :class:`RLSState` and its :class:`RLSWork`; ``cfg``: an :class:`RLSConfig`;
    ``Phi`` (p, d), ``Y`` (p,). The rule is :func:`least_squares_step` (square-root RLS/MILS
    with forgetting and its health check); with a window the sample ``window`` steps old is
    removed by :func:`least_squares_downdate` or, when that would be inaccurate, the estimate
    is recomputed over the window (:func:`replay_window`). Works on copies of ``theta`` and
    ``S`` and commits only a healthy step, so a failing lane is either reset
    (``reset_on_failure``: ``P <- P0``, window emptied, ``theta`` kept) or left exactly as it
    was.
    """
    p, d = Phi.shape
    window = cfg.window
    theta = s.theta[lane_i]
    S = s.S[lane_i]
    hPhi = s.hist_Phi[lane_i]
    hY = s.hist_Y[lane_i]
    th = w.theta_try[lane_i]
    Sn = w.S_try[lane_i]
    y_pred = w.y_pred[lane_i]
    for r in range(p):  # prediction with theta(t-1); innovation e(t) = y(t) - y_pred
        acc = 0.0
        for i in range(d):
            acc += Phi[r, i] * theta[i]
        y_pred[r] = acc
    status = OK
    if cfg.adapt:
        copy_vector(theta, th)
        copy_matrix(S, Sn)
        ok = least_squares_step(th, Sn, Phi, Y, cfg.lam, w, lane_i) == LS_OK
        count = s.count[lane_i]
        slot = count % window if window > 0 else 0
        if ok and window > 0 and count >= window:
            if not (
                downdate_is_accurate(Sn, hPhi[slot], w.F[lane_i], w.M[lane_i])
                and least_squares_downdate(th, Sn, hPhi[slot], hY[slot], w, lane_i) == LS_OK
            ):
                saved_Phi = w.saved_Phi[lane_i]  # recompute over the window after this step
                saved_Y = w.saved_Y[lane_i]
                copy_matrix(hPhi[slot], saved_Phi)
                copy_vector(hY[slot], saved_Y)
                copy_matrix(Phi, hPhi[slot])
                copy_vector(Y, hY[slot])
                ok = replay_window(th, Sn, cfg, hPhi, hY, (slot + 1) % window, w, lane_i)
                copy_matrix(saved_Phi, hPhi[slot])
                copy_vector(saved_Y, hY[slot])
                status = RECOMPUTED
            ok = ok and factor_is_healthy(Sn, 0, d)
        for i in range(d):
            ok = ok and math.isfinite(th[i])
        if not ok:
            if not cfg.reset_on_failure:
                return FAILED
            copy_matrix(cfg.S0, S)
            s.count[lane_i] = 0
            s.n_resets[lane_i] += 1
            status = FAILED
        else:
            copy_vector(th, theta)
            copy_matrix(Sn, S)
            if window > 0:
                copy_matrix(Phi, hPhi[slot])
                copy_vector(Y, hY[slot])
                s.count[lane_i] = count + 1
            if status == RECOMPUTED:
                s.n_recomputes[lane_i] += 1
        _gain(s.K[lane_i], S, Phi, th)
    y_hat = s.y_hat[lane_i]
    innovation = s.innovation[lane_i]
    for r in range(p):
        y_hat[r] = y_pred[r]
        innovation[r] = Y[r] - y_pred[r]
    s.t[lane_i] += 1
    return status


@lane(entry=True)
def rls_run(s, w, lane_i, cfg, Phis, Ys, out):  # pragma: no cover
    """``T`` steps of :func:`rls_step` on lane ``lane_i``: ``out[t] = theta(t)``.

    Returns ``(failures, first failing step or -1)``; without ``cfg.reset_on_failure`` it stops
    at the first failure (that step not applied).
    """
    failures = 0
    first = -1
    for t in range(Phis.shape[0]):
        status = rls_step(s, w, lane_i, cfg, Phis[t], Ys[t])
        if status == FAILED:
            failures += 1
            if first < 0:
                first = t
            if not cfg.reset_on_failure:
                return failures, first
        copy_vector(s.theta[lane_i], out[t])
    return failures, first


@lanes(min_lanes=1)  # a lane is a whole record of samples
def rls_run_lanes(
    s, w, cfg, Phis, Ys, out, failures, first_failure, first, last
):  # pragma: no cover
    """:func:`rls_run` on every lane (``failures[i]``, ``first_failure[i]``: its results)."""
    for i in range(first, last):
        failures[i], first_failure[i] = rls_run(s, w, i, cfg, Phis[i], Ys[i], out[i])
