"""The RL agents' observation: a window of past outputs, references and inputs.

The plant state is not observed (unless it is the output, as on the measured-state MIMO
plants); an RL agent sees what the self-tuning controller sees, the input/output history.
:class:`HistoryWindow` turns the raw ``[y(k), r(k)]`` observation of a SISO stcgym environment
into a flat ``float32`` vector of the last ``W`` samples::

    [ y(k-W+1) .. y(k) | r(k-W+1) .. r(k) | u(k-W) .. u(k-1) | e(k-W+1) .. e(k) ]
       / y_scale          / y_scale           / action_bound     / y_scale (optional)

with ``e = r - y``. With ``p`` outputs and ``m`` inputs (``stcgym/StateSpace-v0``, whose
measured-state output is the state ``x``) each block holds the window of every channel in turn
(``y_1`` window, ..., ``y_p`` window), so the SISO vector is the case ``p = m = 1``. Samples
before the start of the episode are zero (the environment's own convention: every signal is
zero before the first step). Values are clipped to ``[-obs_clip, obs_clip]`` so that a run-away
output cannot blow up the network's inputs.

The action space is normalised to ``[-1, 1]`` and rescaled to the environment's
``[-action_bound, action_bound]`` (the Stable-Baselines3 tip for continuous actions: Gaussian and
squashed policies work best on a unit box).

The same feature construction is needed at evaluation time, when the harness hands every
controller the raw environment observation: :class:`HistoryBuffer` holds it and is shared by the
wrapper (training) and :class:`stcgym.agents.rl.sb3.SB3Policy` (evaluation), so the two cannot drift
apart.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import ArrayLike, NDArray

__all__ = ["WindowConfig", "HistoryBuffer", "HistoryWindow", "TrainingReward"]


@dataclass(frozen=True)
class WindowConfig:
    """How the observation window is built.

    Parameters
    ----------
    window
        Number ``W`` of past samples of each signal (``W >= 1``). The plant order bounds what
        is needed: an order-``n`` plant is fully described by ``n`` past outputs and inputs, and
        a few more help with noise.
    include_error
        Append the tracking error ``e = r - y`` (redundant, but it spares the network a
        subtraction and speeds learning up).
    y_scale
        Outputs, references and errors are divided by it (the reference amplitude is a good
        choice).
    obs_clip
        Every feature is clipped to ``[-obs_clip, obs_clip]`` after scaling.

    Raises
    ------
    ValueError
        On construction: ``window`` not an integer ``>= 1``, ``y_scale`` or ``obs_clip`` not a
        finite positive number.

    Examples
    --------
    >>> from stcgym.agents import WindowConfig
    >>> WindowConfig(window=3).n_features  # y, r, u and e = r - y
    12
    >>> WindowConfig(window=3, include_error=False).n_features
    9
    >>> WindowConfig(window=0)
    Traceback (most recent call last):
    ...
    ValueError: window must be an integer >= 1, got 0
    """

    window: int = 10
    include_error: bool = True
    y_scale: float = 1.0
    obs_clip: float = 10.0

    def __post_init__(self) -> None:
        if int(self.window) != self.window or self.window < 1:
            raise ValueError(f"window must be an integer >= 1, got {self.window!r}")
        if not (np.isfinite(self.y_scale) and self.y_scale > 0):
            raise ValueError(f"y_scale must be a positive number, got {self.y_scale!r}")
        if not (np.isfinite(self.obs_clip) and self.obs_clip > 0):
            raise ValueError(f"obs_clip must be a positive number, got {self.obs_clip!r}")

    @property
    def n_features(self) -> int:
        """Length of the SISO observation: ``window`` rows of y, r, u (and r - y)."""
        return self.features_for(1, 1)

    def features_for(self, n_outputs: int, n_inputs: int) -> int:
        """Length of the observation with ``n_outputs`` outputs and ``n_inputs`` inputs."""
        per_output = 3 if self.include_error else 2
        return self.window * (per_output * int(n_outputs) + int(n_inputs))

    def to_dict(self) -> dict[str, Any]:
        """The window's settings as JSON data."""
        return asdict(self)


