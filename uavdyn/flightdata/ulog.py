"""Import of PX4 ULog files into a Sortie on a uniform time grid.

PX4 ULog, per the conventions of ``shared/data/flightlogs/README.md``:

* pitch ``theta = asin(2 (q0 q2 - q3 q1))`` from ``vehicle_attitude.q`` (FRD body to NED);
* pitch rate from ``vehicle_angular_velocity.xyz[1]``, else ``vehicle_attitude.pitchspeed``,
  else ``sensor_combined.gyro_rad[1]``;
* body velocities ``[u, v, w] = R(q)^T [vx, vy, vz]`` from ``vehicle_local_position`` (ground
  relative, no wind correction);
* multirotor controls: ``actuator_controls_0`` (control[3] thrust -> collective, control[1] ->
  pitch_cmd), else ``vehicle_thrust_setpoint``/``vehicle_torque_setpoint`` (PX4 >= 1.14), else
  ``actuator_motors`` (X frame: collective = mean, pitch_cmd = (front - rear) / (2 pitch_mix));
  fixed-wing controls from ``actuator_controls_1`` (elevator = -control[1] x 30 deg, since PX4's
  positive pitch command is nose up and this product's positive elevator is nose down);
* stray samples (timestamp 0, or a block far from the rest) are cut off each topic and the
  count is recorded in ``sortie.meta``; a stamp far from its neighbours inside a topic is
  corruption (flipped bytes) and is refused with its byte offset; all signals are resampled
  to one uniform grid over the time span common to the topics used: states by linear
  interpolation (quaternions normalised), controls by zero-order hold (they are commands).

Reliability (SPEC section 9): the file is read and its framing checked by :mod:`.ulog_format`;
non-finite or non-unit source samples raise :class:`FlightDataError` naming the file (and
topic, field or option), and the imported arrays then go through the same
:func:`check_values` as CSV data. The ALFA importer and the helpers this module was split into
stay importable from here.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from uavdyn.flightdata.alfa import (
    ALFA_GRID_TOPICS,
    ALFA_PWM_RANGE,
    ALFA_TIME,
    ALFA_TOPICS,
    MAX_ALFA_CSV_BYTES,
    import_alfa,
)
from uavdyn.flightdata.attitude import (
    QUATERNION_NORM_TOLERANCE,
    _first_non_unit,
    pitch_from_quaternion,
    roll_from_quaternion,
    rotation_matrices,
)
from uavdyn.flightdata.diagnostics import integrated_pitch_rms, summary
from uavdyn.flightdata.errors import FlightDataError
from uavdyn.flightdata.import_checks import (
    MAX_RATE_HZ,
    _as_path,
    _check_bool,
    _check_name,
    _check_rate,
    _checked,
    _finite_real,
)
from uavdyn.flightdata.resample import (
    HOLD_TOLERANCE_S,
    MAX_GRID_ROWS,
    _grid,
    _hold,
    _interp,
    _quaternions_on_grid,
    main_block,
    states_on_grid,
)
from uavdyn.flightdata.sortie import Sortie
from uavdyn.flightdata.speed_check import check_speed_scale
from uavdyn.flightdata.ulog_format import (
    _MAX_STAMP_US,
    MAX_FORMAT_DEPTH,
    MAX_TOPIC_FIELDS,
    MAX_TOTAL_FIELDS,
    MAX_ULOG_BYTES,
    ULOG_MAGIC,
    ULOG_TOPICS,
    ULOG_VERSIONS,
    _read_ulog,
    log_content,
    topic_names,
)
from uavdyn.model import CONTROL_BOUNDS

__all__ = [
    "ALFA_GRID_TOPICS", "ALFA_PWM_RANGE", "ALFA_TIME", "ALFA_TOPICS", "CONTROL_SOURCES",
    "FIXED_WING_MAV_TYPES", "HOLD_TOLERANCE_S", "MAX_ALFA_CSV_BYTES", "MAX_FORMAT_DEPTH",
    "MAX_GRID_ROWS", "MAX_RATE_HZ", "MAX_TOPIC_FIELDS", "MAX_TOTAL_FIELDS", "MAX_ULOG_BYTES",
    "PX4_QUAD_X_FRONT", "PX4_QUAD_X_REAR", "QUATERNION_NORM_TOLERANCE", "ULOG_MAGIC",
    "ULOG_TOPICS", "ULOG_VERSIONS", "import_alfa", "import_ulog", "integrated_pitch_rms",
    "main_block", "pitch_from_quaternion", "roll_from_quaternion", "rotation_matrices",
    "summary",
]

PX4_QUAD_X_FRONT = (0, 2)  # PX4 quad X motor order: 1 front-right, 2 rear-left, 3 front-left,
PX4_QUAD_X_REAR = (1, 3)   # 4 rear-right (0-based here)
FIXED_WING_MAV_TYPES = {1}  # MAV_TYPE_FIXED_WING; VTOLs are imported as multirotors by default
CONTROL_SOURCES = ("auto", "actuator_controls", "setpoints", "motors")


class _Topics:
    """Access to the topics of one parsed ULog, each cut to its main block of samples."""

    def __init__(self, ulog, path: Path,
                 offsets: dict[tuple[str, int], list[int]] | None = None) -> None:
        self.ulog, self.path, self.offsets = ulog, path, offsets or {}
        self.origin_us = int(ulog.start_timestamp)
        self.dropped: dict[str, int] = {}
        self.duplicates: dict[str, int] = {}

    def get(self, name: str, fields: list[str], multi_id: int = 0
            ) -> tuple[np.ndarray, np.ndarray] | None:
        """``(t seconds from log start, values N x len(fields))`` of a topic cut to its main
        block of samples, or None when the topic, a field or two usable samples are absent.
        A non-finite value among the used samples raises (naming topic and field)."""
        for d in self.ulog.data_list:
            if d.name == name and d.multi_id == multi_id:
                if "timestamp" not in d.data or not all(f in d.data for f in fields):
                    return None
                raw_stamps = d.data["timestamp"]
                keep = main_block(raw_stamps)
                if len(keep) < 2:
                    return None
                _check_time_order(raw_stamps, keep, name, self.path)
                self._check_inner_strays(raw_stamps, keep, name, multi_id)
                if int(raw_stamps[keep].max()) >= _MAX_STAMP_US:
                    raise FlightDataError(f"corrupt timestamp {int(raw_stamps[keep].max())} us",
                                          self.path, column=f"{name}.timestamp")
                self.dropped[name] = len(raw_stamps) - len(keep)
                # integer microseconds relative to the log start, then seconds: epoch-based
                # (SITL) stamps would lose precision as floats
                stamps = raw_stamps[keep].astype(np.int64) - np.int64(self.origin_us)
                t = stamps.astype(float) * 1e-6
                t, first = np.unique(t, return_index=True)  # duplicated stamps: first sample
                if len(t) < 2:
                    return None
                if len(t) < len(keep):
                    self.duplicates[name] = len(keep) - len(t)
                vals = np.column_stack([d.data[f][keep].astype(float) for f in fields])[first]
                bad = np.argwhere(~np.isfinite(vals))
                if len(bad):
                    k, j = (int(i) for i in bad[0])
                    raise FlightDataError(
                        f"non-finite value {vals[k, j]} in topic '{name}', field '{fields[j]}' "
                        f"(used sample {k + 1}, t = {t[k]:.6f} s from the log start)",
                        self.path, column=f"{name}.{fields[j]}")
                return t, vals
        return None


    def _check_inner_strays(self, raw_stamps: np.ndarray, keep: np.ndarray, name: str,
                            multi_id: int) -> None:
        """Refuse a sample cut as stray that lies among the kept ones in the file (a stamp
        far from its neighbours in the middle of a topic: flipped or overwritten bytes, not
        the zero stamps and far blocks at the ends that PX4 logs carry), naming its byte."""
        inside = np.zeros(len(raw_stamps), bool)
        inside[int(keep.min()):int(keep.max()) + 1] = True
        inside[keep] = False
        inside &= raw_stamps != 0
        if not inside.any():
            return
        k = int(np.flatnonzero(inside)[0])
        offsets = self.offsets.get((name, multi_id), [])
        at = f" at byte {offsets[k]}" if k < len(offsets) else ""
        raise FlightDataError(f"corrupt ULog file: data message {k + 1} of topic {name}"
                              f"{at} has timestamp {int(raw_stamps[k])} us, far from the "
                              "samples around it (flipped or overwritten bytes)", self.path,
                              column=f"{name}.timestamp")


def _check_unit(q: np.ndarray, t: np.ndarray, path: Path) -> None:
    """Refuse attitude quaternions that are not unit length (:func:`_first_non_unit`)."""
    first = _first_non_unit(q)
    if first is not None:
        k, norm = first
        raise FlightDataError(f"vehicle_attitude.q has norm {norm:.6g}, not a unit "
                              f"quaternion (used sample {k + 1}, t = {t[k]:.6f} s)", path,
                              column="vehicle_attitude.q")


def _vehicle_kind(ulog) -> str:
    """``fixed_wing`` for the log's MAV_TYPE in FIXED_WING_MAV_TYPES, else ``multirotor``."""
    mav_type = ulog.initial_parameters.get("MAV_TYPE")
    return "fixed_wing" if mav_type in FIXED_WING_MAV_TYPES else "multirotor"


