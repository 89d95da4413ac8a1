"""CSV files of an experiment folder: reading and vectorised validation (private).

Every CSV file of an experiment folder (``jumps.csv``, ``trajectories.csv``,
``intrusions.csv``) and the batch table of ``granbayes simulate --batch`` is read here as
stripped strings and checked column by column: :class:`_CsvTable` records every problem,
and :meth:`_CsvTable.raise_first_problem` raises the first one in file order (row, then
column), naming the file, the row and the column. The checks work on whole columns (only
the cells a vectorised mask flags go through the per-cell messages), so a file of 100,000
rows costs microseconds per row.

It is long (about 1,000 lines) for one job: the reader keeps the exact row numbering of the
file (blank lines, quoted fields, wrong field counts) and parses numbers as ``float``
does, with a fast path that is only taken where it gives the same values bit for bit;
splitting it would put the two halves of each guard in different places.
"""

from __future__ import annotations

import codecs
import csv
import difflib
import functools
import io
import itertools
import math
import operator
import re
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from operator import methodcaller
from pathlib import Path
from typing import NoReturn

import numpy as np
import pandas as pd

from ._errors import InputError


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


def _cell_choice(text: str, column: str, allowed: Sequence[str]) -> str | None:
    """Describe why a CSV cell is not one of ``allowed`` (case-sensitive), or return None.

    Parameters
    ----------
    text : str
        The stripped cell.
    column : str
        Its column, for the message.
    allowed : sequence of str
        The valid values.
    """
    if text in allowed:
        return None
    got = f"unknown {column} '{text}'{_suggest(text, allowed)}" if text else "empty cell"
    return f"{got}; valid values: {', '.join(allowed)}"


#: Integers a CSV cell may hold: those of a 64-bit integer column (``Int64``).
_INTEGER_LIMIT = 2.0**63


def _cell_integer(text: str) -> tuple[int | None, str | None]:
    """Convert one CSV cell to an integer (an empty cell is "not given").

    Parameters
    ----------
    text : str
        The stripped cell.

    Returns
    -------
    value : int or None
        The integer (None when the cell is empty or bad).
    problem : str or None
        What is wrong with the cell, or None.
    """
    if not text:
        return None, None
    number = _parse_float(text)
    if number is None or not math.isfinite(number) or number != int(number):
        return None, f"expected an integer, got '{text}'"
    if not -_INTEGER_LIMIT <= number < _INTEGER_LIMIT:
        return None, f"expected an integer of at most 64 bits, got '{text}'"
    return int(number), None


