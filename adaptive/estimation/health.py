"""Numerical health of the recursive estimators (:mod:`stcgym.adaptive.estimation.recursive`).

Numerical health
----------------
``P`` is propagated as an upper-triangular square-root factor (Carlson's update), so it cannot
lose symmetry or positive definiteness through cancellation. After every update the factor is
checked (every entry finite, every diagonal entry positive: the one health check, see
:mod:`stcgym.adaptive.estimation.least_squares`), and ``r``, the gain denominators and the
parameter increment are checked for overflow / NaN. On a failure the default
``on_failure="reset"`` resets ``P`` to ``P(0)`` (``r`` to ``r(0)``, the finite-history window is
emptied), keeps the last finite ``theta_hat``, counts the event in :attr:`n_resets` and emits a
:class:`RuntimeWarning`; ``on_failure="raise"`` leaves the estimator exactly as before the call
and raises :class:`NumericalHealthError`. A non-finite state estimate is reset to ``x_hat(1)``
the same way (``health["n_state_resets"]``); a non-finite Kalman covariance to ``P1(1)``. No NaN
is returned silently. A rejected call (bad input, wrong call order) changes nothing.

Frozen on a wrong model (``health["frozen"]``)
---------------------------------------------
With the paper's ``p0 = 1e6`` the RLS/MILS family (and the D- rules) can freeze at a wrong
estimate: an early unstable ``A_hat(t)`` makes the open-loop observer's ``x_hat`` huge, the huge
``phi_hat`` entries collapse ``P`` before ``theta`` is right, and with ``lambda = 1`` it never
recovers while every numerical counter stays 0. The estimator therefore raises the ``frozen``
flag (and one :class:`RuntimeWarning` when it first switches on) while, after the first 2000
steps, the mean gain ``phi_hat^T P phi_hat`` is below ``1e-3`` and the innovation power exceeds
``frozen_ratio`` (default 0.05) times the output power (means over ~1000 steps; details in
:mod:`stcgym.adaptive.estimation.estimator`). Measured (the design notes of the documentation
say how; O-RLS, O-MILS, O-D-RLS, KF-RLS, O-D-MILS,
``p0`` = 1e6 and 100, three second-order plants incl. one with a zero at 4.64, three seeds,
200 000 steps, white input, observer form): with output noise std 0.1 all 39 of 90 runs whose
final parameter error exceeds 10 % are flagged at the end (41 of the 42 above 5 %), and 4 of
the 51 runs below 10 %. The flag means "the model explains too little of the output": on data
whose noise is more than ``frozen_ratio`` of the output power it fires on good estimates too
(noise std 1.0: 30 of the 45 runs below 10 % flagged), so raise ``frozen_ratio`` there (``math.inf``
disables it). The remedies are ``p0`` of 10-100, ``forgetting < 1`` or ``project_stable=True``.

"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from stcgym.adaptive.estimation.estimator import ST_PD_LOST

__all__ = ["NumericalHealthError", "describe_events", "health_error"]


class NumericalHealthError(FloatingPointError):
    """A covariance or normaliser lost positive definiteness or became non-finite.

    Raised by the estimators when ``on_failure="raise"`` (the estimator is then left exactly
    as before the call); with the default ``"reset"`` they recover instead and emit a
    :class:`RuntimeWarning`.

    Parameters
    ----------
    *args
        The message (the algorithm, the time ``t`` and what failed).

    Examples
    --------
    An output of ``1e300`` overflows ``P``; the estimator stays at ``t = 1``:

    >>> from stcgym.adaptive import NumericalHealthError, make_estimator
    >>> est = make_estimator("O-RLS", 2, on_failure="raise")
    >>> _ = est.update(1e200)
    >>> _ = est.predict(1e200)
    >>> try:
    ...     est.update(1e300)
    ... except NumericalHealthError as exc:
    ...     print(exc)
    O-RLS at t=2: P(t) / r(t) overflowed or is not finite
    >>> est.t
    1
    """


def describe_events(
    name: str, t: int, status: NDArray, mask: int, *, times: bool, single: bool
) -> str | None:
    """Where the events ``mask`` of ``status`` happened, for a warning or error (``None``: none).

    ``status`` holds the ``ST_*`` bits of the lane functions per lane, or per step of one lane
    (``times=True``, the last entry at time ``t``); ``single``: one plant, reported by time.
    """
    hit = np.flatnonzero(status & mask)
    if hit.size == 0:
        return None
    if times:
        first = t - (status.size - 1 - int(hit[0]))
        return f"{name} at t={first}" + (f" ({hit.size} times)" if hit.size > 1 else "")
    if single:
        return f"{name} at t={t}"
    return f"{name}: lanes {hit[:5].tolist()}{'...' if hit.size > 5 else ''}"


def health_error(status: NDArray, rule: str | None, state: str | None) -> NumericalHealthError:
    """The error for a failed parameter rule (``rule``) or else a failed state estimate."""
    reason = (
        "P(t) is not symmetric positive definite (rank lost)"
        if np.any(status & ST_PD_LOST)
        else "P(t) / r(t) overflowed or is not finite"
    )
    if rule:
        return NumericalHealthError(f"{rule}: {reason}")
    return NumericalHealthError(f"{state}: state estimate x_hat(t+1) is not finite")
