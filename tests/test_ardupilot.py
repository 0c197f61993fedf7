"""ArduPilot DataFlash import: logs with known content written by tests/dataflash_writer.py
(a level leg, a 30 deg banked turn through north-west to south-east, a pitch doublet at 50 Hz)
must come back as the written truth."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from dataflash_writer import DataFlashWriter

from uavdyn.flightdata.ardupilot import PYMAVLINK_HINT, read_dataflash
from uavdyn.flightdata.attitude import body_from_euler
from uavdyn.flightdata.control_map import ChannelMap
from uavdyn.flightdata.errors import FlightDataError

RATE = 50
T0_US = 2_000_000
WIND_NED = np.array([4.0, -3.0, 0.0])
AIRSPEED = 20.0
PWM_PER_RAD = 500 / 0.35   # SERVO MIN/TRIM/MAX 1000/1500/2000 us <-> +-0.35 rad

MESSAGES = {
    "PARM": ("QNff", "TimeUS,Name,Value,Default"),
    "VER": ("QBHBBBBIZHB", "TimeUS,BT,BST,Maj,Min,Pat,FWT,GH,FWS,APJ,BU"),
    "MSG": ("QZ", "TimeUS,Message"),
    "ATT": ("QccccCCCCB", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw,AEKF"),
    "IMU": ("QBffffffIIfBBHH", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz"),
    "XKF1": ("QBccCfffffffccce", "TimeUS,C,Roll,Pitch,Yaw,VN,VE,VD,dPD,PN,PE,PD,GX,GY,GZ,OH"),
    "XKF2": ("QBccccchhhhhhfff", "TimeUS,C,AX,AY,AZ,VWN,VWE,MN,ME,MD,MX,MY,MZ,IDX,IDY,IS"),
    "GPS": ("QBBIHBcLLeffffB", "TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw,U"),
    "ARSP": ("QBffcffBBffB", "TimeUS,I,Airspeed,DiffPress,Temp,RawPress,Offset,U,H,Hp,TR,Pri"),
    "CTUN": ("QccccffffBffi", "TimeUS,NavRoll,Roll,NavPitch,Pitch,ThO,RdO,ThD,As,AsT,SAs,E2T,GU"),
    "RCOU": ("QHHHHHHHHHHHHHH", "TimeUS," + ",".join(f"C{i}" for i in range(1, 15))),
    "POS": ("QLLfff", "TimeUS,Lat,Lng,Alt,RelHomeAlt,RelOriginAlt"),
    "BARO": ("QBffcf", "TimeUS,I,Alt,Press,Temp,CRt"),
    "STAT": ("QBfBBBBBB", "TimeUS,isFlying,isFlyProb,Armed,Safety,Crash,Still,Stage,Hit"),
    "RATE": ("Qfffffffffffff", "TimeUS,RDes,R,ROut,PDes,P,POut,YDes,Y,YOut,ADes,A,AOut,AOutSlew"),
}
COPTER_CTUN = ("Qfffff", "TimeUS,ThI,ABst,ThO,ThH,DAlt")


def _smooth(x: np.ndarray) -> np.ndarray:
    """0 -> 1 smoothstep on [0, 1]."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def truth(duration: float = 30.0) -> dict[str, np.ndarray]:
    """The flight: level 0-10 s, a 30 deg banked turn 10-20 s (yaw crossing +-180 deg), a
    wings-level pitch doublet 22-24 s with its elevator doublet; air-relative body velocity
    at 20 m/s, a steady 5 m/s wind."""
    t = np.arange(int(duration * RATE)) / RATE
    roll = np.radians(30) * (_smooth((t - 10) / 2) - _smooth((t - 18) / 2))
    doublet = np.where((t >= 22) & (t < 23), 1.0, np.where((t >= 23) & (t < 24), -1.0, 0.0))
    pitch = 0.05 + 0.1 * np.sin(np.pi * np.clip(t - 22, 0, 2)) * ((t > 22) & (t < 24))
    yaw_rate = 9.81 * np.tan(roll) / AIRSPEED
    yaw = 2.5 + np.concatenate([[0.0], np.cumsum(yaw_rate[1:] + yaw_rate[:-1]) / (2 * RATE)])
    roll_dot, pitch_dot = np.gradient(roll, t), np.gradient(pitch, t)
    p = roll_dot - yaw_rate * np.sin(pitch)
    q = pitch_dot * np.cos(roll) + yaw_rate * np.sin(roll) * np.cos(pitch)
    r = -pitch_dot * np.sin(roll) + yaw_rate * np.cos(roll) * np.cos(pitch)
    alpha = 0.06 + 0.02 * doublet
    body_air = np.column_stack([AIRSPEED * np.cos(alpha), np.zeros_like(t),
                                AIRSPEED * np.sin(alpha)])
    dcm = body_from_euler(roll, pitch, yaw)
    ned_air = np.einsum("nji,nj->ni", dcm, body_air)        # body -> NED is the transpose
    elevator = -0.105 * doublet                               # 150 us of PWM per 0.105 rad
    throttle = 0.55 + 0.1 * (t > 10) * (t < 20)
    return {"t": t, "roll": roll, "pitch": pitch, "yaw": yaw, "p": p, "q": q, "r": r,
            "body_air": body_air, "ned_ground": ned_air + WIND_NED, "dcm": dcm,
            "elevator": elevator, "throttle": throttle, "alt": 350.0 + 2 * t,
            "flying": (t >= 1.0).astype(float)}


