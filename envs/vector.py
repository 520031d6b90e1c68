"""Native Gymnasium vector environments: ``B`` linear plants stepped by one compiled batch loop.

``ObserverCanonicalVectorEnv``, ``ObservabilityCanonicalVectorEnv`` and ``StateSpaceVectorEnv``
are the vector counterparts of the single environments in :mod:`stcgym.envs.plants` (their
``vector_entry_point``, so ``gym.make_vec(id, num_envs=B)`` builds them). Each sub-environment
("lane") has its own parameters, state, noise streams, reference and seed; ``step`` runs the
plant step of :mod:`stcgym.envs.dynamics` for every lane in one compiled batch loop (Python loops
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

Reset seeds follow :class:`gymnasium.vector.SyncVectorEnv` (``seed=s`` gives lane ``i`` the seed
``s + i``), and so do autoresets: ``autoreset_mode`` is Gymnasium's ``NEXT_STEP`` by default
(``SAME_STEP`` and ``DISABLED`` on request), and an autoreset starts the lane's next episode like
``env.reset()`` without options. Infos are Gymnasium vector infos (one array per key with a
``"_key"`` mask); ``reset`` options may be given per lane (leading axis ``num_envs``); unknown
keys raise ``ValueError``, and every bad argument raises before any lane changes. The whole
contract: the Vector environments section of the Environments page of the documentation.

For a compiled rollout of ``T`` steps, :meth:`LinearPlantVectorEnv.lookahead` returns the
references, parameters and noise the next ``T`` steps would use, without changing the env.

The base class lives in :mod:`stcgym.envs.vector_base`, the per-lane streams and argument checks
in :mod:`stcgym.envs.lanes`; both are importable from here as before.
"""

from __future__ import annotations

from collections.abc import Hashable
from typing import Any

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from stcgym.envs import dynamics
from stcgym.envs.canonical import check_ab, split_theta
from stcgym.envs.catalogue import PlantSpec
from stcgym.envs.lanes import episode_streams, lane_matrix, lane_rows
from stcgym.envs.plants import (
    CanonicalPlantEnv,
    LinearPlantEnv,
    ObservabilityCanonicalEnv,
    ObserverCanonicalEnv,
    StateSpaceEnv,
)
from stcgym.envs.signals import Schedule
from stcgym.envs.vector_base import USER_SCHEDULE, LinearPlantVectorEnv
from stcgym.lanes.validation import real_array

__all__ = [
    "LinearPlantVectorEnv",
    "CanonicalPlantVectorEnv",
    "ObserverCanonicalVectorEnv",
    "ObservabilityCanonicalVectorEnv",
    "StateSpaceVectorEnv",
    "episode_streams",
]


