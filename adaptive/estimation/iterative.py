"""Iterative (batch) joint parameter/state estimators of Ding & Ma (2014), sections 4-5.

On a batch of ``L`` samples the parameter vector ``theta = [a1..an, b1..bn]`` of a canonical SISO
plant (observability form (146)-(153) or observer form (1)-(8)) is refined over iterations
``k = 1, 2, ...``; every iteration builds the stacked regressor ``H_k`` from the state
estimates of iteration ``k-1``, updates ``theta_k`` and then re-estimates all states
``x_hat_k(1..L)`` with ``A_hat_k``, ``b_hat_k``:

=========  =====================================================================================
rule       parameter update
=========  =====================================================================================
GI         (164)-(169): ``theta_k = theta_{k-1} + mu_k H_k^T (Y - H_k theta_{k-1})``
D-GI       (190)-(200): the same per block ``a`` (regressor ``Phi_k``) and ``b`` (``Psi``)
LSI        (208)-(212): ``theta_k = (H_k^T H_k)^{-1} H_k^T Y``
D-LSI      (229)-(237): ``a_k = (Phi_k^T Phi_k)^{-1} Phi_k^T (Y - Psi b_{k-1})``,
           ``b_k = (Psi^T Psi)^{-1} Psi^T (Y - Phi_k a_{k-1})``
=========  =====================================================================================

State re-estimation: prefix ``O-`` open-loop observer (238)-(241), prefix ``KF-`` Kalman filter
(258)-(263). Plain rule names (``"LSI"``, ...) take the true states ``x`` and skip it.

Conventions: every signal and state is zero for ``t <= 0``; ``u[k]``, ``y[k]`` are ``u(t)``,
``y(t)`` for ``t = k + 1``. Regressors:

* observability form (153): ``phi(t) = [-x_n(t-n), ..., -x_1(t-n), u(t-1), ..., u(t-n)]``;
* observer form (8): ``phi(t) = [-x_1(t-1), ..., -x_1(t-n), u(t-1), ..., u(t-n)]``.

Iteration 0 uses random states for ``t = 1..L`` (the paper: "random, so that ``H_1`` is
invertible") drawn from ``seed``; ``theta_0 = 1_{2n} / p0`` and ``x_hat_k(1) = 1_n / p0``.
Iteration stops when ``||theta_k - theta_{k-1}|| <= tol`` or after ``iterations`` iterations.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.estimation import flops as _flops
from stcgym.adaptive.estimation.health import NumericalHealthError
from stcgym.adaptive.estimation.state_estimation import state_trajectory
from stcgym.adaptive.variants import STATE_ESTIMATORS
from stcgym.envs.canonical import check_form, companion_A
from stcgym.lanes.validation import integer, non_negative, positive, vector_pair

__all__ = [
    "ITERATIVE_NAMES",
    "IterativeResult",
    "NumericalHealthError",
    "fit_iterative",
    "parse_iterative_name",
]

_RULES = ("GI", "D-GI", "LSI", "D-LSI")
# State estimates beyond this magnitude count as overflow: their Gram matrices (sums of L
# squares) would overflow double precision in the next parameter update.
STATE_LIMIT = 1e100
_STATE_ESTIMATORS = ("O", "KF")
ITERATIVE_NAMES: tuple[str, ...] = tuple(f"{s}-{r}" for s in _STATE_ESTIMATORS for r in _RULES)
_ALL_NAMES = ITERATIVE_NAMES + _RULES


@dataclass(frozen=True)
class IterativeResult:
    """Outcome of :func:`fit_iterative`.

    Attributes
    ----------
    name : str
        Canonical algorithm name, e.g. ``"KF-D-LSI"`` (``"LSI"`` etc. with known states).
    form : str
        ``"observability"`` or ``"observer"``.
    theta : ndarray, shape (2n,)
        Final estimate ``[a1..an, b1..bn]``.
    theta_history : ndarray, shape (iterations + 1, 2n)
        ``theta_0, theta_1, ..., theta_k``; row 0 is the initial value ``1_{2n} / p0``.
    x_hat : ndarray, shape (L, n)
        State estimates ``x_hat_k(t)``, ``t = 1..L``, computed with the final ``theta`` (the
        given states for the plain names).
    iterations : int
        Number of parameter updates performed (``k``).
    converged : bool
        Whether ``||theta_k - theta_{k-1}|| <= tol`` was reached.
    flops_per_iteration : int
        Tables 5-8 of the paper (see :func:`stcgym.adaptive.estimation.flops.iterative`).
    step_sizes : ndarray, shape (iterations, 1 or 2)
        GI step ``mu_k`` (D-GI: ``mu_a,k``, ``mu_b,k``) per iteration; empty for LSI rules.
    rank_deficient : bool
        True if some least-squares problem was rank deficient and the minimum-norm ``lstsq``
        solution was used instead of ``(H^T H)^{-1} H^T Y``.

    Examples
    --------
    See :func:`fit_iterative`, which returns one (its gradient-iteration example shows the
    history and the step sizes).
    """

    name: str
    form: str
    theta: NDArray
    theta_history: NDArray
    x_hat: NDArray
    iterations: int
    converged: bool
    flops_per_iteration: int
    step_sizes: NDArray = field(default_factory=lambda: np.zeros((0, 1)))
    rank_deficient: bool = False

    @property
    def n(self) -> int:
        """Plant order."""
        return self.theta.size // 2

    @property
    def a(self) -> NDArray:
        """Final denominator estimate ``a1..an``."""
        return self.theta[: self.n].copy()

    @property
    def b(self) -> NDArray:
        """Final ``b1..bn`` (numerator in the observer form, Markov parameters otherwise)."""
        return self.theta[self.n :].copy()


# ---------------------------------------------------------------------------------- helpers
def parse_iterative_name(name: str) -> tuple[str | None, str]:
    """The one parser of iterative algorithm names: ``(state estimator or None, rule)``.

    Accepts ``"KF-D-LSI"``, the paper's ``"D-LSI-KF"`` order, ``"lsi"`` (a plain rule: known
    states, state estimator ``None``), case-insensitive, ``_`` or blanks for ``-``. Raises
    ``ValueError`` listing the accepted names otherwise.
    """
    key = str(name).strip().upper().replace("_", "-").replace(" ", "-")
    for se in _STATE_ESTIMATORS:
        if key.startswith(se + "-") and key[len(se) + 1 :] in _RULES:
            return se, key[len(se) + 1 :]
        if key.endswith("-" + se) and key[: -len(se) - 1] in _RULES:  # the paper's "GI-KF"
            return se, key[: -len(se) - 1]
    if key in _RULES:
        return None, key
    raise ValueError(
        f"name must be one of {_ALL_NAMES} (case-insensitive; 'GI-KF' style also accepted), "
        f"got {name!r}"
    )


def _lagged(v: NDArray, lag: int) -> NDArray:
    """``v(t - lag)`` for ``t = 1..L`` with zeros for ``t - lag <= 0``."""
    out = np.zeros_like(v)
    if lag < v.shape[0]:
        out[lag:] = v[: v.shape[0] - lag]
    return out


def _psi(u: NDArray, n: int) -> NDArray:
    """Stacked input regressor ``Psi``, row ``t``: ``[u(t-1), ..., u(t-n)]`` (235)."""
    return np.column_stack([_lagged(u, i) for i in range(1, n + 1)])


def _phi(x: NDArray, form: str) -> NDArray:
    """Stacked state regressor ``Phi`` from states ``x`` (shape ``(L, n)``, rows ``t = 1..L``).

    Observability form (234): row ``t`` is ``[-x_n(t-n), ..., -x_1(t-n)]``; observer form (8):
    ``[-x_1(t-1), ..., -x_1(t-n)]``.
    """
    L, n = x.shape
    if form == "observability":
        return -_lagged(x[:, ::-1], n)
    return -np.column_stack([_lagged(x[:, 0], i) for i in range(1, n + 1)])


def _lstsq(M: NDArray, rhs: NDArray) -> tuple[NDArray, bool]:
    """``(M^T M)^{-1} M^T rhs`` via an orthogonal solver; minimum-norm if rank deficient.

    ``lstsq`` is used instead of forming and inverting ``M^T M`` because it squares neither the
    condition number nor fails on singular ``M^T M`` (e.g. ``u = 0`` makes ``Psi = 0``). The
    columns are equilibrated first (``M D^{-1}``, ``D`` their norms; solve; ``D^{-1}``): the
    rank decision compares singular values with the largest one, so state columns 1e14 times
    the input columns would otherwise count as rank-deficient and lose the input block. A zero
    column keeps scale 1 and stays a rank deficiency (minimum-norm in the scaled columns).
    """
    norms = np.linalg.norm(M, axis=0)
    scale = np.where(norms > 0.0, norms, 1.0)
    sol, _, rank, _ = np.linalg.lstsq(M / scale, rhs, rcond=None)
    return sol / scale, bool(rank < M.shape[1])


def _lambda_max(M: NDArray) -> float:
    return float(np.linalg.eigvalsh(M.T @ M)[-1]) if M.size else 0.0


def _gi_step(M: NDArray, mu: float | None) -> float:
    """Step size: the given ``mu`` or the default ``1 / lambda_max(M^T M)`` (half the bound
    ``2 / lambda_max`` of (168), which keeps the iteration a contraction also for D-GI)."""
    lmax = _lambda_max(M)
    if mu is None:
        return 1.0 / lmax if lmax > 0 else 0.0
    if lmax > 0 and mu > 2.0 / lmax:
        warnings.warn(
            f"GI step mu = {mu:g} exceeds 2 / lambda_max = {2.0 / lmax:g} (168); the iteration "
            "may diverge",
            RuntimeWarning,
            stacklevel=4,
        )
    return mu


def _states(
    A: NDArray, b: NDArray, u: NDArray, y: NDArray, x1: NDArray, kalman: bool, q: float, r: float
) -> NDArray:
    """State re-estimation over the batch with ``A_hat_k``, ``b_hat_k``: the open-loop observer
    (238)-(241) or the Kalman filter (258)-(263) with process noise ``q I`` and measurement
    weight ``r`` (the paper: ``q = 0``, ``r = 1``, ``P(1) = I``) -- the same lane functions as
    the recursive estimators' state step."""
    n = b.size
    xs = np.empty((u.size, n))
    state_trajectory(
        np.ascontiguousarray(A, dtype=float),
        np.ascontiguousarray(b, dtype=float),
        u,
        y,
        np.ascontiguousarray(x1, dtype=float),
        kalman,
        np.eye(n),
        q * np.eye(n),
        float(r),
        xs,
    )
    return xs


