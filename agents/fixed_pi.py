"""``fixed_pi``: the best fixed PI law of a training distribution, the robust-control reference.

One PI law for every plant of a distribution, tuned on its training split:

    e(k) = r(k) - y(k),   s(k) = s(k-1) + e(k),   u(k) = clip(K_p e(k) + K_i s(k), -u_max, u_max),

with conditional integration as anti-windup (``s`` holds while the input is saturated in the
direction the error pushes it). What adaptation buys is the gap between it and the adaptive
controllers; what a learned controller without identification can reach on a distribution is
at least its score (a PI law is one policy a network can represent).

It knows the training split's episodes (its tuning data) and nothing of the test plant: no
order, no model, no estimate. The gains minimise the RL agents' training objective on the
training split (:mod:`stcgym.agents.rl.reward`): the mean over :data:`TUNING_PLANTS` training
plants (one episode each, seeds from :data:`TUNING_SEED`) of the episode's cost / LQG's on the
same episode, capped at :data:`~stcgym.agents.rl.reward.DEFAULT_COST_CAP` (a diverged episode
counts the cap). The median alone, the report's statistic, would pick a law that diverges on
a fifth of the plants: on ``ladder-l1-v1`` the median-tuned law had a median of 1.63 on the
validation plants and diverged on 23 % of them. The search: a grid over both signs and three
decades of each gain, then Nelder-Mead (scipy) on the logarithms of the gains from the grid's
best point. Deterministic, and cached per training distribution within a process.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stcgym.adaptive.policy import LanePolicy

__all__ = ["TUNING_PLANTS", "TUNING_SEED", "FixedPI", "PIGains", "training_split", "tune_fixed_pi"]

#: Training plants (one episode each) the gains are tuned on, and the episodes' first seed
#: (apart from the bench's test, validation, bound and LQG-cost episodes).
TUNING_PLANTS = 200
TUNING_SEED = 40_000
#: The grid: ``K_p`` and ``K_i`` of either sign (the same for both), magnitudes log-spaced.
_KP_GRID = np.geomspace(0.01, 3.0, 8)
_KI_GRID = np.geomspace(0.001, 1.0, 8)
#: Nelder-Mead's budget from the grid's best point, and the batches of ``TUNING_PLANTS``
#: episodes a tuning runs at most (the grid's, then Nelder-Mead's)
NELDER_MEAD_EVALUATIONS = 60
TUNING_EVALUATIONS = 2 * _KP_GRID.size * _KI_GRID.size + NELDER_MEAD_EVALUATIONS


class FixedPI(LanePolicy):
    """A fixed PI law on every lane (module docstring).

    Parameters
    ----------
    kp, ki : float
        Proportional and integral gains.
    action_bound : float
        ``u_max``.
    num_envs : int or None
        ``None``: one plant; else that many lanes.

    Examples
    --------
    >>> import numpy as np
    >>> from stcgym.agents.fixed_pi import FixedPI
    >>> pi = FixedPI(0.5, 0.1, action_bound=1.0, num_envs=2)
    >>> pi.predict(np.array([[0.0, 1.0], [0.0, 4.0]]))[0]  # 0.5 + 0.1; 2.0 + 0.4 clipped
    array([[0.6],
           [1. ]])
    >>> pi.predict(np.array([[0.0, 1.0], [0.0, 4.0]]))[0]  # lane 1 saturated: its sum stays 0
    array([[0.7],
           [1. ]])
    """

    def __init__(
        self, kp: float, ki: float, action_bound: float, num_envs: int | None = None
    ) -> None:
        for name, value in (("kp", kp), ("ki", ki), ("action_bound", action_bound)):
            if not np.isfinite(value):
                raise ValueError(f"{name} must be a finite number, got {value!r}")
        if not action_bound > 0:
            raise ValueError(f"action_bound must be positive, got {action_bound!r}")
        self.kp, self.ki, self.action_bound = float(kp), float(ki), float(action_bound)
        self.num_envs = num_envs
        self._s = np.zeros(self.num_lanes)

    def _act(self, obs: NDArray, starts: NDArray | None, deterministic: bool) -> NDArray:
        if starts is not None:
            self._s[starts] = 0.0
        e = obs[:, 1] - obs[:, 0]
        s = self._s + e
        v = self.kp * e + self.ki * s
        u = np.clip(v, -self.action_bound, self.action_bound)
        windup = (u != v) & (np.sign(self.ki * e) == np.sign(v))
        self._s = np.where(windup, self._s, s)
        return u.reshape(-1, 1)

    def _reset_lanes(self, idx: NDArray) -> None:
        self._s[idx] = 0.0


@dataclass(frozen=True)
class PIGains:
    """Tuned gains and their training score (the mean capped cost / LQG on the tuning
    episodes)."""

    kp: float
    ki: float
    score: float
    evaluations: int


def training_split(spec: Any) -> Any:
    """The training distribution of the env spec ``spec``: its family's ``train`` split (for a
    test, validation or held-out scenario of a family), or ``spec`` itself (catalogue plants).

    Raises
    ------
    ValueError
        A family without a ``train`` split.
    """
    if spec.family is None:
        return spec
    if "train" not in spec.split_names():
        raise ValueError(f"fixed_pi is tuned on a train split; family {spec.family!r} has none")
    return replace(spec, split="train")


def _score(kp: float, ki: float, spec: Any, episodes: Any, lqg: NDArray) -> float:
    from stcgym.agents.evaluation.episodes import run_episodes

    batch = run_episodes(
        lambda plants, seeds: FixedPI(kp, ki, spec.action_bound, len(plants)), spec, episodes
    )
    from stcgym.agents.rl.reward import DEFAULT_COST_CAP

    return float(np.mean(np.minimum(batch.cost.mean(axis=1) / lqg, DEFAULT_COST_CAP)))


@functools.lru_cache(maxsize=16)
def tune_fixed_pi(spec: Any, plants: int = TUNING_PLANTS) -> PIGains:
    """The best fixed PI law for the distribution of the env spec ``spec`` (module docstring).

    Parameters
    ----------
    spec : EnvSpec
        The training distribution (its action bound is the law's).
    plants : int
        Tuning plants, one episode each (the first ``plants`` of the split).

    Returns
    -------
    PIGains
    """
    from scipy.optimize import minimize

    from stcgym.agents.controllers import CONTROLLERS, YARDSTICK
    from stcgym.agents.evaluation.episodes import EpisodeSet, run_episodes
    from stcgym.agents.evaluation.scenario import Scenario

    episodes = EpisodeSet.of(spec, 1, TUNING_SEED, int(plants))
    yardstick = CONTROLLERS[YARDSTICK].build(None, Scenario.of("fixed_pi", spec, episodes))
    lqg = run_episodes(yardstick, spec, episodes, informed=True).cost.mean(axis=1)
    count = 0

    def score(kp: float, ki: float) -> float:
        nonlocal count
        count += 1
        return _score(kp, ki, spec, episodes, lqg)

    grid = [
        (score(sign * kp, sign * ki), sign, kp, ki)
        for sign in (1.0, -1.0)
        for kp in _KP_GRID
        for ki in _KI_GRID
    ]
    best, sign, kp0, ki0 = min(grid)
    result = minimize(
        lambda x: score(sign * np.exp(x[0]), sign * np.exp(x[1])),
        np.log([kp0, ki0]),
        method="Nelder-Mead",
        options={
            "maxfev": NELDER_MEAD_EVALUATIONS,
            "xatol": 0.02,
            "fatol": 1e-3,
            "initial_simplex": None,
        },  # fmt: skip
    )
    if result.fun < best:
        kp0, ki0, best = float(np.exp(result.x[0])), float(np.exp(result.x[1])), float(result.fun)
    return PIGains(sign * kp0, sign * ki0, best, count)
