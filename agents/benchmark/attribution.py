"""Identification or design? The report's answer, generated from the numbers.

On held-out plants the self-tuning controller identifies the plant online and designs a
controller on the estimate. The informed RL baselines (:mod:`stcgym.agents.rl.interfaces`)
separate the two: ``theta_ppo`` is PPO given an online estimate of the same kind, so what it
gains over ``ppo`` (the window alone) is what identification is worth to a learned
controller, and what ``stc`` still gains over ``theta_ppo`` is the model-based design on top
of it; ``residual_ppo`` learns on top of the controller, so what it gains over ``stc`` is what
the design leaves to learn. Every comparison is paired on the same (plant, episode) (the
paired cost ratio, geometric mean, with its bootstrap interval:
:func:`~stcgym.agents.evaluation.statistics.paired_comparison`); a ratio counts as lower or
higher only when its interval excludes 1.

:func:`identification_or_design` writes one sentence per scenario of the plant family (test
split, held-out variants, the jump) and a summary, whichever way the numbers fall.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from stcgym.agents.benchmark.headline import paired
from stcgym.agents.evaluation.statistics import Estimate

__all__ = ["identification_or_design", "verdict"]

#: The agents the answer compares: the controller, RL with the estimate, RL without, and RL
#: on top of the controller.
STC, THETA, PLAIN, RESIDUAL = "stc", "theta_ppo", "ppo", "residual_ppo"


def verdict(ratio: Estimate) -> str:
    """``"lower"``, ``"higher"`` or ``"same"``: where a paired cost ratio's interval lies
    against 1.

    Examples
    --------
    >>> from stcgym.agents.benchmark.attribution import verdict
    >>> from stcgym.agents.evaluation.statistics import Estimate
    >>> verdict(Estimate(0.8, 0.7, 0.9)), verdict(Estimate(0.95, 0.8, 1.1))
    ('lower', 'same')
    """
    if ratio.high < 1:
        return "lower"
    if ratio.low > 1:
        return "higher"
    return "same"


def _share(gain: Estimate, gap: Estimate) -> float:
    """The share of the log cost gap ``gap`` (stc / ppo) that ``gain`` (theta_ppo / ppo)
    closes."""
    if gap.value <= 0 or gain.value <= 0 or gap.value == 1:
        return math.nan
    return math.log(gain.value) / math.log(gap.value)


def _sentence(
    name: str, tables: dict[str, Any], reps: int, own: bool = False
) -> tuple[str, str | None]:
    """The sentence of one scenario and its class (``None``: no advantage to attribute);
    ``own``: ``theta_ppo`` is given the controller's own estimate."""
    gap = paired(tables, STC, PLAIN, reps=reps)["ratio"]
    gain = paired(tables, THETA, PLAIN, reps=reps)["ratio"]
    design = paired(tables, STC, THETA, reps=reps)["ratio"]
    figures = (
        f"stc / ppo {gap.format(3)}, theta_ppo / ppo {gain.format(3)}, "
        f"stc / theta_ppo {design.format(3)}"
    )
    if verdict(gap) != "lower":
        who = "ppo's is lower" if verdict(gap) == "higher" else "neither is reliably lower"
        return f"`{name}`: no advantage of the self-tuning controller over PPO to attribute " \
               f"({who}; {figures})", None  # fmt: skip
    share = _share(gain, gap)
    if verdict(gain) != "lower":
        kind = "design"
        text = (
            "the estimate does not lower RL's cost, so the advantage lies in what the "
            "controller does with its estimate, the model-based design"
        )
        if not own:
            text += " (or in an estimate better than the one RL was given)"
    elif verdict(design) == "lower":
        kind = "both"
        text = (
            f"the estimate closes {100 * share:.0f} % of the log-cost gap and the design on "
            "top of identification the rest: both contribute"
        )
    else:
        kind = "identification"
        text = (
            "the estimate closes the gap (RL given it is no worse than the controller): the "
            "advantage is the online identification"
        )
    return f"`{name}`: {text} ({figures})", kind


