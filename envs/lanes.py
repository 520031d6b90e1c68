"""Per-lane building blocks of the vector environments (:mod:`stcgym.envs.vector`).

The per-episode random streams of a lane (:func:`episode_streams`), the block-refilled noise
buffers (:class:`LaneNormals`), the step of the lanes' parameter schedules and the checks of
the vector envs' arguments: constructor arguments, reset seeds, the reset mask, actions, options
given for all lanes or one per lane.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode
from numpy.typing import ArrayLike, NDArray

from stcgym.lanes.validation import real_array

__all__ = [
    "NOISE_BUFFER_BYTES",
    "LaneNormals",
    "advance_schedules",
    "episode_streams",
    "lane_actions",
    "lane_matrix",
    "lane_rows",
    "lane_seeds",
    "per_lane",
    "reset_mask",
    "vector_arguments",
]

#: Child indices of the per-episode ``SeedSequence`` split (see ``LinearPlantEnv.reset``).
STREAM_V, STREAM_W, STREAM_REF, STREAM_SCHED, STREAM_DRAW = range(5)
#: Default memory budget of one noise buffer (all lanes); sets the block length per refill.
NOISE_BUFFER_BYTES = 64 * 2**20


def episode_streams(entropy: int, which: Sequence[int]) -> list[np.random.Generator]:
    """Generators of the per-episode child streams ``which`` (indices 0-4) of ``entropy``.

    ``LinearPlantEnv.reset`` draws ``entropy = np_random.integers(2**63)`` and builds
    ``default_rng(c)`` for ``c in SeedSequence(entropy).spawn(5)`` (output noise, process noise,
    reference, schedule, draws). Child ``j`` is ``SeedSequence(entropy, spawn_key=(j,))``, so a
    subset costs only what it uses.

    Parameters
    ----------
    entropy : int
        The episode's entropy (a non-negative integer).
    which : sequence of int
        Child indices, each in ``0 .. 4``.

    Returns
    -------
    list of numpy.random.Generator
        One per entry of ``which``.

    Examples
    --------
    >>> import numpy as np
    >>> from stcgym.envs.vector import episode_streams
    >>> (noise,) = episode_streams(123, [0])
    >>> spawned = np.random.default_rng(np.random.SeedSequence(123).spawn(5)[0])
    >>> bool(noise.standard_normal() == spawned.standard_normal())
    True
    """
    return [np.random.default_rng(np.random.SeedSequence(entropy, spawn_key=(j,))) for j in which]


class LaneNormals:
    """Per-lane standard-normal streams with a shared read position, refilled in blocks.

    Row ``k`` of the buffer ``(block, B, width)`` holds every lane's next normals, so a step
    reads one contiguous row. A lane that restarts (new episode, new generator) mid-block fills
    the rest of the current block from its new generator; since numpy generators produce the
    same sequence however the draws are chunked, every lane sees exactly the normals its single
    environment would.
    """

    def __init__(self, num_envs: int, width: int, budget_bytes: int) -> None:
        self.width = width
        self.block = int(np.clip(budget_bytes // (8 * num_envs * max(width, 1)), 16, 512))
        self.buf = np.zeros((self.block, num_envs, width))
        self.rngs: list[np.random.Generator | None] = [None] * num_envs
        self.pos = self.block  # next row to read; == block means "refill first"

    def restart(self, idx: NDArray, rngs: list[np.random.Generator], first: bool) -> NDArray:
        """New generators for lanes ``idx``; returns their first row when ``first`` (else empty).

        The remaining rows of the current block are filled so that the next :meth:`take`
        continues each restarted lane's new stream.
        """
        out = np.empty((len(idx), self.width))
        rest = self.block - self.pos
        for j, (i, g) in enumerate(zip(idx, rngs, strict=True)):
            self.rngs[i] = g
            if first:
                out[j] = g.standard_normal((1, self.width))[0]
            if rest:
                self.buf[self.pos :, i, :] = g.standard_normal((rest, self.width))
        return out

    def take(self) -> NDArray:
        """One row ``(B, width)`` of normals (a view, valid until the next call)."""
        if self.pos == self.block:
            for i, g in enumerate(self.rngs):
                if g is not None:
                    self.buf[:, i, :] = g.standard_normal((self.block, self.width))
            self.pos = 0
        self.pos += 1
        return self.buf[self.pos - 1]

    @property
    def nbytes(self) -> int:
        return self.buf.nbytes


def per_lane(value: ArrayLike, num_envs: int, shape: tuple[int, ...], name: str) -> NDArray:
    """Broadcast an option to ``(num_envs, *shape)``: one value for all lanes or one per lane."""
    arr = real_array(value, name)
    if arr.shape == shape:
        arr = np.broadcast_to(arr, (num_envs, *shape))
    elif arr.shape != (num_envs, *shape):
        raise ValueError(
            f"{name} must have shape {shape} (all lanes) or {(num_envs, *shape)} (one per lane), "
            f"got {arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


def lane_rows(arr: NDArray, num_envs: int, width: int, name: str) -> NDArray:
    """``arr`` checked to be finite with one row of ``width`` per lane."""
    if arr.shape != (num_envs, width) or not np.all(np.isfinite(arr)):
        raise ValueError(f"per-lane {name} must be finite with shape ({num_envs}, {width})")
    return arr


def lane_matrix(
    options: dict[str, Any], key: str, shape: tuple[int, int], num_envs: int, default: NDArray
) -> NDArray:
    """Option ``key`` as one ``shape`` matrix per lane (``default`` for every lane if absent)."""
    if key not in options:
        return np.broadcast_to(default, (num_envs, *shape))
    return per_lane(options[key], num_envs, shape, f"options['{key}']")


def lane_seeds(seed: Any, num_envs: int) -> list[int | None] | None:
    """Reset seeds per lane as :class:`gymnasium.vector.SyncVectorEnv` reads them.

    ``s`` gives lane ``i`` the seed ``s + i``; a list gives one seed (or ``None``) per lane;
    ``None`` returns ``None`` (each lane keeps its generator).

    Raises
    ------
    TypeError
        ``seed`` of another kind.
    ValueError
        A list of the wrong length or with an entry that is not a non-negative integer or None.
    """
    B = num_envs
    if seed is None:
        return None
    if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
        return [int(seed) + i for i in range(B)]
    if isinstance(seed, (Sequence, np.ndarray)) and not isinstance(seed, str):
        seeds = list(seed)
        if len(seeds) != B:
            raise ValueError(f"a list of seeds must have num_envs={B} entries, got {len(seeds)}")
        for s in seeds:
            if s is not None and (
                isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0
            ):
                raise ValueError(f"seed entries must be non-negative integers or None, got {s!r}")
        return seeds
    raise TypeError(f"seed must be an int, a list of num_envs={B} ints, or None, got {seed!r}")


def reset_mask(mask: Any, num_envs: int) -> NDArray:
    """The lanes to reset: all for ``None``, else a bool array ``(num_envs,)`` with a True entry.

    Raises
    ------
    ValueError
        A mask of another shape or dtype, ragged, or selecting no lane.
    """
    B = num_envs
    if mask is None:
        return np.ones(B, dtype=bool)
    try:
        mask = np.asarray(mask)
    except (TypeError, ValueError):
        mask = np.zeros(0)  # ragged: reported below
    if mask.shape != (B,) or mask.dtype != np.bool_ or not mask.any():
        raise ValueError(
            f"options['reset_mask'] must be a bool array of shape ({B},) with a True entry"
        )
    return mask


def vector_arguments(
    num_envs: Any, max_episode_steps: Any, autoreset_mode: Any, render_mode: Any
) -> tuple[int, int | None, AutoresetMode]:
    """The checked ``(num_envs, max_episode_steps, autoreset_mode)`` of a vector env.

    Raises
    ------
    TypeError
        ``num_envs`` not an integer.
    ValueError
        ``num_envs < 1``; a ``render_mode`` (vector envs do not render); ``max_episode_steps``
        not a positive integer or None; an unknown ``autoreset_mode``.
    """
    if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)):
        raise TypeError(f"num_envs must be a positive integer, got {num_envs!r}")
    if num_envs < 1:
        raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
    if render_mode is not None:
        raise ValueError("the vector environments do not render; use a single env for that")
    if max_episode_steps is not None and (
        isinstance(max_episode_steps, bool)
        or not isinstance(max_episode_steps, (int, np.integer))
        or max_episode_steps < 1
    ):
        raise ValueError(
            f"max_episode_steps must be a positive integer or None, got {max_episode_steps!r}"
        )
    try:
        mode = AutoresetMode(autoreset_mode)
    except ValueError as exc:
        raise ValueError(
            f"autoreset_mode must be one of {[m.value for m in AutoresetMode]}, "
            f"got {autoreset_mode!r}"
        ) from exc
    return int(num_envs), None if max_episode_steps is None else int(max_episode_steps), mode


def lane_actions(actions: ArrayLike, num_envs: int, m: int, active: NDArray | None) -> NDArray:
    """Actions as a C-contiguous ``(num_envs, m)`` array (``(num_envs,)`` accepted for ``m = 1``).

    Lanes outside ``active`` (a bool mask; ``None``: all) may hold non-finite actions.

    Raises
    ------
    ValueError
        Actions of another shape, or not finite in an active lane.
    """
    B = num_envs
    u = real_array(actions, "actions")
    if u.shape == (B,) and m == 1:
        u = u.reshape(B, 1)
    if u.shape != (B, m):
        raise ValueError(f"actions must have shape ({B}, {m}), got {u.shape}")
    ok = np.isfinite(u)
    if not ok.all() and (active is None or not ok[active].all()):
        raise ValueError("actions must be finite (no lane was stepped)")
    return np.ascontiguousarray(u)


def advance_schedules(
    schedules: list[Any], schedule_id: NDArray, t: NDArray, params: NDArray, next_change: NDArray
) -> None:
    """Re-read, in place, ``params`` of the lanes whose schedule may have changed at step ``t``.

    Lane ``i`` follows ``schedules[schedule_id[i]]`` (``-1``: constant) and is due when
    ``next_change[i] <= t[i]``; its ``next_change`` moves on to the schedule's next change.
    """
    due = np.flatnonzero(next_change <= t)
    if due.size == 0:
        return
    for s, sched in enumerate(schedules):
        lanes = due[schedule_id[due] == s]
        if lanes.size:
            k = t[lanes]
            params[lanes] = sched.values(k, lanes)
            next_change[lanes] = sched.next_change(k, lanes)
