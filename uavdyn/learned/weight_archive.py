"""Reading a weight file's container safely: a regular file within a size bound, a zip
archive whose directory is checked before anything is extracted (member count, declared sizes,
no encryption), ``.npy`` members whose headers are checked before any allocation (no object
dtypes, no pickles), and typed readers of single keys (integer, text, real array, JSON info),
each refusing with one line naming the file and the key."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np

from uavdyn.learned.envelope import Envelope, SteadyBox
from uavdyn.safefiles import UnreadableFile, read_regular

MAX_FILE_BYTES = 64 * 2**20          # a weight file is a few kB; refuse before reading more
MAX_UNCOMPRESSED_BYTES = 256 * 2**20  # zip bombs: bound on the members' declared sizes
MAX_MEMBERS = 64
ENVELOPE_KEYS = ("env_low", "env_high", "env_fade")
# (optional, all four or none) the envelope's steady box (SafeConfig.steady_gate): where the
# correction may act in steady flight; a file without them gates as before
STEADY_KEYS = ("env_steady_low", "env_steady_high", "env_steady_inv_fade", "env_steady_rate")


class WeightFileError(ValueError):
    """A weight file is missing, malformed or made for another airframe; the message names the
    file and the offending key."""


def show(value: object, limit: int = 60) -> str:
    """``repr`` of a value from a file, cut to one short line (it may hold anything)."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


# -- reading the container ---------------------------------------------------------------------

def read_npz(path: Path) -> dict[str, np.ndarray]:
    """All arrays of the archive, after the file and zip-directory checks (bounded memory)."""
    raw = _read_regular_file(path)
    if raw[:6] == b"\x93NUMPY":
        raise WeightFileError(f"{path}: is a single .npy array, not a .npz archive of named "
                              "arrays")
    try:
        archive = zipfile.ZipFile(io.BytesIO(raw))
    except (zipfile.BadZipFile, zipfile.LargeZipFile, ValueError, OSError, EOFError) as exc:
        raise WeightFileError(f"{path}: not a .npz (zip) weight file ({_reason(exc)})") from None
    content: dict[str, np.ndarray] = {}
    with archive:
        infos = archive.infolist()
        if len(infos) > MAX_MEMBERS:
            raise WeightFileError(f"{path}: {len(infos)} archive members; a weight file has at "
                                  f"most {MAX_MEMBERS}")
        total, seen = 0, set()
        for info in infos:
            key = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
            if not info.filename.endswith(".npy") or info.is_dir():
                raise WeightFileError(f"{path}: member {show(info.filename)} is not a .npy "
                                      "array")
            if key in seen or key == "":
                raise WeightFileError(f"{path}: key {show(key)} appears twice or is empty")
            total += info.file_size
            if total > MAX_UNCOMPRESSED_BYTES:
                what = (f"declares {info.file_size}" if info.file_size > MAX_UNCOMPRESSED_BYTES
                        else f"brings the archive's declared total to {total}")
                raise WeightFileError(f"{path}: key {show(key)} {what} bytes uncompressed; a "
                                      f"weight file unpacks to at most "
                                      f"{MAX_UNCOMPRESSED_BYTES // 2**20} MB (a zip bomb?)")
            if info.flag_bits & 0x1:
                raise WeightFileError(f"{path}: key {show(key)} is encrypted")
            seen.add(key)
        for info in infos:
            key = info.filename[:-4]
            try:
                with archive.open(info) as member:
                    content[key] = _read_member(path, key, member, info.file_size)
            except WeightFileError:
                raise
            except Exception as exc:  # zlib, CRC, header parsing...: all one line
                raise WeightFileError(f"{path}: key {show(key)} is not a readable .npy array "
                                      f"({_reason(exc)})") from None
    return content


def _read_regular_file(path: Path) -> bytes:
    """The bytes of ``path`` if it is a non-empty regular file within the size bound
    (:func:`uavdyn.safefiles.read_regular`: a FIFO or device is never opened)."""
    try:
        raw = read_regular(path, MAX_FILE_BYTES, "a weight file")
    except UnreadableFile as exc:
        reason = "weight file not found" if exc.missing else exc.reason
        raise WeightFileError(f"{path}: {reason}") from None
    if not raw:
        raise WeightFileError(f"{path}: weight file is empty")
    return raw


