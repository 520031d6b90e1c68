"""Plant families: random n-th-order SISO plants drawn reproducibly from a small spec.

A family spec is data (a YAML or JSON file, or a dict). Every key is optional except ``count``;
unknown keys, negative counts and impossible ranges raise :class:`FamilySpecError` before any
work starts. Example (YAML)::

    name: demo
    seed: 0              # family seed: plant i is drawn from SeedSequence([seed, i])
    count: 200           # number of plants
    order: 2             # n: poles (and n - 1 zeros) of (b1 z^{n-1} + ... + bn) / A(z)
    poles:
      magnitude: [0.3, 0.95]         # radius of the stable poles (uniform)
      angle: [0.05, 0.5]             # angle of complex poles, as a fraction of pi (uniform)
      complex_share: 0.5             # chance that each pole pair is complex
      unstable_share: 0.2            # share of plants with one real pole outside the unit circle
      unstable_magnitude: [1.02, 1.2]
    zeros:
      magnitude: [0.0, 0.9]          # |zero| of the minimum-phase zeros (real, random sign)
      nonminimum_phase_share: 0.2    # share of plants with one zero outside the unit circle
      nonminimum_phase_magnitude: [1.2, 3.0]
    dc_gain: [0.5, 5.0]              # B(1)/A(1), log-uniform; both ends of one sign
    noise_std: 0.05                  # output noise standard deviation
    reference: {kind: square, period: 100, amplitude: 1.0}   # square, step, sine, zero
    steps: 1000                      # episode length
    control_cost: 0.01               # rho in the cost (y - r)^2 + rho u^2
    action_bound: 10.0
    y_bound: 100.0                   # |y| beyond this ends the episode (not bounded)
    jump:                            # optional: parameters jump once per episode
      at: 0.5                        # fraction of the episode (or a step number >= 1)
      magnitude_scale: [0.8, 1.1]    # stable pole radii scaled by this (capped below 1)
      angle_scale: [0.8, 1.2]
      dc_gain_scale: [0.5, 2.0]      # log-uniform
    drift: {std: 0.0005}             # optional, instead of jump: random walk on [a; b]

Drawing (:func:`draw_plant`): the poles are ``n // 2`` pairs, each complex with probability
``complex_share`` (radius and angle uniform in their ranges), else two real poles of uniform
radius; odd ``n`` adds one real pole. With probability ``unstable_share`` the largest real pole
(or, for an all-complex draw, the first pair, made real) is replaced by an unstable real pole.
The ``n - 1`` zeros are real, of uniform magnitude and random sign; with probability
``nonminimum_phase_share`` the first one lies outside the unit circle (order 1: no zeros).
The numerator is scaled so that ``B(1) / A(1)`` is the drawn DC gain. Everything a plant is
comes from ``numpy.random.SeedSequence([seed, index])``: plant ``i`` of a family is the same
whether drawn alone, in a chunk of 10^4 or on another machine. The jump's target plant is drawn
from the same stream by scaling the plant's poles and gain.

:func:`plant_features` lists what the sweep tables report about a plant (largest pole
magnitude, |DC gain|, ...). The independent check against python-control (poles, zeros, DC
gain of the drawn transfer function) lives in the tests.
"""

from __future__ import annotations

import copy
import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "DEFAULT_FAMILY",
    "FamilySpec",
    "FamilySpecError",
    "Plant",
    "draw_plant",
    "draw_plants",
    "load_family",
    "plant_features",
]


class FamilySpecError(ValueError):
    """A family spec that cannot be drawn from (the message names the key and what is expected)."""


#: Every key a family spec may have, with its default (``count`` has none).
DEFAULT_FAMILY: dict[str, Any] = {
    "name": "family",
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
    "noise_std": 0.05,
    "reference": {"kind": "square", "period": 100, "amplitude": 1.0},
    "steps": 1000,
    "control_cost": 0.01,
    "action_bound": 10.0,
    "y_bound": 100.0,
    "jump": None,
    "drift": None,
}
_JUMP_DEFAULT: dict[str, Any] = {
    "at": 0.5,
    "magnitude_scale": [1.0, 1.0],
    "angle_scale": [1.0, 1.0],
    "dc_gain_scale": [1.0, 1.0],
}
_DRIFT_DEFAULT: dict[str, Any] = {"std": 0.0}
_REFERENCE_KINDS = ("square", "meander", "step", "sine", "zero")
#: Stable poles are capped at this radius after a jump's scaling (the family stays stable).
_MAX_STABLE_RADIUS = 0.995


