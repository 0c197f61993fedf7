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
import importlib.util
import math
import struct
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from ulog_writer import MAGIC, write_ulog

from uavdyn.flightdata import FlightDataError, check_values, import_alfa, import_ulog

START_US = 500_000      # the log header's start timestamp
FIRST_US = 1_000_000    # first sample of the state topics
RATE_HZ = 100           # rate of the state topics
N = 401                 # 4 s of state samples
PITCH_AMP, PITCH_W = 0.3, 2 * math.pi * 0.5   # theta = A sin(w t), t in absolute seconds
MAX_DEFL = math.radians(30.0)                  # documented elevator deflection at |command| 1


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
    rot = attitude(t, yaw0 + yaw_rate * (t - FIRST_US * 1e-6), roll)
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
    """Control samples from 45 ms before the state topics to after them: half a 100 Hz step
    off the grid instants, so that the zero-order hold has no ties to break."""
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
    nav_ns = alfa_stamps(int(duration_s * 20) + 2, 20.0, offset_ms=-5.0)   # covers the span
    files["mavros-nav_info-pitch"] = (nav_ns, {
        "field.commanded": 0 * nav_ns + 2.0,
        "field.measured": np.degrees(theta_true(alfa_rel(nav_ns)))})
    for suffix, (stamps_ns, cols) in files.items():
        if suffix != skip:
            mavros_csv(folder / f"{ALFA_STEM}-{suffix}.csv", stamps_ns, cols)
    return {"pwm": (alfa_rel(pwm_ns), pwm), "throttle": (alfa_rel(hud_ns), throttle)}


def interp_bound(f, t0: float, t1: float, h: float) -> float:
    """Error bound ``h^2/8 max|f''|`` of linear interpolation with sample spacing ``h``
    (``f''`` by central differences of the truth on a fine grid, all components)."""
    t = np.linspace(t0, t1, 4001)
    d = 1e-3
    second = (f(t + d) - 2 * f(t) + f(t - d)) / d**2
    return float(h**2 / 8 * np.max(np.abs(second)))


def v_ned_true(t: np.ndarray) -> np.ndarray:
    """NED velocity of the truth with zero yaw and roll (the resampling tests)."""
    return attitude(t, 0.0).apply(body_velocity_true(t))


needs_pyulog = pytest.mark.skipif(importlib.util.find_spec("pyulog") is None,
                                  reason="pyulog (optional extra 'ulog') is not installed")


# ----------------------------------------------------------------------------- the writer


def test_writer_header_and_message_framing(tmp_path):
    """The documented byte layout: 16-byte header, flag bits first, then 3-byte-framed
    messages (definitions I/P/F, then A before D) that tile the file exactly."""
    t_us = stamps(3, 100.0)
    path = write_ulog(tmp_path / "f.ulg",
                      {"a": {"timestamp": t_us, "x": np.arange(3, dtype=np.float32)}},
                      params={"MAV_TYPE": 2}, info={"sys_name": "s"}, start_us=123_456)
    raw = path.read_bytes()
    assert raw[:7] == MAGIC == b"\x55\x4c\x6f\x67\x01\x12\x35"
    assert raw[7] == 1 and struct.unpack("<Q", raw[8:16]) == (123_456,)
    kinds, sizes, pos = [], [], 16
    while pos < len(raw):
        size, kind = struct.unpack("<HB", raw[pos:pos + 3])
        kinds.append(chr(kind))
        sizes.append(size)
        pos += 3 + size
    assert pos == len(raw)  # the messages tile the file exactly
    assert "".join(kinds) == "BIPFADDD"
    assert sizes[0] == 40   # 8 compat + 8 incompat flag bytes + 3 uint64 appended offsets
    assert sizes[-1] == 2 + 8 + 4   # msg_id + uint64 timestamp + float32 x
    fmt_at = 16 + sum(3 + s for s in sizes[:3]) + 3
    assert raw[fmt_at:fmt_at + sizes[3]] == b"a:uint64_t timestamp;float x;"


@needs_pyulog
def test_writer_round_trips_through_pyulog(tmp_path):
    """pyulog (an independent reader) gets back every field, type, array element, instance,
    parameter and info string exactly, and sees no corruption."""
    from pyulog import ULog

    rng = np.random.default_rng(1)
    n = 57
    t_us = np.sort(rng.integers(1_000_000, 9_000_000, n)).astype(np.uint64)
    topic = {"timestamp": t_us,
             "q": rng.normal(size=(n, 4)).astype(np.float32),
             "speed": rng.normal(size=n).astype(np.float32),
             "altitude": rng.normal(size=n) * 1e3,                   # float64 -> double
             "count": rng.integers(-2**31, 2**31 - 1, n, dtype=np.int32),
             "flags": rng.integers(0, 255, n, dtype=np.uint8),
             "big": rng.integers(0, 2**62, n, dtype=np.uint64)}
    other = {"timestamp": t_us[::3] + np.uint64(7), "xyz": rng.normal(size=(19, 3)).astype(
        np.float32)}
    second = {k: v[::2] for k, v in topic.items()}   # instance 1: every other sample
    path = write_ulog(tmp_path / "rt.ulg",
                      {"my_topic": topic, ("my_topic", 1): second, "other": other},
                      params={"MAV_TYPE": 13, "FW_AIRSPD_TRIM": 15.5},
                      info={"sys_name": "PX4", "ver_hw": "SITL"}, start_us=987_654)
    ulog = ULog(str(path))
    assert not ulog.file_corruption
    assert ulog.start_timestamp == 987_654
    assert ulog.msg_info_dict == {"sys_name": "PX4", "ver_hw": "SITL"}
    assert ulog.initial_parameters == {"MAV_TYPE": 13, "FW_AIRSPD_TRIM": 15.5}
    assert isinstance(ulog.initial_parameters["MAV_TYPE"], int)
    fields = {f[2]: (f[0], f[1]) for f in ulog.message_formats["my_topic"].fields}
    assert fields == {"timestamp": ("uint64_t", 0), "q": ("float", 4), "speed": ("float", 0),
                      "altitude": ("double", 0), "count": ("int32_t", 0),
                      "flags": ("uint8_t", 0), "big": ("uint64_t", 0)}
    got = {(d.name, d.multi_id): d.data for d in ulog.data_list}
    assert set(got) == {("my_topic", 0), ("my_topic", 1), ("other", 0)}
    for key, truth in ((("my_topic", 0), topic), (("my_topic", 1), second),
                       (("other", 0), other)):
        data = got[key]
        for name, values in truth.items():
            if values.ndim == 2:
                for i in range(values.shape[1]):
                    assert data[f"{name}[{i}]"].dtype == values.dtype
                    np.testing.assert_array_equal(data[f"{name}[{i}]"], values[:, i])
            else:
                assert data[name].dtype == values.dtype
                np.testing.assert_array_equal(data[name], values)


