"""Malformed PX4 ULog files and ALFA folders for the fuzz runner (``tests/test_fuzz.py``).

Every case starts from a small valid input written here (a 2 s multirotor ULog through
``tests/ulog_writer.py``, a 4 s ALFA folder of MAVROS CSVs; both import cleanly, see
``test_ulog_synthetic.py::test_fuzz_baselines_import_cleanly``) and breaks one thing: the
header, the framing (truncation at many byte offsets, huge or zero message sizes), the format
definitions (bit flips in topic names and types, nesting bombs), the data (NaN, zero
quaternions, missing topics, no common time), the file type (FIFO, folder, symlink to
``/dev/zero``, oversize sparse file), or one ALFA topic CSV (missing, empty, ragged, NaN,
non-numeric, non-increasing time, escaping symlink). Mutations are seeded, so every run
builds the same bytes. There is no CLI route for ULog/ALFA import, so ``cli`` is None.
"""

from __future__ import annotations

import functools
import math
import os
import struct
from collections.abc import Callable
from pathlib import Path

import numpy as np
from fuzz_common import Case
from ulog_writer import ulog_bytes, write_ulog

from uavdyn.flightdata import FlightDataError, import_alfa, import_ulog

ULOG_NAME = "log.ulg"
ALFA_DIR = "alfa_seq"
ALFA_STEM = "flight"
STATE_HZ, CONTROL_HZ, SECONDS = 50, 10, 2.0
FIRST_US = 1_000_000


# ----------------------------------------------------------------------------- valid ULog


def _ulog_cli(path: Path, out: Path) -> list[str]:
    """The CLI route: ``uavdyn import-log`` of the file as a ULog."""
    return ["import-log", str(path), "--format", "ulog", "--out", str(out)]


def _alfa_cli(path: Path, out: Path) -> list[str]:
    """The CLI route: ``uavdyn import-log`` of the folder as an ALFA sequence."""
    return ["import-log", str(path), "--format", "alfa", "--out", str(out)]


