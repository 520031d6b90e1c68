"""The tracking law ``u = sat(N r - K_x x - k_i xi)`` with anti-windup, as a lane function.

The law state is a 3-float record (:class:`LawState`: the integrator ``xi``, the saturation
flag of the last step, the unsaturated input); ``gain`` is the gain record of
:mod:`.safe_set` (``[K_x (n), k_i, N, has_gain, rcond]``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

from stcgym.envs.compiled import lane

__all__ = ["LAW", "LAW_SIZE", "LawState", "track"]


class LawState(NamedTuple):
    """Fields of the law state (offsets in its 3-float record)."""

    xi: int  # integral of the tracking error
    saturated: int  # 1.0 when the last input was saturated
    u_unsat: int  # the last input before saturation


#: Offsets of the law state's fields (``law[LAW.xi]``).
LAW = LawState(*range(len(LawState._fields)))
LAW_SIZE = len(LawState._fields)


@lane(inline=True)
def track(gain, law, x, y, r, excitation, action_bound, integral, anti_windup):
    """``u(t) = sat(-K_x x(t) - k_i xi(t) + N r(t) + e(t))``; advances ``xi`` to ``xi(t+1)``.

    ``xi(t+1) = xi(t) + r(t) - y(t)`` (integral of the measured tracking error), frozen while
    the input is saturated and the error would drive it further into saturation (conditional
    integration: ``d u / d xi = -k_i``). Without a gain yet (``gain[n + 2] == 0``) only the
    excitation is applied and ``xi`` stays. ``action_bound = inf`` means no saturation.
    """
    n = x.size
    has_gain = gain[n + 2] > 0.0
    xi = law[LAW.xi]
    if has_gain:
        u = gain[n + 1] * r + excitation - gain[n] * xi
        for i in range(n):
            u -= gain[i] * x[i]
    else:
        u = excitation
    law[LAW.u_unsat] = u
    saturated = abs(u) > action_bound
    u_sat = math.copysign(action_bound, u) if saturated else u
    law[LAW.saturated] = 1.0 if saturated else 0.0
    if integral and has_gain:
        err = r - y
        if not (anti_windup and saturated and (-gain[n] * err) * u > 0.0):
            law[LAW.xi] = xi + err
    return u_sat
