"""numpydoc enforced: every public callable documents every parameter it takes.

For each name in the ``__all__`` of every public module of the package: functions (and
methods of public classes) need a numpydoc ``Parameters`` section naming each parameter of
their signature (``*args``/``**kwargs`` excepted); classes document their constructor's
fields under ``Parameters`` or ``Attributes``. Style (sections, blank lines, capitals) is
ruff's pydocstyle with the numpy convention (``pyproject.toml``).
"""

from __future__ import annotations

import importlib
import inspect
import re

import pytest

import granbayes

SECTION = re.compile(
    r"^(?P<name>Parameters|Attributes|Other Parameters)\n-+\n(?P<body>.*?)(?=^\S[^\n]*\n-+\n|\Z)",
    re.S | re.M,
)
ENTRY = re.compile(r"^(?P<names>\*{0,2}[A-Za-z_][\w]*(?:\s*,\s*\*{0,2}[A-Za-z_][\w]*)*)\s*(?::|$)")


def documented(doc: str, sections: tuple[str, ...]) -> set[str] | None:
    """Names documented in the given numpydoc sections (``None``: no such section)."""
    doc = inspect.cleandoc(doc)
    names: set[str] | None = None
    for m in SECTION.finditer(doc):
        if m.group("name") not in sections:
            continue
        names = names or set()
        for line in m.group("body").splitlines():
            e = ENTRY.match(line)  # entries start at column 0; descriptions are indented
            if e:
                names |= {n.strip().lstrip("*") for n in e.group("names").split(",")}
    return names


#: Modules whose ``__all__`` is checked: the public surface (``granbayes`` and
#: ``PUBLIC_MODULES``) and the implementation modules behind it (their names are what the
#: top level re-exports, and what the rest of the package calls).
CHECKED = sorted({"granbayes", *granbayes.PUBLIC_MODULES, *granbayes.MOVED_MODULES.values()})


def _public() -> list[tuple[str, str, object]]:
    out, seen = [], set()
    for module_name in CHECKED:
        module = importlib.import_module(module_name)
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name)
            if not (inspect.isfunction(obj) or inspect.isclass(obj)) or id(obj) in seen:
                continue  # re-exported names are checked once, where they are defined
            seen.add(id(obj))
            out.append((module_name, name, obj))
            if inspect.isclass(obj):
                for mname, meth in vars(obj).items():
                    if inspect.isfunction(meth) and not mname.startswith("_"):
                        out.append((module_name, f"{name}.{mname}", meth))
    return out


def _parameters(obj: object) -> list[str]:
    try:
        sig = inspect.signature(obj)
    except (TypeError, ValueError):
        return []
    skip = (inspect.Parameter.VAR_POSITIONAL, inspect.Parameter.VAR_KEYWORD)
    return [
        p.name
        for p in sig.parameters.values()
        if p.name not in ("self", "cls") and p.kind not in skip and not p.name.startswith("_")
    ]


@pytest.mark.parametrize(
    ("module", "name", "obj"), [pytest.param(*p, id=f"{p[0]}.{p[1]}") for p in _public()]
)
def test_every_parameter_is_documented(module: str, name: str, obj: object) -> None:
    doc = inspect.getdoc(obj) or ""
    assert doc.strip(), f"{module}.{name} has no docstring"
    params = _parameters(obj)
    if not params:
        return
    sections = ("Parameters", "Attributes") if inspect.isclass(obj) else ("Parameters",)
    names = documented(doc, sections)
    assert names is not None, f"{module}.{name}: no {'/'.join(sections)} section"
    missing = [p for p in params if p not in names]
    assert not missing, f"{module}.{name}: parameters not documented: {missing}"
