"""The registry of variants: every parameter rule, state estimator and design, declared once.

Each entry says what the rest of the code needs to know about its variant, so that adding one
is an entry here plus its lane function:

* :class:`Rule` (:data:`RULES`): the parameter update of the estimator -- its compile-time
  code, whether it keeps a covariance ``P = S S^T`` or a normaliser ``r``, whether the
  innovation length ``p`` may exceed 1, the keywords that apply to it (and its own
  parameters, with their defaults and ranges), the record fields it keeps, its flops per
  step, and whether it holds the self-tuning loop;
* :class:`StateEstimator` (:data:`STATE_ESTIMATORS`): the state estimate of the regressor --
  code, record fields, flops, the self-tuning controller's default ``p0``;
* :class:`Design` (:data:`DESIGNS`): the certainty-equivalence design of the self-tuning
  controller -- the compiled design it runs, its parameters and the known-model oracle that
  applies the same design to the true model.

:func:`parse_name` is the one parser of estimator names (``"KF-D-MILS"``); the lane functions
compare codes for equality only (never an order between variants).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from stcgym.adaptive.estimation import flops as _flops
from stcgym.envs.validation import real_in

__all__ = [
    "ALGORITHMS",
    "DESIGNS",
    "RULES",
    "STATE_ESTIMATORS",
    "Design",
    "EstimatorName",
    "Parameter",
    "Rule",
    "StateEstimator",
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


@dataclass(frozen=True)
class Rule:
    """A parameter-update rule (``theta_hat(t-1) -> theta_hat(t)``)."""

    name: str
    code: int  # what the lane functions branch on (compared for equality only)
    equations: str  # the equations of Ding & Ma (2014), or the reference
    covariance: bool  # keeps P = S S^T (least squares); else no covariance
    multi_innovation: bool  # p may exceed 1
    keywords: tuple[str, ...]  # the make_estimator keywords that apply to this rule alone
    fields: Shapes  # its record fields and shapes for (n, p)
    flops: Callable[[int, int, bool], int]  # (n, p, stacked_r) -> flops per step
    decomposed_flops: Callable[[int, int, bool], int]
    holds_loop: bool  # the self-tuning controller holds the loop with it (else it warns)
    paper: bool = True  # one of the paper's rules (its names are in ALGORITHMS)
    parameters: tuple[Parameter, ...] = ()

    @property
    def normaliser(self) -> bool:
        """Whether the rule keeps the gradient normalisers ``r`` (SG, MISG)."""
        return "r" in self.fields(1, 1)


@dataclass(frozen=True)
class StateEstimator:
    """A state estimator of the regressor's ``x_hat`` (Ding & Ma 2014, section 2)."""

    name: str
    code: int
    equations: str
    fields: Callable[[int], dict[str, tuple[int, ...]]]  # record fields and shapes for n
    flops: Callable[[int], int]
    controller_p0: float  # P(0) = p0 I of the self-tuning controller's estimator
    filtered_regressor: bool  # regressor="filtered" applies
    injection: bool  # injection / injection_warmup apply (with regressor="filtered")
    paper: bool = True


@dataclass(frozen=True)
class Design:
    """A certainty-equivalence design of the self-tuning controller."""

    name: str
    kernel: str  # the compiled design it runs: "place" (Ackermann) or "lq" (Riccati)
    doc: str
    parameters: tuple[str, ...]  # the controller's settings it reads
    oracle: str  # the known-model oracle (a class of stcgym.adaptive) with the same design
    oracle_options: dict[str, Any] = field(default_factory=dict)
    poles: float | None = None  # every closed-loop pole fixed here (None: from `poles`)

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

