"""Import of the real logs in shared/data/flightlogs (PX4 ULog and the ALFA fixed-wing CSVs):
each imports onto a uniform grid, pitch from the quaternion agrees with independent pitch
sources, the integrated pitch rate follows pitch (RMS printed), and a summary table is shown.
They are collected only where ``../shared`` exists (see conftest.py); the importers' tests on
synthetic logs with known content, which need nothing outside the repository, are in
``tests/test_ulog_synthetic.py``."""

from pathlib import Path

import numpy as np
import pytest

from uavdyn.flightdata import FlightDataError, check_values, export, import_ulog, read_csv

pytest.importorskip("pyulog", reason="pyulog (optional extra 'ulog') is not installed")

LOGS = Path(__file__).resolve().parents[2] / "shared/data/flightlogs"
ULOGS = sorted(LOGS.glob("*.ulg")) if LOGS.is_dir() else []
ALFA = sorted(p for p in LOGS.glob("alfa_*") if p.is_dir()) if LOGS.is_dir() else []
needs_logs = pytest.mark.skipif(not ULOGS, reason=f"real flight logs not found at {LOGS}")


@pytest.fixture(scope="module")
def imported():
    return {p.name: import_ulog(p) for p in ULOGS}


@needs_logs
def test_each_ulog_imports_on_a_uniform_grid(imported):
    from uavdyn.flightdata.ulog import summary

    assert len(imported) == 3
    rows = []
    for name, s in imported.items():
        assert s.kind == "multirotor"
        steps = np.diff(s.time)
        assert np.allclose(steps, steps[0], rtol=1e-9) and steps[0] > 0
        assert np.all(np.isfinite(s.to_array()))
        assert s.duration > 5.0
        # the importer output passes the loader's checks, pitch-plane kinematics included
        check_values(name, s.kind, s.time, s.states, s.controls)
        rows.append(summary(s))
    cols = ["name", "rows", "duration_s", "rate_hz", "theta_deg", "q_radps", "u_mps", "w_mps",
            "u0", "u1", "roll_max_deg", "rms_int_q_vs_theta_rad", "rms_int_q_vs_theta_1s_rad"]
    print("\n| " + " | ".join(cols) + " |\n|" + "---|" * len(cols))
    for r in rows:
        print("| " + " | ".join(f"{r[c]:.2e}" if isinstance(r[c], float) and c.startswith("rms")
                                else str(r[c]) for c in cols) + " |")
    print("(u0, u1 = collective, pitch_cmd; sources per log in sortie.meta['sources'])")


@needs_logs
def test_integrated_pitch_rate_follows_pitch(imported):
    """Integrating q reproduces pitch: over 1 s windows to a few mrad; over the whole log the
    drift stays small (gyro bias, and roll coupling in the hand-moved log)."""
    from uavdyn.flightdata.ulog import integrated_pitch_rms

    for name, s in imported.items():
        full, windowed = integrated_pitch_rms(s), integrated_pitch_rms(s, 1.0)
        print(f"\n{name}: RMS(theta - integral q) whole log {full:.2e} rad, "
              f"1 s windows {windowed:.2e} rad, pitch swing {np.ptp(s.states[:, 3]):.3f} rad")
        assert windowed < 0.01
        assert full < 0.1
    moving = imported["pyulog_sample.ulg"]
    assert np.ptp(moving.states[:, 3]) > 0.2  # the hand-moved log really pitches (+-8 deg)
    assert integrated_pitch_rms(moving, 1.0) < 0.05 * np.ptp(moving.states[:, 3])


@needs_logs
def test_pitch_from_quaternion_matches_independent_sources(imported):
    """No ULog here logs an Euler pitch of the estimate (only setpoints), so the quaternion
    pitch is checked against (a) an independent Euler decomposition (scipy, ZYX) of the same
    quaternions and (b) the separate control_state quaternion of the 2016 log."""
    from pyulog import ULog
    from scipy.spatial.transform import Rotation

    from uavdyn.flightdata.ulog import pitch_from_quaternion

    for path in ULOGS:
        ulog = ULog(str(path))
        euler_pitch = [d for d in ulog.data_list if d.name == "vehicle_attitude"
                       and "pitch" in d.data]
        att = next(d for d in ulog.data_list if d.name == "vehicle_attitude")
        Q = np.column_stack([att.data[f"q[{i}]"] for i in range(4)]).astype(float)
        Q = Q[np.linalg.norm(Q, axis=1) > 0.5]
        ours = pitch_from_quaternion(Q / np.linalg.norm(Q, axis=1, keepdims=True))
        scipy_pitch = Rotation.from_quat(Q[:, [1, 2, 3, 0]]).as_euler("ZYX")[:, 1]
        assert np.max(np.abs(ours - scipy_pitch)) < 1e-9
        if euler_pitch:  # pragma: no cover - none of the shipped logs has one
            assert np.sqrt(np.mean((ours - euler_pitch[0].data["pitch"]) ** 2)) < 0.01
    s = imported["pyulog_sample.ulg"]
    ulog = ULog(str(LOGS / "pyulog_sample.ulg"))
    cs = next(d for d in ulog.data_list if d.name == "control_state")
    Qc = np.column_stack([cs.data[f"q[{i}]"] for i in range(4)]).astype(float)
    pitch_cs = np.interp(s.time + s.meta["start_time_s"], cs.data["timestamp"] * 1e-6,
                         pitch_from_quaternion(Qc))
    rms = float(np.sqrt(np.mean((pitch_cs - s.states[:, 3]) ** 2)))
    print(f"\npyulog_sample: vehicle_attitude pitch vs control_state pitch RMS "
          f"{np.degrees(rms):.4f} deg")
    assert rms < np.radians(0.1)


