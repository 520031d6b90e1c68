"""The scenarios of ``stcgym bench`` and the RL training environments they use.

Every SISO scenario draws its episodes the same way: the benchmark family's episode settings
(output noise, a random-steps reference, a random initial state, its control cost and
divergence bound), and one action bound for every controller, set from the LQG yardstick's
input range on the training distribution (:func:`stcgym.agents.evaluation.bounds.
lqg_action_bound`).

``nominal:P``
    The catalogue plant ``P``; RL agents train on ``P`` itself.
``family:test``
    The test split of the plant family (``BenchConfig.family``, e.g. ``siso2-v1``); RL agents
    train on its training split, with parameter jumps at random times in a share of the
    episodes (the family's ``jump.probability``), and their learning curves and plateau rule
    read the validation split. Without jumps.
``family:<variant>``
    A named out-of-distribution split of the family (``ood_*``): plants none of the
    controllers was tuned or trained on (another order, unstable poles further out, ...). The
    self-tuning controllers keep the training distribution's order.
``jump:test``
    The test split with the parameter jump in every episode, at a random time.
``<rung>:test``
    The test split of a rung of the difficulty ladder (``BenchConfig.ladder``, e.g.
    ``ladder-l1-v1``: :data:`~stcgym.envs.families.LADDER`), under the rung's own action
    bound; the RL agents of ``BenchConfig.ladder_agents`` train on the rung's training split
    (training key ``family:<rung>``), the classical controllers run as on the family.
``mimo:P``
    The MIMO catalogue plant ``P`` with measured state and the cost of its performance output
    (:mod:`stcgym.agents.benchmark.mimo`).
``mimo_switch``
    The quadruple tank whose valves switch from ``P-`` to ``P+`` half-way through the episode.
``mimo_family:test``
    The test split of the quadruple tanks drawn from their valve settings
    (:data:`~stcgym.envs.tank_family.TANK_FAMILY`); RL agents train on its training split and
    their learning curves read the validation split.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from stcgym.agents.benchmark.config import is_family_key
from stcgym.agents.evaluation.bounds import BOUND_SEED
from stcgym.agents.evaluation.env_spec import EnvSpec
from stcgym.agents.evaluation.episodes import EpisodeSet
from stcgym.agents.evaluation.scenario import Scenario

if TYPE_CHECKING:
    from stcgym.agents.benchmark.config import BenchConfig

__all__ = [
    "CURVE_SEED",
    "Scenario",
    "TrainingEnv",
    "family_train_spec",
    "make_scenarios",
    "nominal_spec",
    "training_envs",
]

#: First seed of the learning-curve (validation) episodes: apart from the test episodes'
#: (``BenchConfig.first_seed``) and the bound episodes'
#: (:data:`~stcgym.agents.evaluation.bounds.BOUND_SEED`).
CURVE_SEED = 10_000


@dataclass(frozen=True)
class TrainingEnv:
    """Where the RL agents of one training key train, and the episodes their learning curves
    (validation) and the action bound (training distribution) are measured on."""

    key: str
    train: EnvSpec
    curve: EnvSpec
    curve_episodes: EpisodeSet
    bound_episodes: EpisodeSet

    @property
    def curve_scenario(self) -> Scenario:
        """The learning-curve (validation) episodes as a scenario, for building a controller
        on them (the yardstick that scores the curve)."""
        return Scenario(
            name=f"{self.key}:curve",
            kind="curve",
            env=self.curve,
            episodes=self.curve_episodes,
            train_key=self.key,
            controller_order=self.curve.order,
        )


def _episode_settings(cfg: BenchConfig, family: str | None = None) -> dict[str, Any]:
    """The episode settings of ``family`` (default: the bench's family, whose settings every
    other SISO scenario shares), with the ``BenchConfig`` overrides."""
    from stcgym.envs.families import get_family

    fam = get_family(family or cfg.family)
    return dict(
        steps=cfg.episode_steps or fam.steps,
        noise_std=fam["noise_std"] if cfg.noise_std is None else cfg.noise_std,
        control_cost=fam["control_cost"],
        y_bound=fam["y_bound"],
        reference=fam["reference"],
        initial_state_std=fam["initial_state_std"],
    )


def _bound(cfg: BenchConfig, key: str) -> float:
    # before the bounds are measured (validation, plans) the family's own bound stands in
    return float(cfg.action_bounds.get(key, 10.0))


def nominal_spec(cfg: BenchConfig, plant: str) -> EnvSpec:
    """The environment of ``nominal:<plant>``: the catalogue plant, the family's episodes."""
    return EnvSpec((plant,), action_bound=_bound(cfg, f"nominal:{plant}"), **_episode_settings(cfg))


