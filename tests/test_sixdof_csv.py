"""The generic six-degree-of-freedom CSV: a synthetic log with known values comes back on the
grid (body and NED velocities, irregular stamps, gaps as NaN exactly there), and every
malformed file is refused with one line naming file, row and column."""

from __future__ import annotations

import numpy as np
import pytest

from uavdyn.flightdata.attitude import body_from_euler
from uavdyn.flightdata.control_map import ChannelMap
from uavdyn.flightdata.errors import FlightDataError
from uavdyn.flightdata.sixdof_csv import read_sixdof_csv

RATE = 50.0


def flight(t: np.ndarray) -> dict[str, np.ndarray]:
    """Smooth known channels (a banked turn through yaw +-pi, a pitch oscillation)."""
    roll = 0.4 * np.sin(0.3 * t)
    pitch = 0.05 + 0.08 * np.sin(1.1 * t)
    yaw = np.pi - 0.5 + 0.25 * t                      # crosses +-pi at t = 2 s
    yaw = (yaw + np.pi) % (2 * np.pi) - np.pi
    body = np.column_stack([20 + np.sin(0.5 * t), 0.3 * np.cos(t), 1.2 + 0.2 * np.sin(t)])
    ned = np.einsum("nji,nj->ni", body_from_euler(roll, pitch, yaw), body)
    return {"time": t, "roll": roll, "pitch": pitch, "yaw": yaw,
            "p": 0.12 * np.cos(0.3 * t), "q": 0.088 * np.cos(1.1 * t), "r": 0.25 + 0 * t,
            "u": body[:, 0], "v": body[:, 1], "w": body[:, 2],
            "vn": ned[:, 0], "ve": ned[:, 1], "vd": ned[:, 2],
            "elevator": -0.05 + 0.02 * np.sign(np.sin(2 * t)), "throttle": 0.6 + 0 * t,
            "collective": 0.5 + 0.1 * np.sin(t), "pitch_cmd": 0.2 * np.sin(3 * t),
            "airspeed": np.linalg.norm(body, axis=1), "altitude_m": 300 + t,
            "airborne": (t > 1).astype(float)}


def write(path, data: dict[str, np.ndarray], columns: list[str], blank=None) -> None:
    """A CSV of ``columns``; ``blank`` maps a column to the row indices left empty."""
    rows = [",".join(columns)]
    for k in range(len(data["time"])):
        cells = []
        for c in columns:
            empty = blank is not None and k in blank.get(c, ())
            cells.append("" if empty else repr(float(data[c][k])))
        rows.append(",".join(cells))
    path.write_text("\n".join(rows) + "\n")


BODY = ["time", "roll", "pitch", "p", "q", "r", "u", "v", "w", "elevator", "throttle"]
NED = ["time", "roll", "pitch", "yaw", "p", "q", "r", "vn", "ve", "vd", "elevator",
       "throttle"]


def test_round_trip_body_velocities(tmp_path):
    t = np.arange(0, 10, 1 / RATE)
    data = flight(t)
    write(tmp_path / "f.csv", data, BODY + ["altitude_m", "airborne", "vn"])
    log = read_sixdof_csv(tmp_path / "f.csv", "fixed_wing")
    assert log.kind == "fixed_wing" and log.velocity_reference == "ground"
    assert log.dt == pytest.approx(1 / RATE) and len(log.time) == len(t)
    for c in ("roll", "pitch", "p", "q", "r", "u", "v", "w"):
        np.testing.assert_allclose(log.channels[c], data[c], atol=1e-12, err_msg=c)
    np.testing.assert_allclose(log.controls, np.column_stack([data["elevator"],
                                                              data["throttle"]]), atol=1e-12)
    np.testing.assert_allclose(log.altitude_m, data["altitude_m"], atol=1e-9)
    np.testing.assert_array_equal(log.airborne, data["airborne"] == 1)
    assert log.airspeed is None
    assert log.meta["control_map"]["elevator"] == {"source": "elevator", "raw": [0.0, 1.0],
                                                   "value": [0.0, 1.0]}
    assert "median stamp interval" in log.meta["resampling"]
    assert log.meta["unused_columns"] == ["vn"]


def test_ned_velocities_rotated_with_yaw_across_pi(tmp_path):
    t = np.arange(0, 6, 1 / RATE)
    data = flight(t)
    write(tmp_path / "f.csv", data, NED)
    log = read_sixdof_csv(tmp_path / "f.csv", "fixed_wing")
    for c in ("u", "v", "w"):
        np.testing.assert_allclose(log.channels[c], data[c], atol=1e-9, err_msg=c)