def _mean_rate(t: np.ndarray) -> float:
    """Mean sample rate (Hz) of the sample times ``t`` (s)."""
    return (len(t) - 1) / (t[-1] - t[0])


def _check_ulog_options(path: Path, rate_hz: object, kind: object, pitch_mix: object,
                        control_source: object, name: object, flags: dict[str, object]
                        ) -> None:
    """The options of :func:`import_ulog`, checked before the file is read; ``flags`` are
    the True/False options by name."""
    _check_rate(rate_hz, path, allow_none=True)
    if kind is not None and not isinstance(kind, str):
        raise FlightDataError(f"option kind must be a string {tuple(CONTROL_BOUNDS)} or None, "
                              f"got {kind!r}", path)
    if kind is not None and kind not in CONTROL_BOUNDS:
        raise FlightDataError(f"unknown kind '{kind}' (option kind must be one of "
                              f"{tuple(CONTROL_BOUNDS)})", path)
    if not _finite_real(pitch_mix) or not float(pitch_mix) > 0:
        raise FlightDataError(f"option pitch_mix must be a finite number > 0, got "
                              f"{pitch_mix!r}", path)
    if not isinstance(control_source, str) or control_source not in CONTROL_SOURCES:
        raise FlightDataError(f"option control_source must be one of {CONTROL_SOURCES}, got "
                              f"{control_source!r}", path)
    _check_name(name, path)
    for option, value in flags.items():
        _check_bool(value, option, path)


