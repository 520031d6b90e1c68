#!/bin/bash
# The code figures of the compiled layer (offset reads, ordinal variant comparisons, name
# parsers, numba internals, docstring lengths, lane-function arity) of adaptive/, envs/ and
# lanes/ (where it exists), for a repository root given as $1 (default: this one).
# Run: bash benchmarks/code_metrics.sh [ROOT]
cd "${1:-$(dirname "$0")/..}" || exit 1
PY=${PYTHON:-python3}
count() { grep -rshoE "$1" --include=*.py adaptive envs lanes | wc -l; }
echo "offset reads x[at.*]/x[INTS.*]/x[LAW.*]/Ws[MAT.*]/Vs[VEC.*]: $(count '\w+\[(at|INTS|LAW|MAT|VEC)\.')"
echo "  of them rec[at.: $(count '\brec\[at\.')"
echo "offset slices at.x : at.x + k: $(count 'at\.\w+ *: *at\.\w+ *\+')"
echo "work[<arithmetic>:]: $(count 'work\[[^]:,]*[-+*/][^]:,]*:')"
echo "view2d/view3d calls: $(grep -rshoE '\bview[23]d\(' --include=*.py adaptive envs lanes | wc -l)"
echo "-1 sentinels (at.X < 0 / >= 0): $(count 'at\.\w+ *(<|>=) *0')"
echo "ordinal variant comparisons: $(count '(rule|state|design|kind)\w* *(>=|<=|<|>) *[A-Z][A-Z_]+')"
echo "modules splitting estimator names: $(grep -rslE 'split\("-"\)|partition\("-"\)|startswith\("KF' --include=*.py adaptive envs lanes | tr '\n' ' ')"
echo "modules using numba internals: $(grep -rslE 'numba\.core|numba\.np|_nrt|no_cpython_wrapper|populate_array|CPUDispatcher|no_cfunc_wrapper' --include=*.py adaptive envs lanes | tr '\n' ' ')"
echo "benchmarks/ mentioned in adaptive/ envs/: $(count 'benchmarks/')"
$PY - <<'PY'
import ast, pathlib
long, arity = [], []
for f in sorted([*pathlib.Path("adaptive").rglob("*.py"), *pathlib.Path("envs").rglob("*.py"), *pathlib.Path("lanes").rglob("*.py")]):
    tree = ast.parse(f.read_text())
    doc = ast.get_docstring(tree, clean=False)
    if doc and len(doc.splitlines()) > 40:
        long.append(f"{f} ({len(doc.splitlines())})")
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef):
            names = [ast.unparse(d).split("(")[0] for d in node.decorator_list]
            if any(n in ("lane", "lanes") for n in names):
                arity.append((len(node.args.args) + len(node.args.kwonlyargs), node.name))
print(f"module docstrings over 40 lines: {len(long)}: {', '.join(long)}")
arity.sort()
print(f"lane functions: {len(arity)}; >= 8 parameters: {sum(a >= 8 for a, _ in arity)}; "
      f">= 11: {sum(a >= 11 for a, _ in arity)}; most: {arity[-1]}")
PY
