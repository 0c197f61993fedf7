"""Identification: parameters scaled by known factors are recovered from noise-free data from
the nominal preset to 0.5 % (exactly, up to the solver tolerance); with the emulator's sensor
noise the estimates fall within 2 standard errors; requests the data cannot answer are refused
with the parameter named; the CLI writes a loadable airframe file with provenance."""

import numpy as np
import pytest

from uavdyn.airframes import load_airframe
from uavdyn.cli import main
from uavdyn.emulation.emulator import SensorNoise
from uavdyn.flightdata import Sortie
from uavdyn.identify import IdentifyError, identify
from uavdyn.integrate import free_run, rk4_step
from uavdyn.integrate.inputs import chirp, multistep_3211
from uavdyn.linear import trim
from uavdyn.model import build_model

SCALED = {"C_m_alpha": 1.15, "C_m_q": 0.90, "C_L_alpha": 1.20, "rho": 0.90}


def _sorties(truth, n, seed, duration=12.0, excite=True, noise=0.0):
    """Sysid flights of ``truth`` (3-2-1-1 then chirp on the elevator, throttle wiggle)."""
    rng = np.random.default_rng(seed)
    step = rk4_step(build_model(truth).f)
    sigma = np.array([SensorNoise.u, SensorNoise.w, SensorNoise.q, SensorNoise.theta]) * noise
    out = []
    for i in range(n):
        point = trim(truth, 21.0 + 2.0 * i)
        t = np.arange(int(round(duration / 0.01)) + 1) * 0.01
        u = np.tile(point.u, (len(t), 1))
        if excite:
            u[:, 0] += multistep_3211(t, np.radians(2.0), start=1.0 + 0.2 * i)
            u[:, 0] += chirp(t, np.radians(1.0), start=5.0, duration=duration - 5.0)
            u[:, 1] += 0.05 * np.sin(0.6 * t + i)
        x = free_run(step, point.x, u[:-1], truth.p, 0.005, 2)
        x = x + rng.normal(size=x.shape) * sigma
        out.append(Sortie(f"s{seed}_{i}", "fixed_wing", t, x, u, "sysid"))
    return out


@pytest.fixture(scope="module")
def truth(aerosonde):
    return aerosonde.replace(**{k: getattr(aerosonde.params, k) * f for k, f in SCALED.items()})


@pytest.mark.slow
def test_recovers_scaled_parameters_from_noise_free_data(aerosonde, truth):
    result = identify(aerosonde, _sorties(truth, 4, 0), _sorties(truth, 1, 1), list(SCALED),
                      progress=False)
    for e in result.estimates:
        true = getattr(truth.params, e.name)
        assert abs(e.value - true) <= 5e-3 * abs(true), (e.name, e.value, true)
        assert abs(e.value - e.nominal) > 0.05 * abs(true)  # it really moved from nominal
    assert result.fit["validation"]["theta_rmse"]["identified"] < 1e-6
    assert result.fit["validation"]["theta_rmse"]["nominal"] > 1e-3
    # lift is rho * C_L_alpha: the two are strongly (negatively) correlated, and flagged
    assert any({a, b} == {"rho", "C_L_alpha"} and c < -0.9 for a, b, c in
               result.flagged_pairs)


@pytest.mark.slow
def test_with_sensor_noise_estimates_fall_within_two_standard_errors(aerosonde, truth):
    names = [*SCALED, "C_m_delta_e"]  # C_m_delta_e is not scaled: it must stay at nominal
    result = identify(aerosonde, _sorties(truth, 4, 2, noise=1.0), [], names,
                      progress=False)
    for e in result.estimates:
        true = getattr(truth.params, e.name)
        print(f"{e.name}: {e.value:.5g} +- {e.std_error:.2g}, truth {true:.5g}")
        assert e.std_error > 0
        assert abs(e.value - true) <= 2 * e.std_error + 1e-9 * abs(true), \
            (e.name, e.value, true, e.std_error)


def test_refuses_unknown_and_unexcited_parameters(aerosonde):
    data = _sorties(aerosonde, 2, 3, duration=4.0)
    with pytest.raises(IdentifyError, match=r"\['C_m_magic'\] are not in the fixed_wing model"):
        identify(aerosonde, data, [], ["C_m_alpha", "C_m_magic"], progress=False)
    steady = _sorties(aerosonde, 2, 4, duration=4.0, excite=False)  # trim: q stays 0
    with pytest.raises(IdentifyError, match=r"do not excite C_m_q: the pitch rate q varies by"):
        identify(aerosonde, steady, [], ["C_m_q"], progress=False)  # screened before the fit
    with pytest.raises(IdentifyError, match=r"do not excite parameter\(s\) \['C_m_q'\]"):
        identify(aerosonde, steady, [], ["C_m_q"], progress=False, screen=False)  # Jacobian


