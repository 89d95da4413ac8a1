"""The measurement files of an experiment folder, read and validated (private).

``jumps.csv`` (measured jump heights), ``trajectories.csv`` (tracked jumps, one row per
video frame), ``intrusions.csv`` (force-depth curves of constant-speed intrusions) and the
batch table of ``granbayes simulate --batch``: one validated row per record, or a clear
message naming the file, the row and the column of the first bad cell
(:mod:`granbayes._tables`), before any computation.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from ._errors import InputError
from ._experiment import _COMMAND_RANGES, _ROBOT_RANGES, Experiment
from ._tables import (
    _FINITE,
    _FRACTION,
    _POSITIVE,
    _CsvTable,
    _file_in,
    _Range,
    _read_csv,
    _suggest,
)
from .commands import SETTINGS, CommandSettings, build_command, command_names
from .forces import PARAMETER_NAMES, registered_parameters

__all__ = [
    "BATCH_EXPERIMENT_COLUMNS",
    "BATCH_FORCE_COLUMNS",
    "BATCH_REQUIRED_FORCE_COLUMNS",
    "FRAME_LIMIT_S",
    "load_batch_table",
    "load_intrusions",
    "load_jumps",
    "load_trajectories",
    "Measurements",
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


#: Latest frame time a tracked jump may have after its command ends [s]: the simulation
#: of a tracked jump runs to its last frame (physics-model.md section 5b).
FRAME_LIMIT_S = 5.0

#: Columns of ``trajectories.csv`` that must not change between the frames of one jump.
_PER_JUMP = ("phi", "command", "trial", *SETTINGS)

_TRAJECTORY_REQUIRED: tuple[str, ...] = ("jump", "phi", "command", "t_s")
_POSITION_COLUMNS: tuple[str, ...] = ("x_foot_mm", "x_rod_mm")

_INTRUSION_REQUIRED: tuple[str, ...] = ("test", "phi", "speed_mm_s", "depth_mm", "force_N")
_NON_NEGATIVE = _Range(0.0, lower_closed=True)


def _constant_within(
    table: _CsvTable, groups: np.ndarray, values: object, column: str, what: str
) -> None:
    """Record the first row where ``column`` differs from its group's first row.

    Parameters
    ----------
    table : _CsvTable
        The file (problems are recorded in it).
    groups : ndarray of int
        Group code of every record (a tracked jump, an intrusion test).
    values : array_like
        The column's converted values (NaN compares equal to NaN).
    column : str
        The column, for the message.
    what : str
        What a group is, for the message (``"jump"``, ``"test"``).
    """
    v = pd.Series(np.asarray(values, dtype=object))
    first_index = pd.Series(np.arange(len(v))).groupby(groups).transform("first").to_numpy()
    first = v.to_numpy()[first_index]
    same = (v.to_numpy() == first) | (pd.isna(v).to_numpy() & pd.isna(first))
    ids = table.texts(what)

    def problem(i: int) -> str:
        r0 = int(table.rows[first_index[i]])
        return (
            f"{column} changes within {what} '{ids[i]}': '{table.cell(i, column)}' here, "
            f"'{table.cell(first_index[i], column)}' in row {r0}; one {what} has one {column}"
        )

    table.report_first(column, ~same, problem)


def _group_codes(table: _CsvTable, column: str) -> np.ndarray:
    """Integer code of every record's group id (``jump``, ``test``); empty ids recorded."""
    ids = table.texts(column)
    empty = np.array([not t for t in ids], dtype=bool)
    table.report_first(column, empty, lambda i: "empty cell, expected an id")
    codes, _ = pd.factorize(pd.Series(ids), sort=False)
    return codes


