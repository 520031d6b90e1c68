"""A sweep's settings: the family, named controllers, episode seeds and chunk size, all checked
(each controller built once) before any work starts."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from stcgym.agents.sweeps.chunk import CONTROLLER_KINDS, make_controller
from stcgym.envs.families import FamilySpec, draw_plant, load_family

__all__ = ["DEFAULT_CHUNK", "SweepConfig", "SweepError"]

DEFAULT_CHUNK = 10_000


class SweepError(ValueError):
    """Bad sweep input (controllers, seeds, chunk size, run folder), raised before any work."""


@dataclass(frozen=True)
class SweepConfig:
    """A validated sweep: the family, named controllers, episode seeds and the chunk size."""

    family: FamilySpec
    controllers: dict[str, dict[str, Any]]
    seeds: tuple[int, ...]
    chunk_size: int = DEFAULT_CHUNK

    @classmethod
    def build(
        cls,
        family: FamilySpec | Mapping[str, Any] | str | os.PathLike,
        controllers: Mapping[str, Mapping[str, Any]] | Sequence[str] | None = None,
        seeds: int | Sequence[int] = 1,
        chunk_size: int = DEFAULT_CHUNK,
    ) -> SweepConfig:
        """Validate everything (building each controller once) before any work starts.

        ``controllers``: names of the default kinds (``["stc", "oracle", "lqg"]``, the
        default) or ``{name: {"kind": kind, **keywords}}`` (``kind`` defaults to the name).
        ``seeds``: a count ``S`` (seeds ``0..S-1``) or the list of episode seeds.
        """
        fam = family if isinstance(family, FamilySpec) else load_family(family)
        span = fam.jump_range()  # the post-jump metrics are read from one step in every lane
        if span is not None and (span[0] != span[1] or fam.jump_probability < 1):
            raise SweepError(
                f"family: a sweep needs a fixed jump (one step, probability 1), got jump.at "
                f"{fam['jump']['at']!r} and jump.probability {fam.jump_probability}"
            )
        if controllers is None:
            controllers = list(CONTROLLER_KINDS)
        if not isinstance(controllers, Mapping):
            controllers = {str(name): {} for name in controllers}
        ctl = {str(k): dict(v or {}) for k, v in controllers.items()}
        if not ctl:
            raise SweepError("controllers: give at least one controller")
        ctl.setdefault("oracle", {"kind": "oracle"})
        for name, kw in ctl.items():
            kind = str(kw.setdefault("kind", name)).lower()
            kw["kind"] = kind
            if kind not in CONTROLLER_KINDS:
                raise SweepError(
                    f"controller {name!r}: kind must be one of {list(CONTROLLER_KINDS)}, "
                    f"got {kind!r}"
                )
        if ctl["oracle"]["kind"] != "oracle":
            raise SweepError("the controller named 'oracle' must be of kind oracle")
        if isinstance(seeds, bool) or (isinstance(seeds, int) and seeds < 1):
            raise SweepError(f"seeds must be a count >= 1 or a list of seeds, got {seeds!r}")
        seed_list = list(range(seeds)) if isinstance(seeds, int) else list(seeds)
        if not seed_list or any(
            isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0 for s in seed_list
        ):
            raise SweepError(f"seeds must be non-negative integers, got {seeds!r}")
        if len(set(seed_list)) != len(seed_list):
            raise SweepError(f"seeds must be distinct, got {seed_list}")
        if isinstance(chunk_size, bool) or int(chunk_size) != chunk_size or chunk_size < 1:
            raise SweepError(f"chunk_size must be a positive integer, got {chunk_size!r}")
        cfg = cls(fam, ctl, tuple(int(s) for s in seed_list), int(chunk_size))
        plant = draw_plant(fam, 0)
        for name, kw in ctl.items():
            try:
                make_controller(kw, fam, [plant], batched=False)
            except (TypeError, ValueError) as exc:
                raise SweepError(f"controller {name!r} ({_describe(kw)}): {exc}") from exc
        return cfg

    @property
    def num_lanes(self) -> int:
        return self.family.count * len(self.seeds)

    def tasks(self) -> list[dict[str, Any]]:
        """One JSON task per chunk of lanes (its :func:`task_id` keys resuming)."""
        base = {
            "family": self.family.to_dict(),
            "controllers": self.controllers,
            "seeds": list(self.seeds),
        }
        return [
            {**base, "lanes": [lo, min(lo + self.chunk_size, self.num_lanes)]}
            for lo in range(0, self.num_lanes, self.chunk_size)
        ]

    def to_dict(self) -> dict[str, Any]:
        return {
            "family": self.family.to_dict(),
            "controllers": self.controllers,
            "seeds": list(self.seeds),
            "chunk_size": self.chunk_size,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> SweepConfig:
        return cls.build(d["family"], d["controllers"], list(d["seeds"]), d["chunk_size"])


def _describe(kw: Mapping[str, Any]) -> str:
    return ", ".join(f"{k}={v!r}" for k, v in kw.items())
