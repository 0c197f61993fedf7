"""Reading a PX4 ULog file: header and message-framing checks, then pyulog's parse.

Only a regular file within :data:`MAX_ULOG_BYTES` is read. Before pyulog (the optional
dependency) parses anything, the framing is walked: a cut file (its last message incomplete)
is refused unless asked for, format definitions are bounded, and the data messages of each
imported topic are counted, so that a parse that stopped early at a malformed message, or a
file pyulog flags as corrupt, raises :class:`FlightDataError`; so does a data message whose
size is not its format's or whose id no subscription defined (flipped bytes), with its byte
offset. A ULog cut exactly at a message boundary cannot be told from a shorter log (the
format has no end marker and no per-topic counts): :func:`log_content` reports the messages
read per topic, the logger's dropouts and a topic whose data end early.
"""

from __future__ import annotations

import io
import re
import struct
import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

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
_ULOG_TYPE_BYTES = {"int8_t": 1, "uint8_t": 1, "int16_t": 2, "uint16_t": 2, "int32_t": 4,
                    "uint32_t": 4, "int64_t": 8, "uint64_t": 8, "float": 4, "double": 8,
                    "bool": 1, "char": 1}
_ULOG_BASIC_TYPES = set(_ULOG_TYPE_BYTES)
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
    parser_messages, framing)`` as :func:`_parse_ulog`."""
    _require_pyulog()
    raw = _read_regular(path, path, MAX_ULOG_BYTES)
    return _parse_ulog(raw, path, allow_truncated)


def _format_fields(payload: bytes) -> tuple[str, list[tuple[str, int, str]]] | None:
    """``(name, [(type, count, field name), ...])`` of an ``F`` message, or None if it does
    not parse (pyulog then flags the corruption)."""
    text = payload.decode("utf-8", "ignore")
    if ":" not in text:
        return None
    name, _, body = text.partition(":")
    fields = []
    for part in body.split(";"):
        if not part:
            continue
        type_str, _, field_name = part.partition(" ")
        count = 1
        if "[" in type_str:
            base, _, rest = type_str.partition("[")
            try:
                count = max(int(rest.partition("]")[0]), 1)
            except ValueError:
                return None
            type_str = base
        fields.append((type_str, count, field_name.strip()))
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
    for type_name, count, _ in formats.get(name, ()):
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


@dataclass
class Framing:
    """What the walk over the message framing found: where a cut last message starts (None
    when the messages tile the file), and per imported topic instance its data messages
    (count, byte offsets, payload sizes); the first data message whose id no subscription
    defined."""

    truncated_at: int | None = None
    counts: dict[tuple[str, int], int] = field(default_factory=dict)
    offsets: dict[tuple[str, int], list[int]] = field(default_factory=dict)
    sizes: dict[tuple[str, int], list[int]] = field(default_factory=dict)
    unknown_id_at: int | None = None


def _appended_offsets(raw: bytes, path: Path) -> list[int]:
    """The appended-data offsets of the flag-bits message (rare; none in most logs)."""
    n = len(raw)
    if n >= 19 + 40 and raw[18:19] == b"B":
        size = struct.unpack_from("<H", raw, 16)[0]
        if size >= 40 and raw[19 + 8] & 1:
            appended = [o for o in struct.unpack_from("<3Q", raw, 19 + 16) if o]
            if any(not 16 < o <= n for o in appended) or appended != sorted(appended):
                raise FlightDataError(f"corrupt ULog flag bits: appended-data offsets "
                                      f"{appended} outside the file of {n} bytes", path)
            return appended
    return []


def _scan_ulog(raw: bytes, path: Path) -> Framing:
    """Walk the ULog message framing before pyulog parses anything.

    Checks the format definitions against field-count bounds and the size of every data
    message of an imported topic against its format (:func:`_check_sizes`); records where
    an incomplete last message starts (a cut file) and each imported topic's data messages,
    to compare with what pyulog reads (it stops silently at some malformed messages)."""
    n = len(raw)
    appended = _appended_offsets(raw, path)
    formats: dict[str, list[tuple[str, int, str]]] = {}
    subscribed: list[str] = []
    msg_ids: dict[int, tuple[str, int] | None] = {}
    found = Framing()
    pos = 16
    for end in [*appended, n]:
        while pos < end:
            if pos + 3 > n:
                found.truncated_at = pos
                break
            size, kind = struct.unpack_from("<HB", raw, pos)
            if pos + 3 + size > n:
                found.truncated_at = pos
                break
            if pos + 3 + size > end:
                break  # crosses into appended data: pyulog stops this part here too
            if kind == ord("D") and size >= 2:
                msg_id = struct.unpack_from("<H", raw, pos + 3)[0]
                key = msg_ids.get(msg_id)
                if key is not None:
                    found.counts[key] += 1
                    found.offsets[key].append(pos)
                    found.sizes[key].append(size - 2)
                elif msg_id not in msg_ids and found.unknown_id_at is None:
                    found.unknown_id_at = pos
            elif kind == ord("F"):
                parsed = _format_fields(raw[pos + 3:pos + 3 + size])
                if parsed is not None:
                    formats[parsed[0]] = parsed[1]
            elif kind == ord("A") and size > 3:
                topic = raw[pos + 6:pos + 3 + size].decode("utf-8", "ignore")
                subscribed.append(topic)
                key = (topic, raw[pos + 3]) if topic in ULOG_TOPICS else None
                msg_ids[struct.unpack_from("<H", raw, pos + 4)[0]] = key
                if key is not None:
                    found.counts.setdefault(key, 0)
                    found.offsets.setdefault(key, [])
                    found.sizes.setdefault(key, [])
            pos += 3 + size
        if found.truncated_at is not None:
            break
        pos = max(pos, end)
    memo: dict[str, int | None] = {}
    total = 0
    for name in subscribed:
        total += _flat_size(name, formats, memo, 0, path) if name in formats else 0
        if total > MAX_TOTAL_FIELDS:
            raise FlightDataError(f"corrupt ULog: the subscriptions expand to more than "
                                  f"{MAX_TOTAL_FIELDS} fields", path)
    _check_framing(found, formats, path)
    return found


def _byte_size(name: str, formats: dict, depth: int = 0) -> int | None:
    """Bytes of one message of format ``name`` (nested formats included), or None when a
    type is unknown (pyulog flags that itself). The depth is bounded by :func:`_flat_size`."""
    total = 0
    for type_name, count, _ in formats.get(name, ()):
        if type_name in _ULOG_TYPE_BYTES:
            total += _ULOG_TYPE_BYTES[type_name] * count
        elif type_name in formats and depth < MAX_FORMAT_DEPTH:
            inner = _byte_size(type_name, formats, depth + 1)
            if inner is None:
                return None
            total += inner * count
        else:
            return None
    return total


def _check_framing(found: Framing, formats: dict, path: Path) -> None:
    """Refuse a data message with an id no subscription defined, or an imported topic's data
    message whose size is not its format's (less at most the trailing padding, which the
    PX4 logger may leave out): flipped bytes in a message header, named by byte offset."""
    if found.unknown_id_at is not None:
        raise FlightDataError(f"corrupt ULog file: the data message at byte "
                              f"{found.unknown_id_at} has a message id no subscription "
                              "defined (flipped or overwritten bytes)", path)
    for (topic, multi_id), sizes in found.sizes.items():
        full = _byte_size(topic, formats)
        if full is None or not sizes:
            continue
        padding = 0
        for type_name, count, name in reversed(formats.get(topic, [])):
            if not name.startswith("_padding") or type_name not in _ULOG_TYPE_BYTES:
                break
            padding += _ULOG_TYPE_BYTES[type_name] * count
        sizes_arr = np.asarray(sizes)
        bad = np.flatnonzero((sizes_arr > full) | (sizes_arr < full - padding))
        if len(bad):
            k = int(bad[0])
            raise FlightDataError(
                f"corrupt ULog file: data message {k + 1} of topic {topic} (instance "
                f"{multi_id}) at byte {found.offsets[(topic, multi_id)][k]} has "
                f"{int(sizes_arr[k])} bytes, its format {full}", path,
                column=f"{topic}.message")


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
    ``(ulog, truncated_at, parser_messages, framing)`` (:class:`Framing`)."""
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
    framing = _scan_ulog(raw, path)
    truncated_at, counts = framing.truncated_at, framing.counts
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
    return ulog, truncated_at, messages, framing


