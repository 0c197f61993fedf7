"""The flight-data emulator: richer than the baseline, converged, deterministic, and its parts
(turbulence, actuators, noise, soft limits) behave as documented."""

import dataclasses
import math

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import quad

from uavdyn.emulation import Emulator, dryden_gusts, open_loop_references, plan_mission
from uavdyn.emulation.emulator import (
    TRUTH_DEFAULTS,
    emulator_rhs,
    gust_span,
    soft_clip,
    wind_in_body,
)
from uavdyn.flightdata import check_values
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
    # the gust moves the air-relative alpha, not (directly) the inertial w; the log holds the
    # air-relative velocity, so its alpha is the wing's
    inertial = gusty.aux["emulator_states"]
    alpha_inertial = np.arctan2(inertial[:, 1], inertial[:, 0])
    assert np.max(np.abs(gusty.alpha_air - alpha_inertial)) > 0.01
    alpha_logged = np.arctan2(gusty.true_states[:, 1], gusty.true_states[:, 0])
    np.testing.assert_allclose(alpha_logged, gusty.alpha_air, rtol=0, atol=1e-12)


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


def test_lags_and_rates_come_from_the_airframe_file(aerosonde, f450):
    """A file's tau_elevator/tau_throttle/tau_rotor and [limits] rates become the truth
    model's; a preset (none set) keeps the emulator's defaults; an explicit truth wins."""
    assert Emulator(aerosonde).truth == TRUTH_DEFAULTS["fixed_wing"]
    own = aerosonde.replace(tau_elevator=0.03, tau_throttle=0.1)
    own = dataclasses.replace(own, limits={"elevator": (-0.35, 0.35), "elevator_rate": 5.0})
    em = Emulator(own)
    assert (em.truth["tau_elevator"], em.truth["tau_throttle"], em.truth["rate_elevator"]) == \
        (0.03, 0.1, 5.0)
    assert em.truth["rate_throttle"] == TRUTH_DEFAULTS["fixed_wing"]["rate_throttle"]
    assert em.truth_sources["tau_elevator"] == "airframe file"
    assert em.truth_sources["tau_alpha"] == "emulator default"
    np.testing.assert_array_equal(em.command_limits, [-0.35, 0.35, 0.0, 1.0, 5.0, 0.0])
    assert Emulator(own, truth={"tau_elevator": 0.05}).truth_sources["tau_elevator"] == "given"
    quad_em = Emulator(f450.replace(tau_rotor=0.03))
    assert quad_em.truth["tau_motor_up"] == 0.03
    assert quad_em.truth["tau_motor_down"] == pytest.approx(0.06)


def test_commands_saturate_at_the_files_travel_and_rate(aerosonde, aerosonde_trim):
    """Open-loop elevator commands far beyond the file's travel: the logged command stays
    inside [limits] and moves at most its rate per log interval; without [limits] the same
    commands reach the physical range."""
    u = np.tile(aerosonde_trim.u, (301, 1))
    u[100:200, 0] = 0.6
    u[200:, 0] = -0.6
    own = dataclasses.replace(aerosonde, limits={"elevator": (-0.2, 0.3),
                                                 "elevator_rate": 2.0})
    out = {}
    for af in (aerosonde, own):
        em = Emulator(af)
        fl = em.fly(em.initial_state(aerosonde_trim.x, aerosonde_trim.u, 150.0),
                    open_loop_references(u), noise_scale=0.0)
        out[af is own] = fl.controls[:, 0]
    limited, free = out[True], out[False]
    assert -0.2 - 1e-12 <= limited.min() and limited.max() <= 0.3 + 1e-12
    assert limited.max() > 0.3 - 1e-3 and limited.min() < -0.2 + 1e-3  # the travel is reached
    assert np.abs(np.diff(limited)).max() <= 2.0 * 0.01 + 1e-12
    assert np.abs(np.diff(limited)).max() > 0.99 * 2.0 * 0.01  # ... and the rate
    assert free.max() > 0.52 and free.min() < -0.52
    np.testing.assert_allclose(limited[:100], free[:100], atol=1e-12)  # inside: unchanged


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