def write_plane(path, tr, omit=(), params=None, imu_gap=None, wind=True, airspeed=True,
                velocity="XKF1", vehicle="plane", att_every=1):
    """A DataFlash log of the truth ``tr``; ``omit`` leaves messages out entirely; ATT is
    written every ``att_every``-th sample (a slower attitude than IMU)."""
    w = DataFlashWriter()
    defs = dict(MESSAGES)
    if vehicle == "copter":
        defs["CTUN"] = COPTER_CTUN
    for name, (fmt, cols) in defs.items():
        if name not in omit:
            w.define(name, fmt, cols)
    if "VER" not in omit:
        w.write("VER", TimeUS=T0_US - 1000, BU=3 if vehicle == "plane" else 2)
    default_params = {"SERVO2_FUNCTION": 19, "SERVO2_MIN": 1000, "SERVO2_MAX": 2000,
                      "SERVO2_TRIM": 1500, "SERVO2_REVERSED": 0, "SERVO1_FUNCTION": 4,
                      "SERVO3_FUNCTION": 70}
    for k, v in (default_params if params is None else params).items():
        w.write("PARM", TimeUS=T0_US - 500, Name=k, Value=v)
    reversed_ = (params or default_params).get("SERVO2_REVERSED", 0)
    for k, t in enumerate(tr["t"]):
        us = T0_US + k * 20_000
        deg = {a: float(np.degrees(tr[a][k])) for a in ("roll", "pitch", "yaw")}
        if "ATT" not in omit and k % att_every == 0:
            w.write("ATT", TimeUS=us, Roll=deg["roll"], Pitch=deg["pitch"],
                    Yaw=deg["yaw"] % 360.0)
        if "IMU" not in omit and not (imu_gap and imu_gap[0] <= t <= imu_gap[1]):
            for inst, bias in ((0, 0.0), (1, 1.0)):      # instance 1 must be ignored
                w.write("IMU", TimeUS=us + inst, I=inst, GyrX=tr["p"][k] + bias,
                        GyrY=tr["q"][k] + bias, GyrZ=tr["r"][k] + bias)
        vn, ve, vd = tr["ned_ground"][k]
        if velocity == "XKF1" and "XKF1" not in omit:
            for core, bias in ((0, 0.0), (1, 3.0)):       # core 1 must be ignored
                w.write("XKF1", TimeUS=us + core, C=core, VN=vn + bias, VE=ve, VD=vd)
        if velocity == "GPS":
            w.write("GPS", TimeUS=us, I=0, Status=3, Spd=float(np.hypot(vn, ve)),
                    GCrs=float(np.degrees(np.arctan2(ve, vn)) % 360), VZ=vd)
        if wind and "XKF2" not in omit:
            w.write("XKF2", TimeUS=us, C=0, VWN=WIND_NED[0], VWE=WIND_NED[1])
        if airspeed and "ARSP" not in omit:
            w.write("ARSP", TimeUS=us, I=0, Airspeed=AIRSPEED)
        sign = -1 if reversed_ == 0 else 1
        if "RCOU" not in omit:
            w.write("RCOU", TimeUS=us, C1=1500, C2=1500 + sign * tr["elevator"][k] * PWM_PER_RAD,
                    C3=1000 + 1000 * tr["throttle"][k])
        if "CTUN" not in omit:
            tho = tr["throttle"][k] * (100 if vehicle == "plane" else 1)
            w.write("CTUN", TimeUS=us, ThO=tho)
        if vehicle == "copter":
            w.write("RATE", TimeUS=us, POut=float(np.sin(t)))
        if "POS" not in omit:
            w.write("POS", TimeUS=us, Alt=tr["alt"][k])
        if "BARO" not in omit:
            w.write("BARO", TimeUS=us, I=0, Alt=tr["alt"][k] - 300)
        if "STAT" not in omit:
            w.write("STAT", TimeUS=us, isFlying=tr["flying"][k])
    return w.save(path)


