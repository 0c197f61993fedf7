"""The flight-data emulator: richer than the baseline, converged, deterministic, and its parts
(turbulence, actuators, noise, soft limits) behave as documented."""

import math

import casadi as ca
import numpy as np
import pytest

from uavdyn.emulation import Emulator, dryden_gusts, open_loop_references, plan_mission
from uavdyn.emulation.emulator import TRUTH_DEFAULTS, soft_clip
from uavdyn.integrate import rk4_step, simulate
from uavdyn.integrate.inputs import control_sequence, doublet, multistep_3211
from uavdyn.model import build_model


def _sysid_controls(trim_point, t, elevator=True):
    u = control_sequence("none", t, trim_point.u, 0.0)
    if elevator:
        u[:, 0] += multistep_3211(t, math.radians(3.0), start=2.0, unit=0.4)
        u[:, 0] += doublet(t, math.radians(4.0), start=10.0, width=0.6)
    return u


def test_baseline_and_calm_emulator_differ_measurably(aerosonde, aerosonde_trim):
    """Same inputs, same start: the baseline RK4 and the calm, noise-free emulator disagree in
    pitch by far more than the baseline's own integration error (there is physics to learn)."""
    rate = 100.0
    t = np.arange(2001) / rate  # 20 s
    u = _sysid_controls(aerosonde_trim, t)
    em = Emulator(aerosonde, sample_rate_hz=rate)
    x0 = em.initial_state(aerosonde_trim.x, aerosonde_trim.u, 150.0)
    flight = em.fly(x0, open_loop_references(u), noise_scale=0.0)
    np.testing.assert_allclose(flight.controls, u, atol=1e-12)  # logged = commanded inputs
    u = flight.controls  # the baseline gets exactly what the log holds
    step = rk4_step(build_model(aerosonde).f)
    base = simulate(step, aerosonde_trim.x, u[:-1], aerosonde.p, 1 / rate)
    base_fine = simulate(step, aerosonde_trim.x, np.repeat(u[:-1], 4, axis=0), aerosonde.p,
                         1 / rate / 4)[::4]
    err = base[:, 3] - flight.true_states[:, 3]
    rms, peak = float(np.sqrt(np.mean(err**2))), float(np.max(np.abs(err)))
    numerics = float(np.max(np.abs(base[:, 3] - base_fine[:, 3])))
    print(f"\nfixed wing, 20 s 3-2-1-1 + doublet: baseline RK4 (0.01 s) vs calm emulator pitch "
          f"RMS {rms:.3e} rad, max {peak:.3e} rad; baseline dt 0.01 vs 0.0025: {numerics:.1e}")
    assert rms > 1e-3 and peak > 3e-3
    assert numerics < 1e-4 * rms


def test_quadrotor_baseline_and_emulator_differ(f450, f450_hover):
    """Quadrotor: the closed-loop emulator's commands replayed open loop through the baseline
    model give a clearly different pitch within 1 s (motor lag, mixer limits, rotor effects)."""
    em = Emulator(f450)
    plan = plan_mission("sysid_doublet", f450, 20.0, 100.0, np.random.default_rng(5))
    flight = em.fly(em.initial_state(plan.x0, plan.u0, plan.altitude), plan.references,
                    noise_scale=0.0)
    n = 101
    base = simulate(rk4_step(build_model(f450).f), plan.x0, flight.controls[:n - 1], f450.p,
                    0.01)
    err = base[:, 3] - flight.true_states[:n, 3]
    rms = float(np.sqrt(np.mean(err**2)))
    print(f"\nquadrotor, first 1 s of a doublet sortie: baseline vs emulator pitch RMS "
          f"{rms:.3e} rad")
    assert rms > 1e-3


@pytest.mark.parametrize("airframe_name, mission", [("aerosonde", "sysid_3211"),
                                                    ("f450", "aggressive")])
def test_emulator_is_converged(airframe_name, mission, request):
    """Halving the internal RK4 step changes pitch by < 1e-8 rad over a calm, noise-free 20 s
    sortie (smooth limits keep RK4 fourth order)."""
    af = request.getfixturevalue(airframe_name)
    thetas = []
    for dt in (1e-3, 5e-4):
        em = Emulator(af, internal_dt=dt)
        plan = plan_mission(mission, af, 20.0, 100.0, np.random.default_rng(3))
        fl = em.fly(em.initial_state(plan.x0, plan.u0, plan.altitude), plan.references,
                    noise_scale=0.0)
        thetas.append(fl.true_states[:, 3])
    delta = float(np.max(np.abs(thetas[0] - thetas[1])))
    swing = float(np.ptp(thetas[0]))
    print(f"\n{airframe_name} {mission}: max |pitch(1 ms) - pitch(0.5 ms)| = {delta:.2e} rad "
          f"(pitch swing {swing:.3f} rad)")
    assert delta < 1e-8
    assert swing > 0.05  # the sortie really manoeuvres


@pytest.mark.parametrize("airframe_name, trim_name", [("aerosonde", "aerosonde_trim"),
                                                      ("f450", "f450_hover")])
