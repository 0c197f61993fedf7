"""The interchange-format CSV of one sortie: strict reading into a Sortie, and writing.

CSV header: fixed wing ``time,u,w,q,theta,elevator,throttle``; multirotor
``time,u,w,q,theta,collective,pitch_cmd``; either optionally followed by the recorded
turning-flight columns ``phi,p,r,beta`` (rad, rad/s, rad/s, rad: inputs like the controls).
SI units, radians, body axes (x forward, z down).
Row k's controls are held over [t_k, t_k+1) (zero-order hold). Files are plain ASCII; a UTF-8
byte-order mark and CRLF line ends are accepted (they parse unambiguously). A file larger than
:data:`CSV_MAX_BYTES` is refused before any byte is read.
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np

from uavdyn.flightdata.checks import _check_finite, check_values
from uavdyn.flightdata.errors import FlightDataError, _short
from uavdyn.flightdata.files import _read_text
from uavdyn.flightdata.sortie import Sortie, csv_columns
from uavdyn.model import CONTROL_NAMES

# Resource bounds, checked before anything is read (a 60 s sortie at 100 Hz is ~0.7 MB).
CSV_MAX_BYTES = 512 * 2**20       # one sortie CSV
MAX_LINE_CHARS = 4096             # one CSV line (a data row of 7 numbers is < 200)
MAX_CELL_CHARS = 64               # one number (17 significant digits need < 25)
MAX_COLUMNS = 64                  # fields a header may have before it is "not a header"

_COLUMN_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,63}")  # a CSV header field
_NUMBER = re.compile(r"[+-]?(?:(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?"
                     r"|nan|inf|infinity)", re.IGNORECASE)
_NUMERIC_BYTES = b"0123456789+-.eE, \t\r\n"  # a body of only these takes numpy's fast path


def parse_number(cell: str) -> float:
    """One number of a CSV cell by the ASCII grammar every CSV reader of this package uses.

    Python's ``float`` also reads ``0_5`` (digit grouping) and non-ASCII digits (Arabic-Indic,
    full-width): neither is a number a logger writes, so a cell is read only if it is
    ``[+-]digits[.digits][e[+-]digits]`` (or ``nan``/``inf``), at most
    :data:`MAX_CELL_CHARS` characters, with nothing around it.

    Parameters
    ----------
    cell : str
        The cell text, already stripped of surrounding blanks by the caller.

    Returns
    -------
    float

    Raises
    ------
    ValueError
        Anything else (the caller names file, row and column).
    """
    if len(cell) > MAX_CELL_CHARS or not _NUMBER.fullmatch(cell):
        raise ValueError(f"not an ASCII number: {_short(cell, 24)}")
    return float(cell)


def write_csv(sortie: Sortie, path: str | Path) -> Path:
    """Write one sortie in the interchange CSV format (17 significant digits: lossless)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    header = ",".join(csv_columns(sortie.kind, sortie.lateral))
    np.savetxt(path, sortie.to_array(), delimiter=",", header=header, comments="", fmt="%.17g")
    return path


def export(sortie: Sortie, path: str | Path, true_states: bool = False) -> Path:
    """Export any sortie (emulated, loaded or imported from a ULog) to the CSV format;
    ``true_states=True`` writes its noise-free states instead of the measured ones."""
    if true_states:
        if sortie.true_states is None:
            raise FlightDataError(f"sortie '{sortie.name}' has no true (noise-free) states")
        sortie = replace(sortie, states=sortie.true_states)
    return write_csv(sortie, path)


def _expected_headers(kind: str | None) -> str:
    kinds = [kind] if kind in CONTROL_NAMES else list(CONTROL_NAMES)
    return " or ".join(f"'{','.join(csv_columns(k))}'" for k in kinds)


def _parse_header(line: str, path: Path, kind: str | None) -> list[str]:
    """Column names of the first line, or an error that does not echo the line: a first line
    that is not a short list of identifiers is not a header (it may be anything at all)."""
    fields = [h.strip(" \t") for h in line.split(",")] if len(line) <= MAX_LINE_CHARS else []
    if not 2 <= len(fields) <= MAX_COLUMNS or not all(_COLUMN_NAME.fullmatch(h) for h in fields):
        raise FlightDataError("not a CSV file with the expected header: the first line is not "
                              "a comma-separated list of column names; expected "
                              + _expected_headers(kind), path, line=1)
    return fields


def _kind_from_header(header: list[str], path: Path) -> str:
    cols = set(header)
    for kind, names in CONTROL_NAMES.items():
        if set(names) & cols:
            return kind
    raise FlightDataError(
        f"cannot tell the airframe kind from the header {_short(','.join(header), 60)}: "
        f"expected the control columns {CONTROL_NAMES['fixed_wing']} (fixed wing) or "
        f"{CONTROL_NAMES['multirotor']} (multirotor)", path, line=1)


def _check_header(header: list[str], expected: tuple[str, ...], path: Path) -> None:
    for name in expected:
        if name not in header:
            raise FlightDataError(f"missing column '{name}' in the header; expected "
                                  f"'{','.join(expected)}'", path, line=1, column=name)
    for name in header:
        if name not in expected:
            raise FlightDataError(f"unexpected column '{name}' in the header; expected "
                                  f"'{','.join(expected)}'", path, line=1, column=name)
    if len(header) != len(set(header)):
        dup = next(h for h in header if header.count(h) > 1)
        raise FlightDataError("duplicated column in the header", path, line=1, column=dup)
    if tuple(header) != expected:
        raise FlightDataError(f"columns out of order: header '{','.join(header)}', expected "
                              f"'{','.join(expected)}'", path, line=1)


