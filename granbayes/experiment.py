"""The experiment: the robot, the command settings and the bed, as loaded from a folder.

An experiment folder (``shared/data-format.md``) holds ``experiment.toml`` (robot, command
settings, bed) and ``jumps.csv`` (one measured jump per row). Every TOML key is optional and
defaults to the representative values of the physics model (``docs/physics-model.md``).

This module is the first step of the data flow: it only reads and validates. It knows
nothing about simulation or inference.
"""

from __future__ import annotations

import csv
import dataclasses
import difflib
import io
import math
import re
import tomllib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import InputError
from .forces import PARAMETER_NAMES, registered_parameters

__all__ = [
    "BATCH_EXPERIMENT_COLUMNS",
    "BATCH_FORCE_COLUMNS",
    "BATCH_REQUIRED_FORCE_COLUMNS",
    "COMMAND_NAMES",
    "CommandSettings",
    "Experiment",
    "G",
    "Robot",
    "load_batch_table",
    "load_experiment",
    "load_jumps",
]

#: Gravitational acceleration [m/s^2].
G = 9.81

#: The five jump commands, in the order used everywhere (tables, figures, arrays).
COMMAND_NAMES: tuple[str, ...] = (
    "single",
    "preload",
    "stutter",
    "delayed_stutter",
    "delayed_stutter_preload",
)


@dataclass(frozen=True)
class Robot:
    """The jumping robot (all SI).

    Parameters
    ----------
    m_motor : float
        Actuator (forcer) mass [kg]; moves along the thrust rod.
    m_rod : float
        Thrust rod and everything rigid above the spring [kg].
    m_foot : float
        Foot plate below the spring [kg].
    k_spring : float
        Leg spring stiffness [N/m].
    c_spring : float
        Leg spring damping [N s/m].
    foot_radius : float
        Radius of the circular foot [m].
    grain_density : float
        Density of one grain [kg/m^3].
    """

    m_motor: float = 1.0
    m_rod: float = 0.2
    m_foot: float = 0.1
    k_spring: float = 5760.0
    c_spring: float = 5.0
    foot_radius: float = 0.035
    grain_density: float = 1100.0

    @property
    def m_upper(self) -> float:
        """Rod plus motor mass ``M`` [kg]."""
        return self.m_motor + self.m_rod

    @property
    def f0_hz(self) -> float:
        """Resonant frequency ``sqrt(k_spring / M) / (2 pi)`` of the leg [Hz]."""
        return math.sqrt(self.k_spring / self.m_upper) / (2.0 * math.pi)


@dataclass(frozen=True)
class CommandSettings:
    """Actuator settings shared by the jump commands (units as in ``experiment.toml``).

    Parameters
    ----------
    amplitude_mm : float
        Actuator amplitude ``A`` [mm] (half the stroke).
    freq_hz : float
        Actuator frequency [Hz].
    delay_ms : float
        Hold of the ``delayed_stutter`` command [ms].
    settle_periods : float
        Hold of the ``delayed_stutter_preload`` command [periods].
    """

    amplitude_mm: float = 20.0
    freq_hz: float = 10.0
    delay_ms: float = 50.0
    settle_periods: float = 3.0

    @property
    def amplitude(self) -> float:
        """Amplitude [m]."""
        return self.amplitude_mm * 1e-3

    @property
    def period(self) -> float:
        """Period ``1 / freq`` [s]."""
        return 1.0 / self.freq_hz

    @property
    def delay(self) -> float:
        """Delay [s]."""
        return self.delay_ms * 1e-3


