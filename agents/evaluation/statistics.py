"""Point estimates with confidence intervals, the way the ``rliable`` library computes them.

Agarwal et al. (2021), "Deep reinforcement learning at the edge of the statistical precipice":
with a handful of runs, report the interquartile mean (IQM: the mean of the middle 50 % of the
runs, robust to outliers yet less noisy than the median) with stratified-bootstrap confidence
intervals, and the probability of improvement ``P(X < Y)`` (here: of a lower cost) of one
controller over another. This module only adapts ``rliable`` to costs (lower is better) and
to the bench's tables; the estimators and the bootstrap are ``rliable``'s. :func:`summarize`
gives the plain per-seed statistics of the detail tables (median, IQR, CVaR, failure rate).

In the bench the unit is the *run*: one training run of an RL agent (its training seed), one
controller seed of a self-tuning controller (its probe), the single run of a deterministic
controller. Each run meets the same test plants and episodes, so the scores form a matrix
``(runs, plants)`` (each entry a mean over that plant's episodes) and the intervals of
:func:`interval_estimates` (``pool_tasks=True``) are rliable's stratified bootstrap over runs,
one stratum per test plant. Comparisons between two controllers are paired on the same
``(plant, episode)``: :func:`paired_comparison` gives the probability of the lower cost and the
geometric-mean cost ratio, :func:`rate_estimate` a rate (such as divergence) with its own
interval; both bootstrap the runs of each side and the test plants together, since a claim about
a controller is a claim about the plant distribution as well as its training.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "Estimate",
    "PairedComparison",
    "interval_estimates",
    "number_text",
    "paired_comparison",
    "bounded_estimates",
    "probability_of_improvement",
    "rate_estimate",
    "summarize",
]


def number_text(x: float | None, digits: int = 3) -> str:
    """``x`` as a table cell writes it: ``digits`` significant digits, ``-`` for a missing
    value (``None`` or ``nan``), ``inf`` / ``-inf``."""
    if x is None or math.isnan(x):
        return "-"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return f"{x:.{digits}g}"


@dataclass(frozen=True)
class Estimate:
    """A point estimate with its confidence interval ``[low, high]``.

    :meth:`format` writes ``value [low, high]``, or the value alone where the interval is the
    point (one run on one plant, or the yardstick's own ratio: nothing to resample).
    """

    value: float
    low: float
    high: float

    def format(self, digits: int = 3) -> str:
        if math.isnan(self.value):
            return "-"
        value = number_text(self.value, digits)
        if self.low == self.high == self.value:  # nothing to resample: no interval to show
            return value
        return f"{value} [{number_text(self.low, digits)}, {number_text(self.high, digits)}]"

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Estimate:
        """The estimate ``statistics.json`` holds as ``{value, low, high}`` (``null`` for
        ``nan``, infinities as the strings ``"inf"`` / ``"-inf"``)."""

        def number(x: Any) -> float:
            return math.nan if x is None else float(x)

        return cls(number(data["value"]), number(data["low"]), number(data["high"]))


def _rs(seed: int) -> np.random.RandomState:
    # rliable's bootstrap takes a legacy RandomState.
    return np.random.RandomState(seed)


def _bootstrap(score_dict, func, reps: int, confidence: float, seed: int):
    from rliable import library as rly

    # rliable's stratified bootstrap draws its indices from numpy's global generator (and
    # passes random_state on to arch): seed both, and leave the global state as it was.
    saved = np.random.get_state()  # noqa: NPY002  (rliable uses the legacy global generator)
    np.random.seed(int(seed))  # noqa: NPY002
    try:
        with warnings.catch_warnings():
            # arch warns that RandomState is deprecated; it is what rliable passes.
            warnings.simplefilter("ignore", FutureWarning)
            return rly.get_interval_estimates(
                score_dict,
                func,
                reps=int(reps),
                confidence_interval_size=confidence,
                random_state=_rs(seed),
            )
    finally:
        np.random.set_state(saved)  # noqa: NPY002


def _iqm_columns(x: np.ndarray) -> np.ndarray:
    """scipy's ``trim_mean(x, 0.25, axis=0)`` (rliable's IQM): the mean of the sorted values
    after cutting ``int(0.25 n)`` from each end."""
    n = x.shape[0]
    cut = int(0.25 * n)
    return np.mean(np.sort(x, axis=0)[cut : n - cut], axis=0)


def _improvement(x: np.ndarray, y: np.ndarray) -> float:
    """rliable's ``P(X > Y)`` per task (Mann-Whitney U / (n_x n_y), ties one half), averaged."""
    gt = x[:, None, :] > y[None, :, :]
    eq = x[:, None, :] == y[None, :, :]
    return float(np.mean(np.mean(gt + 0.5 * eq, axis=(0, 1))))


