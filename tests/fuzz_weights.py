"""Malformed weight files (run by ``tests/test_fuzz.py``): damaged containers, zip bombs, pickles,
wrong dtypes/shapes, non-finite numbers, bad names and JSON, special files, other airframes.

Every case must make :func:`uavdyn.learned.load_weights` raise :class:`WeightFileError` with one
line naming the file, and ``uavdyn modes --hybrid --weights FILE`` fail with one line and no
traceback. The base file is a valid 'improved' network for the Aerosonde preset.
"""

from __future__ import annotations

import functools
import io
import json
import os
import pickle
import socket
import struct
import warnings
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
from fuzz_common import Case

import uavdyn.learned
from uavdyn.learned import FORMULATIONS, WeightFileError

NAME = "w.npz"
HIDDEN = 8


@functools.cache
def _aerosonde():
    from uavdyn.airframes import load_airframe
    return load_airframe("aerosonde")


def good_arrays(formulation: str = "improved", kind: str = "fixed_wing") -> dict:
    """The arrays of a valid weight file, exactly as ``save_weights`` writes them."""
    rng = np.random.default_rng(7)
    form = FORMULATIONS[formulation]
    sizes = [form.n_in, HIDDEN, HIDDEN, HIDDEN, form.n_out]
    arrays = {
        "format_version": np.array(2), "formulation": np.array(formulation),
        "activation": np.array("relu"), "kind": np.array(kind),
        "airframe_hash": np.array(_aerosonde().param_hash()), "dt": np.array(0.005),
        "in_mean": rng.normal(size=form.n_in), "in_scale": rng.uniform(0.5, 2, form.n_in),
        "out_mean": rng.normal(size=form.n_out) * 0.01,
        "out_scale": rng.uniform(0.01, 0.1, form.n_out),
        "info": np.array(json.dumps({"note": "fuzz base"})),
    }
    for i in range(4):
        arrays[f"W{i}"] = rng.normal(size=(sizes[i + 1], sizes[i])) / np.sqrt(sizes[i])
        arrays[f"b{i}"] = rng.normal(size=sizes[i + 1]) * 0.1
    if form.takes_time:
        arrays["t_range"] = np.array([0.0, 60.0])
    return arrays


def _npz_bytes(arrays: dict) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)  # object arrays are pickled here (allow_pickle defaults to True)
    return buf.getvalue()


def _npy_bytes(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array)
    return buf.getvalue()


def _write(folder: Path, data: bytes) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / NAME
    path.write_bytes(data)
    return path


def _zip(folder: Path, members: list[tuple[str, bytes]],
         method: int = zipfile.ZIP_STORED) -> Path:
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # duplicate names are deliberate
        with zipfile.ZipFile(buf, "w", method) as zf:
            for name, data in members:
                zf.writestr(name, data)
    return _write(folder, buf.getvalue())


def _members(arrays: dict) -> list[tuple[str, bytes]]:
    return [(f"{k}.npy", _npy_bytes(np.asarray(v))) for k, v in arrays.items()]


def _patch_central(data: bytes, member: str, offset: int, fmt: str, value: int) -> bytes:
    """Overwrite a field of ``member``'s central-directory entry (what zipfile trusts)."""
    raw = bytearray(data)
    pos = 0
    while True:
        pos = raw.index(b"PK\x01\x02", pos)
        (name_len,) = struct.unpack_from("<H", raw, pos + 28)
        if raw[pos + 46:pos + 46 + name_len] == member.encode():
            struct.pack_into(fmt, raw, pos + offset, value)
            return bytes(raw)
        pos += 4


# -- case builders -------------------------------------------------------------------------------

def arrays_case(name: str, change: Callable[[dict], None], formulation: str = "improved",
                **kw) -> Case:
    """A case whose file is the base arrays after ``change(arrays)`` (mutates in place)."""
    def build(folder: Path) -> Path:
        arrays = good_arrays(formulation)
        change(arrays)
        return _write(folder, _npz_bytes(arrays))
    return _case(name, build, **kw)


def _set(**values) -> Callable[[dict], None]:
    return lambda arrays: arrays.update(values)


def _drop(*keys: str) -> Callable[[dict], None]:
    def change(arrays: dict) -> None:
        for key in keys:
            arrays.pop(key)
    return change


def _load(path: Path) -> object:
    return uavdyn.learned.load_weights(path)


