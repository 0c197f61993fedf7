"""Import of real flight logs into the :class:`uavdyn.flightdata.Sortie` type: PX4 ULog files
(through the optional ``pyulog`` package) and the ALFA fixed-wing CSV folders (MAVROS topics).

PX4 ULog, per the conventions of ``shared/data/flightlogs/README.md``:

* pitch ``theta = asin(2 (q0 q2 - q3 q1))`` from ``vehicle_attitude.q`` (FRD body to NED);
* pitch rate from ``vehicle_angular_velocity.xyz[1]``, else ``vehicle_attitude.pitchspeed``,
  else ``sensor_combined.gyro_rad[1]``;
* body velocities ``[u, v, w] = R(q)^T [vx, vy, vz]`` from ``vehicle_local_position`` (ground
  relative, no wind correction);
* multirotor controls: ``actuator_controls_0`` (control[3] thrust -> collective, control[1] ->
  pitch_cmd), else ``vehicle_thrust_setpoint``/``vehicle_torque_setpoint`` (PX4 >= 1.14), else
  ``actuator_motors`` (X frame: collective = mean, pitch_cmd = (front - rear) / (2 pitch_mix));
  fixed-wing controls from ``actuator_controls_1`` (elevator = -control[1] x 30 deg, since PX4's
  positive pitch command is nose up and this product's positive elevator is nose down);
* stray samples (timestamp 0, or a block far from the rest) are cut off each topic and the
  count is recorded in ``sortie.meta``; all signals are resampled to one uniform grid over the
  time span common to the topics used: states by linear interpolation (quaternions
  normalised), controls by zero-order hold (they are commands).

Reliability (SPEC section 9): only regular files are opened (checked with ``stat`` first, so a
FIFO or a device is never opened), within a size bound; ALFA topic files must lie inside the
given folder (no escaping symlinks). A cut ULog (its last message incomplete), a file pyulog
flags as corrupt, non-finite or non-unit source samples and every malformed ALFA CSV raise
:class:`FlightDataError` naming the file (and topic, field, row or column where they apply).
The imported arrays then go through the same :func:`check_values` as CSV data. A ULog cut
exactly at a message boundary cannot be told from a shorter log: the format has no end marker.
"""

from __future__ import annotations

import csv
import io
import math
import numbers
import os
import stat
import struct
import threading
from pathlib import Path

import numpy as np

from uavdyn.flightdata.dataset import FlightDataError, Sortie, check_values
from uavdyn.model import CONTROL_BOUNDS
from uavdyn.safefiles import UnreadableFile, read_regular, stat_regular

try:  # optional dependency; imported here so that no module is loaded during an import
    import pyulog as _pyulog
except ImportError:  # pragma: no cover - depends on the environment
    _pyulog = None

PX4_QUAD_X_FRONT = (0, 2)  # PX4 quad X motor order: 1 front-right, 2 rear-left, 3 front-left,
PX4_QUAD_X_REAR = (1, 3)   # 4 rear-right (0-based here)
FIXED_WING_MAV_TYPES = {1}  # MAV_TYPE_FIXED_WING; VTOLs are imported as multirotors by default
CONTROL_SOURCES = ("auto", "actuator_controls", "setpoints", "motors")

MAX_ULOG_BYTES = 2 * 1024**3        # refuse larger ULog files before reading them
MAX_ALFA_CSV_BYTES = 512 * 1024**2  # the same for each ALFA topic CSV (real ones are < 1 MB)
MAX_RATE_HZ = 10_000.0              # grid rates above this are refused (no such log rates)
MAX_GRID_ROWS = 20_000_000          # and so are grids that would need more rows than this
MAX_TOPIC_FIELDS = 65_536           # flattened fields of one ULog topic (PX4: a few hundred)
MAX_TOTAL_FIELDS = 2_000_000        # summed over all subscriptions of one ULog
MAX_FORMAT_DEPTH = 32               # nesting of ULog formats (PX4: at most 3)
QUATERNION_NORM_TOLERANCE = 0.1     # |norm - 1| of logged attitude quaternions
HOLD_TOLERANCE_S = 1e-7             # a sample 0.1 us "after" a grid instant is at it (rounding)
ULOG_MAGIC = b"ULog\x01\x12\x35"
ULOG_VERSIONS = (0, 1)
ULOG_TOPICS = ("vehicle_attitude", "vehicle_angular_velocity", "sensor_combined",
               "vehicle_local_position", "actuator_controls_0", "actuator_controls_1",
               "vehicle_thrust_setpoint", "vehicle_torque_setpoint", "actuator_motors")
_ULOG_BASIC_TYPES = {"int8_t", "uint8_t", "int16_t", "uint16_t", "int32_t", "uint32_t",
                     "int64_t", "uint64_t", "float", "double", "bool", "char"}
_MAX_STAMP_US = 2**62               # larger timestamps (146,000 years) are corrupt data
_PYULOG_LOCK = threading.Lock()     # serialises the capture of pyulog's printed warnings


def _require_pyulog():
    """The pyulog module, or an ImportError that says how to install it."""
    if _pyulog is None:  # pragma: no cover - depends on the environment
        raise ImportError("importing ULog files needs the optional dependency pyulog: "
                          "pip install 'uavdyn[ulog]' (or pip install pyulog)")
    return _pyulog


def pitch_from_quaternion(q: np.ndarray) -> np.ndarray:
    """Pitch of FRD-to-NED quaternions, ``asin(2(q0q2 - q3q1))``.

    Parameters
    ----------
    q : ndarray
        ``N x 4`` unit quaternions (w, x, y, z).

    Returns
    -------
    ndarray
        ``N`` pitch angles (rad), nose up positive.
    """
    q = np.asarray(q, float)
    return np.arcsin(np.clip(2 * (q[:, 0] * q[:, 2] - q[:, 3] * q[:, 1]), -1.0, 1.0))


def roll_from_quaternion(q: np.ndarray) -> np.ndarray:
    """Roll of FRD-to-NED quaternions (kept in ``meta`` to judge the pitch-plane assumption).

    Parameters
    ----------
    q : ndarray
        ``N x 4`` unit quaternions (w, x, y, z).

    Returns
    -------
    ndarray
        ``N`` roll angles (rad), right wing down positive.
    """
    q = np.asarray(q, float)
    return np.arctan2(2 * (q[:, 0] * q[:, 1] + q[:, 2] * q[:, 3]),
                      1 - 2 * (q[:, 1] ** 2 + q[:, 2] ** 2))


