"""The project's own probes of log content (issue 42 findings 1, 2 and 5).

Each case writes one malformed log (an ALFA folder copied from the shipped real sequence with
one cell changed, a synthetic PX4 ULog through ``tests/ulog_writer.py``, a generic
six-degree-of-freedom CSV, a dataset CSV) and asserts a one-line error naming the file and
the row, column, channel or topic; the CLI ``uavdyn import-log`` route of the log formats
shows the same line and no traceback. Genuine logs (the shipped ALFA flight, a ULog with an
accelerometer) still import: no false positives.
"""

from __future__ import annotations

import json
import shutil
import struct
from pathlib import Path

import numpy as np
import pytest

from tests.reallogs import alfa_folder
from tests.test_sixdof_csv import BODY, flight, write
from tests.test_ulog_synthetic import (
    actuator_controls,
    attitude,
    body_velocity_true,
    seconds,
    stamps,
    state_topics,
    write_log,
)
from uavdyn.cli.app import main
from uavdyn.flightdata import (
    FlightDataError,
    import_ulog,
    read_alfa_flight,
    read_csv,
    write_csv,
)
from uavdyn.flightdata.control_map import ChannelMap
from uavdyn.flightdata.sixdof_csv import read_sixdof_csv
from uavdyn.flightdata.sortie import Sortie
from uavdyn.flightdata.ulog_flight import read_ulog_flight

G = 9.80665
ARABIC_HALF = "\u0660.\u0665"   # 0.5 in Arabic-Indic digits: Python's float reads it


def _one_line(exc: FlightDataError, *names: str) -> str:
    text = str(exc)
    assert "\n" not in text
    for name in names:
        assert name in text, (name, text)
    return text


def _cli_refuses(capsys, tmp_path: Path, log: Path, *names: str, extra=()) -> str:
    """``import-log`` of ``log`` fails with one line naming ``names`` and no traceback."""
    code = main(["import-log", str(log), *extra, "--out", str(tmp_path / "out")])
    out, err = capsys.readouterr()
    assert code != 0 and "Traceback" not in err + out
    lines = [x for x in err.splitlines() if x.strip()]
    assert len(lines) == 1, err
    for name in names:
        assert name in lines[0], (name, lines[0])
    return lines[0]


# ----------------------------------------------------------------------------- ALFA


def _alfa_copy(tmp_path: Path, suffix: str, column: str, row: int, value) -> tuple[Path, Path]:
    """The shipped ALFA folder with one cell of one topic replaced (``value`` a string) or its
    column transformed (``value`` a function of the float)."""
    folder = tmp_path / "alfa"
    shutil.copytree(alfa_folder(), folder)
    path = next(folder.glob(f"*-{suffix}.csv"))
    lines = path.read_text().splitlines()
    j = lines[0].split(",").index(column)
    for k in range(1, len(lines)) if callable(value) else [row]:
        cells = lines[k].split(",")
        cells[j] = repr(value(float(cells[j]))) if callable(value) else value
        lines[k] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return folder, path


ALFA_CASES = {
    "throttle_5": ("mavros-vfr_hud", "field.throttle", 12, "5.0", "outside"),
    "pwm_3000": ("mavros-rc-out", "field.channels1", 12, "3000", "outside"),
    "throttle_underscore": ("mavros-vfr_hud", "field.throttle", 12, "0_5", "cannot read"),
    "throttle_arabic_digits": ("mavros-vfr_hud", "field.throttle", 12, ARABIC_HALF,
                               "cannot read"),
}


@pytest.mark.parametrize("suffix,column,row,value,what", ALFA_CASES.values(),
                         ids=ALFA_CASES.keys())
def test_alfa_values_outside_the_channel_or_not_ascii_numbers(tmp_path, capsys, suffix, column,
                                                              row, value, what):
    folder, path = _alfa_copy(tmp_path, suffix, column, row, value)
    with pytest.raises(FlightDataError, match=what) as err:
        read_alfa_flight(folder)
    _one_line(err.value, path.name, f"data row {row}", column)
    _cli_refuses(capsys, tmp_path, folder, path.name, f"data row {row}", column)