def _columns(values: ArrayLike) -> np.ndarray:
    x = np.asarray(values, dtype=float)
    return x.reshape(-1, 1) if x.ndim <= 1 else x


def interval_estimates(
    scores: Mapping[str, ArrayLike],
    *,
    pool_tasks: bool = False,
    reps: int = 1000,
    confidence: float = 0.95,
    seed: int = 0,
) -> dict[str, dict[str, list[Estimate]]]:
    """IQM and median of every entry of ``scores`` with stratified-bootstrap intervals.

    Parameters
    ----------
    scores
        ``name -> values``: a 1-D array of runs, or ``(runs, columns)``. The bootstrap resamples
        runs within each column (rliable's stratified bootstrap, one stratum per column).
        Values must be finite (censor first); an entry without runs gives ``nan``.
    pool_tasks
        ``False``: every column is its own metric, with its own estimates (one bootstrap for
        all of them, which is what keeps a report with many metrics fast). ``True``: the
        columns are tasks of one metric and the estimates pool them (rliable's aggregate IQM
        and median across tasks); one estimate.
    reps, confidence, seed
        Bootstrap replications, interval size and the bootstrap's seed.

    Returns
    -------
    dict
        ``name -> {"iqm": [Estimate per column], "median": [...]}``.
    """

    def stats(x: np.ndarray) -> np.ndarray:
        if pool_tasks:  # rliable's aggregate IQM and median over every (run, task) score
            return np.array([_iqm_columns(x.reshape(-1, 1))[0], np.median(x)])
        # rliable's aggregate_iqm / aggregate_median column by column in one vectorised call:
        # the bootstrap calls this `reps` times, and scipy's trim_mean (rliable's IQM) costs
        # milliseconds per call in argument handling alone, which made the report take
        # minutes. _iqm_columns is the same estimator (tested against rliable's).
        return np.concatenate([_iqm_columns(x), np.median(x, axis=0)])

    data, out = {}, {}
    for name, values in scores.items():
        x = _columns(values)
        k = 1 if pool_tasks else x.shape[1]
        if x.shape[0] == 0:
            nan = Estimate(math.nan, math.nan, math.nan)
            out[name] = {"iqm": [nan] * k, "median": [nan] * k}
            continue
        if not np.all(np.isfinite(x)):
            raise ValueError(f"scores[{name!r}] must be finite (censor inf before), got {x}")
        data[name] = x
    if data:
        point, ci = _bootstrap(data, stats, reps, confidence, seed)
        for name, x in data.items():
            k = 1 if pool_tasks else x.shape[1]
            est = [
                Estimate(float(point[name][i]), float(ci[name][0, i]), float(ci[name][1, i]))
                for i in range(2 * k)
            ]
            out[name] = {"iqm": est[:k], "median": est[k:]}
    return out


def probability_of_improvement(
    costs: Mapping[str, ArrayLike],
    challenger: str,
    others: Sequence[str] | None = None,
    *,
    reps: int = 1000,
    confidence: float = 0.95,
    seed: int = 0,
) -> dict[str, Estimate]:
    """``P(cost of challenger < cost of other)`` with a stratified-bootstrap interval.

    rliable's probability of improvement (the Mann-Whitney U statistic over all pairs of runs,
    ties counting one half, averaged over tasks) on negated costs. ``costs`` as in
    :func:`interval_estimates` (columns are tasks); ``others`` default to every other entry.

    """
    x = -_columns(costs[challenger])
    # rliable.metrics.probability_of_improvement runs scipy's Mann-Whitney test (milliseconds
    # of argument handling) once per bootstrap replication; _improvement is the same statistic
    # in one numpy expression (checked against rliable's in the tests).
    names = [n for n in (others if others is not None else costs) if n != challenger]
    pairs, out = {}, {}
    for name in names:
        y = -_columns(costs[name])
        if x.size == 0 or y.size == 0:
            out[name] = Estimate(math.nan, math.nan, math.nan)
            continue
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
            raise ValueError("costs must be finite for the probability of improvement")
        pairs[name] = (x, y)
    if pairs:
        point, ci = _bootstrap(pairs, _improvement, reps, confidence, seed)
        for name in pairs:
            lo, hi = np.ravel(ci[name])
            out[name] = Estimate(float(np.ravel(point[name])[0]), float(lo), float(hi))
    return out


