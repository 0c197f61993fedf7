"""Actuator lags, transport delays, tables and ISA through every tool that uses the physics step:
the lag is the analytic first-order response, a delay shifts the response by whole samples,
presets are unchanged, trim/linearise/modes/discrete maps see the augmented state, the
evaluation restarts from recorded commands, the MPC carries its own commands, and the CasADi,
compiled C, NumPy and torch steps agree. Truths: closed forms, an adaptive ODE solver on the
continuous model, CasADi's own Jacobians and exp(A dt)."""

import dataclasses
import math

import casadi as ca
import numpy as np
import pytest
import scipy.linalg
from scipy.integrate import solve_ivp

from uavdyn.airframes.tables import parse_tables
from uavdyn.evaluation import Solver, evaluate_trajectory, fine_reference, sortie_free_run
from uavdyn.flightdata import Sortie
from uavdyn.integrate import (
    augment_states,
    augmented_rk_step,
    body_model,
    compile_function,
    find_compiler,
    free_run,
    physics_step,
    rk4_step,
    simulate,
)
from uavdyn.linear import (
    discrete_map_modes,
    linear_state_names,
    linearise,
    modes,
    stall_speed,
    static_lift_coefficient,
    trim,
    trim_state,
)
from uavdyn.linear.trim import body_structure
from uavdyn.model import (
    NUMPY_OPS,
    build_model,
    isa_density_ratio,
    make_rhs,
    structure_of,
    torch_ops,
)
from uavdyn.mpc import MPCConfig, TrackingMPC, fly_closed_loop, physics_plant

TAU_E, TAU_T = 0.05, 0.3


@pytest.fixture(scope="module")
def lagged(aerosonde):
    """The Aerosonde with an elevator servo lag, an engine lag and a 2-sample elevator delay."""
    return aerosonde.replace(tau_elevator=TAU_E, tau_throttle=TAU_T).with_delays(elevator=2)


@pytest.fixture(scope="module")
def lagged_trim(lagged):
    return trim(lagged, 25.0)


def _doublet(point, n: int, dt: float) -> np.ndarray:
    t = np.arange(n) * dt
    u = np.tile(point.u, (n, 1))
    u[(t >= 0.2) & (t < 0.5), 0] += 0.05
    u[(t >= 0.5) & (t < 0.8), 0] -= 0.05
    u[t >= 0.3, 1] += 0.1
    return u


def _continuous_reference(airframe, x0, controls, dt: float) -> np.ndarray:
    """The continuous model with its actuator ODEs ``a_dot = (c - a)/tau`` (``c``: the command
    of ``d`` samples before, the first before the start), integrated by DOP853 at 1e-13 over
    each zero-order-held sample, from the actuators at rest on the first command."""
    structure = structure_of(airframe)
    rhs = make_rhs(body_structure(airframe), ops=NUMPY_OPS)
    p = airframe.p
    taus = [p[i] for i in structure.tau_indices]
    delays = structure.delay_samples
    lag = structure.lag_indices
    y = np.concatenate([x0, [controls[0][c] for c in lag]])
    out = [y[:4].copy()]
    for n in range(len(controls)):
        cmd = np.array([controls[max(n - delays[c], 0)][c] for c in range(2)])

        def f(_t, yy, cmd=cmd):
            effective = cmd.copy()
            for j, c in enumerate(lag):
                effective[c] = yy[4 + j]
            lags = [(cmd[c] - yy[4 + j]) / taus[j] for j, c in enumerate(lag)]
            return np.concatenate([rhs(yy[:4], effective, p), lags])

        y = solve_ivp(f, (0.0, dt), y, method="DOP853", rtol=1e-13, atol=1e-13).y[:, -1]
        out.append(y[:4].copy())
    return np.array(out)


# ------------------------------------------------------------------ the lag and the delay


