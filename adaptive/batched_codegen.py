"""A tiny tracer that turns straight-line numeric code into two kernels: numpy and scalar.

The batched "fast" estimators and controller are written once as ordinary Python over
:class:`Sym` values (``a * b + c``, :func:`where`, :func:`sqrt`, ...). Tracing records every
operation; :func:`compile_kernel` emits

* a **numpy** kernel: every variable is a lane vector, state and inputs are rows of
  lane-contiguous 2-D arrays (``(num_vars, B)``), so each operation is one vectorised ufunc call
  over all lanes of a chunk;
* a **scalar** kernel: the same statements on Python floats in local variables (one plant at
  about 15-20 ns per operation, no numpy call overhead).

Both kernels execute the same IEEE operations in the same order (``+ - * /``, ``sqrt`` and
comparisons are correctly rounded in both numpy and CPython, and no fused multiply-add is ever
formed), so a scalar run is **bit-for-bit** equal to any lane of the numpy run. Where scalar
Python would raise (division by zero, ``sqrt`` of a negative number) the caller re-runs the step
with the numpy kernel on one lane, which yields the IEEE result (``inf``/``nan``) instead.

Constant folding removes the structural zeros and ones of the canonical matrices (``x * 0``,
``x * 1``, ``x + 0``), which is where most of the speed over dense matrix code comes from; dead
code is dropped. Folding ``x * 0 -> 0`` is exact for finite ``x``; non-finite values are caught by
the algorithms' own health checks.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Union

import numpy as np

__all__ = [
    "Sym",
    "Tracer",
    "Value",
    "Kernel",
    "compile_kernel",
    "where",
    "sqrt",
    "isfinite",
    "floor",
    "logical_and",
    "logical_or",
    "logical_not",
    "dot",
    "total",
    "absolute",
    "maximum",
    "guard",
    "assume",
    "to_float",
    "all_of",
    "any_of",
]


class Sym:
    """A traced value (float or bool) named ``name`` in the generated code."""

    __slots__ = ("tr", "name", "is_bool")

    def __init__(self, tr: Tracer, name: str, is_bool: bool = False) -> None:
        self.tr, self.name, self.is_bool = tr, name, is_bool

    # arithmetic ------------------------------------------------------------------------------
    def __add__(self, o: Value) -> Value:
        return _add(self, o)

    def __radd__(self, o: Value) -> Value:
        return _add(o, self)

    def __sub__(self, o: Value) -> Value:
        return _sub(self, o)

    def __rsub__(self, o: Value) -> Value:
        return _sub(o, self)

    def __mul__(self, o: Value) -> Value:
        return _mul(self, o)

    def __rmul__(self, o: Value) -> Value:
        return _mul(o, self)

    def __truediv__(self, o: Value) -> Value:
        return _div(self, o)

    def __rtruediv__(self, o: Value) -> Value:
        return _div(o, self)

    def __neg__(self) -> Value:
        return self.tr.op("neg", self)

    # comparisons (bool results) --------------------------------------------------------------
    def __gt__(self, o: Value) -> Value:
        return _cmp(">", self, o)

    def __lt__(self, o: Value) -> Value:
        return _cmp("<", self, o)

    def __ge__(self, o: Value) -> Value:
        return _cmp(">=", self, o)

    def __le__(self, o: Value) -> Value:
        return _cmp("<=", self, o)

    def eq(self, o: Value) -> Value:
        return _cmp("==", self, o)

    def ne(self, o: Value) -> Value:
        return _cmp("!=", self, o)

    def __bool__(self) -> bool:  # pragma: no cover - a programming error in traced code
        raise TypeError("a traced value has no truth value; use where()/logical_*()")

    def __repr__(self) -> str:
        return f"Sym({self.name})"


Value = Union[Sym, float, bool]  # noqa: UP007 - a runtime alias (X | Y needs Python 3.10 types)


def _const(v: Value) -> bool:
    return not isinstance(v, Sym)


def _tracer(*vals: Value) -> Tracer:
    for v in vals:
        if isinstance(v, Sym):
            return v.tr
    raise AssertionError("no traced operand")  # pragma: no cover


def _add(a: Value, b: Value) -> Value:
    if _const(a) and _const(b):
        return float(a) + float(b)
    if _const(b) and b == 0.0:
        return a
    if _const(a) and a == 0.0:
        return b
    return _tracer(a, b).op("add", a, b)


def _sub(a: Value, b: Value) -> Value:
    if _const(a) and _const(b):
        return float(a) - float(b)
    if _const(b) and b == 0.0:
        return a
    if _const(a) and a == 0.0:
        return -b  # type: ignore[operator]
    return _tracer(a, b).op("sub", a, b)


def _mul(a: Value, b: Value) -> Value:
    if _const(a) and _const(b):
        return float(a) * float(b)
    if _const(a):
        a, b = b, a
    if _const(b):
        if b == 0.0:
            return 0.0
        if b == 1.0:
            return a
        if b == -1.0:
            return -a  # type: ignore[operator]
    return _tracer(a, b).op("mul", a, b)


def _div(a: Value, b: Value) -> Value:
    if _const(a) and _const(b):
        return float(a) / float(b)
    if _const(b) and b == 1.0:
        return a
    if _const(a) and a == 0.0:
        return 0.0
    return _tracer(a, b).op("div", a, b)


def _cmp(op: str, a: Value, b: Value) -> Value:
    if _const(a) and _const(b):
        return bool(eval(f"{float(a)!r} {op} {float(b)!r}"))  # noqa: S307 - constants only
    return _tracer(a, b).op("cmp" + op, a, b, is_bool=True)


def where(c: Value, a: Value, b: Value) -> Value:
    """``a`` where ``c`` is true, else ``b`` (both are evaluated)."""
    if _const(c):
        return a if c else b
    if _const(a) and _const(b) and float(a) == float(b):
        return a
    if a is b:
        return a
    is_bool = (isinstance(a, bool) or (isinstance(a, Sym) and a.is_bool)) and (
        isinstance(b, bool) or (isinstance(b, Sym) and b.is_bool)
    )
    return _tracer(c).op("where", c, a, b, is_bool=is_bool)


def sqrt(a: Value) -> Value:
    if _const(a):
        return math.sqrt(a)
    return a.tr.op("sqrt", a)  # type: ignore[union-attr]


def absolute(a: Value) -> Value:
    if _const(a):
        return abs(float(a))
    return a.tr.op("abs", a)  # type: ignore[union-attr]


def maximum(a: Value, b: Value) -> Value:
    """``max(a, b)`` that propagates NaN like ``numpy.max``."""
    if _const(a) and _const(b):
        fa, fb = float(a), float(b)
        return fa if (fa != fa or fa >= fb) else fb
    return where(logical_or(_cmp("!=", a, a) if not _const(a) else False, a >= b), a, b)  # type: ignore[operator]


def isfinite(a: Value) -> Value:
    if _const(a):
        return math.isfinite(a)
    return a.tr.op("isfinite", a, is_bool=True)  # type: ignore[union-attr]


def floor(a: Value) -> Value:
    if _const(a):
        return float(math.floor(a))
    return a.tr.op("floor", a)  # type: ignore[union-attr]


def logical_and(a: Value, b: Value) -> Value:
    if _const(a):
        return b if a else False
    if _const(b):
        return a if b else False
    return a.tr.op("and", a, b, is_bool=True)  # type: ignore[union-attr]


def logical_or(a: Value, b: Value) -> Value:
    if _const(a):
        return True if a else b
    if _const(b):
        return True if b else a
    return a.tr.op("or", a, b, is_bool=True)  # type: ignore[union-attr]


def logical_not(a: Value) -> Value:
    if _const(a):
        return not a
    return a.tr.op("not", a, is_bool=True)  # type: ignore[union-attr]


def all_of(vals: Sequence[Value]) -> Value:
    out: Value = True
    for v in vals:
        out = logical_and(out, v)
    return out


def any_of(vals: Sequence[Value]) -> Value:
    out: Value = False
    for v in vals:
        out = logical_or(out, v)
    return out


def dot(a: Sequence[Value], b: Sequence[Value]) -> Value:
    """``sum_k a_k b_k`` left to right (structural zeros folded away)."""
    acc: Value = 0.0
    for x, y in zip(a, b, strict=True):
        acc = acc + x * y  # type: ignore[operator]
    return acc


def total(vals: Sequence[Value]) -> Value:
    acc: Value = 0.0
    for v in vals:
        acc = acc + v  # type: ignore[operator]
    return acc


def guard(c: Value) -> Value:
    """Mark ``c`` as a rare condition (see :class:`Tracer`); returns ``c`` or ``False``."""
    if _const(c):
        return c
    tr = c.tr  # type: ignore[union-attr]
    if tr.nominal:
        tr.guards.append(c)
        return False
    return c


def assume(c: Value) -> Value:
    """Mark ``c`` as the common case: ``guard(not c)``, returning ``c`` or ``True``."""
    return logical_not(guard(logical_not(c)))


def to_float(c: Value) -> Value:
    """A bool as 1.0 / 0.0."""
    return where(c, 1.0, 0.0)


@dataclass
class _Op:
    dest: str
    kind: str
    args: tuple[Value, ...]


class Tracer:
    """Records operations; build inputs with :meth:`input`, then :func:`compile_kernel`.

    With ``nominal=True`` every :func:`guard` condition (a rare event such as a health failure)
    is recorded and replaced by ``False``: the trace is the common path only, with all the
    recovery selections folded away. The compiled kernel then reports in its last output
    whether any guard fired, and the caller re-runs those lanes with the general kernel.
    """

    def __init__(self, nominal: bool = False) -> None:
        self.ops: list[_Op] = []
        self._k = 0
        self.inputs: dict[str, tuple[str, int]] = {}  # Sym name -> (array, row)
        self.nominal = nominal
        self.guards: list[Value] = []
        self._memo: dict[tuple, Sym] = {}

    def input(self, array: str, row: int, is_bool: bool = False) -> Sym:
        name = f"{array}{row}"
        self.inputs[name] = (array, row)
        return Sym(self, name, is_bool)

    def op(self, kind: str, *args: Value, is_bool: bool = False) -> Sym:
        # Common-subexpression elimination: the same pure operation on the same operands
        # (constants compared by value and type) is computed once.
        key = (kind, *[(a.name,) if isinstance(a, Sym) else (type(a), a) for a in args])
        hit = self._memo.get(key)
        if hit is not None:
            return hit
        name = f"v{self._k}"
        self._k += 1
        self.ops.append(_Op(name, kind, args))
        sym = Sym(self, name, is_bool)
        self._memo[key] = sym
        return sym


# --------------------------------------------------------------------------------------------
# Code generation
# --------------------------------------------------------------------------------------------
def _arg(v: Value) -> str:
    if isinstance(v, Sym):
        return v.name
    if isinstance(v, bool):
        return repr(v)
    f = float(v)
    if not math.isfinite(f):
        return "_inf" if f > 0 else "_ninf" if f < 0 else "_nan"
    return repr(f)


_SCALAR_FORMS = {
    "add": "{0} + {1}",
    "sub": "{0} - {1}",
    "mul": "{0} * {1}",
    "div": "{0} / {1}",
    "neg": "-{0}",
    "sqrt": "_sqrt({0})",
    "abs": "abs({0})",
    "isfinite": "_isfinite({0})",
    "floor": "_floor({0})",
    "where": "{1} if {0} else {2}",
    "and": "{0} and {1}",
    "or": "{0} or {1}",
    "not": "not {0}",
}
_UFUNCS = {
    "add": "_np.add",
    "sub": "_np.subtract",
    "mul": "_np.multiply",
    "div": "_np.divide",
    "neg": "_np.negative",
    "sqrt": "_np.sqrt",
    "abs": "_np.absolute",
    "isfinite": "_np.isfinite",
    "floor": "_np.floor",
    "and": "_np.logical_and",
    "or": "_np.logical_or",
    "not": "_np.logical_not",
    "cmp>": "_np.greater",
    "cmp<": "_np.less",
    "cmp>=": "_np.greater_equal",
    "cmp<=": "_np.less_equal",
    "cmp==": "_np.equal",
    "cmp!=": "_np.not_equal",
}


def _scalar_expr(op: _Op, inline: dict[str, str]) -> str:
    """Python expression of ``op``; single-use operands are inlined (parenthesised), which
    saves a store and a load per operation without changing any rounding."""
    a = [
        f"({inline[x.name]})" if isinstance(x, Sym) and x.name in inline else _arg(x)
        for x in op.args
    ]
    if op.kind.startswith("cmp"):
        return f"{a[0]} {op.kind[3:]} {a[1]}"
    return _SCALAR_FORMS[op.kind].format(*a)


def _scalar_body(ops: list[_Op], finals: Sequence[Value], max_depth: int = 40) -> list[str]:
    uses: dict[str, int] = {}
    for op in ops:
        for x in op.args:
            if isinstance(x, Sym):
                uses[x.name] = uses.get(x.name, 0) + 1
    for v in finals:
        if isinstance(v, Sym):
            uses[v.name] = uses.get(v.name, 0) + 2  # finals need a name
    inline: dict[str, str] = {}
    depth: dict[str, int] = {}
    lines = []
    for op in ops:
        d = 1 + max(
            (depth.get(x.name, 0) for x in op.args if isinstance(x, Sym) and x.name in inline),
            default=0,
        )
        expr = _scalar_expr(op, inline)
        for x in op.args:
            if isinstance(x, Sym):
                inline.pop(x.name, None)
        if uses.get(op.dest, 0) == 1 and d < max_depth:
            inline[op.dest] = expr
            depth[op.dest] = d
        else:
            lines.append(f"{op.dest} = {expr}")
    return lines


def _live_ops(ops: list[_Op], outputs: Sequence[Value]) -> list[_Op]:
    """Dead-code elimination: the ops that some output depends on, in order."""
    need = {v.name for v in outputs if isinstance(v, Sym)}
    keep: list[_Op] = []
    for op in reversed(ops):
        if op.dest in need:
            keep.append(op)
            need.update(x.name for x in op.args if isinstance(x, Sym))
    keep.reverse()
    return keep


@dataclass
class Kernel:
    """A compiled kernel pair.

    ``numpy(S, N, K, I, O, F, G)``: reads the dynamic state rows ``S``, constant rows ``K`` and
    input rows ``I`` of a chunk, writes **every** dynamic row of ``N`` (double buffering) and the
    output rows ``O``; ``F`` (float) and ``G`` (bool) are scratch buffers with at least
    :attr:`n_float` / :attr:`n_bool` rows of the chunk length.

    ``scalar(S, K, I)`` takes tuples of floats and returns ``(new_S, outputs)`` tuples.
    """

    n_state: int
    n_const: int
    n_inputs: int
    n_outputs: int
    n_float: int
    n_bool: int
    numpy: Callable[..., None]
    scalar: Callable[..., tuple[tuple[Any, ...], tuple[Any, ...]]]
    n_ops: int
    source: dict[str, str] = field(repr=False, default_factory=dict)


def compile_kernel(
    tr: Tracer,
    state_in: Sequence[Sym],
    state_out: Sequence[Value],
    outputs: Sequence[Value],
    const_in: Sequence[Sym] = (),
    name: str = "kernel",
) -> Kernel:
    """Emit and compile the numpy and scalar kernels of a trace.

    ``state_in[k]`` is the traced value of dynamic state row ``k`` (``tr.input("S", k)``) and
    ``state_out[k]`` its new value; constants are ``tr.input("K", j)``, inputs
    ``tr.input("I", j)``. For a nominal trace (``Tracer(nominal=True)``) an extra last output
    is added: whether any guard fired in that lane.
    """
    outputs = list(outputs)
    if tr.nominal:
        outputs.append(any_of(tr.guards))
    finals = list(state_out) + outputs
    ops = _live_ops(tr.ops, finals)
    n_state = len(state_in)
    used = {x.name for op in ops for x in op.args if isinstance(x, Sym)}
    used |= {v.name for v in finals if isinstance(v, Sym)}
    rows = {
        arr: sorted((r, nm) for nm, (a, r) in tr.inputs.items() if a == arr and nm in used)
        for arr in ("S", "K", "I")
    }
    n_inputs = max([r for r, _ in rows["I"]], default=-1) + 1
    is_bool = {op.dest: False for op in ops}
    for op in ops:
        is_bool[op.dest] = op.kind.startswith("cmp") or op.kind in ("isfinite", "and", "or", "not")
        if op.kind == "where":
            a, b = op.args[1], op.args[2]
            is_bool[op.dest] = all(
                isinstance(v, bool) or (isinstance(v, Sym) and (is_bool.get(v.name) or v.is_bool))
                for v in (a, b)
            )

    # ---- numpy target: buffer allocation by liveness ----------------------------------------
    last_use: dict[str, int] = {}
    for i, op in enumerate(ops):
        for x in op.args:
            if isinstance(x, Sym):
                last_use[x.name] = i
    end = len(ops)
    for v in finals:
        if isinstance(v, Sym):
            last_use[v.name] = end
    # A value that is the new content of exactly one state row (and not an output) is computed
    # straight into that row of N.
    target: dict[str, int] = {}
    counts: dict[str, int] = {}
    for v in finals:
        if isinstance(v, Sym):
            counts[v.name] = counts.get(v.name, 0) + 1
    defined = {op.dest for op in ops}
    for k, v in enumerate(state_out):
        if isinstance(v, Sym) and v.name in defined and counts[v.name] == 1:
            target[v.name] = k
    body: list[str] = []
    for r, nm in rows["S"]:
        body.append(f"{nm} = S[{r}]")
    for r, nm in rows["K"]:
        body.append(f"{nm} = K[{r}]")
    for r, nm in rows["I"]:
        body.append(f"{nm} = I[{r}]")
    free = {"F": [], "G": []}
    count = {"F": 0, "G": 0}
    slot: dict[str, str] = {}
    fresh: set[str] = set()  # values in arrays of their own (numpy.where results)
    # Each value's buffer is freed after its last use.
    frees_at: dict[int, list[str]] = {}
    for nm, i in last_use.items():
        frees_at.setdefault(i, []).append(nm)
    for i, op in enumerate(ops):
        d = op.dest
        a = [_arg(x) for x in op.args]
        if op.kind == "where":
            # numpy.where allocates, but is several times faster than a masked copyto.
            if d in target:
                body.append(f"N[{target[d]}] = {d} = _np.where({a[0]}, {a[1]}, {a[2]})")
            else:
                body.append(f"{d} = _np.where({a[0]}, {a[1]}, {a[2]})")
                fresh.add(d)
        else:
            if d in target:
                out = f"N[{target[d]}]"
            else:
                pool = "G" if is_bool[d] else "F"
                if free[pool]:
                    out = free[pool].pop()
                else:
                    out = f"{pool}[{count[pool]}]"
                    count[pool] += 1
                slot[d] = out
            body.append(f"{d} = {_UFUNCS[op.kind]}({', '.join(a)}, out={out})")
        for nm in frees_at.get(i, []):
            if nm in slot:
                buf = slot.pop(nm)
                free["G" if buf.startswith("G") else "F"].append(buf)
            elif nm in fresh:
                fresh.discard(nm)
                body.append(f"del {nm}")
    for j, v in enumerate(outputs):
        body.append(f"O[{j}] = {_arg(v)}")
    for k, v in enumerate(state_out):
        if isinstance(v, Sym) and target.get(v.name) == k:
            continue
        body.append(f"N[{k}] = {_arg(v)}")
    np_src = f"def {name}(S, N, K, I, O, F, G):\n" + "\n".join("    " + ln for ln in body)

    # ---- scalar target ----------------------------------------------------------------------
    sbody: list[str] = []
    for arr, seq in (("S", state_in), ("K", const_in)):
        names = [s.name if s.name in used else "_" for s in seq]
        if names:
            sbody.append(f"({', '.join(names)},) = {arr}")
    for r, nm in rows["I"]:
        sbody.append(f"{nm} = I[{r}]")
    sbody += _scalar_body(ops, finals)
    outs = ", ".join(_arg(v) for v in state_out)
    res = ", ".join(_arg(v) for v in outputs)
    sbody.append(f"return ({outs}{',' if state_out else ''}), ({res}{',' if outputs else ''})")
    sc_src = f"def {name}(S, K, I):\n" + "\n".join("    " + ln for ln in sbody)

    consts = {"_inf": math.inf, "_ninf": -math.inf, "_nan": math.nan}
    np_globals: dict[str, Any] = {"_np": np, **consts}
    sc_globals: dict[str, Any] = {
        "_sqrt": math.sqrt,
        "_isfinite": math.isfinite,
        "_floor": lambda x: float(math.floor(x)),
        **consts,
    }
    exec(compile(np_src, f"<{name}:numpy>", "exec"), np_globals)  # noqa: S102 - generated
    exec(compile(sc_src, f"<{name}:scalar>", "exec"), sc_globals)  # noqa: S102 - generated
    return Kernel(
        n_state=n_state,
        n_const=len(const_in),
        n_inputs=n_inputs,
        n_outputs=len(outputs),
        n_float=count["F"],
        n_bool=count["G"],
        numpy=np_globals[name],
        scalar=sc_globals[name],
        n_ops=len(ops),
        source={"numpy": np_src, "scalar": sc_src},
    )