class HistoryBuffer:
    """Windows of ``y``, ``r`` (``n_outputs`` each) and ``u`` (``n_inputs``) for ``batch``
    independent lanes.

    Call :meth:`start` with the first observation of an episode, then alternate
    :meth:`push_action` (the input actually applied) and :meth:`push_obs` (the observation that
    followed); :meth:`features` gives the network input at any time.

    Parameters
    ----------
    config : WindowConfig
        The window's settings.
    action_bound : float
        Inputs are divided by it (the env's action bound).
    batch : int, default 1
        Number of lanes.
    n_outputs, n_inputs : int, default 1
        Channels of ``y`` (and ``r``) and of ``u``.

    Examples
    --------
    A window of two samples without the error rows, ``y(0) = 0.5``, ``u(0) = 2``,
    ``y(1) = 0.8`` and ``r = 1``:

    >>> from stcgym.agents import HistoryBuffer, WindowConfig
    >>> buf = HistoryBuffer(WindowConfig(window=2, include_error=False), action_bound=10.0)
    >>> buf.start([0.5, 1.0])
    >>> buf.push_action([2.0])
    >>> buf.push_obs([0.8, 1.0])
    >>> buf.features()  # [y(0), y(1) | r(0), r(1) | u(-1), u(0) / 10]
    array([[0.5, 0.8, 1. , 1. , 0. , 0.2]], dtype=float32)
    """

    def __init__(
        self,
        config: WindowConfig,
        action_bound: float,
        batch: int = 1,
        n_outputs: int = 1,
        n_inputs: int = 1,
    ) -> None:
        self.config, self.action_bound, self.batch = config, float(action_bound), int(batch)
        self.n_outputs, self.n_inputs = int(n_outputs), int(n_inputs)
        w, p = config.window, self.n_outputs
        self._y = np.zeros((batch, p, w))
        self._r = np.zeros((batch, p, w))
        self._u = np.zeros((batch, self.n_inputs, w))

    def _split(self, obs: ArrayLike) -> tuple[NDArray, NDArray]:
        p = self.n_outputs
        o = np.asarray(obs, dtype=float).reshape(self.batch, 2 * p)
        return o[:, :p], o[:, p:]

    def start(self, obs: ArrayLike, lanes: ArrayLike | None = None) -> None:
        """Begin an episode (all lanes, or the boolean mask ``lanes``) at observation ``obs``.

        Parameters
        ----------
        obs : array_like, shape (batch, 2 n_outputs)
            ``[y(0), r(0)]`` per lane (a ``(2 n_outputs,)`` array for one lane).
        lanes : array_like of bool, optional
            Boolean mask of length ``batch`` (default all lanes).
        """
        mask = np.ones(self.batch, bool) if lanes is None else np.asarray(lanes, bool)
        y, r = self._split(obs)
        for arr in (self._y, self._r, self._u):
            arr[mask] = 0.0
        self._y[mask, :, -1], self._r[mask, :, -1] = y[mask], r[mask]

    def push_obs(self, obs: ArrayLike, lanes: ArrayLike | None = None) -> None:
        """Append ``[y(k), r(k)]`` (for all lanes, or the boolean mask ``lanes``).

        Parameters
        ----------
        obs : array_like, shape (batch, 2 n_outputs)
            ``[y(k), r(k)]`` per lane.
        lanes : array_like of bool, optional
            Boolean mask of length ``batch`` (default all lanes).
        """
        mask = np.ones(self.batch, bool) if lanes is None else np.asarray(lanes, bool)
        y, r = self._split(obs)
        for arr, v in ((self._y, y), (self._r, r)):
            arr[mask] = np.roll(arr[mask], -1, axis=2)
            arr[mask, :, -1] = v[mask]

    def push_action(self, u: ArrayLike) -> None:
        """Append the applied inputs ``u(k)`` (one row per lane, in plant units).

        Parameters
        ----------
        u : array_like, shape (batch,) or (batch, n_inputs)
            The inputs actually applied (after clipping).
        """
        self._u[:] = np.roll(self._u, -1, axis=2)
        self._u[:, :, -1] = np.asarray(u, dtype=float).reshape(self.batch, self.n_inputs)

    def features(self) -> NDArray:
        """``(batch, n_features)`` float32 network input (see the module docstring)."""
        c, b = self.config, self.batch
        parts = [self._y / c.y_scale, self._r / c.y_scale, self._u / self.action_bound]
        if c.include_error:
            parts.append((self._r - self._y) / c.y_scale)
        feats = np.concatenate([part.reshape(b, -1) for part in parts], axis=1)
        return np.clip(np.nan_to_num(feats), -c.obs_clip, c.obs_clip).astype(np.float32)


