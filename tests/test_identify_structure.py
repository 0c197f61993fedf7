"""Identification on the model structure of issue 11: a truth with an actuator lag, a transport
delay and another air density (plus scaled coefficients) is flown by the augmented physics step
(:func:`uavdyn.integrate.physics_step`) and identified from the NOMINAL preset (no lag, no
delay): noise-free within 0.5 % (the delay exact); with the emulator's sensor noise within 2
standard errors. Also a quadrotor (rotor lag, a delay on each command, mass), breakpoint-table
values, the per-sortie standard atmosphere, and the fitted airframe file's round trip."""

import dataclasses

import numpy as np
import pytest

from uavdyn.airframes import load_airframe
from uavdyn.airframes.tables import Table
from uavdyn.emulation.emulator import SensorNoise
from uavdyn.flightdata import Sortie
from uavdyn.identify import IdentifyError, identify, write_outputs
from uavdyn.integrate import augment_states, physics_step, rollout
from uavdyn.integrate.inputs import doublet, multistep_3211
from uavdyn.linear import trim
from uavdyn.model import sortie_params, structure_of

T = 0.01          # 100 Hz logs
SUBSTEPS = 2      # RK4 sub-steps per sample: the data and the fit use the same discrete step
NOISE = np.array([SensorNoise.u, SensorNoise.w, SensorNoise.q, SensorNoise.theta])
NAMES = ["C_m_alpha", "C_m_q", "C_L_alpha", "tau_elevator", "delay_elevator", "rho"]


def _fly(truth, u: np.ndarray, x0: np.ndarray, altitude: float | None = None) -> np.ndarray:
    """Open-loop flight of ``truth``'s augmented step from ``x0`` with the actuators at rest
    on the first command: the body states at every sample."""
    structure = structure_of(truth)
    p = sortie_params(truth, altitude)
    z0 = augment_states(structure, x0[None], u[:1], p, T)[0]
    z = np.array(rollout(physics_step(truth, substeps=SUBSTEPS), len(u) - 1)(
        z0, u[:-1].T, p, T)).T
    return np.vstack([x0, z[:, :4]])