@dataclass(frozen=True)
class FamilySpec:
    """A validated family spec: ``data`` holds every key (defaults filled in), JSON-able."""

    data: dict[str, Any]

    def __getitem__(self, key: str) -> Any:
        return self.data[key]

    @property
    def count(self) -> int:
        return int(self.data["count"])

    @property
    def order(self) -> int:
        return int(self.data["order"])

    @property
    def steps(self) -> int:
        return int(self.data["steps"])

    @property
    def jump_step(self) -> int | None:
        jump = self.data["jump"]
        return None if jump is None else _jump_step(jump["at"], self.steps)

    @property
    def period(self) -> int:
        """Reference period (the window of the re-convergence metric); ``steps // 10`` if none."""
        ref = self.data["reference"]
        return int(ref.get("period", max(1, self.steps // 10)))

    def to_dict(self) -> dict[str, Any]:
        return copy.deepcopy(self.data)

    @classmethod
    def from_dict(cls, spec: Mapping[str, Any]) -> FamilySpec:
        """Validate ``spec`` (see the module docstring) and fill in defaults."""
        return cls(_validate(spec))


@dataclass(frozen=True)
class Plant:
    """One drawn plant: observer-form ``a``, ``b`` (and after the jump), its roots and gain."""

    index: int
    a: NDArray
    b: NDArray
    poles: NDArray
    zeros: NDArray
    dc_gain: float
    a_after: NDArray | None = None
    b_after: NDArray | None = None
    poles_after: NDArray | None = None
    dc_gain_after: float | None = None


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
    d["noise_std"] = _number(d["noise_std"], "noise_std", lo=0.0)
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
    return d


def _reference(ref: Any) -> dict[str, Any]:
    if isinstance(ref, (int, float)) and not isinstance(ref, bool):
        return {"kind": "step", "amplitude": _number(ref, "reference")}
    if not isinstance(ref, Mapping) or "kind" not in ref:
        raise _fail("reference", "a mapping with a 'kind' (square, step, sine, zero)", ref)
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


def _jump(jump: Any, steps: int) -> dict[str, Any] | None:
    if jump is None:
        return None
    j = _merge(jump, _JUMP_DEFAULT, "jump")
    at = _number(j["at"], "jump.at", lo=0.0)
    step = _jump_step(at, steps)
    if not 0 < step < steps or (at >= 1 and at != int(at)):
        raise _fail("jump.at", f"a fraction in (0, 1) or a step in [1, {steps - 1}]", j["at"])
    j["magnitude_scale"] = _range(j["magnitude_scale"], "jump.magnitude_scale", lo=0.0)
    j["angle_scale"] = _range(j["angle_scale"], "jump.angle_scale", lo=0.0)
    j["dc_gain_scale"] = _range(j["dc_gain_scale"], "jump.dc_gain_scale", lo=0.0)
    if j["dc_gain_scale"][0] <= 0:
        raise _fail("jump.dc_gain_scale", "a range of positive factors", j["dc_gain_scale"])
    return j


def load_family(source: str | os.PathLike | Mapping[str, Any]) -> FamilySpec:
    """Read and validate a family spec from a ``.yaml``/``.yml``/``.json`` file or a dict."""
    if isinstance(source, Mapping):
        return FamilySpec.from_dict(source)
    path = Path(source)
    if not path.is_file():
        raise FileNotFoundError(f"family spec file not found: {path}")
    text = path.read_text()
    if path.suffix.lower() in (".yaml", ".yml"):
        try:
            import yaml
        except ImportError as exc:  # pragma: no cover  (PyYAML comes with ray and most stacks)
            raise FamilySpecError(
                "reading YAML needs PyYAML (pip install pyyaml); or use JSON"
            ) from exc
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise FamilySpecError(f"family spec {path}: not valid YAML: {exc}") from exc
    else:
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise FamilySpecError(f"family spec {path}: not valid JSON: {exc}") from exc
    return FamilySpec.from_dict(data if data is not None else {})


# --------------------------------------------------------------------------------------------
# Drawing
# --------------------------------------------------------------------------------------------
def _uniform(rng: np.random.Generator, r: Sequence[float]) -> float:
    return float(rng.uniform(r[0], r[1])) if r[1] > r[0] else float(r[0])


def _log_uniform(rng: np.random.Generator, r: Sequence[float]) -> float:
    sign = 1.0 if r[0] > 0 else -1.0
    lo, hi = sorted((math.log(abs(r[0])), math.log(abs(r[1]))))
    return sign * math.exp(_uniform(rng, (lo, hi)))


def _draw_poles(rng: np.random.Generator, n: int, p: Mapping[str, Any]) -> NDArray:
    poles: list[complex] = []
    for _ in range(n // 2):
        if rng.random() < p["complex_share"]:
            rad = _uniform(rng, p["magnitude"])
            ang = math.pi * _uniform(rng, p["angle"])
            pole = rad * complex(math.cos(ang), math.sin(ang))
            poles += [pole, pole.conjugate()]
        else:
            poles += [
                complex(_uniform(rng, p["magnitude"])),
                complex(_uniform(rng, p["magnitude"])),
            ]
    if n % 2:
        poles.append(complex(_uniform(rng, p["magnitude"])))
    if rng.random() < p["unstable_share"]:
        unstable = _uniform(rng, p["unstable_magnitude"])
        real = [i for i, z in enumerate(poles) if z.imag == 0]
        if real:  # replace the largest real pole
            i = max(real, key=lambda k: abs(poles[k]))
            poles[i] = complex(unstable)
        else:  # all complex: the first pair becomes two real poles, one unstable
            poles[0], poles[1] = complex(unstable), complex(abs(poles[0]))
    return np.array(poles)


def _draw_zeros(rng: np.random.Generator, n: int, z: Mapping[str, Any]) -> NDArray:
    zeros = [
        _uniform(rng, z["magnitude"]) * (1.0 if rng.random() < 0.5 else -1.0) for _ in range(n - 1)
    ]
    if n > 1 and rng.random() < z["nonminimum_phase_share"]:
        zeros[0] = _uniform(rng, z["nonminimum_phase_magnitude"]) * (
            1.0 if rng.random() < 0.5 else -1.0
        )
    return np.array(zeros, dtype=float)


def _coefficients(poles: NDArray, zeros: NDArray, dc_gain: float) -> tuple[NDArray, NDArray]:
    """Observer-form ``a`` (monic ``A(z)`` without its leading 1) and ``b`` with ``B(1)/A(1)``."""
    den = np.real(np.poly(poles))
    num = np.real(np.poly(zeros)) if zeros.size else np.ones(1)
    scale = dc_gain * np.polyval(den, 1.0) / np.polyval(num, 1.0)
    b = scale * num
    return den[1:].copy(), b


def _jumped(
    rng: np.random.Generator, poles: NDArray, zeros: NDArray, dc_gain: float, j: Mapping
) -> tuple[NDArray, NDArray, NDArray, float]:
    """The plant after the jump: pole radii and angles scaled, gain scaled (same zeros)."""
    mag_scale = _uniform(rng, j["magnitude_scale"])
    ang_scale = _uniform(rng, j["angle_scale"])
    gain = dc_gain * math.exp(_uniform(rng, np.log(j["dc_gain_scale"])))
    radius = np.abs(poles) * mag_scale
    stable = np.abs(poles) < 1.0
    radius[stable] = np.minimum(radius[stable], _MAX_STABLE_RADIUS)
    # Real poles are positive (angle 0) and stay real; conjugate pairs stay conjugate.
    angle = np.clip(np.angle(poles) * ang_scale, -math.pi, math.pi)
    after = radius * np.exp(1j * angle)
    a, b = _coefficients(after, zeros, gain)
    return a, b, after, gain


def draw_plant(family: FamilySpec, index: int) -> Plant:
    """Plant ``index`` of ``family``: a pure function of ``(family, family.seed, index)``."""
    if not 0 <= int(index) < family.count:
        raise ValueError(f"index must be in [0, {family.count}), got {index!r}")
    rng = np.random.default_rng(np.random.SeedSequence([family["seed"], int(index)]))
    n = family.order
    poles = _draw_poles(rng, n, family["poles"])
    zeros = _draw_zeros(rng, n, family["zeros"])
    gain = _log_uniform(rng, family["dc_gain"])
    a, b = _coefficients(poles, zeros, gain)
    extra: dict[str, Any] = {}
    if family["jump"] is not None:
        a2, b2, poles2, gain2 = _jumped(rng, poles, zeros, gain, family["jump"])
        extra = dict(a_after=a2, b_after=b2, poles_after=poles2, dc_gain_after=gain2)
    return Plant(int(index), a, b, poles, zeros, gain, **extra)


def draw_plants(family: FamilySpec, indices: Sequence[int] | range) -> list[Plant]:
    """:func:`draw_plant` for each index (the draws do not depend on each other)."""
    return [draw_plant(family, i) for i in indices]


def plant_features(plant: Plant) -> dict[str, float]:
    """The per-plant columns of the sweep table.

    ``pole_mag_max`` (largest pole magnitude), ``pole_angle_max`` (largest pole angle / pi),
    ``dc_gain``, ``abs_dc_gain``, ``zero_mag_max`` (0 without zeros), ``unstable`` and
    ``nonminimum_phase`` (0/1), and after a jump ``pole_mag_max_after``, ``abs_dc_gain_after``.
    """
    mags = np.abs(plant.poles)
    zmag = np.abs(plant.zeros)
    f = {
        "pole_mag_max": float(mags.max()),
        "pole_angle_max": float(np.abs(np.angle(plant.poles)).max() / math.pi),
        "dc_gain": float(plant.dc_gain),
        "abs_dc_gain": float(abs(plant.dc_gain)),
        "zero_mag_max": float(zmag.max()) if zmag.size else 0.0,
        "unstable": float(mags.max() >= 1.0),
        "nonminimum_phase": float(zmag.size > 0 and zmag.max() >= 1.0),
    }
    if plant.poles_after is not None:
        f["pole_mag_max_after"] = float(np.abs(plant.poles_after).max())
        f["abs_dc_gain_after"] = float(abs(plant.dc_gain_after))
    return f
