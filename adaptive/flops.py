"""Computational cost (flops = multiplications + additions) of the seed paper's algorithms.

The formulas are those of tables 1-8 of Ding & Ma 2014 (``shared/docs/algorithms.md`` §7):
per step for the recursive algorithms, per iteration for the iterative ones. ``n`` is the plant
order, ``p`` the innovation length and ``L`` the batch length.
"""

from __future__ import annotations


def _positive(**values: int) -> None:
    for name, v in values.items():
        if int(v) != v or v < 1:
            raise ValueError(f"{name} must be a positive integer, got {v!r}")


def o_rls(n: int) -> int:
    """O-RLS per step, table 1: ``16n^2 + 16n - 1``."""
    _positive(n=n)
    return 16 * n**2 + 16 * n - 1


def kf_mils(n: int, p: int) -> int:
    """KF-MILS per step, table 2:
    ``16n^2 p + 8n p^2 + 4n p + 2p^3 - 2p^2 + p + 4n^2 + 10n - 1``."""
    _positive(n=n, p=p)
    return (
        16 * n**2 * p + 8 * n * p**2 + 4 * n * p + 2 * p**3 - 2 * p**2 + p + 4 * n**2 + 10 * n - 1
    )


def d_rls(n: int) -> int:
    """D-RLS per step, table 3: ``8n^2 + 12n``."""
    _positive(n=n)
    return 8 * n**2 + 12 * n


def d_mils(n: int, p: int) -> int:
    """D-MILS per step, table 4: ``8n^2 p + 8n p^2 + 4p^3 + 4n p - 4p^2``."""
    _positive(n=n, p=p)
    return 8 * n**2 * p + 8 * n * p**2 + 4 * p**3 + 4 * n * p - 4 * p**2


def lsi(n: int, L: int) -> int:
    """LSI per iteration, table 5: ``16n^3 + 8n^2 L + 4n L - 4n``."""
    _positive(n=n, L=L)
    return 16 * n**3 + 8 * n**2 * L + 4 * n * L - 4 * n


def d_lsi(n: int, L: int) -> int:
    """D-LSI per iteration, table 6: ``4n^3 + 4n^2 L + 8n L - 2n^2 - 4n``."""
    _positive(n=n, L=L)
    return 4 * n**3 + 4 * n**2 * L + 8 * n * L - 2 * n**2 - 4 * n


def o_lsi(n: int, L: int) -> int:
    """O-LSI per iteration, table 7: ``16n^3 + 8n^2 L + 8n L - 4n - L``."""
    _positive(n=n, L=L)
    return 16 * n**3 + 8 * n**2 * L + 8 * n * L - 4 * n - L


def kf_d_lsi(n: int, L: int) -> int:
    """KF-D-LSI per iteration, table 8: ``4n^3 + 8n^2 L + 19n L - L - 4n``."""
    _positive(n=n, L=L)
    return 4 * n**3 + 8 * n**2 * L + 19 * n * L - L - 4 * n