def _update(
    rule: str,
    Phi: NDArray,
    Psi: NDArray,
    Y: NDArray,
    theta: NDArray,
    mu_a: float | None,
    mu_b: float | None,
) -> tuple[NDArray, bool, tuple[float, ...]]:
    """One parameter iteration; returns ``(theta_k, rank deficient?, step sizes)``."""
    n = Phi.shape[1]
    a_prev, b_prev = theta[:n], theta[n:]
    if rule == "LSI":  # (208)
        theta_new, deficient = _lstsq(np.hstack([Phi, Psi]), Y)
        return theta_new, deficient, ()
    if rule == "D-LSI":
        # (229)-(230): both blocks use the previous iterate of the other block (Jacobi style)
        a_new, d1 = _lstsq(Phi, Y - Psi @ b_prev)
        b_new, d2 = _lstsq(Psi, Y - Phi @ a_prev)
        return np.concatenate([a_new, b_new]), d1 or d2, ()
    if rule == "GI":  # (164), (168)
        H = np.hstack([Phi, Psi])
        step = _gi_step(H, mu_a)
        return theta + step * (H.T @ (Y - H @ theta)), False, (step,)
    # D-GI (190)-(191): one shared residual, a separate step size per block (197)-(198)
    e = Y - Phi @ a_prev - Psi @ b_prev
    step_a, step_b = _gi_step(Phi, mu_a), _gi_step(Psi, mu_b)
    theta_new = np.concatenate([a_prev + step_a * (Phi.T @ e), b_prev + step_b * (Psi.T @ e)])
    return theta_new, False, (step_a, step_b)


