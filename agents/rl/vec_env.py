"""Stable-Baselines3 ``VecEnv`` adapter of the native vector envs (:mod:`stcgym.envs.vector`)."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode
from numpy.typing import NDArray
from stable_baselines3.common.vec_env import VecEnv

from stcgym.envs.vector import LinearPlantVectorEnv

__all__ = ["SB3VecEnv"]


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