@dataclass(frozen=True)
class Experiment:
    """A robot, its command settings and the bed's critical packing.

    Parameters
    ----------
    robot : Robot
        The robot.
    command : CommandSettings
        Default command settings (``jumps.csv`` rows may override them).
    phi_c : float
        Critical packing fraction of the bed [-].
    source : str, optional
        Where the experiment was loaded from (for messages and provenance).
    """

    robot: Robot = field(default_factory=Robot)
    command: CommandSettings = field(default_factory=CommandSettings)
    phi_c: float = 0.612
    source: str | None = None

    def replace(self, **changes: float) -> Experiment:
        """Return a copy with robot or command fields replaced by keyword.

        Parameters
        ----------
        **changes
            Field names of :class:`Robot` or :class:`CommandSettings`, or ``phi_c``.

        Returns
        -------
        Experiment
        """
        robot_keys = {f.name for f in dataclasses.fields(Robot)}
        command_keys = {f.name for f in dataclasses.fields(CommandSettings)}
        unknown = set(changes) - robot_keys - command_keys - {"phi_c"}
        if unknown:
            raise KeyError(f"unknown experiment key(s): {sorted(unknown)}")
        robot = dataclasses.replace(
            self.robot, **{k: v for k, v in changes.items() if k in robot_keys}
        )
        command = dataclasses.replace(
            self.command, **{k: v for k, v in changes.items() if k in command_keys}
        )
        phi_c = changes.get("phi_c", self.phi_c)
        return Experiment(robot=robot, command=command, phi_c=phi_c, source=self.source)


# --------------------------------------------------------------------------------------
# Allowed ranges of the numeric inputs
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Range:
    """An interval of allowed values; every value must also be finite.

    Parameters
    ----------
    lower, upper : float
        Interval ends (``-inf``/``inf`` for unbounded).
    lower_closed : bool
        Whether ``lower`` itself is allowed (the upper end is always open).
    """

    lower: float = -math.inf
    upper: float = math.inf
    lower_closed: bool = False

    def __contains__(self, value: float) -> bool:
        above = value >= self.lower if self.lower_closed else value > self.lower
        return above and value < self.upper

    def __str__(self) -> str:
        if math.isinf(self.upper):
            return f">= {self.lower:g}" if self.lower_closed else f"> {self.lower:g}"
        kind, bracket = ("half-open", "[") if self.lower_closed else ("open", "(")
        return f"in the {kind} interval {bracket}{self.lower:g}, {self.upper:g})"


_FINITE = _Range()
_POSITIVE = _Range(0.0)
_NON_NEGATIVE = _Range(0.0, lower_closed=True)
_FRACTION = _Range(0.0, 1.0)

#: ``[robot]`` keys and their ranges (same names and order as :class:`Robot`).
_ROBOT_RANGES: dict[str, _Range] = {
    "m_motor": _POSITIVE,
    "m_rod": _POSITIVE,
    "m_foot": _POSITIVE,
    "k_spring": _POSITIVE,
    "c_spring": _NON_NEGATIVE,
    "foot_radius": _POSITIVE,
    "grain_density": _POSITIVE,
}

#: ``[command]`` keys and their ranges (same names and order as :class:`CommandSettings`).
_COMMAND_RANGES: dict[str, _Range] = {
    "amplitude_mm": _POSITIVE,
    "freq_hz": _POSITIVE,
    "delay_ms": _NON_NEGATIVE,
    "settle_periods": _NON_NEGATIVE,
}

#: The sections of ``experiment.toml`` and the keys each one allows.
_TOML_SECTIONS: dict[str, dict[str, _Range]] = {
    "robot": _ROBOT_RANGES,
    "command": _COMMAND_RANGES,
    "bed": {"phi_c": _FRACTION},
}

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
_JUMP_SETTING_COLUMNS: tuple[str, ...] = ("freq_hz", "amplitude_mm", "delay_ms", "settle_periods")

_JUMP_REQUIRED: tuple[str, ...] = ("phi", "command", "height_mm")
_BATCH_REQUIRED: tuple[str, ...] = ("command", "phi")

#: Force parameters a batch table must have a column of: those without an "off" value
#: (``granbayes.forces``: the depth term's stiffness ``k`` [N/m], part of every law). An
#: empty cell is simulated and fails alone, with its status, like ``k = 0``.
BATCH_REQUIRED_FORCE_COLUMNS: tuple[str, ...] = ("k",)


# --------------------------------------------------------------------------------------
# Value checks shared by the TOML and CSV loaders
# --------------------------------------------------------------------------------------


def _suggest(word: str, options: Iterable[str]) -> str:
    """Return ``" (did you mean 'x'?)"`` for a close match of ``word``, else ``""``."""
    close = difflib.get_close_matches(word, list(options), n=1)
    return f" (did you mean '{close[0]}'?)" if close else ""