def test_alfa_airspeed_in_kmh_is_refused_and_the_real_flight_passes(tmp_path, capsys):
    real = read_alfa_flight(alfa_folder())
    fit = real.meta["speed_check"]
    assert 0.8 < fit["u"]["scale"] < 1.25   # the genuine flight: airspeed in m/s
    folder, _ = _alfa_copy(tmp_path, "mavros-nav_info-airspeed", "field.measured", 0,
                           lambda v: 3.6 * v)
    with pytest.raises(FlightDataError, match="looks scaled") as err:
        read_alfa_flight(folder)
    _one_line(err.value, folder.name, "nav_info-airspeed")
    _cli_refuses(capsys, tmp_path, folder, "looks scaled", "nav_info-airspeed")


# ----------------------------------------------------------------------------- ULog


def _accelerometer(t_us: np.ndarray) -> dict[str, np.ndarray]:
    """sensor_combined of the truth flight (yaw and roll 0): specific force in body axes,
    ``R^T (dV_ned/dt - g e_z)`` (float32 like PX4)."""
    t = seconds(t_us)
    rot = attitude(t, 0.0)
    v_ned = rot.apply(body_velocity_true(t))
    a_ned = np.gradient(v_ned, t, axis=0) - np.array([0.0, 0.0, G])
    force = rot.inv().apply(a_ned)
    return {"timestamp": t_us, "accelerometer_m_s2": force.astype(np.float32),
            "gyro_rad": np.zeros((len(t), 3), np.float32)}


def _long_ulog(path: Path, speed_factor: float = 1.0, seconds_long: float = 30.0) -> Path:
    """A multirotor ULog of the truth flight with an accelerometer, its NED velocities
    multiplied by ``speed_factor``."""
    n = int(seconds_long * 50) + 1
    t_us = stamps(n, 50.0)
    topics = state_topics(t_us)
    for key in ("vx", "vy", "vz"):
        topics["vehicle_local_position"][key] = (topics["vehicle_local_position"][key]
                                                 * np.float32(speed_factor))
    topics["sensor_combined"] = _accelerometer(t_us)
    topics.update(actuator_controls(stamps(int(seconds_long * 10) + 6, 10.0,
                                           first_us=int(t_us[0]) - 45_000)))
    return write_log(path, topics)


@pytest.mark.parametrize("factor", [3.6, 1.94])
def test_ulog_velocity_in_kmh_or_knots_is_refused(tmp_path, capsys, factor):
    good = read_ulog_flight(_long_ulog(tmp_path / "good.ulg"))
    assert abs(good.meta["speed_check"]["u"]["scale"] - 1.0) < 0.05
    path = _long_ulog(tmp_path / "kmh.ulg", factor)
    with pytest.raises(FlightDataError, match="looks scaled") as err:
        read_ulog_flight(path)
    _one_line(err.value, path.name, "vehicle_local_position")
    _cli_refuses(capsys, tmp_path, path, path.name, "looks scaled")
    assert abs(import_ulog(tmp_path / "good.ulg").meta["speed_check"]["u"]["scale"] - 1) < 0.05
    with pytest.raises(FlightDataError, match="looks scaled"):   # the whole-log importer too
        import_ulog(path)


def _messages(raw: bytes) -> list[tuple[int, int, str]]:
    """``(offset, payload size, type)`` of every message after the 16-byte header."""
    out, pos = [], 16
    while pos < len(raw):
        size, kind = struct.unpack_from("<HB", raw, pos)
        out.append((pos, size, chr(kind)))
        pos += 3 + size
    return out


def _topic_ids(raw: bytes) -> dict[int, str]:
    return {struct.unpack_from("<H", raw, p + 4)[0]: raw[p + 6:p + 3 + s].decode()
            for p, s, k in _messages(raw) if k == "A"}


