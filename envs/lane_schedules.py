"""The time-varying parameter schedules of the ``B`` lanes of a native vector environment.

Lanes that follow the same schedule (the same key: the constructor's schedule, or a catalogue
plant's) share one schedule object holding every lane's state; lane ``i`` follows
``schedules[schedule_id[i]]`` (``-1``: constant parameters) and must re-read its parameters at
step ``next_change[i]``. :class:`~stcgym.envs.vector_base.LinearPlantVectorEnv` starts a lane's
schedule when the lane starts an episode and advances the due lanes after each step.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Hashable, Sequence

import numpy as np
from numpy.typing import NDArray

from stcgym.envs.lanes import STREAM_SCHED, advance_schedules, episode_streams
from stcgym.envs.signals import NEVER, Schedule

__all__ = ["LaneSchedules"]


class LaneSchedules:
    """The schedules of ``num_envs`` lanes, keyed like the vector env's schedule keys.

    Parameters
    ----------
    num_envs : int
        Number of lanes ``B``.

    Attributes
    ----------
    schedules : list of Schedule
        One object per key met so far.
    schedule_id : ndarray of int64, shape (B,)
        Lane ``i``'s index in ``schedules``; ``-1``: constant parameters.
    next_change : ndarray of int64, shape (B,)
        The first step at which lane ``i``'s parameters must be re-read.
    """

    def __init__(self, num_envs: int) -> None:
        self.num_envs = num_envs
        self.schedules: list[Schedule] = []
        self._keys: dict[Hashable, int] = {}
        self.schedule_id = np.full(num_envs, -1, dtype=np.int64)
        self.next_change = np.full(num_envs, NEVER, dtype=np.int64)

    @property
    def varying(self) -> bool:
        """Whether some lane follows a time-varying schedule."""
        return bool((self.schedule_id >= 0).any())

    def _index(self, key: Hashable, make: Callable[[Hashable], Schedule]) -> int:
        if key not in self._keys:
            sched = make(key)
            sched.allocate(self.num_envs)
            self._keys[key] = len(self.schedules)
            self.schedules.append(sched)
        return self._keys[key]

    def start(
        self,
        idx: NDArray,
        nominal: NDArray,
        keys: Sequence[Hashable | None],
        entropy: Sequence[int],
        make: Callable[[Hashable], Schedule],
    ) -> NDArray:
        """Start the schedules of lanes ``idx`` at ``t = 0``; returns their ``params(0)``.

        ``nominal[j]`` and ``keys[j]`` (``None``: constant) are lane ``idx[j]``'s nominal
        parameters and schedule key, ``entropy[j]`` its episode entropy (whose schedule stream
        a random schedule draws from); ``make(key)`` builds the schedule object of a key met
        for the first time (the vector env's hook).
        """
        params = np.array(nominal, dtype=float, copy=True)
        self.schedule_id[idx] = -1
        self.next_change[idx] = NEVER
        for key in {key for key in keys if key is not None}:
            rows = np.array([j for j, kj in enumerate(keys) if kj == key], dtype=np.int64)
            lanes = idx[rows]
            s = self._index(key, make)
            sched = self.schedules[s]
            rngs = [episode_streams(entropy[j], [STREAM_SCHED])[0] for j in rows]
            sched.reset_lanes(lanes, params[rows], rngs)
            zero = np.zeros(len(lanes), dtype=np.int64)
            params[rows] = sched.values(zero, lanes)
            if sched.time_varying:
                self.schedule_id[lanes] = s
                self.next_change[lanes] = sched.next_change(zero, lanes)
        return params

    def advance(self, t: NDArray, params: NDArray) -> None:
        """Re-read, in place, ``params`` of the lanes whose schedule may have changed at ``t``."""
        advance_schedules(self.schedules, self.schedule_id, t, params, self.next_change)

    def lookahead(self, t: NDArray, params: NDArray, steps: int) -> NDArray:
        """The parameters in force at steps ``t + j``, ``j < steps``, shape ``(B, steps, ...)``,
        on copies of the schedules (nothing here changes)."""
        scheds = copy.deepcopy(self.schedules)
        params = params.copy()
        next_change = self.next_change.copy()
        out = np.empty((self.num_envs, steps, *params.shape[1:]))
        for j in range(steps):
            advance_schedules(scheds, self.schedule_id, t + j, params, next_change)
            out[:, j] = params
        return out

    @property
    def nbytes(self) -> int:
        """Bytes of the per-lane arrays."""
        return self.schedule_id.nbytes + self.next_change.nbytes
