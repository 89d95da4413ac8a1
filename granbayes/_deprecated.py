"""Old public names kept as deprecated aliases of their new ones (PEP 562 module attributes).

A module lists its aliases, old name -> new name, and uses :func:`alias_getattr` as its
module ``__getattr__``: ``from granbayes._fitting import FitConfig`` then still works, gives
the very class now named ``FitSettings`` and warns (``DeprecationWarning``, pointing at the
line that used the old name). The aliases are not in ``__all__``.
"""

from __future__ import annotations

import functools
import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import os
import sys
import warnings
from collections.abc import Callable, Mapping
from types import ModuleType
from typing import Any, TypeVar

_F = TypeVar("_F", bound=Callable[..., Any])

__all__ = [
    "alias_getattr",
    "install_moved_modules",
    "outside_package",
    "renamed_keyword",
    "warn_alias",
]


def warn_alias(module: str, old: str, new: str) -> None:
    """Warn that ``module.old`` is a deprecated alias of ``module.new`` (for its user)."""
    warnings.warn(
        f"{module}.{old} is a deprecated alias of {new}; use {new}",
        DeprecationWarning,
        stacklevel=3,  # the line that used the old name (through the module __getattr__)
    )


def alias_getattr(module: str, aliases: Mapping[str, str]) -> Callable[[str], object]:
    """A module ``__getattr__`` serving ``aliases`` (old name -> new name) with a warning.

    Parameters
    ----------
    module : str
        The module's ``__name__``.
    aliases : mapping of str to str
        Deprecated name -> the name of the same object now.

    Returns
    -------
    callable
        ``__getattr__(name)``: the object now named ``aliases[name]``, after a
        ``DeprecationWarning``; ``AttributeError`` for any other name.
    """

    def __getattr__(name: str) -> object:
        new = aliases.get(name)
        if new is None:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        warn_alias(module, name, new)
        return getattr(sys.modules[module], new)

    return __getattr__


class _MovedModuleLoader(importlib.abc.Loader):
    """Loads an old module path as the module now at its new path."""

    def __init__(self, new: str) -> None:
        self.new = new

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        private = any(part.startswith("_") for part in self.new.split("."))
        use = "the names 'granbayes' exports" if private else self.new
        warnings.warn(
            f"{spec.name} is a deprecated module path (now {self.new}); use {use}",
            DeprecationWarning,
            stacklevel=2,
        )
        return importlib.import_module(self.new)

    def exec_module(self, module: ModuleType) -> None:
        """Nothing to run: the module at the new path is already executed."""


class _MovedModuleFinder(importlib.abc.MetaPathFinder):
    """Finds the old paths of moved modules (old path -> new path)."""

    def __init__(self, moved: Mapping[str, str]) -> None:
        self.moved = dict(moved)

    def find_spec(self, fullname, path=None, target=None):
        new = self.moved.get(fullname)
        if new is None:
            return None
        return importlib.util.spec_from_loader(fullname, _MovedModuleLoader(new))


def install_moved_modules(moved: Mapping[str, str]) -> None:
    """Make old module paths importable as the modules now at the new paths.

    Parameters
    ----------
    moved : mapping of str to str
        Old dotted module path -> new dotted module path.
    """
    if not any(isinstance(f, _MovedModuleFinder) for f in sys.meta_path):
        sys.meta_path.append(_MovedModuleFinder(moved))


_PACKAGE = os.path.dirname(os.path.abspath(__file__)) + os.sep


def outside_package() -> int:
    """The ``stacklevel`` of the first frame outside the package, for ``warnings.warn``.

    Called by the function that warns: a deprecation names the user's line even through
    decorators and public functions that pass the old form on. (``skip_file_prefixes``
    would say the same, but does not skip at ``stacklevel=2`` in Python 3.12.1.)

    Returns
    -------
    int
        1 for the caller itself, 2 for its caller, ...
    """
    level, frame = 1, sys._getframe(1)
    while frame is not None and os.path.abspath(frame.f_code.co_filename).startswith(_PACKAGE):
        level, frame = level + 1, frame.f_back
    return level


def renamed_keyword(old: str, new: str = "settings") -> Callable[[_F], _F]:
    """Decorator: a function's keyword ``old`` is now ``new``; ``old=`` still works, warned.

    The project's vocabulary names every ``*Settings`` argument ``settings``; the public
    functions that called it ``config`` or ``options`` accept the old keyword with a
    ``DeprecationWarning`` that points at the caller's line.

    Parameters
    ----------
    old : str
        The former keyword.
    new : str
        The keyword now.

    Returns
    -------
    callable
        The decorator.
    """

    def decorate(func: _F) -> _F:
        @functools.wraps(func)
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            if old in kwargs:
                if new in kwargs:
                    raise TypeError(f"{func.__name__}() got both {old}= and {new}=")
                warnings.warn(
                    f"{func.__name__}({old}=...) is deprecated; use {new}=...",
                    DeprecationWarning,
                    stacklevel=outside_package(),  # decorators stack: name the caller
                )
                kwargs[new] = kwargs.pop(old)
            return func(*args, **kwargs)

        return wrapper  # type: ignore[return-value]

    return decorate
