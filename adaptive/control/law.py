"""The tracking law ``u = sat(N r - K_x x - k_i xi)`` with anti-windup, as a lane function.

:func:`track` is a pure function of the law state, the integrator ``xi``: it returns the input,
``xi(t+1)``, whether the input saturated and the input before saturation. ``gain`` is the
:class:`.safe_set.Gain` of the lanes (``K_x``, ``k_i``, ``N``), ``lane_i`` the one to read;
whether a design has been accepted yet (``has_gain``) is the caller's, kept beside it.
"""

from __future__ import annotations

import math

from stcgym.lanes.compiled import lane

__all__ = ["track"]


@lane(inline=True)
def track(gain, lane_i, has_gain, xi, x, y, r, excitation, action_bound, integral, anti_windup):
    """``u(t) = sat(-K_x x(t) - k_i xi(t) + N r(t) + e(t))``; returns
    ``(u(t), xi(t+1), saturated, u_unsat)``.

    ``xi(t+1) = xi(t) + r(t) - y(t)`` (integral of the measured tracking error), frozen while
    the input is saturated and the error would drive it further into saturation (conditional
    integration: ``d u / d xi = -k_i``). Without a gain yet (``has_gain`` false) only the
    excitation is applied and ``xi`` stays. ``action_bound = inf`` means no saturation.
    """
    n = x.size
    K_x = gain.K_x[lane_i]
    k_i = gain.k_i[lane_i]
    if has_gain:
        u = gain.N[lane_i] * r + excitation - k_i * xi
        for i in range(n):
            u -= K_x[i] * x[i]
    else:
        u = excitation
    saturated = abs(u) > action_bound
    u_sat = math.copysign(action_bound, u) if saturated else u
    xi_next = xi
    if integral and has_gain:
        err = r - y
        if not (anti_windup and saturated and (-k_i * err) * u > 0.0):
            xi_next = xi + err
    return u_sat, xi_next, saturated, u