# ----------------------------------------------------------------------------- wind and gusts


def test_wind_rotates_into_body_axes_with_pitch():
    """Inertial wind [W_x, W_z] (x forward, z down) in body axes: u = cos W_x - sin W_z,
    w = sin W_x + cos W_z; nose straight up (90 deg), a head wind appears entirely in w."""
    head = -6.0
    u_w, w_w = wind_in_body(0.0, head, 0.0, np)
    assert (u_w, w_w) == (head, 0.0)
    u_w, w_w = wind_in_body(math.pi / 2, head, 0.0, np)
    assert abs(u_w) < 1e-15 and w_w == pytest.approx(head, abs=1e-15)
    theta, wx, wz = 0.3, -4.0, 1.5
    u_w, w_w = wind_in_body(theta, wx, wz, np)
    assert u_w == pytest.approx(math.cos(theta) * wx - math.sin(theta) * wz, abs=1e-15)
    assert w_w == pytest.approx(math.sin(theta) * wx + math.cos(theta) * wz, abs=1e-15)
    assert math.hypot(u_w, w_w) == pytest.approx(math.hypot(wx, wz), abs=1e-14)


@pytest.mark.parametrize("kind", ["fixed_wing", "multirotor"])
def test_dynamics_see_the_wind_rotated_with_the_current_pitch(kind, aerosonde, f450):
    """At any state, the emulator's dynamics with an inertial wind equal the dynamics with a
    body-axis gust of exactly the rotated wind at that state's pitch (theta up to 90 deg)."""
    af = aerosonde if kind == "fixed_wing" else f450
    f_wind, f_gust = emulator_rhs(kind, with_wind=True), emulator_rhs(kind)
    em = Emulator(af)
    rng = np.random.default_rng(2)
    cmd = np.array([0.0, 0.6]) if kind == "fixed_wing" else np.array([0.55, 0.0])
    for theta in (0.0, 0.4, -0.3, math.pi / 2):
        x = em.initial_state(np.array([22.0, 1.0, 0.05, theta]) if kind == "fixed_wing"
                             else np.array([2.0, 0.3, 0.05, theta]), cmd, 100.0)
        wind = rng.normal(size=2) * 4
        u_w, w_w = wind_in_body(theta, wind[0], wind[1], np)
        a = np.asarray(f_wind(x, np.r_[cmd, 0.0, 0.0, 0.0, wind], em.pe)).ravel()
        b = np.asarray(f_gust(x, np.r_[cmd, u_w, w_w, 0.0], em.pe)).ravel()
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)
        calm = np.asarray(f_gust(x, np.r_[cmd, 0.0, 0.0, 0.0], em.pe)).ravel()
        assert np.max(np.abs(a - calm)) > 1e-3  # the wind does act


def test_calm_flight_is_unchanged_by_the_wind_input(aerosonde, aerosonde_trim):
    """No wind and no gust: the logged (air-relative) states are the inertial ones bit for bit,
    and a zero wind is the same flight as no wind."""
    em = Emulator(aerosonde)
    plan = plan_mission("sysid_3211", aerosonde, 10.0, 100.0, np.random.default_rng(1))
    x0 = em.initial_state(plan.x0, plan.u0, plan.altitude)
    a = em.fly(x0, plan.references, noise_scale=0.0)
    b = em.fly(x0, plan.references, noise_scale=0.0, wind=[0.0, 0.0])
    np.testing.assert_array_equal(a.true_states, a.aux["emulator_states"][:, :4])
    np.testing.assert_array_equal(a.true_states, b.true_states)
    np.testing.assert_array_equal(a.controls, b.controls)
    with pytest.raises(ValueError, match="wind must be"):
        em.fly(x0, plan.references, wind=np.zeros((3, 2)))


