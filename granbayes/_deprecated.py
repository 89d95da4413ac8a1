"""Old public names kept as deprecated aliases of their new ones (PEP 562 module attributes).

A module lists its aliases, old name -> new name, and uses :func:`alias_getattr` as its
module ``__getattr__``: ``from granbayes.fitting import FitConfig`` then still works, gives
the very class now named ``FitSettings`` and warns (``DeprecationWarning``, pointing at the
line that used the old name). The aliases are not in ``__all__``.
"""

from __future__ import annotations

import sys
import warnings
from collections.abc import Callable, Mapping

__all__ = ["alias_getattr", "warn_alias"]


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
