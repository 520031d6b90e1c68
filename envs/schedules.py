"""Parameter schedules of the stcgym environments: jumps, ramps and drift, for a vector of lanes.

A :class:`Schedule` is allocated for ``B`` lanes, reset with each lane's nominal parameter array
(theta of a canonical plant, ``[A B]`` of a state-space plant, ``Theta`` of the static object)
and asked for the parameters in force with :meth:`values(k, lanes) <Schedule.values>`; ``k``
never decreases within a lane's episode. :meth:`~Schedule.next_change` tells when a lane's
parameters may change next, so a vector env re-reads only lanes whose parameters move. The
single-lane forms ``schedule.reset(nominal, rng)`` and ``schedule(k)`` are lane 0 of a one-lane
schedule. A user schedule subclasses :class:`Schedule` and implements
:meth:`~Schedule.reset_lanes` and :meth:`~Schedule.values` (see :class:`Ramp` for a short
example).
"""

from __future__ import annotations

import copy
import numbers
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.envs.references import _LANE0, _lanes, _repr
from stcgym.lanes.validation import finite_array, integer_range, real_in, real_number

__all__ = [
    "NEVER",
    "Schedule",
    "Constant",
    "Jumps",
    "RandomJump",
    "Ramp",
    "RandomWalk",
    "make_schedule",
]

#: ``next_change`` of a lane whose parameters never change again.
NEVER = int(np.iinfo(np.int64).max)


