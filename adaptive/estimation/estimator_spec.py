"""The estimators' configuration on the Python side: names, validation, lane state, config.

``spec = EstimatorSpec.build(name, n, **make_estimator_keywords)`` validates one estimator
configuration exactly like :func:`stcgym.adaptive.make_estimator` (which builds one itself) and
gives

* ``spec.config`` -- the :class:`EstimatorConfig` every lane function takes;
* ``spec.make_state(B)`` / ``spec.make_work(B)`` -- the :class:`EstimatorState` and
  :class:`EstimatorWork` of ``B`` lanes: named tuples of batched arrays, lane ``i``'s field
  ``f`` being ``state.f[i]``, e.g. ``theta`` (2n), ``x_hat`` (n), ``S`` (2n x 2n: the
  upper-triangular factor of ``P = S S^T``; block-diagonal ``diag(S_a, S_b)`` for D- rules;
  size 0 for SG/MISG), ``P1`` (n x n), ``Q`` (n x n, the KF process-noise covariance, may be
  overwritten before every state step), ``E`` (p, the innovation ``E(p, t)``), ``r`` (2,
  SG/MISG normalisers);
* ``spec.shapes()`` -- the shape of every field of both, declared once;
* ``spec.initial_state()`` -- one lane's state at ``t = 0``.

The lane functions themselves are in :mod:`stcgym.adaptive.estimation.estimator`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.estimation.least_squares import upper_factor
from stcgym.adaptive.variants import ALGORITHMS, EstimatorName, Rule, parse_name, variant
from stcgym.adaptive.variants import RULES as _RULES
from stcgym.adaptive.variants import STATE_ESTIMATORS as _STATES
from stcgym.envs.canonical import as_finite_vector, check_form
from stcgym.lanes.compiled import lane_state, read_only, state_nbytes_per_lane
from stcgym.lanes.validation import (
    covariance,
    forgetting_factor,
    integer,
    one_of,
    positive,
    real_in,
)

__all__ = [
    "ALGORITHMS",
    "REGRESSORS",
    "EstimatorConfig",
    "EstimatorSettings",
    "EstimatorSpec",
    "EstimatorState",
    "EstimatorWork",
    "parse_name",
    "upper_cholesky",
]

#: Which state estimate the regressor ``phi_hat`` is built from (see :meth:`EstimatorSpec.build`).
REGRESSORS: tuple[str, ...] = ("predicted", "filtered")
#: Frozen-signal defaults (see :mod:`.estimator`; calibrated in
# ``stcgym.adaptive.estimation.health``).
FROZEN_RATE = 1e-3
FROZEN_RATIO = 0.05
FROZEN_GAIN = 1e-3


class EstimatorState(NamedTuple):
    """The estimator's lane state: field ``f`` of lane ``i`` is ``state.f[i]`` (a batch of
    ``B`` lanes holds ``(B, *shape)`` arrays; shapes in :meth:`EstimatorSpec.shapes`, ``d = 2n``,
    a field the configuration does not use has a zero in its shape)."""

    theta: NDArray  # theta_hat(t) (d)
    S: NDArray  # upper factor of P = S S^T (d, d; covariance rules)
    S0: NDArray  # the factor of P(0), for the safe reset
    r: NDArray  # SG/MISG normalisers (2)
    r0: NDArray  # r(0)
    x_hat: NDArray  # the state estimate x_hat(t) (n)
    x_init: NDArray  # x_hat(1), for the state reset
    xs: NDArray  # the last n state estimates (n, n; observability-form regressor (153))
    phi: NDArray  # the regressor phi_hat(t+1) (d)
    Phi: NDArray  # the stacked Phi(p, t) (p, d)
    Y: NDArray  # the stacked Y(p, t) (p)
    E: NDArray  # the innovation E(p, t) (p)
    y: NDArray  # the last y(t)
    K: NDArray  # closed-loop observer gain (n; CO)
    P1: NDArray  # Kalman covariance (n, n; KF)
    P1_init: NDArray  # P1(1)
    Q: NDArray  # Kalman process noise (n, n; KF)
    L1: NDArray  # Kalman gain (n; KF)
    theta0: NDArray  # theta(0) (d; finite window)
    hist_Phi: NDArray  # the window's blocks (W, p, d)
    hist_Y: NDArray  # (W, p)
    t: NDArray  # time (int)
    phase: NDArray  # True between update and predict
    enabled: NDArray  # adaptation switch
    n_resets: NDArray  # event counters (int)
    n_state_resets: NDArray
    n_kf_resets: NDArray
    n_projections: NDArray
    n_window_recomputes: NDArray
    count: NDArray  # blocks added to the window (int)
    ewma_e2: NDArray  # frozen signal: running means of e^2, y^2 and the gain q
    ewma_y2: NDArray
    ewma_q: NDArray
    frozen: NDArray  # the frozen flag


class EstimatorWork(NamedTuple):
    """The estimator's scratch, one row a lane (its content is irrelevant between calls)."""

    delta: NDArray  # the increment of theta (d)
    gain: NDArray  # the rule's P phi (the numerator of L(t), (33)); MILS: Phi^T E (d)
    factor_work: NDArray  # the least-squares factor updates' scratch (2d)
    theta_prev: NDArray  # theta(t-1) of the projection; the window's theta (d)
    E_replay: NDArray  # the innovation of a replayed block (p)
    E_old: NDArray  # the innovation of the block leaving the window (p)
    S_saved: NDArray  # a copy of S (d, d): the window's downdate, a restart's factor
    A: NDArray  # the model A_hat(t) (n, n)
    x_next: NDArray  # x_hat(t+1) (n)
    AP: NDArray  # the Kalman step's A P1 (n, n)
    P_upd: NDArray  # its P1(t+1) until it is accepted (n, n)
    x_reg: NDArray  # x_hat(t|t) of the filtered regressor (n)


