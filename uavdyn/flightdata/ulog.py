"""Import of real flight logs into the :class:`uavdyn.flightdata.Sortie` type: PX4 ULog files
(through the optional ``pyulog`` package) and the ALFA fixed-wing CSV folders (MAVROS topics).

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
  count is recorded in ``sortie.meta``; all signals are resampled to one uniform grid over the
  time span common to the topics used: states by linear interpolation (quaternions
  normalised), controls by zero-order hold (they are commands).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from uavdyn.flightdata.dataset import FlightDataError, Sortie
from uavdyn.model import CONTROL_BOUNDS

PX4_QUAD_X_FRONT = (0, 2)  # PX4 quad X motor order: 1 front-right, 2 rear-left, 3 front-left,
PX4_QUAD_X_REAR = (1, 3)   # 4 rear-right (0-based here)
FIXED_WING_MAV_TYPES = {1}  # MAV_TYPE_FIXED_WING; VTOLs are imported as multirotors by default
CONTROL_SOURCES = ("auto", "actuator_controls", "setpoints", "motors")


def _require_pyulog():
    try:
        import pyulog
    except ImportError:  # pragma: no cover - depends on the environment
        raise ImportError("importing ULog files needs the optional dependency pyulog: "
                          "pip install 'uavdyn[ulog]' (or pip install pyulog)") from None
    return pyulog


def pitch_from_quaternion(q: np.ndarray) -> np.ndarray:
    """Pitch (rad) of FRD-to-NED quaternions ``N x 4`` (w, x, y, z): ``asin(2(q0q2 - q3q1))``."""
    q = np.asarray(q, float)
    return np.arcsin(np.clip(2 * (q[:, 0] * q[:, 2] - q[:, 3] * q[:, 1]), -1.0, 1.0))


def roll_from_quaternion(q: np.ndarray) -> np.ndarray:
    """Roll (rad) of FRD-to-NED quaternions (w, x, y, z)."""
    q = np.asarray(q, float)
    return np.arctan2(2 * (q[:, 0] * q[:, 1] + q[:, 2] * q[:, 3]),
                      1 - 2 * (q[:, 1] ** 2 + q[:, 2] ** 2))


def rotation_matrices(q: np.ndarray) -> np.ndarray:
    """``N x 3 x 3`` rotation matrices body -> world of unit quaternions (w, x, y, z)."""
    w, x, y, z = (q[:, i] for i in range(4))
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], axis=1)


def main_block(t: np.ndarray, gap_factor: float = 50.0, min_gap_s: float = 1.0) -> np.ndarray:
    """Indices of the longest contiguous run of samples: zero timestamps and samples separated
    from the rest by a gap of more than ``max(min_gap_s, gap_factor x median step)`` are cut
    (the stray samples PX4 logs sometimes carry)."""
    t = np.asarray(t, float)
    idx = np.flatnonzero(t > 0)
    if len(idx) < 2:
        return idx
    order = idx[np.argsort(t[idx], kind="stable")]
    ts = t[order]
    steps = np.diff(ts)
    positive = steps[steps > 0]
    median = float(np.median(positive)) if len(positive) else 0.0
    limit = max(min_gap_s, gap_factor * median)
    cuts = np.flatnonzero(steps > limit)
    bounds = np.concatenate([[0], cuts + 1, [len(ts)]])
    k = int(np.argmax(np.diff(bounds)))
    return order[bounds[k]:bounds[k + 1]]


class _Topics:
    """Access to the topics of one parsed ULog, each cut to its main block of samples."""

    def __init__(self, ulog, path: Path) -> None:
        self.ulog, self.path = ulog, path
        self.origin_us = int(ulog.start_timestamp)
        self.dropped: dict[str, int] = {}

    def get(self, name: str, fields: list[str], multi_id: int = 0
            ) -> tuple[np.ndarray, np.ndarray] | None:
        """``(t seconds from log start, values N x len(fields))`` of a topic cut to its main
        block of samples, or None when the topic or a field is absent."""
        for d in self.ulog.data_list:
            if d.name == name and d.multi_id == multi_id:
                if not all(f in d.data for f in fields):
                    return None
                keep = main_block(d.data["timestamp"])
                if len(keep) < 2:
                    return None
                self.dropped[name] = len(d.data["timestamp"]) - len(keep)
                # integer microseconds relative to the log start, then seconds: epoch-based
                # (SITL) stamps would lose precision as floats
                stamps = d.data["timestamp"][keep].astype(np.int64) - self.origin_us
                t = stamps.astype(float) * 1e-6
                t, first = np.unique(t, return_index=True)  # duplicated stamps: first sample
                vals = np.column_stack([d.data[f][keep].astype(float) for f in fields])[first]
                return t, vals
        return None


def _interp(t_grid: np.ndarray, t: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(t_grid, t, v[:, j]) for j in range(v.shape[1])])


def _hold(t_grid: np.ndarray, t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Zero-order hold: the last sample at or before each grid time (the first before it)."""
    i = np.clip(np.searchsorted(t, t_grid, side="right") - 1, 0, len(t) - 1)
    return v[i]