def _residual(name: str, tables: dict[str, Any], reps: int) -> tuple[str, str]:
    ratio = paired(tables, RESIDUAL, STC, reps=reps)["ratio"]
    v = verdict(ratio)
    what = {
        "lower": "learning improves on the controller's design",
        "higher": "the learned correction makes the controller worse",
        "same": "the learned correction leaves the controller's cost where it was",
    }[v]
    return f"`{name}`: residual_ppo / stc {ratio.format(3)}, {what}", v


def _given(estimator: str) -> str:
    """What ``theta_ppo`` is given, for the paragraph's opening."""
    if estimator == "ELS":
        return (
            "`theta_ppo` is given the controller's own estimate (its extended least squares, "
            "run beside the agent on the inputs the agent applies): between `stc` and "
            "`theta_ppo` only the design differs."
        )
    return (
        "`theta_ppo` is given the estimate of one of the paper's estimators (the knowledge "
        "table names it), not the controller's own extended least squares."
    )


def identification_or_design(
    scenarios: Sequence[tuple[str, dict[str, Any]]],
    *,
    reps: int,
    stops: dict | None = None,
    estimator: str = "O-RLS",
) -> list[str]:
    """The report's paragraph (lines of markdown): is the self-tuning controller's advantage
    on unseen plants the online identification or the model-based design on top of it?

    Parameters
    ----------
    scenarios : sequence of (str, dict)
        ``(scenario name, tables)`` of the plant family's scenarios, ``tables`` as
        :func:`~stcgym.agents.benchmark.headline.scenario_tables` gives them.
    reps : int
        Bootstrap replications of the paired comparisons.
    stops : dict, optional
        ``agent -> training_stops`` summary: agents that hit their training cap are named.
    estimator : str, default "O-RLS"
        The estimator ``theta_ppo`` observed (its interface's): ``"ELS"`` is the
        controller's own, which leaves the design alone between ``stc`` and ``theta_ppo``.

    Returns
    -------
    list of str
        Empty when ``stc``, ``ppo`` and ``theta_ppo`` are not all in some scenario.
    """
    lines, kinds = [], []
    residual, res_kinds = [], []
    for name, tables in scenarios:
        if not {STC, THETA, PLAIN} <= set(tables):
            continue
        text, kind = _sentence(name, tables, reps, own=estimator == "ELS")
        lines.append(f"- {text}.")
        kinds.append(kind)
        if RESIDUAL in tables:
            text, v = _residual(name, tables, reps)
            residual.append(f"- {text}.")
            res_kinds.append(v)
    if not lines:
        return []
    attributed = [k for k in kinds if k is not None]
    summary = (
        f"Of {len(kinds)} scenarios of the plant family, the self-tuning controller has the "
        f"lower cost than PPO in {len(attributed)}"
    )
    if attributed:
        counts = {k: attributed.count(k) for k in ("identification", "both", "design")}
        summary += (
            f": there the online estimate given to PPO accounts for the advantage in "
            f"{counts['identification']}, for part of it in {counts['both']}, and for none of "
            f"it in {counts['design']} (where the model-based design carries it)"
        )
    residual_text = ", `residual_ppo` PPO correcting the controller" if residual else ""
    out = [
        "Is the self-tuning controller's advantage on unseen plants the online "
        "identification, or the model-based design on top of it? `theta_ppo` is PPO given an "
        f"online estimate, `ppo` the same without it{residual_text}. Paired on the same "
        "(plant, episode), cost ratios with 95 % intervals; a ratio is lower or higher only "
        "when its interval excludes 1. " + _given(estimator),
        "",
        summary + ".",
        "",
        *lines,
    ]
    if residual:
        better = res_kinds.count("lower")
        out += [
            "",
            f"Residual RL on the controller lowers its cost in {better} of {len(res_kinds)} "
            "scenarios:",
            "",
            *residual,
        ]
    capped = [a for a, s in (stops or {}).items() if a in (THETA, PLAIN, RESIDUAL) and s["cap"]]
    if capped:
        out += [
            "",
            f"Caveat: {', '.join(capped)} reached the training cap before a plateau in some "
            "runs; more training may move these ratios.",
        ]
    return out
