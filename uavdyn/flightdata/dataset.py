"""Flight data: the in-memory sortie type, the SPEC section 3 interchange format (a folder with
``manifest.json`` and one CSV per sortie), loading with consistency checks, preprocessing
(zero-phase low-pass filter, normalisation from the training split) and export.

CSV header: fixed wing ``time,u,w,q,theta,elevator,throttle``; multirotor
``time,u,w,q,theta,collective,pitch_cmd``. SI units, radians, body axes (x forward, z down).
Row k's controls are held over [t_k, t_k+1) (zero-order hold). Files are plain ASCII; a UTF-8
byte-order mark and CRLF line ends are accepted (they parse unambiguously).

Every problem found in a file raises :class:`FlightDataError` whose one-line message names the
file, the row (``data row r`` counts data rows from 1; ``CSV line r+1`` counts the header as
line 1), the column or the manifest key (``sorties[3].file``), and what is wrong. Nothing is
silently dropped or repaired, and content that is not in the expected format is never echoed.

Reading is defensive (SPEC section 9): every file a manifest names must resolve inside the
dataset folder (no absolute paths, no ``..``, no symbolic link whose target leaves the folder);
a file is ``stat``-ed before it is opened, so a FIFO, a device or a folder is refused without
being opened, and files larger than :data:`MANIFEST_MAX_BYTES` / :data:`CSV_MAX_BYTES` are
refused before any byte is read.
"""

from __future__ import annotations

import json
import math
import os
import re
import stat
from dataclasses import dataclass, field, replace
from pathlib import Path, PurePosixPath, PureWindowsPath

import numpy as np
from scipy.signal import butter, filtfilt

from uavdyn.model import CONTROL_BOUNDS, CONTROL_NAMES, STATE_NAMES
from uavdyn.safefiles import (
    DuplicateKey,
    UnreadableFile,
    describe_mode,
    no_duplicate_keys,
    os_reason,
    read_regular,
)

SPLIT_NAMES = ("train", "validation", "test")
# Physical plausibility limits (units slip-ups such as degrees or km/h land outside them).
SPEED_LIMIT = {"fixed_wing": 100.0, "multirotor": 50.0}  # |u|, |w| in m/s
PITCH_RATE_LIMIT = 10.0  # rad/s (573 deg/s)
PITCH_LIMIT = math.pi    # rad
CONTROL_TOLERANCE = 1e-9
TIME_TOLERANCE = 1e-3    # allowed relative deviation of each interval from the nominal one
KINEMATIC_WINDOW_S = 1.0
KINEMATIC_TOLERANCE = 0.05  # rad, plus 10 % of the pitch travelled in the window
MIN_ROWS = 3             # two intervals: the least that lets "uniform time" be checked

# Resource bounds, checked before anything is read (a 60 s sortie at 100 Hz is ~0.7 MB).
MANIFEST_MAX_BYTES = 10 * 2**20   # manifest.json
CSV_MAX_BYTES = 512 * 2**20       # one sortie CSV
MANIFEST_MAX_DEPTH = 32           # nesting of JSON objects/arrays in the manifest
MANIFEST_MAX_SORTIES = 100_000
MAX_LINE_CHARS = 4096             # one CSV line (a data row of 7 numbers is < 200)
MAX_CELL_CHARS = 64               # one number (17 significant digits need < 25)
MAX_COLUMNS = 64                  # fields a header may have before it is "not a header"
SAMPLE_RATE_MAX_HZ = 1e5

_IDENTIFIER = re.compile(r"[A-Za-z0-9_.-]{1,64}")         # manifest 'airframe'
_COLUMN_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,63}")  # a CSV header field
_NUMBER = re.compile(r"[+-]?(?:(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?"
                     r"|nan|inf|infinity)", re.IGNORECASE)
_NUMERIC_BYTES = b"0123456789+-.eE, \t\r\n"  # a body of only these takes numpy's fast path
_BOM = b"\xef\xbb\xbf"

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


# ----------------------------------------------------------------------------- safe reading


def _read_regular(shown: Path, real: str | Path, limit: int, what: str, folder_hint: str,
                  resolved: bool) -> bytes:
    """The bytes of the regular file ``real`` (``shown`` in messages), at most ``limit``
    (:func:`uavdyn.safefiles.read_regular`). A ``resolved`` path (symbolic links already
    resolved and checked to stay inside the dataset folder) is not followed again if a link
    appears there meanwhile."""
    try:
        return read_regular(real, limit, what, follow_symlinks=not resolved)
    except UnreadableFile as exc:
        reason = exc.reason + (folder_hint if exc.reason.startswith("is a folder") else "")
        raise FlightDataError(reason, shown) from None


