"""Native Gymnasium vector environments: ``B`` linear plants stepped in one numpy operation.

``ObserverCanonicalVectorEnv``, ``ObservabilityCanonicalVectorEnv`` and ``StateSpaceVectorEnv``
are the vector counterparts of the single environments in :mod:`stcgym.envs.plants` (their
``vector_entry_point``, so ``gym.make_vec(id, num_envs=B)`` builds them). Each sub-environment
("lane") has its own parameters, state, noise streams, reference and seed; ``step`` advances all
lanes with a handful of array operations and no per-lane Python loop (Python loops run only for
lanes that reset, and once per noise block to refill the per-lane noise buffers).

Equivalence with single environments
------------------------------------
Lane ``i`` reproduces ``gym.make(id, **kwargs)`` reset with the same seed: the same observations,
rewards, ``terminated``/``truncated`` flags and info values (up to float rounding of the matrix
products), episode after episode. This holds because the vector env repeats the single env's
per-episode RNG split exactly: the lane's ``np_random`` (seeded like ``Env.reset(seed=s)``) draws
one 63-bit integer per episode, whose ``SeedSequence`` children 0-4 feed output noise, process
noise, reference, schedule and draws. Only the children an episode actually uses are built (a
child is ``SeedSequence(entropy, spawn_key=(j,))``, identical to ``spawn(5)[j]``), and noise is
drawn per lane in blocks whose size only sets memory use: a numpy ``Generator`` gives the same
normals whether drawn in one block of 512 or in smaller pieces.

Reset seeds follow :class:`gymnasium.vector.SyncVectorEnv`: ``seed=s`` gives lane ``i`` the seed
``s + i``; a list gives one seed per lane; ``None`` keeps each lane's generator (fresh entropy on
first use).

Autoreset
---------
``autoreset_mode`` (constructor argument, also in ``metadata["autoreset_mode"]``) is Gymnasium's
``NEXT_STEP`` by default: after a lane ends, the next ``step`` ignores that lane's action, resets
it (next episode of the lane's generator) and returns its first observation with reward 0 and
both flags false. ``SAME_STEP`` resets in the same call and reports ``infos["final_obs"]`` /
``infos["final_info"]`` (what :class:`SB3VecEnv` needs); ``DISABLED`` leaves resets to the caller
(``reset(options={"reset_mask": mask})``). ``max_episode_steps`` truncates like ``TimeLimit``.

Infos are Gymnasium vector infos: one array per key with a boolean ``"_key"`` mask; the keys are
those of the single env (``info_keys=(...)`` keeps a subset, ``()`` none: cheaper for many lanes).

Options of ``reset`` are those of the single environment and apply to every lane being reset;
parameter options (``"theta"``, ``"a"``/``"b"``, ``"initial_state"``, state-space ``"A"``/``"B"``)
may also be given per lane with a leading axis of length ``num_envs``.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from numpy.typing import ArrayLike, NDArray

from stcgym.envs.canonical import check_ab, split_theta
from stcgym.envs.catalogue import PlantSpec, get_plant
from stcgym.envs.plants import (
    CanonicalPlantEnv,
    LinearPlantEnv,
    ObservabilityCanonicalEnv,
    ObserverCanonicalEnv,
    StateSpaceEnv,
)
from stcgym.envs.signals import (
    ArrayReference,
    Constant,
    Jumps,
    Schedule,
    Sine,
    SquareWave,
    Step,
    Zero,
)

__all__ = [
    "LinearPlantVectorEnv",
    "CanonicalPlantVectorEnv",
    "ObserverCanonicalVectorEnv",
    "ObservabilityCanonicalVectorEnv",
    "StateSpaceVectorEnv",
    "SB3VecEnv",
    "episode_streams",
]

#: Child indices of the per-episode ``SeedSequence`` split (see ``LinearPlantEnv.reset``).
_V, _W, _REF, _SCHED, _DRAW = range(5)
#: Default memory budget of one noise buffer (all lanes); sets the block length per refill.
NOISE_BUFFER_BYTES = 64 * 2**20
_NEVER = np.iinfo(np.int64).max


def episode_streams(entropy: int, which: Sequence[int]) -> list[np.random.Generator]:
    """Generators of the per-episode child streams ``which`` (indices 0-4) of ``entropy``.

    ``LinearPlantEnv.reset`` draws ``entropy = np_random.integers(2**63)`` and builds
    ``default_rng(c)`` for ``c in SeedSequence(entropy).spawn(5)`` (output noise, process noise,
    reference, schedule, draws). Child ``j`` is ``SeedSequence(entropy, spawn_key=(j,))``, so a
    subset costs only what it uses.
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
        self.block = int(np.clip(budget_bytes // (8 * num_envs * width), 16, 512))
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


# Reference types whose value is a pure function of k and of parameters shared by all lanes.
_PURE_REFERENCES = (SquareWave, Step, Sine, Zero, ArrayReference)


def _pure_reference_values(ref: Any, k: NDArray) -> NDArray:
    """``[ref(k_i) for k_i in k]`` for a :data:`_PURE_REFERENCES` instance, vectorised."""
    t = type(ref)
    if t is SquareWave:
        return ref.offset + np.where(
            (k % ref.period) < ref.period / 2, ref.amplitude, -ref.amplitude
        )
    if t is Step:
        return np.where(k >= ref.at, ref.amplitude, ref.initial)
    if t is Sine:
        return ref.offset + ref.amplitude * np.sin(2 * np.pi * k / ref.period + ref.phase)
    if t is Zero:
        return np.zeros(k.shape)
    return ref.values[np.minimum(k, ref.values.size - 1)]  # ArrayReference


def _per_lane(value: ArrayLike, num_envs: int, shape: tuple[int, ...], name: str) -> NDArray:
    """Broadcast an option to ``(num_envs, *shape)``: one value for all lanes or one per lane."""
    arr = np.asarray(value, dtype=float)
    if arr.shape == shape:
        return np.broadcast_to(arr, (num_envs, *shape))
    if arr.shape == (num_envs, *shape):
        return arr
    raise ValueError(
        f"{name} must have shape {shape} (all lanes) or {(num_envs, *shape)} (one per lane), "
        f"got {arr.shape}"
    )


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
    exact
        Step with the single env's own matrix products, stacked: observations equal to
        single envs to rounding (slower). Otherwise the canonical structure is used (equal to
        about 1e-15 relative per step).
    **kwargs
        The single environment's arguments (``single_cls``); one prototype single env is built
        from them to validate them and to hold the shared configuration.

    Public state (leading axis = lane): ``x``, ``t``, ``params``, ``y_clean``, ``n_clipped``;
    :attr:`memory_per_lane` in bytes.
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
        exact: bool = False,
        render_mode: str | None = None,
        **kwargs: Any,
    ) -> None:
        if int(num_envs) != num_envs or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        if render_mode is not None:
            raise ValueError("the vector environments do not render; use a single env for that")
        if max_episode_steps is not None and (
            int(max_episode_steps) != max_episode_steps or max_episode_steps < 1
        ):
            raise ValueError("max_episode_steps must be a positive integer or None")
        self.num_envs = B = int(num_envs)
        self.max_episode_steps = None if max_episode_steps is None else int(max_episode_steps)
        self.autoreset_mode = AutoresetMode(autoreset_mode)
        self.metadata = {**type(self).metadata, "autoreset_mode": self.autoreset_mode}
        self.render_mode = None
        # None: every key of the single env's info; a subset saves the per-step copies.
        self.info_keys = None if info_keys is None else tuple(info_keys)
        # exact: step with the single env's own matrix products, stacked (numpy applies the
        # same formula to each lane), so observations equal those of single envs to rounding;
        # not bit for bit: OpenBLAS may pick another kernel for a stacked product, by CPU.
        self.exact = bool(exact)

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
        self._clipped = np.zeros(B, dtype=bool)
        self._diverged = np.zeros(B, dtype=bool)
        self._terminated = np.zeros(B, dtype=bool)
        self._truncated = np.zeros(B, dtype=bool)
        self._needs_reset = np.ones(B, dtype=bool)  # no episode yet
        self._lane_rng: list[np.random.Generator | None] = [None] * B
        self._v = _LaneNormals(B, p, noise_buffer_bytes) if self.noise_std else None
        self._w = _LaneNormals(B, n, noise_buffer_bytes) if self.process_noise_std else None
        # References: pure ones are evaluated for all lanes at once; others get one copy per
        # lane, reset from the lane's reference stream like the single env does.
        self._pure_refs = all(type(r) in _PURE_REFERENCES for r in proto.reference)
        self._lane_refs: list[list[Any] | None] = [None] * B
        # Time-varying schedules: one object per lane; `_next_change[i]` is the first step at
        # which lane i's parameters must be re-read (never for constant plants).
        self._schedules: list[Schedule | None] = [None] * B
        self._next_change = np.full(B, _NEVER, dtype=np.int64)
        self._any_schedule = False
        self._started = False
        self._obs = np.zeros((B, 2 * p))
        self._init_params()
        if self.exact:
            self._A = np.zeros((B, n, n))
            self._Bm = np.zeros((B, n, m))

    # ------------------------------------------------------------------ subclass hooks
    def _make_proto(self, kwargs: dict[str, Any]) -> LinearPlantEnv:
        return self.single_cls(**kwargs)

    def _init_params(self) -> None:
        """Allocate ``self.params`` (leading axis = lane)."""
        raise NotImplementedError

    def _nominal(
        self, idx: NDArray, options: dict[str, Any], draw: list[np.random.Generator | None]
    ) -> tuple[NDArray, list[Schedule | None]]:
        """Nominal parameters ``(len(idx), ...)`` and schedules (``None`` = constant)."""
        raise NotImplementedError

    def _needs_draw_rng(self, options: dict[str, Any]) -> bool:
        """Whether :meth:`_nominal` consumes the lanes' draw streams."""
        return False

    def _advance(self, u: NDArray) -> NDArray:
        """``A x + B u`` for all lanes (``u`` of shape ``(B, m)``)."""
        raise NotImplementedError

    def _lane_matrices(self, params: NDArray) -> tuple[NDArray, NDArray]:
        """Stacked ``(A, B)`` of parameter rows (``exact`` mode)."""
        raise NotImplementedError

    def _set_lane_matrices(self, idx: Any) -> None:
        if self.exact:
            self._A[idx], self._Bm[idx] = self._lane_matrices(self.params[idx])

    def _advance_exact(self, u: NDArray) -> NDArray:
        """``A @ x + B @ u`` per lane with the single env's matmul calls."""
        return (self._A @ self.x[:, :, None])[:, :, 0] + (self._Bm @ u[:, :, None])[:, :, 0]

    def _output(self, x: NDArray, u: NDArray | None, idx: NDArray | None = None) -> NDArray:
        """Noise-free output ``C x + D u`` of lanes ``idx`` (all when ``None``); ``u=None`` at
        reset, before any input."""
        raise NotImplementedError

    def _param_infos(self, infos: dict[str, Any], mask: NDArray) -> None:
        raise NotImplementedError

    # ------------------------------------------------------------------ resets
    def _reset_lanes(
        self, idx: NDArray, seeds: Sequence[int | None] | None, options: dict[str, Any]
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
        if not self._pure_refs:
            for j, i in enumerate(idx):
                refs = [copy.deepcopy(r) for r in self._proto.reference]
                (rng_ref,) = episode_streams(entropy[j], [_REF])
                for ref, child in zip(refs, rng_ref.spawn(len(refs)), strict=True):
                    ref.reset(child)
                self._lane_refs[i] = refs

        uses_std = "initial_state" not in options and "initial_state_std" in options
        draw: list[np.random.Generator | None] = [None] * k
        if uses_std or self._needs_draw_rng(options):
            draw = [episode_streams(e, [_DRAW])[0] for e in entropy]
        nominal, schedules = self._nominal(idx, options, draw)

        # Schedules: params(0) and the first step at which they may change again.
        params = np.array(nominal, dtype=float, copy=True)
        self._next_change[idx] = _NEVER
        for j, i in enumerate(idx):
            sched = schedules[j]
            if sched is None or not sched.time_varying:
                self._schedules[i] = None
                if sched is not None:
                    params[j] = sched(0)
                continue
            (rng_sched,) = episode_streams(entropy[j], [_SCHED])
            sched.reset(nominal[j], rng_sched)
            params[j] = sched(0)
            self._schedules[i] = sched
            self._next_change[i] = _first_change(sched, 0)
        self.params[idx] = params
        self._set_lane_matrices(idx)
        self._any_schedule = bool((self._next_change != _NEVER).any())

        if "initial_state" in options:
            x0 = _per_lane(options["initial_state"], self.num_envs, (n,), "initial_state")[idx]
            if not np.all(np.isfinite(x0)):
                raise ValueError("options['initial_state'] must be finite")
            self.x[idx] = x0
        elif uses_std:
            std = float(options["initial_state_std"])
            if not np.isfinite(std) or std < 0:
                raise ValueError("options['initial_state_std'] must be a finite number >= 0")
            self.x[idx] = [std * g.standard_normal(n) for g in draw]
        elif self._proto._initial_state is not None:
            self.x[idx] = self._proto._initial_state
        else:
            self.x[idx] = 0.0

        self.t[idx] = 0
        self.n_clipped[idx] = 0
        self._clipped[idx] = False
        self._diverged[idx] = False
        self._terminated[idx] = False
        self._truncated[idx] = False
        self._needs_reset[idx] = False
        y_clean = self._output(self.x[idx], None, idx)
        self.y_clean[idx] = y_clean
        y = y_clean + self.noise_std * v0 if v0 is not None else y_clean
        self._obs[idx, : self.n_outputs] = y
        self._obs[idx, self.n_outputs :] = self._references(self.t[idx], idx)

    def reset(
        self,
        *,
        seed: int | Sequence[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[NDArray, dict[str, Any]]:
        """Reset all lanes, or those of ``options["reset_mask"]``; see the module docstring."""
        B = self.num_envs
        options = dict(options or {})
        if seed is None:
            seeds: list[int | None] | None = None
        elif isinstance(seed, (int, np.integer)):
            super().reset(seed=int(seed))
            seeds = [int(seed) + i for i in range(B)]
        else:
            seeds = list(seed)
            if len(seeds) != B:
                raise ValueError(
                    f"a list of seeds must have num_envs={B} entries, got {len(seeds)}"
                )
        mask = options.pop("reset_mask", None)
        if mask is None:
            mask = np.ones(B, dtype=bool)
        else:
            mask = np.asarray(mask)
            if mask.shape != (B,) or mask.dtype != np.bool_ or not mask.any():
                raise ValueError(
                    f"options['reset_mask'] must be a bool array of shape ({B},) with a True entry"
                )
        idx = np.flatnonzero(mask)
        if not self._started and not mask.all():
            raise ValueError("the first reset must reset every lane (no reset_mask)")
        self._reset_lanes(idx, None if seeds is None else [seeds[i] for i in idx], options)
        self._started = True
        return self._obs.copy(), self._infos(mask)

    # ------------------------------------------------------------------ stepping
    def _references(self, k: NDArray, idx: NDArray | None = None) -> NDArray:
        """``r(k)`` of lanes ``idx`` (all lanes when ``None``), shape ``(len, p)``."""
        if self._pure_refs:
            return np.stack([_pure_reference_values(r, k) for r in self._proto.reference], axis=1)
        lanes = range(self.num_envs) if idx is None else idx
        return np.array(
            [[ref(int(kk)) for ref in self._lane_refs[i]] for i, kk in zip(lanes, k, strict=True)]
        ).reshape(len(k), self.n_outputs)

    def _check_actions(self, actions: ArrayLike, active: NDArray | None) -> NDArray:
        B, m = self.num_envs, self.n_inputs
        u = np.asarray(actions, dtype=float)
        if u.shape == (B,) and m == 1:
            u = u.reshape(B, 1)
        if u.shape != (B, m):
            raise ValueError(f"actions must have shape ({B}, {m}), got {u.shape}")
        ok = np.isfinite(u)
        if not ok.all() and (active is None or not ok[active].all()):
            raise ValueError("actions must be finite (no lane was stepped)")
        return u

    def step(self, actions: ArrayLike) -> tuple[NDArray, NDArray, NDArray, NDArray, dict[str, Any]]:
        """Advance every lane one step; see the module docstring for autoreset and infos."""
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
        u = self._check_actions(actions, ~autoreset if any_reset else None)
        if any_reset:  # ignored actions of resetting lanes may be anything
            u = np.where(autoreset[:, None], 0.0, u)
        b = self.action_bound
        uc = np.clip(u, -b, b)
        self._clipped = (uc != u).any(axis=1)
        self.n_clipped += self._clipped
        u = uc

        with np.errstate(over="ignore", invalid="ignore"):
            x = self._advance_exact(u) if self.exact else self._advance(u)
            if self._w is not None:
                x += self.process_noise_std * self._w.take()
            self.x = x
            self.t += 1
            if self._any_schedule:
                self._update_schedules()
            y_clean = self._output(x, u, None)
            y = y_clean + self.noise_std * self._v.take() if self._v is not None else y_clean
            r = self._references(self.t)
            finite = np.isfinite(np.sum(x)) and np.isfinite(np.sum(y))
            if finite:
                diverged = (np.abs(y) > self.y_bound).any(axis=1)
            else:
                fin = np.isfinite(x).all(axis=1) & np.isfinite(y).all(axis=1)
                diverged = ~fin | (np.abs(y) > self.y_bound).any(axis=1)
                if not fin.all():
                    # Keep observation and reward finite, as the single env does.
                    bad = ~fin
                    yb = np.clip(
                        np.nan_to_num(y[bad], posinf=self.y_bound, neginf=-self.y_bound),
                        -self.y_bound,
                        self.y_bound,
                    )
                    y = y.copy() if y is y_clean else y
                    y[bad] = yb
                    y_clean = y_clean.copy()
                    y_clean[bad] = yb
            self.y_clean = y_clean
            e = np.clip(y_clean, -self.y_bound, self.y_bound) - r
            if self.n_outputs == 1 and self.n_inputs == 1:
                rewards = -(e[:, 0] * e[:, 0] + self.control_cost * (u[:, 0] * u[:, 0]))
            else:
                rewards = -(
                    np.einsum("ij,ij->i", e, e) + self.control_cost * np.einsum("ij,ij->i", u, u)
                )
        self._diverged = diverged
        terminated = diverged.copy()
        if self.max_episode_steps is not None:
            truncated = self.t >= self.max_episode_steps
        else:
            truncated = np.zeros(self.num_envs, dtype=bool)
        obs = self._obs
        obs[:, : self.n_outputs] = y
        obs[:, self.n_outputs :] = r

        final: dict[str, Any] = {}
        if any_reset:  # NEXT_STEP: lanes that ended last step start over instead
            idx = np.flatnonzero(autoreset)
            self._reset_lanes(idx, None, {})
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
            self._reset_lanes(idx, None, {})
            self._needs_reset[:] = False
        else:
            self._needs_reset = done
        self._terminated, self._truncated = terminated, truncated
        infos = self._infos(np.ones(self.num_envs, dtype=bool))
        infos.update(final)
        return obs.copy(), rewards, terminated, truncated, infos

    def _update_schedules(self) -> None:
        """Re-read the parameters of lanes whose schedule may have changed at their step."""
        for i in np.flatnonzero(self._next_change <= self.t):
            sched = self._schedules[i]
            if sched is None:  # lane reset to a constant plant
                self._next_change[i] = _NEVER
                continue
            k = int(self.t[i])
            self.params[i] = sched(k)
            self._set_lane_matrices([i])
            self._next_change[i] = _first_change(sched, k)
        self._any_schedule = bool((self._next_change != _NEVER).any())
        self._params_changed()

    def _params_changed(self) -> None:
        """Hook: some lanes' parameters were rewritten."""

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
        """Bytes of lane state (arrays and noise buffers) per lane, Python objects excluded."""
        arrays = [
            self.x,
            self.t,
            self.y_clean,
            self.n_clipped,
            self._clipped,
            self._diverged,
            self._terminated,
            self._truncated,
            self._needs_reset,
            self._next_change,
            self.params,
            getattr(self, "_obs", np.zeros(0)),
        ]
        total = sum(a.nbytes for a in arrays)
        total += sum(s.nbytes for s in (self._v, self._w) if s is not None)
        return total / self.num_envs

    def close_extras(self, **kwargs: Any) -> None:
        pass


def _first_change(sched: Schedule, k: int) -> int:
    """First step after ``k`` at which ``sched`` may return different parameters."""
    if isinstance(sched, Constant):
        return _NEVER
    if type(sched) is Jumps:
        later = sched._steps[sched._steps > k]
        return int(later[0]) if later.size else _NEVER
    return k + 1  # Ramp, RandomWalk, user schedules: every step


class CanonicalPlantVectorEnv(LinearPlantVectorEnv):
    """Lanes of a SISO canonical plant; ``params`` is ``theta = [a; b]`` per lane ``(B, 2n)``.

    Keyword arguments are those of :class:`~stcgym.envs.plants.CanonicalPlantEnv`; ``a`` and
    ``b`` may also have shape ``(num_envs, n)`` (one plant per lane). With a list of catalogue
    names (``plant=[...]``) every lane draws its own plant each episode, as the single env does.
    ``plant_index`` gives each lane's catalogue index in that list (``-1``: user parameters).
    """

    single_cls: type[CanonicalPlantEnv] = CanonicalPlantEnv

    def _make_proto(self, kwargs: dict[str, Any]) -> LinearPlantEnv:
        a, b = kwargs.get("a"), kwargs.get("b")
        self._lane_theta: NDArray | None = None
        if a is not None and b is not None and np.ndim(a) == 2 and np.ndim(b) == 2:
            a2, b2 = np.asarray(a, float), np.asarray(b, float)
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
        self.params = np.zeros((B, 2 * n))
        self.plant_index = np.full(B, -1, dtype=np.int64)
        proto: CanonicalPlantEnv = self._proto  # type: ignore[assignment]
        self._family: list[PlantSpec] = proto._family
        self._family_theta = np.array([proto._theta_of(s) for s in self._family]).reshape(-1, 2 * n)
        self.form = proto.form

    @property
    def theta(self) -> NDArray:
        """Parameters ``[a; b]`` in force, one row per lane (a copy)."""
        return self.params.copy()

    @property
    def plants(self) -> list[PlantSpec | None]:
        """Each lane's catalogue plant of this episode (``None`` for user parameters)."""
        return [self._family[j] if j >= 0 else None for j in self.plant_index]

    def _needs_draw_rng(self, options: dict[str, Any]) -> bool:
        overridden = any(key in options for key in ("theta", "a", "b", "plant"))
        return not overridden and len(self._family) > 1

    def _nominal(
        self, idx: NDArray, options: dict[str, Any], draw: list[np.random.Generator | None]
    ) -> tuple[NDArray, list[Schedule | None]]:
        proto: CanonicalPlantEnv = self._proto  # type: ignore[assignment]
        n, k = self.n_states, len(idx)
        specs: list[PlantSpec | None] = [None] * k
        index = np.full(k, -1, dtype=np.int64)
        if "theta" in options:
            th = np.asarray(options["theta"], dtype=float)
            theta = (
                _lane_rows(th, self.num_envs, idx, 2 * n, "options['theta']")
                if th.ndim == 2
                else np.broadcast_to(np.concatenate(split_theta(th)), (k, th.size))
            )
        elif "a" in options or "b" in options:
            a_opt, b_opt = options.get("a"), options.get("b")
            if np.ndim(a_opt) == 2 or np.ndim(b_opt) == 2:
                a2 = _lane_rows(np.asarray(a_opt, float), self.num_envs, idx, n, "options['a']")
                b2 = _lane_rows(np.asarray(b_opt, float), self.num_envs, idx, n, "options['b']")
                theta = np.hstack((a2, b2))
            else:
                theta = np.broadcast_to(np.concatenate(check_ab(a_opt, b_opt)), (k, 2 * n))
        elif "plant" in options:
            spec = get_plant(options["plant"])
            theta = np.broadcast_to(proto._theta_of(spec), (k, 2 * spec.n))
            specs = [spec] * k
            index[:] = self._family.index(spec) if spec in self._family else -1
        elif self._family:
            if len(self._family) > 1:
                index = np.array([g.integers(len(self._family)) for g in draw], dtype=np.int64)
            else:
                index[:] = 0
            theta = self._family_theta[index]
            specs = [self._family[j] for j in index]
        elif self._lane_theta is not None:
            theta = self._lane_theta[idx]
        else:
            theta = np.broadcast_to(proto._user_theta, (k, 2 * n))
        if theta.shape[1] != 2 * n:
            raise ValueError(
                f"episode parameters must have order n={n} like the env "
                f"(theta of length {2 * n}), got length {theta.shape[1]}"
            )
        if not np.all(np.isfinite(theta)):
            raise ValueError("episode parameters must be finite")
        self.plant_index[idx] = index
        schedules: list[Schedule | None]
        if proto._user_schedule:
            user = proto.schedule
            schedules = [copy.deepcopy(user) if user.time_varying else None for _ in range(k)]
        else:
            schedules = [
                proto._catalogue_schedule(s) if s is not None and s.schedule else None
                for s in specs
            ]
        return theta, schedules

    def _output(self, x: NDArray, u: NDArray | None, idx: NDArray | None = None) -> NDArray:
        return x[:, :1].copy()  # C = e1, D = 0: C x + D u is x_1 exactly

    def _lane_matrices(self, params: NDArray) -> tuple[NDArray, NDArray]:
        n = self.n_states
        k = params.shape[0]
        A = np.tile(np.eye(n, k=1), (k, 1, 1))
        if self.form == "observer":
            A[:, :, 0] = -params[:, :n]
        else:
            A[:, -1, :] = -params[:, n - 1 :: -1]
        return A, params[:, n:, None].copy()

    def _param_infos(self, infos: dict[str, Any], mask: NDArray) -> None:
        theta = self.params.copy()
        n = self.n_states
        infos["y_clean"] = infos["y_clean"][:, 0]
        infos["theta"], infos["a"], infos["b"] = theta, theta[:, :n], theta[:, n:]


def _lane_rows(arr: NDArray, num_envs: int, idx: NDArray, width: int, name: str) -> NDArray:
    if arr.shape != (num_envs, width) or not np.all(np.isfinite(arr)):
        raise ValueError(f"per-lane {name} must be finite with shape ({num_envs}, {width})")
    return arr[idx]


class ObserverCanonicalVectorEnv(CanonicalPlantVectorEnv):
    """Vector version of :class:`~stcgym.envs.plants.ObserverCanonicalEnv` (eq. (1)-(5)).

    ``x(k+1)_i = -a_i x_1 + x_{i+1} + b_i u`` (``x_{n+1} = 0``), ``y = x_1``.
    """

    single_cls = ObserverCanonicalEnv

    def _advance(self, u: NDArray) -> NDArray:
        n = self.n_states
        th, x = self.params, self.x
        xn = th[:, :n] * x[:, :1]
        np.negative(xn, out=xn)
        xn[:, :-1] += x[:, 1:]
        xn += th[:, n:] * u
        return xn


class ObservabilityCanonicalVectorEnv(CanonicalPlantVectorEnv):
    """Vector version of :class:`~stcgym.envs.plants.ObservabilityCanonicalEnv` (eq. (146)).

    ``x(k+1)_i = x_{i+1} + b_i u`` for ``i < n``, ``x(k+1)_n = -sum_j a_{n+1-j} x_j + b_n u``.
    """

    single_cls = ObservabilityCanonicalEnv

    def _advance(self, u: NDArray) -> NDArray:
        n = self.n_states
        th, x = self.params, self.x
        xn = np.empty_like(x)
        xn[:, :-1] = x[:, 1:]
        last = th[:, n - 1] * x[:, 0]
        for j in range(1, n):
            last += th[:, n - 1 - j] * x[:, j]
        xn[:, -1] = -last
        xn += th[:, n:] * u
        return xn


class StateSpaceVectorEnv(LinearPlantVectorEnv):
    """Vector version of :class:`~stcgym.envs.plants.StateSpaceEnv`; ``params`` is ``[A B]``.

    All lanes share the matrices unless ``reset(options=...)`` sets ``"A"``/``"B"`` (also per
    lane, shape ``(num_envs, n, n)`` / ``(num_envs, n, m)``) or a schedule varies them.
    """

    single_cls = StateSpaceEnv

    def _init_params(self) -> None:
        proto: StateSpaceEnv = self._proto  # type: ignore[assignment]
        n, m = proto._B0.shape
        self.params = np.zeros((self.num_envs, n, n + m))
        self._AB0 = np.hstack((proto._A0, proto._B0))
        self._C, self._D = proto._C, proto._D
        self._shared = True  # every lane runs the nominal [A B]: one matrix product

    def _nominal(
        self, idx: NDArray, options: dict[str, Any], draw: list[np.random.Generator | None]
    ) -> tuple[NDArray, list[Schedule | None]]:
        proto: StateSpaceEnv = self._proto  # type: ignore[assignment]
        n, m = proto._B0.shape
        k = len(idx)
        A = self._lane_matrix(options, "A", (n, n), idx, proto._A0)
        Bm = self._lane_matrix(options, "B", (n, m), idx, proto._B0)
        nominal = np.concatenate((A, Bm), axis=2)
        sched = proto.schedule
        schedules = [copy.deepcopy(sched) if sched.time_varying else None for _ in range(k)]
        if "A" in options or "B" in options or sched.time_varying:
            self._shared = False
        elif len(idx) == self.num_envs:
            self._shared = True
        return nominal, schedules

    def _lane_matrix(
        self, options: dict[str, Any], key: str, shape: tuple[int, int], idx: NDArray, default
    ) -> NDArray:
        if key not in options:
            return np.broadcast_to(default, (len(idx), *shape))
        arr = np.asarray(options[key], dtype=float)
        if arr.shape == shape:
            arr = np.broadcast_to(arr, (len(idx), *shape))
        elif arr.shape == (self.num_envs, *shape):
            arr = arr[idx]
        else:
            raise ValueError(
                f"options['{key}'] must have shape {shape} or {(self.num_envs, *shape)}, "
                f"got {arr.shape}"
            )
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"options['{key}'] must be finite")
        return arr

    def _params_changed(self) -> None:
        self._shared = False

    def _lane_matrices(self, params: NDArray) -> tuple[NDArray, NDArray]:
        n = self.n_states
        return params[:, :, :n].copy(), params[:, :, n:].copy()

    def _advance(self, u: NDArray) -> NDArray:
        n = self.n_states
        if self._shared:
            return self.x @ self._AB0[:, :n].T + u @ self._AB0[:, n:].T
        P = self.params
        return np.einsum("bij,bj->bi", P[:, :, :n], self.x) + np.einsum(
            "bij,bj->bi", P[:, :, n:], u
        )

    def _output(self, x: NDArray, u: NDArray | None, idx: NDArray | None = None) -> NDArray:
        if self.exact:
            y = (self._C @ x[:, :, None])[:, :, 0]
            if u is not None:
                y = y + (self._D @ u[:, :, None])[:, :, 0]
            return y
        y = x @ self._C.T
        if u is not None:
            y = y + u @ self._D.T
        return y

    def _param_infos(self, infos: dict[str, Any], mask: NDArray) -> None:
        infos["params"] = self.params.copy()


# ---------------------------------------------------------------------------------------------
# Stable-Baselines3 adapter
# ---------------------------------------------------------------------------------------------
def SB3VecEnv(venv: LinearPlantVectorEnv, *, full_info: bool = False) -> Any:  # noqa: N802
    """Wrap a native vector env as a Stable-Baselines3 ``VecEnv`` (SB3 is imported lazily).

    The native env is switched to ``SAME_STEP`` autoreset, which is SB3's convention: a finished
    lane is reset within the step, with its last observation in ``info["terminal_observation"]``
    and ``info["TimeLimit.truncated"]`` set on time-outs. Seeds given to ``seed()`` and options
    given to ``set_options()`` apply at the next ``reset()``, as in SB3. ``full_info=True``
    also copies every info key into the per-lane dicts (slow for many lanes). Rewards are
    float32, like SB3's ``DummyVecEnv``.
    """
    return _sb3_class()(venv, full_info=full_info)


_SB3_CLASS: type | None = None


def _sb3_class() -> type:
    """Build the adapter class on first use, so that SB3 stays an optional dependency."""
    global _SB3_CLASS
    if _SB3_CLASS is not None:
        return _SB3_CLASS
    from stable_baselines3.common.vec_env import VecEnv

    class _SB3VecEnv(VecEnv):
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
            self.reset_infos = self._lane_infos(infos, np.ones(self.num_envs, dtype=bool))
            self._reset_seeds()
            self._reset_options()
            return obs

        def step_async(self, actions: NDArray) -> None:
            self._actions = np.asarray(actions, dtype=float).reshape(self.num_envs, -1)

        def step_wait(self) -> tuple[NDArray, NDArray, NDArray, list[dict[str, Any]]]:
            obs, rewards, terminated, truncated, infos = self.venv.step(self._actions)
            dones = terminated | truncated
            lane_infos = self._lane_infos(infos, np.zeros(self.num_envs, dtype=bool))
            for i in np.flatnonzero(dones):
                lane_infos[i]["terminal_observation"] = infos["final_obs"][i]
                lane_infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
            return obs, rewards.astype(np.float32), dones, lane_infos

        def _lane_infos(self, infos: dict[str, Any], _: NDArray) -> list[dict[str, Any]]:
            if not self.full_info:
                return [{} for _ in range(self.num_envs)]
            keys = [
                k for k in infos if not k.startswith("_") and k not in ("final_obs", "final_info")
            ]
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

    _SB3_CLASS = _SB3VecEnv
    return _SB3_CLASS
