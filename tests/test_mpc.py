"""The tracking MPC flies the emulator (the "real aircraft") through a pitch step and a climb;
a failed solve is never applied (the fallback is, and it is counted); the real-time iteration
converges to the full SQP's optimum and flies the same trajectory; its compiled QP Function is
built once and loaded from the cache on the next construction; predictions stay finite."""

import math
from dataclasses import replace

import casadi as ca
import numpy as np
import pytest

from uavdyn.emulation import Emulator
from uavdyn.integrate import body_model, rk4_step
from uavdyn.model import build_model
from uavdyn.mpc import (
    MPCConfig,
    RTIController,
    TrackingMPC,
    TrackingProblem,
    build_controller,
    emulator_plant,
    fly_closed_loop,
)


@pytest.fixture(scope="module")
def physics(aerosonde):
    return body_model(rk4_step(build_model(aerosonde).f), aerosonde.kind, aerosonde)


@pytest.fixture(scope="module")
def setup(aerosonde, aerosonde_trim, physics):
    emulator = Emulator(aerosonde)
    x0 = emulator.initial_state(aerosonde_trim.x, aerosonde_trim.u, 100.0)
    mpc = TrackingMPC(physics, aerosonde_trim.u,
                      MPCConfig(horizon=20, dt=0.05))
    return mpc, emulator_plant(emulator, 0.05), x0


def _rti(step, af, trim, horizon, **kw):
    cfg = MPCConfig(horizon=horizon, dt=0.05, mode="rti", compile=kw.pop("compile", False),
                    **kw)
    return RTIController(TrackingProblem(step, trim.u, cfg))


def test_pitch_step_settles_on_the_emulator(setup, aerosonde_trim):
    mpc, plant, x0 = setup
    step = math.radians(5.0)

    def theta_ref(t):
        return aerosonde_trim.x[3] + np.where(t >= 0.5, step, 0.0)

    result = fly_closed_loop(mpc, plant, x0, aerosonde_trim.u, 80, theta_ref,
                             lambda t: np.full_like(t, 100.0), 25.0, weights=(100.0, 0.0, 1.0))
    assert result.success.all() and result.counts()["solved"] == 80
    err = np.abs(result.states[1:, 3] - result.theta_ref)
    assert err[result.time[1:] >= 3.0].max() < math.radians(0.2)  # settled within 0.2 deg
    assert result.states[:, 3].max() > aerosonde_trim.x[3] + 0.9 * step  # and it did move
    # control bounds and rate bounds hold
    assert np.all(np.abs(np.diff(result.controls[:, 0])) <= mpc.rates[0] * 0.05 + 1e-9)
    assert np.all(result.controls[:, 1] <= 1 + 1e-9) and np.all(result.controls[:, 1] >= -1e-9)


def test_climb_tracks_altitude_ramp(setup, aerosonde_trim):
    mpc, plant, x0 = setup

    def h_ref(t):
        return 100.0 + 2.0 * np.clip(t - 0.5, 0.0, None)

    result = fly_closed_loop(mpc, plant, x0, aerosonde_trim.u, 100, lambda t: 0 * t + 0.05,
                             h_ref, 25.0, weights=(1.0, 1.0, 1.0))
    assert result.success.all()
    assert result.states[-1, 4] > 108.0  # climbed (ramp reaches 109 m at t = 5 s)
    assert result.rmse("h", t_from=2.0) < 0.5


def test_bad_configuration(aerosonde, aerosonde_trim, physics):
    with pytest.raises(ValueError, match="horizon must be >= 1"):
        TrackingMPC(physics, aerosonde_trim.u,
                    MPCConfig(horizon=0))
    with pytest.raises(ValueError, match="solver must be 'sqp' or 'ipopt'"):
        TrackingMPC(physics, aerosonde_trim.u,
                    MPCConfig(solver="x"))
    with pytest.raises(ValueError, match="mode must be one of"):
        TrackingMPC(physics, aerosonde_trim.u,
                    MPCConfig(mode="fast"))
    with pytest.raises(ValueError, match="qp_solver must be one of"):
        _rti(physics, aerosonde, aerosonde_trim, 3, qp_solver="nope")
    from uavdyn.integrate import compile_function
    with pytest.raises(ValueError, match="uncompiled SX Function"):
        TrackingMPC(physics.with_function(compile_function(physics.function)), aerosonde_trim.u)
    mpc = TrackingMPC(physics, aerosonde_trim.u,
                      MPCConfig(horizon=3))
    with pytest.raises(ValueError, match=r"x0 must be \[u, w, q, theta, h\]"):
        mpc.solve(aerosonde_trim.x, aerosonde_trim.u, 0.0, 100.0, 25.0)