class HistoryWindow(gym.Wrapper):
    """Window observation and ``[-1, 1]`` action space on a stcgym environment.

    ``info["u"]`` carries the applied input in plant units (a float for one input, else an
    array). Works under ``gym.make_vec`` and SB3's ``make_vec_env`` (pass it as
    ``wrapper_class``).

    Parameters
    ----------
    env
        An environment observing ``[y(k), r(k)]`` with an ``(m,)`` action box: every canonical
        stcgym environment (one output, one input), or ``stcgym/StateSpace-v0`` (``p`` outputs
        and references, ``m`` inputs, one bound for every input).
    config
        :class:`WindowConfig` (or a dict of its fields); default ``WindowConfig()``.

    Raises
    ------
    ValueError
        An action space that is not a 1-D box with one bound, an observation that is not
        ``[y, r]`` (an even length), or a ``config`` dict with a field out of range.

    Examples
    --------
    >>> import gymnasium as gym
    >>> import numpy as np
    >>> import stcgym.envs
    >>> from stcgym.agents import HistoryWindow
    >>> env = HistoryWindow(gym.make("stcgym/ObserverCanonical-v0", plant="unstable2"),
    ...                     {"window": 3})
    >>> env.observation_space, env.action_space
    (Box(-10.0, 10.0, (12,), float32), Box(-1.0, 1.0, (1,), float32))
    >>> obs, info = env.reset(seed=0)
    >>> obs, reward, terminated, truncated, info = env.step(np.array([0.1]))
    >>> info["u"]  # 0.1 of the action bound 10
    1.0
    >>> obs.reshape(4, 3)  # rows y, r, u / 10, r - y
    array([[0. , 0. , 0.5],
           [0. , 1. , 1. ],
           [0. , 0. , 0.1],
           [0. , 1. , 0.5]], dtype=float32)
    """

    def __init__(self, env: gym.Env, config: WindowConfig | dict | None = None) -> None:
        super().__init__(env)
        if config is None:
            config = WindowConfig()
        elif isinstance(config, dict):
            config = WindowConfig(**config)
        self.config = config
        box = env.action_space
        if (
            not isinstance(box, spaces.Box)
            or len(box.shape) != 1
            or not np.all(box.high == box.high[0])
        ):
            raise ValueError(f"HistoryWindow needs a 1-D action box with one bound, got {box}")
        shape = env.observation_space.shape
        if len(shape) != 1 or shape[0] < 2 or shape[0] % 2:
            raise ValueError(f"HistoryWindow needs the observation [y, r], got shape {shape}")
        self.n_outputs, self.n_inputs = shape[0] // 2, box.shape[0]
        self.action_bound = float(box.high[0])
        self._buf = HistoryBuffer(config, self.action_bound, 1, self.n_outputs, self.n_inputs)
        n_features = config.features_for(self.n_outputs, self.n_inputs)
        self.observation_space = spaces.Box(
            -config.obs_clip, config.obs_clip, shape=(n_features,), dtype=np.float32
        )
        self.action_space = spaces.Box(-1.0, 1.0, shape=(self.n_inputs,), dtype=np.float32)

    def reset(self, **kwargs: Any) -> tuple[NDArray, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self._buf.start(obs)
        return self._buf.features()[0], info

    def step(self, action: ArrayLike) -> tuple[NDArray, float, bool, bool, dict[str, Any]]:
        a = np.clip(np.asarray(action, dtype=float).reshape(-1)[: self.n_inputs], -1.0, 1.0)
        u = a * self.action_bound
        obs, reward, terminated, truncated, info = self.env.step(u)
        self._buf.push_action(u)
        self._buf.push_obs(obs)
        info["u"] = float(u[0]) if self.n_inputs == 1 else u
        return self._buf.features()[0], reward, terminated, truncated, info


class TrainingReward(gym.Wrapper):
    """The reward an RL agent is trained on (training only; evaluation uses the raw reward).

    Two changes to the environment's reward ``-cost``, both needed for learning to work at all:

    * the per-step cost is compressed, ``c -> s log(1 + c / s)`` with ``s = cost_squash``: a
      saturated input on a high-gain plant costs thousands per step while a good controller
      costs ~0.1, and value functions fitted over that range learn nothing about the small
      costs. The map is the identity for ``c << s`` (good policies are ranked as before) and
      logarithmic above, so it keeps a slope where plain clipping would leave a saturated
      deterministic actor (TD3) without any gradient;
    * a diverged episode is charged for the steps it did not live: the reward is a negative cost
      per step, so an episode that ends early would collect *less* cost than a well-controlled
      one and an agent would learn to blow the loop up. On divergence (``terminated`` with
      ``info["diverged"]``) the terminal step's (compressed) cost is charged once more for every
      step left until ``horizon``, the convention the evaluation harness uses to score failed
      runs.

    ``reward_scale`` then multiplies every reward. ``cost_squash=None`` leaves the cost as is.

    Parameters
    ----------
    env : gymnasium.Env
        An stcgym environment (reward ``-cost``, ``info["diverged"]`` on divergence).
    horizon : int
        Episode length the divergence charge runs to, ``>= 1``.
    reward_scale : float, default 1.0
        Factor on every reward.
    cost_squash : float or None, default 1.0
        ``s > 0`` of the compression, or ``None``.

    Raises
    ------
    ValueError
        ``horizon`` not a positive integer or ``cost_squash`` not positive.

    Examples
    --------
    The first step of ``unstable2`` costs 0.26 (see its env's example); trained on
    ``-log(1 + 0.26)``:

    >>> import gymnasium as gym
    >>> import numpy as np
    >>> import stcgym.envs
    >>> from stcgym.agents import TrainingReward
    >>> env = TrainingReward(gym.make("stcgym/ObserverCanonical-v0", plant="unstable2"),
    ...                      horizon=100)
    >>> _ = env.reset(seed=0)
    >>> obs, reward, terminated, truncated, info = env.step(np.array([1.0]))
    >>> round(reward, 6), round(-float(np.log1p(0.26)), 6)
    (-0.231112, -0.231112)
    """

    def __init__(
        self,
        env: gym.Env,
        horizon: int,
        reward_scale: float = 1.0,
        cost_squash: float | None = 1.0,
    ) -> None:
        super().__init__(env)
        if int(horizon) != horizon or horizon < 1:
            raise ValueError(f"horizon must be a positive integer, got {horizon!r}")
        if cost_squash is not None and not cost_squash > 0:
            raise ValueError(f"cost_squash must be positive or None, got {cost_squash!r}")
        self.horizon, self.reward_scale = int(horizon), float(reward_scale)
        self.cost_squash = cost_squash
        self._k = 0

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        self._k = 0
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._k += 1
        if self.cost_squash is not None:
            s = self.cost_squash
            reward = -s * float(np.log1p(max(-float(reward), 0.0) / s))
        if terminated and info.get("diverged", False):
            reward = reward * (1 + max(self.horizon - self._k, 0))
        return obs, float(reward) * self.reward_scale, terminated, truncated, info