@pytest.fixture(scope="module")
def pymavlink():
    """Every test that reads a log needs the optional pymavlink (the install-hint test not)."""
    return pytest.importorskip("pymavlink")


@pytest.fixture(scope="module")
def tr(pymavlink):
    return truth()


def test_fixed_wing_channels_equal_the_written_truth(tmp_path, tr):
    log = read_dataflash(write_plane(tmp_path / "plane.bin", tr))
    assert log.kind == "fixed_wing" and log.source == "ArduPilot DataFlash"
    assert log.meta["vehicle"].startswith("VER.BU = 3")
    assert log.dt == pytest.approx(1 / RATE) and len(log.time) == len(tr["t"])
    assert log.meta["start_time_s"] == pytest.approx(T0_US * 1e-6)
    c = log.channels
    for key in ("roll", "pitch"):   # ATT stores centidegrees
        np.testing.assert_allclose(c[key], tr[key], atol=1e-4)
    for key in ("p", "q", "r"):     # IMU instance 0, float32
        np.testing.assert_allclose(c[key], tr[key], atol=1e-5)
    assert log.velocity_reference == "air"
    np.testing.assert_allclose(np.column_stack([c["u"], c["v"], c["w"]]), tr["body_air"],
                               atol=1e-2)
    np.testing.assert_allclose(log.controls[:, 0], tr["elevator"], atol=1e-3)
    np.testing.assert_allclose(log.controls[:, 1], tr["throttle"], atol=1e-6)
    np.testing.assert_allclose(log.airspeed, AIRSPEED, atol=1e-5)
    np.testing.assert_allclose(log.altitude_m, tr["alt"], atol=1e-3)
    assert log.meta["altitude_reference"].startswith("AMSL")
    np.testing.assert_array_equal(log.airborne, tr["flying"] == 1)
    assert log.meta["control_map"]["elevator"] == {"source": "RCOU.C2", "raw": [1000, 2000],
                                                   "value": [0.35, -0.35]}
    assert "percent" in log.meta["control_map_notes"]["throttle"]
    assert "assumed" in log.meta["control_map_notes"]["elevator"]


def test_a_slow_att_gets_the_imu_grid_and_the_pitch_between_its_samples(tmp_path, tr):
    """ATT at 5 Hz, IMU at 50 Hz (issue 41 item 4): the grid follows IMU, and roll and pitch
    between the ATT samples come from the integrated gyro, close to the written truth where a
    straight line between the ATT samples is not."""
    log = read_dataflash(write_plane(tmp_path / "slow.bin", tr, att_every=10))
    assert log.dt == pytest.approx(1 / RATE)
    assert log.meta["grid"].startswith("50 Hz from IMU (50 Hz), the fastest body-rate topic")
    n = len(log.time)           # the grid ends at the last ATT sample
    t = tr["t"][:n]
    inner = (t >= 0.2) & (t <= t[-1] - 0.2)
    for key in ("roll", "pitch"):   # the truth's rates are finite differences: kinks smear
        line = np.interp(t, tr["t"][::10], tr[key][::10])
        rms_line = np.sqrt(np.mean((line - tr[key][:n])[inner] ** 2))
        rms = np.sqrt(np.mean((log.channels[key] - tr[key][:n])[inner] ** 2))
        assert rms < rms_line / 3 and rms < 3e-4, (key, rms, rms_line)
        np.testing.assert_allclose(log.channels[key][inner], tr[key][:n][inner], atol=2e-3)


def test_turn_crosses_180_deg_without_a_yaw_swing(tmp_path, tr):
    """The turn's yaw passes +-180 deg: u, w there are as accurate as anywhere."""
    assert tr["yaw"].max() > np.pi
    log = read_dataflash(write_plane(tmp_path / "plane.bin", tr))
    turn = (tr["t"] > 10) & (tr["t"] < 20)
    assert np.degrees(np.abs(log.channels["roll"][turn])).max() == pytest.approx(30, abs=0.01)
    np.testing.assert_allclose(log.channels["u"][turn], tr["body_air"][turn, 0], atol=1e-2)