RULES: dict[str, Rule] = {
    rule.name: rule
    for rule in (
        Rule(
            "SG", 0, "(12)-(15), D-: (96)-(103)", False, False, _GRADIENT, _normalisers,
            lambda n, p, s: _flops.sg(n), lambda n, p, s: _flops.d_sg(n), holds_loop=False,
        ),
        Rule(
            "MISG", 1, "(16)-(22), D-: (104)-(117)", False, True, _GRADIENT, _normalisers,
            lambda n, p, s: _flops.misg(n, p, stacked_r=s),
            lambda n, p, s: _flops.d_misg(n, p, stacked_r=s), holds_loop=False,
        ),
        Rule(
            "RLS", 2, "(32)-(36), D-: (124)-(133)", True, False, _LEAST_SQUARES, _covariance,
            lambda n, p, s: _flops.rls(n), lambda n, p, s: _flops.d_rls(n), holds_loop=True,
        ),
        Rule(
            "MILS", 3, "(37)-(44), D-: (134)-(145)", True, True, _LEAST_SQUARES, _covariance,
            lambda n, p, s: _flops.mils(n, p), lambda n, p, s: _flops.d_mils(n, p),
            holds_loop=True,
        ),
        # the normalised-gradient (projection) algorithm, not in the paper: Astrom & Wittenmark,
        # Adaptive Control (2nd ed., 1995), sec. 2.3; MATLAB recursiveLS "NormalizedGradient".
        # Flops as sg(): e (4n), alpha + phi^T phi (4n), mu e / (.) (2), theta + phi (.) (4n);
        # D-: the normaliser and the scaling once per half.
        Rule(
            "NG", 4, "theta += mu phi e / (alpha + phi^T phi)", False, False, (), _nothing,
            lambda n, p, s: 12 * n + 2, lambda n, p, s: 12 * n + 4, holds_loop=False,
            paper=False,
            parameters=(
                Parameter(
                    "adaptation_gain", 1.0,
                    lambda v: real_in(v, "adaptation_gain (mu)", 0, 2, lo_open=True, hi_open=True),
                    "mu in (0, 2): the step along phi (1: the a-posteriori error of the update "
                    "is alpha / (alpha + phi^T phi) of e)",
                ),
                Parameter(
                    "normalization_bias", math.ulp(1.0),
                    lambda v: real_in(v, "normalization_bias (alpha)", 0, lo_open=True),
                    "alpha > 0: keeps the step finite for a vanishing regressor (default: "
                    "machine epsilon, as MATLAB's)",
                ),
            ),
        ),
    )
}  # fmt: skip

# ---- state estimators -----------------------------------------------------------------------
STATE_ESTIMATORS: dict[str, StateEstimator] = {
    s.name: s
    for s in (
        StateEstimator(
            "O", 0, "(46)-(49)", lambda n: {}, _flops.open_loop_observer, 300.0, True, True
        ),
        StateEstimator(
            "CO", 1, "(50)-(53)", lambda n: {"K": (n,)}, _flops.closed_loop_observer, 300.0,
            False, False, paper=False,
        ),
        StateEstimator(
            "KF", 2, "(66)-(72)",
            lambda n: {"P1": (n, n), "P1_init": (n, n), "Q": (n, n), "L1": (n,)},
            _flops.kalman_filter, 100.0, True, False,
        ),
    )
}  # fmt: skip

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
DESIGNS: dict[str, Design] = {
    d.name: d
    for d in (
        Design(
            "pole_placement", "place",
            "Ackermann's formula on the integral-augmented model: every closed-loop pole at "
            "`poles`", ("poles",), "KnownModelController",
        ),
        Design(
            "lq", "lq",
            "one Riccati iteration a sample of the LQ problem on the integral-augmented model "
            "(weights `law.lq_weights`)", ("law.lq_weights",), "LQGController",
        ),
        # Astrom & Wittenmark, Adaptive Control (2nd ed., 1995), sec. 3.2: deadbeat control is
        # pole placement with every closed-loop pole at the origin
        Design(
            "deadbeat", "place",
            "Ackermann's formula with every closed-loop pole at z = 0: (A - b K)^(n+1) = 0 on "
            "the integral-augmented model, the error of the estimated model dies in n + 1 "
            "samples", (), "KnownModelController", {"poles": 0.0}, poles=0.0,
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
