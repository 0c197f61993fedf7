"""Bounded, defensive reading of flight-data files as bytes or checked text.

Only regular files are opened (``stat``-ed first, so a FIFO, a device or a folder is refused
without being opened), and a file larger than its bound is refused before any byte is read
(:mod:`uavdyn.safefiles`); every problem becomes a :class:`FlightDataError` naming the file.
"""

from __future__ import annotations

from pathlib import Path

from uavdyn.flightdata.errors import FlightDataError
from uavdyn.safefiles import UnreadableFile, read_regular

_BOM = b"\xef\xbb\xbf"


def _read_regular(shown: Path, real: str | Path, limit: int, what: str = "a regular file",
                  folder_hint: str = "", resolved: bool = False) -> bytes:
    """The bytes of the regular file ``real`` (``shown`` in messages), at most ``limit``
    (:func:`uavdyn.safefiles.read_regular`), or a :class:`FlightDataError` with the reason;
    ``folder_hint`` is added to it when ``real`` is a folder. A ``resolved`` path (symbolic
    links already resolved and checked to stay inside the dataset folder) is not followed
    again if a link appears there meanwhile."""
    try:
        return read_regular(real, limit, what, follow_symlinks=not resolved)
    except UnreadableFile as exc:
        reason = exc.reason + (folder_hint if exc.reason.startswith("is a folder") else "")
        raise FlightDataError(reason, shown) from None


def _utf8_text(raw: bytes, shown: Path, label: str, detail: str = "binary content: ") -> str:
    """``raw`` decoded as UTF-8; a NUL byte or bytes that are not UTF-8 are refused with
    their offset, as ``not a text <label> file (<detail>...)``."""
    nul = raw.find(b"\x00")
    if nul >= 0:
        raise FlightDataError(f"not a text {label} file ({detail}NUL byte at offset {nul})",
                              shown)
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FlightDataError(f"not a text {label} file ({detail}byte "
                              f"0x{raw[exc.start]:02x} at offset {exc.start} is not UTF-8)",
                              shown) from None


def _read_text(shown: Path, real: str | Path, limit: int, what: str, label: str,
               folder_hint: str, resolved: bool) -> tuple[str, bytes]:
    """Bounded read plus the checks every text format shares (BOM, empty, binary, UTF-8);
    ``label`` (CSV, JSON) names the format in messages. Returns the text and its bytes (a
    UTF-8 byte-order mark removed from both; an empty text for a blank file)."""
    raw = _read_regular(shown, real, limit, what, folder_hint, resolved)
    if raw.startswith(_BOM):
        raw = raw[len(_BOM):]
    if not raw.strip():
        return "", raw
    return _utf8_text(raw, shown, label), raw
