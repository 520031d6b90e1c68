"""The window interface: an RL agent's observation window alone, and its action as the input
applied (the base of every interface of :mod:`stcgym.agents.rl.interfaces`)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.agents.rl.wrappers import HistoryBuffer, WindowConfig

__all__ = ["WindowInterface"]


class WindowInterface:
    """The window alone, for ``batch`` lanes: ``u = clip(a, -L, L) s`` with ``s`` the action
    unit and ``L = u_max / s`` the half-width of the action box.

    Parameters
    ----------
    window : WindowConfig
        The window's settings.
    action_bound : float
        ``u_max``.
    batch : int
        Lanes.
    channels : (int, int)
        Outputs and inputs ``(p, m)``.
    action_unit : float, optional
        ``s``; default ``u_max`` (the box ``[-1, 1]``).

    Attributes
    ----------
    action_unit, action_limit : float
        ``s`` and ``L``: the agent's action box is ``[-L, L]`` per input.

    Examples
    --------
    With the bound 27 and a unit of 3 the action 0.5 is the input 1.5, and the whole bound
    stays reachable (the box is ``[-9, 9]``):

    >>> import numpy as np
    >>> from stcgym.agents import WindowConfig
    >>> from stcgym.agents.rl.interfaces import WindowInterface
    >>> lanes = WindowInterface(WindowConfig(window=2), 27.0, batch=2, action_unit=3.0)
    >>> lanes.action_limit
    9.0
    >>> lanes.to_input(np.array([[0.5], [20.0]]))[:, 0].tolist()
    [1.5, 27.0]
    """

    def __init__(
        self,
        window: WindowConfig,
        action_bound: float,
        batch: int = 1,
        channels: tuple[int, int] = (1, 1),
        *,
        action_unit: float | None = None,
    ) -> None:
        self.window, self.action_bound, self.batch = window, float(action_bound), int(batch)
        self.channels = (int(channels[0]), int(channels[1]))
        self.buffer = HistoryBuffer(window, self.action_bound, self.batch, *self.channels)
        self.action_unit = self.action_bound if action_unit is None else float(action_unit)
        self.action_limit = self.action_bound / self.action_unit

    @property
    def n_features(self) -> int:
        return self.window.features_for(*self.channels)

    def observe(self, obs: ArrayLike, starts: NDArray | None = None) -> None:
        """The observation ``[y(t), r(t)]`` of every lane; ``starts`` (a boolean mask) marks
        the lanes whose episode starts with it (``None``: none)."""
        if starts is not None and starts.any():
            self.buffer.start(obs, starts)
            if not starts.all():
                self.buffer.push_obs(obs, ~starts)
        else:
            self.buffer.push_obs(obs)

    def terminal_features(self, last: NDArray, lanes: NDArray) -> NDArray:
        """The features of the final observations ``last`` of the lanes ``lanes`` (a boolean
        mask), whose next :meth:`observe` starts an episode (rows of other lanes: unused)."""
        self.buffer.push_obs(last, lanes)
        return self.buffer.features()

    def features(self) -> NDArray:
        """``(batch, n_features)`` float32 network input."""
        return self.buffer.features()

    def _record(self, u: NDArray) -> NDArray:
        self.buffer.push_action(u)
        return u

    def to_input(self, action: ArrayLike) -> NDArray:
        """The input ``(batch, m)`` applied for the network's ``action`` (recorded)."""
        limit = self.action_limit
        a = np.clip(np.asarray(action, dtype=float).reshape(self.batch, -1), -limit, limit)
        return self._record(np.clip(a * self.action_unit, -self.action_bound, self.action_bound))

    def _with_extra(self, window: NDArray, extra: NDArray) -> NDArray:
        clip = self.window.obs_clip
        extra = np.clip(np.nan_to_num(extra), -clip, clip).astype(np.float32)
        return np.concatenate([window, extra], axis=1)
