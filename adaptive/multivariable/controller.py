"""Multivariable self-tuning LQ control of measured-state plants, for one plant or a batch.

:class:`MultivariableSelfTuningController` closes the loop on ``stcgym/StateSpace-v0`` (``x+ =
A x + B u + w``, the state measured: ``C = I``, ``D = 0``). Every sample its compiled lane step
(:mod:`stcgym.adaptive.multivariable.controller_step`) runs: the ``[A B]`` estimator of Kunik,
Kovalenko & Al Sadi (2001) -> change detection -> certainty-equivalence LQ design in the safe
set -> control (a seeded probe at start-up, then ``u = sat(-K x + F r)``). ``num_envs=B`` holds
the state of ``B`` lanes and steps them in one batch loop; a single controller is the case
``B = 1`` of the same compiled step, so it equals its lane of a batch bit for bit.

Tracking is by feed-forward: ``F r`` steers to the equilibrium ``(x_s, u_s)`` of the estimated
model that is cheapest in the LQ cost for the reference ``r`` (the reference itself when it is
an equilibrium; with fewer inputs than states generally not every reference is).

Safe behaviour: until an estimate of full rank passes the safe set (stabilisable with a
Schur-stable closed loop, bounded gains, an equilibrium for every reference) the controller
applies only its bounded probe; a model that never becomes stabilisable therefore keeps the
probe, with ``diagnostics["n_rejected"]`` and ``["last_rejection"]`` saying why.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.control.options import (
    ChangeDetection,
    SafeSet,
    StartupOptions,
    option_group,
)
from stcgym.adaptive.control.safe_set import STATUS_NAMES
from stcgym.adaptive.multivariable import controller_step as km
from stcgym.adaptive.multivariable.state_matrix import make_state_matrix
from stcgym.adaptive.policy import SelfTuningLanes
from stcgym.envs.env_settings import (
    input_limits,
    mimo_env_settings,
    resolve_dimensions,
    split_observation,
)
from stcgym.lanes.compiled import FixedTypes
from stcgym.lanes.validation import covariance, real_in

__all__ = [
    "MultivariableSelfTuningController",
    "cross_weight",
    "lq_weight_matrices",
]

_step = FixedTypes(km.mimo_step)
_steps = FixedTypes(km.mimo_steps)

#: The start-up probe's input cost ``a^2 trace(R)`` is at most this share of the largest state
#: cost ``(x - r)^T Q (x - r)`` seen while probing (measured: the multivariable page).
PROBE_COST_SHARE = 0.004
#: ``P <- P0 I`` after a failed health check of the estimator's covariance.
P0_RESTART = 100.0
#: The design solves the Riccati equation to convergence, instead of one warm-started step, when
#: the model moved by less than ``SETTLE_TOL`` of its largest entry since the last sample while
#: that step moved ``P`` by more than ``LAG_TOL`` of its largest entry (measured on he1 and the
#: quadruple tank: the multivariable page).
SETTLE_TOL = 0.01
LAG_TOL = 0.05


def lq_weight_matrices(
    n: int, m: int, Q: Any = None, R: Any = None, control_cost: float = 0.01
) -> tuple[NDArray, NDArray]:
    """Validated LQ weights: ``Q`` (``n x n``, symmetric positive semidefinite, default ``I``)
    and ``R`` (``m x m``, symmetric positive definite, default ``control_cost I``), the env's
    cost ``||x - r||^2 + control_cost ||u||^2``. A scalar means that multiple of the identity,
    a vector the diagonal (:func:`stcgym.lanes.validation.covariance`)."""
    Qm = covariance(1.0 if Q is None else Q, n, "Q", allow_singular=True)
    return Qm, covariance(control_cost if R is None else R, m, "R")


def cross_weight(N: Any, Q: NDArray, R: NDArray) -> NDArray:
    """Validated cross weight ``N`` (``n x m``, default zero) of the stage cost
    ``x^T Q x + u^T R u + 2 x^T N u`` (python-control's ``dlqr(A, B, Q, R, N)``), for validated
    ``Q`` and ``R``: the joint weight ``[[Q, N], [N^T, R]]`` must be positive semidefinite, i.e.
    ``Q - N R^{-1} N^T`` is (otherwise the cost is unbounded below). ``ValueError`` naming
    ``N`` and the expected form otherwise."""
    n, m = Q.shape[0], R.shape[0]
    if N is None:
        return np.zeros((n, m))
    arr = np.asarray(N, dtype=float)
    if arr.ndim == 1 and m == 1 and arr.shape == (n,):
        arr = arr.reshape(n, 1)
    if arr.shape != (n, m) or not np.all(np.isfinite(arr)):
        raise ValueError(f"N must be a finite {n} x {m} matrix (states x inputs), got {N!r}")
    QN = Q - arr @ np.linalg.solve(R, arr.T)
    QN = 0.5 * (QN + QN.T)
    scale = max(1.0, float(np.max(np.abs(Q))))
    if np.min(np.linalg.eigvalsh(QN)) < -1e-10 * scale:
        raise ValueError(
            "N must leave the joint weight [[Q, N], [N^T, R]] positive semidefinite "
            f"(Q - N R^-1 N^T has the eigenvalue {np.min(np.linalg.eigvalsh(QN)):.3g}), got {N!r}"
        )
    return np.ascontiguousarray(arr)


def plant_and_weights(
    policy: Any, n: Any, m: Any, num_envs: Any, action_bound: Any, env: Any, Q: Any, R: Any, N: Any
) -> tuple[int, int]:
    """Set a state-feedback policy's plant settings and LQ weights; return ``(n, m)``.

    ``n_states``, ``n_inputs`` (= ``action_dim``), ``obs_dim``, ``num_envs`` and
    ``action_bound`` from the arguments and ``env``
    (:func:`~stcgym.envs.env_settings.resolve_dimensions`); ``Q``, ``R``
    (:func:`lq_weight_matrices`, ``R`` by default the env's control cost) and ``N``
    (:func:`cross_weight`).
    """
    n, m, policy.num_envs, policy.action_bound, cost, policy.obs_dim = resolve_dimensions(
        n, m, num_envs, action_bound, env
    )
    policy.n_states, policy.n_inputs = n, m
    policy.action_dim = m
    policy.Q, policy.R = lq_weight_matrices(n, m, Q, R, cost)
    policy.N = cross_weight(N, policy.Q, policy.R)
    return n, m


class MultivariableSelfTuningController(SelfTuningLanes):
    """Self-tuning LQ controller of a measured-state plant ``x+ = A x + B u`` (module docstring).

    Parameters
    ----------
    n_states, n_inputs
        Plant dimensions (read from ``env`` when given; they must match it).
    env
        A ``stcgym/StateSpace-v0`` env or vector env: dimensions, ``action_bound``,
        ``control_cost`` (the default ``R``) and ``num_envs``; its output must be the state.
        Or any Gymnasium env (or vector env) whose observation is a 1-D ``Box`` holding the
        state ``x`` (regulation to zero) or ``[x, r]`` (give ``n_states``), with a 1-D ``Box``
        action space: ``n_inputs`` and ``action_bound`` (the largest symmetric bound inside
        it) are read from it (:func:`~stcgym.envs.env_settings.mimo_env_settings`).
    num_envs
        ``None`` for one plant (``predict`` on ``(2 n,)`` gives ``(m,)``), or ``B`` lanes
        (``(B, 2 n)`` gives ``(B, m)``).
    Q, R
        LQ weights (default the env's cost: ``Q = I``, ``R = control_cost I``); ``Q`` positive
        semidefinite, ``R`` positive definite.
    N
        Cross weight ``(n, m)`` of the stage cost ``e^T Q e + u^T R u + 2 e^T N u``, ``e = x - r``
        (python-control's ``dlqr(A, B, Q, R, N)``; default zero); ``[[Q, N], [N^T, R]]`` must
        be positive semidefinite.
    action_bound
        Saturation of every input (default the env's, else 10).
    input_range
        ``(low, high)``: every input's range, numbers or ``m`` values each, with
        ``low < 0 < high`` (default the env's input range or action space, else
        ``+-action_bound``); kept inside ``+-action_bound``. The controller clips its input to
        it, so that the estimator learns from the input the plant received.
    seed
        Probe seed: an int (lane ``i`` gets ``seed + i``) or one int per lane.
    forgetting
        ``lambda`` of the estimator in ``(0, 1]``.
    dependence_tol
        Relative threshold of the minimum-norm phase below which a regressor counts as
        dependent on the past ones.
    startup, safe_set, change_detection
        Option groups of :mod:`stcgym.adaptive.control.options` (``probe_steps`` default ``n + m +
        1``,
        one more than the fewest probe samples that give ``n + m`` regressors, a full-rank
        estimate; the amplitude is also capped so that the probe's input cost ``a^2 trace(R)``
        stays within :data:`PROBE_COST_SHARE` of the largest state cost ``(x - r)^T Q (x - r)``
        seen while probing, and a capped default probe stops at ``n + m`` samples, unextended;
        ``max_probe_steps`` ``5 (n + m)``; the safe set uses ``b_min`` and ``gain_max``).

    Raises
    ------
    ValueError
        Dimensions missing or not matching ``env``, an env whose output is not the state,
        malformed ``Q``/``R``/``N``, ``action_bound`` or ``seed``, ``forgetting`` outside
        ``(0, 1]``, ``dependence_tol`` outside ``(0, 1)``, an option group or dict with a field
        out of its range.

    Attributes
    ----------
    K : ndarray -- gain in use, ``(m, n)`` or ``(B, m, n)`` (zeros before the first design).
    F : ndarray -- reference feed-forward in use, same shapes.
    A_hat, B_hat : ndarray -- the estimate ``[A B]``.

    Examples
    --------
    In closed loop with a double integrator sampled at 0.1 s (observation ``[x, x_ref]``):
    after the probe the estimate is the true model and the gain that of the known-model
    :class:`~stcgym.adaptive.LQRController`:

    >>> import numpy as np
    >>> from stcgym.adaptive import LQRController, MultivariableSelfTuningController
    >>> A = np.array([[1.0, 0.1], [0.0, 1.0]])
    >>> B = np.array([[0.005], [0.1]])
    >>> stc = MultivariableSelfTuningController(2, 1, Q=1.0, R=0.01, seed=0)
    >>> x, x_ref = np.zeros(2), np.array([1.0, 0.0])
    >>> for t in range(50):
    ...     u, _ = stc.predict(np.concatenate([x, x_ref]))
    ...     x = A @ x + B @ u
    >>> np.round(stc.A_hat, 4), np.round(stc.B_hat, 4)
    (array([[1. , 0.1],
           [0. , 1. ]]), array([[0.005],
           [0.1  ]]))
    >>> np.allclose(stc.K, LQRController(A, B, Q=1.0, R=0.01).K)
    True
    >>> np.round(x, 3)
    array([0.976, 0.024])
    """

    status_names = STATUS_NAMES

    def __init__(
        self,
        n_states: int | None = None,
        n_inputs: int | None = None,
        *,
        env: Any = None,
        num_envs: int | None = None,
        Q: ArrayLike | float | None = None,
        R: ArrayLike | float | None = None,
        N: ArrayLike | None = None,
        action_bound: float | None = None,
        input_range: tuple[Any, Any] | None = None,
        seed: int | ArrayLike = 0,
        forgetting: float = 1.0,
        dependence_tol: float = 1e-9,
        startup: StartupOptions | dict | None = None,
        safe_set: SafeSet | dict | None = None,
        change_detection: ChangeDetection | dict | None = None,
    ) -> None:
        n, m = plant_and_weights(self, n_states, n_inputs, num_envs, action_bound, env, Q, R, N)
        env_range = None if env is None else mimo_env_settings(env, n_states)["input_range"]
        self.input_low, self.input_high = input_limits(
            input_range, m, float(self.action_bound), env_range
        )
        self.forgetting = real_in(forgetting, "forgetting", lo=0.0, hi=1.0, lo_open=True)
        self.dependence_tol = real_in(
            dependence_tol, "dependence_tol", lo=0.0, hi=1.0, lo_open=True, hi_open=True
        )
        self.startup = su = option_group(startup, StartupOptions, "startup")
        self.safe_set = ss = option_group(safe_set, SafeSet, "safe_set")
        self.change_detection = cd = option_group(
            change_detection, ChangeDetection, "change_detection"
        )
        self.B = self.num_lanes
        self.seeds = self._lane_ints(seed, "seed")
        q = n + m
        # the shortest probe was the cheapest on a random family of MIMO plants (median
        # episode ratio 1.022-1.024 against 1.036-1.039 with 2 (n + m), 3 seeds); n + m probe
        # samples give the n + m regressors [x; u] of a full-rank estimate, and a probe capped
        # by the state cost stops there (every open-loop sample then costs more than the
        # estimate gains from it: the multivariable page), an uncapped one takes one more
        probe_steps = q + 1 if su.probe_steps is None else int(su.probe_steps)
        probe_min = q if su.probe_steps is None else probe_steps
        probe_max = 5 * q if su.max_probe_steps is None else int(su.max_probe_steps)
        self._cfg = km.MimoConfig(
            n=n,
            m=m,
            probe_steps=probe_steps,
            probe_min=probe_min,
            probe_max=max(probe_max, probe_steps),
            action_bound=float(self.action_bound),
            probe_amplitude=float(su.probe_amplitude),
            probe_output=float(su.probe_output),
            probe_cost_share=PROBE_COST_SHARE,
            input_weight=float(np.trace(self.R)),
            forgetting=float(self.forgetting),
            dependence_tol=float(self.dependence_tol),
            p0=P0_RESTART,
            b_min=float(ss.b_min),
            gain_max=float(ss.gain_max),
            solve_tol=1e-12,
            solve_max_iter=64,
            settle_tol=SETTLE_TOL,
            lag_tol=LAG_TOL,
            Q=np.array(self.Q, dtype=float),
            R=np.array(self.R, dtype=float),
            N=np.array(self.N, dtype=float),
            **cd.step_fields(),
        )
        # a reset lane starts here: C = 0, the minimum-norm phase from R = I, no gain, P_lq = Q
        self._est_init, _ = make_state_matrix(n, m, 1)
        self._est, self._est_work = make_state_matrix(n, m, self.B)
        init, _ = km.make_mimo_state(n, m, 1)
        init.P_lq[0] = self.Q
        init.u_low[0] = self.input_low
        init.u_high[0] = self.input_high
        init.closed_t[0] = -1
        init.fresh[0] = True  # a fresh model to design for
        self._init = init
        self._state, self._work = km.make_mimo_state(n, m, self.B)
        self._state.seed[:] = self.seeds
        self._state.episode[:] = -1  # the first reset starts episode 0
        self._u = np.zeros((self.B, m))
        self.reset()

    # ------------------------------------------------------------------ protocol
    def _act(self, obs: NDArray, starts: NDArray | None, deterministic: bool) -> NDArray:
        """``u(t)`` of every lane from ``[x(t), r(t)]``."""
        if starts is not None:
            self._reset_lanes(np.flatnonzero(starts))
        X, Rr = split_observation(obs, self.n_states)
        args = (self._state, self._work, self._est, self._est_work)
        if self.num_envs is None:
            _step(*args, 0, self._cfg, X[0], Rr[0], self._u[0])
            return self._u[0].copy()
        _steps(*args, self._cfg, X, Rr, self._u)
        return self._u.copy()

    def _act_one(self, observation: NDArray, values: list, deterministic: bool) -> NDArray:
        """One plant's ``u(t)`` from ``[x(t), r(t)]``: the compiled step on the two halves of
        the observation (contiguous views), without the batch's array handling."""
        n = self.n_states
        if self.obs_dim == n or not observation.flags.c_contiguous:  # r = 0, or a strided view
            return self._act(observation[None, :], None, deterministic)
        u = self._u[0]
        _step(self._state, self._work, self._est, self._est_work, 0, self._cfg,
              observation[:n], observation[n:], u)  # fmt: skip
        return u.copy()

    # ------------------------------------------------------------------ views
    @property
    def K(self) -> NDArray:
        """Gain in use, ``(m, n)`` (``(B, m, n)`` for lanes); zeros before the first design."""
        return self._lanes_out(self._state.K)

    @property
    def F(self) -> NDArray:
        """Reference feed-forward in use (``u = -K x + F r``), shapes as :attr:`K`."""
        return self._lanes_out(self._state.F)

    @property
    def theta(self) -> NDArray:
        """The estimate ``[A_hat B_hat]``, ``(n, n + m)`` (``(B, n, n + m)`` for lanes)."""
        return self._lanes_out(np.swapaxes(self._est.theta, 1, 2))

    @property
    def A_hat(self) -> NDArray:
        """The estimate ``A_hat`` ``(n, n)`` (per lane ``(B, n, n)``), the first ``n`` columns of
        :attr:`theta`."""
        return self.theta[..., : self.n_states]

    @property
    def B_hat(self) -> NDArray:
        """The estimate ``B_hat`` ``(n, m)`` (per lane ``(B, n, m)``), the last ``m`` columns of
        :attr:`theta`."""
        return self.theta[..., self.n_states :]

    @property
    def diagnostics(self) -> dict[str, Any]:
        """Counters and flags per lane (scalars for a single controller)."""
        q = self.n_states + self.n_inputs
        flags = {"has_gain": self._state.has_gain, "full_rank": self._est.rank >= q}
        return self._diagnostics(
            flags, {"n_resets": self._state.n_resets, "n_catch_up": self._state.n_catch_up}
        )

    def __repr__(self) -> str:
        return self._repr(f"n_states={self.n_states}, n_inputs={self.n_inputs}")
