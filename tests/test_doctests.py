"""Docstring examples are tests: doctest every module of the installed ``online_backlash`` package.

The modules are found with :mod:`pkgutil`, including the sub-packages that ship from the
repository's top-level ``replay/`` and ``drivers/`` folders (mapped in ``pyproject.toml``, so
they are not under ``online_backlash/`` on disk and need their own walk).
"""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

import online_backlash
import online_backlash.drivers
import online_backlash.replay
from online_backlash._moved import MOVED_MODULES

FLAGS = doctest.NORMALIZE_WHITESPACE | doctest.ELLIPSIS


def _module_names() -> list[str]:
    names = {"online_backlash"}
    for package in (online_backlash, online_backlash.replay, online_backlash.drivers):
        names.add(package.__name__)
        names.update(m.name for m in pkgutil.walk_packages(package.__path__, package.__name__ + "."))
    return sorted(names - MOVED_MODULES.keys())  # an old name is its new module, doctested under that name


MODULES = _module_names()


def test_the_walk_finds_the_mapped_subpackages():
    assert "online_backlash.replay.csv" in MODULES and "online_backlash.estimators.batch" in MODULES
    assert any(name.startswith("online_backlash.drivers.") for name in MODULES)


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=FLAGS, report=True, verbose=False)
    assert result.failed == 0, f"{result.failed} of {result.attempted} doctest examples failed in {name}"