@pytest.mark.parametrize("mode", ["sqp", "rti"])
def test_a_forced_solver_failure_is_never_applied(aerosonde, aerosonde_trim, physics, mode):
    """An infeasible QP (the previous command far beyond the elevator travel, so no rate-limited
    move reaches the travel) fails the solver. The failed plan is not applied: the previous
    successful plan's next control is (counted as shifted), and once that plan is used up the
    last command is held (counted as held)."""
    N = 3
    if mode == "sqp":
        mpc = TrackingMPC(physics, aerosonde_trim.u,
                          MPCConfig(horizon=N, max_iter=10))
    else:
        mpc = _rti(physics, aerosonde, aerosonde_trim, N)
    x0 = np.append(aerosonde_trim.x, 100.0)
    theta_up = aerosonde_trim.x[3] + 0.05
    good = mpc.solve(x0, aerosonde_trim.u, theta_up, 100.0, 25.0)
    assert good.success and good.source == "solved"
    np.testing.assert_array_equal(good.u, good.predicted_controls[:, 0])
    plan = good.predicted_controls.copy()
    impossible = np.array([1.5, aerosonde_trim.u[1]])  # elevator 1.5 rad, travel +-0.52 rad
    applied = []
    for _ in range(N):
        res = mpc.solve(x0, impossible, theta_up, 100.0, 25.0)
        assert not res.success
        applied.append((res.source, res.u))
        if res.predicted_controls is not None:  # whatever the solver returned is not applied
            assert not np.array_equal(res.u, res.predicted_controls[:, 0]) or \
                res.source != "solved"
    assert [s for s, _ in applied] == ["shifted", "shifted", "held"]
    np.testing.assert_array_equal(applied[0][1], plan[:, 1])
    np.testing.assert_array_equal(applied[1][1], plan[:, 2])
    np.testing.assert_array_equal(applied[2][1], impossible)  # held: the last command
    assert mpc.counts == {"solved": 1, "shifted": 2, "held": 1}
    # after a failure the next solve starts again from a feasible command and succeeds
    again = mpc.solve(x0, aerosonde_trim.u, theta_up, 100.0, 25.0)
    assert again.success and again.source == "solved"


def test_a_diverged_prediction_is_a_failed_solve_and_never_applied(aerosonde, aerosonde_trim):
    """A prediction model that returns NaN makes every solve fail; with no plan to fall back
    on, the closed loop holds the last applied control."""
    x, u, p, dt = (ca.SX.sym("x", 4), ca.SX.sym("u", 2), ca.SX.sym("p", len(aerosonde.p)),
                   ca.SX.sym("dt"))
    broken = ca.Function("broken", [x, u, p, dt], [x + np.nan * (u[0] + 1.0)],
                         ["x", "u", "p", "dt"], ["x_next"])
    broken = body_model(broken, aerosonde.kind, aerosonde)
    x0 = np.append(aerosonde_trim.x, 100.0)
    u0 = aerosonde_trim.u + [0.01, 0.0]
    for mpc in (TrackingMPC(broken, aerosonde_trim.u,
                            MPCConfig(horizon=5, dt=0.05, max_iter=3)),
                _rti(broken, aerosonde, aerosonde_trim, 5)):
        res = mpc.solve(x0, aerosonde_trim.u, aerosonde_trim.x[3], 100.0, 25.0)
        assert not res.success and res.source == "held"
        result = fly_closed_loop(mpc, lambda xp, uu: (x0, x0), x0, u0, 4,
                                 lambda t: 0 * t + aerosonde_trim.x[3],
                                 lambda t: 0 * t + 100.0, 25.0)
        assert not result.success.any() and result.counts()["held"] == 4
        np.testing.assert_array_equal(result.controls, np.tile(u0, (4, 1)))