#: Integer and boolean fields of :class:`EstimatorState` (the others are float64).
STATE_DTYPES: dict[str, Any] = {
    **dict.fromkeys(
        ("t", "count", "n_resets", "n_state_resets", "n_kf_resets", "n_projections",
         "n_window_recomputes"),
        np.int64,
    ),
    **dict.fromkeys(("phase", "enabled", "frozen"), np.bool_),
}  # fmt: skip


class EstimatorConfig(NamedTuple):
    """Configuration of the estimator's lane functions."""

    n: int
    p: int  # innovation length
    rule: int  # the rule's code (.variants.RULES)
    covariance: bool  # the rule keeps P = S S^T
    normaliser: bool  # the rule keeps the normalisers r
    decomposed: bool  # D- rule (a and b halves)
    state: int  # the state estimator's code (.variants.STATE_ESTIMATORS)
    observability: bool  # observability canonical form (else observer form)
    window: int  # finite history W (0: none)
    check_every: int  # factor health check every so many steps (0: never)
    stacked_r: bool  # MISG: one normaliser over the stacked window
    project_stable: bool  # reject updates to an unstable A_hat
    filtered: bool  # the regressor takes the measurement-corrected x_hat(t|t)
    forgetting: float  # lambda
    injection: float  # O filtered: the fraction of the deadbeat injection after the warm-up
    injection_warmup: int  # O filtered: steps with the whole injection
    R: float  # Kalman measurement-noise variance
    frozen_rate: float
    frozen_ratio: float
    frozen_gain: float
    rule_parameters: NDArray  # the rule's own parameters (.variants.Rule.parameters), in order


def _rule_parameters(rule: Rule, given: dict[str, Any]) -> tuple[float, ...]:
    """The validated values of ``rule``'s own parameters (defaults where not ``given``); a
    keyword of another rule is a ``ValueError``, a keyword of no rule a ``TypeError``."""
    own = {q.name: q for q in rule.parameters}
    for keyword in given:
        if keyword not in own:
            rules = [r.name for r in _RULES.values() if keyword in {q.name for q in r.parameters}]
            if not rules:
                raise TypeError(f"make_estimator() got an unexpected keyword argument {keyword!r}")
            raise ValueError(f"{keyword} applies to {'/'.join(rules)} rules only, not {rule.name}")
    return tuple(q.check(given.get(q.name, q.default)) for q in rule.parameters)


def _states_with(kalman: bool) -> str:
    """The names of the state estimators that are (or are not) Kalman filters, ``"O/CO"``."""
    return "/".join(e.name for e in _STATES.values() if e.kalman == kalman)


def _initial_vector(value: ArrayLike | None, name: str, length: int, p0: float) -> NDArray:
    """The given initial vector, finite and of ``length``, or the paper's default ``1/p0``
    in every entry (``theta_hat(0)``, ``x_hat(1)``)."""
    if value is None:
        return np.full(length, 1.0 / p0)
    return as_finite_vector(value, name, length=length)


