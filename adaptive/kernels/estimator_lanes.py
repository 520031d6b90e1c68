"""The estimator's batch loops and its ``T``-step loop, on the lane functions of :mod:`.estimator`.

``update_lanes(R, at, cfg, y, status)`` and ``predict_lanes(R, at, cfg, u, status)`` run
``estimator_update`` / ``estimator_predict`` over the rows of a ``(B, size)`` record (blocks of rows
on threads for a large batch); ``run_lane(rec, at, cfg, u, y, thetas, status, stop_mask)`` runs
``T`` steps of one lane in one compiled call. All three may slide a finite history window
(``windowed=True``).
"""

from __future__ import annotations

from numpy.typing import NDArray

from stcgym.adaptive.kernels.estimator import estimator_predict, estimator_update
from stcgym.adaptive.kernels.estimator_spec import EstimatorConfig, EstimatorRecord
from stcgym.envs.compiled import lane, lanes

__all__ = ["predict_lanes", "run_lane", "update_lanes"]


@lanes
def update_lanes(
    R: NDArray,
    at: EstimatorRecord,
    cfg: EstimatorConfig,
    y: NDArray,
    status: NDArray,
    first: int,
    last: int,
) -> None:
    """``estimator_update`` on every row of ``R`` (one lane per row)."""
    for i in range(first, last):
        status[i] = estimator_update(R[i], at, cfg, y[i], True)


@lanes
def predict_lanes(
    R: NDArray,
    at: EstimatorRecord,
    cfg: EstimatorConfig,
    u: NDArray,
    status: NDArray,
    first: int,
    last: int,
) -> None:
    """``estimator_predict`` on every row of ``R``."""
    for i in range(first, last):
        status[i] = estimator_predict(R[i], at, cfg, u[i])


@lane(entry=True)
def run_lane(
    rec: NDArray,
    at: EstimatorRecord,
    cfg: EstimatorConfig,
    u: NDArray,
    y: NDArray,
    thetas: NDArray,
    status: NDArray,
    stop_mask: int,
) -> int:
    """``T`` steps ``update(y[k])``, ``predict(u[k])`` of one lane; ``thetas[k] = theta_hat``
    after the update, ``status[k]`` the events of step ``k``. Stops after the first step whose
    status has a bit of ``stop_mask``; returns the number of steps done."""
    d = 2 * cfg.n
    for k in range(u.shape[0]):
        st = estimator_update(rec, at, cfg, y[k], True)
        for i in range(d):
            thetas[k, i] = rec[at.theta + i]
        if st & stop_mask:
            status[k] = st
            return k + 1
        st |= estimator_predict(rec, at, cfg, u[k])
        status[k] = st
        if st & stop_mask:
            return k + 1
    return u.shape[0]
