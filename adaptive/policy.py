"""The policy protocol shared by the classical controllers and the RL agents, and its base class.

The protocol is the calling convention of Stable-Baselines3 models,

    action, state = policy.predict(obs, state=None, episode_start=None, deterministic=True)

plus ``reset()``, so one evaluation loop can run an SB3 model, the self-tuning regulator and the
known-model oracles alike. SB3 models satisfy :class:`Policy` structurally (``isinstance`` works
through :class:`typing.runtime_checkable`) except for ``reset``; :func:`reset_policy` copes with
both.

:class:`LanePolicy` writes ``predict`` once for every policy of stcgym. Such a policy keeps one
lane per plant (``num_envs=None``: one plant; ``num_envs=B``: ``B`` plants, see
:mod:`stcgym.lanes.compiled`):

* ``num_envs=None`` takes one observation of shape ``(obs_dim,)`` and gives an action of shape
  ``(action_dim,)``; ``num_envs=B`` takes ``(B, obs_dim)`` and gives ``(B, action_dim)``
  (``action_dim = 1`` for the single-input controllers). Any other shape, a batch
  given to a single policy included, is a ``ValueError`` naming ``observation`` and the shape
  expected.
* ``episode_start`` (a bool or one per lane, as SB3's ``evaluate_policy`` passes it) starts a
  new episode on those lanes first.
* The recurrent ``state`` argument is returned unchanged: a policy keeps its own state per lane
  (the SB3 adapter its LSTM state).
* Everything is validated before any lane is touched: a rejected call changes nothing.

A subclass sets ``num_envs`` and implements two hooks: :meth:`LanePolicy._act` (the step of
every lane on a validated ``(lanes, obs_dim)`` batch) and :meth:`LanePolicy._reset_lanes`
(a new episode on some lanes). :meth:`LanePolicy.reset` validates its ``lanes`` argument and
calls the latter.
"""

from __future__ import annotations

import math
import sys
from abc import ABC, abstractmethod
from numbers import Integral
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.lanes.compiled import set_lanes
from stcgym.lanes.validation import lane_indices

__all__ = [
    "OBSERVATION_LIMIT",
    "LanePolicy",
    "Policy",
    "episode_starts",
    "reset_policy",
    "validate_observation",
]