@pytest.mark.parametrize("dt", [0.001, 0.01, 0.05, 0.2])  # 0.2 s > tau: still exact
def test_lag_is_the_analytic_first_order_step_response(aerosonde, aerosonde_trim, dt):
    af = aerosonde.replace(tau_elevator=TAU_E, tau_throttle=TAU_T)
    step = physics_step(af)
    n = 20
    u = np.tile(aerosonde_trim.u, (n, 1))
    u[:, 0] += 0.05  # elevator step at t = 0, throttle held
    z = simulate(step, trim_state(af, aerosonde_trim), u, af.p, dt, check=False)
    t = np.arange(n + 1) * dt
    c0, c1 = aerosonde_trim.u[0], u[0, 0]
    np.testing.assert_allclose(z[:, 4], c1 + (c0 - c1) * np.exp(-t / TAU_E), rtol=0,
                               atol=1e-12)
    np.testing.assert_allclose(z[:, 5], aerosonde_trim.u[1], rtol=0, atol=1e-15)


def test_rotor_lag_acts_on_both_multirotor_commands(f450, f450_hover):
    af = f450.replace(tau_rotor=0.07)
    assert structure_of(af).lagged == ("collective", "pitch_cmd")
    u = np.tile(f450_hover.u + [0.02, 0.05], (15, 1))
    z = simulate(physics_step(af), trim_state(af, f450_hover), u, af.p, 0.01)
    decay = np.exp(-np.arange(16) * 0.01 / 0.07)
    for i in range(2):
        expected = u[0, i] + (f450_hover.u[i] - u[0, i]) * decay
        np.testing.assert_allclose(z[:, 4 + i], expected, rtol=0, atol=1e-12)


def test_lagged_step_converges_to_the_continuous_model_at_fourth_order(lagged, lagged_trim):
    """The actuator value at each RK stage's time keeps RK4's order on the body."""
    errors = []
    for dt in (0.01, 0.005):
        u = _doublet(lagged_trim, int(round(1.0 / dt)), dt)
        ref = _continuous_reference(lagged, lagged_trim.x, u, dt)
        z = simulate(physics_step(lagged), trim_state(lagged, lagged_trim), u, lagged.p, dt)
        errors.append(np.abs(z[:, :4] - ref).max())
    order = math.log2(errors[0] / errors[1])
    assert order > 3.7, errors
    assert errors[1] < 1e-6


@pytest.mark.parametrize("delays", [{"elevator": 1}, {"elevator": 3, "throttle": 3},
                                    {"elevator": 3, "throttle": 1}])
@pytest.mark.parametrize("substeps", [1, 4])
def test_delay_shifts_the_whole_response_by_whole_samples(aerosonde, aerosonde_trim, delays,
                                                          substeps):
    """With substeps the buffers still shift once per call: the shift is in calls."""
    base = aerosonde.replace(tau_elevator=TAU_E)
    delayed = base.with_delays(**delays)
    dt, n = 0.01, 120
    u = _doublet(aerosonde_trim, n, dt)
    u[1:, 0] += 0.01 * np.sin(np.arange(1, n))  # every sample differs
    zd = simulate(physics_step(delayed, substeps=substeps), trim_state(delayed, aerosonde_trim),
                  u, delayed.p, dt)
    structure = structure_of(delayed)
    for c, k in enumerate(structure.delay_samples):
        # the channel's buffer holds the last k commands, most recent first
        offset = 4 + structure.n_actuator + sum(structure.delay_samples[:c])
        for j in range(1, k + 1):
            np.testing.assert_array_equal(zd[j + 5:, offset + j - 1], u[5:n - j + 1, c])
    # shift the commands instead: the undelayed airframe flies the same trajectory
    shifted = np.array([[u[max(m - structure.delay_samples[c], 0), c] for c in range(2)]
                        for m in range(n)])
    zs = simulate(physics_step(base, substeps=substeps), trim_state(base, aerosonde_trim),
                  shifted, base.p, dt)
    np.testing.assert_allclose(zd[:, :5], zs, rtol=0, atol=1e-12)
    assert np.ptp(zd[:, 3]) > 1e-3  # the doublet moved the pitch
    if len(set(structure.delay_samples)) == 1:  # one delay on all: the whole response
        k = structure.delay_samples[0]  # is the undelayed one, k samples later
        free = simulate(physics_step(base, substeps=substeps), zd[k, :5], u[:n - k], base.p,
                        dt)
        np.testing.assert_allclose(zd[k:, :5], free, rtol=0, atol=1e-12)


