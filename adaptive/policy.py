"""A minimal policy protocol shared by the classical controllers and the RL agents.

It is the calling convention of Stable-Baselines3 models,

    action, state = policy.predict(obs, state=None, episode_start=None, deterministic=True)

plus ``reset()``, so one evaluation loop can run an SB3 model, the self-tuning regulator and the
known-model oracles alike. SB3 models satisfy :class:`Policy` structurally (``isinstance`` works
through :class:`typing.runtime_checkable`) except for ``reset``; :func:`reset_policy` copes with
both.

:class:`StatefulPolicy` is the base of the known-model oracles (the self-tuning controller,
:class:`~stcgym.adaptive.controller.SelfTuningController`, holds its lanes in arrays itself).
A controller is a causal filter with internal state (estimates, integrator); the base class
turns a single-observation step ``_act(obs) -> u`` into the SB3 convention:

* a single observation of shape ``(obs_dim,)`` gives an action of shape ``(1,)``;
* a batch of shape ``(B, obs_dim)`` (a vectorised env) gives actions of shape ``(B, 1)``; each
  batch row ("lane") is served by its own deep copy of the freshly reset controller, created on
  first use, so the lanes never share state;
* ``episode_start`` (a bool or an array of ``B`` bools, as SB3's ``evaluate_policy`` passes it)
  resets the controller (the lane) before it acts;
* the recurrent ``state`` argument is accepted and returned unchanged (``None``): the state is kept
  inside the object;
* every observation of the call is validated before any lane is touched, so a rejected call
  (wrong shape, NaN/inf) leaves every controller exactly as it was.
"""

from __future__ import annotations

import copy
from abc import ABC, abstractmethod
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["Policy", "StatefulPolicy", "reset_policy", "validate_observation"]


@runtime_checkable
class Policy(Protocol):
    """Anything with SB3's ``predict`` signature."""

    def predict(
        self,
        observation: Any,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[NDArray, Any]: ...


def reset_policy(policy: Any) -> None:
    """Call ``policy.reset()`` when it has one (SB3 feed-forward policies have no state)."""
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
            f"observation must be finite, got {obs[0] if single else obs}; the controller state "
            "was left unchanged"
        )
    return obs, single


class StatefulPolicy(ABC):
    """Base class: SB3-style ``predict`` over a per-lane stateful single-step law ``_act``."""

    #: Length of one observation; the envs observe ``[y(t), r(t)]``.
    obs_dim: int = 2

    def __init__(self) -> None:
        self._lanes: list[StatefulPolicy] | None = None

    # -- to implement -------------------------------------------------------------------------
    @abstractmethod
    def _reset_state(self) -> None:
        """Restore the state the controller had right after construction."""

    @abstractmethod
    def _act(self, obs: NDArray) -> float:
        """One step on one finite observation of shape ``(obs_dim,)``; returns ``u(t)``."""

    # -- protocol -----------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the episode: estimates, integrator, excitation, logs; batch lanes dropped."""
        self._lanes = None
        self._reset_state()

    def predict(
        self,
        observation: ArrayLike,
        state: Any = None,
        episode_start: ArrayLike | bool | None = None,
        deterministic: bool = True,
    ) -> tuple[NDArray, Any]:
        """SB3-compatible step; see the module docstring.

        ``deterministic`` is accepted for compatibility only: the controllers' excitation signals
        are seeded pseudo-random sequences that are part of the control law, and the result is
        reproducible either way. A batch of observations runs one copy of this controller per
        row (same settings and seed, hence the same excitation sequence), like B identical
        controllers on B plants; the batched controllers take a seed per lane instead.
        """
        obs, single = validate_observation(observation, self.obs_dim)
        starts = self._episode_starts(episode_start, obs.shape[0])
        if single:
            if starts[0]:
                self.reset()
            return np.array([self._act(obs[0])]), state
        if self._lanes is None or len(self._lanes) != obs.shape[0]:
            proto = copy.deepcopy(self)
            proto.reset()
            self._lanes = [copy.deepcopy(proto) for _ in range(obs.shape[0])]
        actions = np.empty((obs.shape[0], 1))
        for i, lane in enumerate(self._lanes):
            if starts[i]:
                lane.reset()
            actions[i, 0] = lane._act(obs[i])
        return actions, state

    @staticmethod
    def _episode_starts(episode_start: ArrayLike | bool | None, batch: int) -> NDArray:
        if episode_start is None:
            return np.zeros(batch, dtype=bool)
        starts = np.asarray(episode_start, dtype=bool).reshape(-1)
        if starts.size == 1:
            return np.full(batch, bool(starts[0]))
        if starts.size != batch:
            raise ValueError(
                f"episode_start must be a bool or have one entry per observation ({batch}), "
                f"got {starts.size}"
            )
        return starts
