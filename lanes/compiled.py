"""Compiled lane functions: how every step of stcgym is written once and run for 1 or B plants.

Convention (shared by the plant step in :mod:`stcgym.envs`, the estimators and the self-tuning
controller in :mod:`stcgym.adaptive`):

* A **lane function** advances *one* plant (or estimator, or controller) by one step. It is
  decorated with :func:`lane`, works on the arrays of that one lane (1-D views), mutates them in
  place and returns plain numbers (a status code, an output). It contains the paper's equations
  and nothing about batching. Lane functions that Python calls are ``@lane(entry=True)``; the
  others are helpers of lane functions and raise ``TypeError`` if Python calls them.
* The **lane state** of a step is a ``typing.NamedTuple`` of batched arrays: field ``f`` of
  lane ``i`` is ``state.f[i]``, a row view, and the lane function reads it by name
  (``s.theta[lane]``, ``w.K[lane]``). Each field is declared once, with its shape in a shapes
  function of the step (e.g. ``controller_shapes``); :func:`lane_state` builds the batch, a
  field a configuration does not use has a zero in its shape, counters are ``int64`` and flags
  ``bool``. Scratch is the same kind of tuple (:func:`make_work`; a scratch made of named
  parts is built with :func:`fields_of`), one row a lane, every field its own memory. The
  configuration of a lane function is a ``NamedTuple`` too (int, float, bool fields and 1-D
  ``float64`` arrays: ``cfg.n``, ``cfg.alpha``). numba types all of them by their fields'
  types and dimensions, not their values or sizes, so one compiled function serves every
  order; reset, copy, pickle and memory accounting are plain array operations.
* A **batch loop** is decorated with :func:`lanes` and is nothing but
  ``for i in range(first, last): lane_fn(s, w, i, ...)``: its last two parameters are a range
  of lanes, which its Python caller leaves out (``loop(s, ...)`` runs every row of the first
  argument, or of its first field; a large batch is split into blocks of rows run on several
  threads, :class:`LaneLoop`). A single plant calls the same lane function on lane 0 of a
  one-lane state, so a single plant equals lane ``i`` of a batch **bit for bit by
  construction**, on any CPU and any number of threads: the same compiled machine code runs on
  the same numbers (no BLAS, no LAPACK inside lane functions; small dense loops are written
  out).

Compilation is lazy (first call) and cached on disk (``cache=True``), so importing stcgym
compiles nothing and a second process starts fast. A compile that is still running after
:data:`COMPILE_NOTICE_AFTER` seconds is announced once per process, on the ``stcgym`` logger
(:class:`CompileNotice`). ``NUMBA_DISABLE_JIT=1`` runs the very same source as plain Python
(slow, but debuggable with pdb and coverage). Where the cache lives and why an edited kernel
never runs stale machine code: :mod:`stcgym.lanes.kernel_cache`.
"""

from __future__ import annotations

import functools
import inspect
import logging
import os
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

import numba
import numpy as np
from numba.extending import overload
from numpy.typing import NDArray

from stcgym.lanes import numba_internals as internals
from stcgym.lanes.kernel_cache import guard_cache

F = TypeVar("F", bound=Callable[..., Any])
R = TypeVar("R", bound=tuple)

#: Seconds after which a compile of stcgym kernels still running is announced (once a process).
COMPILE_NOTICE_AFTER = 1.0
#: What the notice says a first run costs, in seconds: the first
#: ``SelfTuningController(2).predict`` with an empty cache took 17 s on an idle 2-core machine,
#: 16-18 s at load 4.5-4.9 and up to 36 s under heavier load (the first-run page).
#: A second estimator family or design adds 3-13 s when first used.
FIRST_RUN_SECONDS = (15, 40)

logger = logging.getLogger("stcgym")


