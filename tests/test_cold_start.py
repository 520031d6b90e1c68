"""Cold start: compile only what is used, say when compiling, and never run a stale cache.

The subprocess tests run a copy of the package (``envs`` and ``adaptive`` under a temporary
``stcgym/``) with their own numba cache directory, so they see what a new user, an upgrade or
a read-only installation sees, whatever the state of this checkout's cache.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numba
import numpy as np
import pytest
from numba.core import event

import stcgym.adaptive
import stcgym.envs
import stcgym.lanes
from stcgym.adaptive.control import controller_step as kc
from stcgym.lanes import compiled, kernel_cache

PACKAGES = {
    "lanes": Path(stcgym.lanes.__file__).parent,
    "envs": Path(stcgym.envs.__file__).parent,
    "adaptive": Path(stcgym.adaptive.__file__).parent,
}

# A closed loop on a fixed plant in numpy: prints the inputs, and which stcgym functions
# compiled (numba's compile events) and loaded from the cache (dispatcher statistics).
CLOSED_LOOP = """
import json, sys
import numpy as np
from numba.core import event
rec = event.RecordingListener()
event.register("numba:compile", rec)
from stcgym.adaptive import SelfTuningController
from stcgym.adaptive.control import controller_step as kc
ctl = SelfTuningController(2)
A = np.array([[1.5, 1.0], [-0.56, 0.0]]); b = np.array([1.0, 0.5])
x = np.zeros(2); us = []
for t in range(40):
    u = float(ctl.predict(np.array([x[0], 1.0]))[0][0]); us.append(u)
    x = A @ x + b * u
compiled = sorted({e.data["dispatcher"].py_func.__name__ for _, e in rec.buffer if e.is_start})
hits = sum(kc.controller_step.stats.cache_hits.values())
print(json.dumps({"u": us, "compiled": compiled, "hits": hits,
                  "cache": kc.controller_step.stats.cache_path}))
"""

# The plant step alone (no controller): where the cache lives does not depend on the kernel,
# and this one compiles in about a second.
PLANT_STEPS = """
import json
import numpy as np
from stcgym.envs import dynamics
x, theta = np.zeros(2), np.array([-1.5, 0.56, 1.0, 0.5])
ys = []
for t in range(10):
    out = dynamics.canonical_plant_step(x, theta, 1.0, 10.0, 0.0, np.zeros(0), 0.0, 0.0,
                                        1.0, 0.0, 1e6, dynamics.OBSERVER)
    ys.append(float(out[5]))
print(json.dumps({"y": ys, "hits": sum(dynamics.canonical_plant_step.stats.cache_hits.values()),
                  "cache": dynamics.canonical_plant_step.stats.cache_path}))
