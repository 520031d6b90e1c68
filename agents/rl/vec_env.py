"""Stable-Baselines3 ``VecEnv`` adapter of the native vector envs (:mod:`stcgym.envs.vector`),
and the RL agents' observation window, interface and training reward over all its lanes at
once."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode
from numpy.typing import ArrayLike, NDArray
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

from stcgym.agents.rl.interfaces import InterfaceSpec
from stcgym.agents.rl.wrappers import WindowConfig, training_reward
from stcgym.envs.vector import LinearPlantVectorEnv

__all__ = ["SB3VecEnv", "VecHistoryWindow"]


class SB3VecEnv(VecEnv):
    """A native vector env as a Stable-Baselines3 ``VecEnv``.

    The native env is switched to ``SAME_STEP`` autoreset, which is SB3's convention: a finished
    lane is reset within the step, with its last observation in ``info["terminal_observation"]``
    and ``info["TimeLimit.truncated"]`` set on time-outs. Seeds given to ``seed()`` and options
    given to ``set_options()`` apply at the next ``reset()``, as in SB3. ``full_info=True``
    also copies every info key into the per-lane dicts (slow for many lanes). Rewards are
    float32, like SB3's ``DummyVecEnv``.
    """

    def __init__(self, venv: LinearPlantVectorEnv, *, full_info: bool = False) -> None:
        venv = venv.unwrapped if hasattr(venv, "unwrapped") else venv
        if not isinstance(venv, LinearPlantVectorEnv):
            raise TypeError(f"expected a stcgym vector env, got {type(venv).__name__}")
        venv.autoreset_mode = AutoresetMode.SAME_STEP
        venv.metadata = {**venv.metadata, "autoreset_mode": AutoresetMode.SAME_STEP}
        self.venv, self.full_info = venv, full_info
        self._actions: NDArray | None = None
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)

    def reset(self) -> NDArray:
        seeds = None if all(s is None for s in self._seeds) else self._seeds
        options = self._options[0] if self._options and self._options[0] else None
        if any(o != self._options[0] for o in self._options):
            raise ValueError("per-lane options differ; give them as per-lane arrays instead")
        obs, infos = self.venv.reset(seed=seeds, options=options)
        self.reset_infos = self._lane_infos(infos)
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: NDArray) -> None:
        self._actions = np.asarray(actions, dtype=float).reshape(self.num_envs, -1)

    def step_wait(self) -> tuple[NDArray, NDArray, NDArray, list[dict[str, Any]]]:
        obs, rewards, terminated, truncated, infos = self.venv.step(self._actions)
        dones = terminated | truncated
        lane_infos = self._lane_infos(infos)
        for i in np.flatnonzero(dones):
            lane_infos[i]["terminal_observation"] = infos["final_obs"][i]
            lane_infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
        return obs, rewards.astype(np.float32), dones, lane_infos

    def _lane_infos(self, infos: dict[str, Any]) -> list[dict[str, Any]]:
        if not self.full_info:
            return [{} for _ in range(self.num_envs)]
        keys = [k for k in infos if not k.startswith("_") and k not in ("final_obs", "final_info")]
        return [{k: infos[k][i] for k in keys} for i in range(self.num_envs)]

    def close(self) -> None:
        self.venv.close()

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        return [getattr(self.venv, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        setattr(self.venv, attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: Any = None, **method_kwargs: Any
    ) -> list[Any]:
        fn = getattr(self.venv, method_name)
        return [fn(*method_args, **method_kwargs) for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]


class VecHistoryWindow(VecEnvWrapper):
    """:class:`~stcgym.agents.rl.wrappers.HistoryWindow` and the training reward of
    :class:`~stcgym.agents.rl.wrappers.TrainingReward` for a whole SB3 ``VecEnv`` of stcgym
    lanes (e.g. :class:`SB3VecEnv` of a native vector env), in numpy over all lanes at once.

    Observations are the window features of :class:`~stcgym.agents.rl.wrappers.HistoryBuffer`
    (one buffer of ``num_envs`` lanes), actions the interface's box (``[-1, 1]``, or ``[-L,
    L]`` in units of its action unit) rescaled to ``[-action_bound, action_bound]``, rewards
    :func:`~stcgym.agents.rl.wrappers.training_reward` (the scored cost by default, a
    divergence charged for the steps not lived). A lane that ends is restarted by the
    wrapped env within the step (SB3's convention): its window starts afresh at the new
    episode's first observation, and
    ``infos[i]["terminal_observation"]`` holds the features of its last one. A lane ends by
    divergence when it is done and not truncated by the time limit (stcgym envs terminate on
    nothing else).

    Parameters
    ----------
    venv : stable_baselines3.common.vec_env.VecEnv
        Lanes observing ``[y, r]`` (``2 p`` values) with an ``(m,)`` action box; the action
        bound is its largest magnitude (an asymmetric box, e.g. pumps within their voltage
        range, is clipped to by the env).
    config : WindowConfig
        The window's settings.
    horizon : int
        Episode length the divergence charge runs to.
    reward_scale, cost_squash
        As :class:`~stcgym.agents.rl.wrappers.TrainingReward`.
    interface : InterfaceSpec, optional
        What the agent observes besides the window and how its action becomes the input
        (:mod:`stcgym.agents.rl.interfaces`: an estimator's estimate, a self-tuning
        controller's input corrected by the action); default the window alone.
    plant_costs : array_like, optional
        LQG's cost per step of each plant of the training distribution
        (:func:`~stcgym.agents.rl.reward.plant_lqg_costs`): the reward is then the score per
        step, the cost in units of the lane's plant's (read from ``plant_index`` when the
        step is asked for, so a lane restarted within the step is charged its old plant's).
    plant_index : callable, optional
        Returns each lane's plant, an index into ``plant_costs`` (the native vector env's
        ``plant_index``); required with ``plant_costs``.
    cost_cap : float, optional
        The largest per-step cost after the division (:func:`~stcgym.agents.rl.wrappers.
        training_reward`).
    true_params : callable, optional
        Returns each lane's true parameters ``(num_envs, 2 n)`` (the native vector env's
        ``params``): told to the ``"true"`` interface after every step (a lane restarted
        within the step keeps its old plant's in its terminal features).

    Examples
    --------
    Four lanes of ``unstable2``; lane ``i`` sees what :class:`~stcgym.agents.HistoryWindow`
    on the single env reset with seed ``i`` sees:

    >>> import gymnasium as gym
    >>> import numpy as np
    >>> import stcgym.envs
    >>> from stcgym.agents import HistoryWindow, WindowConfig
    >>> from stcgym.agents.rl.vec_env import SB3VecEnv, VecHistoryWindow
    >>> config = WindowConfig(window=3)
    >>> lanes = gym.make_vec("stcgym/ObserverCanonical-v0", num_envs=4, plant="unstable2",
    ...                      noise_std=0.1)
    >>> venv = VecHistoryWindow(SB3VecEnv(lanes), config, horizon=100)
    >>> venv.seed(0)
    [0, 1, 2, 3]
    >>> obs = venv.reset()
    >>> venv.step_async(np.full((4, 1), 0.1))
    >>> obs, rewards, dones, infos = venv.step_wait()
    >>> single = HistoryWindow(gym.make("stcgym/ObserverCanonical-v0", plant="unstable2",
    ...                                 noise_std=0.1), config)
    >>> _ = single.reset(seed=2)
    >>> obs_2, reward_2, *_ = single.step(np.array([0.1]))
    >>> bool(np.array_equal(obs[2], obs_2)), bool(np.isclose(rewards[2], reward_2))
    (True, True)
    """

    def __init__(
        self,
        venv: VecEnv,
        config: WindowConfig,
        horizon: int,
        reward_scale: float = 1.0,
        cost_squash: float | None = None,
        *,
        interface: InterfaceSpec | None = None,
        plant_costs: ArrayLike | None = None,
        plant_index: Callable[[], NDArray] | None = None,
        cost_cap: float | None = None,
        true_params: Callable[[], NDArray] | None = None,
    ) -> None:
        box = venv.action_space
        if not isinstance(box, spaces.Box) or len(box.shape) != 1:
            raise ValueError(f"VecHistoryWindow needs a 1-D action box, got {box}")
        bound = float(np.max(np.maximum(np.abs(box.low), np.abs(box.high))))
        shape = venv.observation_space.shape
        if len(shape) != 1 or shape[0] < 2 or shape[0] % 2:
            raise ValueError(f"VecHistoryWindow needs the observation [y, r], got shape {shape}")
        if int(horizon) != horizon or horizon < 1:
            raise ValueError(f"horizon must be a positive integer, got {horizon!r}")
        if (plant_costs is None) != (plant_index is None):
            raise ValueError("plant_costs and plant_index go together")
        if cost_cap is not None and not cost_cap > 0:
            raise ValueError(f"cost_cap must be positive or None, got {cost_cap!r}")
        p, m = shape[0] // 2, box.shape[0]
        self.plant_costs = None if plant_costs is None else np.asarray(plant_costs, dtype=float)
        self.plant_index, self.cost_cap = plant_index, cost_cap
        self.true_params = true_params
        self._lqg: NDArray | None = None
        self.config, self.action_bound = config, bound
        self.horizon, self.reward_scale, self.cost_squash = int(horizon), reward_scale, cost_squash
        self.interface = InterfaceSpec() if interface is None else interface
        self._lanes = self.interface.build(config, self.action_bound, venv.num_envs, (p, m))
        self._k = np.zeros(venv.num_envs, dtype=np.int64)
        self._u = np.zeros((venv.num_envs, m))
        n_features = self._lanes.n_features
        observation_space = spaces.Box(
            -config.obs_clip, config.obs_clip, shape=(n_features,), dtype=np.float32
        )
        limit = self._lanes.action_limit  # 1 unless the interface has an action unit
        action_space = spaces.Box(-limit, limit, shape=(m,), dtype=np.float32)
        super().__init__(venv, observation_space, action_space)

    def _tell_params(self) -> None:
        if self.true_params is not None:
            theta = np.asarray(self.true_params()).reshape(self.num_envs, -1)
            n = theta.shape[1] // 2
            self._lanes.set_model(theta[:, :n], theta[:, n:])

    def reset(self) -> NDArray:
        obs = self.venv.reset()
        self._tell_params()
        self._lanes.observe(obs, np.ones(self.num_envs, dtype=bool))
        self._k[:] = 0
        return self._lanes.features()

    def step_async(self, actions: NDArray) -> None:
        if self.plant_costs is not None:
            self._lqg = self.plant_costs[np.asarray(self.plant_index())]
        self._u = self._lanes.to_input(actions)
        self.venv.step_async(self._u)

    def step_wait(self) -> tuple[NDArray, NDArray, NDArray, list[dict[str, Any]]]:
        obs, rewards, dones, infos = self.venv.step_wait()
        self._k += 1
        done = np.asarray(dones, dtype=bool)
        diverged = np.array(
            [
                d and not info.get("TimeLimit.truncated", False)
                for d, info in zip(done, infos, strict=True)
            ]
        )
        r = training_reward(
            rewards, self._k, diverged, self.horizon, self.reward_scale, self.cost_squash,
            lqg_cost=self._lqg, cost_cap=self.cost_cap,
        )  # fmt: skip
        if done.any():
            last = np.array(obs, dtype=float)
            for i in np.flatnonzero(done):
                last[i] = infos[i]["terminal_observation"]
            final = self._lanes.terminal_features(last, done)
            for i in np.flatnonzero(done):
                infos[i]["terminal_observation"] = final[i]
            self._k[done] = 0
        self._tell_params()
        self._lanes.observe(obs, done)
        return self._lanes.features(), r.astype(np.float32), dones, infos
