"""The base class of the native vector environments: ``B`` lanes of one linear plant.

The lanes, resets, autoreset, stepping and infos that :mod:`stcgym.envs.vector`'s concrete
environments share (see that module for the equivalence with single environments); the
per-lane streams and argument checks are in :mod:`stcgym.envs.lanes`, the lanes' time-varying
schedules in :mod:`stcgym.envs.lane_schedules`.
"""

from __future__ import annotations

import copy
import dataclasses
import warnings
from collections.abc import Hashable, Sequence
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from numpy.typing import ArrayLike, NDArray

from stcgym.envs import dynamics
from stcgym.envs.lane_schedules import LaneSchedules
from stcgym.envs.lanes import (
    NOISE_BUFFER_BYTES,
    STREAM_DRAW,
    STREAM_REF,
    STREAM_V,
    STREAM_W,
    LaneNormals,
    episode_streams,
    lane_actions,
    lane_seeds,
    per_lane,
    reset_mask,
    vector_arguments,
)
from stcgym.envs.plants import LinearPlantEnv
from stcgym.envs.signals import Schedule
from stcgym.lanes.validation import non_negative as _non_negative

__all__ = ["LinearPlantVectorEnv", "USER_SCHEDULE"]

USER_SCHEDULE = "user schedule"  #: key of the schedule given to the constructor