def rotation_matrices(q: np.ndarray) -> np.ndarray:
    """Rotation matrices body -> world, to rotate NED velocities into body axes.

    Parameters
    ----------
    q : ndarray
        ``N x 4`` unit quaternions (w, x, y, z).

    Returns
    -------
    ndarray
        ``N x 3 x 3`` matrices.
    """
    w, x, y, z = (q[:, i] for i in range(4))
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], axis=1)


def main_block(t: np.ndarray, gap_factor: float = 50.0, min_gap_s: float = 1.0) -> np.ndarray:
    """Indices of the longest contiguous run of samples (PX4 logs carry stray samples).

    Parameters
    ----------
    t : ndarray
        Sample times (any unit consistent with ``min_gap_s``; microseconds are divided by
        the caller where needed). Zero times are never kept.
    gap_factor, min_gap_s : float
        A gap longer than ``max(min_gap_s, gap_factor x median step)`` splits the samples.

    Returns
    -------
    ndarray
        Indices into ``t`` of the longest run, in time order.
    """
    t = np.asarray(t, float)
    idx = np.flatnonzero(t > 0)
    if len(idx) < 2:
        return idx
    order = idx[np.argsort(t[idx], kind="stable")]
    ts = t[order]
    steps = np.diff(ts)
    positive = steps[steps > 0]
    median = float(np.median(positive)) if len(positive) else 0.0
    limit = max(min_gap_s, gap_factor * median)
    cuts = np.flatnonzero(steps > limit)
    bounds = np.concatenate([[0], cuts + 1, [len(ts)]])
    k = int(np.argmax(np.diff(bounds)))
    return order[bounds[k]:bounds[k + 1]]


# ----------------------------------------------------------------------------- file access


def _as_path(path: object, option: str) -> Path:
    """``path`` as a Path; anything but a non-empty str or os.PathLike is refused up front."""
    if isinstance(path, (str, os.PathLike)) and str(path) != "":
        try:
            return Path(path)
        except TypeError:  # a PathLike giving bytes
            pass
    raise FlightDataError(f"option {option} must be a non-empty path (str or os.PathLike), "
                          f"got {path!r}")


def _stat_regular(path: Path, limit: int) -> os.stat_result:
    """``stat`` without opening (:func:`uavdyn.safefiles.stat_regular`), as a FlightDataError."""
    try:
        return stat_regular(path, limit, "a regular file")
    except UnreadableFile as exc:
        raise FlightDataError(exc.reason, path) from None


def _read_regular(path: Path, limit: int) -> bytes:
    """All bytes of a regular file of at most ``limit`` bytes
    (:func:`uavdyn.safefiles.read_regular`), as a FlightDataError."""
    try:
        return read_regular(path, limit, "a regular file")
    except UnreadableFile as exc:
        raise FlightDataError(exc.reason, path) from None


def _check_rate(rate_hz: object, path: Path, allow_none: bool) -> None:
    if rate_hz is None and allow_none:
        return
    if (not isinstance(rate_hz, numbers.Real) or isinstance(rate_hz, (bool, np.bool_))
            or not math.isfinite(float(rate_hz)) or not 0 < float(rate_hz) <= MAX_RATE_HZ):
        raise FlightDataError(f"option rate_hz must be a finite number in (0, {MAX_RATE_HZ:g}] "
                              f"Hz{' or None' if allow_none else ''}, got {rate_hz!r}", path)


def _check_bool(value: object, option: str, path: Path) -> None:
    if not isinstance(value, (bool, np.bool_)):
        raise FlightDataError(f"option {option} must be True or False, got {value!r}", path)


def _check_name(name: object, path: Path) -> None:
    if name is not None and (not isinstance(name, str) or not name):
        raise FlightDataError(f"option name must be a non-empty string or None, got {name!r}",
                              path)


def _checked(path: Path, kind: str, time: np.ndarray, states: np.ndarray,
             controls: np.ndarray, rate_hz: float, kinematic: bool) -> None:
    """:func:`check_values` on imported arrays; its row (of the resampled grid, not of any
    file) is restated as a grid row and time so that nobody looks for it in a CSV."""
    try:
        check_values(path, kind, time, states, controls, sample_rate_hz=rate_hz,
                     kinematic=kinematic)
    except FlightDataError as exc:
        if exc.row is None:
            raise
        detail = getattr(exc, "reason", None)
        if detail is None:  # older FlightDataError: strip the location prefix
            prefix = str(FlightDataError("", exc.file, exc.row, exc.column, exc.line))
            detail = str(exc)[len(prefix):].strip()
        k = min(max(exc.row - 1, 0), len(time) - 1)
        raise FlightDataError(f"imported grid row {exc.row} (t = {time[k]:.3f} s): {detail}",
                              path, column=exc.column) from None


def _grid(t0: float, t1: float, rate_hz: float, path: Path) -> np.ndarray:
    """The uniform grid ``t0 + k / rate_hz`` over ``[t0, t1]`` (at least 2, at most
    MAX_GRID_ROWS rows)."""
    rows = (t1 - t0) * rate_hz
    if rows + 1 > MAX_GRID_ROWS:
        raise FlightDataError(f"the common time span {t1 - t0:.6g} s at rate_hz {rate_hz:g} "
                              f"would need {rows:.3g} rows, above the limit of {MAX_GRID_ROWS}; "
                              "pass a lower rate_hz", path, column="time")
    n = int(math.floor(rows + 1e-9)) + 1
    if n < 2:
        raise FlightDataError(f"the common time span {t1 - t0:.6g} s holds fewer than 2 "
                              f"samples at rate_hz {rate_hz:g}", path, column="time")
    return t0 + np.arange(n) / rate_hz


# ----------------------------------------------------------------------------- ULog framing


def _format_fields(payload: bytes) -> tuple[str, list[tuple[str, int]]] | None:
    """``(name, [(type, count), ...])`` of an ``F`` message, or None if it does not parse
    (pyulog then flags the corruption)."""
    text = payload.decode("utf-8", "ignore")
    if ":" not in text:
        return None
    name, _, body = text.partition(":")
    fields = []
    for part in body.split(";"):
        if not part:
            continue
        type_str = part.split(" ")[0]
        count = 1
        if "[" in type_str:
            base, _, rest = type_str.partition("[")
            try:
                count = max(int(rest.partition("]")[0]), 1)
            except ValueError:
                return None
            type_str = base
        fields.append((type_str, count))
    return name, fields