def test_truth_conventions():
    """The truth itself: the quaternions are FRD->NED with pitch nose-up (the nose's down
    component is -sin theta), the body rates are the attitude's derivative, and the ALFA
    FLU->ENU attitude points the nose up by sin theta."""
    t = np.linspace(1.0, 5.0, 201)
    for yaw, roll in ((0.0, 0.0), (2.5, 0.0), (-2.0, 0.4)):
        nose_ned = attitude(t, yaw, roll).apply([1.0, 0.0, 0.0])
        np.testing.assert_allclose(nose_ned[:, 2], -np.sin(theta_true(t)), atol=1e-12)
        np.testing.assert_allclose(np.arctan2(nose_ned[:, 1], nose_ned[:, 0]), yaw,
                                   atol=1e-12)
    dt, yaw_rate, roll = 1e-4, 0.4, 0.3

    def rot(tt):
        return attitude(tt, 2.0 + yaw_rate * tt, roll)

    omega = (rot(t).inv() * rot(t + dt)).as_rotvec() / dt   # body rates at t + dt/2
    np.testing.assert_allclose(omega, body_rates_true(t + dt / 2, yaw_rate, roll), atol=1e-6)
    r_enu_flu = NED_ENU @ attitude(t, 0.9).as_matrix() @ FRD_FLU
    np.testing.assert_allclose(r_enu_flu[:, 2, 0], np.sin(theta_true(t)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(r_enu_flu), 1.0, atol=1e-12)


# ----------------------------------------------------------------------------- ULog import

YAW_CASES = {"level_yaw0": (0.0, 0.0, 0.0), "yaw_2.5": (2.5, 0.0, 0.0),
             "turn_through_pi": (3.0, 0.4, 0.0), "rolled_0.3": (-1.0, 0.0, 0.3)}


@needs_pyulog
@pytest.mark.parametrize("yaw0,yaw_rate,roll", YAW_CASES.values(), ids=YAW_CASES.keys())
def test_ulog_recovers_pitch_rate_velocities_and_controls(tmp_path, yaw0, yaw_rate, roll):
    """theta = A sin(w t) comes back to float32 precision whatever the heading (constant,
    or turning through +-180 deg) and with roll; q is the body pitch rate; u, w are the
    body-axis (x forward, z down) velocities; the controls are the held commands; the grid is
    the documented uniform one; and the result passes check_values."""
    path = multirotor_log(tmp_path / "mr.ulg", yaw0=yaw0, yaw_rate=yaw_rate, roll=roll)
    s = import_ulog(path)
    t = absolute_time(s)
    # the grid: attitude rate (100 Hz), over the span common to the topics (states from 1 s)
    assert s.kind == "multirotor" and s.meta["mav_type"] == 2
    assert s.meta["rate_hz"] == RATE_HZ and len(s.time) == N
    np.testing.assert_array_equal(s.time, np.arange(N) / RATE_HZ)
    assert s.meta["start_time_s"] == pytest.approx(FIRST_US * 1e-6, abs=1e-12)
    # states against the truth
    np.testing.assert_allclose(s.states[:, 3], theta_true(t), rtol=0, atol=2e-6)
    np.testing.assert_allclose(s.states[:, 2], body_rates_true(t, yaw_rate, roll)[:, 1],
                               rtol=0, atol=1e-6)
    v_body = body_velocity_true(t)
    np.testing.assert_allclose(s.states[:, 0], v_body[:, 0], rtol=0, atol=1e-5)
    np.testing.assert_allclose(s.states[:, 1], v_body[:, 2], rtol=0, atol=1e-5)
    np.testing.assert_allclose(s.meta["roll"], roll, rtol=0, atol=2e-6)
    # controls: commands held from the last 10 Hz sample (never interpolated)
    tc = seconds(control_stamps())
    np.testing.assert_array_equal(s.controls[:, 0], held(t, tc, f32(collective_true(tc))))
    np.testing.assert_array_equal(s.controls[:, 1], held(t, tc, f32(pitch_cmd_true(tc))))
    assert s.meta["sources"]["q"] == "vehicle_angular_velocity.xyz[1]"
    assert s.meta["sources"]["collective"] == "actuator_controls_0.control[3]"
    assert s.meta["sys_name"] == "uavdyn synthetic" and s.meta["ver_hw"] == "TEST_V1"
    assert s.meta["stray_samples_cut"] == {}
    check_values(path, s.kind, s.time, s.states, s.controls)


@needs_pyulog
def test_ulog_grid_spans_the_common_time_at_the_attitude_rate(tmp_path):
    """Default rate = the attitude topic's mean rate rounded to 1 Hz (250 Hz with jitter);
    the grid covers only the time all used topics share; states between samples are linear
    interpolations (error within h^2/8 max|f''|); ``rate_hz`` picks another grid."""
    rng = np.random.default_rng(7)
    n_att = 1001                                   # 4 s at 250 Hz, 0-99 us jitter
    att_us = stamps(n_att, 250.0) + rng.integers(0, 100, n_att).astype(np.uint64)
    vel_us = stamps(301, 100.0, offset_us=200_000)   # 1.2 s .. 4.2 s
    topics = state_topics(att_us)
    topics["vehicle_angular_velocity"] = state_topics(vel_us)["vehicle_angular_velocity"]
    topics["vehicle_local_position"] = state_topics(vel_us)["vehicle_local_position"]
    topics.update(actuator_controls(control_stamps(50.0)))
    path = write_log(tmp_path / "grid.ulg", topics)
    t0, t1 = seconds(vel_us[[0, -1]])
    for rate, expected_rate in ((None, 250.0), (40.0, 40.0), (33.3, 33.3)):
        s = import_ulog(path, rate_hz=rate)
        assert s.meta["rate_hz"] == expected_rate
        n = math.floor((t1 - t0) * expected_rate + 1e-9) + 1
        np.testing.assert_allclose(s.time, np.arange(n) / expected_rate, rtol=0, atol=1e-12)
        assert s.meta["start_time_s"] == pytest.approx(t0, abs=1e-9)
        assert s.meta["start_time_s"] + s.time[-1] <= t1 + 1e-9
        t = absolute_time(s)
        h_att = float(np.max(np.diff(seconds(att_us))))
        tol = 1.5 * interp_bound(theta_true, t0, t1, h_att) + 2e-6
        np.testing.assert_allclose(s.states[:, 3], theta_true(t), rtol=0, atol=tol)
        tol_q = interp_bound(theta_dot_true, t0, t1, 0.01) + 1e-6
        np.testing.assert_allclose(s.states[:, 2], theta_dot_true(t), rtol=0, atol=tol_q)
        tol_v = math.sqrt(3) * interp_bound(v_ned_true, t0, t1, 0.01) + 1e-5
        np.testing.assert_allclose(s.states[:, 0], body_velocity_true(t)[:, 0], atol=tol_v)
        np.testing.assert_allclose(s.states[:, 1], body_velocity_true(t)[:, 2], atol=tol_v)
        check_values(path, s.kind, s.time, s.states, s.controls, sample_rate_hz=expected_rate)


@needs_pyulog
def test_ulog_quaternion_sign_flips_do_not_disturb_interpolation(tmp_path):
    """q and -q are the same attitude: a log whose quaternions flip sign every other sample
    gives the same pitch, also between samples (the importer makes the sign continuous
    before interpolating)."""
    topics = {**state_topics(stamps(N, RATE_HZ)), **actuator_controls(control_stamps())}
    q = topics["vehicle_attitude"]["q"].copy()
    q[1::2] *= -1
    topics["vehicle_attitude"] = {"timestamp": topics["vehicle_attitude"]["timestamp"], "q": q}
    s = import_ulog(write_log(tmp_path / "flip.ulg", topics), rate_hz=40.0)
    t = absolute_time(s)
    tol = 1.5 * interp_bound(theta_true, t[0], t[-1], 0.01) + 2e-6
    np.testing.assert_allclose(s.states[:, 3], theta_true(t), rtol=0, atol=tol)
    tol_v = math.sqrt(3) * interp_bound(v_ned_true, t[0], t[-1], 0.01) + 1e-5
    np.testing.assert_allclose(s.states[:, 0], body_velocity_true(t)[:, 0], atol=tol_v)


def motor_topic(t_us: np.ndarray, pitch_mix: float) -> dict[str, dict[str, np.ndarray]]:
    """actuator_motors of a quad X (PX4 order: 1 front-right, 2 rear-left, 3 front-left,
    4 rear-right): front motors at collective + mix x pitch, rear at collective - mix x
    pitch; the 8 unused outputs NaN, as PX4 logs them."""
    t = seconds(t_us)
    c, p = collective_true(t), pitch_cmd_true(t)
    m = np.full((len(t), 12), np.nan, np.float32)
    m[:, [0, 2]] = (c + pitch_mix * p)[:, None]
    m[:, [1, 3]] = (c - pitch_mix * p)[:, None]
    return {"actuator_motors": {"timestamp": t_us, "control": m}}


def setpoint_topics(t_us: np.ndarray) -> dict[str, dict[str, np.ndarray]]:
    """PX4 >= 1.14 thrust (NED body z: negative is up) and torque setpoints; the torque one
    at a different rate, so the importer must hold both on the union of their times."""
    t = seconds(t_us)
    thrust = np.zeros((len(t), 3), np.float32)
    thrust[:, 2] = -collective_true(t)
    tq_us = t_us[::2] + np.uint64(3_000)
    torque = np.zeros((len(tq_us), 3), np.float32)
    torque[:, 1] = pitch_cmd_true(seconds(tq_us))
    return {"vehicle_thrust_setpoint": {"timestamp": t_us, "xyz": thrust},
            "vehicle_torque_setpoint": {"timestamp": tq_us, "xyz": torque}}


@needs_pyulog
@pytest.mark.parametrize("source", ["actuator_controls", "setpoints", "motors"])
def test_ulog_multirotor_control_sources(tmp_path, source):
    """Each documented control source alone gives collective and pitch_cmd back: thrust ->
    collective (setpoint sign flipped), pitch command -> pitch_cmd, and the quad-X motor mix
    inverted with ``pitch_mix``."""
    c_us = control_stamps(20.0)
    controls = {"actuator_controls": actuator_controls(c_us), "setpoints": setpoint_topics(c_us),
                "motors": motor_topic(c_us, 0.2)}[source]
    path = write_log(tmp_path / f"{source}.ulg", {**state_topics(stamps(N, RATE_HZ)),
                                                  **controls})
    s = import_ulog(path, pitch_mix=0.2)
    t = absolute_time(s)
    tc = seconds(c_us)
    tq = seconds(c_us[::2] + np.uint64(3_000)) if source == "setpoints" else tc
    coll = held(t, tc, f32(collective_true(tc)))
    pitch = held(t, tq, f32(pitch_cmd_true(tq)))
    tol = 1e-6 if source == "motors" else 0.0   # the motor mix is undone in float32 values
    np.testing.assert_allclose(s.controls[:, 0], coll, rtol=0, atol=tol)
    np.testing.assert_allclose(s.controls[:, 1], pitch, rtol=0, atol=tol)
    expected = {"actuator_controls": "actuator_controls_0.control[3]",
                "setpoints": "-vehicle_thrust_setpoint.xyz[2]",
                "motors": "mean of actuator_motors.control[0..3]"}[source]
    assert s.meta["sources"]["collective"] == expected
    check_values(path, s.kind, s.time, s.states, s.controls)


@needs_pyulog
def test_ulog_control_source_priority_and_forcing(tmp_path):
    """With all sources logged 'auto' takes actuator_controls_0, then the setpoints, then the
    motors; ``control_source`` forces one; a forced absent source or an unknown name is an
    error, not a silent fallback."""
    c_us = control_stamps(20.0)
    topics = {**state_topics(stamps(N, RATE_HZ)), **setpoint_topics(c_us),
              **motor_topic(c_us, 0.1)}
    only_two = write_log(tmp_path / "two.ulg", topics)
    every = write_log(tmp_path / "all.ulg", {**topics, **actuator_controls(c_us)})
    assert import_ulog(every).meta["sources"]["collective"].startswith("actuator_controls_0")
    assert import_ulog(only_two).meta["sources"]["collective"].startswith("-vehicle_thrust")
    for source, prefix in (("setpoints", "-vehicle_thrust"), ("motors", "mean of"),
                           ("actuator_controls", "actuator_controls_0")):
        s = import_ulog(every, control_source=source)
        assert s.meta["sources"]["collective"].startswith(prefix)
        t, tc = absolute_time(s), seconds(c_us)
        np.testing.assert_allclose(s.controls[:, 0], held(t, tc, f32(collective_true(tc))),
                                   atol=1e-6)
    with pytest.raises(FlightDataError, match="requested control source 'actuator_controls'"):
        import_ulog(only_two, control_source="actuator_controls")
    with pytest.raises(ValueError, match="control_source must be one of"):
        import_ulog(every, control_source="servos")


RATE_SOURCES = {
    "vehicle_angular_velocity": "vehicle_angular_velocity.xyz[1]",
    "vehicle_attitude.pitchspeed": "vehicle_attitude.pitchspeed",
    "sensor_combined": "sensor_combined.gyro_rad[1]",
}


@needs_pyulog
@pytest.mark.parametrize("best", RATE_SOURCES)
def test_ulog_pitch_rate_source_order(tmp_path, best):
    """The pitch rate comes from vehicle_angular_velocity, else vehicle_attitude.pitchspeed,
    else sensor_combined: lower-priority sources logged alongside carry a decoy (q + 1) that
    must not be picked."""
    t_us = stamps(N, RATE_HZ)
    topics = {**state_topics(t_us), **actuator_controls(control_stamps())}
    q = topics.pop("vehicle_angular_velocity")["xyz"][:, 1]
    order = list(RATE_SOURCES)
    gyro = np.zeros((N, 3), np.float32)
    gyro[:, 1] = q if best == "sensor_combined" else q + 1
    topics["sensor_combined"] = {"timestamp": t_us, "gyro_rad": gyro,
                                 "accelerometer_m_s2": np.zeros((N, 3), np.float32)}
    if order.index(best) <= 1:
        topics["vehicle_attitude"] = {**topics["vehicle_attitude"],
                                      "pitchspeed": q if order.index(best) == 1 else q + 1}
    if best == "vehicle_angular_velocity":
        xyz = np.zeros((N, 3), np.float32)
        xyz[:, 1] = q
        topics["vehicle_angular_velocity"] = {"timestamp": t_us, "xyz": xyz}
    s = import_ulog(write_log(tmp_path / "rate.ulg", topics))
    assert s.meta["sources"]["q"] == RATE_SOURCES[best]
    np.testing.assert_allclose(s.states[:, 2], theta_dot_true(absolute_time(s)), atol=1e-6)


@needs_pyulog
@pytest.mark.parametrize("mav_type,kind", [(1, "fixed_wing"), (2, "multirotor"),
                                           (13, "multirotor"), (22, "multirotor"),
                                           (None, "multirotor")])
def test_ulog_vehicle_kind_from_mav_type(tmp_path, mav_type, kind):
    """MAV_TYPE 1 (fixed wing) -> fixed_wing; quad (2), hexa (13), VTOL (22) or no MAV_TYPE
    -> multirotor; ``kind=`` overrides the parameter."""
    c_us = control_stamps()
    topics = {**state_topics(stamps(N, RATE_HZ)), **actuator_controls(c_us, 0),
              **actuator_controls(c_us, 1)}
    path = write_log(tmp_path / "k.ulg", topics, mav_type=mav_type)
    s = import_ulog(path)
    assert s.kind == kind and s.meta["mav_type"] == mav_type
    other = "multirotor" if kind == "fixed_wing" else "fixed_wing"
    assert import_ulog(path, kind=other).kind == other
    with pytest.raises(FlightDataError, match="unknown kind 'helicopter'"):
        import_ulog(path, kind="helicopter")


@needs_pyulog
def test_ulog_fixed_wing_elevator_and_throttle(tmp_path):
    """Fixed wing: elevator = -actuator_controls_1.control[1] x 30 deg (PX4's positive pitch
    command is nose up, this product's positive elevator nose down), throttle =
    control[3]."""
    c_us = control_stamps(25.0)
    tc = seconds(c_us)
    rng = np.random.default_rng(3)
    control = np.zeros((len(c_us), 8), np.float32)
    control[:, 1] = rng.uniform(-1, 1, len(c_us))
    control[:3, 1] = [1.0, 1.0, -1.0]     # full nose-up (held at 1.0 s), then full nose-down
    control[:, 3] = rng.uniform(0, 1, len(c_us))
    topics = {**state_topics(stamps(N, RATE_HZ)),
              "actuator_controls_1": {"timestamp": c_us, "control": control}}
    path = write_log(tmp_path / "fw.ulg", topics, mav_type=1)
    s = import_ulog(path)
    t = absolute_time(s)
    assert s.kind == "fixed_wing"
    elevator = held(t, tc, -control[:, 1].astype(float) * MAX_DEFL)
    # 3e-6: the product stores 30 deg as 0.5236 rad (CONTROL_BOUNDS), 1.2e-6 rad off
    np.testing.assert_allclose(s.controls[:, 0], elevator, rtol=0, atol=3e-6)
    np.testing.assert_array_equal(s.controls[:, 1], held(t, tc, f32(control[:, 3])))
    # full nose-up command (sample at 0.995 s) -> -30 deg; full nose-down (1.035 s) -> +30 deg
    assert s.controls[0, 0] == pytest.approx(-MAX_DEFL, abs=3e-6)
    assert s.controls[4, 0] == pytest.approx(MAX_DEFL, abs=3e-6)
    assert s.meta["sources"]["elevator"] == "-actuator_controls_1.control[1] x 30 deg"
    np.testing.assert_allclose(s.states[:, 3], theta_true(t), atol=2e-6)
    check_values(path, s.kind, s.time, s.states, s.controls)


@needs_pyulog
def test_ulog_stray_samples_are_cut_and_counted(tmp_path):
    """A zero timestamp and a block of samples 200 s after the rest (the stray samples real
    PX4 logs carry) are cut from that topic and counted in ``meta``; the result is unchanged."""
    topics = {**state_topics(stamps(N, RATE_HZ)), **actuator_controls(control_stamps())}
    att = topics["vehicle_attitude"]
    late = att["timestamp"][-1] + np.uint64(200_000_000) + stamps(3, 100.0, first_us=0)
    topics["vehicle_attitude"] = {
        "timestamp": np.concatenate([[0], att["timestamp"], late]).astype(np.uint64),
        "q": np.vstack([att["q"][:1], att["q"], att["q"][:3]])}
    s = import_ulog(write_log(tmp_path / "stray.ulg", topics))
    assert s.meta["stray_samples_cut"] == {"vehicle_attitude": 4}
    assert len(s.time) == N and s.duration == pytest.approx(4.0)
    np.testing.assert_allclose(s.states[:, 3], theta_true(absolute_time(s)), atol=2e-6)


def _drop(topics: dict, *names) -> dict:
    return {k: v for k, v in topics.items() if k not in names}


MISSING = {
    "no_attitude": (lambda t: _drop(t, "vehicle_attitude"), 2, "theta"),
    "attitude_only_instance_1": (lambda t: {**_drop(t, "vehicle_attitude"),
                                            ("vehicle_attitude", 1): t["vehicle_attitude"]},
                                 2, "theta"),
    "no_rate_topic": (lambda t: _drop(t, "vehicle_angular_velocity"), 2, "q"),
    "no_local_position": (lambda t: _drop(t, "vehicle_local_position"), 2, "u"),
    "no_multirotor_controls": (lambda t: _drop(t, "actuator_controls_0"), 2, "collective"),
    "fixed_wing_without_actuator_controls_1": (lambda t: t, 1, "elevator"),
    "no_common_time": (lambda t: {**t, "actuator_controls_0": actuator_controls(
        stamps(10, 10.0, offset_us=10_000_000))["actuator_controls_0"]}, 2, "time"),
}


@needs_pyulog
@pytest.mark.parametrize("make,mav_type,column", MISSING.values(), ids=MISSING.keys())
def test_ulog_missing_topics_raise(tmp_path, make, mav_type, column):
    """A log without what a channel needs raises FlightDataError naming that channel."""
    topics = make({**state_topics(stamps(N, RATE_HZ)), **actuator_controls(control_stamps())})
    path = write_log(tmp_path / "m.ulg", topics, mav_type=mav_type)
    with pytest.raises(FlightDataError) as err:
        import_ulog(path)
    assert err.value.column == column and err.value.file == str(path)


@needs_pyulog
def test_ulog_unreadable_files_raise(tmp_path):
    """Random bytes, an empty file, a valid header followed by random bytes and a missing
    file raise FlightDataError (not pyulog's or the OS's exceptions)."""
    rng = np.random.default_rng(11)
    good = multirotor_log(tmp_path / "good.ulg").read_bytes()
    cases = {"random.ulg": rng.bytes(4096), "empty.ulg": b"",
             "header_then_noise.ulg": good[:16] + rng.bytes(4096)}
    for name, raw in cases.items():
        (tmp_path / name).write_bytes(raw)
        with pytest.raises(FlightDataError, match=name):
            import_ulog(tmp_path / name)
    with pytest.raises(FlightDataError, match="file not found"):
        import_ulog(tmp_path / "missing.ulg")


def _cut(tmp_path: Path, fraction: float) -> Path:
    raw = multirotor_log(tmp_path / "full.ulg").read_bytes()
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(raw[:int(len(raw) * fraction)])
    return cut


@needs_pyulog
def test_ulog_truncated_file_gives_no_nans_and_a_true_prefix(tmp_path):
    """A file cut at 50 % of its bytes, imported on request (``allow_truncated``): the result
    is finite and right (the truth over a shorter span), it does not invent data, and
    ``meta`` says where the file was cut."""
    cut = _cut(tmp_path, 0.5)
    s = import_ulog(cut, allow_truncated=True)
    t = absolute_time(s)
    assert 16 < s.meta["truncated_at_byte"] < cut.stat().st_size
    assert np.all(np.isfinite(s.to_array()))
    assert 0 < s.duration < 4.0
    np.testing.assert_allclose(s.states[:, 3], theta_true(t), atol=2e-6)
    np.testing.assert_allclose(s.states[:, 0], body_velocity_true(t)[:, 0], atol=1e-5)


@needs_pyulog
@pytest.mark.parametrize("fraction", [0.5, 0.01, 0.999])
def test_ulog_truncated_file_raises(tmp_path, fraction):
    """By default a cut file (last message incomplete; pyulog itself does not flag it) is an
    error naming the file, wherever the cut falls; a complete log reports no cut."""
    cut = _cut(tmp_path, fraction)
    with pytest.raises(FlightDataError, match=f"{cut.name}: truncated ULog file"):
        import_ulog(cut)
    assert import_ulog(tmp_path / "full.ulg").meta["truncated_at_byte"] is None


def _with_bad_samples(topics: dict, what: str) -> dict:
    """Copy of ``topics`` with three non-finite (or zero-quaternion) samples in one field."""
    topic, field, value, col = {"nan_quaternion": ("vehicle_attitude", "q", np.nan, None),
                                "zero_quaternion": ("vehicle_attitude", "q", 0.0, None),
                                "nan_velocity": ("vehicle_local_position", "vx", np.nan, None),
                                "nan_control": ("actuator_controls_0", "control", np.nan, 3),
                                }[what]
    a = topics[topic][field].copy()
    if col is None:
        a[20:23] = value
    else:
        a[2:5, col] = value
    return {**topics, topic: {**topics[topic], field: a}}


@needs_pyulog
@pytest.mark.parametrize("what,column", [("nan_quaternion", "vehicle_attitude.q[0]"),
                                         ("zero_quaternion", "vehicle_attitude.q"),
                                         ("nan_velocity", "vehicle_local_position.vx"),
                                         ("nan_control", "actuator_controls_0.control[3]")])
def test_ulog_non_finite_samples_are_not_passed_through(tmp_path, what, column):
    """Non-finite or zero-norm source samples are refused, naming the file, topic and field
    (never NaN in the imported sortie)."""
    topics = _with_bad_samples({**state_topics(stamps(N, RATE_HZ)),
                                **actuator_controls(control_stamps())}, what)
    path = write_log(tmp_path / "nan.ulg", topics)
    with pytest.raises(FlightDataError, match="nan.ulg") as err:
        import_ulog(path)
    assert err.value.column == column


@needs_pyulog
def test_ulog_controls_logged_at_grid_instants_are_held_exactly(tmp_path):
    """Controls logged at exactly the grid instants: "the last sample at or before each grid
    time" is that instant's own sample, for every row."""
    t_us = stamps(N, RATE_HZ)
    s = import_ulog(write_log(tmp_path / "ongrid.ulg", {**state_topics(t_us),
                                                        **actuator_controls(t_us)}))
    np.testing.assert_array_equal(s.controls[:, 0], f32(collective_true(seconds(t_us))))


@needs_pyulog
@pytest.mark.parametrize("rate", [0.0, -10.0])
def test_ulog_non_positive_rate_is_refused(tmp_path, rate):
    with pytest.raises((ValueError, FlightDataError)):
        import_ulog(multirotor_log(tmp_path / "r.ulg"), rate_hz=rate)


# ----------------------------------------------------------------------------- ALFA import


def test_alfa_recovers_pitch_rate_velocities_and_controls(tmp_path):
    """ENU/FLU MAVROS topics: nose-up pitch, q = pitch rate (FRD), u forward, w down, the
    servo PWM 1178..1593 us mapped linearly onto -30..+30 deg (above centre = positive,
    nose-down), throttle held, all on the default 10 Hz grid over the common span."""
    controls = write_alfa(tmp_path / "seq")
    s = import_alfa(tmp_path / "seq")
    assert s.kind == "fixed_wing" and s.name == "seq"
    # every used topic starts at or before ALFA_T0 and the state topics end at 6 s
    np.testing.assert_allclose(s.time, np.arange(61) / 10.0, rtol=0, atol=1e-12)
    t = s.time
    np.testing.assert_allclose(s.states[:, 3], theta_true(t), rtol=0, atol=1e-6)
    np.testing.assert_allclose(s.states[:, 2], theta_dot_true(t), rtol=0, atol=2e-6)
    np.testing.assert_allclose(s.states[:, 0], body_velocity_true(t)[:, 0], atol=1e-6)
    np.testing.assert_allclose(s.states[:, 1], body_velocity_true(t)[:, 2], atol=1e-6)
    t_pwm, pwm = controls["pwm"]
    centre, half = (PWM_LO + PWM_HI) / 2, (PWM_HI - PWM_LO) / 2
    elevator = held(t, t_pwm, (pwm - centre) / half * MAX_DEFL)
    np.testing.assert_allclose(s.controls[:, 0], elevator, rtol=0, atol=3e-6)
    # rows 0-1 hold PWM 1178 (-30 deg), rows 2-3 PWM 1593 (+30 deg), rows 4-5 PWM 1500
    np.testing.assert_allclose(s.controls[:6, 0], np.radians([-30, -30, 30, 30, 16.55, 16.55]),
                               atol=1e-3)
    np.testing.assert_array_equal(s.controls[:, 1], held(t, *controls["throttle"]))
    nav_tol = interp_bound(theta_true, 0, 6, 0.05) + 1e-9
    np.testing.assert_allclose(s.meta["nav_pitch"], theta_true(t), rtol=0, atol=nav_tol)
    check_values(tmp_path / "seq", s.kind, s.time, s.states, s.controls)


def test_alfa_rate_and_banked_flight(tmp_path):
    """At 55 deg of bank the pitch is still recovered, q is the body rate theta' cos(roll),
    and the pitch-plane kinematic check fails, as it should; ``rate_hz`` sets the grid."""
    write_alfa(tmp_path / "bank", roll=math.radians(55))
    s = import_alfa(tmp_path / "bank", rate_hz=25.0)
    np.testing.assert_allclose(s.time, np.arange(151) / 25.0, rtol=0, atol=1e-12)
    tol = interp_bound(theta_true, 0, 6, 0.02) * 1.5 + 1e-6
    np.testing.assert_allclose(s.states[:, 3], theta_true(s.time), rtol=0, atol=tol)
    q_true = theta_dot_true(s.time) * math.cos(math.radians(55))
    np.testing.assert_allclose(s.states[:, 2], q_true, rtol=0,
                               atol=interp_bound(theta_dot_true, 0, 6, 0.02) + 1e-6)
    with pytest.raises(FlightDataError, match="kinematic inconsistency"):
        check_values("bank", s.kind, s.time, s.states, s.controls)


def _edit(folder: Path, suffix: str, edit) -> None:
    f = folder / f"{ALFA_STEM}-{suffix}.csv"
    f.write_text(edit(f.read_text()))


def _break_row(text: str, row: int, value: str) -> str:
    lines = text.splitlines()
    parts = lines[row].split(",")
    parts[4] = value
    lines[row] = ",".join(parts)
    return "\n".join(lines) + "\n"


ALFA_BROKEN = {
    "missing_topic_file": ("mavros-rc-out", None, "no '\\*-mavros-rc-out.csv' file"),
    "missing_column": ("mavros-vfr_hud", lambda s: s.replace("field.throttle", "field.thr"),
                       "missing column 'field.throttle'"),
    "unreadable_number": ("mavros-imu-data", lambda s: _break_row(s, 10, "abc"),
                          r"data row 10 \(CSV line 11\), column 'field.orientation.x': "
                          r"cannot read 'abc' as a number"),
    "empty_file": ("mavros-vfr_hud", lambda s: "", "empty file"),
}


@pytest.mark.parametrize("suffix,edit,message", ALFA_BROKEN.values(), ids=ALFA_BROKEN.keys())
def test_alfa_malformed_folders_raise(tmp_path, suffix, edit, message):
    folder = tmp_path / "seq"
    write_alfa(folder, skip=suffix if edit is None else None)
    if edit is not None:
        _edit(folder, suffix, edit)
    with pytest.raises(FlightDataError, match=message):
        import_alfa(folder)


def test_alfa_not_a_folder_raises(tmp_path):
    with pytest.raises(FlightDataError, match="not an ALFA sequence folder"):
        import_alfa(tmp_path / "absent")


ALFA_SILENT = {
    "header_only_topic": lambda s: s.splitlines()[0] + "\n",
    "one_row_topic": lambda s: "\n".join(s.splitlines()[:2]) + "\n",
    "topic_after_the_others": lambda s: "\n".join(
        [s.splitlines()[0]] + [str(int(line.split(",")[0]) + 100 * 10**9)
                               + line[line.index(","):] for line in s.splitlines()[1:]]) + "\n",
}


@pytest.mark.parametrize("edit", ALFA_SILENT.values(), ids=ALFA_SILENT.keys())
def test_alfa_topics_without_common_time_raise(tmp_path, edit):
    """A topic with no rows, one row, or rows after the others' end is an error naming that
    topic's file (not an empty Sortie or a bare IndexError)."""
    folder = tmp_path / "seq"
    write_alfa(folder)
    _edit(folder, "mavros-vfr_hud", edit)
    with pytest.raises(FlightDataError, match=f"{ALFA_STEM}-mavros-vfr_hud.csv"):
        import_alfa(folder)


# ----------------------------------------------------------------------------- options


BAD_ULOG_OPTIONS = {
    "rate_nan": ({"rate_hz": float("nan")}, "rate_hz"),
    "rate_inf": ({"rate_hz": float("inf")}, "rate_hz"),
    "rate_bool": ({"rate_hz": True}, "rate_hz"),
    "rate_text": ({"rate_hz": "100"}, "rate_hz"),
    "rate_huge": ({"rate_hz": 1e9}, "rate_hz"),
    "pitch_mix_zero": ({"pitch_mix": 0.0}, "pitch_mix"),
    "pitch_mix_negative": ({"pitch_mix": -0.1}, "pitch_mix"),
    "pitch_mix_nan": ({"pitch_mix": float("nan")}, "pitch_mix"),
    "pitch_mix_inf": ({"pitch_mix": float("inf")}, "pitch_mix"),
    "pitch_mix_bool": ({"pitch_mix": True}, "pitch_mix"),
    "kind_int": ({"kind": 3}, "option kind"),
    "kind_list": ({"kind": ["multirotor"]}, "option kind"),
    "control_source_int": ({"control_source": 5}, "control_source"),
    "control_source_none": ({"control_source": None}, "control_source"),
    "name_int": ({"name": 5}, "option name"),
    "name_empty": ({"name": ""}, "option name"),
    "check_int": ({"check": 1}, "option check"),
    "kinematic_text": ({"kinematic": "no"}, "option kinematic"),
    "allow_truncated_none": ({"allow_truncated": None}, "option allow_truncated"),
}


@needs_pyulog
@pytest.mark.parametrize("options,option", BAD_ULOG_OPTIONS.values(),
                         ids=BAD_ULOG_OPTIONS.keys())
def test_ulog_bad_options_raise_naming_the_option(tmp_path, options, option):
    """Every option is validated up front, with one line naming it (and the file)."""
    path = multirotor_log(tmp_path / "opt.ulg")
    with pytest.raises(FlightDataError, match=option) as err:
        import_ulog(path, **options)
    assert "\n" not in str(err.value) and "opt.ulg" in str(err.value)


@needs_pyulog
@pytest.mark.parametrize("path", [5, None, b"x.ulg", ""])
def test_ulog_path_must_be_a_path(path):
    with pytest.raises(FlightDataError, match="option path"):
        import_ulog(path)


@pytest.mark.parametrize("options,option", [({"rate_hz": 0}, "rate_hz"),
                                            ({"rate_hz": float("nan")}, "rate_hz"),
                                            ({"rate_hz": None}, "rate_hz"),
                                            ({"name": 3}, "option name"),
                                            ({"check": "yes"}, "option check"),
                                            ({"kinematic": 0}, "option kinematic")])
def test_alfa_bad_options_raise_naming_the_option(tmp_path, options, option):
    write_alfa(tmp_path / "seq")
    with pytest.raises(FlightDataError, match=option):
        import_alfa(tmp_path / "seq", **options)


@needs_pyulog
def test_ulog_value_checks_run_unless_opted_out(tmp_path):
    """The importer runs check_values itself: a pitch rate twice too large fails the
    kinematic check (with the grid row and time), passes with ``kinematic=False``; a 500 m/s
    velocity fails the range check, passes (unchecked) with ``check=False``."""
    topics = {**state_topics(stamps(N, RATE_HZ)), **actuator_controls(control_stamps())}
    rate = topics["vehicle_angular_velocity"]
    doubled = write_log(tmp_path / "q2.ulg", {**topics, "vehicle_angular_velocity": {
        **rate, "xyz": rate["xyz"] * np.float32(2)}})
    with pytest.raises(FlightDataError, match=r"q2.ulg, column 'theta': imported grid row "
                       r"\d+ \(t = [\d.]+ s\): kinematic inconsistency"):
        import_ulog(doubled)
    s = import_ulog(doubled, kinematic=False)
    assert s.meta["checked"] == {"values": True, "kinematic": False}
    pos = topics["vehicle_local_position"]
    fast = write_log(tmp_path / "fast.ulg", {**topics, "vehicle_local_position": {
        **pos, "vx": pos["vx"] * np.float32(100)}})
    with pytest.raises(FlightDataError, match="column 'u'.*outside the physical range"):
        import_ulog(fast)
    assert import_ulog(fast, check=False).meta["checked"]["values"] is False


@needs_pyulog
def test_ulog_non_regular_files_are_never_opened(tmp_path):
    """A FIFO (opening it would block), a symlink to /dev/zero (endless) and a folder are
    refused from ``stat`` alone; a sparse file above the size bound is refused unread."""
    import os

    fifo = tmp_path / "pipe.ulg"
    os.mkfifo(fifo)
    with pytest.raises(FlightDataError, match="pipe.ulg: is a FIFO"):
        import_ulog(fifo)
    (tmp_path / "zero.ulg").symlink_to("/dev/zero")
    with pytest.raises(FlightDataError, match="zero.ulg: is a character device"):
        import_ulog(tmp_path / "zero.ulg")
    (tmp_path / "dir.ulg").mkdir()
    with pytest.raises(FlightDataError, match="dir.ulg: is a folder"):
        import_ulog(tmp_path / "dir.ulg")
    with (tmp_path / "big.ulg").open("wb") as fh:
        fh.truncate(3 * 1024**3)
    with pytest.raises(FlightDataError, match="big.ulg: file is 3221225472 bytes, more than the"):
        import_ulog(tmp_path / "big.ulg")


def test_alfa_topic_files_must_stay_inside_the_folder(tmp_path):
    """A topic file symlinked to another file inside the folder is read; one resolving
    outside it is refused (never opened), naming the link."""
    folder = tmp_path / "seq"
    write_alfa(folder)
    hud = folder / f"{ALFA_STEM}-mavros-vfr_hud.csv"
    inside = folder / "sub"
    inside.mkdir()
    hud.rename(inside / "hud.csv")
    hud.symlink_to(inside / "hud.csv")
    assert import_alfa(folder).kind == "fixed_wing"
    hud.unlink()
    (inside / "hud.csv").rename(tmp_path / "hud.csv")
    hud.symlink_to(tmp_path / "hud.csv")
    with pytest.raises(FlightDataError, match="mavros-vfr_hud.csv: resolves to .*outside the "
                       "ALFA folder"):
        import_alfa(folder)


# ----------------------------------------------------------------------------- fuzz cases


@needs_pyulog
def test_fuzz_baselines_import_cleanly(tmp_path):
    """The valid inputs every case of ``tests/fuzz_ulog.py`` breaks import and pass the
    checks, so that each case fails for its own defect."""
    import fuzz_ulog

    s = import_ulog(fuzz_ulog.write_log(tmp_path / "ok.ulg"))
    assert len(s.time) > 50 and s.meta["truncated_at_byte"] is None
    a = import_alfa(fuzz_ulog.write_alfa(tmp_path / "alfa"), kinematic=True)
    assert len(a.time) > 30


@needs_pyulog
def test_fuzz_cases_raise_naming_the_file(tmp_path):
    """Each seeded malformed input raises the importer's own error, in one line naming the
    file (a local run of the cases; ``tests/test_fuzz.py`` also audits file access)."""
    import fuzz_ulog

    cases = fuzz_ulog.cases()
    assert len(cases) >= 60 and len({c.name for c in cases}) == len(cases)
    for case in cases:
        folder = tmp_path / case.name
        folder.mkdir()
        path = case.build(folder)
        with pytest.raises(case.error) as err:
            case.load(path)
        assert type(err.value) is case.error, case.name
        message = str(err.value)
        assert (case.names or path.name) in message and "\n" not in message, (case.name,
                                                                             message)


@needs_pyulog
def test_ulog_timestamps_going_backwards_are_refused(tmp_path):
    """Two attitude samples swapped in the file (a corrupt or spliced log) used to be sorted
    silently; the import now refuses it naming the topic and where. The same samples in time
    order import."""
    topics = {**state_topics(stamps(N, RATE_HZ)), **actuator_controls(control_stamps())}
    att = topics["vehicle_attitude"]
    swapped = att["timestamp"].copy()
    swapped[[100, 101]] = swapped[[101, 100]]
    topics["vehicle_attitude"] = {**att, "timestamp": swapped}
    path = write_log(tmp_path / "back.ulg", topics, merge=False)
    with pytest.raises(FlightDataError, match="back.ulg.*go backwards at its sample 101") as err:
        import_ulog(path)
    assert err.value.column == "vehicle_attitude.timestamp"
    topics["vehicle_attitude"] = att
    assert len(import_ulog(write_log(tmp_path / "ok.ulg", topics, merge=False)).time) == N