END_GAP_MIN_S = 1.0        # a topic ending this long before the log's last sample is a gap,
END_GAP_INTERVALS = 10     # or this many of its own sample intervals, whichever is longer


def topic_names(sources) -> list[str]:
    """The imported topics named in channel-source descriptions.

    Parameters
    ----------
    sources : iterable of str
        Descriptions such as ``actuator_controls_0.control[3]``,
        ``-vehicle_thrust_setpoint.xyz[2]``, ``mean of actuator_motors.control[0..3]``.

    Returns
    -------
    list of str
        The topic names of :data:`ULOG_TOPICS` among them, sorted.
    """
    return sorted({t for text in sources for t in re.findall(r"([a-z][a-z0-9_]*)\.", text)
                   if t in ULOG_TOPICS})


def log_content(ulog, used: list[str]) -> dict:
    """What was read of the log, for the import report and the manifest's provenance.

    ULog keeps no per-topic message counts, so ``messages_read`` counts the data messages of
    each imported topic (``name`` or ``name[instance]``) as read; ``dropouts`` are the
    logger's own record of lost data (``O`` messages). ``warnings`` name a used topic whose
    data end well before the log's last sample (more than :data:`END_GAP_MIN_S` and
    :data:`END_GAP_INTERVALS` of its intervals: a gap at the end, e.g. a log cut or a
    sensor lost), and any dropouts.

    Parameters
    ----------
    ulog : pyulog.ULog
        The parsed log.
    used : list of str
        The topics the import used (only these are judged for a gap at the end).

    Returns
    -------
    dict
        ``messages_read`` (topic -> count), ``dropouts`` (``count``, ``total_ms``) and
        ``warnings`` (one sentence each), merged into the import's ``meta``.
    """
    from uavdyn.flightdata.resample import main_block

    read: dict[str, int] = {}
    ends: dict[str, tuple[float, float]] = {}
    for d in ulog.data_list:
        stamps = d.data.get("timestamp")
        if stamps is None:
            continue
        key = d.name if d.multi_id == 0 else f"{d.name}[{d.multi_id}]"
        read[key] = read.get(key, 0) + len(stamps)
        keep = main_block(stamps)
        if len(keep) >= 2:
            t = np.sort(stamps[keep].astype(np.int64)) * 1e-6
            ends[key] = (float(t[-1]), float(np.median(np.diff(t))))
    warnings = []
    if ends:
        last = max(end for end, _ in ends.values())
        for name in used:
            if name in ends:
                end, step = ends[name]
                if last - end > max(END_GAP_MIN_S, END_GAP_INTERVALS * step):
                    warnings.append(f"topic {name} ends {last - end:.2f} s before the log's "
                                    "last sample (a gap at the end: data lost or the log cut)")
    dropped = [int(getattr(x, "duration", 0)) for x in getattr(ulog, "dropouts", [])]
    if dropped:
        warnings.append(f"the logger recorded {len(dropped)} dropout(s), {sum(dropped)} ms of "
                        "data lost")
    return {"messages_read": dict(sorted(read.items())),
            "dropouts": {"count": len(dropped), "total_ms": sum(dropped)},
            "warnings": warnings}
