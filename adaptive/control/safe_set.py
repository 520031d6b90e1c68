"""The safe set every certainty-equivalence design passes, and the gain it writes.

Shared by pole placement (:mod:`.placement`) and the LQ designs (:mod:`.lq`): the tests
of the safe set in order, the accepted design (:class:`Gain`: ``K_x``, ``k_i``, ``N``,
``rcond``), written **only on success** (a rejected model keeps the last good gain), and the
designs' scratch
(:data:`DesignWork`: named fields, one row a lane, shapes in :func:`design_shapes`).

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
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from stcgym.adaptive.kernels.canonical import augment_integral, model_matrices
from stcgym.envs.dynamics import matvec
from stcgym.lanes.compiled import fields_of, lane, lane_state, make_work
from stcgym.lanes.linalg import all_finite, copy_matrix, copy_vector, invert, norm1
from stcgym.lanes.validation import real_in

__all__ = [
    "STATUS_NAMES",
    "ControllabilityWork",
    "DesignConfig",
    "DesignWork",
    "Gain",
    "ModelWork",
    "SafeSetBounds",
    "SteadyStateWork",
    "controllability",
    "design_shapes",
    "design_start",
    "design_work",
    "feedback_gain",
    "finish",
    "gain_shapes",
    "make_gain",
    "safe_bounds",
    "safe_set",
    "steady_state",
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


class Gain(NamedTuple):
    """The design in force on every lane, one row a lane (shapes in :func:`gain_shapes`): what
    the tracking law ``u = sat(N r - K_x x - k_i xi)`` applies (:mod:`.law`), written by
    :func:`finish` only when the safe set accepts a design. Whether any design has been
    accepted yet is the caller's to keep."""

    K_x: NDArray  # state gain (n,)
    k_i: NDArray  # integral gain (0 without integral action)
    N: NDArray  # reference feed-forward (0 when off)
    rcond: NDArray  # reciprocal condition number of the design's controllability matrix


def gain_shapes(n: int) -> dict[str, tuple[int, ...]]:
    """The shapes of one lane's :class:`Gain` fields for order ``n``."""
    return {"K_x": (int(n),), "k_i": (), "N": (), "rcond": ()}


def make_gain(n: int, num_lanes: int) -> Gain:
    """A zeroed :class:`Gain` of ``num_lanes`` lanes for order ``n``."""
    return lane_state(Gain, gain_shapes(n), num_lanes)


def feedback_gain(gain: Gain, integral: bool) -> NDArray:
    """The state-feedback gain of every lane, ``[K_x, k_i]`` with integral action and ``K_x``
    without: ``(lanes, n + integral)`` (a view of ``gain.K_x`` without integral action)."""
    return np.column_stack((gain.K_x, gain.k_i)) if integral else gain.K_x


class ModelWork(NamedTuple):
    """The model of ``theta``, the candidate gain and its steady state (every design)."""

    A: NDArray  # A_hat (n, n)
    b: NDArray  # b_hat (n,)
    A_aug: NDArray  # the (integral-augmented) model (m, m)
    b_aug: NDArray  # (m,)
    K: NDArray  # the candidate gain [K_x, k_i] (m,)
    x_ss: NDArray  # the steady state for the output 1 (n,)


class ControllabilityWork(NamedTuple):
    """The controllability test (:func:`controllability`) and Ackermann's formula."""

    C: NDArray  # the column-normalised controllability matrix Ctrb / norms (m, m)
    C_lu: NDArray  # its copy, reduced by the inversion (m, m)
    Cinv: NDArray  # C^{-1} (m, m)
    norms: NDArray  # the column norms of Ctrb (m,)
    v: NDArray  # a vector iterate: A^k b for Ctrb, e_m^T C^{-1} A^k for Ackermann (m,)
    v_next: NDArray  # its successor (m,)


class SteadyStateWork(NamedTuple):
    """The steady-state (Rosenbrock) system of the feed-forward (:func:`steady_state`)."""

    M: NDArray  # [[A - I, b], [c, 0]] (n + 1, n + 1)
    M_lu: NDArray  # its copy, reduced by the inversion (n + 1, n + 1)
    Minv: NDArray  # M^{-1} (n + 1, n + 1)