"""


def _copy_package(root: Path) -> Path:
    """``root/stcgym/{lanes,envs,adaptive}``: a copy of the package without its caches."""
    for name, src in PACKAGES.items():
        shutil.copytree(src, root / "stcgym" / name, ignore=shutil.ignore_patterns("__pycache__"))
    return root


def _run(code: str, path: Path, **env: str) -> subprocess.CompletedProcess:
    full = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CACHE")}
    full.update(PYTHONPATH=str(path), PYTHONDONTWRITEBYTECODE="1", **env)
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=full, cwd=path
    )
    assert done.returncode == 0, done.stderr
    return done


def _json(done: subprocess.CompletedProcess) -> dict:
    return json.loads(done.stdout.strip().splitlines()[-1])


# ------------------------------------------------------------------------ compile notice
@pytest.fixture
def notice_log(caplog: pytest.LogCaptureFixture):
    caplog.set_level(logging.WARNING, logger="stcgym.test-notice")
    listeners = []

    def install(after: float, owns=lambda dispatcher: True) -> compiled.CompileNotice:
        notice = compiled.CompileNotice(after, owns, logging.getLogger("stcgym.test-notice"))
        event.register("numba:compile", notice)
        listeners.append(notice)
        return notice

    yield install, caplog
    for notice in listeners:
        event.unregister("numba:compile", notice)


def _fresh_kernels():
    """Two functions never compiled before (no cache): each call below compiles."""

    def first(x):
        acc = 0.0
        for i in range(x.shape[0]):
            acc += x[i] * x[i]
        return acc

    def second(x):
        return x + 1.0

    return numba.njit(first), numba.njit(second)


def test_compile_notice_says_it_once_for_a_slow_compile(notice_log) -> None:
    install, caplog = notice_log
    notice = install(after=0.0)  # every compile counts as slow
    first, second = _fresh_kernels()
    first(np.ones(3))
    second(1.0)
    second(1)  # a third compile (an int signature)
    lines = [r.getMessage() for r in caplog.records if r.name == "stcgym.test-notice"]
    assert len(lines) == 1, lines
    assert lines[0].startswith("stcgym is compiling its kernels (numba) on first use ")
    low, high = compiled.FIRST_RUN_SECONDS
    assert f"starting with {first.py_func.__qualname__}:" in lines[0]
    assert f"about {low}-{high} s, once" in lines[0] and "cached afterwards" in lines[0]
    assert notice.announced


def test_compile_notice_is_quiet_for_quick_and_foreign_compiles(notice_log) -> None:
    install, caplog = notice_log
    install(after=3600.0)  # nothing takes an hour
    install(after=0.0, owns=compiled._is_stcgym_kernel)  # slow, but not stcgym's
    first, second = _fresh_kernels()
    first(np.ones(3))
    second(1.0)
    assert not [r for r in caplog.records if r.name == "stcgym.test-notice"]
    assert compiled._is_stcgym_kernel(kc.controller_step)
    assert not compiled._is_stcgym_kernel(first)


def test_installed_notice_prints_one_line_on_a_cold_start_only(tmp_path: Path) -> None:
    """A new environment (empty cache): the user sees one line on stderr, however many kernels
    compile (here with the threshold at 0 s, so the plant step's short compile counts); the
    next process loads the cache and prints nothing."""
    code = (
        "import stcgym.lanes.compiled as c; c.NOTICE.after = 0.0\n"
        "import gymnasium as gym, numpy as np, stcgym.envs\n"
        "env = gym.make('stcgym/ObserverCanonical-v0', plant='unstable2'); env.reset(seed=0)\n"
        "env.step(np.array([0.0])); env.step(np.array([1.0]))\n"
        "import stcgym.envs.dynamics as d\n"
        "print(sum(len(f.stats.cache_misses) for f in vars(d).values() if hasattr(f, 'stats')))\n"
    )
    pkg, cache = _copy_package(tmp_path / "pkg"), str(tmp_path / "cache")
    done = _run(code, pkg, NUMBA_CACHE_DIR=cache)
    lines = [ln for ln in done.stderr.splitlines() if "compiling its kernels" in ln]
    assert len(lines) == 1, done.stderr
    low, high = compiled.FIRST_RUN_SECONDS
    assert f"about {low}-{high} s" in lines[0]
    assert int(done.stdout.split()[-1]) >= 2  # several kernels compiled, one line
    cached = _run(code, pkg, NUMBA_CACHE_DIR=cache)
    assert "compiling" not in cached.stderr, cached.stderr
    assert int(cached.stdout.split()[-1]) == 0  # nothing compiled: all loaded from the cache


# ------------------------------------------------------------------------ kernel cache
def test_kernel_sources_cover_the_modules_kernels_inline_and_read() -> None:
    root = Path(kernel_cache.__file__).resolve().parents[1]  # holds lanes/, envs/ and adaptive/
    names = {p.relative_to(root).as_posix() for p in kernel_cache.kernel_sources()}
    for expected in (
        "adaptive/control/controller_step.py",  # defines kernels
        "adaptive/control/law.py",  # inlined into the controller step
        "adaptive/estimation/estimator_spec.py",  # no kernel, but its constants are compiled in
        "adaptive/variants.py",
        "lanes/compiled.py",
        "adaptive/control/rollout.py",
    ):
        assert expected in names, names
    for python_only in (
        "adaptive/control/options.py",
        "adaptive/control/controller.py",
        "adaptive/estimation/recursive.py",
        "lanes/validation.py",
    ):
        assert (root / python_only).is_file()
        assert python_only not in names  # no kernel reads them: editing them keeps the cache


def _fake_dispatcher(directory: Path) -> SimpleNamespace:
    return SimpleNamespace(stats=SimpleNamespace(cache_path=str(directory)))


def test_guard_cache_empties_a_directory_filled_from_other_sources(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(kernel_cache, "_checked", set())
    stale = tmp_path / "stale"
    fresh = tmp_path / "fresh"
    for directory, stamp in ((stale, "another version"), (fresh, None)):
        directory.mkdir()
        for name in ("m.f-10.py311.nbi", "m.f-10.py311.1.nbc", "m.cpython-311.pyc"):
            (directory / name).write_text("x")
        if stamp is not None:
            (directory / kernel_cache.STAMP_NAME).write_text(stamp)
    kernel_cache.guard_cache(_fake_dispatcher(stale))
    assert sorted(p.name for p in stale.iterdir()) == sorted(
        ["m.cpython-311.pyc", kernel_cache.STAMP_NAME]
    )
    assert (stale / kernel_cache.STAMP_NAME).read_text() == kernel_cache.kernel_fingerprint()
    # a directory with the current stamp keeps its entries
    (fresh / kernel_cache.STAMP_NAME).write_text(kernel_cache.kernel_fingerprint())
    kernel_cache.guard_cache(_fake_dispatcher(fresh))
    assert len(list(fresh.glob("*.nb?"))) == 2
    # checked once per process: a later stale stamp in a checked directory is left alone
    (stale / "m.f-10.py311.nbi").write_text("x")
    kernel_cache.guard_cache(_fake_dispatcher(stale))
    assert (stale / "m.f-10.py311.nbi").exists()
    kernel_cache.guard_cache(SimpleNamespace())  # without the JIT: nothing to do


def test_edited_inlined_helper_is_recompiled_not_loaded_stale(tmp_path: Path) -> None:
    """Run the controller, rerun (loaded from the cache, same inputs), edit the tracking law
    (another module, inlined into the controller step), rerun: the inputs follow the edit.
    Also: the default controller compiles neither the paper's estimator nor the LQ design."""
    pkg = _copy_package(tmp_path / "pkg")
    cache = str(tmp_path / "cache")
    first = _json(_run(CLOSED_LOOP, pkg, NUMBA_CACHE_DIR=cache))
    assert "controller_step" in first["compiled"]
    for unused in ("estimator_update", "estimator_predict", "lq_design"):
        assert unused not in first["compiled"]
    again = _json(_run(CLOSED_LOOP, pkg, NUMBA_CACHE_DIR=cache))
    assert again["hits"] == 1 and "controller_step" not in again["compiled"]
    assert again["u"] == first["u"]
    law = pkg / "stcgym" / "adaptive" / "control" / "law.py"
    text = law.read_text()
    line = "    saturated = abs(u) > action_bound\n"
    assert text.count(line) == 1
    law.write_text(text.replace(line, "    u += 0.25\n" + line))
    edited = _json(_run(CLOSED_LOOP, pkg, NUMBA_CACHE_DIR=cache))
    assert "controller_step" in edited["compiled"] and edited["hits"] == 0
    closed = [i for i, (a, b) in enumerate(zip(first["u"], edited["u"], strict=True)) if a != b]
    assert closed, "the edit did not reach the compiled controller step"


def test_read_only_package_caches_in_the_user_directory(tmp_path: Path) -> None:
    """A read-only installation: numba cannot write next to the sources and caches in the
    user-wide directory (``$XDG_CACHE_HOME/numba``); the second process loads from there."""
    pkg = _copy_package(tmp_path / "pkg")
    folders = ("lanes", "envs", "adaptive", "adaptive/kernels", "adaptive/estimation",
               "adaptive/control", "adaptive/multivariable", "adaptive/regression")  # fmt: skip
    for name in folders:
        (pkg / "stcgym" / name / "__pycache__").write_text("")  # no cache directory possible
    for path in [pkg, *pkg.rglob("*")]:
        path.chmod(path.stat().st_mode & ~(stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))
    xdg = tmp_path / "xdg"
    try:
        runs = [_json(_run(PLANT_STEPS, pkg, XDG_CACHE_HOME=str(xdg))) for _ in range(2)]
    finally:
        for path in [pkg, *pkg.rglob("*")]:
            path.chmod(path.stat().st_mode | stat.S_IWUSR)
    assert runs[0]["cache"].startswith(str(xdg / "numba"))
    assert runs[0]["hits"] == 0 and runs[1]["hits"] == 1
    assert runs[1]["y"] == runs[0]["y"]
    assert not list(pkg.rglob("*.nbi"))


def test_cold_start_script_finds_the_readme_examples() -> None:
    """``benchmarks/cold_start.py`` times the README's three quick-start examples: its section
    heading must still be the README's (a renamed heading stopped the script after the api rows)."""
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "cold_start.py"
    spec = importlib.util.spec_from_file_location("cold_start_script", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    blocks = module.readme_blocks(module.README_SECTION)
    assert len(blocks) == 3
    assert all("import" in block for block in blocks)