#: Smallest cost a ratio is taken of: a per-episode cost is a sum of squares and never 0 in
#: practice, but a ratio or logarithm of an exact 0 would not be finite.
COST_FLOOR = 1e-12


@dataclass(frozen=True)
class PairedComparison:
    """Controller X against controller Y on the same ``(plant, episode)`` units.

    ``probability``: ``P(cost_X < cost_Y)`` (ties one half), over every pair of a run of X and
    a run of Y on each unit; ``ratio``: the geometric mean of ``cost_X / cost_Y`` over the same
    pairs (below 1: X costs less). Each with its bootstrap interval.
    """

    probability: Estimate
    ratio: Estimate


def _units(values: ArrayLike, name: str) -> np.ndarray:
    x = np.asarray(values, dtype=float)
    if x.ndim == 2:
        x = x[:, :, None]
    if x.ndim != 3 or 0 in x.shape:
        raise ValueError(
            f"{name} must have shape (runs, plants, episodes) or (runs, plants), got {x.shape}"
        )
    return x


def _counts(rng: np.random.Generator, reps: int, n: int) -> np.ndarray:
    """Multinomial resampling counts ``(reps, n)``: how often each of ``n`` items is drawn
    when ``n`` are drawn with replacement (all ones for a single item)."""
    if n == 1:
        return np.ones((reps, 1))
    return rng.multinomial(n, np.full(n, 1.0 / n), size=reps).astype(float)


def _bootstrap_mean(
    table: np.ndarray, reps: int, confidence: float, seed: int
) -> tuple[float, float, float]:
    """Mean of ``table[i, j, p]`` (run of X, run of Y, plant) and its percentile interval
    when the runs of X, the runs of Y and the plants are resampled independently."""
    rx, ry, P = table.shape
    rng = np.random.default_rng(seed)
    wx, wy, wp = _counts(rng, reps, rx), _counts(rng, reps, ry), _counts(rng, reps, P)
    stats = np.einsum("ri,rj,rp,ijp->r", wx, wy, wp, table) / (rx * ry * P)
    alpha = (1.0 - confidence) / 2.0
    lo, hi = np.quantile(stats, [alpha, 1.0 - alpha])
    return float(table.mean()), float(lo), float(hi)


