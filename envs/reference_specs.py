"""A :class:`~stcgym.envs.references.Reference` from a flexible specification: a name, a dict,
a number, an array, a callable or a reference (:func:`make_reference`), one a channel
(:func:`make_references`).
"""

from __future__ import annotations

import copy
import numbers
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from stcgym.envs.references import (
    PRBS,
    ArrayReference,
    CallableReference,
    RandomSteps,
    Reference,
    Sine,
    SquareWave,
    Step,
    Zero,
)
from stcgym.lanes.validation import real_number

__all__ = ["make_reference", "make_references"]

_REFERENCES: dict[str, type[Reference]] = {
    "square": SquareWave,
    "meander": SquareWave,
    "step": Step,
    "sine": Sine,
    "prbs": PRBS,
    "random_steps": RandomSteps,
    "zero": Zero,
}


def make_reference(spec: Any = "square", **kwargs: Any) -> Reference:
    """Build a :class:`Reference` from a flexible specification.

    Parameters
    ----------
    spec : Reference, str, dict, float, array_like, callable or None, default "square"
        A :class:`Reference` (copied, so that envs never share per-lane state); a name
        (``"square"``/``"meander"``, ``"step"``, ``"sine"``, ``"prbs"``,
        ``"random_steps"``, ``"zero"``, case-insensitive) with keyword arguments for it; a
        dict ``{"kind": name, ...}``; a number (constant reference); a 1-D array
        (:class:`ArrayReference`, held at its last value); a callable ``k -> r``
        (:class:`CallableReference`); ``None`` (:class:`Zero`).
    **kwargs
        Arguments of the named reference's class (:class:`SquareWave`, :class:`Step`,
        :class:`Sine`, :class:`PRBS`, :class:`RandomSteps`).

    Returns
    -------
    Reference
        A new object.

    Raises
    ------
    ValueError, TypeError
        Naming ``reference`` (or the offending parameter) and the expected form: an unknown
        name, a dict without ``"kind"``, an argument the named class does not take or rejects.

    Examples
    --------
    >>> from stcgym.envs import make_reference
    >>> make_reference("sine", period=50)
    Sine(period=50.0, amplitude=1.0, phase=0.0, offset=0.0)
    >>> make_reference({"kind": "step", "at": 10})
    Step(amplitude=1.0, at=10, initial=0.0)
    >>> make_reference(0.5)(7)  # a constant
    0.5
    >>> make_reference("triangle")
    Traceback (most recent call last):
        ...
    ValueError: reference must be one of ['meander', 'prbs', 'random_steps', 'sine', ...], ...
    """
    if isinstance(spec, Reference):
        return copy.deepcopy(spec)
    if spec is None:
        return Zero()
    if isinstance(spec, str):
        key = spec.lower()
        if key not in _REFERENCES:
            raise ValueError(
                f"reference must be one of {sorted(_REFERENCES)}, a number, an array, a "
                f"callable or a Reference; got {spec!r}"
            )
        try:
            return _REFERENCES[key](**kwargs)
        except TypeError as exc:
            if "argument" not in str(exc):
                raise
            raise TypeError(f"reference {key!r}: {exc}") from exc
    if isinstance(spec, Mapping):
        params = dict(spec)
        kind = params.pop("kind", None)
        if not isinstance(kind, str):
            raise ValueError(
                f"a reference dict needs a 'kind' entry naming one of {sorted(_REFERENCES)}, "
                f"e.g. {{'kind': 'square'}}; got {spec!r}"
            )
        return make_reference(kind, **params, **kwargs)
    if callable(spec):
        return CallableReference(spec)
    if isinstance(spec, (numbers.Real, np.number)) and not isinstance(spec, bool):
        value = real_number(spec, "reference")
        return Step(amplitude=value, at=0, initial=value)
    if isinstance(spec, (Sequence, np.ndarray)) and not isinstance(spec, bytes):
        return ArrayReference(spec)
    raise TypeError(
        f"reference must be a name {sorted(_REFERENCES)}, a dict with 'kind', a number, a 1-D "
        f"array, a callable k -> r or a Reference; got {spec!r}"
    )


def make_references(spec: Any, count: int) -> list[Reference]:
    """One reference per output channel.

    A list or tuple of exactly ``count`` specs gives one per channel (with ``count == 1`` only
    when its entry is not a number: ``[0.5]`` is a one-value array); any other spec is built
    once and copied, so that random references draw independent bits per channel.
    """
    if isinstance(spec, (list, tuple)) and len(spec) == count:
        numbers_only = all(isinstance(s, (numbers.Real, np.number)) for s in spec)
        if count > 1 or not numbers_only:  # a one-channel list of specs, not an array
            return [make_reference(s) for s in spec]
    ref = make_reference(spec)
    return [ref] + [copy.deepcopy(ref) for _ in range(count - 1)]
