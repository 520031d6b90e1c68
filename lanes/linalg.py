"""Small dense linear algebra and copies written out for lane functions (no BLAS, no LAPACK, no
allocation).

The matrices of a lane are a few rows wide (the order of a plant plus an integrator), where a
call into a library costs more than the arithmetic; see :mod:`stcgym.lanes.compiled`. All are
inlined into their callers. A whole-array assignment ``dst[:] = src`` inside a compiled lane
function may allocate a temporary for operands that could overlap, which lane functions
(compiled without numba's reference-counting runtime) must not do: :func:`copy_matrix` and
:func:`copy_vector` copy element by element instead. The plants' ``y = C x`` is
:func:`stcgym.envs.dynamics.matvec`.
"""

from __future__ import annotations

import math

from numpy.typing import NDArray

from stcgym.lanes.compiled import lane

__all__ = ["all_finite", "copy_matrix", "copy_vector", "invert", "matmul", "max_abs", "norm1"]


@lane(inline=True)
def all_finite(v):
    for i in range(v.size):
        if not math.isfinite(v.flat[i]):
            return False
    return True


@lane(inline=True)
def matmul(X, Y, out, trans_x=False, trans_y=False):
    """``out = op(X) @ op(Y)`` for small matrices, ``op`` the transpose when asked (``out``
    distinct from ``X`` and ``Y``; its shape is the product's)."""
    rows = out.shape[0]
    cols = out.shape[1]
    inner = X.shape[0] if trans_x else X.shape[1]
    for i in range(rows):
        for j in range(cols):
            s = 0.0
            for k in range(inner):
                s += (X[k, i] if trans_x else X[i, k]) * (Y[j, k] if trans_y else Y[k, j])
            out[i, j] = s


@lane(inline=True)
def norm1(M):
    """Largest absolute column sum."""
    m = M.shape[0]
    best = 0.0
    for j in range(m):
        s = 0.0
        for i in range(m):
            s += abs(M[i, j])
        if s > best or not math.isfinite(s):
            best = s
    return best


@lane(inline=True)
def max_abs(M):
    best = 0.0
    for i in range(M.size):
        v = abs(M.flat[i])
        if v > best or not math.isfinite(v):
            best = v
    return best


@lane(inline=True)
def invert(M, Minv):
    """Gauss-Jordan inverse with partial pivoting; ``M`` is destroyed. False if singular."""
    m = M.shape[0]
    for i in range(m):
        for j in range(m):
            Minv[i, j] = 1.0 if i == j else 0.0
    for col in range(m):
        piv = col
        best = abs(M[col, col])
        for i in range(col + 1, m):
            if abs(M[i, col]) > best:
                best = abs(M[i, col])
                piv = i
        if not (best > 0.0 and math.isfinite(best)):
            return False
        if piv != col:
            for j in range(m):
                tmp = M[col, j]
                M[col, j] = M[piv, j]
                M[piv, j] = tmp
                tmp = Minv[col, j]
                Minv[col, j] = Minv[piv, j]
                Minv[piv, j] = tmp
        inv_p = 1.0 / M[col, col]
        for j in range(m):
            M[col, j] *= inv_p
            Minv[col, j] *= inv_p
        for i in range(m):
            if i != col:
                f = M[i, col]
                if f != 0.0:
                    for j in range(m):
                        M[i, j] -= f * M[col, j]
                        Minv[i, j] -= f * Minv[col, j]
    return True


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