def _quaternions_on_grid(t_grid, t, q):
    q = q.copy()
    for k in range(1, len(q)):  # sign continuity so that interpolation is meaningful
        if np.dot(q[k], q[k - 1]) < 0:
            q[k] = -q[k]
    qi = _interp(t_grid, t, q)
    return qi / np.linalg.norm(qi, axis=1, keepdims=True)


def _vehicle_kind(ulog) -> str:
    mav_type = ulog.initial_parameters.get("MAV_TYPE")
    return "fixed_wing" if mav_type in FIXED_WING_MAV_TYPES else "multirotor"


def import_ulog(path: str | Path, rate_hz: float | None = None, kind: str | None = None,
                pitch_mix: float = 0.1, name: str | None = None,
                control_source: str = "auto") -> Sortie:
    """Read a PX4 ULog file into a :class:`Sortie` on a uniform grid at ``rate_hz`` (default:
    the attitude topic's mean rate, rounded to 1 Hz). ``kind`` defaults to the log's MAV_TYPE
    (fixed wing for MAV_TYPE 1, else multirotor). ``pitch_mix`` maps motor outputs to
    pitch_cmd when only motor commands are logged. Channel sources, topic rates and cut stray
    samples are recorded in ``meta``. ``control_source`` forces one multirotor control source
    (``actuator_controls``, ``setpoints`` or ``motors``) instead of the first one present."""
    if control_source not in CONTROL_SOURCES:
        raise ValueError(f"control_source must be one of {CONTROL_SOURCES}, got "
                         f"'{control_source}'")
    pyulog = _require_pyulog()
    path = Path(path)
    if not path.exists():
        raise FlightDataError("file not found", path)
    try:
        ulog = pyulog.ULog(str(path))
    except Exception as exc:  # pyulog raises plain Exceptions on foreign data
        raise FlightDataError(f"not a readable ULog file ({type(exc).__name__}: {exc})",
                              path) from None
    topics = _Topics(ulog, path)
    kind = kind or _vehicle_kind(ulog)
    if kind not in CONTROL_BOUNDS:
        raise FlightDataError(f"unknown kind '{kind}'", path)
    sources: dict[str, str] = {}
    att = topics.get("vehicle_attitude", [f"q[{i}]" for i in range(4)])
    if att is None:
        raise FlightDataError("no vehicle_attitude.q topic: cannot compute pitch", path,
                              column="theta")
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
        raise FlightDataError("no vehicle_local_position.vx/vy/vz: cannot compute u, w", path,
                              column="u")
    sources["u,w"] = "vehicle_local_position.vx/vy/vz rotated by vehicle_attitude.q"
    controls, control_sources = _controls(topics, kind, pitch_mix, path, control_source)
    sources.update(control_sources)
    used = [att, rate, vel, controls]
    t0 = max(u[0][0] for u in used)
    t1 = min(u[0][-1] for u in used)
    if not t1 > t0:
        raise FlightDataError("the attitude, rate, velocity and control topics share no time "
                              "span", path, column="time")
    if rate_hz is None:
        rate_hz = max(1.0, round((len(att[0]) - 1) / (att[0][-1] - att[0][0])))
    n = int(math.floor((t1 - t0) * rate_hz + 1e-9)) + 1
    grid = t0 + np.arange(n) / rate_hz
    quat = _quaternions_on_grid(grid, *att)
    theta = pitch_from_quaternion(quat)
    q = _interp(grid, *rate)[:, 0]
    v_ned = _interp(grid, *vel)
    v_body = np.einsum("nji,nj->ni", rotation_matrices(quat), v_ned)
    states = np.column_stack([v_body[:, 0], v_body[:, 2], q, theta])
    ctrl = _hold(grid, *controls)
    meta = {
        "file": str(path), "source": "PX4 ULog", "sources": sources,
        "start_time_s": float(t0) + topics.origin_us * 1e-6, "rate_hz": float(rate_hz),
        "topic_rates_hz": {key: round((len(v[0]) - 1) / (v[0][-1] - v[0][0]), 1)
                           for key, v in (("attitude", att), ("pitch_rate", rate),
                                          ("velocity", vel), ("controls", controls))},
        "stray_samples_cut": {k: v for k, v in topics.dropped.items() if v},
        "roll": roll_from_quaternion(quat),
        "sys_name": ulog.msg_info_dict.get("sys_name", ""),
        "ver_hw": ulog.msg_info_dict.get("ver_hw", ""),
        "mav_type": ulog.initial_parameters.get("MAV_TYPE"),
    }
    return Sortie(name=name or path.stem, kind=kind, time=np.arange(n) / rate_hz,
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


def integrated_pitch_rms(sortie: Sortie, window_s: float | None = None) -> float:
    """RMS (rad) of ``theta - (theta_0 + integral of q)``; with ``window_s`` the integral is
    restarted every ``window_s`` seconds (so slow gyro bias drift does not accumulate)."""
    t, q, theta = sortie.time, sortie.states[:, 2], sortie.states[:, 3]
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (q[1:] + q[:-1]) * np.diff(t))])
    if window_s is None:
        return float(np.sqrt(np.mean((theta - theta[0] - cum) ** 2)))
    seg = np.floor((t - t[0]) / window_s).astype(int)
    err = np.empty_like(theta)
    for s in np.unique(seg):
        i = np.flatnonzero(seg == s)
        err[i] = (theta[i] - theta[i[0]]) - (cum[i] - cum[i[0]])
    return float(np.sqrt(np.mean(err**2)))