def _range_problem(value: float, allowed: _Range, shown: str) -> str | None:
    """Describe why ``value`` is not allowed, or return None if it is.

    Parameters
    ----------
    value : float
        The value (already converted to float).
    allowed : _Range
        Its allowed interval.
    shown : str
        How to show the value in the message (the user's spelling).
    """
    if not math.isfinite(value):
        return f"expected a finite number, got {shown}"
    if value not in allowed:
        return f"got {shown}, must be {allowed}"
    return None


def _parse_float(text: str) -> float | None:
    """Parse a stripped CSV cell as a float; None if it is not a number."""
    if "_" in text:  # Python's float() accepts "1_000"; a CSV file should not.
        return None
    try:
        return float(text)
    except ValueError:
        return None


def _cell_float(text: str, allowed: _Range, *, required: bool) -> tuple[float, str | None]:
    """Convert one CSV cell to a float and check its range.

    Parameters
    ----------
    text : str
        The stripped cell.
    allowed : _Range
        Allowed interval.
    required : bool
        Whether an empty cell is a problem (otherwise it becomes NaN, "not given").

    Returns
    -------
    value : float
        The number (NaN when the cell is empty or bad).
    problem : str or None
        What is wrong with the cell, or None.
    """
    if not text:
        return math.nan, ("empty cell, expected a number" if required else None)
    value = _parse_float(text)
    if value is None:
        return math.nan, f"expected a number, got '{text}'"
    return value, _range_problem(value, allowed, f"'{text}'")


# --------------------------------------------------------------------------------------
# Reading files
# --------------------------------------------------------------------------------------


def _read_text(path: Path) -> str:
    """Read a UTF-8 text file (an optional byte-order mark is dropped).

    Raises
    ------
    InputError
        If the file cannot be read or is not UTF-8.
    """
    try:
        return path.read_text(encoding="utf-8-sig")
    except FileNotFoundError as err:
        raise InputError("file not found", file=path) from err
    except IsADirectoryError as err:
        raise InputError("expected a file, got a folder", file=path) from err
    except UnicodeDecodeError as err:
        raise InputError(f"not UTF-8 text ({err.reason} at byte {err.start})", file=path) from err
    except OSError as err:
        raise InputError(f"cannot read file: {err.strerror or err}", file=path) from err


def _file_in(path: str | Path, name: str | None) -> Path:
    """Resolve an experiment folder or a file to the file to read.

    Parameters
    ----------
    path : str or Path
        A folder or a file.
    name : str or None
        File to read inside a folder; None if a folder is not accepted.

    Raises
    ------
    InputError
        If the path (or the file inside the folder) does not exist.
    """
    path = Path(path)
    if not path.exists():
        raise InputError("no such file or folder", file=path)
    if path.is_dir():
        if name is None:
            raise InputError("expected a CSV file, got a folder", file=path)
        inner = path / name
        if not inner.is_file():
            raise InputError(f"the experiment folder has no {name}", file=inner)
        return inner
    return path


# --------------------------------------------------------------------------------------
# experiment.toml
# --------------------------------------------------------------------------------------

#: One part of a TOML key: bare, "basic" or 'literal'.
_TOML_KEY_PART = r"""(?:[A-Za-z0-9_-]+|"[^"]*"|'[^']*')"""
_TOML_TABLE_HEADER = re.compile(rf"\[\[?\s*({_TOML_KEY_PART}(?:\s*\.\s*{_TOML_KEY_PART})*)\s*\]")
_TOML_KEY = re.compile(rf"({_TOML_KEY_PART}(?:\s*\.\s*{_TOML_KEY_PART})*)\s*=")


def _toml_key_path(dotted: str) -> list[str]:
    """Split a dotted TOML key (parts possibly quoted) into its parts."""
    return [part.strip("\"'") for part in re.findall(_TOML_KEY_PART, dotted)]


