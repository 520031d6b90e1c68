"""The RL agents' observation: a window of past outputs, references and inputs, and the
integral of the tracking error.

The plant state is not observed (unless it is the output, as on the measured-state MIMO
plants); an RL agent sees what the self-tuning controller sees, the input/output history.
:class:`HistoryWindow` turns the raw ``[y(k), r(k)]`` observation of a SISO stcgym environment
into a flat ``float32`` vector of the last ``W`` samples::

    [ y(k-W+1) .. y(k) | r(k-W+1) .. r(k) | u(k-W) .. u(k-1) | e(k-W+1) .. e(k) | z(k) ]
       / y_scale          / y_scale           / action_bound     / y_scale          integral

with ``e = r - y`` (optional) and the integral of the tracking error (optional, on by default)

    z(k) = clip(z(k-1) + integral_gain e(k) / y_scale, -obs_clip, obs_clip),   z(-1) = 0,

the structural prior that the self-tuning controller's integral action has: with it a policy
can remove a steady-state offset on a plant whose gain it does not know. The clip is its
anti-windup. With ``p`` outputs and ``m`` inputs (``stcgym/StateSpace-v0``, whose
measured-state output is the state ``x``) each block holds the window of every channel in turn
(``y_1`` window, ..., ``y_p`` window) and ``z`` has one entry per output, so the SISO vector is
the case ``p = m = 1``. Samples before the start of the episode are zero (the environment's own
convention: every signal is zero before the first step). Values are clipped to
``[-obs_clip, obs_clip]`` so that a run-away output cannot blow up the network's inputs.

The action space is normalised to ``[-1, 1]`` and rescaled to the environment's
``[-action_bound, action_bound]`` (the Stable-Baselines3 tip for continuous actions: Gaussian and
squashed policies work best on a unit box). Where the bound is much larger than the inputs a
plant needs, the bench's Gaussian-policy agents act in units of a typical input instead
(:mod:`stcgym.agents.rl.interfaces`, "The action unit").

The same feature construction is needed at evaluation time, when the harness hands every
controller the raw environment observation: :class:`HistoryBuffer` holds it and is shared by the
wrappers (training: :class:`HistoryWindow` here, :class:`~stcgym.agents.rl.vec_env.
VecHistoryWindow` on a native vector env) and :class:`stcgym.agents.rl.policy.SB3Policy`
(evaluation), so the two cannot drift apart.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "WindowConfig",
    "HistoryBuffer",
    "HistoryWindow",
    "TrainingReward",
    "training_reward",
]


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
    include_integral
        Append the integral of the tracking error ``z`` (module docstring), one value per
        output.
    integral_gain
        The integral's gain per step: a tracking error of ``y_scale`` held for
        ``1 / integral_gain`` steps moves ``z`` by 1.
    y_scale
        Outputs, references and errors are divided by it (the reference amplitude is a good
        choice).
    obs_clip
        Every feature is clipped to ``[-obs_clip, obs_clip]`` after scaling.

    Raises
    ------
    ValueError
        On construction: ``window`` not an integer ``>= 1``, ``y_scale``, ``obs_clip`` or
        ``integral_gain`` not a finite positive number.

    Examples
    --------
    >>> from stcgym.agents import WindowConfig
    >>> WindowConfig(window=3).n_features  # y, r, u and e = r - y, and the integral z
    13
    >>> WindowConfig(window=3, include_error=False, include_integral=False).n_features
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
    include_integral: bool = True
    integral_gain: float = 0.05

    def __post_init__(self) -> None:
        if int(self.window) != self.window or self.window < 1:
            raise ValueError(f"window must be an integer >= 1, got {self.window!r}")
        for name in ("y_scale", "obs_clip", "integral_gain"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")

    @property
    def n_features(self) -> int:
        """Length of the SISO observation: ``window`` rows of y, r, u (and r - y)."""
        return self.features_for(1, 1)

    def features_for(self, n_outputs: int, n_inputs: int) -> int:
        """Length of the observation with ``n_outputs`` outputs and ``n_inputs`` inputs."""
        per_output = 3 if self.include_error else 2
        integral = int(n_outputs) if self.include_integral else 0
        return self.window * (per_output * int(n_outputs) + int(n_inputs)) + integral

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
    ``y(1) = 0.8`` and ``r = 1``; the integral is ``0.1 (1 - 0.5) + 0.1 (1 - 0.8)``:

    >>> from stcgym.agents import HistoryBuffer, WindowConfig
    >>> config = WindowConfig(window=2, include_error=False, integral_gain=0.1)
    >>> buf = HistoryBuffer(config, action_bound=10.0)
    >>> buf.start([0.5, 1.0])
    >>> buf.push_action([2.0])
    >>> buf.push_obs([0.8, 1.0])
    >>> buf.features()  # [y(0), y(1) | r(0), r(1) | u(-1), u(0) / 10 | z(1)]
    array([[0.5 , 0.8 , 1.  , 1.  , 0.  , 0.2 , 0.07]], dtype=float32)
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
        self._z = np.zeros((batch, p))

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
        for arr in (self._y, self._r, self._u, self._z):
            arr[mask] = 0.0
        self._y[mask, :, -1], self._r[mask, :, -1] = y[mask], r[mask]
        self._integrate(mask)

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
        self._integrate(mask)

    def _integrate(self, mask: NDArray) -> None:
        """``z(k) = clip(z(k-1) + integral_gain e(k) / y_scale, -obs_clip, obs_clip)``."""
        c = self.config
        e = np.nan_to_num(self._r[mask, :, -1] - self._y[mask, :, -1]) / c.y_scale
        self._z[mask] = np.clip(self._z[mask] + c.integral_gain * e, -c.obs_clip, c.obs_clip)

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
        if c.include_integral:
            parts.append(self._z)
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
        and references, ``m`` inputs; actions are scaled by the box's largest magnitude and
        the env clips them to its range).
    config
        :class:`WindowConfig` (or a dict of its fields); default ``WindowConfig()``.

    Raises
    ------
    ValueError
        An action space that is not a 1-D box, an observation that is not
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
    (Box(-10.0, 10.0, (13,), float32), Box(-1.0, 1.0, (1,), float32))
    >>> obs, info = env.reset(seed=0)
    >>> obs, reward, terminated, truncated, info = env.step(np.array([0.1]))
    >>> info["u"]  # 0.1 of the action bound 10
    1.0
    >>> obs[:12].reshape(4, 3)  # rows y, r, u / 10, r - y
    array([[0. , 0. , 0.5],
           [0. , 1. , 1. ],
           [0. , 0. , 0.1],
           [0. , 1. , 0.5]], dtype=float32)
    >>> round(float(obs[12]), 6)  # the integral z(1) = 0.05 (1 - 0) + 0.05 (1 - 0.5)
    0.075
    """

    def __init__(self, env: gym.Env, config: WindowConfig | dict | None = None) -> None:
        super().__init__(env)
        if config is None:
            config = WindowConfig()
        elif isinstance(config, dict):
            config = WindowConfig(**config)
        self.config = config
        box = env.action_space
        if not isinstance(box, spaces.Box) or len(box.shape) != 1:
            raise ValueError(f"HistoryWindow needs a 1-D action box, got {box}")
        shape = env.observation_space.shape
        if len(shape) != 1 or shape[0] < 2 or shape[0] % 2:
            raise ValueError(f"HistoryWindow needs the observation [y, r], got shape {shape}")
        self.n_outputs, self.n_inputs = shape[0] // 2, box.shape[0]
        # the largest magnitude: an asymmetric box (pumps within their range) is the env's clip
        self.action_bound = float(np.max(np.maximum(np.abs(box.low), np.abs(box.high))))
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
    """The reward an RL agent is trained on: the scored cost, with divergence charged.

    Given ``plant_costs`` (each plant's LQG cost per step, :func:`~stcgym.agents.rl.reward.
    plant_lqg_costs`), the reward is the score per step, ``-min(cost / c_LQG(plant),
    cost_cap)``, on the plant each reset draws (``info["plant"]``): the bench's default
    (:mod:`stcgym.agents.rl.reward`). Without, it is the environment's own ``-cost``. In both,
    a diverged episode is charged for the steps it did not live: the reward is a negative cost
    per step, so an episode that ends early would collect *less* cost than a well-controlled
    one and an agent would learn to blow the loop up. On divergence (``terminated`` with
    ``info["diverged"]``) the terminal step's reward is charged once more for every step left
    until ``horizon``, the convention the evaluation scores failed runs by
    (:func:`stcgym.adaptive.control.rollout.charge_divergence`), at most ``cost_cap`` per step.

    ``reward_scale`` then multiplies every reward (a constant rescaling; a running one is
    SB3's ``VecNormalize``). ``cost_squash=s`` optionally compresses the per-step cost,
    ``c -> s log(1 + c / s)``, before the charge: an ablation, off by default, since it trains
    on another objective than the score (it favours policies with rare large transients).

    Parameters
    ----------
    env : gymnasium.Env
        An stcgym environment (reward ``-cost``, ``info["diverged"]`` on divergence; the
        plant's name in ``info["plant"]`` or ``env.unwrapped.plant.name``).
    horizon : int
        Episode length the divergence charge runs to, ``>= 1``.
    reward_scale : float, default 1.0
        Factor on every reward.
    cost_squash : float or None, default None
        ``s > 0`` of the compression, or ``None`` (the scored cost).
    plant_costs : mapping of str to float, optional
        LQG's cost per step by plant name: the reward is then in units of it.
    cost_cap : float, optional
        The largest per-step cost after the division (``None``: no cap).

    Raises
    ------
    ValueError
        ``horizon`` not a positive integer, ``cost_squash`` or ``cost_cap`` not positive; on
        reset, a plant that ``plant_costs`` does not hold.

    Examples
    --------
    The first step of ``unstable2`` costs 0.26 (see its env's example), and that is the
    reward; with the compression it would be ``-log(1 + 0.26)``; in units of an LQG cost of
    0.13 per step, -2:

    >>> import gymnasium as gym
    >>> import numpy as np
    >>> import stcgym.envs
    >>> from stcgym.agents import TrainingReward
    >>> env = TrainingReward(gym.make("stcgym/ObserverCanonical-v0", plant="unstable2"),
    ...                      horizon=100)
    >>> _ = env.reset(seed=0)
    >>> round(env.step(np.array([1.0]))[1], 6)
    -0.26
    >>> squashed = TrainingReward(gym.make("stcgym/ObserverCanonical-v0", plant="unstable2"),
    ...                           horizon=100, cost_squash=1.0)
    >>> _ = squashed.reset(seed=0)
    >>> round(squashed.step(np.array([1.0]))[1], 6), round(-float(np.log1p(0.26)), 6)
    (-0.231112, -0.231112)
    >>> ratio = TrainingReward(gym.make("stcgym/ObserverCanonical-v0", plant="unstable2"),
    ...                        horizon=100, plant_costs={"unstable2": 0.13}, cost_cap=100.0)
    >>> _ = ratio.reset(seed=0)
    >>> round(ratio.step(np.array([1.0]))[1], 6)
    -2.0
    """

    def __init__(
        self,
        env: gym.Env,
        horizon: int,
        reward_scale: float = 1.0,
        cost_squash: float | None = None,
        *,
        plant_costs: dict[str, float] | None = None,
        cost_cap: float | None = None,
    ) -> None:
        super().__init__(env)
        if int(horizon) != horizon or horizon < 1:
            raise ValueError(f"horizon must be a positive integer, got {horizon!r}")
        if cost_squash is not None and not cost_squash > 0:
            raise ValueError(f"cost_squash must be positive or None, got {cost_squash!r}")
        if cost_cap is not None and not cost_cap > 0:
            raise ValueError(f"cost_cap must be positive or None, got {cost_cap!r}")
        self.horizon, self.reward_scale = int(horizon), float(reward_scale)
        self.cost_squash, self.cost_cap = cost_squash, cost_cap
        self.plant_costs = None if plant_costs is None else dict(plant_costs)
        self._k = 0
        self._lqg: float | None = None

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self._k = 0
        if self.plant_costs is not None:
            plant = getattr(self.env.unwrapped, "plant", None)
            name = info.get("plant") or getattr(plant, "name", None)
            if name not in self.plant_costs:
                raise ValueError(f"plant_costs holds no LQG cost of the plant {name!r}")
            self._lqg = float(self.plant_costs[name])
        return obs, info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._k += 1
        diverged = bool(terminated and info.get("diverged", False))
        r = training_reward(
            reward, self._k, diverged, self.horizon, self.reward_scale, self.cost_squash,
            lqg_cost=self._lqg, cost_cap=self.cost_cap,
        )  # fmt: skip
        return obs, float(r), terminated, truncated, info