# ---------------------------------------------------------------------------------- public
def fit_iterative(
    name: str,
    u: ArrayLike,
    y: ArrayLike,
    n: int,
    *,
    form: str = "observability",
    iterations: int = 50,
    tol: float = 1e-8,
    seed: int | np.random.SeedSequence | np.random.Generator | None = None,
    x: ArrayLike | None = None,
    mu: float | tuple[float, float] | None = None,
    p0: float = 1e6,
    kalman: tuple[float, float] = (0.0, 1.0),
) -> IterativeResult:
    """Run an iterative (batch) joint parameter and state estimator on ``L`` samples.

    Parameters
    ----------
    name
        ``"O-GI"``, ``"KF-GI"``, ``"O-D-GI"``, ``"KF-D-GI"``, ``"O-LSI"``, ``"KF-LSI"``,
        ``"O-D-LSI"``, ``"KF-D-LSI"`` (case-insensitive; the paper's ``"LSI-KF"`` spelling is
        accepted too), or a plain rule ``"GI"``, ``"D-GI"``, ``"LSI"``, ``"D-LSI"`` together
        with the true states ``x``.
    u, y
        Input and output samples ``u(1..L)``, ``y(1..L)``; equal lengths ``L > 2n``, finite.
    n
        Plant order (``>= 1``).
    form
        ``"observability"`` (the paper's section 4, eq. (146)-(153)) or ``"observer"`` (eq. (1),
        (8)); the paper notes the algorithms carry over unchanged.
    iterations
        Maximum number of iterations ``k``.
    tol
        Stop when ``||theta_k - theta_{k-1}|| <= tol``.
    seed
        Seed (int, ``SeedSequence`` or ``Generator``) of the random iteration-0 states, drawn
        ``N(0, s^2)`` with ``s`` the RMS of ``y`` (``1`` if ``y = 0``) so that ``H_1`` has the
        scale of the data.
    x
        True states ``x(1..L)``, shape ``(L, n)``; required by (and only allowed with) the plain
        rule names. ``H`` is then built once from ``x``; ``"LSI"`` gives batch least squares.
    mu
        GI step size(s): ``None`` (default) uses ``mu_k = 1 / lambda_max(H_k^T H_k)`` every
        iteration (D-GI: ``1 / lambda_max`` of ``Phi_k^T Phi_k`` and of ``Psi^T Psi``). A float
        (D-GI: a float or a pair ``(mu_a, mu_b)``) fixes it; exceeding the bound (168) warns.
    p0
        The paper's large number: ``theta_0 = 1_{2n} / p0`` and ``x_hat_k(1) = 1_n / p0``.
    kalman
        ``(q, r)``: the process-noise variance (times ``I``) and the measurement-noise weight of
        the Kalman filter; the paper's filter (258)-(263) is ``(0, 1)``.

    Returns
    -------
    IterativeResult

    Raises
    ------
    ValueError
        Bad name, form, lengths, non-finite data, ``n < 1``, ``L <= 2n``, bad options.
    NumericalHealthError
        The state re-estimation or the parameter update overflowed (e.g. an unstable
        ``A_hat_k`` driven open loop over a long batch); the message names the iteration.

    Examples
    --------
    With the true states, ``"LSI"`` is batch least squares and recovers the observer-form
    plant ``theta = [-1.2, 0.5, 1, 0.4]`` from noise-free data:

    >>> import numpy as np
    >>> from stcgym.adaptive import fit_iterative
    >>> A = np.array([[1.2, 1.0], [-0.5, 0.0]])
    >>> b = np.array([1.0, 0.4])
    >>> u = np.random.default_rng(0).standard_normal(50)
    >>> x = np.zeros((50, 2))
    >>> for t in range(49):
    ...     x[t + 1] = A @ x[t] + b * u[t]
    >>> res = fit_iterative("LSI", u, x[:, 0], 2, form="observer", x=x)
    >>> np.round(res.theta, 4), res.converged
    (array([-1.2,  0.5,  1. ,  0.4]), True)

    Gradient iteration (GI) on the same data converges to the same plant, and the result keeps
    every iterate and the step size ``mu_k`` of every iteration:

    >>> res = fit_iterative("GI", u, x[:, 0], 2, form="observer", x=x, iterations=2000)
    >>> res.name, res.converged, np.round(res.theta, 4)
    ('GI', True, array([-1.2,  0.5,  1. ,  0.4]))
    >>> res.theta_history.shape == (res.iterations + 1, 4), res.step_sizes.shape[1]
    (True, 1)
    >>> fit_iterative("LSI", u, x[:, 0], 2)
    Traceback (most recent call last):
    ...
    ValueError: the plain rule 'LSI' needs the true states x (shape (L, n)); ...
    """
    state_est, rule = parse_iterative_name(name)
    canonical = rule if state_est is None else f"{state_est}-{rule}"
    form = check_form(form)
    n = integer(n, "n")
    u_arr, y_arr = vector_pair(u, y, ("u", "y"), " L")
    L = u_arr.size
    if L <= 2 * n:
        raise ValueError(f"need L > 2n = {2 * n} samples for 2n = {2 * n} parameters, got L={L}")
    iterations = integer(iterations, "iterations")
    tol = non_negative(tol, "tol")
    p0 = positive(p0, "p0")
    if not isinstance(kalman, (tuple, list)) or len(kalman) != 2:
        raise ValueError(f"kalman must be a pair (q, r), got {kalman!r}")
    kalman_q = non_negative(kalman[0], "kalman q")
    kalman_r = positive(kalman[1], "kalman r")
    mu_a, mu_b = _parse_mu(mu, rule)

    if state_est is None:
        if x is None:
            raise ValueError(
                f"the plain rule {rule!r} needs the true states x (shape (L, n)); use "
                f"'O-{rule}' or 'KF-{rule}' to estimate them"
            )
        x_known = np.array(x, dtype=float)
        if x_known.ndim == 1 and n == 1:
            x_known = x_known.reshape(-1, 1)
        if x_known.shape != (L, n):
            raise ValueError(f"x must have shape (L, n) = {(L, n)}, got {x_known.shape}")
        if not np.all(np.isfinite(x_known)):
            raise ValueError("x must be finite")
        x_prev = x_known
    else:
        if x is not None:
            raise ValueError(f"x (known states) is only allowed with the plain rules {_RULES}")
        rng = np.random.default_rng(seed)
        scale = float(np.sqrt(np.mean(y_arr**2))) or 1.0
        x_prev = scale * rng.standard_normal((L, n))

    Y = y_arr
    Psi = _psi(u_arr, n)
    theta = np.full(2 * n, 1.0 / p0)
    history = [theta.copy()]
    steps: list[tuple[float, ...]] = []
    rank_deficient = False
    converged = False
    x1 = np.full(n, 1.0 / p0)
    k = 0
    for k in range(1, iterations + 1):  # noqa: B007 - k is reported after the loop
        Phi = _phi(x_prev, form)
        with np.errstate(over="ignore", invalid="ignore"):
            theta_new, deficient, step = _update(rule, Phi, Psi, Y, theta, mu_a, mu_b)
        rank_deficient |= deficient
        if step:
            steps.append(step)
        if not np.all(np.isfinite(theta_new)):
            raise NumericalHealthError(
                f"{canonical}: parameter update overflowed at iteration {k}; "
                f"last finite theta = {theta}"
            )
        delta = float(np.linalg.norm(theta_new - theta))
        theta = theta_new
        history.append(theta.copy())
        if state_est is not None:
            A_hat = companion_A(theta[:n], form)
            kf = STATE_ESTIMATORS[state_est].kalman  # the observer ignores q and r
            x_prev = _states(A_hat, theta[n:], u_arr, Y, x1, kf, kalman_q, kalman_r)
            if not np.all(np.abs(x_prev) <= STATE_LIMIT):  # also catches inf and NaN
                rho = float(np.max(np.abs(np.linalg.eigvals(A_hat))))
                raise NumericalHealthError(
                    f"{canonical}: state re-estimation overflowed at iteration {k} (spectral "
                    f"radius of A_hat_k = {rho:.4g} over L = {L} samples); theta_k = {theta}"
                )
        if delta <= tol:
            converged = True
            break

    step_arr = np.array(steps, dtype=float).reshape(len(steps), -1) if steps else np.zeros((0, 1))
    hist = np.array(history)
    for arr in (theta, hist, x_prev, step_arr):
        arr.flags.writeable = False
    return IterativeResult(
        name=canonical,
        form=form,
        theta=theta,
        theta_history=hist,
        x_hat=x_prev,
        iterations=k,
        converged=converged,
        flops_per_iteration=_flops.iterative(state_est, rule, n, L),
        step_sizes=step_arr,
        rank_deficient=rank_deficient,
    )


def _parse_mu(mu: float | tuple[float, float] | None, rule: str) -> tuple[float | None, ...]:
    if mu is None:
        return None, None
    if rule not in ("GI", "D-GI"):
        raise ValueError(f"mu (step size) only applies to the GI rules, not {rule!r}")
    if isinstance(mu, (tuple, list)):
        if rule != "D-GI" or len(mu) != 2:
            raise ValueError(
                "mu must be a positive float (GI) or a float or pair (mu_a, mu_b) (D-GI)"
            )
        return positive(mu[0], "mu_a"), positive(mu[1], "mu_b")
    m = positive(mu, "mu")
    return m, m
