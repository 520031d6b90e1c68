"""The safe set every certainty-equivalence design passes, and the gain record it writes.

Shared by pole placement (:mod:`.pole_placement`) and the LQ designs (:mod:`.lq`): the tests
of the safe set in order, the gain record ``[K_x, k_i, N, rcond]`` (:func:`gain_size`), written
**only on success** (a rejected model keeps the last good gain), and the designs' scratch
(:func:`work_size`, :func:`split_work`).

Safe set ``safe`` (float64, length 4; :func:`safe_set` builds and validates it)
------------------------------------------------------------------------------
``[b_min, rcond_min, dc_rcond_min, gain_max]`` (:class:`SafeSetBounds`, read by name through
:func:`safe_bounds`), tested in this order, first failure reported:

==== ====================== ==========================================================
code name                   meaning
==== ====================== ==========================================================
0    ``ok``                 gain accepted and written
1    ``nonfinite``          ``theta`` is not finite
2    ``b_small``            ``max |b| < b_min``
3    ``uncontrollable``     reciprocal 1-norm condition of the column-normalised
                            controllability matrix of the (augmented) model
                            ``<= max(rcond_min, 1e-14)``
4    ``dc_singular``        feed-forward on and the steady-state (Rosenbrock) matrix
                            ``[[A - I, b], [c, 0]]`` has rcond
                            ``< max(dc_rcond_min, 1e-13)`` (a zero at ``z = 1``)
5    ``gain_large``         ``max(|K|, |N|) > gain_max`` (or non-finite)
6    ``not_stabilisable``   LQ: the Riccati iterate or doubling blew up (``> 1e150``)
                            or the gain's closed loop is not Schur stable; the
                            one-step variant restarts ``P`` at the state weight ``Q``
7    ``not_converged``      LQ solve: no convergence within ``max_iter`` steps
8    ``unit_circle_mode``   multi-input LQ (:mod:`.mimo_lq`): stabilisable, but a mode
                            on the unit circle is unobservable through the state weight
==== ====================== ==========================================================

``STATUS_NAMES[code]`` gives the name.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from stcgym.adaptive.kernels.canonical import augment_integral, model_matrices
from stcgym.adaptive.kernels.linalg import all_finite, invert, matvec, norm1
from stcgym.adaptive.kernels.records import view2d, view3d
from stcgym.envs.compiled import lane
from stcgym.envs.validation import real_in

__all__ = [
    "MAT",
    "N_MAT",
    "N_MAT_SOLVE",
    "N_VEC",
    "STATUS_NAMES",
    "VEC",
    "SafeSetBounds",
    "controllability",
    "finish",
    "gain_size",
    "design_start",
    "safe_bounds",
    "safe_set",
    "solve_work_size",
    "split_work",
    "steady_state",
    "work_size",
]

# Status codes of a design (values, not offsets).
OK = 0
NONFINITE = 1
B_SMALL = 2
UNCONTROLLABLE = 3
DC_SINGULAR = 4
GAIN_LARGE = 5
NOT_STABILISABLE = 6
NOT_CONVERGED = 7
UNIT_CIRCLE_MODE = 8
STATUS_NAMES = (
    "ok",
    "nonfinite",
    "b_small",
    "uncontrollable",
    "dc_singular",
    "gain_large",
    "not_stabilisable",
    "not_converged",
    "unit_circle_mode",
)

#: Floors of the conditioning tests (below them a "solution" is rounding noise).
RCOND_FLOOR = 1e-14
DC_RCOND_FLOOR = 1e-13


class MatrixSlots(NamedTuple):
    """Matrix slots (each ``mm x mm``, ``mm = n + 1``) of the design scratch, by use."""

    A: int  # the model
    A_aug: int  # the (integral-augmented) model
    m0: int
    m1: int
    m2: int
    m3: int
    m4: int
    m5: int
    m6: int
    m7: int
    m8: int
    m9: int
    m10: int


class VectorSlots(NamedTuple):
    """Vector slots (each ``mm``) of the design scratch, by use."""

    b_aug: int
    K: int
    x_ss: int
    v0: int
    v1: int
    v2: int
    b: int
    v4: int
    v5: int


#: Slot numbers of the scratch (``Ws[MAT.A_aug, :m, :m]``, ``Vs[VEC.K, :m]``).
MAT = MatrixSlots(*range(len(MatrixSlots._fields)))
VEC = VectorSlots(*range(len(VectorSlots._fields)))
N_MAT = 5  # matrix slots every design needs (A .. m2)
N_MAT_SOLVE = len(MatrixSlots._fields)  # matrix slots of the solve-to-convergence variants
N_VEC = len(VectorSlots._fields)


def gain_size(n: int) -> int:
    """Length of the gain record ``[K_x (n), k_i, N, rcond]``: the state gain, the integral gain
    ``k_i`` (0 without integral action), the reference feed-forward ``N`` (0 when off) and the
    reciprocal condition number of the accepted design's controllability matrix. Whether any
    design has succeeded yet is the caller's to keep."""
    return int(n) + 3


