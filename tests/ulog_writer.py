"""A small writer of PX4 ULog files, so that the ULog importer can be tested on logs whose
content is known exactly instead of on real logs that live outside the repository.

Layout written (PX4 "ULog file format", little endian throughout):

* file header, 16 bytes: magic ``55 4c 6f 67 01 12 35`` ("ULog" 01 12 35), version byte,
  uint64 start timestamp (microseconds);
* every message: uint16 payload size, uint8 type, then the payload;
* definitions section: ``B`` flag bits (8 compat bytes, 8 incompat bytes, 3 uint64 appended
  offsets; all zero here), ``I`` info and ``P`` initial parameters (uint8 key length, key
  ``"<type> <name>"``, raw value), ``F`` formats (``"name:type field;type[n] field;..."``);
* data section: one ``A`` (uint8 multi_id, uint16 msg_id, topic name) per topic, then ``D``
  messages (uint16 msg_id, packed fields in format order) of all topics merged in timestamp
  order, as the PX4 logger writes them (so a cut file loses the end of every topic).

Strings carry no terminating NUL. Only what the importer tests need is supported: flat topics
(no nested types), scalar and fixed-size array fields of the basic numeric types.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from pathlib import Path

import numpy as np

MAGIC = b"ULog\x01\x12\x35"
FILE_VERSION = 1

# numpy dtype -> ULog basic type name (the ULog type of a field follows its array's dtype)
ULOG_TYPES: dict[np.dtype, str] = {
    np.dtype(np.int8): "int8_t", np.dtype(np.uint8): "uint8_t",
    np.dtype(np.int16): "int16_t", np.dtype(np.uint16): "uint16_t",
    np.dtype(np.int32): "int32_t", np.dtype(np.uint32): "uint32_t",
    np.dtype(np.int64): "int64_t", np.dtype(np.uint64): "uint64_t",
    np.dtype(np.float32): "float", np.dtype(np.float64): "double",
    np.dtype(np.bool_): "bool",
}

TopicKey = str | tuple[str, int]  # topic name, or (name, multi_id) for a further instance


def _message(kind: bytes, payload: bytes) -> bytes:
    """One ULog message: 3-byte header (uint16 payload size, uint8 type) and payload."""
    if len(payload) > 0xFFFF:
        raise ValueError(f"ULog message '{kind.decode()}' too long ({len(payload)} bytes)")
    return struct.pack("<HB", len(payload), kind[0]) + payload


def _key_value(type_name: str, name: str, value: bytes) -> bytes:
    """Payload of the info and parameter messages: key length, ``"<type> <name>"``, value."""
    key = f"{type_name} {name}".encode()
    if len(key) > 0xFF:
        raise ValueError(f"ULog key too long: {key!r}")
    return bytes([len(key)]) + key + value


def _info(name: str, value: str) -> bytes:
    raw = value.encode()
    return _message(b"I", _key_value(f"char[{len(raw)}]", name, raw))


def _parameter(name: str, value: float | int) -> bytes:
    """``P`` message: Python ints are written as ``int32_t`` (PX4 integer parameters such as
    MAV_TYPE), everything else as ``float`` (PX4 float parameters)."""
    if isinstance(value, (bool, np.bool_)):
        raise TypeError(f"parameter {name}: PX4 parameters are int32 or float, not bool")
    if isinstance(value, (int, np.integer)):
        return _message(b"P", _key_value("int32_t", name, struct.pack("<i", int(value))))
    return _message(b"P", _key_value("float", name, struct.pack("<f", float(value))))


def _split_key(key: TopicKey) -> tuple[str, int]:
    return (key, 0) if isinstance(key, str) else (str(key[0]), int(key[1]))


def _topic_layout(name: str, fields: Mapping[str, np.ndarray]
                  ) -> tuple[str, np.dtype, dict[str, np.ndarray]]:
    """The format string, the packed record dtype and the checked arrays of one topic.

    ``timestamp`` goes first (uint64 microseconds); a 2-D ``N x k`` array becomes the array
    field ``type[k] name`` (ULog readers expose it as ``name[0]`` ... ``name[k-1]``)."""
    if "timestamp" not in fields:
        raise ValueError(f"topic '{name}' has no 'timestamp' field")
    stamps = np.asarray(fields["timestamp"])
    if stamps.ndim != 1 or not np.issubdtype(stamps.dtype, np.integer):
        raise ValueError(f"topic '{name}': timestamp must be a 1-D integer array (us)")
    if np.any(stamps < 0):
        raise ValueError(f"topic '{name}': negative timestamps")
    arrays = {"timestamp": stamps.astype(np.uint64)}
    arrays.update({k: np.asarray(v) for k, v in fields.items() if k != "timestamp"})
    n = len(stamps)
    parts, dtype = [], []
    for field, a in arrays.items():
        if a.dtype not in ULOG_TYPES:
            raise ValueError(f"topic '{name}', field '{field}': unsupported dtype {a.dtype}")
        if a.ndim not in (1, 2) or a.shape[0] != n:
            raise ValueError(f"topic '{name}', field '{field}': shape {a.shape}, expected "
                             f"({n},) or ({n}, k) like the timestamps")
        base = ULOG_TYPES[a.dtype]
        if a.ndim == 1:
            parts.append(f"{base} {field}")
            dtype.append((field, a.dtype.newbyteorder("<")))
        else:
            parts.append(f"{base}[{a.shape[1]}] {field}")
            dtype.append((field, a.dtype.newbyteorder("<"), (a.shape[1],)))
    return f"{name}:" + "".join(p + ";" for p in parts), np.dtype(dtype), arrays


def write_ulog(path: str | Path, topics: Mapping[TopicKey, Mapping[str, np.ndarray]],
               params: Mapping[str, float | int] | None = None,
               info: Mapping[str, str] | None = None, start_us: int = 0,
               flag_bits: bool = True, merge: bool = True) -> Path:
    """Write a ULog file (the bytes of :func:`ulog_bytes`) and return its path."""
    path = Path(path)
    path.write_bytes(ulog_bytes(topics, params, info, start_us, flag_bits, merge))
    return path


def ulog_bytes(topics: Mapping[TopicKey, Mapping[str, np.ndarray]],
               params: Mapping[str, float | int] | None = None,
               info: Mapping[str, str] | None = None, start_us: int = 0,
               flag_bits: bool = True, merge: bool = True) -> bytes:
    """The bytes of a ULog file, built in memory (the fuzz cases mutate them).

    ``topics`` maps a topic name (or ``(name, multi_id)``) to its fields: ``timestamp``
    (integer microseconds) and named 1-D or ``N x k`` arrays whose dtype gives the ULog type
    (float32 -> ``float``, float64 -> ``double``, ...). ``params`` become the initial
    parameters (int -> int32_t, float -> float), ``info`` string info messages; ``start_us``
    is the header's start timestamp. Instances of one topic name share one format, so their
    fields must agree. ``merge``: the samples of all topics in timestamp order, as a logger
    writes them; False: each topic's samples in the order given, topic after topic (to write
    samples whose timestamps go backwards)."""
    params = dict(params or {})
    info = dict(info or {})
    formats: dict[str, str] = {}
    subscriptions = []  # (name, multi_id, packed records, timestamps)
    for key, fields in topics.items():
        name, multi_id = _split_key(key)
        fmt, dtype, arrays = _topic_layout(name, fields)
        if formats.setdefault(name, fmt) != fmt:
            raise ValueError(f"instances of topic '{name}' have different fields")
        records = np.zeros(len(arrays["timestamp"]), dtype=dtype)
        for field, a in arrays.items():
            records[field] = a
        subscriptions.append((name, multi_id, records, arrays["timestamp"]))

    out = [MAGIC, bytes([FILE_VERSION]), struct.pack("<Q", int(start_us))]
    if flag_bits:  # must be the first message after the header
        out.append(_message(b"B", bytes(16) + struct.pack("<3Q", 0, 0, 0)))
    out += [_info(k, v) for k, v in info.items()]
    out += [_parameter(k, v) for k, v in params.items()]
    out += [_message(b"F", fmt.encode()) for fmt in formats.values()]
    for msg_id, (name, multi_id, _, _) in enumerate(subscriptions):
        out.append(_message(b"A", struct.pack("<BH", multi_id, msg_id) + name.encode()))

    # merge the samples of all topics in timestamp order (stable: topic order breaks ties)
    stamps = np.concatenate([s[3] for s in subscriptions]) if subscriptions else np.zeros(0)
    owner = np.concatenate([np.full(len(s[3]), i) for i, s in enumerate(subscriptions)]
                           ) if subscriptions else np.zeros(0, int)
    row = np.concatenate([np.arange(len(s[3])) for s in subscriptions]
                         ) if subscriptions else np.zeros(0, int)
    for k in (np.argsort(stamps, kind="stable") if merge else range(len(stamps))):
        msg_id = int(owner[k])
        record = subscriptions[msg_id][2][row[k]].tobytes()
        out.append(_message(b"D", struct.pack("<H", msg_id) + record))

    return b"".join(out)