def test_airspeed_rule_without_a_wind_estimate(tmp_path, tr):
    log = read_dataflash(write_plane(tmp_path / "plane.bin", tr, wind=False))
    assert log.velocity_reference == "airspeed"
    ground_body = np.einsum("nij,nj->ni", tr["dcm"], tr["ned_ground"])
    np.testing.assert_allclose(log.channels["w"], ground_body[:, 2], atol=1e-2)
    np.testing.assert_allclose(log.channels["v"], ground_body[:, 1], atol=1e-2)
    expected_u = np.sqrt(AIRSPEED ** 2 - ground_body[:, 2] ** 2)
    np.testing.assert_allclose(log.channels["u"], expected_u, atol=1e-2)


def test_ground_reference_from_gps(tmp_path, tr):
    log = read_dataflash(write_plane(tmp_path / "plane.bin", tr, wind=False, airspeed=False,
                                     velocity="GPS"))
    assert log.velocity_reference == "ground" and log.airspeed is None
    ground_body = np.einsum("nij,nj->ni", tr["dcm"], tr["ned_ground"])
    got = np.column_stack([log.channels[k] for k in "uvw"])
    np.testing.assert_allclose(got, ground_body, atol=2e-2)
    assert log.meta["sources"]["u, v, w"].startswith("GPS")


def test_gyro_gap_is_nan_exactly_there(tmp_path, tr):
    log = read_dataflash(write_plane(tmp_path / "plane.bin", tr, imu_gap=(5.0, 6.5)))
    t = log.time
    inside = (t > 4.98 + 1e-9) & (t < 6.52 - 1e-9)
    for key in ("p", "q", "r"):
        assert np.isnan(log.channels[key][inside]).all()
        assert np.isfinite(log.channels[key][~inside]).all()
    assert np.isfinite(log.channels["pitch"]).all()


def test_reversed_servo_on_another_output_and_percent(tmp_path, tr):
    params = {"SERVO2_FUNCTION": 19, "SERVO2_MIN": 1000, "SERVO2_MAX": 2000,
              "SERVO2_TRIM": 1500, "SERVO2_REVERSED": 1}
    log = read_dataflash(write_plane(tmp_path / "plane.bin", tr, params=params))
    np.testing.assert_allclose(log.controls[:, 0], tr["elevator"], atol=1e-3)
    assert log.meta["control_map"]["elevator"]["value"] == [-0.35, 0.35]


def test_elevons_without_an_elevator_servo_are_refused(tmp_path, tr):
    params = {"SERVO1_FUNCTION": 77, "SERVO2_FUNCTION": 78}
    path = write_plane(tmp_path / "plane.bin", truth(3.0),
                       params=params)
    with pytest.raises(FlightDataError, match="SERVOn_FUNCTION = 19"):
        read_dataflash(path)
    # a given elevator map reads the named output instead
    given = [ChannelMap("elevator", "RCOU.C2", 1000, 2000, 0.35, -0.35)]
    log = read_dataflash(path, control_maps=given)
    assert log.meta["control_map_notes"]["elevator"] == "given by the user"


def test_control_map_override(tmp_path, tr):
    path = write_plane(tmp_path / "plane.bin", tr)
    maps = [ChannelMap("elevator", "RCOU.C2", 1000, 2000, 0.7, -0.7),
            ChannelMap("throttle", "RCOU.C3", 1000, 2000, 0.0, 1.0)]
    log = read_dataflash(path, control_maps=maps)
    np.testing.assert_allclose(log.controls[:, 0], 2 * tr["elevator"], atol=2e-3)
    np.testing.assert_allclose(log.controls[:, 1], tr["throttle"], atol=1e-3)
    assert log.meta["control_map"]["throttle"]["source"] == "RCOU.C3"
    with pytest.raises(FlightDataError, match="no field C20"):
        read_dataflash(path, control_maps=[ChannelMap("throttle", "RCOU.C20", 0, 1, 0, 1)])
    with pytest.raises(FlightDataError, match="MESSAGE.FIELD"):
        read_dataflash(path, control_maps=[ChannelMap("throttle", "RCOU", 0, 1, 0, 1)])
    with pytest.raises(FlightDataError, match="collective"):
        read_dataflash(path, control_maps=[ChannelMap("collective", "RCOU.C3", 0, 1, 0, 1)])


def test_multirotor(tmp_path, tr):
    log = read_dataflash(write_plane(tmp_path / "copter.bin", tr, vehicle="copter",
                                     omit=("STAT",)))
    assert log.kind == "multirotor" and log.meta["vehicle"].startswith("VER.BU = 2")
    np.testing.assert_allclose(log.controls[:, 0], tr["throttle"], atol=1e-6)
    np.testing.assert_allclose(log.controls[:, 1], np.sin(tr["t"]), atol=1e-6)
    assert "fraction" in log.meta["control_map_notes"]["collective"]
    assert log.airborne is None