@pytest.mark.parametrize("head_wind", [6.0, -4.0])  # head wind, tail wind
def test_logged_velocity_is_air_relative_in_steady_wind(aerosonde, aerosonde_trim, head_wind):
    """A trim point flown in a steady horizontal wind, started in equilibrium with the air
    mass: the logged airspeed sqrt(u^2 + w^2) and pitch stay at trim while the ground speed
    (inertial) differs from the airspeed by the wind."""
    em = Emulator(aerosonde)
    wind = np.array([-head_wind, 0.0])
    x0 = em.initial_state(aerosonde_trim.x, aerosonde_trim.u, 150.0, wind=wind)
    ref = open_loop_references(np.tile(aerosonde_trim.u, (1001, 1)))
    fl = em.fly(x0, ref, noise_scale=0.0, wind=wind)
    v_trim = math.hypot(aerosonde_trim.x[0], aerosonde_trim.x[1])
    airspeed = np.hypot(fl.true_states[:, 0], fl.true_states[:, 1])
    np.testing.assert_allclose(airspeed, v_trim, atol=1e-6)
    np.testing.assert_allclose(fl.true_states, np.tile(aerosonde_trim.x, (1001, 1)), atol=1e-6)
    inertial = fl.aux["emulator_states"]
    theta = inertial[:, 3]
    ground_speed = inertial[:, 0] * np.cos(theta) + inertial[:, 1] * np.sin(theta)
    air_speed_x = fl.true_states[:, 0] * np.cos(theta) + fl.true_states[:, 1] * np.sin(theta)
    np.testing.assert_allclose(ground_speed - air_speed_x, -head_wind, atol=1e-9)
    assert np.ptp(fl.aux["h"]) < 1e-4  # level: a horizontal wind does not make it climb
    np.testing.assert_allclose(fl.aux["V_air"], airspeed, atol=1e-12)
    # The same start without telling the emulator the wind is not an equilibrium in that wind
    drift = em.fly(em.initial_state(aerosonde_trim.x, aerosonde_trim.u, 150.0), ref,
                   noise_scale=0.0, wind=wind)
    assert abs(np.hypot(*drift.true_states[0, :2]) - v_trim) > 0.9 * abs(head_wind)


@pytest.mark.parametrize("airframe_name", ["aerosonde", "f450"])
def test_turbulent_windy_sortie_log_is_consistent(airframe_name, request):
    """A mission in a 6 m/s head wind with Dryden turbulence: the log passes the loader's
    checks (d theta/dt ~ q included, q and theta being inertial) and its u, w are the
    inertial velocities minus the pitch-rotated wind minus the gust."""
    af = request.getfixturevalue(airframe_name)
    rng = np.random.default_rng(4)
    plan = plan_mission("sysid_doublet", af, 20.0, 100.0, rng)
    n = plan.references.shape[0]
    gusts = dryden_gusts(rng, n, 0.01, 25.0 if af.kind == "fixed_wing" else 6.0, 1.5,
                         gust_span(af))
    wind = np.array([-6.0, 0.0])
    em = Emulator(af)
    fl = em.fly(em.initial_state(plan.x0, plan.u0, plan.altitude, wind=wind), plan.references,
                gusts, rng, wind=wind)
    check_values(f"{airframe_name} windy", af.kind, fl.time, fl.measured_states, fl.controls,
                 100.0)
    check_values(f"{airframe_name} windy true", af.kind, fl.time, fl.true_states,
                 fl.controls, 100.0)
    X = fl.aux["emulator_states"]
    u_w, w_w = wind_in_body(X[:, 3], wind[0], wind[1], np)
    np.testing.assert_allclose(fl.true_states[:, 0], X[:, 0] - u_w - gusts[:, 0], atol=1e-12)
    np.testing.assert_allclose(fl.true_states[:, 1], X[:, 1] - w_w - gusts[:, 1], atol=1e-12)
    np.testing.assert_array_equal(fl.true_states[:, 2:], X[:, 2:4])
    np.testing.assert_array_equal(fl.wind, np.tile(wind, (n, 1)))


