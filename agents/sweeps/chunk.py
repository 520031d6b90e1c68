"""One task of a sweep: its lanes in closed loop for every controller, and their table rows.

Lane ``k`` is plant ``k // S`` with seed ``seeds[k % S]`` (``S`` seeds); the lanes of a task
run together on the native vector env with the batched controller (:func:`closed_loop`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.agents.closed_loop import LoopResult, run_closed_loop
from stcgym.envs.families import FamilySpec, Plant, draw_plant, plant_features
from stcgym.envs.signals import NEVER, Schedule

__all__ = [
    "CONTROLLER_KINDS",
    "RECONVERGE_TOL",
    "LaneJumps",
    "closed_loop",
    "make_controller",
    "simulate_chunk",
]

CONTROLLER_KINDS: tuple[str, ...] = ("stc", "oracle", "lqg")
#: A window counts as adapted / re-converged when its cost is within this factor of the oracle's.
RECONVERGE_TOL = 1.2
ENV_ID = "stcgym/ObserverCanonical-v0"


def make_controller(
    kw: Mapping[str, Any], family: FamilySpec, plants: Sequence[Plant], *, batched: bool = True
) -> Any:
    """The batched controller of ``kw`` for the lanes ``plants`` (the oracles get each lane's
    true parameters); ``batched=False``: one controller on ``plants[0]``, to check keywords."""
    from stcgym.adaptive import (
        KnownModelController,
        LawOptions,
        LQGController,
        SelfTuningController,
    )
    from stcgym.adaptive.control.options import cost_weights

    opts = {k: v for k, v in kw.items() if k != "kind"}
    opts.setdefault("action_bound", family["action_bound"])
    lanes: dict[str, Any] = {"num_envs": len(plants)} if batched else {}
    if kw["kind"] == "stc":
        return SelfTuningController(family.order, **lanes, **opts)
    a = np.array([p.a for p in plants]) if batched else plants[0].a
    b = np.array([p.b for p in plants]) if batched else plants[0].b
    if kw["kind"] == "oracle":
        return KnownModelController(a, b, **lanes, **opts)
    # as in stcgym bench: no integral action, the family's cost as the LQ weights
    if not isinstance(opts.get("law"), LawOptions):
        law = dict(opts.get("law") or {})
        law.setdefault("integral", False)
        law.setdefault("lq_weights", cost_weights(family["control_cost"] or 1e-6))
        opts["law"] = law
    if family["noise_std"] <= 0 and "noise_std" not in opts:
        raise ValueError("the lqg oracle needs noise_std > 0 in the family (its Kalman filter)")
    opts.setdefault("noise_std", family["noise_std"])
    return LQGController(a, b, **lanes, **opts)


class LaneJumps(Schedule):
    """Per-lane parameter jump: from step ``step`` on, lane ``i`` has the parameters
    ``after[i]`` (shape ``(B, 2n)``; a :class:`~stcgym.envs.signals.Schedule` for a vector env
    of ``B`` lanes, or for one env with ``after`` of one row)."""

    def __init__(self, step: int, after: ArrayLike) -> None:
        self.step, self.after = int(step), np.asarray(after, dtype=float)

    def values(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        lanes = np.arange(self.num_lanes) if lanes is None else np.asarray(lanes)
        out = self._nominal[lanes].copy()
        jumped = np.asarray(k) >= self.step
        out[jumped] = self.after[lanes[jumped]]
        return out

    def next_change(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        return np.where(np.asarray(k) < self.step, self.step, NEVER).astype(np.int64)


def _vector_env(family: FamilySpec, plants: Sequence[Plant]) -> Any:
    """The native vector env of ``plants``: per-lane ``a``, ``b`` and the family's jump or drift."""
    import gymnasium as gym

    import stcgym.envs  # noqa: F401  (registers the ids)
    from stcgym.envs.signals import RandomWalk

    kwargs: dict[str, Any] = dict(
        num_envs=len(plants),
        a=np.array([p.a for p in plants]),
        b=np.array([p.b for p in plants]),
        **family.env_settings,
        info_keys=(),
    )
    if family.jump_step is not None:
        after = np.array([np.concatenate((p.a_after, p.b_after)) for p in plants])
        kwargs["schedule"] = LaneJumps(family.jump_step, after)
    elif family["drift"] is not None and family["drift"]["std"] > 0:
        kwargs["schedule"] = RandomWalk(family["drift"]["std"])
    return gym.make_vec(ENV_ID, **kwargs).unwrapped