def test_substeps_equal_repeated_calls_for_a_lag(aerosonde, aerosonde_trim):
    af = aerosonde.replace(tau_elevator=TAU_E, tau_throttle=TAU_T)
    z0 = trim_state(af, aerosonde_trim) + [0.1, 0.2, 0.05, 0.01, 0.02, -0.05]
    u = aerosonde_trim.u + [0.03, 0.1]
    one = np.array(physics_step(af, substeps=4)(z0, u, af.p, 0.02)).ravel()
    z = z0
    for _ in range(4):
        z = np.array(physics_step(af)(z, u, af.p, 0.005)).ravel()
    np.testing.assert_allclose(one, z, rtol=0, atol=1e-12)


def test_augment_states_reproduces_the_simulated_actuator_and_buffer_states(lagged,
                                                                             lagged_trim):
    """The NumPy history recursion against the CasADi step, from rest on the first command."""
    dt = 0.01
    rng = np.random.default_rng(3)
    u = lagged_trim.u + rng.normal(0.0, [0.02, 0.05], (200, 2))
    structure = structure_of(lagged)
    z0 = np.concatenate([lagged_trim.x,
                         augment_states(structure, lagged_trim.x[None], u[:1], lagged.p,
                                        dt)[0, 4:]])
    z = simulate(physics_step(lagged), z0, u, lagged.p, dt)
    rebuilt = augment_states(structure, z[:-1, :4], u, lagged.p, dt)
    np.testing.assert_allclose(rebuilt, z[:-1], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(rebuilt[:, 6:], z[:-1, 6:])  # buffers: copies, exact


# ------------------------------------------------------------------ presets unchanged


@pytest.mark.parametrize("name, point_name, zeros", [
    ("aerosonde", "aerosonde_trim", {"tau_elevator": 0.0, "tau_throttle": 0.0}),
    ("f450", "f450_hover", {"tau_rotor": 0.0, "k_inflow": 0.0}),
])
def test_presets_unchanged_with_the_new_keys_absent_or_zero(name, point_name, zeros, request):
    af, point = request.getfixturevalue(name), request.getfixturevalue(point_name)
    controls = [n for n in structure_of(af).control_names]
    explicit = af.replace(**zeros).with_delays(**{c: 0 for c in controls})
    assert not structure_of(explicit).augmented
    plain = rk4_step(build_model(af.kind).f)  # the kind's generic model, alpha-dot terms in
    rng = np.random.default_rng(0)
    for airframe in (af, explicit):
        step = physics_step(airframe)
        assert step.nx == 4 and step.state_names == ("u", "w", "q", "theta")
        for _ in range(5):
            x = point.x + rng.normal(0.0, 0.3, 4)
            u = point.u + rng.normal(0.0, 0.02, 2)
            a = np.array(step(x, u, airframe.p, 0.01)).ravel()
            b = np.array(plain(x, u, airframe.p, 0.01)).ravel()
            np.testing.assert_allclose(a, b, rtol=1e-15, atol=0)
        again = trim(airframe, point.airspeed, point.gamma)
        np.testing.assert_array_equal(again.x, point.x)
        np.testing.assert_array_equal(again.u, point.u)
        np.testing.assert_array_equal(trim_state(airframe, point), point.x)
        A, B = linearise(airframe, point)
        A0, B0 = (np.array(m) for m in build_model(af.kind).jacobians(point.x, point.u,
                                                                      af.p)[:2])
        np.testing.assert_allclose(A, A0, rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(B, B0, rtol=1e-14, atol=1e-14)
        comp = discrete_map_modes(physics_step(airframe), point, 0.01)
        ref = discrete_map_modes(body_model(plain, af.kind), point, 0.01, airframe=af)
        np.testing.assert_allclose(comp.map_eigenvalues, ref.map_eigenvalues, atol=1e-14)
        assert [m.name for m in comp.physics_modes] == [m.name for m in ref.physics_modes]


# ------------------------------------------------------------------ trim, modes, maps


@pytest.mark.parametrize("case", ["fixed_wing", "multirotor"])
def test_trim_state_is_a_fixed_point_of_the_step(case, lagged, lagged_trim, f450, f450_hover):
    if case == "fixed_wing":
        af, point = lagged.with_delays(throttle=1), lagged_trim
    else:
        af = f450.replace(tau_rotor=0.06).with_delays(pitch_cmd=2)
        point = trim(af, 5.0)
    z = trim_state(af, point)
    assert z.shape == (structure_of(af).nx(),)
    for dt in (0.002, 0.02):
        z_next = np.array(physics_step(af)(z, point.u, af.p, dt)).ravel()
        assert np.abs(z_next - z).max() <= 1e-12
    zp = trim_state(af, point, with_position=True)
    rates = np.array(physics_step(af, with_position=True)(zp, point.u, af.p, 0.01)).ravel() - zp
    assert np.abs(np.delete(rates, [4, 5])).max() <= 1e-12  # x_n, h move at the trim speed
    assert math.isclose(rates[4] / 0.01, point.airspeed * math.cos(point.gamma), rel_tol=1e-9)


def test_continuous_modes_contain_the_actuator_poles(lagged, lagged_trim, aerosonde,
                                                     aerosonde_trim):
    A, B = linearise(lagged, lagged_trim)
    assert A.shape == (6, 6) and B.shape == (6, 2)
    eig = np.linalg.eigvals(A)
    for tau in (TAU_E, TAU_T):
        assert np.min(np.abs(eig + 1 / tau)) < 1e-12 / tau
    # the body's own poles are those of the airframe without lags
    body = np.linalg.eigvals(linearise(aerosonde, aerosonde_trim)[0])
    for lam in body:
        assert np.min(np.abs(eig - lam)) < 1e-10
    names = {m.name for m in modes(A, lagged.kind, B, linear_state_names(lagged))}
    assert {"short period", "phugoid", "elevator actuator lag",
            "throttle actuator lag"} <= names
    # A, B are the continuous model of the step: exp of the Van Loan block matrix is the
    # Jacobian of the step at a small dt (its RK4 truncation is O((lambda dt)^5))
    dt = 1e-3
    no_delay = lagged.with_delays(elevator=0)
    step = physics_step(no_delay)
    z, u = ca.SX.sym("z", 6), ca.SX.sym("u", 2)
    out = step(z, u, lagged.p, dt)
    jac = ca.Function("j", [z, u], [ca.jacobian(out, z), ca.jacobian(out, u)])
    F, G = (np.array(m) for m in jac(trim_state(no_delay, lagged_trim), lagged_trim.u))
    M = scipy.linalg.expm(np.block([[A, B], [np.zeros((2, 8))]]) * dt)
    np.testing.assert_allclose(F, M[:6, :6], rtol=0, atol=1e-9)
    np.testing.assert_allclose(G, M[:6, 6:], rtol=0, atol=1e-9)


def test_discrete_map_has_the_lag_and_delay_eigenvalues(lagged, lagged_trim):
    af = lagged.with_delays(throttle=1)  # three buffer states
    dt = 0.004
    comp = discrete_map_modes(physics_step(af), lagged_trim, dt)
    lam = comp.map_eigenvalues
    assert len(lam) == structure_of(af).nx() == 9
    for tau in (TAU_E, TAU_T):
        assert np.min(np.abs(lam - math.exp(-dt / tau))) < 1e-12
    assert np.sum(np.abs(lam) < 1e-12) == 3
    assert np.sum(np.abs(comp.exact_eigenvalues) == 0) == 3
    # the body and lag eigenvalues are exp(A dt)'s to RK4 truncation
    assert np.abs(lam - comp.exact_eigenvalues).max() < 1e-8
    assert comp.made_unstable == []
    assert {"elevator actuator lag", "throttle actuator lag"} <= {m.name for m in comp.map_modes}
    with pytest.raises(ValueError, match="has 7 physics states"):
        discrete_map_modes(physics_step(lagged.with_delays(elevator=1)), lagged_trim, dt,
                           airframe=af)


# ------------------------------------------------------------------ tables and ISA


def _with(airframe, tables=None, atmosphere=None):
    changes = {}
    if tables is not None:
        changes["tables"] = parse_tables(tables, airframe.kind, "test")
    if atmosphere is not None:
        changes["atmosphere"] = atmosphere
    return dataclasses.replace(airframe, **changes)


def test_stall_speed_and_trim_use_the_lift_table(aerosonde):
    """A triangular C_L table peaking at 0.3 rad: the static lift maximum is at its kink, and
    there the CasADi forces hold the weight at the stall speed."""
    af = _with(aerosonde, {"C_L": {"alpha": [-0.2, 0.3, 0.6], "values": [-0.6, 1.2, 0.7]}})
    v_stall, alpha_max, cl_max = stall_speed(af)
    assert alpha_max == pytest.approx(0.3, abs=1e-12)
    assert v_stall != pytest.approx(stall_speed(aerosonde)[0], rel=1e-3)
    forces = build_model(af).forces
    x = [v_stall * math.cos(alpha_max), v_stall * math.sin(alpha_max), 0.0, 0.0]
    X, Z, _, _, _, T = (float(v) for v in forces(x, [0.0, 0.0], af.p))
    lift = (X - T) * math.sin(alpha_max) - Z * math.cos(alpha_max)
    P = af.params
    assert lift == pytest.approx(P.mass * P.gravity, rel=1e-12)
    point = trim(af, 25.0)
    xdot = np.array(build_model(af).f(point.x, point.u, af.p)).ravel()
    assert np.abs(xdot).max() < 1e-9
    assert abs(point.alpha - trim(aerosonde, 25.0).alpha) > 1e-3  # the table is really used


def test_stall_speed_over_a_lift_table_in_airspeed_is_its_fixed_point(aerosonde):
    """A C_L table whose maximum falls with airspeed: the stall speed is the speed at which
    the maximum at that very speed holds the weight (the fixed point, not the nominal speed's
    maximum)."""
    table = {"alpha": [-0.2, 0.3, 0.6], "airspeed": [5.0, 40.0],
             "values": [[-0.6, -0.6], [1.6, 0.8], [0.7, 0.5]]}
    af = _with(aerosonde, {"C_L": table})
    v_stall, alpha_max, cl_max = stall_speed(af)
    assert alpha_max == pytest.approx(0.3, abs=1e-12)
    alphas = np.linspace(0.0, 1.2, 2001)
    at_stall = static_lift_coefficient(af, alphas, v_stall).max()  # the curve at that speed
    assert cl_max == pytest.approx(at_stall, rel=1e-12)
    P = af.params
    assert v_stall == pytest.approx(math.sqrt(2 * P.mass * P.gravity / (P.rho * P.S_wing
                                                                         * at_stall)), rel=1e-12)
    at_nominal = static_lift_coefficient(af, alphas, af.nominal_airspeed).max()
    assert abs(cl_max - at_nominal) > 0.05  # the iteration moved away from the nominal speed


def test_isa_trim_is_the_trim_at_the_density_of_the_altitude(aerosonde):
    isa = _with(aerosonde, atmosphere="isa")
    h = 2000.0
    rho = aerosonde.params.rho * float(isa_density_ratio(h, NUMPY_OPS))
    thin = aerosonde.replace(rho=rho)
    a, b = trim(isa, 25.0, altitude_m=h), trim(thin, 25.0)
    assert a.altitude_m == h and a.as_dict()["altitude_m"] == h
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.u, b.u, rtol=0, atol=1e-12)
    for m, n in zip(linearise(isa, a), linearise(thin, b)):
        np.testing.assert_allclose(m, n, rtol=1e-10, atol=1e-12)
    ratio = stall_speed(isa, altitude_m=h)[0] / stall_speed(isa)[0]
    assert ratio == pytest.approx(math.sqrt(aerosonde.params.rho / rho), rel=1e-12)
    np.testing.assert_array_equal(trim(isa, 25.0).x, trim(aerosonde, 25.0).x)


# ------------------------------------------------------------------ evaluation


def _recorded(airframe, point, n: int, dt: float, seed: int = 1):
    rng = np.random.default_rng(seed)
    u = _doublet(point, n, dt) + rng.normal(0.0, [0.01, 0.02], (n, 2))
    u[0] = point.u  # recorded from trim: at rest on the first command
    z = simulate(physics_step(airframe), trim_state(airframe, point), u[:-1], airframe.p, dt)
    return np.arange(n) * dt, z[:, :4], u


def test_evaluation_restarts_from_the_recorded_command_history(lagged, lagged_trim):
    """On data the augmented step itself produced, every restart (one step, 1 s horizons,
    free run) is exact only if its actuator/buffer states come from the recorded commands."""
    dt = 0.01
    time, states, controls = _recorded(lagged, lagged_trim, 300, dt)
    solver = Solver("physics", physics_step(lagged), dt)
    res = evaluate_trajectory(solver, time, states, controls, lagged.p)
    for mode in ("one_step", "horizon_1s", "free_run"):
        pred, target = res[mode]
        assert pred.shape == target.shape and pred.shape[-1] == 4
        assert np.abs(pred - target).max() < 1e-10, mode
    # restarting with the actuators at rest on the current command instead is visibly wrong
    rest = np.array([np.array(physics_step(lagged)(
        trim_state(lagged, dataclasses.replace(lagged_trim, x=states[k], u=controls[k])),
        controls[k], lagged.p, dt)).ravel()[:4] for k in range(40, 60)])
    assert np.abs(rest - states[41:61]).max() > 1e-6
    with pytest.raises(TypeError, match="give a DiscreteModel"):  # a bare Function has no layout
        Solver("no layout", physics_step(lagged).function, dt)
    # delays count calls: at another step size the step is refused, every mode reported
    refused = evaluate_trajectory(Solver("fine", physics_step(lagged), dt / 2), time, states,
                                  controls, lagged.p)
    assert set(refused["refused"]) == {"one_step", "horizon_1s", "free_run"}
    assert "transport delays" in refused["refused"]["free_run"]


def test_fine_reference_of_a_lagged_airframe_is_the_continuous_model(lagged, lagged_trim,
                                                                     aerosonde, aerosonde_trim):
    dt = 0.01
    u = _doublet(lagged_trim, 101, dt)
    time = np.arange(101) * dt
    ref = fine_reference(lagged, time, lagged_trim.x, u, lagged.p)
    truth = _continuous_reference(lagged, lagged_trim.x, u[:-1], dt)
    assert ref.shape == (101, 4)
    assert np.abs(ref - truth).max() < 1e-9
    # an airframe without lags: the kind's reference, as before
    a = fine_reference(aerosonde, time, aerosonde_trim.x, u, aerosonde.p)
    b = fine_reference(aerosonde.kind, time, aerosonde_trim.x, u, aerosonde.p)
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-13)


