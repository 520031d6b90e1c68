"""Each assumption stcgym makes about numba's internals (stcgym.lanes.numba_internals).

A numba release that changes one of them fails here, by name, before any kernel misbehaves;
``pyproject.toml`` bounds numba to the releases this file passed on (``make test-latest`` runs
the suite on the newest numba of the registry).
"""

from __future__ import annotations

import re
import warnings

import numba
import numpy as np
import pytest

from stcgym.lanes import numba_internals as ni


def _sum_tail(a):
    s = a[1:]  # a view
    acc = 0.0
    for i in range(s.shape[0]):
        acc += s[i]
    return acc


def _allocating(n):
    return np.zeros(n).sum() + n


def _defined_functions(compiled) -> list[str]:
    """Names of the functions defined in the (only) LLVM module of ``compiled``."""
    (ir,) = compiled.inspect_llvm().values()
    return re.findall(r"^define [^@]*@\"?([\w.$]+)", ir, re.M)


def test_without_nrt_an_allocation_is_a_compile_error_and_views_work():
    """``nrt=False`` (numba's ``_nrt`` option): no reference-counting runtime, so a function
    that allocates does not compile, while one that only takes views does."""
    views = ni.dispatcher(_sum_tail, {}, nrt=False, helper=False, cache=False)
    assert views(np.arange(4.0)) == 6.0
    no_rt = ni.dispatcher(_allocating, {}, nrt=False, helper=False, cache=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(numba.core.errors.TypingError):
            no_rt(3)
    with_rt = ni.dispatcher(_allocating, {}, nrt=True, helper=False, cache=False)
    assert with_rt(3) == 3.0


def test_a_helper_has_no_cpython_or_cfunc_wrapper_and_raises_from_python():
    """``helper=True`` (``no_cpython_wrapper``): no CPython wrapper is built (its Python call
    raises ``TypeError``), a compiled caller still calls it; no dispatcher gets a cfunc
    wrapper (``no_cfunc_wrapper``)."""
    helper = ni.dispatcher(_sum_tail, {}, nrt=False, helper=True, cache=False)
    assert isinstance(helper, ni.HelperDispatcher)
    with pytest.raises(TypeError, match="lane helper"):
        helper(np.arange(4.0))

    @numba.njit
    def caller(a):
        return helper(a)

    assert caller(np.arange(4.0)) == 6.0
    names = _defined_functions(helper)
    assert names and not any("cpython" in n or "cfunc" in n for n in names)
    entry = ni.dispatcher(_sum_tail, {}, nrt=False, helper=False, cache=False)
    entry(np.arange(4.0))
    names = _defined_functions(entry)
    assert any("cpython" in n for n in names) and not any("cfunc" in n for n in names)


def test_options_reach_the_compiler():
    """The public ``njit`` options given to :func:`dispatcher` are applied: ``forceinline``
    gives LLVM's ``alwaysinline`` attribute, ``error_model="numpy"`` a division by zero that
    returns inf instead of raising."""

    def ratio(a, b):
        return a / b

    inlined = ni.dispatcher(ratio, {"forceinline": True}, nrt=False, helper=False, cache=False)
    plain = ni.dispatcher(ratio, {}, nrt=False, helper=False, cache=False)
    assert inlined(1.0, 2.0) == plain(1.0, 2.0) == 0.5
    assert "alwaysinline" in next(iter(inlined.inspect_llvm().values()))
    assert "alwaysinline" not in next(iter(plain.inspect_llvm().values()))
    numpy_model = ni.dispatcher(
        ratio, {"error_model": "numpy"}, nrt=False, helper=False, cache=False
    )
    assert numpy_model(1.0, 0.0) == np.inf
    with pytest.raises(ZeroDivisionError):
        plain(1.0, 0.0)


def test_caching_is_enabled_on_request():
    """``cache=True`` turns numba's on-disk cache on (``stats.cache_path``, public)."""
    cached = ni.dispatcher(_sum_tail, {}, nrt=False, helper=False)
    assert cached.stats.cache_path
    assert not ni.dispatcher(_sum_tail, {}, nrt=False, helper=False, cache=False).stats.cache_path


def test_entry_point_runs_the_code_compiled_for_the_given_types():
    """``Dispatcher.compile(types)`` returns a callable entry point of that overload."""
    compiled = ni.dispatcher(_sum_tail, {}, nrt=False, helper=False, cache=False)
    a = np.arange(5.0)
    entry = ni.entry_point(compiled, (numba.typeof(a),))
    assert callable(entry) and entry(a) == 10.0
    a[4] = 100.0  # reads the current values
    assert entry(a) == 106.0
    assert len(compiled.signatures) == 1


def test_compile_events_reach_a_listener():
    """:func:`listen_to_compiles`: numba's ``numba:compile`` events, ``on_start`` and
    ``on_end`` once per compile, with the dispatcher in ``data["dispatcher"]``."""
    seen = []

    class Recorder(ni.CompileListener):
        def on_start(self, ev):
            seen.append(("start", ev.data["dispatcher"].py_func.__name__))

        def on_end(self, ev):
            seen.append(("end", ev.data["dispatcher"].py_func.__name__))

    def fresh_function(x):
        return x + 1

    recorder = Recorder()
    ni.listen_to_compiles(recorder)
    try:
        compiled = ni.dispatcher(fresh_function, {}, nrt=False, helper=False, cache=False)
        assert compiled(1) == 2
    finally:
        ni.listen_to_compiles(recorder, listen=False)
    assert compiled(2.5) == 3.5  # a second compile, unheard
    mine = [s for s in seen if s[1] == "fresh_function"]
    assert mine == [("start", "fresh_function"), ("end", "fresh_function")]