def _fixed_wing_sorties(truth, n: int, seed: int, duration: float = 8.0, noise: float = 0.0,
                        altitudes=None) -> list[Sortie]:
    """Sysid flights: a 3-2-1-1 and a doublet on the elevator, a throttle step."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        altitude = None if altitudes is None else altitudes[i]
        trim_af = truth if altitude is None else truth.replace(
            rho=float(sortie_params(truth, altitude)[truth.param_names.index("rho")]))
        point = trim(trim_af, 21.0 + 2.0 * i)
        t = np.arange(int(round(duration / T)) + 1) * T
        u = np.tile(point.u, (len(t), 1))
        u[:, 0] += multistep_3211(t, np.radians(2.0), start=0.5 + 0.2 * i)
        u[:, 0] += doublet(t, np.radians(1.5), start=4.0, width=0.3)
        u[:, 1] += np.where((t > 5.5) & (t < 7.0), 0.1, 0.0)
        x = _fly(truth, u, point.x, altitude)
        x = x + rng.normal(size=x.shape) * NOISE * noise
        meta = {} if altitude is None else {"manifest_entry": {"altitude_m": altitude}}
        out.append(Sortie(f"s{seed}_{i}", "fixed_wing", t, x, u, "sysid", meta))
    return out


@pytest.fixture(scope="module")
def truth(aerosonde):
    P = aerosonde.params
    return aerosonde.replace(C_m_alpha=1.15 * P.C_m_alpha, C_m_q=0.90 * P.C_m_q,
                             C_L_alpha=1.20 * P.C_L_alpha, tau_elevator=0.05,
                             rho=1.10).with_delays(elevator=2)


def _true_value(truth, name: str) -> float:
    if name.startswith("delay_"):
        return float(truth.delays.get(name[len("delay_"):], 0))
    return float(truth.p[truth.param_names.index(name)])


@pytest.fixture(scope="module")
def noise_free(aerosonde, truth):
    assert aerosonde.params.tau_elevator == 0.0 and not any(aerosonde.delay_samples())
    assert abs(aerosonde.params.rho - 1.10) > 0.1
    return identify(aerosonde, _fixed_wing_sorties(truth, 4, 0),
                    _fixed_wing_sorties(truth, 1, 1), NAMES, progress=False)


@pytest.mark.slow
def test_recovers_lag_delay_density_and_coefficients_from_the_nominal_preset(
        aerosonde, truth, noise_free):
    for e in noise_free.estimates:
        true = _true_value(truth, e.name)
        if e.searched:
            assert e.value == true and e.std_error == 0.0, (e.name, e.value, true)
            continue
        assert abs(e.value - true) <= 5e-3 * abs(true), (e.name, e.value, true)
        assert abs(e.value - e.nominal) > 0.05 * abs(true)  # it really moved from nominal
    assert noise_free.airframe.delays == {"elevator": 2}
    assert noise_free.airframe.params.tau_elevator == pytest.approx(0.05, rel=5e-3)
    # the fitted airframe's own augmented step (delay buffers, lag) predicts the held-out
    # sortie: the fit used delays as shifted data; this checks it is the same model
    fit = noise_free.fit["validation"]["theta_rmse"]
    assert fit["identified"] < 1e-6 < 1e-3 < fit["nominal"]


@pytest.mark.slow
def test_with_sensor_noise_estimates_fall_within_two_standard_errors(aerosonde, truth):
    # the raw fit (keep_undetermined): its statistics are what is checked here; by default a
    # parameter in a collinear group would keep the file's value
    result = identify(aerosonde, _fixed_wing_sorties(truth, 4, 2, noise=1.0), [],
                      [*NAMES, "C_m_delta_e"], progress=False,
                      keep_undetermined=True)  # C_m_delta_e: truth = nominal
    for e in result.estimates:
        true = _true_value(truth, e.name)
        print(f"{e.name}: {e.value:.6g} +- {e.std_error:.2g}, truth {true:.6g}")
        if e.searched:
            assert e.value == true, (e.name, e.value, true)
            continue
        assert e.std_error > 0
        assert abs(e.value - true) <= 2 * e.std_error, (e.name, e.value, true, e.std_error)


def test_fitted_airframe_file_round_trips(tmp_path, aerosonde, noise_free):
    out = tmp_path / "fitted.toml"
    write_outputs(noise_free, aerosonde, "synthetic", "uavdyn identify ...", out,
                  tmp_path / "report")
    loaded = load_airframe(out)
    np.testing.assert_array_equal(loaded.p, noise_free.airframe.p)
    assert loaded.delays == {"elevator": 2} == noise_free.airframe.delays
    assert loaded.param_hash() == noise_free.airframe.param_hash() != aerosonde.param_hash()
    text = out.read_text()
    assert "delay_elevator = 2 samples" in text and "searched" in text
    assert "tau_elevator = 0.05" in text and "dataset: synthetic" in text


def test_airframe_file_keeps_tables_limits_delays_and_atmosphere(tmp_path, aerosonde):
    """The writer's file loads back to the same p, delays, limits, tables and atmosphere."""
    from uavdyn.identify import airframe_toml

    table = Table("C_m", (("alpha", (-0.1, 0.0, 0.1)), ("elevator", (-0.2, 0.2))),
                  (0.3, 0.1, 0.0135, -0.01, -0.2, -0.4))
    rich = dataclasses.replace(aerosonde.replace(tau_throttle=0.2), tables={"C_m": table},
                               atmosphere="isa", limits={"elevator": (-0.3, 0.25),
                                                         "elevator_rate": 2.0})
    rich = rich.with_delays(elevator=3, throttle=1)
    path = tmp_path / "rich.toml"
    path.write_text(airframe_toml(rich, ["a header"]))
    loaded = load_airframe(path)
    assert loaded.param_names == rich.param_names
    np.testing.assert_array_equal(loaded.p, rich.p)
    assert loaded.delay_samples() == (3, 1) and loaded.atmosphere == "isa"
    assert loaded.limits == rich.limits and loaded.tables == rich.tables
    assert loaded.param_hash() == rich.param_hash()


def test_refuses_unknown_and_unexcited_delays(aerosonde):
    point = trim(aerosonde, 23.0)
    t = np.arange(301) * T
    u = np.tile(point.u, (len(t), 1))
    u[:, 1] += np.where(t > 1.0, 0.1, 0.0)  # throttle step; the elevator never moves
    steady = [Sortie("steady", "fixed_wing", t, _fly(aerosonde, u, point.x), u, "sysid")]
    with pytest.raises(IdentifyError, match=r"\['delay_aileron'\] not a delay of the "
                                            r"fixed_wing model; valid delays: delay_elevator, "
                                            r"delay_throttle"):
        identify(aerosonde, steady, [], ["C_m_q", "delay_aileron"], progress=False)
    with pytest.raises(IdentifyError, match=r"do not excite parameter\(s\) \['delay_elevator'\]"):
        identify(aerosonde, steady, [], ["delay_elevator"], progress=False)


@pytest.mark.slow
def test_recovers_breakpoint_table_values(aerosonde):
    """A C_m(alpha) table (sampled from the polynomial) whose values the truth changes: the
    table values flown through are identified as parameters like any other."""
    P = aerosonde.params
    alpha = (-0.1, 0.0, 0.05, 0.1, 0.3)
    values = tuple(P.C_m_0 + P.C_m_alpha * a for a in alpha)
    nominal = dataclasses.replace(aerosonde, tables={"C_m": Table("C_m", (("alpha", alpha),),
                                                                  values)})
    truth = nominal.replace(C_m_table_1=values[1] + 0.01, C_m_table_2=values[2] * 1.2,
                            C_m_table_3=values[3] * 0.85)
    names = ["C_m_table_1", "C_m_table_2", "C_m_table_3"]
    result = identify(nominal, _fixed_wing_sorties(truth, 3, 4, duration=6.0), [], names,
                      progress=False)
    for e in result.estimates:
        true = _true_value(truth, e.name)
        assert abs(e.value - true) <= 5e-3 * abs(true), (e.name, e.value, true)
    assert result.airframe.tables["C_m"].values[1:4] == pytest.approx(
        [_true_value(truth, n) for n in names], rel=5e-3)


