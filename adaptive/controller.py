"""Self-tuning controller: one class for one plant or a batch of plants.

:class:`SelfTuningController` is the indirect self-tuning regulator of the mission. Every sample
its compiled lane step (:mod:`stcgym.adaptive.kernels.controller`) runs: estimator update ->
change detection -> certainty-equivalence design (pole placement or LQ) in the safe set ->
Kalman state estimate on the estimated model -> control (a short seeded probe, then the tracking
law) -> process noise and state step. ``num_envs=B`` holds ``B`` lane records in one array and
steps them in a ``prange``; a single controller is the case ``B = 1`` of the same code, so a
single plant equals its lane of a batch bit for bit.

Options are grouped like SB3's ``policy_kwargs``: :class:`EstimatorOptions`,
:class:`StartupOptions`, :class:`SafeSet`, :class:`ChangeDetection`, :class:`LawOptions`
(frozen dataclasses, validated on construction); the common settings are plain keywords.

Start-up (the redesign of the former open-loop bootstrap)
---------------------------------------------------------
The estimator runs from the first sample on measured data with a moderate ``P(0) = p0 I``; for
the first ``probe_steps = 2n`` samples the input is a small zero-mean probe whose signs are a
counter-based hash of ``(seed, episode, t)`` (a new sequence for every lane and every episode,
reproducible) and whose amplitude is bounded by the observed output,
``probe_amplitude * min(1, probe_output / max |y|)`` (a high-gain or unstable plant is probed
gently). While ``max |y|`` stays below ``probe_output`` (a low-gain plant whose response is
still buried in the noise) the probe runs on, up to ``max_probe_steps = 5n`` samples; then the
loop closes with the tracking law as soon as a design is in the safe set. There is no open-loop
window, no bootstrap estimator, no handover and no replay.

Estimators
----------
``"ELS"`` (default): extended least squares on the ARMAX form
(:mod:`stcgym.adaptive.kernels.extended_ls`), consistent in closed loop from any start. Any
name of the seed paper (``"O-RLS"``, ``"KF-MILS"``, ... :data:`stcgym.adaptive.ALGORITHMS`)
runs the paper's estimator with the closed-loop settings of :class:`EstimatorOptions`: the
regressor is built from the measurement-corrected state ``x_hat(t|t)`` (``regressor=
"filtered"``) instead of the paper's prediction ``x_hat(t|t-1)``, whose model-dependence loses
about a quarter of ordinary plants from a cold start in closed loop. ``KF-`` estimators run
their own Kalman filter with ``R = kf_measurement_noise`` and the controller's process noise
``Q(t)``; ``O-`` estimators become the closed-loop observer (50) with deadbeat output
injection, i.e. least squares on measured outputs, which the output noise biases (there is no
noise model). Every estimator identifies the observer-form realization of the plant's transfer
function (``estimation_form="observer"``); ``theta`` is reported in the plant's form.
``benchmarks/startup.py`` prints every name's figures.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from numbers import Integral, Real
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.kernels import controller as kc
from stcgym.adaptive.kernels import design as dz
from stcgym.adaptive.kernels.estimator import REGRESSORS, EstimatorSpec, check_int
from stcgym.adaptive.kernels.extended_ls import extended_ls_layout
from stcgym.adaptive.placement import characteristic_coefficients, check_poles
from stcgym.adaptive.policy import episode_starts, validate_observation
from stcgym.envs.canonical import check_form, observer_to_observability_b
from stcgym.envs.compiled import FixedTypes

__all__ = [
    "DEFAULT_POLE",
    "OBSERVATION_LIMIT",
    "ChangeDetection",
    "EstimatorOptions",
    "LawOptions",
    "SafeSet",
    "SelfTuningController",
    "StartupOptions",
]

#: Default location of every closed-loop pole.
DEFAULT_POLE = 0.5
#: Observations beyond this magnitude are rejected (squares would overflow inside the step).
OBSERVATION_LIMIT = 1e100

# the controller step with its argument types looked up once (they never change: see FixedTypes)
_controller_step = FixedTypes(kc.controller_step)
_controllers_step = FixedTypes(kc.controllers_step)
#: Estimator names besides the paper's: extended least squares on the ARMAX form.
EXTRA_ESTIMATORS = ("ELS",)
#: Default ``P(0) = p0 I`` of extended least squares and of the paper's ``O-`` estimators.
P0_ELS = 300.0
#: Default ``P(0) = p0 I`` of the paper's ``KF-`` estimators.
P0_KF = 100.0


def _real(value: Any, name: str, *, lo: float = -math.inf, hi: float = math.inf,
          lo_open: bool = False, hi_open: bool = False) -> float:  # fmt: skip
    if isinstance(value, bool) or not isinstance(value, Real):
        raise ValueError(f"{name} must be a real number, got {value!r}")
    v = float(value)
    ok = math.isfinite(v) or (v == math.inf and hi == math.inf and not hi_open)
    ok = ok and (v > lo if lo_open else v >= lo) and (v < hi if hi_open else v <= hi)
    if not ok:
        lb = "(" if lo_open else "["
        rb = ")" if hi_open else "]"
        raise ValueError(f"{name} must lie in {lb}{lo}, {hi}{rb}, got {value!r}")
    return v


@dataclass(frozen=True)
class EstimatorOptions:
    """Estimator settings.

    ``p0``: ``P(0) = p0 I`` (moderate: the estimator starts from ``theta = 0`` on measured
    data; ``None``: :data:`P0_ELS` for ``"ELS"`` and the observer (``O-``) estimators,
    :data:`P0_KF` for the Kalman-filter (``KF-``) estimators); ``forgetting``: ``lambda`` in
    ``(0, 1]``; ``p``: innovation length of the MISG/MILS rules; ``process_noise_gain``: ``q``
    of the Kalman process noise
    ``Q = q [y^2 P_aa + u^2 P_bb - y u (P_ab + P_ba)] + process_noise_floor I``;
    ``measurement_noise``: ``R`` of the controller's Kalman filter on the estimated model. The
    defaults (``p0 = 300``, ``R = 10``, ``q = 0.01``) were chosen on the catalogue plants with
    ``benchmarks/startup.py``: a larger ``R`` makes the filter trust the estimated model more
    than the noisy sample (it keeps the 4th-order plant from chasing noise with an early
    model), a larger ``p0`` lets the estimate move faster in the first samples.

    The paper's estimators (``estimator="O-RLS"``, ``"KF-MILS"``, ...) in the loop:

    * ``regressor``: ``"filtered"`` (default) builds ``phi_hat`` from the measurement-corrected
      state ``x_hat(t|t)`` (see :func:`stcgym.adaptive.make_estimator`); ``"predicted"`` is the
      paper's ``x_hat(t|t-1)``, which loses about a quarter of a random family of
      second-order plants in closed loop (``benchmarks/startup.py``).
    * ``kf_measurement_noise``: ``R`` of the ``KF-`` estimators' own Kalman filter, whose
      process noise is the controller's ``Q`` above. ``0.005`` (twice the variance of the
      benchmark's output noise): while ``P`` is large the filtered ``x1_hat(t|t)`` follows
      ``y``, once it is small it follows the model, so the regressor loses the noise that
      biases least squares on measured outputs. Measured with ``benchmarks/startup.py``
      (KF-MILS, worst catalogue plant over 20 seeds / p90 of 1000 random plants): ``R =
      0.003`` 1.51 (stable4) / -, ``0.005`` 1.49 / 1.43, ``0.01`` 1.60 / 1.42, ``0.03`` 2.02
      (lightly_damped2, 10 seeds) / -; ``R = 10`` (the controller's own) loses 24 of 300
      random plants.
    * ``p0 = 100`` for ``KF-`` (worst catalogue plant 1.52 with 300, 1.44 with 100); the
      ``O-`` estimators keep 300 (with 100 they lose a plant of the random family).
    * ``estimation_form``: the canonical form the estimator identifies. ``"observer"``
      (default): the plant's transfer function in the observer form (1)-(9), whatever the
      plant's form (the forms are interchangeable, section 4 of the paper; ``theta`` is
      reported in the plant's form, like ELS's); ``"plant"``: the plant's own form. In the
      observability form the regressor (153) holds the whole state ``x_hat(t-n)``, whose
      components other than ``x1`` only the model can reconstruct: on ``unstable2`` of that
      form KF-MILS held 3 of 4 seeds at 50-300x the oracle's cost, against every seed near
      the oracle in the observer form.
    """

    p0: float | None = None
    forgetting: float = 1.0
    p: int = 2
    process_noise_gain: float = 0.01
    process_noise_floor: float = 1e-6
    measurement_noise: float = 10.0
    regressor: str = "filtered"
    kf_measurement_noise: float = 0.005
    estimation_form: str = "observer"

    def __post_init__(self) -> None:
        if self.p0 is not None:
            _real(self.p0, "p0", lo=0.0, lo_open=True)
        _real(self.forgetting, "forgetting", lo=0.0, hi=1.0, lo_open=True)
        check_int(self.p, "p", 1)
        _real(self.process_noise_gain, "process_noise_gain", lo=0.0)
        _real(self.process_noise_floor, "process_noise_floor", lo=0.0)
        _real(self.measurement_noise, "measurement_noise", lo=0.0, lo_open=True)
        if self.regressor not in REGRESSORS:
            raise ValueError(f"regressor must be one of {REGRESSORS}, got {self.regressor!r}")
        _real(self.kf_measurement_noise, "kf_measurement_noise", lo=0.0, lo_open=True)
        if self.estimation_form not in ("observer", "plant"):
            raise ValueError(
                f"estimation_form must be 'observer' or 'plant', got {self.estimation_form!r}"
            )

    def initial_covariance(self, estimator: str) -> float:
        """``p0`` for the (canonical) estimator name: the given value or the name's default."""
        if self.p0 is not None:
            return float(self.p0)
        return P0_KF if estimator.upper().startswith("KF-") else P0_ELS


