"""A minimal policy protocol shared by the classical controllers and the RL agents.

It is the calling convention of Stable-Baselines3 models,

    action, state = policy.predict(obs, state=None, episode_start=None, deterministic=True)

plus ``reset()``, so one evaluation loop can run an SB3 model, the self-tuning regulator and the
known-model oracles alike. SB3 models satisfy :class:`Policy` structurally (``isinstance`` works
through :class:`typing.runtime_checkable`) except for ``reset``; :func:`reset_policy` copes with
both.

Every controller of stcgym keeps its lanes in arrays itself (one lane record per plant, see
:mod:`stcgym.envs.compiled`): a single observation of shape ``(obs_dim,)`` gives an action of
shape ``(1,)``, a batch ``(B, obs_dim)`` gives ``(B, 1)``; ``episode_start`` (a bool or ``B``
bools, as SB3's ``evaluate_policy`` passes it) resets those lanes first; the recurrent
``state`` is returned unchanged; every observation is validated before any lane is touched.
:func:`validate_observation` and :func:`episode_starts` are the shared checks.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["Policy", "episode_starts", "reset_policy", "validate_observation"]


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


def episode_starts(episode_start: ArrayLike | bool | None, batch: int) -> NDArray:
    """``episode_start`` as ``batch`` bools (one bool is broadcast); ``ValueError`` naming it
    when its length is neither 1 nor ``batch``."""
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
