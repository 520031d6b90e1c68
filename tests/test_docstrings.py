"""Every public name of the checked packages, and every public method and property of its
classes, has a docstring (a member may inherit its base class's, as :func:`inspect.getdoc`
does); the API reference is generated from them."""

from __future__ import annotations

import importlib
import inspect

import pytest

#: The packages (and the vector envs' module, public through ``gym.make_vec``) whose public
#: names must all carry a docstring.
CHECKED_PACKAGES = (
    "stcgym.envs",
    "stcgym.envs.vector",
    "stcgym.envs.family_env",
    "stcgym.envs.tank_family",
    "stcgym.adaptive",
    "stcgym.agents",
)


def _public_names(package: str) -> list[tuple[str, object]]:
    module = importlib.import_module(package)
    return [(name, getattr(module, name)) for name in module.__all__]


def _undocumented(obj: object) -> list[str]:
    """Names of ``obj`` (a class or function) and of its public members without a docstring:
    ``"."`` for ``obj`` itself. Data (dicts, numbers) carries no docstring of its own and is
    documented where it is defined; it is skipped here."""
    if inspect.ismodule(obj) or not (inspect.isclass(obj) or callable(obj)):
        return []
    missing = [] if inspect.getdoc(obj) else ["."]
    if inspect.isclass(obj):
        for key, value in vars(obj).items():
            if key.startswith("_") or not _is_routine_or_property(value):
                continue
            if not inspect.getdoc(getattr(obj, key)) and not _inherited_doc(obj, key):
                missing.append(key)
    return missing


def _is_routine_or_property(value: object) -> bool:
    return callable(value) or isinstance(value, (property, classmethod, staticmethod))


def _inherited_doc(cls: type, key: str) -> bool:
    return any(
        inspect.getdoc(getattr(base, key, None)) for base in cls.__mro__[1:] if hasattr(base, key)
    )


@pytest.mark.parametrize("package", CHECKED_PACKAGES)
def test_every_public_name_and_member_has_a_docstring(package):
    missing = [
        f"{package}.{name}" + ("" if member == "." else f".{member}")
        for name, obj in _public_names(package)
        for member in _undocumented(obj)
    ]
    assert not missing, f"{len(missing)} public names without a docstring: {missing}"


def test_the_check_sees_a_missing_docstring():
    class Documented:
        """A class with one undocumented method and one undocumented property."""

        def method(self):
            pass

        @property
        def value(self):
            return 0

        def _private(self):
            pass

    def bare():
        pass

    assert _undocumented(Documented) == ["method", "value"]
    assert _undocumented(bare) == ["."]
    assert _undocumented({"data": 1}) == []
