"""Recursive least squares on user-given regressors (what MATLAB's ``recursiveLS`` users expect).

The model is ``y(t) = phi(t) theta + e(t)`` with a regressor that the user builds: a vector of
``num_params`` values for a scalar output, or a ``num_outputs x num_params`` matrix whose row
``r`` is the regressor of output ``r`` (MATLAB's ``H(t)`` in ``y = H theta``). One step is the
recursive least-squares update of Voevoda & Troshina (2016), eq. (2)-(4) (Ding & Ma 2014,
(32)-(36); for a vector output the multi-innovation form (37)-(44)), with exponential
forgetting ``lambda``::

    e(t)     = y(t) - phi(t) theta(t-1)                                 (innovation)
    K(t)     = P(t-1) phi(t)^T [lambda I + phi(t) P(t-1) phi(t)^T]^{-1}  (3)
    theta(t) = theta(t-1) + K(t) e(t)                                   (2)
    P(t)     = [P(t-1) - K(t) phi(t) P(t-1)] / lambda                   (4)

i.e. ``P^{-1}(t) = lambda P^{-1}(t-1) + phi(t)^T phi(t)``: after ``T`` steps ``theta(T)`` is the
regularised least-squares estimate ``(lambda^T P0^{-1} + sum_t lambda^{T-t} phi^T phi)^{-1}
(lambda^T P0^{-1} theta0 + sum_t lambda^{T-t} phi^T y)``. The rule is the project's one
least-squares lane function (:func:`stcgym.adaptive.estimation.least_squares.least_squares_step`):
``P`` is kept as an upper-triangular square-root factor ``P = S S^T`` (Carlson's update), so it
cannot lose symmetry or positive definiteness through cancellation.

The options (initial covariance ``P0``, with ``0`` freezing ``theta`` as Voevoda & Troshina (2016)
note after (4); forgetting; a finite-history window, kept by exact downdates or, where a
downdate would lose digits, by replaying the stored window; MATLAB's ``EnableAdaptation``; the
safe action on numerical trouble; ``num_envs=B`` lanes, each equal to a single estimator bit
for bit) are the parameters of :class:`RecursiveLeastSquares`. The numerical health check is
the project's one: the factor ``S`` finite with a strictly positive diagonal, the gain
denominator positive and finite, ``theta`` finite, after every step.

:meth:`RecursiveLeastSquares.run` steps a whole record (``T`` samples, all lanes) in compiled
code; :meth:`~RecursiveLeastSquares.update` is one step, for an online loop.
"""

from __future__ import annotations

import warnings
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.estimation.estimator_spec import upper_cholesky
from stcgym.adaptive.estimation.health import NumericalHealthError
from stcgym.adaptive.regression.rls_step import (
    FAILED,
    OK,
    RLSConfig,
    make_rls_state,
    rls_run,
    rls_run_lanes,
)
from stcgym.lanes.compiled import state_nbytes_per_lane
from stcgym.lanes.validation import (
    covariance,
    forgetting_factor,
    integer,
    lane_indices,
    one_of,
    real_array,
)

__all__ = ["NumericalHealthError", "RecursiveLeastSquares"]

OnFailure = Literal["reset", "raise"]

# --------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------


def _initial_covariance(value: ArrayLike, d: int) -> tuple[NDArray, NDArray]:
    """``(P0, S0)`` with ``S0`` upper triangular, ``S0 S0^T = P0``; ``P0 = 0`` gives zeros.

    Exactly zero (a scalar, ``d`` values or a ``d x d`` matrix) means "theta never adapts";
    anything else is a covariance as the recursive estimators take it.
    """
    try:
        zero = np.shape(value) in ((), (d,), (d, d)) and not np.any(np.asarray(value, float))
    except (TypeError, ValueError):
        zero = False  # not numbers: covariance names the expected form
    if zero:
        return np.zeros((d, d)), np.zeros((d, d))
    P0 = covariance(value, d, "P0")
    return P0, upper_cholesky(P0)


