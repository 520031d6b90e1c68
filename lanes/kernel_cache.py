"""Where stcgym's compiled kernels are cached, and why an edited kernel never runs stale code.

Location (numba's rules, nothing of stcgym's own): every compiled function is cached
(``cache=True``) in ``NUMBA_CACHE_DIR`` when that is set (one sub-directory per source
directory); otherwise in the ``__pycache__`` directory next to its source file when numba can
create and write it; otherwise in the user-wide cache directory (``$XDG_CACHE_HOME/numba`` or
``~/.cache/numba`` on Linux, ``~/Library/Caches/numba`` on macOS, one sub-directory per source
directory). A wheel installed read-only (system-wide site-packages) therefore caches in the
user's own directory and starts fast from the second process on. When no location is writable
at all, numba raises ``RuntimeError("cannot cache function ...")`` at import; set
``NUMBA_CACHE_DIR`` to a writable directory.

Freshness: numba keys each cached function on a hash of the content of *its own* source file.
Its machine code also contains the functions it calls and inlines from other modules, which
numba does not check, so after an edit or an upgrade of such a module the old machine code
would still be loaded. stcgym therefore stamps each cache directory of its kernels with a
fingerprint of the kernel sources (:func:`kernel_fingerprint` of :func:`kernel_sources`:
every module that defines compiled functions or the named tuples they run on, and the kernels
package). When a kernel is
declared (import time, before anything is loaded from the cache) and the directory's stamp
differs, the directory's numba cache files are deleted and the new stamp written
(:func:`guard_cache`), once per directory and process: the kernels then compile afresh on
first use, from the current sources. Editing a module that no kernel uses
(the Python classes, validation, options) keeps the cache.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from functools import cache
from importlib.util import find_spec
from pathlib import Path
from typing import Any

__all__ = ["STAMP_NAME", "guard_cache", "kernel_fingerprint", "kernel_sources"]

#: Name of the fingerprint file in each cache directory of stcgym kernels.
STAMP_NAME = "stcgym-kernels.sha256"
#: The source text that marks a module defining compiled functions (or their lowering), or the
#: named tuples of lane state and configuration that kernels are compiled for (and constants
#: beside them, such as the estimator specification's).
_KERNEL_MARKS = ("@lane", "njit(", "@lower_builtin(", "NamedTuple")

_checked: set[Path] = set()


def _roots() -> dict[str, Path]:
    """Package name -> directory of the packages that hold kernels: this one (the lane
    framework), the plants' and the estimators' and controllers'."""
    roots = {"stcgym.lanes": Path(__file__).resolve().parent}
    for package in ("stcgym.envs", "stcgym.adaptive"):
        spec = find_spec(package)
        if spec is not None and spec.submodule_search_locations:
            roots[package] = Path(next(iter(spec.submodule_search_locations))).resolve()
    return roots


@cache
def kernel_sources() -> tuple[Path, ...]:
    """The modules whose text the compiled kernels depend on, sorted.

    Every module of ``stcgym.lanes``, ``stcgym.envs`` and ``stcgym.adaptive`` that defines
    compiled functions (decorated ``@lane``/``@lanes`` or ``numba.njit``) or named tuples (the
    lane state and configuration kernels run on, and the constants beside them, such as
    ``estimation.estimator_spec``'s and the registry's codes), and every module of the shared
    kernels package ``stcgym.adaptive.kernels``: the functions a kernel calls or inlines and
    the constants it reads are defined there. Kernels read no constant from elsewhere; the
    Python classes around them (``SelfTuningController``, validation, options) are not part
    of the fingerprint, so editing them keeps the cache.
    """
    roots = _roots()
    files = set()
    for root in roots.values():
        for path in root.rglob("*.py"):
            if path.parent.name == "kernels" or any(m in path.read_text() for m in _KERNEL_MARKS):
                files.add(path)
    return tuple(sorted(files))


@cache
def kernel_fingerprint() -> str:
    """SHA-256 of the kernel sources (:func:`kernel_sources`: relative names and contents)."""
    roots = _roots()
    digest = hashlib.sha256()
    for path in kernel_sources():
        package = next(p for p, r in roots.items() if r in path.parents)
        digest.update(f"{package}/{path.relative_to(roots[package]).as_posix()}\n".encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def guard_cache(dispatcher: Any) -> None:
    """Empty the cache directory of ``dispatcher`` if it was filled from other kernel sources.

    Called for every kernel when it is declared; checks each directory once per process (see
    the module docstring). Without the JIT (``NUMBA_DISABLE_JIT=1``) there is no cache.
    """
    stats = getattr(dispatcher, "stats", None)
    if stats is None or not stats.cache_path:
        return
    directory = Path(stats.cache_path)
    if directory in _checked:
        return
    _checked.add(directory)
    fingerprint = kernel_fingerprint()
    stamp = directory / STAMP_NAME
    try:
        if stamp.read_text() == fingerprint:
            return
    except OSError:  # no stamp yet (an empty or a foreign cache)
        pass
    for pattern in ("*.nbi", "*.nbc"):
        for entry in directory.glob(pattern):
            entry.unlink(missing_ok=True)
    fd, tmp = tempfile.mkstemp(dir=directory, prefix=STAMP_NAME, suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        f.write(fingerprint)
    os.replace(tmp, stamp)