@runtime_checkable
class Policy(Protocol):
    """Anything with SB3's ``predict`` signature.

    A structural protocol (:func:`typing.runtime_checkable`): SB3's models, the self-tuning
    controllers, the known-model oracles and any object of your own with such a ``predict``
    are policies; ``isinstance`` checks only that ``predict`` exists. A policy with
    per-episode state also has ``reset()`` (see :func:`reset_policy`).

    Examples
    --------
    >>> import numpy as np
    >>> from stcgym.adaptive import Policy
    >>> class Proportional:
    ...     def predict(self, observation, state=None, episode_start=None, deterministic=True):
    ...         y, r = observation
    ...         return np.array([0.5 * (r - y)]), state
    >>> isinstance(Proportional(), Policy)
    True
    >>> Proportional().predict(np.array([0.2, 1.0]))
    (array([0.4]), None)
    """

    def predict(
        self,
        observation: Any,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[NDArray, Any]:
        """The actions for ``observation`` and the (recurrent) state, as SB3's models return."""
        ...


def reset_policy(policy: Any) -> None:
    """Call ``policy.reset()`` when it has one (SB3 feed-forward policies have no state).

    Parameters
    ----------
    policy : object
        Any policy; an object without a callable ``reset`` is left alone.

    Returns
    -------
    None

    Examples
    --------
    >>> from stcgym.adaptive import reset_policy
    >>> class Counter:
    ...     steps = 3
    ...     def reset(self):
    ...         self.steps = 0
    >>> c = Counter()
    >>> reset_policy(c), c.steps
    (None, 0)
    >>> reset_policy(object())  # no reset: nothing to do
    """
    reset = getattr(policy, "reset", None)
    if callable(reset):
        reset()


def validate_observation(observation: ArrayLike, obs_dim: int) -> tuple[NDArray, bool]:
    """Return ``(obs_batch, single)``: a finite ``(B, obs_dim)`` float array and whether the input
    was a single observation. Raises ``ValueError`` with the offending values otherwise."""
    try:
        obs = np.asarray(observation, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"observation must be numeric, got {observation!r}") from exc
    single = obs.ndim == 1
    if single:
        obs = obs[None, :]
    if obs.ndim != 2 or obs.shape[1] != obs_dim:
        raise ValueError(
            f"observation must have shape ({obs_dim},) or (batch, {obs_dim}) "
            f"([y(t), r(t)]), got shape {np.shape(observation)}"
        )
    if not np.all(np.isfinite(obs)):
        raise ValueError(
            f"observation must be finite, got {obs[0] if single else obs}; the policy was left "
            "unchanged"
        )
    return obs, single


def episode_starts(episode_start: ArrayLike | bool | None, batch: int) -> NDArray:
    """``episode_start`` as ``batch`` bools (one bool is broadcast); ``ValueError`` naming it
    when it is not boolean (0/1 integers pass) or its length is neither 1 nor ``batch``."""
    if episode_start is None:
        return np.zeros(batch, dtype=bool)
    es = np.asarray(episode_start)
    if es.dtype != bool and not (es.dtype.kind in "iu" and np.all((es == 0) | (es == 1))):
        raise ValueError(f"episode_start must be booleans, got {episode_start!r}")
    starts = es.astype(bool).reshape(-1)
    if starts.size == 1:
        return np.full(batch, bool(starts[0]))
    if starts.size != batch:
        raise ValueError(
            f"episode_start must be a bool or have one entry per observation ({batch}), "
            f"got {starts.size}"
        )
    return starts


#: Observations beyond this magnitude are rejected by the self-tuning controllers and the LQ
#: oracle (squares would overflow inside their steps).
OBSERVATION_LIMIT = 1e100

_FLOAT64 = np.dtype(np.float64)
_FLOAT_MAX = sys.float_info.max


class LanePolicy(ABC):
    """SB3's ``predict`` and ``reset`` for a policy of one plant or of ``num_envs`` plants.

    Subclasses set :attr:`num_envs` and implement :meth:`_act` and :meth:`_reset_lanes`; see the
    module docstring for the calling convention.
    """

    #: Length of one observation: the envs observe ``[y(t), r(t)]``.
    obs_dim: int = 2
    #: Length of one action (the number of plant inputs).
    action_dim: int = 1
    #: Largest accepted observation magnitude (a policy whose step would overflow sets it).
    observation_limit: float = math.inf
    #: ``None`` (one plant) or the number of lanes ``B``.
    num_envs: int | None = None

    @property
    def num_lanes(self) -> int:
        """Lanes held: 1 for a single plant, else ``num_envs``."""
        return 1 if self.num_envs is None else self.num_envs

    def predict(
        self,
        observation: ArrayLike,
        state: Any = None,
        episode_start: ArrayLike | bool | None = None,
        deterministic: bool = True,
    ) -> tuple[NDArray, Any]:
        """SB3's calling convention: the actions for ``observation`` (one row per lane).

        Parameters
        ----------
        observation
            ``[y(t), r(t)]``: shape ``(obs_dim,)`` for ``num_envs=None``, ``(num_envs,
            obs_dim)`` otherwise; finite, magnitude at most :attr:`observation_limit`.
        state
            Returned unchanged (the policy keeps its own state per lane).
        episode_start
            A bool or one bool per lane: those lanes start a new episode first.
        deterministic
            Passed on to the policy's step (the classical controllers ignore it).

        Returns
        -------
        actions, state
            ``(action_dim,)`` for a single plant, ``(num_envs, action_dim)`` for lanes;
            ``state`` as given.

        Raises
        ------
        ValueError
            A malformed ``observation`` or ``episode_start``, or a step the policy rejects; the
            policy is left unchanged.
        """
        if (
            episode_start is None
            and self.num_envs is None
            and type(observation) is np.ndarray
            and observation.dtype is _FLOAT64
            and observation.shape == (self.obs_dim,)
        ):
            # the common single-plant call; a non-finite or too large value (the comparison
            # fails for nan and inf) takes the validating path below
            bound = min(self.observation_limit, _FLOAT_MAX)
            values = observation.tolist()
            for v in values:
                if not -bound <= v <= bound:
                    break
            else:
                return self._act_one(observation, values, deterministic), state
        obs, single = self._observations(observation)
        starts = episode_starts(episode_start, self.num_lanes)
        actions = self._act(obs, starts if starts.any() else None, deterministic)
        dim = self.action_dim
        return (actions.reshape(dim) if single else actions.reshape(-1, dim)), state

    def reset(self, lanes: ArrayLike | None = None) -> None:
        """Start a new episode on every lane, or on ``lanes`` (indices or a boolean mask)."""
        self._reset_lanes(lane_indices(lanes, self.num_lanes))

    def _repr(self, settings: str) -> str:
        """``Class(settings)``, with ``num_envs`` for lanes: the policies' ``repr``."""
        lanes = "" if self.num_envs is None else f", num_envs={self.num_envs}"
        return f"{type(self).__name__}({settings}{lanes})"

    def _lanes_out(self, arr: NDArray, scalar: type | None = None) -> Any:
        """A copy of every lane of ``arr``; for a single plant a copy of lane 0, or lane 0 as a
        Python ``scalar`` (``int``, ``float``) when given."""
        if self.num_envs is not None:
            return arr.copy()
        return arr[0].copy() if scalar is None else scalar(arr[0])

    def _observations(self, observation: ArrayLike) -> tuple[NDArray, bool]:
        """The validated ``(lanes, obs_dim)`` batch and whether a single observation was given."""
        obs, single = validate_observation(observation, self.obs_dim)
        if single != (self.num_envs is None) or obs.shape[0] != self.num_lanes:
            expected = (
                f"({self.obs_dim},)"
                if self.num_envs is None
                else f"({self.num_envs}, {self.obs_dim}), one row per lane"
            )
            raise ValueError(
                f"observation must have shape {expected} for num_envs={self.num_envs}, got "
                f"shape {np.shape(observation)}"
            )
        too_large = np.abs(obs) > self.observation_limit
        if too_large.any():
            raise ValueError(
                f"observation magnitude must be <= {self.observation_limit:g}, got "
                f"{obs[too_large.any(axis=1)][0]}; the policy was left unchanged"
            )
        return obs, single

    @abstractmethod
    def _act(self, obs: NDArray, starts: NDArray | None, deterministic: bool) -> NDArray:
        """Step every lane: ``obs`` is a validated ``(lanes, obs_dim)`` batch, ``starts`` a
        boolean mask of the lanes that start an episode first (``None``: none). Returns a new
        array of the actions of every lane, ``lanes * action_dim`` values (shape ``(lanes,)``
        or ``(lanes, action_dim)``; a single plant's fast path returns it as it is, so a policy
        of ``action_dim > 1`` returns ``(action_dim,)`` there); a step that fails raises
        ``ValueError`` and changes nothing."""

    def _act_one(self, observation: NDArray, values: list, deterministic: bool) -> NDArray:
        """The single plant's step on a validated observation (``values``: the same as Python
        floats); by default :meth:`_act` on a batch of one. A policy whose one-plant step can
        skip the batch's array handling overrides it (the cost every Gymnasium step pays)."""
        return self._act(observation[None, :], None, deterministic)

    @abstractmethod
    def _reset_lanes(self, idx: NDArray) -> None:
        """Start a new episode on the lanes ``idx`` (validated int64 indices)."""


class SelfTuningLanes(LanePolicy):
    """The lane state and counters of the self-tuning controllers (SISO and MIMO).

    Every lane counts the step ``t``, the ``episode``, the step the loop closed at
    (``closed_t``, ``-1`` while open) and the counters that :attr:`diagnostics` reports, and
    keeps the ``seed`` of its probe; :meth:`_counter` gives one of them for every lane. A
    controller holds its lane state ``_state`` (a named tuple of batched arrays with those
    counters as fields, :func:`stcgym.lanes.compiled.lane_state`) and its estimator's ``_est``;
    a reset copies one lane's initial values ``_init`` and ``_est_init`` into them.
    """

    observation_limit = OBSERVATION_LIMIT
    #: One seed per lane.
    seeds: NDArray
    #: The name of each status code of the designs (``last_rejection`` of :attr:`diagnostics`).
    status_names: tuple[str, ...]
    _state: Any
    _init: Any
    _est: Any
    _est_init: Any

    def _lane_ints(self, value: Any, name: str) -> NDArray:
        """``value + 0..B-1`` for an int, else ``B`` ints (one per lane), as int64."""
        B = self.num_lanes
        if isinstance(value, Integral) and not isinstance(value, bool):
            return (int(value) + np.arange(B)).astype(np.int64)
        try:
            arr = np.asarray(value)
        except (ValueError, TypeError):  # ragged nested sequences
            arr = np.empty(0)
        if arr.ndim != 1 or arr.size != B or arr.dtype.kind not in "iu":
            raise ValueError(f"{name} must be an int or {B} ints (one per lane), got {value!r}")
        return arr.astype(np.int64)

    def _counter(self, name: str) -> NDArray:
        """The counter ``name`` of every lane (``(lanes,)`` int64, a view)."""
        return getattr(self._state, name)

    def _reset_lanes(self, idx: NDArray) -> None:
        """A new episode on the lanes ``idx``: the state back to ``_init`` (the estimator's to
        ``_est_init``), the lane's seed kept and its episode counter advanced, so its probe is a
        new sequence."""
        s = self._state
        episodes = s.episode[idx] + 1
        set_lanes(s, idx, self._init)
        s.seed[idx] = self.seeds[idx]
        s.episode[idx] = episodes
        set_lanes(self._est, idx, self._est_init)

    @property
    def t(self) -> int | NDArray:
        """Samples since the lane's last reset."""
        return self._lanes_out(self._counter("t"), int)

    def _diagnostics(
        self, flags: dict[str, NDArray], counters: dict[str, NDArray]
    ) -> dict[str, Any]:
        """:attr:`diagnostics`: ``t``, ``episode``, the controller's ``flags``, the loop's
        closing step and the shared counters, then the controller's own ``counters``; scalars
        for a single controller."""
        c = self._counter
        out = {
            "t": c("t"),
            "episode": c("episode"),
            **flags,
            "closed_at": c("closed_t"),
            "n_rejected": c("n_rejected"),
            "last_rejection": np.array([self.status_names[k] for k in c("last_reason")]),
            "n_alarms": c("n_alarms"),
            "n_saturated": c("n_saturated"),
            "n_probe": c("n_probe"),
            **counters,
        }
        if self.num_envs is None:
            return {k: (v[0].item() if hasattr(v[0], "item") else v[0]) for k, v in out.items()}
        return {k: v.copy() for k, v in out.items()}
