"""The error every flight-data reader raises, with a one-line message naming where.

Every problem found in a file raises :class:`FlightDataError` whose one-line message names the
file, the row (``data row r`` counts data rows from 1; ``CSV line r+1`` counts the header as
line 1), the column or the manifest key (``sorties[3].file``), and what is wrong. Nothing is
silently dropped or repaired, and content that is not in the expected format is never echoed.
"""

from __future__ import annotations

from pathlib import Path


def _display(path: str | Path) -> str:
    """A path as it can appear on one line of a message (non-printable characters escaped)."""
    text = str(path)
    return text if text.isprintable() else repr(text)[1:-1]


def _short(text: str, limit: int = 40) -> str:
    """A short, printable, quoted prefix of ``text`` for a message (never a whole line)."""
    return repr(text[:limit]) + ("..." if len(text) > limit else "")


class FlightDataError(ValueError):
    """A flight-data file is malformed; the one-line message names file, row and column.

    The parts are also kept as attributes: ``file``, ``row`` (1-based data row), ``line``
    (1-based CSV line, header = line 1), ``column`` (each may be None) and ``reason`` (the
    message without the location)."""

    def __init__(self, message: str, file: str | Path | None = None, row: int | None = None,
                 column: str | None = None, line: int | None = None) -> None:
        self.reason = message
        self.file = None if file is None else str(file)
        self.row = row
        self.line = line if line is not None else (None if row is None else row + 1)
        self.column = column
        where = []
        if self.file is not None:
            where.append(_display(self.file))
        if row is not None:
            where.append(f"data row {row} (CSV line {self.line})")
        elif self.line is not None:
            where.append(f"CSV line {self.line}")
        if column is not None:
            where.append(f"column '{column}'")
        text = ": ".join([", ".join(where), message]) if where else message
        super().__init__(" ".join(text.split()))  # always one line
