"""When an RL agent's training stops: at the plateau of its learning curve, or at its cap.

The rule (:class:`PlateauRule`): every ``eval_interval`` environment steps the deterministic
policy is evaluated on the learning-curve episodes (the bench's own cost); an evaluation
*improves* when its cost is more than ``min_improvement`` (5 %) below the reference cost, the
cost of the last evaluation that improved. Training stops when ``patience`` (3) consecutive
evaluations have not improved, or at the cap (the training budget), whichever comes first.
Evaluations count towards ``patience`` only once ``min_fraction`` (half) of the cap has
been trained: many RL learning curves stay flat at the untrained policy's cost for their first
few evaluations (SAC on the randomised plant family did for 8-18 thousand of its 100 thousand
steps), and a rule without this floor would call that flat start a plateau. With a floor of a
quarter every PPO run of the standard tier on the family stopped at the earliest step the
rule allowed (4.3e5 of a cap of 1e6), and in 6 of 15 the kept checkpoint was the untrained
network: half the cap is trained before the rule may stop a run.

This is Stable-Baselines3's ``StopTrainingOnNoModelImprovement`` (its parent callback's
``best_mean_reward`` is the negated reference cost, so a gain below 5 % is no new best), run
after each evaluation of the bench's learning-curve callback, SB3's ``EvalCallback`` pattern.
How training ended is a :class:`StopSummary`: ``"plateau"`` (the rule stopped it) or ``"cap"``
(the budget ran out first: the curve had gained more than 5 % within the last ``patience``
evaluations, or there were too few evaluations to tell), with the step of the kept checkpoint
and whether it ``improved`` on the untrained policy: a run kept at step 0 is reported as "no
improvement over initialisation", never as a trained agent's cost.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

__all__ = ["STOP_STATUSES", "PlateauRule", "PlateauTracker", "StopSummary"]

#: How a training run ended.
STOP_STATUSES: tuple[str, ...] = ("plateau", "cap")


@dataclass(frozen=True)
class PlateauRule:
    """Stop when ``patience`` consecutive evaluations gain no more than ``min_improvement``.

    Parameters
    ----------
    min_improvement
        Relative gain an evaluation must make on the reference cost to count, in ``[0, 1)``.
    patience
        Consecutive evaluations without such a gain that stop training (an integer ``>= 1``).
    min_fraction
        Fraction of the cap trained before evaluations count towards ``patience``, in
        ``[0, 1]`` (``0``: from the first evaluation).
    """

    min_improvement: float = 0.05
    patience: int = 3
    min_fraction: float = 0.5

    def __post_init__(self) -> None:
        m = self.min_improvement
        if isinstance(m, bool) or not isinstance(m, (int, float)) or not 0 <= m < 1:
            raise ValueError(f"--min-improvement must be a number in [0, 1), got {m!r}")
        p = self.patience
        if isinstance(p, bool) or not isinstance(p, int) or p < 1:
            raise ValueError(f"--patience must be an integer >= 1 (evaluations), got {p!r}")
        f = self.min_fraction
        if isinstance(f, bool) or not isinstance(f, (int, float)) or not 0 <= f <= 1:
            raise ValueError(f"--min-train-fraction must be a number in [0, 1], got {f!r}")

    def min_evals(self, cap: int, eval_interval: int) -> int:
        """Evaluations (one every ``eval_interval`` steps) before ``min_fraction`` of ``cap``:
        they do not count towards ``patience``."""
        return max(0, math.ceil(self.min_fraction * cap / eval_interval) - 1)

    def describe(self, eval_interval: int | str = "eval_interval") -> str:
        """The rule in one sentence (``--help``, the report, ``agent.json``)."""
        return (
            f"stop when the learning-curve cost has not improved on its best by more than "
            f"{self.min_improvement * 100:g} % in {self.patience} consecutive evaluations "
            f"(one every {eval_interval} env steps) once {self.min_fraction * 100:g} % of the "
            "cap is trained, or at the cap"
        )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class StopSummary:
    """How one training run ended (``agent.json``, the bench's rows and report)."""

    status: str  # "plateau" or "cap"
    steps: int  # environment steps used
    cap: int
    eval_interval: int
    evaluations: int  # evaluations the rule saw
    last_improvement_step: int | None  # the last evaluation that gained more than the minimum
    reference_cost: float  # the cost of that evaluation
    rule: str
    #: the training step of the kept checkpoint (``None``: not recorded)
    best_step: int | None = None
    #: whether the kept checkpoint scores below the untrained policy (step 0); ``False``: the
    #: agent reported is the initialisation ("no improvement over initialisation")
    improved: bool | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class PlateauTracker:
    """The reference cost of :class:`PlateauRule` and when it last moved.

    ``best_mean_reward`` is the negated reference cost: the attribute SB3's
    ``StopTrainingOnNoModelImprovement`` reads from its parent callback.
    """

    def __init__(self, rule: PlateauRule) -> None:
        self.rule = rule
        self.reference_cost = math.inf
        self.last_improvement_step: int | None = None
        self.evaluations = 0

    @property
    def best_mean_reward(self) -> float:
        return -self.reference_cost

    def observe(self, step: int, cost: float) -> bool:
        """Record the evaluation at ``step``; ``True`` when it improved on the reference."""
        self.evaluations += 1
        gain = math.isfinite(cost) and (
            not math.isfinite(self.reference_cost)
            or cost < (1.0 - self.rule.min_improvement) * self.reference_cost
        )
        if gain:
            self.reference_cost, self.last_improvement_step = float(cost), int(step)
        return bool(gain)

    def summary(self, status: str, steps: int, cap: int, eval_interval: int) -> StopSummary:
        return StopSummary(
            status,
            int(steps),
            int(cap),
            int(eval_interval),
            self.evaluations,
            self.last_improvement_step,
            self.reference_cost,
            self.rule.describe(eval_interval),
        )