def _flat_size(name: str, formats: dict, memo: dict, depth: int, path: Path) -> int:
    """Number of flattened fields of format ``name`` (pyulog expands nested types and arrays
    field by field: a few nested arrays could otherwise ask for billions of fields)."""
    if name in memo:
        if memo[name] is None:
            raise FlightDataError(f"corrupt ULog formats: format '{name}' contains itself",
                                  path)
        return memo[name]
    if depth > MAX_FORMAT_DEPTH:
        raise FlightDataError(f"corrupt ULog formats: nesting deeper than {MAX_FORMAT_DEPTH} "
                              f"at format '{name}'", path)
    memo[name] = None  # in progress: a cycle leads back here
    total = 0
    for type_name, count in formats.get(name, ()):
        if type_name in _ULOG_BASIC_TYPES:
            size = 1
        elif type_name in formats:
            size = _flat_size(type_name, formats, memo, depth + 1, path)
        else:
            size = 0  # unknown type: pyulog refuses it (corruption)
        total += size * count
        if total > MAX_TOPIC_FIELDS:
            raise FlightDataError(f"corrupt ULog formats: format '{name}' expands to more than "
                                  f"{MAX_TOPIC_FIELDS} fields", path)
    memo[name] = total
    return total


def _scan_ulog(raw: bytes, path: Path) -> tuple[int | None, dict[tuple[str, int], int]]:
    """Walk the ULog message framing before pyulog parses anything.

    Checks the format definitions against field-count bounds. Returns the byte offset of an
    incomplete last message (a cut file; None when the messages tile the file) and the number
    of data messages of each imported topic instance, to compare with what pyulog reads (it
    stops silently at some malformed messages)."""
    n = len(raw)
    appended: list[int] = []
    if n >= 19 + 40 and raw[18:19] == b"B":  # flag bits: appended-data offsets (rare)
        size = struct.unpack_from("<H", raw, 16)[0]
        if size >= 40 and raw[19 + 8] & 1:
            appended = [o for o in struct.unpack_from("<3Q", raw, 19 + 16) if o]
            if any(not 16 < o <= n for o in appended) or appended != sorted(appended):
                raise FlightDataError(f"corrupt ULog flag bits: appended-data offsets "
                                      f"{appended} outside the file of {n} bytes", path)
    formats: dict[str, list[tuple[str, int]]] = {}
    subscribed: list[str] = []
    msg_ids: dict[int, tuple[str, int]] = {}
    counts: dict[tuple[str, int], int] = {}
    truncated_at = None
    pos = 16
    for end in [*appended, n]:
        while pos < end:
            if pos + 3 > n:
                truncated_at = pos
                break
            size, kind = struct.unpack_from("<HB", raw, pos)
            if pos + 3 + size > n:
                truncated_at = pos
                break
            if pos + 3 + size > end:
                break  # crosses into appended data: pyulog stops this part here too
            if kind == ord("D") and size >= 2:
                key = msg_ids.get(struct.unpack_from("<H", raw, pos + 3)[0])
                if key is not None:
                    counts[key] += 1
            elif kind == ord("F"):
                parsed = _format_fields(raw[pos + 3:pos + 3 + size])
                if parsed is not None:
                    formats[parsed[0]] = parsed[1]
            elif kind == ord("A") and size > 3:
                topic = raw[pos + 6:pos + 3 + size].decode("utf-8", "ignore")
                subscribed.append(topic)
                if topic in ULOG_TOPICS:
                    key = (topic, raw[pos + 3])
                    msg_ids[struct.unpack_from("<H", raw, pos + 4)[0]] = key
                    counts.setdefault(key, 0)
            pos += 3 + size
        if truncated_at is not None:
            break
        pos = max(pos, end)
    memo: dict[str, int | None] = {}
    total = 0
    for name in subscribed:
        total += _flat_size(name, formats, memo, 0, path) if name in formats else 0
        if total > MAX_TOTAL_FIELDS:
            raise FlightDataError(f"corrupt ULog: the subscriptions expand to more than "
                                  f"{MAX_TOTAL_FIELDS} fields", path)
    return truncated_at, counts


def _run_pyulog(pyulog, raw: bytes) -> tuple[object, list[str]]:
    """pyulog's parse of ``raw`` (only the topics used), with the warnings it prints collected
    instead of written to stdout. Only pyulog's own ``print`` is replaced (not sys.stdout,
    which would swallow other threads' output), under a lock so that concurrent imports
    restore it in order."""
    core = getattr(pyulog, "core", None)
    messages: list[str] = []

    def collect(*args: object, **_: object) -> None:
        text = " ".join(str(a) for a in args).strip()
        if text:
            messages.append(text)

    with _PYULOG_LOCK:
        saved = vars(core).get("print") if core is not None else None
        if core is not None:
            core.print = collect
        try:
            ulog = pyulog.ULog(io.BytesIO(raw), message_name_filter_list=list(ULOG_TOPICS))
        finally:
            if core is not None:
                if saved is None:
                    del core.print
                else:
                    core.print = saved
    return ulog, messages