def _load_for_aerosonde(path: Path) -> object:
    return uavdyn.learned.load_weights(path, _aerosonde())


def _cli(path: Path, out: Path) -> list[str]:
    return ["modes", "--airframe", "aerosonde", "--hybrid", "--weights", str(path)]


def _case(name: str, build: Callable[[Path], Path], load=_load, names: str | None = None,
          tags: tuple[str, ...] = ()) -> Case:
    return Case(name, build, load, WeightFileError, _cli, names, ("weights", *tags))


def _raw(name: str, make: Callable[[], bytes]) -> Case:
    return _case(name, lambda folder: _write(folder, make()))


def _good_bytes() -> bytes:
    return _npz_bytes(good_arrays())


def _random(n: int, prefix: bytes = b"") -> Callable[[], bytes]:
    return lambda: prefix + np.random.default_rng(n).bytes(n)


def _truncated(keep: Callable[[int], int]) -> Callable[[], bytes]:
    def make() -> bytes:
        data = _good_bytes()
        return data[:keep(len(data))]
    return make


def _bomb(folder: Path) -> Path:
    """A real zip bomb: a 320 MB .npy of zeros deflated to a few hundred kB."""
    count = 40_000_000
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f8", "fortran_order": False,
                                               "shape": (count,)})
    header = buf.getvalue()
    members = _members(good_arrays())
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, data in members:
            if name != "W0.npy":
                zf.writestr(name, data)
        info = zipfile.ZipInfo("W0.npy")
        info.compress_type = zipfile.ZIP_DEFLATED
        with zf.open(info, "w", force_zip64=True) as fh:
            fh.write(header)
            zeros = bytes(1 << 22)
            for _ in range(count * 8 // len(zeros)):
                fh.write(zeros)
    return _write(folder, out.getvalue())


def _declared_huge(folder: Path) -> Path:
    data = _good_bytes()
    return _write(folder, _patch_central(data, "W1.npy", 24, "<I", 0xFFFFFFF0))


def _many_declared(folder: Path) -> Path:
    data = _good_bytes()
    for key in ("W0", "W1", "W2", "W3", "in_mean", "in_scale"):  # 6 x 60 MB > 256 MB
        data = _patch_central(data, f"{key}.npy", 24, "<I", 60 * 2**20)
    return _write(folder, data)


def _encrypted_flag(folder: Path) -> Path:
    return _write(folder, _patch_central(_good_bytes(), "b0.npy", 8, "<H", 0x1))


def _unknown_method(folder: Path) -> Path:
    return _write(folder, _patch_central(_good_bytes(), "b0.npy", 10, "<H", 99))


def _bad_crc(folder: Path) -> Path:
    data = bytearray(_good_bytes())
    with zipfile.ZipFile(io.BytesIO(bytes(data))) as zf:
        info = zf.getinfo("W1.npy")
    (name_len, extra_len) = struct.unpack_from("<HH", data, info.header_offset + 26)
    last = info.header_offset + 30 + name_len + extra_len + info.compress_size - 1
    data[last] ^= 0x55
    return _write(folder, bytes(data))


def _header(descr: str, shape: tuple, data: bytes = b"") -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False,
                                               "shape": shape})
    return buf.getvalue() + data


def _member_replaced(key: str, payload: bytes) -> Callable[[Path], Path]:
    def build(folder: Path) -> Path:
        members = [(n, payload if n == f"{key}.npy" else d)
                   for n, d in _members(good_arrays())]
        return _zip(folder, members)
    return build


def _extra_member(name: str, payload: bytes) -> Callable[[Path], Path]:
    return lambda folder: _zip(folder, [*_members(good_arrays()), (name, payload)])


def _special(make: Callable[[Path], None]) -> Callable[[Path], Path]:
    def build(folder: Path) -> Path:
        folder.mkdir(parents=True, exist_ok=True)
        make(folder / NAME)
        return folder / NAME
    return build


def _unix_socket(path: Path) -> None:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        sock.bind(str(path))
    finally:
        sock.close()


def _fifo_target(path: Path) -> None:
    os.mkfifo(path.with_name("pipe"))
    path.symlink_to(path.with_name("pipe"))


def _sparse_huge(path: Path) -> None:
    with open(path, "wb") as fh:
        fh.truncate(65 * 2**20)


def _deep_json() -> str:
    return "[" * 100_000 + "]" * 100_000