def upper_cholesky(P: NDArray) -> NDArray:
    """Upper-triangular ``S`` with ``S S^T = P`` (``P`` symmetric positive definite)."""
    S = np.zeros_like(P)
    if not upper_factor(np.ascontiguousarray(P, dtype=float), S):
        raise ValueError("P is not symmetric positive definite")
    return S


@dataclass(frozen=True, kw_only=True)
class EstimatorSettings:
    """The settings of a recursive estimator: the keywords of
    :func:`stcgym.adaptive.make_estimator` besides ``name``, ``n``, ``num_envs`` and a rule's
    own parameters, with their defaults (each documented there). Not checked here:
    :meth:`EstimatorSpec.build` validates them against the estimator they are for.

    >>> from stcgym.adaptive import EstimatorSettings, EstimatorSpec
    >>> tracking = EstimatorSettings(p=3, forgetting=0.98)
    >>> EstimatorSpec.build("KF-MILS", 2, tracking).forgetting
    0.98
    """

    p: int = 1
    p0: float = 1e6
    form: str = "observer"
    forgetting: float = 1.0
    window: int | None = None
    theta0: ArrayLike | None = None
    P0: ArrayLike | None = None
    r0: float | None = None
    stacked_r: bool = False
    x_init: ArrayLike | None = None
    P1_init: ArrayLike | None = None
    process_noise: ArrayLike | None = None
    measurement_noise: float | None = None
    observer_gain: Any = None
    enabled: bool = True
    on_failure: str = "reset"
    pd_check_every: int = 1
    project_stable: bool = False
    frozen_ratio: float = FROZEN_RATIO
    regressor: str = "predicted"
    injection: float = 1.0
    injection_warmup: int = 0


_SETTINGS = frozenset(f.name for f in fields(EstimatorSettings))


