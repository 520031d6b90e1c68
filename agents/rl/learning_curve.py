"""The learning curve of an RL agent: the bench's score of the deterministic policy measured
during training, on validation episodes.

:func:`curve_checkpoints` chooses the training steps at which the curve is measured (log-spaced,
then every evaluation interval of the plateau rule), :func:`curve_cost` measures one point on a
fixed :class:`~stcgym.agents.evaluation.episodes.EpisodeSet` (with per-episode reference costs,
the LQG yardstick's on the same episodes: the median of the cost ratios; without, the mean cost
per step), and :func:`make_curve_callback` is the SB3 callback that records the curve during
:func:`~stcgym.agents.train_agent`, stops training on a plateau
(:mod:`stcgym.agents.rl.stopping`) and keeps the best checkpoint.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from stcgym.agents.evaluation.env_spec import EnvSpec
from stcgym.agents.evaluation.episodes import EpisodeSet, run_episodes
from stcgym.agents.rl.stopping import PlateauRule, PlateauTracker

__all__ = [
    "UPDATE_DIAGNOSTICS",
    "CurveOptions",
    "curve_checkpoints",
    "curve_cost",
    "make_curve_callback",
    "summarise_updates",
    "update_record",
]

#: The health of a policy update, from SB3's logger (``train/<name>``): PPO's and RecurrentPPO's
#: ``approx_kl`` (the mean KL estimate of the last epoch), ``clip_fraction``,
#: ``explained_variance`` (of the value function on the rollout), ``entropy_loss`` (minus the
#: policy's entropy) and ``std`` (the exploration scale); SAC's and TD3's losses and entropy
#: coefficient. Healthy PPO: ``approx_kl`` about 0.01-0.03, ``clip_fraction`` 0.05-0.2.
UPDATE_DIAGNOSTICS: tuple[str, ...] = (
    "approx_kl",
    "clip_fraction",
    "explained_variance",
    "entropy_loss",
    "std",
    "value_loss",
    "n_updates",
    "actor_loss",
    "critic_loss",
    "ent_coef",
)


@dataclass(frozen=True)
class CurveOptions:
    """How :func:`~stcgym.agents.train_agent` measures its learning curve, which checkpoint it
    keeps and when it stops: SB3's ``EvalCallback`` settings, on the bench's own score.

    Attributes
    ----------
    spec
        The validation environment (``None``: the training spec).
    episodes
        The validation episodes (``None``: two per plant of ``spec``, its first 20 plants,
        seeds from 10 000), run by the deterministic policy as one batch of lanes.
    points
        Log-spaced measurements up to the first ``interval``, or up to the budget without a
        plateau rule (:func:`curve_checkpoints`); step 0 is always measured.
    reference
        The yardstick's mean cost per step on each episode: the curve is then the median cost
        ratio to it (:func:`curve_cost`), else the mean cost per step.
    keep_best
        Keep the checkpoint with the lowest score (RL Zoo's ``EvalCallback`` best model)
        rather than the last one. Validation episodes only, never the bench's test episodes.
    plateau
        Stop on a plateau of the curve (:class:`~stcgym.agents.rl.stopping.PlateauRule`),
        the budget then being a cap; measured every ``interval`` env steps.
    interval
        The plateau rule's evaluation interval in env steps (a positive integer, required
        with ``plateau``).
    """

    spec: EnvSpec | None = None
    episodes: EpisodeSet | None = None
    points: int = 10
    reference: Sequence[float] | None = None
    keep_best: bool = True
    plateau: PlateauRule | None = None
    interval: int | None = None

    def __post_init__(self) -> None:
        if isinstance(self.points, bool) or int(self.points) != self.points or self.points < 1:
            raise ValueError(f"points must be a positive integer, got {self.points!r}")
        if self.plateau is None:
            return
        n = self.interval
        if n is None or isinstance(n, bool) or int(n) != n or n < 1:
            raise ValueError(f"interval must be a positive integer with a plateau, got {n!r}")
        object.__setattr__(self, "interval", int(n))


def update_record(logged: dict[str, Any], step: int) -> dict[str, float] | None:
    """``{"step", <diagnostic>: value}`` of the :data:`UPDATE_DIAGNOSTICS` SB3's logger holds
    (``logged``: its ``name_to_value``) after an update; ``None`` before the first."""
    values = {
        name: float(logged[f"train/{name}"])
        for name in UPDATE_DIAGNOSTICS
        if f"train/{name}" in logged and np.isfinite(logged[f"train/{name}"])
    }
    return None if not values else {"step": int(step), **values}


def summarise_updates(updates: Sequence[dict[str, float]]) -> dict[str, dict[str, float]]:
    """Median and 10-90 % range of each diagnostic over a run's updates (the report's
    summary of a run), and the share of PPO updates outside the healthy ranges.

    Examples
    --------
    >>> from stcgym.agents.rl.learning_curve import summarise_updates
    >>> s = summarise_updates([{"step": 1, "approx_kl": 0.02}, {"step": 2, "approx_kl": 0.06}])
    >>> s["approx_kl"]["median"], s["approx_kl"]["above_healthy"]
    (0.04, 0.5)
    """
    out: dict[str, dict[str, float]] = {}
    for name in UPDATE_DIAGNOSTICS:
        values = np.array([u[name] for u in updates if name in u], dtype=float)
        if values.size == 0:
            continue
        lo, med, hi = np.quantile(values, [0.1, 0.5, 0.9])
        out[name] = {"median": float(med), "p10": float(lo), "p90": float(hi),
                     "updates": int(values.size)}  # fmt: skip
        if name in HEALTHY:
            out[name]["above_healthy"] = float(np.mean(values > HEALTHY[name][1]))
    return out


#: The usual ranges of PPO's update diagnostics in well-tuned runs (what the report flags).
HEALTHY: dict[str, tuple[float, float]] = {"approx_kl": (0.01, 0.03), "clip_fraction": (0.05, 0.2)}


def curve_cost(
    policy: Any,
    spec: EnvSpec,
    episodes: EpisodeSet,
    reference: Sequence[float] | None = None,
    *,
    informed: bool = False,
) -> float:
    """One learning-curve point: ``policy`` (for ``len(episodes)`` lanes, or a lane builder)
    on ``episodes`` (``informed``: told the true parameters, :func:`~stcgym.agents.evaluation.
    episodes.run_episodes`).

    With ``reference`` (one cost per episode, the yardstick's mean cost per step on it): the
    median over episodes of ``cost / reference``, the score the plateau rule reads (a median,
    so that one diverged validation episode does not decide it); without: the mean cost per
    step over the episodes.
    """
    cost = run_episodes(policy, spec, episodes, informed=informed).cost.mean(axis=1)
    if reference is None:
        return float(np.mean(cost))
    ref = np.asarray(reference, dtype=float)
    if ref.shape != cost.shape or not np.all(ref > 0):
        raise ValueError(f"reference must hold {cost.size} positive costs, got {ref}")
    return float(np.median(cost / ref))


def curve_checkpoints(steps: int, points: int, eval_interval: int | None = None) -> list[int]:
    """Training steps at which the learning curve is measured.

    Without ``eval_interval``: ``points`` log-spaced steps up to ``steps``. Log spacing puts as
    many points on 1e3-1e4 steps as on 1e4-1e5, which is what the data-efficiency plot (log-x)
    needs. With it: ``points`` log-spaced steps up to the first interval, then every
    ``eval_interval`` steps up to ``steps`` (the evaluations of the plateau rule). Step 0 (the
    untrained policy) is always measured too.
    """
    steps, points = int(steps), max(1, int(points))
    head = steps if eval_interval is None else min(steps, int(eval_interval))
    first = max(1, min(1000, head // (2 * points) or 1))
    marks = np.round(np.geomspace(first, head, points)).astype(int)
    if eval_interval is not None:
        marks = np.concatenate([marks, np.arange(head, steps + 1, int(eval_interval))])
    return [int(m) for m in np.unique(marks)]


def make_curve_callback(
    curve: list,
    policy: Any,
    checkpoints: Sequence[int],
    evaluate_curve: Any,
    keep_best: bool,
    plateau: PlateauRule | None = None,
    eval_interval: int | None = None,
    cap: int = 0,
    snapshot: Callable[[], Any] | None = None,
    restore: Callable[[Any], None] | None = None,
    updates: list | None = None,
) -> Any:
    """The learning-curve callback: SB3's ``EvalCallback`` pattern on the bench's own score.

    ``evaluate_curve(policy)`` measures one point (lower is better). With ``plateau``, every
    evaluation at a multiple of ``eval_interval`` is passed to SB3's
    ``StopTrainingOnNoModelImprovement`` (its ``callback_after_eval``), which stops training
    after ``plateau.patience`` evaluations without a gain of ``plateau.min_improvement``,
    counted once ``plateau.min_fraction`` of ``cap`` (the training budget) is trained.
    ``snapshot()`` is called before each point and returns what must travel with the kept
    checkpoint besides the policy's weights (the observation normaliser's statistics, which the
    policy evaluated takes then); ``restore(state)`` puts the kept one back at the end.
    ``updates``, when given, receives one :func:`update_record` per policy update (read at the
    start of the next rollout, before anything else is logged).
    """
    import copy

    from stable_baselines3.common.callbacks import (
        EventCallback,
        StopTrainingOnNoModelImprovement,
    )

    tracker = None if plateau is None else PlateauTracker(plateau)
    after_eval = (
        None
        if plateau is None
        else StopTrainingOnNoModelImprovement(
            max_no_improvement_evals=plateau.patience - 1,
            min_evals=plateau.min_evals(cap, eval_interval),
        )
    )

    class _Curve(EventCallback):
        # Recorded at the start of a rollout, i.e. right after the previous policy update (PPO
        # collects n_steps x n_envs before it learns; SAC/TD3 update after every rollout).
        def _on_training_start(self) -> None:
            super()._on_training_start()
            self.best_cost, self.best_state, self.best_step = float("inf"), None, 0
            self.tracker, self.stopped_at = tracker, None
            self._continue = True
            self._marks = list(checkpoints)
            self._record()

        @property
        def best_mean_reward(self) -> float:
            # what StopTrainingOnNoModelImprovement reads: only a gain above the minimum counts
            return self.tracker.best_mean_reward

        def _record(self) -> None:
            extra = snapshot() if snapshot is not None else None
            cost = evaluate_curve(policy)
            curve.append((int(self.num_timesteps), cost))
            rule_eval = False
            while self._marks and self._marks[0] <= self.num_timesteps:
                mark = self._marks.pop(0)
                rule_eval |= eval_interval is not None and mark > 0 and mark % eval_interval == 0
            # Through SB3's logger: TensorBoard (--tensorboard-log) shows the curve next to
            # SB3's own training statistics.
            self.logger.record("eval/curve_score", cost)
            if self.tracker is not None and rule_eval:
                self.tracker.observe(self.num_timesteps, cost)
                self._continue = self._on_event()
                self.logger.record("eval/plateau_reference_cost", self.tracker.reference_cost)
                self.logger.record(
                    "eval/evals_without_improvement", after_eval.no_improvement_evals
                )
                if not self._continue:
                    self.stopped_at = int(self.num_timesteps)
            self.logger.dump(self.num_timesteps)
            if keep_best and cost < self.best_cost:
                self.best_cost, self.best_step = cost, int(self.num_timesteps)
                self.best_state = (copy.deepcopy(self.model.policy.state_dict()), extra)

        def _take_update(self) -> None:
            if updates is not None:
                record = update_record(self.logger.name_to_value, self.num_timesteps)
                last = {} if not updates else {k: v for k, v in updates[-1].items() if k != "step"}
                if record is not None and {k: v for k, v in record.items() if k != "step"} != last:
                    updates.append(record)

        def _on_rollout_start(self) -> None:
            self._take_update()
            if self._continue and self._marks and self.num_timesteps >= self._marks[0]:
                self._record()

        def _on_step(self) -> bool:
            # SB3 stops learn() when a callback's on_step returns False
            return self._continue

        def _on_training_end(self) -> None:
            self._take_update()  # the last update, logged after the last rollout
            # (after a stop the policy is the one just evaluated: no second evaluation)
            if self.stopped_at is None and curve[-1][0] != self.num_timesteps:
                self._record()
            if keep_best and self.best_state is not None and self.best_cost < curve[-1][1]:
                weights, extra = self.best_state
                self.model.policy.load_state_dict(weights)
                if restore is not None:
                    restore(extra)
            else:
                self.best_step = int(self.num_timesteps)

    return _Curve(after_eval)
