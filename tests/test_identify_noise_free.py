"""Noise-free data from ``uavdyn simulate`` (issue 42): the excitation screen's absolute floors
are advice, not a veto, and a perturbed Aerosonde flown by ``uavdyn simulate`` is recovered
from the nominal preset through the command line alone."""

import json
import re
from pathlib import Path

import numpy as np
import pytest

import uavdyn.airframes
from uavdyn.cli import main
from uavdyn.flightdata import load_dataset
from uavdyn.identify.excitation import screen_excitation

# +15 % C_m_alpha, -10 % C_m_q, +20 % C_L_alpha on the Aerosonde preset
NOMINAL = {"C_m_alpha": -2.74, "C_m_q": -38.21, "C_L_alpha": 5.61}
TRUE = {"C_m_alpha": -2.74 * 1.15, "C_m_q": -38.21 * 0.90, "C_L_alpha": 5.61 * 1.20}
INPUTS = [(profile, channel) for profile in ("doublet", "3211", "chirp") for channel in (0, 1)]


def perturbed_airframe(path: Path) -> Path:
    """The Aerosonde preset's TOML with the three true values written in."""
    text = (Path(uavdyn.airframes.__file__).parent / "aerosonde.toml").read_text()
    text = text.replace('name = "aerosonde"', 'name = "aerosonde_perturbed"')
    for name, value in TRUE.items():
        text, n = re.subn(rf"(\[params\.{name}\]\nvalue = )\S+", rf"\g<1>{value!r}", text)
        assert n == 1, name
    path.write_text(text)
    return path


def simulated_dataset(folder: Path, airframe: Path, duration: float = 20.0,
                      inputs: list[tuple[str, int]] = INPUTS) -> Path:
    """``uavdyn simulate`` each input (100 Hz) into ``folder``, with a manifest (all train)."""
    folder.mkdir()
    sorties = []
    for profile, channel in inputs:
        name = f"{profile}_ch{channel}.csv"
        assert main(["simulate", "--airframe", str(airframe), "--input", profile, "--channel",
                     str(channel), "--duration", str(duration), "--dt", "0.01",
                     "--out", str(folder / name)]) == 0
        sorties.append({"file": name, "mission": f"{profile} on channel {channel}",
                        "duration_s": duration, "split": "train"})
    (folder / "manifest.json").write_text(json.dumps(
        {"airframe": "aerosonde_perturbed", "kind": "fixed_wing", "sample_rate_hz": 100.0,
         "source": "uavdyn simulate", "sorties": sorties}, indent=1))
    return folder


def test_the_default_doublet_is_screened_as_advice_not_refused(tmp_path, capsys):
    data = simulated_dataset(tmp_path / "data", perturbed_airframe(tmp_path / "p.toml"),
                             duration=10.0, inputs=[("doublet", 0)])
    train = load_dataset(data).train
    refused, advice = screen_excitation(["C_m_alpha", "C_L_alpha", "C_m_q"], train)
    assert refused == []
    assert advice and advice[0].startswith("C_m_alpha: the angle of attack")


def test_a_signal_at_its_noise_is_still_refused(tmp_path):
    data = simulated_dataset(tmp_path / "data", perturbed_airframe(tmp_path / "p.toml"),
                             duration=4.0, inputs=[("none", 0)])
    train = load_dataset(data).train
    train[0].states[:, 2] += np.random.default_rng(1).normal(0.0, 1e-3, len(train[0].time))
    refused, advice = screen_excitation(["C_m_q"], train)  # q is its own noise: refused
    assert refused and refused[0].startswith("C_m_q: the pitch rate q varies by") and not advice


@pytest.mark.slow
def test_noise_free_recovery_through_the_cli(tmp_path, capsys):
    data = simulated_dataset(tmp_path / "data", perturbed_airframe(tmp_path / "p.toml"))
    out = tmp_path / "fitted.toml"
    code = main(["identify", "--airframe", "aerosonde", "--dataset", str(data), "--params",
                 ",".join(TRUE), "--out", str(out), "--quiet"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "NOT DETERMINED" not in captured.out, captured.out
    report = json.loads((tmp_path / "fitted_report" / "identify.json").read_text())
    for e in report["estimates"]:
        error = e["value"] / TRUE[e["name"]] - 1.0
        print(f"{e['name']}: {e['value']:.6g} (true {TRUE[e['name']]:.6g}, nominal "
              f"{NOMINAL[e['name']]:g}), error {100 * error:+.2e} %")
        assert abs(error) < 0.01, e
        assert "kept_file_value" not in e, e


def test_halves_within_a_thousandth_of_the_value_agree():
    """On noise-free data the halves' errors shrink to 1e-7: C_m_q's halves of the recovery
    below differed by 3.5e-6 of the value, 20 combined errors, and flagged it."""
    from uavdyn.identify.consistency import compare_halves
    from uavdyn.identify.result import Estimate, IdentificationResult

    def result_with(estimates):
        return IdentificationResult(airframe=None, estimates=list(estimates),
                                    correlation=np.eye(len(estimates)), flagged_pairs=[],
                                    state_sigma=np.ones(4), cost_initial=1.0, cost_final=1.0,
                                    iterations=1, seconds=0.0, window_s=1.0, dt=0.005)

    halves = iter([[Estimate("C_m_q", 0, -34.38887, 1e-6, std_error_corrected=5.1e-6)],
                   [Estimate("C_m_q", 0, -34.38899, 1e-6, std_error_corrected=2.1e-6)]])
    result = result_with([Estimate("C_m_q", -38.21, -34.38890, 1e-7,
                                   std_error_corrected=6e-7)])
    compare_halves(lambda *a, **k: result_with(next(halves)), result, list(range(6)),
                   ["C_m_q"], 10, {})
    assert result.estimates[0].determined, result.estimates[0].flags()


def test_allow_low_excitation_fits_what_the_screen_refuses(tmp_path, capsys):
    """q at its own noise: refused, the message naming the option; with it, fitted and
    left undetermined by its standard errors (the file's value kept)."""
    from uavdyn.flightdata import read_csv, write_csv

    data = simulated_dataset(tmp_path / "data", perturbed_airframe(tmp_path / "p.toml"),
                             duration=6.0, inputs=[("none", 0)])
    sortie = read_csv(data / "none_ch0.csv")
    noise = np.random.default_rng(0).normal(size=sortie.states.shape)
    sortie.states = sortie.states + noise * np.array([0.05, 0.05, 1e-3, 1e-3])
    write_csv(sortie, data / "none_ch0.csv")
    argv = ["identify", "--airframe", "aerosonde", "--dataset", str(data), "--params", "C_m_q",
            "--out", str(tmp_path / "fit.toml"), "--quiet"]
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "do not excite C_m_q" in err and "--allow-low-excitation" in err
    assert main([*argv, "--allow-low-excitation"]) == 0
    assert "KEPT: not determined" in capsys.readouterr().out
