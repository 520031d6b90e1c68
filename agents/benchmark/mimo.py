"""The ``mimo`` scenarios of ``stcgym bench``: multi-input plants posed as their literature
poses them (the environments and yardsticks: :mod:`stcgym.agents.evaluation.mimo`).

Each plant of ``--mimo-plants`` (the MIMO catalogue, :data:`stcgym.envs.MIMO_PLANTS`) is one
scenario ``mimo:<plant>`` on ``stcgym/StateSpace-v0`` with ``cost="performance"``, in its
formulation (:func:`~stcgym.agents.evaluation.mimo.formulation`), the inputs clipped to the
plant's physical range as well as to the bench's action bound
(:mod:`stcgym.agents.evaluation.bounds`).

``mimo_switch`` is the quadruple tank whose valves switch from ``P-`` to ``P+`` half-way
through the episode (the linearised model jumps from ``quadruple_tank`` to
``quadruple_tank_nmp``; the deviation variables are kept): the known-model yardstick is told
the new model at the switch, the self-tuning controller must re-identify it, and the RL
agents train on episodes with the switch. ``mimo_family:test`` is the test split of the
quadruple tanks drawn from their valve settings.

The controllers that declare ``"mimo"`` among their plants
(:class:`~stcgym.agents.controllers.ControllerInfo`) run there: the multivariable self-tuning
LQ controller (``stc_mimo``) and the yardstick ``lqg``, the LQR on the true ``(A, B)``
(:class:`~stcgym.agents.evaluation.mimo.InformedLQR`), both weighted by the scenario's cost
(``Q = C_z' C_z``, ``R = D_z' D_z + control_cost I``, ``N = C_z' D_z``; tracking ``r_x`` with
``Q`` tracks ``r``); the window RL agents train on the scenario's own episodes and observe the
same ``[x, r_x]``. The SISO-only controllers and the recurrent agents (trained on the SISO
family) are left out.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from stcgym.agents.evaluation.mimo import (
    CONTROLGYM_SETTINGS,
    SWITCH,
    TANK_REFERENCE,
    MimoEnvSpec,
    formulation,
)
from stcgym.envs.mimo_plants import get_mimo_plant, mimo_plant_names

if TYPE_CHECKING:
    from stcgym.agents.benchmark.config import BenchConfig
    from stcgym.agents.benchmark.scenarios import Scenario

__all__ = [
    "check_mimo_plants",
    "has_yardstick",
    "mimo_scenarios",
    "mimo_spec",
    "tank_family_spec",
]


def check_mimo_plants(names: list[str], *, yardstick: bool = True) -> None:
    """Raise ``ValueError`` naming ``--mimo-plants`` for names outside the MIMO catalogue or
    listed twice, and (``yardstick``) for a plant without an LQ yardstick: that check solves a
    Riccati equation with the compiled solver, so a caller validating many options runs it
    last, and only when a MIMO scenario will run."""
    bad = [p for p in names if p not in mimo_plant_names()]
    if bad:
        raise ValueError(
            f"unknown MIMO plant(s) {bad} in --mimo-plants; MIMO catalogue: {mimo_plant_names()}"
        )
    if len(set(names)) != len(names):
        raise ValueError(f"--mimo-plants lists a plant twice: {names}")
    if not yardstick:
        return
    bad = [p for p in names if not has_yardstick(p)]
    if bad:
        raise ValueError(
            f"--mimo-plants: {bad} have no stabilising LQ solution for their cost, so no "
            "yardstick (ac1: controlgym's cost leaves its integrator state unweighted)"
        )


def has_yardstick(plant: str) -> bool:
    """Whether the LQR yardstick exists for ``plant``'s cost in its formulation.

    Examples
    --------
    >>> from stcgym.agents.benchmark.mimo import has_yardstick
    >>> has_yardstick("he1"), has_yardstick("ac1")
    (True, False)
    """
    from stcgym.adaptive.multivariable.lqr import lqr_design

    spec = get_mimo_plant(plant)
    rho = 0.0 if formulation(plant) == "controlgym" else 0.01
    try:
        lqr_design(*spec.discrete(), *spec.lq_weights(rho))
    except ValueError:
        return False
    return True


def mimo_spec(cfg: BenchConfig, plant: str, key: str | None = None) -> MimoEnvSpec:
    """The environment of ``mimo:<plant>`` in its formulation (:func:`formulation`); ``key``
    names the scenario whose action bound applies (default ``mimo:<plant>``)."""
    from stcgym.agents.benchmark.scenarios import _episode_settings

    bound = float(cfg.action_bounds.get(key or f"mimo:{plant}", 10.0))
    if formulation(plant) == "controlgym":
        settings = dict(CONTROLGYM_SETTINGS)
        if cfg.episode_steps:
            settings["steps"] = cfg.episode_steps
        return MimoEnvSpec((plant,), action_bound=bound, **settings)
    bench = _episode_settings(cfg)
    return MimoEnvSpec(
        (plant,),
        steps=bench["steps"],
        noise_std=bench["noise_std"],
        control_cost=bench["control_cost"],
        action_bound=bound,
        reference=TANK_REFERENCE,
    )


def tank_family_spec(cfg: BenchConfig, split: str) -> MimoEnvSpec:
    """The environment of ``mimo_family:<split>``: the quadruple-tank family's ``split`` with
    the process formulation's episodes (as ``mimo:quadruple_tank``) and the action bound of
    ``mimo_family``."""
    from stcgym.agents.benchmark.scenarios import _episode_settings
    from stcgym.envs.tank_family import TANK_FAMILY

    bench = _episode_settings(cfg)
    return MimoEnvSpec(
        family=TANK_FAMILY.key,
        split=split,
        steps=bench["steps"],
        noise_std=bench["noise_std"],
        control_cost=bench["control_cost"],
        action_bound=float(cfg.action_bounds.get("mimo_family", 10.0)),
        reference=TANK_REFERENCE,
    )


def mimo_scenarios(cfg: BenchConfig) -> list[Scenario]:
    """One ``mimo:<plant>`` scenario per plant of ``cfg.mimo_plants`` (``"mimo"`` in
    ``cfg.scenarios``), ``mimo_switch`` (``"mimo_switch"``) and ``mimo_family:test``
    (``"mimo_family"``); the RL agents of each train on its own episodes (training key: the
    scenario's name), those of ``mimo_family:test`` on the family's training split (training
    key ``mimo_family``)."""
    from dataclasses import replace

    from stcgym.agents.benchmark.scenarios import Scenario
    from stcgym.agents.evaluation.episodes import EpisodeSet

    out = []
    n = cfg.nominal_episodes
    seeds = tuple(range(cfg.first_seed, cfg.first_seed + n))
    if "mimo" in cfg.scenarios:
        for p in cfg.mimo_plants:
            env = mimo_spec(cfg, p)
            eps = EpisodeSet((env.plants[0],) * n, seeds)
            out.append(Scenario(f"mimo:{p}", "mimo", env, eps, f"mimo:{p}", env.order))
    if "mimo_switch" in cfg.scenarios:
        first, then = SWITCH
        base = mimo_spec(cfg, first, key="mimo_switch")
        env = replace(base, switch_to=then, jump_step=base.steps // 2)
        eps = EpisodeSet((first,) * n, seeds)
        out.append(
            Scenario("mimo_switch", "mimo_switch", env, eps, "mimo_switch", env.order,
                     adaptation=True)
        )  # fmt: skip
    if "mimo_family" in cfg.scenarios:
        env = tank_family_spec(cfg, "test")
        eps = EpisodeSet.of(env, cfg.episodes_per_plant, cfg.first_seed, cfg.test_plants)
        out.append(Scenario("mimo_family:test", "mimo_family", env, eps, "mimo_family", env.order))
    return out