@dataclass(frozen=True)
class StartupOptions:
    """Start-up: a seeded zero-mean probe, bounded by the observed output, then the loop closes.

    ``probe_steps`` samples (``None``: ``2n``) of ``+-a(t)``, ``a(t) = probe_amplitude *
    min(1, probe_output / y_max(t))`` with ``y_max(t)`` the largest ``|y|`` seen so far; the
    probe goes on past ``probe_steps`` while ``y_max < probe_output``, for at most
    ``max_probe_steps`` samples (``None``: ``5n``; ``0`` or ``probe_steps`` turns the extension
    off). ``probe_output = inf`` with ``max_probe_steps = 0`` gives the former fixed probe,
    ``+-probe_amplitude`` for ``probe_steps`` samples. Defaults chosen with
    ``benchmarks/startup.py``: scaling the probe down on high-gain plants takes the 90th
    percentile of the random family's episode ratio from 1.79 to 1.44 (300 plants), and the
    extension takes ``stable4`` from 1.82 to 1.41 (10 seeds).
    """

    probe_amplitude: float = 0.5
    probe_steps: int | None = None
    probe_output: float = 0.5
    max_probe_steps: int | None = None

    def __post_init__(self) -> None:
        _real(self.probe_amplitude, "probe_amplitude", lo=0.0)
        if self.probe_steps is not None:
            check_int(self.probe_steps, "probe_steps", 0)
        _real(self.probe_output, "probe_output", lo=0.0, lo_open=True)
        if self.max_probe_steps is not None:
            check_int(self.max_probe_steps, "max_probe_steps", 0)