# --------------------------------------------------------------------------------------------
# Public class
# --------------------------------------------------------------------------------------------


class RecursiveLeastSquares:
    """Recursive least squares ``y(t) = phi(t) theta + e(t)`` on user regressors.

    The module docstring gives the equations.

    Parameters
    ----------
    num_params : int
        ``d``, the length of ``theta``.
    num_outputs : int
        ``p``; with ``p > 1`` the regressor is a ``p x d`` matrix whose row ``r`` is the
        regressor of output ``r`` (MATLAB's ``H(t)`` in ``y = H theta``).
    theta0 : array_like, shape (d,), optional
        Initial estimate (zeros).
    P0 : float, array_like (d,) or (d, d)
        Initial covariance (``1e4``, MATLAB's ``InitialParameterCovariance``): a positive
        scalar, a vector (the diagonal) or a symmetric positive definite matrix; or exactly
        ``0``: the gain (3) is then zero and ``theta`` stays at ``theta0`` for ever.
    forgetting : float
        ``lambda`` in ``(0, 1]`` (``1``: no forgetting).
    window : int, optional
        Finite history of ``W`` samples (needs ``forgetting = 1`` and a positive definite
        ``P0``): the exact regularised estimate over the last ``W`` samples (``P0^{-1}`` and
        ``theta0`` stay as the prior). Each new sample is added and the one ``W`` steps old
        removed by an exact downdate; when the downdate would lose digits (a squared pivot of
        ``I - phi P phi^T`` below ``rls_step.WINDOW_DOWNDATE_TOL = 1e-4``: the
        sample carries nearly all the information in some direction) the estimate is
        recomputed by replaying the stored window from the prior instead (counted in
        :attr:`n_recomputes`).
    enabled : bool
        Adaptation switch (settable later through :attr:`enabled`), MATLAB's
        ``EnableAdaptation``: ``False`` freezes ``theta`` and ``P`` (the innovation and
        ``y_hat`` are still computed).
    on_failure : {"reset", "raise"}
        Safe action when the health check fails after a step (the factor of ``P`` not finite
        or its diagonal not strictly positive, the gain denominator not positive and finite,
        ``theta`` not finite): ``"reset"`` keeps the last ``theta``, resets ``P`` to ``P0``
        (empties the window), counts it in :attr:`n_resets` and warns; ``"raise"`` raises
        :class:`~stcgym.adaptive.NumericalHealthError` and leaves the failing lanes as they
        were before the failing step.
    num_envs : int, optional
        Number of lanes ``B``; ``None`` for a single estimator (no leading axis). The lanes
        are independent and stepped together by one batch loop over the same lane function
        as a single estimator, so lane ``i`` equals a single estimator fed lane ``i``'s data
        bit for bit.

    Raises
    ------
    ValueError
        On construction: ``num_params``, ``num_outputs``, ``window`` or ``num_envs`` not a
        positive integer, ``P0`` neither ``0`` nor positive definite of size ``d``, ``theta0``
        not a finite vector of length ``d``, ``forgetting`` outside ``(0, 1]``, ``window``
        with ``forgetting < 1`` or with ``P0 = 0``, ``on_failure`` not ``"reset"`` or
        ``"raise"``.

    Examples
    --------
    >>> from stcgym.adaptive import RecursiveLeastSquares
    >>> est = RecursiveLeastSquares(2, P0=1e6)
    >>> for phi, y in [([1.0, 0.0], 2.0), ([0.0, 1.0], -1.0), ([1.0, 1.0], 1.0)]:
    ...     theta = est.update(phi, y)
    >>> np.round(theta, 4)
    array([ 2., -1.])
    """

    def __init__(
        self,
        num_params: int,
        num_outputs: int = 1,
        *,
        theta0: ArrayLike | None = None,
        P0: float | ArrayLike = 1e4,
        forgetting: float = 1.0,
        window: int | None = None,
        enabled: bool = True,
        on_failure: OnFailure = "reset",
        num_envs: int | None = None,
    ) -> None:
        d = integer(num_params, "num_params", 1)
        p = integer(num_outputs, "num_outputs", 1)
        self._d, self._p = d, p
        self._lam = forgetting_factor(forgetting)
        self._P0, self._S0 = _initial_covariance(P0, d)
        self._frozen = not np.any(self._P0)  # P0 = 0: the gain is zero for ever
        if theta0 is None:
            self._theta0 = np.zeros(d)
        else:
            th = np.array(theta0, dtype=float).reshape(-1)
            if th.size != d or not np.all(np.isfinite(th)):
                raise ValueError(f"theta0 must be a finite vector of length {d}, got {theta0!r}")
            self._theta0 = th
        self._window = 0 if window is None else integer(window, "window", 1)
        if self._window:
            if self._lam != 1.0:
                raise ValueError("window (finite history) and forgetting < 1 are exclusive")
            if self._frozen:
                raise ValueError("window (finite history) needs a positive definite P0, got 0")
        one_of(on_failure, "on_failure", ("reset", "raise"))
        self._reset_on_failure = on_failure == "reset"
        self._batched = num_envs is not None
        B = 1 if num_envs is None else integer(num_envs, "num_envs", 1)
        self.enabled = enabled

        self._num_lanes = B
        self._state, self._work = make_rls_state(d, p, self._window, B)
        self._lead = (B,) if self._batched else ()
        self._out1 = np.empty((1, d))
        self.reset()

    # ---------------------------------------------------------------- lifecycle
    def reset(self, lanes: ArrayLike | None = None) -> None:
        """Back to ``theta0``, ``P0``, ``t = 0`` (all lanes, or the given lane indices / mask).

        Parameters
        ----------
        lanes : array_like of int or bool, optional
            Lane indices or a boolean mask of length ``B`` (default all lanes).

        Raises
        ------
        ValueError
            An index out of range or a mask of the wrong length.
        """
        idx = lane_indices(lanes, self._num_lanes)
        for field in self._state:
            field[idx] = 0
        self._state.theta[idx] = self._theta0
        self._state.S[idx] = self._S0

    # ---------------------------------------------------------------- data checks
    def _regressor(self, phi: ArrayLike, lead: tuple[int, ...]) -> NDArray:
        """``phi`` as ``lead + (p, d)`` float64, C-contiguous; ValueError naming it otherwise."""
        return self._per_output(phi, "phi", lead, (self._d,))

    def _output(self, y: ArrayLike, lead: tuple[int, ...]) -> NDArray:
        """``y`` as ``lead + (p,)`` float64, C-contiguous; ValueError naming it otherwise."""
        return self._per_output(y, "y", lead, ())

    def _per_output(
        self, value: ArrayLike, name: str, lead: tuple[int, ...], row: tuple[int, ...]
    ) -> NDArray:
        """``value`` as ``lead + (p,) + row``, finite; with one output its axis may be left out."""
        p = self._p
        arr = real_array(value, name)
        if p == 1 and arr.shape == lead + row:
            arr = np.expand_dims(arr, len(lead))
        if arr.shape != lead + (p, *row):
            want = lead + row if p == 1 else lead + (p, *row)
            what = f" ({'num_outputs x ' if p > 1 else ''}num_params)" if row else ""
            raise ValueError(f"{name} must have shape {want}{what}, got {arr.shape}")
        if not np.isfinite(arr).all():
            raise ValueError(f"{name} must be finite (no NaN or inf)")
        return np.ascontiguousarray(arr)

    def _config(self) -> RLSConfig:
        adapt = self._enabled and not self._frozen
        return RLSConfig(
            self._theta0, self._S0, self._lam, self._window, adapt, self._reset_on_failure
        )

    # ---------------------------------------------------------------- stepping
    def update(self, phi: ArrayLike, y: ArrayLike) -> NDArray:
        """One step with regressor ``phi(t)`` and measurement ``y(t)``; returns ``theta(t)``.

        Parameters
        ----------
        phi : array_like, shape (d,) or (p, d)
            The regressor ``phi(t)`` (one row per output); ``(B, d)`` or ``(B, p, d)`` with
            ``num_envs=B``.
        y : float or array_like, shape (p,)
            The measurement ``y(t)``; ``(B,)`` or ``(B, p)`` with ``num_envs=B``.

        Returns
        -------
        ndarray, shape (d,) or (B, d)
            ``theta(t)``.

        Raises
        ------
        ValueError
            Bad shapes or non-finite values, before any state changes.
        NumericalHealthError
            With ``on_failure="raise"``, a step that would lose positive definiteness or
            overflow (not applied).
        """
        Phi = self._regressor(phi, self._lead)
        Y = self._output(y, self._lead)
        if self._batched:  # the batch loop over lanes, one step
            B = self._num_lanes
            failures = np.zeros(B, dtype=np.int64)
            rls_run_lanes(
                self._state,
                self._work,
                self._config(),
                Phi[:, None],
                Y[:, None],
                np.empty((B, 1, self._d)),
                failures,
                np.zeros(B, dtype=np.int64),
            )
            status = np.where(failures > 0, FAILED, OK)
        else:  # the same lane function, called directly (no thread pool for one lane)
            fails, _ = rls_run(
                self._state, self._work, 0, self._config(), Phi[None], Y[None], self._out1
            )
            if not fails:
                return self._out1[0].copy()
            status = np.array([FAILED])
        failed = np.flatnonzero(status == FAILED)
        if failed.size:
            self._failure(failed, "the covariance factor or theta lost finiteness or rank")
        return self.theta

    def run(self, phi: ArrayLike, y: ArrayLike) -> NDArray:
        """Many steps in compiled code: ``phi`` (T, d) / (T, p, d), ``y`` (T,) / (T, p).

        With ``num_envs=B`` a leading ``B`` axis on both. With ``on_failure="raise"`` a failing
        lane stops before its failing step (the other lanes finish) and the error names the
        step.

        Parameters
        ----------
        phi : array_like, shape (T, d) or (T, p, d)
            Regressors of ``T`` steps (``(B, T, ...)`` with ``num_envs=B``).
        y : array_like, shape (T,) or (T, p)
            Measurements of the same steps (``(B, T, ...)`` with ``num_envs=B``).

        Returns
        -------
        ndarray, shape (T, d) or (B, T, d)
            ``theta(t)`` after each step.

        Raises
        ------
        ValueError
            Bad shapes or non-finite values, before any state changes.
        NumericalHealthError
            With ``on_failure="raise"``, as for :meth:`update`.
        """
        B = self._num_lanes
        phi_arr = np.asarray(phi, dtype=float)
        T_axis = 1 if self._batched else 0
        if phi_arr.ndim <= T_axis:
            raise ValueError(f"phi must have a time axis, got shape {phi_arr.shape}")
        T = phi_arr.shape[T_axis]
        lead = (B, T) if self._batched else (T,)
        Phis = self._regressor(phi_arr, lead)
        Ys = self._output(y, lead)
        if not self._batched:
            Phis, Ys = Phis[None], Ys[None]
        out = np.empty((B, T, self._d))
        failures = np.zeros(B, dtype=np.int64)
        first = np.zeros(B, dtype=np.int64)
        if self._batched:
            rls_run_lanes(self._state, self._work, self._config(), Phis, Ys, out, failures, first)
        else:  # one lane: the lane function itself
            failures[0], first[0] = rls_run(
                self._state, self._work, 0, self._config(), Phis[0], Ys[0], out[0]
            )
        failed = np.flatnonzero(failures)
        if failed.size:
            step = int(first[failed].min())
            self._failure(
                failed,
                f"the covariance factor or theta lost finiteness or rank at run() step {step}",
                count=int(failures.sum()),
            )
        return out if self._batched else out[0]

    def predict(self, phi: ArrayLike) -> NDArray:
        """``phi theta`` with the current estimate (no state change).

        Parameters
        ----------
        phi : array_like, shape (d,) or (p, d)
            A regressor (``(B, ...)`` with ``num_envs=B``).

        Returns
        -------
        ndarray, shape (p,) or (B, p)
            The model output.

        Raises
        ------
        ValueError
            ``phi`` malformed or not finite.
        """
        Phi = self._regressor(phi, self._lead)
        return np.einsum("...rd,...d->...r", Phi, self.theta)

    def _failure(self, failed: NDArray, reason: str, *, count: int | None = None) -> None:
        """Raise (``on_failure="raise"``) or warn about lanes the lane function reset."""
        lanes_txt = f"lane(s) {failed.tolist()}" if self._batched else "estimator"
        msg = f"RecursiveLeastSquares {lanes_txt}: {reason}"
        if not self._reset_on_failure:
            raise NumericalHealthError(msg + " (the failing step was not applied)")
        n = failed.size if count is None else count
        warnings.warn(f"{msg}; P reset to P0 ({n} reset(s))", RuntimeWarning, stacklevel=3)

    # ---------------------------------------------------------------- read-only state
    def _get(self, name: str) -> NDArray:
        v = getattr(self._state, name)
        return v.copy() if self._batched else v[0].copy()

    def _counter(self, name: str) -> int | NDArray:
        n = getattr(self._state, name).copy()
        return n if self._batched else int(n[0])

    @property
    def theta(self) -> NDArray:
        """``theta(t)``: (d,) or (B, d)."""
        return self._get("theta")

    @property
    def P(self) -> NDArray:
        """``P(t) = S S^T``: (d, d) or (B, d, d)."""
        S = self._get("S")
        return S @ S.swapaxes(-1, -2)

    @property
    def S(self) -> NDArray:
        """The upper-triangular square-root factor, ``P = S S^T``."""
        return self._get("S")

    @property
    def K(self) -> NDArray:
        """Gain of the last step ``K(t) = P(t) phi(t)^T`` (eq. (3)): (d,) or (d, p), lanes first."""
        K = self._get("K")
        return K[..., 0] if self._p == 1 else K

    @property
    def innovation(self) -> NDArray:
        """``e(t) = y(t) - phi(t) theta(t-1)`` of the last step: (p,) or (B, p)."""
        return self._get("innovation")

    @property
    def y_hat(self) -> NDArray:
        """One-step prediction ``phi(t) theta(t-1)`` of the last step: (p,) or (B, p)."""
        return self._get("y_hat")

    @property
    def t(self) -> int | NDArray:
        """Steps since the last reset (per lane with ``num_envs``)."""
        return self._counter("t")

    @property
    def n_resets(self) -> int | NDArray:
        """Covariance resets after numerical failures (per lane with ``num_envs``)."""
        return self._counter("n_resets")

    @property
    def n_recomputes(self) -> int | NDArray:
        """Finite-history recomputations from the stored window (ill-conditioned downdates)."""
        return self._counter("n_recomputes")

    @property
    def enabled(self) -> bool:
        """Adaptation switch: ``False`` freezes ``theta`` and ``P`` (predictions still made)."""
        return self._enabled

    @enabled.setter
    def enabled(self, value: bool) -> None:
        self._enabled = bool(value)

    @property
    def num_params(self) -> int:
        """Regressor length ``d`` (parameters per output)."""
        return self._d

    @property
    def num_outputs(self) -> int:
        """Outputs ``p`` fitted with the one gain."""
        return self._p

    @property
    def num_envs(self) -> int | None:
        """Lanes ``B`` of a batched estimator; ``None`` for a single one."""
        return self._num_lanes if self._batched else None

    @property
    def nbytes_per_lane(self) -> int:
        """Bytes of one lane's state and scratch (the estimator's whole state)."""
        return state_nbytes_per_lane(self._state) + state_nbytes_per_lane(self._work)

    def __repr__(self) -> str:
        lanes_txt = f", num_envs={self._num_lanes}" if self._batched else ""
        return (
            f"RecursiveLeastSquares(num_params={self._d}, num_outputs={self._p}, "
            f"forgetting={self._lam}, window={self._window or None}{lanes_txt})"
        )