def test_wind_makes_velocities_air_relative(tmp_path):
    t = np.arange(0, 4, 1 / RATE)
    data = flight(t)
    wind = np.array([5.0, -2.0, 0.5])
    data["vn"], data["ve"], data["vd"] = (data["vn"] + wind[0], data["ve"] + wind[1],
                                          data["vd"] + wind[2])
    for j, c in enumerate(("wind_n", "wind_e", "wind_d")):
        data[c] = wind[j] + 0 * t
    write(tmp_path / "f.csv", data, NED + ["wind_n", "wind_e", "wind_d"])
    log = read_sixdof_csv(tmp_path / "f.csv", "fixed_wing")
    assert log.velocity_reference == "air"
    for c in ("u", "v", "w"):
        np.testing.assert_allclose(log.channels[c], data[c], atol=1e-9, err_msg=c)


def test_airspeed_rule(tmp_path):
    t = np.arange(0, 4, 1 / RATE)
    data = flight(t)
    data["airspeed"] = data["airspeed"] + 1.0
    write(tmp_path / "f.csv", data, BODY + ["airspeed"])
    log = read_sixdof_csv(tmp_path / "f.csv", "fixed_wing")
    assert log.velocity_reference == "airspeed"
    np.testing.assert_allclose(log.channels["u"], np.sqrt(data["airspeed"] ** 2 -
                                                          data["w"] ** 2), atol=1e-9)
    np.testing.assert_allclose(log.airspeed, data["airspeed"], atol=1e-12)


def test_irregular_stamps_resampled(tmp_path):
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.015, 0.025, 400))
    data = flight(t)
    write(tmp_path / "f.csv", data, BODY)
    log = read_sixdof_csv(tmp_path / "f.csv", "fixed_wing", rate_hz=40.0)
    grid = t[0] + np.arange(len(log.time)) / 40.0
    assert log.meta["start_time_s"] == pytest.approx(t[0])
    assert grid[-1] <= t[-1] + 1e-9
    truth = flight(grid)
    for c in ("pitch", "q", "u"):   # linear interpolation of smooth signals: close
        np.testing.assert_allclose(log.channels[c], truth[c], atol=2e-3, err_msg=c)
    # controls are held: the value of the last row at or before each grid time
    held = data["elevator"][np.searchsorted(t, grid, side="right") - 1]
    np.testing.assert_allclose(log.controls[:, 0], held)
    assert "rate_hz = 40 Hz given" in log.meta["resampling"]


def test_time_gap_and_empty_cells_are_nan_exactly_there(tmp_path):
    t = np.arange(0, 10, 1 / RATE)
    keep = (t < 4.0) | (t > 5.0)                         # a 1.04 s pause in the stamps
    data = {k: v[keep] for k, v in flight(t).items()}
    rows = np.flatnonzero(np.isclose(data["time"], 7.0) | np.isclose(data["time"], 7.02))
    write(tmp_path / "f.csv", data, BODY, blank={"q": set(rows.tolist())})
    log = read_sixdof_csv(tmp_path / "f.csv", "fixed_wing")
    t_grid = log.time
    pause = (t_grid > 3.98 + 1e-9) & (t_grid < 5.02 - 1e-9)
    for c in ("roll", "pitch", "p", "r", "u", "v", "w"):
        np.testing.assert_array_equal(np.isnan(log.channels[c]), pause, err_msg=c)
    assert np.isnan(log.controls[pause]).all() and np.isfinite(log.controls[~pause]).all()
    near = (t_grid > 6.98 + 1e-9) & (t_grid < 7.04 - 1e-9)
    np.testing.assert_array_equal(np.isnan(log.channels["q"]), pause | near)
    ok = ~(pause | near)
    np.testing.assert_allclose(log.channels["q"][ok], flight(t_grid[ok])["q"], atol=1e-12)


def test_nan_cell_is_a_gap_like_an_empty_one(tmp_path):
    t = np.arange(0, 2, 1 / RATE)
    write(tmp_path / "f.csv", flight(t), BODY)
    lines = (tmp_path / "f.csv").read_text().splitlines()
    cells = lines[50].split(",")                       # data row 50, t = 0.98 s
    cells[BODY.index("r")] = "nan"
    lines[50] = ",".join(cells)
    (tmp_path / "f.csv").write_text("\n".join(lines) + "\n")
    log = read_sixdof_csv(tmp_path / "f.csv", "fixed_wing")
    np.testing.assert_array_equal(np.flatnonzero(np.isnan(log.channels["r"])), [49])


def test_multirotor_and_a_pwm_column_map(tmp_path):
    t = np.arange(0, 3, 1 / RATE)
    data = flight(t)
    data["pwm"] = 1500 + 500 * data["pitch_cmd"]
    write(tmp_path / "f.csv", data, BODY[:-2] + ["collective", "pwm"])
    log = read_sixdof_csv(tmp_path / "f.csv", "multirotor",
                          control_maps=[ChannelMap("pitch_cmd", "pwm", 1000, 2000, -1, 1)])
    np.testing.assert_allclose(log.controls[:, 0], data["collective"], atol=1e-12)
    np.testing.assert_allclose(log.controls[:, 1], data["pitch_cmd"], atol=1e-9)
    assert log.meta["control_map"]["pitch_cmd"]["source"] == "pwm"


