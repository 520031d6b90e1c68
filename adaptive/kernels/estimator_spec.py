"""The estimators' configuration on the Python side: names, validation, the record and the config.

``spec = EstimatorSpec.build(name, n, **make_estimator_keywords)`` validates one estimator
configuration exactly like :func:`stcgym.adaptive.make_estimator` (which builds one itself) and
gives

* ``spec.layout`` -- the :class:`~stcgym.envs.compiled.Layout` of the estimator's record
  (fields :class:`EstimatorRecord`); ``spec.size`` floats per lane;
* ``spec.at`` -- the offsets of its fields in a record of its own, ``spec.record(base)`` the
  same inside a larger lane record starting at ``base``;
* ``spec.config`` -- the :class:`EstimatorConfig` every lane function takes;
* ``spec.initial_record()`` -- one lane's record at ``t = 0`` (shape ``(size,)``);
* ``spec.offset(name)`` -- the offset of a field, e.g. ``"theta"`` (2n), ``"x_hat"`` (n),
  ``"S"`` (2n x 2n, row-major: the upper-triangular factor of ``P = S S^T``; block-diagonal
  ``diag(S_a, S_b)`` for D- rules; absent (size 0) for SG/MISG), ``"P1"`` (n x n), ``"Q"``
  (n x n, the KF process-noise covariance, may be overwritten before every state step),
  ``"E"`` (p, the innovation ``E(p, t)``), ``"r"`` (2, SG/MISG normalisers).

The lane functions themselves are in :mod:`stcgym.adaptive.kernels.estimator`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.kernels.least_squares import upper_factor
from stcgym.adaptive.kernels.variants import ALGORITHMS, Rule, parse_name, variant
from stcgym.adaptive.kernels.variants import RULES as _RULES
from stcgym.adaptive.kernels.variants import STATE_ESTIMATORS as _STATES
from stcgym.envs.canonical import as_finite_vector, check_form
from stcgym.envs.compiled import Layout
from stcgym.envs.validation import (
    covariance,
    forgetting_factor,
    integer,
    one_of,
    positive,
    real_in,
)

__all__ = [
    "ALGORITHMS",
    "FIELDS",
    "REGRESSORS",
    "RULES",
    "STATE_ESTIMATORS",
    "EstimatorConfig",
    "EstimatorRecord",
    "EstimatorSpec",
    "parse_name",
    "upper_cholesky",
]

#: The rules' names (:data:`.variants.RULES` has what the code knows about each).
RULES: tuple[str, ...] = tuple(_RULES)
#: The state estimators' names (:data:`.variants.STATE_ESTIMATORS`).
STATE_ESTIMATORS: tuple[str, ...] = tuple(_STATES)
#: Which state estimate the regressor ``phi_hat`` is built from (see :meth:`EstimatorSpec.build`).
REGRESSORS: tuple[str, ...] = ("predicted", "filtered")
#: Frozen-signal defaults (see :mod:`.estimator`; calibrated in ``stcgym.adaptive.health``).
FROZEN_RATE = 1e-3
FROZEN_RATIO = 0.05
FROZEN_GAIN = 1e-3


class EstimatorRecord(NamedTuple):
    """Fields of the estimator's lane record (offsets; sizes set by :class:`EstimatorSpec`)."""

    theta: int  # theta_hat(t) (2n)
    S: int  # upper factor of P = S S^T (2n, 2n; empty for SG/MISG)
    S0: int  # the factor of P(0), for the safe reset
    r: int  # SG/MISG normalisers (2; empty for RLS/MILS)
    r0: int  # r(0)
    x_hat: int  # the state estimate x_hat(t) (n)
    x_init: int  # x_hat(1), for the state reset
    xs: int  # the last n state estimates (observability-form regressor (153))
    phi: int  # the regressor phi_hat(t+1) (2n)
    Phi: int  # the stacked Phi(p, t) (p, 2n)
    Y: int  # the stacked Y(p, t) (p)
    E: int  # the innovation E(p, t) (p)
    y: int  # the last y(t)
    K: int  # closed-loop observer gain (CO)
    P1: int  # Kalman covariance (KF)
    P1_init: int  # P1(1)
    Q: int  # Kalman process noise (KF)
    L1: int  # Kalman gain (KF)
    theta0: int  # theta(0) (finite window)
    hist_Phi: int  # the window's blocks (W, p, 2n)
    hist_Y: int  # (W, p)
    t: int  # time
    phase: int  # 1 between update and predict
    enabled: int  # adaptation switch
    n_resets: int
    n_state_resets: int
    n_kf_resets: int
    n_projections: int
    n_window_recomputes: int
    count: int  # blocks added to the window
    ewma_e2: int  # frozen signal: running means of e^2, y^2 and the gain q
    ewma_y2: int
    ewma_q: int
    frozen: int
    work: int  # scratch