def _state_stamps() -> np.ndarray:
    n = int(SECONDS * STATE_HZ) + 1
    return (FIRST_US + np.arange(n) * (1_000_000 // STATE_HZ)).astype(np.uint64)


def _control_stamps() -> np.ndarray:
    n = int((SECONDS + 0.5) * CONTROL_HZ)
    return (FIRST_US - 30_000 + np.arange(n) * (1_000_000 // CONTROL_HZ)).astype(np.uint64)


def ulog_topics() -> dict[str, dict[str, np.ndarray]]:
    """The topics of the valid log: pitch ``0.1 sin(pi t)`` (yaw and roll 0), its rate, body
    velocity (5, 0, 0.5) m/s in NED, and ``actuator_controls_0`` commands."""
    ts = _state_stamps()
    t = ts.astype(float) * 1e-6
    theta = 0.1 * np.sin(math.pi * t)
    q = np.zeros((len(t), 4), np.float32)
    q[:, 0], q[:, 2] = np.cos(theta / 2), np.sin(theta / 2)
    xyz = np.zeros((len(t), 3), np.float32)
    xyz[:, 1] = 0.1 * math.pi * np.cos(math.pi * t)
    u, w = 5.0, 0.5
    tc = _control_stamps()
    control = np.zeros((len(tc), 8), np.float32)
    control[:, 1] = 0.1 * np.sin(tc.astype(float) * 1e-6)
    control[:, 3] = 0.5
    return {
        "vehicle_attitude": {"timestamp": ts, "q": q},
        "vehicle_angular_velocity": {"timestamp": ts, "xyz": xyz},
        "vehicle_local_position": {
            "timestamp": ts,
            "vx": (u * np.cos(theta) + w * np.sin(theta)).astype(np.float32),
            "vy": np.zeros(len(t), np.float32),
            "vz": (-u * np.sin(theta) + w * np.cos(theta)).astype(np.float32)},
        "actuator_controls_0": {"timestamp": tc, "control": control},
    }


LOG_OPTIONS = {"info": {"sys_name": "fuzz"}, "start_us": 500_000}


def write_log(path: Path, topics: dict | None = None, mav_type: int = 2) -> Path:
    """A ULog of ``topics`` (default the valid ones) with MAV_TYPE ``mav_type``."""
    return write_ulog(path, ulog_topics() if topics is None else topics,
                      params={"MAV_TYPE": mav_type}, **LOG_OPTIONS)


@functools.lru_cache(maxsize=1)
def _valid_bytes() -> bytes:
    """Bytes of the valid log, built in memory once (no file outside a case folder)."""
    return ulog_bytes(ulog_topics(), params={"MAV_TYPE": 2}, **LOG_OPTIONS)


def valid_ulog() -> bytes:
    """The valid log's bytes (a fresh copy to mutate)."""
    return bytes(_valid_bytes())


def messages(raw: bytes) -> list[tuple[int, int, str]]:
    """``(offset, payload size, type)`` of each message of a well-framed ULog."""
    out, pos = [], 16
    while pos + 3 <= len(raw):
        size, kind = struct.unpack_from("<HB", raw, pos)
        out.append((pos, size, chr(kind)))
        pos += 3 + size
    return out


def _format_message(raw: bytes, topic: str) -> tuple[int, int]:
    """Offset and size of the ``F`` message defining ``topic``."""
    for pos, size, kind in messages(raw):
        if kind == "F" and raw[pos + 3:pos + 3 + size].startswith(topic.encode() + b":"):
            return pos, size
    raise KeyError(topic)


def _message(kind: str, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), ord(kind)) + payload


# ----------------------------------------------------------------------------- ULog cases


def _bytes_case(name: str, make: Callable[[], bytes], *tags: str) -> Case:
    def build(folder: Path) -> Path:
        path = folder / ULOG_NAME
        path.write_bytes(make())
        return path
    return Case(name=f"ulog_{name}", build=build, load=import_ulog, error=FlightDataError,
                cli=_ulog_cli,
                tags=("ulog", *tags))


def _topics_case(name: str, edit: Callable[[dict], dict], mav_type: int = 2) -> Case:
    def build(folder: Path) -> Path:
        return write_log(folder / ULOG_NAME, edit(ulog_topics()), mav_type)
    return Case(name=f"ulog_{name}", build=build, load=import_ulog, error=FlightDataError,
                cli=_ulog_cli,
                tags=("ulog", "content"))


def _flip(raw: bytes, offset: int, bit: int) -> bytes:
    out = bytearray(raw)
    out[offset] ^= 1 << bit
    return bytes(out)


def _flip_case(name: str, offset: int, bit: int) -> Case:
    return _bytes_case(name, lambda: _flip(valid_ulog(), offset, bit), "bitflip")


def _truncations() -> list[Case]:
    """Cuts at fractions of the file and at chosen places (inside the header, the flag bits,
    a format, a subscription, a data message's header and payload); never at a message
    boundary, where a cut file cannot be told from a shorter log."""
    raw = _valid_bytes()
    msgs = messages(raw)
    starts = {pos for pos, _, _ in msgs} | {len(raw)}
    first = {kind: pos for pos, _, kind in reversed(msgs)}
    data = [pos for pos, _, kind in msgs if kind == "D"]
    offsets = {"header_5": 5, "header_12": 12, "flag_bits": first["B"] + 10,
               "first_format": first["F"] + 7, "subscription": first["A"] + 4,
               "data_header": data[len(data) // 3] + 1, "data_header_2": data[-5] + 2,
               "last_byte": len(raw) - 1}
    rng = np.random.default_rng(2024)
    for frac in (0.05, 0.2, 0.35, 0.5, 0.65, 0.8, 0.95):
        offsets[f"{int(frac * 100)}pct"] = int(len(raw) * frac)
    for k in range(4):
        offsets[f"random_{k}"] = int(rng.integers(17, len(raw) - 1))
    cases = []
    for label, cut in offsets.items():
        while cut in starts and cut > 16:  # move a boundary cut one byte into the message
            cut += 1
        cases.append(_bytes_case(f"truncated_{label}", lambda c=cut: valid_ulog()[:c],
                                 "truncation"))
    return cases


def _format_flips() -> list[Case]:
    """Seeded bit flips in the topic name or a field type of the format of a used topic:
    the name no longer matches its subscription, or the type is no ULog type."""
    raw = _valid_bytes()
    rng = np.random.default_rng(7)
    cases = []
    for topic in ("vehicle_attitude", "vehicle_angular_velocity", "vehicle_local_position",
                  "actuator_controls_0"):
        pos, _ = _format_message(raw, topic)
        offset = pos + 3 + int(rng.integers(0, len(topic)))
        cases.append(_flip_case(f"format_name_bitflip_{topic}", offset,
                                int(rng.integers(0, 7))))
    for topic, type_name in (("vehicle_attitude", b"float[4]"),
                             ("vehicle_local_position", b"float vx")):
        pos, size = _format_message(raw, topic)
        offset = raw.index(type_name, pos + 3) + int(rng.integers(0, 5))
        cases.append(_flip_case(f"format_type_bitflip_{topic}", offset,
                                int(rng.integers(0, 7))))
    return cases


def _set_size(raw: bytes, pos: int, size: int) -> bytes:
    out = bytearray(raw)
    out[pos:pos + 2] = struct.pack("<H", size)
    return bytes(out)


def _insert_definitions(raw: bytes, extra: bytes) -> bytes:
    """``extra`` messages inserted just before the first format message."""
    pos, _ = _format_message(raw, "vehicle_attitude")
    first_f = min(p for p, _, k in messages(raw) if k == "F")
    pos = min(pos, first_f)
    return raw[:pos] + extra + raw[pos:]


def _append_subscription(raw: bytes, topic: str, msg_id: int = 900) -> bytes:
    """A subscription ``A`` message for ``topic`` inserted after the last existing one."""
    last_a = max(p + 3 + s for p, s, k in messages(raw) if k == "A")
    add = _message("A", struct.pack("<BH", 0, msg_id) + topic.encode())
    return raw[:last_a] + add + raw[last_a:]


def _framing_cases() -> list[Case]:
    raw = _valid_bytes()
    msgs = messages(raw)
    first = {kind: pos for pos, _, kind in reversed(msgs)}
    data = [pos for pos, _, kind in msgs if kind == "D"]
    cases = [
        _bytes_case("huge_size_flag_bits", lambda: _set_size(valid_ulog(), first["B"], 0xFFFF),
                    "framing"),
        _bytes_case("huge_size_format", lambda: _set_size(valid_ulog(), first["F"], 0xFFFF),
                    "framing"),
        _bytes_case("huge_size_subscription",
                    lambda: _set_size(valid_ulog(), first["A"], 0xFFFF), "framing"),
        _bytes_case("huge_size_data", lambda: _set_size(valid_ulog(), data[len(data) // 2],
                                                        0xFFFF), "framing"),
        _bytes_case("zero_size_data", lambda: _set_size(valid_ulog(), data[len(data) // 2], 0),
                    "framing"),
        _bytes_case("unknown_msg_id", lambda: _set_msg_id(valid_ulog(), data[10], 999),
                    "framing"),
        _bytes_case("incompatible_flag", lambda: _flip(valid_ulog(), first["B"] + 3 + 8, 1),
                    "header"),
        _bytes_case("appended_offset_past_end", lambda: _appended_offset(valid_ulog()),
                    "header"),
        _bytes_case("nested_format_bomb", lambda: _append_subscription(_insert_definitions(
            valid_ulog(), _message("F", b"bomb_a:uint64_t timestamp;bomb_b[60000] b;")
            + _message("F", b"bomb_b:float[60000] x;")), "bomb_a"), "format"),
        _bytes_case("self_nested_format", lambda: _append_subscription(_insert_definitions(
            valid_ulog(), _message("F", b"loop:uint64_t timestamp;loop inner;")), "loop"),
            "format"),
        _bytes_case("huge_array_format", lambda: _append_subscription(_insert_definitions(
            valid_ulog(), _message("F", b"wide:uint64_t timestamp;float[99999999] x;")),
            "wide"), "format"),
    ]
    return cases


def _set_msg_id(raw: bytes, pos: int, msg_id: int) -> bytes:
    """The data message at ``pos`` re-addressed to subscription ``msg_id``."""
    out = bytearray(raw)
    out[pos + 3:pos + 5] = struct.pack("<H", msg_id)
    return bytes(out)


def _appended_offset(raw: bytes) -> bytes:
    """Flag bits claiming appended data at an offset past the end of the file."""
    pos = [p for p, _, k in messages(raw) if k == "B"][0]
    out = bytearray(raw)
    out[pos + 3 + 8] |= 1
    out[pos + 3 + 16:pos + 3 + 24] = struct.pack("<Q", len(raw) + 1000)
    return bytes(out)


def _header_cases() -> list[Case]:
    rng = np.random.default_rng(11)
    cases = [
        _bytes_case("empty", lambda: b"", "header"),
        _bytes_case("ten_bytes", lambda: valid_ulog()[:10], "header"),
        _bytes_case("header_only", lambda: valid_ulog()[:16], "header"),
        _bytes_case("version_2", lambda: valid_ulog()[:7] + b"\x02" + valid_ulog()[8:],
                    "header"),
        _bytes_case("version_255", lambda: valid_ulog()[:7] + b"\xff" + valid_ulog()[8:],
                    "header"),
        _bytes_case("start_timestamp_2_63", lambda: valid_ulog()[:8]
                    + struct.pack("<Q", 2**63) + valid_ulog()[16:], "header"),
        _bytes_case("text_file", lambda: b"timestamp,q0,q1\n1,2,3\n" * 50, "header"),
    ]
    for k in range(4):
        offset, bit = int(rng.integers(0, 7)), int(rng.integers(0, 8))
        cases.append(_flip_case(f"magic_bitflip_{k}", offset, bit))
    for k, size in enumerate((1, 4096, 65536)):
        cases.append(_bytes_case(f"random_bytes_{size}",
                                 lambda s=size, seed=k: np.random.default_rng(seed).bytes(s),
                                 "random"))
    for k, size in enumerate((512, 20000)):
        cases.append(_bytes_case(f"header_then_random_{size}",
                                 lambda s=size, seed=100 + k: valid_ulog()[:16]
                                 + np.random.default_rng(seed).bytes(s), "random"))
    cases.append(_bytes_case("random_after_definitions", lambda: _random_tail(valid_ulog()),
                             "random"))
    return cases


def _random_tail(raw: bytes) -> bytes:
    """The definitions section kept, the data section replaced by seeded random bytes."""
    first_a = min(p for p, _, k in messages(raw) if k == "A")
    return raw[:first_a] + np.random.default_rng(5).bytes(len(raw) - first_a)


def _drop(*names: str) -> Callable[[dict], dict]:
    return lambda topics: {k: v for k, v in topics.items() if k not in names}


def _bad_value(topic: str, field: str, value: float, rows=slice(20, 23)
               ) -> Callable[[dict], dict]:
    def edit(topics: dict) -> dict:
        a = topics[topic][field].copy()
        if a.ndim == 2 and field != "q":
            a[rows, 3 if topic.startswith("actuator") else 1] = value
        else:
            a[rows] = value
        return {**topics, topic: {**topics[topic], field: a}}
    return edit


def _shift(topic: str, seconds: float) -> Callable[[dict], dict]:
    def edit(topics: dict) -> dict:
        stamps = topics[topic]["timestamp"] + np.uint64(int(seconds * 1e6))
        return {**topics, topic: {**topics[topic], "timestamp": stamps}}
    return edit


def _scale(topic: str, field: str, factor: float) -> Callable[[dict], dict]:
    def edit(topics: dict) -> dict:
        return {**topics, topic: {**topics[topic],
                                  field: (topics[topic][field] * factor).astype(np.float32)}}
    return edit


def _same_stamp(topic: str) -> Callable[[dict], dict]:
    def edit(topics: dict) -> dict:
        stamps = np.full_like(topics[topic]["timestamp"], FIRST_US)
        return {**topics, topic: {**topics[topic], "timestamp": stamps}}
    return edit


def _content_cases() -> list[Case]:
    return [
        _topics_case("no_attitude", _drop("vehicle_attitude")),
        _topics_case("no_rate", _drop("vehicle_angular_velocity")),
        _topics_case("no_local_position", _drop("vehicle_local_position")),
        _topics_case("no_controls", _drop("actuator_controls_0")),
        _topics_case("no_topics", _drop(*ulog_topics())),
        _topics_case("fixed_wing_without_controls", lambda t: t, mav_type=1),
        _topics_case("nan_quaternion", _bad_value("vehicle_attitude", "q", np.nan)),
        _topics_case("zero_quaternion", _bad_value("vehicle_attitude", "q", 0.0)),
        _topics_case("half_quaternion", _scale("vehicle_attitude", "q", 0.5)),
        _topics_case("nan_velocity", _bad_value("vehicle_local_position", "vx", np.nan)),
        _topics_case("inf_velocity", _bad_value("vehicle_local_position", "vz", np.inf)),
        _topics_case("nan_pitch_rate", _bad_value("vehicle_angular_velocity", "xyz", np.nan)),
        _topics_case("nan_control", _bad_value("actuator_controls_0", "control", np.nan,
                                               slice(3, 5))),
        _topics_case("controls_after_states", _shift("actuator_controls_0", 100.0)),
        _topics_case("all_stamps_equal", _same_stamp("vehicle_attitude")),
        _topics_case("velocity_500_mps", _scale("vehicle_local_position", "vx", 100.0)),
        _topics_case("pitch_rate_in_deg_per_s", _scale("vehicle_angular_velocity", "xyz",
                                                       180 / math.pi)),
        _topics_case("pitch_rate_sign_flipped", _scale("vehicle_angular_velocity", "xyz",
                                                       -1.0)),
        _topics_case("thrust_above_one", _scale("actuator_controls_0", "control", 3.0)),
    ]


def _file_type_cases() -> list[Case]:
    def fifo(folder: Path) -> Path:
        path = folder / "pipe.ulg"
        os.mkfifo(path)
        return path

    def directory(folder: Path) -> Path:
        path = folder / "dir.ulg"
        path.mkdir()
        return path

    def dev_zero(folder: Path) -> Path:
        path = folder / "zero.ulg"
        path.symlink_to("/dev/zero")
        return path

    def dangling(folder: Path) -> Path:
        path = folder / "dangling.ulg"
        path.symlink_to(folder / "nowhere.ulg")
        return path

    def missing(folder: Path) -> Path:
        return folder / "missing.ulg"

    def oversize(folder: Path) -> Path:
        path = folder / "huge.ulg"
        with path.open("wb") as fh:  # sparse: no disk space used
            fh.write(valid_ulog()[:16])
            fh.truncate(3 * 1024**3)
        return path

    return [Case(name=f"ulog_{f.__name__}", build=f, load=import_ulog, error=FlightDataError,
                cli=_ulog_cli,
                 tags=("ulog", "file_type"))
            for f in (fifo, directory, dev_zero, dangling, missing, oversize)]


# ----------------------------------------------------------------------------- valid ALFA


ALFA_T0_NS = 1_531_943_810_000_000_000


def _alfa_tables() -> dict[str, tuple[list[str], list[list[str]]]]:
    """Header and rows (as text) of each topic CSV of a valid 4 s level flight at 20 Hz
    (pitch 0.05 sin t in the ENU/FLU frames, yaw 0), servo and HUD at 5 Hz."""
    def stamps(rate: float, n: int, offset_ms: float = 0.0) -> list[int]:
        return [ALFA_T0_NS + int(offset_ms * 1e6) + int(round(k * 1e9 / rate))
                for k in range(n)]

    def table(cols: list[str], t_ns: list[int], values: list[list[float]]):
        header = ["%time", "field.header.seq", "field.header.stamp", "field.header.frame_id",
                  *cols]
        rows = [[str(t), str(i), str(t - 1000), "base_link", *(repr(float(v)) for v in vals)]
                for i, (t, vals) in enumerate(zip(t_ns, values))]
        return header, rows

    n = 81
    t = stamps(20.0, n)
    rel = [(x - ALFA_T0_NS) * 1e-9 for x in t]
    theta = [0.05 * math.sin(s) for s in rel]
    rate = [0.05 * math.cos(s) for s in rel]
    # ENU/FLU quaternion of a nose-up pitch theta at yaw 0 (east): rotation by -theta about y
    quat = [[math.cos(-th / 2), 0.0, math.sin(-th / 2), 0.0] for th in theta]  # w x y z
    out = {
        "mavros-imu-data": table(
            [f"field.orientation.{c}" for c in "xyzw"] + ["field.angular_velocity.y"], t,
            [[q[1], q[2], q[3], q[0], -r] for q, r in zip(quat, rate)]),
        "mavros-imu-data_raw": table(["field.angular_velocity.x", "field.angular_velocity.y"],
                                     t, [[0.0, -r] for r in rate]),
        "mavros-local_position-odom": table(
            ["field.twist.twist.linear.x", "field.twist.twist.linear.y",
             "field.twist.twist.linear.z"], t, [[15.0, 0.0, -0.5] for _ in t]),
        "mavros-nav_info-pitch": table(["field.commanded", "field.measured"], t,
                                       [[0.0, math.degrees(th)] for th in theta]),
    }
    ts = stamps(5.0, 22, offset_ms=-50.0)
    out["mavros-rc-out"] = table([f"field.channels{i}" for i in range(3)], ts,
                                 [[1500.0, 1385.0 + 10 * (k % 3), 1400.0]
                                  for k in range(len(ts))])
    out["mavros-vfr_hud"] = table(["field.airspeed", "field.throttle"], ts,
                                  [[15.0, 0.4 + 0.05 * (k % 4)] for k in range(len(ts))])
    for suffix, (header, rows) in out.items():  # integer PWM, as MAVROS writes it
        if suffix == "mavros-rc-out":
            out[suffix] = (header, [r[:4] + [str(int(float(v))) for v in r[4:]] for r in rows])
    return out


def _csv_text(header: list[str], rows: list[list[str]]) -> str:
    return "\n".join(",".join(r) for r in [header, *rows]) + "\n"


def write_alfa(folder: Path, edit: Callable[[dict], dict] | None = None) -> Path:
    """An ALFA folder (after ``edit`` of ``{suffix: text}``; a None text leaves the file
    out)."""
    folder.mkdir(parents=True, exist_ok=True)
    texts = {suffix: _csv_text(*tab) for suffix, tab in _alfa_tables().items()}
    if edit is not None:
        texts = edit(texts)
    for suffix, text in texts.items():
        if text is not None:
            (folder / f"{ALFA_STEM}-{suffix}.csv").write_text(text)
    return folder


def topic_file(suffix: str) -> str:
    return f"{ALFA_STEM}-{suffix}.csv"


# ----------------------------------------------------------------------------- ALFA cases


def _alfa_case(name: str, edit: Callable[[dict], dict] | None, names: str | None,
               after: Callable[[Path], None] | None = None) -> Case:
    """``names`` is the topic file the message must name (None: the folder)."""
    def build(folder: Path) -> Path:
        seq = write_alfa(folder / ALFA_DIR, edit)
        if after is not None:
            after(seq)
        return seq
    return Case(name=f"alfa_{name}", build=build, load=import_alfa, error=FlightDataError,
                cli=_alfa_cli,
                names=names, tags=("alfa",))


def _set(suffix: str, text: str | None) -> Callable[[dict], dict]:
    return lambda texts: {**texts, suffix: text}


def _lines(suffix: str, change: Callable[[list[str]], list[str]]) -> Callable[[dict], dict]:
    return lambda texts: {**texts, suffix: "\n".join(change(texts[suffix].splitlines())) + "\n"}


def _cell(row: int, col: int, value: str) -> Callable[[list[str]], list[str]]:
    def change(lines: list[str]) -> list[str]:
        parts = lines[row].split(",")
        parts[col] = value
        return lines[:row] + [",".join(parts)] + lines[row + 1:]
    return change


def _shift_lines(seconds: float) -> Callable[[list[str]], list[str]]:
    def change(lines: list[str]) -> list[str]:
        out = [lines[0]]
        for line in lines[1:]:
            t, rest = line.split(",", 1)
            out.append(f"{int(t) + int(seconds * 1e9)},{rest}")
        return out
    return change


def _replace_with(suffix: str, make: Callable[[Path], None]) -> Callable[[Path], None]:
    def after(seq: Path) -> None:
        path = seq / topic_file(suffix)
        path.unlink()
        make(path)
    return after


def _alfa_cases() -> list[Case]:
    hud, imu, raw = "mavros-vfr_hud", "mavros-imu-data", "mavros-imu-data_raw"
    odom, servo, nav = "mavros-local_position-odom", "mavros-rc-out", "mavros-nav_info-pitch"
    f = topic_file

    def outside_target(path: Path) -> None:
        target = path.parent.parent / "outside.csv"
        target.write_text(_csv_text(*_alfa_tables()[hud]))
        path.symlink_to(target)

    def extra_match(seq: Path) -> None:
        (seq / f"other-{servo}.csv").write_text(_csv_text(*_alfa_tables()[servo]))

    def oversize(path: Path) -> None:
        with path.open("wb") as fh:
            fh.truncate(600 * 1024**2)

    cases = [
        _alfa_case("missing_topic_file", _set(servo, None), None),
        _alfa_case("missing_nav_file", _set(nav, None), None),
        _alfa_case("empty_file", _set(hud, ""), f(hud)),
        _alfa_case("whitespace_file", _set(hud, "\n \n"), f(hud)),
        _alfa_case("header_only", _lines(imu, lambda ls: ls[:1]), f(imu)),
        _alfa_case("one_row", _lines(raw, lambda ls: ls[:2]), f(raw)),
        _alfa_case("ragged_extra_field", _lines(odom, lambda ls: ls[:5] + [ls[5] + ",1.0"]
                                                + ls[6:]), f(odom)),
        _alfa_case("ragged_missing_field", _lines(servo, lambda ls: ls[:3]
                                                  + [ls[3].rsplit(",", 1)[0]] + ls[4:]),
                   f(servo)),
        _alfa_case("nan_throttle", _lines(hud, _cell(4, 5, "nan")), f(hud)),
        _alfa_case("inf_gyro", _lines(raw, _cell(7, 5, "inf")), f(raw)),
        _alfa_case("nan_nav_pitch", _lines(nav, _cell(9, 5, "NaN")), f(nav)),
        _alfa_case("non_numeric_orientation", _lines(imu, _cell(10, 4, "abc")), f(imu)),
        _alfa_case("empty_cell", _lines(odom, _cell(3, 4, "")), f(odom)),
        _alfa_case("float_time", _lines(odom, _cell(2, 0, "1.5e18")), f(odom)),
        _alfa_case("negative_time", _lines(hud, _cell(2, 0, "-5")), f(hud)),
        _alfa_case("time_backwards", _lines(raw, lambda ls: ls[:5] + [ls[6], ls[5]] + ls[7:]),
                   f(raw)),
        _alfa_case("duplicate_time", _lines(imu, lambda ls: ls[:5] + [ls[5]] + ls[5:]),
                   f(imu)),
        _alfa_case("topic_after_the_others", _lines(hud, _shift_lines(100.0)), f(hud)),
        _alfa_case("topic_before_the_others", _lines(servo, _shift_lines(-100.0)), f(servo)),
        _alfa_case("missing_column", lambda t: {**t, hud: t[hud].replace("field.throttle",
                                                                         "field.thr", 1)},
                   f(hud)),
        _alfa_case("duplicate_column", lambda t: {**t, hud: t[hud].replace(
            "field.airspeed", "field.throttle", 1)}, f(hud)),
        _alfa_case("zero_quaternion", _lines(imu, lambda ls: ls[:8] + [",".join(
            ls[8].split(",")[:4] + ["0.0"] * 4 + ls[8].split(",")[8:])] + ls[9:]), f(imu)),
        _alfa_case("blank_line_inside", _lines(raw, lambda ls: ls[:10] + [""] + ls[10:]),
                   f(raw)),
        _alfa_case("nul_bytes", _set(imu, "%time,field\x00x\n1,2\n"), f(imu)),
        _alfa_case("field_too_large", _lines(odom, _cell(3, 3, "x" * 200_000)), f(odom)),
        _alfa_case("pwm_out_of_range", _lines(servo, _cell(3, 5, "2500")), f(servo)),
        _alfa_case("throttle_percent", _lines(hud, _cell(6, 5, "45.0")), f(hud)),
        _alfa_case("topic_is_folder", None, f(hud),
                   after=_replace_with(hud, lambda p: p.mkdir())),
        _alfa_case("topic_is_fifo", None, f(hud), after=_replace_with(hud, os.mkfifo)),
        _alfa_case("topic_symlink_dev_zero", None, f(imu),
                   after=_replace_with(imu, lambda p: p.symlink_to("/dev/zero"))),
        _alfa_case("topic_symlink_escapes_folder", None, f(hud),
                   after=_replace_with(hud, outside_target)),
        _alfa_case("topic_oversize_sparse", None, f(odom), after=_replace_with(odom, oversize)),
        _alfa_case("ambiguous_topic_files", None, None, after=extra_match),
    ]

    def binary(folder: Path) -> Path:
        seq = write_alfa(folder / ALFA_DIR)
        (seq / f(raw)).write_bytes(b"%time,x\n" + bytes(range(128, 256)) * 4)
        return seq

    def not_a_folder(folder: Path) -> Path:
        path = folder / "seq.csv"
        path.write_text("%time\n1\n")
        return path

    cases += [Case(name="alfa_not_utf8", build=binary, load=import_alfa, cli=_alfa_cli,
                   error=FlightDataError, names=f(raw), tags=("alfa",)),
              Case(name="alfa_folder_is_a_file", build=not_a_folder, load=import_alfa,
                   cli=_alfa_cli,
                   error=FlightDataError, tags=("alfa",)),
              Case(name="alfa_folder_missing", build=lambda folder: folder / "absent",
                   load=import_alfa, error=FlightDataError, cli=_alfa_cli, tags=("alfa",))]
    return cases


def cases() -> list[Case]:
    """All ULog and ALFA malformed-input cases (seeded, deterministic)."""
    return (_header_cases() + _truncations() + _format_flips() + _framing_cases()
            + _content_cases() + _file_type_cases() + _alfa_cases())
