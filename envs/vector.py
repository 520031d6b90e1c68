"""Native Gymnasium vector environments: ``B`` linear plants stepped by one compiled batch loop.

``ObserverCanonicalVectorEnv``, ``ObservabilityCanonicalVectorEnv`` and ``StateSpaceVectorEnv``
are the vector counterparts of the single environments in :mod:`stcgym.envs.plants` (their
``vector_entry_point``, so ``gym.make_vec(id, num_envs=B)`` builds them). Each sub-environment
("lane") has its own parameters, state, noise streams, reference and seed; ``step`` runs the
plant step of :mod:`stcgym.envs.dynamics` for every lane in one ``prange`` loop (Python loops
run only for lanes that reset, once per noise block to refill the per-lane noise buffers, and for
the per-lane generators of random references and schedules).

Equivalence with single environments
------------------------------------
Lane ``i`` reproduces ``gym.make(id, **kwargs)`` reset with the same seed **bit for bit**: the
same observations, rewards, ``terminated``/``truncated`` flags and info values, episode after
episode. The plant step is the same compiled lane function on the same numbers; references and
schedules produce the same values for a lane as for a single env (:mod:`stcgym.envs.signals`);
and the vector env repeats the single env's per-episode RNG split exactly: the lane's
``np_random`` (seeded like ``Env.reset(seed=s)``) draws one 63-bit integer per episode, whose
``SeedSequence`` children 0-4 feed output noise, process noise, reference, schedule and draws.
Only the children an episode actually uses are built (a child is ``SeedSequence(entropy,
spawn_key=(j,))``, identical to ``spawn(5)[j]``), and noise is drawn per lane in blocks whose size
only sets memory use: a numpy ``Generator`` gives the same normals whether drawn in one block of
512 or in smaller pieces.

Reset seeds follow :class:`gymnasium.vector.SyncVectorEnv`: ``seed=s`` gives lane ``i`` the seed
``s + i``; a list gives one seed per lane; ``None`` keeps each lane's generator (fresh entropy on
first use).

Autoreset
---------
``autoreset_mode`` (constructor argument, also in ``metadata["autoreset_mode"]``) is Gymnasium's
``NEXT_STEP`` by default: after a lane ends, the next ``step`` ignores that lane's action, resets
it (next episode of the lane's generator) and returns its first observation with reward 0 and
both flags false. ``SAME_STEP`` resets in the same call and reports ``infos["final_obs"]`` /
``infos["final_info"]`` (what Stable-Baselines3 needs: :class:`stcgym.agents.rl.vec_env.SB3VecEnv`
switches to it); ``DISABLED`` leaves resets to the caller (``reset(options={"reset_mask":
mask})``). ``max_episode_steps`` truncates like ``TimeLimit``.
An autoreset starts the lane's next episode like ``env.reset()`` without options, as
``SyncVectorEnv`` does: parameters given through ``reset(options=...)`` last one episode (a
``UserWarning`` says so the first time such a lane autoresets); give per-lane ``a``/``b`` to the
constructor to keep them.

Infos are Gymnasium vector infos: one array per key with a boolean ``"_key"`` mask; the keys are
those of the single env (``info_keys=(...)`` keeps a subset, ``()`` none: cheaper for many lanes).

Options of ``reset`` are those of the single environment and apply to every lane being reset;
parameter options (``"theta"``, ``"a"``/``"b"``, ``"initial_state"``, state-space ``"A"``/``"B"``)
may also be given per lane with a leading axis of length ``num_envs``. Unknown keys raise
``ValueError``; every bad argument raises before any lane changes.

For a compiled rollout of ``T`` steps, :meth:`LinearPlantVectorEnv.lookahead` returns the
references, parameters and noise the next ``T`` steps would use, without changing the env.
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
from stcgym.envs.canonical import check_ab, split_theta
from stcgym.envs.catalogue import PlantSpec, get_plant
from stcgym.envs.plants import (
    CanonicalPlantEnv,
    LinearPlantEnv,
    ObservabilityCanonicalEnv,
    ObserverCanonicalEnv,
    StateSpaceEnv,
)
from stcgym.envs.signals import NEVER, Schedule
from stcgym.envs.validation import non_negative as _non_negative
from stcgym.envs.validation import real_array as _real_array

__all__ = [
    "LinearPlantVectorEnv",
    "CanonicalPlantVectorEnv",
    "ObserverCanonicalVectorEnv",
    "ObservabilityCanonicalVectorEnv",
    "StateSpaceVectorEnv",
    "episode_streams",
]

#: Child indices of the per-episode ``SeedSequence`` split (see ``LinearPlantEnv.reset``).
_V, _W, _REF, _SCHED, _DRAW = range(5)
#: Default memory budget of one noise buffer (all lanes); sets the block length per refill.
NOISE_BUFFER_BYTES = 64 * 2**20
_NEVER = NEVER
_USER = "user schedule"  # key of the schedule given to the constructor


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


class _LaneNormals:
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


def _per_lane(value: ArrayLike, num_envs: int, shape: tuple[int, ...], name: str) -> NDArray:
    """Broadcast an option to ``(num_envs, *shape)``: one value for all lanes or one per lane."""
    arr = _real_array(value, name)
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


class LinearPlantVectorEnv(VectorEnv):
    """Base class: ``num_envs`` lanes of a :class:`~stcgym.envs.plants.LinearPlantEnv`.

    Parameters
    ----------
    num_envs
        Number of lanes ``B``.
    max_episode_steps
        Truncation after this many steps (``gym.make_vec`` passes the registered value).
    autoreset_mode
        ``"NextStep"`` (default), ``"SameStep"`` or ``"Disabled"``; see the module docstring.
    noise_buffer_bytes
        Memory for each noise buffer (all lanes); sets how many draws per lane are refilled
        at once (16 to 512). Results do not depend on it.
    info_keys
        Keys of ``infos`` to return (default all of the single env's; ``()`` for none).
    **kwargs
        The single environment's arguments (``single_cls``); one prototype single env is built
        from them to validate them and to hold the shared configuration.

    Public state (leading axis = lane): ``x``, ``t``, ``params``, ``y_clean``, ``n_clipped``;
    :attr:`memory_per_lane` in bytes.

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
        noise_budget = int(_non_negative(noise_buffer_bytes, "noise_buffer_bytes"))
        self.num_envs = B = int(num_envs)
        self.max_episode_steps = None if max_episode_steps is None else int(max_episode_steps)
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
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(B, 2 * p), dtype=np.float64)
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
        self._v = _LaneNormals(B, p, noise_budget) if self.noise_std else None
        self._w = _LaneNormals(B, n, noise_budget) if self.process_noise_std else None
        self._no_noise = np.zeros((B, 0))
        self._no_noise_1d = np.zeros(B)
        # References: one object per output channel, holding every lane's state.
        self.reference = [copy.deepcopy(r) for r in proto.reference]
        for ref in self.reference:
            ref.allocate(B)
        self._random_refs = any(r.random for r in self.reference)
        # Time-varying schedules: objects holding their lanes' state, keyed like _schedule_key;
        # `_schedule_id[i]` is lane i's (-1: constant) and `_next_change[i]` the first step at
        # which lane i's parameters must be re-read.
        self._schedules: list[Schedule] = []
        self._schedule_keys: dict[Hashable, int] = {}
        self._schedule_id = np.full(B, -1, dtype=np.int64)
        self._next_change = np.full(B, _NEVER, dtype=np.int64)
        self._started = False
        self._obs = np.zeros((B, 2 * p))
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
        if key == _USER:
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

    # ------------------------------------------------------------------ schedules
    def _schedule_index(self, key: Hashable) -> int:
        if key not in self._schedule_keys:
            sched = self._make_schedule(key)
            sched.allocate(self.num_envs)
            self._schedule_keys[key] = len(self._schedules)
            self._schedules.append(sched)
        return self._schedule_keys[key]

    def _update_schedules(self) -> None:
        """Re-read the parameters of lanes whose schedule may have changed at their step."""
        due = np.flatnonzero(self._next_change <= self.t)
        if due.size == 0:
            return
        for s, sched in enumerate(self._schedules):
            lanes = due[self._schedule_id[due] == s]
            if lanes.size:
                k = self.t[lanes]
                self.params[lanes] = sched.values(k, lanes)
                self._next_change[lanes] = sched.next_change(k, lanes)

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
            x0 = _per_lane(
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
        entropy = []
        for j, i in enumerate(idx):
            seed = None if seeds is None else seeds[j]
            if seed is not None or self._lane_rng[i] is None:
                self._lane_rng[i], _ = seeding.np_random(seed)
            entropy.append(int(self._lane_rng[i].integers(2**63)))

        v0 = None
        if self._v is not None:
            v0 = self._v.restart(idx, [episode_streams(e, [_V])[0] for e in entropy], True)
        if self._w is not None:
            self._w.restart(idx, [episode_streams(e, [_W])[0] for e in entropy], False)
        if self._random_refs:
            children = [episode_streams(e, [_REF])[0].spawn(len(self.reference)) for e in entropy]
            for c, ref in enumerate(self.reference):
                ref.reset_lanes(idx, [ch[c] for ch in children])

        draw: list[np.random.Generator | None] = [None] * k
        if std is not None or self._needs_draw_rng(parsed):
            draw = [episode_streams(e, [_DRAW])[0] for e in entropy]
        nominal, keys = self._nominal(idx, parsed, draw)

        # Schedules: params(0) and the first step at which they may change again.
        params = np.array(nominal, dtype=float, copy=True)
        self._schedule_id[idx] = -1
        self._next_change[idx] = _NEVER
        for key in {key for key in keys if key is not None}:
            rows = np.array([j for j, kj in enumerate(keys) if kj == key], dtype=np.int64)
            lanes = idx[rows]
            s = self._schedule_index(key)
            sched = self._schedules[s]
            rngs = [episode_streams(entropy[j], [_SCHED])[0] for j in rows]
            sched.reset_lanes(lanes, params[rows], rngs)
            zero = np.zeros(len(lanes), dtype=np.int64)
            params[rows] = sched.values(zero, lanes)
            if sched.time_varying:
                self._schedule_id[lanes] = s
                self._next_change[lanes] = sched.next_change(zero, lanes)
        self.params[idx] = params

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
        self._obs[idx, self.n_outputs :] = self._references(self.t[idx], idx)

    def reset(
        self,
        *,
        seed: int | Sequence[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[NDArray, dict[str, Any]]:
        """Reset all lanes, or those of ``options["reset_mask"]``; see the module docstring.

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
        if seed is None:
            seeds: list[int | None] | None = None
        elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            seeds = [int(seed) + i for i in range(B)]
        elif isinstance(seed, (Sequence, np.ndarray)) and not isinstance(seed, str):
            seeds = list(seed)
            if len(seeds) != B:
                raise ValueError(
                    f"a list of seeds must have num_envs={B} entries, got {len(seeds)}"
                )
            for s in seeds:
                if s is not None and (
                    isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0
                ):
                    raise ValueError(
                        f"seed entries must be non-negative integers or None, got {s!r}"
                    )
        else:
            raise TypeError(
                f"seed must be an int, a list of num_envs={B} ints, or None, got {seed!r}"
            )
        mask = options.pop("reset_mask", None)
        if mask is None:
            mask = np.ones(B, dtype=bool)
        else:
            try:
                mask = np.asarray(mask)
            except (TypeError, ValueError):
                mask = np.zeros(0)  # ragged: reported below
            if mask.shape != (B,) or mask.dtype != np.bool_ or not mask.any():
                raise ValueError(
                    f"options['reset_mask'] must be a bool array of shape ({B},) with a True entry"
                )
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
        """``r(k)`` of lanes ``idx`` (all lanes when ``None``), shape ``(len, p)``."""
        out = np.empty((len(k), self.n_outputs))
        for c, ref in enumerate(self.reference):
            out[:, c] = ref.values(k, idx)
        return out

    def _check_actions(self, actions: ArrayLike, active: NDArray | None) -> NDArray:
        B, m = self.num_envs, self.n_inputs
        u = _real_array(actions, "actions")
        if u.shape == (B,) and m == 1:
            u = u.reshape(B, 1)
        if u.shape != (B, m):
            raise ValueError(f"actions must have shape ({B}, {m}), got {u.shape}")
        ok = np.isfinite(u)
        if not ok.all() and (active is None or not ok[active].all()):
            raise ValueError("actions must be finite (no lane was stepped)")
        return np.ascontiguousarray(u)

    def step(self, actions: ArrayLike) -> tuple[NDArray, NDArray, NDArray, NDArray, dict[str, Any]]:
        """Advance every lane one step; see the module docstring for autoreset and infos.

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
        u_raw = self._check_actions(actions, ~autoreset if any_reset else None)
        if any_reset:  # ignored actions of resetting lanes may be anything
            u_raw = np.where(autoreset[:, None], 0.0, u_raw)
        r = self._references(self.t + 1)  # a user reference may raise: before any change
        z_w = self._w.take() if self._w is not None else self._no_noise
        z_v = self._v.take() if self._v is not None else self._no_noise
        self._step_lanes(u_raw, z_w, z_v, r)
        self.n_clipped += self._clipped
        self.t += 1
        self._update_schedules()
        rewards = self._reward.copy()
        terminated = self._diverged.copy()
        if self.max_episode_steps is not None:
            truncated = self.t >= self.max_episode_steps
        else:
            truncated = np.zeros(self.num_envs, dtype=bool)
        obs = self._obs
        obs[:, : self.n_outputs] = self._y
        obs[:, self.n_outputs :] = r

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
        between). Returns a dict of arrays: ``"r"`` ``(B, T, p)`` with ``r[:, j] = r(t + 1 + j)``
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
        scheds = copy.deepcopy(self._schedules)
        v, w = copy.deepcopy(self._v), copy.deepcopy(self._w)
        out: dict[str, Any] = {
            "r": np.empty((B, T, p)),
            "z_v": np.zeros((B, T, p)),
            "z_w": np.zeros((B, T, n)),
            "params": None,
        }
        varying = bool((self._schedule_id >= 0).any())
        if varying:
            out["params"] = np.empty((B, T, *self.params.shape[1:]))
        params = self.params.copy()
        next_change = self._next_change.copy()
        for j in range(T):
            k = self.t + j
            for c, ref in enumerate(refs):
                out["r"][:, j, c] = ref.values(k + 1)
            if v is not None:
                out["z_v"][:, j] = v.take()
            if w is not None:
                out["z_w"][:, j] = w.take()
            if varying:
                due = np.flatnonzero(next_change <= k)
                for s, sched in enumerate(scheds):
                    lanes = due[self._schedule_id[due] == s]
                    if lanes.size:
                        params[lanes] = sched.values(k[lanes], lanes)
                        next_change[lanes] = sched.next_change(k[lanes], lanes)
                out["params"][:, j] = params
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
        >>> envs = gym.make_vec("stcgym/ObserverCanonical-v0", num_envs=1000, noise_std=0.1)
        >>> _ = envs.reset(seed=0)
        >>> envs.memory_per_lane < 10_000
        True
        """
        arrays = [
            self.x,
            self.t,
            self.y_clean,
            self.n_clipped,
            self._u,
            self._y,
            self._reward,
            self._clipped,
            self._diverged,
            self._terminated,
            self._truncated,
            self._needs_reset,
            self._from_options,
            self._schedule_id,
            self._next_change,
            self.params,
            self._obs,
        ]
        total = sum(a.nbytes for a in arrays)
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


class CanonicalPlantVectorEnv(LinearPlantVectorEnv):
    """Lanes of a SISO canonical plant; ``params`` is ``theta = [a; b]`` per lane ``(B, 2n)``.

    Keyword arguments are those of :class:`~stcgym.envs.plants.CanonicalPlantEnv`; ``a`` and
    ``b`` may also have shape ``(num_envs, n)`` (one plant per lane). With a list of catalogue
    names (``plant=[...]``) every lane draws its own plant each episode, as the single env does.
    ``plant_index`` gives each lane's catalogue index in that list (``-1``: user parameters).

    Parameters
    ----------
    num_envs, max_episode_steps, autoreset_mode, noise_buffer_bytes, info_keys
        As :class:`LinearPlantVectorEnv`.
    a, b : array_like, shape (n,) or (num_envs, n), optional
        One plant for every lane, or (both two-dimensional) one row per lane.
    **kwargs
        The other arguments of :class:`~stcgym.envs.plants.CanonicalPlantEnv`.

    Raises
    ------
    ValueError
        Per-lane ``a`` and ``b`` of different shapes, without ``num_envs`` rows, or not finite;
        anything :class:`LinearPlantVectorEnv` rejects.

    Examples
    --------
    One first-order plant per lane:

    >>> import gymnasium as gym
    >>> import numpy as np
    >>> import stcgym.envs
    >>> envs = gym.make_vec(
    ...     "stcgym/ObserverCanonical-v0", num_envs=2, a=[[-0.5], [0.5]], b=[[1.0], [2.0]],
    ...     reference="zero",
    ... )
    >>> _ = envs.reset(seed=0)
    >>> envs.theta
    array([[-0.5,  1. ],
           [ 0.5,  2. ]])
    >>> obs, *_ = envs.step(np.array([1.0, 1.0]))
    >>> obs[:, 0]  # y(1) = b u(0) per lane
    array([1., 2.])
    """

    single_cls: type[CanonicalPlantEnv] = CanonicalPlantEnv

    def _make_proto(self, kwargs: dict[str, Any]) -> LinearPlantEnv:
        a, b = kwargs.get("a"), kwargs.get("b")
        self._lane_theta: NDArray | None = None
        if a is not None and b is not None and np.ndim(a) == 2 and np.ndim(b) == 2:
            a2, b2 = _real_array(a, "a"), _real_array(b, "b")
            if a2.shape != b2.shape or a2.shape[0] != self.num_envs:
                raise ValueError(
                    f"per-lane a and b must both have shape (num_envs={self.num_envs}, n), "
                    f"got {a2.shape} and {b2.shape}"
                )
            if not (np.all(np.isfinite(a2)) and np.all(np.isfinite(b2))):
                raise ValueError("a and b must be finite")
            self._lane_theta = np.hstack((a2, b2))
            kwargs = {**kwargs, "a": a2[0], "b": b2[0]}
        return self.single_cls(**kwargs)

    def _init_params(self) -> None:
        B, n = self.num_envs, self.n_states
        proto: CanonicalPlantEnv = self._proto  # type: ignore[assignment]
        self.params = np.zeros((B, 2 * n))
        self.params[:] = proto.params if self._lane_theta is None else self._lane_theta
        self.plant_index = np.full(B, -1 if proto.plant is None else 0, dtype=np.int64)
        self.family: list[PlantSpec] = proto.family
        self._family_theta = np.array([proto.theta_of(s) for s in self.family]).reshape(-1, 2 * n)
        self.form = proto.form
        self.form_code = proto.form_code

    @property
    def theta(self) -> NDArray:
        """Parameters ``[a; b]`` in force, one row per lane (a copy), shape ``(B, 2n)``."""
        return self.params.copy()

    @property
    def plants(self) -> list[PlantSpec | None]:
        """Each lane's catalogue plant of this episode (``None`` for user parameters)."""
        return [self.family[j] if j >= 0 else None for j in self.plant_index]

    def _parse_options(self, options: dict[str, Any]) -> Any:
        n, B = self.n_states, self.num_envs
        if ("a" in options) != ("b" in options):
            raise ValueError("options 'a' and 'b' must be given together (theta = [a; b])")
        if "theta" in options:
            th = _real_array(options["theta"], "options['theta']")
            if th.ndim == 2:
                return ("theta", _lane_rows(th, B, 2 * n, "options['theta']"), None)
            theta = np.concatenate(split_theta(th))
        elif "a" in options or "b" in options:
            a_opt, b_opt = options.get("a"), options.get("b")
            if np.ndim(a_opt) == 2 or np.ndim(b_opt) == 2:
                a2 = _lane_rows(_real_array(a_opt, "options['a']"), B, n, "options['a']")
                b2 = _lane_rows(_real_array(b_opt, "options['b']"), B, n, "options['b']")
                return ("theta", np.hstack((a2, b2)), None)
            theta = np.concatenate(check_ab(a_opt, b_opt))
        elif "plant" in options:
            spec = get_plant(options["plant"])
            if spec.n != n:
                raise ValueError(
                    f"options['plant'] {spec.name!r} has order {spec.n}, the env has order {n}"
                )
            return ("plant", self._proto.theta_of(spec), spec)
        else:
            return None
        if theta.size != 2 * n:
            raise ValueError(
                f"episode parameters must have order n={n} like the env "
                f"(theta of length {2 * n}), got length {theta.size}"
            )
        return ("theta", np.broadcast_to(theta, (B, 2 * n)), None)

    def _needs_draw_rng(self, parsed: Any) -> bool:
        return parsed is None and len(self.family) > 1

    def _nominal(
        self, idx: NDArray, parsed: Any, draw: list[np.random.Generator | None]
    ) -> tuple[NDArray, list[Hashable | None]]:
        proto: CanonicalPlantEnv = self._proto  # type: ignore[assignment]
        n, k = self.n_states, len(idx)
        specs: list[PlantSpec | None] = [None] * k
        index = np.full(k, -1, dtype=np.int64)
        if parsed is not None and parsed[0] == "theta":
            theta = parsed[1][idx]
        elif parsed is not None:  # a catalogue plant for these lanes
            spec = parsed[2]
            theta = np.broadcast_to(parsed[1], (k, 2 * n))
            specs = [spec] * k
            index[:] = self.family.index(spec) if spec in self.family else -1
        elif self.family:
            if len(self.family) > 1:
                index = np.array([g.integers(len(self.family)) for g in draw], dtype=np.int64)
            else:
                index[:] = 0
            theta = self._family_theta[index]
            specs = [self.family[j] for j in index]
        elif self._lane_theta is not None:
            theta = self._lane_theta[idx]
        else:
            theta = np.broadcast_to(proto.user_theta, (k, 2 * n))
        self.plant_index[idx] = index
        if proto.has_user_schedule:
            keys: list[Hashable | None] = [_USER] * k
        else:
            keys = [s.name if s is not None and s.schedule else None for s in specs]
        return theta, keys

    def _make_schedule(self, key: Hashable) -> Schedule:
        if key == _USER:
            return super()._make_schedule(key)
        return self._proto.catalogue_schedule(get_plant(str(key)))

    def _step_lanes(self, u_raw: NDArray, z_w: NDArray, z_v: NDArray, r: NDArray) -> None:
        B = self.num_envs  # SISO: one column per lane, as (B,) views
        dynamics.canonical_plants_step(
            self.x, self.params, u_raw.reshape(B), self.action_bound, self.process_noise_std,
            z_w, self.noise_std, z_v.reshape(B) if z_v.size else self._no_noise_1d,
            r.reshape(B), self.control_cost, self.y_bound, self.form_code, self._u.reshape(B),
            self.y_clean.reshape(B), self._y.reshape(B), self._reward, self._clipped,
            self._diverged,
        )  # fmt: skip

    def _reset_outputs(self, idx: NDArray) -> NDArray:
        y = np.empty((len(idx), 1))
        dynamics.canonical_outputs(self.x, idx, y)
        return y

    def _param_infos(self, infos: dict[str, Any], mask: NDArray) -> None:
        theta = self.params.copy()
        n = self.n_states
        infos["y_clean"] = infos["y_clean"][:, 0]
        infos["theta"], infos["a"], infos["b"] = theta, theta[:, :n], theta[:, n:]


def _lane_rows(arr: NDArray, num_envs: int, width: int, name: str) -> NDArray:
    if arr.shape != (num_envs, width) or not np.all(np.isfinite(arr)):
        raise ValueError(f"per-lane {name} must be finite with shape ({num_envs}, {width})")
    return arr


class ObserverCanonicalVectorEnv(CanonicalPlantVectorEnv):
    """Vector version of :class:`~stcgym.envs.plants.ObserverCanonicalEnv` (eq. (1)-(5)).

    What ``gym.make_vec("stcgym/ObserverCanonical-v0", num_envs=B, **kwargs)`` builds.

    Parameters
    ----------
    num_envs, **kwargs
        As :class:`CanonicalPlantVectorEnv`.

    Examples
    --------
    >>> import gymnasium as gym
    >>> import numpy as np
    >>> import stcgym.envs
    >>> envs = gym.make_vec("stcgym/ObserverCanonical-v0", num_envs=3, plant="unstable2")
    >>> type(envs).__name__
    'ObserverCanonicalVectorEnv'
    >>> envs.observation_space, envs.action_space
    (Box(-inf, inf, (3, 2), float64), Box(-10.0, 10.0, (3, 1), float64))
    >>> obs, infos = envs.reset(seed=0)
    >>> obs, rewards, terminated, truncated, infos = envs.step(np.array([1.0, 0.5, -1.0]))
    >>> obs[:, 0], np.round(rewards, 4)  # y(1) = b1 u(0) = 0.5 u(0); r(1) = 1
    (array([ 0.5 ,  0.25, -0.5 ]), array([-0.26 , -0.565, -2.26 ]))
    """

    single_cls = ObserverCanonicalEnv


class ObservabilityCanonicalVectorEnv(CanonicalPlantVectorEnv):
    """Vector version of :class:`~stcgym.envs.plants.ObservabilityCanonicalEnv` (eq. (146)-(147)).

    What ``gym.make_vec("stcgym/ObservabilityCanonical-v0", num_envs=B, **kwargs)`` builds.

    Parameters
    ----------
    num_envs, **kwargs
        As :class:`CanonicalPlantVectorEnv`; ``b`` (per lane or shared) holds Markov parameters.

    Examples
    --------
    >>> import gymnasium as gym
    >>> import stcgym.envs
    >>> envs = gym.make_vec("stcgym/ObservabilityCanonical-v0", num_envs=2, plant="stable2")
    >>> _ = envs.reset(seed=0)
    >>> envs.theta  # b as Markov parameters, every lane
    array([[-1.5,  0.7,  1. ,  2. ],
           [-1.5,  0.7,  1. ,  2. ]])
    """

    single_cls = ObservabilityCanonicalEnv


class StateSpaceVectorEnv(LinearPlantVectorEnv):
    """Vector version of :class:`~stcgym.envs.plants.StateSpaceEnv`; ``params`` is ``[A B]``.

    All lanes share the matrices unless ``reset(options=...)`` sets ``"A"``/``"B"`` (also per
    lane, shape ``(num_envs, n, n)`` / ``(num_envs, n, m)``) or a schedule varies them. What
    ``gym.make_vec("stcgym/StateSpace-v0", num_envs=B, **kwargs)`` builds.

    Parameters
    ----------
    num_envs, max_episode_steps, autoreset_mode, noise_buffer_bytes, info_keys
        As :class:`LinearPlantVectorEnv`.
    **kwargs
        The arguments of :class:`~stcgym.envs.plants.StateSpaceEnv` (shared by every lane).

    Examples
    --------
    >>> import gymnasium as gym
    >>> import numpy as np
    >>> import stcgym.envs
    >>> envs = gym.make_vec("stcgym/StateSpace-v0", num_envs=2)
    >>> obs, infos = envs.reset(seed=0, options={"B": np.eye(2)})
    >>> obs, *_ = envs.step(np.array([[1.0, 0.0], [0.0, 1.0]]))
    >>> obs[:, :2]  # y(1) = x(1) = B u(0) per lane
    array([[1., 0.],
           [0., 1.]])
    >>> infos["params"].shape  # [A B] per lane
    (2, 2, 4)
    """

    single_cls = StateSpaceEnv

    def _init_params(self) -> None:
        proto: StateSpaceEnv = self._proto  # type: ignore[assignment]
        n, m = proto.B_nominal.shape
        self._AB0 = np.ascontiguousarray(np.hstack((proto.A_nominal, proto.B_nominal)))
        self.params = np.zeros((self.num_envs, n, n + m))
        self.params[:] = self._AB0
        self.C, self.D = proto.C, proto.D
        self._tmp = np.zeros((self.num_envs, n))

    def _parse_options(self, options: dict[str, Any]) -> Any:
        if "A" not in options and "B" not in options:
            return None
        proto: StateSpaceEnv = self._proto  # type: ignore[assignment]
        n, m = proto.B_nominal.shape
        B = self.num_envs
        A = _lane_matrix(options, "A", (n, n), B, proto.A_nominal)
        Bm = _lane_matrix(options, "B", (n, m), B, proto.B_nominal)
        return np.concatenate((A, Bm), axis=2)

    def _nominal(
        self, idx: NDArray, parsed: Any, draw: list[np.random.Generator | None]
    ) -> tuple[NDArray, list[Hashable | None]]:
        k = len(idx)
        if parsed is None:
            nominal = np.broadcast_to(self._AB0, (k, *self._AB0.shape))
        else:
            nominal = parsed[idx]
        return nominal, [_USER if self._proto.schedule.time_varying else None] * k

    def _step_lanes(self, u_raw: NDArray, z_w: NDArray, z_v: NDArray, r: NDArray) -> None:
        dynamics.state_space_plants_step(
            self.x, self.params, self.C, self.D, u_raw, self.action_bound,
            self.process_noise_std, z_w, self.noise_std, z_v, r, self.control_cost,
            self.y_bound, self._u, self.y_clean, self._y, self._reward, self._clipped,
            self._diverged, self._tmp,
        )  # fmt: skip

    def _reset_outputs(self, idx: NDArray) -> NDArray:
        y = np.empty((len(idx), self.n_outputs))
        dynamics.state_outputs(self.x, idx, self.C, y)
        return y

    def _param_infos(self, infos: dict[str, Any], mask: NDArray) -> None:
        infos["params"] = self.params.copy()


def _lane_matrix(
    options: dict[str, Any], key: str, shape: tuple[int, int], num_envs: int, default: NDArray
) -> NDArray:
    if key not in options:
        return np.broadcast_to(default, (num_envs, *shape))
    return _per_lane(options[key], num_envs, shape, f"options['{key}']")