@dataclass(frozen=True, eq=False)
class EstimatorSpec:
    """One validated estimator configuration: lane-state shapes, configuration, initial state.

    Build it with :meth:`build` (the keywords of :func:`stcgym.adaptive.make_estimator`).
    ``theta0``, ``P0``, ``x_init``, ``P1_init``, ``Q`` are the per-lane initial values written
    by :meth:`initial_state`. ``observer_gain`` may be a callable (evaluated by the Python
    class before every state step); the lane functions read the gain ``K`` from the state.

    Parameters
    ----------
    name, n, p, form
        Canonical algorithm name (upper case), plant order, innovation length, canonical form.
    state, decomposed, rule
        The parts of ``name`` (:func:`parse_name`); :attr:`variant` holds their registry
        entries.
    forgetting, window, stacked_r, project_stable, pd_check_every, on_failure, enabled
        As for :func:`stcgym.adaptive.make_estimator`.
    theta0, P0, r0, x_init, P1_init, Q, R, observer_gain
        Initial values and filter settings (``P0`` ``None`` for SG/MISG rules; ``P1_init``
        and ``Q`` ``None`` unless the state estimator is ``KF``).
    frozen : tuple of 3 floats
        ``(rate, ratio, gain)`` of the "frozen on a wrong model" signal.
    regressor : {"predicted", "filtered"}
        The state estimate ``phi_hat`` is built from.
    injection, injection_warmup
        ``O`` with ``regressor="filtered"``: the fraction of the deadbeat output injection
        after the first ``injection_warmup`` steps (1 and 0: the whole injection throughout).

    Raises
    ------
    ValueError
        From :meth:`build`: an argument out of its range or shape, or one that does not
        apply to the rule or state estimator (``P0`` for SG, ``r0`` for RLS,
        ``process_noise`` for ``O``, ...), naming it.

    Examples
    --------
    >>> from stcgym.adaptive import EstimatorSpec
    >>> spec = EstimatorSpec.build("kf-d-mils", 2, p=3)
    >>> spec.name, spec.state, spec.decomposed, spec.rule
    ('KF-D-MILS', 'KF', True, 'MILS')
    >>> spec.initial_state().theta.shape  # one lane of EstimatorState
    (1, 4)
    >>> EstimatorSpec.build("O-RLS", 2, r0=2.0)
    Traceback (most recent call last):
    ...
    ValueError: r0 applies to SG/MISG rules only, not RLS
    """

    name: str
    n: int
    p: int
    form: str
    state: str
    rule: str
    decomposed: bool
    forgetting: float
    window: int | None
    stacked_r: bool
    project_stable: bool
    pd_check_every: int
    on_failure: str
    enabled: bool
    theta0: NDArray = field(repr=False)
    P0: NDArray | None = field(repr=False)
    r0: float = 1.0
    x_init: NDArray = field(default=None, repr=False)  # type: ignore[assignment]
    P1_init: NDArray | None = field(default=None, repr=False)
    Q: NDArray | None = field(default=None, repr=False)
    R: float = 1.0
    observer_gain: Any = field(default=None, repr=False)
    frozen: tuple[float, float, float] = (FROZEN_RATE, FROZEN_RATIO, FROZEN_GAIN)
    regressor: str = "predicted"
    injection: float = 1.0
    injection_warmup: int = 0
    #: the values of the rule's own parameters (:attr:`.variants.Rule.parameters`), in order
    rule_parameters: tuple[float, ...] = ()
    #: the registry entries of ``name`` (resolved from it when not given)
    variant: EstimatorName = field(default=None, repr=False, compare=False)  # type: ignore[assignment]

    # ---- construction ---------------------------------------------------------------------
    @classmethod
    def build(
        cls,
        name: str | EstimatorName,
        n: int,
        settings: EstimatorSettings | None = None,
        **options: Any,
    ) -> EstimatorSpec:
        """Validate ``make_estimator``'s arguments (a ``ValueError`` naming the argument).

        Parameters
        ----------
        name, n
            As for :func:`stcgym.adaptive.make_estimator`; ``name`` may be the registry's
            record of a name already resolved (:func:`.variants.variant`).
        settings
            The estimator's settings (default: :class:`EstimatorSettings`'s defaults).
        **options
            Settings by keyword, as :func:`stcgym.adaptive.make_estimator` takes them (each
            replaces the one of ``settings``), and the rule's own parameters.

        Returns
        -------
        EstimatorSpec

        Raises
        ------
        ValueError
            An unknown name, or an argument out of its range, of the wrong shape or not
            applying to the rule or state estimator.
        """
        given = {k: options.pop(k) for k in list(options) if k in _SETTINGS}
        s = replace(settings or EstimatorSettings(), **given)
        rule_parameters = options
        v = name if isinstance(name, EstimatorName) else variant(name)
        decomposed, rule = v.decomposed, v.rule.name
        n = integer(n, "n", 1)
        p = integer(s.p, "p", 1)
        if not v.rule.multi_innovation and p != 1:
            multi = "/".join(r.name for r in _RULES.values() if r.multi_innovation)
            raise ValueError(
                f"p (innovation length) applies to {multi}; {rule} has p = 1, got p={p}"
            )
        p0 = positive(s.p0, "p0")
        form = check_form(s.form)
        lam = forgetting_factor(s.forgetting, "forgetting (lambda)")
        given = {"P0": s.P0 is not None, "r0": s.r0 is not None, "stacked_r": bool(s.stacked_r)}
        given.update(window=s.window is not None, forgetting=lam != 1.0)
        for keyword, is_given in given.items():
            if is_given and keyword not in v.rule.keywords:
                rules = "/".join(r.name for r in _RULES.values() if keyword in r.keywords)
                raise ValueError(f"{keyword} applies to {rules} rules only, not {rule}")
        least_squares = v.rule.covariance
        window = s.window
        if window is not None:
            window = integer(window, "window", 1)
            if lam != 1.0:
                raise ValueError("window and forgetting < 1 are mutually exclusive")
        d = 2 * n
        theta0_arr = _initial_vector(s.theta0, "theta0", d, p0)
        P0_mat = None
        if least_squares:
            P0_mat = p0 * np.eye(d) if s.P0 is None else covariance(s.P0, d, "P0")
            if decomposed and (np.any(P0_mat[:n, n:] != 0.0) or np.any(P0_mat[n:, :n] != 0.0)):
                raise ValueError(
                    "P0 must be block-diagonal diag(P_a, P_b) for D- rules (separate a and b "
                    "covariances)"
                )
        r0_val = 1.0 if s.r0 is None else positive(s.r0, "r0")
        x_init_arr = _initial_vector(s.x_init, "x_init", n, p0)
        P1 = Q = None
        R = 1.0
        gain: Any = None
        if v.state.kalman:
            if s.observer_gain is not None:
                raise ValueError(
                    f"observer_gain applies to {_states_with(False)} state estimators, not "
                    f"{v.state.name}"
                )
            P1 = np.eye(n) if s.P1_init is None else covariance(s.P1_init, n, "P1_init")
            Q = (
                np.zeros((n, n))
                if s.process_noise is None
                else covariance(s.process_noise, n, "process_noise", allow_singular=True)
            )
            if s.measurement_noise is not None:
                R = positive(s.measurement_noise, "measurement_noise")
        else:
            kf = ("P1_init", "process_noise", "measurement_noise")
            given = [k for k in kf if getattr(s, k) is not None]
            if given:
                raise ValueError(
                    f"{', '.join(given)} apply to {_states_with(True)} state estimators only"
                )
            if v.state.observer_gain and s.observer_gain is None:
                raise ValueError(
                    f"{v.state.name} (closed-loop observer) needs observer_gain=K (or a callable)"
                )
            if s.observer_gain is not None:  # the closed-loop observer on that gain
                v = v._replace(state=next(e for e in _STATES.values() if e.observer_gain))
                if callable(s.observer_gain):
                    gain = s.observer_gain
                else:
                    K = np.asarray(s.observer_gain, dtype=float)
                    if K.shape != (n,) or not np.all(np.isfinite(K)):
                        raise ValueError(
                            f"observer_gain must be a finite vector of length n={n} or a "
                            f"callable (a_hat, b_hat) -> K, got {s.observer_gain!r}"
                        )
                    gain = K.copy()
        one_of(s.on_failure, "on_failure", ("reset", "raise"))
        pd_check_every = integer(s.pd_check_every, "pd_check_every", 0)
        frozen_ratio = real_in(
            s.frozen_ratio, "frozen_ratio (math.inf: no frozen signal)", 0.0, lo_open=True
        )
        one_of(s.regressor, "regressor", REGRESSORS)
        if s.regressor == "filtered" and not v.state.filtered_regressor:
            raise ValueError(
                "regressor='filtered' applies to the open-loop observer (O) and the Kalman filter "
                "(KF); the closed-loop observer (CO, observer_gain) has its own output injection"
            )
        injection = real_in(s.injection, "injection", 0.0, 1.0)
        injection_warmup = integer(s.injection_warmup, "injection_warmup", 0)
        partial = injection != 1.0 or injection_warmup != 0
        if partial and (not v.state.injection or s.regressor != "filtered"):
            raise ValueError(
                "injection and injection_warmup apply to the open-loop observer (O) with "
                f"regressor='filtered', not to {v.state.name} with regressor={s.regressor!r}"
            )
        return cls(
            name=v.name,
            n=n,
            p=p,
            form=form,
            state=v.state.name,
            rule=rule,
            decomposed=decomposed,
            forgetting=lam,
            window=window,
            stacked_r=bool(s.stacked_r),
            project_stable=bool(s.project_stable),
            pd_check_every=pd_check_every,
            on_failure=s.on_failure,
            enabled=bool(s.enabled),
            theta0=theta0_arr,
            P0=P0_mat,
            r0=r0_val,
            x_init=x_init_arr,
            P1_init=P1,
            Q=Q,
            R=R,
            observer_gain=gain,
            frozen=(FROZEN_RATE, float(frozen_ratio), FROZEN_GAIN),
            regressor=s.regressor,
            injection=injection,
            injection_warmup=injection_warmup,
            rule_parameters=_rule_parameters(v.rule, rule_parameters),
            variant=v,
        )

    def __post_init__(self) -> None:
        if self.variant is None:
            object.__setattr__(self, "variant", variant(self.name))
        v = self.variant
        config = EstimatorConfig(
            n=self.n,
            p=self.p,
            rule=v.rule.code,
            covariance=v.rule.covariance,
            normaliser=v.rule.normaliser,
            decomposed=bool(self.decomposed),
            state=v.state.code,
            observability=self.form == "observability",
            window=self.window or 0,
            check_every=int(self.pd_check_every),
            stacked_r=bool(self.stacked_r),
            project_stable=bool(self.project_stable),
            filtered=self.regressor == "filtered",
            forgetting=float(self.forgetting),
            injection=float(self.injection),
            injection_warmup=int(self.injection_warmup),
            R=float(self.R),
            frozen_rate=float(self.frozen[0]),
            frozen_ratio=float(self.frozen[1]),
            frozen_gain=float(self.frozen[2]),
            rule_parameters=read_only(self.rule_parameters),
        )
        object.__setattr__(self, "config", config)

    #: the lane functions' configuration
    config: EstimatorConfig = field(init=False, repr=False)

    def shapes(self) -> tuple[dict[str, tuple[int, ...]], dict[str, tuple[int, ...]]]:
        """The shapes of one lane's :class:`EstimatorState` and :class:`EstimatorWork` fields:
        the one place they are declared (a field the rule or state estimator does not keep
        has a zero in its shape, with the dimensions the lane functions index it by)."""
        n, p, d = self.n, self.p, 2 * self.n
        v = self.variant
        W = self.window or 0
        state: dict[str, tuple[int, ...]] = {
            "theta": (d,),
            "S": (0, 0),
            "S0": (0, 0),
            "r": (0,),
            "r0": (0,),
            "x_hat": (n,),
            "x_init": (n,),
            "xs": (n if self.form == "observability" else 0, n),
            "phi": (d,),
            "Phi": (p, d),
            "Y": (p,),
            "E": (p,),
            "K": (0,),
            "P1": (0, 0),
            "P1_init": (0, 0),
            "Q": (0, 0),
            "L1": (0,),
            "theta0": (d if W else 0,),
            "hist_Phi": (W, p, d),
            "hist_Y": (W, p),
            **v.rule.fields(n, p),  # the rule's and the state estimator's own fields
            **v.state.fields(n),
        }
        for scalar in EstimatorState._fields:
            state.setdefault(scalar, ())
        work = {
            "delta": (d,), "gain": (d,), "factor_work": (2 * d,), "theta_prev": (d,),
            "E_replay": (p,), "E_old": (p,), "S_saved": (d, d), "A": (n, n), "x_next": (n,),
            "AP": (n, n), "P_upd": (n, n), "x_reg": (n,),
        }  # fmt: skip
        return state, work

    def make_state(self, num_lanes: int) -> EstimatorState:
        """A zeroed :class:`EstimatorState` of ``num_lanes`` lanes (:meth:`initial_state`
        holds the values at ``t = 0``)."""
        return lane_state(EstimatorState, self.shapes()[0], num_lanes, STATE_DTYPES)

    def make_work(self, num_lanes: int) -> EstimatorWork:
        """The scratch of ``num_lanes`` lanes."""
        return lane_state(EstimatorWork, self.shapes()[1], num_lanes)

    @property
    def nbytes_per_lane(self) -> int:
        """Bytes of one lane's state and scratch."""
        return state_nbytes_per_lane(self.make_state(1)) + state_nbytes_per_lane(self.make_work(1))

    @property
    def normaliser(self) -> bool:
        """Whether the rule keeps the gradient normalisers ``r`` (SG, MISG)."""
        return self.variant.rule.normaliser

    @property
    def least_squares(self) -> bool:
        """Whether the rule keeps a covariance ``P = S S^T`` (RLS, MILS)."""
        return self.variant.rule.covariance

    def initial_state(
        self, theta0: NDArray | None = None, P0: NDArray | None = None
    ) -> EstimatorState:
        """One lane's state at ``t = 0`` (``theta_hat(0)``, ``P(0)``, ``x_hat(1)``, ...),
        optionally with this lane's own ``theta0`` / ``P0``.

        Parameters
        ----------
        theta0 : ndarray, shape (2n,), optional
            This lane's ``theta_hat(0)`` (default the spec's).
        P0 : ndarray, shape (2n, 2n), optional
            This lane's ``P(0)`` (default the spec's; RLS/MILS rules).

        Returns
        -------
        EstimatorState
            One lane (row 0 of every field).
        """
        s = self.make_state(1)
        th0 = self.theta0 if theta0 is None else theta0
        s.theta[0] = th0
        if self.window:
            s.theta0[0] = th0
        if self.least_squares:
            P = self.P0 if P0 is None else P0
            n = self.n
            if self.decomposed:
                S0 = np.zeros_like(P)
                S0[:n, :n] = upper_cholesky(P[:n, :n])
                S0[n:, n:] = upper_cholesky(P[n:, n:])
            else:
                S0 = upper_cholesky(P)
            s.S[0] = S0
            s.S0[0] = S0
        if self.normaliser:
            s.r[0] = self.r0
            s.r0[0] = self.r0
        s.x_hat[0] = self.x_init
        s.x_init[0] = self.x_init
        if self.variant.state.kalman:
            s.P1[0] = self.P1_init
            s.P1_init[0] = self.P1_init
            s.Q[0] = self.Q
        if self.variant.state.observer_gain and not callable(self.observer_gain):
            s.K[0] = self.observer_gain
        s.enabled[0] = self.enabled
        return s
