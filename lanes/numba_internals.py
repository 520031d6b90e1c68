"""The numba internals stcgym relies on, in one module; each assumption has its own test.

Everything else in stcgym uses numba's public surface (``numba.njit`` and its documented options,
``numba.typeof``, the dispatcher's ``py_func`` and ``stats``). What follows has no public
equivalent; ``pyproject.toml`` bounds numba to the releases the test suite passed on, and
``tests/test_numba_internals.py`` checks every assumption below, so a numba release that
breaks one fails there, by name:

* :func:`dispatcher`: a cached CPU dispatcher compiled without numba's reference-counting
  runtime (the ``_nrt`` option: lane functions never allocate, and the counters of array
  views contend between threads), without the cfunc wrapper, and for helpers without the
  CPython wrapper (``no_cpython_wrapper``); a helper is a :class:`HelperDispatcher`, whose
  Python call raises instead of jumping to a null address.
* :func:`entry_point`: the machine code compiled for given argument types, called without
  numba's typing of every argument (``Dispatcher.compile``).
* :class:`CompileListener`, :func:`listen_to_compiles`: numba's ``numba:compile`` events
  (``numba.core.event``, described in numba's developer manual).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba
from numba.core import event
from numba.core.registry import CPUDispatcher

__all__ = [
    "CompileListener",
    "HelperDispatcher",
    "dispatcher",
    "entry_point",
    "listen_to_compiles",
]

#: numba's event listener base class (``on_start`` / ``on_end`` receive an event whose
#: ``data["dispatcher"]`` is the function being compiled).
CompileListener = event.Listener


def listen_to_compiles(listener: event.Listener, listen: bool = True) -> None:
    """Register ``listener`` for numba's ``numba:compile`` events (every compile, nested
    ones included); ``listen=False`` removes it again."""
    if listen:
        event.register("numba:compile", listener)
    else:
        event.unregister("numba:compile", listener)


class HelperDispatcher(CPUDispatcher):
    """A function compiled for other compiled functions only: numba builds no CPython
    wrapper for it, so calling it from Python would jump to a null address; this class
    raises instead."""

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        raise TypeError(
            f"{self.py_func.__module__}.{self.py_func.__qualname__} is a lane helper, "
            "compiled to be called from other lane functions only (declare it with "
            "@lane(entry=True) to call it from Python)"
        )


def dispatcher(
    fn: Callable[..., Any], options: dict[str, Any], *, nrt: bool, helper: bool, cache: bool = True
) -> Any:
    """``fn`` as a cached nopython dispatcher with the public ``numba.njit`` ``options``
    (``nogil``, ``error_model``, ``forceinline``, ``inline``...), and two internal choices:
    ``nrt=False`` compiles it without the reference-counting runtime (an allocation is then a
    compile error), ``helper=True`` without the CPython wrapper (a :class:`HelperDispatcher`).
    numba's cfunc wrapper (for first-class function use) is never built. ``cache``: numba's
    on-disk cache, as ``numba.njit(cache=True)``."""
    targetoptions = {"nopython": True, **options, "no_cfunc_wrapper": True}
    if not nrt:
        targetoptions["_nrt"] = False
    if helper:
        targetoptions["no_cpython_wrapper"] = True
    cls = HelperDispatcher if helper else CPUDispatcher
    result = cls(py_func=fn, locals={}, targetoptions=targetoptions)
    if cache:
        result.enable_caching()
    return result


def entry_point(compiled: Any, arg_types: tuple) -> Callable[..., Any]:
    """The machine code of the dispatcher ``compiled`` for the numba types ``arg_types`` (from
    numba's cache, or compiled now): a callable that converts its arguments for those types
    without typing them again (so it must only ever see arguments of those types)."""
    return compiled.compile(tuple(arg_types))


def jit_disabled() -> bool:
    """``NUMBA_DISABLE_JIT=1``: decorators return the plain Python functions."""
    return bool(numba.config.DISABLE_JIT)
