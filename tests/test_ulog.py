"""Import of real logs (PX4 ULog and the ALFA fixed-wing CSVs): each imports onto a uniform
grid, pitch from the quaternion agrees with independent pitch sources, the integrated pitch
rate follows pitch (RMS printed), and a summary table is shown.

The logs are the trimmed copies shipped in ``tests/data/reallogs`` (see ``tests/reallogs.py``
and the README there: every sample of the topics/columns the importers read is kept, and each
copy imports to exactly the same arrays as its original), so these tests run in any clone.
pyulog is installed by the ``dev`` extra, so a missing pyulog fails here rather than skipping.
The 2016 pyulog example log (hand-moved quadrotor, ``control_state`` topic) is too large to
ship; the importers' tests on synthetic logs with known content, its 2016-layout fallbacks
(``vehicle_attitude.pitchspeed``) included, are in ``tests/test_ulog_synthetic.py``."""

import numpy as np
import pytest
from reallogs import alfa_folder, ulog, ulogs

from uavdyn.flightdata import FlightDataError, check_values, export, import_ulog, read_csv

ULOGS = ulogs()
SITL = ulog("px4_sitl_hover.ulg")
VTOL = ulog("px4_vtol_ground_run.ulg")


@pytest.fixture(scope="module")
def imported():
    return {p.name: import_ulog(p) for p in ULOGS}


def test_each_ulog_imports_on_a_uniform_grid(imported):
    from uavdyn.flightdata.ulog import summary

    assert len(imported) == 2
    assert set(imported) == {SITL.name, VTOL.name}
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


def test_integrated_pitch_rate_follows_pitch(imported):
    """Integrating q reproduces pitch: over 1 s windows to a few mrad; over the whole log the
    drift stays small (gyro bias)."""
    from uavdyn.flightdata.ulog import integrated_pitch_rms

    for name, s in imported.items():
        full, windowed = integrated_pitch_rms(s), integrated_pitch_rms(s, 1.0)
        print(f"\n{name}: RMS(theta - integral q) whole log {full:.2e} rad, "
              f"1 s windows {windowed:.2e} rad, pitch swing {np.ptp(s.states[:, 3]):.3f} rad")
        assert windowed < 0.01
        assert full < 0.1


def test_pitch_from_quaternion_matches_independent_sources(imported):
    """No ULog here logs an Euler pitch of the estimate (only setpoints), so the quaternion
    pitch is checked against an independent Euler decomposition (scipy, ZYX) of the same
    quaternions."""
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


def test_stray_samples_are_cut_and_recorded(imported):
    small = imported[VTOL.name]
    assert small.meta["stray_samples_cut"]  # this log has stray samples (README)
    assert small.duration < 10.0  # not the 19.5 min the header claims
    assert small.meta["sources"]["q"] == "vehicle_angular_velocity.xyz[1]"
    # PX4 <= 1.13 layout: the multirotor controls come from actuator_controls_0
    assert small.meta["sources"]["collective"] == "actuator_controls_0.control[3]"


def test_control_sources_agree(imported):
    """The SITL log has both the thrust/torque setpoints and the motor commands: collective
    from the X-frame motor mean follows the thrust setpoint."""
    path = SITL
    sp = imported[path.name]
    assert sp.meta["sources"]["collective"] == "-vehicle_thrust_setpoint.xyz[2]"
    motors = import_ulog(path, control_source="motors")
    assert motors.meta["sources"]["collective"].startswith("mean of actuator_motors")
    n = min(len(sp.time), len(motors.time))
    r = np.corrcoef(sp.controls[:n, 0], motors.controls[:n, 0])[0, 1]
    assert r > 0.95
    with pytest.raises(FlightDataError, match="requested control source 'actuator_controls'"):
        import_ulog(path, control_source="actuator_controls")


def test_bad_inputs_and_export(imported, tmp_path):
    junk = tmp_path / "junk.ulg"
    junk.write_bytes(b"definitely not a ulog file" * 20)
    with pytest.raises(FlightDataError, match="junk.ulg: not a readable ULog file"):
        import_ulog(junk)
    with pytest.raises(FlightDataError, match="file not found"):
        import_ulog(tmp_path / "missing.ulg")
    s = imported[SITL.name]
    back = read_csv(export(s, tmp_path / "sample.csv"))
    np.testing.assert_array_equal(back.states, s.states)
    np.testing.assert_array_equal(back.controls, s.controls)


def test_alfa_fixed_wing_import():
    """ALFA: the quaternion pitch matches the autopilot's logged Euler pitch; the banked flight
    fails the pitch-plane kinematic check, as it should (d theta/dt = q cos(phi) - r sin(phi))."""
    from uavdyn.flightdata.ulog import import_alfa, integrated_pitch_rms, summary

    s = import_alfa(alfa_folder())
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