def _inside(folder_real: str, name: object, key: str, manifest: Path, folder: Path
            ) -> tuple[Path, str]:
    """Check that manifest value ``name`` (at ``key``) names a file inside the dataset folder.

    Returns the path to show in messages (``folder / name``) and the resolved path to read.
    Absolute paths and any ``..`` component are refused outright; a symbolic link is followed
    only if its resolved target stays inside the (resolved) folder."""
    if not isinstance(name, str):
        raise FlightDataError(f"{key}: expected a file name (string), got "
                              f"{type(name).__name__}", manifest)
    if not name or not name.strip():
        raise FlightDataError(f"{key}: empty file name", manifest)
    if len(name) > 1024 or not name.isprintable():
        raise FlightDataError(f"{key}: file name {_short(name)} is too long or has "
                              "non-printable characters", manifest)
    if "\\" in name:
        raise FlightDataError(f"{key}: file name {_short(name)} has a backslash; use '/' "
                              "between folders", manifest)
    if PurePosixPath(name).is_absolute() or PureWindowsPath(name).drive:
        raise FlightDataError(f"{key}: absolute path {_short(name)} refused: a manifest may "
                              "only name files inside the dataset folder", manifest)
    if ".." in PurePosixPath(name).parts:
        raise FlightDataError(f"{key}: path {_short(name)} has a '..' component, refused: a "
                              "manifest may only name files inside the dataset folder", manifest)
    shown = folder / name
    real = os.path.realpath(os.path.join(folder_real, name))
    if os.path.commonpath([folder_real, real]) != folder_real:
        raise FlightDataError(f"{key}: {_short(name)} is a symbolic link (or lies under one) "
                              "whose target is outside the dataset folder: refused", manifest)
    return shown, real


def _read_text(shown: Path, real: str | Path, limit: int, what: str, label: str,
               folder_hint: str, resolved: bool) -> tuple[str, bytes]:
    """Bounded read plus the checks every text format shares (BOM, empty, binary, UTF-8);
    ``label`` (CSV, JSON) names the format in messages."""
    raw = _read_regular(shown, real, limit, what, folder_hint, resolved)
    if raw.startswith(_BOM):
        raw = raw[len(_BOM):]
    if not raw.strip():
        return "", raw
    nul = raw.find(b"\x00")
    if nul >= 0:
        raise FlightDataError(f"not a text {label} file (binary content: NUL byte at offset "
                              f"{nul})", shown)
    try:
        return raw.decode("utf-8"), raw
    except UnicodeDecodeError as exc:
        raise FlightDataError(f"not a text {label} file (binary content: byte "
                              f"0x{raw[exc.start]:02x} at offset {exc.start} is not UTF-8)",
                              shown) from None


def csv_columns(kind: str) -> tuple[str, ...]:
    """The interchange-format header for an airframe kind."""
    if not isinstance(kind, str) or kind not in CONTROL_NAMES:
        raise FlightDataError(f"unknown airframe kind {kind!r}; expected one of "
                              f"{tuple(CONTROL_NAMES)}")
    return ("time",) + STATE_NAMES + CONTROL_NAMES[kind]


@dataclass
class Sortie:
    """One flight: uniformly sampled time, states ``N x 4`` and controls ``N x 2``;
    ``true_states`` (optional) are the noise-free states of an emulated flight."""

    name: str
    kind: str
    time: np.ndarray
    states: np.ndarray
    controls: np.ndarray
    mission: str = ""
    meta: dict = field(default_factory=dict)
    true_states: np.ndarray | None = None

    @property
    def dt(self) -> float:
        """Median sample interval (s)."""
        return float(np.median(np.diff(self.time)))

    @property
    def duration(self) -> float:
        """Last minus first time stamp (s)."""
        return float(self.time[-1] - self.time[0])

    @property
    def split(self) -> str:
        """``train``/``validation``/``test`` as recorded in the manifest ('' if none)."""
        return str(self.meta.get("split", ""))

    def to_array(self) -> np.ndarray:
        """``N x 7`` table in the CSV column order (time, states, controls)."""
        return np.column_stack([self.time, self.states, self.controls])


def write_csv(sortie: Sortie, path: str | Path) -> Path:
    """Write one sortie in the interchange CSV format (17 significant digits: lossless)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    header = ",".join(csv_columns(sortie.kind))
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


def write_manifest(folder: str | Path, airframe: str, kind: str, sample_rate_hz: float,
                   source: str, sorties: list[dict], **extra) -> Path:
    """Write ``manifest.json``: ``sorties`` entries need ``file``, ``mission``, ``duration_s``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    manifest = {"airframe": airframe, "kind": kind, "sample_rate_hz": sample_rate_hz,
                "source": source, "sorties": sorties, **extra}
    path = folder / "manifest.json"
    path.write_text(json.dumps(manifest, indent=2, sort_keys=False) + "\n")
    return path


# ----------------------------------------------------------------------------- reading CSV


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
            if len(cell) > MAX_CELL_CHARS or not _NUMBER.fullmatch(cell):
                raise FlightDataError(f"cannot read {_short(cell, 24)} as a number", path, r,
                                      header[c])
            out[r - 1, c] = float(cell)
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


