"""Packaging: every module imports, every third-party import is declared, one version, a
licence, and the reference data inside the package.

The installed wheel itself is tested in ``tests/test_install.py``.
"""

from __future__ import annotations

import ast
import importlib
import importlib.metadata
import pkgutil
import re
import sys
import tomllib
from pathlib import Path

import pytest

import granbayes

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = Path(granbayes.__file__).resolve().parent
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())


def _modules() -> list[str]:
    return sorted(m.name for m in pkgutil.walk_packages(granbayes.__path__, prefix="granbayes."))


def _normalise(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _requirement(text: str) -> tuple[str, list[str], str]:
    """(name, extras, marker) of a requirement string such as ``dask[distributed]>=2024``."""
    text, _, marker = text.partition(";")
    m = re.match(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)\s*(?:\[([^\]]*)\])?", text)
    extras = [e.strip() for e in (m.group(2) or "").split(",") if e.strip()]
    return _normalise(m.group(1)), extras, marker.strip()


def _declared() -> set[str]:
    """Distributions the runtime dependencies declare, with those their extras pull in."""
    declared = set()
    for text in PYPROJECT["project"]["dependencies"]:
        name, extras, _ = _requirement(text)
        declared.add(name)
        for req in importlib.metadata.requires(name) or []:
            sub, _, marker = _requirement(req)
            if any(re.search(rf"extra\s*==\s*['\"]{e}['\"]", marker) for e in extras):
                declared.add(sub)
    return declared


def _third_party_imports(path: Path) -> set[str]:
    """Top-level names of the absolute imports in a source file, stdlib excluded."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names.update(alias.name.partition(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.partition(".")[0])
    return {n for n in names if n not in sys.stdlib_module_names and n != "granbayes"}


@pytest.mark.parametrize("module", _modules())
def test_every_module_imports(module: str) -> None:
    """Each module of the package imports on its own."""
    importlib.import_module(module)


def test_every_third_party_import_is_declared() -> None:
    """Every third-party package a module imports (at the top or inside a function) comes
    from a distribution that pyproject.toml's dependencies declare, directly or through a
    declared extra (``dask[distributed]``)."""
    to_distributions = importlib.metadata.packages_distributions()
    declared = _declared()
    missing = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        for name in _third_party_imports(path):
            dists = {_normalise(d) for d in to_distributions.get(name, [name])}
            if not dists & declared:
                missing.setdefault(name, []).append(str(path.relative_to(PACKAGE)))
    assert not missing, f"imported but not declared in pyproject.toml: {missing}"


def test_version_is_written_once() -> None:
    """The version lives in pyproject.toml; the package reads its installed metadata."""
    version = PYPROJECT["project"]["version"]
    assert granbayes.__version__ == importlib.metadata.version("granbayes") == version
    for path in PACKAGE.rglob("*.py"):
        assert f'"{version}"' not in path.read_text(encoding="utf-8"), path


def test_licence() -> None:
    """A BSD-3-Clause LICENSE file, as pyproject.toml declares, shipped in the wheel."""
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("BSD 3-Clause License")
    assert "Copyright (c)" in text and "the granbayes developers" in text
    assert PYPROJECT["project"]["license"] == "BSD-3-Clause"
    assert PYPROJECT["project"]["license-files"] == ["LICENSE"]


def test_reference_data_is_package_data() -> None:
    """The demo's data set lives inside the package and the package data pattern ships all
    of it; no module builds a path above its own folder."""
    from granbayes._cli import REFERENCE_DATA as cli_reference
    from granbayes._synthetic import REFERENCE_DATA

    assert cli_reference == REFERENCE_DATA
    assert REFERENCE_DATA.resolve().is_relative_to(PACKAGE)
    files = sorted(p.name for p in REFERENCE_DATA.iterdir())
    assert {"experiment.toml", "jumps.csv", "TRUTH.md", "truth.toml"} <= set(files)
    patterns = PYPROJECT["tool"]["setuptools"]["package-data"]["granbayes"]
    for name in files:
        rel = (REFERENCE_DATA / name).relative_to(PACKAGE)
        assert any(rel.match(p) for p in patterns), rel
    for path in PACKAGE.rglob("*.py"):
        assert not re.search(r"parents\[\d\]|\.parent\.parent", path.read_text()), path