def closed_loop(
    kw: Mapping[str, Any], family: FamilySpec, plants: Sequence[Plant], lane_seeds: Sequence[int]
) -> LoopResult:
    """Run controller ``kw`` on lanes ``plants`` (noise seeds ``lane_seeds``) for one episode.

    The public route: the native vector env (per-lane ``a``, ``b``, the family's jump as a
    per-lane schedule, reset with one seed per lane) and the batched controller
    (``num_envs=B``), driven by :func:`~stcgym.agents.closed_loop.run_closed_loop` (the compiled
    rollout for the self-tuning controller; costs under its divergence rule). Lane ``i`` is the
    single env with the same plant and schedule reset with ``seed=lane_seeds[i]``, driven by
    the single controller. The oracle is told the new parameters at the jump (under drift:
    every step).
    """
    J = family.jump_step
    ctl = make_controller(kw, family, plants)
    env = _vector_env(family, plants)
    obs, _ = env.reset(seed=[int(s) for s in lane_seeds])
    before_step = None
    if kw["kind"] == "oracle":
        drift = family["drift"] is not None and family["drift"]["std"] > 0

        def before_step(k: int) -> None:
            if k == J:
                ctl.set_model(np.array([p.a_after for p in plants]), [p.b_after for p in plants])
            elif drift and k > 0:
                _tell_oracles(ctl, env.params)

    result = run_closed_loop(ctl, env, obs, family.steps, before_step=before_step)
    env.close()
    return result


def _tell_oracles(ctl: Any, params: NDArray) -> None:
    """Under drift the oracle knows the parameters in force; a lane whose drifted model cannot
    be designed on keeps its last one (``set_model`` changes nothing when it raises)."""
    n = ctl.n
    try:
        ctl.set_model(params[:, :n], params[:, n:])
    except ValueError:
        for i, th in enumerate(params):
            try:
                ctl.set_model(th[:n], th[n:], lanes=[i])
            except ValueError:
                pass


def _lane_seed(*entropy: int) -> int:
    """A 32-bit env seed from ``SeedSequence(entropy)``."""
    return int(np.random.SeedSequence(list(entropy)).generate_state(1)[0])


def simulate_chunk(task: Mapping[str, Any]) -> dict[str, list]:
    """The task function: the table rows of lanes ``task["lanes"]``, column-wise compact:
    ``{"columns": names, "rows": [values, ...]}`` (JSON data, about half the size of dicts)."""
    family = FamilySpec.from_dict(task["family"])
    seeds = list(task["seeds"])
    lanes = range(*task["lanes"])
    S = len(seeds)
    pairs = [(k // S, seeds[k % S]) for k in lanes]
    plants_by_index = {i: draw_plant(family, i) for i in sorted({i for i, _ in pairs})}
    plants = [plants_by_index[i] for i, _ in pairs]
    lane_seeds = [_lane_seed(family["seed"], i, sd) for i, sd in pairs]
    results = {
        name: closed_loop(kw, family, plants, lane_seeds)
        for name, kw in task["controllers"].items()
    }
    rows = _rows(family, task["controllers"], pairs, plants, results)
    columns = list(rows[0]) if rows else []
    return {"columns": columns, "rows": [list(r.values()) for r in rows]}


def _rows(
    family: FamilySpec,
    controllers: Mapping[str, Mapping[str, Any]],
    pairs: list[tuple[int, int]],
    plants: list[Plant],
    results: Mapping[str, LoopResult],
) -> list[dict[str, Any]]:
    from stcgym.agents.evaluation.evaluate import default_windows

    T, J = family.steps, family.jump_step
    win = default_windows(T, J)
    oracle = results["oracle"]
    o_cost = oracle.cost.mean(axis=1)
    o_steady = _window(oracle.cost, win.steady)
    rows = []
    for lane, ((index, seed), plant) in enumerate(zip(pairs, plants, strict=True)):
        base: dict[str, Any] = {"family": family["name"], "plant": index, "seed": seed}
        base.update(plant_features(plant))
        base.update({f"a{j + 1}": float(v) for j, v in enumerate(plant.a)})
        base.update({f"b{j + 1}": float(v) for j, v in enumerate(plant.b)})
        for name, res in results.items():
            c = res.cost[lane]
            row = dict(base, controller=name, kind=controllers[name]["kind"])
            row.update(
                bounded=int(not res.diverged[lane]),
                steps_run=int(res.steps_run[lane]),
                cost=float(c.mean()),
                cost_start=float(c[slice(*win.start)].mean()),
                cost_steady=float(c[slice(*win.steady)].mean()),
                cost_post_jump=math.nan,
                reconverge_steps=math.nan,
            )
            row["ratio"] = _ratio(row["cost"], o_cost[lane])
            row["steady_ratio"] = _ratio(row["cost_steady"], o_steady[lane])
            row["adapt_steps"] = (
                math.inf
                if res.diverged[lane]
                else _settling(c, oracle.cost[lane], family, 0, J or T)
            )
            if J is not None:
                row["cost_post_jump"] = float(c[slice(*win.post_jump)].mean())
                row["reconverge_steps"] = (
                    math.inf
                    if res.diverged[lane]
                    else _settling(c, oracle.cost[lane], family, J, T)
                )
            rows.append(row)
    return rows


def _window(cost: NDArray, window: tuple[int, int]) -> NDArray:
    return cost[:, window[0] : window[1]].mean(axis=1)


def _ratio(x: float, ref: float) -> float:
    return float(x / ref) if ref > 0 else math.inf


def _settling(cost: NDArray, oracle: NDArray, family: FamilySpec, start: int, stop: int) -> float:
    from stcgym.agents.evaluation.response import settling_step

    return settling_step(
        cost, oracle, span=family.period, start=start, stop=stop, tol=RECONVERGE_TOL
    )