def _parse_ulog(raw: bytes, path: Path, allow_truncated: bool):
    """pyulog's parse of ``raw`` after the header, framing and corruption checks; returns
    ``(ulog, truncated_at, parser_messages)``."""
    pyulog = _require_pyulog()
    if len(raw) < 16:
        raise FlightDataError(f"not a readable ULog file: {len(raw)} bytes, shorter than the "
                              "16-byte ULog header", path)
    if raw[:7] != ULOG_MAGIC:
        raise FlightDataError(f"not a readable ULog file: wrong magic bytes {raw[:7]!r} "
                              f"(expected {ULOG_MAGIC!r})", path)
    if raw[7] not in ULOG_VERSIONS:
        raise FlightDataError(f"not a readable ULog file: unsupported ULog version {raw[7]} "
                              f"(this importer reads versions {ULOG_VERSIONS})", path)
    start = struct.unpack_from("<Q", raw, 8)[0]
    if start >= _MAX_STAMP_US:
        raise FlightDataError(f"corrupt ULog header: start timestamp {start} us", path)
    truncated_at, counts = _scan_ulog(raw, path)
    if truncated_at is not None and not allow_truncated:
        raise FlightDataError(f"truncated ULog file: the message at byte {truncated_at} runs "
                              f"past the end of the file ({len(raw)} bytes; a cut or "
                              "corrupt log); pass allow_truncated=True to import the complete "
                              "messages before it", path)
    try:
        ulog, messages = _run_pyulog(pyulog, raw)
    except Exception as exc:  # pyulog raises plain Exceptions on foreign data
        raise FlightDataError(f"not a readable ULog file ({type(exc).__name__}: {exc})",
                              path) from None
    if ulog.file_corruption:
        detail = f" ({messages[0][:120]})" if messages else ""
        raise FlightDataError(f"corrupt ULog file: pyulog found malformed messages{detail}",
                              path)
    read: dict[tuple[str, int], int] = {}
    for d in ulog.data_list:
        key = (d.name, d.multi_id)
        read[key] = read.get(key, 0) + len(next(iter(d.data.values()), ()))
    for (topic, multi_id), count in counts.items():
        if read.get((topic, multi_id), 0) != count:
            raise FlightDataError(f"corrupt ULog file: topic {topic} (instance {multi_id}) has "
                                  f"{count} data messages, but the parser read "
                                  f"{read.get((topic, multi_id), 0)} (it stopped at a "
                                  "malformed message)", path)
    return ulog, truncated_at, messages


class _Topics:
    """Access to the topics of one parsed ULog, each cut to its main block of samples."""

    def __init__(self, ulog, path: Path) -> None:
        self.ulog, self.path = ulog, path
        self.origin_us = int(ulog.start_timestamp)
        self.dropped: dict[str, int] = {}
        self.duplicates: dict[str, int] = {}

    def get(self, name: str, fields: list[str], multi_id: int = 0
            ) -> tuple[np.ndarray, np.ndarray] | None:
        """``(t seconds from log start, values N x len(fields))`` of a topic cut to its main
        block of samples, or None when the topic, a field or two usable samples are absent.
        A non-finite value among the used samples raises (naming topic and field)."""
        for d in self.ulog.data_list:
            if d.name == name and d.multi_id == multi_id:
                if "timestamp" not in d.data or not all(f in d.data for f in fields):
                    return None
                raw_stamps = d.data["timestamp"]
                keep = main_block(raw_stamps)
                if len(keep) < 2:
                    return None
                if int(raw_stamps[keep].max()) >= _MAX_STAMP_US:
                    raise FlightDataError(f"corrupt timestamp {int(raw_stamps[keep].max())} us",
                                          self.path, column=f"{name}.timestamp")
                self.dropped[name] = len(raw_stamps) - len(keep)
                # integer microseconds relative to the log start, then seconds: epoch-based
                # (SITL) stamps would lose precision as floats
                stamps = raw_stamps[keep].astype(np.int64) - np.int64(self.origin_us)
                t = stamps.astype(float) * 1e-6
                t, first = np.unique(t, return_index=True)  # duplicated stamps: first sample
                if len(t) < 2:
                    return None
                if len(t) < len(keep):
                    self.duplicates[name] = len(keep) - len(t)
                vals = np.column_stack([d.data[f][keep].astype(float) for f in fields])[first]
                bad = np.argwhere(~np.isfinite(vals))
                if len(bad):
                    k, j = (int(i) for i in bad[0])
                    raise FlightDataError(
                        f"non-finite value {vals[k, j]} in topic '{name}', field '{fields[j]}' "
                        f"(used sample {k + 1}, t = {t[k]:.6f} s from the log start)",
                        self.path, column=f"{name}.{fields[j]}")
                return t, vals
        return None


def _interp(t_grid: np.ndarray, t: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(t_grid, t, v[:, j]) for j in range(v.shape[1])])


