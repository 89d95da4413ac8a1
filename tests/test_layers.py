"""Who imports whom: the package follows the flow of data and nothing reaches back up.

The import graph is read from the source (``ast``, no import is executed), between the
package's top-level modules and subpackages (``granbayes._fitting``, ``granbayes.stats``,
...). Each rule below is a design decision of the README's "Package layout"; a change that
breaks one must change the design on purpose, not by accident.
"""

from __future__ import annotations

import ast
from functools import cache
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "granbayes"


def _unit(module: str) -> str:
    """``granbayes.stats._loo`` -> ``stats``; ``granbayes`` -> ``granbayes``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


@cache
def _module_imports() -> dict[str, set[str]]:
    """Full module name -> full names of the package modules it imports."""
    graph: dict[str, set[str]] = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        is_init = parts[-1] == "__init__"
        if is_init:
            parts = parts[:-1]
        module = ".".join(parts)
        package = parts if is_init else parts[:-1]
        found: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package[: len(package) - (node.level - 1)]
                    target = ".".join(base + ([node.module] if node.module else []))
                    if node.module is None:  # from . import x
                        found.update(f"{target}.{a.name}" for a in node.names)
                    else:
                        found.add(target)
                elif node.module and node.module.split(".")[0] == "granbayes":
                    found.add(node.module)
            elif isinstance(node, ast.Import):
                found.update(a.name for a in node.names if a.name.split(".")[0] == "granbayes")
        graph[module] = found
    return graph


@cache
def _unit_graph() -> dict[str, set[str]]:
    """Top-level module or subpackage -> the other ones it imports."""
    graph: dict[str, set[str]] = {}
    for module, targets in _module_imports().items():
        unit = _unit(module)
        graph.setdefault(unit, set()).update(_unit(t) for t in targets if _unit(t) != unit)
    return graph


def _reach(unit: str) -> set[str]:
    """Every unit imported by ``unit``, directly or through others."""
    graph, seen, todo = _unit_graph(), set(), [unit]
    while todo:
        for nxt in graph.get(todo.pop(), ()):
            if nxt not in seen:
                seen.add(nxt)
                todo.append(nxt)
    return seen


def test_the_graph_is_read() -> None:
    """The reader sees the imports it must see (a broken reader would pass every rule)."""
    graph = _unit_graph()
    assert {"stats", "figures", "_sampler", "_fitting", "testing", "_criticism"} <= set(graph)
    assert "_likelihood" in graph["_fitting"] and "_sampler" in graph["_fitting"]
    assert "stats" in graph["report"]


def test_no_cycles_between_modules() -> None:
    """The package's modules form a directed acyclic graph; none imports the package root."""
    for unit in _unit_graph():
        if unit != "granbayes":
            assert unit not in _reach(unit), f"{unit} imports itself back"
            assert "granbayes" not in _unit_graph()[unit], f"{unit} imports the package root"


def test_the_sampler_knows_nothing_of_the_model() -> None:
    """Like emcee: the ensemble sampler imports no other module of the package."""
    assert _unit_graph()["_sampler"] == set()


@pytest.mark.parametrize("layer", ["stats", "figures"])
def test_statistics_and_figures_know_nothing_of_fits(layer: str) -> None:
    """The statistics and figures layers take DataTrees and arrays, never a fit's machinery."""
    forbidden = {"_sampler", "_likelihood", "_fitting", "_criticism", "kinds", "_saved", "report"}
    assert not (_reach(layer) & forbidden), sorted(_reach(layer) & forbidden)


def test_the_report_only_writes() -> None:
    """The report reads saved results: it imports neither the fitting nor the sampling."""
    assert not (_unit_graph()["report"] & {"_sampler", "_fitting", "_criticism", "_likelihood"})


def test_the_oracle_shares_no_numerical_code_with_the_kernel() -> None:
    """The test kit's data makers never reach the compiled kernel or the simulator."""
    makers = {
        f"granbayes.testing.{m}"
        for m in ("_oracle", "_effects", "_synthetic", "_lab", "_replicate")
    }
    for module in makers:
        targets = _module_imports()[module]
        inside = {t for t in targets if t.startswith("granbayes.testing")}
        assert inside <= makers, (module, inside - makers)
        units = {_unit(t) for t in targets - inside}
        reach = units | set().union(*(_reach(u) for u in units))
        assert not reach & {"_kernel", "_simulator", "_synthetic"}, module


def test_the_package_imports_the_test_kit_only_for_the_verdict_study_and_joint_sbc() -> None:
    """Fits, diagnoses and reports never depend on the test kit; its data makers do.

    The verdict study makes its data sets with the oracle, and the simulation-based
    calibration of a joint fit its replicates (``_sbc.draw_measurements``).
    """
    users = {u for u, d in _unit_graph().items() if "testing" in d and u != "testing"}
    assert users == {"calibration", "_sbc"}
