"""Zero-cost 2-D views into a lane record.

``view2d(a, offset, rows, cols)`` is ``a[offset : offset + rows * cols].reshape((rows, cols))``:
the C-ordered matrix stored at ``offset`` of the contiguous 1-D array ``a``. Inside compiled
lane functions numba's ``reshape`` calls a run-time helper that recomputes strides (about
60 ns per call, several per estimator step, more than the arithmetic of a 2nd-order step), so
the compiled version fills in the array structure directly
(:func:`stcgym.envs.numba_internals.register_view`). With ``NUMBA_DISABLE_JIT=1`` the plain
``reshape`` above runs.
"""

from __future__ import annotations

from numpy.typing import NDArray

from stcgym.envs.compiled import lane
from stcgym.envs.numba_internals import register_view

__all__ = ["copy_matrix", "copy_vector", "view2d", "view3d"]


def view2d(a: NDArray, offset: int, rows: int, cols: int) -> NDArray:
    """The ``rows x cols`` C-ordered matrix stored at ``a[offset:]`` (a view)."""
    return a[offset : offset + rows * cols].reshape((rows, cols))


def view3d(a: NDArray, offset: int, count: int, rows: int, cols: int) -> NDArray:
    """``count`` C-ordered ``rows x cols`` matrices stored one after the other at ``a[offset:]``
    (a ``(count, rows, cols)`` view)."""
    return a[offset : offset + count * rows * cols].reshape((count, rows, cols))


register_view(view2d, 2)
register_view(view3d, 3)


@lane(inline=True)
def copy_matrix(src: NDArray, dst: NDArray) -> None:
    """``dst[:, :] = src`` written out (a whole-array assignment may allocate a temporary for
    overlapping operands, which lane functions must not do)."""
    for i in range(src.shape[0]):
        for j in range(src.shape[1]):
            dst[i, j] = src[i, j]


@lane(inline=True)
def copy_vector(src: NDArray, dst: NDArray) -> None:
    """``dst[:] = src`` written out (see :func:`copy_matrix`)."""
    for i in range(src.shape[0]):
        dst[i] = src[i]