#: The scratch of every design on the model of ``theta`` (all that pole placement needs): the
#: fields of :class:`ModelWork`, :class:`ControllabilityWork` and :class:`SteadyStateWork`, one
#: row a lane (``w.K[lane]``), shapes in :func:`design_shapes`.
DesignWork = NamedTuple(  # type: ignore[misc]
    "DesignWork", fields_of(ModelWork, ControllabilityWork, SteadyStateWork)
)


def design_shapes(n: int, integral: bool) -> dict[str, tuple[int, ...]]:
    """The shapes of one lane's :data:`DesignWork` fields for order ``n`` (``m = n +
    integral``): the one place they are declared."""
    n = int(n)
    m = n + int(bool(integral))
    return {
        "A": (n, n),
        "b": (n,),
        **dict.fromkeys(("A_aug", "C", "C_lu", "Cinv"), (m, m)),
        **dict.fromkeys(("b_aug", "K", "norms", "v", "v_next"), (m,)),
        "x_ss": (n,),
        **dict.fromkeys(("M", "M_lu", "Minv"), (n + 1, n + 1)),
    }


def design_work(n: int, integral: bool, num_lanes: int = 1) -> Any:
    """A :data:`DesignWork` of ``num_lanes`` lanes for order ``n``."""
    return make_work(DesignWork, design_shapes(n, integral), num_lanes)


class DesignConfig(NamedTuple):
    """The settings of a design on the model of ``theta`` (the self-tuning controller passes its
    own configuration, which has these fields)."""

    form: int  # the canonical form of theta (canonical.OBSERVER / OBSERVABILITY)
    integral: bool  # integral action: the design is on the augmented model (m = n + 1)
    feedforward: bool  # the reference feed-forward N
    safe: NDArray  # the safe set [b_min, rcond_min, dc_rcond_min, gain_max] (safe_set())
    char_poly: NDArray  # pole placement: the closed-loop characteristic polynomial (m,)


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
    like the other configuration vectors (``char_poly``, the LQ weights): one float64 array.
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


@lane(inline=True)
def controllability(A, b, w, lane_i):
    """Invert the column-normalised controllability matrix ``C = Ctrb / norms`` of ``(A, b)``
    (``m x m``): writes ``w.C``, ``w.Cinv = C^{-1}`` and the column norms ``w.norms`` of lane
    ``lane_i``; returns the reciprocal 1-norm condition of ``C`` (0.0 when singular or
    non-finite)."""
    m = A.shape[0]
    C = w.C[lane_i]
    C_lu = w.C_lu[lane_i]
    Cinv = w.Cinv[lane_i]
    norms = w.norms[lane_i]
    v = w.v[lane_i]
    Av = w.v_next[lane_i]
    copy_vector(b, v)
    for k in range(m):
        s = 0.0
        for i in range(m):
            C[i, k] = v[i]
            s += v[i] * v[i]
        norms[k] = math.sqrt(s)
        matvec(A, v, Av)
        copy_vector(Av, v)
    for k in range(m):
        if not (norms[k] > 0.0 and math.isfinite(norms[k])):
            return 0.0
    for i in range(m):
        for k in range(m):
            C[i, k] /= norms[k]
            C_lu[i, k] = C[i, k]
    if not invert(C_lu, Cinv):
        return 0.0
    rcond = 1.0 / (norm1(C) * norm1(Cinv))
    if not math.isfinite(rcond):
        return 0.0
    return rcond


@lane(inline=True)
def _steady_state(A, b, w, lane_i):
    n = A.shape[0]
    M = w.M[lane_i]
    Minv = w.Minv[lane_i]
    M_lu = w.M_lu[lane_i]
    x_ss = w.x_ss[lane_i]
    for i in range(n + 1):
        for j in range(n + 1):
            M[i, j] = 0.0
    for i in range(n):
        for j in range(n):
            M[i, j] = A[i, j] - (1.0 if i == j else 0.0)
        M[i, n] = b[i]
    M[n, 0] = 1.0
    copy_matrix(M, M_lu)
    if not invert(M_lu, Minv) or not all_finite(Minv):
        for i in range(n):
            x_ss[i] = 0.0
        return 0.0, 0.0
    for i in range(n):
        x_ss[i] = Minv[i, n]
    rcond = 1.0 / (norm1(M) * norm1(Minv))
    return Minv[n, n], rcond


