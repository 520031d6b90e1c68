"""Reference signals ``r(k)`` of the stcgym environments, produced for a vector of lanes.

A :class:`Reference` is :meth:`~Reference.allocate`-d for ``B`` lanes (the plants of a vector
env; a single env is one lane), :meth:`reset_lanes <Reference.reset_lanes>` at the start of an
episode of some lanes (random references draw from the generators handed over, children of the
environment's ``np_random``, so an episode is reproducible from its seed), and asked for ``r``
with :meth:`values(k, lanes) <Reference.values>` (``k`` one step per lane). The single-lane forms
``ref.reset(rng)`` and ``ref(k)`` are lane 0 of a one-lane reference: the same code. A user
reference is most easily a callable ``k -> r`` (:class:`CallableReference`);
:func:`~stcgym.envs.reference_specs.make_reference` builds one from a name, a number, an
array, a callable or a dict.
"""

from __future__ import annotations

import numbers
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.lanes.validation import integer, integer_range, non_negative, real_number

__all__ = [
    "Reference",
    "SquareWave",
    "Step",
    "Sine",
    "PRBS",
    "RandomSteps",
    "Zero",
    "ArrayReference",
    "CallableReference",
]

_LANE0 = np.zeros(1, dtype=np.int64)


def _repr(obj: object) -> str:
    """``Class(field=value, ...)`` of the public settings (not the per-lane state)."""
    fields = ", ".join(
        f"{k}={v!r}" for k, v in vars(obj).items() if not k.startswith("_") and k != "num_lanes"
    )
    return f"{type(obj).__name__}({fields})"


def _lanes(lanes: ArrayLike | None, num_lanes: int) -> NDArray[np.int64]:
    return np.arange(num_lanes) if lanes is None else np.asarray(lanes, dtype=np.int64)


