"""Computational cost (flops = multiplications + additions) of the seed paper's algorithms.

The formulas are those of tables 1-8 of Ding & Ma (2014):
per step for the recursive algorithms, per iteration for the iterative ones. ``n`` is the plant
order, ``p`` the innovation length and ``L`` the batch length.
"""

from __future__ import annotations

from stcgym.lanes.validation import integer


def _positive(**values: int) -> None:
    """Check that every size (``n``, ``p``, ``L``) is an integer ``>= 1``."""
    for name, v in values.items():
        integer(v, name)


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
    """D-LSI per iteration, the sum of table 6's rows: ``4n^3 + 4n^2 L + 8n L - 4n``.

    Table 6's printed total is ``2n^2`` lower (its additions carry ``-4n^2`` where the rows give
    ``-2n^2``); table 8 (KF-D-LSI), which repeats those rows, agrees with the rows, so every
    D-LSI count here uses the rows.
    """
    _positive(n=n, L=L)
    return 4 * n**3 + 4 * n**2 * L + 8 * n * L - 4 * n


def o_lsi(n: int, L: int) -> int:
    """O-LSI per iteration, table 7: ``16n^3 + 8n^2 L + 8n L - 4n - L``."""
    _positive(n=n, L=L)
    return 16 * n**3 + 8 * n**2 * L + 8 * n * L - 4 * n - L


def kf_d_lsi(n: int, L: int) -> int:
    """KF-D-LSI per iteration, table 8: ``4n^3 + 8n^2 L + 19n L - L - 4n``."""
    _positive(n=n, L=L)
    return 4 * n**3 + 8 * n**2 * L + 19 * n * L - L - 4 * n


# ---------------------------------------------------------------------------------------------
# Recursive algorithms not covered by tables 1-4, counted with the same conventions
# (a division is a multiplication, a subtraction an addition, the structure of A_hat is used,
# lambda = 1, no finite history). A full algorithm = parameter rule + state estimator:
# table 1 = rls + open_loop_observer, table 2 = mils + kalman_filter; tables 3-4 (d_rls, d_mils)
# are the parameter parts only.
# ---------------------------------------------------------------------------------------------


def open_loop_observer(n: int) -> int:
    """Open-loop observer (46), table 1 row ``x_hat(t+1)``: ``2n`` mult + ``2n - 1`` add."""
    _positive(n=n)
    return 4 * n - 1


def closed_loop_observer(n: int) -> int:
    """Closed-loop observer (50): the open-loop observer plus ``K [y - c x_hat]``
    (``n + 1`` mult, ``n`` add as in table 2): ``6n``. A gain callable is not counted."""
    _positive(n=n)
    return 6 * n


def kalman_filter(n: int) -> int:
    """Kalman filter (66)-(68), table 2 rows ``x_hat``, ``L1``, ``P1``, ``zeta1``:
    ``4n^2 + 10n - 1``."""
    _positive(n=n)
    return 4 * n**2 + 10 * n - 1


def sg(n: int) -> int:
    """SG parameter update (12)-(15): ``e`` (2n, 2n), ``r`` (2n, 2n), ``e / r`` (1, 0),
    ``theta + phi (e / r)`` (2n, 2n): ``12n + 1``."""
    _positive(n=n)
    return 12 * n + 1


def misg(n: int, p: int, *, stacked_r: bool = False) -> int:
    """MISG parameter update (16)-(22): ``E`` (2np, 2np), ``r`` (2n, 2n), ``E / r`` (p, 0),
    ``Phi (E / r)`` (2np, 2n(p-1)), ``theta +`` (0, 2n): ``8np + 4n + p``.
    With ``||Phi(p, t)||^2`` in ``r`` (remark 1): ``12np + p``. Equals :func:`sg` at p = 1."""
    _positive(n=n, p=p)
    if stacked_r:
        return 12 * n * p + p
    return 8 * n * p + 4 * n + p


def rls(n: int) -> int:
    """RLS parameter update (32)-(36), table 1 without the observer: ``16n^2 + 12n``."""
    _positive(n=n)
    return 16 * n**2 + 12 * n


def mils(n: int, p: int) -> int:
    """MILS parameter update (37)-(44), table 2 without the Kalman filter:
    ``16n^2 p + 8n p^2 + 4n p + 2p^3 - 2p^2 + p`` (``rls(n) + 1`` at p = 1: table 2 counts the
    1 x 1 inverse as a flop)."""
    _positive(n=n, p=p)
    return 16 * n**2 * p + 8 * n * p**2 + 4 * n * p + 2 * p**3 - 2 * p**2 + p


def d_sg(n: int) -> int:
    """D-SG parameter update (96)-(103): shared ``e`` (2n, 2n), ``r1``, ``r2`` (2n, 2n),
    ``e / r1``, ``e / r2`` (2, 0), two block updates (2n, 2n): ``12n + 2``."""
    _positive(n=n)
    return 12 * n + 2


