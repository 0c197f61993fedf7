"""design-input: the flight-test input timed from the airframe's own modes, inside its limits,
and the standard errors it predicts (checked against independent truths)."""

from __future__ import annotations

import dataclasses
import itertools
import json
from pathlib import Path

import numpy as np
import pytest

from uavdyn.airframes import load_airframe
from uavdyn.cli.app import main
from uavdyn.excitation import (
    DesignError,
    design_input,
    emulate_design,
    predict_errors,
    relative_peak_factor,
    schroeder_multisine,
)
from uavdyn.excitation.signals import energy_spectrum
from uavdyn.identify import identify
from uavdyn.linear import linearise, trim

ROOT = Path(__file__).resolve().parents[1]
TRAINER = ROOT / "examples" / "trainer.toml"
X500 = ROOT / "examples" / "x500.toml"
MOMENTS = ["C_m_alpha", "C_m_q", "C_m_delta_e"]


@pytest.fixture(scope="module")
def trainer():
    return load_airframe(TRAINER)


def short_period_rad_s(airframe) -> float:
    """Independently: the fastest oscillatory pole of the linearised airframe (with its
    actuator states), |lambda|."""
    A, _ = linearise(airframe, trim(airframe, airframe.nominal_airspeed))
    eig = np.linalg.eigvals(A)
    return float(np.max(np.abs(eig[np.abs(eig.imag) > 1e-6])))


def test_3211_and_doublet_timing_follow_the_short_period(trainer):
    w = short_period_rad_s(trainer)
    d = design_input(trainer, "mixed")
    assert d.mode.natural_frequency == pytest.approx(w, rel=1e-9)
    dt = 1.0 / d.sample_rate_hz
    unit = round(1.6 / w / dt) * dt
    width = round(2.3 / w / dt) * dt
    e3211 = [e for e in d.events if e["signal"] == "3211"]
    edbl = [e for e in d.events if e["signal"] == "doublet"]
    assert e3211 and edbl
    assert all(e["length_s"] == pytest.approx(7 * unit) for e in e3211)
    assert all(e["length_s"] == pytest.approx(2 * width) for e in edbl)
    # the first 3-2-1-1 on the schedule: steps of 3, 2, 1, 1 units of alternating sign
    u = d.increments[:, 0]
    start = int(round(e3211[0]["t_s"] / dt))
    steps = np.round(u[start:start + int(round(7 * unit / dt))] / d.amplitude).astype(int)
    runs = [len(list(g)) for _, g in itertools.groupby(steps)]
    assert np.allclose(np.array(runs) * dt, np.array([3, 2, 1, 1]) * unit)
    # the doublet puts its energy peak on the short period
    k = int(round(edbl[0]["t_s"] / dt))
    pulse = u[k:k + int(round(2 * width / dt))]
    omega = np.linspace(0.5, 60, 6000)
    peak = omega[np.argmax(energy_spectrum(pulse, dt, omega))]
    assert peak == pytest.approx(w, rel=0.08)


@pytest.mark.parametrize("path", [TRAINER, X500])
@pytest.mark.parametrize("signal", ["mixed", "multisine"])
def test_commands_stay_inside_the_limits(path, signal):
    af = load_airframe(path)
    d = design_input(af, signal)
    lo, hi = np.array(af.control_bounds()).T
    cmd = np.array(d.trim_controls) + d.increments
    assert np.all(cmd >= lo - 1e-12) and np.all(cmd <= hi + 1e-12)
    ch = d.channel
    room = min(hi[ch] - d.trim_controls[ch], d.trim_controls[ch] - lo[ch])
    assert np.max(np.abs(d.increments[:, ch])) <= 0.8 * room + 1e-12


def test_a_tight_limit_cuts_the_amplitude_and_an_oversized_one_is_refused(trainer):
    tight = dataclasses.replace(trainer, limits={**trainer.limits, "elevator": (-0.02, 0.04)})
    d = design_input(tight, "3211")
    trim_e = d.trim_controls[0]
    assert d.amplitude == pytest.approx(0.8 * min(0.04 - trim_e, trim_e + 0.02))
    assert "limits" in d.amplitude_why
    with pytest.raises(DesignError, match="--amplitude"):
        design_input(trainer, "3211", amplitude=0.5)


def test_schroeder_multisine_spans_the_band_with_a_low_peak_factor():
    rate, period, band = 100.0, 10.0, (0.5, 4.0)
    t = np.arange(int(period * rate)) / rate
    u = schroeder_multisine(t, 1.0, band, period)
    assert np.max(np.abs(u)) == pytest.approx(1.0, rel=1e-3)
    spectrum = np.abs(np.fft.rfft(u))
    f = np.fft.rfftfreq(len(u), 1 / rate)
    on = f[spectrum > 0.01 * spectrum.max()]
    assert on.min() == pytest.approx(band[0]) and on.max() == pytest.approx(band[1])
    harmonics = np.arange(5, 41) / period
    assert np.allclose(np.sort(on), harmonics)
    zero_phase = schroeder_multisine(t, 1.0, band, period, phases=np.zeros(len(harmonics)))
    assert relative_peak_factor(u) < 1.6
    assert relative_peak_factor(zero_phase) > 2.5 * relative_peak_factor(u) / 1.6


