"""Longitudinal segments of six-degree-of-freedom logs, and real logs end to end.

The segmenter is checked on a synthetic flight whose turn entry and exit are known exactly
(level flight, a coordinated 30 deg banked turn, a wings-level elevator doublet); the real-log
path on the trimmed copies shipped in ``tests/data/reallogs`` (no ``../shared`` needed):
ALFA import -> identify -> evaluate, a PX4 SITL hover at its own 20 Hz, the hover's refusal of
a pitch derivative it does not excite, and a ground run with no usable segment.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from tests.reallogs import alfa_folder, ulog
from uavdyn.cli.app import main
from uavdyn.flightdata import FlightDataError, load_dataset
from uavdyn.flightdata.control_map import ChannelMap, override, parse_channel_map
from uavdyn.flightdata.flightlog import FlightLog
from uavdyn.flightdata.segments import SegmentRules, find_segments, segment_sorties
from uavdyn.integrate import fitting_steps, substeps_for

G = 9.80665
RATE = 50.0
V = 20.0


def _synthetic_flight() -> tuple[FlightLog, float, float]:
    """Level 10 s, a 30 deg coordinated turn (roll ramps 0 -> 30 deg over 2 s, holds, ramps
    back), then a wings-level elevator doublet; pitch = integral of q exactly. Returns the
    flight and the times the roll passes 10 deg going in and coming out."""
    t = np.arange(0, 36.0 + 1e-9, 1 / RATE)
    phi = np.interp(t, [0, 10, 12, 18, 20, 36], np.radians([0, 0, 30, 30, 0, 0]))
    psi_dot = G * np.tan(phi) / V
    q_turn, r = psi_dot * np.sin(phi), psi_dot * np.cos(phi)
    doublet = np.where((t > 25) & (t < 26), 1.0, 0.0) - np.where((t >= 26) & (t < 27), 1.0, 0.0)
    q_doublet = 0.1 * doublet
    theta = 0.05 + np.concatenate([[0], np.cumsum(0.5 * (q_doublet[1:] + q_doublet[:-1]))
                                   / RATE])
    channels = {"roll": phi, "pitch": theta, "p": np.gradient(phi, t), "q": q_turn + q_doublet,
                "r": r, "u": np.full_like(t, V), "v": np.zeros_like(t),
                "w": np.full_like(t, 1.0)}
    controls = np.column_stack([-0.05 * doublet, np.full_like(t, 0.5)])
    flight = FlightLog("synthetic", "fixed_wing", t, channels, controls, "air", "test",
                       meta={"file": "synthetic"})
    enter = 10 + 2 * (10 / 30)  # roll passes 10 deg
    leave = 18 + 2 * (20 / 30)
    return flight, enter, leave


def test_the_turn_is_cut_within_one_sample_of_its_threshold_crossings():
    flight, enter, leave = _synthetic_flight()
    report = find_segments(flight)
    assert len(report.kept) == 2
    first, second = report.kept
    dt = 1 / RATE
    # the last kept sample before the turn and the first after it sit at the crossings
    assert first.start_s == 0.0 and abs(first.end_s - enter) <= dt + 1e-9
    assert first.end_s <= enter
    assert abs(second.start_s - leave) <= dt + 1e-9 and second.start_s >= leave
    assert second.end_s == pytest.approx(36.0)
    assert "banked above 10 deg" in first.cut_after
    assert "banked above 10 deg" in second.cut_before
    assert report.excluded["banked above 10 deg"] == pytest.approx(
        (leave - enter) / 36.0, abs=2 * dt / 36.0)
    sorties = segment_sorties(report)
    assert [s.time[0] for s in sorties] == [0.0, 0.0]
    # each segment's states are the flight's own samples, time restarted
    np.testing.assert_array_equal(sorties[1].states[:, 2],
                                  flight.channels["q"][second.start:second.stop])


def test_thresholds_are_options_and_a_flight_without_a_segment_is_refused_in_one_line():
    flight, enter, leave = _synthetic_flight()
    wide = SegmentRules(max_roll_deg=40, max_yaw_rate_deg_s=40, kinematic=False)
    kept = find_segments(flight, wide)
    assert len(kept.kept) == 1 and kept.kept[0].duration == pytest.approx(36.0)
    # with the kinematic check, the banked stretch is dropped: theta_dot is not q in a turn
    with pytest.raises(FlightDataError, match="kinematic inconsistency"):
        find_segments(flight, SegmentRules(max_roll_deg=40, max_yaw_rate_deg_s=40))
    with pytest.raises(FlightDataError) as info:
        find_segments(flight, SegmentRules(min_duration_s=20.0))
    message = str(info.value)
    assert "\n" not in message
    assert "no longitudinal segment of at least 20 s" in message
    assert "banked above 10 deg" in message and "longest stretch" in message


def test_a_sensor_gap_splits_a_segment_and_is_never_bridged():
    flight, _, _ = _synthetic_flight()
    flight.channels["q"][400:410] = np.nan  # 0.2 s gap at t = 8 s
    report = find_segments(flight)
    assert report.kept[0].end_s == pytest.approx(399 / RATE)
    assert "sensor gap" in report.kept[0].cut_after
    assert not any(np.isnan(s.states).any() for s in segment_sorties(report))


def test_a_control_map_is_linear_overridable_and_refuses_bad_text():
    m = parse_channel_map("elevator=RCOU.C2:1100:1900:0.35:-0.35")
    assert m.source == "RCOU.C2" and m.apply(np.array([1100, 1500, 1900])).tolist() == \
        pytest.approx([0.35, 0.0, -0.35])
    base = {"elevator": ChannelMap("elevator", "x", 0, 1, 0, 1),
            "throttle": ChannelMap("throttle", "y", 0, 1, 0, 1)}
    assert override(base, [m])["elevator"] is m
    for bad in ("elevator", "elevator=RCOU.C2:1:2:3", "elevator=RCOU.C2:a:2:3:4",
                "elevator=RCOU.C2:5:5:0:1"):
        with pytest.raises(FlightDataError):
            parse_channel_map(bad)
    with pytest.raises(FlightDataError, match="collective"):
        override(base, [ChannelMap("collective", "z", 0, 1, 0, 1)])


def test_solver_steps_are_whole_fractions_of_any_log_interval():
    for rate in (10.0, 20.0, 94.0, 100.0, 250.0):
        sample = 1 / rate
        for dt in fitting_steps(sample, (0.005, 0.01, 0.02)):
            n = sample / dt if dt <= sample else dt / sample
            assert abs(n - round(n)) < 1e-9
        n = substeps_for(sample, 0.005, 2)
        assert n >= 2 and sample / n <= 0.005 + 1e-12
    assert fitting_steps(0.01, (0.005, 0.01, 0.02)) == (0.005, 0.01, 0.02)  # unchanged at 100 Hz


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.slow
def test_alfa_flight_imports_splits_identifies_and_evaluates_with_no_hand_edit(tmp_path,
                                                                             capsys,
                                                                             monkeypatch):
    from pathlib import Path

    # the CasADi VM, not compiled C: the journey is what is tested here (compiling this
    # airframe's libraries cost the suite ~30 s); .ci/run takes the same log through the
    # compiled defaults from the wheel
    monkeypatch.setenv("UAVDYN_CC", "")

    airframe = str(Path(__file__).resolve().parents[1] / "examples" / "alfa_t28.toml")
    data = tmp_path / "alfa"
    code, out, err = _run(capsys, "import-log", str(alfa_folder()), "--out", str(data))
    assert code == 0, err
    manifest = json.loads((data / "manifest.json").read_text())
    splits = [e["split"] for e in manifest["sorties"]]
    assert len(splits) >= 3 and set(splits) == {"train", "validation", "test"}
    for entry in manifest["sorties"]:
        assert entry["duration_s"] >= 5.0 and entry["velocity_reference"] == "airspeed"
        assert entry["cut"]["before"] and entry["source_end_s"] > entry["source_start_s"]
    assert (data / "import_timeline.png").stat().st_size > 10_000
    assert "kept" in out and "split: train" in out
    ds = load_dataset(data)
    assert ds.sample_rate_hz == 10.0
    fitted = tmp_path / "alfa_id.toml"
    code, out, err = _run(capsys, "identify", "--airframe", airframe, "--dataset", str(data),
                          "--params", "C_m_0,C_L_0,C_D_0", "--out", str(fitted), "--quiet")
    assert code == 0, err
    result = tmp_path / "eval.json"
    code, out, err = _run(capsys, "evaluate", "--airframe", airframe, "--identified",
                          str(fitted), "--dataset", str(data), "--out", str(result))
    assert code == 0, err
    ladder = json.loads(result.read_text())["ladder"]
    assert ladder["models"][:2] == ["nominal physics", "identified physics"]
    assert ladder["dt"] == pytest.approx(0.01)  # the 0.1 s log interval in 10 sub-steps
    one_second = next(h for h in ladder["headline"] if h["mode"] == "horizon_1s")
    assert one_second["sorties"] == splits.count("test")
    for model in ("nominal physics", "identified physics"):
        assert math.isfinite(one_second["models"][model]["rmse"])


def test_a_px4_hover_at_its_own_rate_imports_and_does_not_determine_its_pitch_derivative(
        tmp_path, capsys, monkeypatch):
    from pathlib import Path

    monkeypatch.setenv("UAVDYN_CC", "")  # the CasADi VM: see the ALFA test

    # by default the grid follows the 50 Hz gyro (the attitude is logged at 20.8 Hz)
    code, out, err = _run(capsys, "import-log", str(ulog("px4_sitl_hover.ulg")),
                          "--out", str(tmp_path / "hover50"))
    assert code == 0, err
    manifest = json.loads((tmp_path / "hover50" / "manifest.json").read_text())
    assert manifest["sample_rate_hz"] == pytest.approx(50.0)
    assert manifest["logs"][0]["grid"].startswith("50 Hz from vehicle_angular_velocity")
    assert "1 sortie: train only" in out    # one segment: a stated split, not a refusal
    data = tmp_path / "hover"
    code, out, err = _run(capsys, "import-log", str(ulog("px4_sitl_hover.ulg")),
                          "--rate", "20", "--out", str(data))
    assert code == 0, err
    manifest = json.loads((data / "manifest.json").read_text())
    assert manifest["sample_rate_hz"] == pytest.approx(20.0)  # the attitude topic's rate
    assert len(manifest["sorties"]) == 1 and "in-air flag" in manifest["sorties"][0]["cut"][
        "before"]
    airframe = str(Path(__file__).resolve().parents[1] / "examples" / "x500.toml")
    # evaluate runs at the log's own 20 Hz (the paper's 0.02 s step does not divide 0.05 s:
    # the nearest whole fraction, 0.05 / 3 s, is used) without resampling the data
    code, out, err = _run(capsys, "evaluate", "--airframe", airframe, "--dataset", str(data),
                          "--all-sorties", "--out", str(tmp_path / "e.json"))
    assert code == 0, err
    result = json.loads((tmp_path / "e.json").read_text())
    steps = sorted({row["dt"] for row in result["ladder"]["per_sortie"]})
    assert steps == [pytest.approx(0.05 / 5)]
    solvers = json.dumps(result["table1"])
    assert "0.0166667 s" in solvers and "0.02 s" not in solvers
    # q moves 3x its noise but less than the advisory floor: a warning, and the corrected
    # standard errors decide (issue 42): not determined, the file's value kept
    code, out, err = _run(capsys, "identify", "--airframe", airframe, "--dataset", str(data),
                          "--params", "pitch_damping", "--out", str(tmp_path / "x.toml"),
                          "--quiet")
    assert code == 0, err
    assert "warning: pitch_damping: the pitch rate q varies by" in err
    assert "0 of 1 parameters determined" in out and "KEPT: not determined" in out
    assert "Traceback" not in err


def test_a_ground_run_has_no_segment_and_says_why(tmp_path, capsys):
    code, out, err = _run(capsys, "import-log", str(ulog("px4_vtol_ground_run.ulg")),
                          "--out", str(tmp_path / "ground"))
    assert code == 2
    assert "no longitudinal segment" in err and "on the ground" in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "ground").exists()


def test_a_lower_rate_is_low_pass_filtered_so_nothing_folds_back():
    """A 4 Hz tone in a 50 Hz log resampled to 5 Hz (Nyquist 2.5 Hz) would alias to a 1 Hz
    tone of full amplitude; the anti-alias filter removes it, and a 0.3 Hz motion is kept."""
    from uavdyn.flightdata.flightlog import resample_flight

    flight, _, _ = _synthetic_flight()
    t = flight.time
    flight.channels["u"] = V + 1.0 * np.sin(2 * np.pi * 4.0 * t)
    flight.channels["w"] = 1.0 + 0.5 * np.sin(2 * np.pi * 0.3 * t)
    low = resample_flight(flight, 5.0)
    assert low.dt == pytest.approx(0.2) and "Butterworth" in low.meta["resampling"]
    inner = slice(10, -10)  # away from the filter's edge transients
    assert np.max(np.abs(low.channels["u"][inner] - V)) < 0.05       # the 4 Hz tone is gone
    np.testing.assert_allclose(low.channels["w"][inner],
                               (1.0 + 0.5 * np.sin(2 * np.pi * 0.3 * low.time))[inner],
                               atol=0.01)                             # 0.3 Hz kept
    naive = np.interp(low.time, t, flight.channels["u"])
    assert np.max(np.abs(naive - V)) > 0.5  # what resampling without the filter would give
    assert resample_flight(flight, RATE) is flight