def _hold(t_grid: np.ndarray, t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Zero-order hold: the last sample at or before each grid time (the first before it).

    A sample counts as "at" a grid time within HOLD_TOLERANCE_S: ``t0 + k / rate`` and
    ``stamp * 1e-6`` of the very same instant can differ by an ulp, and the hold must not
    then fall back to the previous command (stamps are whole microseconds, so 0.1 us never
    lets a genuinely later sample in)."""
    i = np.clip(np.searchsorted(t, t_grid + HOLD_TOLERANCE_S, side="right") - 1, 0, len(t) - 1)
    return v[i]


def _quaternions_on_grid(t_grid: np.ndarray, t: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Quaternions made sign-continuous (q and -q are one attitude), interpolated and
    normalised."""
    dots = np.einsum("ij,ij->i", q[1:], q[:-1])
    signs = np.cumprod(np.concatenate([[1.0], np.where(dots < 0, -1.0, 1.0)]))
    qi = _interp(t_grid, t, q * signs[:, None])
    return qi / np.linalg.norm(qi, axis=1, keepdims=True)


def _check_unit(q: np.ndarray, t: np.ndarray, path: Path) -> None:
    """Refuse attitude quaternions that are not unit length (a zero quaternion is PX4's 'no
    estimate'; normalising it would give NaN pitch)."""
    norm = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(np.abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE)
    if len(bad):
        k = int(bad[0])
        raise FlightDataError(f"vehicle_attitude.q has norm {norm[k]:.6g}, not a unit "
                              f"quaternion (used sample {k + 1}, t = {t[k]:.6f} s)", path,
                              column="vehicle_attitude.q")


def _vehicle_kind(ulog) -> str:
    mav_type = ulog.initial_parameters.get("MAV_TYPE")
    return "fixed_wing" if mav_type in FIXED_WING_MAV_TYPES else "multirotor"


def import_ulog(path: str | Path, rate_hz: float | None = None, kind: str | None = None,
                pitch_mix: float = 0.1, name: str | None = None,
                control_source: str = "auto", *, check: bool = True, kinematic: bool = True,
                allow_truncated: bool = False) -> Sortie:
    """Read a PX4 ULog file into a :class:`Sortie` on a uniform grid.

    Channel sources, topic rates, cut stray samples and duplicated stamps are recorded in
    ``meta``; the result passes :func:`check_values` (the same checks as CSV data) unless
    the caller opts out.

    Parameters
    ----------
    path : str or Path
        The ``.ulg`` file; must be a regular file of at most ``MAX_ULOG_BYTES``.
    rate_hz : float, optional
        Grid rate in (0, ``MAX_RATE_HZ``]; default the attitude topic's mean rate rounded to
        1 Hz.
    kind : {'fixed_wing', 'multirotor'}, optional
        Default from the log's MAV_TYPE (fixed wing for MAV_TYPE 1, else multirotor).
    pitch_mix : float
        Finite, > 0: maps motor outputs to pitch_cmd when only motor commands are logged.
    name : str, optional
        Sortie name (default: the file stem).
    control_source : {'auto', 'actuator_controls', 'setpoints', 'motors'}
        Forces one multirotor control source instead of the first one present.
    check : bool
        Run :func:`check_values` on the result (default True).
    kinematic : bool
        Include its pitch-plane kinematic check ``d theta/dt ~ q`` (default True). Pass False
        for logs whose motion is not in the pitch plane (hand-moved, banked turns), where
        ``d theta/dt = q cos(roll) - r sin(roll)`` legitimately differs from q.
    allow_truncated : bool
        Import the complete messages of a cut file (``meta['truncated_at_byte']`` says where)
        instead of raising (default False).

    Returns
    -------
    Sortie

    Raises
    ------
    FlightDataError
        One line naming the file (and topic/field or option) for anything wrong: unreadable,
        cut or corrupt file, missing topic, non-finite or non-unit samples, no common time
        span, bad options, failed value checks.
    ImportError
        When the optional dependency pyulog is not installed.
    """
    path = _as_path(path, "path")
    _check_rate(rate_hz, path, allow_none=True)
    if kind is not None and not isinstance(kind, str):
        raise FlightDataError(f"option kind must be a string {tuple(CONTROL_BOUNDS)} or None, "
                              f"got {kind!r}", path)
    if kind is not None and kind not in CONTROL_BOUNDS:
        raise FlightDataError(f"unknown kind '{kind}' (option kind must be one of "
                              f"{tuple(CONTROL_BOUNDS)})", path)
    if (not isinstance(pitch_mix, numbers.Real) or isinstance(pitch_mix, (bool, np.bool_))
            or not math.isfinite(float(pitch_mix)) or not float(pitch_mix) > 0):
        raise FlightDataError(f"option pitch_mix must be a finite number > 0, got "
                              f"{pitch_mix!r}", path)
    if not isinstance(control_source, str) or control_source not in CONTROL_SOURCES:
        raise FlightDataError(f"option control_source must be one of {CONTROL_SOURCES}, got "
                              f"{control_source!r}", path)
    _check_name(name, path)
    for option, value in (("check", check), ("kinematic", kinematic),
                          ("allow_truncated", allow_truncated)):
        _check_bool(value, option, path)
    _require_pyulog()
    raw = _read_regular(path, MAX_ULOG_BYTES)
    ulog, truncated_at, parser_messages = _parse_ulog(raw, path, allow_truncated)
    del raw
    topics = _Topics(ulog, path)
    kind = kind or _vehicle_kind(ulog)
    sources: dict[str, str] = {}
    att = topics.get("vehicle_attitude", [f"q[{i}]" for i in range(4)])
    if att is None:
        raise FlightDataError("no usable vehicle_attitude.q topic (at least 2 samples): cannot "
                              "compute pitch", path, column="theta")
    _check_unit(att[1], att[0], path)
    sources["theta"] = "vehicle_attitude.q"
    rate = None
    for topic, field in (("vehicle_angular_velocity", "xyz[1]"),
                         ("vehicle_attitude", "pitchspeed"),
                         ("sensor_combined", "gyro_rad[1]")):
        rate = topics.get(topic, [field])
        if rate is not None:
            sources["q"] = f"{topic}.{field}"
            break
    if rate is None:
        raise FlightDataError("no pitch-rate topic (vehicle_angular_velocity, "
                              "vehicle_attitude.pitchspeed or sensor_combined.gyro_rad)", path,
                              column="q")
    vel = topics.get("vehicle_local_position", ["vx", "vy", "vz"])
    if vel is None:
        raise FlightDataError("no usable vehicle_local_position.vx/vy/vz: cannot compute u, w",
                              path, column="u")
    sources["u,w"] = "vehicle_local_position.vx/vy/vz rotated by vehicle_attitude.q"
    controls, control_sources = _controls(topics, kind, float(pitch_mix), path, control_source)
    sources.update(control_sources)
    used = [att, rate, vel, controls]
    t0 = max(u[0][0] for u in used)
    t1 = min(u[0][-1] for u in used)
    if not t1 > t0:
        raise FlightDataError("the attitude, rate, velocity and control topics share no time "
                              "span", path, column="time")
    if rate_hz is None:
        rate_hz = max(1.0, round((len(att[0]) - 1) / (att[0][-1] - att[0][0])))
        if rate_hz > MAX_RATE_HZ:
            raise FlightDataError(f"the attitude topic's mean rate {rate_hz:g} Hz is above "
                                  f"{MAX_RATE_HZ:g} Hz (corrupt timestamps?); pass rate_hz",
                                  path, column="time")
    rate_hz = float(rate_hz)
    grid = _grid(t0, t1, rate_hz, path)
    n = len(grid)
    quat = _quaternions_on_grid(grid, *att)
    theta = pitch_from_quaternion(quat)
    q = _interp(grid, *rate)[:, 0]
    v_ned = _interp(grid, *vel)
    v_body = np.einsum("nji,nj->ni", rotation_matrices(quat), v_ned)
    states = np.column_stack([v_body[:, 0], v_body[:, 2], q, theta])
    ctrl = _hold(grid, *controls)
    time = np.arange(n) / rate_hz
    if check:
        _checked(path, kind, time, states, ctrl, rate_hz, kinematic)
    meta = {
        "file": str(path), "source": "PX4 ULog", "sources": sources,
        "start_time_s": float(t0) + topics.origin_us * 1e-6, "rate_hz": rate_hz,
        "topic_rates_hz": {key: round((len(v[0]) - 1) / (v[0][-1] - v[0][0]), 1)
                           for key, v in (("attitude", att), ("pitch_rate", rate),
                                          ("velocity", vel), ("controls", controls))},
        "stray_samples_cut": {k: v for k, v in topics.dropped.items() if v},
        "duplicate_stamps": dict(topics.duplicates),
        "truncated_at_byte": truncated_at,
        "parser_messages": parser_messages,
        "checked": {"values": check, "kinematic": bool(check and kinematic)},
        "roll": roll_from_quaternion(quat),
        "sys_name": ulog.msg_info_dict.get("sys_name", ""),
        "ver_hw": ulog.msg_info_dict.get("ver_hw", ""),
        "mav_type": ulog.initial_parameters.get("MAV_TYPE"),
    }
    return Sortie(name=name or path.stem, kind=kind, time=time,
                  states=states, controls=ctrl, mission="ulog", meta=meta)


def _controls(topics: _Topics, kind: str, pitch_mix: float, path: Path, source: str = "auto"
              ) -> tuple[tuple[np.ndarray, np.ndarray], dict[str, str]]:
    if kind == "fixed_wing":
        c = topics.get("actuator_controls_1", ["control[1]", "control[3]"])
        if c is None:
            raise FlightDataError("no actuator_controls_1 (fixed-wing pitch and throttle "
                                  "commands)", path, column="elevator")
        max_defl = CONTROL_BOUNDS["fixed_wing"][0][1]
        vals = np.column_stack([-c[1][:, 0] * max_defl, c[1][:, 1]])
        return (c[0], vals), {"elevator": "-actuator_controls_1.control[1] x 30 deg",
                              "throttle": "actuator_controls_1.control[3]"}

    def wanted(name):
        return source in ("auto", name)

    c = topics.get("actuator_controls_0", ["control[3]", "control[1]"]) \
        if wanted("actuator_controls") else None
    if c is not None:
        return c, {"collective": "actuator_controls_0.control[3]",
                   "pitch_cmd": "actuator_controls_0.control[1]"}
    thrust = topics.get("vehicle_thrust_setpoint", ["xyz[2]"]) if wanted("setpoints") else None
    torque = topics.get("vehicle_torque_setpoint", ["xyz[1]"]) if wanted("setpoints") else None
    if thrust is not None and torque is not None:
        t = np.union1d(thrust[0], torque[0])
        vals = np.column_stack([-_hold(t, *thrust)[:, 0], _hold(t, *torque)[:, 0]])
        return (t, vals), {"collective": "-vehicle_thrust_setpoint.xyz[2]",
                           "pitch_cmd": "vehicle_torque_setpoint.xyz[1]"}
    motors = topics.get("actuator_motors", [f"control[{i}]" for i in range(4)]) \
        if wanted("motors") else None
    if motors is not None:
        m = motors[1]
        front = m[:, list(PX4_QUAD_X_FRONT)].mean(axis=1)
        rear = m[:, list(PX4_QUAD_X_REAR)].mean(axis=1)
        vals = np.column_stack([m.mean(axis=1), (front - rear) / (2 * pitch_mix)])
        return (motors[0], vals), {"collective": "mean of actuator_motors.control[0..3]",
                                   "pitch_cmd": "(front - rear motors)/(2 pitch_mix), quad X"}
    what = "actuator_controls_0, vehicle_thrust/torque_setpoint or actuator_motors" \
        if source == "auto" else f"the requested control source '{source}'"
    raise FlightDataError(f"no multirotor control topic ({what})", path, column="collective")


def integrated_pitch_rms(sortie: Sortie, window_s: float | None = None) -> float:
    """How well the integrated pitch rate follows pitch (a check of an import's conventions).

    Parameters
    ----------
    sortie : Sortie
        An imported flight.
    window_s : float, optional
        Restart the integral every ``window_s`` seconds, so that slow gyro bias drift does
        not accumulate; default one integral over the whole flight.

    Returns
    -------
    float
        RMS (rad) of ``theta - (theta_0 + integral of q)``.
    """
    t, q, theta = sortie.time, sortie.states[:, 2], sortie.states[:, 3]
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (q[1:] + q[:-1]) * np.diff(t))])
    if window_s is None:
        return float(np.sqrt(np.mean((theta - theta[0] - cum) ** 2)))
    seg = np.floor((t - t[0]) / window_s).astype(int)
    err = np.empty_like(theta)
    for s in np.unique(seg):
        i = np.flatnonzero(seg == s)
        err[i] = (theta[i] - theta[i[0]]) - (cum[i] - cum[i[0]])
    return float(np.sqrt(np.mean(err**2)))