def check_values(path: str | Path, kind: str, time: np.ndarray, states: np.ndarray,
                 controls: np.ndarray, sample_rate_hz: float | None = None,
                 kinematic: bool = True) -> None:
    """Consistency checks of one sortie's arrays, so that bad data never reaches a model.

    Finite values, at least :data:`MIN_ROWS` rows, strictly increasing and uniform time,
    physical ranges, controls within bounds and, if ``kinematic``, d theta/dt against q.

    Parameters
    ----------
    path : str or Path
        What to name in messages (the file, or a description of generated data).
    kind : str
        ``fixed_wing`` or ``multirotor``.
    time, states, controls : ndarray
        ``N``, ``N x 4`` and ``N x 2`` arrays in the CSV column order.
    sample_rate_hz : float, optional
        The time column must match this rate.
    kinematic : bool
        Also check d theta/dt against q (default).

    Raises
    ------
    FlightDataError
        The first problem, naming ``path``, the data row and the column.
    """
    columns = csv_columns(kind)
    table = np.column_stack([time, states, controls])
    bad = np.argwhere(~np.isfinite(table))
    if len(bad):
        r, c = bad[0]
        raise FlightDataError(f"value {table[r, c]} is not finite", path, int(r) + 1,
                              columns[c])
    if len(time) < MIN_ROWS:
        raise FlightDataError(f"only {len(time)} data row(s); a sortie needs at least "
                              f"{MIN_ROWS} (need at least 2 for a sample interval, {MIN_ROWS} "
                              "to check that time is uniform)", path)
    steps = np.diff(time)
    nonpos = np.flatnonzero(steps <= 0)
    if len(nonpos):
        k = int(nonpos[0]) + 1
        raise FlightDataError(f"time {float(time[k])!r} s is not greater than the previous "
                              f"row's {float(time[k - 1])!r} s (time must strictly increase)",
                              path, k + 1,
                              "time")
    nominal = float(np.median(steps))
    if sample_rate_hz is not None:
        if abs(nominal * sample_rate_hz - 1.0) > TIME_TOLERANCE:
            raise FlightDataError(f"median sample interval {nominal:.6g} s does not match the "
                                  f"manifest's sample_rate_hz {sample_rate_hz:g}", path,
                                  column="time")
        nominal = 1.0 / sample_rate_hz
    off = np.flatnonzero(np.abs(steps - nominal) > TIME_TOLERANCE * nominal)
    if len(off):
        k = int(off[0]) + 1
        raise FlightDataError(f"time step {steps[k - 1]:.6g} s from the previous row differs "
                              f"from the nominal {nominal:.6g} s by more than "
                              f"{TIME_TOLERANCE:.1%} (time must be uniform)", path, k + 1, "time")
    limits = {"u": SPEED_LIMIT[kind], "w": SPEED_LIMIT[kind], "q": PITCH_RATE_LIMIT,
              "theta": PITCH_LIMIT}
    units = {"u": "m/s", "w": "m/s", "q": "rad/s", "theta": "rad"}
    for j, name in enumerate(STATE_NAMES):
        over = np.flatnonzero(np.abs(states[:, j]) > limits[name])
        if len(over):
            r = int(over[0])
            raise FlightDataError(
                f"value {states[r, j]:.6g} {units[name]} is outside the physical range "
                f"[-{limits[name]:g}, {limits[name]:g}] {units[name]} (wrong units, e.g. "
                f"degrees or km/h?)", path, r + 1, name)
    for j, (name, (lo, hi)) in enumerate(zip(CONTROL_NAMES[kind], CONTROL_BOUNDS[kind])):
        out = np.flatnonzero((controls[:, j] < lo - CONTROL_TOLERANCE)
                             | (controls[:, j] > hi + CONTROL_TOLERANCE))
        if len(out):
            r = int(out[0])
            raise FlightDataError(f"value {controls[r, j]:.6g} is outside the control range "
                                  f"[{lo:g}, {hi:g}]", path, r + 1, name)
    if kinematic:
        check_kinematics(path, time, states)


