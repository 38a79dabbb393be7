"""The packages' docstrings index their modules: each names every module beside it, so that a
reader's map of the service cannot go stale (it had listed 16 of 33)."""

from __future__ import annotations

import importlib
import pkgutil
import re

import pytest

import service


def packages() -> list[str]:
    found = ["service"]
    for module in pkgutil.walk_packages(service.__path__, "service."):
        if module.ispkg:
            found.append(module.name)
    return found


@pytest.mark.parametrize("name", packages())
def test_the_docstring_names_every_module_of_the_package(name):
    package = importlib.import_module(name)
    named = set(re.findall(r"``(\w+)``", package.__doc__ or ""))
    modules = {m.name for m in pkgutil.iter_modules(package.__path__)} - {"__main__"}
    assert modules - named == set(), f"{name}'s docstring does not name these modules"
