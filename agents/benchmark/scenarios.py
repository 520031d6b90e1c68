"""The scenarios of ``stcgym bench`` (nominal, family, jump, mimo) and the RL training
environments they use."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from stcgym.agents.benchmark.evaluate import EnvSpec
from stcgym.agents.rl.configs import RECURRENT_ALGORITHMS
from stcgym.envs.catalogue import TIMEVARYING2_AFTER, get_plant, plant_names

if TYPE_CHECKING:
    from stcgym.agents.benchmark.config import BenchConfig

__all__ = ["JUMP_FORM", "Scenario", "make_scenarios", "parse_jump", "training_envs"]

#: What ``--jump`` accepts, as its error messages say.
JUMP_FORM = "'timevarying2' or 'BEFORE:AFTER' (two catalogue plants of the same order)"


def parse_jump(spec: str) -> tuple[str, str, tuple[float, ...]]:
    """``"timevarying2"`` or ``"A:B"`` -> ``(label, pre-jump plant, post-jump theta)``.

    Raises ``ValueError`` naming ``--jump`` and the expected form for anything else: a missing
    plant name, an unknown one, two plants of different orders or the same plant twice.
    """
    s = spec.strip().lower()
    if s == "timevarying2":
        return s, "stable2", tuple(TIMEVARYING2_AFTER[0] + TIMEVARYING2_AFTER[1])
    before, colon, after = (part.strip() for part in s.partition(":"))
    if not (colon and before and after):
        raise ValueError(f"--jump must be {JUMP_FORM}, got {spec!r}")
    unknown = [p for p in (before, after) if p not in plant_names()]
    if unknown:
        raise ValueError(
            f"--jump {spec!r}: unknown plant(s) {unknown}; expected {JUMP_FORM} from "
            f"{plant_names()}"
        )
    a, b = get_plant(before), get_plant(after)
    if a.n != b.n:
        raise ValueError(
            f"--jump {spec!r}: both plants must have the same order ({before} has {a.n}, "
            f"{after} has {b.n}); expected {JUMP_FORM}"
        )
    if before == after:
        raise ValueError(f"--jump {spec!r}: the plant must change; expected {JUMP_FORM}")
    return f"{before}>{after}", before, tuple(b.theta)


@dataclass(frozen=True)
class Scenario:
    """One evaluation setting: environment, plant and the RL training environment it uses."""

    name: str
    kind: str
    env: EnvSpec
    plant: str
    train_key: str
    jump_to: tuple[float, ...] | None = None

    def train_key_for(self, algo: str) -> str | None:
        """The training environment of ``algo``'s agents evaluated here (``None``: not here)."""
        if algo in RECURRENT_ALGORITHMS:
            return "family" if self.kind in ("family", "jump") else None
        return self.train_key


def make_scenarios(cfg: BenchConfig) -> list[Scenario]:
    T = cfg.episode_steps
    out: list[Scenario] = []
    if "nominal" in cfg.scenarios:
        for p in cfg.plants:
            out.append(Scenario(f"nominal:{p}", "nominal", cfg.env_spec([p], T), p, f"nominal:{p}"))
    if "family" in cfg.scenarios:
        for p in cfg.family_test:
            out.append(Scenario(f"family:{p}", "family", cfg.env_spec([p], T), p, "family"))
    if "jump" in cfg.scenarios:
        for spec in cfg.jumps:
            label, before, theta = parse_jump(spec)
            env = cfg.env_spec([before], T, jump_step=T // 2, jump_to=theta)
            out.append(Scenario(f"jump:{label}", "jump", env, before, f"nominal:{before}", theta))
    if "mimo" in cfg.scenarios:
        from stcgym.agents.benchmark.mimo import mimo_scenarios

        out += mimo_scenarios(cfg)
    return out


def training_envs(
    cfg: BenchConfig, scenarios: Sequence[Scenario]
) -> dict[str, tuple[EnvSpec, EnvSpec]]:
    """``train_key -> (training env, learning-curve env)`` for every key an RL agent uses.

    The training environment is the evaluation one, with shorter episodes; ``train_y_bound``
    (times the reference amplitude) optionally replaces the divergence bound, so that training
    episodes end (and are charged to the end, see :class:`~stcgym.agents.rl.wrappers.
    TrainingReward`) earlier. In our tests a bound of 10 got SAC and TD3 out of a saturated
    local optimum on ``unstable2`` but made exploration end episodes all the time on the
    high-gain ``stable2`` and ruined them there, so the default keeps the environment's bound.
    The learning curve is always measured on the evaluation settings.
    """
    keys = dict.fromkeys(
        k for sc in scenarios for a in cfg.rl_agents if (k := sc.train_key_for(a)) is not None
    )
    envs: dict[str, tuple[EnvSpec, EnvSpec]] = {}
    for key in keys:  # "family", "nominal:<plant>" or "mimo:<plant>"
        plants = cfg.family_train if key == "family" else [key.split(":", 1)[1]]
        curve = cfg.env_spec(plants, cfg.train_episode_steps)
        train = curve
        if cfg.train_y_bound is not None:
            train = cfg.env_spec(
                plants, cfg.train_episode_steps, y_bound=cfg.train_y_bound * curve.amplitude
            )
        envs[key] = (train, curve)
    return envs
