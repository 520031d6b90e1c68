"""The registry of variants: every parameter rule, state estimator, estimator and design,
declared once.

Each entry says what the rest of the code needs to know about its variant, so that adding one
is an entry here plus its lane function (the recipes: the contributors' page of the
documentation):

* :class:`Rule` (:data:`RULES`): the parameter update of the estimator -- whether it keeps
  a covariance ``P = S S^T`` or a normaliser ``r``, whether the innovation length ``p`` may
  exceed 1, the keywords that apply to it (and its own parameters, with their defaults and
  ranges), the lane-state fields it keeps, its flops per step, and whether it holds the
  self-tuning loop;
* :class:`StateEstimator` (:data:`STATE_ESTIMATORS`): the state estimate of the regressor --
  lane-state fields, flops, the self-tuning controller's default ``p0``;
* :class:`ExtendedLS` (:data:`CONTROLLER_ESTIMATORS`): an estimator of the self-tuning
  controller outside the paper's ``<state>-[D-]<rule>`` names, extended least squares;
* :class:`Design` (:data:`DESIGNS`): the certainty-equivalence design of the self-tuning
  controller -- the compiled design it runs (:class:`CompiledDesign`: its lane function, its
  compiled argument, lane state and scratch), its parameters and the known-model oracle that
  applies the same design to the true model.

A name is resolved once into its record: :func:`variant` (``"KF-D-MILS"`` ->
:class:`EstimatorName`), :func:`controller_estimator` (``"ELS"`` or a paper name), and
:func:`compiled_version` maps an estimator and a design to the version of the controller step
that is compiled for them. Everything else reads the record's fields, never the name. Each
entry's compile-time ``code`` is its position in its table, assigned here; the lane functions
compare codes for equality only (never an order between variants).
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

from stcgym.adaptive.estimation import flops as _flops
from stcgym.lanes.validation import real_in

__all__ = [
    "ALGORITHMS",
    "CONTROLLER_ESTIMATORS",
    "DESIGNS",
    "PLACEMENT",
    "RULES",
    "STATE_ESTIMATORS",
    "CompiledDesign",
    "CompiledVersion",
    "Design",
    "EstimatorName",
    "ExtendedLS",
    "Parameter",
    "Rule",
    "StateEstimator",
    "compiled_design",
    "compiled_version",
    "controller_estimator",
    "parse_name",
    "variant",
]

Shapes = Callable[[int, int], dict[str, tuple[int, ...]]]


@dataclass(frozen=True)
class Parameter:
    """A keyword of its own that a rule takes (``make_estimator(..., name=value)``)."""

    name: str
    default: float
    check: Callable[[Any], float]  # the validated value, or a ValueError naming the keyword
    doc: str


@dataclass(frozen=True, kw_only=True)
class Rule:
    """A parameter-update rule (``theta_hat(t-1) -> theta_hat(t)``)."""

    name: str
    equations: str  # the equations of Ding & Ma (2014), or the reference
    covariance: bool  # keeps P = S S^T (least squares); else no covariance
    multi_innovation: bool  # p may exceed 1
    keywords: tuple[str, ...]  # the make_estimator keywords that apply to this rule alone
    fields: Shapes  # its lane-state fields and shapes for (n, p)
    flops: Callable[[int, int, bool], int]  # (n, p, stacked_r) -> flops per step
    decomposed_flops: Callable[[int, int, bool], int]
    holds_loop: bool  # the self-tuning controller holds the loop with it (else it warns)
    paper: bool = True  # one of the paper's rules (its names are in ALGORITHMS)
    parameters: tuple[Parameter, ...] = ()
    code: int = -1  # what the lane functions branch on: its position in RULES (_numbered)

    @property
    def normaliser(self) -> bool:
        """Whether the rule keeps the gradient normalisers ``r`` (SG, MISG)."""
        return "r" in self.fields(1, 1)


@dataclass(frozen=True, kw_only=True)
class StateEstimator:
    """A state estimator of the regressor's ``x_hat`` (Ding & Ma 2014, section 2)."""

    name: str
    equations: str
    fields: Callable[[int], dict[str, tuple[int, ...]]]  # lane-state fields and shapes for n
    flops: Callable[[int], int]
    controller_p0: float  # P(0) = p0 I of the self-tuning controller's estimator
    filtered_regressor: bool  # regressor="filtered" applies
    injection: bool  # injection / injection_warmup apply (with regressor="filtered")
    paper: bool = True
    code: int = -1  # its position in STATE_ESTIMATORS (_numbered)

    @property
    def kalman(self) -> bool:
        """Whether it is a Kalman filter: keeps ``P1``, ``Q`` (``P1_init``, ``process_noise``
        and ``measurement_noise`` apply)."""
        return "P1" in self.fields(1)

    @property
    def observer_gain(self) -> bool:
        """Whether it runs on a given observer gain ``K`` (``observer_gain`` required)."""
        return "K" in self.fields(1)