def load_trajectories(path: str | Path, experiment: Experiment | None = None) -> pd.DataFrame:
    """Load and validate the tracked jumps of an experiment (one row per video frame).

    Parameters
    ----------
    path : str or Path
        An experiment folder (``trajectories.csv`` inside it is read) or a CSV file.
    experiment : Experiment, optional
        Supplies the command settings of jumps that do not give them (default
        ``Experiment()``).

    Returns
    -------
    pandas.DataFrame
        One row per frame, in file order: ``jump`` (str, the id), ``phi`` [-],
        ``command``, ``t_s`` [s], ``x_foot_mm`` and/or ``x_rod_mm`` [mm] (whichever the
        file has), ``trial`` (``Int64``, if the file has it) and always the command
        settings ``freq_hz``, ``amplitude_mm``, ``delay_ms``, ``settle_periods`` (the
        row's value, else ``experiment.command``).

    Raises
    ------
    InputError
        At the first problem in file order, naming the file, the row and the column: a
        missing required column or neither position column; an empty ``jump``; a bad
        ``phi``, ``command`` or setting (as in ``jumps.csv``); a non-finite ``t_s`` or
        position; ``t_s`` not strictly increasing within a jump; ``phi``, ``command``,
        ``trial`` or a setting that changes between the frames of one jump; a frame more
        than :data:`FRAME_LIMIT_S` after the end of its jump's command.
    """
    experiment = Experiment() if experiment is None else experiment
    numbers = ("phi", "t_s", "trial", *_POSITION_COLUMNS, *_JUMP_SETTING_COLUMNS)
    table = _read_csv(_file_in(path, "trajectories.csv"), numbers)
    table.require(_TRAJECTORY_REQUIRED)
    positions = [c for c in _POSITION_COLUMNS if c in table.columns]
    if not positions:
        raise InputError(
            "no position column: a tracked jump needs x_foot_mm (foot height above the "
            "surface [mm]), x_rod_mm (rod displacement [mm]) or both; the file has: "
            + ", ".join(table.columns),
            file=table.file,
            column="x_foot_mm",
        )
    groups = _group_codes(table, "jump")
    converted: dict[str, object] = {
        "jump": table.texts("jump"),
        "phi": table.floats("phi", _FRACTION, required=True),
        "command": table.choices("command", command_names()),
        "t_s": table.floats("t_s", _FINITE, required=True),
    }
    for name in positions:
        converted[name] = table.floats(name, _FINITE, required=True)
    if "trial" in table.columns:
        converted["trial"] = table.integers("trial")
    for name in _JUMP_SETTING_COLUMNS:
        default = float(getattr(experiment.command, name))
        if name in table.columns:
            values = table.floats(name, _COMMAND_RANGES[name], required=False)
            converted[name] = np.where(np.isnan(values), default, values)
        else:
            converted[name] = np.full(len(table.rows), default)
    for name in _PER_JUMP:
        if name in table.columns:
            _constant_within(table, groups, converted[name], name, "jump")
    t = np.asarray(converted["t_s"], dtype=float)
    previous = pd.Series(t).groupby(groups).shift(1).to_numpy()
    ids = converted["jump"]
    table.report_first(
        "t_s",
        np.isfinite(previous) & ~(t > previous),
        lambda i: (
            f"t_s = {table.cell(i, 't_s')} is not after the previous frame of jump "
            f"'{ids[i]}' ({previous[i]:g} s): frame times must increase strictly"
        ),
    )
    table.raise_first_problem()
    frame = table.frame(converted)
    # frames far beyond the command: the simulation of a tracked jump runs to its last frame
    for code in np.unique(groups):
        rows = np.flatnonzero(groups == code)
        r = frame.iloc[rows[0]]
        settings = CommandSettings(**{s: float(r[s]) for s in SETTINGS})
        end = build_command(str(r["command"]), settings).t_end
        late = rows[t[rows] > end + FRAME_LIMIT_S]
        if len(late):
            i = int(late[0])
            table.report(
                int(table.rows[i]),
                "t_s",
                f"t_s = {table.cell(i, 't_s')} is more than {FRAME_LIMIT_S:g} s after the "
                f"end of the command of jump '{ids[i]}' ({end:.4g} s)",
            )
    table.raise_first_problem()
    return frame