def kinematic_residual(time: np.ndarray, states: np.ndarray,
                       window_s: float = KINEMATIC_WINDOW_S) -> tuple[np.ndarray, np.ndarray]:
    """Per window of ``window_s`` seconds (half-overlapping): the pitch change minus the
    trapezoid integral of q, and the pitch travelled (integral of |q|). Start indices are
    the first return value's index times the hop; see :func:`check_kinematics`."""
    theta, q = states[:, 3], states[:, 2]
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (q[1:] + q[:-1]) * np.diff(time))])
    cum_abs = np.concatenate([[0.0], np.cumsum(0.5 * np.abs(q[1:] + q[:-1]) * np.diff(time))])
    n = len(time)
    width = max(1, int(round(window_s / float(np.median(np.diff(time))))))
    width = min(width, n - 1)
    starts = np.arange(0, n - width, max(1, width // 2))
    if len(starts) == 0:
        starts = np.array([0])
    ends = starts + width
    diff = (theta[ends] - theta[starts]) - (cum[ends] - cum[starts])
    travel = cum_abs[ends] - cum_abs[starts]
    return np.column_stack([starts, ends, diff]), travel


def _robust_std(values: np.ndarray) -> float:
    """Standard deviation of the Gaussian bulk of ``values`` from their median absolute
    deviation (1.4826 MAD), which a few spikes or outliers do not move."""
    return 1.4826 * float(np.median(np.abs(values - np.median(values))))


def pitch_noise_std(time: np.ndarray, states: np.ndarray) -> float:
    """The white part of the pitch measurement noise (rad), from the data alone.

    Over one sample the pitch change minus the trapezoid integral of q leaves the difference of
    two independent pitch noise samples (variance ``2 sigma^2``); the dynamics contribute
    ``O(dt^3)`` and a gyro bias only a constant, so the residual's spread, taken robustly (the
    median absolute deviation, which a few spikes do not move), gives ``sigma``. A pitch that is
    itself the integral of q, or heavily filtered, gives about 0: nothing is then subtracted
    where the estimate is used (:func:`excess_rmse`).

    Parameters
    ----------
    time : ndarray, shape (N,)
        Sample times (s), N >= 3.
    states : ndarray, shape (N, 4)
        Recorded ``u, w, q, theta``.

    Returns
    -------
    float
        Estimated standard deviation of the pitch noise (rad).
    """
    dt = float(np.median(np.diff(time)))
    residual = kinematic_residual(time, states, dt)[0][:, 2]
    return _robust_std(residual) / math.sqrt(2.0)


def white_noise_std(signal: np.ndarray) -> float:
    """The white part of a sampled signal's noise, from the signal alone: the second difference
    of a signal sampled fast against its dynamics is mostly noise (variance ``6 sigma^2`` for
    white noise), taken robustly (median absolute deviation). Content above the sampling's
    reach (gusts in air-relative velocities) counts as noise, which for weighting residuals is
    what it is."""
    second = np.diff(np.asarray(signal, float), 2)
    if len(second) == 0:
        return 0.0
    return _robust_std(second) / math.sqrt(6.0)


def excess_rmse(rmse: float, noise_std: float) -> float:
    """The RMSE against the true states that an RMSE against noisy records implies: white
    measurement noise adds its variance to the expected squared error of any prediction that
    does not see it, so it is taken off (clamped at 0; an infinite RMSE stays infinite).

    Ratios of raw RMSEs shrink towards 1 as errors approach the noise level: on a calm sortie
    whose free-run pitch error is near a 0.002 rad pitch noise, a correction 1.3x worse against
    the truth scores 1.08x against the records. Ratios of these excess RMSEs do not.
    """
    if not math.isfinite(rmse):
        return rmse
    return math.sqrt(max(rmse * rmse - noise_std * noise_std, 0.0))


def check_kinematics(path: str | Path, time: np.ndarray, states: np.ndarray,
                     window_s: float = KINEMATIC_WINDOW_S,
                     tolerance: float = KINEMATIC_TOLERANCE) -> None:
    """d theta/dt ~ q: over every window the pitch change must match the integrated pitch rate
    within ``tolerance`` rad plus 10 % of the pitch travelled (noise and gyro bias of valid
    logs pass; pitch in degrees, q in deg/s or a flipped sign do not)."""
    windows, travel = kinematic_residual(time, states, window_s)
    allowed = tolerance + 0.1 * travel
    bad = np.flatnonzero(np.abs(windows[:, 2]) > allowed)
    if len(bad):
        i = int(bad[0])
        a, b, d = int(windows[i, 0]), int(windows[i, 1]), windows[i, 2]
        raise FlightDataError(
            f"kinematic inconsistency over data rows {a + 1}-{b + 1} (t = {time[a]:.3f}-"
            f"{time[b]:.3f} s): the pitch change differs from the integral of q by {d:.4g} rad "
            f"(allowed {allowed[i]:.3g} rad); theta and q disagree (units or sign?)", path,
            b + 1, "theta")


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
    expected = csv_columns(kind)
    _check_header(header, expected, shown)
    time, states, controls = data[:, 0], data[:, 1:5], data[:, 5:7]
    if check:
        check_values(shown, kind, time, states, controls, sample_rate_hz)
    else:
        bad = np.argwhere(~np.isfinite(data))
        if len(bad):
            raise FlightDataError(f"value {data[tuple(bad[0])]} is not finite", shown,
                                  int(bad[0][0]) + 1, expected[bad[0][1]])
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

    Raises
    ------
    FlightDataError
        Any problem, on one line naming the file and, where it applies, row and column.
    """
    path = Path(path)
    return _load_csv(path, path, kind, sample_rate_hz, check, name)


# ----------------------------------------------------------------------------- datasets


@dataclass(frozen=True)
class Normalisation:
    """Mean and standard deviation of states and controls (from the training split only)."""

    state_mean: np.ndarray
    state_std: np.ndarray
    control_mean: np.ndarray
    control_std: np.ndarray
    sorties: tuple[str, ...] = ()

    def normalise(self, states: np.ndarray, controls: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Zero-mean, unit-std states and controls (statistics of the training split)."""
        return ((states - self.state_mean) / self.state_std,
                (controls - self.control_mean) / self.control_std)

    def denormalise(self, states: np.ndarray, controls: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
        """Inverse of :meth:`normalise`."""
        return (states * self.state_std + self.state_mean,
                controls * self.control_std + self.control_mean)

    def as_dict(self) -> dict:
        """JSON-friendly form (to store beside trained weights)."""
        return {"state_mean": self.state_mean.tolist(), "state_std": self.state_std.tolist(),
                "control_mean": self.control_mean.tolist(),
                "control_std": self.control_std.tolist(), "sorties": list(self.sorties)}


def normalisation(sorties: list[Sortie]) -> Normalisation:
    """Statistics pooled over ``sorties`` (pass the training split only). A channel that is
    constant gets std 1 so normalising never divides by zero."""
    if not sorties:
        raise FlightDataError("no sorties to compute normalisation statistics from (is the "
                              "training split empty?)")
    S = np.vstack([s.states for s in sorties])
    U = np.vstack([s.controls for s in sorties])

    def std(a):
        sd = a.std(axis=0)
        return np.where(sd > 1e-12, sd, 1.0)

    return Normalisation(S.mean(axis=0), std(S), U.mean(axis=0), std(U),
                         tuple(s.name for s in sorties))


def lowpass(sortie: Sortie, cutoff_hz: float, order: int = 4) -> Sortie:
    """Zero-phase Butterworth low-pass (``scipy.signal.filtfilt``) of the measured states.
    Controls (commands, held per interval) and true states are left as they are."""

    fs = 1.0 / sortie.dt
    if not 0 < cutoff_hz < fs / 2:
        raise FlightDataError(f"sortie '{sortie.name}': cutoff {cutoff_hz} Hz must be between 0 "
                              f"and the Nyquist frequency {fs / 2:g} Hz")
    b, a = butter(order, cutoff_hz / (fs / 2))
    if len(sortie.time) <= 3 * max(len(a), len(b)):
        raise FlightDataError(f"sortie '{sortie.name}' is too short ({len(sortie.time)} rows) "
                              f"for an order-{order} zero-phase filter")
    states = filtfilt(b, a, sortie.states, axis=0)
    meta = dict(sortie.meta, lowpass_hz=cutoff_hz, lowpass_order=order)
    return replace(sortie, states=states, meta=meta)


@dataclass
class Dataset:
    """A loaded dataset: its manifest and sorties (in manifest order), split by sortie."""

    path: Path
    manifest: dict
    sorties: list[Sortie]

    @property
    def kind(self) -> str:
        """``fixed_wing`` or ``multirotor`` (from the manifest)."""
        return self.manifest["kind"]

    @property
    def sample_rate_hz(self) -> float:
        """Log rate (Hz) from the manifest."""
        return float(self.manifest["sample_rate_hz"])

    @property
    def splits(self) -> dict[str, list[str]]:
        """Sortie names per split (``unsplit`` for sorties the manifest gives no split)."""
        out: dict[str, list[str]] = {name: [] for name in SPLIT_NAMES}
        for s in self.sorties:
            out.setdefault(s.split or "unsplit", []).append(s.name)
        return out

    def split(self, name: str) -> list[Sortie]:
        """The sorties of one split, in manifest order."""
        if name not in SPLIT_NAMES:
            raise ValueError(f"unknown split '{name}'; expected one of {SPLIT_NAMES}")
        return [s for s in self.sorties if s.split == name]

    @property
    def train(self) -> list[Sortie]:
        """Training sorties (the only ones normalisation statistics come from)."""
        return self.split("train")

    @property
    def validation(self) -> list[Sortie]:
        """Validation sorties (model selection, early stopping)."""
        return self.split("validation")

    @property
    def test(self) -> list[Sortie]:
        """Held-out test sorties (final figures only)."""
        return self.split("test")

    def normalisation(self) -> Normalisation:
        """Normalisation statistics from the training split only (never validation/test)."""
        return normalisation(self.train)

    def lowpass(self, cutoff_hz: float, order: int = 4) -> Dataset:
        """A copy with every sortie's measured states low-pass filtered (zero phase)."""
        return Dataset(self.path, dict(self.manifest, lowpass_hz=cutoff_hz),
                       [lowpass(s, cutoff_hz, order) for s in self.sorties])

    def export(self, folder: str | Path) -> Path:
        """Write the dataset (manifest + CSVs, true states too where present) to ``folder``."""
        folder = Path(folder)
        entries = []
        for s in self.sorties:
            entry = dict(s.meta.get("manifest_entry", {}))
            entry.update(file=f"{s.name}.csv", mission=s.mission, duration_s=s.duration)
            write_csv(s, folder / entry["file"])
            if s.true_states is not None:
                entry["true_file"] = f"{s.name}_true.csv"
                export(s, folder / entry["true_file"], true_states=True)
            entries.append(entry)
        extra = {k: v for k, v in self.manifest.items()
                 if k not in ("airframe", "kind", "sample_rate_hz", "source", "sorties")}
        return write_manifest(folder, self.manifest.get("airframe", ""), self.kind,
                              self.sample_rate_hz, self.manifest.get("source", ""), entries,
                              **extra)


# ----------------------------------------------------------------------------- manifest


def _json_type(value: object) -> str:
    """The JSON name of a parsed value's type (what a manifest author recognises)."""
    if isinstance(value, bool):
        return "boolean"
    if value is None:
        return "null"
    return {dict: "object", list: "array", str: "string", int: "number",
            float: "number"}.get(type(value), type(value).__name__)


def _depth(value: object) -> int:
    """Nesting depth of objects/arrays (iterative: a deep value cannot exhaust the stack)."""
    deepest, stack = 0, [(value, 1)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, (dict, list)):
            deepest = max(deepest, depth)
            if depth > MANIFEST_MAX_DEPTH:
                break
            stack.extend((v, depth + 1) for v in (item.values() if isinstance(item, dict)
                                                  else item))
    return deepest


def _number(value: object, key: str, path: Path) -> float:
    """A finite JSON number (a boolean is not a number, nor is a numeric string)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise FlightDataError(f"{key}: expected a number, got {_json_type(value)}", path)
    try:
        number = float(value)
    except OverflowError:
        raise FlightDataError(f"{key}: an integer of {value.bit_length()} bits is too large "
                              "to be a finite number", path) from None
    if not math.isfinite(number):
        raise FlightDataError(f"{key}: {number!r} is not a finite number", path)
    return number


def _string(value: object, key: str, path: Path) -> str:
    if not isinstance(value, str):
        raise FlightDataError(f"{key}: expected a string, got {_json_type(value)}", path)
    return value


def _parse_json(shown: Path, real: str | Path) -> object:
    text, _ = _read_text(shown, real, MANIFEST_MAX_BYTES, "a JSON manifest", "JSON", "", True)
    if not text.strip():
        raise FlightDataError("empty file: expected a JSON object (the dataset manifest)", shown)
    try:
        return json.loads(text, object_pairs_hook=no_duplicate_keys)
    except json.JSONDecodeError as exc:
        raise FlightDataError(f"line {exc.lineno}, column {exc.colno}: invalid JSON: "
                              f"{exc.msg}", shown) from None
    except DuplicateKey as exc:
        raise FlightDataError(f"key {_short(str(exc.args[0]))} appears twice in one JSON "
                              "object (which one is meant is ambiguous)", shown) from None
    except RecursionError:
        raise FlightDataError(f"JSON nested too deeply (at most {MANIFEST_MAX_DEPTH} levels)",
                              shown) from None
    except ValueError as exc:  # e.g. an integer with more digits than Python converts
        reason = "a number has too many digits" if "digits" in str(exc) else type(exc).__name__
        raise FlightDataError(f"invalid JSON: {reason}", shown) from None


def _validate_manifest(manifest: object, path: Path) -> dict:
    """Keys, JSON types and ranges of a parsed manifest (not yet its file paths)."""
    if not isinstance(manifest, dict):
        raise FlightDataError(f"the manifest must be a JSON object, not {_json_type(manifest)}",
                              path)
    if _depth(manifest) > MANIFEST_MAX_DEPTH:
        raise FlightDataError(f"JSON nested too deeply (at most {MANIFEST_MAX_DEPTH} levels)",
                              path)
    for key in ("airframe", "kind", "sample_rate_hz", "source", "sorties"):
        if key not in manifest:
            raise FlightDataError(f"missing key '{key}'", path)
    airframe = _string(manifest["airframe"], "key 'airframe'", path)
    if airframe and (not _IDENTIFIER.fullmatch(airframe) or airframe.startswith(".")):
        raise FlightDataError(f"key 'airframe': {_short(airframe)} is not an airframe name "
                              "(letters, digits, '_', '-', '.', not starting with '.', at most "
                              "64 characters)", path)
    kind = _string(manifest["kind"], "key 'kind'", path)
    if kind not in CONTROL_NAMES:
        raise FlightDataError(f"key 'kind': {_short(kind)} is not one of "
                              f"{tuple(CONTROL_NAMES)}", path)
    rate = manifest["sample_rate_hz"]
    if isinstance(rate, bool) or not isinstance(rate, (int, float)):
        raise FlightDataError(f"key 'sample_rate_hz': expected a positive number, got "
                              f"{_json_type(rate)}", path)
    rate = _number(rate, "key 'sample_rate_hz'", path)
    if not 0 < rate <= SAMPLE_RATE_MAX_HZ:
        raise FlightDataError(f"key 'sample_rate_hz': {rate!r} is not a positive number of "
                              f"at most {SAMPLE_RATE_MAX_HZ:g} Hz", path)
    _string(manifest["source"], "key 'source'", path)
    sorties = manifest["sorties"]
    if not isinstance(sorties, list) or not sorties:
        raise FlightDataError(f"key 'sorties' must be a non-empty array of objects, got "
                              f"{_json_type(sorties) if sorties != [] else 'an empty array'}",
                              path)
    if len(sorties) > MANIFEST_MAX_SORTIES:
        raise FlightDataError(f"key 'sorties' lists {len(sorties)} sorties, more than "
                              f"{MANIFEST_MAX_SORTIES}", path)
    for i, entry in enumerate(sorties):
        where = f"sorties[{i}]"
        if not isinstance(entry, dict):
            raise FlightDataError(f"{where} must be an object, not {_json_type(entry)}", path)
        for key in ("file", "mission", "duration_s"):
            if key not in entry:
                raise FlightDataError(f"{where}: missing key '{key}'", path)
        _string(entry["file"], f"{where}.file", path)
        _string(entry["mission"], f"{where}.mission", path)
        if _number(entry["duration_s"], f"{where}.duration_s", path) < 0:
            raise FlightDataError(f"{where}.duration_s: {entry['duration_s']!r} is negative",
                                  path)
        if "split" in entry:
            split = _string(entry["split"], f"{where}.split", path)
            if split not in SPLIT_NAMES:
                raise FlightDataError(f"{where}: split {_short(split)} is not one of "
                                      f"{SPLIT_NAMES} (key {where}.split)", path)
        if entry.get("true_file") is not None:
            _string(entry["true_file"], f"{where}.true_file", path)
        if "condition" in entry:
            _string(entry["condition"], f"{where}.condition", path)
        if "altitude_m" in entry:
            _number(entry["altitude_m"], f"{where}.altitude_m", path)
        if "rows" in entry:
            rows = entry["rows"]
            if isinstance(rows, bool) or not isinstance(rows, int) or rows < 0:
                got = f"{rows!r}" if isinstance(rows, int) and not isinstance(rows, bool) \
                    and rows < 0 else _json_type(rows)
                raise FlightDataError(f"{where}.rows: expected a whole number >= 0, got {got}",
                                      path)
    return manifest


@dataclass(frozen=True)
class _Entry:
    """Where one manifest sortie's files are: shown in messages, and resolved for reading."""

    index: int
    shown: Path
    real: str
    true_shown: Path | None
    true_real: str | None


def _manifest_files(manifest: dict, path: Path, folder: Path) -> list[_Entry]:
    """Resolve every file the manifest names inside ``folder``; no file is listed twice and
    no two sorties share a name (the file stem)."""
    folder_real = os.path.realpath(folder)
    entries: list[_Entry] = []
    seen: dict[str, str] = {}
    names: dict[str, str] = {}
    for i, entry in enumerate(manifest["sorties"]):
        resolved = []
        for key in ("file", "true_file"):
            if key == "true_file" and entry.get(key) is None:
                resolved.append((None, None))
                continue
            where = f"sorties[{i}].{key}"
            shown, real = _inside(folder_real, entry[key], where, path, folder)
            if real in seen:
                raise FlightDataError(f"{where}: {_short(entry[key])} is the same file as "
                                      f"{seen[real]}; every file may be listed once", path)
            seen[real] = where
            resolved.append((shown, real))
        name = PurePosixPath(entry["file"]).stem
        if name in names:
            raise FlightDataError(f"sorties[{i}].file: sortie name {_short(name)} (the file "
                                  f"name without extension) is already used by {names[name]}",
                                  path)
        names[name] = f"sorties[{i}].file"
        (shown, real), (tshown, treal) = resolved
        entries.append(_Entry(i, shown, real, tshown, treal))
    return entries


def _manifest_in(path: Path) -> tuple[dict, list[_Entry]]:
    """Read and validate the manifest ``path`` and resolve the files it lists."""
    folder = path.parent
    if not os.path.lexists(path):
        raise FlightDataError("no manifest.json in the dataset folder", path)
    folder_real = os.path.realpath(folder)
    real = os.path.realpath(path)
    if os.path.commonpath([folder_real, real]) != folder_real:
        raise FlightDataError("is a symbolic link whose target is outside the dataset "
                              "folder: refused", path)
    manifest = _validate_manifest(_parse_json(path, real), path)
    return manifest, _manifest_files(manifest, path, folder)


def read_manifest(path: str | Path) -> dict:
    """Read and validate a dataset's ``manifest.json``.

    Checks the JSON (size, encoding, nesting, duplicated keys), the required keys and their
    types and ranges, and that every file it names (``file``, ``true_file``) resolves inside
    the manifest's folder; the CSV files themselves are not read.

    Parameters
    ----------
    path : str or Path
        The ``manifest.json`` file.

    Returns
    -------
    dict
        The manifest as parsed.

    Raises
    ------
    FlightDataError
        On one line naming the manifest and the key (e.g. ``sorties[3].file``).
    """
    return _manifest_in(Path(path))[0]


def _stat_given(path: Path) -> os.stat_result:
    try:
        return os.stat(path)
    except FileNotFoundError:
        raise FlightDataError("no such file or folder", path) from None
    except OSError as exc:
        raise FlightDataError(os_reason(exc), path) from None
    except ValueError:
        raise FlightDataError("invalid path (NUL byte)", path) from None


def load_dataset(path: str | Path, check: bool = True, lowpass_hz: float | None = None,
                 load_true: bool = True) -> Dataset:
    """Load a dataset folder (``manifest.json`` + CSVs) or one CSV file, checking everything.

    Every file a manifest names must resolve inside the dataset folder and be a regular file
    within the size bounds (see the module docstring); each CSV passes :func:`check_values`.

    Parameters
    ----------
    path : str or Path
        The dataset folder, its ``manifest.json``, or a single CSV file.
    check : bool
        Run the consistency checks of :func:`check_values` on every file (default).
    lowpass_hz : float, optional
        Zero-phase low-pass filter of the measured states (Hz).
    load_true : bool
        Also read each sortie's ``true_file`` (noise-free states), if the manifest has one.

    Returns
    -------
    Dataset

    Raises
    ------
    FlightDataError
        Any problem, on one line naming the file and the row, column or manifest key.
    """
    path = Path(path)
    if lowpass_hz is not None and (isinstance(lowpass_hz, bool)
                                   or not isinstance(lowpass_hz, (int, float))
                                   or not 0 < lowpass_hz < math.inf):
        raise FlightDataError(f"lowpass_hz must be a positive number of Hz, got {lowpass_hz!r}",
                              path)
    st = _stat_given(path)
    if stat.S_ISREG(st.st_mode) and path.name != "manifest.json":
        s = read_csv(path, check=check)
        rate = 1.0 / s.dt
        manifest = {"airframe": "", "kind": s.kind, "sample_rate_hz": rate,
                    "source": f"single CSV {path.name}",
                    "sorties": [{"file": path.name, "mission": "", "duration_s": s.duration}]}
        ds = Dataset(path, manifest, [s])
        return ds.lowpass(lowpass_hz) if lowpass_hz else ds
    if not (stat.S_ISDIR(st.st_mode) or stat.S_ISREG(st.st_mode)):
        raise FlightDataError(f"is {describe_mode(st.st_mode)}, not a dataset folder or a CSV "
                              "file: refused without opening it", path)
    folder = path if stat.S_ISDIR(st.st_mode) else path.parent
    manifest, entries = _manifest_in(folder / "manifest.json")
    kind, rate = manifest["kind"], float(manifest["sample_rate_hz"])
    sorties = []
    for where, entry in zip(entries, manifest["sorties"]):
        i, file = where.index, where.shown
        s = _load_csv(file, where.real, kind, rate, check, PurePosixPath(entry["file"]).stem,
                      f"sorties[{i}].file")
        if abs(s.duration - float(entry["duration_s"])) > 1.5 / rate:
            raise FlightDataError(f"the manifest says duration_s {entry['duration_s']!r} "
                                  f"(sorties[{i}].duration_s) but the file spans "
                                  f"{s.duration:.6g} s", file, column="time")
        if "rows" in entry and entry["rows"] != len(s.time):
            raise FlightDataError(f"the manifest says rows {entry['rows']} (sorties[{i}].rows) "
                                  f"but the file has {len(s.time)} data rows", file)
        if load_true and where.true_shown is not None:
            tfile = where.true_shown
            t = _load_csv(tfile, where.true_real, kind, rate, check, None,
                          f"sorties[{i}].true_file")
            if len(t.time) != len(s.time) or not np.array_equal(t.time, s.time):
                raise FlightDataError(f"time column differs from its measured file "
                                      f"{_short(entry['file'])} (sorties[{i}].true_file)",
                                      tfile, column="time")
            if not np.array_equal(t.controls, s.controls):
                r = int(np.flatnonzero(np.any(t.controls != s.controls, axis=1))[0]) + 1
                raise FlightDataError(f"controls differ from its measured file "
                                      f"{_short(entry['file'])} (sorties[{i}].true_file)",
                                      tfile, r)
            s.true_states = t.states
        s.mission = entry["mission"]
        s.meta.update(split=entry.get("split", ""), condition=entry.get("condition", ""),
                      manifest_entry=entry)
        sorties.append(s)
    ds = Dataset(folder, manifest, sorties)
    return ds.lowpass(lowpass_hz) if lowpass_hz else ds
