"""How fast a controller gets good and how it answers a reference step.

Cost-based settling (the headline metrics of ``stcgym bench``) compares a controller's per-step
cost ``c(k)`` with a reference controller's cost ``c_ref(k)`` *on the same episode* (same seed,
noise and reference; the reference is the known-model oracle). Over forward windows of
``span`` steps (one reference period, so that every window holds the same reference steps and
the ratio is not a ratio of two noise floors)::

    ratio(k) = sum(c[k : k + span]) / sum(c_ref[k : k + span])

:func:`settling_step` is the first ``k >= start`` from which on *every* window inside
``[start, stop)`` has ``ratio <= tol``, counted from ``start``:

* ``0`` when the controller is within ``tol`` from the start (nothing to recover from);
* ``inf`` when the last window is still above ``tol``: a controller that never recovers can
  never read ``0`` (it does not depend on the controller's own final level);
* otherwise the number of steps after which it stays within ``tol``.

With ``start = 0`` it is the adaptation time (data an online learner needs to get within
``tol`` of the oracle); with ``start`` = the jump step it is the re-convergence time after a
parameter jump, against the oracle that is told the new parameters. :func:`curve_settling_step`
is the same rule on a learning curve (RL agents: training steps).

:func:`step_response` gives the control engineer's figures for the reference steps of a
square wave: overshoot (% of the step) and settling time (steps until the output stays within a
band of +-5 % of the step around the new reference).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["curve_settling_step", "settling_step", "step_response"]


def settling_step(
    cost: ArrayLike,
    reference: ArrayLike,
    *,
    span: int,
    start: int = 0,
    stop: int | None = None,
    tol: float = 1.2,
) -> float:
    """Steps after ``start`` from which every ``span``-window cost ratio stays ``<= tol``.

    Parameters
    ----------
    cost, reference
        Per-step costs of the controller and of the reference controller on the same episode.
    span
        Window length (clipped to ``stop - start``).
    start, stop
        The part of the episode that is scored (default: all of it).
    tol
        Allowed ratio to the reference cost.

    Returns
    -------
    float
        ``0.0`` if every window is within ``tol``, ``inf`` if the last one is not, else the
        settling step counted from ``start`` (see the module docstring).
    """
    c = np.asarray(cost, dtype=float)
    ref = np.asarray(reference, dtype=float)
    if c.shape != ref.shape or c.ndim != 1:
        raise ValueError(
            f"cost and reference must be 1-D of one length, got {c.shape}, {ref.shape}"
        )
    stop = len(c) if stop is None else int(stop)
    start = int(start)
    if not 0 <= start < stop <= len(c):
        raise ValueError(f"need 0 <= start < stop <= {len(c)}, got start={start}, stop={stop}")
    if not tol > 0:
        raise ValueError(f"tol must be positive, got {tol}")
    span = max(1, min(int(span), stop - start))
    if not np.all(np.isfinite(c[start:stop])):
        return math.inf
    cs = np.concatenate(([0.0], np.cumsum(c[start:stop])))
    rs = np.concatenate(([0.0], np.cumsum(ref[start:stop])))
    num, den = cs[span:] - cs[:-span], rs[span:] - rs[:-span]
    # A window the reference finishes at zero cost: within tol only if this one does too.
    above = np.where(den > 0, num > tol * den, num > 0)
    if not above.any():
        return 0.0
    last = int(np.nonzero(above)[0][-1])
    return math.inf if last == len(above) - 1 else float(last + 1)


def curve_settling_step(
    curve: Sequence[tuple[float, float]], reference: float, tol: float = 1.2
) -> float:
    """First curve step (e.g. training steps) from which on every cost is ``<= tol * reference``.

    ``curve`` is a list of ``(step, cost)`` in step order; ``inf`` when the last point is above.
    """
    if not curve:
        return math.nan
    steps = [float(s) for s, _ in curve]
    ok = [math.isfinite(c) and c <= tol * reference for _, c in curve]
    if not ok[-1]:
        return math.inf
    i = len(ok) - 1
    while i > 0 and ok[i - 1]:
        i -= 1
    return steps[i]


def _edges(r: np.ndarray, lo: int, hi: int) -> list[int]:
    prev = np.concatenate(([0.0], r[:-1]))  # every signal is zero before the first step
    return [int(k) for k in np.nonzero(r != prev)[0] if lo <= k < hi]


def step_response(
    y: ArrayLike, r: ArrayLike, *, start: int = 0, stop: int | None = None, band: float = 0.05
) -> dict[str, float]:
    """Overshoot and settling time at the reference steps inside ``[start, stop)``.

    Each reference change at step ``k`` (a step of size ``d``) is scored on ``y`` until the next
    change: overshoot ``= max(0, max(sign(d) (y - r_new))) / |d|`` in %, settling = steps after
    ``k`` until ``|y - r_new| <= band |d|`` holds for good (``inf`` if never). Returns the
    medians over the steps, and ``n_steps`` (``nan`` figures when there is none).
    """
    y = np.asarray(y, dtype=float)
    r = np.asarray(r, dtype=float)
    stop = len(r) if stop is None else int(stop)
    edges = _edges(r, int(start), stop)
    if not edges:
        return {"overshoot_pct": math.nan, "settling_steps": math.nan, "n_steps": 0.0}
    bounds = [*edges[1:], stop]
    over, settle = [], []
    for k, k2 in zip(edges, bounds, strict=True):
        d = r[k] - (r[k - 1] if k > 0 else 0.0)
        seg = y[k:k2]
        if seg.size == 0 or not np.all(np.isfinite(seg)):
            over.append(math.inf)
            settle.append(math.inf)
            continue
        err = seg - r[k]
        over.append(100.0 * max(0.0, float(np.max(np.sign(d) * err))) / abs(d))
        outside = np.nonzero(np.abs(err) > band * abs(d))[0]
        if outside.size and outside[-1] == seg.size - 1:
            settle.append(math.inf)
        else:
            settle.append(float(outside[-1] + 1) if outside.size else 0.0)
    return {
        "overshoot_pct": _median(over),
        "settling_steps": _median(settle),
        "n_steps": float(len(edges)),
    }


def _median(values: list[float]) -> float:
    # Order statistic, so that inf (never settled) counts as the worst value, not as nan.
    s = sorted(values)
    return float(s[(len(s) - 1) // 2])