def _parse_rows(lines: list[str], header: list[str], path: Path) -> np.ndarray:
    """The strict, row-by-row parse: finds the exact row and column of a problem."""
    ncol = len(header)
    out = np.empty((len(lines), ncol))
    for r, line in enumerate(lines, start=1):
        fields = line.split(",")
        if len(fields) != ncol:
            raise FlightDataError(f"has {len(fields)} fields, the header has {ncol}", path, r)
        for c, text in enumerate(fields):
            cell = text.strip(" \t")
            try:
                out[r - 1, c] = parse_number(cell)
            except ValueError:
                raise FlightDataError(f"cannot read {_short(cell, 24)} as a number", path, r,
                                      header[c]) from None
    return out


def _read_table(shown: Path, real: str | Path, kind: str | None, folder_hint: str,
                resolved: bool) -> tuple[list[str], np.ndarray]:
    """Header and numbers of one CSV file (bounded, strict, nothing echoed but short cells)."""
    text, raw = _read_text(shown, real, CSV_MAX_BYTES, "a CSV file", "CSV", folder_hint,
                           resolved)
    if not text.strip():
        raise FlightDataError("empty file: expected a header row and data rows", shown)
    if not text.isascii():
        pos = re.search(r"[^\x00-\x7f]", text).start()
        line = text.count("\n", 0, pos) + 1
        where = {"row": line - 1} if line > 1 else {"line": 1}
        raise FlightDataError(f"non-ASCII character U+{ord(text[pos]):04X}; a CSV file holds "
                              "plain ASCII column names and numbers", shown, **where)
    lines = [s[:-1] if s.endswith("\r") else s for s in text.split("\n")]
    while lines and not lines[-1].strip():
        lines.pop()
    header = _parse_header(lines[0], shown, kind)
    body = lines[1:]
    if not body:
        raise FlightDataError("no data rows after the header", shown)
    if not raw.rstrip(b" \t\r").endswith(b"\n"):  # a writer ends every row with a newline
        raise FlightDataError("the last line has no newline at its end: the file looks cut "
                              "(a partial write or a copy stopped early); write it again",
                              shown, len(body))
    longest = max(range(len(body)), key=lambda k: len(body[k]))
    if len(body[longest]) > MAX_LINE_CHARS:
        raise FlightDataError(f"line of {len(body[longest])} characters, more than the "
                              f"{MAX_LINE_CHARS} a data row may have", shown, longest + 1)
    for r, line in enumerate(body, start=1):
        if not line.strip():
            raise FlightDataError("blank line inside the data", shown, r)
    rest = raw[raw.index(b"\n") + 1:]
    plain = not rest.translate(None, _NUMERIC_BYTES) and rest.count(b"\r") == rest.count(b"\r\n")
    data = None
    if plain:  # fast path; the strict parse below finds the exact row and column of a problem
        try:
            data = np.loadtxt(body, delimiter=",", comments=None, ndmin=2, dtype=float)
        except ValueError:
            data = None
        if data is not None and data.shape != (len(body), len(header)):
            data = None
    if data is None:
        data = _parse_rows(body, header, shown)
    return header, data


def _load_csv(shown: Path, real: str | Path, kind: str | None, sample_rate_hz: float | None,
              check: bool, name: str | None, key: str | None = None) -> Sortie:
    """:func:`read_csv` with separate paths to show (``shown``) and to read (``real``, a
    manifest entry already resolved inside its folder, listed at manifest ``key``)."""
    if kind is not None and (not isinstance(kind, str) or kind not in CONTROL_NAMES):
        raise FlightDataError(f"unknown airframe kind {kind!r}; expected one of "
                              f"{tuple(CONTROL_NAMES)}", shown)
    try:
        header, data = _read_table(shown, real, kind, "" if key else
                                   " (or load the folder with load_dataset)", key is not None)
    except FlightDataError as exc:
        if key is None or exc.row is not None or exc.line is not None:
            raise
        raise FlightDataError(f"{exc.reason} (listed as {key} in the manifest)", exc.file
                              ) from None
    if kind is None:
        kind = _kind_from_header(header, shown)
    expected = csv_columns(kind, lateral="phi" in header)
    _check_header(header, expected, shown)
    time, states, controls = data[:, 0], data[:, 1:5], data[:, 5:]
    if check:
        check_values(shown, kind, time, states, controls, sample_rate_hz)
    else:
        _check_finite(shown, data, expected)
    return Sortie(name=name or shown.stem, kind=kind, time=time.copy(), states=states.copy(),
                  controls=controls.copy(), meta={"file": str(shown)})


def read_csv(path: str | Path, kind: str | None = None, sample_rate_hz: float | None = None,
             check: bool = True, name: str | None = None) -> Sortie:
    """Read one interchange-format CSV into a :class:`Sortie`.

    The path is the caller's choice, so a symbolic link is followed; it must still lead to a
    regular file of at most :data:`CSV_MAX_BYTES` (checked before opening it).

    Parameters
    ----------
    path : str or Path
        The CSV file.
    kind : str, optional
        ``fixed_wing`` or ``multirotor``; default: told from the header's control columns.
    sample_rate_hz : float, optional
        Expected log rate; the time column must match it.
    check : bool
        Run all consistency checks of :func:`check_values` (default); if False only
        finiteness is checked.
    name : str, optional
        Sortie name (default: the file stem).

    Returns
    -------
    Sortie
        Named ``name`` or the file stem; ``meta['file']`` is the path read.

    Raises
    ------
    FlightDataError
        Any problem, on one line naming the file and, where it applies, row and column.
    """
    path = Path(path)
    return _load_csv(path, path, kind, sample_rate_hz, check, name)