class Schedule:
    """Parameters in force at step ``k``, per lane: a function of the lane's nominal array and k.

    The value for step ``k`` governs the transition from ``k`` to ``k + 1``. The base class holds
    each lane's nominal parameters (``_nominal``, shape ``(B, *shape)``) and returns them;
    subclasses override :meth:`values` (and :meth:`reset_lanes` if they keep more per-lane
    state) and :meth:`next_change`. The parameter array is the environment's: ``theta = [a; b]``
    of a canonical plant, ``[A B]`` of a state-space plant, ``Theta`` of the static object.

    Examples
    --------
    A schedule of your own: the gain ``b`` of a first-order plant halves at step 5.

    >>> import numpy as np
    >>> from stcgym.envs import Schedule
    >>> class HalveGain(Schedule):
    ...     def values(self, k, lanes=None):
    ...         theta = super().values(k, lanes)  # nominal, one row per lane
    ...         theta[np.asarray(k) >= 5, 1] *= 0.5
    ...         return theta
    >>> schedule = HalveGain()
    >>> schedule.reset(np.array([-0.9, 1.0]), np.random.default_rng(0))
    >>> schedule(4), schedule(5)
    (array([-0.9,  1. ]), array([-0.9,  0.5]))

    Passed as ``schedule=`` to an environment, it acts on the episode's parameters:

    >>> import gymnasium as gym
    >>> import stcgym.envs
    >>> env = gym.make(
    ...     "stcgym/ObserverCanonical-v0", a=[-0.9], b=[1.0], schedule=HalveGain()
    ... )
    >>> _ = env.reset(seed=0)
    >>> for _ in range(5):
    ...     _, _, _, _, info = env.step(np.array([0.0]))
    >>> info["theta"]
    array([-0.9,  0.5])
    """

    def allocate(self, num_lanes: int) -> None:
        """Prepare per-lane state for ``num_lanes`` lanes (allocated at the first reset).

        Parameters
        ----------
        num_lanes : int
            Number of lanes ``B``.
        """
        self.num_lanes = int(num_lanes)
        self._nominal: NDArray | None = None

    def reset_lanes(
        self, lanes: NDArray, nominal: NDArray, rngs: Sequence[np.random.Generator | None]
    ) -> None:
        """New episode in ``lanes`` with nominal parameters ``nominal`` (one row per lane).

        Parameters
        ----------
        lanes : ndarray of int
            Indices of the lanes that start an episode.
        nominal : ndarray, shape (len(lanes), ...)
            Each lane's nominal parameter array.
        rngs : sequence of numpy.random.Generator or None
            One generator per entry of ``lanes`` (random schedules draw from it).

        Raises
        ------
        ValueError
            A subclass's parameters do not match the shape of ``nominal`` (e.g. a
            :class:`Jumps` array for another plant order).
        """
        nominal = np.asarray(nominal, dtype=float)
        shape = nominal.shape[1:]
        if self._nominal is None or self._nominal.shape[1:] != shape:
            self._nominal = np.zeros((self.num_lanes, *shape))
        self._nominal[lanes] = nominal

    def values(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        """Parameters in force at step ``k[j]`` for lane ``lanes[j]``.

        Parameters
        ----------
        k : ndarray of int
            One step index per entry of ``lanes``; never decreasing within a lane's episode.
        lanes : ndarray of int, optional
            Lane indices; ``None`` means all lanes.

        Returns
        -------
        ndarray, shape (len(lanes), ...)
            One parameter array per entry of ``lanes`` (a new array).
        """
        return self._nominal[_lanes(lanes, self.num_lanes)].copy()

    def next_change(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        """First step after ``k[j]`` at which lane ``lanes[j]`` may get other parameters.

        Parameters
        ----------
        k : ndarray of int
            One step index per entry of ``lanes``.
        lanes : ndarray of int, optional
            Lane indices; ``None`` means all lanes.

        Returns
        -------
        ndarray of int64
            Like ``k``; :data:`NEVER` for a lane whose parameters stay as they are. The base
            class answers ``k + 1`` (a change may come at any step).
        """
        return np.asarray(k, dtype=np.int64) + 1

    @property
    def time_varying(self) -> bool:
        """Whether the parameters may change within an episode (``False`` lets a loop skip
        :meth:`values` after the reset)."""
        return True

    # single-lane convenience (lane 0 of a one-lane schedule)
    def reset(self, nominal: NDArray, rng: np.random.Generator) -> None:
        """Start a new episode of a one-lane schedule with nominal parameters ``nominal``.

        Parameters
        ----------
        nominal : array_like
            The episode's nominal parameter array.
        rng : numpy.random.Generator
            The episode's generator (used by random schedules only).
        """
        if getattr(self, "num_lanes", None) != 1:
            self.allocate(1)
        self.reset_lanes(_LANE0, np.asarray(nominal, dtype=float)[None], [rng])

    def __call__(self, k: int) -> NDArray:
        return self.values(np.array([k], dtype=np.int64), _LANE0)[0]

    def __repr__(self) -> str:
        return _repr(self)


class Constant(Schedule):
    """Time-invariant plant: the nominal parameters throughout (``schedule=None``).

    Examples
    --------
    >>> import numpy as np
    >>> from stcgym.envs import Constant
    >>> schedule = Constant()
    >>> schedule.reset(np.array([-0.9, 1.0]), np.random.default_rng(0))
    >>> schedule(1000), schedule.time_varying
    (array([-0.9,  1. ]), False)
    """

    def next_change(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        return np.full(np.shape(k), NEVER, dtype=np.int64)

    @property
    def time_varying(self) -> bool:
        return False


def _check_shape(value: ArrayLike, like: tuple[int, ...], name: str) -> NDArray:
    arr = finite_array(value, name)
    if arr.shape != like:
        raise ValueError(
            f"{name} must have the shape of the plant parameters {like}, got {arr.shape}"
        )
    return arr


class Jumps(Schedule):
    """Abrupt parameter changes: ``{step: new_parameters}`` (or a sequence of pairs).

    From step ``k_i`` on, the plant uses the ``i``-th array (same shape as the nominal one).
    ``make_schedule`` builds this from a dict.

    Parameters
    ----------
    changes : mapping of int to array_like, or sequence of (int, array_like)
        At least one pair; steps are non-negative integers (sorted here), arrays finite. Their
        shape is checked against the nominal parameters at each reset.

    Raises
    ------
    TypeError
        ``changes`` is neither a mapping nor a sequence of pairs.
    ValueError
        No pair; a step that is not a non-negative integer; an array not finite; at reset, an
        array whose shape differs from the nominal parameters'.

    Examples
    --------
    The catalogue's ``timevarying2``: ``stable2`` until step 1000, then new parameters.

    >>> import numpy as np
    >>> from stcgym.envs import Jumps
    >>> schedule = Jumps({1000: [-1.2, 0.52, 0.9, 0.3]})
    >>> schedule.reset(np.array([-1.5, 0.7, 1.0, 0.5]), np.random.default_rng(0))
    >>> schedule(999), schedule(1000)
    (array([-1.5,  0.7,  1. ,  0.5]), array([-1.2 ,  0.52,  0.9 ,  0.3 ]))
    >>> int(schedule.next_change(np.array([0]))[0])
    1000
    """

    def __init__(self, changes: Mapping[int, ArrayLike] | Sequence[tuple[int, ArrayLike]]):
        try:
            items = list(changes.items()) if isinstance(changes, Mapping) else list(changes)
            items = [(k, v) for k, v in items]
        except (TypeError, ValueError) as exc:
            raise TypeError(
                f"schedule changes must be {{step: parameters}} or (step, parameters) pairs, "
                f"got {changes!r}"
            ) from exc
        if not items:
            raise ValueError("schedule changes must name at least one (step, parameters) pair")
        for k, _ in items:
            if isinstance(k, (str, bytes, bool)) or not isinstance(k, (numbers.Real, np.number)):
                raise ValueError(f"schedule jump steps must be non-negative integers, got {k!r}")
            if not np.isfinite(k) or int(k) != k or k < 0:
                raise ValueError(f"schedule jump steps must be non-negative integers, got {k!r}")
        self.changes = sorted(
            (
                (int(k), _check_shape(v, np.shape(v), f"schedule parameters at step {k}"))
                for k, v in items
            ),
            key=lambda kv: kv[0],
        )
        self._steps = np.array([k for k, _ in self.changes], dtype=np.int64)

    def reset_lanes(
        self, lanes: NDArray, nominal: NDArray, rngs: Sequence[np.random.Generator | None]
    ) -> None:
        super().reset_lanes(lanes, nominal, rngs)
        shape = self._nominal.shape[1:]
        self._table = np.stack(
            [_check_shape(v, shape, f"parameters at step {k}") for k, v in self.changes]
        )

    def values(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        lanes = _lanes(lanes, self.num_lanes)
        i = np.searchsorted(self._steps, k, side="right")
        out = self._nominal[lanes].copy()
        jumped = i > 0
        out[jumped] = self._table[i[jumped] - 1]
        return out

    def next_change(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        i = np.searchsorted(self._steps, k, side="right")
        later = np.append(self._steps, NEVER)
        return later[i]


class RandomJump(Schedule):
    """One jump to ``after`` at a random step, in a random share of the episodes.

    At each reset every lane draws from its episode's schedule generator, in this order,
    whether its episode has the jump (with probability ``probability``) and the jump step, an
    integer uniform in ``[at_low, at_high]`` (both draws are made whether or not the episode
    jumps, so the stream use does not depend on the outcome). From that step on the lane's
    parameters are ``after``; before it (and throughout an episode without the jump) the
    nominal ones.

    Parameters
    ----------
    after : array_like
        The parameters after the jump: finite, the shape of the plant's parameter array
        (checked at each reset).
    at : int or (int, int)
        The jump step, or a range ``[low, high]`` of steps (integers, ``0 <= low <= high``).
    probability : float, default 1.0
        The chance that an episode has the jump, in ``[0, 1]``.

    Raises
    ------
    ValueError
        ``at`` not a non-negative integer or a range of them with ``low <= high``;
        ``probability`` outside ``[0, 1]``; ``after`` not finite, or (at reset) not of the
        parameters' shape.
    TypeError
        ``probability`` not a real number.

    Examples
    --------
    >>> import numpy as np
    >>> from stcgym.envs import RandomJump
    >>> schedule = RandomJump(after=[-0.5, 2.0], at=(10, 20), probability=1.0)
    >>> schedule.reset(np.array([-0.9, 1.0]), np.random.default_rng(0))
    >>> step = int(schedule.next_change(np.array([0]))[0])
    >>> 10 <= step <= 20, schedule(step - 1), schedule(step)
    (True, array([-0.9,  1. ]), array([-0.5,  2. ]))
    """

    def __init__(self, after: ArrayLike, at: int | Sequence[int], probability: float = 1.0):
        self.after = _check_shape(after, np.shape(after), "after")
        self.at = integer_range(at, "at", minimum=0)
        self.probability = real_in(probability, "probability", 0.0, 1.0)

    def allocate(self, num_lanes: int) -> None:
        super().allocate(num_lanes)
        self._step = np.full(self.num_lanes, NEVER, dtype=np.int64)
        self._after: NDArray | None = None

    def _targets(self, lanes: NDArray, nominal: NDArray) -> NDArray:
        """The parameters after the jump of ``lanes`` (one row per lane, like ``nominal``)."""
        return np.broadcast_to(_check_shape(self.after, nominal.shape[1:], "after"), nominal.shape)

    def reset_lanes(
        self, lanes: NDArray, nominal: NDArray, rngs: Sequence[np.random.Generator | None]
    ) -> None:
        super().reset_lanes(lanes, nominal, rngs)
        shape = self._nominal.shape[1:]
        targets = self._targets(np.asarray(lanes), self._nominal[lanes])
        if self._after is None or self._after.shape[1:] != shape:
            self._after = np.zeros((self.num_lanes, *shape))
        self._after[lanes] = targets
        low, high = self.at
        for i, g in zip(lanes, rngs, strict=True):
            happens = g.random() < self.probability
            step = int(g.integers(low, high + 1))
            self._step[i] = step if happens else NEVER

    def values(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        lanes = _lanes(lanes, self.num_lanes)
        out = self._nominal[lanes].copy()
        jumped = np.asarray(k) >= self._step[lanes]
        out[jumped] = self._after[lanes[jumped]]
        return out

    def next_change(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        step = self._step[_lanes(lanes, self.num_lanes)]
        return np.where(np.asarray(k, dtype=np.int64) < step, step, NEVER)


class Ramp(Schedule):
    """Slow linear drift from the nominal parameters to ``target`` over steps start..stop.

    ``theta(k) = nominal + s(k) (target - nominal)`` with ``s(k) = (k - start) / (stop -
    start)`` clipped to ``[0, 1]``: the nominal parameters up to ``start``, ``target`` from
    ``stop`` on.

    Parameters
    ----------
    target : array_like
        Finite; the shape of the plant's parameter array (checked at each reset).
    start, stop : int
        Integer steps with ``0 <= start < stop``.

    Raises
    ------
    ValueError
        ``start``/``stop`` not integers with ``0 <= start < stop``; ``target`` not finite, or
        (at reset) not of the parameters' shape.
    TypeError
        ``start`` or ``stop`` not a real number.

    Examples
    --------
    >>> import numpy as np
    >>> from stcgym.envs import Ramp
    >>> schedule = Ramp(target=[-0.5, 2.0], start=10, stop=14)
    >>> schedule.reset(np.array([-0.9, 1.0]), np.random.default_rng(0))
    >>> np.array([schedule(k) for k in (10, 12, 14, 20)])
    array([[-0.9,  1. ],
           [-0.7,  1.5],
           [-0.5,  2. ],
           [-0.5,  2. ]])
    """

    def __init__(self, target: ArrayLike, start: int, stop: int) -> None:
        s0, s1 = real_number(start, "start"), real_number(stop, "stop")
        if int(s0) != s0 or int(s1) != s1 or not 0 <= s0 < s1:
            raise ValueError(
                f"need integer steps 0 <= start < stop, got start={start}, stop={stop}"
            )
        self.target = _check_shape(target, np.shape(target), "target")
        self.start, self.stop = int(s0), int(s1)

    def reset_lanes(
        self, lanes: NDArray, nominal: NDArray, rngs: Sequence[np.random.Generator | None]
    ) -> None:
        super().reset_lanes(lanes, nominal, rngs)
        self._target = _check_shape(self.target, self._nominal.shape[1:], "target")

    def values(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        lanes = _lanes(lanes, self.num_lanes)
        s = np.clip((np.asarray(k) - self.start) / (self.stop - self.start), 0.0, 1.0)
        nom = self._nominal[lanes]
        s = s.reshape(s.shape + (1,) * (nom.ndim - 1))
        return nom + s * (self._target - nom)

    def next_change(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        k = np.asarray(k, dtype=np.int64)
        return np.where(k < self.stop, np.maximum(k + 1, self.start + 1), NEVER)


class RandomWalk(Schedule):
    """Random-walk drift: each step after ``start`` adds ``N(0, std^2)`` to the masked entries.

    ``mask`` (boolean, the parameters' shape) selects which entries drift; by default all. Each
    lane walks with its own generator. The walk can make a plant unstable; the environment's
    divergence bound ends such an episode.

    Parameters
    ----------
    std : float
        Standard deviation of one step's increment, ``>= 0``.
    start : int, default 0
        The last step with the nominal parameters (a non-negative integer).
    mask : array_like of bool, optional
        Which entries drift (the parameters' shape, checked at each reset); ``None``: all.

    Raises
    ------
    ValueError
        ``std`` negative or not finite; ``start`` not a non-negative integer; at reset, a
        ``mask`` of the wrong shape.
    TypeError
        ``std`` or ``start`` not a real number.

    Examples
    --------
    Only ``b`` drifts, from step 10 on; the same generator gives the same walk:

    >>> import numpy as np
    >>> from stcgym.envs import RandomWalk
    >>> schedule = RandomWalk(std=0.01, start=10, mask=[False, True])
    >>> schedule.reset(np.array([-0.9, 1.0]), np.random.default_rng(1))
    >>> schedule(10)
    array([-0.9,  1. ])
    >>> theta = schedule(500)
    >>> float(theta[0]), bool(theta[1] != 1.0)
    (-0.9, True)
    """

    def __init__(self, std: float, start: int = 0, mask: ArrayLike | None = None) -> None:
        self.std = real_number(std, "std")
        if self.std < 0:
            raise ValueError(f"std must be non-negative, got {std}")
        s0 = real_number(start, "start")
        if int(s0) != s0 or s0 < 0:
            raise ValueError(f"start must be a non-negative integer step, got {start!r}")
        self.start = int(s0)
        self.mask = None if mask is None else np.asarray(mask, dtype=bool)

    def allocate(self, num_lanes: int) -> None:
        super().allocate(num_lanes)
        self._rngs: list[np.random.Generator | None] = [None] * self.num_lanes
        self._k = np.zeros(self.num_lanes, dtype=np.int64)
        self._value: NDArray | None = None

    def reset_lanes(
        self, lanes: NDArray, nominal: NDArray, rngs: Sequence[np.random.Generator | None]
    ) -> None:
        super().reset_lanes(lanes, nominal, rngs)
        shape = self._nominal.shape[1:]
        self._mask = np.ones(shape, bool) if self.mask is None else self.mask
        if self._mask.shape != shape:
            raise ValueError(f"mask must have shape {shape}, got {self._mask.shape}")
        if self._value is None or self._value.shape[1:] != shape:
            self._value = np.zeros((self.num_lanes, *shape))
        for i, g in zip(lanes, rngs, strict=True):
            self._rngs[i] = np.random.default_rng(g.integers(2**63))
        self._k[lanes] = self.start
        self._value[lanes] = self._nominal[lanes]

    def values(self, k: NDArray, lanes: NDArray | None = None) -> NDArray:
        lanes = _lanes(lanes, self.num_lanes)
        k = np.asarray(k, dtype=np.int64)
        out = np.empty((len(lanes), *self._value.shape[1:]))
        for j, (i, ki) in enumerate(zip(lanes, k, strict=True)):
            rng, value = self._rngs[i], self._value[i]
            while self._k[i] < ki:
                self._k[i] += 1
                value = value + self.std * rng.standard_normal(value.shape) * self._mask
            self._value[i] = out[j] = value
        return out


def make_schedule(spec: Any) -> Schedule:
    """Build a :class:`Schedule` from ``None``/``"constant"``, a Schedule, or ``{step: params}``.

    A given Schedule is copied, so that envs never share per-lane state.

    Parameters
    ----------
    spec : Schedule, dict, "constant" or None
        ``None`` or ``"constant"`` (case-insensitive): :class:`Constant`; a :class:`Schedule`:
        a deep copy; a dict ``{step: parameters}``: :class:`Jumps`.

    Returns
    -------
    Schedule
        A new object.

    Raises
    ------
    TypeError
        Any other ``spec``.
    ValueError
        A dict that :class:`Jumps` rejects.

    Examples
    --------
    >>> from stcgym.envs import make_schedule
    >>> make_schedule(None)
    Constant()
    >>> make_schedule({100: [-1.2, 0.9]})
    Jumps(changes=[(100, array([-1.2,  0.9]))])
    """
    if spec is None or (isinstance(spec, str) and spec.lower() == "constant"):
        return Constant()
    if isinstance(spec, Schedule):
        return copy.deepcopy(spec)
    if isinstance(spec, Mapping):
        return Jumps(spec)
    raise TypeError(
        f"schedule must be None, 'constant', a Schedule (Jumps, Ramp, RandomWalk) or a dict "
        f"{{step: parameters}}, got {spec!r}"
    )
