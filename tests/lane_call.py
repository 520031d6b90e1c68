"""Calling a lane helper from a test.

Lane helpers (``@lane`` without ``entry=True``, :func:`stcgym.lanes.compiled.lane`) are compiled
without numba's CPython wrapper, so Python cannot call them directly. A test reaches one the way
the lane functions do: through a compiled caller, here a one-line ``njit`` function per helper.
"""

from __future__ import annotations

from functools import cache
from typing import Any

import numba


@cache
def _caller(helper: Any) -> Any:
    @numba.njit
    def call(*args):  # type: ignore[no-untyped-def]
        return helper(*args)

    return call


def call(helper: Any, *args: Any) -> Any:
    """``helper(*args)`` through a compiled caller (the helper's own compiled code runs)."""
    return _caller(helper)(*args)
