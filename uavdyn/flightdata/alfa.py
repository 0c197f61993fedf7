"""Import of ALFA fixed-wing sequence folders (MAVROS topic CSVs) into a Sortie.

Each topic is the folder's one ``*-<topic>.csv`` file (``rostopic echo -p`` layout), which must
be a regular file of at most :data:`MAX_ALFA_CSV_BYTES` resolving inside the folder (no
escaping symlinks). Every malformed topic CSV raises :class:`FlightDataError` naming the file
(and its row and column where they apply); the resampled arrays then go through the same
:func:`check_values` as CSV data.
"""

from __future__ import annotations

import csv
import io
import math
import os
import stat
from pathlib import Path

import numpy as np

from uavdyn.flightdata.attitude import (
    _first_non_unit,
    pitch_from_quaternion,
    roll_from_quaternion,
)
from uavdyn.flightdata.control_map import ChannelMap, check_channel, override
from uavdyn.flightdata.csvio import parse_number
from uavdyn.flightdata.errors import FlightDataError
from uavdyn.flightdata.fast_grid import fastest_grid, gyro_aided_attitude
from uavdyn.flightdata.files import _read_regular, _utf8_text
from uavdyn.flightdata.flightlog import FlightLog
from uavdyn.flightdata.import_checks import (
    _as_path,
    _check_bool,
    _check_name,
    _check_rate,
    _checked,
)
from uavdyn.flightdata.resample import (
    _grid,
    _hold,
    _interp,
    _quaternions_on_grid,
    commands_on_grid,
    in_gap,
    states_on_grid,
)
from uavdyn.flightdata.sortie import Sortie
from uavdyn.flightdata.speed_check import check_speed_scale
from uavdyn.model import CONTROL_BOUNDS

MAX_ALFA_CSV_BYTES = 512 * 1024**2  # the same for each ALFA topic CSV (real ones are < 1 MB)
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

    def __init__(self, path: Path, t_ns: np.ndarray, vals: np.ndarray,
                 fields: list[str] | None = None) -> None:
        self.path, self.t_ns, self.vals, self.fields = path, t_ns, vals, fields or []


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


def _alfa_topic(folder: Path, root: Path, suffix: str, fields: list[str],
                optional: tuple[str, ...] = ()) -> _AlfaTopic:
    """Read the fields of one topic CSV (``rostopic echo -p`` layout) with every check: text,
    header, one value per column in every row, integer strictly increasing ``%time``, finite
    ASCII numbers, at least 2 rows. The ``optional`` fields the header has are read too
    (after ``fields``; ``.fields`` lists what was read)."""
    path = _alfa_file(folder, root, suffix)
    raw = _read_regular(path, path, MAX_ALFA_CSV_BYTES)
    if not raw.strip():
        raise FlightDataError("empty file: expected a header row and data rows", path)
    text = _utf8_text(raw, path, "CSV", detail="")
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
        fields = [*fields, *(f for f in optional if header.count(f) == 1)]
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
                    v = parse_number(row[i].strip(" \t"))
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
    return _AlfaTopic(path, t_ns, np.array(rows, dtype=float), fields)