def paired_comparison(
    x: ArrayLike,
    y: ArrayLike,
    *,
    reps: int = 2000,
    confidence: float = 0.95,
    seed: int = 0,
) -> PairedComparison:
    """Paired probability of the lower cost and cost ratio of X against Y, with intervals.

    Parameters
    ----------
    x, y : array_like, shape (runs, plants, episodes) or (runs, plants)
        Costs (lower is better) of the runs of X and of Y; entry ``[r, p, e]`` of both is the
        same episode ``e`` of test plant ``p``. The run counts may differ (an RL agent's
        training seeds against a deterministic controller's single run).
    reps, confidence, seed
        Bootstrap replications, interval size and the bootstrap's seed.

    Returns
    -------
    PairedComparison
        ``probability``: the mean over runs ``i`` of X, ``j`` of Y, plants and episodes of
        ``[x_ipe < y_jpe] + [x_ipe = y_jpe] / 2``; ``ratio``: ``exp`` of the mean of
        ``log(x_ipe / y_jpe)`` (costs floored at :data:`COST_FLOOR`). Intervals: percentile
        bootstrap resampling the runs of X, the runs of Y and the plants (each with
        replacement, independently).

    Raises
    ------
    ValueError
        Shapes that differ in plants or episodes, or costs that are not finite.

    Examples
    --------
    Two runs of X against one run of Y on two plants (one episode each): X is lower in 3 of
    the 4 pairs, and by a factor 2 in every pair but one, where it is 2x higher:

    >>> from stcgym.agents.evaluation.statistics import paired_comparison
    >>> c = paired_comparison([[1.0, 1.0], [1.0, 4.0]], [[2.0, 2.0]], reps=200)
    >>> round(c.probability.value, 3), round(c.ratio.value, 3)
    (0.75, 0.707)
    """
    X, Y = _units(x, "x"), _units(y, "y")
    if X.shape[1:] != Y.shape[1:]:
        raise ValueError(
            f"x and y must cover the same (plants, episodes), got {X.shape[1:]} and {Y.shape[1:]}"
        )
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Y))):
        raise ValueError("costs must be finite for a paired comparison (charge divergences)")
    xs, ys = X[:, None], Y[None, :]  # (rx, 1, P, E) against (1, ry, P, E)
    wins = np.mean((xs < ys) + 0.5 * (xs == ys), axis=3)
    logs = np.mean(np.log(np.maximum(xs, COST_FLOOR) / np.maximum(ys, COST_FLOOR)), axis=3)
    p = _bootstrap_mean(wins, reps, confidence, seed)
    r = _bootstrap_mean(logs, reps, confidence, seed)
    return PairedComparison(Estimate(*p), Estimate(*(math.exp(v) for v in r)))