def summary(sortie: Sortie) -> dict:
    """One row of numbers describing an imported log, for comparison tables.

    Parameters
    ----------
    sortie : Sortie
        An imported flight.

    Returns
    -------
    dict
        Name, kind, rows, duration, rate, ranges of each channel, maximum roll and the
        integrated-pitch-rate RMS (whole flight and 1 s windows).
    """
    S, U = sortie.states, sortie.controls

    def span(x, digits):
        return (round(float(np.min(x)), digits), round(float(np.max(x)), digits))

    roll = sortie.meta.get("roll")
    return {
        "name": sortie.name, "kind": sortie.kind, "rows": len(sortie.time),
        "duration_s": round(sortie.duration, 2), "rate_hz": round(1 / sortie.dt, 2),
        "theta_deg": span(np.degrees(S[:, 3]), 2), "q_radps": span(S[:, 2], 3),
        "u_mps": span(S[:, 0], 2), "w_mps": span(S[:, 1], 2),
        "u0": span(U[:, 0], 3), "u1": span(U[:, 1], 3),
        "roll_max_deg": None if roll is None else round(float(np.degrees(np.abs(roll).max())), 1),
        "rms_int_q_vs_theta_rad": integrated_pitch_rms(sortie),
        "rms_int_q_vs_theta_1s_rad": integrated_pitch_rms(sortie, 1.0),
    }




# ----------------------------------------------------------------------------- ALFA CSV

ALFA_TIME = "%time"
ALFA_TOPICS: dict[str, tuple[str, list[str]]] = {  # key: (file name suffix, fields read)
    "imu": ("mavros-imu-data", [f"field.orientation.{c}" for c in "wxyz"]),
    "gyro": ("mavros-imu-data_raw", ["field.angular_velocity.y"]),
    "odom": ("mavros-local_position-odom",
             ["field.twist.twist.linear.x", "field.twist.twist.linear.z"]),
    "servo": ("mavros-rc-out", ["field.channels1"]),
    "hud": ("mavros-vfr_hud", ["field.throttle"]),
    "nav": ("mavros-nav_info-pitch", ["field.measured"]),
}
ALFA_GRID_TOPICS = ("imu", "gyro", "odom", "servo", "hud")  # the grid spans their common time
ALFA_PWM_RANGE = (1178.0, 1593.0)  # servo 2 (elevator) PWM of -30 .. +30 deg (inferred)


