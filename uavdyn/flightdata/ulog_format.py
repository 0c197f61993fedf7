"""Reading a PX4 ULog file: header and message-framing checks, then pyulog's parse.

Only a regular file within :data:`MAX_ULOG_BYTES` is read. Before pyulog (the optional
dependency) parses anything, the framing is walked: a cut file (its last message incomplete)
is refused unless asked for, format definitions are bounded, and the data messages of each
imported topic are counted, so that a parse that stopped early at a malformed message, or a
file pyulog flags as corrupt, raises :class:`FlightDataError`. A ULog cut exactly at a message
boundary cannot be told from a shorter log: the format has no end marker.
"""

from __future__ import annotations

import io
import struct
import threading
from pathlib import Path

from uavdyn.flightdata.errors import FlightDataError
from uavdyn.flightdata.files import _read_regular

try:  # optional dependency; imported here so that no module is loaded during an import
    import pyulog as _pyulog
except ImportError:  # pragma: no cover - depends on the environment
    _pyulog = None

MAX_ULOG_BYTES = 2 * 1024**3        # refuse larger ULog files before reading them
MAX_TOPIC_FIELDS = 65_536           # flattened fields of one ULog topic (PX4: a few hundred)
MAX_TOTAL_FIELDS = 2_000_000        # summed over all subscriptions of one ULog
MAX_FORMAT_DEPTH = 32               # nesting of ULog formats (PX4: at most 3)
ULOG_MAGIC = b"ULog\x01\x12\x35"
ULOG_VERSIONS = (0, 1)
ULOG_TOPICS = ("vehicle_attitude", "vehicle_angular_velocity", "sensor_combined",
               "vehicle_local_position", "actuator_controls_0", "actuator_controls_1",
               "vehicle_thrust_setpoint", "vehicle_torque_setpoint", "actuator_motors",
               "vehicle_global_position", "vehicle_land_detected", "airspeed",
               "airspeed_validated", "wind", "wind_estimate", "vehicle_status")
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


def _read_ulog(path: Path, allow_truncated: bool):
    """Read and parse the ULog file ``path`` (pyulog needed); returns ``(ulog, truncated_at,
    parser_messages)`` as :func:`_parse_ulog`."""
    _require_pyulog()
    raw = _read_regular(path, path, MAX_ULOG_BYTES)
    return _parse_ulog(raw, path, allow_truncated)


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