def work_size(n: int) -> int:
    """Scratch length of ``place_design``, ``lq_design`` (and ``ackermann_gain``,
    ``steady_state``) for order ``n``: ``5 (n+1)^2 + 9 (n+1)``. The scratch is float64, 1-D,
    its content irrelevant between calls, one per thread or per lane, never shared by two
    lanes."""
    mm = int(n) + 1
    return N_MAT * mm * mm + N_VEC * mm


def solve_work_size(n: int) -> int:
    """Scratch length of ``lq_solve`` (and ``dare``) for order ``n``: ``13 (n+1)^2 + 9 (n+1)``."""
    mm = int(n) + 1
    return N_MAT_SOLVE * mm * mm + N_VEC * mm


class SafeSetBounds(NamedTuple):
    """The entries of the safe-set vector by name (:func:`safe_bounds` reads them)."""

    b_min: float  # max |b_hat| >= b_min
    rcond_min: float  # reciprocal condition of the controllability matrix
    dc_rcond_min: float  # reciprocal condition of the steady-state matrix
    gain_max: float  # max(|K|, |N|) <= gain_max


@lane(inline=True)
def safe_bounds(safe):
    """The safe-set vector ``safe`` (float64, length 4) as a :class:`SafeSetBounds`: the one
    place that knows the order of its entries.

    The lane functions take the vector and build the tuple inside, so the safe set travels
    like the other configuration vectors (``alpha``, the LQ weights): one float64 array.
    """
    return SafeSetBounds(safe[0], safe[1], safe[2], safe[3])


def safe_set(
    b_min: float = 0.0,
    rcond_min: float = 0.0,
    dc_rcond_min: float = 0.0,
    gain_max: float = math.inf,
) -> NDArray[np.float64]:
    """Validated safe-set vector ``[b_min, rcond_min, dc_rcond_min, gain_max]`` (the fields of
    :class:`SafeSetBounds`, in that order).

    Raises ``ValueError`` naming the setting for anything but a finite ``b_min >= 0``,
    ``0 <= rcond_min < 1``, ``0 <= dc_rcond_min < 1`` and ``gain_max > 0`` (``inf`` allowed):
    ``gain_max <= 0`` would reject every design and leave the loop open for ever.
    """
    bounds = SafeSetBounds(
        real_in(b_min, "b_min", 0.0, math.inf, hi_open=True),
        real_in(rcond_min, "rcond_min (a reciprocal condition)", 0.0, 1.0, hi_open=True),
        real_in(dc_rcond_min, "dc_rcond_min (a reciprocal condition)", 0.0, 1.0, hi_open=True),
        real_in(gain_max, "gain_max (inf: no limit)", 0.0, lo_open=True),
    )
    return np.array(bounds, dtype=np.float64)


@lane(returns_views=True)
def split_work(work, mm, n_mat):
    """The scratch as ``Ws`` ``(n_mat, mm, mm)`` and ``Vs`` ``(9, mm)`` views (every slot after
    that a cheap basic slice ``Ws[slot, :m, :m]``). A scratch shorter than that would corrupt
    the result, so it is an error. Inlined into its caller: a lane function compiled without
    NRT may return views only where numba inlines it."""
    if work.size < n_mat * mm * mm + N_VEC * mm:
        raise ValueError("work array too short: see work_size(n) / solve_work_size(n)")
    return view3d(work, 0, n_mat, mm, mm), view2d(work, n_mat * mm * mm, N_VEC, mm)


@lane(inline=True)
def controllability(A, b, Ws, Vs):
    """Invert the column-normalised controllability matrix ``Ctrb / norms``.

    Leaves ``Cn^{-1}`` in matrix slot ``MAT.m2`` and the column norms in vector slot ``VEC.v0``;
    returns the reciprocal 1-norm condition of ``Cn`` (0.0 when singular or non-finite).
    """
    m = A.shape[0]
    C = Ws[MAT.m0, :m, :m]
    T = Ws[MAT.m1, :m, :m]
    Cinv = Ws[MAT.m2, :m, :m]
    norms = Vs[VEC.v0, :m]
    v = Vs[VEC.v1, :m]
    w = Vs[VEC.v2, :m]
    for i in range(m):
        v[i] = b[i]
    for k in range(m):
        s = 0.0
        for i in range(m):
            C[i, k] = v[i]
            s += v[i] * v[i]
        norms[k] = math.sqrt(s)
        matvec(A, v, w)
        for i in range(m):
            v[i] = w[i]
    for k in range(m):
        if not (norms[k] > 0.0 and math.isfinite(norms[k])):
            return 0.0
    for i in range(m):
        for k in range(m):
            C[i, k] /= norms[k]
            T[i, k] = C[i, k]
    if not invert(T, Cinv):
        return 0.0
    rcond = 1.0 / (norm1(C) * norm1(Cinv))
    if not math.isfinite(rcond):
        return 0.0
    return rcond