def _toml_line(text: str, section: str, key: str | None) -> int | None:
    """Find the line that defines ``section.key`` (or the section itself), best effort.

    ``tomllib`` does not report where a key was defined; this scan recognises table
    headers (``[robot]``, ``[[robot]]``) and plain and dotted keys (``robot.m_motor = 1``),
    and falls back to the line of the section when the key is in an inline table.

    Parameters
    ----------
    text : str
        The TOML document (already known to be valid).
    section : str
        Top-level table name.
    key : str or None
        Key inside the section, or None for the section itself.

    Returns
    -------
    int or None
        1-based line number, or None if not found.
    """
    current: list[str] = []
    section_line = None
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        header = _TOML_TABLE_HEADER.match(line)
        if header:
            current = _toml_key_path(header.group(1))
            if current[:1] == [section] and section_line is None:
                section_line = number
            if key is None and current == [section]:
                return number
            continue
        match = _TOML_KEY.match(line)
        if not match:
            continue
        full = current + _toml_key_path(match.group(1))
        if full[:1] == [section] and section_line is None:
            section_line = number
        if key is not None and full[:2] == [section, key]:
            return number
    return section_line


def _toml_type_name(value: object) -> str:
    """Name a TOML value's type for messages."""
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list):
        return "an array"
    if isinstance(value, dict):
        return "a table"
    return "a date/time"


def _toml_entry(section: str, key: str | None, raw: object) -> tuple[float, str | None]:
    """Check one top-level entry (``key`` None) or one key of a section.

    Returns
    -------
    value : float
        The key's value as a float (NaN for a top-level entry or a bad value).
    problem : str or None
        What is wrong, or None.
    """
    if key is None:
        if section not in _TOML_SECTIONS:
            sections = ", ".join(f"[{name}]" for name in _TOML_SECTIONS)
            hint = _suggest(section, _TOML_SECTIONS)
            return math.nan, (
                f"unknown section or top-level key '{section}'{hint}; allowed sections: {sections}"
            )
        if not isinstance(raw, dict):
            return math.nan, f"expected a table [{section}], got {_toml_type_name(raw)}"
        return math.nan, None
    allowed = _TOML_SECTIONS[section]
    if key not in allowed:
        hint = _suggest(key, allowed)
        return math.nan, (
            f"unknown key '{key}' in [{section}]{hint}; allowed keys: {', '.join(allowed)}"
        )
    if isinstance(raw, bool) or not isinstance(raw, int | float):
        shown = str(raw).lower() if isinstance(raw, bool) else repr(raw)
        return math.nan, f"expected a number, got {_toml_type_name(raw)} ({shown})"
    try:
        value = float(raw)
    except OverflowError:  # an integer beyond the float range
        value = math.inf
    return value, _range_problem(value, allowed[key], repr(raw))


def _toml_values(data: Mapping[str, object], text: str, file: Path) -> dict[str, float]:
    """Validate a parsed ``experiment.toml`` and flatten it to ``Experiment.replace`` keys.

    Parameters
    ----------
    data : Mapping
        Result of :func:`tomllib.loads`.
    text : str
        The document, to locate offending lines.
    file : Path
        The file, for messages.

    Returns
    -------
    dict of str to float
        Key (without section) to value, in the document's units.

    Raises
    ------
    InputError
        At the first unknown section or key, wrong type or out-of-range value; ``column``
        is ``section.key`` (or the section) and ``row`` its line if it can be found.
    """
    values: dict[str, float] = {}
    for section, table in data.items():
        entries: list[tuple[str | None, object]] = [(None, table)]
        if isinstance(table, dict):
            entries += list(table.items())
        for key, raw in entries:
            value, problem = _toml_entry(section, key, raw)
            if problem is not None:
                raise InputError(
                    problem,
                    file=file,
                    row=_toml_line(text, section, key),
                    column=section if key is None else f"{section}.{key}",
                )
            if key is not None:
                values[key] = value
    return values