@dataclass(frozen=True)
class SafeSet:
    """A design is used only when ``max |b_hat| >= b_min``, the normalised controllability
    matrix has reciprocal condition ``>= rcond_min``, the steady-state matrix ``>= dc_rcond_min``
    (no zero at ``z = 1``) and ``max |K|, |N| <= gain_max``; otherwise the last good gain stays."""

    b_min: float = 1e-4
    rcond_min: float = 1e-6
    dc_rcond_min: float = 0.0
    gain_max: float = 1e3

    def __post_init__(self) -> None:
        dz.safe_set(self.b_min, self.rcond_min, self.dc_rcond_min, self.gain_max)

    def vector(self) -> NDArray:
        return dz.safe_set(self.b_min, self.rcond_min, self.dc_rcond_min, self.gain_max)


@dataclass(frozen=True)
class ChangeDetection:
    """Covariance resetting when the short EWMA of ``e^2`` (rate ``short``) exceeds
    ``threshold`` x the long one (rate ``long``), in closed loop, at most once per ``holdoff``
    steps: ``P <- inflation P``. ``threshold = 5`` (was 10): the self-tuning LQ loop keeps the
    innovation smaller after a parameter jump, and with 10 it missed the bench's jump on 5 of 8
    seeds; with 5 there is still no false alarm on the 1000 random time-invariant plants of
    ``benchmarks/startup.py``."""

    enabled: bool = True
    threshold: float = 5.0
    holdoff: int = 100
    inflation: float = 100.0
    short: float = 0.1
    long: float = 0.01

    def __post_init__(self) -> None:
        if not isinstance(self.enabled, (bool, np.bool_)):
            raise ValueError(f"enabled must be a bool, got {self.enabled!r}")
        _real(self.threshold, "threshold", lo=1.0, lo_open=True)
        check_int(self.holdoff, "holdoff", 0)
        _real(self.inflation, "inflation", lo=1.0)
        _real(self.short, "short", lo=0.0, hi=1.0, lo_open=True)
        _real(self.long, "long", lo=0.0, hi=1.0, lo_open=True)


