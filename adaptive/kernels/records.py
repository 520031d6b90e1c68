"""Copies written out for lane functions.

A whole-array assignment ``dst[:] = src`` inside a compiled lane function may allocate a
temporary for operands that could overlap, which lane functions (compiled without numba's
reference-counting runtime, :func:`stcgym.lanes.compiled.lane`) must not do: these loops copy
element by element instead.
"""

from __future__ import annotations

from numpy.typing import NDArray

from stcgym.lanes.compiled import lane

__all__ = ["copy_matrix", "copy_vector"]


@lane(inline=True)
def copy_matrix(src: NDArray, dst: NDArray) -> None:
    """``dst[:, :] = src`` written out."""
    for i in range(src.shape[0]):
        for j in range(src.shape[1]):
            dst[i, j] = src[i, j]


@lane(inline=True)
def copy_vector(src: NDArray, dst: NDArray) -> None:
    """``dst[:] = src`` written out."""
    for i in range(src.shape[0]):
        dst[i] = src[i]
