"""Fixed sets of evaluation episodes, run as one batch of lanes.

An :class:`EpisodeSet` lists the episodes every controller of a scenario meets: for each, the
plant (a catalogue name or a member of a family split) and the seed of ``env.reset`` (noise,
reference, initial state, jump time). :func:`run_episodes` runs a controller on all of them at
once: one native vector env (:meth:`~stcgym.agents.evaluation.env_spec.EnvSpec.make_vec`), lane
``i`` reset with seed ``seeds[i]`` on plant ``plants[i]``, and one batched policy
(``num_envs = B``), driven by the closed-loop driver
(:func:`~stcgym.agents.closed_loop.run_closed_loop`), whose divergence rule charges a lane that
leaves ``y_bound`` its last cost for every step it did not live. Lane ``i`` is the single env
reset with the same seed and plant, so a batch equals its episodes run one by one.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stcgym.agents.closed_loop import run_closed_loop
from stcgym.agents.evaluation.env_spec import EnvSpec

__all__ = ["BatchEpisodes", "EpisodeSet", "LaneBuilder", "run_episodes"]

#: ``builder(plants, seeds) -> policy``: a policy for ``len(plants)`` lanes, lane ``i`` on the
#: plant spec ``plants[i]`` (only the oracles may look at it) with the episode seed ``seeds[i]``
#: (a controller with random parts draws its own stream from it).
LaneBuilder = Callable[[list[Any], list[int]], Any]

#: Lanes of one vector env at most (the traces of a batch are ``(B, T)`` arrays).
MAX_LANES = 512


@dataclass(frozen=True)
class EpisodeSet:
    """The evaluation episodes of a scenario: ``plants[i]`` reset with ``seeds[i]``.

    Parameters
    ----------
    plants : tuple of str
        One plant name per episode (catalogue names, or members of the spec's family split).
    seeds : tuple of int
        One reset seed per episode.

    Examples
    --------
    Two episodes on each of the first three plants of a family's test split:

    >>> from stcgym.agents.evaluation.env_spec import EnvSpec
    >>> from stcgym.agents.evaluation.episodes import EpisodeSet
    >>> spec = EnvSpec(family="siso2-v1", split="test")
    >>> eps = EpisodeSet.of(spec, per_plant=2, first_seed=100, max_plants=3)
    >>> eps.plants[:3]
    ('siso2-v1/test/1100', 'siso2-v1/test/1100', 'siso2-v1/test/1101')
    >>> eps.seeds
    (100, 101, 102, 103, 104, 105)
    >>> eps.units  # (plants, episodes per plant)
    (3, 2)
    """

    plants: tuple[str, ...]
    seeds: tuple[int, ...]

    def __post_init__(self) -> None:
        if len(self.plants) != len(self.seeds) or not self.plants:
            raise ValueError("an episode set needs one plant and one seed per episode")

    @classmethod
    def of(
        cls, spec: EnvSpec, per_plant: int, first_seed: int, max_plants: int | None = None
    ) -> EpisodeSet:
        """``per_plant`` episodes on each plant of ``spec`` (its first ``max_plants``), with
        the seeds ``first_seed, first_seed + 1, ...`` in plant-major order."""
        names = spec.plant_names()[: max_plants or None]
        plants = tuple(name for name in names for _ in range(int(per_plant)))
        return cls(plants, tuple(int(first_seed) + i for i in range(len(plants))))

    @property
    def units(self) -> tuple[int, int]:
        """``(plants, episodes per plant)`` when every plant has the same number of episodes
        in a row (as :meth:`of` builds them)."""
        names = list(dict.fromkeys(self.plants))
        per = len(self.plants) // len(names)
        if (
            per * len(names) != len(self.plants)
            or tuple(n for n in names for _ in range(per)) != self.plants
        ):
            raise ValueError("the episodes are not per_plant episodes of each plant in a row")
        return len(names), per

    def to_dict(self) -> dict[str, Any]:
        return {"plants": list(self.plants), "seeds": list(self.seeds)}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> EpisodeSet:
        return cls(tuple(data["plants"]), tuple(int(s) for s in data["seeds"]))


@dataclass
class BatchEpisodes:
    """What one controller did on an :class:`EpisodeSet` (``B`` episodes of ``T`` steps).

    ``cost`` holds the charged cost per step (the divergence rule's charge included);
    ``y`` (noise-free output), ``r`` and ``u`` the traces, ``nan`` after a divergence;
    ``jump_step`` the first step whose parameters differ from step 0's (``-1``: none);
    ``theta``/``theta_hat`` the true and estimated parameters with ``record_theta``.
    """

    plants: list[str]
    seeds: list[int]
    cost: NDArray
    diverged: NDArray
    steps_run: NDArray
    jump_step: NDArray
    y: NDArray
    r: NDArray
    u: NDArray
    n_clipped: NDArray
    predict_s: float
    theta: NDArray | None = None
    theta_hat: NDArray | None = None

    @property
    def num_episodes(self) -> int:
        return len(self.seeds)

    def take(self, lanes: Sequence[int]) -> BatchEpisodes:
        """The episodes ``lanes`` only (copies)."""
        idx = np.asarray(lanes, dtype=int)

        def pick(a: NDArray | None) -> NDArray | None:
            return None if a is None else a[idx].copy()

        return BatchEpisodes(
            [self.plants[i] for i in idx],
            [self.seeds[i] for i in idx],
            *(pick(a) for a in (self.cost, self.diverged, self.steps_run, self.jump_step)),
            *(pick(a) for a in (self.y, self.r, self.u, self.n_clipped)),
            self.predict_s,
            pick(self.theta),
            pick(self.theta_hat),
        )


def _concat(parts: list[BatchEpisodes]) -> BatchEpisodes:
    if len(parts) == 1:
        return parts[0]

    def cat(name: str) -> NDArray | None:
        arrays = [getattr(p, name) for p in parts]
        return None if arrays[0] is None else np.concatenate(arrays)

    return BatchEpisodes(
        [p for part in parts for p in part.plants],
        [s for part in parts for s in part.seeds],
        *(cat(n) for n in ("cost", "diverged", "steps_run", "jump_step", "y", "r", "u")),
        cat("n_clipped"),
        sum(p.predict_s for p in parts),
        cat("theta"),
        cat("theta_hat"),
    )


def run_episodes(
    builder: LaneBuilder | Any,
    spec: EnvSpec,
    episodes: EpisodeSet,
    *,
    informed: bool = False,
    record_theta: bool = False,
    max_lanes: int = MAX_LANES,
) -> BatchEpisodes:
    """Run a controller on every episode of ``episodes``, as batches of lanes.

    Parameters
    ----------
    builder : LaneBuilder or policy
        ``builder(plants, seeds)`` returning a policy for that many lanes; or a policy for
        exactly ``len(episodes)`` lanes (then ``max_lanes`` must not split the set).
    spec : EnvSpec
        The scenario's environment.
    episodes : EpisodeSet
        Plants and seeds.
    informed : bool, default False
        Tell the policy the true parameters whenever they change (a parameter jump), through
        ``policy.set_model(a, b, lanes=changed)`` before the step's action is chosen: the
        known-model oracles, which know the plant at every step.
    record_theta : bool, default False
        Keep the true parameters per step and the policy's ``theta`` estimate (``nan`` where
        it has none).
    max_lanes : int
        Lanes of one vector env at most.

    Returns
    -------
    BatchEpisodes
        Costs, outcomes and traces, in the order of ``episodes``.

    Examples
    --------
    The known-model oracle on two episodes of ``unstable2``, and the same episodes one by one
    through :func:`~stcgym.agents.evaluation.evaluate.run_episode`:

    >>> import numpy as np
    >>> from stcgym.adaptive import KnownModelController
    >>> from stcgym.agents import EnvSpec, run_episode
    >>> from stcgym.agents.evaluation.episodes import EpisodeSet, run_episodes
    >>> spec = EnvSpec("unstable2", steps=200)
    >>> def oracles(plants, seeds):
    ...     return KnownModelController([p.a for p in plants], [p.b for p in plants],
    ...                                 num_envs=len(plants), action_bound=spec.action_bound)
    >>> batch = run_episodes(oracles, spec, EpisodeSet(("unstable2",) * 2, (0, 1)))
    >>> batch.cost.shape, batch.diverged.tolist(), batch.jump_step.tolist()
    ((2, 200), [False, False], [-1, -1])
    >>> def oracle(plant, seed):
    ...     return KnownModelController(plant.a, plant.b, action_bound=spec.action_bound)
    >>> bool(np.allclose(batch.cost[1], run_episode(oracle, spec, seed=1).cost))
    True
    """
    B = len(episodes.seeds)
    if hasattr(builder, "predict") and B > max_lanes:
        raise ValueError(f"a ready policy runs {B} lanes in one batch, above max_lanes={max_lanes}")
    parts = []
    for lo in range(0, B, int(max_lanes)):
        hi = min(B, lo + int(max_lanes))
        sub = EpisodeSet(episodes.plants[lo:hi], episodes.seeds[lo:hi])
        parts.append(_run_batch(builder, spec, sub, informed, record_theta))
    return _concat(parts)


def _run_batch(
    builder: Any, spec: EnvSpec, episodes: EpisodeSet, informed: bool, record_theta: bool
) -> BatchEpisodes:
    env = spec.make_vec(len(episodes.seeds), info_keys=())
    named = len(set(spec.plant_names())) > 1 or spec.family is not None
    obs, lane_plants = spec.reset_lanes(
        env, list(episodes.seeds), list(episodes.plants) if named else None
    )
    policy = builder if hasattr(builder, "predict") else builder(lane_plants, list(episodes.seeds))
    B, T = len(episodes.seeds), spec.steps
    p_y = env.n_outputs
    # the traces hold the performance output z = C_z x where the cost weighs one, else y
    C_z = getattr(env, "C_z", None)
    p = p_y if C_z is None else C_z.shape[0]

    def output() -> NDArray:
        return env.y_clean if C_z is None else env.x @ C_z.T

    def reference(obs_k: NDArray) -> NDArray:  # r of z (a target state observed: C_z r_x)
        r_obs = obs_k[:, p_y:]
        return r_obs if r_obs.shape[1] == p else r_obs @ C_z.T

    m = env.single_action_space.shape[0]
    y = np.full((B, T + 1, p), np.nan)
    r = np.full((B, T + 1, p), np.nan)
    u = np.full((B, T, m), np.nan)
    y[:, 0], r[:, 0] = output(), reference(obs)
    clipped = np.zeros((B, T), dtype=bool)
    params0 = env.params.copy()
    last = params0.copy()
    jump_step = np.full(B, -1, dtype=np.int64)
    theta = theta_hat = None
    if record_theta:
        theta = np.full((B, T + 1, params0[0].size), np.nan)
        theta_hat = np.full((B, T, params0[0].size), np.nan)
        theta[:, 0] = params0.reshape(B, -1)

    def before_step(k: int) -> None:
        changed = np.any((env.params != last).reshape(B, -1), axis=1)
        if not changed.any():
            return
        jump_step[changed & (jump_step < 0)] = k
        last[changed] = env.params[changed]
        if informed:
            n = spec.order
            if spec.plant_kind == "mimo":  # [A B] of each lane
                new = env.params[changed]
                policy.set_model(new[:, :, :n], new[:, :, n:], lanes=changed)
                return
            new = env.params[changed].reshape(int(changed.sum()), -1)
            policy.set_model(new[:, :n], new[:, n:], lanes=changed)

    def on_step(k: int, action: NDArray, obs_k: NDArray, info: dict[str, Any]) -> None:
        a = np.asarray(action, dtype=float).reshape(B, m)
        low, high = env.action_space.low, env.action_space.high  # (B, m): the env's clip
        clipped[:, k] = np.any((a < low) | (a > high), axis=1)
        u[:, k] = np.clip(a, low, high)
        y[:, k + 1], r[:, k + 1] = output(), reference(obs_k)
        if record_theta:
            theta[:, k + 1] = env.params.reshape(B, -1)
            est = getattr(policy, "theta", None)
            if est is not None and np.size(est) == theta_hat[:, k].size:
                theta_hat[:, k] = np.reshape(est, (B, -1))

    with warnings.catch_warnings():
        # a lane that ends early restarts (autoreset) with the constructor's plant: what it
        # does then is not scored, so the env's warning about that plant does not apply
        warnings.filterwarnings("ignore", message="autoreset: lanes whose parameters")
        loop = run_closed_loop(policy, env, obs, T, before_step=before_step, on_step=on_step)
    env.close()
    # Nothing after a divergence belongs to the episode: the lane restarts with another one
    # (whose plant change is no jump of this episode).
    for i, lived in enumerate(loop.steps_run):
        y[i, lived + 1 :], r[i, lived + 1 :], u[i, lived:] = np.nan, np.nan, np.nan
        clipped[i, lived:] = False
        if jump_step[i] > lived:
            jump_step[i] = -1
        if record_theta:
            theta[i, lived + 1 :], theta_hat[i, lived:] = np.nan, np.nan
    squeeze = (lambda a: a[..., 0]) if p == 1 else (lambda a: a)
    return BatchEpisodes(
        list(episodes.plants),
        list(episodes.seeds),
        loop.cost,
        loop.diverged,
        loop.steps_run,
        jump_step,
        squeeze(y),
        squeeze(r),
        u[..., 0] if m == 1 else u,
        clipped.sum(axis=1),
        loop.predict_s,
        theta,
        theta_hat,
    )