@dataclass(frozen=True, kw_only=True)
class CompiledDesign:
    """A compiled design of the self-tuning controller's step 3: its lane function and what
    the controller builds for it. The class of its compiled argument chooses the compiled
    version of the controller step that runs it (:func:`stcgym.lanes.compiled.chosen_by_type`);
    a design module declares one as ``COMPILED_DESIGN``, which :attr:`Design.compiled` names."""

    argument: type  # the named tuple class of its compiled argument (one class a design)
    step: Callable[..., int]  # the lane function step(argument, theta, cfg, state, gain, w,
    # lane_i) -> status: the gain of theta into lane lane_i of gain (a safe_set.Gain)
    make_argument: Callable[[int, Any], tuple]  # (n, law: LawOptions) -> its compiled argument
    make_state: Callable[[int, Any, int], tuple]  # (n, law, num_lanes) -> its lane state,
    # every lane at its cold start (an empty named tuple: it keeps none)
    make_work: Callable[[int, bool, int], tuple]  # (n, integral, num_lanes) -> its scratch, with
    # the model A, b of theta_hat (safe_set.DesignWork's fields) that the Kalman filter reads


@dataclass(frozen=True, kw_only=True)
class Design:
    """A certainty-equivalence design of the self-tuning controller."""

    name: str
    compiled: str  # the module whose COMPILED_DESIGN it runs (a CompiledDesign)
    doc: str
    parameters: tuple[str, ...]  # the controller's settings it reads
    oracle: str  # the known-model oracle (a class of stcgym.adaptive) with the same design
    oracle_options: dict[str, Any] = field(default_factory=dict)
    poles: float | None = None  # every closed-loop pole fixed here (None: from `poles`)

    @property
    def compiled_design(self) -> CompiledDesign:
        """The :class:`CompiledDesign` it runs (its module imported on first use)."""
        return importlib.import_module(self.compiled).COMPILED_DESIGN

    def make_oracle(self, a: Any, b: Any, **options: Any) -> Any:
        """The known-model oracle of this design on the true ``a``, ``b`` (``options``: the
        oracle's own keywords, e.g. ``law``, ``num_envs``)."""
        import stcgym.adaptive  # the oracles are built on these kernels

        oracle = getattr(stcgym.adaptive, self.oracle)
        return oracle(a, b, **self.oracle_options, **options)


# ---- parameter rules ------------------------------------------------------------------------
def _covariance(n: int, p: int) -> dict[str, tuple[int, ...]]:
    return {"S": (2 * n, 2 * n), "S0": (2 * n, 2 * n)}


def _normalisers(n: int, p: int) -> dict[str, tuple[int, ...]]:
    return {"r": (2,), "r0": (2,)}


def _nothing(n: int, p: int) -> dict[str, tuple[int, ...]]:
    return {}


_LEAST_SQUARES = ("P0", "window", "forgetting")
_GRADIENT = ("r0", "stacked_r", "forgetting")


def _numbered(*entries: Any) -> dict[str, Any]:
    """A table of entries by name, each entry's ``code`` its position in the table."""
    return {e.name: replace(e, code=code) for code, e in enumerate(entries)}