def test_ulog_with_16_flipped_bytes_is_refused_with_the_byte_offset(tmp_path, capsys):
    """16 bytes inverted in one vehicle_attitude message (its timestamp and first quaternion
    component): the sample's stamp is then far from the rest, and was cut as a 'stray
    sample' before; it is corruption, named with its topic and byte offset."""
    raw = bytearray(_long_ulog(tmp_path / "good.ulg", seconds_long=6.0).read_bytes())
    ids = _topic_ids(bytes(raw))
    data = [p for p, s, k in _messages(bytes(raw)) if k == "D"
            and ids[struct.unpack_from("<H", raw, p + 3)[0]] == "vehicle_attitude"]
    at = data[len(data) // 2] + 5          # after the 3-byte header and the 2-byte msg id
    raw[at:at + 16] = bytes(b ^ 0xFF for b in raw[at:at + 16])
    path = tmp_path / "flipped.ulg"
    path.write_bytes(bytes(raw))
    with pytest.raises(FlightDataError, match="corrupt") as err:
        read_ulog_flight(path)
    _one_line(err.value, path.name, "vehicle_attitude", f"byte {at - 5}")
    _cli_refuses(capsys, tmp_path, path, path.name, "vehicle_attitude")


def test_ulog_cut_at_a_message_boundary_reports_the_messages_read(tmp_path, capsys):
    """A cut exactly between two messages cannot be told from a shorter log (ULog has no end
    marker): the messages read per topic are recorded, shown in the summary and kept in the
    manifest; a topic whose data end well before the log's last stamp is warned about."""
    full = _long_ulog(tmp_path / "full.ulg", seconds_long=20.0)
    raw = full.read_bytes()
    cut_at = next(p for p, _, _ in _messages(raw) if p > len(raw) // 2)
    path = tmp_path / "cut.ulg"
    path.write_bytes(raw[:cut_at])
    whole, part = read_ulog_flight(full), read_ulog_flight(path)
    read = part.meta["messages_read"]
    assert set(read) >= {"vehicle_attitude", "vehicle_local_position", "sensor_combined"}
    assert 0 < read["vehicle_attitude"] < whole.meta["messages_read"]["vehicle_attitude"]
    assert part.meta["warnings"] == []
    code = main(["import-log", str(path), "--min-duration", "1", "--min-speed", "0",
                 "--out", str(tmp_path / "out")])
    out, err = capsys.readouterr()
    assert code == 0 and "Traceback" not in out + err
    line = next(x for x in out.splitlines() if "messages read:" in x)
    assert f"vehicle_attitude {read['vehicle_attitude']}" in line
    logs = json.loads((tmp_path / "out" / "manifest.json").read_text())["logs"]
    assert logs[0]["messages_read"] == read
    # a topic that stops early: the velocity ends 5 s before the log does
    n = 20 * 50 + 1
    t_us = stamps(n, 50.0)
    topics = state_topics(t_us)
    lp = topics["vehicle_local_position"]
    topics["vehicle_local_position"] = {k: v[: n - 250] for k, v in lp.items()}
    topics.update(actuator_controls(stamps(206, 10.0, first_us=int(t_us[0]) - 45_000)))
    gap = read_ulog_flight(write_log(tmp_path / "gap.ulg", topics))
    assert any("vehicle_local_position" in w and "before the log's last" in w
               for w in gap.meta["warnings"]), gap.meta["warnings"]


# ----------------------------------------------------------------------------- generic CSV


def _sixdof(tmp_path: Path, edit) -> Path:
    data = flight(np.arange(0, 3, 0.02))
    edit(data)
    path = tmp_path / "f.csv"
    write(path, data, BODY[:-1] + ["throttle"] if "pwm" not in data else BODY[:-2] +
          ["pwm", "throttle"])
    return path


def test_generic_csv_throttle_and_pwm_outside_the_channel(tmp_path, capsys):
    path = _sixdof(tmp_path, lambda d: d["throttle"].__setitem__(7, 5.0))
    with pytest.raises(FlightDataError, match="outside") as err:
        read_sixdof_csv(path, "fixed_wing")
    _one_line(err.value, path.name, "data row 8", "throttle")
    _cli_refuses(capsys, tmp_path, path, path.name, "throttle", extra=("--kind", "fixed_wing"))

    def pwm(d):
        d["pwm"] = 1500 + 0 * d["time"]
        d["pwm"][4] = 3000.0
    path = _sixdof(tmp_path, pwm)
    with pytest.raises(FlightDataError, match="outside") as err:
        read_sixdof_csv(path, "fixed_wing",
                        control_maps=[ChannelMap("elevator", "pwm", 1100, 1900, 0.35, -0.35)])
    _one_line(err.value, path.name, "data row 5", "pwm")


def test_generic_csv_cells_are_parsed_as_ascii_numbers(tmp_path):
    path = _sixdof(tmp_path, lambda d: None)
    lines = path.read_text().splitlines()
    cells = lines[3].split(",")
    cells[-1] = "0_5"
    path.write_text("\n".join([*lines[:3], ",".join(cells), *lines[4:]]) + "\n")
    with pytest.raises(FlightDataError, match="cannot read") as err:
        read_sixdof_csv(path, "fixed_wing")
    _one_line(err.value, path.name, "data row 3", "throttle")


# ----------------------------------------------------------------------------- dataset CSV


def _sortie_csv(path: Path) -> Path:
    t = np.arange(0, 2, 0.01)
    states = np.column_stack([20 + 0 * t, 1 + 0 * t, 0 * t, 0.05 + 0 * t])
    controls = np.column_stack([-0.02 + 0 * t, 0.5 + 0 * t])
    return write_csv(Sortie(name="s", kind="fixed_wing", time=t, states=states,
                            controls=controls), path)


def test_dataset_csv_cut_inside_its_last_number_is_refused(tmp_path):
    path = _sortie_csv(tmp_path / "s.csv")
    read_csv(path)
    raw = path.read_bytes()
    path.write_bytes(raw[:-2])           # "0.5\n" cut to "0.": still a number
    with pytest.raises(FlightDataError, match="looks cut") as err:
        read_csv(path)
    _one_line(err.value, path.name, "data row 200")


def test_dataset_csv_numbers_are_ascii():
    from uavdyn.flightdata.csvio import parse_number
    assert parse_number("0.5") == 0.5 and parse_number("-1e-3") == -1e-3
    for bad in ("0_5", ARABIC_HALF, "1_000", " 1", "0x10", ""):
        with pytest.raises(ValueError):
            parse_number(bad)



# ----------------------------------------------------------------------------- speed check


def _cruise(seed: int, seconds_long: float = 300.0, rate: float = 50.0):
    """A fixed-wing flight's channels and accelerometer with realistic disturbances: Dryden-
    like gusts of 1.5 m/s (10 s correlation) in the air-relative u and w that the
    accelerometer does not see, accelerometer noise 0.5 m/s^2 and bias 0.1 m/s^2, velocity
    noise 0.1 m/s."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds_long, 1 / rate)
    u = 20 + 3 * np.sin(0.05 * t) + 1.5 * np.sin(0.3 * t + seed)
    w = 1 + 0.5 * np.sin(0.4 * t)
    theta = 0.05 + 0.1 * np.sin(0.2 * t + seed)
    q = np.gradient(theta, t)
    force = np.column_stack([np.gradient(u, t) + q * w + G * np.sin(theta), 0 * t,
                             np.gradient(w, t) - q * u - G * np.cos(theta)])
    force += rng.normal(0.0, 0.5, force.shape) + rng.normal(0.0, 0.1, 3)
    a = np.exp(-1 / (10.0 * rate))
    gust = np.zeros((len(t), 2))
    kick = rng.normal(0.0, 1.5 * np.sqrt(1 - a * a), gust.shape)
    for k in range(1, len(t)):
        gust[k] = a * gust[k - 1] + kick[k]
    zero = 0 * t
    channels = {"roll": zero, "pitch": theta, "p": zero, "q": q, "r": zero,
                "u": u + gust[:, 0] + rng.normal(0, 0.1, len(t)), "v": zero,
                "w": w + gust[:, 1] + rng.normal(0, 0.1, len(t))}
    return t, channels, force


@pytest.mark.parametrize("seed", range(6))
def test_speed_check_passes_turbulence_and_noise_and_refuses_kmh(seed):
    """Gusts the accelerometer cannot see and sensor noise scatter the fit without biasing
    it (within 4 standard errors of 1) and never refuse it; the same flight in km/h, all
    velocities or only u, is refused naming u."""
    from uavdyn.flightdata.speed_check import check_speed_scale
    t, channels, force = _cruise(seed)
    fit = check_speed_scale("cruise.csv", t, channels, force, {"u": "u"})["u"]
    assert abs(fit["scale"] - 1.0) < 4 * fit["standard_error"]
    for names in ("uvw", "u"):
        scaled = {**channels, **{k: 3.6 * channels[k] for k in names}}
        with pytest.raises(FlightDataError, match="looks scaled") as err:
            check_speed_scale("cruise.csv", t, scaled, force, {"u": "u"})
        assert "column 'u'" in str(err.value)


def test_dataset_with_both_files_cut_at_the_same_place_is_refused(tmp_path, capsys):
    """A sortie CSV and its true-states CSV cut at the same byte inside their last number
    (an interrupted copy of the dataset): the loader and the CLI refuse it in one line."""
    from tests.fuzz_dataset import write_dataset
    from uavdyn.flightdata import load_dataset
    folder = write_dataset(tmp_path / "ds")
    load_dataset(folder)
    for name in ("s0.csv", "s0_true.csv"):
        raw = (folder / name).read_bytes()
        (folder / name).write_bytes(raw[:-3])
    with pytest.raises(FlightDataError, match="looks cut") as err:
        load_dataset(folder)
    _one_line(err.value, "s0.csv", "data row")
    code = main(["evaluate", "--airframe", "f450", "--dataset", str(folder), "--out",
                 str(tmp_path / "m.json")])
    out, err_text = capsys.readouterr()
    assert code != 0 and "Traceback" not in out + err_text
    assert [x for x in err_text.splitlines() if x.strip()][0].count("looks cut") == 1


@pytest.mark.parametrize("damage", ["unknown_id", "short_message"])
def test_ulog_data_message_framing_damage_is_refused_with_the_byte_offset(tmp_path, damage):
    """One data message of vehicle_attitude given an id no subscription defined, or made 4
    bytes shorter than its format (size field consistent, so the framing still tiles the
    file): refused naming the byte offset (before, pyulog's corruption flag refused both
    without saying where)."""
    raw = bytearray(_long_ulog(tmp_path / "good.ulg", seconds_long=6.0).read_bytes())
    ids = _topic_ids(bytes(raw))
    at, size, _ = next((p, s, k) for p, s, k in _messages(bytes(raw))[200:] if k == "D"
                       and ids[struct.unpack_from("<H", raw, p + 3)[0]] == "vehicle_attitude")
    if damage == "unknown_id":
        struct.pack_into("<H", raw, at + 3, 999)
    else:
        struct.pack_into("<H", raw, at, size - 4)
        del raw[at + 3 + size - 4:at + 3 + size]
    path = tmp_path / f"{damage}.ulg"
    path.write_bytes(bytes(raw))
    with pytest.raises(FlightDataError, match="corrupt ULog file") as err:
        read_ulog_flight(path)
    _one_line(err.value, path.name, f"byte {at}")
