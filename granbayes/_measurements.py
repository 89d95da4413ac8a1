"""The measurement files of an experiment folder, read and validated (private).

``jumps.csv`` (measured jump heights) and the batch table of ``granbayes simulate
--batch``: one validated row per jump, or a clear message naming the file, the row and the
column of the first bad cell (:mod:`granbayes._tables`), before any computation.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ._tables import (
    _FINITE,
    _FRACTION,
    _CsvTable,
    _file_in,
    _Range,
    _read_csv,
    _suggest,
)
from .commands import SETTINGS, command_names
from .errors import InputError
from .experiment import _COMMAND_RANGES, _ROBOT_RANGES, Experiment
from .forces import PARAMETER_NAMES, registered_parameters

__all__ = [
    "BATCH_EXPERIMENT_COLUMNS",
    "BATCH_FORCE_COLUMNS",
    "BATCH_REQUIRED_FORCE_COLUMNS",
    "load_batch_table",
    "load_jumps",
]

#: Force-term parameter columns of a batch table: every parameter of the force-term
#: registry (:data:`granbayes.forces.PARAMETER_NAMES`, in its units).
BATCH_FORCE_COLUMNS: tuple[str, ...] = PARAMETER_NAMES

#: Per-row experiment override columns of a batch table (robot, then command settings).
BATCH_EXPERIMENT_COLUMNS: tuple[str, ...] = (*_ROBOT_RANGES, *_COMMAND_RANGES)


def _force_ranges() -> dict[str, _Range]:
    """Allowed values of the force columns, read from the registry at each call.

    Each column takes the lower bound of its parameter in :mod:`granbayes.forces`, always
    included, and no upper bound: ``r_unload >= 1`` (an unloading line less steep than the
    loading curve would let the bed create energy), the others ``>= 0``. A value the
    simulator refuses (``k = 0``, a value above a parameter's upper bound) is simulated and
    fails alone, with its status.

    Returns
    -------
    dict of str to _Range
        Column name to allowed values, for every registered parameter.
    """
    return {p.name: _Range(p.lower, lower_closed=True) for p in registered_parameters()}


#: The per-row command-setting columns of ``jumps.csv``, in output order.
_JUMP_SETTING_COLUMNS: tuple[str, ...] = SETTINGS

_JUMP_REQUIRED: tuple[str, ...] = ("phi", "command", "height_mm")

_BATCH_REQUIRED: tuple[str, ...] = ("command", "phi")

#: Force parameters a batch table must have a column of: those without an "off" value
#: (``granbayes.forces``: the depth term's stiffness ``k`` [N/m], part of every law). An
#: empty cell is simulated and fails alone, with its status, like ``k = 0``.
BATCH_REQUIRED_FORCE_COLUMNS: tuple[str, ...] = ("k",)


def load_jumps(path: str | Path, experiment: Experiment | None = None) -> pd.DataFrame:
    """Load and validate the measured jumps of an experiment.

    Parameters
    ----------
    path : str or Path
        An experiment folder (``jumps.csv`` inside it is read) or a CSV file.
    experiment : Experiment, optional
        Supplies the command settings of rows that do not give them (default
        ``Experiment()``).

    Returns
    -------
    pandas.DataFrame
        One row per jump, in file order, with ``phi`` [-] (float), ``command`` (str),
        ``height_mm`` [mm] (float), ``trial`` (``Int64``, only if the file has it) and
        always ``freq_hz`` [Hz], ``amplitude_mm`` [mm], ``delay_ms`` [ms] and
        ``settle_periods`` [periods] (float): the row's own value where the column exists
        and the cell is not empty, else ``experiment.command``. Other columns are kept as
        (whitespace-stripped) strings. File columns come first, in file order.

    Raises
    ------
    InputError
        At the first problem in file order, naming the file, the 1-based data row (the
        first line after the header is row 1) and the column: unreadable, malformed or
        empty file, header only, missing ``phi``/``command``/``height_mm`` (row None),
        unknown command, non-numeric, empty or non-finite ``phi``/``height_mm``, ``phi``
        outside (0, 1), ``freq_hz``/``amplitude_mm`` <= 0, ``delay_ms``/``settle_periods``
        < 0, a non-integer ``trial``, or a row with the wrong number of fields.
    """
    experiment = Experiment() if experiment is None else experiment
    numbers = ("phi", "height_mm", "trial", *_JUMP_SETTING_COLUMNS)
    table = _read_csv(_file_in(path, "jumps.csv"), numbers)
    table.require(_JUMP_REQUIRED)
    converted: dict[str, object] = {
        "phi": table.floats("phi", _FRACTION, required=True),
        "command": table.choices("command", command_names()),
        "height_mm": table.floats("height_mm", _FINITE, required=True),
    }
    if "trial" in table.columns:
        converted["trial"] = table.integers("trial")
    for name in _JUMP_SETTING_COLUMNS:
        default = float(getattr(experiment.command, name))
        if name in table.columns:
            values = table.floats(name, _COMMAND_RANGES[name], required=False)
            converted[name] = np.where(np.isnan(values), default, values)
        else:
            converted[name] = np.full(len(table.rows), default)
    table.raise_first_problem()
    return table.frame(converted)


def load_batch_table(path: str | Path) -> pd.DataFrame:
    """Load and validate the input table of ``granbayes simulate --batch``.

    Parameters
    ----------
    path : str or Path
        A CSV file. Required columns: ``command``, ``phi`` [-] and ``k`` [N/m]
        (:data:`BATCH_REQUIRED_FORCE_COLUMNS`; an empty cell makes that row fail with
        status ``failed:bad-input``). Optional numeric columns: the other force-term
        parameters (every parameter registered in :data:`granbayes.forces.TERMS`, in its
        unit) and the per-row experiment overrides :data:`BATCH_EXPERIMENT_COLUMNS` (units of
        ``experiment.toml``).

    Returns
    -------
    pandas.DataFrame
        One row per simulation, in file order: ``command`` (str), ``phi`` (float), each
        optional numeric column present (float, NaN where the cell is empty, meaning "not
        given"), and every other column as (whitespace-stripped) strings, in file order.

    Raises
    ------
    InputError
        At the first problem in file order, naming the file, the 1-based data row and the
        column: unreadable, malformed or empty file, header only, missing required column
        (``command``, ``phi``, ``k``), unknown command, ``phi`` not a number in (0, 1), a
        non-numeric or non-finite value in an optional numeric column, a force parameter
        < 0 (``r_unload`` < 1), or an experiment override outside the range allowed by
        :func:`load_experiment`.
    """
    return _load_batch(path)[0]


def _load_batch(path: str | Path) -> tuple[pd.DataFrame, _CsvTable]:
    """:func:`load_batch_table`, also returning the table as read (for the batch output).

    Returns
    -------
    frame : pandas.DataFrame
        As :func:`load_batch_table` returns it.
    table : _CsvTable
        The file's cells as read (:meth:`_CsvTable.to_text` writes them back).
    """
    ranges = _force_ranges() | _ROBOT_RANGES | _COMMAND_RANGES
    table = _read_csv(_file_in(path, None), ("phi", *ranges))
    table.require(_BATCH_REQUIRED)
    for name in BATCH_REQUIRED_FORCE_COLUMNS:
        if name not in table.columns:
            raise InputError(
                f"missing required column{_suggest(name, table.columns)}: every force law "
                f"has the depth term, whose stiffness {name} [N/m] has no default; the file "
                f"has: {', '.join(table.columns)}",
                file=table.file,
                column=name,
            )
    converted: dict[str, object] = {
        "command": table.choices("command", command_names()),
        "phi": table.floats("phi", _FRACTION, required=True),
    }
    for name, allowed in ranges.items():
        if name in table.columns:
            converted[name] = table.floats(name, allowed, required=False)
    table.raise_first_problem()
    return table.frame(converted), table