@lane(entry=True)
def steady_state(A, b, w, lane_i):
    """Steady state of ``x = A x + b u``, ``y = x_1 = 1``: writes ``x_ss`` into ``w.x_ss[lane]``,
    returns ``(u_ss, rcond)`` from the Rosenbrock system ``[[A - I, b], [c, 0]] [x_ss; u_ss] =
    [0; 1]`` (regular exactly when the model has no zero at ``z = 1``; works with an integrator
    in ``A``). ``rcond = 0``: singular (``x_ss = 0``, ``u_ss = 0``). ``w``: the fields of
    :class:`SteadyStateWork` and ``x_ss`` (a :data:`DesignWork` of order ``n``)."""
    if w.M.shape[1] != A.shape[0] + 1:
        raise ValueError("steady_state: w is not the scratch of this order (design_work(n))")
    return _steady_state(A, b, w, lane_i)


@lane(inline=True)
def _prepare(theta, cfg, w, lane_i):
    """The safe-set tests every design shares, in order (finite, ``b_min``, controllability);
    builds ``A``, ``b`` and ``(A_aug, b_aug)`` in ``w`` and leaves ``C^{-1}`` there.
    Returns ``(status, rcond)``."""
    n = theta.size // 2
    if not all_finite(theta):
        return NONFINITE, 0.0
    bounds = safe_bounds(cfg.safe)
    bmax = 0.0
    for i in range(n):
        bmax = max(bmax, abs(theta[n + i]))
    if bmax < bounds.b_min:
        return B_SMALL, 0.0
    Ad = w.A_aug[lane_i]
    bd = w.b_aug[lane_i]
    A = w.A[lane_i]
    b = w.b[lane_i]
    model_matrices(theta, cfg.form, A, b)
    augment_integral(A, b, cfg.integral, Ad, bd)
    rcond = controllability(Ad, bd, w, lane_i)
    if not rcond > max(bounds.rcond_min, RCOND_FLOOR):
        return UNCONTROLLABLE, rcond
    return OK, rcond


@lane(inline=True)
def design_start(theta, cfg, w, lane_i):
    """The start every design shares (``cfg``: a :class:`DesignConfig`): the model of ``theta``
    built into lane ``lane_i`` of the scratch ``w`` (``w.A``, ``w.b``, the augmented ``w.A_aug``,
    ``w.b_aug`` of size ``m = n + integral``) and the safe-set tests passed in order (finite,
    ``b_min``, controllability; ``w.Cinv`` left for Ackermann's formula). Returns
    ``(status, rcond)``; the design goes on only when ``status == OK``. A scratch built for
    another order or integral action is an error."""
    n = theta.size // 2
    m = n + (1 if cfg.integral else 0)
    if w.A.shape[1] != n or w.A_aug.shape[1] != m:
        raise ValueError("design scratch of another order: build it with design_work(n, integral)")
    return _prepare(theta, cfg, w, lane_i)


@lane(inline=True)
def finish(theta, cfg, rcond, gain, w, lane_i):
    """Feed-forward from the steady state, the gain bound, and the commit: the candidate gain
    ``w.K[lane]`` (``[K_x, k_i]``), the feed-forward ``N`` and ``rcond`` become lane ``lane_i``
    of the :class:`Gain` ``gain``."""
    n = theta.size // 2
    bounds = safe_bounds(cfg.safe)
    K = w.K[lane_i]
    x_ss = w.x_ss[lane_i]
    N = 0.0
    if cfg.feedforward:
        u_ss, dc_rcond = _steady_state(w.A[lane_i], w.b[lane_i], w, lane_i)
        if not dc_rcond >= max(bounds.dc_rcond_min, DC_RCOND_FLOOR):
            return DC_SINGULAR
        N = u_ss
        for i in range(n):
            N += K[i] * x_ss[i]
    m = n + (1 if cfg.integral else 0)
    kmax = abs(N)
    for i in range(m):
        if abs(K[i]) > kmax or not math.isfinite(K[i]):
            kmax = abs(K[i]) if math.isfinite(K[i]) else math.inf
    if not (kmax <= bounds.gain_max and math.isfinite(N)):
        return GAIN_LARGE
    copy_vector(K[:n], gain.K_x[lane_i])
    gain.k_i[lane_i] = K[n] if cfg.integral else 0.0
    gain.N[lane_i] = N
    gain.rcond[lane_i] = rcond
    return OK
