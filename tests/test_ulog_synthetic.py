"""The PX4 ULog and ALFA importers on synthetic logs with known content (no ``../shared``).

Each log is written here (ULog through ``tests/ulog_writer.py``, ALFA as MAVROS CSV files)
from analytic truth: a pitch profile ``theta = A sin(w t)`` built into the attitude quaternion
from an aerospace yaw-pitch-roll sequence (scipy, not the importer's formula), the consistent
pitch rate, body velocities rotated into NED/ENU, and controls. The importer must give that
truth back on its documented uniform grid, pass ``check_values``, pick its sources in the
documented order and reject unreadable input. The writer itself is checked against pyulog.
"""

from __future__ import annotations

import csv
import math
import struct
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from ulog_writer import MAGIC, write_ulog

from uavdyn.flightdata import FlightDataError, check_values, import_alfa, import_ulog

pyulog = pytest.importorskip("pyulog", reason="pyulog (optional extra 'ulog') is not installed")

START_US = 500_000      # the log header's start timestamp
FIRST_US = 1_000_000    # first sample of the state topics
RATE_HZ = 100           # rate of the state topics
N = 401                 # 4 s of state samples
PITCH_AMP, PITCH_W = 0.3, 2 * math.pi * 0.5   # theta = A sin(w t), t in absolute seconds
MAX_DEFL = math.radians(30.0)                  # documented elevator deflection at |command| 1
F32_EPS = float(np.finfo(np.float32).eps)


# ----------------------------------------------------------------------------- truth


def theta_true(t: np.ndarray) -> np.ndarray:
    return PITCH_AMP * np.sin(PITCH_W * t)


def theta_dot_true(t: np.ndarray) -> np.ndarray:
    return PITCH_AMP * PITCH_W * np.cos(PITCH_W * t)


def body_velocity_true(t: np.ndarray) -> np.ndarray:
    """``N x 3`` FRD body velocity (u forward, v right, w down), m/s."""
    return np.column_stack([5.0 + 2.0 * np.sin(0.7 * t), 0.0 * t, 0.5 * np.cos(1.3 * t)])


def collective_true(t: np.ndarray) -> np.ndarray:
    return 0.5 + 0.2 * np.sin(t)


def pitch_cmd_true(t: np.ndarray) -> np.ndarray:
    return 0.3 * np.cos(2.0 * t)


def f32(x: np.ndarray) -> np.ndarray:
    """The value a float32 log field really holds, as float64 (truth for exact comparisons)."""
    return np.asarray(x, np.float32).astype(float)


def attitude(t: np.ndarray, yaw: np.ndarray | float, roll: float = 0.0) -> Rotation:
    """FRD body -> NED rotation of the aerospace yaw-pitch-roll sequence (scipy ``ZYX``)."""
    yaw = np.broadcast_to(yaw, t.shape)
    return Rotation.from_euler("ZYX", np.column_stack([yaw, theta_true(t), roll + 0 * t]))


def wxyz(rot: Rotation) -> np.ndarray:
    """Quaternions in the PX4 / importer order (w, x, y, z); scipy's is (x, y, z, w)."""
    return rot.as_quat()[:, [3, 0, 1, 2]]


def stamps(n: int, rate_hz: float, first_us: int = FIRST_US, offset_us: int = 0) -> np.ndarray:
    return (first_us + offset_us + np.round(np.arange(n) * 1e6 / rate_hz)).astype(np.uint64)


def seconds(t_us: np.ndarray) -> np.ndarray:
    return t_us.astype(float) * 1e-6