class CompileNotice(internals.CompileListener):
    """Say once, on ``logger``, that kernels are compiling when a compile takes over ``after`` s.

    A listener of numba's ``numba:compile`` events (:func:`.numba_internals.listen_to_compiles`):
    when an outermost compile of a function that ``owns`` accepts starts, a timer is armed; if
    the compile still runs after ``after`` seconds the timer logs one warning (the user sees it
    while waiting), and a compile that ends later than ``after`` without it having fired logs
    it at the end. The line says that stcgym compiles its kernels on first use, how long a
    first run takes (:data:`FIRST_RUN_SECONDS`) and that the result is cached. After it the
    listener stays silent. Loads from numba's on-disk cache are not compiles and say nothing.
    """

    def __init__(
        self, after: float, owns: Callable[[Any], bool], log: logging.Logger = logger
    ) -> None:
        self.after = after
        self.owns = owns
        self.log = log
        self.announced = False
        self._depth = 0
        self._started = 0.0
        self._name = ""
        self._timer: threading.Timer | None = None
        self._lock = threading.Lock()

    def on_start(self, ev: Any) -> None:
        self._depth += 1
        dispatcher = ev.data["dispatcher"]
        if self._depth == 1 and not self.announced and self.owns(dispatcher):
            self._name = dispatcher.py_func.__qualname__
            self._started = time.perf_counter()
            self._timer = threading.Timer(self.after, self._announce)
            self._timer.daemon = True
            self._timer.start()

    def on_end(self, ev: Any) -> None:
        self._depth -= 1
        if self._depth == 0 and self._timer is not None:
            self._timer.cancel()
            self._timer = None
            if time.perf_counter() - self._started > self.after:
                self._announce()

    def _announce(self) -> None:
        with self._lock:
            if self.announced:
                return
            self.announced = True
        low, high = FIRST_RUN_SECONDS
        self.log.warning(
            "stcgym is compiling its kernels (numba) on first use in this environment, "
            "starting with %s: this takes about %d-%d s, once; they are cached afterwards "
            "and later runs start in about a second",
            self._name,
            low,
            high,
        )


def _is_stcgym_kernel(dispatcher: Any) -> bool:
    return dispatcher.py_func.__module__.startswith("stcgym.")


#: The installed notice (``NOTICE.after`` is :data:`COMPILE_NOTICE_AFTER`).
NOTICE = CompileNotice(COMPILE_NOTICE_AFTER, _is_stcgym_kernel)
internals.listen_to_compiles(NOTICE)

#: A lane function compiled for other lane functions only (:func:`lane` without ``entry=True``).
LaneHelper = internals.HelperDispatcher


def _jit(
    fn: F | None,
    allocates: bool,
    inline: bool = False,
    inline_ir: bool = False,
    entry: bool = True,
) -> Any:
    options: dict[str, Any] = {
        "nogil": True,
        "error_model": "numpy",
        # LLVM's alwaysinline where asked, else never (numba would otherwise pass the flag on
        # from an inlined caller to the helpers it compiles)
        "forceinline": inline,
    }
    if inline_ir:
        options["inline"] = "always"

    def decorate(f: F) -> Any:
        if internals.jit_disabled():
            return f
        compiled = internals.dispatcher(f, options, nrt=allocates, helper=not entry)
        guard_cache(compiled)
        return compiled

    return decorate if fn is None else decorate(fn)


def lane(
    fn: F | None = None,
    *,
    allocates: bool = False,
    inline: bool = False,
    inline_ir: bool = False,
    entry: bool = False,
) -> Any:
    """Compile ``fn`` as a lane function (nopython, cached, releases the GIL).

    ``error_model="numpy"``: a division by zero gives inf/nan like numpy instead of raising,
    so lane functions test their own denominators and report numerical trouble as status codes.

    Lane functions **never allocate**: their scratch is a named scratch of the caller (one row a
    lane). They are therefore compiled without numba's reference-counting runtime (NRT,
    :func:`.numba_internals.dispatcher`): with it every slice of a state increments and decrements
    an atomic counter on the batch's memory block, and when a batch runs on several threads they all
    hammer that one counter (measured on the plant step: 87 -> 30 ns per lane on one thread, 800 ->
    17 ns on two). Compiling an allocation (``np.empty``, ``.copy()``) then fails, which keeps the
    rule honest. The few set-up helpers that do allocate (the solve-to-convergence designs of a
    fresh model) say so with ``@lane(allocates=True)``.

    ``entry=True`` for the lane functions that Python calls (the controller step, the estimator
    steps, the designs, the plant steps...). The others are helpers of lane functions, compiled
    without numba's CPython wrapper (the code that unboxes every argument from Python objects):
    that wrapper is a sizeable part of the compile time of a small function, and a helper never
    needs it. Calling a helper from Python raises ``TypeError`` (:class:`LaneHelper`).

    ``inline=True`` for the small building blocks called every step (a Kalman step, a 3 x 3
    inverse, the design's and the controller's helpers): the helper gets LLVM's
    ``alwaysinline`` attribute (numba's ``forceinline`` flag), so LLVM inlines it into every
    caller. numba compiles every function separately and links the callees' code into the
    caller's module; without the attribute LLVM keeps most of them as calls, and a call with
    a few array arguments (each passed as a dozen machine words) costs as much as the arithmetic
    of a small step (the compiled rollout of the default controller: 1.1 us a step inlined,
    1.5-2.2 us not). The helper is still compiled once, and shared by every caller and every
    controller version.

    ``inline_ir=True`` (numba's own ``inline="always"``) rebuilds and retypes the helper inside
    every caller instead of compiling it once: numba's inlining was 10-12 of the 17-19 s of a
    cold ``place_design`` when every helper used it (the cold-start page of the documentation),
    so it is only for two kinds of helper: one that returns views of its arguments (a function
    compiled without NRT may return an array only where numba inlines it), and a part of a
    larger lane function that is also called alone, with one caller a version (the controller
    step's two halves, ``controller_act`` and ``controller_commit``): compiled as a unit of its
    own, its whole body would go through LLVM's optimiser twice, once alone and once inlined
    into the whole step (measured: 2.5-3 s more on the controller's cold first ``predict``).
    """
    return _jit(fn, allocates, inline=inline, inline_ir=inline_ir, entry=entry)