@dataclass(frozen=True)
class LawOptions:
    """Tracking law: integral action on ``r - y``, reference feed-forward ``N r``,
    conditional-integration anti-windup, control on the filtered ``x(t|t)``; LQ weights
    ``[q_y, q_i, rho]`` of ``design="lq"``.

    The LQ weights are the envs' cost, ``(y - r)^2 + 0.01 u^2`` (``q_y = 1``, ``rho = 0.01``,
    as :class:`~stcgym.adaptive.LQGController`), plus a small weight ``q_i = 1e-4`` on the
    integrator, which the oracle does not have: it keeps the integrator detectable (offset-free
    tracking whatever the estimation bias, time constant of the order of 100 samples) while
    leaving the loop close to the oracle's LQ loop. With ``q_i = 1e-2`` the steady-state cost
    was 1.04-1.21x the oracle's; with ``1e-4`` it is 1.01-1.04x.
    """

    integral: bool = True
    feedforward: bool = True
    anti_windup: bool = True
    filtered: bool = True
    lq_weights: tuple[float, float, float] = dz.DEFAULT_LQ_WEIGHTS

    def __post_init__(self) -> None:
        for name in ("integral", "feedforward", "anti_windup", "filtered"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name} must be a bool, got {getattr(self, name)!r}")
        w = tuple(self.lq_weights)
        if len(w) != 3:
            raise ValueError(f"lq_weights must be (q_y, q_i, rho), got {self.lq_weights!r}")
        _real(w[0], "lq_weights[0] (q_y)", lo=0.0, lo_open=True)
        _real(w[1], "lq_weights[1] (q_i)", lo=0.0)
        _real(w[2], "lq_weights[2] (rho)", lo=0.0, lo_open=True)


def _frozen(values: Any) -> NDArray:
    """A read-only ``float64`` copy: a configuration array of the lane functions."""
    arr = np.array(values, dtype=np.float64)
    arr.setflags(write=False)
    return arr


def _options(value: Any, cls: type, name: str) -> Any:
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


def _env_spec(env: Any) -> tuple[int | None, float | None, str | None, int | None]:
    """``(n, action_bound, form, num_envs)`` of an stcgym env, vector env or wrapper."""
    base = getattr(env, "unwrapped", env)
    n_inputs = getattr(base, "n_inputs", 1)
    n_outputs = getattr(base, "n_outputs", 1)
    if n_inputs != 1 or n_outputs != 1:
        raise ValueError(
            f"the self-tuning regulator is single-input single-output; the env has "
            f"{n_inputs} inputs and {n_outputs} outputs"
        )
    n = getattr(base, "n_states", None)
    bound = getattr(base, "action_bound", None)
    form = getattr(base, "form", None)
    num = getattr(env, "num_envs", None)
    return (
        None if n is None else int(n),
        None if bound is None else float(np.max(bound)),
        None if form is None else str(form),
        None if num is None else int(num),
    )


_DEFAULT = object()