def test_kind_from_messages_and_relative_altitude(tmp_path, tr):
    log = read_dataflash(write_plane(tmp_path / "plane.bin", truth(3.0), omit=("VER", "POS")))
    assert log.kind == "fixed_wing" and log.meta["vehicle"].startswith("inferred")
    assert "NOT above mean sea level" in log.meta["altitude_reference"]
    assert read_dataflash(tmp_path / "plane.bin", kind="multirotor",
                          control_maps=[ChannelMap("pitch_cmd", "RCOU.C2", 1000, 2000, -1, 1)]
                          ).kind == "multirotor"


@pytest.mark.parametrize("missing, named", [("IMU", "IMU"), ("ATT", "ATT"),
                                            ("CTUN", "CTUN.ThO"), ("RCOU", "RCOU.C2")])
def test_missing_message_is_one_line_naming_it(pymavlink, tmp_path, missing, named):
    path = write_plane(tmp_path / "plane.bin", truth(3.0), omit=(missing,))
    with pytest.raises(FlightDataError) as err:
        read_dataflash(path)
    text = str(err.value)
    assert named in text and "\n" not in text and "plane.bin" in text


def test_no_velocity_message(pymavlink, tmp_path):
    path = write_plane(tmp_path / "plane.bin", truth(3.0), omit=("XKF1",))
    with pytest.raises(FlightDataError, match="no velocity message"):
        read_dataflash(path)


def test_not_a_dataflash_file_and_bad_options(pymavlink, tmp_path):
    bad = tmp_path / "notes.bin"
    bad.write_bytes(b"hello, this is no log")
    with pytest.raises(FlightDataError, match="not an ArduPilot DataFlash"):
        read_dataflash(bad)
    (tmp_path / "empty.bin").write_bytes(b"")
    with pytest.raises(FlightDataError, match="empty file"):
        read_dataflash(tmp_path / "empty.bin")
    with pytest.raises(FlightDataError, match="file not found"):
        read_dataflash(tmp_path / "absent.bin")
    with pytest.raises(FlightDataError, match="unknown kind"):
        read_dataflash(bad, kind="glider")
    with pytest.raises(FlightDataError, match="rate_hz"):
        read_dataflash(bad, rate_hz=-1)
    with pytest.raises(FlightDataError, match="control_maps"):
        read_dataflash(bad, control_maps=["elevator=RCOU.C2:1:2:3:4"])


def test_truncated_log_reads_its_complete_messages(tmp_path, tr):
    path = write_plane(tmp_path / "plane.bin", truth(3.0))
    data = path.read_bytes()
    path.write_bytes(data[:-7])
    log = read_dataflash(path)
    assert np.isfinite(log.channels["pitch"]).all()


def test_missing_pymavlink_gives_the_install_hint(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "pymavlink", None)
    monkeypatch.setitem(sys.modules, "pymavlink.DFReader", None)
    with pytest.raises(FlightDataError) as err:
        read_dataflash(tmp_path / "any.bin")
    assert err.value.reason == PYMAVLINK_HINT


def test_import_log_cuts_a_bin_log_into_segments_with_the_same_columns(tmp_path, tr, capsys):
    """``uavdyn import-log`` on a .bin: the wings-level parts of the written flight become
    sorties whose columns are the interchange format's, values equal to the written truth."""
    from uavdyn.cli.app import main
    from uavdyn.flightdata import csv_columns, load_dataset

    log = tmp_path / "plane.bin"
    write_plane(log, tr)
    out = tmp_path / "data"
    assert main(["import-log", str(log), "--fractions", "1,0,0", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "kept" in printed and "banked above 10 deg" in printed
    ds = load_dataset(out)
    assert ds.kind == "fixed_wing" and ds.sorties
    header = (out / f"{ds.sorties[0].name}.csv").read_text().splitlines()[0].split(",")
    assert tuple(header) == csv_columns("fixed_wing")
    flight = read_dataflash(log)
    for s, entry in zip(ds.sorties, s_entries(out)):
        start = int(round(entry["flight_time_s"][0] * flight.meta["rate_hz"]))
        np.testing.assert_allclose(s.states[:, 3], flight.channels["pitch"][
            start:start + len(s.time)], atol=1e-6)
        assert np.all(np.abs(flight.channels["roll"][start:start + len(s.time)])
                      <= np.radians(10) + 1e-9)


def s_entries(folder):
    """The manifest's sortie entries."""
    import json

    return json.loads((folder / "manifest.json").read_text())["sorties"]