def test_sortie_free_run_uses_the_sortie_altitude_and_the_augmented_state(lagged, lagged_trim):
    isa = _with(lagged, atmosphere="isa")
    dt = 0.01
    time, states, controls = _recorded(lagged, lagged_trim, 150, dt)
    sortie = Sortie(name="s", kind="fixed_wing", time=time, states=states, controls=controls,
                    meta={"manifest_entry": {"altitude_m": 1500.0}})
    step = physics_step(isa)
    got = sortie_free_run(step, sortie, isa, dt)
    p = isa.p
    i = isa.param_names.index("rho")
    p[i] *= float(isa_density_ratio(1500.0, NUMPY_OPS))
    z0 = trim_state(isa, lagged_trim)
    expected = free_run(step, z0, controls[:-1], p, dt)[:, :4]
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    sea = sortie_free_run(step, sortie, isa.p, dt)
    assert np.abs(sea - got).max() > 1e-4  # the altitude really changed the density
    np.testing.assert_allclose(sea, states, rtol=0, atol=1e-9)  # recorded at sea level


# ------------------------------------------------------------------ MPC


def test_mpc_closes_the_loop_with_lag_and_delay(aerosonde):
    af = aerosonde.replace(tau_elevator=0.08, tau_throttle=0.3).with_delays(elevator=1)
    point = trim(af, 25.0)
    dt = 0.05
    mpc = TrackingMPC(physics_step(af), point.u, MPCConfig(horizon=20, dt=dt))
    assert mpc.nx == 5 + 3
    plant = physics_plant(af, dt, substeps=5)
    z0 = trim_state(af, point, with_position=True)
    z0[5] = 100.0
    carried, flown = [], []

    def plant_step(z, u):
        if u is not None:
            carried.append(mpc.last_actuators.copy())  # what its last solve started from
            flown.append(z[6:].copy())  # the plant's actuator/buffer states at that time
        return plant(z, u)

    step = math.radians(5.0)
    result = fly_closed_loop(mpc, plant_step, z0, point.u, 80,
                             lambda t: point.x[3] + np.where(t >= 0.5, step, 0.0),
                             lambda t: np.full_like(t, 100.0), 25.0, weights=(100.0, 0.0, 1.0))
    assert result.success.all()
    np.testing.assert_allclose(np.array(carried), np.array(flown), rtol=0, atol=1e-12)
    err = np.abs(result.states[1:, 3] - result.theta_ref)
    assert err[result.time[1:] >= 3.0].max() < 0.05 * step
    assert result.states[:, 3].max() > point.x[3] + 0.9 * step
    assert np.all(np.abs(np.diff(result.controls[:, 0])) <= mpc.rates[0] * dt + 1e-9)
    with pytest.raises(ValueError, match="carries position states"):
        TrackingMPC(physics_step(af, with_position=True), point.u, MPCConfig(horizon=3, dt=dt))