def _dryden_q_variance(airspeed, intensity, span, sigma_w=0.7, L_w=50.0):
    """Variance of the MIL-F-8785C pitch-rate gust, integral of its PSD (white noise of
    two-sided PSD pi: var = int_0^inf |H_q(i omega)|^2 d omega), H_q = (s/V)/(1 + 4b s/(pi V))
    H_w, written here from the transfer functions (not from the code's state space)."""
    V = airspeed
    k2 = (sigma_w * intensity) ** 2 * 3 * V / (math.pi * L_w)
    a, T = V / L_w, 4 * span / (math.pi * V)

    def psd(w):
        return (w / V) ** 2 / (1 + (T * w) ** 2) * k2 * (w**2 + a**2 / 3) / (w**2 + a**2) ** 2

    return quad(psd, 0.0, np.inf, limit=500)[0]


def test_dryden_pitch_rate_gust_has_the_analytic_variance_and_uses_the_span():
    """200,000 samples (2,000 s at 0.01 s) of q_g for the Aerosonde span and a 0.45 m span:
    each sample variance is within 4 batch-means standard errors (20 batches) and 3 % of the
    analytic variance; the larger span filters more (lower variance); u_g, w_g do not depend
    on the span (same seed, same values)."""
    V, intensity = 25.0, 1.5
    out = {}
    for span in (2.8956, 0.45):
        g = dryden_gusts(np.random.default_rng(4), 200_000, 0.01, V, intensity, span)
        analytic = _dryden_q_variance(V, intensity, span)
        sample = float(g[:, 2].var())
        se = float(g[:, 2].reshape(20, -1).var(axis=1).std(ddof=1) / math.sqrt(20))
        print(f"\nspan {span} m: q_g variance sample {sample:.5g}, analytic {analytic:.5g} "
              f"(rad/s)^2, standard error {se:.2g}")
        assert abs(sample - analytic) < 4 * se
        assert abs(sample / analytic - 1) < 0.03
        out[span] = (g, analytic)
    assert out[2.8956][1] < 0.5 * out[0.45][1]
    np.testing.assert_allclose(out[2.8956][0][:, :2], out[0.45][0][:, :2], rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="wingspan"):
        dryden_gusts(np.random.default_rng(1), 10, 0.01, 25.0, 1.0, wingspan=0.0)


def test_gust_span_comes_from_the_airframe(aerosonde, f450):
    assert gust_span(aerosonde) == pytest.approx(2.8956)
    assert gust_span(f450) == pytest.approx(2 * 0.225 * math.cos(math.pi / 4) + 0.254)


@pytest.mark.parametrize("airframe_name", ["aerosonde", "f450"])
def test_turbulent_datagen_sortie_flies_in_an_inertial_head_wind(airframe_name, request):
    """The dataset generator's turbulent sortie: an inertial head wind (W_x < 0, W_z = 0), the
    span of the airframe in the gusts, a fixed wing started trimmed in the moving air (logged
    airspeed at t = 0 is the plan's trim airspeed), and a log of air-relative u, w."""
    from uavdyn.emulation.datagen import Recipe, _fly_one

    af = request.getfixturevalue(airframe_name)
    recipe = Recipe(airframe=airframe_name, duration_s=10.0, mean_wind_mps=(4.0, 6.0))
    item = {"index": 3, "mission": "sysid_doublet", "condition": "turbulent", "split": "test"}
    flight, plan, intensity, wind, _ = _fly_one(recipe, af, Emulator(af), item, 0)
    assert wind[0] <= -4.0 and wind[1] == 0.0 and intensity > 0
    np.testing.assert_array_equal(flight.wind, np.tile(wind, (len(flight.time), 1)))
    X = flight.aux["emulator_states"]
    u_w, w_w = wind_in_body(X[:, 3], wind[0], wind[1], np)
    np.testing.assert_allclose(flight.true_states[:, 0], X[:, 0] - u_w - flight.gusts[:, 0],
                               atol=1e-12)
    if af.kind == "fixed_wing":
        v0 = math.hypot(plan.x0[0], plan.x0[1])
        airspeed0 = math.hypot(*(flight.true_states[0, :2] + flight.gusts[0, :2]))
        assert airspeed0 == pytest.approx(v0, abs=1e-9)
    else:  # the multirotor starts at rest over the ground, so the wind blows through it
        np.testing.assert_allclose(X[0, :2], plan.x0[:2], atol=1e-12)