class LinearPlantVectorEnv(VectorEnv):
    """Base class: ``num_envs`` lanes of a :class:`~stcgym.envs.plants.LinearPlantEnv`.

    Public state (leading axis = lane): ``x``, ``t``, ``params``, ``y_clean``, ``n_clipped``;
    :attr:`memory_per_lane` in bytes.

    Parameters
    ----------
    num_envs
        Number of lanes ``B``.
    max_episode_steps
        Truncation after this many steps (``gym.make_vec`` passes the registered value).
    autoreset_mode
        ``"NextStep"`` (default: the step after a lane ends resets it and returns its first
        observation), ``"SameStep"`` (resets in the same step, with ``infos["final_obs"]``
        and ``infos["final_info"]``) or ``"Disabled"`` (resets left to the caller:
        ``reset(options={"reset_mask": mask})``).
    noise_buffer_bytes
        Memory for each noise buffer (all lanes); sets how many draws per lane are refilled
        at once (16 to 512). Results do not depend on it.
    info_keys
        Keys of ``infos`` to return (default all of the single env's; ``()`` for none).
    **kwargs
        The single environment's arguments (``single_cls``); one prototype single env is built
        from them to validate them and to hold the shared configuration.

    Raises
    ------
    TypeError
        ``num_envs`` not an integer; a single-env argument of the wrong kind.
    ValueError
        ``num_envs < 1``; ``max_episode_steps`` not a positive integer; an unknown
        ``autoreset_mode``; a ``render_mode`` (vector envs do not render); ``noise_buffer_bytes``
        negative; any argument the single environment rejects.

    Examples
    --------
    Lane ``i`` of a vector env reset with ``seed=s`` is the single env reset with ``s + i``,
    bit for bit (here with output noise):

    >>> import gymnasium as gym
    >>> import numpy as np
    >>> import stcgym.envs
    >>> kwargs = dict(plant="unstable2", reference="zero", noise_std=0.1)
    >>> envs = gym.make_vec("stcgym/ObserverCanonical-v0", num_envs=3, **kwargs)
    >>> single = gym.make("stcgym/ObserverCanonical-v0", **kwargs)
    >>> obs, infos = envs.reset(seed=0)
    >>> obs_2, info_2 = single.reset(seed=2)
    >>> u = np.array([[1.0], [0.5], [-1.0]])
    >>> obs, rewards, terminated, truncated, infos = envs.step(u)
    >>> obs_2, reward_2, *_ = single.step(u[2])
    >>> bool(np.array_equal(obs[2], obs_2)), bool(rewards[2] == reward_2)
    (True, True)
    """

    single_cls: type[LinearPlantEnv] = LinearPlantEnv
    metadata: dict[str, Any] = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(
        self,
        num_envs: int = 1,
        *,
        max_episode_steps: int | None = None,
        autoreset_mode: str | AutoresetMode = AutoresetMode.NEXT_STEP,
        noise_buffer_bytes: int = NOISE_BUFFER_BYTES,
        info_keys: Sequence[str] | None = None,
        render_mode: str | None = None,
        **kwargs: Any,
    ) -> None:
        B, max_steps, mode = vector_arguments(
            num_envs, max_episode_steps, autoreset_mode, render_mode
        )
        noise_budget = int(_non_negative(noise_buffer_bytes, "noise_buffer_bytes"))
        self.num_envs = B
        self.max_episode_steps = max_steps
        self.autoreset_mode = mode
        self.metadata = {**type(self).metadata, "autoreset_mode": self.autoreset_mode}
        self.render_mode = None
        # None: every key of the single env's info; a subset saves the per-step copies.
        self.info_keys = None if info_keys is None else tuple(info_keys)

        proto = self._make_proto(kwargs)
        self._proto = proto
        self.n_states, self.n_inputs, self.n_outputs = n, m, p = (
            proto.n_states,
            proto.n_inputs,
            proto.n_outputs,
        )
        self.noise_std, self.process_noise_std = proto.noise_std, proto.process_noise_std
        self.control_cost, self.action_bound, self.y_bound = (
            proto.control_cost,
            proto.action_bound,
            proto.y_bound,
        )
        self.single_observation_space = proto.observation_space
        self.single_action_space = proto.action_space
        self.n_references = proto.n_references
        p_r = proto.observation_space.shape[0] - p  # the observed references' width
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(B, p + p_r), dtype=np.float64)
        self.action_space = spaces.Box(
            -self.action_bound, self.action_bound, shape=(B, m), dtype=np.float64
        )

        # Lane state.
        self.x = np.zeros((B, n))
        self.t = np.zeros(B, dtype=np.int64)
        self.y_clean = np.zeros((B, p))
        self.n_clipped = np.zeros(B, dtype=np.int64)
        self._u = np.zeros((B, m))
        self._y = np.zeros((B, p))
        self._reward = np.zeros(B)
        self._clipped = np.zeros(B, dtype=bool)
        self._diverged = np.zeros(B, dtype=bool)
        self._terminated = np.zeros(B, dtype=bool)
        self._truncated = np.zeros(B, dtype=bool)
        self._needs_reset = np.ones(B, dtype=bool)  # no episode yet
        self._from_options = np.zeros(B, dtype=bool)  # parameters given by reset(options)
        self._warned_revert = False
        self._lane_rng: list[np.random.Generator | None] = [None] * B
        self._v = LaneNormals(B, p, noise_budget) if self.noise_std else None
        self._w = LaneNormals(B, n, noise_budget) if self.process_noise_std else None
        self._no_noise = np.zeros((B, 0))
        self._no_noise_1d = np.zeros(B)
        # References: one object per output channel, holding every lane's state.
        self.reference = [copy.deepcopy(r) for r in proto.reference]
        for ref in self.reference:
            ref.allocate(B)
        self._random_refs = any(r.random for r in self.reference)
        # Time-varying schedules: objects holding their lanes' state (see _make_schedule).
        self._lane_schedules = LaneSchedules(B)
        self._started = False
        self._obs = np.zeros((B, p + p_r))
        self._init_params()

    # ------------------------------------------------------------------ subclass hooks
    def _make_proto(self, kwargs: dict[str, Any]) -> LinearPlantEnv:
        return self.single_cls(**kwargs)

    def _init_params(self) -> None:
        """Allocate ``self.params`` (leading axis = lane), set to the constructor's plant."""
        raise NotImplementedError

    def _parse_options(self, options: dict[str, Any]) -> Any:
        """Validate parameter options (per lane or for all lanes) without changing anything."""
        return None

    def _nominal(
        self, idx: NDArray, parsed: Any, draw: list[np.random.Generator | None]
    ) -> tuple[NDArray, list[Hashable | None]]:
        """Nominal parameters ``(len(idx), ...)`` and schedule keys (``None`` = constant)."""
        raise NotImplementedError

    def _make_schedule(self, key: Hashable) -> Schedule:
        """A fresh schedule object for ``key`` (see :meth:`_nominal`)."""
        if key == USER_SCHEDULE:
            return copy.deepcopy(self._proto.schedule)
        raise KeyError(key)

    def _needs_draw_rng(self, parsed: Any) -> bool:
        """Whether :meth:`_nominal` consumes the lanes' draw streams."""
        return False

    def _step_lanes(self, u_raw: NDArray, z_w: NDArray, z_v: NDArray, r: NDArray) -> None:
        """The batch loop of :mod:`stcgym.envs.dynamics` for this plant (all lanes)."""
        raise NotImplementedError

    def _reset_outputs(self, idx: NDArray) -> NDArray:
        """``C x(0)`` of lanes ``idx`` (before any input), shape ``(len(idx), p)``."""
        raise NotImplementedError

    def _param_infos(self, infos: dict[str, Any], mask: NDArray) -> None:
        raise NotImplementedError

    # ------------------------------------------------------------------ resets
    def _check_options(self, options: dict[str, Any]) -> tuple[Any, NDArray | None, float | None]:
        allowed = self._proto.reset_options
        unknown = sorted(set(options) - allowed)
        if unknown:
            raise ValueError(
                f"unknown reset option(s) {unknown} for {type(self).__name__}; expected keys "
                f"from {sorted(allowed | {'reset_mask'})}"
            )
        parsed = self._parse_options(options)
        x0 = std = None
        if "initial_state" in options:
            x0 = per_lane(
                options["initial_state"],
                self.num_envs,
                (self.n_states,),
                "options['initial_state']",
            )
        elif "initial_state_std" in options:
            std = _non_negative(options["initial_state_std"], "options['initial_state_std']")
        return parsed, x0, std

    def _reset_lanes(
        self,
        idx: NDArray,
        seeds: Sequence[int | None] | None,
        parsed: Any = None,
        x0: NDArray | None = None,
        std: float | None = None,
    ) -> None:
        """Start a new episode in lanes ``idx`` (exactly like ``LinearPlantEnv.reset``)."""
        k = len(idx)
        n = self.n_states
        proto = self._proto
        if x0 is None and std is None and proto.initial_state is None:
            std = proto.initial_state_std or None  # the constructor's, drawn as the option's
        entropy = []
        for j, i in enumerate(idx):
            seed = None if seeds is None else seeds[j]
            if seed is not None or self._lane_rng[i] is None:
                self._lane_rng[i], _ = seeding.np_random(seed)
            entropy.append(int(self._lane_rng[i].integers(2**63)))

        v0 = None
        if self._v is not None:
            v0 = self._v.restart(idx, [episode_streams(e, [STREAM_V])[0] for e in entropy], True)
        if self._w is not None:
            self._w.restart(idx, [episode_streams(e, [STREAM_W])[0] for e in entropy], False)
        if self._random_refs:
            children = [
                episode_streams(e, [STREAM_REF])[0].spawn(len(self.reference)) for e in entropy
            ]
            for c, ref in enumerate(self.reference):
                ref.reset_lanes(idx, [ch[c] for ch in children])

        draw: list[np.random.Generator | None] = [None] * k
        if std is not None or self._needs_draw_rng(parsed):
            draw = [episode_streams(e, [STREAM_DRAW])[0] for e in entropy]
        nominal, keys = self._nominal(idx, parsed, draw)

        # Schedules: params(0) and the first step at which they may change again.
        self.params[idx] = self._lane_schedules.start(
            idx, nominal, keys, entropy, self._make_schedule
        )

        if x0 is not None:
            self.x[idx] = x0[idx]
        elif std is not None:
            self.x[idx] = [std * g.standard_normal(n) for g in draw]
        elif self._proto.initial_state is not None:
            self.x[idx] = self._proto.initial_state
        else:
            self.x[idx] = 0.0

        self.t[idx] = 0
        self.n_clipped[idx] = 0
        self._clipped[idx] = False
        self._diverged[idx] = False
        self._terminated[idx] = False
        self._truncated[idx] = False
        self._needs_reset[idx] = False
        y_clean = self._reset_outputs(idx)
        self.y_clean[idx] = y_clean
        y = y_clean.copy()
        if v0 is not None:
            for j in range(k):
                dynamics.add_noise(y[j], self.noise_std, v0[j])
        self._obs[idx, : self.n_outputs] = y
        self._obs[idx, self.n_outputs :] = self._proto._observed_reference(
            self._references(self.t[idx], idx)
        )

    def reset(
        self,
        *,
        seed: int | Sequence[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[NDArray, dict[str, Any]]:
        """Reset all lanes, or those of ``options["reset_mask"]``; see :mod:`stcgym.envs.vector`.

        Parameters
        ----------
        seed : int, list of int or None, optional
            ``s``: lane ``i`` gets seed ``s + i``; a list: one seed (or ``None``) per lane;
            ``None``: each lane continues its generator.
        options : dict, optional
            The single environment's reset options (one value for every lane being reset, or
            a leading axis of length ``num_envs`` for parameter options), and
            ``"reset_mask"``: a bool array of shape ``(num_envs,)`` selecting the lanes to reset
            (not at the first reset).

        Returns
        -------
        observations : ndarray, shape (num_envs, 2 p)
        infos : dict
            Gymnasium vector infos (one array per key and a ``"_key"`` mask).

        Raises
        ------
        TypeError
            ``options`` not a dict; ``seed`` of the wrong kind.
        ValueError
            A list of seeds of the wrong length or with a negative entry; a bad
            ``reset_mask``; an option the single env rejects or of the wrong per-lane shape.
        """
        B = self.num_envs
        if options is not None and not isinstance(options, dict):
            raise TypeError(f"options must be a dict or None, got {options!r}")
        options = dict(options or {})
        seeds = lane_seeds(seed, B)
        mask = reset_mask(options.pop("reset_mask", None), B)
        idx = np.flatnonzero(mask)
        if not self._started and not mask.all():
            raise ValueError("the first reset must reset every lane (no reset_mask)")
        parsed, x0, std = self._check_options(options)
        if isinstance(seed, (int, np.integer)):
            super().reset(seed=int(seed))
        self._reset_lanes(idx, None if seeds is None else [seeds[i] for i in idx], parsed, x0, std)
        self._from_options[idx] = parsed is not None
        self._started = True
        return self._obs.copy(), self._infos(mask)

    def _autoreset(self, idx: NDArray) -> None:
        if not self._warned_revert and self._from_options[idx].any():
            warnings.warn(
                "autoreset: lanes whose parameters came from reset(options=...) start their next "
                "episode with the constructor's plant (as SyncVectorEnv does); give per-lane "
                "a/b to the constructor to keep them",
                UserWarning,
                stacklevel=3,
            )
            self._warned_revert = True
        self._from_options[idx] = False
        self._reset_lanes(idx, None)

    # ------------------------------------------------------------------ stepping
    def _references(self, k: NDArray, idx: NDArray | None = None) -> NDArray:
        """``r(k)`` of lanes ``idx`` (all lanes when ``None``), shape ``(len, p_r)``."""
        out = np.empty((len(k), self.n_references))
        for c, ref in enumerate(self.reference):
            out[:, c] = ref.values(k, idx)
        return out

    def step(self, actions: ArrayLike) -> tuple[NDArray, NDArray, NDArray, NDArray, dict[str, Any]]:
        """Advance every lane one step; see :mod:`stcgym.envs.vector` for autoreset and infos.

        Parameters
        ----------
        actions : array_like, shape (num_envs, m)
            One finite action per lane (shape ``(num_envs,)`` when ``m == 1``); the actions of
            lanes being autoreset are ignored.

        Returns
        -------
        observations : ndarray, shape (num_envs, 2 p)
        rewards, terminated, truncated : ndarray, shape (num_envs,)
        infos : dict
            Gymnasium vector infos; with ``autoreset_mode="SameStep"`` also ``"final_obs"``
            and ``"final_info"`` of the lanes that ended.

        Raises
        ------
        ValueError
            Actions of the wrong shape or not finite, before any lane changes.
        RuntimeError
            ``step`` before ``reset``; with ``autoreset_mode="Disabled"``, a step while an
            ended lane has not been reset.
        """
        mode = self.autoreset_mode
        if not self._started:
            raise RuntimeError("call reset() before step()")
        autoreset = self._needs_reset.copy()
        if mode is AutoresetMode.DISABLED and autoreset.any():
            raise RuntimeError(
                f"lanes {np.flatnonzero(autoreset)[:10]} ended; reset them with "
                "reset(options={'reset_mask': mask}) before stepping (autoreset_mode DISABLED)"
            )
        any_reset = bool(autoreset.any())
        u_raw = lane_actions(
            actions, self.num_envs, self.n_inputs, ~autoreset if any_reset else None
        )
        if any_reset:  # ignored actions of resetting lanes may be anything
            u_raw = np.where(autoreset[:, None], 0.0, u_raw)
        r = self._references(self.t + 1)  # a user reference may raise: before any change
        z_w = self._w.take() if self._w is not None else self._no_noise
        z_v = self._v.take() if self._v is not None else self._no_noise
        self._step_lanes(u_raw, z_w, z_v, r)
        self.n_clipped += self._clipped
        self.t += 1
        self._lane_schedules.advance(self.t, self.params)
        rewards = self._reward.copy()
        terminated = self._diverged.copy()
        if self.max_episode_steps is not None:
            truncated = self.t >= self.max_episode_steps
        else:
            truncated = np.zeros(self.num_envs, dtype=bool)
        obs = self._obs
        obs[:, : self.n_outputs] = self._y
        obs[:, self.n_outputs :] = self._proto._observed_reference(r)

        final: dict[str, Any] = {}
        if any_reset:  # NEXT_STEP: lanes that ended last step start over instead
            idx = np.flatnonzero(autoreset)
            self._autoreset(idx)
            rewards[idx] = 0.0
            terminated[idx] = False
            truncated[idx] = False
        done = terminated | truncated
        if mode is AutoresetMode.SAME_STEP and done.any():
            idx = np.flatnonzero(done)
            final_obs = np.full(self.num_envs, None, dtype=object)
            for i in idx:
                final_obs[i] = obs[i].copy()
            final["final_obs"], final["_final_obs"] = final_obs, done.copy()
            final["final_info"], final["_final_info"] = self._infos(done), done.copy()
            self._autoreset(idx)
            self._needs_reset[:] = False
        else:
            self._needs_reset = done
        self._terminated, self._truncated = terminated, truncated
        infos = self._infos(np.ones(self.num_envs, dtype=bool))
        infos.update(final)
        return obs.copy(), rewards, terminated, truncated, infos

    # ------------------------------------------------------------------ rollouts
    def lookahead(self, steps: int) -> dict[str, Any]:
        """What the next ``steps`` calls of :meth:`step` would use, without changing the env.

        For a compiled rollout of ``T = steps`` steps of every lane (no lane resetting in
        between). Returns a dict of arrays: ``"r"`` ``(B, T, p_r)`` with ``r[:, j] = r(t + 1 + j)``
        (the reference returned with the observation of step ``j``), ``"z_v"`` ``(B, T, p)``
        and ``"z_w"`` ``(B, T, n)`` the standard normals of the output and process noise (zeros
        when that noise is off), and ``"params"``: ``None`` for constant plants, else
        ``(B, T, *param_shape)`` with the parameters in force at step ``t + j``. Feeding these
        to the lane functions of :mod:`stcgym.envs.dynamics` reproduces the env bit for bit.

        Parameters
        ----------
        steps : int
            ``T >= 1``.

        Returns
        -------
        dict
            ``"r"``, ``"z_v"``, ``"z_w"``, ``"params"`` as above.

        Raises
        ------
        ValueError
            ``steps`` not a positive integer.
        RuntimeError
            Before the first ``reset``.

        Examples
        --------
        >>> import gymnasium as gym
        >>> import stcgym.envs
        >>> envs = gym.make_vec("stcgym/ObserverCanonical-v0", num_envs=3, noise_std=0.1)
        >>> _ = envs.reset(seed=0)
        >>> {key: None if v is None else v.shape for key, v in envs.lookahead(4).items()}
        {'r': (3, 4, 1), 'z_v': (3, 4, 1), 'z_w': (3, 4, 2), 'params': None}
        """
        if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
            raise ValueError(f"steps must be a positive integer, got {steps!r}")
        if not self._started:
            raise RuntimeError("call reset() before lookahead()")
        T, B, n, p = int(steps), self.num_envs, self.n_states, self.n_outputs
        refs = copy.deepcopy(self.reference)
        v, w = copy.deepcopy(self._v), copy.deepcopy(self._w)
        out: dict[str, Any] = {
            "r": np.empty((B, T, self.n_references)),
            "z_v": np.zeros((B, T, p)),
            "z_w": np.zeros((B, T, n)),
            "params": None,
        }
        for j in range(T):
            for c, ref in enumerate(refs):
                out["r"][:, j, c] = ref.values(self.t + j + 1)
            if v is not None:
                out["z_v"][:, j] = v.take()
            if w is not None:
                out["z_w"][:, j] = w.take()
        if self._lane_schedules.varying:
            out["params"] = self._lane_schedules.lookahead(self.t, self.params, T)
        return out

    # ------------------------------------------------------------------ infos
    def _infos(self, mask: NDArray) -> dict[str, Any]:
        keys = self.info_keys
        if keys is not None and not keys:
            return {}
        infos: dict[str, Any] = {
            "t": self.t.copy(),
            "x": self.x.copy(),
            "y_clean": self.y_clean.copy(),
        }
        self._param_infos(infos, mask)
        infos["clipped"] = self._clipped.copy()
        infos["n_clipped"] = self.n_clipped.copy()
        infos["diverged"] = self._diverged.copy()
        if keys is not None:
            infos = {k: v for k, v in infos.items() if k in keys}
        for key in list(infos):
            infos["_" + key] = mask.copy()
        return infos

    # ------------------------------------------------------------------ misc
    @property
    def memory_per_lane(self) -> float:
        """Bytes of lane state (arrays and noise buffers) per lane, Python objects excluded.

        Examples
        --------
        >>> import gymnasium as gym
        >>> import stcgym.envs
        >>> env_id = "stcgym/ObserverCanonical-v0"
        >>> envs = gym.make_vec(env_id, num_envs=1000, noise_std=0.1)
        >>> _ = envs.reset(seed=0)
        >>> envs.memory_per_lane < 10_000
        True
        """
        arrays = [
            self.x, self.t, self.y_clean, self.n_clipped, self._u, self._y, self._reward,
            self._clipped, self._diverged, self._terminated, self._truncated, self._needs_reset,
            self._from_options, self.params, self._obs,
        ]  # fmt: skip
        total = sum(a.nbytes for a in arrays) + self._lane_schedules.nbytes
        total += sum(s.nbytes for s in (self._v, self._w) if s is not None)
        return total / self.num_envs

    def close_extras(self, **kwargs: Any) -> None:
        pass

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        spec = state.get("spec")
        if spec is not None and "sys" in getattr(spec, "kwargs", {}):
            # As StateSpaceEnv: re-specify a python-control system (holds a lambda) by matrices.
            proto = self._proto
            kwargs = {k: v for k, v in spec.kwargs.items() if k not in ("sys", "canonical")}
            kwargs.update(A=proto.A_nominal, B=proto.B_nominal, C=proto.C, D=proto.D, dt=proto.dt)
            state["spec"] = dataclasses.replace(spec, kwargs=kwargs)
        return state
