"""The registry of kinds of measurement: everything about a kind in one entry.

A kind of measurement (jump heights today; tracked trajectories and intrusion curves)
carries, in its :class:`Kind` entry of :data:`KINDS`:

* its file in an experiment folder and its loader with validation (bad input named by
  file, row and column);
* its unit of leave-one-out (a jump, a tracked jump, an intrusion test);
* its likelihood block (:class:`granbayes._likelihood.Block`): what it asks the simulator
  for, its own coordinates and its observation model;
* its part of a fit's DataTree (observed data and their coordinates, read back);
* its residual cells (:mod:`granbayes.stats`) and its figures (:mod:`granbayes.figures`).

Adding a kind is one :func:`register_kind` call plus its tests
(``tests/test_registry.py`` registers one at run time and fits it). The statistics and
figures layers know nothing of this registry; the fit, the criticism and the reports
read it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import pandas as pd

from .._experiment import Experiment
from .._likelihood import Block, ObservationSettings
from .._measurements import Measurements
from ._heights import HEIGHTS
from ._intrusions import INTRUSIONS
from ._kind import Kind
from ._trajectories import TRAJECTORIES

__all__ = [
    "KINDS",
    "Kind",
    "blocks_for",
    "kind_names",
    "load_measurements",
    "measurements",
    "register_kind",
]


#: The registered kinds, in the order their units are numbered.
KINDS: dict[str, Kind] = {}


def register_kind(kind: Kind) -> Kind:
    """Add a kind of measurement to the registry (see the module docstring).

    Parameters
    ----------
    kind : Kind
        The entry; its name must be new.

    Returns
    -------
    Kind

    Raises
    ------
    ValueError
        If a kind of that name is registered already.
    """
    if kind.name in KINDS:
        raise ValueError(f"a kind named {kind.name!r} is registered already")
    KINDS[kind.name] = kind
    return kind


def kind_names() -> tuple[str, ...]:
    """Names of the registered kinds, in unit order."""
    return tuple(KINDS)


def measurements(tables: Mapping[str, pd.DataFrame]) -> Measurements:
    """Tables of several kinds as :class:`~granbayes.Measurements` (registry order).

    Parameters
    ----------
    tables : mapping of str to pandas.DataFrame
        Kind name to its validated table.

    Returns
    -------
    Measurements

    Raises
    ------
    KeyError
        For an unregistered kind.
    """
    unknown = sorted(set(tables) - set(KINDS))
    if unknown:
        raise KeyError(f"unknown kind(s) {unknown}; registered: {', '.join(KINDS)}")
    ordered = {k: tables[k] for k in KINDS if k in tables}
    return Measurements(ordered, {k: KINDS[k].unit_column for k in ordered})


def load_measurements(
    folder: str | Path, experiment: Experiment, use: Sequence[str] | None = None
) -> Measurements:
    """Every measurement file of an experiment folder, read and validated.

    Parameters
    ----------
    folder : str or Path
        The experiment folder.
    experiment : Experiment
        Its settings (command defaults of rows that do not give them).
    use : sequence of str, optional
        The kinds to read (``granbayes fit --data``); default: every kind whose file is
        in the folder.

    Returns
    -------
    Measurements

    Raises
    ------
    InputError
        For a bad file (naming file, row and column), a requested kind whose file is
        missing, or a folder with no measurement file at all.
    """
    from .._errors import InputError

    folder = Path(folder)
    names = (
        list(use) if use is not None else [k for k in KINDS if (folder / KINDS[k].file).exists()]
    )
    unknown = [k for k in names if k not in KINDS]
    if unknown:
        raise InputError(
            f"unknown kind of data {', '.join(unknown)}; known: {', '.join(KINDS)}", file=folder
        )
    if not names:
        files = ", ".join(k.file for k in KINDS.values())
        raise InputError(
            f"no measurement file in the folder (expected one of {files})", file=folder
        )
    tables = {}
    for name in names:
        path = folder / KINDS[name].file
        if not path.exists():
            raise InputError(f"--data {name}: no {KINDS[name].file} in the folder", file=folder)
        tables[name] = KINDS[name].load(path, experiment)
    return measurements(tables)


def blocks_for(data: Measurements, settings: ObservationSettings) -> list[Block]:
    """The likelihood blocks of some measurements, one per kind present (unit order).

    Parameters
    ----------
    data : Measurements
        The measurements of one model.
    settings : ObservationSettings
        Observation-model settings.

    Returns
    -------
    list of Block
    """
    return [KINDS[k].block(data.tables[k], settings) for k in data.kinds]


register_kind(HEIGHTS)
register_kind(TRAJECTORIES)
register_kind(INTRUSIONS)