def load_intrusions(path: str | Path) -> pd.DataFrame:
    """Load and validate the intrusion tests of an experiment (one row per sample).

    Parameters
    ----------
    path : str or Path
        An experiment folder (``intrusions.csv`` inside it is read) or a CSV file.

    Returns
    -------
    pandas.DataFrame
        One row per sample, in file order: ``test`` (str, the id), ``phi`` [-],
        ``speed_mm_s`` [mm/s], ``depth_mm`` [mm], ``force_N`` [N] and ``foot_radius`` [m]
        (NaN where not given: the robot's).

    Raises
    ------
    InputError
        At the first problem in file order, naming the file, the row and the column: a
        missing required column; an empty ``test``; ``phi`` outside (0, 1); a negative or
        non-finite ``speed_mm_s`` or ``depth_mm``; a non-finite ``force_N``; a
        ``foot_radius`` <= 0; ``phi``, ``speed_mm_s`` or ``foot_radius`` that changes
        between the samples of one test.
    """
    numbers = ("phi", "speed_mm_s", "depth_mm", "force_N", "foot_radius")
    table = _read_csv(_file_in(path, "intrusions.csv"), numbers)
    table.require(_INTRUSION_REQUIRED)
    groups = _group_codes(table, "test")
    converted: dict[str, object] = {
        "test": table.texts("test"),
        "phi": table.floats("phi", _FRACTION, required=True),
        "speed_mm_s": table.floats("speed_mm_s", _NON_NEGATIVE, required=True),
        "depth_mm": table.floats("depth_mm", _NON_NEGATIVE, required=True),
        "force_N": table.floats("force_N", _FINITE, required=True),
    }
    if "foot_radius" in table.columns:
        converted["foot_radius"] = table.floats("foot_radius", _POSITIVE, required=False)
    else:
        converted["foot_radius"] = np.full(len(table.rows), np.nan)
    for name in ("phi", "speed_mm_s", "foot_radius"):
        if name in table.columns:
            _constant_within(table, groups, converted[name], name, "test")
    table.raise_first_problem()
    return table.frame(converted)