def load_experiment(path: str | Path) -> Experiment:
    """Load and validate an experiment's robot, command settings and bed.

    Parameters
    ----------
    path : str or Path
        An experiment folder (``experiment.toml`` inside it is read; a folder without one
        gives all defaults) or a TOML file. Every key is optional; the allowed ones are
        ``[robot]`` ``m_motor``, ``m_rod``, ``m_foot`` [kg], ``k_spring`` [N/m],
        ``c_spring`` [N s/m], ``foot_radius`` [m], ``grain_density`` [kg/m^3];
        ``[command]`` ``amplitude_mm`` [mm], ``freq_hz`` [Hz], ``delay_ms`` [ms],
        ``settle_periods`` [periods]; ``[bed]`` ``phi_c`` [-].

    Returns
    -------
    Experiment
        With ``source`` set to ``str(path)``.

    Raises
    ------
    InputError
        If the path does not exist, the TOML is malformed (``row`` is the line), or a
        section or key is unknown, not a number (booleans are refused), not finite, or out
        of range: masses, ``k_spring``, ``foot_radius``, ``grain_density``,
        ``amplitude_mm`` and ``freq_hz`` must be > 0; ``c_spring``, ``delay_ms`` and
        ``settle_periods`` >= 0; ``phi_c`` in (0, 1). ``column`` is ``section.key``.
    """
    folder_or_file = Path(path)
    if not folder_or_file.exists():
        raise InputError("no such file or folder", file=folder_or_file)
    if folder_or_file.is_dir():
        file = folder_or_file / "experiment.toml"
        if not file.exists():
            return Experiment(source=str(path))
    else:
        file = folder_or_file
    text = _read_text(file)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        line = getattr(err, "lineno", None)
        if line is None:
            found = re.search(r"line (\d+)", str(err))
            line = int(found.group(1)) if found else None
        raise InputError(f"malformed TOML: {err}", file=file, row=line) from err
    values = _toml_values(data, text, file)
    return Experiment(source=str(path)).replace(**values)


# --------------------------------------------------------------------------------------
# CSV tables
# --------------------------------------------------------------------------------------


@dataclass
class _CsvTable:
    """A CSV file read as stripped strings, with the problems found so far.

    Cell checks do not raise at once: they record problems, and
    :meth:`raise_first_problem` reports the first one in file order (row, then column).

    Parameters
    ----------
    file : Path
        The file, for messages.
    header : list of str
        Header names in file order, including empty ones of unnamed columns.
    rows : list of int
        1-based data row number of each record (line of the file minus the header's line).
    cells : dict of str to list of str
        Stripped cells of each named column, in file order.
    """

    file: Path
    header: list[str]
    rows: list[int]
    cells: dict[str, list[str]]
    problems: list[tuple[int, int, InputError]] = field(default_factory=list)

    @property
    def columns(self) -> list[str]:
        """Names of the (named) columns in file order."""
        return list(self.cells)

    def report(self, row: int, column: str | None, message: str, *, position: int = -1) -> None:
        """Record a problem in ``row``.

        Parameters
        ----------
        row : int
            1-based data row.
        column : str or None
            Column name; None for a problem of the whole row or of an unnamed column.
        message : str
            What is wrong.
        position : int
            Field index ordering a problem without a column name within its row (-1: before
            every cell).
        """
        if column is not None:
            position = self.header.index(column)
        self.problems.append(
            (row, position, InputError(message, file=self.file, row=row, column=column))
        )

    def raise_first_problem(self) -> None:
        """Raise the first recorded problem in file order, if any.

        Raises
        ------
        InputError
        """
        if self.problems:
            raise min(self.problems, key=lambda problem: problem[:2])[2]

    def require(self, names: Sequence[str]) -> None:
        """Check that the required columns are present.

        Raises
        ------
        InputError
            Naming the first missing column (``row`` is None).
        """
        for name in names:
            if name not in self.columns:
                hint = _suggest(name, self.columns)
                raise InputError(
                    f"missing required column{hint}; the file has: {', '.join(self.columns)}",
                    file=self.file,
                    column=name,
                )

    def floats(self, column: str, allowed: _Range, *, required: bool) -> np.ndarray:
        """Convert a column to floats, recording each bad cell.

        Parameters
        ----------
        column : str
            Column name (must exist).
        allowed : _Range
            Allowed interval of every value (values must also be finite).
        required : bool
            Whether empty cells are problems; otherwise they become NaN ("not given").

        Returns
        -------
        numpy.ndarray
            float64 values, NaN where a cell is empty or bad.
        """
        values = np.empty(len(self.rows))
        for index, (row, text) in enumerate(zip(self.rows, self.cells[column], strict=True)):
            values[index], problem = _cell_float(text, allowed, required=required)
            if problem is not None:
                self.report(row, column, problem)
        return values

    def choices(self, column: str, allowed: Sequence[str]) -> list[str]:
        """Check that every cell of a column is one of ``allowed`` (case-sensitive)."""
        cells = self.cells[column]
        for row, text in zip(self.rows, cells, strict=True):
            if text not in allowed:
                got = (
                    f"unknown {column} '{text}'{_suggest(text, allowed)}" if text else "empty cell"
                )
                self.report(row, column, f"{got}; valid values: {', '.join(allowed)}")
        return list(cells)

    def integers(self, column: str) -> pd.Series:
        """Convert a column to nullable integers (empty cells become ``<NA>``)."""
        values: list[int | None] = []
        for row, text in zip(self.rows, self.cells[column], strict=True):
            number = _parse_float(text) if text else None
            if text and (number is None or not math.isfinite(number) or number != int(number)):
                self.report(row, column, f"expected an integer, got '{text}'")
                number = None
            values.append(None if number is None else int(number))
        return pd.Series(values, dtype="Int64")

    def frame(self, converted: Mapping[str, object]) -> pd.DataFrame:
        """Assemble the result: file columns in order (converted where given), then the rest.

        Parameters
        ----------
        converted : Mapping
            Column name to converted values; columns not in the file are appended.
        """
        data = {name: converted.get(name, self.cells[name]) for name in self.columns}
        data.update({name: values for name, values in converted.items() if name not in data})
        return pd.DataFrame(data, index=pd.RangeIndex(len(self.rows)))


