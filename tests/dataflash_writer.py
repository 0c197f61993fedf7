"""A minimal ArduPilot DataFlash (.bin) writer, so tests can build logs with known content.

The format (ArduPilot's ``AP_Logger/LogStructure.h``, read by pymavlink's ``DFReader``): each
message is the header bytes 0xA3 0x95, a type byte, then the little-endian packed payload.
Type 128 is FMT (``Type B, Length B, Name n, Format N, Columns Z``), which defines every other
type: its format characters give the payload layout, scaled ones (``c C e E L``) holding the
value times 100 (``L``: times 1e7).
"""

from __future__ import annotations

import struct
from pathlib import Path

HEAD = b"\xa3\x95"
FMT_TYPE = 128
# format character: (struct code, scale the written integer carries)
FORMAT_TO_STRUCT = {
    "a": ("64s", None), "b": ("b", None), "B": ("B", None), "h": ("h", None),
    "H": ("H", None), "i": ("i", None), "I": ("I", None), "f": ("f", None),
    "d": ("d", None), "n": ("4s", None), "N": ("16s", None), "Z": ("64s", None),
    "c": ("h", 100), "C": ("H", 100), "e": ("i", 100), "E": ("I", 100), "L": ("i", 1e7),
    "M": ("b", None), "q": ("q", None), "Q": ("Q", None), "g": ("e", None),
}
FMT_FORMAT, FMT_COLUMNS = "BBnNZ", "Type,Length,Name,Format,Columns"


class DataFlashWriter:
    """Builds a DataFlash log in memory: :meth:`define` each message, then :meth:`write`."""

    def __init__(self) -> None:
        self._defs: dict[str, tuple[int, str, list[str], struct.Struct]] = {}
        self._out = bytearray()
        self._next_type = FMT_TYPE + 1
        self._define(FMT_TYPE, "FMT", FMT_FORMAT, FMT_COLUMNS)

    def _define(self, type_id: int, name: str, fmt: str, columns: str) -> None:
        packer = struct.Struct("<" + "".join(FORMAT_TO_STRUCT[c][0] for c in fmt))
        self._defs[name] = (type_id, fmt, columns.split(","), packer)
        self.write("FMT", Type=type_id, Length=3 + packer.size, Name=name, Format=fmt,
                   Columns=columns)

    def define(self, name: str, fmt: str, columns: str) -> DataFlashWriter:
        """Define message ``name`` (ArduPilot format characters, comma-separated columns)."""
        if len(fmt) != len(columns.split(",")):
            raise ValueError(f"{name}: {len(fmt)} format characters, "
                             f"{len(columns.split(','))} columns")
        self._define(self._next_type, name, fmt, columns)
        self._next_type += 1
        return self

    def write(self, name: str, **values: float | int | str) -> None:
        """One message; a column not given is written as zero (or an empty string)."""
        type_id, fmt, columns, packer = self._defs[name]
        unknown = set(values) - set(columns)
        if unknown:
            raise KeyError(f"{name} has no column {sorted(unknown)}")
        packed = []
        for c, col in zip(fmt, columns):
            v = values.get(col, 0)
            code, scale = FORMAT_TO_STRUCT[c]
            if code.endswith("s"):
                packed.append(str(v or "").encode())
            elif scale is not None:
                packed.append(int(round(float(v) * scale)))
            elif code in "fde":
                packed.append(float(v))
            else:
                packed.append(int(round(v)))
        self._out += HEAD + bytes([type_id]) + packer.pack(*packed)

    def to_bytes(self) -> bytes:
        """The log so far."""
        return bytes(self._out)

    def save(self, path: str | Path) -> Path:
        """Write the log to ``path``."""
        path = Path(path)
        path.write_bytes(self.to_bytes())
        return path