def _check_time_order(raw_stamps: np.ndarray, keep: np.ndarray, name: str, path: Path) -> None:
    """Refuse a topic whose used samples go back in time in the file (a corrupt or spliced log:
    sorting them would silently reorder the flight)."""
    in_file_order = np.sort(keep)
    stamps = raw_stamps[in_file_order].astype(np.int64)
    back = np.flatnonzero(np.diff(stamps) < 0)
    if len(back):
        k = int(back[0])
        raise FlightDataError(
            f"timestamps of topic '{name}' go backwards at its sample {int(in_file_order[k + 1])}"
            f" ({int(stamps[k + 1])} us after {int(stamps[k])} us): a log's samples are in time "
            "order, so the log is corrupt or spliced", path, column=f"{name}.timestamp")


def _state_topics(topics: _Topics, path: Path) -> tuple[tuple, tuple, tuple, dict[str, str]]:
    """The attitude, pitch-rate and velocity samples (each ``(t, values)``) and the source of
    each state, from the first topic present of each."""
    sources: dict[str, str] = {}
    att = topics.get("vehicle_attitude", [f"q[{i}]" for i in range(4)])
    if att is None:
        raise FlightDataError("no usable vehicle_attitude.q topic (at least 2 samples): cannot "
                              "compute pitch", path, column="theta")
    _check_unit(att[1], att[0], path)
    sources["theta"] = "vehicle_attitude.q"
    rate = None
    for topic, field in (("vehicle_angular_velocity", "xyz[1]"),
                         ("vehicle_attitude", "pitchspeed"),
                         ("sensor_combined", "gyro_rad[1]")):
        rate = topics.get(topic, [field])
        if rate is not None:
            sources["q"] = f"{topic}.{field}"
            break
    if rate is None:
        raise FlightDataError("no pitch-rate topic (vehicle_angular_velocity, "
                              "vehicle_attitude.pitchspeed or sensor_combined.gyro_rad)", path,
                              column="q")
    vel = topics.get("vehicle_local_position", ["vx", "vy", "vz"])
    if vel is None:
        raise FlightDataError("no usable vehicle_local_position.vx/vy/vz: cannot compute u, w",
                              path, column="u")
    sources["u,w"] = "vehicle_local_position.vx/vy/vz rotated by vehicle_attitude.q"
    return att, rate, vel, sources


def _ulog_grid(used: list[tuple], rate_hz: float | None, path: Path) -> tuple[np.ndarray, float]:
    """The uniform grid over the time span the ``used`` topics share (the attitude topic
    first), at ``rate_hz`` or else the attitude topic's mean rate rounded to 1 Hz."""
    t0 = max(u[0][0] for u in used)
    t1 = min(u[0][-1] for u in used)
    if not t1 > t0:
        raise FlightDataError("the attitude, rate, velocity and control topics share no time "
                              "span", path, column="time")
    if rate_hz is None:
        rate_hz = max(1.0, round(_mean_rate(used[0][0])))
        if rate_hz > MAX_RATE_HZ:
            raise FlightDataError(f"the attitude topic's mean rate {rate_hz:g} Hz is above "
                                  f"{MAX_RATE_HZ:g} Hz (corrupt timestamps?); pass rate_hz",
                                  path, column="time")
    rate_hz = float(rate_hz)
    return _grid(t0, t1, rate_hz, path), rate_hz