def _float_cells(texts: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """``float(text)`` of every cell, and where ``float`` refuses the text.

    One pass of ``float`` over the cells; a refused cell is located from how far the pass
    got, marked, and the pass resumes after it (each refused cell costs one Python step).

    Parameters
    ----------
    texts : list of str
        The cells.

    Returns
    -------
    values : numpy.ndarray
        float64 values, NaN where refused.
    refused : numpy.ndarray
        bool, True where ``float(text)`` raises ``ValueError`` (an empty cell included).
    """
    n = len(texts)
    values = np.full(n, np.nan)
    refused = np.zeros(n, dtype=bool)
    cells = iter(texts)
    start = 0
    while start < n:
        try:
            values[start:] = np.fromiter(map(float, cells), np.float64, count=n - start)
        except ValueError:
            bad = n - operator.length_hint(cells) - 1  # the cell float() refused
            refused[bad] = True
            good = texts[start:bad]
            values[start:bad] = np.fromiter(map(float, good), np.float64, count=len(good))
            start = bad + 1
        else:
            break
    return values, refused


#: Whether pandas' C reader parses a plain decimal number exactly as ``float`` does: pandas
#: >= 3.1 parses with fast_float, which rounds correctly (as ``float`` does).
_PANDAS_VERSION = tuple(int(part) for part in re.findall(r"\d+", pd.__version__)[:2])

_PANDAS_PARSES_EXACTLY = _PANDAS_VERSION >= (3, 1)

#: Columns (and tables) of fewer cells are parsed by ``float`` alone: pandas' reader has a
#: fixed cost of about a millisecond.
_PANDAS_MIN_CELLS = 1000

#: The bytes of plain decimal numbers (``-1.5e+3``), one per line.
_DECIMAL_BYTES = b"0123456789+-.eE\n"


def _decimal_floats(texts: list[str]) -> np.ndarray | None:
    """``float(text)`` of every cell, if all are plain decimal numbers, in bulk; else None.

    Cells made of digits, signs, ``.``, ``e`` and ``E`` only are parsed by pandas' C reader
    where it rounds exactly as ``float`` does (:data:`_PANDAS_PARSES_EXACTLY`); a cell it
    refuses (``1e``, ``-``), or any other character, returns None (parse with ``float``).
    For such cells both parsers accept the same texts (the decimal grammar) and round
    correctly, so they give the same numbers (``tests/test_experiment.py`` checks it).

    Parameters
    ----------
    texts : list of str
        Non-empty cells.

    Returns
    -------
    numpy.ndarray or None
        float64 values.
    """
    if not _PANDAS_PARSES_EXACTLY or len(texts) < _PANDAS_MIN_CELLS:
        return None
    joined = "\n".join(texts)
    if not joined.isascii():
        return None
    data = joined.encode("ascii")
    if data.translate(None, _DECIMAL_BYTES):
        return None
    try:
        values = pd.read_csv(
            io.BytesIO(data),
            header=None,
            names=["value"],
            dtype=np.float64,
            na_filter=False,
            skip_blank_lines=False,
            engine="c",
        )["value"].to_numpy()
    except ValueError:  # a cell that is not a number (pandas' errors are ValueErrors)
        return None
    return values if len(values) == len(texts) else None


def _number_cells(texts: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Parse a column's cells as :func:`_parse_float` does, in bulk.

    Parameters
    ----------
    texts : list of str
        The stripped cells.

    Returns
    -------
    values : numpy.ndarray
        float64 values, NaN where a cell is empty or not a number.
    empty : numpy.ndarray
        bool, True where a cell is empty.
    refused : numpy.ndarray
        bool, True where a non-empty cell is not a number: ``float`` refuses it, or it
        contains ``_`` (which ``float`` accepts and :func:`_parse_float` does not).
    """
    n = len(texts)
    empty = np.zeros(n, dtype=bool)
    given = texts
    if "" in texts:
        empty = np.fromiter(map(operator.not_, texts), dtype=bool, count=n)
        given = list(map(texts.__getitem__, np.flatnonzero(~empty).tolist()))
    values = _decimal_floats(given)
    if values is not None:
        refused = np.zeros(len(given), dtype=bool)
    else:
        values, refused = _float_cells(given)
        if "_" in "".join(given):
            refused |= np.fromiter(
                map(operator.contains, given, itertools.repeat("_")),
                dtype=bool,
                count=len(given),
            )
            values[refused] = np.nan
    if given is texts:
        return values, empty, refused
    all_values = np.full(n, np.nan)
    all_refused = np.zeros(n, dtype=bool)
    all_values[~empty] = values
    all_refused[~empty] = refused
    return all_values, empty, all_refused


def _outside(values: np.ndarray, allowed: _Range) -> np.ndarray:
    """Mask of the values :func:`_range_problem` refuses: not finite, or outside ``allowed``."""
    above = values >= allowed.lower if allowed.lower_closed else values > allowed.lower
    return ~(above & (values < allowed.upper) & np.isfinite(values))


def _read_text(path: Path) -> str:
    """Read a UTF-8 text file (an optional byte-order mark is dropped).

    Every line break (CR LF, a lone CR) becomes a line feed, as in a file opened in text
    mode.

    Raises
    ------
    InputError
        If the file cannot be read or is not UTF-8.
    """
    return _read_file(path)[0]


def _read_file(path: Path) -> tuple[str, bytes]:
    """Read a UTF-8 text file: its text, as :func:`_read_text` gives it, and its bytes.

    The bytes are read and decoded at once (faster than a file opened in text mode).

    Returns
    -------
    text : str
        The text.
    data : bytes
        The file's bytes as they are (byte-order mark and line breaks included).

    Raises
    ------
    InputError
        If the file cannot be read or is not UTF-8.
    """
    try:
        data = path.read_bytes()
        text = data.decode("utf-8-sig")
    except FileNotFoundError as err:
        raise InputError("file not found", file=path) from err
    except IsADirectoryError as err:
        raise InputError("expected a file, got a folder", file=path) from err
    except UnicodeDecodeError as err:
        raise InputError(f"not UTF-8 text ({err.reason} at byte {err.start})", file=path) from err
    except OSError as err:
        raise InputError(f"cannot read file: {err.strerror or err}", file=path) from err
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    return text, data


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


@dataclass
class _CsvTable:
    """A CSV file read as stripped strings, with the problems found so far.

    Cell checks do not raise at once: they record problems, and
    :meth:`raise_first_problem` reports the first one in file order (row, then column).
    Each check finds the cells that may break its rule in bulk and records the first bad
    one of its column: within a column the first bad cell is the only one that can come
    first in file order, so only it gets a message.

    Parameters
    ----------
    file : Path
        The file, for messages.
    header : list of str
        Header names in file order, including empty ones of unnamed columns.
    rows : numpy.ndarray
        1-based data row number of each record (line of the file minus the header's
        line), int64, increasing.
    cells : dict of str to list of str
        Stripped cells of the named columns read as text, in file order: every one,
        except those in ``numbers`` (:meth:`texts` gives any column).
    problems : list of (int, int, InputError)
        Recorded problems: row, field position (-1: the whole row) and the error.
    lines : list of str, optional
        The line of each data record as it is in the file, where every line equals its
        named cells joined by commas (an ASCII file without quotes, whitespace, unnamed
        columns or rows of the wrong length); None otherwise. Lets
        :meth:`to_text` copy the rows instead of joining their cells again.
    numbers : dict of str to numpy.ndarray
        Columns parsed as numbers while reading (:func:`_read_numbers`): float64, each
        value ``float(cell)``, NaN exactly where the cell is empty.
    """

    file: Path
    header: list[str]
    rows: np.ndarray
    cells: dict[str, list[str]]
    problems: list[tuple[int, int, InputError]] = field(default_factory=list)
    lines: list[str] | None = None
    numbers: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def columns(self) -> list[str]:
        """Names of the (named) columns in file order."""
        return [name for name in self.header if name]

    def texts(self, column: str) -> list[str]:
        """The stripped cells of a named column, in file order.

        Parameters
        ----------
        column : str
            Column name (must exist).

        Returns
        -------
        list of str
            One cell per data record (a column parsed as numbers is split from ``lines``).
        """
        if column not in self.cells:  # parsed as numbers: split the lines again
            split = map(methodcaller("split", ","), self.lines)
            self.cells[column] = list(map(operator.itemgetter(self.header.index(column)), split))
        return self.cells[column]

    def cell(self, index: int, column: str) -> str:
        """One stripped cell (for the message about it).

        Parameters
        ----------
        index : int
            0-based data record.
        column : str
            Column name (must exist).

        Returns
        -------
        str
        """
        if column in self.cells:
            return self.cells[column][index]
        return self.lines[index].split(",")[self.header.index(column)]

    def number_cells(self, column: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A column's cells as numbers, in bulk.

        Parameters
        ----------
        column : str
            Column name (must exist).

        Returns
        -------
        values, empty, refused : numpy.ndarray
            As :func:`_number_cells` (from ``numbers`` if the column was parsed on reading).
        """
        if column in self.numbers:
            values = self.numbers[column]
            return values, np.isnan(values), np.zeros(len(values), dtype=bool)
        return _number_cells(self.texts(column))

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

    def report_first(
        self,
        column: str | None,
        suspects: np.ndarray,
        problem_of: Callable[[int], str | None],
        *,
        position: int = -1,
    ) -> None:
        """Record the first problem among the suspect cells of a column.

        Parameters
        ----------
        column : str or None
            Column name (None: an unnamed column, ordered by ``position``).
        suspects : numpy.ndarray
            bool, one per data row: the cells that may be bad (a bulk mask; it may flag
            cells the rule accepts, never miss one it refuses).
        problem_of : callable
            The per-cell rule: record index to the problem's message, or None.
        position : int
            Field index of an unnamed column.
        """
        for index in np.flatnonzero(suspects).tolist():
            message = problem_of(index)
            if message is not None:
                self.report(int(self.rows[index]), column, message, position=position)
                return

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
        """Convert a column to floats (:func:`_cell_float`), recording its first bad cell.

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
            float64 values, NaN where a cell is empty or not a number.
        """
        values, empty, refused = self.number_cells(column)
        suspects = refused | (~empty & _outside(values, allowed))
        if required:
            suspects |= empty
        self.report_first(
            column,
            suspects,
            lambda i: _cell_float(self.cell(i, column), allowed, required=required)[1],
        )
        return values

    def choices(self, column: str, allowed: Sequence[str]) -> list[str]:
        """Check that every cell of a column is one of ``allowed`` (:func:`_cell_choice`)."""
        cells = self.texts(column)
        valid = frozenset(allowed)
        if not valid.issuperset(cells):
            known = np.fromiter(map(valid.__contains__, cells), dtype=bool, count=len(cells))
            self.report_first(column, ~known, lambda i: _cell_choice(cells[i], column, allowed))
        return list(cells)

    def integers(self, column: str) -> pd.Series:
        """Convert a column to nullable integers (:func:`_cell_integer`; empty: ``<NA>``)."""
        values, empty, refused = self.number_cells(column)
        integral = (
            np.isfinite(values)
            & (values == np.trunc(values))
            & (values >= -_INTEGER_LIMIT)
            & (values < _INTEGER_LIMIT)
        )
        missing = empty | refused | ~integral
        self.report_first(
            column, missing & ~empty, lambda i: _cell_integer(self.cell(i, column))[1]
        )
        numbers = np.where(missing, 0.0, values).astype(np.int64)
        return pd.Series(pd.arrays.IntegerArray(numbers, missing))

    def frame(self, converted: Mapping[str, object]) -> pd.DataFrame:
        """Assemble the result: file columns in order (converted where given), then the rest.

        Parameters
        ----------
        converted : Mapping
            Column name to converted values; columns not in the file are appended.
        """
        data = {
            name: converted[name] if name in converted else self.texts(name)
            for name in self.columns
        }
        data.update({name: values for name, values in converted.items() if name not in data})
        return pd.DataFrame(data, index=pd.RangeIndex(len(self.rows)))

    def to_text(self, columns: Mapping[str, Sequence[str]], *, line_end: str = "\n") -> str:
        """The table as CSV text, with columns replaced or added.

        Parameters
        ----------
        columns : Mapping
            Column name to one text cell per data row: replaces the named column of the
            file in its place, or is appended (in the mapping's order).
        line_end : str
            Line terminator.

        Returns
        -------
        str
            The header and one line per data row: the named columns as read (stripped
            cells, a file's own spelling of every number), quoted where the csv module's
            minimal quoting would quote them.
        """
        named = self.columns
        names = [*named, *(name for name in columns if name not in named)]
        alone = len(names) == 1
        header = ",".join(_csv_quoted(names, alone=alone)) + line_end
        added = [_csv_quoted(list(cells), alone=alone) for cells in columns.values()]
        if self.lines is not None and not any(name in named for name in columns):
            return header + _csv_rows([self.lines, *added], line_end)
        texts = dict(zip(columns, added, strict=True))
        table = [
            texts[name] if name in texts else _csv_quoted(self.texts(name), alone=alone)
            for name in names
        ]
        return header + _csv_rows(table, line_end)


def _csv_rows(columns: Sequence[Sequence[str]], line_end: str) -> str:
    """Rows of CSV text from columns of cells, in one join over all the pieces.

    Parameters
    ----------
    columns : sequence of sequence of str
        The cells of each column, already quoted; equally long.
    line_end : str
        Line terminator (after every row).

    Returns
    -------
    str
    """
    n_rows = len(columns[0])
    pieces: list[Iterable[str]] = []
    for cells in columns:
        if pieces:
            pieces.append(itertools.repeat(",", n_rows))
        pieces.append(cells)
    pieces.append(itertools.repeat(line_end, n_rows))
    return "".join(itertools.chain.from_iterable(zip(*pieces, strict=True)))


#: Characters that make the csv module's minimal quoting quote a field.
_CSV_SPECIAL = re.compile(r'[,"\r\n]')


def _csv_quoted(cells: list[str], *, alone: bool = False) -> list[str]:
    """Cells as the csv module's minimal quoting writes them.

    Parameters
    ----------
    cells : list of str
        The cells of one column.
    alone : bool
        Whether the column is the only one (an empty cell is then quoted, as a line of
        one empty field is otherwise a blank line).

    Returns
    -------
    list of str
        ``cells`` itself when no cell needs quotes.
    """
    if not _CSV_SPECIAL.search("".join(cells)) and not (alone and "" in cells):
        return cells
    return [
        f'"{cell.replace(chr(34), chr(34) * 2)}"'
        if _CSV_SPECIAL.search(cell) or (alone and not cell)
        else cell
        for cell in cells
    ]


#: ASCII characters ``str.strip`` removes, other than the line feed: an ASCII file
#: without any of them has no cell to strip.
_ASCII_SPACE = " \t\x0b\x0c\r\x1c\x1d\x1e\x1f"


def _plain_lines(text: str) -> list[str] | None:
    """The lines of a CSV text without quoting, or None if the csv module must read it.

    Where a text has no double quote (nor NUL or carriage-return characters, nor a line
    longer than the csv module's field size limit: the caller checks that), ``csv.reader``
    reads each line as one record, the line split at its commas.

    Parameters
    ----------
    text : str
        The file's text.

    Returns
    -------
    list of str or None
        One per record (no record follows the final line break).
    """
    if '"' in text or "\x00" in text or "\r" in text:
        return None
    lines = text.split("\n")
    if not lines[-1]:
        lines.pop()
    return lines


def _quoted_records(text: str, file: Path) -> tuple[list[list[str]], np.ndarray]:
    """Read a CSV text with the csv module.

    Parameters
    ----------
    text : str
        The file's text (every line break already a line feed).
    file : Path
        The file, for messages.

    Returns
    -------
    records : list of list of str
        The fields of each record (blank lines included, as empty records).
    starts : numpy.ndarray
        int64, the line each record starts on (a record spans one line plus one per line
        break inside its quoted fields).

    Raises
    ------
    InputError
        If the csv module cannot parse the text (``row``: the record where it fails).
    """
    reader = csv.reader(io.StringIO(text, newline=""), strict=True)
    try:
        records = list(reader)
    except csv.Error:
        _raise_csv_error(text, file)
    breaks = np.fromiter(
        map(methodcaller("count", "\n"), map("".join, records)),
        dtype=np.int64,
        count=len(records),
    )
    return records, np.cumsum(breaks + 1) - breaks


def _raise_csv_error(text: str, file: Path) -> NoReturn:
    """Read a text the csv module fails on record by record, to name the row, and raise.

    Raises
    ------
    InputError
        ``malformed CSV``, with the data row of the record where the csv module fails
        (None before the header).
    """
    reader = csv.reader(io.StringIO(text, newline=""), strict=True)
    header_line: int | None = None
    line_end = 0  # last line of the previous record
    try:
        for fields in reader:
            start, line_end = line_end + 1, reader.line_num
            if header_line is None and any(cell.strip() for cell in fields):
                header_line = start
    except csv.Error as err:
        row = line_end + 1 - header_line if header_line is not None else None
        raise InputError(f"malformed CSV: {err}", file=file, row=row) from err
    raise InputError("malformed CSV", file=file)  # unreachable: the same reader failed


#: Spellings of NaN that a decimal parser might accept (C's ``strtod``, fast_float): every
#: case of ``nan``, signed or not, and with a payload.
_NAN_SPELLINGS = tuple(
    sign + "".join(letters) + payload
    for sign in ("", "+", "-")
    for letters in itertools.product("nN", "aA", "nN")
    for payload in ("", "(1)")
)


@functools.cache
def _pandas_refuses_nan_text() -> bool:
    """Whether pandas' C reader, as :func:`_read_numbers` calls it, refuses every NaN text.

    Asked of the installed pandas once per process (about 50 one-cell reads), instead of
    scanning every table's text for ``nan`` whenever it has an empty cell: if it refuses
    them all, a NaN it returns can only be an empty cell.

    Returns
    -------
    bool
        True if every spelling in :data:`_NAN_SPELLINGS` raises ``ValueError``.
    """
    for spelling in _NAN_SPELLINGS:
        try:
            pd.read_csv(
                io.BytesIO(f"x\n{spelling}\n".encode("ascii")),
                dtype={"x": np.float64},
                keep_default_na=False,
                na_values={"x": [""]},
                quoting=csv.QUOTE_NONE,
                engine="c",
            )
        except ValueError:
            continue
        return False
    return True


def _read_numbers(table: _CsvTable, text: bytes, start: int, numbers: Collection[str]) -> bool:
    """Read a plain table's data with pandas' C reader, columns in ``numbers`` as numbers.

    The table has no quotes, whitespace, unnamed columns, blank lines or rows of the wrong
    length, so the reader splits its rows as :func:`_read_csv` does. A cell it parses as a
    finite number is a plain decimal number, parsed as ``float`` does
    (:func:`_decimal_floats`); an infinite one is refused later by the range checks, with
    the cell's text. An empty cell gives NaN, and no other cell does: pandas refuses the
    spellings of NaN with these options (:func:`_pandas_refuses_nan_text` asks it once),
    and should a version not, a table whose text spells ``nan`` (in any case) is read
    cell by cell instead. Where the reader refuses a cell,
    nothing is changed.

    Parameters
    ----------
    table : _CsvTable
        The table as :func:`_read_csv` found it (``lines`` set, no cells yet); gets
        ``numbers`` and the text columns' ``cells``.
    text : bytes
        The file's text, ASCII.
    start : int
        Where its data rows start (below the header).
    numbers : collection of str
        Columns to parse as numbers, if the file has them.

    Returns
    -------
    bool
        Whether the table was read.
    """
    parsed = [name for name in table.header if name in numbers]
    if (
        not parsed
        or not _PANDAS_PARSES_EXACTLY
        or len(table.rows) * len(table.header) < _PANDAS_MIN_CELLS
    ):
        return False
    body = io.BytesIO(text)  # shares the bytes
    body.seek(start)
    try:
        frame = pd.read_csv(
            body,
            header=None,
            names=table.header,
            index_col=False,
            dtype={name: np.float64 if name in numbers else object for name in table.header},
            keep_default_na=False,
            na_values={name: [""] for name in parsed},
            skip_blank_lines=False,
            quoting=csv.QUOTE_NONE,
            engine="c",
        )
    except ValueError:  # a cell of a numeric column that is not a number
        return False
    if len(frame) != len(table.rows):
        return False
    values = {name: frame[name].to_numpy(np.float64, copy=True) for name in parsed}
    if any(np.isnan(column).any() for column in values.values()):
        if not _pandas_refuses_nan_text() and text.lower().find(b"nan", start) >= 0:
            return False
    table.numbers = values
    table.cells = {name: frame[name].tolist() for name in table.header if name not in numbers}
    return True


def _read_csv(file: Path, numbers: Collection[str] = ()) -> _CsvTable:
    """Read a CSV file as stripped strings and check its shape.

    Blank lines (and lines of empty fields only) are skipped; data rows are numbered by
    their line in the file relative to the header line, so row 1 directly follows the
    header. A column whose header name is empty is dropped if all its cells are empty.
    A file without double quotes is split at line breaks and commas (what the csv module
    does with it), one with quotes is read by the csv module; either way without Python
    code per row or cell (except for rows of the wrong length). A plain file (no quotes,
    whitespace, unnamed columns, blank lines or rows of the wrong length) has its columns
    in ``numbers`` parsed by pandas' C reader (:func:`_read_numbers`), where that gives
    exactly ``float(cell)``.

    Parameters
    ----------
    file : Path
        The CSV file (UTF-8, comma separated, optional byte-order mark).
    numbers : collection of str
        Columns the caller reads as numbers (:meth:`_CsvTable.floats`,
        :meth:`_CsvTable.integers`): these may be parsed while reading.

    Returns
    -------
    _CsvTable
        Rows with the wrong number of fields are padded or cut; the first one is
        recorded as a problem, and so is the first value in each unnamed column.

    Raises
    ------
    InputError
        If the file cannot be read or parsed, is empty, has only a header, or repeats a
        column name.
    """
    text, raw = _read_file(file)
    lines = _plain_lines(text)
    spaced = lines is None or not text.isascii() or any(c in text for c in _ASCII_SPACE)
    if lines is not None:
        # per line, in Python's C loops: cheaper than NumPy over the bytes (whose 20 MB
        # temporaries of a large file cost more in page faults than the counting itself)
        lengths = np.fromiter(map(len, lines), dtype=np.int64, count=len(lines))
        commas = np.fromiter(map(methodcaller("count", ","), lines), np.int64, len(lines))
        if lengths.size and lengths.max() > csv.field_size_limit():
            lines = None  # a field may be longer than the csv module allows: let it say so
    if lines is not None:
        starts = np.arange(1, len(lines) + 1, dtype=np.int64)
        if spaced:  # blank: nothing but commas and whitespace
            unblank = map(str.strip, map(methodcaller("replace", ",", ""), lines))
            filled = np.fromiter(map(bool, unblank), dtype=bool, count=len(lines))
        else:  # blank: nothing but commas
            filled = commas != lengths
        fields = commas + 1
    else:
        records, starts = _quoted_records(text, file)
        fields = np.fromiter(map(len, records), dtype=np.int64, count=len(records))
        # a record is blank if every field is whitespace, i.e. if all of it is
        unblank = map(str.strip, map("".join, records))
        filled = np.fromiter(map(bool, unblank), dtype=bool, count=len(records))
    kept = np.flatnonzero(filled)
    if not kept.size:
        raise InputError("empty file, expected a header line and data rows", file=file)
    first = int(kept[0])
    header = [
        name.strip() for name in (lines[first].split(",") if lines is not None else records[first])
    ]
    data = kept[1:]
    if not data.size:
        raise InputError("no data rows (only a header line)", file=file)
    named = [name for name in header if name]
    for index, name in enumerate(named):
        if name in named[:index]:
            raise InputError("duplicate column name", file=file, column=name)

    table = _CsvTable(file=file, header=header, rows=starts[data] - starts[first], cells={})
    width = len(header)
    wrong = np.flatnonzero(fields[data] != width).tolist()
    if wrong:
        found = int(fields[data[wrong[0]]])
        table.report(int(table.rows[wrong[0]]), None, f"{found} fields, but the header has {width}")
    contiguous = data.size == len(fields) - first - 1  # no blank line below the header
    if lines is not None:
        body = lines[first + 1 :] if contiguous else list(map(lines.__getitem__, data.tolist()))
        for index in wrong:  # pad or cut the rows of the wrong length only
            body[index] = ",".join((body[index].split(",") + [""] * width)[:width])
        if not spaced and not wrong and len(named) == width:
            table.lines = body
            data_start = len("\n".join(lines[: first + 1])) + 1
            if b"\r" in raw or raw.startswith(codecs.BOM_UTF8):  # the bytes of the text
                raw = text.encode("ascii")
            if contiguous and _read_numbers(table, raw, data_start, numbers):
                return table
        cells = ",".join(body).split(",")  # no cell holds a comma: the file has no quotes
    else:
        body = records[first + 1 :] if contiguous else list(map(records.__getitem__, data.tolist()))
        for index in wrong:
            body[index] = (body[index] + [""] * width)[:width]
        cells = list(itertools.chain.from_iterable(body))
    if spaced:
        cells = list(map(str.strip, cells))
    for index, name in enumerate(header):
        column = cells[index::width]
        if name:
            table.cells[name] = column
        elif any(column):
            values = np.fromiter(map(bool, column), dtype=bool, count=len(column))
            table.report_first(
                None,
                values,
                lambda i, column=column, index=index: (
                    f"value '{column[i]}' in column {index + 1}, which has no header name"
                ),
                position=index,
            )
    return table