def _check_alfa_ranges(topics: dict[str, _AlfaTopic]) -> None:
    """Source values the mapping cannot take (the one channel check,
    :func:`~uavdyn.flightdata.control_map.check_channel`): elevator PWM outside the servo
    range of +-30 deg, throttle outside 0..1 (named in their file, not as grid rows)."""
    max_defl = CONTROL_BOUNDS["fixed_wing"][0][1]
    for key, m in (("servo", ChannelMap("elevator", "field.channels1", *ALFA_PWM_RANGE,
                                        -max_defl, max_defl)),
                   ("hud", ChannelMap("throttle", "field.throttle", 0.0, 1.0, 0.0, 1.0))):
        check_channel(m, topics[key].vals[:, 0], topics[key].path)


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
        Fixed wing, ``mission='alfa'``, time from 0 s on the grid.

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
    first = _first_non_unit(imu.vals)
    if first is not None:
        k, norm = first
        raise FlightDataError(f"orientation (w, x, y, z) has norm {norm:.6g}, not a unit "
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


ALFA_FLIGHT_TOPICS: dict[str, tuple[str, list[str]]] = {  # six-degree-of-freedom channels
    "imu": ("mavros-imu-data", [f"field.orientation.{c}" for c in "wxyz"]),
    "gyro": ("mavros-imu-data_raw", [f"field.angular_velocity.{c}" for c in "xyz"]),
    "odom": ("mavros-local_position-odom", [f"field.twist.twist.linear.{c}" for c in "xyz"]),
    "servo": ("mavros-rc-out", ["field.channels1"]),
    "hud": ("mavros-vfr_hud", ["field.throttle", "field.altitude"]),
    "airspeed": ("mavros-nav_info-airspeed", ["field.measured"]),
}


ALFA_ACCELEROMETER = tuple(f"field.linear_acceleration.{c}" for c in "xyz")  # raw IMU, FLU


def _alfa_speed_check(folder: Path, topics: dict[str, _AlfaTopic], grid: np.ndarray,
                      raw_imu: np.ndarray, channels: dict[str, np.ndarray]) -> dict | None:
    """The speed-scale check (:mod:`uavdyn.flightdata.speed_check`) where the raw IMU topic
    has its accelerometer (FLU, turned to FRD here); None where it has not."""
    if topics["gyro"].vals.shape[1] < 6:
        return None
    force = raw_imu[:, 3:6] * np.array([1.0, -1.0, -1.0])
    sources = {"u": f"{topics['airspeed'].path.name} field.measured (u)",
               "w": f"{topics['odom'].path.name} field.twist.twist.linear.z (w)"}
    return check_speed_scale(folder, grid, channels, force, sources)


ALFA_SERVO_MAP = (1100.0, 1900.0, -0.35, 0.35)  # ArduPlane's default servo range, +-20 deg


def default_alfa_maps() -> dict[str, ChannelMap]:
    """The default maps of :func:`read_alfa_flight`. The elevator's is an inference, stated:
    servo 2 over ArduPlane's default range (SERVO2_MIN/MAX 1100/1900 us, trim 1500 us = 0) to
    +-0.35 rad (a usual model elevator throw; the log records neither), PWM above trim taken
    as trailing edge down (the command correlates negatively with pitch rate)."""
    return {"elevator": ChannelMap("elevator", "mavros-rc-out/field.channels1",
                                   *ALFA_SERVO_MAP),
            "throttle": ChannelMap("throttle", "mavros-vfr_hud/field.throttle", 0.0, 1.0,
                                   0.0, 1.0)}


def read_alfa_flight(folder: str | Path, rate_hz: float | None = None, name: str | None = None,
                     control_maps: list[ChannelMap] | None = None) -> FlightLog:
    """Read an ALFA sequence folder as a six-degree-of-freedom flight on a uniform grid.

    MAVROS frames converted to aircraft ones (FLU body, ENU world -> FRD, NED): roll as
    logged, nose-up pitch = -pitch of the ENU/FLU quaternion, ``p, q, r = x, -y, -z`` of the
    raw gyro, ``u, v, w = x, -y, -z`` of the odometry twist (ground relative); ``u`` from the
    airspeed sensor (``nav_info-airspeed.measured``) as ``sqrt(Va^2 - w^2)``; altitude from
    ``vfr_hud.altitude`` (MSL). The log has no in-air flag: the segmenter's speed floor stands
    in for it. Samples in a topic's gap are NaN.

    The grid follows the fastest body-rate topic, the raw gyro (``mavros-imu-data_raw``,
    about 10 Hz), and roll and pitch between the attitude samples (2.5 Hz) come from the
    integrated gyro (:mod:`uavdyn.flightdata.fast_grid`); ``meta['grid']`` says which topic
    set the rate and every topic's rate.

    Parameters
    ----------
    folder : str or Path
        The sequence folder.
    rate_hz : float, optional
        Grid rate (default: the raw gyro's rate, :func:`~uavdyn.flightdata.fast_grid.fastest_grid`).
    name : str, optional
        Flight name (default the folder name).
    control_maps : list of ChannelMap, optional
        Replace a default map; ``source`` is ``<topic suffix>/<field>``, e.g.
        ``mavros-rc-out/field.channels1``.

    Returns
    -------
    FlightLog
    """
    folder = _as_path(folder, "folder")
    _check_rate(rate_hz, folder, allow_none=True)
    _check_name(name, folder)
    if not folder.is_dir():
        raise FlightDataError("not an ALFA sequence folder (not a folder)", folder)
    root = Path(os.path.realpath(folder))
    maps = override(default_alfa_maps(), control_maps)
    wanted = dict(ALFA_FLIGHT_TOPICS)
    for control, m in maps.items():
        suffix, _, field_name = m.source.partition("/")
        if not field_name:
            raise FlightDataError(f"control map for {control}: source {m.source!r} must be "
                                  "<topic suffix>/<field>, e.g. mavros-rc-out/field.channels1",
                                  folder)
        wanted[f"control:{control}"] = (suffix, [field_name])
    topics = {key: _alfa_topic(folder, root, suffix, fields,
                               ALFA_ACCELEROMETER if key == "gyro" else ())
              for key, (suffix, fields) in wanted.items()}
    for control, m in maps.items():
        got = topics[f"control:{control}"]
        check_channel(m, got.vals[:, 0], got.path, column=got.fields[0])
    first = _first_non_unit(topics["imu"].vals)
    if first is not None:
        raise FlightDataError(f"orientation (w, x, y, z) has norm {first[1]:.6g}, not a unit "
                              "quaternion", topics["imu"].path, first[0] + 1, "field.orientation")
    origin = min(int(tp.t_ns[0]) for tp in topics.values())
    rel = {key: (tp.t_ns - origin) * 1e-9 for key, tp in topics.items()}
    t0 = max(float(rel[k][0]) for k in ("imu", "gyro", "odom"))
    t1 = min(float(rel[k][-1]) for k in ("imu", "gyro", "odom"))
    choice = fastest_grid({wanted[k][0]: rel[k] for k in ALFA_FLIGHT_TOPICS},
                          (wanted["gyro"][0],), wanted["imu"][0], rate_hz=rate_hz)
    grid = _grid(t0, t1, choice.rate_hz, folder)

    def on_grid(key: str, hold: bool = False) -> np.ndarray:
        return (commands_on_grid if hold else states_on_grid)(grid, rel[key], topics[key].vals)

    gyro, vel = on_grid("gyro"), on_grid("odom")
    if choice.gyro_aided:
        quats = topics["imu"].vals
        roll, pitch = gyro_aided_attitude(grid, rel["imu"], roll_from_quaternion(quats),
                                          -pitch_from_quaternion(quats), gyro[:, 0],
                                          -gyro[:, 1], -gyro[:, 2])
    else:
        quat = _quaternions_on_grid(grid, rel["imu"], topics["imu"].vals)
        roll, pitch = roll_from_quaternion(quat), -pitch_from_quaternion(quat)
    att_gap = in_gap(grid, rel["imu"])
    roll[att_gap] = pitch[att_gap] = np.nan
    va = on_grid("airspeed")[:, 0]
    w = -vel[:, 2]
    with np.errstate(invalid="ignore"):
        u = np.sqrt(np.maximum(va**2 - w**2, 0.0))
    controls = np.column_stack([maps[c].apply(on_grid(f"control:{c}", hold=True)[:, 0])
                                for c in ("elevator", "throttle")])
    channels = {"roll": roll, "pitch": pitch, "p": gyro[:, 0], "q": -gyro[:, 1],
                "r": -gyro[:, 2], "u": u, "v": -vel[:, 1], "w": w}
    meta = {"file": str(folder), "start_time_s": origin * 1e-9 + t0, "rate_hz": choice.rate_hz,
            "speed_check": _alfa_speed_check(folder, topics, grid, gyro, channels),
            "files": {key: str(tp.path) for key, tp in topics.items()}, "grid": choice.reason,
            "topic_rates_hz": choice.topic_rates_hz,
            "sources": {"roll,pitch": "mavros-imu-data orientation (pitch negated: ENU/FLU)"
                        + (", between its samples the integrated raw gyro"
                           if choice.gyro_aided else ""),
                        "p,q,r": "mavros-imu-data_raw angular_velocity x, -y, -z",
                        "v,w": "mavros-local_position-odom twist -y, -z (ground relative)",
                        "u": "sqrt(Va^2 - w^2), Va = mavros-nav_info-airspeed measured",
                        "altitude_m": "mavros-vfr_hud altitude (MSL)"},
            "control_map": {k: m.describe() for k, m in maps.items()},
            "resampling": f"topics (2.5-19 Hz) on a uniform {choice.rate_hz:g} Hz grid: "
                          + ("attitude gyro-aided between its samples, " if choice.gyro_aided
                             else "") + "states linear, controls held; NaN in topic gaps"}
    return FlightLog(name=name or root.name, kind="fixed_wing", time=grid - grid[0],
                     channels=channels, controls=controls, velocity_reference="airspeed",
                     source="ALFA (MAVROS CSV)", altitude_m=on_grid("hud")[:, 1], airspeed=va,
                     meta=meta)