@pytest.mark.slow
def test_cli_writes_a_loadable_airframe_with_provenance(tmp_path, aerosonde, truth, capsys):
    from uavdyn.flightdata import write_csv, write_manifest

    data = tmp_path / "data"
    data.mkdir()
    sorties = _sorties(truth, 3, 5, duration=6.0)
    entries = []
    for s, split in zip(sorties, ("train", "train", "validation")):
        write_csv(s, data / f"{s.name}.csv")
        entries.append({"file": f"{s.name}.csv", "mission": "sysid", "duration_s": 6.0,
                        "split": split})
    write_manifest(data, airframe="aerosonde", kind="fixed_wing", sample_rate_hz=100.0,
                   source="test", sorties=entries)
    out = tmp_path / "fitted.toml"
    assert main(["identify", "--airframe", "aerosonde", "--dataset", str(data), "--params",
                 "C_m_alpha,C_m_q", "--out", str(out), "--quiet"]) == 0
    fitted = load_airframe(out)
    assert fitted.name == "aerosonde_identified"
    assert abs(fitted.params.C_m_alpha - truth.params.C_m_alpha) < 0.05 * abs(
        truth.params.C_m_alpha)
    text = out.read_text()
    assert "# Identified by uavdyn from 'aerosonde'" in text and "C_m_alpha =" in text
    assert (tmp_path / "fitted_report" / "identify.png").read_bytes()[:4] == b"\x89PNG"
    assert "identified 2 parameter(s)" in capsys.readouterr().out
    assert main(["identify", "--airframe", "aerosonde", "--dataset", str(data), "--params",
                 "nope", "--out", str(out), "--quiet"]) == 2


@pytest.mark.slow
def test_recovers_an_alpha_dot_derivative_from_a_zero_nominal(aerosonde):
    """An unset optional key (nominal 0) is fitted inside the schema's physical bounds, with
    the alpha-dot terms switched into the model because the key is being fitted."""
    truth = aerosonde.replace(C_m_alpha_dot=-8.0)
    result = identify(aerosonde, _sorties(truth, 3, 6), [], ["C_m_alpha_dot", "C_m_q"],
                      progress=False)
    fitted = {e.name: e.value for e in result.estimates}
    assert abs(fitted["C_m_alpha_dot"] + 8.0) < 1e-4
    assert abs(fitted["C_m_q"] - aerosonde.params.C_m_q) < 1e-4 * abs(aerosonde.params.C_m_q)


def test_bound_flag_marks_estimates_on_a_bound_not_small_interior_ones():
    """An estimate IPOPT left a hair inside its bound is flagged; a small estimate of a
    zero-nominal parameter with a wide physical range (0..1e3 in units of 1) is not."""
    from uavdyn.identify.output_error import _at_bound

    assert _at_bound(6e-4, 0.0, 1e3) == ""
    assert _at_bound(1e-9, 0.0, 1e3) == "lower"
    assert _at_bound(-0.9 + 1e-8, -0.9, 0.9) == "lower"
    assert _at_bound(0.9 - 1e-7, -0.9, 0.9) == "upper"
    assert _at_bound(0.3, -0.9, 0.9) == ""


def test_a_fit_ending_on_its_bound_writes_its_file_and_says_so(tmp_path, aerosonde, truth,
                                                                capsys):
    """--bounds below the truth: the optimum is on the bound, the estimate is the bound
    (projected, never outside it), the file is written and loads, and the headline flags it;
    by default the file keeps the airframe file's value (a value on a bound is not determined
    by the data), with --keep-undetermined it holds the bound."""
    from uavdyn.flightdata import write_csv, write_manifest

    data = tmp_path / "data"
    data.mkdir()
    entries = []
    for s, split in zip(_sorties(truth, 3, 7, duration=6.0), ("train", "train", "validation")):
        write_csv(s, data / f"{s.name}.csv")
        entries.append({"file": f"{s.name}.csv", "mission": "sysid", "duration_s": 6.0,
                        "split": split})
    write_manifest(data, airframe="aerosonde", kind="fixed_wing", sample_rate_hz=100.0,
                   source="test", sorties=entries)
    nominal, true = aerosonde.params.C_m_alpha, truth.params.C_m_alpha  # true: 1.15 x nominal
    low, high = sorted((nominal, 0.5 * (nominal + true)))  # the truth is outside
    out = tmp_path / "fitted.toml"
    assert main(["identify", "--airframe", "aerosonde", "--dataset", str(data), "--params",
                 "C_m_alpha", "--bounds", f"C_m_alpha={low}:{high}", "--out", str(out),
                 "--quiet"]) == 0
    assert load_airframe(out).params.C_m_alpha == nominal
    assert "kept the airframe file's value" in capsys.readouterr().out
    assert main(["identify", "--airframe", "aerosonde", "--dataset", str(data), "--params",
                 "C_m_alpha", "--bounds", f"C_m_alpha={low}:{high}", "--out", str(out),
                 "--quiet", "--keep-undetermined", "--force"]) == 0
    value = load_airframe(out).params.C_m_alpha
    edge = low if true < low else high
    assert low <= value <= high and value == pytest.approx(edge, rel=1e-6)
    printed = capsys.readouterr().out
    assert "the fit ended on its" in printed and "bound" in printed
    assert "flagged: C_m_alpha (on its " in printed  # in the headline, not only the table
    assert main(["identify", "--airframe", "aerosonde", "--dataset", str(data), "--params",
                 "C_m_alpha", "--bounds", "C_m_q=-1:0", "--out", str(out), "--force"]) == 2
    assert "--bounds C_m_q: only a continuous parameter named in --params" in \
        capsys.readouterr().err


