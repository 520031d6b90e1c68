"""Family specs: the keys a plant family is written in, their defaults and their validation.

A spec is data (a dict from YAML or JSON) with the keys of :data:`DEFAULT_FAMILY`;
:meth:`FamilySpec.from_dict` validates it, fills in the defaults and raises
:class:`FamilySpecError` naming the key for anything that cannot be drawn from. Drawing plants
and the named families live in :mod:`stcgym.envs.families`.
"""

from __future__ import annotations

import copy
import math
import re
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

__all__ = ["DEFAULT_FAMILY", "FamilySpec", "FamilySpecError"]


class FamilySpecError(ValueError):
    """A family spec that cannot be drawn from (the message names the key and what is expected)."""


#: Every key a family spec may have, with its default (``count`` has none).
DEFAULT_FAMILY: dict[str, Any] = {
    "name": "family",
    "version": 1,
    "seed": 0,
    "count": None,
    "order": 2,
    "poles": {
        "magnitude": [0.3, 0.95],
        "angle": [0.05, 0.5],
        "complex_share": 0.5,
        "unstable_share": 0.0,
        "unstable_magnitude": [1.02, 1.2],
    },
    "zeros": {
        "magnitude": [0.0, 0.9],
        "nonminimum_phase_share": 0.0,
        "nonminimum_phase_magnitude": [1.2, 3.0],
    },
    "dc_gain": [0.5, 5.0],
    "negative_gain_share": 0.0,
    "noise_std": 0.05,
    "reference": {"kind": "square", "period": 100, "amplitude": 1.0},
    "initial_state_std": 0.0,
    "steps": 1000,
    "control_cost": 0.01,
    "action_bound": 10.0,
    "y_bound": 100.0,
    "jump": None,
    "drift": None,
    "splits": None,
    "variants": None,
}
_JUMP_DEFAULT: dict[str, Any] = {
    "at": 0.5,
    "probability": 1.0,
    "magnitude_scale": [1.0, 1.0],
    "angle_scale": [1.0, 1.0],
    "dc_gain_scale": [1.0, 1.0],
}
_DRIFT_DEFAULT: dict[str, Any] = {"std": 0.0}
_REFERENCE_KINDS = ("square", "meander", "step", "sine", "zero", "random_steps")
#: Split and variant names: they become part of plant names (``family-v1/split/index``).
_NAME = re.compile(r"^[A-Za-z0-9_.-]+$")
#: The keys that are settings of the plant envs (:attr:`FamilySpec.env_settings`).
_ENV_SETTINGS = (
    "noise_std",
    "control_cost",
    "action_bound",
    "y_bound",
    "reference",
    "initial_state_std",
)
#: Keys replaced whole (never deep-merged) when a variant is built over its base spec.
_REPLACED_WHOLE = ("reference", "splits")