def _ulog_states(grid: np.ndarray, att: tuple, rate: tuple, vel: tuple
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The states ``u, w, q, theta`` on the grid, the attitude quaternions there and the body
    velocities ``u, v, w``."""
    quat = _quaternions_on_grid(grid, *att)
    theta = pitch_from_quaternion(quat)
    q = _interp(grid, *rate)[:, 0]
    v_ned = _interp(grid, *vel)
    v_body = np.einsum("nji,nj->ni", rotation_matrices(quat), v_ned)
    return np.column_stack([v_body[:, 0], v_body[:, 2], q, theta]), quat, v_body


ACCELEROMETER = ("sensor_combined", [f"accelerometer_m_s2[{i}]" for i in range(3)])


def ulog_speed_check(topics: _Topics, grid: np.ndarray, channels: dict[str, np.ndarray],
                     source: str, path: Path) -> dict | None:
    """The speed-scale check (:mod:`uavdyn.flightdata.speed_check`) against
    ``sensor_combined.accelerometer_m_s2`` (FRD specific force) where the log has it (a
    non-finite accelerometer sample leaves the check out, as any optional channel)."""
    try:
        found = topics.get(*ACCELEROMETER)
    except FlightDataError:
        found = None
    if found is None:
        return None
    return check_speed_scale(path, grid, channels, states_on_grid(grid, *found), {"u": source})


def import_ulog(path: str | Path, rate_hz: float | None = None, kind: str | None = None,
                pitch_mix: float = 0.1, name: str | None = None,
                control_source: str = "auto", *, check: bool = True, kinematic: bool = True,
                allow_truncated: bool = False) -> Sortie:
    """Read a PX4 ULog file into a :class:`Sortie` on a uniform grid.

    Channel sources, topic rates, cut stray samples and duplicated stamps are recorded in
    ``meta``; the result passes :func:`check_values` (the same checks as CSV data) unless
    the caller opts out.

    Parameters
    ----------
    path : str or Path
        The ``.ulg`` file; must be a regular file of at most ``MAX_ULOG_BYTES``.
    rate_hz : float, optional
        Grid rate in (0, ``MAX_RATE_HZ``]; default the attitude topic's mean rate rounded to
        1 Hz.
    kind : {'fixed_wing', 'multirotor'}, optional
        Default from the log's MAV_TYPE (fixed wing for MAV_TYPE 1, else multirotor).
    pitch_mix : float
        Finite, > 0: maps motor outputs to pitch_cmd when only motor commands are logged.
    name : str, optional
        Sortie name (default: the file stem).
    control_source : {'auto', 'actuator_controls', 'setpoints', 'motors'}
        Forces one multirotor control source instead of the first one present.
    check : bool
        Run :func:`check_values` on the result (default True).
    kinematic : bool
        Include its pitch-plane kinematic check ``d theta/dt ~ q`` (default True). Pass False
        for logs whose motion is not in the pitch plane (hand-moved, banked turns), where
        ``d theta/dt = q cos(roll) - r sin(roll)`` legitimately differs from q.
    allow_truncated : bool
        Import the complete messages of a cut file (``meta['truncated_at_byte']`` says where)
        instead of raising (default False).

    Returns
    -------
    Sortie
        ``mission='ulog'``, controls held on the grid, roll and provenance in ``meta``.

    Raises
    ------
    FlightDataError
        One line naming the file (and topic/field or option) for anything wrong: unreadable,
        cut or corrupt file, missing topic, non-finite or non-unit samples, no common time
        span, bad options, failed value checks.
    ImportError
        When the optional dependency pyulog is not installed.
    """
    path = _as_path(path, "path")
    _check_ulog_options(path, rate_hz, kind, pitch_mix, control_source, name,
                        {"check": check, "kinematic": kinematic,
                         "allow_truncated": allow_truncated})
    ulog, truncated_at, parser_messages, framing = _read_ulog(path, allow_truncated)
    topics = _Topics(ulog, path, framing.offsets)
    kind = kind or _vehicle_kind(ulog)
    att, rate, vel, sources = _state_topics(topics, path)
    controls, control_sources = _controls(topics, kind, float(pitch_mix), path, control_source)
    sources.update(control_sources)
    grid, rate_hz = _ulog_grid([att, rate, vel, controls], rate_hz, path)
    states, quat, v_body = _ulog_states(grid, att, rate, vel)
    ctrl = _hold(grid, *controls)
    time = np.arange(len(grid)) / rate_hz
    if check:
        _checked(path, kind, time, states, ctrl, rate_hz, kinematic)
    zero = np.zeros(len(grid))   # p and r are not read here (their terms are small)
    speed = ulog_speed_check(topics, grid, {
        "roll": roll_from_quaternion(quat), "pitch": states[:, 3], "p": zero, "q": states[:, 2],
        "r": zero, "u": v_body[:, 0], "v": v_body[:, 1], "w": v_body[:, 2]}, sources["u,w"],
        path)
    meta = {
        "file": str(path), "source": "PX4 ULog", "sources": sources,
        "start_time_s": float(grid[0]) + topics.origin_us * 1e-6, "rate_hz": rate_hz,
        "topic_rates_hz": {key: round(_mean_rate(v[0]), 1)
                           for key, v in (("attitude", att), ("pitch_rate", rate),
                                          ("velocity", vel), ("controls", controls))},
        "stray_samples_cut": {k: v for k, v in topics.dropped.items() if v},
        "duplicate_stamps": dict(topics.duplicates),
        "truncated_at_byte": truncated_at,
        "parser_messages": parser_messages, "speed_check": speed,
        **log_content(ulog, topic_names(sources.values())),
        "checked": {"values": check, "kinematic": bool(check and kinematic)},
        "roll": roll_from_quaternion(quat),
        "sys_name": ulog.msg_info_dict.get("sys_name", ""),
        "ver_hw": ulog.msg_info_dict.get("ver_hw", ""),
        "mav_type": ulog.initial_parameters.get("MAV_TYPE"),
    }
    return Sortie(name=name or path.stem, kind=kind, time=time,
                  states=states, controls=ctrl, mission="ulog", meta=meta)


def _controls(topics: _Topics, kind: str, pitch_mix: float, path: Path, source: str = "auto"
              ) -> tuple[tuple[np.ndarray, np.ndarray], dict[str, str]]:
    if kind == "fixed_wing":
        c = topics.get("actuator_controls_1", ["control[1]", "control[3]"])
        if c is None:
            raise FlightDataError("no actuator_controls_1 (fixed-wing pitch and throttle "
                                  "commands)", path, column="elevator")
        max_defl = CONTROL_BOUNDS["fixed_wing"][0][1]
        vals = np.column_stack([-c[1][:, 0] * max_defl, c[1][:, 1]])
        return (c[0], vals), {"elevator": "-actuator_controls_1.control[1] x 30 deg",
                              "throttle": "actuator_controls_1.control[3]"}

    def wanted(name):
        return source in ("auto", name)

    c = topics.get("actuator_controls_0", ["control[3]", "control[1]"]) \
        if wanted("actuator_controls") else None
    if c is not None:
        return c, {"collective": "actuator_controls_0.control[3]",
                   "pitch_cmd": "actuator_controls_0.control[1]"}
    thrust = topics.get("vehicle_thrust_setpoint", ["xyz[2]"]) if wanted("setpoints") else None
    torque = topics.get("vehicle_torque_setpoint", ["xyz[1]"]) if wanted("setpoints") else None
    if thrust is not None and torque is not None:
        t = np.union1d(thrust[0], torque[0])
        vals = np.column_stack([-_hold(t, *thrust)[:, 0], _hold(t, *torque)[:, 0]])
        return (t, vals), {"collective": "-vehicle_thrust_setpoint.xyz[2]",
                           "pitch_cmd": "vehicle_torque_setpoint.xyz[1]"}
    motors = topics.get("actuator_motors", [f"control[{i}]" for i in range(4)]) \
        if wanted("motors") else None
    if motors is not None:
        m = motors[1]
        front = m[:, list(PX4_QUAD_X_FRONT)].mean(axis=1)
        rear = m[:, list(PX4_QUAD_X_REAR)].mean(axis=1)
        vals = np.column_stack([m.mean(axis=1), (front - rear) / (2 * pitch_mix)])
        return (motors[0], vals), {"collective": "mean of actuator_motors.control[0..3]",
                                   "pitch_cmd": "(front - rear motors)/(2 pitch_mix), quad X"}
    what = "actuator_controls_0, vehicle_thrust/torque_setpoint or actuator_motors" \
        if source == "auto" else f"the requested control source '{source}'"
    raise FlightDataError(f"no multirotor control topic ({what})", path, column="collective")