def test_baseline_trim_is_calm_emulator_equilibrium(airframe_name, trim_name, request):
    af, tp = request.getfixturevalue(airframe_name), request.getfixturevalue(trim_name)
    em = Emulator(af)
    ref = open_loop_references(np.tile(tp.u, (2001, 1)))
    fl = em.fly(em.initial_state(tp.x, tp.u, 100.0), ref, noise_scale=0.0)
    assert np.max(np.abs(fl.true_states - tp.x)) < 1e-6


def test_turbulence_enters_and_is_seeded(aerosonde, aerosonde_trim):
    em = Emulator(aerosonde)
    x0 = em.initial_state(aerosonde_trim.x, aerosonde_trim.u, 150.0)
    ref = open_loop_references(np.tile(aerosonde_trim.u, (2001, 1)))
    g1 = dryden_gusts(np.random.default_rng(7), 2001, 0.01, 25.0, 1.5)
    g2 = dryden_gusts(np.random.default_rng(7), 2001, 0.01, 25.0, 1.5)
    np.testing.assert_array_equal(g1, g2)
    calm = em.fly(x0, ref, noise_scale=0.0)
    gusty = em.fly(x0, ref, g1, noise_scale=0.0)
    assert np.ptp(gusty.true_states[:, 3]) > 10 * max(np.ptp(calm.true_states[:, 3]), 1e-9)
    # the gust moves the air-relative alpha, not (directly) the inertial w
    alpha_inertial = np.arctan2(gusty.true_states[:, 1], gusty.true_states[:, 0])
    assert np.max(np.abs(gusty.alpha_air - alpha_inertial)) > 0.01


def test_dryden_statistics():
    assert np.all(dryden_gusts(np.random.default_rng(0), 100, 0.01, 25.0, 0.0) == 0)
    g = dryden_gusts(np.random.default_rng(1), 400_000, 0.01, 25.0, 2.0)
    np.testing.assert_allclose(g[:, :2].std(axis=0), [2 * 1.06, 2 * 0.7], rtol=0.06)
    assert abs(g[:, 0].mean()) < 0.1
    with pytest.raises(ValueError, match="intensity"):
        dryden_gusts(np.random.default_rng(1), 10, 0.01, 25.0, -1.0)


def test_sensor_noise_and_true_states(f450, f450_hover):
    em = Emulator(f450)
    ref = open_loop_references(np.tile(f450_hover.u, (3001, 1)))
    x0 = em.initial_state(f450_hover.x, f450_hover.u, 30.0)
    noisy = em.fly(x0, ref, rng=np.random.default_rng(0))
    clean = em.fly(x0, ref, rng=np.random.default_rng(0), noise_scale=0.0)
    np.testing.assert_array_equal(noisy.true_states, clean.true_states)
    np.testing.assert_array_equal(clean.measured_states, clean.true_states)
    resid = noisy.measured_states - noisy.true_states
    n = em.noise
    np.testing.assert_allclose(resid[:, [0, 1, 3]].std(axis=0), [n.u, n.w, n.theta], rtol=0.1)
    np.testing.assert_allclose(resid[:, 2].std(), n.q, rtol=0.1)


def test_actuator_lag_and_rate_limit(aerosonde, aerosonde_trim):
    """A 20 deg elevator step: the surface lags the command and never moves faster than the
    rate limit."""
    em = Emulator(aerosonde)
    u = np.tile(aerosonde_trim.u, (301, 1))
    u[100:, 0] += math.radians(20.0)
    fl = em.fly(em.initial_state(aerosonde_trim.x, aerosonde_trim.u, 150.0),
                open_loop_references(u), noise_scale=0.0)
    act = fl.aux["act0"]
    rate = np.abs(np.diff(act)) / em.dt_log
    limit = TRUTH_DEFAULTS["fixed_wing"]["rate_elevator"]
    assert rate.max() <= limit * (1 + 1e-9)
    assert rate.max() > 0.9 * limit  # the limit is reached: a 20 deg step is rate limited
    assert abs(act[101] - u[101, 0]) > math.radians(10)  # lagging
    assert abs(act[-1] - u[-1, 0]) < 1e-4


def test_soft_clip_is_identity_inside_and_bounded():
    x = ca.SX.sym("x")
    f = ca.Function("f", [x], [soft_clip(x, 0.0, 1.0)])
    vals = np.array([float(f(v)) for v in (-5.0, -1e-3, 0.3, 0.6, 1.001, 50.0, 1e6)])
    assert np.all((vals >= 0) & (vals <= 1))
    assert abs(vals[2] - 0.3) < 1e-12 and abs(vals[3] - 0.6) < 1e-12
    assert np.isfinite(float(f(-1e6)))


def test_emulator_rejects_bad_settings(aerosonde):
    with pytest.raises(ValueError, match="must divide"):
        Emulator(aerosonde, internal_dt=3e-3)
    with pytest.raises(ValueError, match="unknown truth parameter"):
        Emulator(aerosonde, truth={"tau_motor_up": 0.1})
    with pytest.raises(ValueError, match="references must be"):
        Emulator(aerosonde).fly(np.zeros(10), np.zeros((5, 3)))
