"""The ``Examples`` of the public API run as written: every public name of ``stcgym.envs``,
``stcgym.adaptive``, ``stcgym.agents`` and ``stcgym.envs.vector`` (each one's ``__all__``) and
every public method and property of its classes, with the standard :mod:`doctest` module.

Each example runs in a fresh namespace holding only ``np`` (numpy), so it imports what it uses,
as a user's script would. ``ELLIPSIS`` and ``NORMALIZE_WHITESPACE`` are on.
"""

from __future__ import annotations

import doctest
import importlib
import inspect

import numpy as np
import pytest

#: The public packages, and the vector envs' module: those classes are public through
#: ``gym.make_vec`` rather than through the package's ``__all__``.
MODULES = (
    "stcgym.envs",
    "stcgym.adaptive",
    "stcgym.agents",
    "stcgym.envs.vector",
    "stcgym.envs.family_env",
    "stcgym.envs.tank_family",
)
OPTIONFLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE


def _members(obj: object) -> list[tuple[str, object]]:
    """The public methods and properties a class defines itself (inherited ones are collected
    with the class that defines them)."""
    if not inspect.isclass(obj):
        return []
    out = []
    for key, value in vars(obj).items():
        if key.startswith("_"):
            continue
        if isinstance(value, property):
            out.append((key, value))
        elif callable(value) or isinstance(value, (classmethod, staticmethod)):
            out.append((key, getattr(obj, key)))
    return out


def _documented_objects() -> list[tuple[str, object]]:
    """``(qualified name, object)`` of every public name and member, each object once."""
    out, seen = [], set()
    for package in MODULES:
        module = importlib.import_module(package)
        for name in module.__all__:
            obj = getattr(module, name)
            if not (inspect.isclass(obj) or callable(obj)):
                continue  # data: its text lives in the source as a comment
            for member, value in [("", obj), *_members(obj)]:
                if id(value) in seen:
                    continue
                seen.add(id(value))
                out.append((f"{package}.{name}" + (f".{member}" if member else ""), value))
    return out


def _doctests() -> list[tuple[str, doctest.DocTest]]:
    finder = doctest.DocTestFinder(recurse=False)
    out = []
    for qualname, obj in _documented_objects():
        for test in finder.find(obj, qualname, globs={}):
            if test.examples:
                out.append((qualname, test))
    return out


_TESTS = _doctests()


@pytest.mark.parametrize("test", [pytest.param(t, id=q) for q, t in _TESTS])
def test_the_examples_run_as_written(test):
    test.globs = {"np": np}
    runner = doctest.DocTestRunner(optionflags=OPTIONFLAGS)
    report: list[str] = []
    result = runner.run(test, out=report.append)
    assert result.failed == 0, "".join(report)


def test_the_collection_finds_the_examples_of_classes_functions_and_members():
    names = {q for q, _ in _TESTS}
    assert "stcgym.adaptive.RecursiveLeastSquares" in names  # a class
    assert "stcgym.envs.get_plant" in names  # a function
    assert "stcgym.envs.PlantSpec.dc_gain" in names  # a property
    assert "stcgym.envs.vector.ObserverCanonicalVectorEnv" in names  # a vector env


def test_a_wrong_expected_output_fails():
    def wrong():
        """
        >>> 1 + 1
        3
        """

    (test,) = doctest.DocTestFinder(recurse=False).find(wrong, "wrong", globs={})
    runner = doctest.DocTestRunner(optionflags=OPTIONFLAGS)
    assert runner.run(test, out=lambda _: None).failed == 1