class _AlfaTopic:
    """One MAVROS topic CSV: its path, integer-nanosecond receive times and the fields read."""

    def __init__(self, path: Path, t_ns: np.ndarray, vals: np.ndarray) -> None:
        self.path, self.t_ns, self.vals = path, t_ns, vals


def _alfa_file(folder: Path, root: Path, suffix: str) -> Path:
    """The one ``*-<suffix>.csv`` file of the folder, which must resolve inside it."""
    end = f"-{suffix}.csv"
    try:
        matches = sorted(p for p in folder.iterdir() if p.name.endswith(end))
    except OSError as exc:
        raise FlightDataError(f"cannot list the ALFA folder ({exc.strerror or exc})",
                              folder) from None
    if not matches:
        raise FlightDataError(f"no '*{end}' file in the ALFA folder", folder)
    if len(matches) > 1:
        raise FlightDataError(f"several files match '*{end}' "
                              f"({', '.join(p.name for p in matches)}): ambiguous", folder)
    path = matches[0]
    real = Path(os.path.realpath(path))
    if real != root and root not in real.parents:
        raise FlightDataError(f"resolves to {real}, outside the ALFA folder {root}: refused",
                              path)
    return path


def _alfa_topic(folder: Path, root: Path, suffix: str, fields: list[str]) -> _AlfaTopic:
    """Read the fields of one topic CSV (``rostopic echo -p`` layout) with every check: text,
    header, one value per column in every row, integer strictly increasing ``%time``, finite
    numbers, at least 2 rows."""
    path = _alfa_file(folder, root, suffix)
    raw = _read_regular(path, MAX_ALFA_CSV_BYTES)
    if not raw.strip():
        raise FlightDataError("empty file: expected a header row and data rows", path)
    nul = raw.find(b"\x00")
    if nul >= 0:
        raise FlightDataError(f"not a text CSV file (NUL byte at offset {nul})", path)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FlightDataError(f"not a text CSV file (byte 0x{raw[exc.start]:02x} at offset "
                              f"{exc.start} is not UTF-8)", path) from None
    del raw
    reader = csv.reader(io.StringIO(text, newline=""))
    times: list[int] = []
    rows: list[list[float]] = []
    try:
        header = next(reader)
        ncol = len(header)
        for f in [ALFA_TIME, *fields]:
            if f not in header:
                raise FlightDataError(f"missing column '{f}'", path, line=1, column=f)
            if header.count(f) > 1:
                raise FlightDataError(f"column '{f}' appears {header.count(f)} times in the "
                                      "header", path, line=1, column=f)
        i_time = header.index(ALFA_TIME)
        i_fields = [header.index(f) for f in fields]
        blank = None
        for r, row in enumerate(reader, start=1):
            if not row:
                blank = blank or (r, reader.line_num)
                continue
            if blank is not None:
                raise FlightDataError("blank line inside the data", path, blank[0],
                                      line=blank[1])
            if len(row) != ncol:
                raise FlightDataError(f"has {len(row)} fields, the header has {ncol}", path, r,
                                      line=reader.line_num)
            stamp = row[i_time]
            if not (stamp.isascii() and stamp.isdigit() and len(stamp) <= 19
                    and int(stamp) < 2**63):
                raise FlightDataError(f"cannot read {stamp[:40]!r} as integer nanoseconds",
                                      path, r, ALFA_TIME, line=reader.line_num)
            values = []
            for f, i in zip(fields, i_fields):
                try:
                    v = float(row[i])
                except ValueError:
                    raise FlightDataError(f"cannot read {row[i][:40]!r} as a number", path, r,
                                          f, line=reader.line_num) from None
                if not math.isfinite(v):
                    raise FlightDataError(f"value {v} is not finite", path, r, f,
                                          line=reader.line_num)
                values.append(v)
            times.append(int(stamp))
            rows.append(values)
    except csv.Error as exc:
        raise FlightDataError(f"malformed CSV ({exc})", path, line=reader.line_num) from None
    except StopIteration:  # pragma: no cover - raw.strip() was non-empty, so a header exists
        raise FlightDataError("empty file", path) from None
    if not rows:
        raise FlightDataError("no data rows after the header", path)
    if len(rows) < 2:
        raise FlightDataError("only 1 data row; need at least 2 to resample onto the grid",
                              path)
    t_ns = np.array(times, dtype=np.int64)
    back = np.flatnonzero(np.diff(t_ns) <= 0)
    if len(back):
        k = int(back[0]) + 1
        raise FlightDataError(f"time {int(t_ns[k])} ns is not after the previous row's "
                              f"{int(t_ns[k - 1])} ns (time must strictly increase)", path,
                              k + 1, ALFA_TIME)
    return _AlfaTopic(path, t_ns, np.array(rows, dtype=float))


def _check_alfa_ranges(topics: dict[str, _AlfaTopic]) -> None:
    """Source values the mapping cannot take: elevator PWM outside the servo range of +-30
    deg, throttle outside 0..1 (named in their file, not as resampled grid rows)."""
    for key, column, (lo, hi), unit in (("servo", "field.channels1", ALFA_PWM_RANGE, " us"),
                                        ("hud", "field.throttle", (0.0, 1.0), "")):
        v = topics[key].vals[:, 0]
        out = np.flatnonzero((v < lo) | (v > hi))
        if len(out):
            k = int(out[0])
            raise FlightDataError(f"value {v[k]:g}{unit} is outside the range {lo:g}-{hi:g}"
                                  f"{unit} this importer maps", topics[key].path, k + 1, column)


