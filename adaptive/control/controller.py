"""Self-tuning controller: one class for one plant or a batch of plants.

:class:`SelfTuningController` is the indirect self-tuning regulator of the mission. Every sample
its compiled lane step (:mod:`stcgym.adaptive.control.controller_step`) runs: estimator update ->
change detection -> certainty-equivalence design (pole placement or LQ) in the safe set ->
Kalman state estimate on the estimated model -> control (a short seeded probe, then the tracking
law) -> process noise and state step. ``num_envs=B`` holds ``B`` lanes of named state (a row of
every field each) and steps them in one batch loop; a single controller is the case ``B = 1`` of
the same code, so a single plant equals its lane of a batch bit for bit.

Options are grouped like SB3's ``policy_kwargs`` (:mod:`stcgym.adaptive.control.options`):
:class:`EstimatorOptions`, :class:`StartupOptions`, :class:`SafeSet`, :class:`ChangeDetection`,
:class:`LawOptions` (frozen dataclasses, validated on construction; the known-model oracles
take the same ``law``); the common settings are plain keywords. ``predict`` and ``reset`` are
those of :class:`~stcgym.adaptive.policy.LanePolicy`.

Start-up
--------
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
(:mod:`stcgym.adaptive.control.extended_ls`), consistent in closed loop from any start. A name of
the seed paper (``"O-RLS"``, ``"KF-MILS"``, ... :data:`stcgym.adaptive.ALGORITHMS`) runs the
paper's estimator with the closed-loop settings of :class:`EstimatorOptions` (the regressor
from ``x_hat(t|t)``, the ``KF-`` filters' own ``R``, the ``O-`` estimators' partial output
injection). Every estimator identifies the observer-form realization of the plant's transfer
function; ``theta`` is reported in the plant's form.
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.control import controller_step as kc
from stcgym.adaptive.control.extended_ls import ExtendedLSConfig, make_extended_ls
from stcgym.adaptive.control.options import (
    DEFAULT_POLE,
    ChangeDetection,
    EstimatorOptions,
    LawOptions,
    SafeSet,
    StartupOptions,
    option_group,
)
from stcgym.adaptive.control.placement import characteristic_coefficients, check_poles
from stcgym.adaptive.control.safe_set import STATUS_NAMES, feedback_gain
from stcgym.adaptive.estimation.estimator_spec import EstimatorSpec
from stcgym.adaptive.policy import OBSERVATION_LIMIT, SelfTuningLanes, episode_starts
from stcgym.adaptive.variants import (
    DESIGNS,
    RULES,
    STATE_ESTIMATORS,
    CompiledVersion,
    EstimatorName,
    compiled_version,
    controller_estimator,
)
from stcgym.envs.canonical import observer_to_observability_b
from stcgym.envs.dynamics import OBSERVABILITY, OBSERVER
from stcgym.envs.env_settings import plant_settings
from stcgym.lanes.compiled import FixedTypes, read_only, state_nbytes_per_lane
from stcgym.lanes.validation import integer

__all__ = ["OBSERVATION_LIMIT", "SelfTuningController"]


@dataclass(frozen=True)
class _Steps:
    """The compiled entry points of one version, their argument types looked up once
    (:class:`~stcgym.lanes.compiled.FixedTypes`)."""

    step: FixedTypes  # one plant: controller_step(*args, 0, y, r)
    steps: FixedTypes  # every lane: controllers_step(*args, y, r, u)
    act: FixedTypes  # steps 1-5 (propose): controllers_act(*args, y, r, u)
    commit: FixedTypes  # step 6 (commit) with the applied input: controllers_commit(*args, u)


class _StepsByVersion(dict):
    """One :class:`_Steps` a compiled version (variants.compiled_version: the estimator and the
    design; the argument types differ between versions), made on first use."""

    def __missing__(self, version: CompiledVersion) -> _Steps:
        steps = self[version] = _Steps(
            step=FixedTypes(kc.controller_step),
            steps=FixedTypes(kc.controllers_step),
            act=FixedTypes(kc.controllers_act),
            commit=FixedTypes(kc.controllers_commit),
        )
        return steps


_STEPS = _StepsByVersion()


class SelfTuningController(SelfTuningLanes):
    """Indirect self-tuning regulator for one plant (``num_envs=None``) or ``B`` plants.

    Parameters
    ----------
    n
        Plant order.
    estimator
        ``"ELS"`` (default) or a paper name (``"O-RLS"``, ``"KF-MILS"``, ...; the SG, MISG and
        D- rules warn that they do not hold the loop on many plants).
    design
        A name of :data:`~stcgym.adaptive.variants.DESIGNS` (each entry says what it
        computes and its known-model oracle): ``"pole_placement"`` (Ackermann on the
        integral-augmented model, ``poles``) or ``"lq"`` (one Riccati iteration per step,
        weights ``law.lq_weights``).
    poles
        A scalar (all ``n + 1`` poles) or ``n + 1`` values (``n`` without integral action);
        a design that fixes the poles itself ignores it.
    action_bound
        Saturation (default: the env's, else
        :data:`~stcgym.envs.env_settings.DEFAULT_ACTION_BOUND` = 10).
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
        Option groups (instances or dicts; :mod:`stcgym.adaptive.control.options`). ``law`` is
        shared
        with the known-model oracles.

    Raises
    ------
    ValueError
        Any setting outside its documented range (the message names it).

    Examples
    --------
    On the open-loop unstable ``unstable2`` without noise, the estimate reaches the true
    parameters while the loop holds:

    >>> import gymnasium as gym
    >>> import stcgym.envs
    >>> from stcgym.adaptive import SelfTuningController
    >>> env = gym.make("stcgym/ObserverCanonical-v0", plant="unstable2", noise_std=0.0)
    >>> ctl = SelfTuningController(2, env=env)
    >>> obs, info = env.reset(seed=0)
    >>> for _ in range(300):
    ...     action, _ = ctl.predict(obs)
    ...     obs, reward, terminated, truncated, info = env.step(action)
    >>> terminated, np.round(ctl.theta, 3), info["theta"]
    (False, array([-1.699,  0.659,  0.5  ,  0.3  ]), array([-1.7 ,  0.66,  0.5 ,  0.3 ]))
    >>> ctl.K.shape  # [K_x, k_i] on the integral-augmented model
    (3,)

    One controller for ``B`` lanes of a vector env takes one observation row per lane:

    >>> batch = SelfTuningController(2, num_envs=3, seed=1)
    >>> batch.predict(np.zeros((3, 2)))[0].shape
    (3, 1)
    """

    status_names = STATUS_NAMES

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
        self.n = n = integer(n, "n (plant order)", 1)
        self.num_envs, self.action_bound, self.form = plant_settings(
            n, num_envs=num_envs, action_bound=action_bound, form=form, env=env
        )
        self.B = self.num_lanes
        if not isinstance(design, str) or design not in DESIGNS:
            raise ValueError(f"design must be one of {tuple(DESIGNS)}, got {design!r}")
        self.design = design
        d = DESIGNS[design]
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
        self.poles = check_poles(poles if d.poles is None else d.poles, m)
        self.seeds = self._lane_ints(seed, "seed")
        # -- estimator: its name resolved once into the registry's record
        v = controller_estimator(estimator)
        self.estimator = v.name
        # the canonical form the estimator identifies (ELS: always the observer form)
        plant_form = v.plant_form and eo.estimation_form == "plant"
        self._estimation_form = self.form if plant_form else "observer"
        #: ``P(0) = p0 I`` in use (``estimator_options.p0`` or the estimator's default)
        self.p0 = eo.initial_covariance(v)
        self._spec = self._paper_spec(v, estimator) if v.paper else None
        ps = self.startup.probe_steps
        probe_steps = 2 * n if ps is None else int(ps)
        pm = self.startup.max_probe_steps
        observability = self._estimation_form == "observability"
        cfg = kc.ControllerConfig(
            n=int(n),
            integral=bool(lw.integral),
            feedforward=bool(lw.feedforward),
            anti_windup=bool(lw.anti_windup),
            filtered=bool(lw.filtered),
            probe_steps=probe_steps,
            probe_max=max(5 * n if pm is None else int(pm), probe_steps),
            # ELS estimates the observer-form transfer function
            form=OBSERVABILITY if observability else OBSERVER,
            action_bound=float(self.action_bound),
            probe_amplitude=float(self.startup.probe_amplitude),
            q_gain=float(eo.process_noise_gain),
            q_floor=float(eo.process_noise_floor),
            R=float(eo.measurement_noise),
            probe_output=float(self.startup.probe_output),
            safe=read_only(self.safe_set.vector()),
            char_poly=read_only(characteristic_coefficients(self.poles)),
            **cd.step_fields(),
        )
        # the compiled version (variants.compiled_version) is chosen by which of est_cfg /
        # els_cfg is None (the step compiled for one estimator contains none of the other) and
        # the class of the design's compiled argument (the step contains that design only)
        self._version = compiled_version(v, d)
        cd = d.compiled_design
        if self._spec is None:  # extended least squares
            self._est_init, _ = make_extended_ls(n, 1, self.p0)
            est, est_work = make_extended_ls(n, self.B, self.p0)
            est_cfg, els_cfg = None, ExtendedLSConfig(float(eo.forgetting), float(self.p0))
        else:
            self._est_init = self._spec.initial_state()
            est, est_work = self._spec.make_state(self.B), self._spec.make_work(self.B)
            est_cfg, els_cfg = self._spec.config, None
        # a reset lane starts here: Kalman filter at x(1) = 0, P1(1) = I; no gain; the loop
        # open; the design at its cold start (the estimator at theta(0) = 0, P(0) = p0 I:
        # _est_init)
        init, _ = kc.make_controller_state(n, 1, lw, cd)
        init.P1[0] = np.eye(n)
        init.closed_t[0] = -1
        self._init = init
        state, work = kc.make_controller_state(n, self.B, lw, cd)
        state.seed[:] = self.seeds
        state.episode[:] = -1  # the first reset starts episode 0
        self._args = kc.ControllerArgs(
            s=state, w=work, cfg=cfg, est=est, est_work=est_work, est_cfg=est_cfg,
            els_cfg=els_cfg, design=cd.make_argument(n, lw),
        )  # fmt: skip
        self._u = np.zeros(self.B)
        self._step_one: Any = None  # the single plant's bound step (_act_one)
        self._open = False  # propose() has opened a sample that commit() has not ended
        self.reset()

    def _paper_spec(self, v: EstimatorName, estimator: str) -> EstimatorSpec:
        """The paper estimator ``v`` with the closed-loop settings of ``estimator_options``
        (the keywords that apply to its rule and state estimator); warns when it does not hold
        the loop."""
        if not v.holds_loop:
            slow = ", ".join(r for r, rule in RULES.items() if not rule.holds_loop)
            good = [r for r, rule in RULES.items() if rule.holds_loop]
            states = [name for name, st in STATE_ESTIMATORS.items() if st.paper]
            holding = [f"'{s}-{r}'" for s in reversed(states) for r in good]
            warnings.warn(
                f"estimator {estimator!r} does not hold the loop on a sizeable share of "
                f"ordinary plants: the gradient rules ({slow}) adapt too slowly for a cold "
                "start, and the decomposition rules (D-) update a and b as if their "
                "regressors were uncorrelated, which feedback makes them not; "
                f"{', '.join(holding)} or the default 'ELS' hold it",
                UserWarning,
                stacklevel=3,
            )
        n, eo = self.n, self.estimator_options
        kw: dict[str, Any] = {
            "p0": self.p0, "form": self._estimation_form, "forgetting": eo.forgetting,
            "theta0": np.zeros(2 * n),
        }  # fmt: skip
        if v.rule.multi_innovation:
            kw["p"] = eo.p
        if v.state.filtered_regressor:
            kw["regressor"] = eo.regressor
        if v.state.injection and eo.regressor == "filtered":
            kw["injection"] = eo.injection
            kw["injection_warmup"] = eo.injection_warmup
        if v.state.kalman:
            kw["process_noise"] = eo.process_noise_floor * np.eye(n)
            kw["measurement_noise"] = eo.kf_measurement_noise
        return EstimatorSpec.build(v, n, **kw)

    # ------------------------------------------------------------------ the compiled arguments
    @property
    def compiled_args(self) -> kc.ControllerArgs:
        """The arguments of the compiled steps (lane state, scratch, configurations), in
        their order: ``controller_step(*ctl.compiled_args, lane_i, y, r)``. Its arrays are the
        controller's own: a compiled call through them advances the controller."""
        return self._args

    @property
    def _state(self) -> kc.ControllerState:
        return self._args.s

    @property
    def _est(self) -> Any:
        return self._args.est

    # ------------------------------------------------------------------ protocol
    def _act_one(self, observation: NDArray, values: list, deterministic: bool) -> NDArray:
        """One plant's ``u(t)`` from ``[y(t), r(t)]`` (Python floats): the compiled step with
        every other argument bound once (the lane state and the configuration)."""
        step = self._step_one
        if step is None:  # the first call (or the first after unpickling)
            self._act(observation[None, :], None, deterministic)
            step = _STEPS[self._version].step
            self._step_one = functools.partial(step.entry, *self._args, 0)
            return self._u.copy()
        if self._open:
            self._refuse_open()
        u = self._u
        u[0] = step(values[0], values[1])
        return u.copy()

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_step_one"] = None  # binds the lane state's arrays: rebuilt after unpickling
        return state

    def _act(self, obs: NDArray, starts: NDArray | None, deterministic: bool) -> NDArray:
        """``u(t)`` of every lane from ``[y(t), r(t)]``; ``deterministic`` is ignored (the probe
        is part of the law)."""
        if self._open:
            self._refuse_open()
        if starts is not None:
            self._reset_lanes(np.flatnonzero(starts))
        u = self._u
        if self.B == 1:
            y, r = obs[0].tolist()  # Python floats: the cheapest arguments for numba's dispatch
            u[0] = _STEPS[self._version].step(*self._args, 0, y, r)
        else:
            y = np.ascontiguousarray(obs[:, 0])
            r = np.ascontiguousarray(obs[:, 1])
            _STEPS[self._version].steps(*self._args, y, r, u)
        return u.copy()

    # ------------------------------------------------------------------ applied input
    def propose(
        self, observation: ArrayLike, episode_start: ArrayLike | bool | None = None
    ) -> NDArray:
        """The input the controller chooses for ``[y(t), r(t)]``, leaving the sample open
        until :meth:`commit` says which input the plant was given.

        :meth:`predict` is ``propose`` and ``commit`` of the proposal. A caller that applies
        another input -- a residual agent's correction on top of the controller's, a safety
        filter, a human override -- proposes, applies its own input and commits that one: the
        controller's estimator and Kalman filter then hold the input the plant really got (an
        input they did not see would be an unmodelled disturbance, biasing ``theta_hat``).
        ``propose`` runs the estimator's measurement step with ``y(t)``, the design, ``x(t|t)``
        and the control law (steps 1-5 of
        :func:`~stcgym.adaptive.control.controller_step.controller_step`); ``commit`` the
        time update (step 6).

        Parameters
        ----------
        observation, episode_start
            As for :meth:`predict`.

        Returns
        -------
        NDArray
            The proposed ``u(t)``: ``(1,)`` for a single plant, ``(num_envs, 1)`` for lanes.

        Raises
        ------
        ValueError
            A malformed ``observation`` or ``episode_start`` (nothing changes).
        RuntimeError
            A sample is already open (commit it first).

        Examples
        --------
        A correction on top of the controller's input, handed back to it:

        >>> import numpy as np
        >>> from stcgym.adaptive import SelfTuningController
        >>> ctl = SelfTuningController(2)
        >>> u = ctl.propose(np.array([0.1, 1.0]))
        >>> ctl.commit(u + 0.2)  # the plant was given u + 0.2
        >>> ctl.t
        1
        """
        if self._open:
            self._refuse_open()
        obs, single = self._observations(observation)
        starts = episode_starts(episode_start, self.B)
        if starts.any():
            self._reset_lanes(np.flatnonzero(starts))
        u = self._u
        y = np.ascontiguousarray(obs[:, 0])
        _STEPS[self._version].act(*self._args, y, np.ascontiguousarray(obs[:, 1]), u)
        self._open = True
        return u.copy() if single else u.reshape(-1, 1).copy()

    def commit(self, applied: ArrayLike) -> None:
        """End the sample :meth:`propose` opened with the input the plant was given: the
        controller's time update (process noise, Kalman filter, the estimator's state step)
        runs on ``applied`` instead of its proposal.

        Parameters
        ----------
        applied
            ``u(t)`` as applied: a number or shape ``(1,)`` for a single plant, ``(num_envs,)``
            or ``(num_envs, 1)`` for lanes; finite. It is taken as given (not clipped to the
            controller's ``action_bound``).

        Raises
        ------
        RuntimeError
            No sample is open (:meth:`propose` first).
        ValueError
            ``applied`` of another size or not finite (nothing changes).
        """
        if not self._open:
            raise RuntimeError("commit(applied) ends a sample opened by propose(); none is open")
        u = np.asarray(applied, dtype=np.float64)
        if u.size != self.B or (u.ndim > 1 and u.shape[-1] != 1) or u.ndim > 2:
            shape = "(1,)" if self.num_envs is None else f"({self.B},) or ({self.B}, 1)"
            raise ValueError(
                f"applied must be the input of every lane, shape {shape}, got shape {u.shape}"
            )
        u = np.ascontiguousarray(u.reshape(self.B))
        if not np.all(np.isfinite(u)):
            raise ValueError(f"applied must be finite, got {u}")
        _STEPS[self._version].commit(*self._args, u)
        self._open = False

    def _refuse_open(self) -> None:
        raise RuntimeError(
            "propose() opened a sample: commit(applied) the input the plant was given first"
        )

    def _reset_lanes(self, idx: NDArray) -> None:
        if self._open:
            if np.unique(idx).size < self.B:
                raise RuntimeError(
                    "reset of some lanes while propose() has a sample open: commit(applied) "
                    "first (a reset of every lane drops the open sample)"
                )
            self._open = False
        super()._reset_lanes(idx)

    # ------------------------------------------------------------------ views
    @property
    def theta(self) -> NDArray:
        """``theta_hat = [a_hat; b_hat]`` in the plant's canonical form (per lane if batched)."""
        n = self.n
        th = self._est.theta[:, : 2 * n].copy()
        if self.form == "observability" and self._estimation_form == "observer":
            for i in range(self.B):
                if np.all(np.isfinite(th[i])):
                    th[i, n:] = observer_to_observability_b(th[i, :n], th[i, n:])
        return self._lanes_out(th)

    @property
    def x_hat(self) -> NDArray:
        """The controller's state estimate ``x(t+1|t)`` (Kalman filter on the estimated model)."""
        return self._lanes_out(self._state.x)

    @property
    def K(self) -> NDArray:
        """Gain in use ``[K_x, k_i]`` (zeros before the first accepted design)."""
        return self._lanes_out(feedback_gain(self._state.gain, self.law.integral))

    @property
    def N(self) -> NDArray | float:
        """Reference feed-forward gain in use."""
        return self._lanes_out(self._state.gain.N, float)

    @property
    def diagnostics(self) -> dict[str, Any]:
        """Counters and flags per lane (scalars for a single controller)."""
        s = self._state
        return self._diagnostics(
            {"has_gain": s.has_gain},
            {"n_kf_resets": s.n_kf_resets, "estimator_status": s.est_status},
        )

    @property
    def nbytes_per_lane(self) -> int:
        """Memory of one lane's state and scratch (the controller's and the estimator's)."""
        a = self._args
        return sum(map(state_nbytes_per_lane, (a.s, a.w, a.est, a.est_work)))

    def __repr__(self) -> str:
        return self._repr(f"n={self.n}, estimator={self.estimator!r}, design={self.design!r}")