@pytest.mark.slow
def test_structure_selection_keeps_the_term_the_truth_has(aerosonde):
    """The truth flies an alpha-dot pitching moment the nominal airframe lacks: starting from
    [C_m_alpha, C_m_q], --structure auto keeps C_m_alpha_dot (measured: validation 1 s pitch
    RMSE 9.6e-4 -> 7.9e-4 rad), recovers it, and keeps no term the truth does not have."""
    from uavdyn.identify.selection import select_structure

    truth = aerosonde.replace(C_m_alpha_dot=-8.0)
    train = _sorties(truth, 3, 11, duration=8.0, noise=0.2)
    validation = _sorties(truth, 1, 12, duration=8.0, noise=0.2)
    result, start, log = select_structure(aerosonde, train, validation,
                                          ["C_m_alpha", "C_m_q"], progress=False)
    kept = [e["step"] for e in log if e["kept"] and e["step"] != "base"]
    assert kept == ["C_m_alpha_dot"], log
    base = log[0]["validation_theta_rmse"]
    chosen = next(e["validation_theta_rmse"] for e in log if e["kept"] and e is not log[0])
    assert chosen <= 0.98 * base  # the stated criterion
    assert result.fit["validation"]["theta_rmse"]["identified"] == pytest.approx(chosen)
    fitted = {e.name: e for e in result.estimates}
    e = fitted["C_m_alpha_dot"]
    assert abs(e.value + 8.0) <= 3 * e.std_error_corrected, (e.value, e.std_error_corrected)
    tried = {e["step"] for e in log}
    assert "C_L_alpha2" in tried and any(t.startswith("C_m(alpha) table") for t in tried)


def test_each_sortie_is_weighted_by_its_own_noise_level(aerosonde, truth):
    """Maximum likelihood with a noise level per sortie: the true model, two sorties with the
    emulator's sensor noise and two with ten times it; the refit weighs each sortie by
    1 / its residual RMS, so the quiet ones get about ten times the weight."""
    quiet, loud = _sorties(truth, 2, 3, noise=1.0), _sorties(truth, 2, 4, noise=10.0)
    result = identify(truth, quiet + loud, [], ["C_m_alpha", "C_m_q"], progress=False,
                      check_halves=False, screen=False, free_run=False)
    weights = next(e["sortie_weights"] for e in result.search if e["step"] == "re-weighted")
    ratio = min(weights[0], weights[1]) / max(weights[2], weights[3])
    assert 7.0 < ratio < 13.0, weights
    for e in result.estimates:  # and the fit stays where the truth is
        true = getattr(truth.params, e.name)
        assert abs(e.value - true) <= 3 * e.std_error_corrected, (e.name, e.value, true)


def test_a_slew_time_fits_with_its_lag_at_zero(aerosonde, truth):
    """A rate limit fitted on an actuator whose lag the file keeps at 0 (a pure rate limiter;
    the default's refit does this when the lag is not determined): the derivatives stay
    finite, so the fit runs (it was refused as 'not excited', its Jacobian NaN)."""
    assert aerosonde.params.tau_elevator == 0.0
    result = identify(aerosonde, _sorties(truth, 2, 5), [], ["C_m_q", "slew_elevator"],
                      progress=False, check_halves=False, free_run=False, screen=False,
                      keep_undetermined=True)
    c_m_q = next(e for e in result.estimates if e.name == "C_m_q")
    assert np.isfinite(c_m_q.value) and np.isfinite(c_m_q.std_error_corrected)
