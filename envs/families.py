"""Plant families: random n-th-order SISO plants drawn reproducibly from a small spec.

A family spec is data (a YAML or JSON file, or a dict) with the keys of :data:`DEFAULT_FAMILY`,
each optional except ``count``: the order, the ranges and shares of stable and unstable poles,
minimum- and nonminimum-phase zeros and DC gains, the episode settings (noise, reference,
initial state, length, cost, bounds), an optional per-episode ``jump`` or ``drift`` of the
parameters, named ``splits`` and ``variants``. Unknown keys, negative counts, impossible ranges,
overlapping splits and clashing names raise :class:`FamilySpecError` (naming the key) before any
work starts. Every key, annotated: "Writing a family spec" in the Environments page of the
documentation.

:func:`draw_plant` draws plant ``i`` from ``numpy.random.SeedSequence([seed, i])`` alone, so a
plant is the same whether drawn alone, in a chunk of 10^4, in any split or on another machine;
only the jump's time (and whether an episode has it) is drawn per episode, by the environment
(:class:`~stcgym.envs.schedules.RandomJump`).

**Splits** name disjoint ranges of plant indices (:meth:`FamilySpec.split_indices`), e.g. train,
validation and test. **Variants** are other families derived from this one
(:meth:`FamilySpec.variant`), e.g. out-of-distribution test plants. Where a family is used by
split name (:meth:`FamilySpec.members`, the ``split`` of
:class:`~stcgym.envs.family_env.PlantFamilyEnv`), a variant's name means all its plants; split
and variant names must therefore differ.

**Named families**: :data:`FAMILIES` maps a name to its spec; :func:`get_family` accepts such a
name, a spec dict, a path to a YAML/JSON file or a :class:`FamilySpec`. ``"siso2-v1"`` is the
benchmark's default family (see :data:`FAMILIES`); :data:`LADDER` names four families of its
plants that add one difficulty at a time (``ladder-l1-v1``: stable, minimum phase, positive
gain; ... ``ladder-l4-v1``: ``siso2-v1``'s plants). The keys of a spec and their validation are
in :mod:`stcgym.envs.family_spec`.

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

from stcgym.envs.family_spec import DEFAULT_FAMILY, FamilySpec, FamilySpecError

__all__ = [
    "DEFAULT_FAMILY",
    "FAMILIES",
    "LADDER",
    "FamilySpec",
    "FamilySpecError",
    "Plant",
    "draw_plant",
    "draw_plants",
    "get_family",
    "load_family",
    "plant_features",
]


#: Stable poles are capped at this radius after a jump's scaling (the family stays stable).
_MAX_STABLE_RADIUS = 0.995


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


#: The named families, spec dict by ``"<name>-v<version>"``; :func:`get_family` looks them up.
#: Add a family of your own by assigning a spec dict to a new name.
#:
#: ``"siso2-v1"``, the benchmark's default: 1300 second-order plants, stable and unstable
#: (a quarter with a real pole in 1.02-1.15), minimum and nonminimum phase (a quarter with a
#: zero at radius 1.3-3), both gain signs (half negative, ``|DC gain|`` 0.5-5 log-uniform),
#: output noise 0.05, random steps of amplitude 1 held 25-75 steps (on average as often as a
#: square wave of period 100 changes), ``x(0) ~ N(0, 0.25 I)``,
#: 1000-step episodes, half of which jump between 30 % and 70 % of the episode (poles scaled
#: by 0.85-1.1 in radius and 0.8-1.2 in angle, gain by 0.5-2). Splits ``train`` (plants
#: 0-999), ``validation`` (1000-1099) and ``test`` (1100-1299); out-of-distribution variants of
#: 200 plants each: ``ood_fast_unstable`` (every plant unstable, pole 1.15-1.3),
#: ``ood_near_zero`` (every plant nonminimum phase, zero 1.05-1.3: near the unit circle),
#: ``ood_lightly_damped`` (complex poles at radius 0.95-0.99, all stable), ``ood_high_gain``
#: (``|DC gain|`` 5-20) and ``ood_order3`` (third-order plants). Measured over all 1300 plants
#: and the 1000 of the variants, before and after the jump: every coefficient is finite and no
#: ``b`` is all zero; the smallest ``max |b_i|`` is 5.6e-4 (6.3e-5 after a jump that scales an
#: unstable pole close to ``z = 1``: ``A(1)``, and with it ``b`` at the drawn DC gain, becomes
#: small), the largest ``|a_i|`` 3.02 (order 3) and ``|b_i|`` 133 (``ood_high_gain``).
FAMILIES: dict[str, dict[str, Any]] = {
    "siso2-v1": {
        "name": "siso2",
        "version": 1,
        "seed": 2026,
        "count": 1300,
        "order": 2,
        "poles": {
            "magnitude": [0.3, 0.95],
            "angle": [0.05, 0.5],
            "complex_share": 0.5,
            "unstable_share": 0.25,
            "unstable_magnitude": [1.02, 1.15],
        },
        "zeros": {
            "magnitude": [0.0, 0.9],
            "nonminimum_phase_share": 0.25,
            "nonminimum_phase_magnitude": [1.3, 3.0],
        },
        "dc_gain": [0.5, 5.0],
        "negative_gain_share": 0.5,
        "noise_std": 0.05,
        "reference": {"kind": "random_steps", "amplitude": 1.0, "hold": [25, 75]},
        "initial_state_std": 0.5,
        "steps": 1000,
        "control_cost": 0.01,
        "action_bound": 10.0,
        "y_bound": 20.0,
        "jump": {
            "at": [0.3, 0.7],
            "probability": 0.5,
            "magnitude_scale": [0.85, 1.1],
            "angle_scale": [0.8, 1.2],
            "dc_gain_scale": [0.5, 2.0],
        },
        "splits": {"train": [0, 1000], "validation": [1000, 1100], "test": [1100, 1300]},
        "variants": {
            "ood_fast_unstable": {
                "count": 200,
                "poles": {"unstable_share": 1.0, "unstable_magnitude": [1.15, 1.3]},
            },
            "ood_near_zero": {
                "count": 200,
                "zeros": {"nonminimum_phase_share": 1.0, "nonminimum_phase_magnitude": [1.05, 1.3]},
            },
            "ood_lightly_damped": {
                "count": 200,
                "poles": {"magnitude": [0.95, 0.99], "complex_share": 1.0, "unstable_share": 0.0},
            },
            "ood_high_gain": {"count": 200, "dc_gain": [5.0, 20.0]},
            "ood_order3": {"count": 200, "order": 3},
        },
    },
}


def _rung(level: int, *, negative_gain: bool, nonminimum_phase: bool, unstable: bool) -> dict:
    """A rung of the ladder: ``siso2-v1``'s spec with the named features switched off, its
    jump kept (the after-jump plants stay drawn) but with probability 0, and the held-out
    variants whose definition the rung contains."""
    spec = copy.deepcopy(FAMILIES["siso2-v1"])
    spec["name"] = f"ladder-l{level}"
    spec["jump"]["probability"] = 0.0
    if not negative_gain:
        spec["negative_gain_share"] = 0.0
    if not nonminimum_phase:
        spec["zeros"]["nonminimum_phase_share"] = 0.0
        del spec["variants"]["ood_near_zero"]
    if not unstable:
        spec["poles"]["unstable_share"] = 0.0
        del spec["variants"]["ood_fast_unstable"]
    return spec


#: The difficulty ladder: four families of ``siso2-v1``'s plants, each rung adding one feature
#: an adaptive controller must handle. ``ladder-l1-v1``: stable, minimum phase, positive gain;
#: ``ladder-l2-v1``: both gain signs; ``ladder-l3-v1``: also nonminimum-phase zeros;
#: ``ladder-l4-v1``: also unstable poles, the plants of ``siso2-v1``. Every rung has
#: ``siso2-v1``'s seed, order, ranges, shares (of the features it has), episode settings,
#: splits (train 0-999, validation 1000-1099, test 1100-1299) and the held-out variants its
#: definition contains (``ood_near_zero`` from L3 on, ``ood_fast_unstable`` on L4 only).
#: Parameter jumps are a separate axis: each rung keeps ``siso2-v1``'s jump with probability 0,
#: and ``jump_probability=0.5`` (of ``stcgym/PlantFamily-v0`` or the bench's ``EnvSpec``)
#: switches it on; ``ladder-l4-v1`` with it gives ``siso2-v1``'s episodes step for step.
#: The draws are nested: a rung's plant ``i`` is the next rung's plant ``i`` wherever that one
#: lies inside the rung's definition (a feature's draw happens only where it is present), and
#: L1's plant ``i`` is L2's with its gain made positive.
LADDER: tuple[str, ...] = ("ladder-l1-v1", "ladder-l2-v1", "ladder-l3-v1", "ladder-l4-v1")
FAMILIES.update(
    {
        "ladder-l1-v1": _rung(1, negative_gain=False, nonminimum_phase=False, unstable=False),
        "ladder-l2-v1": _rung(2, negative_gain=True, nonminimum_phase=False, unstable=False),
        "ladder-l3-v1": _rung(3, negative_gain=True, nonminimum_phase=True, unstable=False),
        "ladder-l4-v1": _rung(4, negative_gain=True, nonminimum_phase=True, unstable=True),
    }
)


def get_family(family: str | os.PathLike | Mapping[str, Any] | FamilySpec) -> FamilySpec:
    """A validated family from a registered name, a spec dict, a YAML/JSON file or a spec.

    Parameters
    ----------
    family : str, path-like, dict or FamilySpec
        A key of :data:`FAMILIES` (e.g. ``"siso2-v1"``), a path to a ``.yaml``/``.yml``/
        ``.json`` spec (read with ``yaml.safe_load`` / ``json``), a spec dict, or a
        :class:`FamilySpec` (returned as it is).

    Returns
    -------
    FamilySpec

    Raises
    ------
    ValueError
        A string that is neither a registered name nor the path of a file; the message lists
        the registered names.
    FamilySpecError
        A spec that does not validate (a ``ValueError`` too).
    FileNotFoundError
        A ``.yaml``/``.yml``/``.json`` path that does not exist.
    TypeError
        Any other kind of ``family``.

    Examples
    --------
    >>> from stcgym.envs.families import get_family
    >>> family = get_family("siso2-v1")
    >>> family.key, family.count, family.split_indices("test")
    ('siso2-v1', 1300, range(1100, 1300))
    >>> family.split_names
    ['train', 'validation', 'test', 'ood_fast_unstable', 'ood_near_zero', 'ood_lightly_damped',
     'ood_high_gain', 'ood_order3']
    """
    if isinstance(family, FamilySpec):
        return family
    if isinstance(family, Mapping):
        return FamilySpec.from_dict(family)
    if isinstance(family, str) and family in FAMILIES:
        return FamilySpec.from_dict(FAMILIES[family])
    if isinstance(family, (str, os.PathLike)):
        path = Path(family)
        if path.is_file() or path.suffix.lower() in (".yaml", ".yml", ".json"):
            return load_family(path)
        raise ValueError(
            f"family must be a registered name (one of {sorted(FAMILIES)}), a path to a "
            f".yaml/.json spec, a spec dict or a FamilySpec; got {family!r}"
        )
    raise TypeError(
        f"family must be a registered name, a path, a spec dict or a FamilySpec, got {family!r}"
    )


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
    """Plant ``index`` of ``family``: a pure function of ``(family, family.seed, index)``.

    Everything is drawn from ``numpy.random.SeedSequence([seed, index])``. The poles are
    ``n // 2`` pairs, each complex with probability ``complex_share`` (radius and angle uniform
    in their ranges), else two real poles of uniform radius; odd ``n`` adds one real pole. With
    probability ``unstable_share`` the largest real pole (or, for an all-complex draw, the first
    pair, made real) is replaced by an unstable real pole. The ``n - 1`` zeros are real, of
    uniform magnitude and random sign; with probability ``nonminimum_phase_share`` the first one
    lies outside the unit circle (order 1: no zeros). The numerator is scaled so that
    ``B(1) / A(1)`` is the drawn DC gain (log-uniform). The jump's target plant is drawn next by
    scaling the plant's poles and gain; last, with probability ``negative_gain_share``, the
    signs of the gain and of ``b`` (before and after the jump) flip.
    """
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
    # Drawn last, so that the plants of a family without sign flips stay what they were.
    if rng.random() < family["negative_gain_share"]:
        b, gain = -b, -gain
        if extra:
            extra.update(b_after=-extra["b_after"], dc_gain_after=-extra["dc_gain_after"])
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