def body_rates_true(t: np.ndarray, yaw_rate: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """``N x 3`` FRD body rates [p, q, r] of the truth with constant roll and yaw rate, from the
    Euler-angle kinematics: p = -psi' sin(theta), q = theta' cos(roll) + psi' cos(theta)
    sin(roll), r = -theta' sin(roll) + psi' cos(theta) cos(roll)."""
    th, thd = theta_true(t), theta_dot_true(t)
    return np.column_stack([-yaw_rate * np.sin(th),
                            thd * np.cos(roll) + yaw_rate * np.cos(th) * np.sin(roll),
                            -thd * np.sin(roll) + yaw_rate * np.cos(th) * np.cos(roll)])


def state_topics(t_us: np.ndarray, yaw_rate: float = 0.0, yaw0: float = 0.0,
                 roll: float = 0.0) -> dict[str, dict[str, np.ndarray]]:
    """vehicle_attitude, vehicle_angular_velocity and vehicle_local_position of the truth
    (yaw ``yaw0 + yaw_rate (t - t_first)``, constant ``roll``), float32 like PX4."""
    t = seconds(t_us)
    rot = attitude(t, yaw0 + yaw_rate * (t - seconds(np.uint64(FIRST_US))), roll)
    v_ned = rot.apply(body_velocity_true(t))
    return {
        "vehicle_attitude": {"timestamp": t_us, "q": wxyz(rot).astype(np.float32)},
        "vehicle_angular_velocity": {"timestamp": t_us, "xyz": body_rates_true(
            t, yaw_rate, roll).astype(np.float32)},
        "vehicle_local_position": {"timestamp": t_us,
                                   **{k: v_ned[:, i].astype(np.float32)
                                      for i, k in enumerate(("vx", "vy", "vz"))}},
    }


def actuator_controls(t_us: np.ndarray, group: int = 0) -> dict[str, dict[str, np.ndarray]]:
    """PX4 actuator_controls_<group>: control[1] pitch command, control[3] thrust."""
    t = seconds(t_us)
    control = np.zeros((len(t), 8), np.float32)
    control[:, 1], control[:, 3] = pitch_cmd_true(t), collective_true(t)
    return {f"actuator_controls_{group}": {"timestamp": t_us, "control": control}}


def control_stamps(rate_hz: float = 10.0) -> np.ndarray:
    """Control samples from before the state topics to after them, half a state-sample step
    off the grid instants so that the zero-order hold has no ties."""
    n = int(6.0 * rate_hz)
    return stamps(n, rate_hz, first_us=FIRST_US - 45_000)


def held(t_grid: np.ndarray, t_samples: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Independent zero-order hold: the sample with the largest time <= each grid time."""
    out = np.empty(len(t_grid))
    for k, t in enumerate(t_grid):
        out[k] = values[np.flatnonzero(t_samples <= t)[-1]]
    return out


def write_log(path: Path, topics: dict, mav_type: int | None = 2, **kw) -> Path:
    params = {} if mav_type is None else {"MAV_TYPE": mav_type}
    return write_ulog(path, topics, params=params, start_us=START_US,
                      info={"sys_name": "uavdyn synthetic", "ver_hw": "TEST_V1"}, **kw)


def multirotor_log(path: Path, **state_kw) -> Path:
    return write_log(path, {**state_topics(stamps(N, RATE_HZ), **state_kw),
                            **actuator_controls(control_stamps())})


def absolute_time(s) -> np.ndarray:
    """Log time (s, same clock as the ULog timestamps) of each row of an imported sortie."""
    return s.meta["start_time_s"] + s.time


# ----------------------------------------------------------------------------- ALFA folders

ALFA_T0_NS = 1_531_943_810_000_000_000   # epoch nanoseconds, like the real ALFA files
ALFA_STEM = "carbonZ_synthetic"
PWM_LO, PWM_HI = 1178, 1593              # documented servo range of +-30 deg elevator
NED_ENU = np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]])   # swaps NED <-> ENU
FRD_FLU = np.diag([1.0, -1, -1])                           # swaps FRD <-> FLU


def mavros_csv(path: Path, t_ns: np.ndarray, columns: dict[str, np.ndarray | list],
               frame_id: str = "base_link") -> Path:
    """One MAVROS topic as ``rostopic echo -p`` writes it: ``%time`` (ns), header fields,
    then ``field.*`` columns."""
    with path.open("w", newline="") as fh:
        out = csv.writer(fh)
        out.writerow(["%time", "field.header.seq", "field.header.stamp",
                      "field.header.frame_id", *columns])
        for i, t in enumerate(t_ns):
            out.writerow([int(t), i, int(t) - 400_000, frame_id,
                          *(repr(float(c[i])) if isinstance(c[i], (float, np.floating))
                            else str(c[i]) for c in columns.values())])
    return path


def alfa_stamps(n: int, rate_hz: float, offset_ms: float = 0.0) -> np.ndarray:
    """Integer epoch nanoseconds of ``n`` samples at ``rate_hz`` from ALFA_T0 + offset."""
    return ALFA_T0_NS + int(offset_ms * 1e6) + np.round(np.arange(n) * 1e9 / rate_hz
                                                        ).astype(np.int64)


def alfa_rel(t_ns: np.ndarray) -> np.ndarray:
    """Seconds since ALFA_T0 (exact integer arithmetic before the conversion)."""
    return (np.asarray(t_ns, np.int64) - ALFA_T0_NS) * 1e-9


def write_alfa(folder: Path, roll: float = 0.0, duration_s: float = 6.0, seed: int = 0,
               skip: str | None = None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """A minimal ALFA sequence folder of the truth flight (fixed yaw, constant ``roll``).

    The FLU->ENU attitude is ``NED_ENU @ R(FRD->NED) @ FRD_FLU``; gyro and odometry twist are
    FLU body vectors. The controls (servo PWM, HUD throttle) are seeded random steps. Returns
    the control samples ``{"pwm": (t_rel, pwm), "throttle": (t_rel, thr)}``."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    n = int(duration_s * 50) + 1
    t_ns = alfa_stamps(n, 50.0)                       # IMU, raw IMU, odometry at 50 Hz
    t = alfa_rel(t_ns)
    yaw = 0.9
    r_ned_frd = attitude(t, yaw, roll).as_matrix()
    r_enu_flu = NED_ENU @ r_ned_frd @ FRD_FLU
    quat = Rotation.from_matrix(r_enu_flu).as_quat()  # x, y, z, w
    pqr_frd = np.column_stack([0 * t, theta_dot_true(t) * np.cos(roll),
                               -theta_dot_true(t) * np.sin(roll)])
    gyro_flu = pqr_frd @ FRD_FLU.T
    twist_flu = body_velocity_true(t) @ FRD_FLU.T
    files = {}
    orientation = {f"field.orientation.{c}": quat[:, i] for i, c in enumerate("xyzw")}
    rates = {f"field.angular_velocity.{c}": gyro_flu[:, i] for i, c in enumerate("xyz")}
    files["mavros-imu-data"] = (t_ns, {**orientation, **rates})
    files["mavros-imu-data_raw"] = (t_ns, {**{k: 0 * t for k in orientation}, **rates})
    files["mavros-local_position-odom"] = (t_ns, {
        "field.child_frame_id": ["base_link"] * n,
        **{f"field.pose.pose.position.{c}": 0 * t for c in "xyz"},
        **{f"field.twist.twist.linear.{c}": twist_flu[:, i] for i, c in enumerate("xyz")},
        **{f"field.twist.twist.angular.{c}": gyro_flu[:, i] for i, c in enumerate("xyz")}})
    n_pwm = int(duration_s * 5) + 3                   # servo outputs at 5 Hz, from -30 ms
    pwm_ns = alfa_stamps(n_pwm, 5.0, offset_ms=-30.0)
    pwm = rng.integers(PWM_LO, PWM_HI + 1, n_pwm)
    pwm[:3] = [PWM_LO, PWM_HI, 1500]                  # both ends of the range and mid-high
    files["mavros-rc-out"] = (pwm_ns, {f"field.channels{i}": pwm if i == 1 else
                                       np.full(n_pwm, 1500) for i in range(8)})
    n_hud = int(duration_s * 4) + 3                   # HUD at 4 Hz, from -70 ms
    hud_ns = alfa_stamps(n_hud, 4.0, offset_ms=-70.0)
    throttle = rng.uniform(0.0, 1.0, n_hud)
    files["mavros-vfr_hud"] = (hud_ns, {"field.airspeed": 0 * throttle + 17.0,
                                        "field.groundspeed": 0 * throttle + 19.0,
                                        "field.heading": np.full(n_hud, 82),
                                        "field.throttle": throttle,
                                        "field.altitude": 0 * throttle + 380.0,
                                        "field.climb": 0 * throttle})
    nav_ns = alfa_stamps(int(duration_s * 20) + 1, 20.0, offset_ms=-5.0)
    files["mavros-nav_info-pitch"] = (nav_ns, {
        "field.commanded": 0 * nav_ns + 2.0,
        "field.measured": np.degrees(theta_true(alfa_rel(nav_ns)))})
    for suffix, (stamps_ns, cols) in files.items():
        if suffix != skip:
            mavros_csv(folder / f"{ALFA_STEM}-{suffix}.csv", stamps_ns, cols)
    return {"pwm": (alfa_rel(pwm_ns), pwm), "throttle": (alfa_rel(hud_ns), throttle)}