def summary(sortie: Sortie) -> dict:
    """One row of numbers describing an imported log (for tables)."""
    S, U = sortie.states, sortie.controls

    def span(x, digits):
        return (round(float(np.min(x)), digits), round(float(np.max(x)), digits))

    roll = sortie.meta.get("roll")
    return {
        "name": sortie.name, "kind": sortie.kind, "rows": len(sortie.time),
        "duration_s": round(sortie.duration, 2), "rate_hz": round(1 / sortie.dt, 2),
        "theta_deg": span(np.degrees(S[:, 3]), 2), "q_radps": span(S[:, 2], 3),
        "u_mps": span(S[:, 0], 2), "w_mps": span(S[:, 1], 2),
        "u0": span(U[:, 0], 3), "u1": span(U[:, 1], 3),
        "roll_max_deg": None if roll is None else round(float(np.degrees(np.abs(roll).max())), 1),
        "rms_int_q_vs_theta_rad": integrated_pitch_rms(sortie),
        "rms_int_q_vs_theta_1s_rad": integrated_pitch_rms(sortie, 1.0),
    }


# ----------------------------------------------------------------------------- ALFA CSV


def _alfa_topic(folder: Path, suffix: str, fields: list[str]) -> tuple[np.ndarray, np.ndarray]:
    files = sorted(folder.glob(f"*-{suffix}.csv"))
    if not files:
        raise FlightDataError(f"no '*-{suffix}.csv' file in the ALFA folder", folder)
    path = files[0]

    with path.open(newline="") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None:
            raise FlightDataError("empty file", path)
        cols = {h: i for i, h in enumerate(header)}
        for f in ["%time", *fields]:
            if f not in cols:
                raise FlightDataError(f"missing column '{f}'", path, line=1, column=f)
        rows = []
        for r, row in enumerate(reader, start=1):
            try:
                rows.append([float(row[cols["%time"]]) * 1e-9]
                            + [float(row[cols[f]]) for f in fields])
            except (ValueError, IndexError):
                raise FlightDataError("cannot read the row's numbers", path, r) from None
    a = np.array(rows)
    t, first = np.unique(a[:, 0], return_index=True)
    return t, a[first, 1:]


