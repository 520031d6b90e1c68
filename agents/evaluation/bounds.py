"""One action bound per scenario for every controller, set from the LQG yardstick.

A bound that only the RL agents feel (a wide box they must explore) or only the classical
controllers feel (a clip they were not designed for) makes a comparison unequal. The bench
gives every controller of a training distribution the same bound: the input range that the
LQG controller on the true model uses on that distribution's training episodes, with a margin,

    bound = margin * quantile_q( max_k |u_LQG(k)| over each episode ),

rounded up to two significant digits (``margin = 1.5``, ``q = 0.99`` by default; LQG runs
unbounded for this). The yardstick itself then runs under the bound too, which it reaches on
at most the rare episodes above the quantile.

The same run gives the action unit of the Gaussian-policy RL agents
(:mod:`stcgym.agents.rl.interfaces`, "The action unit"): the input LQG stays within on all
but 1 % of the steps,

    unit = quantile_0.99( |u_LQG(k)| over every step of every episode ),

rounded up the same way. It scales the agents' actions only; the bound stays everyone's. On
the benchmark family (bound 27, unit 3.4) PPO's validation score after 1.5e5 steps was 20x
LQG's with units of 1.1 to 3 (zero input: 17x) and 65x, rising, with a unit of 5.4 (the median
peak).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from stcgym.agents.evaluation.env_spec import EnvSpec
from stcgym.agents.evaluation.episodes import EpisodeSet, run_episodes
from stcgym.agents.evaluation.scenario import Scenario

__all__ = [
    "BOUND_MARGIN",
    "BOUND_SEED",
    "BOUND_QUANTILE",
    "UNIT_QUANTILE",
    "bound_of_peaks",
    "lqg_action_bound",
    "lqg_action_unit",
    "lqg_inputs",
    "round_up",
]

#: First seed of the episodes that set the action bound and unit (apart from the test and
#: validation episodes').
BOUND_SEED = 20_000
BOUND_MARGIN = 1.5
BOUND_QUANTILE = 0.99
UNIT_QUANTILE = 0.99
#: The bound LQG runs under while its input range is measured (none in practice).
_UNBOUNDED = 1e9


def round_up(x: float, digits: int = 2) -> float:
    """``x > 0`` rounded up to ``digits`` significant digits.

    Examples
    --------
    >>> from stcgym.agents.evaluation.bounds import round_up
    >>> round_up(3.4501), round_up(0.0123), round_up(120.0)
    (3.5, 0.013, 120.0)
    """
    if not (math.isfinite(x) and x > 0):
        raise ValueError(f"x must be a positive finite number, got {x!r}")
    scale = 10.0 ** (math.floor(math.log10(x)) - digits + 1)
    return round(math.ceil(round(x / scale, 9)) * scale, 12)


def lqg_action_bound(
    spec: EnvSpec,
    episodes: EpisodeSet,
    *,
    margin: float = BOUND_MARGIN,
    quantile: float = BOUND_QUANTILE,
) -> tuple[float, np.ndarray]:
    """The action bound of a training distribution (module docstring).

    Parameters
    ----------
    spec : EnvSpec
        The training distribution (its own ``action_bound`` is ignored).
    episodes : EpisodeSet
        The training episodes LQG (``CONTROLLERS["lqg"]``, told every jump) runs on.
    margin, quantile
        As in the module docstring.

    Returns
    -------
    bound : float
        The rounded bound.
    peaks : ndarray
        ``max_k |u(k)|`` of every episode.

    Raises
    ------
    RuntimeError
        LQG diverged on some training episode even without a bound (the distribution holds a
        plant no linear controller holds at this noise: a family spec to fix).
    """
    peaks = lqg_inputs(spec, episodes).max(axis=(1, 2))
    return bound_of_peaks(peaks, margin=margin, quantile=quantile), peaks


def bound_of_peaks(
    peaks: np.ndarray, *, margin: float = BOUND_MARGIN, quantile: float = BOUND_QUANTILE
) -> float:
    """The action bound of the episodes' input peaks ``max_k |u(k)|`` (module docstring)."""
    return round_up(margin * float(np.quantile(np.asarray(peaks, dtype=float), quantile)))


def lqg_action_unit(inputs: np.ndarray, quantile: float = UNIT_QUANTILE) -> float:
    """The RL agents' action unit from LQG's inputs ``|u(k)|`` (:func:`lqg_inputs`, any
    shape: every step of every episode; module docstring).

    Examples
    --------
    >>> import numpy as np
    >>> from stcgym.agents.evaluation.bounds import lqg_action_unit
    >>> lqg_action_unit(np.linspace(0.0, 3.0, 101))  # 99 % of the steps within 2.97
    3.0
    """
    return round_up(float(np.quantile(np.asarray(inputs, dtype=float), quantile)))


def lqg_inputs(spec: EnvSpec, episodes: EpisodeSet) -> np.ndarray:
    """``|u(k)|`` of the LQG controller on the true model (told every jump), without an input
    bound, on ``episodes`` of ``spec``: shape ``(episodes, steps, inputs)``.

    Raises
    ------
    RuntimeError
        LQG diverged on some episode even without a bound.
    """
    from stcgym.agents.controllers import CONTROLLERS, YARDSTICK

    free = replace(spec, action_bound=_UNBOUNDED)
    builder = CONTROLLERS[YARDSTICK].build(None, Scenario.of("bound", free, episodes))
    batch = run_episodes(builder, free, episodes, informed=True)
    if batch.diverged.any():
        bad = [episodes.plants[i] for i in np.flatnonzero(batch.diverged)][:5]
        raise RuntimeError(f"LQG on the true model diverged without an input bound on {bad}")
    return np.abs(np.nan_to_num(batch.u.reshape(len(episodes.seeds), spec.steps, -1)))
