"""Self-tuning controller: one class for one plant or a batch of plants.

:class:`SelfTuningController` is the indirect self-tuning regulator of the mission. Every sample
its compiled lane step (:mod:`stcgym.adaptive.kernels.controller`) runs: estimator update ->
change detection -> certainty-equivalence design (pole placement or LQ) in the safe set ->
Kalman state estimate on the estimated model -> control (a short seeded probe, then the tracking
law) -> process noise and state step. ``num_envs=B`` holds ``B`` lane records in one array and
steps them in a ``prange``; a single controller is the case ``B = 1`` of the same code, so a
single plant equals its lane of a batch bit for bit.

Options are grouped like SB3's ``policy_kwargs`` (:mod:`stcgym.adaptive.options`):
:class:`EstimatorOptions`, :class:`StartupOptions`, :class:`SafeSet`, :class:`ChangeDetection`,
:class:`LawOptions` (frozen dataclasses, validated on construction; the known-model oracles
take the same ``law``); the common settings are plain keywords. ``predict`` and ``reset`` are
those of :class:`~stcgym.adaptive.policy.LanePolicy`.

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

import warnings
from numbers import Integral
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.kernels import controller as kc
from stcgym.adaptive.kernels import design as dz
from stcgym.adaptive.kernels.estimator import check_int
from stcgym.adaptive.kernels.extended_ls import extended_ls_layout
from stcgym.adaptive.options import (
    DEFAULT_POLE,
    ChangeDetection,
    EstimatorOptions,
    LawOptions,
    SafeSet,
    StartupOptions,
    option_group,
    plant_settings,
)
from stcgym.adaptive.placement import characteristic_coefficients, check_poles
from stcgym.adaptive.policy import LanePolicy
from stcgym.envs.canonical import observer_to_observability_b

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

#: Observations beyond this magnitude are rejected (squares would overflow inside the step).
OBSERVATION_LIMIT = 1e100
#: Estimator names besides the paper's: extended least squares on the ARMAX form.
EXTRA_ESTIMATORS = ("ELS",)


class SelfTuningController(LanePolicy):
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
        Saturation (default: the env's, else
        :data:`~stcgym.adaptive.options.DEFAULT_ACTION_BOUND` = 10).
    num_envs
        ``None`` for one plant (``predict`` on ``(2,)`` gives ``(1,)``), or ``B`` lanes
        (``predict`` on ``(B, 2)`` gives ``(B, 1)``).
    seed
        Probe seed: an int (lane ``i`` gets ``seed + i``) or one int per lane.
    form
        Canonical form of the plant (``theta`` is reported in it); default the env's, else
        ``"observer"``.
    env
        Optional env or vector env to check ``n``, ``form``, ``action_bound``, ``num_envs``.
    estimator_options, startup, safe_set, change_detection, law
        Option groups (instances or dicts; :mod:`stcgym.adaptive.options`). ``law`` is shared
        with the known-model oracles.

    Raises
    ------
    ValueError
        Any setting outside its documented range (the message names it).
    """

    observation_limit = OBSERVATION_LIMIT

    def __init__(
        self,
        n: int,
        *,
        estimator: str = "ELS",
        design: str = "pole_placement",
        poles: ArrayLike = DEFAULT_POLE,
        action_bound: float | None = None,
        num_envs: int | None = None,
        seed: int | ArrayLike = 0,
        form: str | None = None,
        env: Any = None,
        estimator_options: EstimatorOptions | dict | None = None,
        startup: StartupOptions | dict | None = None,
        safe_set: SafeSet | dict | None = None,
        change_detection: ChangeDetection | dict | None = None,
        law: LawOptions | dict | None = None,
    ) -> None:
        self.n = n = check_int(n, "n (plant order)", 1)
        self.num_envs, self.action_bound, self.form = plant_settings(
            n, num_envs=num_envs, action_bound=action_bound, form=form, env=env
        )
        self.B = self.num_lanes
        if design not in ("pole_placement", "lq"):
            raise ValueError(f"design must be 'pole_placement' or 'lq', got {design!r}")
        self.design = design
        self.estimator_options = eo = option_group(
            estimator_options, EstimatorOptions, "estimator_options"
        )
        self.startup = option_group(startup, StartupOptions, "startup")
        self.safe_set = option_group(safe_set, SafeSet, "safe_set")
        self.change_detection = cd = option_group(
            change_detection, ChangeDetection, "change_detection"
        )
        self.law = lw = option_group(law, LawOptions, "law")
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
            est_size, d = est_lay.size, 3 * n
        else:
            from stcgym.adaptive.kernels.estimator import EstimatorSpec, parse_name

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
            est_size, d = self._spec.size, 2 * n
        # the estimator's record ends with its scratch ("scratch" / "work"), shared with the design
        if self._spec is None:
            est_scratch = est_lay.fields["scratch"][1][0]
        else:
            est_scratch = self._spec.layout.fields["work"][1][0]
        self._layout, self._off = kc.controller_layout(n, est_size, est_scratch, lq=design == "lq")
        # -- configuration arrays
        cf = np.zeros(kc.C_ALPHA + m)
        cf[kc.C_ACTION_BOUND] = self.action_bound
        cf[kc.C_PROBE] = self.startup.probe_amplitude
        cf[kc.C_Q_GAIN] = eo.process_noise_gain
        cf[kc.C_Q_FLOOR] = eo.process_noise_floor
        cf[kc.C_R] = eo.measurement_noise
        cf[kc.C_THRESHOLD] = cd.threshold
        cf[kc.C_INFLATION] = cd.inflation
        cf[kc.C_P0] = self.p0
        cf[kc.C_LAMBDA] = eo.forgetting
        cf[kc.C_EW_SHORT] = cd.short
        cf[kc.C_EW_LONG] = cd.long
        cf[kc.C_SAFE : kc.C_SAFE + 4] = self.safe_set.vector()
        cf[kc.C_WEIGHTS : kc.C_WEIGHTS + 3] = lw.lq_weights
        cf[kc.C_PROBE_OUTPUT] = self.startup.probe_output
        cf[kc.C_ALPHA :] = characteristic_coefficients(self.poles)
        ci = np.full(kc.N_KCFG, -1, dtype=np.int64)
        ci[kc.K_N] = n
        ci[kc.K_INTEGRAL] = int(lw.integral)
        ci[kc.K_FEEDFORWARD] = int(lw.feedforward)
        ci[kc.K_ANTI_WINDUP] = int(lw.anti_windup)
        ci[kc.K_FILTERED] = int(lw.filtered)
        ps = self.startup.probe_steps
        ci[kc.K_PROBE_STEPS] = 2 * n if ps is None else ps
        pm = self.startup.max_probe_steps
        ci[kc.K_PROBE_MAX] = max(5 * n if pm is None else pm, ci[kc.K_PROBE_STEPS])
        ci[kc.K_DESIGN] = kc.LQ if design == "lq" else kc.POLE_PLACEMENT
        ci[kc.K_DETECT] = int(cd.enabled)
        ci[kc.K_HOLDOFF] = cd.holdoff
        ci[kc.K_D] = d
        base = int(self._off[kc.O_EST])
        init = self._layout.empty(1)[0]
        if self._spec is None:
            ci[kc.K_EST] = kc.ELS
            ci[kc.K_FORM] = dz.OBSERVER  # ELS estimates the observer-form transfer function
            eoff = est_lay.offsets(("theta", "S", "phi", "scratch")) + base
            ci[kc.K_ELS : kc.K_ELS + 4] = eoff
            init[eoff[1] : eoff[1] + d * d] = (np.sqrt(self.p0) * np.eye(d)).ravel()  # P = S S^T
            # read-only like the paper estimators' config: one compiled signature for both
            self._ecf = np.zeros(1)
            self._eci = np.zeros(1, dtype=np.int64)
            self._ecf.setflags(write=False)
            self._eci.setflags(write=False)
        else:
            spec = self._spec
            ci[kc.K_EST] = kc.PAPER
            observability = self._estimation_form == "observability"
            ci[kc.K_FORM] = dz.OBSERVABILITY if observability else dz.OBSERVER
            ci[kc.K_TH] = base + spec.offset("theta")
            ci[kc.K_E] = base + spec.offset("E")
            ci[kc.K_S] = base + spec.offset("S") if spec.least_squares else -1
            ci[kc.K_EQ] = base + spec.offset("Q") if spec.state == "KF" else -1
            init[base : base + spec.size] = spec.initial_record()
            self._ecf = np.asarray(spec.cfg_f, dtype=np.float64)
            self._eci = np.asarray(spec.cfg_i, dtype=np.int64)
        init[self._off[kc.O_P1] : self._off[kc.O_P1] + n * n] = np.eye(n).ravel()
        if design == "lq":
            P_lq = dz.lq_initial_P(n, lw.integral, np.asarray(lw.lq_weights, dtype=float))
            o = self._off[kc.O_PLQ]
            init[o : o + P_lq.size] = P_lq.ravel()
        cf.setflags(write=False)
        ci.setflags(write=False)
        init.setflags(write=False)
        self._cf, self._ci, self._init = cf, ci, init
        self._F = np.empty((self.B, self._layout.size))
        self._G = np.zeros((self.B, kc.N_INT), dtype=np.int64)
        self._G[:, kc.I_SEED] = self.seeds
        self._G[:, kc.I_EPISODE] = -1  # the first reset starts episode 0
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

    # ------------------------------------------------------------------ protocol
    def _reset_lanes(self, idx: NDArray) -> None:
        """Start a new episode on the lanes ``idx``.

        Estimator at ``theta(0) = 0``, ``P(0) = p0 I``; Kalman filter at ``x(1) = 0``,
        ``P1(1) = I``; no gain; ``t = 0``; each reset lane's episode counter advances, so its
        probe is a new sequence."""
        self._F[idx] = self._init
        G = self._G
        episodes = G[idx, kc.I_EPISODE] + 1
        G[idx] = 0
        G[idx, kc.I_SEED] = self.seeds[idx]
        G[idx, kc.I_EPISODE] = episodes
        G[idx, kc.I_CLOSED_T] = -1

    def _act(self, obs: NDArray, starts: NDArray | None, deterministic: bool) -> NDArray:
        """``u(t)`` of every lane from ``[y(t), r(t)]``; ``deterministic`` is ignored (the probe
        is part of the law)."""
        if starts is not None:
            self._reset_lanes(np.flatnonzero(starts))
        u = self._u
        if self.B == 1:
            y, r = obs[0].tolist()  # Python floats: the cheapest arguments for numba's dispatch
            u[0] = kc.controller_step(
                self._F[0], self._G[0], self._off, self._cf, self._ci, self._ecf, self._eci,
                y, r,
            )  # fmt: skip
        else:
            y = np.ascontiguousarray(obs[:, 0])
            r = np.ascontiguousarray(obs[:, 1])
            kc.controllers_step(
                self._F, self._G, self._off, self._cf, self._ci, self._ecf, self._eci, y, r, u
            )
        return u.copy()

    # ------------------------------------------------------------------ views
    def _lanes_out(self, arr: NDArray) -> NDArray:
        return arr[0].copy() if self.num_envs is None else arr.copy()

    @property
    def theta(self) -> NDArray:
        """``theta_hat = [a_hat; b_hat]`` in the plant's canonical form (per lane if batched)."""
        n = self.n
        o = int(self._ci[kc.K_ELS] if self._spec is None else self._ci[kc.K_TH])
        th = self._F[:, o : o + 2 * n].copy()
        if self.form == "observability" and self._estimation_form == "observer":
            for i in range(self.B):
                if np.all(np.isfinite(th[i])):
                    th[i, n:] = observer_to_observability_b(th[i, :n], th[i, n:])
        return self._lanes_out(th)

    @property
    def x_hat(self) -> NDArray:
        """The controller's state estimate ``x(t+1|t)`` (Kalman filter on the estimated model)."""
        o = self._off[kc.O_X]
        return self._lanes_out(self._F[:, o : o + self.n])

    @property
    def K(self) -> NDArray:
        """Gain in use ``[K_x, k_i]`` (zeros before the first accepted design)."""
        o = self._off[kc.O_GAIN]
        m = self.n + int(self.law.integral)
        return self._lanes_out(self._F[:, o : o + m])

    @property
    def N(self) -> NDArray | float:
        """Reference feed-forward gain in use."""
        o = self._off[kc.O_GAIN] + self.n + 1
        v = self._F[:, o].copy()
        return float(v[0]) if self.num_envs is None else v

    @property
    def t(self) -> int | NDArray:
        """Samples since the lane's last reset."""
        v = self._G[:, kc.I_T].copy()
        return int(v[0]) if self.num_envs is None else v

    @property
    def diagnostics(self) -> dict[str, Any]:
        """Counters and flags per lane (scalars for a single controller)."""
        G = self._G
        has_gain = self._F[:, self._off[kc.O_GAIN] + self.n + 2] > 0
        out = {
            "t": G[:, kc.I_T],
            "episode": G[:, kc.I_EPISODE],
            "has_gain": has_gain,
            "closed_at": G[:, kc.I_CLOSED_T],
            "n_rejected": G[:, kc.I_N_REJECTED],
            "last_rejection": np.array([dz.STATUS_NAMES[c] for c in G[:, kc.I_LAST_REASON]]),
            "n_alarms": G[:, kc.I_N_ALARMS],
            "n_saturated": G[:, kc.I_N_SATURATED],
            "n_probe": G[:, kc.I_N_PROBE],
            "n_kf_resets": G[:, kc.I_N_KF_RESETS],
            "estimator_status": G[:, kc.I_EST_STATUS],
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