def training_reward(
    reward: ArrayLike,
    steps: ArrayLike,
    diverged: ArrayLike,
    horizon: int,
    reward_scale: float = 1.0,
    cost_squash: float | None = None,
    *,
    lqg_cost: ArrayLike | None = None,
    cost_cap: float | None = None,
) -> NDArray:
    """The training reward of :class:`TrainingReward` for one step of one or many lanes.

    Parameters
    ----------
    reward : array_like
        The environments' rewards ``-cost``.
    steps : array_like of int
        Steps lived in the episode, this one included.
    diverged : array_like of bool
        Lanes whose episode ended in a divergence at this step.
    horizon, reward_scale, cost_squash
        As :class:`TrainingReward`.
    lqg_cost : array_like, optional
        Each lane's plant's LQG cost per step: the cost is divided by it (the score per step,
        :mod:`stcgym.agents.rl.reward`).
    cost_cap : float, optional
        The largest per-step cost (after the division), charged at most per step not lived.

    Returns
    -------
    ndarray
        ``reward_scale * r`` with ``r = -min(cost / lqg_cost, cost_cap)`` (optionally
        compressed), times ``1 + horizon - steps`` on the diverged lanes.

    Examples
    --------
    A cost of 0.5 on a plant whose LQG cost is 0.1 is 5x LQG; a divergence at step 998 of
    1000 with a cost of 900x LQG is charged the cap for this step and the two not lived:

    >>> from stcgym.agents.rl.wrappers import training_reward
    >>> training_reward([-0.5, -90.0], [10, 998], [False, True], 1000,
    ...                 lqg_cost=[0.1, 0.1], cost_cap=100.0)
    array([  -5., -300.])
    """
    r = np.asarray(reward, dtype=float)
    if lqg_cost is not None:
        r = r / np.asarray(lqg_cost, dtype=float)
    if cost_cap is not None:
        r = np.maximum(r, -float(cost_cap))
    if cost_squash is not None:
        r = -cost_squash * np.log1p(np.maximum(-r, 0.0) / cost_squash)
    left = np.maximum(horizon - np.asarray(steps), 0)
    r = np.where(np.asarray(diverged, dtype=bool), r * (1 + left), r)
    return r * reward_scale