RULES: dict[str, Rule] = _numbered(
    Rule(
        name="SG", equations="(12)-(15), D-: (96)-(103)", covariance=False,
        multi_innovation=False, keywords=_GRADIENT, fields=_normalisers,
        flops=lambda n, p, s: _flops.sg(n), decomposed_flops=lambda n, p, s: _flops.d_sg(n),
        holds_loop=False,
    ),
    Rule(
        name="MISG", equations="(16)-(22), D-: (104)-(117)", covariance=False,
        multi_innovation=True, keywords=_GRADIENT, fields=_normalisers,
        flops=lambda n, p, s: _flops.misg(n, p, stacked_r=s),
        decomposed_flops=lambda n, p, s: _flops.d_misg(n, p, stacked_r=s), holds_loop=False,
    ),
    Rule(
        name="RLS", equations="(32)-(36), D-: (124)-(133)", covariance=True,
        multi_innovation=False, keywords=_LEAST_SQUARES, fields=_covariance,
        flops=lambda n, p, s: _flops.rls(n), decomposed_flops=lambda n, p, s: _flops.d_rls(n),
        holds_loop=True,
    ),
    Rule(
        name="MILS", equations="(37)-(44), D-: (134)-(145)", covariance=True,
        multi_innovation=True, keywords=_LEAST_SQUARES, fields=_covariance,
        flops=lambda n, p, s: _flops.mils(n, p),
        decomposed_flops=lambda n, p, s: _flops.d_mils(n, p), holds_loop=True,
    ),
    # the normalised-gradient (projection) algorithm, not in the paper: Astrom & Wittenmark,
    # Adaptive Control (2nd ed., 1995), sec. 2.3; MATLAB recursiveLS "NormalizedGradient".
    # Flops as sg(): e (4n), bias + phi^T phi (4n), mu e / (.) (2), theta + phi (.) (4n);
    # D-: the normaliser and the scaling once per half.
    Rule(
        name="NG", equations="theta += mu phi e / (bias + phi^T phi)", covariance=False,
        multi_innovation=False, keywords=(), fields=_nothing,
        flops=lambda n, p, s: 12 * n + 2, decomposed_flops=lambda n, p, s: 12 * n + 4,
        holds_loop=False, paper=False,
        parameters=(
            Parameter(
                "adaptation_gain", 1.0,
                lambda v: real_in(v, "adaptation_gain (mu)", 0, 2, lo_open=True, hi_open=True),
                "mu in (0, 2): the step along phi (1: the a-posteriori error of the update "
                "is bias / (bias + phi^T phi) of e)",
            ),
            Parameter(
                "normalization_bias", math.ulp(1.0),
                lambda v: real_in(v, "normalization_bias (alpha)", 0, lo_open=True),
                "the bias (MATLAB's alpha) > 0: keeps the step finite for a vanishing "
                "regressor (default: machine epsilon, as MATLAB's)",
            ),
        ),
    ),
)  # fmt: skip

# ---- state estimators -----------------------------------------------------------------------
STATE_ESTIMATORS: dict[str, StateEstimator] = _numbered(
    StateEstimator(
        name="O", equations="(46)-(49)", fields=lambda n: {}, flops=_flops.open_loop_observer,
        controller_p0=300.0, filtered_regressor=True, injection=True,
    ),
    StateEstimator(
        name="CO", equations="(50)-(53)", fields=lambda n: {"K": (n,)},
        flops=_flops.closed_loop_observer, controller_p0=300.0, filtered_regressor=False,
        injection=False, paper=False,
    ),
    StateEstimator(
        name="KF", equations="(66)-(72)",
        fields=lambda n: {"P1": (n, n), "P1_init": (n, n), "Q": (n, n), "L1": (n,)},
        flops=_flops.kalman_filter, controller_p0=100.0, filtered_regressor=True,
        injection=False,
    ),
)  # fmt: skip

#: The 16 algorithms of the paper (``CO-...`` and the rules added since are accepted as well).
ALGORITHMS: tuple[str, ...] = tuple(
    f"{s}-{d}{r}"
    for d in ("", "D-")
    for r, rule in RULES.items()
    if rule.paper
    for s, est in STATE_ESTIMATORS.items()
    if est.paper
)