class CanonicalPlantVectorEnv(LinearPlantVectorEnv):
    """Lanes of a SISO canonical plant; ``params`` is ``theta = [a; b]`` per lane ``(B, 2n)``.

    Keyword arguments are those of :class:`~stcgym.envs.plants.CanonicalPlantEnv`; ``a`` and
    ``b`` may also have shape ``(num_envs, n)`` (one plant per lane). With a list of plants
    (``plant=[...]``: names or ``PlantSpec`` objects) every lane draws its own plant each
    episode, as the single env does. ``plant_index`` gives each lane's index in that list
    (``-1``: another plant). ``reset(options={"plant": ...})`` takes one plant for every lane
    being reset or a list of ``num_envs`` plants, one per lane (names of this env's plants or
    of the catalogue, or ``PlantSpec`` objects).

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
    ...     "stcgym/ObserverCanonical-v0",
    ...     num_envs=2,
    ...     a=[[-0.5], [0.5]],
    ...     b=[[1.0], [2.0]],
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
            a2, b2 = real_array(a, "a"), real_array(b, "b")
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
        self.members: list[PlantSpec] = proto.members
        self._members_theta = np.array([proto.theta_of(s) for s in self.members]).reshape(-1, 2 * n)
        self._lane_plants: list[PlantSpec | None] = [proto.plant] * B
        self.form = proto.form
        self.form_code = proto.form_code

    @property
    def theta(self) -> NDArray:
        """Parameters ``[a; b]`` in force, one row per lane (a copy), shape ``(B, 2n)``."""
        return self.params.copy()

    @property
    def plants(self) -> list[PlantSpec | None]:
        """Each lane's plant of this episode (``None`` for user parameters)."""
        return list(self._lane_plants)

    def _parse_options(self, options: dict[str, Any]) -> Any:
        n, B = self.n_states, self.num_envs
        if ("a" in options) != ("b" in options):
            raise ValueError("options 'a' and 'b' must be given together (theta = [a; b])")
        if "theta" in options:
            th = real_array(options["theta"], "options['theta']")
            if th.ndim == 2:
                return ("theta", lane_rows(th, B, 2 * n, "options['theta']"), None)
            theta = np.concatenate(split_theta(th))
        elif "a" in options or "b" in options:
            a_opt, b_opt = options.get("a"), options.get("b")
            if np.ndim(a_opt) == 2 or np.ndim(b_opt) == 2:
                a2 = lane_rows(real_array(a_opt, "options['a']"), B, n, "options['a']")
                b2 = lane_rows(real_array(b_opt, "options['b']"), B, n, "options['b']")
                return ("theta", np.hstack((a2, b2)), None)
            theta = np.concatenate(check_ab(a_opt, b_opt))
        elif "plant" in options:
            return self._parse_plants(options["plant"])
        else:
            return None
        if theta.size != 2 * n:
            raise ValueError(
                f"episode parameters must have order n={n} like the env "
                f"(theta of length {2 * n}), got length {theta.size}"
            )
        return ("theta", np.broadcast_to(theta, (B, 2 * n)), None)

    def _parse_plants(self, plant: Any) -> tuple[str, NDArray, list[PlantSpec]]:
        """``options["plant"]``: one plant for all lanes or a list of one per lane."""
        proto: CanonicalPlantEnv = self._proto  # type: ignore[assignment]
        n, B = self.n_states, self.num_envs
        per_lane = isinstance(plant, (list, tuple, np.ndarray))
        if per_lane and len(plant) != B:
            raise ValueError(
                f"options['plant'] must be one plant or a list of num_envs={B} plants (one per "
                f"lane), got {len(plant)}"
            )
        entries = list(plant) if per_lane else [plant]
        specs = [proto._find_plant(p.item() if isinstance(p, np.generic) else p) for p in entries]
        for spec in specs:
            if spec.n != n:
                raise ValueError(
                    f"options['plant'] {spec.name!r} has order {spec.n}, the env has order {n}"
                )
        theta = np.array([proto.theta_of(spec) for spec in specs])
        if not per_lane:
            return ("plants", np.broadcast_to(theta[0], (B, 2 * n)), specs * B)
        return ("plants", theta, specs)

    def _member_position(self, spec: PlantSpec) -> int:
        """``spec``'s index in :attr:`members` (``-1``: not one of them)."""
        j = self._proto._member_index.get(spec.name, -1)
        return j if j >= 0 and self.members[j] == spec else -1

    def _needs_draw_rng(self, parsed: Any) -> bool:
        return parsed is None and len(self.members) > 1

    def _nominal(
        self, idx: NDArray, parsed: Any, draw: list[np.random.Generator | None]
    ) -> tuple[NDArray, list[Hashable | None]]:
        proto: CanonicalPlantEnv = self._proto  # type: ignore[assignment]
        n, k = self.n_states, len(idx)
        specs: list[PlantSpec | None] = [None] * k
        index = np.full(k, -1, dtype=np.int64)
        if parsed is not None and parsed[0] == "theta":
            theta = parsed[1][idx]
        elif parsed is not None:  # plants given by name (or PlantSpec) for these lanes
            theta = parsed[1][idx]
            specs = [parsed[2][i] for i in idx]
            index[:] = [self._member_position(spec) for spec in specs]
        elif self.members:
            if len(self.members) > 1:
                index = np.array([g.integers(len(self.members)) for g in draw], dtype=np.int64)
            else:
                index[:] = 0
            theta = self._members_theta[index]
            specs = [self.members[j] for j in index]
        elif self._lane_theta is not None:
            theta = self._lane_theta[idx]
        else:
            theta = np.broadcast_to(proto.user_theta, (k, 2 * n))
        self.plant_index[idx] = index
        for j, spec in zip(idx, specs, strict=True):
            self._lane_plants[j] = spec
        if proto.has_user_schedule:
            keys: list[Hashable | None] = [USER_SCHEDULE] * k
        else:  # a plant with a schedule of its own: the PlantSpec is the key
            keys = [s if s is not None and s.schedule else None for s in specs]
        return theta, keys

    def _make_schedule(self, key: Hashable) -> Schedule:
        if isinstance(key, PlantSpec):
            return self._proto.catalogue_schedule(key)
        return super()._make_schedule(key)

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
        dynamics.canonical_outputs(idx, self.x, y)
        return y

    def _param_infos(self, infos: dict[str, Any], mask: NDArray) -> None:
        theta = self.params.copy()
        n = self.n_states
        infos["y_clean"] = infos["y_clean"][:, 0]
        infos["theta"], infos["a"], infos["b"] = theta, theta[:, :n], theta[:, n:]


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
    >>> envs = gym.make_vec(
    ...     "stcgym/ObservabilityCanonical-v0", num_envs=2, plant="stable2"
    ... )
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
        self.C_z, self.D_z, self.input_range = proto.C_z, proto.D_z, proto.input_range
        self.noise_input = proto.noise_input
        if self.input_range is not None:
            low, high = (np.broadcast_to(b, (self.num_envs, m)) for b in self.input_range)
            self.action_space = spaces.Box(low, high, dtype=np.float64)
        self._z_w = np.zeros((self.num_envs, n))
        self._no_reference = np.zeros((self.num_envs, proto.n_outputs))

    def _parse_options(self, options: dict[str, Any]) -> Any:
        if "A" not in options and "B" not in options:
            return None
        proto: StateSpaceEnv = self._proto  # type: ignore[assignment]
        n, m = proto.B_nominal.shape
        B = self.num_envs
        A = lane_matrix(options, "A", (n, n), B, proto.A_nominal)
        Bm = lane_matrix(options, "B", (n, m), B, proto.B_nominal)
        return np.concatenate((A, Bm), axis=2)

    def _nominal(
        self, idx: NDArray, parsed: Any, draw: list[np.random.Generator | None]
    ) -> tuple[NDArray, list[Hashable | None]]:
        k = len(idx)
        if parsed is None:
            nominal = np.broadcast_to(self._AB0, (k, *self._AB0.shape))
        else:
            nominal = parsed[idx]
        return nominal, [USER_SCHEDULE if self._proto.schedule.time_varying else None] * k

    def _step_lanes(self, u_raw: NDArray, z_w: NDArray, z_v: NDArray, r: NDArray) -> None:
        proto: StateSpaceEnv = self._proto  # type: ignore[assignment]
        clipped = None
        if self.input_range is not None or self.C_z is not None:
            low, high = proto._bounds()
            u = np.clip(u_raw, low, high)
            clipped = np.any(u != u_raw, axis=1)
            u_raw = np.ascontiguousarray(u)
        if self.noise_input is not None and z_w.shape[1]:
            dynamics.noise_inputs(z_w, self.noise_input, self._z_w)
            z_w = self._z_w
        if self.C_z is not None:  # the LQ stage cost at x(k), before the step moves it
            cost = np.empty(self.num_envs)
            r_k = np.ascontiguousarray(self._references(self.t))
            dynamics.performance_rewards(
                self.x, u_raw, r_k, self.C_z, self.D_z, self.control_cost, cost
            )
            r = self._no_reference
        dynamics.state_space_plants_step(
            self.x, self.params, self.C, self.D, u_raw, self.action_bound,
            self.process_noise_std, z_w, self.noise_std, z_v, r, self.control_cost,
            self.y_bound, self._u, self.y_clean, self._y, self._reward, self._clipped,
            self._diverged, self._tmp,
        )  # fmt: skip
        if self.C_z is not None:
            self._reward[:] = cost
        if clipped is not None:
            self._clipped |= clipped

    def _reset_outputs(self, idx: NDArray) -> NDArray:
        y = np.empty((len(idx), self.n_outputs))
        dynamics.state_outputs(idx, self.x, self.C, y)
        return y

    def _param_infos(self, infos: dict[str, Any], mask: NDArray) -> None:
        infos["params"] = self.params.copy()