def _read_member(path: Path, key: str, member, declared: int) -> np.ndarray:
    """One ``.npy`` member, its header checked before any allocation: no object dtypes, and the
    data it declares must fit in the member's declared size."""
    version = np.lib.format.read_magic(member)
    if version == (1, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_1_0(member)
    elif version == (2, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_2_0(member)
    else:
        raise WeightFileError(f"{path}: key {show(key)} uses .npy format version {version}; "
                              "expected 1.0 or 2.0")
    if dtype.hasobject:
        raise WeightFileError(f"{path}: key {show(key)} holds Python objects (pickled data); a "
                              "weight file holds only numbers and strings")
    count = 1
    for n in shape:
        count *= int(n)
    nbytes = count * dtype.itemsize
    if nbytes > declared:
        raise WeightFileError(f"{path}: key {show(key)} declares shape {shape} ({nbytes} bytes) "
                              f"but its member holds at most {declared}")
    data = member.read(nbytes)
    if len(data) != nbytes:
        raise WeightFileError(f"{path}: key {show(key)} is truncated ({len(data)} of {nbytes} "
                              "bytes)")
    if member.read(1):  # also reaches the end, where zipfile checks the CRC
        raise WeightFileError(f"{path}: key {show(key)} has data past its declared shape")
    if dtype.itemsize == 0:
        return np.zeros(shape, dtype)
    array = np.frombuffer(data, dtype=dtype, count=count)
    return array.reshape(shape, order="F" if fortran else "C").copy()


def _reason(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    text = text if len(text) <= 120 else text[:117] + "..."
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


# -- reading the keys --------------------------------------------------------------------------

def _describe(value: np.ndarray) -> str:
    return f"dtype {value.dtype.str} and shape {value.shape}"


def integer_key(path: Path, content: dict, key: str) -> int:
    value = content[key]
    if value.dtype.kind not in "iu" or value.ndim != 0:
        raise WeightFileError(f"{path}: key '{key}' must be an integer scalar, got "
                              f"{_describe(value)}")
    return int(value)


def text_key(path: Path, content: dict, key: str) -> str:
    value = content[key]
    if value.dtype.kind != "U" or value.ndim != 0:
        raise WeightFileError(f"{path}: key '{key}' must be a text string, got "
                              f"{_describe(value)}")
    return str(value[()])


def real_key(path: Path, content: dict, key: str, ndim: int) -> np.ndarray:
    """A real float64 array of ``ndim`` dimensions, finite: ints widen, while bool, complex,
    strings, records and dates are refused rather than coerced."""
    value = content[key]
    if value.dtype.kind not in "fiu" or value.dtype.fields is not None:
        raise WeightFileError(f"{path}: key '{key}' must hold real numbers, got "
                              f"{_describe(value)}")
    if value.ndim != ndim:
        what = {0: "a scalar", 1: "a vector", 2: "a matrix"}[ndim]
        raise WeightFileError(f"{path}: key '{key}' must be {what} ({ndim}-D), got shape "
                              f"{value.shape}")
    with np.errstate(over="ignore", invalid="ignore"):
        out = value.astype(np.float64)
    if not np.all(np.isfinite(out)):
        raise WeightFileError(f"{path}: key '{key}' contains non-finite values")
    return out


def info_key(path: Path, content: dict) -> dict:
    if "info" not in content:
        return {}
    text = text_key(path, content, "info")
    try:
        info = json.loads(text)
    except (ValueError, RecursionError) as exc:
        detail = exc.msg if isinstance(exc, json.JSONDecodeError) else type(exc).__name__
        raise WeightFileError(f"{path}: key 'info' is not valid JSON ({detail})") from None
    if not isinstance(info, dict):
        raise WeightFileError(f"{path}: key 'info' must be a JSON object, got "
                              f"{type(info).__name__}")
    return info


def envelope_arrays(envelope: Envelope) -> dict[str, np.ndarray]:
    """The keys a weight file stores an envelope (and its steady box, if any) under."""
    arrays = dict(zip(ENVELOPE_KEYS, (envelope.low, envelope.high, envelope.fade)))
    steady = envelope.steady
    if steady is not None:
        arrays.update(zip(STEADY_KEYS, (steady.low, steady.high, steady.inv_fade, steady.rate)))
    return arrays


def _all_or_none(path: Path, content: dict, keys: tuple[str, ...], what: str) -> bool:
    """Whether ``content`` holds the group ``keys`` (refusing a part of it)."""
    present = [k for k in keys if k in content]
    if present and len(present) != len(keys):
        raise WeightFileError(f"{path}: key(s) {sorted(set(keys) - set(present))} missing "
                              f"beside {present}: {what} needs all {len(keys)}")
    return bool(present)


def read_envelope(path: Path, content: dict) -> Envelope | None:
    """The envelope (with its steady box where the file has one), or None without one."""
    if not _all_or_none(path, content, ENVELOPE_KEYS, "the envelope"):
        return None
    steady = None
    if _all_or_none(path, content, STEADY_KEYS, "the steady box"):
        try:
            steady = SteadyBox(*(real_key(path, content, k, 1) for k in STEADY_KEYS))
        except ValueError as exc:
            raise WeightFileError(f"{path}: keys {', '.join(STEADY_KEYS)}: {exc}") from None
    try:
        return Envelope(*(real_key(path, content, k, 1) for k in ENVELOPE_KEYS), steady)
    except ValueError as exc:
        raise WeightFileError(f"{path}: key 'env_low'/'env_high'/'env_fade': {exc}") from None
