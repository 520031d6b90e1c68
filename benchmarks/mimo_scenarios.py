"""The MIMO scenarios of ``stcgym bench`` without RL: LQR, zero input and ``stc_mimo``.

Usage::

    python benchmarks/mimo_scenarios.py [--episodes 10] [--first-seed 1000] [--family-plants 100]

Runs the standard tier's ``mimo:quadruple_tank``, ``mimo:quadruple_tank_nmp``, ``mimo_switch``,
``mimo_family:test`` and the full tier's ``mimo:he1`` (:mod:`stcgym.agents.benchmark.mimo`)
with the bench's own
controllers (``CONTROLLERS["lqg"]``, ``"zero"``, ``"stc_mimo"``) through
:func:`~stcgym.agents.evaluation.episodes.run_episodes`, on ``--episodes`` episodes from seed
``--first-seed`` (the bench's test seeds). Figures per scenario: mean cost per step of LQR and
zero input, LQR / zero input (how far the scenario is from floor-bound), ``stc_mimo`` / LQR
over the whole episode, its second half and last quarter, and ``bound`` / LQR and ``stc_mimo`` /
``bound``, with ``bound`` what identification costs at the least: the self-tuning controller's
own probe for the ``n + m`` samples without which no estimate of ``[A B]`` exists (open loop,
as any controller without a model must run), then LQR with the true gain (a controller that
identifies the model exactly from the fewest samples); for ``mimo_switch`` the ratio in
50-step windows (every 25 samples) after the switch and the samples after which every later
window is within 1.2x (the mean over the episodes). ``mimo_family:test`` runs one episode on
each of the first ``--family-plants`` test members (the bench's test episodes, seeds 1000 on)
and also prints the median over the members of each controller's ratio, for all of them and
per phase (``gamma1 + gamma2`` above or below 1). ``docs/multivariable.md`` quotes them.
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from stcgym.agents.benchmark import build_config, make_scenarios
from stcgym.agents.controllers import CONTROLLERS
from stcgym.agents.evaluation.episodes import EpisodeSet, run_episodes


class ProbeThenLQR:
    """The ``bound`` row: ``stc``'s probe for its first ``samples`` steps of an episode, then
    ``lqr`` (both are stepped every sample, so the probe is exactly the self-tuning
    controller's)."""

    def __init__(self, stc: Any, lqr: Any, samples: int) -> None:
        self.stc, self.lqr, self.samples, self.t = stc, lqr, samples, 0

    def predict(self, obs: Any, state: Any = None, episode_start: Any = None, deterministic=True):
        if episode_start is not None and np.all(episode_start):
            self.t = 0
        probe, _ = self.stc.predict(obs, state, episode_start, deterministic)
        u, _ = self.lqr.predict(obs, state, episode_start, deterministic)
        self.t += 1
        return (probe if self.t <= self.samples else u), None

    def set_model(self, *args: Any, **kwargs: Any) -> None:
        self.lqr.set_model(*args, **kwargs)

    def reset(self) -> None:
        self.t = 0
        self.stc.reset()
        self.lqr.reset()


WINDOW, STRIDE, TOLERANCE = 50, 25, 1.2


def reconverged(stc: np.ndarray, lqr: np.ndarray) -> tuple[list[float], int | None]:
    """Window ratios of the mean per-step costs after the switch and the first window start
    from which every later window is within :data:`TOLERANCE`."""
    starts = range(0, len(stc) - WINDOW + 1, STRIDE)
    ratios = [stc[i : i + WINDOW].mean() / lqr[i : i + WINDOW].mean() for i in starts]
    first = next(
        (j * STRIDE for j in range(len(ratios)) if all(r <= TOLERANCE for r in ratios[j:])), None
    )
    return ratios, first


def family_medians(eps: EpisodeSet, cost: dict[str, np.ndarray]) -> None:
    """Median over the members of zero input / LQR and ``stc_mimo`` / LQR (whole episode and
    second half), for all members and per phase."""
    from stcgym.envs.tank_family import TANK_FAMILY

    sums = np.array([sum(TANK_FAMILY.gamma(int(p.rsplit("/", 1)[1]))) for p in eps.plants])
    T = cost["lqg"].shape[1]
    lqr, half = cost["lqg"].mean(axis=1), cost["lqg"][:, T // 2 :].mean(axis=1)
    for label, rows in (
        ("all", sums > 0),
        ("minimum phase", sums > 1),
        ("nonminimum phase", sums < 1),
    ):
        zero = np.median(cost["zero"].mean(axis=1)[rows] / lqr[rows])
        stc = np.median(cost["stc_mimo"].mean(axis=1)[rows] / lqr[rows])
        stc_half = np.median(cost["stc_mimo"][rows, T // 2 :].mean(axis=1) / half[rows])
        print(
            f"  {label} ({int(rows.sum())} members): LQR {lqr[rows].mean():.4g} per step; "
            f"median zero / LQR {zero:.3g}, stc_mimo / LQR {stc:.3f} (second half "
            f"{stc_half:.3f})"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=1000)
    parser.add_argument("--family-plants", type=int, default=100)
    args = parser.parse_args()
    cfg = build_config(
        run="mimo-scenarios",
        mode="standard",
        scenarios="mimo,mimo_switch,mimo_family",
        mimo_plants="quadruple_tank,quadruple_tank_nmp,he1",
        agents="lqg,stc_mimo",
    )
    seeds = tuple(range(args.first_seed, args.first_seed + args.episodes))
    for sc in make_scenarios(cfg):
        if sc.env.family is None:
            eps = EpisodeSet((sc.env.plants[0],) * len(seeds), seeds)
        else:
            n = args.family_plants
            eps = EpisodeSet(sc.episodes.plants[:n], sc.episodes.seeds[:n])
        runs = {
            name: run_episodes(
                CONTROLLERS[name].build(cfg, sc), sc.env, eps, informed=CONTROLLERS[name].informed
            )
            for name in ("lqg", "zero", "stc_mimo")
        }
        n, m = sc.env.channels
        stc, lqr = CONTROLLERS["stc_mimo"].build(cfg, sc), CONTROLLERS["lqg"].build(cfg, sc)

        def bound(plants: list, lane_seeds: list, stc=stc, lqr=lqr, k=n + m) -> ProbeThenLQR:
            # built by run_episodes with each batch's own plants and seeds, as every row is
            return ProbeThenLQR(stc(plants, lane_seeds), lqr(plants, lane_seeds), k)

        runs["bound"] = run_episodes(bound, sc.env, eps, informed=True)
        cost = {name: batch.cost for name, batch in runs.items()}
        T = cost["lqg"].shape[1]
        lqr, stc = cost["lqg"], cost["stc_mimo"]
        diverged = int(runs["zero"].diverged.sum())
        print(
            f"{sc.name}: LQR {lqr.mean():.4g} per step, zero input {cost['zero'].mean():.4g} "
            f"({diverged} diverged), LQR / zero {lqr.mean() / cost['zero'].mean():.3f}; "
            f"stc_mimo / LQR: whole {stc.mean() / lqr.mean():.3f}, second half "
            f"{stc[:, T // 2 :].mean() / lqr[:, T // 2 :].mean():.3f}, last quarter "
            f"{stc[:, 3 * T // 4 :].mean() / lqr[:, 3 * T // 4 :].mean():.3f}; bound / LQR "
            f"{cost['bound'].mean() / lqr.mean():.3f}, stc_mimo / bound "
            f"{stc.mean() / cost['bound'].mean():.3f}"
        )
        if sc.env.family is not None:
            family_medians(eps, cost)
        if sc.env.switch_to is not None:
            J = int(sc.env.jump_step)
            ratios, first = reconverged(stc[:, J:].mean(axis=0), lqr[:, J:].mean(axis=0))
            print(f"  after the switch at {J}: windows {np.round(ratios, 2).tolist()}")
            print(f"  within {TOLERANCE}x of LQR from {first} samples after the switch on")


if __name__ == "__main__":
    main()