def test_rti_converges_to_the_full_sqp(aerosonde, aerosonde_trim, physics):
    """Unshifted real-time iterations at one state (Gauss-Newton SQP, full steps) reach the
    nlpsol SQP's optimum: plans agree to 1e-6 (elevator rad, throttle), slacks included in the
    cost; the line-searched Gauss-Newton SQP of mode "sqp" to 1e-5."""
    N = 10
    cfg = MPCConfig(horizon=N, dt=0.05)
    sqp = TrackingMPC(physics, aerosonde_trim.u, cfg)
    rti = _rti(physics, aerosonde, aerosonde_trim, N)
    x0 = np.array([aerosonde_trim.x[0] - 1.0, aerosonde_trim.x[1], 0.1,
                   aerosonde_trim.x[3] - 0.05, 100.0])
    args = (x0, aerosonde_trim.u, aerosonde_trim.x[3] + math.radians(8.0), 101.0, 25.0,
            (100.0, 1.0, 1.0))
    a = sqp.solve(*args)
    b = rti.iterate(*args, iterations=30, tol=1e-12)
    assert a.success and b.success
    np.testing.assert_allclose(b.predicted_controls, a.predicted_controls, rtol=0, atol=1e-6)
    # the Gauss-Newton SQP with line search (mode "sqp") reaches it from a cold start too
    gn = build_controller(physics, aerosonde_trim.u,
                          MPCConfig(horizon=N, dt=0.05, mode="sqp", compile=False,
                                    sqp_tol=1e-9))
    c = gn.solve(*args)
    assert c.success and c.iterations > 1
    # it stops on a predicted relative decrease below 1e-10: the last throttle, which acts on
    # the final state only, is then within 2e-6 of the optimum
    np.testing.assert_allclose(c.predicted_controls, a.predicted_controls, rtol=0, atol=1e-5)


def test_sqp_at_its_iteration_limit_applies_only_a_plan_that_lowered_the_merit(
        aerosonde, aerosonde_trim, physics):
    """Stopped at the iteration limit, the full SQP applies the last plan it linearised about
    when the line search lowered the exact-penalty merit below the warm start's (checked here
    on the merit Function itself), and the plan keeps the hard control bounds; with one
    iteration there is no such plan and the solve fails, its control never applied."""
    from uavdyn.mpc.rti import ITERATION_LIMIT
    N = 10
    x0 = np.array([aerosonde_trim.x[0] - 1.0, aerosonde_trim.x[1], 0.1,
                   aerosonde_trim.x[3] - 0.05, 100.0])
    args = (x0, aerosonde_trim.u, aerosonde_trim.x[3] + math.radians(8.0), 101.0, 25.0,
            (100.0, 1.0, 1.0))
    cfg = MPCConfig(horizon=N, dt=0.05, mode="sqp", compile=False, sqp_tol=1e-12)
    limited = build_controller(physics, aerosonde_trim.u, replace(cfg, sqp_max_iter=3))
    warm = limited.warm_plan(aerosonde_trim.u)
    res = limited.solve(*args)
    assert res.success and res.status == ITERATION_LIMIT and res.iterations == 3
    assert res.source == "solved"
    refs = limited.references(*args[2:5])
    xa = (np.concatenate([x0, limited.actuator_states(aerosonde_trim.u)]) if limited.n_extra
          else x0)

    def merit(plan):
        return float(limited.merit(xa, plan, aerosonde_trim.u, refs, args[5]))

    m_warm, m_plan = merit(warm), merit(res.predicted_controls)
    assert m_plan < m_warm
    lo, hi = limited.bounds[:, :1], limited.bounds[:, 1:]
    assert np.all(res.predicted_controls >= lo - 1e-12)
    assert np.all(res.predicted_controls <= hi + 1e-12)
    # the converged SQP goes further down than the limited one stopped
    full = build_controller(physics, aerosonde_trim.u, cfg).solve(*args)
    assert full.success and full.status != ITERATION_LIMIT
    assert merit(full.predicted_controls) <= m_plan
    once = build_controller(physics, aerosonde_trim.u, replace(cfg, sqp_max_iter=1))
    failed = once.solve(*args)
    assert not failed.success and failed.status == "maximum iterations"
    assert failed.source == "held"


def test_rti_and_sqp_fly_the_same_trajectory(aerosonde, aerosonde_trim, physics):
    """In closed loop on the emulator one QP per step tracks like the converged SQPs (the
    nlpsol reference and the Gauss-Newton SQP): pitch histories within 2e-3 rad (0.11 deg) of
    each other over a +5 deg step."""
    emulator = Emulator(aerosonde)
    x0 = emulator.initial_state(aerosonde_trim.x, aerosonde_trim.u, 100.0)
    step = math.radians(5.0)

    def theta_ref(t):
        return aerosonde_trim.x[3] + np.where(t >= 0.5, step, 0.0)

    runs = []
    for mpc in (TrackingMPC(physics, aerosonde_trim.u,
                            MPCConfig(horizon=15)),
                _rti(physics, aerosonde, aerosonde_trim, 15),
                build_controller(physics, aerosonde_trim.u,
                                 MPCConfig(horizon=15, mode="sqp", compile=False))):
        runs.append(fly_closed_loop(mpc, emulator_plant(emulator, 0.05), x0, aerosonde_trim.u,
                                    50, theta_ref, lambda t: np.full_like(t, 100.0), 25.0,
                                    weights=(100.0, 0.0, 1.0)))
    sqp, rti, gn = runs
    assert sqp.success.all() and rti.success.all() and gn.success.all()
    for run in (rti, gn):
        assert np.abs(run.states[:, 3] - sqp.states[:, 3]).max() < 2e-3
        assert abs(run.rmse("theta", 0.5) - sqp.rmse("theta", 0.5)) < 1e-3