def chosen_by_type(choose: Callable[[type], Any]) -> Callable[[F], F]:
    """Make ``fn(arg, ...)`` a lane function that runs ``choose(type(arg))(arg, ...)``: the
    lane function of the class of its first argument (a named tuple), which takes ``fn``'s
    parameters under the same names.

    The choice is made when numba types the caller, from the argument's type: each class gets
    a compiled version of the caller that contains only its own implementation (as ``if x is
    None`` chooses a version on ``None``, for any number of alternatives). The implementation
    is inlined into the caller as numba IR (like ``inline_ir=True``). ``fn``'s body is the
    same choice made at run time, for Python and ``NUMBA_DISABLE_JIT=1``.
    """

    def decorate(fn: F) -> F:
        if internals.jit_disabled():
            return fn

        def typer(*args: Any) -> Any:  # numba calls it with the arguments' types
            return choose(args[0].instance_class).py_func

        typer.__signature__ = inspect.signature(fn)  # type: ignore[attr-defined]
        overload(fn, inline="always")(typer)
        return fn

    return decorate


#: Fewest lanes a thread of a batch loop gets by default: below ``2 * DEFAULT_MIN_LANES`` lanes a
#: batch runs on the calling thread (waking a thread and waiting for it costs tens of
#: microseconds, tens of controller steps).
DEFAULT_MIN_LANES = 128


def lanes(
    fn: F | None = None, *, allocates: bool = False, min_lanes: int = DEFAULT_MIN_LANES
) -> Any:
    """Compile ``fn(*args, first, last)`` as a batch loop over the lanes ``first .. last - 1``
    (one thread, cached, releases the GIL); without NRT unless ``allocates=True`` (see
    :func:`lane`). Returns a :class:`LaneLoop`: Python calls it without ``first, last``.

    ``min_lanes``: the fewest lanes worth a thread of their own (a block of a batch split over
    threads), about 100 microseconds of work: the default suits a controller or estimator step
    (about 1 us a lane); a whole rollout per lane takes 1, a plant step (30 ns) far more.
    """

    def decorate(f: F) -> LaneLoop:
        return LaneLoop(f, _jit(f, allocates), min_lanes)

    return decorate if fn is None else decorate(fn)


def _blocks(num_lanes: int, min_lanes: int) -> int:
    """How many blocks of rows a batch of ``num_lanes`` lanes runs as: one per thread that
    ``numba.get_num_threads()`` allows (numba's own setting: ``NUMBA_NUM_THREADS``,
    ``numba.set_num_threads``), each of at least ``min_lanes`` lanes."""
    most = num_lanes // max(int(min_lanes), 1)
    if most < 2:  # not worth a thread: no need to ask numba
        return 1
    return max(1, min(numba.get_num_threads(), most))


_pool: ThreadPoolExecutor | None = None
_pool_lock = threading.Lock()


