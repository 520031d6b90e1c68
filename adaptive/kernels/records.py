"""Zero-cost 2-D views into a lane record.

``view2d(a, offset, rows, cols)`` is ``a[offset : offset + rows * cols].reshape((rows, cols))``:
the C-ordered matrix stored at ``offset`` of the contiguous 1-D array ``a``. Inside compiled
lane functions numba's ``reshape`` calls a run-time helper that recomputes strides (about
60 ns per call, several per estimator step, more than the arithmetic of a 2nd-order step), so
the compiled version builds the view directly from the data pointer (``numba.carray``). The
view has no owner of its own: it is valid while ``a`` is, which holds inside a lane function
(never return it). With ``NUMBA_DISABLE_JIT=1`` the plain ``reshape`` above runs.
"""

from __future__ import annotations

import numba
from numba import types
from numba.extending import intrinsic, overload
from numpy.typing import NDArray

__all__ = ["view2d"]


def view2d(a: NDArray, offset: int, rows: int, cols: int) -> NDArray:
    """The ``rows x cols`` C-ordered matrix stored at ``a[offset:]`` (a view)."""
    return a[offset : offset + rows * cols].reshape((rows, cols))


@intrinsic
def _element_pointer(typingctx, arr, offset):  # type: ignore[no-untyped-def]
    """Pointer to ``arr[offset]`` (contiguous 1-D ``arr``)."""
    sig = types.CPointer(arr.dtype)(arr, offset)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        return builder.gep(ary.data, [args[1]])

    return sig, codegen


@overload(view2d, inline="always")
def _view2d_compiled(a, offset, rows, cols):  # type: ignore[no-untyped-def]
    def impl(a, offset, rows, cols):  # type: ignore[no-untyped-def]
        return numba.carray(_element_pointer(a, offset), (rows, cols))

    return impl
