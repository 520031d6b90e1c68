"""Recursive least squares on user regressors, ``y(t) = phi(t) theta + e(t)``: the lane step.

One lane record (fields :class:`RLSRecord`) holds a whole estimator: ``theta``, the
square-root factor ``S`` of ``P = S S^T``, the gain and the finite-history window.
:func:`rls_step` is one sample of the shared least-squares lane function
(:func:`stcgym.adaptive.estimation.least_squares.least_squares_step`) with forgetting, an
optional finite window (a rank-one downdate when it is accurate, else a replay of the stored
window) and the common health policy; :func:`rls_run` is a record of samples, and
:func:`rls_run_lanes` its batch loop over lanes. :class:`stcgym.adaptive.RecursiveLeastSquares`
is its Python face.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from stcgym.adaptive.estimation.least_squares import (
    DOWNDATE_TOL,
    factor_is_healthy,
    least_squares_downdate,
    least_squares_step,
)
from stcgym.adaptive.estimation.least_squares import OK as LS_OK
from stcgym.adaptive.kernels.records import copy_matrix, copy_vector, view2d, view3d
from stcgym.envs.compiled import lane, lanes

__all__ = [
    "FAILED",
    "OK",
    "RECOMPUTED",
    "WINDOW_DOWNDATE_TOL",
    "RLSRecord",
    "rls_run",
    "rls_run_lanes",
    "rls_step",
    "work_size",
]

#: A finite-history sample is removed by a downdate only when every pivot of
#: ``I - phi P phi^T`` exceeds this (the kernels' one limit); otherwise the window is replayed.
WINDOW_DOWNDATE_TOL = DOWNDATE_TOL

# lane status codes
OK = 0
FAILED = 1  # non-finite or non-positive: P reset (or the lane left untouched)
RECOMPUTED = 2  # finite history recomputed from the stored window


# --------------------------------------------------------------------------------------------
# The estimator step on one lane record (the rule itself is the shared least-squares lane
# function of :mod:`stcgym.adaptive.estimation.least_squares`)
# --------------------------------------------------------------------------------------------


class RLSRecord(NamedTuple):
    """Fields of a :class:`RecursiveLeastSquares` lane record (offsets, in layout order)."""

    theta: int  # (d,)
    S: int  # (d, d) upper factor of P = S S^T
    innovation: int  # (p,) e(t)
    y_hat: int  # (p,) prediction with theta(t-1)
    K: int  # (d, p) gain
    t: int
    n_resets: int
    n_recomputes: int
    count: int  # samples in the window
    hist_Phi: int  # (W, p, d)
    hist_Y: int  # (W, p)
    work: int  # scratch: no allocation inside the lane function


def work_size(d: int, p: int) -> int:
    """Scratch floats of one lane: ``theta`` and ``S`` copies, the rule's work, ``y_pred``,
    the ``(p, d)``, ``(p, p)`` scratch of :func:`downdate_is_accurate` and a saved window
    block ``(p, d)``, ``(p,)`` (lane functions never allocate)."""
    return d + d * d + (3 * d + p + d * d) + p + p * d + p * p + p * d + p


@lane
def replay_window(theta, S, theta0, S0, hist_Phi, hist_Y, first, work):  # pragma: no cover
    """Finite-history estimate recomputed by replaying the stored samples from the prior.

    ``theta <- theta0``, ``S <- S0``, then :func:`least_squares_step` on every stored sample,
    oldest (slot ``first``) first: exactly the regularised estimate over the window, without the
    cancellation of a downdate. Returns ``False`` when a step fails.
    """
    W = hist_Phi.shape[0]
    copy_vector(theta0, theta)
    copy_matrix(S0, S)
    for k in range(W):
        slot = (first + k) % W
        if least_squares_step(theta, S, hist_Phi[slot], hist_Y[slot], 1.0, work) != LS_OK:
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


@lane
def rls_step(rec, at, Phi, Y, theta0, S0, lam, window, adapt, reset_on_failure):  # pragma: no cover
    """One step of :class:`RecursiveLeastSquares` on one lane record; returns a status code.

    ``Phi`` (p, d), ``Y`` (p,). The rule is :func:`least_squares_step` (square-root RLS/MILS
    with forgetting and its health check); with a window the sample ``window`` steps old is
    removed by :func:`least_squares_downdate` or, when that would be inaccurate, the estimate
    is recomputed over the window (:func:`replay_window`). Works on copies of ``theta`` and
    ``S`` and commits only a healthy step, so a failing lane is either reset
    (``reset_on_failure``: ``P <- P0``, window emptied, ``theta`` kept) or left exactly as it
    was.
    """
    p, d = Phi.shape
    theta = rec[at.theta : at.theta + d]
    S = view2d(rec, at.S, d, d)
    hPhi = view3d(rec, at.hist_Phi, window, p, d)
    hY = view2d(rec, at.hist_Y, window, p)
    o = at.work
    th = rec[o : o + d]
    Sn = view2d(rec, o + d, d, d)
    work = rec[o + d + d * d : o + 4 * d + p + 2 * d * d]
    o += 4 * d + p + 2 * d * d
    y_pred = rec[o : o + p]
    F = view2d(rec, o + p, p, d)
    M = view2d(rec, o + p + p * d, p, p)
    o += p + p * d + p * p
    saved_Phi = view2d(rec, o, p, d)
    saved_Y = rec[o + p * d : o + p * d + p]
    for r in range(p):  # prediction with theta(t-1); innovation e(t) = y(t) - y_pred
        acc = 0.0
        for i in range(d):
            acc += Phi[r, i] * theta[i]
        y_pred[r] = acc
    status = OK
    if adapt:
        copy_vector(theta, th)
        copy_matrix(S, Sn)
        ok = least_squares_step(th, Sn, Phi, Y, lam, work) == LS_OK
        count = int(rec[at.count])
        slot = count % window if window > 0 else 0
        if ok and window > 0 and count >= window:
            if not (
                downdate_is_accurate(Sn, hPhi[slot], F, M)
                and least_squares_downdate(th, Sn, hPhi[slot], hY[slot], work) == LS_OK
            ):
                copy_matrix(hPhi[slot], saved_Phi)  # recompute over the window after this step
                copy_vector(hY[slot], saved_Y)
                copy_matrix(Phi, hPhi[slot])
                copy_vector(Y, hY[slot])
                ok = replay_window(th, Sn, theta0, S0, hPhi, hY, (slot + 1) % window, work)
                copy_matrix(saved_Phi, hPhi[slot])
                copy_vector(saved_Y, hY[slot])
                status = RECOMPUTED
            ok = ok and factor_is_healthy(Sn, 0, d)
        for i in range(d):
            ok = ok and math.isfinite(th[i])
        if not ok:
            if not reset_on_failure:
                return FAILED
            copy_matrix(S0, S)
            rec[at.count] = 0.0
            rec[at.n_resets] += 1.0
            status = FAILED
        else:
            copy_vector(th, theta)
            copy_matrix(Sn, S)
            if window > 0:
                copy_matrix(Phi, hPhi[slot])
                copy_vector(Y, hY[slot])
                rec[at.count] = count + 1.0
            if status == RECOMPUTED:
                rec[at.n_recomputes] += 1.0
        _gain(view2d(rec, at.K, d, p), S, Phi, th)
    for r in range(p):
        rec[at.y_hat + r] = y_pred[r]
        rec[at.innovation + r] = Y[r] - y_pred[r]
    rec[at.t] += 1.0
    return status


@lane(entry=True)
def rls_run(
    rec, at, Phis, Ys, theta0, S0, lam, window, adapt, reset_on_failure, out
):  # pragma: no cover
    """``T`` steps of :func:`rls_step` on one lane: ``out[t] = theta(t)``.

    Returns ``(failures, first failing step or -1)``; without ``reset_on_failure`` it stops at
    the first failure (that step not applied).
    """
    d = Phis.shape[2]
    failures = 0
    first = -1
    for t in range(Phis.shape[0]):
        status = rls_step(rec, at, Phis[t], Ys[t], theta0, S0, lam, window, adapt, reset_on_failure)
        if status == FAILED:
            failures += 1
            if first < 0:
                first = t
            if not reset_on_failure:
                return failures, first
        copy_vector(rec[at.theta : at.theta + d], out[t])
    return failures, first


@lanes(min_lanes=1)  # a lane is a whole record of samples
def rls_run_lanes(
    F,
    at,
    Phis,
    Ys,
    theta0,
    S0,
    lam,
    window,
    adapt,
    reset_on_failure,
    out,
    failures,
    first_failure,
    first: int,
    last: int,
):  # pragma: no cover
    """:func:`rls_run` on every lane (``failures[i]``, ``first_failure[i]``: its results)."""
    for i in range(first, last):
        failures[i], first_failure[i] = rls_run(
            F[i], at, Phis[i], Ys[i], theta0, S0, lam, window, adapt, reset_on_failure, out[i]
        )