def d_misg(n: int, p: int, *, stacked_r: bool = False) -> int:
    """D-MISG parameter update (104)-(117): shared ``E`` (2np, 2np), ``r1``, ``r2`` (2n, 2n),
    ``E / r_i`` (2p, 0), two blocks ``Phi_i (E / r_i)`` + add (2np, 2np): ``8np + 4n + 2p``.
    With ``||Phi||^2``, ``||Psi||^2`` in ``r`` (116)-(117): ``12np + 2p``."""
    _positive(n=n, p=p)
    if stacked_r:
        return 12 * n * p + 2 * p
    return 8 * n * p + 4 * n + 2 * p


# --------------------------------------------------------------------------------------------
# Iterative algorithms without a table in the paper (appended for
# stcgym.adaptive.estimation.iterative).
#
# Same accounting as tables 5-8: multiplications + additions of the parameter update and of the
# state re-estimation over t = 1..L; building the regressors (copies and sign changes) is free,
# a matrix inverse of size k costs k^3 + (k^3 - k^2) and products are not symmetry-exploited.
# D-LSI is table 6 by its rows (see ``d_lsi``), as table 8 is.


def observer_states(n: int, L: int) -> int:
    """Open-loop state observer (238) over t = 1..L, row of table 7: ``2nL + (2n-1)L``
    (``L * open_loop_observer(n)``)."""
    _positive(n=n, L=L)
    return L * open_loop_observer(n)


def kalman_states(n: int, L: int) -> int:
    """Kalman filter (258)-(263) over t = 1..L, the filter rows of table 8: ``4n^2 L + 11nL - L``.

    (x update ``2nL + (2n-1)L``, gain times innovation ``nL + (n+1)L``, gain ``2nL + nL``,
    covariance ``(n^2+2n)L + (n^2+n-1)L``, ``zeta = P A^T`` ``n^2 L + (n^2-n)L``.) This is
    ``nL`` more than ``L * kalman_filter(n)`` from table 2's rows; table 8's rows are used so
    that KF-D-LSI reproduces table 8.
    """
    _positive(n=n, L=L)
    return 4 * n**2 * L + 11 * n * L - L


def gi(n: int, L: int) -> int:
    """GI (164)-(169) per iteration (no table in the paper): ``8n^2 L + 8nL - 4n^2 + 2n``.

    ``H theta`` and ``Y - H theta``: ``4nL``; ``H^T e``: ``4nL - 2n``; ``theta + mu g``: ``4n``;
    the Gram matrix ``H^T H`` for the step size (168): ``8n^2 L - 4n^2`` as in table 5. The
    largest eigenvalue itself (LAPACK, iterative) is not counted.
    """
    _positive(n=n, L=L)
    return 8 * n**2 * L + 8 * n * L - 4 * n**2 + 2 * n


def d_gi(n: int, L: int) -> int:
    """D-GI (190)-(200) per iteration (no table): ``4n^2 L + 8nL - 2n^2 + 2n``.

    Shared residual ``Y - Phi a - Psi b``: ``4nL``; ``Phi^T e`` and ``Psi^T e``: ``2(2nL - n)``;
    two scaled updates: ``4n``; Gram matrices ``Phi^T Phi`` and ``Psi^T Psi`` for the step sizes
    (197)-(198): ``2(2n^2 L - n^2)``. Eigenvalues not counted.
    """
    _positive(n=n, L=L)
    return 4 * n**2 * L + 8 * n * L - 2 * n**2 + 2 * n


#: The parameter updates of the iterative algorithms, and their state re-estimation over
#: ``t = 1..L``. Without a table, ``S-R`` costs ``R + S`` per iteration (e.g. O-GI is
#: ``gi + observer_states``, KF-D-GI ``d_gi + kalman_states``); tables 7 and 8 count O-LSI and
#: KF-D-LSI themselves.
_ITERATIVE_UPDATES = {"GI": gi, "D-GI": d_gi, "LSI": lsi, "D-LSI": d_lsi}
_ITERATIVE_STATES = {"O": observer_states, "KF": kalman_states}
_ITERATIVE_TABLES = {"O-LSI": o_lsi, "KF-D-LSI": kf_d_lsi}


def iterative(states: str | None, rule: str, n: int, L: int) -> int:
    """Flops per iteration of the iterative rule ``rule`` (``"GI"``, ``"D-GI"``, ``"LSI"``,
    ``"D-LSI"``) with the state estimator ``states`` (``"O"``, ``"KF"``, or ``None`` for the
    parameter update alone, as used with known states): the parts of a name as
    :func:`~stcgym.adaptive.estimation.iterative.parse_iterative_name` returns them.

    Tables 5-8 for LSI, D-LSI, O-LSI and KF-D-LSI; the counts above for the others.
    """
    key = rule if states is None else f"{states}-{rule}"
    if key in _ITERATIVE_TABLES:
        return _ITERATIVE_TABLES[key](n, L)
    update = _ITERATIVE_UPDATES[rule](n, L)
    return update if states is None else update + _ITERATIVE_STATES[states](n, L)
