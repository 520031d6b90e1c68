"""How the bench's report writes a number in a table cell."""

from __future__ import annotations

import math

from stcgym.agents.evaluation.statistics import Estimate, number_text

__all__ = ["number", "percent", "thousands"]


def number(x: float | None, digits: int = 3) -> str:
    """``x`` to ``digits`` significant digits; ``-`` for a missing value, ``inf`` / ``-inf``,
    and the exponent form from ``10 ** (digits + 2)`` on (a diverged cost)."""
    if x is not None and math.isfinite(x) and abs(x) >= 10 ** (digits + 2):
        return f"{x:.2e}"
    return number_text(x, digits)


def thousands(x: float) -> str:
    """A count of steps: ``"2.3k"`` from a thousand on, ``"1.2M"`` from a million on."""
    if x >= 999_500:  # what would round to 1e+03k
        return f"{x / 1e6:.3g}M"
    return f"{x / 1000:.3g}k" if x >= 1000 else f"{x:.0f}"


def percent(e: Estimate) -> str:
    """A share with its interval, in percent: ``"3.2 % [1.2, 5.7]"``."""
    return f"{100 * e.value:.1f} % [{100 * e.low:.1f}, {100 * e.high:.1f}]"
