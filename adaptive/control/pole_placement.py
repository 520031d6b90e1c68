"""Pole placement by Ackermann's formula on the (integral-augmented) model: lane functions.

``place_design(theta, cfg, gain, w, lane_i) -> int``
    Ackermann pole placement of the ``m`` poles with monic characteristic polynomial
    ``z^m + char_poly[0] z^{m-1} + ... + char_poly[m-1]`` (``cfg.char_poly``, length ``m``) on
    the (augmented) model of ``theta``; ``N = u_ss + K_x x_ss`` from the steady state. ``cfg``:
    a :class:`.safe_set.DesignConfig` (form, integral action, feed-forward, safe set); ``w`` is
    a :data:`.safe_set.DesignWork` (:func:`.safe_set.design_work`), of which lane ``lane_i`` is
    used. Returns the status code of :mod:`.safe_set`; ``gain`` is written only on success.
``ackermann_gain(A, b, char_poly, K, w, lane_i) -> rcond``
    The same formula on a general pair (``rcond <= 0``: singular; ``K`` written only when
    ``rcond > 0``; ``w`` with the fields of :class:`.safe_set.ControllabilityWork`), used by
    the numpy helpers of :mod:`stcgym.adaptive.control.placement`.
``place_design_lanes(thetas, cfg, gains, status, w)``
    The batch loop (``w`` a :data:`.safe_set.DesignWork` with a row a lane).

:data:`COMPILED_DESIGN` is the self-tuning controller's pole placement (its compiled argument
:class:`Placement` is empty: the poles are the controller's ``cfg.char_poly``; it keeps no lane
state).
"""

from __future__ import annotations

from typing import NamedTuple

from stcgym.adaptive.control.safe_set import (
    OK,
    controllability,
    design_start,
    design_work,
    finish,
)
from stcgym.adaptive.variants import CompiledDesign
from stcgym.lanes.compiled import lane, lanes

__all__ = [
    "COMPILED_DESIGN",
    "Placement",
    "ackermann_gain",
    "place_design",
    "place_design_lanes",
]


@lane(inline=True)
def _ackermann_from_ctrb(A, char_poly, K, w, lane_i):
    """Ackermann's formula ``K = e_m^T Ctrb^{-1} phi_d(A)`` (Ackermann 1972; Franklin, Powell &
    Workman, *Digital Control of Dynamic Systems*, 3rd ed.) with ``phi_d(z) = z^m + c_1 z^{m-1}
    + ... + c_m`` (``c = char_poly``), as ``K = sum_k c_{m-k} v A^k`` with ``v`` the last row of
    ``Ctrb^{-1}`` (``phi_d(A)`` never formed: ``m`` row-vector/matrix products), from the
    inverse ``w.Cinv`` and column norms ``w.norms`` that :func:`.safe_set.controllability`
    left in lane ``lane_i``."""
    m = A.shape[0]
    Cinv = w.Cinv[lane_i]
    norms = w.norms[lane_i]
    v = w.v[lane_i]
    vA = w.v_next[lane_i]
    for j in range(m):  # v = e_m^T Ctrb^{-1} (the columns of Ctrb were scaled by norms)
        v[j] = Cinv[m - 1, j] / norms[m - 1]
        K[j] = char_poly[m - 1] * v[j]  # c_m v A^0
    for k in range(1, m + 1):  # + c_{m-k} v A^k, k = 1..m (c_0 = 1): K = v phi_d(A)
        coef = char_poly[m - 1 - k] if k < m else 1.0
        for j in range(m):
            acc = 0.0
            for r in range(m):
                acc += v[r] * A[r, j]
            vA[j] = acc
        for j in range(m):
            v[j] = vA[j]
            K[j] += coef * v[j]


@lane(entry=True)
def ackermann_gain(A, b, char_poly, K, w, lane_i):
    """Ackermann gain of a general pair ``(A, b)`` (``m x m``; ``w`` with the fields of
    :class:`.safe_set.ControllabilityWork` for order ``m``, lane ``lane_i`` used).

    ``eig(A - b K)`` are the roots of ``z^m + char_poly[0] z^{m-1} + ... + char_poly[m-1]``.
    Returns the reciprocal 1-norm condition of the column-normalised controllability matrix
    (``<= 0``: singular or non-finite, ``K`` untouched).
    """
    if w.C.shape[1] != A.shape[0]:
        raise ValueError("ackermann_gain: w is not the scratch of this order")
    rcond = controllability(A, b, w, lane_i)  # Ctrb = [b, A b, ..., A^{m-1} b] and its inverse
    if rcond > 0.0:
        _ackermann_from_ctrb(A, char_poly, K, w, lane_i)
    return rcond


@lane(entry=True, inline=True)
def place_design(theta, cfg, gain, w, lane_i):
    """Pole placement on the (augmented) model of ``theta``; see the module docstring.

    Returns the status code; lane ``lane_i`` of ``gain`` (a :class:`.safe_set.Gain`) is written
    only when it is ``OK`` (0).
    """
    status, rcond = design_start(theta, cfg, w, lane_i)  # model, augmentation, Ctrb^{-1}
    if status != OK:
        return status
    _ackermann_from_ctrb(w.A_aug[lane_i], cfg.char_poly, w.K[lane_i], w, lane_i)
    return finish(theta, cfg, rcond, gain, w, lane_i)  # safe set, steady state, N


@lanes(min_lanes=16)  # one design a lane
def place_design_lanes(thetas, cfg, gains, status, w, first, last):
    """:func:`place_design` for every lane (``thetas`` ``(B, 2n)``, ``gains`` a
    :class:`.safe_set.Gain` of ``B`` lanes, ``status`` ``(B,)`` int64, ``w`` a
    :data:`.safe_set.DesignWork` of ``B`` lanes)."""
    for i in range(first, last):
        status[i] = place_design(thetas[i], cfg, gains, w, i)


class Placement(NamedTuple):
    """The compiled argument of the controller's pole placement (none: the poles are the
    controller's ``cfg.char_poly``); also its lane state (it keeps none)."""


@lane(inline=True)
def controller_design(design, theta, cfg, state, gain, w, lane_i):
    """Step 3 of the self-tuning controller: :func:`place_design` (``design``, ``state``:
    empty :class:`Placement`)."""
    return place_design(theta, cfg, gain, w, lane_i)


COMPILED_DESIGN = CompiledDesign(
    argument=Placement,
    step=controller_design,
    make_argument=lambda n, law: Placement(),
    make_state=lambda n, law, num_lanes: Placement(),
    make_work=design_work,
)
