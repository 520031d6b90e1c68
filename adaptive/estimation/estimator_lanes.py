"""The estimator's batch loops and its ``T``-step loop, on the lane functions of :mod:`.estimator`.

``update_lanes(s, w, cfg, y, status)`` and ``predict_lanes(s, w, cfg, u, status)`` run
``estimator_update`` / ``estimator_predict`` on every lane of the state ``s`` and scratch ``w``
(blocks of lanes on threads for a large batch); ``run_lane(s, w, lane_i, cfg, u, y, thetas, status,
stop_mask)`` runs ``T`` steps of lane ``lane_i`` in one compiled call. All three may slide a finite
history window (``windowed=True``).
"""

from __future__ import annotations

from numpy.typing import NDArray

from stcgym.adaptive.estimation.estimator import estimator_predict, estimator_update
from stcgym.adaptive.estimation.estimator_spec import EstimatorConfig, EstimatorState, EstimatorWork
from stcgym.lanes.compiled import lane, lanes
from stcgym.lanes.linalg import copy_vector

__all__ = ["predict_lanes", "run_lane", "update_lanes"]


@lanes
def update_lanes(
    s: EstimatorState,
    w: EstimatorWork,
    cfg: EstimatorConfig,
    y: NDArray,
    status: NDArray,
    first: int,
    last: int,
) -> None:
    """``estimator_update`` on every lane."""
    for i in range(first, last):
        status[i] = estimator_update(s, w, i, cfg, y[i], True)


@lanes
def predict_lanes(
    s: EstimatorState,
    w: EstimatorWork,
    cfg: EstimatorConfig,
    u: NDArray,
    status: NDArray,
    first: int,
    last: int,
) -> None:
    """``estimator_predict`` on every lane."""
    for i in range(first, last):
        status[i] = estimator_predict(s, w, i, cfg, u[i])


@lane(entry=True)
def run_lane(
    s: EstimatorState,
    w: EstimatorWork,
    lane_i: int,
    cfg: EstimatorConfig,
    u: NDArray,
    y: NDArray,
    thetas: NDArray,
    status: NDArray,
    stop_mask: int,
) -> int:
    """``T`` steps ``update(y[k])``, ``predict(u[k])`` of lane ``lane_i``; ``thetas[k] = theta_hat``
    after the update, ``status[k]`` the events of step ``k``. Stops after the first step whose
    status has a bit of ``stop_mask``; returns the number of steps done."""
    theta = s.theta[lane_i]
    for k in range(u.shape[0]):
        st = estimator_update(s, w, lane_i, cfg, y[k], True)
        copy_vector(theta, thetas[k])
        if st & stop_mask:
            status[k] = st
            return k + 1
        st |= estimator_predict(s, w, lane_i, cfg, u[k])
        status[k] = st
        if st & stop_mask:
            return k + 1
    return u.shape[0]