def _weighted_iqm_median(v: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """IQM and median of the sorted values ``v`` (n,) under weights ``w`` (reps, n): each value
    counted ``w`` times; the IQM is the mean of the middle half of the mass (a value that
    straddles a quartile counts with the part of its weight inside)."""
    c = np.cumsum(w, axis=1)
    total = c[:, -1:]
    lo, hi = 0.25 * total, 0.75 * total
    before = c - w
    inside = np.clip(np.minimum(c, hi) - np.maximum(before, lo), 0.0, None)
    # a sum, not a matrix product: BLAS kernels differ by CPU, and a committed run's
    # statistics must render to the same digits on any machine
    iqm = (inside * v).sum(axis=1) / (hi - lo)[:, 0]
    median = v[np.argmax(c >= 0.5 * total, axis=1)]
    return iqm, median


def bounded_estimates(
    values: ArrayLike, *, reps: int = 2000, confidence: float = 0.95, seed: int = 0
) -> dict[str, Any]:
    """IQM and median of per-(run, plant) values that exist only where an episode stayed
    bounded (``nan`` elsewhere), with intervals from a bootstrap over runs and plants.

    A cost ratio is no cost figure for an episode that diverged (its cost is the charge for
    leaving the bounds), so the bench reports the ratio over the bounded episodes and the
    divergence rate apart (:func:`rate_estimate`), never a statistic that mixes them.
    rliable's stratified bootstrap needs a value in every cell; here the runs and the plants
    are resampled independently and the statistics taken over the resampled cells that hold
    a value.

    Parameters
    ----------
    values : array_like, shape (runs, plants)
        ``nan`` where the run has no bounded episode of the plant.
    reps, confidence, seed
        Bootstrap replications, interval size and seed.

    Returns
    -------
    dict
        ``{"iqm": Estimate, "median": Estimate, "n": cells with a value}``; ``nan`` estimates
        when no cell has one.

    Examples
    --------
    >>> import numpy as np
    >>> from stcgym.agents.evaluation.statistics import bounded_estimates
    >>> est = bounded_estimates([[1.0, 2.0, np.nan, 4.0], [1.5, 2.5, 3.0, np.nan]], reps=200)
    >>> est["n"], round(est["median"].value, 2)
    (6, 2.0)
    """
    x = np.asarray(values, dtype=float)
    if x.ndim != 2 or 0 in x.shape:
        raise ValueError(f"values must have shape (runs, plants), got {x.shape}")
    ok = ~np.isnan(x)
    if not ok.any():
        nan = Estimate(math.nan, math.nan, math.nan)
        return {"iqm": nan, "median": nan, "n": 0}
    runs, plants = np.nonzero(ok)
    order = np.argsort(x[ok], kind="stable")
    v, runs, plants = x[ok][order], runs[order], plants[order]
    iqm, median = _weighted_iqm_median(v, np.ones((1, v.size)))
    rng = np.random.default_rng(seed)
    wr, wp = _counts(rng, reps, x.shape[0]), _counts(rng, reps, x.shape[1])
    w = wr[:, runs] * wp[:, plants]
    keep = w.sum(axis=1) > 0  # a draw of only all-diverged cells has no value: left out
    b_iqm, b_median = _weighted_iqm_median(v, w[keep])
    alpha = (1.0 - confidence) / 2.0
    q = [alpha, 1.0 - alpha]
    return {
        "iqm": Estimate(float(iqm[0]), *map(float, np.quantile(b_iqm, q))),
        "median": Estimate(float(median[0]), *map(float, np.quantile(b_median, q))),
        "n": int(v.size),
    }


def rate_estimate(
    flags: ArrayLike, *, reps: int = 2000, confidence: float = 0.95, seed: int = 0
) -> Estimate:
    """The share of flagged episodes (e.g. diverged) with a bootstrap interval.

    Parameters
    ----------
    flags : array_like of bool, shape (runs, plants, episodes) or (runs, plants)
        One flag per run and episode.
    reps, confidence, seed
        As :func:`paired_comparison`: runs and plants resampled independently.

    Returns
    -------
    Estimate
        The share over every run, plant and episode, and its percentile interval.

    Examples
    --------
    >>> from stcgym.agents.evaluation.statistics import rate_estimate
    >>> rate_estimate([[0, 0, 1, 0]], reps=200).value
    0.25
    """
    F = _units(flags, "flags")
    table = F.mean(axis=2)[:, None, :]  # (runs, 1, plants): one "run of Y"
    return Estimate(*_bootstrap_mean(table, reps, confidence, seed))


def summarize(values: Sequence[float], failed: Sequence[bool] | None = None) -> dict[str, float]:
    """Median, IQR, CVaR of the worst quarter, mean and failure rate of per-seed values.

    ``nan`` values (a column that does not apply) are dropped; ``inf`` counts as a very bad
    value (it makes the CVaR infinite, which is the honest worst case).

    Parameters
    ----------
    values : sequence of float
        One value per seed (lower is better).
    failed : sequence of bool, optional
        One flag per seed; gives ``failure_rate``.

    Returns
    -------
    dict of str to float
        ``n`` (values kept), ``median``, ``iqr``, ``cvar25`` (mean of the ``ceil(n/4)``
        largest), ``mean``, and ``failure_rate`` when ``failed`` is given; ``nan`` statistics
        when no value is left.

    Examples
    --------
    >>> from stcgym.agents import summarize
    >>> summarize([1.0, 2.0, 3.0, 10.0, float("nan")], [False, False, False, True, False])
    {'n': 4.0, 'median': 2.5, 'iqr': 3.0, 'cvar25': 10.0, 'mean': 4.0, 'failure_rate': 0.2}
    """
    x = np.asarray(values, dtype=float)
    x = x[~np.isnan(x)]
    out = {"n": float(x.size)}
    if x.size == 0:
        out.update(median=math.nan, iqr=math.nan, cvar25=math.nan, mean=math.nan)
    else:
        q25, med, q75 = (
            np.percentile(x, [25, 50, 75]) if np.all(np.isfinite(x)) else (_inf_percentiles(x))
        )
        worst = np.sort(x)[-max(1, math.ceil(x.size / 4)) :]
        out.update(
            median=float(med),
            iqr=float(q75 - q25) if np.isfinite(q75 - q25) else math.inf,
            cvar25=float(np.mean(worst)),
            mean=float(np.mean(x)),
        )
    if failed is not None:
        f = np.asarray(failed, dtype=bool)
        out["failure_rate"] = float(np.mean(f)) if f.size else math.nan
    return out


def _inf_percentiles(x: NDArray) -> tuple[float, float, float]:
    # np.percentile interpolates inf - inf into nan; order statistics are what we mean here.
    s = np.sort(x)
    idx = [min(len(s) - 1, int(round(q * (len(s) - 1)))) for q in (0.25, 0.5, 0.75)]
    return tuple(float(s[i]) for i in idx)  # type: ignore[return-value]