def _read_csv(file: Path) -> _CsvTable:
    """Read a CSV file as stripped strings and check its shape.

    Blank lines (and lines of empty fields only) are skipped; data rows are numbered by
    their line in the file relative to the header line, so row 1 directly follows the
    header. A column whose header name is empty is dropped if all its cells are empty.

    Parameters
    ----------
    file : Path
        The CSV file (UTF-8, comma separated, optional byte-order mark).

    Returns
    -------
    _CsvTable
        Rows with the wrong number of fields are recorded as problems (and padded or cut).

    Raises
    ------
    InputError
        If the file cannot be read or parsed, is empty, has only a header, or repeats a
        column name.
    """
    text = _read_text(file)
    reader = csv.reader(io.StringIO(text, newline=""), strict=True)
    header: list[str] | None = None
    header_line = 0
    records: list[tuple[int, list[str]]] = []
    line_end = 0  # last line of the previous record
    try:
        for fields in reader:
            start, line_end = line_end + 1, reader.line_num
            stripped = [cell.strip() for cell in fields]
            if not any(stripped):
                continue
            if header is None:
                header, header_line = stripped, start
            else:
                records.append((start - header_line, stripped))
    except csv.Error as err:
        row = line_end + 1 - header_line if header is not None else None
        raise InputError(f"malformed CSV: {err}", file=file, row=row) from err
    if header is None:
        raise InputError("empty file, expected a header line and data rows", file=file)
    if not records:
        raise InputError("no data rows (only a header line)", file=file)
    named = [name for name in header if name]
    for index, name in enumerate(named):
        if name in named[:index]:
            raise InputError("duplicate column name", file=file, column=name)

    table = _CsvTable(
        file=file,
        header=header,
        rows=[row for row, _ in records],
        cells={name: [] for name in named},
    )
    for row, fields in records:
        if len(fields) != len(header):
            table.report(row, None, f"{len(fields)} fields, but the header has {len(header)}")
            fields = (fields + [""] * len(header))[: len(header)]
        for index, (name, cell) in enumerate(zip(header, fields, strict=True)):
            if name:
                table.cells[name].append(cell)
            elif cell:
                message = f"value '{cell}' in column {index + 1}, which has no header name"
                table.report(row, None, message, position=index)
    return table


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
    table = _read_csv(_file_in(path, "jumps.csv"))
    table.require(_JUMP_REQUIRED)
    converted: dict[str, object] = {
        "phi": table.floats("phi", _FRACTION, required=True),
        "command": table.choices("command", COMMAND_NAMES),
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
    table = _read_csv(_file_in(path, None))
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
        "command": table.choices("command", COMMAND_NAMES),
        "phi": table.floats("phi", _FRACTION, required=True),
    }
    for name, allowed in (_force_ranges() | _ROBOT_RANGES | _COMMAND_RANGES).items():
        if name in table.columns:
            converted[name] = table.floats(name, allowed, required=False)
    table.raise_first_problem()
    return table.frame(converted)