def _thread_pool() -> ThreadPoolExecutor:
    global _pool
    with _pool_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(
                max_workers=numba.config.NUMBA_NUM_THREADS, thread_name_prefix="stcgym-lanes"
            )
        return _pool


def _forget_pool() -> None:  # a forked child has none of the parent's threads
    global _pool, _pool_lock
    _pool, _pool_lock = None, threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pool)


def run_blocks(loop: Callable[..., Any], args: Sequence[Any], min_lanes: int) -> None:
    """``loop(*args, first, last)`` over every row of ``args[0]``: on the calling thread, or in
    contiguous blocks of rows on a thread pool (:func:`_blocks`), the first block on the calling
    thread. Each block writes only its own rows, and a lane's numbers never depend on the
    block it ran in. An exception in any block is raised after every block has finished."""
    first = args[0]  # the lanes' rows, or a lane state (whose first field has a row a lane)
    num_lanes = (first if hasattr(first, "shape") else first[0]).shape[0]
    k = _blocks(num_lanes, min_lanes)
    if k == 1:
        loop(*args, 0, num_lanes)
        return
    edges = [num_lanes * j // k for j in range(k + 1)]
    pool = _thread_pool()
    futures = [pool.submit(loop, *args, edges[j], edges[j + 1]) for j in range(1, k)]
    try:
        loop(*args, edges[0], edges[1])
    finally:
        for future in futures:
            future.exception()  # wait for every block before the rows are read or raised
    for future in futures:
        future.result()


class LaneLoop:
    """A batch loop (:func:`lanes`): call it without its ``first, last`` parameters.

    ``loop(F, ...)`` runs lanes ``0 .. B - 1`` (``B = F.shape[0]``, the first argument's rows)
    through :func:`run_blocks`: small batches on the calling thread, large ones in blocks on
    ``numba.get_num_threads()`` threads. The loop is not compiled with numba's parallel
    accelerator: a ``prange`` loop would compile the lane function twice more (numba's gufunc
    and the function around it, each optimising the whole step again: about four times the
    serial loop's cold compile for the controller step). Handing a block to a pool thread costs
    about 35 us, hence ``min_lanes`` (measured on the performance page of the documentation).
    """

    def __init__(self, py_func: Callable[..., Any], dispatcher: Any, min_lanes: int) -> None:
        functools.update_wrapper(self, py_func)
        self.py_func = py_func
        self.dispatcher = dispatcher  # the serial loop (the plain function without the JIT)
        self.min_lanes = int(min_lanes)

    def __call__(self, *args: Any) -> None:
        run_blocks(self.dispatcher, args, self.min_lanes)

    def compile(self, arg_types: tuple) -> Callable[..., None]:
        """The loop compiled for ``arg_types`` (the types of the Python call's arguments),
        called without numba's typing of the arguments (:class:`FixedTypes`)."""
        if not hasattr(self.dispatcher, "compile"):  # the JIT is disabled: plain Python
            entry = self.dispatcher
        else:
            types = tuple(arg_types) + (numba.int64, numba.int64)
            entry = internals.entry_point(self.dispatcher, types)
        return functools.partial(_run_compiled, entry, self)

    def __reduce__(self) -> str:  # pickle by reference, like a function
        return self.__qualname__


def _run_compiled(entry: Callable[..., Any], loop: LaneLoop, *args: Any) -> None:
    run_blocks(entry, args, loop.min_lanes)  # read at each call: the setting may change


class FixedTypes:
    """Call a lane function with arguments whose types never change, without numba's typing of
    every argument on every call.

    numba types each argument of each call to pick the compiled overload; for the named-tuple
    states and configurations that costs about 8 us a call (their types are rebuilt field by
    field), several lane steps. A Python class whose calls always pass the same argument types
    (the same named-tuple classes of the same array types, float or float64 scalars) looks the
    overload up once, on the first call (``Dispatcher.compile`` of those types: numba's
    on-disk cache or a compile), and calls it directly afterwards. Without the JIT
    (``NUMBA_DISABLE_JIT=1``) it calls the Python function.

    The types are not checked again: an instance must only ever see one set of argument types
    (a call with other types runs machine code compiled for the first ones). A function with
    several compiled versions chosen by argument types (the controller step: ELS or a paper
    estimator, pole placement or LQ) gets one instance per version.
    """

    __slots__ = ("entry", "fn")

    def __init__(self, fn: Callable[..., Any]) -> None:
        self.fn = fn
        self.entry: Callable[..., Any] | None = None

    def __call__(self, *args: Any) -> Any:
        entry = self.entry
        if entry is None:
            if not hasattr(self.fn, "compile"):  # the JIT is disabled: plain Python
                entry = self.fn
            else:
                entry = internals.entry_point(self.fn, tuple(numba.typeof(a) for a in args))
            self.entry = entry
        return entry(*args)


def lane_state(
    fields: type[R],
    shapes: dict[str, tuple[int, ...]],
    num_lanes: int,
    dtypes: dict[str, Any] | None = None,
    nested: dict[str, tuple] | None = None,
) -> R:
    """A zeroed batch of named lane state: ``fields`` (a ``NamedTuple`` class) with field ``f``
    an array of shape ``(num_lanes, *shapes[f])`` (``float64`` unless ``dtypes`` says
    otherwise), or the lane state ``nested[f]`` (of ``num_lanes`` lanes too) for a field that
    groups named parts of its own. Lane ``i`` of field ``f`` is ``state.f[i]`` (a row view); a
    field a configuration does not use has a zero in its shape, so the lane functions loop over
    it without a test. numba types the tuple by its fields' dtypes and dimensions, not their
    sizes: one compiled function serves every order.

    >>> from typing import NamedTuple
    >>> class Pair(NamedTuple):
    ...     theta: object
    ...     t: object
    >>> s = lane_state(Pair, {"theta": (4,), "t": ()}, 3, {"t": np.int64})
    >>> s.theta.shape, s.t.dtype
    ((3, 4), dtype('int64'))
    """
    names = fields._fields
    parts = nested or {}
    if set(shapes) | set(parts) != set(names) or set(shapes) & set(parts):
        raise ValueError(
            f"shapes and nested must name exactly the fields of {fields.__name__}, each once: "
            f"{names}"
        )
    types = dtypes or {}
    num_lanes = int(num_lanes)
    return fields(
        *(
            parts[f]
            if f in parts
            else np.zeros((num_lanes, *shapes[f]), dtype=types.get(f, np.float64))
            for f in names
        )
    )


def fields_of(*groups: type[tuple]) -> list[tuple[str, type]]:
    """The fields of the named-tuple classes ``groups``, in order: the field list of a lane
    state or scratch made of them, ``NamedTuple(name, fields_of(...))`` (a field name twice is
    an error of ``NamedTuple``)."""
    return [(f, np.ndarray) for g in groups for f in g._fields]


def make_work(fields: type[R], shapes: dict[str, tuple[int, ...]], num_lanes: int) -> R:
    """A zeroed ``float64`` scratch of type ``fields`` for ``num_lanes`` lanes
    (:func:`lane_state`), each field shaped by ``shapes``, which may declare more fields than
    ``fields`` has (the shapes of a family of scratch types declared in one place)."""
    return lane_state(fields, {f: shapes[f] for f in fields._fields}, num_lanes)


def read_only(values: Any) -> NDArray:
    """A read-only ``float64`` copy of ``values``: a configuration array of the lane functions
    (a field of a compiled argument, which no step writes)."""
    arr = np.array(values, dtype=np.float64)
    arr.setflags(write=False)
    return arr


def set_lanes(dst: R, lanes: Any, src: R, row: Any = 0) -> None:
    """``dst.f[lanes] = src.f[row]`` for every field ``f`` of two lane states (a reset, a copy
    of some lanes), fields that are lane states themselves included."""
    for d, s in zip(dst, src, strict=True):
        if isinstance(d, tuple):
            set_lanes(d, lanes, s, row)
        else:
            d[lanes] = s[row]


def state_arrays(state: tuple) -> list[NDArray]:
    """Every array of a lane state, in field order, those of fields that are lane states
    themselves included (to save and restore some lanes)."""
    out: list[NDArray] = []
    for a in state:
        out.extend(state_arrays(a) if isinstance(a, tuple) else (a,))
    return out


def state_nbytes_per_lane(state: tuple) -> int:
    """Bytes of one lane of a lane state (every field's row; a field that is itself a lane
    state, such as a scratch made of named parts, counts its own fields)."""
    return sum(
        state_nbytes_per_lane(a) if isinstance(a, tuple) else (a[0].nbytes if a.shape[0] else 0)
        for a in state
    )