class Measurements:
    """Every measurement of an experiment: one table per kind, and their units.

    A *unit* is what leave-one-out leaves out: a jump of ``jumps.csv``, a tracked jump of
    ``trajectories.csv`` (all its frames), an intrusion test of ``intrusions.csv`` (all
    its samples). Units are numbered across kinds, kind by kind in the order of
    ``tables``, and within a kind in order of first appearance.

    Parameters
    ----------
    tables : mapping of str to pandas.DataFrame
        Kind name to its validated table (every row has ``phi``); kinds without rows are
        dropped.
    unit_columns : mapping of str to str or None
        Kind name to the column naming its units (``None``: every row is a unit).
    origin : mapping of str to ndarray, optional
        For measurements selected from others (:meth:`select`): the row each row was in
        the original tables (default: the rows themselves).

    Examples
    --------
    >>> import pandas as pd
    >>> m = Measurements.from_jumps(pd.DataFrame({"phi": [0.6, 0.6], "height_mm": [1, 2]}))
    >>> m.kinds, m.n_units
    (('heights',), 2)
    """

    def __init__(
        self,
        tables: Mapping[str, pd.DataFrame],
        unit_columns: Mapping[str, str | None],
        origin: Mapping[str, np.ndarray] | None = None,
    ) -> None:
        kept = {k: t for k, t in tables.items() if len(t)}
        self.tables = {k: t.reset_index(drop=True) for k, t in kept.items()}
        self.unit_columns = {k: unit_columns.get(k) for k in self.tables}
        #: Row of every row in the tables these were selected from (itself: 0, 1, ...).
        self.origin = {
            k: np.arange(len(t)) if origin is None else np.asarray(origin[k])
            for k, t in self.tables.items()
        }
        self._unit_of_row: dict[str, np.ndarray] = {}
        self._n: dict[str, int] = {}
        for kind, table in self.tables.items():
            col = self.unit_columns[kind]
            if col is None:
                codes = np.arange(len(table))
            else:
                codes, _ = pd.factorize(table[col].astype(str), sort=False)
            self._unit_of_row[kind] = np.asarray(codes, dtype=np.int64)
            self._n[kind] = int(codes.max()) + 1 if len(codes) else 0

    @classmethod
    def from_jumps(cls, table: pd.DataFrame) -> Measurements:
        """Jump heights only (``table`` as :func:`load_jumps` returns it)."""
        return cls({"heights": table}, {"heights": None})

    @property
    def kinds(self) -> tuple[str, ...]:
        """The kinds present, in unit order."""
        return tuple(self.tables)

    def unit_of_row(self, kind: str) -> np.ndarray:
        """The unit (within its kind) of every row of a kind's table.

        Parameters
        ----------
        kind : str
            A kind of measurement (``heights``, ``trajectories``, ``intrusions``).
        """
        return self._unit_of_row[kind]

    def n_units_of(self, kind: str) -> int:
        """Number of units of a kind (0 if absent).

        Parameters
        ----------
        kind : str
            A kind of measurement (``heights``, ``trajectories``, ``intrusions``).
        """
        return self._n.get(kind, 0)

    @property
    def n_units(self) -> int:
        """Number of units over every kind."""
        return sum(self._n.values())

    def offset(self, kind: str) -> int:
        """Global number of a kind's first unit.

        Parameters
        ----------
        kind : str
            A kind of measurement (``heights``, ``trajectories``, ``intrusions``).
        """
        out = 0
        for k in self.tables:
            if k == kind:
                return out
            out += self._n[k]
        raise KeyError(kind)

    @property
    def units(self) -> pd.DataFrame:
        """One row per unit, in global order.

        Columns ``kind``, ``unit`` (within its kind), ``phi``, ``label`` (its id, or its
        row for jump heights) and ``command`` (None for a kind without commands).
        """
        parts = []
        for kind, table in self.tables.items():
            first = pd.Series(np.arange(len(table))).groupby(self._unit_of_row[kind]).first()
            rows = table.iloc[first.to_numpy()]
            col = self.unit_columns[kind]
            parts.append(
                pd.DataFrame(
                    {
                        "kind": kind,
                        "unit": np.arange(len(rows)),
                        "phi": rows["phi"].to_numpy(float),
                        "label": rows[col].astype(str).to_numpy()
                        if col is not None
                        else rows.index.astype(str).to_numpy(),
                        "command": rows["command"].to_numpy()
                        if "command" in rows
                        else np.full(len(rows), None),
                    }
                )
            )
        return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()

    @property
    def phis(self) -> np.ndarray:
        """Sorted distinct volume fractions over every kind."""
        return np.unique(np.concatenate([t["phi"].to_numpy(float) for t in self.tables.values()]))

    def select(self, units: np.ndarray) -> Measurements:
        """The measurements of some units (global numbers; kept in their order of appearance).

        Parameters
        ----------
        units : ndarray of int or bool
            Global unit numbers, or a mask over every unit.

        Returns
        -------
        Measurements
        """
        units = np.asarray(units)
        keep = units if units.dtype == bool else np.isin(np.arange(self.n_units), units)
        tables, origin = {}, {}
        for kind, table in self.tables.items():
            start = self.offset(kind)
            rows = keep[start : start + self._n[kind]][self._unit_of_row[kind]]
            tables[kind] = table[rows]
            origin[kind] = self.origin[kind][rows]
        return Measurements(tables, self.unit_columns, origin)

    def at_phi(self, phi: float) -> Measurements:
        """The measurements at one volume fraction.

        Parameters
        ----------
        phi : float
            A measured volume fraction [-].
        """
        return self.select(self.units["phi"].to_numpy(float) == phi)

    def units_at_phi(self, phi: float) -> np.ndarray:
        """Global numbers of the units at one volume fraction.

        Parameters
        ----------
        phi : float
            A measured volume fraction [-].
        """
        return np.flatnonzero(self.units["phi"].to_numpy(float) == phi)

    def hash_text(self) -> str:
        """The tables as text, for a hash of the data (heights alone: the jumps table's CSV)."""
        if self.kinds == ("heights",):
            return self.tables["heights"].to_csv(index=False)
        return "".join(f"[{k}]\n{t.to_csv(index=False)}" for k, t in self.tables.items())

    def __repr__(self) -> str:
        inside = ", ".join(f"{k}: {self._n[k]} units" for k in self.tables)
        return f"Measurements({inside})"