def _refused(path, match, **kwargs):
    kwargs.setdefault("kind", "fixed_wing")
    with pytest.raises(FlightDataError, match=match) as err:
        read_sixdof_csv(path, **kwargs)
    assert "\n" not in str(err.value) and path.name in str(err.value)
    return err.value


@pytest.mark.parametrize("column", ["time", "roll", "pitch", "p", "q", "r"])
def test_missing_required_column(tmp_path, column):
    data = flight(np.arange(0, 1, 0.02))
    write(tmp_path / "f.csv", data, [c for c in BODY if c != column])
    err = _refused(tmp_path / "f.csv", f"missing column '{column}'")
    assert err.column == column and "velocities either u, v, w" in err.reason


def test_missing_velocity_yaw_wind_and_control_columns(tmp_path):
    data = flight(np.arange(0, 1, 0.02))
    write(tmp_path / "a.csv", data, [c for c in BODY if c != "v"])
    assert _refused(tmp_path / "a.csv", "missing velocity column 'v'").column == "v"
    write(tmp_path / "b.csv", data, [c for c in NED if c != "yaw"])
    _refused(tmp_path / "b.csv", "missing column 'yaw': NED velocities")
    write(tmp_path / "c.csv", data, [c for c in BODY if c != "throttle"])
    assert _refused(tmp_path / "c.csv", "no column 'throttle'").column == "throttle"
    data["wind_n"] = data["wind_e"] = 0 * data["time"]
    write(tmp_path / "d.csv", data, BODY + ["wind_n", "wind_e"])
    _refused(tmp_path / "d.csv", "missing column 'wind_d'")
    write(tmp_path / "e.csv", data, BODY)
    _refused(tmp_path / "e.csv", "no column 'servo'",
             control_maps=[ChannelMap("elevator", "servo", 1000, 2000, 0.3, -0.3)])


def test_bad_cells_and_rows(tmp_path):
    data = flight(np.arange(0, 1, 0.02))
    write(tmp_path / "f.csv", data, BODY)
    lines = (tmp_path / "f.csv").read_text().splitlines()

    def variant(name, row, col, text):
        cells = lines[row].split(",")
        cells[BODY.index(col)] = text
        out = lines[:row] + [",".join(cells)] + lines[row + 1:]
        (tmp_path / name).write_text("\n".join(out) + "\n")
        return tmp_path / name

    err = _refused(variant("a.csv", 3, "pitch", "abc"), "cannot read 'abc' as a number")
    assert (err.row, err.column) == (3, "pitch")
    err = _refused(variant("b.csv", 5, "u", "inf"), "non-finite")
    assert (err.row, err.column) == (5, "u")
    err = _refused(variant("c.csv", 4, "time", "0.02"), "not after the previous row")
    assert (err.row, err.column) == (4, "time")
    err = _refused(variant("d.csv", 2, "time", ""), "empty time cell")
    assert err.row == 2
    err = _refused(variant("e.csv", 6, "pitch", "45"), "outside \\[-pi/2, pi/2\\]")
    assert (err.row, err.column) == (6, "pitch")
    (tmp_path / "g.csv").write_text("\n".join(lines[:3] + [lines[3] + ",1"] + lines[4:]))
    assert _refused(tmp_path / "g.csv", "has 12 fields, the header has 11").row == 3


def test_refused_files_and_options(tmp_path):
    data = flight(np.arange(0, 1, 0.02))
    write(tmp_path / "f.csv", data, BODY)
    _refused(tmp_path / "f.csv", "unknown kind 'glider'", kind="glider")
    _refused(tmp_path / "f.csv", "unknown kind None", kind=None)
    _refused(tmp_path / "f.csv", "rate_hz", rate_hz=0)
    _refused(tmp_path / "f.csv", "control_maps", control_maps="elevator=x:1:2:3:4")
    _refused(tmp_path / "f.csv", "'collective'",
             control_maps=[ChannelMap("collective", "u", 0, 1, 0, 1)])
    (tmp_path / "empty.csv").write_text("")
    _refused(tmp_path / "empty.csv", "empty file")
    (tmp_path / "junk.csv").write_text("1,2,3\n4,5,6\n")
    _refused(tmp_path / "junk.csv", "first line is not a comma-separated list")
    (tmp_path / "dup.csv").write_text("time,time\n1,2\n")
    assert _refused(tmp_path / "dup.csv", "duplicated column").column == "time"
    _refused(tmp_path / "absent.csv", "file not found")