@pytest.mark.slow
def test_isa_density_per_sortie_fits_the_sea_level_density(aerosonde):
    """With atmosphere = "isa" each sortie flies at the density of its manifest altitude;
    fitting rho gives the sea-level value, not one average over the altitudes."""
    nominal = dataclasses.replace(aerosonde, atmosphere="isa")
    truth = nominal.replace(rho=1.18)
    sorties = _fixed_wing_sorties(truth, 3, 5, duration=5.0, altitudes=(0.0, 1500.0, 3000.0))
    result = identify(nominal, sorties, [], ["rho", "C_m_alpha"], progress=False)
    rho = result.estimates[0]
    assert rho.name == "rho" and abs(rho.value - 1.18) <= 1e-6 * 1.18, rho


def _quadrotor_sorties(truth, n: int, seed: int, duration: float = 6.0) -> list[Sortie]:
    """Closed-loop pitch-plane flights (a PD pitch loop keeps the quadrotor upright) with
    collective steps and pitch doublets on top; the logged commands are the loop's output."""
    structure = structure_of(truth)
    step = physics_step(truth, substeps=SUBSTEPS)
    hover = trim(truth, 0.0)
    out = []
    for i in range(n):
        t = np.arange(int(round(duration / T)) + 1) * T
        extra_c = 0.04 * np.where((t > 1.0 + 0.3 * i) & (t < 2.5), 1.0, 0.0) \
            - 0.03 * np.where((t > 3.5) & (t < 4.5 + 0.2 * i), 1.0, 0.0)
        theta_ref = doublet(t, 0.08, start=0.7 + 0.2 * i, width=0.6) \
            + doublet(t, -0.05, start=3.0, width=0.4)
        x = np.empty((len(t), 4))
        u = np.empty((len(t), 2))
        x[0] = hover.x
        z = augment_states(structure, hover.x[None], hover.u[None], truth.p, T)[0]
        for k in range(len(t)):
            pitch = 0.6 * (theta_ref[k] - x[k, 3]) - 0.12 * x[k, 2]
            u[k] = [hover.u[0] + extra_c[k], hover.u[1] + pitch]
            if k + 1 < len(t):
                z = np.array(step(z, u[k], truth.p, T)).ravel()
                x[k + 1] = z[:4]
        out.append(Sortie(f"q{seed}_{i}", "multirotor", t, x, u, "sysid"))
    return out


@pytest.mark.slow
def test_recovers_a_quadrotor_rotor_lag_delays_and_mass(f450):
    truth = f450.replace(tau_rotor=0.04, mass=1.1 * f450.params.mass).with_delays(
        collective=2, pitch_cmd=1)
    names = ["tau_rotor", "delay_collective", "delay_pitch_cmd", "mass"]
    result = identify(f450, _quadrotor_sorties(truth, 3, 6), [], names, progress=False)
    for e in result.estimates:
        true = _true_value(truth, e.name)
        if e.searched:
            assert e.value == true, (e.name, e.value, true)
        else:
            assert abs(e.value - true) <= 5e-3 * abs(true), (e.name, e.value, true)
    assert result.airframe.delays == {"collective": 2, "pitch_cmd": 1}


def test_window_start_states_equal_the_steps_own_actuator_history(aerosonde):
    """The fit summary restarts each window from actuator and buffer states computed by a
    CasADi loop; they equal :func:`uavdyn.integrate.augmented.actuator_history`."""
    from uavdyn.identify.windows import actuator_states
    from uavdyn.integrate import actuator_history

    airframe = aerosonde.replace(tau_elevator=0.03, tau_throttle=0.4).with_delays(elevator=2,
                                                                                 throttle=1)
    controls = np.random.default_rng(7).normal(size=(300, 2)) * [0.05, 0.1] + [0.0, 0.5]
    structure = structure_of(airframe)
    np.testing.assert_allclose(actuator_states(structure, controls, airframe.p, T),
                               actuator_history(structure, controls, airframe.p, T),
                               rtol=0, atol=1e-15)


def test_recovers_rotor_craft_moments_and_inflow_from_zero_nominals(f450):
    """The speed-stability moment ``M_u``, a constant moment ``M_0`` and the axial-inflow loss
    ``k_inflow`` (all absent from the preset) are recovered beside the mixer gain from
    closed-loop flights, where the pitch loop's steady command holds the unmodelled moments."""
    truth = f450.replace(M_u=0.012, M_0=-0.003, k_inflow=6e-4,
                         pitch_mix=1.2 * f450.params.pitch_mix)
    assert f450.params.M_u == f450.params.M_0 == f450.params.k_inflow == 0.0
    names = ["M_u", "M_0", "k_inflow", "pitch_mix"]
    result = identify(f450, _quadrotor_sorties(truth, 3, 7), [], names, progress=False)
    for e in result.estimates:
        true = _true_value(truth, e.name)
        assert abs(e.value - true) <= 5e-3 * abs(true), (e.name, e.value, true)
