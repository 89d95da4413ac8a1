"""User-facing input errors.

Every problem with a user's files is reported as one :class:`InputError` that names the
file, the row and the column (or TOML key), so the command line can print one clear line
instead of a traceback.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["InputError"]


class InputError(ValueError):
    """Bad user input, located by file, row and column.

    Parameters
    ----------
    message : str
        What is wrong, in words.
    file : str or Path, optional
        The offending file.
    row : int, optional
        1-based data row of a CSV file (the header is row 0), or line of a TOML file.
    column : str, optional
        CSV column or TOML key (``section.key``).
    """

    def __init__(
        self,
        message: str,
        *,
        file: str | Path | None = None,
        row: int | None = None,
        column: str | None = None,
    ) -> None:
        self.message = message
        self.file = None if file is None else str(file)
        self.row = row
        self.column = column
        super().__init__(str(self))

    def __str__(self) -> str:
        """The message with the file, row and column it names."""
        where = []
        if self.file is not None:
            where.append(self.file)
        if self.row is not None:
            where.append(f"row {self.row}")
        if self.column is not None:
            where.append(f"column '{self.column}'")
        prefix = ", ".join(where)
        return f"{prefix}: {self.message}" if prefix else self.message