def test_compiled_qp_function_is_reused_on_a_second_construction(
        aerosonde, aerosonde_trim, physics, tmp_path, monkeypatch):
    """The first construction builds the QP Function's library into the cache; the second
    builds nothing and loads the same verified file (start-up times printed, not asserted)."""
    import time

    from uavdyn.integrate import codegen
    if codegen.find_compiler() is None:
        pytest.skip("no C compiler")
    monkeypatch.setenv(codegen.CACHE_ENV, str(tmp_path / "cache"))
    builds = []
    real_build = codegen._build

    def counting_build(*args, **kwargs):
        builds.append(args[3])  # the library path
        return real_build(*args, **kwargs)

    monkeypatch.setattr(codegen, "_build", counting_build)
    t0 = time.perf_counter()
    first = _rti(physics, aerosonde, aerosonde_trim, 3, compile=True)
    t1 = time.perf_counter()
    assert len(builds) == 1 and first.qp_data.is_a("External")
    lib = builds[0]
    stamp = (lib.stat().st_ino, lib.stat().st_mtime_ns)
    second = _rti(physics, aerosonde, aerosonde_trim, 3, compile=True)
    t2 = time.perf_counter()
    assert len(builds) == 1  # nothing rebuilt
    assert (lib.stat().st_ino, lib.stat().st_mtime_ns) == stamp
    print(f"start-up: first {t1 - t0:.2f} s (gcc build), second {t2 - t1:.3f} s (cache)")
    x0 = np.append(aerosonde_trim.x, 100.0)
    a = first.solve(x0, aerosonde_trim.u, aerosonde_trim.x[3] + 0.05, 100.0, 25.0)
    b = second.solve(x0, aerosonde_trim.u, aerosonde_trim.x[3] + 0.05, 100.0, 25.0)
    assert a.success and b.success
    np.testing.assert_array_equal(a.predicted_controls, b.predicted_controls)


def test_predictions_are_finite_everywhere_and_exact_in_the_envelope(aerosonde, aerosonde_trim,
                                                                     physics):
    """The airspeed floor keeps the fixed-wing prediction finite at zero or negative forward
    speed (where the aerodynamics divide by the airspeed) and leaves it exact above the floor;
    a start beyond a soft state bound still gives a feasible QP (positive slack)."""
    mpc = _rti(physics, aerosonde, aerosonde_trim, 5)
    stage = mpc.problem.stage
    for u_body in (-5.0, 0.0, 1e-9, 3.0):
        x = np.array([u_body, 0.0, 0.0, 0.0, 100.0])
        assert np.all(np.isfinite(np.array(stage(x, aerosonde_trim.u))))
    x = np.append(aerosonde_trim.x, 100.0)
    raw = np.array(physics(aerosonde_trim.x, aerosonde_trim.u, aerosonde.p, 0.05)).ravel()
    np.testing.assert_allclose(np.array(stage(x, aerosonde_trim.u)).ravel()[:4], raw,
                               rtol=0, atol=1e-12)
    steep = np.array([aerosonde_trim.x[0], aerosonde_trim.x[1], 0.0, math.radians(40.0),
                      100.0])  # beyond the +-30 deg soft pitch bound
    res = mpc.solve(steep, aerosonde_trim.u, math.radians(40.0), 100.0, 25.0)
    assert res.success and np.all(np.isfinite(res.u))