# ------------------------------------------------------------------ C, NumPy, torch


@pytest.mark.skipif(find_compiler() is None, reason="no C compiler")
def test_compiled_augmented_step_equals_the_vm(lagged, lagged_trim):
    af = lagged.with_delays(throttle=2)
    step = physics_step(af, substeps=2)
    compiled = step.compiled().function
    assert compiled.is_a("External") and compile_function(step.function).is_a("External")
    rng = np.random.default_rng(5)
    z0 = trim_state(af, lagged_trim)
    for _ in range(10):
        z = z0 + rng.normal(0.0, 0.1, z0.size)
        u = lagged_trim.u + rng.normal(0.0, 0.03, 2)
        a = np.array(compiled(z, u, af.p, 0.01)).ravel()
        b = np.array(step(z, u, af.p, 0.01)).ravel()
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("with_position, substeps", [(False, 1), (True, 3)])
def test_numpy_and_torch_steps_equal_casadi(lagged, lagged_trim, with_position, substeps):
    torch = pytest.importorskip("torch")
    af = _with(lagged.with_delays(throttle=1),
               {"C_m": {"alpha": [-0.2, 0.0, 0.2, 0.4], "values": [0.2, 0.02, -0.2, -0.5]}},
               atmosphere="isa")
    structure = structure_of(af)
    step = physics_step(af, with_position=with_position, substeps=substeps)
    nz, B, dt = structure.nx(with_position), 6, 0.01
    rng = np.random.default_rng(7)
    z0 = trim_state(af, lagged_trim, with_position=with_position)
    if with_position:
        z0[5] = 800.0
    Z = z0[:, None] + rng.normal(0.0, 0.1, (nz, B))
    U = lagged_trim.u[:, None] + rng.normal(0.0, 0.03, (2, B))
    expected = np.column_stack([np.array(step(Z[:, k], U[:, k], af.p, dt)).ravel()
                                for k in range(B)])
    rhs_np = make_rhs(structure, with_position, NUMPY_OPS)
    got_np = augmented_rk_step(structure, rhs_np, Z, U, af.p, dt, ops=NUMPY_OPS,
                               with_position=with_position, substeps=substeps)
    np.testing.assert_allclose(got_np, expected, rtol=1e-12, atol=1e-12)
    ops = torch_ops()
    rhs_t = make_rhs(structure, with_position, ops)
    got_t = augmented_rk_step(structure, rhs_t, torch.as_tensor(Z), torch.as_tensor(U),
                              torch.as_tensor(af.p), dt, ops=ops, with_position=with_position,
                              substeps=substeps)
    np.testing.assert_allclose(got_t.numpy(), expected, rtol=1e-12, atol=1e-12)


def test_a_lag_about_to_be_fitted_at_zero_is_the_limit_of_a_fast_lag(aerosonde, aerosonde_trim):
    """``fitting`` keeps the actuator state at tau = 0: the step is finite there and equals its
    limit tau -> 0+ (no 0/0 at the first stage's time)."""
    step = physics_step(aerosonde, fitting=("tau_elevator",))
    assert step.nx == 5 and step.state_names[-1] == "elevator_actuator"
    z = np.append(aerosonde_trim.x, aerosonde_trim.u[0] - 0.02)
    u = aerosonde_trim.u + [0.03, 0.0]
    at_zero = np.array(step(z, u, aerosonde.p, 0.01)).ravel()
    fast = np.array(step(z, u, aerosonde.replace(tau_elevator=1e-9).p, 0.01)).ravel()
    assert np.all(np.isfinite(at_zero))
    assert at_zero[4] == u[0]  # the actuator reached its command
    np.testing.assert_allclose(at_zero, fast, rtol=0, atol=1e-12)
