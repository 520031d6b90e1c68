"""The rows of ``metrics.csv``: one per scenario, controller, run and episode, scored against
the yardstick on the same episode.

Every cost figure of a row comes from the per-step (charged) costs of the episode and of the
LQG yardstick on the same episode (:class:`Yardstick`): the cost ratio, the normalised score
``(C_zero - C) / (C_zero - C_LQG)`` (1: as good as LQG, 0: no better than zero input; only where
zero input stays bounded and costs more than LQG), the ratios of the steady and post-jump
windows, and the settling steps of :func:`~stcgym.agents.evaluation.response.settling_step`
(adaptation of an online learner, re-convergence after a jump).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stcgym.agents.benchmark.metrics_csv import TOLERANCE
from stcgym.agents.evaluation.evaluate import cost_metrics
from stcgym.agents.evaluation.response import curve_settling_step, settling_step

__all__ = ["Yardstick", "episode_rows", "rl_steps_to_target"]


@dataclass
class Yardstick:
    """A scenario's reference numbers per episode.

    ``cost``: LQG's per-step costs ``(B, T)``; ``jump_step``: each episode's jump step (``-1``:
    none), read off LQG's informed run; ``zero_cost`` and ``zero_bounded``: zero input's mean
    cost per step and whether it stayed bounded.
    """

    cost: NDArray
    jump_step: NDArray
    zero_cost: NDArray
    zero_bounded: NDArray

    def __post_init__(self) -> None:
        self.metrics = cost_metrics(self.cost, self.jump_step)

    @property
    def score_defined(self) -> NDArray:
        """Episodes where the normalised score is defined."""
        return self.zero_bounded & (self.zero_cost > self.metrics["cost"])


def _ratio(x: NDArray, ref: NDArray) -> NDArray:
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(ref > 0, x / ref, math.nan)


def rl_steps_to_target(
    curve: Sequence[tuple[float, float]],
    test_ratios: NDArray,
    in_distribution: bool,
    tol: float = TOLERANCE,
) -> float:
    """An RL run's training steps to get within ``tol`` of the yardstick, for one scenario.

    Read off the run's learning curve (``(step, score)`` with the score the median cost ratio
    to the yardstick on the validation episodes: :func:`~stcgym.agents.evaluation.response.
    curve_settling_step`), and only where that curve speaks for the scenario: ``nan`` when the
    scenario's episodes are not drawn from the validation distribution (a held-out variant,
    a single other plant), ``inf`` when the run is not within ``tol`` on the scenario's own
    episodes either (median of ``test_ratios``, its cost ratios there), whatever its curve
    says.

    Examples
    --------
    A curve that reaches 1.1x of LQG at step 2000, and the test episodes at 1.05x or 50x:

    >>> import numpy as np
    >>> from stcgym.agents.benchmark.rows import rl_steps_to_target
    >>> curve = [(0, 30.0), (1000, 2.0), (2000, 1.1), (3000, 1.05)]
    >>> rl_steps_to_target(curve, np.array([1.0, 1.05, 1.1]), True)
    2000.0
    >>> rl_steps_to_target(curve, np.array([40.0, 50.0, 60.0]), True)
    inf
    >>> rl_steps_to_target(curve, np.array([1.0, 1.05, 1.1]), False)
    nan
    """
    if not in_distribution:
        return math.nan
    if not float(np.median(test_ratios)) <= tol:
        return math.inf
    return curve_settling_step(curve, 1.0, tol)


def episode_rows(
    scenario: Any,
    controller: str,
    family: str,
    run: int,
    cost: NDArray,
    response: dict[str, NDArray],
    yard: Yardstick,
    *,
    online: bool,
    steps_to_target: float | None = None,
    extra: dict[str, Any] | None = None,
) -> list[dict[str, Any]]:
    """The rows of one controller run on the episodes of ``scenario``.

    Parameters
    ----------
    scenario : Scenario
        Its ``name``, ``kind``, ``episodes`` and ``env.span`` are read.
    controller, family, run
        The row labels (``family``: ``"rl"``, ``"adaptive"``, ``"oracle"``, ``"reference"``).
    cost : ndarray, shape (B, T)
        The run's per-step costs, episode by episode.
    response : dict of str to ndarray
        The trace columns (:func:`~stcgym.agents.evaluation.evaluate.response_metrics`).
    yard : Yardstick
        The scenario's reference numbers.
    online : bool
        An online learner: its ``steps_to_target`` is the episode's adaptation time and its
        ``data_steps`` the steps it lived.
    steps_to_target : float, optional
        An RL run's training steps to its target (the same value in every row).
    extra : dict, optional
        Columns shared by every row (RL training figures).
    """
    m = cost_metrics(np.asarray(cost, dtype=float), yard.jump_step)
    ref = yard.metrics
    score = np.full(len(m["cost"]), math.nan)
    ok = yard.score_defined
    score[ok] = (yard.zero_cost[ok] - m["cost"][ok]) / (yard.zero_cost[ok] - ref["cost"][ok])
    ratios = {
        key: _ratio(m[col], ref[col])
        for key, col in (
            ("cost_ratio", "cost"),
            ("steady_ratio", "cost_steady"),
            ("post_jump_ratio", "cost_post_jump"),
        )
    }
    span = scenario.env.span
    rows = []
    for i, (plant, seed) in enumerate(
        zip(scenario.episodes.plants, scenario.episodes.seeds, strict=True)
    ):
        J = int(yard.jump_step[i])
        c, c_ref = cost[i], yard.cost[i]
        row = {
            "scenario": scenario.name,
            "kind": scenario.kind,
            "plant": plant,
            "controller": controller,
            "family": family,
            "run": run,
            "seed": seed,
            "jump_step": J if J >= 1 else "",
            **{k: v[i] for k, v in m.items()},
            **{k: v[i] for k, v in ratios.items()},
            "score": score[i],
            "reconverge_steps": math.nan,
            "steps_to_target": math.nan if steps_to_target is None else steps_to_target,
            "data_steps": 0,
            **{k: v[i] for k, v in response.items()},
            **(extra or {}),
        }
        if J >= 1:
            row["reconverge_steps"] = settling_step(c, c_ref, span=span, start=J, tol=TOLERANCE)
        if online:
            stop = J if J >= 1 else len(c)
            row["steps_to_target"] = settling_step(c, c_ref, span=span, stop=stop, tol=TOLERANCE)
            row["data_steps"] = int(response["steps_run"][i])
        rows.append(row)
    return rows