def family_spec(
    cfg: BenchConfig, split: str, jump_probability: float | None, rung: str | None = None
) -> EnvSpec:
    """The family split ``split`` with the bench's episode settings and the family's bound:
    of the bench's family, or of the ladder's ``rung`` (under its own bound)."""
    return EnvSpec(
        family=rung or cfg.family,
        split=split,
        jump_probability=jump_probability,
        action_bound=_bound(cfg, "family" if rung is None else f"family:{rung}"),
        **_episode_settings(cfg, rung),
    )


def family_train_spec(cfg: BenchConfig, rung: str | None = None) -> EnvSpec:
    """The RL agents' training distribution: the training split, the family's own jumps."""
    return family_spec(cfg, "train", None, rung)


def make_scenarios(cfg: BenchConfig) -> list[Scenario]:
    """The scenarios of ``cfg`` in report order (see the module docstring)."""
    from stcgym.envs.catalogue import get_plant

    out: list[Scenario] = []
    first = cfg.first_seed
    if "nominal" in cfg.scenarios:
        for p in cfg.plants:
            env = nominal_spec(cfg, p)
            eps = EpisodeSet(
                (p,) * cfg.nominal_episodes, tuple(range(first, first + cfg.nominal_episodes))
            )
            out.append(
                Scenario(f"nominal:{p}", "nominal", env, eps, f"nominal:{p}", get_plant(p).n)
            )
    if {"family", "ood", "jump"} & set(cfg.scenarios):
        order = family_spec(cfg, "train", None).order

        def split_scenario(name: str, kind: str, split: str, p_jump: float, **kw: Any) -> Scenario:
            env = family_spec(cfg, split, p_jump)
            eps = EpisodeSet.of(env, cfg.episodes_per_plant, first, cfg.test_plants)
            return Scenario(name, kind, env, eps, "family", order, **kw)

        if "family" in cfg.scenarios:
            out.append(split_scenario("family:test", "family", "test", 0.0, adaptation=True))
        if "ood" in cfg.scenarios:
            for variant in cfg.ood:
                out.append(
                    split_scenario(f"family:{variant}", "ood", variant, 0.0, in_distribution=False)
                )
        if "jump" in cfg.scenarios:
            out.append(split_scenario("jump:test", "jump", "test", 1.0, adaptation=True))
    if "ladder" in cfg.scenarios:
        for rung in cfg.ladder:
            env = family_spec(cfg, "test", 0.0, rung)
            eps = EpisodeSet.of(env, cfg.episodes_per_plant, first, cfg.test_plants)
            out.append(Scenario(f"{rung}:test", "ladder", env, eps, f"family:{rung}", env.order))
    if {"mimo", "mimo_switch", "mimo_family"} & set(cfg.scenarios):
        from stcgym.agents.benchmark.mimo import mimo_scenarios

        out += mimo_scenarios(cfg)
    return out


def training_envs(cfg: BenchConfig, scenarios: Sequence[Scenario]) -> dict[str, TrainingEnv]:
    """``train_key -> TrainingEnv`` for every key a scenario uses (and so RL, the action bound
    and the learning curves): ``"nominal:<plant>"``, ``"family"``, ``"family:<rung>"``,
    ``"mimo:<plant>"``,
    ``"mimo_switch"`` or ``"mimo_family"``.

    Training episodes are evaluation episodes: the same length, noise, reference, initial
    state, jumps and bound; a family (the SISO one, the quadruple tanks) trains on its training
    split (jumps with the family's probability) and is validated on its validation split,
    drawn the same way.
    """
    keys = dict.fromkeys(sc.train_key for sc in scenarios)
    out: dict[str, TrainingEnv] = {}
    n = cfg.curve_episodes
    for key in keys:
        if is_family_key(key) or key == "mimo_family":
            if is_family_key(key):
                rung = key.split(":", 1)[1] if ":" in key else None
                train = family_train_spec(cfg, rung)
                curve = family_spec(cfg, "validation", None, rung)
            else:
                from stcgym.agents.benchmark.mimo import tank_family_spec

                train, curve = tank_family_spec(cfg, "train"), tank_family_spec(cfg, "validation")
            curve_eps = EpisodeSet.of(curve, 1, CURVE_SEED, n)
            bound_eps = EpisodeSet.of(train, 1, BOUND_SEED, cfg.bound_plants)
        else:
            train = next(sc.env for sc in scenarios if sc.train_key == key)
            curve = train
            name = train.plants[0]
            curve_eps = EpisodeSet((name,) * n, tuple(range(CURVE_SEED, CURVE_SEED + n)))
            m = cfg.bound_plants
            bound_eps = EpisodeSet((name,) * m, tuple(range(BOUND_SEED, BOUND_SEED + m)))
        out[key] = TrainingEnv(key, train, curve, curve_eps, bound_eps)
    return out
