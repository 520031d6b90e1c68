"""Option groups shared by the self-tuning controller and the known-model oracles.

The settings are grouped like SB3's ``policy_kwargs``: :class:`EstimatorOptions`,
:class:`StartupOptions`, :class:`SafeSet` and :class:`ChangeDetection` belong to the self-tuning
controller alone; :class:`LawOptions` (integral action, feed-forward, anti-windup, control on the
filtered state, the LQ weights ``[q_y, q_i, rho]``) is the tracking law of the controller *and*
of the oracles, with the same defaults. Each group is a frozen dataclass validated on
construction; :func:`option_group` also accepts a dict of its fields. The settings read from an
env (``num_envs``, ``action_bound``, ``form``) are resolved by
:func:`stcgym.envs.env_settings.plant_settings`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from numpy.typing import NDArray

from stcgym.adaptive.control import lq, safe_set
from stcgym.adaptive.estimation.estimator_spec import REGRESSORS
from stcgym.adaptive.variants import (
    CONTROLLER_ESTIMATORS,
    STATE_ESTIMATORS,
    EstimatorName,
    ExtendedLS,
    controller_estimator,
)
from stcgym.lanes.validation import flag, forgetting_factor, integer, one_of, real_in

__all__ = [
    "DEFAULT_POLE",
    "ChangeDetection",
    "EstimatorOptions",
    "LawOptions",
    "SafeSet",
    "StartupOptions",
    "cost_weights",
    "option_group",
]

#: Default location of every closed-loop pole (controller and known-model oracle).
DEFAULT_POLE = 0.5
#: Default ``P(0) = p0 I`` of extended least squares and of the paper's ``O-`` estimators.
P0_ELS = CONTROLLER_ESTIMATORS["ELS"].controller_p0
#: Default ``P(0) = p0 I`` of the paper's ``KF-`` estimators.
P0_KF = STATE_ESTIMATORS["KF"].controller_p0


@dataclass(frozen=True)
class EstimatorOptions:
    """Estimator settings of the self-tuning controller.

    The defaults were chosen on the closed loop of the catalogue plants and a random family
    of second-order plants (the design notes of the documentation give the figures and the
    values tried). For the paper's estimators (``estimator="O-RLS"``, ``"KF-MILS"``, ...):
    ``regressor="filtered"`` builds ``phi_hat`` from the measurement-corrected state
    ``x_hat(t|t)`` (:func:`stcgym.adaptive.make_estimator`; the paper's ``"predicted"``
    ``x_hat(t|t-1)`` loses about a quarter of ordinary plants in closed loop);
    ``kf_measurement_noise`` is ``R`` of the ``KF-`` estimators' own Kalman filter, whose
    process noise is the controller's ``Q``; the ``O-`` estimators take the whole output
    injection for ``injection_warmup`` steps, then ``injection`` of it (the regressor keeps
    the rest of the model's noise-free prediction, which reduces the bias output noise gives
    least squares on measured outputs); ``estimation_form="observer"`` identifies the plant's
    transfer function in the observer form (1)-(9) whatever the plant's form (``theta`` is
    reported in the plant's form), since in the observability form the regressor (153) holds
    state components only the model can reconstruct.

    Parameters
    ----------
    p0 : float or None, default None
        ``P(0) = p0 I``, ``> 0`` (moderate: the estimator starts from ``theta = 0`` on measured
        data). ``None``: :data:`P0_ELS` (300) for ``"ELS"`` and the observer (``O-``)
        estimators, :data:`P0_KF` (100) for the Kalman-filter (``KF-``) estimators.
    forgetting : float, default 1.0
        Forgetting factor ``lambda`` in ``(0, 1]``.
    p : int, default 2
        Innovation length ``p >= 1`` of the multi-innovation rules (MISG, MILS).
    process_noise_gain : float, default 0.01
        ``q >= 0`` of the Kalman process noise
        ``Q = q [y^2 P_aa + u^2 P_bb - y u (P_ab + P_ba)] + process_noise_floor I``.
    process_noise_floor : float, default 1e-6
        The ``>= 0`` floor added to ``Q``.
    measurement_noise : float, default 10.0
        ``R > 0`` of the controller's Kalman filter on the estimated model.
    regressor : {"filtered", "predicted"}, default "filtered"
        The state the paper's estimators build ``phi_hat`` from.
    kf_measurement_noise : float, default 0.005
        ``R > 0`` of the ``KF-`` estimators' own Kalman filter.
    injection : float, default 0.4
        The ``O-`` estimators' share of the output injection after the warm-up, in ``[0, 1]``.
    injection_warmup : int, default 50
        Steps with the whole injection, ``>= 0``.
    estimation_form : {"observer", "plant"}, default "observer"
        The canonical form the estimator identifies.

    Raises
    ------
    ValueError
        On construction, naming the first field out of its range or set.

    Examples
    --------
    >>> from stcgym.adaptive import EstimatorOptions
    >>> opts = EstimatorOptions(forgetting=0.99)
    >>> opts.initial_covariance("KF-MILS"), opts.initial_covariance("O-RLS")
    (100.0, 300.0)
    >>> EstimatorOptions(forgetting=1.5)
    Traceback (most recent call last):
    ...
    ValueError: forgetting must lie in (0, 1], got 1.5
    """

    p0: float | None = None
    forgetting: float = 1.0
    p: int = 2
    process_noise_gain: float = 0.01
    process_noise_floor: float = 1e-6
    measurement_noise: float = 10.0
    regressor: str = "filtered"
    kf_measurement_noise: float = 0.005
    injection: float = 0.4
    injection_warmup: int = 50
    estimation_form: str = "observer"

    def __post_init__(self) -> None:
        if self.p0 is not None:
            real_in(self.p0, "p0", lo=0.0, lo_open=True)
        forgetting_factor(self.forgetting, "forgetting")
        integer(self.p, "p", 1)
        real_in(self.process_noise_gain, "process_noise_gain", lo=0.0)
        real_in(self.process_noise_floor, "process_noise_floor", lo=0.0)
        real_in(self.measurement_noise, "measurement_noise", lo=0.0, lo_open=True)
        one_of(self.regressor, "regressor", REGRESSORS)
        real_in(self.kf_measurement_noise, "kf_measurement_noise", lo=0.0, lo_open=True)
        real_in(self.injection, "injection", 0.0, 1.0)
        integer(self.injection_warmup, "injection_warmup", 0)
        one_of(self.estimation_form, "estimation_form", ("observer", "plant"))

    def initial_covariance(self, estimator: str | EstimatorName | ExtendedLS) -> float:
        """``p0`` for the (canonical) estimator name: the given value or the name's default.

        Parameters
        ----------
        estimator : str or a record of :mod:`stcgym.adaptive.variants`
            An estimator name (``"ELS"``, ``"O-RLS"``, ``"KF-MILS"``, ...) or its record
            (:func:`~stcgym.adaptive.variants.controller_estimator`).

        Returns
        -------
        float
            ``p0`` if given, else the estimator's ``controller_p0`` in the registry:
            :data:`P0_ELS` for ``"ELS"`` (:data:`~stcgym.adaptive.variants.CONTROLLER_ESTIMATORS`)
            and ``O-`` names, :data:`P0_KF` for ``KF-`` names
            (:data:`~stcgym.adaptive.variants.STATE_ESTIMATORS`).
        """
        if self.p0 is not None:
            return float(self.p0)
        if isinstance(estimator, str):
            estimator = controller_estimator(estimator)
        return estimator.controller_p0


@dataclass(frozen=True)
class StartupOptions:
    """Start-up: a seeded zero-mean probe, bounded by the observed output, then the loop closes.

    The probe is ``probe_steps`` samples of ``+-a(t)``, ``a(t) = probe_amplitude *
    min(1, probe_output / y_max(t))`` with ``y_max(t)`` the largest ``|y|`` seen so far; it
    goes on past ``probe_steps`` while ``y_max < probe_output``, for at most
    ``max_probe_steps`` samples. ``probe_output = inf`` with ``max_probe_steps = 0`` gives a
    fixed probe, ``+-probe_amplitude`` for ``probe_steps`` samples. The scaled probe is for
    high-gain plants, the extension for slow ones such as ``stable4``.

    Parameters
    ----------
    probe_amplitude : float, default 0.5
        Largest probe amplitude, ``>= 0``.
    probe_steps : int or None, default None
        Length of the probe, ``>= 0``; ``None``: ``2n`` for a plant of order ``n``.
    probe_output : float, default 0.5
        The ``|y|`` the probe scales down to and waits for, ``> 0`` (``inf`` allowed).
    max_probe_steps : int or None, default None
        Longest probe with the extension, ``>= 0``; ``None``: ``5n``; ``0`` or
        ``probe_steps`` turns the extension off.

    Raises
    ------
    ValueError
        On construction, naming the first field out of its range.

    Examples
    --------
    A fixed probe of ``+-1`` for 8 samples:

    >>> from stcgym.adaptive import StartupOptions
    >>> StartupOptions(probe_amplitude=1.0, probe_steps=8, probe_output=float("inf"),
    ...                max_probe_steps=0)
    StartupOptions(probe_amplitude=1.0, probe_steps=8, probe_output=inf, max_probe_steps=0)
    >>> StartupOptions(probe_output=0)
    Traceback (most recent call last):
    ...
    ValueError: probe_output must lie in (0, inf], got 0
    """

    probe_amplitude: float = 0.5
    probe_steps: int | None = None
    probe_output: float = 0.5
    max_probe_steps: int | None = None

    def __post_init__(self) -> None:
        real_in(self.probe_amplitude, "probe_amplitude", lo=0.0)
        if self.probe_steps is not None:
            integer(self.probe_steps, "probe_steps", 0)
        real_in(self.probe_output, "probe_output", lo=0.0, lo_open=True)
        if self.max_probe_steps is not None:
            integer(self.max_probe_steps, "max_probe_steps", 0)


@dataclass(frozen=True)
class SafeSet:
    """The safe set of designs: outside it the last good gain stays.

    A design is used only when ``max |b_hat| >= b_min``, the normalised controllability
    matrix has reciprocal condition ``>= rcond_min``, the steady-state matrix ``>= dc_rcond_min``
    (no zero at ``z = 1``) and ``max |K|, |N| <= gain_max``.

    Parameters
    ----------
    b_min : float, default 1e-4
        Smallest accepted ``max |b_hat|``, ``>= 0``.
    rcond_min : float, default 1e-6
        Smallest accepted reciprocal condition number of the normalised controllability
        matrix, ``>= 0``.
    dc_rcond_min : float, default 0.0
        Smallest accepted reciprocal condition number of the steady-state matrix, ``>= 0``.
    gain_max : float, default 1e3
        Largest accepted ``|K|`` and ``|N|`` entry, ``> 0``.

    Raises
    ------
    ValueError
        On construction, naming the first field out of its range.

    Examples
    --------
    >>> from stcgym.adaptive import SafeSet
    >>> SafeSet(gain_max=50.0).vector()
    array([1.e-04, 1.e-06, 0.e+00, 5.e+01])
    >>> SafeSet(b_min=-1)
    Traceback (most recent call last):
    ...
    ValueError: b_min must lie in [0, inf), got -1
    """

    b_min: float = 1e-4
    rcond_min: float = 1e-6
    dc_rcond_min: float = 0.0
    gain_max: float = 1e3

    def __post_init__(self) -> None:
        self.vector()

    def vector(self) -> NDArray:
        """The safe-set vector the design lane functions read.

        See :func:`~stcgym.adaptive.control.safe_set.safe_set`.
        """
        return safe_set.safe_set(self.b_min, self.rcond_min, self.dc_rcond_min, self.gain_max)


@dataclass(frozen=True)
class ChangeDetection:
    """Covariance resetting on a change of the plant.

    When the short EWMA of ``e^2`` (rate ``short``) exceeds ``threshold`` x the long one
    (rate ``long``), in closed loop, at most once per ``holdoff`` steps: ``P <- inflation P``.
    ``threshold = 5`` catches the bench's parameter jump with no false alarm on 1000 random
    time-invariant plants (design notes).

    Parameters
    ----------
    enabled : bool, default True
        Whether change detection runs.
    threshold : float, default 5.0
        Ratio of the short to the long EWMA that triggers a reset, ``> 1``.
    holdoff : int, default 100
        Fewest steps between two resets, ``>= 0``.
    inflation : float, default 100.0
        Factor ``>= 1`` applied to ``P`` at a reset.
    short, long : float, defaults 0.1 and 0.01
        Rates of the two EWMAs, in ``(0, 1]``.

    Raises
    ------
    ValueError
        On construction, naming the first field out of its range (``enabled`` must be a
        bool).

    Examples
    --------
    >>> from stcgym.adaptive import ChangeDetection
    >>> ChangeDetection(threshold=3.0).holdoff
    100
    >>> ChangeDetection(threshold=1)
    Traceback (most recent call last):
    ...
    ValueError: threshold must lie in (1, inf], got 1
    """

    enabled: bool = True
    threshold: float = 5.0
    holdoff: int = 100
    inflation: float = 100.0
    short: float = 0.1
    long: float = 0.01

    def __post_init__(self) -> None:
        flag(self.enabled, "enabled")
        real_in(self.threshold, "threshold", lo=1.0, lo_open=True)
        integer(self.holdoff, "holdoff", 0)
        real_in(self.inflation, "inflation", lo=1.0)
        real_in(self.short, "short", lo=0.0, hi=1.0, lo_open=True)
        real_in(self.long, "long", lo=0.0, hi=1.0, lo_open=True)

    def step_fields(self) -> dict[str, Any]:
        """The change-detection fields of both controllers' compiled configurations
        (:class:`~stcgym.adaptive.control.controller_step.ControllerConfig`,
        :class:`~stcgym.adaptive.multivariable.controller_step.MimoConfig`)."""
        return {
            "detect": bool(self.enabled),
            "holdoff": int(self.holdoff),
            "threshold": float(self.threshold),
            "inflation": float(self.inflation),
            "ew_short": float(self.short),
            "ew_long": float(self.long),
        }


@dataclass(frozen=True)
class LawOptions:
    """Tracking law: integral action on ``r - y``, reference feed-forward ``N r``,
    conditional-integration anti-windup, control on the filtered ``x(t|t)``; LQ weights
    ``[q_y, q_i, rho]`` of an LQ design (``design="lq"`` of the controller, the LQG oracle).

    The self-tuning controller and both known-model oracles take this group with the same
    defaults (:class:`~stcgym.adaptive.KnownModelController` uses the flags,
    :class:`~stcgym.adaptive.LQGController` the flags and the weights).

    The LQ weights are the envs' cost, ``(y - r)^2 + 0.01 u^2`` (``q_y = 1``, ``rho = 0.01``;
    :func:`cost_weights` gives them for another ``control_cost``), plus a small weight
    ``q_i = 1e-4`` on the integrator: it keeps the integrator detectable (offset-free tracking
    whatever the estimation bias, time constant of the order of 100 samples) while leaving the
    loop close to the LQ loop without integrator (steady-state cost 1.01-1.04x that of LQG
    without integral action). With integral action ``q_i`` must be > 0: with ``q_i = 0`` the
    integrator is invisible to the cost and the LQ gain leaves it alone (``k_i = 0``).

    Parameters
    ----------
    integral : bool, default True
        Integral action on ``r - y``.
    feedforward : bool, default True
        Reference feed-forward ``N r``.
    anti_windup : bool, default True
        Conditional integration while the input saturates.
    filtered : bool, default True
        Control on the filtered state ``x(t|t)`` rather than the predicted ``x(t|t-1)``.
    lq_weights : tuple of 3 floats, default ``(1.0, 1e-4, 0.01)``
        ``(q_y, q_i, rho)`` with ``q_y > 0``, ``q_i >= 0`` (``> 0`` with integral action) and
        ``rho > 0``.

    Raises
    ------
    ValueError
        On construction: a flag that is not a bool, ``lq_weights`` not of length 3, a weight
        out of its range, ``q_i = 0`` with ``integral=True``.

    Examples
    --------
    The law for an env whose cost is ``(y - r)^2 + 0.1 u^2``:

    >>> from stcgym.adaptive import LawOptions
    >>> from stcgym.adaptive.control.options import cost_weights
    >>> LawOptions(lq_weights=cost_weights(0.1)).lq_weights
    (1.0, 0.0001, 0.1)
    >>> LawOptions(lq_weights=(1.0, 0.0, 0.01))
    Traceback (most recent call last):
    ...
    ValueError: lq_weights[1] (q_i) must be > 0 with integral action ...
    """

    integral: bool = True
    feedforward: bool = True
    anti_windup: bool = True
    filtered: bool = True
    lq_weights: tuple[float, float, float] = lq.DEFAULT_LQ_WEIGHTS

    def __post_init__(self) -> None:
        for name in ("integral", "feedforward", "anti_windup", "filtered"):
            flag(getattr(self, name), name)
        w = tuple(self.lq_weights)
        if len(w) != 3:
            raise ValueError(f"lq_weights must be (q_y, q_i, rho), got {self.lq_weights!r}")
        real_in(w[0], "lq_weights[0] (q_y)", lo=0.0, lo_open=True)
        q_i = real_in(w[1], "lq_weights[1] (q_i)", lo=0.0)
        real_in(w[2], "lq_weights[2] (rho)", lo=0.0, lo_open=True)
        if self.integral and q_i == 0.0:
            raise ValueError(
                "lq_weights[1] (q_i) must be > 0 with integral action (with q_i = 0 the "
                "integrator is invisible to the LQ cost and gets no gain), got 0.0"
            )


def cost_weights(control_cost: float) -> tuple[float, float, float]:
    """LQ weights ``[q_y, q_i, rho]`` of the envs' cost ``(y - r)^2 + control_cost u^2``: ``q_y =
    1``, ``rho = control_cost`` and the default integrator weight ``q_i`` of :class:`LawOptions`
    (``LawOptions(lq_weights=cost_weights(c))`` is the law for an env of ``control_cost=c``)."""
    return (1.0, lq.DEFAULT_LQ_WEIGHTS[1], float(control_cost))


def option_group(value: Any, cls: type, name: str) -> Any:
    """``value`` as an instance of the option group ``cls``: ``None`` gives the defaults, a
    dict its fields; anything else is a ``ValueError`` naming ``name``."""
    if value is None:
        return cls()
    if isinstance(value, cls):
        return value
    if isinstance(value, dict):
        try:
            return cls(**value)
        except TypeError as exc:
            raise ValueError(f"{name}: {exc}") from exc
    raise ValueError(f"{name} must be a {cls.__name__} or a dict of its fields, got {value!r}")
