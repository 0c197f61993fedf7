"""Regenerate the trimmed real-log copies in this folder from the original files.

Usage::

    python tests/data/reallogs/make_trimmed.py SOURCE [--out FOLDER]

``SOURCE`` is a folder holding the originals under their names in the shared flight-log set
(``pyulog_sample_px4_events.ulg``, ``pyulog_sample.ulg``, ``pyulog_sample_log_small.ulg`` and
``alfa_carbonZ_2018-07-18-15-53-31_1_engine_failure/``); ``--out`` defaults to the folder of
this script. See README.md here for the sources and the licences.

* ALFA CSVs: every row is kept; only the columns in ``ALFA_COLUMNS`` (and ``%time``) are kept,
  in their original order, each value copied as the same text. The source files have no
  quoting, so a line is split and joined on commas.
* PX4 ULogs: read with pyulog keeping only the topics in ``ULOG_TOPICS`` (every sample of
  them) and written back with ``ULog.write_ulog`` (pyulog >= 1.3). The header, formats, info,
  multi-info, parameter (initial, default, changed), logged-string and dropout messages are all
  written back. ``sensor_combined`` is dropped from the logs that also have
  ``vehicle_angular_velocity`` (their importer never reads it), to keep the copies small.

Each copy is checked after writing: the ALFA CSVs and the kept ULog topics hold the same
values as the originals (ULog: bitwise, with info, parameters and logged messages), and when
``uavdyn`` is importable, ``import_alfa`` / ``import_ulog(..., kinematic=False)`` give exactly
the same arrays for the copy as for the original.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ALFA_SEQUENCE = "alfa_carbonZ_2018-07-18-15-53-31_1_engine_failure"
ALFA_PREFIX = "carbonZ_2018-07-18-15-53-31_1_engine_failure-"
_XYZ, _XYZW = ("x", "y", "z"), ("x", "y", "z", "w")
ALFA_COLUMNS: dict[str, list[str] | None] = {  # file suffix: columns kept (None: all)
    "mavros-imu-data": [f"field.orientation.{c}" for c in _XYZW]
    + [f"field.angular_velocity.{c}" for c in _XYZ],
    "mavros-imu-data_raw": [f"field.angular_velocity.{c}" for c in _XYZ]
    + [f"field.linear_acceleration.{c}" for c in _XYZ],
    "mavros-local_position-odom": [f"field.pose.pose.position.{c}" for c in _XYZ]
    + [f"field.pose.pose.orientation.{c}" for c in _XYZW]
    + [f"field.twist.twist.linear.{c}" for c in _XYZ]
    + [f"field.twist.twist.angular.{c}" for c in _XYZ],
    "mavros-local_position-velocity": [f"field.twist.linear.{c}" for c in _XYZ],
    "mavros-nav_info-airspeed": ["field.measured", "field.commanded"],
    "mavros-nav_info-pitch": ["field.measured", "field.commanded"],
    "mavros-rc-out": [f"field.channels{i}" for i in range(8)],
    "mavros-vfr_hud": ["field.airspeed", "field.groundspeed", "field.throttle", "field.climb",
                       "field.altitude", "field.heading"],
    "mavros-state": ["field.mode", "field.armed"],
    "failure_status-engines": None,
}
ULOG_TOPICS = [
    "vehicle_attitude", "vehicle_angular_velocity", "vehicle_local_position",
    "vehicle_global_position", "sensor_combined", "control_state", "airspeed",
    "airspeed_validated", "wind", "wind_estimate", "vehicle_land_detected", "vehicle_status",
    "actuator_controls_0", "actuator_controls_1", "actuator_motors", "vehicle_thrust_setpoint",
    "vehicle_torque_setpoint", "actuator_outputs", "vehicle_rates_setpoint",
    "vehicle_attitude_setpoint",
]
ULOGS = {  # original name: shipped name
    "pyulog_sample_px4_events.ulg": "px4_sitl_hover.ulg",
    "pyulog_sample_log_small.ulg": "px4_vtol_ground_run.ulg",
}
# Not shipped: pyulog_sample.ulg (the 2016 log, would be px4_sample_2016.ulg). Its kept topics
# come to 2.8 MB (sensor_combined 1.2 MB, control_state 0.4 MB, vehicle_attitude 0.25 MB at
# 94 Hz over 69 s), more than the whole size budget of this folder; `--with-2016` writes it.
OPTIONAL_ULOGS = {"pyulog_sample.ulg": "px4_sample_2016.ulg"}


def trim_alfa_csv(src: Path, dst: Path, columns: list[str] | None) -> tuple[int, int]:
    """Copy ``src`` to ``dst`` keeping ``%time`` and ``columns`` (all when None); returns the
    number of data rows and of columns written."""
    lines = src.read_bytes().decode("utf-8").split("\n")
    if lines[-1] == "":
        lines.pop()
    header = lines[0].split(",")
    if columns is None:
        keep = list(range(len(header)))
    else:
        missing = [c for c in ["%time", *columns] if c not in header]
        if missing:
            raise SystemExit(f"{src}: missing columns {missing}")
        wanted = {"%time", *columns}
        keep = [i for i, c in enumerate(header) if c in wanted]
    out = []
    for n, line in enumerate(lines, start=1):
        if '"' in line or "\r" in line:
            raise SystemExit(f"{src}, line {n}: quoting or CR, not the plain layout expected")
        cells = line.split(",")
        if len(cells) != len(header):
            raise SystemExit(f"{src}, line {n}: {len(cells)} fields, header has {len(header)}")
        out.append(",".join(cells[i] for i in keep))
    dst.write_bytes(("\n".join(out) + "\n").encode("utf-8"))
    return len(lines) - 1, len(keep)


def trim_alfa(source: Path, out: Path) -> None:
    src_dir, dst_dir = source / ALFA_SEQUENCE, out / ALFA_SEQUENCE
    dst_dir.mkdir(parents=True, exist_ok=True)
    names = sorted(p.name for p in src_dir.glob("*.csv"))
    expected = sorted(f"{ALFA_PREFIX}{s}.csv" for s in ALFA_COLUMNS)
    if names != expected:
        raise SystemExit(f"{src_dir}: expected the files {expected}, found {names}")
    for suffix, columns in ALFA_COLUMNS.items():
        name = f"{ALFA_PREFIX}{suffix}.csv"
        rows, ncol = trim_alfa_csv(src_dir / name, dst_dir / name, columns)
        print(f"{ALFA_SEQUENCE}/{name}: {rows} rows, {ncol} columns, "
              f"{(dst_dir / name).stat().st_size} B")


def trim_ulog(src: Path, dst: Path) -> list[str]:
    """Write ``src`` to ``dst`` with only the kept topics; returns the topics written."""
    from pyulog import ULog

    original = ULog(str(src))
    present = {d.name for d in original.data_list}
    topics = [t for t in ULOG_TOPICS if t in present]
    if "vehicle_angular_velocity" in topics and "sensor_combined" in topics:
        topics.remove("sensor_combined")
    ULog(str(src), message_name_filter_list=topics).write_ulog(str(dst))
    check_ulog_copy(original, ULog(str(dst)), topics, dst)
    print(f"{dst.name} (from {src.name}): {dst.stat().st_size} B, "
          f"topics {', '.join(sorted(topics))}")
    return sorted(topics)


def check_ulog_copy(original, copy, topics: list[str], dst: Path) -> None:
    """The copy holds exactly the kept topics, each bitwise equal to the original's, and the
    same header, info, parameter, logged-string and dropout messages."""
    orig = {(d.name, d.multi_id): d for d in original.data_list if d.name in topics}
    kept = {(d.name, d.multi_id): d for d in copy.data_list}
    if set(kept) != set(orig):
        raise SystemExit(f"{dst}: wrote topics {sorted(kept)}, expected {sorted(orig)}")
    for key, d in orig.items():
        e = kept[key]
        if set(d.data) != set(e.data) or any(d.data[f].tobytes() != e.data[f].tobytes()
                                             for f in d.data):
            raise SystemExit(f"{dst}: topic {key} differs from the original")

    def logged(u):
        return [(m.timestamp, m.log_level, m.message) for m in u.logged_messages]

    same = {
        "start timestamp": original.start_timestamp == copy.start_timestamp,
        "info": original.msg_info_dict == copy.msg_info_dict,
        "multi info": original.msg_info_multiple_dict == copy.msg_info_multiple_dict,
        "initial parameters": original.initial_parameters == copy.initial_parameters,
        "default parameters": all(original.get_default_parameters(i)
                                  == copy.get_default_parameters(i) for i in range(2)),
        "changed parameters": original.changed_parameters == copy.changed_parameters,
        "logged messages": logged(original) == logged(copy),
        # a dropout message has no timestamp of its own: pyulog dates it by the last data
        # message before it, which may belong to a dropped topic, so only durations compare
        "dropouts": [m.duration for m in original.dropouts]
        == [m.duration for m in copy.dropouts],
    }
    bad = [k for k, ok in same.items() if not ok]
    if bad:
        raise SystemExit(f"{dst}: differs from the original in {', '.join(bad)}")


def check_imports(source: Path, out: Path, ulogs: dict[str, str]) -> None:
    """With uavdyn importable: each copy imports to exactly the original's arrays."""
    try:
        import numpy as np

        from uavdyn.flightdata import FlightDataError, import_ulog
        from uavdyn.flightdata.ulog import import_alfa
    except ImportError as exc:
        print(f"import check skipped: {exc}")
        return

    def same(a, b) -> bool:
        return all(np.array_equal(getattr(a, k), getattr(b, k))
                   for k in ("time", "states", "controls"))

    pairs = [(import_alfa(source / ALFA_SEQUENCE), import_alfa(out / ALFA_SEQUENCE),
              ALFA_SEQUENCE)]
    for original, shipped in ulogs.items():
        for kw in ({}, {"control_source": "setpoints"}, {"control_source": "motors"},
                   {"control_source": "actuator_controls"}):
            try:
                a = import_ulog(source / original, kinematic=False, **kw)
            except FlightDataError:  # a control source this log does not have
                continue
            pairs.append((a, import_ulog(out / shipped, kinematic=False, **kw),
                          f"{shipped} {kw or ''}"))
    for a, b, what in pairs:
        if not same(a, b):
            raise SystemExit(f"{what}: the copy imports to different arrays")
        print(f"{what}: imports to the same arrays as the original "
              f"({a.states.shape[0]} rows)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("source", type=Path, help="folder holding the original logs")
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent,
                        help="output folder (default: this script's folder)")
    parser.add_argument("--with-2016", action="store_true",
                        help="also write px4_sample_2016.ulg (2.8 MB, not shipped)")
    args = parser.parse_args(argv)
    if not args.source.is_dir():
        raise SystemExit(f"{args.source}: not a folder")
    args.out.mkdir(parents=True, exist_ok=True)
    ulogs = {**ULOGS, **(OPTIONAL_ULOGS if args.with_2016 else {})}
    trim_alfa(args.source, args.out)
    for original, shipped in ulogs.items():
        trim_ulog(args.source / original, args.out / shipped)
    check_imports(args.source, args.out, ulogs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