def test_predicted_error_falls_like_one_over_root_sorties(trainer):
    d = design_input(trainer, "mixed", duration_s=12.0)
    flights = emulate_design(d, trainer, 8, seed=3, turbulent_fraction=0.0)
    few = predict_errors(trainer, flights[:2], MOMENTS, max_windows=None)
    many = predict_errors(trainer, flights, MOMENTS, max_windows=None)
    assert np.allclose(few.std_error / many.std_error, 2.0, rtol=0.15)
    # and like the noise
    noisy = predict_errors(trainer, flights[:2], MOMENTS, noise_scale=2.0, max_windows=None)
    assert np.allclose(noisy.std_error / few.std_error, 2.0, rtol=1e-6)


def test_cramer_rao_prediction_is_below_the_achieved_corrected_error(trainer):
    d = design_input(trainer, "mixed", duration_s=12.0)
    flights = emulate_design(d, trainer, 4, seed=5, turbulent_fraction=1.0)
    predicted = predict_errors(trainer, flights, MOMENTS)
    result = identify(trainer, flights, [], MOMENTS, progress=False, check_halves=False,
                      screen=False)
    achieved = np.array([e.std_error_corrected for e in result.estimates])
    assert np.all(predicted.std_error < achieved)
    values = np.array([e.value for e in result.estimates])
    assert np.all(np.abs(values) > 3 * achieved)  # the design determines the moments


def test_cli_writes_the_schedule_and_ardupilot_parameters_for_a_multirotor(tmp_path, capsys):
    out = tmp_path / "x500_design"
    assert main(["design-input", "--airframe", str(X500), "--out", str(out), "--sorties", "2",
                 "--duration", "12", "--signal", "doublet"]) == 0
    lines = (out / "schedule.csv").read_text().splitlines()
    header = [ln for ln in lines if not ln.startswith("#")][0]
    assert header == "time_s,collective_delta,pitch_cmd_delta,autopilot"
    params = dict(ln.split(",") for ln in (out / "ardupilot_sysid.param").read_text()
                  .splitlines() if not ln.startswith("#"))
    design = json.loads((out / "design.json").read_text())
    assert params["SID_AXIS"] == "11"
    assert float(params["SID_F_START_HZ"]) == pytest.approx(design["band_hz"][0], rel=1e-3)
    assert float(params["SID_F_STOP_HZ"]) == pytest.approx(design["band_hz"][1], rel=1e-3)
    assert float(params["SID_MAGNITUDE"]) == pytest.approx(design["amplitude"], rel=1e-3)
    assert "chirp" in design["ardupilot"]
    assert "Cramer-Rao" in capsys.readouterr().out


def test_cli_fixed_wing_has_no_sysid_file_and_bad_input_is_one_line(tmp_path, capsys):
    out = tmp_path / "trainer_design"
    assert main(["design-input", "--airframe", str(TRAINER), "--out", str(out),
                 "--sorties", "2", "--duration", "10"]) == 0
    assert not (out / "ardupilot_sysid.param").exists()
    assert "no" in (out / "design.md").read_text().split("ArduPilot:")[1][:200].lower()
    capsys.readouterr()
    assert main(["design-input", "--airframe", str(TRAINER), "--out", str(out),
                 "--amplitude", "0.9"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--amplitude" in err[0] and "Traceback" not in err[0]
    assert main(["design-input", "--airframe", str(TRAINER), "--out", str(out),
                 "--duration", "3"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--duration" in err[0]
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "keep.txt").write_text("mine")
    assert main(["design-input", "--airframe", str(TRAINER), "--out", str(foreign)]) == 2
    assert (foreign / "keep.txt").read_text() == "mine"


def test_fixed_wing_amplitude_gives_the_stated_peak_alpha(trainer):
    """Independently of the design's own simulation: scipy's lsim of the linearised airframe
    on the first inputs of the schedule peaks at the target angle of attack."""
    from scipy.signal import lsim

    d = design_input(trainer, "mixed", alpha_deg=2.0)
    point = trim(trainer, trainer.nominal_airspeed)
    A, B = linearise(trainer, point)
    second = d.events[1]
    on = d.time < second["t_s"] + second["length_s"] + 1.0
    C = np.zeros((1, A.shape[0]))
    V2 = point.x[0] ** 2 + point.x[1] ** 2
    C[0, 0], C[0, 1] = -point.x[1] / V2, point.x[0] / V2
    _, alpha, _ = lsim((A, B[:, [0]], C, np.zeros((1, 1))), d.increments[on, :1],
                       d.time[on], interp=False)
    assert np.degrees(np.max(np.abs(alpha))) == pytest.approx(2.0, rel=0.02)


def test_the_identify_screen_is_checked_on_the_calm_sorties(trainer):
    from uavdyn.excitation.predict import calm_screen

    good = design_input(trainer, "mixed", duration_s=12.0)
    weak = design_input(trainer, "mixed", duration_s=12.0, amplitude=0.004)
    assert calm_screen(emulate_design(good, trainer, 2, turbulent_fraction=0.0), MOMENTS) == []
    refused = calm_screen(emulate_design(weak, trainer, 2, turbulent_fraction=0.0), MOMENTS)
    assert refused and refused[0].startswith("C_m_alpha: the angle of attack")


def test_a_given_mode_frequency_times_the_inputs(trainer):
    d = design_input(trainer, "3211", mode_hz=1.0)
    assert d.unit_s == pytest.approx(round(1.6 / (2 * np.pi) / 0.01) * 0.01)
    json.dumps(d.summary(), allow_nan=False)  # strict JSON: no NaN for the unknown damping