# ---- designs --------------------------------------------------------------------------------
#: The compiled design of Ackermann's formula (poles: the controller's ``cfg.char_poly``).
PLACEMENT = "stcgym.adaptive.control.placement"

DESIGNS: dict[str, Design] = {
    d.name: d
    for d in (
        Design(
            name="pole_placement", compiled=PLACEMENT,
            doc="Ackermann's formula on the integral-augmented model: every closed-loop pole at "
            "`poles`", parameters=("poles",), oracle="KnownModelController",
        ),
        Design(
            name="lq", compiled="stcgym.adaptive.control.lq",
            doc="one Riccati iteration a sample of the LQ problem on the integral-augmented "
            "model (weights `law.lq_weights`)", parameters=("law.lq_weights",),
            oracle="LQGController",
        ),
        # Astrom & Wittenmark, Adaptive Control (2nd ed., 1995), sec. 3.2: deadbeat control is
        # pole placement with every closed-loop pole at the origin
        Design(
            name="deadbeat", compiled=PLACEMENT,
            doc="Ackermann's formula with every closed-loop pole at z = 0: (A - b K)^(n+1) = 0 "
            "on the integral-augmented model, the error of the estimated model dies in n + 1 "
            "samples", parameters=(), oracle="KnownModelController",
            oracle_options={"poles": 0.0}, poles=0.0,
        ),
    )
}  # fmt: skip


class EstimatorName(NamedTuple):
    """A parsed estimator name: its state estimator, ``D-`` or not, and its rule."""

    state: StateEstimator
    decomposed: bool
    rule: Rule

    @property
    def name(self) -> str:
        """The canonical name, e.g. ``"KF-D-MILS"``."""
        return f"{self.state.name}-{'D-' if self.decomposed else ''}{self.rule.name}"

    @property
    def controller_p0(self) -> float:
        """``P(0) = p0 I`` of the self-tuning controller's estimator (the state estimator's)."""
        return self.state.controller_p0

    @property
    def holds_loop(self) -> bool:
        """Whether it holds the self-tuning loop (a rule that does, not decomposed)."""
        return self.rule.holds_loop and not self.decomposed

    #: the controller step compiled for it runs the paper's estimator (est_cfg)
    paper: bool = True
    #: it identifies the plant's own canonical form if asked (estimation_form="plant")
    plant_form: bool = True

    def __reduce__(self) -> tuple[Any, tuple[str]]:
        # pickled by name: the entries hold functions (fields, flops) that do not pickle
        return variant, (self.name,)

    def flops(self, n: int, p: int = 1, stacked_r: bool = False) -> tuple[int, int]:
        """``(parameter update, state estimate)`` flops per step (sizes not checked)."""
        rule_flops = self.rule.decomposed_flops if self.decomposed else self.rule.flops
        return rule_flops(n, p, stacked_r), self.state.flops(n)


@dataclass(frozen=True, kw_only=True)
class ExtendedLS:
    """An estimator of the self-tuning controller outside the paper's names: extended least
    squares on the ARMAX form (:mod:`stcgym.adaptive.control.extended_ls`)."""

    name: str
    equations: str
    controller_p0: float  # P(0) = p0 I by default
    holds_loop: bool = True
    paper: bool = False  # the controller step compiled for it runs ELS (els_cfg)
    plant_form: bool = False  # always the observer form


#: The controller's estimators besides the paper's names.
CONTROLLER_ESTIMATORS: dict[str, ExtendedLS] = {
    "ELS": ExtendedLS(
        name="ELS",
        equations="Astrom & Wittenmark (1995) sec. 2.2-2.3; its step is RLS (32)-(36)",
        controller_p0=STATE_ESTIMATORS["O"].controller_p0,
    ),
}