#: Record fields in layout order.
FIELDS: tuple[str, ...] = EstimatorRecord._fields


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


def _read_only(values: tuple[float, ...]) -> NDArray:
    arr = np.array(values, dtype=np.float64)
    arr.setflags(write=False)
    return arr


def upper_cholesky(P: NDArray) -> NDArray:
    """Upper-triangular ``S`` with ``S S^T = P`` (``P`` symmetric positive definite)."""
    S = np.zeros_like(P)
    if not upper_factor(np.ascontiguousarray(P, dtype=float), S):
        raise ValueError("P is not symmetric positive definite")
    return S


@dataclass(frozen=True, eq=False)
class EstimatorSpec:
    """One validated estimator configuration: record layout, config arrays, initial record.

    Build it with :meth:`build` (the keywords of :func:`stcgym.adaptive.make_estimator`).
    ``theta0``, ``P0``, ``x_init``, ``P1_init``, ``Q`` are the per-lane initial values written
    by :meth:`initial_record`. ``observer_gain`` may be a callable (evaluated by the Python
    class before every state step); the lane functions read the gain ``K`` from the record.

    Parameters
    ----------
    name, n, p, form
        Canonical algorithm name (upper case), plant order, innovation length, canonical form.
    state, decomposed, rule
        The parts of ``name`` (:func:`parse_name`).
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
    >>> spec.initial_record().shape == (spec.size,)
    True
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

    # ---- construction ---------------------------------------------------------------------
    @classmethod
    def build(
        cls,
        name: str,
        n: int,
        *,
        p: int = 1,
        p0: float = 1e6,
        form: str = "observer",
        forgetting: float = 1.0,
        window: int | None = None,
        theta0: ArrayLike | None = None,
        P0: ArrayLike | None = None,
        r0: float | None = None,
        stacked_r: bool = False,
        x_init: ArrayLike | None = None,
        P1_init: ArrayLike | None = None,
        process_noise: ArrayLike | None = None,
        measurement_noise: float | None = None,
        observer_gain: Any = None,
        enabled: bool = True,
        on_failure: str = "reset",
        pd_check_every: int = 1,
        project_stable: bool = False,
        frozen_ratio: float = FROZEN_RATIO,
        regressor: str = "predicted",
        injection: float = 1.0,
        injection_warmup: int = 0,
        **rule_parameters: float,
    ) -> EstimatorSpec:
        """Validate ``make_estimator``'s arguments (a ``ValueError`` naming the argument).

        Parameters
        ----------
        name, n, **options
            As for :func:`stcgym.adaptive.make_estimator`, which documents each.

        Returns
        -------
        EstimatorSpec

        Raises
        ------
        ValueError
            An unknown name, or an argument out of its range, of the wrong shape or not
            applying to the rule or state estimator.
        """
        v = variant(name)
        state, decomposed, rule = v.state.name, v.decomposed, v.rule.name
        n = integer(n, "n", 1)
        p = integer(p, "p", 1)
        if not v.rule.multi_innovation and p != 1:
            multi = "/".join(r.name for r in _RULES.values() if r.multi_innovation)
            raise ValueError(
                f"p (innovation length) applies to {multi}; {rule} has p = 1, got p={p}"
            )
        p0 = positive(p0, "p0")
        form = check_form(form)
        lam = forgetting_factor(forgetting, "forgetting (lambda)")
        given = {"P0": P0 is not None, "r0": r0 is not None, "stacked_r": bool(stacked_r)}
        given.update(window=window is not None, forgetting=lam != 1.0)
        for keyword, is_given in given.items():
            if is_given and keyword not in v.rule.keywords:
                rules = "/".join(r.name for r in _RULES.values() if keyword in r.keywords)
                raise ValueError(f"{keyword} applies to {rules} rules only, not {rule}")
        least_squares = v.rule.covariance
        if window is not None:
            window = integer(window, "window", 1)
            if lam != 1.0:
                raise ValueError("window and forgetting < 1 are mutually exclusive")
        d = 2 * n
        theta0_arr = (
            np.full(d, 1.0 / p0) if theta0 is None else as_finite_vector(theta0, "theta0", length=d)
        )
        P0_mat = None
        if least_squares:
            P0_mat = p0 * np.eye(d) if P0 is None else covariance(P0, d, "P0")
            if decomposed and (np.any(P0_mat[:n, n:] != 0.0) or np.any(P0_mat[n:, :n] != 0.0)):
                raise ValueError(
                    "P0 must be block-diagonal diag(P_a, P_b) for D- rules (separate a and b "
                    "covariances)"
                )
        r0_val = 1.0 if r0 is None else positive(r0, "r0")
        x_init_arr = (
            np.full(n, 1.0 / p0) if x_init is None else as_finite_vector(x_init, "x_init", length=n)
        )
        kf = {
            "P1_init": P1_init,
            "process_noise": process_noise,
            "measurement_noise": measurement_noise,
        }
        P1 = Q = None
        R = 1.0
        gain: Any = None
        if state == "KF":
            if observer_gain is not None:
                raise ValueError("observer_gain applies to O/CO state estimators, not KF")
            P1 = np.eye(n) if P1_init is None else covariance(P1_init, n, "P1_init")
            Q = (
                np.zeros((n, n))
                if process_noise is None
                else covariance(process_noise, n, "process_noise", allow_singular=True)
            )
            if measurement_noise is not None:
                R = positive(measurement_noise, "measurement_noise")
        else:
            given = [k for k, v in kf.items() if v is not None]
            if given:
                raise ValueError(f"{', '.join(given)} apply to KF state estimators only")
            if state == "CO" and observer_gain is None:
                raise ValueError("CO (closed-loop observer) needs observer_gain=K (or a callable)")
            if observer_gain is not None:
                state = "CO"
                if callable(observer_gain):
                    gain = observer_gain
                else:
                    K = np.asarray(observer_gain, dtype=float)
                    if K.shape != (n,) or not np.all(np.isfinite(K)):
                        raise ValueError(
                            f"observer_gain must be a finite vector of length n={n} or a "
                            f"callable (a_hat, b_hat) -> K, got {observer_gain!r}"
                        )
                    gain = K.copy()
        one_of(on_failure, "on_failure", ("reset", "raise"))
        pd_check_every = integer(pd_check_every, "pd_check_every", 0)
        frozen_ratio = real_in(
            frozen_ratio, "frozen_ratio (math.inf: no frozen signal)", 0.0, lo_open=True
        )
        one_of(regressor, "regressor", REGRESSORS)
        if regressor == "filtered" and state == "CO":
            raise ValueError(
                "regressor='filtered' applies to the open-loop observer (O) and the Kalman filter "
                "(KF); the closed-loop observer (CO, observer_gain) has its own output injection"
            )
        injection = real_in(injection, "injection", 0.0, 1.0)
        injection_warmup = integer(injection_warmup, "injection_warmup", 0)
        partial = injection != 1.0 or injection_warmup != 0
        if partial and (state != "O" or regressor != "filtered"):
            raise ValueError(
                "injection and injection_warmup apply to the open-loop observer (O) with "
                f"regressor='filtered', not to {state} with regressor={regressor!r}"
            )
        canonical = f"{state}-{'D-' if decomposed else ''}{rule}"
        return cls(
            name=canonical,
            n=n,
            p=p,
            form=form,
            state=state,
            rule=rule,
            decomposed=decomposed,
            forgetting=lam,
            window=window,
            stacked_r=bool(stacked_r),
            project_stable=bool(project_stable),
            pd_check_every=pd_check_every,
            on_failure=on_failure,
            enabled=bool(enabled),
            theta0=theta0_arr,
            P0=P0_mat,
            r0=r0_val,
            x_init=x_init_arr,
            P1_init=P1,
            Q=Q,
            R=R,
            observer_gain=gain,
            frozen=(FROZEN_RATE, float(frozen_ratio), FROZEN_GAIN),
            regressor=regressor,
            injection=injection,
            injection_warmup=injection_warmup,
            rule_parameters=_rule_parameters(v.rule, rule_parameters),
        )

    def __post_init__(self) -> None:
        n, p, d = self.n, self.p, 2 * self.n
        v = variant(self.name)
        W = self.window or 0
        shapes: dict[str, tuple[int, ...]] = {
            "theta": (d,),
            "x_hat": (n,),
            "x_init": (n,),
            "xs": (n, n) if self.form == "observability" else (0,),
            "phi": (d,),
            "Phi": (p, d),
            "Y": (p,),
            "E": (p,),
            "theta0": (d,) if W else (0,),
            "hist_Phi": (W, p, d) if W else (0,),
            "hist_Y": (W, p) if W else (0,),
            # delta, K, w (2d), theta_prev / replay; E, E_old; saved S; A, x_next, 2 n^2 (KF)
            # x_hat(t|t) of the filtered regressor (n)
            "work": (5 * d + 2 * p + d * d + 3 * n * n + 2 * n,),
            **v.rule.fields(n, p),
            **v.state.fields(n),
        }
        # a field no variant of this configuration keeps is empty
        for name in ("S", "S0", "r", "r0", "K", "P1", "P1_init", "Q", "L1"):
            shapes.setdefault(name, (0,))
        layout = Layout()
        for name in FIELDS:
            layout.add(name, shapes.get(name, ()))
        config = EstimatorConfig(
            n=n,
            p=p,
            rule=v.rule.code,
            covariance=v.rule.covariance,
            normaliser=v.rule.normaliser,
            decomposed=bool(self.decomposed),
            state=v.state.code,
            observability=self.form == "observability",
            window=W,
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
            rule_parameters=_read_only(self.rule_parameters),
        )
        object.__setattr__(self, "layout", layout)
        object.__setattr__(self, "config", config)
        object.__setattr__(self, "at", layout.record(EstimatorRecord))

    # ---- the record -----------------------------------------------------------------------
    layout: Layout = field(init=False, repr=False)
    #: the lane functions' configuration
    config: EstimatorConfig = field(init=False, repr=False)
    #: offsets of the record's fields in a lane record of its own
    at: EstimatorRecord = field(init=False, repr=False)

    @property
    def size(self) -> int:
        """Floats per lane record."""
        return self.layout.size

    @property
    def normaliser(self) -> bool:
        """Whether the rule keeps the gradient normalisers ``r`` (SG, MISG)."""
        return variant(self.name).rule.normaliser

    @property
    def least_squares(self) -> bool:
        """Whether the rule keeps a covariance ``P = S S^T`` (RLS, MILS)."""
        return variant(self.name).rule.covariance

    def offset(self, name: str) -> int:
        """Offset of the field ``name`` relative to the start of the estimator record.

        Parameters
        ----------
        name : str
            A field of :attr:`layout`.

        Returns
        -------
        int
        """
        return self.layout.offset(name)

    def record(self, base: int = 0) -> EstimatorRecord:
        """Offsets of the record's fields when it starts at ``base`` of a larger lane record
        (the self-tuning controller embeds it at the start of its own).

        Parameters
        ----------
        base : int, default 0
            Offset of the estimator record inside the lane record.

        Returns
        -------
        EstimatorRecord
            The named offsets.
        """
        return self.layout.record(EstimatorRecord, base)

    def initial_record(self, theta0: NDArray | None = None, P0: NDArray | None = None) -> NDArray:
        """One lane's record at ``t = 0`` (``theta_hat(0)``, ``P(0)``, ``x_hat(1)``, ...),
        optionally with this lane's own ``theta0`` / ``P0``.

        Parameters
        ----------
        theta0 : ndarray, shape (2n,), optional
            This lane's ``theta_hat(0)`` (default the spec's).
        P0 : ndarray, shape (2n, 2n), optional
            This lane's ``P(0)`` (default the spec's; RLS/MILS rules).

        Returns
        -------
        ndarray, shape (size,)
        """
        lay = self.layout
        rec = lay.empty(1)
        th0 = self.theta0 if theta0 is None else theta0
        lay.view(rec, "theta")[0] = th0
        if self.window:
            lay.view(rec, "theta0")[0] = th0
        if self.least_squares:
            P = self.P0 if P0 is None else P0
            n = self.n
            if self.decomposed:
                S0 = np.zeros_like(P)
                S0[:n, :n] = upper_cholesky(P[:n, :n])
                S0[n:, n:] = upper_cholesky(P[n:, n:])
            else:
                S0 = upper_cholesky(P)
            lay.view(rec, "S")[0] = S0
            lay.view(rec, "S0")[0] = S0
        if variant(self.name).rule.normaliser:
            lay.view(rec, "r")[0] = self.r0
            lay.view(rec, "r0")[0] = self.r0
        lay.view(rec, "x_hat")[0] = self.x_init
        lay.view(rec, "x_init")[0] = self.x_init
        if self.state == "KF":
            lay.view(rec, "P1")[0] = self.P1_init
            lay.view(rec, "P1_init")[0] = self.P1_init
            lay.view(rec, "Q")[0] = self.Q
        if self.state == "CO" and not callable(self.observer_gain):
            lay.view(rec, "K")[0] = self.observer_gain
        lay.view(rec, "enabled")[0] = float(self.enabled)
        return rec[0]
