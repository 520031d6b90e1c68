"""The canonical-form model of an estimate ``theta = [a; b]``: its one compiled home.

``theta = [a_1..a_n, b_1..b_n]`` of a canonical form (Ding & Ma 2014) with ``c = [1, 0, ..., 0]``:

* observer form (``form =`` :data:`stcgym.envs.dynamics.OBSERVER`), eq. (1)/(47): ``A`` has
  the first column ``-a`` and ones on the superdiagonal;
* observability form (:data:`~stcgym.envs.dynamics.OBSERVABILITY`), eq. (146): ones on the
  superdiagonal and the last row ``[-a_n, ..., -a_1]``;

and ``b`` is ``theta[n:]`` in both ((48)/(147)). The integral-augmented model of the tracking
error integral ``xi(t+1) = xi(t) + r(t) - y(t)`` is

    A_aug = [[A, 0], [-c, 1]],  b_aug = [b; 0]    (m = n + 1 states),

and ``det(zI - A_aug) = det(zI - A) (z - 1)`` (block triangular). The numpy faces are
:func:`stcgym.envs.canonical.companion_A` and
:func:`stcgym.adaptive.control.placement.augment_integral`.
"""

from __future__ import annotations

from numpy.typing import NDArray

from stcgym.envs.dynamics import OBSERVABILITY
from stcgym.lanes.compiled import lane, lanes
from stcgym.lanes.linalg import copy_matrix, copy_vector

__all__ = [
    "augment_integral",
    "augmented_characteristic",
    "companion_into",
    "model_matrices",
    "model_matrices_lanes",
]


@lane(inline=True)
def companion_into(theta: NDArray, n: int, observability: bool, A: NDArray) -> None:
    """Write ``A_hat(t)`` of ``theta_hat(t)`` into ``A`` (n, n); see the module docstring."""
    for i in range(n):
        for j in range(n):
            A[i, j] = 1.0 if j == i + 1 else 0.0
    if observability:
        for j in range(n):
            A[n - 1, j] = -theta[n - 1 - j]
    else:
        for i in range(n):
            A[i, 0] = -theta[i]


@lane(inline=True, entry=True)
def model_matrices(theta, form, A, b):
    """Write the canonical-form ``A`` (``n x n``) and ``b`` of ``theta = [a; b]``."""
    n = theta.size // 2
    companion_into(theta, n, form == OBSERVABILITY, A)
    for i in range(n):
        b[i] = theta[n + i]


@lane(inline=True, entry=True)
def augment_integral(A, b, integral, Ad, bd):
    """``(A_aug, b_aug)`` of the integral state ``xi(t+1) = xi(t) + r(t) - c x(t)`` (or a copy)."""
    n = A.shape[0]
    copy_matrix(A, Ad)  # the top-left n x n block
    copy_vector(b, bd)
    if integral:
        for j in range(n + 1):
            Ad[n, j] = 0.0
            Ad[j, n] = 0.0
        Ad[n, 0] = -1.0
        Ad[n, n] = 1.0
        bd[n] = 0.0


@lane(inline=True)
def augmented_characteristic(theta, integral, out):
    """``[c_1..c_m]`` of ``det(zI - A_aug) = (z^n + a_1 z^{n-1} + ... + a_n)(z - 1)`` (both
    canonical forms: ``A_aug`` is block triangular), or ``a`` itself without integral action."""
    n = theta.size // 2
    if not integral:
        copy_vector(theta[:n], out)
        return
    prev = 1.0
    for k in range(n):
        out[k] = theta[k] - prev
        prev = theta[k]
    out[n] = -prev


@lanes(min_lanes=1 << 12)  # a few multiply-adds a lane
def model_matrices_lanes(thetas, form, A, b, first, last):
    """:func:`model_matrices` for every lane: ``A`` ``(B, n, n)``, ``b`` ``(B, n)``."""
    for i in range(first, last):
        model_matrices(thetas[i], form, A[i], b[i])