# --------------------------------------------------------------------------------------------
# References
# --------------------------------------------------------------------------------------------
class Reference:
    """A scalar reference signal ``r(k)`` for a vector of lanes.

    Subclasses implement :meth:`values`; random ones also :meth:`allocate` and
    :meth:`reset_lanes` and set ``random = True`` (a vector env then hands every lane a
    generator at reset; deterministic references are never asked to draw). An environment
    copies the reference it is given, so one object may configure many environments.

    Examples
    --------
    A reference of your own needs only :meth:`values`, vectorised over ``k``:

    >>> import numpy as np
    >>> from stcgym.envs import Reference
    >>> class Staircase(Reference):
    ...     def values(self, k, lanes=None):
    ...         return (np.asarray(k) // 10).astype(float)
    >>> Staircase()(25)
    2.0

    The lane interface, as a vector env uses it (here three lanes at different steps):

    >>> from stcgym.envs import SquareWave
    >>> ref = SquareWave(period=4)
    >>> ref.allocate(3)
    >>> ref.values(np.array([0, 2, 3]))
    array([ 1., -1., -1.])
    """

    #: Whether :meth:`reset_lanes` uses its generators.
    random = False

    def allocate(self, num_lanes: int) -> None:
        """Allocate per-lane state for ``num_lanes`` lanes (deterministic references: none).

        Parameters
        ----------
        num_lanes : int
            Number of lanes ``B``; lane indices are ``0 .. B-1``.
        """
        self.num_lanes = int(num_lanes)

    def reset_lanes(self, lanes: NDArray, rngs: Sequence[np.random.Generator | None]) -> None:
        """Start a new episode in ``lanes`` (random references draw from ``rngs``).

        Parameters
        ----------
        lanes : ndarray of int
            Indices of the lanes that start an episode.
        rngs : sequence of numpy.random.Generator or None
            One generator per entry of ``lanes`` (``None`` for a deterministic reference).
        """

    def values(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        """``r(k[j])`` of lane ``lanes[j]``.

        Parameters
        ----------
        k : ndarray of int
            One step index per entry of ``lanes``.
        lanes : ndarray of int, optional
            Lane indices; ``None`` means all lanes ``0 .. B-1`` (then ``len(k) == B``).

        Returns
        -------
        ndarray of float
            Same shape as ``k``.
        """
        raise NotImplementedError  # pragma: no cover - abstract

    # single-lane convenience (lane 0 of a one-lane reference)
    def reset(self, rng: np.random.Generator) -> None:
        """Start a new episode of a one-lane reference (lane 0; allocates it if needed).

        Parameters
        ----------
        rng : numpy.random.Generator
            The episode's generator (used by random references only).
        """
        if getattr(self, "num_lanes", None) != 1:
            self.allocate(1)
        self.reset_lanes(_LANE0, [rng])

    def __call__(self, k: int) -> float:
        if getattr(self, "num_lanes", None) is None:
            self.allocate(1)
        return float(self.values(np.array([k], dtype=np.int64), _LANE0)[0])

    def __repr__(self) -> str:
        return _repr(self)


class SquareWave(Reference):
    """Square wave ("meander", the seeds' test signal) between ``offset +- amplitude``.

    ``r(k) = offset + amplitude`` during the first half of each period, ``offset - amplitude``
    during the second half (the seeds use unit amplitude, zero offset). The environments'
    default reference (``reference="square"``).

    Parameters
    ----------
    period : int, default 100
        Steps per period, an integer ``>= 2`` (the high half is ``k % period < period / 2``,
        so an odd period gives it the extra step).
    amplitude, offset : float, default 1.0 and 0.0
        Finite real numbers.

    Raises
    ------
    ValueError
        ``period`` not an integer ``>= 2``; ``amplitude`` or ``offset`` not finite.
    TypeError
        ``amplitude`` or ``offset`` not a real number.

    Examples
    --------
    >>> from stcgym.envs import SquareWave
    >>> ref = SquareWave(period=4, amplitude=2.0)
    >>> [ref(k) for k in range(6)]
    [2.0, 2.0, -2.0, -2.0, 2.0, 2.0]
    """

    def __init__(self, period: int = 100, amplitude: float = 1.0, offset: float = 0.0) -> None:
        self.period = integer(period, "period")
        if self.period < 2:
            raise ValueError(f"period must be at least 2 steps, got {period}")
        self.amplitude = real_number(amplitude, "amplitude")
        self.offset = real_number(offset, "offset")

    def values(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        first_half = (k % self.period) < self.period / 2
        return self.offset + np.where(first_half, self.amplitude, -self.amplitude)


class Step(Reference):
    """Step reference: ``r(k) = initial`` before step ``at``, ``amplitude`` from then on.

    Parameters
    ----------
    amplitude : float, default 1.0
        The value from step ``at`` on.
    at : int, default 0
        The step of the change, a non-negative integer (an integral float is accepted).
    initial : float, default 0.0
        The value before ``at``.

    Raises
    ------
    ValueError
        ``at`` negative or not integral; a value not finite.
    TypeError
        A value that is not a real number.

    Examples
    --------
    >>> from stcgym.envs import Step
    >>> ref = Step(2.0, at=3)
    >>> [ref(k) for k in range(5)]
    [0.0, 0.0, 0.0, 2.0, 2.0]
    """

    def __init__(self, amplitude: float = 1.0, at: int = 0, initial: float = 0.0) -> None:
        self.amplitude = real_number(amplitude, "amplitude")
        at_ = real_number(at, "at")
        if int(at_) != at_ or at_ < 0:
            raise ValueError(f"at must be a non-negative integer step, got {at!r}")
        self.at = int(at_)
        self.initial = real_number(initial, "initial")

    def values(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        return np.where(k >= self.at, self.amplitude, self.initial)


class Sine(Reference):
    """Sine reference: ``r(k) = offset + amplitude * sin(2 pi k / period + phase)``.

    Parameters
    ----------
    period : float, default 100.0
        Steps per period, ``> 0`` (need not be an integer).
    amplitude, phase, offset : float, default 1.0, 0.0, 0.0
        Finite real numbers; ``phase`` in radians.

    Raises
    ------
    ValueError
        ``period <= 0``; a value not finite.
    TypeError
        A value that is not a real number.

    Examples
    --------
    >>> import numpy as np
    >>> from stcgym.envs import Sine
    >>> ref = Sine(period=4, amplitude=2.0, offset=1.0)
    >>> np.round([ref(k) for k in range(4)], 6)
    array([ 1.,  3.,  1., -1.])
    """

    def __init__(
        self, period: float = 100.0, amplitude: float = 1.0, phase: float = 0.0, offset: float = 0.0
    ) -> None:
        self.period = real_number(period, "period")
        if self.period <= 0:
            raise ValueError(f"period must be positive, got {period}")
        self.amplitude = real_number(amplitude, "amplitude")
        self.phase = real_number(phase, "phase")
        self.offset = real_number(offset, "offset")

    def values(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        return self.offset + self.amplitude * np.sin(2 * np.pi * k / self.period + self.phase)


class _DrawnReference(Reference):
    """A random reference whose lanes draw as they reach new steps, each from a generator of
    its own made at reset from the one handed over (so that a lane draws exactly what the
    single-lane reference reset with the same generator draws); ``_count`` counts each lane's
    draws this episode. Before the first reset: the draws of generator seed 0."""

    random = True
    _CHUNK = 64

    def _start(self) -> None:
        self.allocate(1)
        self.reset_lanes(_LANE0, [np.random.default_rng(0)])

    def allocate(self, num_lanes: int) -> None:
        super().allocate(num_lanes)
        self._rngs: list[np.random.Generator | None] = [None] * self.num_lanes
        self._count = np.zeros(self.num_lanes, dtype=np.int64)

    def reset_lanes(self, lanes: NDArray, rngs: Sequence[np.random.Generator | None]) -> None:
        for i, g in zip(lanes, rngs, strict=True):
            self._rngs[i] = np.random.default_rng(g.integers(2**63))
            self._count[i] = 0


class PRBS(_DrawnReference):
    """Pseudo-random binary sequence: ``offset +- amplitude`` held for ``hold`` steps per bit.

    Each lane draws its bits from its own episode generator, 64 bits at a time as it reaches
    them, so the sequence changes with the seed, is identical for equal seeds, and a lane of a
    vector env draws exactly the bits of the single env with the same seed. Before its first
    :meth:`reset` the reference holds the bits of generator seed 0.

    Parameters
    ----------
    amplitude : float, default 1.0
        Half the distance between the two levels.
    hold : int, default 10
        Steps per bit, an integer ``>= 1``.
    offset : float, default 0.0
        The middle of the two levels.

    Raises
    ------
    ValueError
        ``hold`` not an integer ``>= 1``; a value not finite.
    TypeError
        ``amplitude`` or ``offset`` not a real number.

    Examples
    --------
    >>> import numpy as np
    >>> from stcgym.envs import PRBS
    >>> ref = PRBS(amplitude=0.5, hold=2)
    >>> ref.reset(np.random.default_rng(7))
    >>> r = np.array([ref(k) for k in range(8)])
    >>> sorted(set(r.tolist())), bool(np.all(r[0::2] == r[1::2]))  # each bit held 2 steps
    ([-0.5, 0.5], True)
    >>> again = PRBS(amplitude=0.5, hold=2)
    >>> again.reset(np.random.default_rng(7))
    >>> bool(np.all(r == [again(k) for k in range(8)]))  # equal seeds, equal bits
    True
    """

    def __init__(self, amplitude: float = 1.0, hold: int = 10, offset: float = 0.0) -> None:
        self.amplitude = real_number(amplitude, "amplitude")
        self.hold = integer(hold, "hold")
        self.offset = real_number(offset, "offset")
        self._start()

    def allocate(self, num_lanes: int) -> None:
        super().allocate(num_lanes)  # _count: bits drawn this episode
        self._bits = np.zeros((self.num_lanes, 0), dtype=np.int8)  # +-1 per lane

    def values(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        lanes = _lanes(lanes, self.num_lanes)
        j = np.asarray(k, dtype=np.int64) // self.hold
        short = j >= self._count[lanes]
        if short.any():
            self._draw(lanes[short], j[short])
        return self.offset + self.amplitude * self._bits[lanes, j].astype(float)

    def _draw(self, lanes: NDArray, j: NDArray) -> None:
        """Extend each lane's bits to cover bit ``j`` (``max(64, missing)`` new draws)."""
        need = int(j.max()) + 1
        if need > self._bits.shape[1]:
            grown = np.zeros((self.num_lanes, max(need, 2 * self._bits.shape[1])), np.int8)
            grown[:, : self._bits.shape[1]] = self._bits
            self._bits = grown
        for i, ji in zip(lanes, j, strict=True):
            c = int(self._count[i])
            if ji < c:  # the same lane asked twice in one call
                continue
            more = self._rngs[i].choice([-1, 1], size=max(self._CHUNK, int(ji) + 1 - c))
            end = c + more.size
            if end > self._bits.shape[1]:
                grown = np.zeros((self.num_lanes, 2 * end), np.int8)
                grown[:, : self._bits.shape[1]] = self._bits
                self._bits = grown
            self._bits[i, c:end] = more
            self._count[i] = end


class RandomSteps(_DrawnReference):
    """Random steps: a piecewise-constant ``r(k)`` with random levels held for random times.

    Each level is uniform in ``[offset - amplitude, offset + amplitude]`` and is held for a whole
    number of steps uniform in ``[hold_min, hold_max]`` (both ends included); the first level
    starts at ``k = 0``. Each lane draws its levels and holds from its own episode generator, 64
    of each at a time as it reaches them, so the signal changes with the seed, is identical for
    equal seeds, and a lane of a vector env draws exactly what the single env with the same seed
    draws. Before its first :meth:`reset` the reference holds the draws of generator seed 0.

    Parameters
    ----------
    amplitude : float, default 1.0
        Half the width of the level range, ``>= 0``.
    hold : int or (int, int), default (50, 150)
        Steps each level is held: ``[hold_min, hold_max]`` with ``1 <= hold_min <= hold_max``
        (a single integer: always that many).
    offset : float, default 0.0
        The middle of the level range.

    Raises
    ------
    ValueError
        ``amplitude`` negative; ``hold`` not an integer ``>= 1`` or a pair ``[low, high]`` of
        them with ``low <= high``; a value not finite.
    TypeError
        ``amplitude`` or ``offset`` not a real number.

    Examples
    --------
    >>> import numpy as np
    >>> from stcgym.envs import RandomSteps
    >>> ref = RandomSteps(amplitude=2.0, hold=(3, 5))
    >>> ref.reset(np.random.default_rng(1))
    >>> r = np.array([ref(k) for k in range(40)])
    >>> bool(np.all(np.abs(r) <= 2.0))
    True
    >>> changes = np.flatnonzero(np.diff(r)) + 1  # the steps where a new level starts
    >>> holds = np.diff(np.concatenate(([0], changes)))
    >>> bool(np.all((holds >= 3) & (holds <= 5)))
    True
    """

    def __init__(
        self, amplitude: float = 1.0, hold: int | Sequence[int] = (50, 150), offset: float = 0.0
    ) -> None:
        self.amplitude = non_negative(amplitude, "amplitude")
        self.hold = integer_range(hold, "hold")
        self.offset = real_number(offset, "offset")
        self._start()

    def allocate(self, num_lanes: int) -> None:
        super().allocate(num_lanes)  # _count: levels drawn this episode
        self._ends = np.zeros((self.num_lanes, self._CHUNK), dtype=np.int64)  # after level s
        self._levels = np.zeros((self.num_lanes, self._CHUNK))
        # The level in force at the step last asked, and its steps [start, stop): most steps
        # read these three arrays only.
        self._now = np.zeros(self.num_lanes)
        self._start = np.zeros(self.num_lanes, dtype=np.int64)
        self._stop = np.zeros(self.num_lanes, dtype=np.int64)

    def reset_lanes(self, lanes: NDArray, rngs: Sequence[np.random.Generator | None]) -> None:
        super().reset_lanes(lanes, rngs)
        self._start[lanes] = self._stop[lanes] = 0  # no level yet: the next look-up draws

    def values(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        lanes, k = _lanes(lanes, self.num_lanes), np.asarray(k, dtype=np.int64)
        if lanes.shape != k.shape:
            lanes, k = np.broadcast_arrays(lanes, k)
        out = self._now[lanes]
        moved = (k >= self._stop[lanes]) | (k < self._start[lanes])
        if moved.any():  # a new level (or a first or backward look-up)
            for j in np.flatnonzero(moved):
                out[j] = self._locate(int(lanes[j]), int(k[j]))
        return out

    def _locate(self, i: int, k: int) -> float:
        """The level of lane ``i`` in force at step ``k`` (remembered as the lane's current
        level), drawing levels as needed."""
        while self._count[i] == 0 or self._ends[i, self._count[i] - 1] <= k:
            self._draw(i)
        s = int(np.searchsorted(self._ends[i, : self._count[i]], k, side="right"))
        self._start[i] = self._ends[i, s - 1] if s else 0
        self._stop[i] = self._ends[i, s]
        self._now[i] = self._levels[i, s]
        return float(self._now[i])

    def _draw(self, i: int) -> None:
        """The next 64 levels and holds of lane ``i`` (levels first, then holds)."""
        c, n = int(self._count[i]), self._CHUNK
        if c + n > self._ends.shape[1]:
            width = 2 * self._ends.shape[1]
            self._ends = np.pad(self._ends, ((0, 0), (0, width - self._ends.shape[1])))
            self._levels = np.pad(self._levels, ((0, 0), (0, width - self._levels.shape[1])))
        rng, (lo, hi) = self._rngs[i], self.hold
        self._levels[i, c : c + n] = rng.uniform(
            self.offset - self.amplitude, self.offset + self.amplitude, n
        )
        start = self._ends[i, c - 1] if c else 0
        self._ends[i, c : c + n] = start + np.cumsum(rng.integers(lo, hi + 1, n))
        self._count[i] = c + n


class Zero(Reference):
    """Regulation: ``r(k) = 0`` (``reference="zero"`` or ``reference=None``).

    Examples
    --------
    >>> import numpy as np
    >>> from stcgym.envs import Zero
    >>> Zero().values(np.array([0, 5, 10]))
    array([0., 0., 0.])
    """

    def values(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        return np.zeros(np.shape(k))


class ArrayReference(Reference):
    """A user array: ``r(k) = values[k]``, the last value held after the array ends.

    Parameters
    ----------
    values : array_like
        Finite real numbers, at least one (flattened to 1-D). ``make_reference`` builds this
        from a list or array.

    Raises
    ------
    TypeError
        ``values`` is not numeric.
    ValueError
        ``values`` is empty or not finite.

    Examples
    --------
    >>> from stcgym.envs import ArrayReference
    >>> ref = ArrayReference([0.0, 1.0, 2.0])
    >>> [ref(k) for k in range(5)]
    [0.0, 1.0, 2.0, 2.0, 2.0]
    """

    def __init__(self, values: ArrayLike) -> None:
        try:
            arr = np.asarray(values, dtype=float).ravel()
        except (TypeError, ValueError) as exc:
            raise TypeError(
                f"reference must be a number, a 1-D array of numbers, a name, a dict, a "
                f"callable or a Reference; got {values!r}"
            ) from exc
        if arr.size == 0 or not np.all(np.isfinite(arr)):
            raise ValueError("reference array must be non-empty and finite")
        self.table = arr

    def values(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        return self.table[np.minimum(k, self.table.size - 1)]

    def __repr__(self) -> str:
        return f"ArrayReference(<{self.table.size} values>)"


class CallableReference(Reference):
    """A user function ``k -> r(k)``; its result must be a finite real number.

    Called once per lane and step, so prefer the built-in references for large vector envs. A
    result that is not a finite number raises ``ValueError`` naming the reference, before the
    environment's state changes. An environment deep-copies its reference: keep ``fn`` free of
    state that must be shared.

    Parameters
    ----------
    fn : callable (int) -> float
        Called with the step index ``k``; returns a finite real number (a one-element array
        is accepted).

    Raises
    ------
    ValueError
        When called: ``fn`` returned something other than a finite real number.

    Examples
    --------
    >>> from stcgym.envs import CallableReference
    >>> ref = CallableReference(lambda k: 0.5 * k)
    >>> ref(4)
    2.0
    >>> CallableReference(lambda k: "high")(0)
    Traceback (most recent call last):
        ...
    ValueError: reference callable must return a finite real number, got 'high' at step 0
    """

    def __init__(self, fn: Callable[[int], float]) -> None:
        self.fn = fn

    def values(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        flat = np.asarray(k).ravel()
        out = np.empty(flat.size)
        for j, kj in enumerate(flat):
            r = self.fn(int(kj))
            if isinstance(r, np.ndarray) and r.size == 1:
                r = r.reshape(())[()]
            if isinstance(r, (str, bytes, bool)) or not isinstance(r, (numbers.Real, np.number)):
                raise ValueError(
                    f"reference callable must return a finite real number, got {r!r} at step {kj}"
                )
            out[j] = float(r)
            if not np.isfinite(out[j]):
                raise ValueError(f"reference callable returned a non-finite value {r} at step {kj}")
        return out.reshape(np.shape(k))