def import_alfa(folder: str | Path, rate_hz: float = 10.0, name: str | None = None) -> Sortie:
    """Read an ALFA sequence folder (MAVROS CSV topics, ENU/FLU frames) as a fixed-wing
    :class:`Sortie`: pitch from the IMU quaternion (nose-up = -pitch of the ENU/FLU
    quaternion), q = -raw gyro y, u = odometry twist x, w = -twist z, elevator from servo
    channel 2 PWM (1178-1593 us mapped linearly to +-30 deg, PWM above centre = positive,
    nose-down elevator: an inference from the data README, consistent with the command's
    negative correlation with pitch rate, not a documented mapping), throttle from
    ``vfr_hud.throttle``. Signals are resampled to ``rate_hz`` (states linear, controls held).
    ``meta['nav_pitch']`` keeps the autopilot's logged Euler pitch on the same grid. The flight
    has banked turns (roll up to 55 deg), where d theta/dt = q cos(roll) - r sin(roll) is not q:
    it fails the pitch-plane kinematic check, as it should."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FlightDataError("not an ALFA sequence folder", folder)
    imu = _alfa_topic(folder, "mavros-imu-data", [f"field.orientation.{c}" for c in "wxyz"])
    gyro = _alfa_topic(folder, "mavros-imu-data_raw", ["field.angular_velocity.y"])
    odom = _alfa_topic(folder, "mavros-local_position-odom",
                       ["field.twist.twist.linear.x", "field.twist.twist.linear.z"])
    servo = _alfa_topic(folder, "mavros-rc-out", ["field.channels1"])
    hud = _alfa_topic(folder, "mavros-vfr_hud", ["field.throttle"])
    nav = _alfa_topic(folder, "mavros-nav_info-pitch", ["field.measured"])
    used = [imu, gyro, odom, servo, hud]
    t0 = max(u[0][0] for u in used)
    t1 = min(u[0][-1] for u in used)
    n = int(math.floor((t1 - t0) * rate_hz + 1e-9)) + 1
    grid = t0 + np.arange(n) / rate_hz
    quat = _quaternions_on_grid(grid, *imu)
    theta = -pitch_from_quaternion(quat)  # ENU/FLU quaternion: nose-up pitch is its negative
    q = -_interp(grid, *gyro)[:, 0]
    vel = _interp(grid, *odom)
    pwm = _hold(grid, *servo)[:, 0]
    lo, hi = 1178.0, 1593.0
    max_defl = CONTROL_BOUNDS["fixed_wing"][0][1]
    elevator = (pwm - 0.5 * (lo + hi)) / (0.5 * (hi - lo)) * max_defl
    throttle = _hold(grid, *hud)[:, 0]
    states = np.column_stack([vel[:, 0], -vel[:, 1], q, theta])
    meta = {"file": str(folder), "source": "ALFA (MAVROS CSV)",
            "nav_pitch": np.radians(_interp(grid, *nav)[:, 0]),
            "sources": {"theta": "-pitch(mavros-imu-data orientation)",
                        "q": "-mavros-imu-data_raw angular_velocity.y",
                        "u,w": "mavros-local_position-odom twist x, -z",
                        "elevator": "rc-out channels1 PWM (inferred mapping)",
                        "throttle": "vfr_hud.throttle"}}
    return Sortie(name=name or folder.name, kind="fixed_wing", time=np.arange(n) / rate_hz,
                  states=states,
                  controls=np.column_stack([elevator, throttle]), mission="alfa", meta=meta)
