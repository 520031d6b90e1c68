"""Reference signals and parameter schedules shared by every stcgym environment.

Both kinds of object are small stateful generators driven by the environment:

* a :class:`Reference` is ``reset(rng)`` at the start of an episode and then asked for ``r(k)``
  at steps ``k = 0, 1, 2, ...``;
* a :class:`Schedule` is ``reset(nominal, rng)`` with the nominal parameter array (theta of a
  canonical plant, ``[A B]`` of a state-space plant, ``Theta`` of the static object) and then
  asked for the parameters in force at step ``k``; ``k`` never decreases within an episode.

Randomness comes only from the ``rng`` handed over at reset (a child of the environment's
``np_random``), so an episode is reproducible from its seed whatever happened before.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "Reference",
    "SquareWave",
    "Step",
    "Sine",
    "PRBS",
    "Zero",
    "ArrayReference",
    "CallableReference",
    "make_reference",
    "make_references",
    "Schedule",
    "Constant",
    "Jumps",
    "Ramp",
    "RandomWalk",
    "make_schedule",
]


def _finite(value: float, name: str) -> float:
    v = float(value)
    if not np.isfinite(v):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return v


def _positive_int(value: int, name: str) -> int:
    if int(value) != value or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


# --------------------------------------------------------------------------------------------
# References
# --------------------------------------------------------------------------------------------
class Reference:
    """A scalar reference signal ``r(k)``; subclasses implement :meth:`__call__`."""

    def reset(self, rng: np.random.Generator) -> None:
        """Start a new episode (random references draw from ``rng``)."""

    def __call__(self, k: int) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    def __repr__(self) -> str:
        fields = ", ".join(f"{k}={v!r}" for k, v in vars(self).items() if not k.startswith("_"))
        return f"{type(self).__name__}({fields})"


class SquareWave(Reference):
    """Square wave ("meander", the seeds' test signal) between ``offset +- amplitude``.

    ``r(k) = offset + amplitude`` during the first half of each period, ``offset - amplitude``
    during the second half (the seeds use unit amplitude, zero offset).
    """

    def __init__(self, period: int = 100, amplitude: float = 1.0, offset: float = 0.0) -> None:
        self.period = _positive_int(period, "period")
        if self.period < 2:
            raise ValueError(f"period must be at least 2 steps, got {period}")
        self.amplitude = _finite(amplitude, "amplitude")
        self.offset = _finite(offset, "offset")

    def __call__(self, k: int) -> float:
        first_half = (k % self.period) < self.period / 2
        return self.offset + (self.amplitude if first_half else -self.amplitude)


class Step(Reference):
    """``r(k) = initial`` before step ``at``, ``amplitude`` from then on."""

    def __init__(self, amplitude: float = 1.0, at: int = 0, initial: float = 0.0) -> None:
        self.amplitude = _finite(amplitude, "amplitude")
        if int(at) != at or at < 0:
            raise ValueError(f"at must be a non-negative integer step, got {at!r}")
        self.at = int(at)
        self.initial = _finite(initial, "initial")

    def __call__(self, k: int) -> float:
        return self.amplitude if k >= self.at else self.initial


class Sine(Reference):
    """``r(k) = offset + amplitude * sin(2 pi k / period + phase)``."""

    def __init__(
        self, period: float = 100.0, amplitude: float = 1.0, phase: float = 0.0, offset: float = 0.0
    ) -> None:
        self.period = _finite(period, "period")
        if self.period <= 0:
            raise ValueError(f"period must be positive, got {period}")
        self.amplitude = _finite(amplitude, "amplitude")
        self.phase = _finite(phase, "phase")
        self.offset = _finite(offset, "offset")

    def __call__(self, k: int) -> float:
        return self.offset + self.amplitude * np.sin(2 * np.pi * k / self.period + self.phase)


class PRBS(Reference):
    """Pseudo-random binary sequence: ``+-amplitude`` held for ``hold`` steps per bit.

    Bits are drawn from the episode's generator, so the sequence changes with the seed and is
    identical for equal seeds.
    """

    def __init__(self, amplitude: float = 1.0, hold: int = 10, offset: float = 0.0) -> None:
        self.amplitude = _finite(amplitude, "amplitude")
        self.hold = _positive_int(hold, "hold")
        self.offset = _finite(offset, "offset")
        self._bits = np.zeros(0)
        self._rng = np.random.default_rng(0)

    def reset(self, rng: np.random.Generator) -> None:
        self._rng = np.random.default_rng(rng.integers(2**63))
        self._bits = np.zeros(0)

    def __call__(self, k: int) -> float:
        j = k // self.hold
        if j >= self._bits.size:
            more = self._rng.choice([-1.0, 1.0], size=max(64, j + 1 - self._bits.size))
            self._bits = np.concatenate((self._bits, more))
        return self.offset + self.amplitude * self._bits[j]


class Zero(Reference):
    """Regulation: ``r(k) = 0``."""

    def __call__(self, k: int) -> float:
        return 0.0


class ArrayReference(Reference):
    """A user array; the last value is held after the array ends."""

    def __init__(self, values: ArrayLike) -> None:
        arr = np.asarray(values, dtype=float).ravel()
        if arr.size == 0 or not np.all(np.isfinite(arr)):
            raise ValueError("reference array must be non-empty and finite")
        self.values = arr

    def __call__(self, k: int) -> float:
        return float(self.values[min(k, self.values.size - 1)])

    def __repr__(self) -> str:
        return f"ArrayReference(<{self.values.size} values>)"


class CallableReference(Reference):
    """A user function ``k -> r(k)``; its result must be a finite number."""

    def __init__(self, fn: Callable[[int], float]) -> None:
        self.fn = fn

    def __call__(self, k: int) -> float:
        r = float(self.fn(k))
        if not np.isfinite(r):
            raise ValueError(f"reference callable returned a non-finite value {r} at step {k}")
        return r


_REFERENCES: dict[str, type[Reference]] = {
    "square": SquareWave,
    "meander": SquareWave,
    "step": Step,
    "sine": Sine,
    "prbs": PRBS,
    "zero": Zero,
}


def make_reference(spec: Any = "square", **kwargs: Any) -> Reference:
    """Build a :class:`Reference` from a flexible specification.

    Parameters
    ----------
    spec
        A :class:`Reference`; a name (``"square"``/``"meander"``, ``"step"``, ``"sine"``,
        ``"prbs"``, ``"zero"``) with keyword arguments for it; a dict ``{"kind": name, ...}``;
        a number (constant reference); a 1-D array (held at its last value); or a callable
        ``k -> r``.
    """
    if isinstance(spec, Reference):
        return spec
    if spec is None:
        return Zero()
    if isinstance(spec, str):
        key = spec.lower()
        if key not in _REFERENCES:
            raise ValueError(
                f"reference must be one of {sorted(_REFERENCES)}, a number, an array, a "
                f"callable or a Reference; got {spec!r}"
            )
        return _REFERENCES[key](**kwargs)
    if isinstance(spec, Mapping):
        params = dict(spec)
        kind = params.pop("kind", None)
        if kind is None:
            raise ValueError("a reference dict needs a 'kind' entry, e.g. {'kind': 'square'}")
        return make_reference(str(kind), **params, **kwargs)
    if callable(spec):
        return CallableReference(spec)
    if np.ndim(spec) == 0:
        return Step(amplitude=_finite(spec, "reference"), at=0, initial=float(spec))
    return ArrayReference(spec)


def make_references(spec: Any, count: int) -> list[Reference]:
    """One reference per output channel.

    A list or tuple of exactly ``count`` specs (``count > 1``) gives one per channel; any other
    spec is built once and copied, so that random references draw independent bits per channel.
    """
    if count > 1 and isinstance(spec, (list, tuple)) and len(spec) == count:
        return [make_reference(s) for s in spec]
    ref = make_reference(spec)
    return [ref] + [copy.deepcopy(ref) for _ in range(count - 1)]


# --------------------------------------------------------------------------------------------
# Parameter schedules
# --------------------------------------------------------------------------------------------
class Schedule:
    """Parameters in force at step ``k``: a function of the nominal array and ``k``.

    The value returned for step ``k`` governs the transition from ``k`` to ``k + 1``.
    """

    def reset(self, nominal: NDArray, rng: np.random.Generator) -> None:
        self._nominal = np.array(nominal, dtype=float)

    def __call__(self, k: int) -> NDArray:
        return self._nominal

    @property
    def time_varying(self) -> bool:
        return True

    def __repr__(self) -> str:
        fields = ", ".join(f"{k}={v!r}" for k, v in vars(self).items() if not k.startswith("_"))
        return f"{type(self).__name__}({fields})"


class Constant(Schedule):
    """Time-invariant plant: the nominal parameters throughout."""

    @property
    def time_varying(self) -> bool:
        return False


def _check_shape(value: ArrayLike, like: NDArray, name: str) -> NDArray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != like.shape:
        raise ValueError(
            f"{name} must have the shape of the plant parameters {like.shape}, got {arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


class Jumps(Schedule):
    """Abrupt parameter changes: ``{step: new_parameters}`` (or a sequence of pairs).

    From step ``k_i`` on, the plant uses the ``i``-th array (same shape as the nominal one).
    """

    def __init__(self, changes: Mapping[int, ArrayLike] | Sequence[tuple[int, ArrayLike]]):
        items = list(changes.items()) if isinstance(changes, Mapping) else list(changes)
        if not items:
            raise ValueError("changes must name at least one (step, parameters) pair")
        for k, _ in items:
            if int(k) != k or k < 0:
                raise ValueError(f"jump steps must be non-negative integers, got {k!r}")
        self.changes = sorted(
            ((int(k), np.asarray(v, dtype=float)) for k, v in items), key=lambda kv: kv[0]
        )

    def reset(self, nominal: NDArray, rng: np.random.Generator) -> None:
        super().reset(nominal, rng)
        self._values = [
            (k, _check_shape(v, self._nominal, f"parameters at step {k}")) for k, v in self.changes
        ]
        self._steps = np.array([k for k, _ in self._values])

    def __call__(self, k: int) -> NDArray:
        i = int(np.searchsorted(self._steps, k, side="right"))
        return self._nominal if i == 0 else self._values[i - 1][1]


class Ramp(Schedule):
    """Slow linear drift from the nominal parameters to ``target`` over steps start..stop."""

    def __init__(self, target: ArrayLike, start: int, stop: int) -> None:
        if int(start) != start or int(stop) != stop or not 0 <= start < stop:
            raise ValueError(
                f"need integer steps 0 <= start < stop, got start={start}, stop={stop}"
            )
        self.target = np.asarray(target, dtype=float)
        self.start, self.stop = int(start), int(stop)

    def reset(self, nominal: NDArray, rng: np.random.Generator) -> None:
        super().reset(nominal, rng)
        self._target = _check_shape(self.target, self._nominal, "target")

    def __call__(self, k: int) -> NDArray:
        s = min(max((k - self.start) / (self.stop - self.start), 0.0), 1.0)
        return self._nominal + s * (self._target - self._nominal)


class RandomWalk(Schedule):
    """Random-walk drift: each step after ``start`` adds ``N(0, std^2)`` to the masked entries.

    ``mask`` (boolean, the parameters' shape) selects which entries drift; by default all. The
    walk can make a plant unstable; the environment's divergence bound ends such an episode.
    """

    def __init__(self, std: float, start: int = 0, mask: ArrayLike | None = None) -> None:
        self.std = _finite(std, "std")
        if self.std < 0:
            raise ValueError(f"std must be non-negative, got {std}")
        self.start = int(start)
        self.mask = None if mask is None else np.asarray(mask, dtype=bool)

    def reset(self, nominal: NDArray, rng: np.random.Generator) -> None:
        super().reset(nominal, rng)
        self._rng = np.random.default_rng(rng.integers(2**63))
        self._mask = np.ones(self._nominal.shape, bool) if self.mask is None else self.mask
        if self._mask.shape != self._nominal.shape:
            raise ValueError(f"mask must have shape {self._nominal.shape}, got {self._mask.shape}")
        self._k = self.start
        self._value = self._nominal.copy()

    def __call__(self, k: int) -> NDArray:
        while self._k < k:
            self._k += 1
            self._value = (
                self._value + self.std * self._rng.standard_normal(self._value.shape) * self._mask
            )
        return self._value


def make_schedule(spec: Any) -> Schedule:
    """Build a :class:`Schedule` from ``None``/``"constant"``, a Schedule, or ``{step: params}``."""
    if spec is None or (isinstance(spec, str) and spec.lower() == "constant"):
        return Constant()
    if isinstance(spec, Schedule):
        return spec
    if isinstance(spec, Mapping):
        return Jumps(spec)
    raise ValueError(
        f"schedule must be None, 'constant', a Schedule (Jumps, Ramp, RandomWalk) or a dict "
        f"{{step: parameters}}, got {spec!r}"
    )