def variant(name: str) -> EstimatorName:
    """The registry entries of an estimator name such as ``"kf-d-mils"`` (case-insensitive,
    surrounding blanks ignored); ``ValueError`` listing the accepted names otherwise."""
    if not isinstance(name, str):
        raise ValueError(f"name must be a string such as 'KF-D-MILS', got {name!r}")
    parts = name.strip().upper().split("-")
    ok = (
        len(parts) in (2, 3)
        and parts[0] in STATE_ESTIMATORS
        and parts[-1] in RULES
        and (len(parts) == 2 or parts[1] == "D")
    )
    if not ok:
        raise ValueError(
            f"unknown algorithm {name!r}; expected '<state>-[D-]<rule>' with state in "
            f"{tuple(STATE_ESTIMATORS)} and rule in {tuple(RULES)}, e.g. one of {ALGORITHMS}"
        )
    return EstimatorName(STATE_ESTIMATORS[parts[0]], len(parts) == 3, RULES[parts[-1]])


def controller_estimator(name: str) -> EstimatorName | ExtendedLS:
    """The record of a self-tuning controller's estimator: a name of
    :data:`CONTROLLER_ESTIMATORS` (``"ELS"``) or of the paper (:func:`variant`); a
    ``ValueError`` naming ``estimator`` otherwise."""
    if not isinstance(name, str):
        raise ValueError(f"estimator must be a name (str), got {name!r}")
    key = name.strip().upper()
    if key in CONTROLLER_ESTIMATORS:
        return CONTROLLER_ESTIMATORS[key]
    try:
        return variant(name)
    except ValueError as exc:
        extra = "' or '".join(CONTROLLER_ESTIMATORS)
        raise ValueError(f"estimator must be '{extra}' or a paper name: {exc}") from None


class CompiledVersion(NamedTuple):
    """A compiled version of the self-tuning controller's step: numba prunes ``if x is None``
    on an argument's type, so ``est_cfg`` / ``els_cfg`` (one of them ``None``) choose the
    estimator it contains, and the class of the design's compiled argument the design."""

    paper: bool  # the paper's estimator (est_cfg), else extended least squares (els_cfg)
    design: str  # the compiled design's module (Design.compiled)


def compiled_version(estimator: EstimatorName | ExtendedLS, design: Design) -> CompiledVersion:
    """The one map from an estimator and a design to the controller step's compiled version."""
    return CompiledVersion(paper=estimator.paper, design=design.compiled)


def compiled_design(argument: type) -> CompiledDesign:
    """The compiled design of :data:`DESIGNS` whose compiled argument is of class
    ``argument`` (the controller step's choice of its design)."""
    for d in DESIGNS.values():
        if d.compiled_design.argument is argument:
            return d.compiled_design
    raise TypeError(f"no design of DESIGNS takes a compiled argument of class {argument!r}")


def parse_name(name: str) -> tuple[str, bool, str]:
    """Split an estimator name into ``(state estimator, decomposed, rule)``.

    ``"KF-D-MILS" -> ("KF", True, "MILS")``; case-insensitive; the state estimator is one of
    ``O``, ``KF``, ``CO`` (closed-loop observer, needs ``observer_gain``).

    Parameters
    ----------
    name : str
        ``"<state>-[D-]<rule>"``: state in :data:`STATE_ESTIMATORS`, rule in :data:`RULES`
        (surrounding blanks ignored).

    Returns
    -------
    state : str
        ``"O"``, ``"KF"`` or ``"CO"``.
    decomposed : bool
        Whether the name has the ``D-`` (model decomposition) part.
    rule : str
        A rule of :data:`RULES`, e.g. ``"MILS"``.

    Raises
    ------
    ValueError
        ``name`` not a string of that form; the message lists the accepted names.

    Examples
    --------
    >>> from stcgym.adaptive import parse_name
    >>> parse_name("kf-d-mils")
    ('KF', True, 'MILS')
    >>> parse_name("O-RLS")
    ('O', False, 'RLS')
    >>> parse_name("O-LSI")
    Traceback (most recent call last):
    ...
    ValueError: unknown algorithm 'O-LSI'; expected '<state>-[D-]<rule>' ...
    """
    v = variant(name)
    return v.state.name, v.decomposed, v.rule.name