def test_hybrid_prediction_model_solves(aerosonde_trim):
    """The shipped safe correction on its augmented state (the identified airframe's actuator
    lags, or a command memory; carried by the controller) inside the real-time iteration: every
    solve succeeds, the pitch settles on the emulator, and the carried states are the exact
    first-order filters of the commands applied."""
    from uavdyn.mpc.study import prediction_models

    setup = prediction_models("aerosonde", mode="rti", models=("hybrid",))
    model = setup.models["hybrid"]
    P = model.airframe.params
    taus = [t for t in (P.tau_elevator, P.tau_throttle)] if P.tau_elevator > 0 else []
    memory_tau = model.model.layout.memory_tau
    assert len(taus) + len(memory_tau) > 0  # the step carries states besides the body
    n_carried = (len(taus) if taus else 0) + 2 * len(memory_tau)
    assert model.model.nx == 4 + n_carried
    mpc = model.controller(MPCConfig(horizon=10, dt=0.05, mode="rti", compile=False))
    assert mpc.nx == 5 + n_carried
    emulator = Emulator(setup.plant_airframe)
    pt = setup.plant_trim
    x0 = emulator.initial_state(pt.x, pt.u, 100.0)
    result = fly_closed_loop(mpc, emulator_plant(emulator, 0.05), x0, pt.u, 40,
                             lambda t: pt.x[3] + np.where(t >= 0.5, 0.05, 0.0),
                             lambda t: np.full_like(t, 100.0), 25.0, weights=(100.0, 0.0, 1.0))
    assert result.success.all()
    assert abs(result.states[-1, 3] - result.theta_ref[-1]) < math.radians(0.3)
    # the carried states: exact first-order filters of the commands applied, at rest on the
    # trim command (written out here: a <- u + (a - u) exp(-dt / tau) per control)
    applied = np.vstack([pt.u, result.controls])
    expected = []
    for tau_list in ([taus] if taus else []) + [[t, t] for t in memory_tau]:
        a = applied[0].copy()
        for u in applied[:-1]:
            a = u + (a - u) * np.exp(-0.05 / np.array(tau_list))
        expected.extend(a)
    np.testing.assert_allclose(mpc.last_actuators, expected, rtol=0, atol=1e-12)


def test_an_airframe_file_flies_its_physics_and_the_plant_can_differ(tmp_path):
    """An airframe file without weights used to be refused ('no shipped correction'); it now
    flies its physics alone, saying why there is no hybrid. A plant with +15 % C_m_alpha
    (the truth a model was identified from) tracks worse than the matched plant."""
    import json

    from uavdyn.airframes import load_airframe, to_toml_dict
    from uavdyn.mpc.study import fly_all, prediction_models

    doc = to_toml_dict(load_airframe("aerosonde"))
    doc["name"] = "mine"
    mine = tmp_path / "mine.json"
    mine.write_text(json.dumps(doc))
    doc["params"]["C_m_alpha"]["value"] *= 1.15
    doc["name"] = "truth"
    truth = tmp_path / "truth.json"
    truth.write_text(json.dumps(doc))
    setup = prediction_models(str(mine))
    assert list(setup.models) == ["physics"] and "give --weights" in setup.missing["hybrid"]
    errors = {}
    for plant in (None, str(truth)):
        setup = prediction_models(str(mine), models=("physics",), plant=plant)
        runs = fly_all(setup, MPCConfig(horizon=20, mode="rti"), scenarios=("pitch-step",))
        result = runs[("pitch-step", "physics")][1]
        assert result.success.all()
        errors[setup.plant_airframe.name] = result.rmse("theta", 1.0)
    assert errors["truth"] > 2 * errors["mine"], errors


def test_a_plant_leaving_the_physical_ranges_ends_the_flight_flagged(f450):
    """A quadrotor held at a constant pitch command tumbles: the flight stops at the first
    sample outside the loader's physical ranges, says when and which state, and the flight
    up to then is kept (a tumbling plant is never reported as a finite tracking error)."""
    from uavdyn.linear import trim, trim_state
    from uavdyn.model import first_departure
    from uavdyn.mpc import physics_plant
    from uavdyn.mpc.policy import MPCResult
    from uavdyn.mpc.study import lost_control

    point = trim(f450)
    command = np.array([point.u[0], 0.3])

    class ConstantCommand:  # a controller that ignores the plant: open loop
        config = MPCConfig(horizon=5, dt=0.05)
        kind = "multirotor"

        def reset(self):
            pass

        def solve(self, *args):
            return MPCResult(command, "solved", True, 0.0, 1, "ok", None, None)

    x0 = trim_state(f450, point, with_position=True)
    res = fly_closed_loop(ConstantCommand(), physics_plant(f450, 0.05), x0, point.u, 400,
                          lambda t: 0 * t, lambda t: 0 * t + 100.0, 0.0)
    assert res.departure is not None and "departed at t = " in res.departure
    left = first_departure(res.states[:, :4], "multirotor")
    assert left is not None and left.index == len(res.states) - 1  # stopped at the first
    assert f"t = {res.time[-1]:.3f} s" in res.departure and left.state in res.departure
    assert len(res.controls) == len(res.states) - 1 == len(res.theta_ref) < 400
    assert lost_control(res)
