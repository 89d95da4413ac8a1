"""The public examples in the package's docstrings run and print what they show.

Every module of the package is run through ``doctest`` (``ELLIPSIS`` and
``NORMALIZE_WHITESPACE``); an example that only illustrates a call that writes files or
takes minutes says ``# doctest: +SKIP``. The test also fails if the package loses all of
its examples (a collector that finds nothing checks nothing).
"""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

import granbayes

#: Every module and subpackage module (``granbayes.analysis.maps`` too), the command's entry
#: point and the package data excepted.
MODULES = sorted(
    info.name.removeprefix("granbayes.")
    for info in pkgutil.walk_packages(granbayes.__path__, "granbayes.")
    if not info.name.endswith("__main__") and not info.name.startswith("granbayes.data")
)


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples_run(name: str) -> None:
    module = importlib.import_module(f"granbayes.{name}")
    flags = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE
    result = doctest.testmod(module, optionflags=flags, verbose=False)
    assert result.failed == 0, f"granbayes.{name}: {result.failed} example(s) failed"


def test_the_package_has_examples() -> None:
    attempted = 0
    for name in MODULES:
        module = importlib.import_module(f"granbayes.{name}")
        finder = doctest.DocTestFinder()
        attempted += sum(len(t.examples) for t in finder.find(module))
    assert attempted >= 15