class SelfTuningController:
    """Indirect self-tuning regulator for one plant (``num_envs=None``) or ``B`` plants.

    Parameters
    ----------
    n
        Plant order.
    estimator
        ``"ELS"`` (default) or a paper name (``"O-RLS"``, ``"KF-MILS"``, ...; the SG, MISG and
        D- rules warn that they do not hold the loop on many plants).
    design
        ``"pole_placement"`` (Ackermann on the integral-augmented model, ``poles``) or ``"lq"``
        (one Riccati iteration per step, weights ``law.lq_weights``).
    poles
        A scalar (all ``n + 1`` poles) or ``n + 1`` values (``n`` without integral action).
    action_bound
        Saturation (default: the env's, else 10).
    num_envs
        ``None`` for one plant (``predict`` on ``(2,)`` gives ``(1,)``), or ``B`` lanes
        (``predict`` on ``(B, 2)`` gives ``(B, 1)``).
    seed
        Probe seed: an int (lane ``i`` gets ``seed + i``) or one int per lane.
    form
        Canonical form of the plant (``theta`` is reported in it); default the env's.
    env
        Optional env or vector env to check ``n``, ``form``, ``action_bound``, ``num_envs``.
    estimator_options, startup, safe_set, change_detection, law
        Option groups (instances or dicts).

    Raises
    ------
    ValueError
        Any setting outside its documented range (the message names it).
    """

    obs_dim = 2

    def __init__(
        self,
        n: int,
        *,
        estimator: str = "ELS",
        design: str = "pole_placement",
        poles: ArrayLike = DEFAULT_POLE,
        action_bound: float | object = _DEFAULT,
        num_envs: int | None = None,
        seed: int | ArrayLike = 0,
        form: str | object = _DEFAULT,
        env: Any = None,
        estimator_options: EstimatorOptions | dict | None = None,
        startup: StartupOptions | dict | None = None,
        safe_set: SafeSet | dict | None = None,
        change_detection: ChangeDetection | dict | None = None,
        law: LawOptions | dict | None = None,
    ) -> None:
        self.n = n = check_int(n, "n (plant order)", 1)
        env_n, env_bound, env_form, env_num = (None,) * 4 if env is None else _env_spec(env)
        if env_n is not None and env_n != n:
            raise ValueError(f"n={n} does not match the env's plant order n={env_n}")
        if num_envs is not None:
            num_envs = check_int(num_envs, "num_envs", 1)
        if env_num is not None and num_envs != env_num:
            raise ValueError(
                f"num_envs={num_envs} does not match the env's num_envs={env_num}: build the "
                f"controller with num_envs={env_num}"
            )
        self.num_envs = num_envs
        self.B = 1 if num_envs is None else num_envs
        if action_bound is _DEFAULT:
            action_bound = env_bound if env_bound is not None else 10.0
        self.action_bound = _real(action_bound, "action_bound", lo=0.0, lo_open=True)
        if env_bound is not None and self.action_bound > env_bound:
            raise ValueError(
                f"action_bound={self.action_bound} exceeds the env's action_bound={env_bound}"
            )
        if form is _DEFAULT:
            form = env_form or "observer"
        self.form = check_form(form)  # type: ignore[arg-type]
        if env_form is not None and env_form != self.form:
            raise ValueError(f"form={self.form!r} does not match the env's form {env_form!r}")
        if design not in ("pole_placement", "lq"):
            raise ValueError(f"design must be 'pole_placement' or 'lq', got {design!r}")
        self.design = design
        self.estimator_options = eo = _options(
            estimator_options, EstimatorOptions, "estimator_options"
        )
        self.startup = _options(startup, StartupOptions, "startup")
        self.safe_set = _options(safe_set, SafeSet, "safe_set")
        self.change_detection = cd = _options(change_detection, ChangeDetection, "change_detection")
        self.law = lw = _options(law, LawOptions, "law")
        m = n + int(lw.integral)
        self.poles = check_poles(poles, m)
        self.seeds = self._lane_ints(seed, "seed")
        # -- estimator record
        if not isinstance(estimator, str):
            raise ValueError(f"estimator must be a name (str), got {estimator!r}")
        self.estimator = estimator.upper()
        # the canonical form the estimator identifies (ELS: always the observer form)
        plant_form = self.estimator != "ELS" and eo.estimation_form == "plant"
        self._estimation_form = self.form if plant_form else "observer"
        #: ``P(0) = p0 I`` in use (``estimator_options.p0`` or the estimator's default)
        self.p0 = eo.initial_covariance(self.estimator)
        if self.estimator == "ELS":
            est_lay = extended_ls_layout(n, True)
            self._spec = None
            d = 3 * n
        else:
            from stcgym.adaptive.kernels.estimator import parse_name

            try:
                state, decomposed, rule = parse_name(estimator)
            except ValueError as exc:
                raise ValueError(f"estimator must be 'ELS' or a paper name: {exc}") from None
            if decomposed or rule in ("SG", "MISG"):
                warnings.warn(
                    f"estimator {estimator!r} does not hold the loop on a sizeable share of "
                    "ordinary plants: the stochastic-gradient rules (SG, MISG) adapt too slowly "
                    "for a cold start, and the decomposition rules (D-) update a and b as if "
                    "their regressors were uncorrelated, which feedback makes them not "
                    "(benchmarks/startup.py measures every name); 'KF-MILS', 'KF-RLS' or the "
                    "default 'ELS' hold it",
                    UserWarning,
                    stacklevel=2,
                )
            kw: dict[str, Any] = {
                "p0": self.p0, "form": self._estimation_form, "forgetting": eo.forgetting,
                "theta0": np.zeros(2 * n),
            }  # fmt: skip
            if rule in ("MISG", "MILS"):
                kw["p"] = eo.p
            if state != "CO":
                kw["regressor"] = eo.regressor
            if state == "KF":
                kw["process_noise"] = eo.process_noise_floor * np.eye(n)
                kw["measurement_noise"] = eo.kf_measurement_noise
            self._spec = EstimatorSpec.build(estimator, n, **kw)
            self.estimator = self._spec.name
            d = 2 * n
        # the estimator's record ends with its scratch ("scratch" / "work"), shared with the design
        absent = dict.fromkeys(("theta", "S", "E", "Q_est", "phi", "scratch"), -1)
        if self._spec is None:
            est_fields = {
                **absent,
                **{k: est_lay.offset(k) for k in ("theta", "S", "phi", "scratch")},
            }
            est_scratch = est_lay.fields["scratch"][1][0]
        else:
            spec = self._spec
            est_lay = spec.layout
            est_fields = {**absent, "theta": spec.offset("theta"), "E": spec.offset("E")}
            if spec.least_squares:
                est_fields["S"] = spec.offset("S")
            if spec.state == "KF":
                est_fields["Q_est"] = spec.offset("Q")
            est_scratch = spec.layout.fields["work"][1][0]
        self._layout, at = kc.controller_record(
            n, est_lay, est_fields, est_scratch, lq=design == "lq"
        )
        self._at = at
        ps = self.startup.probe_steps
        probe_steps = 2 * n if ps is None else int(ps)
        pm = self.startup.max_probe_steps
        observability = self._estimation_form == "observability"
        self._cfg = kc.ControllerConfig(
            n=int(n),
            d=int(d),
            integral=bool(lw.integral),
            feedforward=bool(lw.feedforward),
            anti_windup=bool(lw.anti_windup),
            filtered=bool(lw.filtered),
            probe_steps=probe_steps,
            probe_max=max(5 * n if pm is None else int(pm), probe_steps),
            design=kc.LQ if design == "lq" else kc.POLE_PLACEMENT,
            detect=bool(cd.enabled),
            holdoff=int(cd.holdoff),
            estimator=kc.ELS if self._spec is None else kc.PAPER,
            # ELS estimates the observer-form transfer function
            form=dz.OBSERVABILITY if observability else dz.OBSERVER,
            action_bound=float(self.action_bound),
            probe_amplitude=float(self.startup.probe_amplitude),
            q_gain=float(eo.process_noise_gain),
            q_floor=float(eo.process_noise_floor),
            R=float(eo.measurement_noise),
            threshold=float(cd.threshold),
            inflation=float(cd.inflation),
            p0=float(self.p0),
            forgetting=float(eo.forgetting),
            ew_short=float(cd.short),
            ew_long=float(cd.long),
            probe_output=float(self.startup.probe_output),
            safe=_frozen(self.safe_set.vector()),
            weights=_frozen(lw.lq_weights),
            alpha=_frozen(characteristic_coefficients(self.poles)),
        )
        init = self._layout.empty(1)[0]
        if self._spec is None:
            init[at.S : at.S + d * d] = (np.sqrt(self.p0) * np.eye(d)).ravel()  # P = S S^T
            # the paper estimator's arguments as placeholders of the same types (never read):
            # one compiled controller step serves both kinds
            placeholder = EstimatorSpec.build("O-RLS", n)
            self._est_at, self._est_cfg = placeholder.at, placeholder.config
        else:
            init[at.est : at.est + spec.size] = spec.initial_record()
            self._est_at, self._est_cfg = spec.record(at.est), spec.config
        init[at.P1 : at.P1 + n * n] = np.eye(n).ravel()
        if design == "lq":
            P_lq = dz.lq_initial_P(n, lw.integral, np.asarray(lw.lq_weights, dtype=float))
            init[at.P_lq : at.P_lq + P_lq.size] = P_lq.ravel()
        init.setflags(write=False)
        self._init = init
        self._F = np.empty((self.B, self._layout.size))
        self._G = np.zeros((self.B, len(kc.INTS)), dtype=np.int64)
        self._G[:, kc.INTS.seed] = self.seeds
        self._G[:, kc.INTS.episode] = -1  # the first reset starts episode 0
        self._u = np.zeros(self.B)
        self.reset()

    # ------------------------------------------------------------------ lanes and validation
    def _lane_ints(self, value: Any, name: str) -> NDArray:
        if isinstance(value, (Integral,)) and not isinstance(value, bool):
            return (int(value) + np.arange(self.B)).astype(np.int64)
        try:
            arr = np.asarray(value)
        except (ValueError, TypeError):  # ragged nested sequences
            arr = np.empty(0)
        if arr.ndim != 1 or arr.size != self.B or arr.dtype.kind not in "iu":
            raise ValueError(
                f"{name} must be an int or {self.B} ints (one per lane), got {value!r}"
            )
        return arr.astype(np.int64)

    def _lane_index(self, lanes: Any, name: str = "lanes") -> NDArray:
        arr = np.asarray(lanes)
        if arr.dtype == bool:
            if arr.shape != (self.B,):
                raise ValueError(
                    f"{name} as a boolean mask must have one entry per lane ({self.B}), got "
                    f"shape {arr.shape}"
                )
            return np.flatnonzero(arr).astype(np.int64)
        if arr.dtype.kind not in "iu" or arr.ndim > 1:
            raise ValueError(f"{name} must be lane indices or a boolean mask, got {lanes!r}")
        idx = arr.reshape(-1).astype(np.int64)
        if idx.size and (idx.min() < 0 or idx.max() >= self.B):
            raise ValueError(f"{name} must lie in [0, {self.B - 1}], got {lanes!r}")
        return idx

    # ------------------------------------------------------------------ protocol
    def reset(self, lanes: ArrayLike | None = None) -> None:
        """Start a new episode on all lanes or on ``lanes`` (indices or a boolean mask).

        Estimator at ``theta(0) = 0``, ``P(0) = p0 I``; Kalman filter at ``x(1) = 0``,
        ``P1(1) = I``; no gain; ``t = 0``; each reset lane's episode counter advances, so its
        probe is a new sequence."""
        idx = np.arange(self.B) if lanes is None else self._lane_index(lanes)
        self._F[idx] = self._init
        G = self._G
        episodes = G[idx, kc.INTS.episode] + 1
        G[idx] = 0
        G[idx, kc.INTS.seed] = self.seeds[idx]
        G[idx, kc.INTS.episode] = episodes
        G[idx, kc.INTS.closed_t] = -1

    def predict(
        self,
        observation: ArrayLike,
        state: Any = None,
        episode_start: ArrayLike | bool | None = None,
        deterministic: bool = True,
    ) -> tuple[NDArray, Any]:
        """SB3's calling convention: ``u(t)`` from ``[y(t), r(t)]`` (one row per lane).

        A rejected call (wrong shape, non-finite or beyond :data:`OBSERVATION_LIMIT`, wrong
        ``episode_start``) raises ``ValueError`` before anything changes. ``episode_start``
        (a bool or one per lane) resets those lanes first. ``state`` is returned unchanged;
        ``deterministic`` is accepted for compatibility (the probe is part of the law)."""
        if (
            self.B == 1
            and self.num_envs is None
            and (episode_start is None or episode_start is False)
            and type(observation) is np.ndarray
            and observation.shape == (2,)
            and observation.dtype == np.float64
        ):
            # fast path of the common single-plant call (a float64 [y, r]); anything unusual,
            # including a non-finite or too large value, takes the validating path below
            y, r = float(observation[0]), float(observation[1])
            if abs(y) <= OBSERVATION_LIMIT and abs(r) <= OBSERVATION_LIMIT:
                u = _controller_step(
                    self._F[0], self._G[0], self._at, self._cfg, self._est_at, self._est_cfg,
                    y, r,
                )  # fmt: skip
                self._u[0] = u
                return np.array([u]), state
        obs, single = validate_observation(observation, self.obs_dim)
        if obs.shape[0] != self.B:
            raise ValueError(
                f"observation must have {self.B} rows (one per lane), got {obs.shape[0]}"
            )
        if self.num_envs is not None and single:
            raise ValueError(
                f"observation must have shape ({self.B}, 2) for num_envs={self.num_envs}, got "
                f"shape {np.shape(observation)}"
            )
        if np.any(np.abs(obs) > OBSERVATION_LIMIT):
            raise ValueError(
                f"observation magnitude must be <= {OBSERVATION_LIMIT:g}, got "
                f"{obs[np.any(np.abs(obs) > OBSERVATION_LIMIT, axis=1)][0]}; the controller was "
                "left unchanged"
            )
        starts = None
        if episode_start is not None:
            es = np.asarray(episode_start)
            if es.dtype != bool and not (es.dtype.kind in "iu" and np.all((es == 0) | (es == 1))):
                raise ValueError(f"episode_start must be booleans, got {episode_start!r}")
            starts = episode_starts(es.astype(bool), self.B)
        if starts is not None and starts.any():
            self.reset(starts)
        y = np.ascontiguousarray(obs[:, 0])
        r = np.ascontiguousarray(obs[:, 1])
        u = self._u
        if self.B == 1:
            u[0] = _controller_step(
                self._F[0], self._G[0], self._at, self._cfg, self._est_at, self._est_cfg,
                y[0], r[0],
            )  # fmt: skip
        else:
            _controllers_step(
                self._F, self._G, self._at, self._cfg, self._est_at, self._est_cfg, y, r, u
            )
        if single:
            return u.copy(), state
        return u[:, None].copy(), state

    # ------------------------------------------------------------------ views
    def _lanes_out(self, arr: NDArray) -> NDArray:
        return arr[0].copy() if self.num_envs is None else arr.copy()

    @property
    def theta(self) -> NDArray:
        """``theta_hat = [a_hat; b_hat]`` in the plant's canonical form (per lane if batched)."""
        n = self.n
        o = self._at.theta
        th = self._F[:, o : o + 2 * n].copy()
        if self.form == "observability" and self._estimation_form == "observer":
            for i in range(self.B):
                if np.all(np.isfinite(th[i])):
                    th[i, n:] = observer_to_observability_b(th[i, :n], th[i, n:])
        return self._lanes_out(th)

    @property
    def x_hat(self) -> NDArray:
        """The controller's state estimate ``x(t+1|t)`` (Kalman filter on the estimated model)."""
        o = self._at.x
        return self._lanes_out(self._F[:, o : o + self.n])

    @property
    def K(self) -> NDArray:
        """Gain in use ``[K_x, k_i]`` (zeros before the first accepted design)."""
        o = self._at.gain
        m = self.n + int(self.law.integral)
        return self._lanes_out(self._F[:, o : o + m])

    @property
    def N(self) -> NDArray | float:
        """Reference feed-forward gain in use."""
        o = self._at.gain + self.n + 1
        v = self._F[:, o].copy()
        return float(v[0]) if self.num_envs is None else v

    @property
    def t(self) -> int | NDArray:
        """Samples since the lane's last reset."""
        v = self._G[:, kc.INTS.t].copy()
        return int(v[0]) if self.num_envs is None else v

    @property
    def diagnostics(self) -> dict[str, Any]:
        """Counters and flags per lane (scalars for a single controller)."""
        G = self._G
        has_gain = self._F[:, self._at.gain + self.n + 2] > 0
        ints = kc.INTS
        out = {
            "t": G[:, ints.t],
            "episode": G[:, ints.episode],
            "has_gain": has_gain,
            "closed_at": G[:, ints.closed_t],
            "n_rejected": G[:, ints.n_rejected],
            "last_rejection": np.array([dz.STATUS_NAMES[c] for c in G[:, ints.last_reason]]),
            "n_alarms": G[:, ints.n_alarms],
            "n_saturated": G[:, ints.n_saturated],
            "n_probe": G[:, ints.n_probe],
            "n_kf_resets": G[:, ints.n_kf_resets],
            "estimator_status": G[:, ints.est_status],
        }
        if self.num_envs is None:
            return {k: (v[0].item() if hasattr(v[0], "item") else v[0]) for k, v in out.items()}
        return {k: v.copy() for k, v in out.items()}

    @property
    def nbytes_per_lane(self) -> int:
        """Memory of one lane's records (float and int)."""
        return self._F.shape[1] * 8 + self._G.shape[1] * 8

    def __repr__(self) -> str:
        lanes = "" if self.num_envs is None else f", num_envs={self.num_envs}"
        return (
            f"SelfTuningController(n={self.n}, estimator={self.estimator!r}, "
            f"design={self.design!r}{lanes})"
        )
