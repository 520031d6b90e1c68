"""Zero-cost 2-D views into a lane record.

``view2d(a, offset, rows, cols)`` is ``a[offset : offset + rows * cols].reshape((rows, cols))``:
the C-ordered matrix stored at ``offset`` of the contiguous 1-D array ``a``. Inside compiled
lane functions numba's ``reshape`` calls a run-time helper that recomputes strides (about
60 ns per call, several per estimator step, more than the arithmetic of a 2nd-order step), so
the compiled version fills in the array structure directly (data pointer into ``a``, shape,
strides, ``a``'s memory block as owner). With ``NUMBA_DISABLE_JIT=1`` the plain ``reshape``
above runs.
"""

from __future__ import annotations

from numba import types
from numba.core.imputils import impl_ret_borrowed
from numba.extending import lower_builtin, type_callable
from numba.np.arrayobj import populate_array
from numpy.typing import NDArray

from stcgym.envs.compiled import lane

__all__ = ["copy_matrix", "copy_vector", "view2d", "view3d"]


def view2d(a: NDArray, offset: int, rows: int, cols: int) -> NDArray:
    """The ``rows x cols`` C-ordered matrix stored at ``a[offset:]`` (a view)."""
    return a[offset : offset + rows * cols].reshape((rows, cols))


def view3d(a: NDArray, offset: int, count: int, rows: int, cols: int) -> NDArray:
    """``count`` C-ordered ``rows x cols`` matrices stored one after the other at ``a[offset:]``
    (a ``(count, rows, cols)`` view)."""
    return a[offset : offset + count * rows * cols].reshape((count, rows, cols))


def _register(fn, ndim):  # type: ignore[no-untyped-def]
    """Compile ``fn(a, offset, *shape)`` (``ndim`` sizes) as an in-place lowered view."""

    @type_callable(fn)
    def _type(context):  # type: ignore[no-untyped-def]
        def view_type(a):  # type: ignore[no-untyped-def]
            if isinstance(a, types.Array) and a.ndim == 1 and a.layout == "C":
                return types.Array(a.dtype, ndim, "C")
            return None

        def typer2(a, offset, rows, cols):  # type: ignore[no-untyped-def]
            return view_type(a)

        def typer3(a, offset, count, rows, cols):  # type: ignore[no-untyped-def]
            return view_type(a)

        return typer2 if ndim == 2 else typer3

    @lower_builtin(fn, types.Array, *([types.Integer] * (ndim + 1)))
    def _lower(context, builder, sig, args):  # type: ignore[no-untyped-def]
        """The array structure filled in directly: data pointer ``&a[offset]``, shape, C
        strides, ``a``'s memory block as owner (no call, no run-time helper)."""
        src = context.make_array(sig.args[0])(context, builder, args[0])
        out = context.make_array(sig.return_type)(context, builder)
        pairs = zip(args[1:], sig.args[1:], strict=True)
        offset, *shape = (context.cast(builder, v, t, types.intp) for v, t in pairs)
        stride = context.get_constant(types.intp, context.get_abi_sizeof(src.data.type.pointee))
        strides = [stride]
        for size in shape[:0:-1]:
            strides.insert(0, builder.mul(strides[0], size))
        populate_array(
            out,
            data=builder.gep(src.data, [offset]),
            shape=shape,
            strides=strides,
            itemsize=stride,
            meminfo=src.meminfo,
            parent=None,
        )
        # a new reference to the owner's block when the caller counts references (NRT on);
        # lane functions compile without NRT and the view then costs nothing at all
        return impl_ret_borrowed(context, builder, sig.return_type, out._getvalue())


_register(view2d, 2)
_register(view3d, 3)


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