@needs_logs
def test_stray_samples_are_cut_and_recorded(imported):
    small = imported["pyulog_sample_log_small.ulg"]
    assert small.meta["stray_samples_cut"]  # this log has stray samples (README)
    assert small.duration < 10.0  # not the 19.5 min the header claims
    assert small.meta["sources"]["q"] == "vehicle_angular_velocity.xyz[1]"
    old = imported["pyulog_sample.ulg"]
    assert old.meta["sources"]["q"] == "vehicle_attitude.pitchspeed"  # 2016 layout fallback
    assert old.meta["sources"]["collective"] == "actuator_controls_0.control[3]"


@needs_logs
def test_control_sources_agree(imported):
    """The SITL log has both the thrust/torque setpoints and the motor commands: collective
    from the X-frame motor mean follows the thrust setpoint."""
    path = LOGS / "pyulog_sample_px4_events.ulg"
    sp = imported[path.name]
    assert sp.meta["sources"]["collective"] == "-vehicle_thrust_setpoint.xyz[2]"
    motors = import_ulog(path, control_source="motors")
    assert motors.meta["sources"]["collective"].startswith("mean of actuator_motors")
    n = min(len(sp.time), len(motors.time))
    r = np.corrcoef(sp.controls[:n, 0], motors.controls[:n, 0])[0, 1]
    assert r > 0.95
    with pytest.raises(FlightDataError, match="requested control source 'actuator_controls'"):
        import_ulog(path, control_source="actuator_controls")


@needs_logs
def test_bad_inputs_and_export(imported, tmp_path):
    junk = tmp_path / "junk.ulg"
    junk.write_bytes(b"definitely not a ulog file" * 20)
    with pytest.raises(FlightDataError, match="junk.ulg: not a readable ULog file"):
        import_ulog(junk)
    with pytest.raises(FlightDataError, match="file not found"):
        import_ulog(tmp_path / "missing.ulg")
    s = imported["pyulog_sample.ulg"]
    back = read_csv(export(s, tmp_path / "sample.csv"))
    np.testing.assert_array_equal(back.states, s.states)
    np.testing.assert_array_equal(back.controls, s.controls)


@pytest.mark.skipif(not ALFA, reason=f"ALFA CSV folder not found in {LOGS}")
def test_alfa_fixed_wing_import():
    """ALFA: the quaternion pitch matches the autopilot's logged Euler pitch; the banked flight
    fails the pitch-plane kinematic check, as it should (d theta/dt = q cos(phi) - r sin(phi))."""
    from uavdyn.flightdata.ulog import import_alfa, integrated_pitch_rms, summary

    s = import_alfa(ALFA[0])
    row = summary(s)
    rms = float(np.sqrt(np.mean((s.meta["nav_pitch"] - s.states[:, 3]) ** 2)))
    corr = float(np.corrcoef(s.meta["nav_pitch"], s.states[:, 3])[0, 1])
    print(f"\nALFA {row['name']}: {row['rows']} rows at {row['rate_hz']} Hz, theta "
          f"{row['theta_deg']} deg, u {row['u_mps']} m/s; quaternion vs logged Euler pitch "
          f"RMS {np.degrees(rms):.2f} deg (corr {corr:.3f}); integral-q RMS 1 s windows "
          f"{integrated_pitch_rms(s, 1.0):.3f} rad")
    assert s.kind == "fixed_wing" and np.all(np.isfinite(s.to_array()))
    assert rms < np.radians(2.0) and corr > 0.95
    assert 9.0 < s.states[:, 0].min() and s.states[:, 0].max() < 23.0
    with pytest.raises(FlightDataError, match="kinematic inconsistency"):
        check_values("alfa", s.kind, s.time, s.states, s.controls)