def _check_alfa_overlap(topics: dict[str, _AlfaTopic], rel: dict[str, np.ndarray]) -> None:
    """Every grid topic must overlap every other in time; the error names the topic that
    overlaps the fewest others (the shifted or stray file), and one it misses."""
    def overlap(a: str, b: str) -> bool:
        return max(rel[a][0], rel[b][0]) < min(rel[a][-1], rel[b][-1])

    misses = {k: [j for j in ALFA_GRID_TOPICS if j != k and not overlap(k, j)]
              for k in ALFA_GRID_TOPICS}
    if not any(misses.values()):
        return
    culprit = max(ALFA_GRID_TOPICS, key=lambda k: (len(misses[k]), rel[k][0]))
    other = misses[culprit][0]
    raise FlightDataError(
        f"no time span in common with {topics[other].path.name}: this topic's rows span "
        f"{rel[culprit][0]:.3f}-{rel[culprit][-1]:.3f} s, that one's {rel[other][0]:.3f}-"
        f"{rel[other][-1]:.3f} s (from the earliest first row)", topics[culprit].path,
        column=ALFA_TIME)


def import_alfa(folder: str | Path, rate_hz: float = 10.0, name: str | None = None, *,
                check: bool = True, kinematic: bool = False) -> Sortie:
    """Read an ALFA sequence folder (MAVROS CSV topics, ENU/FLU frames) as a fixed-wing
    :class:`Sortie`.

    Pitch from the IMU quaternion (nose-up = -pitch of the ENU/FLU quaternion), q = -raw gyro
    y, u = odometry twist x, w = -twist z, elevator from servo channel 2 PWM (1178-1593 us
    mapped linearly to +-30 deg, PWM above centre = positive, nose-down elevator: an inference
    from the data README, consistent with the command's negative correlation with pitch rate,
    not a documented mapping), throttle from ``vfr_hud.throttle``. Signals are resampled onto
    a uniform grid over the time all five topics share (states linear, controls held).
    ``meta['nav_pitch']`` keeps the autopilot's logged Euler pitch on the same grid.

    Parameters
    ----------
    folder : str or Path
        The sequence folder; each topic is its one ``*-<topic>.csv`` file, which must be a
        regular file (at most ``MAX_ALFA_CSV_BYTES``) inside the folder.
    rate_hz : float
        Grid rate in (0, ``MAX_RATE_HZ``] (default 10 Hz; the topics are logged at 2.5-19 Hz).
    name : str, optional
        Sortie name (default: the folder name).
    check : bool
        Run :func:`check_values` on the result (default True).
    kinematic : bool
        Include the pitch-plane kinematic check (default False: the flight has banked turns,
        roll up to 55 deg, where d theta/dt = q cos(roll) - r sin(roll) is not q, so the real
        sequence fails it, as it should).

    Returns
    -------
    Sortie

    Raises
    ------
    FlightDataError
        One line naming the folder or the topic CSV (and its row and column where they
        apply): missing, ambiguous, escaping or non-regular topic files, malformed CSV,
        non-numeric or non-finite values, non-increasing time, topics without a common time
        span, bad options, failed value checks.
    """
    folder = _as_path(folder, "folder")
    _check_rate(rate_hz, folder, allow_none=False)
    _check_name(name, folder)
    _check_bool(check, "check", folder)
    _check_bool(kinematic, "kinematic", folder)
    try:
        st = os.stat(folder)
    except (OSError, ValueError) as exc:  # ValueError: a NUL byte in the path
        what = "not found" if isinstance(exc, FileNotFoundError) else f"cannot access it: {exc}"
        raise FlightDataError(f"not an ALFA sequence folder ({what})", folder) from None
    if not stat.S_ISDIR(st.st_mode):
        raise FlightDataError("not an ALFA sequence folder (not a folder)", folder)
    root = Path(os.path.realpath(folder))
    topics = {key: _alfa_topic(folder, root, suffix, fields)
              for key, (suffix, fields) in ALFA_TOPICS.items()}
    imu = topics["imu"]
    norm = np.linalg.norm(imu.vals, axis=1)
    bad = np.flatnonzero(np.abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE)
    if len(bad):
        k = int(bad[0])
        raise FlightDataError(f"orientation (w, x, y, z) has norm {norm[k]:.6g}, not a unit "
                              "quaternion", imu.path, k + 1, "field.orientation")
    _check_alfa_ranges(topics)
    origin = min(int(tp.t_ns[0]) for tp in topics.values())
    rel = {key: (tp.t_ns - origin) * 1e-9 for key, tp in topics.items()}
    _check_alfa_overlap(topics, rel)
    t0 = max(float(rel[k][0]) for k in ALFA_GRID_TOPICS)
    t1 = min(float(rel[k][-1]) for k in ALFA_GRID_TOPICS)
    rate_hz = float(rate_hz)
    grid = _grid(t0, t1, rate_hz, folder)
    n = len(grid)
    quat = _quaternions_on_grid(grid, rel["imu"], imu.vals)
    theta = -pitch_from_quaternion(quat)  # ENU/FLU quaternion: nose-up pitch is its negative
    q = -_interp(grid, rel["gyro"], topics["gyro"].vals)[:, 0]
    vel = _interp(grid, rel["odom"], topics["odom"].vals)
    pwm = _hold(grid, rel["servo"], topics["servo"].vals)[:, 0]
    lo, hi = ALFA_PWM_RANGE
    max_defl = CONTROL_BOUNDS["fixed_wing"][0][1]
    elevator = (pwm - 0.5 * (lo + hi)) / (0.5 * (hi - lo)) * max_defl
    throttle = _hold(grid, rel["hud"], topics["hud"].vals)[:, 0]
    states = np.column_stack([vel[:, 0], -vel[:, 1], q, theta])
    controls = np.column_stack([elevator, throttle])
    time = np.arange(n) / rate_hz
    if check:
        _checked(folder, "fixed_wing", time, states, controls, rate_hz, kinematic)
    meta = {"file": str(folder), "source": "ALFA (MAVROS CSV)",
            "files": {key: str(tp.path) for key, tp in topics.items()},
            "start_time_s": origin * 1e-9 + t0, "rate_hz": rate_hz,
            "nav_pitch": np.radians(_interp(grid, rel["nav"], topics["nav"].vals)[:, 0]),
            "checked": {"values": check, "kinematic": bool(check and kinematic)},
            "sources": {"theta": "-pitch(mavros-imu-data orientation)",
                        "q": "-mavros-imu-data_raw angular_velocity.y",
                        "u,w": "mavros-local_position-odom twist x, -z",
                        "elevator": "rc-out channels1 PWM (inferred mapping)",
                        "throttle": "vfr_hud.throttle"}}
    return Sortie(name=name or root.name, kind="fixed_wing", time=time, states=states,
                  controls=controls, mission="alfa", meta=meta)
