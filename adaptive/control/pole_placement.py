"""Pole placement by Ackermann's formula on the (integral-augmented) model: lane functions.

``place_design(theta, form, integral, feedforward, alpha, safe, gain, work) -> int``
    Ackermann pole placement of the ``m`` poles with monic characteristic polynomial
    ``z^m + alpha[0] z^{m-1} + ... + alpha[m-1]`` (``alpha`` length ``m``) on the (augmented)
    model of ``theta``; ``N = u_ss + K_x x_ss`` from the steady state. Returns the status code
    of :mod:`.safe_set`; ``gain`` is written only on success.
``ackermann_gain(A, b, alpha, K, work) -> rcond``
    The same formula on a general pair (``rcond <= 0``: singular; ``K`` written only when
    ``rcond > 0``), used by the numpy helpers of :mod:`stcgym.adaptive.control.placement`.
``place_design_lanes(thetas, form, integral, feedforward, alpha, safe, gains, status)``
    The batch loop (each lane allocates its own scratch).
"""

from __future__ import annotations

import numpy as np

from stcgym.adaptive.control.safe_set import (
    MAT,
    N_MAT,
    N_VEC,
    OK,
    VEC,
    controllability,
    design_start,
    finish,
    split_work,
)
from stcgym.envs.compiled import lane, lanes

__all__ = ["ackermann_gain", "place_design", "place_design_lanes"]


@lane(inline=True)
def _ackermann_from_ctrb(A, alpha, K, Ws, Vs):
    """``K = e_m^T Ctrb^{-1} phi_d(A) = sum_k alpha_{m-k} w^T A^k`` with ``w`` the last row of
    ``Ctrb^{-1}`` (``phi_d(A)`` never formed: ``m`` row-vector/matrix products)."""
    m = A.shape[0]
    Cinv = Ws[MAT.m2, :m, :m]
    norms = Vs[VEC.v0, :m]
    v = Vs[VEC.v1, :m]
    w = Vs[VEC.v2, :m]
    for j in range(m):
        v[j] = Cinv[m - 1, j] / norms[m - 1]
        K[j] = alpha[m - 1] * v[j]
    for k in range(1, m + 1):
        coef = alpha[m - 1 - k] if k < m else 1.0
        for j in range(m):
            acc = 0.0
            for i in range(m):
                acc += v[i] * A[i, j]
            w[j] = acc
        for j in range(m):
            v[j] = w[j]
            K[j] += coef * v[j]


@lane(entry=True)
def ackermann_gain(A, b, alpha, K, work):
    """Ackermann gain of a general pair ``(A, b)`` (``m x m``; ``work`` of ``work_size(m - 1)``).

    ``eig(A - b K)`` are the roots of ``z^m + alpha[0] z^{m-1} + ... + alpha[m-1]``. Returns the
    reciprocal 1-norm condition of the column-normalised controllability matrix (``<= 0``:
    singular or non-finite, ``K`` untouched).
    """
    mm = A.shape[0]
    Ws, Vs = split_work(work, mm, N_MAT)
    rcond = controllability(A, b, Ws, Vs)
    if rcond > 0.0:
        _ackermann_from_ctrb(A, alpha, K, Ws, Vs)
    return rcond


@lane(entry=True)
def place_design(theta, form, integral, feedforward, alpha, safe, gain, work):
    """Pole placement on the (augmented) model of ``theta``; see the module docstring.

    Returns the status code; ``gain`` is written only when it is ``OK`` (0).
    """
    status, rcond, Ws, Vs, Ad, _, K = design_start(theta, form, integral, safe, work, N_MAT)
    if status != OK:
        return status
    _ackermann_from_ctrb(Ad, alpha, K, Ws, Vs)
    return finish(theta, integral, feedforward, safe, K, rcond, gain, Ws, Vs)


@lanes(allocates=True, min_lanes=16)  # one design a lane
def place_design_lanes(
    thetas, form, integral, feedforward, alpha, safe, gains, status, first, last
):
    """:func:`place_design` for every lane (``thetas`` ``(B, 2n)``, ``gains`` ``(B, n + 3)``,
    ``status`` ``(B,)`` int64); each lane allocates its own scratch."""
    mm = thetas.shape[1] // 2 + 1
    for i in range(first, last):
        work = np.empty(N_MAT * mm * mm + N_VEC * mm)
        status[i] = place_design(
            thetas[i], form, integral, feedforward, alpha, safe, gains[i], work
        )
