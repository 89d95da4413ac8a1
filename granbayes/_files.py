"""Safe writing: a file or a folder appears whole or not at all.

:func:`atomic_path` writes a file through a temporary sibling that is renamed onto the
target only on success; :func:`write_json` and :func:`write_text` use it.
:func:`staged_folder` builds an output folder as ``OUT.partial`` and swaps it in only when
the whole run succeeded (an interrupted run keeps ``OUT.partial`` for a resume).

Used by the command line and by the campaign engine (private to the package; it imports
nothing from it).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "atomic_path",
    "jsonable",
    "partial_folder",
    "staged_folder",
    "write_json",
    "write_text",
]


@contextlib.contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; move it onto ``path`` only on success.

    A failure (an exception inside the ``with`` block) removes the temporary file and
    leaves an existing ``path`` untouched, so a reader never sees a half-written file.
    A process killed inside the block leaves at most a hidden ``.NAME.*.tmp`` sibling.

    Parameters
    ----------
    path : Path
        The final file.

    Yields
    ------
    Path
        Where to write.
    """
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~_umask())
        os.replace(tmp_path, path)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_text(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def jsonable(value: Any) -> Any:
    """Plain JSON values: numpy scalars to Python, tuples to lists, NaN and inf to None."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_json(path: Path, obj: Any) -> None:
    """Write ``obj`` as indented JSON to ``path`` atomically (see :func:`jsonable`)."""
    write_text(path, json.dumps(jsonable(obj), indent=2, allow_nan=False) + "\n")


def partial_folder(out: Path) -> Path:
    """The work folder ``OUT.partial`` of :func:`staged_folder`."""
    out = Path(out)
    return out.with_name(out.name + ".partial")


@contextlib.contextmanager
def staged_folder(out: Path, resume: bool) -> Iterator[Path]:
    """A work folder ``OUT.partial`` that replaces ``out`` only when the block succeeds.

    A failed or interrupted run leaves ``out`` untouched and keeps ``OUT.partial`` (with
    its checkpoints) for a resume; without ``resume`` it is cleared first.

    Parameters
    ----------
    out : Path
        The final folder.
    resume : bool
        Keep an existing ``OUT.partial`` (continue an interrupted run).

    Yields
    ------
    Path
        The work folder.
    """
    out = Path(out)
    work = partial_folder(out)
    if work.exists() and not resume:
        shutil.rmtree(work)
    work.mkdir(parents=True, exist_ok=True)
    yield work
    old = out.with_name(out.name + ".old")
    if old.exists():
        shutil.rmtree(old)
    if out.exists():
        out.rename(old)
    work.rename(out)
    if old.exists():
        shutil.rmtree(old)