@lane(inline=True)
def _steady_state(A, b, x_ss, Ws):
    n = A.shape[0]
    M = Ws[MAT.m0, : n + 1, : n + 1]
    Minv = Ws[MAT.m1, : n + 1, : n + 1]
    T = Ws[MAT.m2, : n + 1, : n + 1]
    for i in range(n + 1):
        for j in range(n + 1):
            M[i, j] = 0.0
    for i in range(n):
        for j in range(n):
            M[i, j] = A[i, j] - (1.0 if i == j else 0.0)
        M[i, n] = b[i]
    M[n, 0] = 1.0
    for i in range(n + 1):
        for j in range(n + 1):
            T[i, j] = M[i, j]
    if not invert(T, Minv) or not all_finite(Minv):
        for i in range(n):
            x_ss[i] = 0.0
        return 0.0, 0.0
    for i in range(n):
        x_ss[i] = Minv[i, n]
    rcond = 1.0 / (norm1(M) * norm1(Minv))
    return Minv[n, n], rcond


@lane(entry=True)
def steady_state(A, b, x_ss, work):
    """Steady state of ``x = A x + b u``, ``y = x_1 = 1``: writes ``x_ss``, returns
    ``(u_ss, rcond)`` from the Rosenbrock system ``[[A - I, b], [c, 0]] [x_ss; u_ss] = [0; 1]``
    (regular exactly when the model has no zero at ``z = 1``; works with an integrator in ``A``).
    ``rcond = 0``: singular (``x_ss = 0``, ``u_ss = 0``)."""
    mm = A.shape[0] + 1
    Ws, _ = split_work(work, mm, N_MAT)
    return _steady_state(A, b, x_ss, Ws)


@lane(inline=True)
def _prepare(theta, form, integral, safe, Ws, Vs):
    """The safe-set tests every design shares, in order (finite, ``b_min``, controllability);
    builds ``A``, ``b`` and ``(A_aug, b_aug)`` in the work and leaves ``Ctrb^{-1}`` there.
    Returns ``(status, rcond)``."""
    n = theta.size // 2
    if not all_finite(theta):
        return NONFINITE, 0.0
    bounds = safe_bounds(safe)
    bmax = 0.0
    for i in range(n):
        bmax = max(bmax, abs(theta[n + i]))
    if bmax < bounds.b_min:
        return B_SMALL, 0.0
    m = n + (1 if integral else 0)
    A = Ws[MAT.A, :n, :n]
    Ad = Ws[MAT.A_aug, :m, :m]
    b = Vs[VEC.b, :n]
    bd = Vs[VEC.b_aug, :m]
    model_matrices(theta, form, A, b)
    augment_integral(A, b, integral, Ad, bd)
    rcond = controllability(Ad, bd, Ws, Vs)
    if not rcond > max(bounds.rcond_min, RCOND_FLOOR):
        return UNCONTROLLABLE, rcond
    return OK, rcond


@lane(returns_views=True)
def design_start(theta, form, integral, safe, work, n_mat):
    """The start every design shares: the scratch split into ``n_mat`` matrix slots
    (:func:`split_work`), the model of ``theta`` built and the safe-set tests passed in order
    (finite, ``b_min``, controllability; ``Ctrb^{-1}`` left in the scratch).

    Returns ``(status, rcond, Ws, Vs, A_aug, b_aug, K)``: the (integral-augmented) model and
    the slot of the gain, each of size ``m = n + integral``; the design goes on only when
    ``status == OK``.
    """
    Ws, Vs = split_work(work, theta.size // 2 + 1, n_mat)
    status, rcond = _prepare(theta, form, integral, safe, Ws, Vs)
    m = theta.size // 2 + (1 if integral else 0)
    return status, rcond, Ws, Vs, Ws[MAT.A_aug, :m, :m], Vs[VEC.b_aug, :m], Vs[VEC.K, :m]


@lane(inline=True)
def finish(theta, integral, feedforward, safe, K, rcond, gain, Ws, Vs):
    """Feed-forward from the steady state, the gain bound, and the commit of ``gain``."""
    n = theta.size // 2
    bounds = safe_bounds(safe)
    A = Ws[MAT.A, :n, :n]
    b = Vs[VEC.b, :n]
    x_ss = Vs[VEC.x_ss, :n]
    N = 0.0
    if feedforward:
        u_ss, dc_rcond = _steady_state(A, b, x_ss, Ws)
        if not dc_rcond >= max(bounds.dc_rcond_min, DC_RCOND_FLOOR):
            return DC_SINGULAR
        N = u_ss
        for i in range(n):
            N += K[i] * x_ss[i]
    m = n + (1 if integral else 0)
    kmax = abs(N)
    for i in range(m):
        if abs(K[i]) > kmax or not math.isfinite(K[i]):
            kmax = abs(K[i]) if math.isfinite(K[i]) else math.inf
    if not (kmax <= bounds.gain_max and math.isfinite(N)):
        return GAIN_LARGE
    for i in range(n):
        gain[i] = K[i]
    gain[n] = K[n] if integral else 0.0
    gain[n + 1] = N
    gain[n + 2] = rcond
    return OK