@dataclass(frozen=True)
class FamilySpec:
    """A validated family spec: ``data`` holds every key (defaults filled in), JSON-able.

    Build one with :meth:`from_dict`, :func:`load_family` or :func:`get_family`; the keys are
    those of :data:`DEFAULT_FAMILY` (annotated: "Writing a family spec" in the Environments page
    of the documentation). ``spec["key"]`` reads a key.

    Examples
    --------
    >>> from stcgym.envs.families import FamilySpec
    >>> spec = FamilySpec.from_dict(
    ...     {"name": "demo", "count": 100, "splits": {"train": [0, 80], "test": [80, 100]},
    ...      "variants": {"big": {"count": 20, "dc_gain": [5.0, 20.0]}}}
    ... )
    >>> spec.key, spec.split_indices("test"), spec.split_names
    ('demo-v1', range(80, 100), ['train', 'test', 'big'])
    >>> big = spec.variant("big")
    >>> big["name"], big.count, big["dc_gain"]
    ('demo.big', 20, [5.0, 20.0])
    """

    data: dict[str, Any]

    def __getitem__(self, key: str) -> Any:
        return self.data[key]

    @property
    def count(self) -> int:
        """Number of plants."""
        return int(self.data["count"])

    @property
    def order(self) -> int:
        """Plant order ``n``."""
        return int(self.data["order"])

    @property
    def steps(self) -> int:
        """Episode length."""
        return int(self.data["steps"])

    @property
    def version(self) -> int:
        """The spec's version (an integer >= 1)."""
        return int(self.data["version"])

    @property
    def key(self) -> str:
        """``"<name>-v<version>"``: the family's name in plant names and in :data:`FAMILIES`."""
        return f"{self.data['name']}-v{self.version}"

    @property
    def jump_probability(self) -> float:
        """The chance that an episode has the jump (0 without a jump)."""
        jump = self.data["jump"]
        return 0.0 if jump is None else float(jump["probability"])

    def jump_range(self, steps: int | None = None) -> tuple[int, int] | None:
        """The jump steps ``(low, high)`` each episode draws from uniformly; ``None`` without
        a jump.

        Parameters
        ----------
        steps : int, optional
            The episode length that fractions of ``jump.at`` refer to (default: the spec's).

        Raises
        ------
        ValueError
            The range does not lie inside ``[1, steps - 1]``.
        """
        jump = self.data["jump"]
        if jump is None:
            return None
        T = self.steps if steps is None else int(steps)
        return _jump_steps(jump["at"], T, "jump.at")

    @property
    def jump_step(self) -> int | None:
        """The jump step of a fixed jump (one step, probability 1); ``None`` without a jump.

        Raises
        ------
        ValueError
            The jump is random (a range of steps or a probability below 1): see
            :meth:`jump_range` and :attr:`jump_probability`.
        """
        span = self.jump_range()
        if span is None:
            return None
        if span[0] != span[1] or self.jump_probability < 1.0:
            raise ValueError(
                f"family {self.key!r} has a random jump (steps {list(span)}, probability "
                f"{self.jump_probability}); read jump_range() and jump_probability"
            )
        return span[0]

    @property
    def period(self) -> int:
        """Reference period (the window of the re-convergence metric); ``steps // 10`` if none."""
        ref = self.data["reference"]
        return int(ref.get("period", max(1, self.steps // 10)))

    @property
    def env_settings(self) -> dict[str, Any]:
        """What an env of the family's plants takes from the spec, as keyword arguments of the
        canonical plant envs: ``noise_std``, ``control_cost``, ``action_bound``, ``y_bound``,
        ``reference`` and ``initial_state_std``."""
        return {key: self.data[key] for key in _ENV_SETTINGS}

    @property
    def splits(self) -> dict[str, range]:
        """The named splits: plant index ranges, disjoint, in the spec's order."""
        return {name: range(*span) for name, span in self.data["splits"].items()}

    @property
    def variant_names(self) -> list[str]:
        """The names of the variants, in the spec's order."""
        return list(self.data["variants"])

    @property
    def split_names(self) -> list[str]:
        """Every name :meth:`members` accepts: the splits, then the variants."""
        return [*self.data["splits"], *self.data["variants"]]

    def split_indices(self, name: str) -> range:
        """The plant indices of split ``name`` (of a variant: all its plants' indices).

        Raises
        ------
        ValueError
            ``name`` is neither a split nor a variant; the message lists the valid names.
        """
        return self.members(name)[1]

    def variant(self, name: str) -> FamilySpec:
        """The variant ``name`` as a family of its own.

        The variant's partial spec is deep-merged over this spec's keys (``reference`` and
        ``splits`` are replaced whole, never merged) and must give its own ``count``. It keeps
        neither the splits nor the variants of its base (its plants form the split ``all``
        unless it names splits of its own); its ``name`` is ``"<base name>.<variant>"`` and its
        ``seed``, unless given, is ``base seed * 2**32 + zlib.crc32(variant name)``, so its
        plants differ from the base's and from another variant's.

        Raises
        ------
        ValueError
            No variant of that name; the message lists the variants.
        """
        if name not in self.data["variants"]:
            raise ValueError(
                f"family {self.key!r} has no variant {name!r}; variants: {self.variant_names}"
            )
        return FamilySpec(_variant_data(self.data, name))

    def members(self, name: str) -> tuple[FamilySpec, range]:
        """The family and plant indices that split or variant ``name`` stands for.

        A split: ``(self, its index range)``; a variant: ``(self.variant(name),
        range(variant count))``.

        Raises
        ------
        ValueError
            ``name`` is neither a split nor a variant; the message lists the valid names.
        """
        if isinstance(name, str) and name in self.data["splits"]:
            return self, range(*self.data["splits"][name])
        if isinstance(name, str) and name in self.data["variants"]:
            variant = self.variant(name)
            return variant, range(variant.count)
        raise ValueError(
            f"split must be one of {self.split_names} (splits and variants of family "
            f"{self.key!r}), got {name!r}"
        )

    def to_dict(self) -> dict[str, Any]:
        """A deep copy of :attr:`data` (validates again unchanged)."""
        return copy.deepcopy(self.data)

    @classmethod
    def from_dict(cls, spec: Mapping[str, Any]) -> FamilySpec:
        """Validate ``spec`` (the keys of :data:`DEFAULT_FAMILY`) and fill in defaults."""
        return cls(_validate(spec))


# --------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------
def _fail(key: str, expected: str, got: Any) -> FamilySpecError:
    return FamilySpecError(f"family spec: {key} must be {expected}, got {got!r}")


def _merge(spec: Mapping[str, Any], defaults: Mapping[str, Any], where: str) -> dict[str, Any]:
    if not isinstance(spec, Mapping):
        raise _fail(where or "the spec", "a mapping (YAML/JSON object)", spec)
    unknown = sorted(set(spec) - set(defaults))
    if unknown:
        prefix = f"{where}." if where else ""
        raise FamilySpecError(
            f"family spec: unknown key(s) {[prefix + k for k in unknown]}; "
            f"valid keys{' of ' + where if where else ''}: {sorted(defaults)}"
        )
    out = copy.deepcopy(dict(defaults))
    out.update(copy.deepcopy(dict(spec)))
    return out


def _number(value: Any, key: str, *, lo: float = -math.inf, hi: float = math.inf) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise _fail(key, "a finite number", value)
    if not lo <= value <= hi:
        raise _fail(key, f"in [{lo}, {hi}]", value)
    return float(value)


def _integer(value: Any, key: str, *, lo: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < lo:
        raise _fail(key, f"an integer >= {lo}", value)
    return int(value)


def _range(value: Any, key: str, *, lo: float = -math.inf, hi: float = math.inf) -> list[float]:
    """A ``[low, high]`` pair inside ``[lo, hi]`` with ``low <= high``."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value, value]
    if not isinstance(value, Sequence) or isinstance(value, str) or len(value) != 2:
        raise _fail(key, "a range [low, high]", value)
    low, high = (_number(v, key, lo=lo, hi=hi) for v in value)
    if low > high:
        raise _fail(key, "a range [low, high] with low <= high", value)
    return [low, high]


def _share(value: Any, key: str) -> float:
    return _number(value, key, lo=0.0, hi=1.0)


def _validate(spec: Mapping[str, Any]) -> dict[str, Any]:
    d = _merge(spec, DEFAULT_FAMILY, "")
    if d["count"] is None:
        raise FamilySpecError("family spec: count (number of plants, an integer >= 1) is required")
    d["name"] = str(d["name"])
    d["version"] = _integer(d["version"], "version", lo=1)
    d["seed"] = _integer(d["seed"], "seed", lo=0)
    d["count"] = _integer(d["count"], "count", lo=1)
    d["order"] = _integer(d["order"], "order", lo=1)
    if d["order"] > 8:
        raise _fail("order", "at most 8", d["order"])

    p = _merge(d["poles"], DEFAULT_FAMILY["poles"], "poles")
    p["magnitude"] = _range(p["magnitude"], "poles.magnitude", lo=0.0)
    if p["magnitude"][1] >= 1.0:
        raise _fail(
            "poles.magnitude",
            "a range of stable radii inside [0, 1) (unstable poles: poles.unstable_share)",
            p["magnitude"],
        )
    p["angle"] = _range(p["angle"], "poles.angle (fraction of pi)", lo=0.0, hi=1.0)
    p["complex_share"] = _share(p["complex_share"], "poles.complex_share")
    if p["complex_share"] > 0 and p["angle"][1] <= 0:
        raise _fail("poles.angle", "a range above 0 when complex_share > 0", p["angle"])
    p["unstable_share"] = _share(p["unstable_share"], "poles.unstable_share")
    p["unstable_magnitude"] = _range(p["unstable_magnitude"], "poles.unstable_magnitude", lo=0)
    if p["unstable_magnitude"][0] <= 1.0:
        raise _fail("poles.unstable_magnitude", "a range of radii above 1", p["unstable_magnitude"])
    d["poles"] = p

    z = _merge(d["zeros"], DEFAULT_FAMILY["zeros"], "zeros")
    z["magnitude"] = _range(z["magnitude"], "zeros.magnitude", lo=0.0)
    if z["magnitude"][1] >= 1.0:
        raise _fail("zeros.magnitude", "a range inside [0, 1) (minimum phase)", z["magnitude"])
    z["nonminimum_phase_share"] = _share(
        z["nonminimum_phase_share"], "zeros.nonminimum_phase_share"
    )
    z["nonminimum_phase_magnitude"] = _range(
        z["nonminimum_phase_magnitude"], "zeros.nonminimum_phase_magnitude", lo=0.0
    )
    if z["nonminimum_phase_magnitude"][0] <= 1.0:
        raise _fail(
            "zeros.nonminimum_phase_magnitude",
            "a range of radii above 1",
            z["nonminimum_phase_magnitude"],
        )
    d["zeros"] = z

    g = _range(d["dc_gain"], "dc_gain")
    if g[0] * g[1] <= 0:
        raise _fail("dc_gain", "a range [low, high] of one sign, excluding 0", d["dc_gain"])
    d["dc_gain"] = g
    d["negative_gain_share"] = _share(d["negative_gain_share"], "negative_gain_share")
    d["noise_std"] = _number(d["noise_std"], "noise_std", lo=0.0)
    d["initial_state_std"] = _number(d["initial_state_std"], "initial_state_std", lo=0.0)
    d["steps"] = _integer(d["steps"], "steps", lo=2)
    d["control_cost"] = _number(d["control_cost"], "control_cost", lo=0.0)
    d["action_bound"] = _number(d["action_bound"], "action_bound", lo=0.0)
    d["y_bound"] = _number(d["y_bound"], "y_bound", lo=0.0)
    if d["action_bound"] <= 0 or d["y_bound"] <= 0:
        raise _fail("action_bound and y_bound", "> 0", (d["action_bound"], d["y_bound"]))
    d["reference"] = _reference(d["reference"])
    d["jump"] = _jump(d["jump"], d["steps"])
    if d["drift"] is not None:
        drift = _merge(d["drift"], _DRIFT_DEFAULT, "drift")
        drift["std"] = _number(drift["std"], "drift.std", lo=0.0)
        d["drift"] = drift
        if d["jump"] is not None:
            raise FamilySpecError("family spec: give jump or drift, not both")
    d["splits"] = _splits(d["splits"], d["count"])
    d["variants"] = _variants(d, d["variants"])
    return d


def _name(value: Any, key: str) -> str:
    if not isinstance(value, str) or not _NAME.match(value):
        raise _fail(key, "a name of letters, digits, '_', '.' or '-'", value)
    return value


def _splits(splits: Any, count: int) -> dict[str, list[int]]:
    """``{name: [start, stop]}``: non-empty, inside ``[0, count)``, pairwise disjoint."""
    if splits is None:
        return {"all": [0, count]}
    if not isinstance(splits, Mapping) or not splits:
        raise _fail("splits", "a non-empty mapping name -> [start, stop]", splits)
    out: dict[str, list[int]] = {}
    for name, span in splits.items():
        key = f"splits.{_name(name, 'splits (a split name)')}"
        if not isinstance(span, Sequence) or isinstance(span, str) or len(span) != 2:
            raise _fail(key, "[start, stop] (plant indices, stop excluded)", span)
        start, stop = _integer(span[0], key, lo=0), _integer(span[1], key, lo=0)
        if not start < stop <= count:
            raise _fail(key, f"[start, stop] with 0 <= start < stop <= count = {count}", span)
        out[name] = [start, stop]
    ordered = sorted(out.items(), key=lambda item: item[1][0])
    for (first, a), (second, b) in zip(ordered, ordered[1:], strict=False):
        if b[0] < a[1]:
            raise FamilySpecError(
                f"family spec: splits.{first} {a} and splits.{second} {b} overlap; splits "
                "must be disjoint"
            )
    return out


def _variants(base: dict[str, Any], variants: Any) -> dict[str, dict[str, Any]]:
    """``{name: partial spec}``, each checked by building the variant."""
    if variants is None:
        return {}
    if not isinstance(variants, Mapping):
        raise _fail("variants", "a mapping name -> partial spec", variants)
    out: dict[str, dict[str, Any]] = {}
    for name, partial in variants.items():
        key = f"variants.{_name(name, 'variants (a variant name)')}"
        if name in base["splits"]:
            raise FamilySpecError(
                f"family spec: {key} has the name of a split; split and variant names must "
                "differ (a variant's name selects all its plants)"
            )
        if not isinstance(partial, Mapping) or "count" not in partial:
            raise _fail(key, "a partial spec (a mapping) that gives its own count", partial)
        if "variants" in partial:
            raise _fail(
                f"{key}.variants", "absent (a variant has no variants)", partial["variants"]
            )
        out[name] = copy.deepcopy(dict(partial))
        try:
            _variant_data({**base, "variants": out}, name)
        except FamilySpecError as exc:
            message = str(exc).replace("family spec: ", f"family spec: {key}: ", 1)
            raise FamilySpecError(message) from exc
    return out


def _deep_merge(base: Mapping[str, Any], over: Mapping[str, Any], top: bool) -> dict[str, Any]:
    out = copy.deepcopy(dict(base))
    for key, value in over.items():
        nested = isinstance(value, Mapping) and isinstance(out.get(key), Mapping)
        if nested and not (top and key in _REPLACED_WHOLE):
            out[key] = _deep_merge(out[key], value, False)
        else:
            out[key] = copy.deepcopy(value)
    return out


def _variant_data(base: Mapping[str, Any], name: str) -> dict[str, Any]:
    """The validated spec of variant ``name`` of the validated spec ``base``."""
    inherited = {k: v for k, v in base.items() if k not in ("splits", "variants", "name", "seed")}
    merged = _deep_merge(inherited, base["variants"][name], True)
    merged.setdefault("name", f"{base['name']}.{name}")
    merged.setdefault("seed", base["seed"] * 2**32 + zlib.crc32(name.encode("utf-8")))
    return _validate(merged)


def _reference(ref: Any) -> dict[str, Any]:
    if isinstance(ref, (int, float)) and not isinstance(ref, bool):
        return {"kind": "step", "amplitude": _number(ref, "reference")}
    if not isinstance(ref, Mapping) or "kind" not in ref:
        raise _fail(
            "reference", "a mapping with a 'kind' (square, step, sine, zero, random_steps)", ref
        )
    kind = str(ref["kind"]).lower()
    if kind not in _REFERENCE_KINDS:
        raise _fail("reference.kind", f"one of {list(_REFERENCE_KINDS)}", ref["kind"])
    from stcgym.envs.signals import make_reference

    out = {**dict(ref), "kind": kind}
    try:
        make_reference(out)
    except (TypeError, ValueError) as exc:
        raise FamilySpecError(f"family spec: reference {ref!r}: {exc}") from exc
    if "period" in out:
        out["period"] = _integer(out["period"], "reference.period", lo=1)
    return out


def _jump_step(at: float, steps: int) -> int:
    """``jump.at``: a fraction of the episode when below 1, else a step number."""
    return int(round(at * steps)) if at < 1 else int(at)


def _jump_at(at: Any) -> float | list[float]:
    """``jump.at`` as given: a number, or a range ``[low, high]`` whose ends are both fractions
    below 1 or both step numbers."""
    expected = "a fraction in (0, 1), a step >= 1, or a range [low, high] of either"
    if isinstance(at, Sequence) and not isinstance(at, str):
        if len(at) != 2:
            raise _fail("jump.at", expected, at)
        low, high = (_number(v, "jump.at", lo=0.0) for v in at)
        if (low < 1) != (high < 1):
            raise _fail("jump.at", "a range of two fractions below 1 or of two steps", at)
        if low > high:
            raise _fail("jump.at", "a range [low, high] with low <= high", at)
        return [at[0], at[1]]
    _number(at, "jump.at", lo=0.0)
    return at


def _jump_steps(at: float | Sequence[float], steps: int, key: str) -> tuple[int, int]:
    """The step range of ``jump.at`` for episodes of ``steps`` steps, inside ``[1, steps - 1]``."""
    ends = list(at) if isinstance(at, Sequence) else [at, at]
    low, high = (_jump_step(v, steps) for v in ends)
    integral = all(v < 1 or v == int(v) for v in ends)
    if not (integral and 0 < low <= high < steps):
        raise _fail(
            key,
            f"fractions in (0, 1) or whole steps in [1, {steps - 1}] (episodes of {steps} steps)",
            at,
        )
    return low, high


def _jump(jump: Any, steps: int) -> dict[str, Any] | None:
    if jump is None:
        return None
    j = _merge(jump, _JUMP_DEFAULT, "jump")
    j["at"] = _jump_at(j["at"])
    _jump_steps(j["at"], steps, "jump.at")
    j["probability"] = _share(j["probability"], "jump.probability")
    j["magnitude_scale"] = _range(j["magnitude_scale"], "jump.magnitude_scale", lo=0.0)
    j["angle_scale"] = _range(j["angle_scale"], "jump.angle_scale", lo=0.0)
    j["dc_gain_scale"] = _range(j["dc_gain_scale"], "jump.dc_gain_scale", lo=0.0)
    if j["dc_gain_scale"][0] <= 0:
        raise _fail("jump.dc_gain_scale", "a range of positive factors", j["dc_gain_scale"])
    return j