def cases() -> list[Case]:
    """At least 45 malformed weight files; all raise WeightFileError."""
    t2 = np.array([0.0, 60.0])
    out = [
        # damaged or foreign containers
        _raw("empty file", lambda: b""),
        _raw("truncated to half", _truncated(lambda n: n // 2)),
        _raw("truncated to 10 bytes", _truncated(lambda n: 10)),
        _raw("end of central directory cut off", _truncated(lambda n: n - 10)),
        _raw("random bytes", _random(4096)),
        _raw("random bytes behind a zip signature", _random(4096, b"PK\x03\x04")),
        _raw("JSON text instead of npz", lambda: json.dumps({"W0": [[1.0]]}).encode()),
        _raw("single .npy array", lambda: _npy_bytes(np.zeros((3, 3)))),
        _raw("pickled dict", lambda: pickle.dumps(good_arrays())),
        _case("empty zip archive", lambda folder: _zip(folder, [])),
        _case("member that is not .npy", _extra_member("README.txt", b"hello")),
        _case("duplicate member name",
              lambda folder: _zip(folder, [*_members(good_arrays()),
                                           ("W0.npy", _npy_bytes(np.zeros((8, 6))))])),
        _case("zip bomb (320 MB of zeros)", _bomb, tags=("slow",)),
        _case("member declares 4 GB uncompressed", _declared_huge),
        _case("members declare 360 MB in total", _many_declared),
        _case("encrypted member flag", _encrypted_flag),
        _case("unsupported compression method", _unknown_method),
        _case("CRC mismatch", _bad_crc),
        _case("npy header declares 8 GB of data", _member_replaced(
            "W0", _header("<f8", (10**9,), bytes(8)))),
        _case("npy data truncated", _member_replaced("W0", _header("<f8", (8, 6), bytes(40)))),
        _case("npy trailing data", _member_replaced(
            "b0", _header("<f8", (8,), bytes(64 + 16)))),
        _case("npy bad magic", _member_replaced("W0", b"NOTNUMPY" + bytes(100))),
        _case("npy unparsable header", _member_replaced(
            "W0", b"\x93NUMPY\x01\x00" + struct.pack("<H", 22) + b"{'descr': <f8 garbage\n")),
        _case("npy format version 9.9", _member_replaced(
            "W0", b"\x93NUMPY\x09\x09" + bytes(64))),
        # pickles
        arrays_case("object array (pickled) in W0",
                    _set(W0=np.array([{"a": 1}] * 3, dtype=object))),
        arrays_case("object scalar (pickled) in info", _set(info=np.array({"a": 1}))),
        # keys
        arrays_case("missing W2 and out_scale", _drop("W2", "out_scale")),
        arrays_case("missing format_version", _drop("format_version")),
        arrays_case("unknown extra key", _set(bias_extra=np.zeros(3))),
        # dtypes
        arrays_case("complex W0", _set(W0=np.ones((HIDDEN, 6), complex))),
        arrays_case("bool W1", _set(W1=np.ones((HIDDEN, HIDDEN), bool))),
        arrays_case("string W2", _set(W2=np.full((HIDDEN, HIDDEN), "1.0"))),
        arrays_case("datetime b0", _set(b0=np.zeros(HIDDEN, "datetime64[s]"))),
        arrays_case("structured in_mean", _set(in_mean=np.zeros(6, [("a", "<f8")]))),
        arrays_case("dt as string", _set(dt=np.array("0.005"))),
        arrays_case("format_version float", _set(format_version=np.array(2.0))),
        arrays_case("format_version string", _set(format_version=np.array("2"))),
        arrays_case("format_version bool", _set(format_version=np.array(True))),
        arrays_case("format_version vector", _set(format_version=np.array([1, 2]))),
        arrays_case("format_version 99", _set(format_version=np.array(99))),
        arrays_case("formulation as number", _set(formulation=np.array(3))),
        arrays_case("formulation as bytes", _set(formulation=np.array(b"improved"))),
        arrays_case("airframe_hash as integers", _set(airframe_hash=np.arange(4))),
        arrays_case("guard unknown", _set(guard=np.array("box-sigmoid"))),
        arrays_case("guard as number", _set(guard=np.array(1))),
        arrays_case("format 4 without guard", _set(format_version=np.array(4))),
        # shapes
        arrays_case("W1 three-dimensional", _set(W1=np.zeros((HIDDEN, HIDDEN, 1)))),
        arrays_case("W0 one-dimensional", _set(W0=np.zeros(6))),
        arrays_case("W0 scalar", _set(W0=np.array(1.0))),
        arrays_case("b0 two-dimensional", _set(b0=np.zeros((HIDDEN, 1)))),
        arrays_case("in_mean column", _set(in_mean=np.zeros((6, 1)))),
        arrays_case("dt vector", _set(dt=np.array([0.005]))),
        arrays_case("W3 wrong output size", _set(W3=np.zeros((4, HIDDEN)), b3=np.zeros(4))),
        arrays_case("zero-width layer", _set(W1=np.zeros((0, HIDDEN)), b1=np.zeros(0),
                                             W2=np.zeros((HIDDEN, 0)))),
        # non-finite and out-of-range numbers
        arrays_case("NaN in b3", _set(b3=np.full(3, np.nan))),
        arrays_case("+inf in in_mean", _set(in_mean=np.full(6, np.inf))),
        arrays_case("-inf in W2", _set(W2=np.full((HIDDEN, HIDDEN), -np.inf))),
        arrays_case("NaN in out_scale", _set(out_scale=np.full(3, np.nan))),
        arrays_case("dt NaN", _set(dt=np.array(np.nan))),
        arrays_case("dt inf", _set(dt=np.array(np.inf))),
        arrays_case("dt negative", _set(dt=np.array(-0.005))),
        arrays_case("dt zero", _set(dt=np.array(0.0))),
        arrays_case("in_scale zero", _set(in_scale=np.zeros(6))),
        arrays_case("in_scale negative", _set(in_scale=-np.ones(6))),
        arrays_case("float overflow to inf on conversion",
                    _set(W0=np.full((HIDDEN, 6), 1e300, np.longdouble) * 1e300)),
        # t_range
        arrays_case("t_range missing (paper)", _drop("t_range"), "paper"),
        arrays_case("t_range reversed", _set(t_range=t2[::-1].copy()), "paper"),
        arrays_case("t_range of three values", _set(t_range=np.array([0.0, 1.0, 2.0])),
                    "paper"),
        arrays_case("t_range NaN", _set(t_range=np.array([0.0, np.nan])), "paper"),
        arrays_case("t_range as string", _set(t_range=np.array("0..60")), "paper"),
        arrays_case("t_range matrix", _set(t_range=t2.reshape(1, 2)), "paper"),
        arrays_case("t_range on a time-free formulation, reversed",
                    _set(t_range=np.array([5.0, 1.0]))),
        # names
        arrays_case("unknown formulation", _set(formulation=np.array("magic"))),
        arrays_case("unknown activation", _set(activation=np.array("sigmoid"))),
        arrays_case("unknown kind", _set(kind=np.array("helicopter"))),
        arrays_case("kind with a newline", _set(kind=np.array("fixed_wing\nrm -rf /"))),
        arrays_case("formulation of 10000 characters", _set(formulation=np.array("x" * 10000))),
        arrays_case("airframe_hash with control characters",
                    _set(airframe_hash=np.array("abc\x1b[2Jdef"))),
        # info
        arrays_case("info not JSON", _set(info=np.array("{not json"))),
        arrays_case("info a JSON list", _set(info=np.array("[1, 2, 3]"))),
        arrays_case("info deeply nested JSON", _set(info=np.array(_deep_json()))),
        arrays_case("info an integer of 5000 digits", _set(info=np.array("1" * 5000))),
        arrays_case("info as a number array", _set(info=np.arange(3.0))),
        # special files
        _case("FIFO", _special(lambda p: os.mkfifo(p)), tags=("special",)),
        _case("directory", _special(lambda p: p.mkdir()), tags=("special",)),
        _case("symlink to /dev/zero", _special(lambda p: p.symlink_to("/dev/zero")),
              tags=("special",)),
        _case("symlink to /dev/null", _special(lambda p: p.symlink_to("/dev/null")),
              tags=("special",)),
        _case("symlink to a FIFO", _special(_fifo_target), tags=("special",)),
        _case("UNIX socket", _special(_unix_socket), tags=("special",)),
        _case("sparse file of 65 MB", _special(_sparse_huge)),
        # other airframes
        arrays_case("wrong airframe hash", _set(airframe_hash=np.array("0123456789abcdef")),
                    load=_load_for_aerosonde),
        arrays_case("multirotor weights for a fixed wing", _set(kind=np.array("multirotor")),
                    load=_load_for_aerosonde),
    ]
    return out
