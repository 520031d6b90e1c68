"""The recursive estimators of Ding & Ma (2014) by name: :func:`make_estimator`.

A paper name (``"O-SG"`` ... ``"KF-D-MILS"``, case-insensitive; ``"CO-..."`` for the
closed-loop observer) is resolved by the registry (:func:`stcgym.adaptive.variants.variant`),
the keywords are validated by
:meth:`~stcgym.adaptive.estimation.estimator_spec.EstimatorSpec.build`, and per-lane initial
values (``num_envs=B``) are checked here. The estimator itself, with the
algorithms, the time convention and the two half-steps, is
:class:`stcgym.adaptive.estimation.recursive.RecursiveEstimator`.
"""

from __future__ import annotations

import dataclasses
import inspect
from typing import TYPE_CHECKING, Any

import numpy as np

from stcgym.adaptive.estimation.estimator_spec import EstimatorSettings, EstimatorSpec
from stcgym.envs.lanes import lane_rows
from stcgym.lanes.validation import covariance, integer

if TYPE_CHECKING:
    from stcgym.adaptive.estimation.recursive import RecursiveEstimator

__all__ = ["make_estimator"]


def make_estimator(
    name: str, n: int, *, num_envs: int | None = None, **options: Any
) -> RecursiveEstimator:
    """Build one of the paper's recursive estimators by name, for one plant or ``num_envs``.

    Parameters
    ----------
    name : str
        ``"<state>-[D-]<rule>"``, case-insensitive: state ``O`` (open-loop observer (46)),
        ``KF`` (Kalman filter (66)) or ``CO`` (closed-loop observer (50), needs
        ``observer_gain``); rule ``SG``, ``MISG``, ``RLS``, ``MILS``; ``D-`` for model
        decomposition. The 16 paper names are in :data:`ALGORITHMS`. ``O-...`` together with
        ``observer_gain`` also gives the closed-loop observer.
    n : int
        Plant order (``theta`` has ``2n`` entries), ``n >= 1``.
    p : int
        Innovation length ``p >= 1`` (MISG/MILS; must be 1 for SG/RLS).
    p0 : float
        The paper's large number: ``theta_hat(0) = 1/p0``, ``P(0) = p0 I``, ``x_hat(1) = 1/p0``.
    form : {"observer", "observability"}
        Canonical form of the plant (regressor (9) or (153), ``A_hat`` (47) or (146)).
    forgetting : float
        ``lambda`` in ``(0, 1]``. RLS/MILS: ``P^{-1}(t) = lambda P^{-1}(t-1) + Phi Phi^T``.
        SG/MISG: ``r(t) = lambda r(t-1) + ||phi||^2`` (keeps the step from vanishing).
    window : int, optional
        Finite history of ``W`` samples (RLS/MILS only, exclusive with ``forgetting < 1``):
        exact regularised least squares over the last ``W`` data blocks by downdating.
    theta0 : array_like, shape (2n,) (or (B, 2n) per lane), optional
        ``theta_hat(0)`` (default ``1/p0``).
    P0 : float, array_like (2n,) or (2n, 2n) (or (B, 2n, 2n) per lane), optional
        ``P(0)`` (RLS/MILS only; block-diagonal for D- rules). Default ``p0 I``.
    r0 : float, optional
        ``r(0)`` of SG/MISG rules (default 1).
    stacked_r : bool
        MISG: ``r(t) = r(t-1) + ||Phi(p, t)||^2`` (remark 1, (116)-(117)).
    x_init : array_like, shape (n,), optional
        ``x_hat(1)`` (default ``1/p0``).
    P1_init, process_noise, measurement_noise :
        Kalman filter only: ``P1(1)`` (default ``I``), ``Q`` (default 0), ``R`` (default 1) --
        the paper's filter. With ``Q = 0`` the gain dies out after a few tens of steps.
    observer_gain : array_like (n,) or callable ``(a_hat, b_hat) -> (n,)``, optional
        Gain ``K`` of the closed-loop observer (50) (``CO-...`` names, or ``O-...``).
    enabled : bool
        Initial adaptation switch.
    on_failure : {"reset", "raise"}
        Action on loss of positive definiteness / overflow (see
        :mod:`stcgym.adaptive.estimation.health`).
    pd_check_every : int
        Run the factor health check every this many steps (default 1, it costs ``O(n^2)``;
        ``0``: only the overflow checks).
    project_stable : bool
        Not in the paper: reject a parameter update whose ``A_hat(t)`` is not Schur stable
        (keep ``theta_hat(t-1)``, ``P(t)`` as updated), the projection of pseudo-linear
        regression methods (Ljung & Soderstrom 1983).
    frozen_ratio : float
        RLS/MILS (and D-) only: the "frozen on a wrong model" signal switches on when, after
        the gain ``phi^T P phi`` has fallen below ``1e-3``, the mean innovation power exceeds
        ``frozen_ratio`` times the mean output power (default 0.05: the model explains less
        than 95 % of the output). On data whose noise exceeds that share of the output power
        raise it (``math.inf`` disables the signal). See :mod:`stcgym.adaptive.estimation.health`.
    regressor : {"predicted", "filtered"}
        State estimate the regressor ``phi_hat`` is built from. ``"predicted"`` (default): the
        paper's ``x_hat(t)`` of (46)/(66). ``"filtered"`` (not in the paper; for closed-loop
        use, where the self-tuning controller takes it): the measurement-corrected
        ``x_hat(t|t) = x_hat(t) + g [y(t) - c x_hat(t)]`` with the Kalman gain
        ``g = P1 c^T / (R + c P1 c^T)`` (``KF``), or ``g = A_hat^{n-1} e_n`` (``c g = 1``:
        ``x1_hat(t|t) = y(t)``) with the state propagated from ``x_hat(t|t)`` (``O``: the
        closed-loop observer (50) with the deadbeat gain ``K = A_hat g``). Not for ``CO``.
        Details in
        :mod:`stcgym.adaptive.estimation.estimator`.
    injection : float
        ``O`` with ``regressor="filtered"`` only: after the warm-up the injection is
        ``injection * g``, in ``[0, 1]`` (default 1: the deadbeat injection throughout; the
        closed-loop observer (50) with ``K = injection * A_hat g``, whose error dynamics in the
        observer form have the characteristic polynomial ``z^n + (1 - injection) a(z)``).
    injection_warmup : int
        ``O`` with ``regressor="filtered"`` only: the first steps, ``>= 0``, with the whole
        injection (default 0).
    num_envs : int, optional
        Number of lanes ``B`` stepped together (``None``: one plant). The same class either way.
    **rule_parameters
        The parameters of a rule of its own: each rule of
        :data:`stcgym.adaptive.variants.RULES` declares them (``Rule.parameters``:
        name, default, range).

    Returns
    -------
    RecursiveEstimator
        At ``t = 0``; ``num_envs`` lanes of it when ``num_envs`` is given.

    Raises
    ------
    ValueError
        An unknown ``name``, or an option out of its range or of the wrong shape, naming it.
    TypeError
        An unknown keyword.

    Examples
    --------
    >>> from stcgym.adaptive import make_estimator
    >>> est = make_estimator("kf-mils", 2, p=3)
    >>> est.name, est.n, est.p, est.form
    ('KF-MILS', 2, 3, 'observer')
    >>> batch = make_estimator("O-RLS", 2, num_envs=4)
    >>> batch.theta.shape
    (4, 4)
    >>> make_estimator("O-RLS", 2, forgetting=2)
    Traceback (most recent call last):
    ...
    ValueError: forgetting (lambda) must lie in (0, 1], got 2
    """
    make_estimator.__signature__.bind(name, n, **options)  # a TypeError: an unknown keyword
    theta0, P0 = options.get("theta0"), options.get("P0")
    lane_theta0 = lane_P0 = None
    if num_envs is not None:
        B = num_envs = integer(num_envs, "num_envs")
        d = 2 * int(n) if isinstance(n, (int, np.integer)) else 0
        if theta0 is not None and np.ndim(theta0) == 2:
            lane_theta0 = lane_rows(np.array(theta0, dtype=float), B, d, "theta0")
            options["theta0"] = lane_theta0[0]
        if P0 is not None and np.ndim(P0) == 3:
            P0_arr = np.asarray(P0, dtype=float)
            if P0_arr.shape != (B, d, d):
                raise ValueError(f"per-lane P0 must have shape ({B}, {d}, {d})")
            lane_P0 = np.array([covariance(M, d, "P0") for M in P0_arr])
            options["P0"] = lane_P0[0]
    spec = EstimatorSpec.build(name, n, **options)
    if lane_P0 is not None and spec.decomposed:
        n_ = spec.n
        if np.any(lane_P0[:, :n_, n_:] != 0.0) or np.any(lane_P0[:, n_:, :n_] != 0.0):
            raise ValueError("per-lane P0 must be block-diagonal diag(P_a, P_b) for D- rules")
    from stcgym.adaptive.estimation.recursive import RecursiveEstimator  # imports this module

    return RecursiveEstimator(spec, num_envs, lane_theta0=lane_theta0, lane_P0=lane_P0)


# One source of truth for the keywords: make_estimator takes EstimatorSettings' fields (which
# EstimatorSpec.build validates) plus num_envs and the rules' own parameters; help() and
# inspect show that combined signature.
_KEYWORD = inspect.Parameter.KEYWORD_ONLY
make_estimator.__signature__ = inspect.Signature(  # type: ignore[attr-defined]
    [
        inspect.Parameter("name", inspect.Parameter.POSITIONAL_OR_KEYWORD, annotation="str"),
        inspect.Parameter("n", inspect.Parameter.POSITIONAL_OR_KEYWORD, annotation="int"),
        *(
            inspect.Parameter(f.name, _KEYWORD, default=f.default, annotation=f.type)
            for f in dataclasses.fields(EstimatorSettings)
        ),
        inspect.Parameter("num_envs", _KEYWORD, default=None, annotation="int | None"),
        inspect.Parameter("rule_parameters", inspect.Parameter.VAR_KEYWORD, annotation="float"),
    ],
    return_annotation="RecursiveEstimator",
)
