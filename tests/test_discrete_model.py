"""The discrete model object: what it says about its state matches what its Function does,
it starts from logged data by the exact lag formula, its Jacobians are the finite differences
of its step, and the same object goes into free runs, the MPC, Monte Carlo and the C bundle."""

import math
import warnings

import numpy as np
import pytest

import uavdyn
from uavdyn.deploy import export_bundle, model_bundle_spec
from uavdyn.evaluation import Solver
from uavdyn.integrate import DiscreteModel, StepUseError, StepUseWarning, find_compiler
from uavdyn.learned import load_weights, shipped_correction, shipped_identified
from uavdyn.montecarlo import MonteCarloError, build_spec, load_dispersions, run_study
from uavdyn.mpc import MPCConfig, build_controller

DT = 0.01


@pytest.fixture(scope="module")
def identified():
    return shipped_identified("aerosonde")


@pytest.fixture(scope="module")
def safe():
    weights, airframe = shipped_correction("aerosonde")
    return uavdyn.hybrid_step(weights, airframe, compile=False), load_weights(weights, airframe)


def test_physics_step_of_a_lagged_airframe_names_its_actuator_states(identified):
    """The shipped identified Aerosonde has an elevator and a throttle lag: the model carries
    both, after the body states, and its Function has exactly that many states."""
    assert identified.params.tau_elevator > 0 and identified.params.tau_throttle > 0
    model = uavdyn.physics_step(identified)
    assert isinstance(model, DiscreteModel)
    assert model.state_names == ("u", "w", "q", "theta", "elevator_actuator",
                                 "throttle_actuator")
    assert model.function.size1_in(0) == model.nx == 6 and model.dt is None
    assert model.control_names == ("elevator", "throttle")
    assert model.param_names == identified.param_names and model.function.size1_in(2) == len(
        identified.p)
    np.testing.assert_array_equal(model.p, identified.p)


def test_hybrid_step_names_body_actuator_and_memory_states_in_order(safe):
    model, net = safe
    n_memory = 2 * len(net.memory_tau)
    assert model.state_names[:6] == ("u", "w", "q", "theta", "elevator_actuator",
                                     "throttle_actuator")
    assert model.state_names[6:] == tuple(f"{c}_memory_{tau:g}s" for tau in net.memory_tau
                                          for c in ("elevator", "throttle"))
    assert model.nx == model.function.size1_in(0) == 6 + n_memory
    assert not model.takes_time and model.t_range is None


def test_initial_state_follows_the_exact_first_order_lag(identified):
    """From a logged command history the actuator states are the exact solution of
    tau a' = u - a with u held over each sample (written out here), at rest on the first."""
    model = uavdyn.physics_step(identified)
    rng = np.random.default_rng(3)
    n = 200
    body = rng.normal(size=(n, 4))
    controls = np.column_stack([rng.normal(0.0, 0.05, n), rng.uniform(0.3, 0.8, n)])
    z = model.initial_state(body, controls, identified.p, DT)
    assert z.shape == (n, 6)
    np.testing.assert_array_equal(z[:, :4], body)
    taus = np.array([identified.params.tau_elevator, identified.params.tau_throttle])
    a = controls[0].copy()
    for k in range(n):
        np.testing.assert_allclose(z[k, 4:], a, rtol=0, atol=1e-14)
        a = controls[k] + (a - controls[k]) * np.exp(-DT / taus)
    # one sample: at rest on its command
    np.testing.assert_array_equal(model.initial_state(body[0], controls[0]),
                                  np.concatenate([body[0], controls[0]]))
    with pytest.raises(ValueError, match="give the commands"):
        model.initial_state(body[0])
    with pytest.raises(ValueError, match="4 body states"):
        model.initial_state(np.zeros(6), controls[0])


def test_jacobians_are_the_finite_differences_of_the_step(safe):
    model, _ = safe
    af = model.airframe
    point = uavdyn.trim(af, 25.0)
    z = model.initial_state(point.x, point.u) + 1e-3
    u = np.asarray(point.u) + [0.01, 0.02]
    x_next, A, B = (np.array(v) for v in model.jacobians()(z, u, af.p, DT))
    np.testing.assert_allclose(x_next.ravel(), np.array(model(z, u, af.p, DT)).ravel(),
                               rtol=0, atol=0)
    h = 1e-6
    for j in range(model.nx):
        e = np.zeros(model.nx)
        e[j] = h
        fd = (np.array(model(z + e, u, af.p, DT)) - np.array(model(z - e, u, af.p, DT))) / (2 * h)
        np.testing.assert_allclose(A[:, j], fd.ravel(), rtol=1e-6, atol=1e-7)
    for j in range(2):
        e = np.zeros(2)
        e[j] = h
        fd = (np.array(model(z, u + e, af.p, DT)) - np.array(model(z, u - e, af.p, DT))) / (2 * h)
        np.testing.assert_allclose(B[:, j], fd.ravel(), rtol=1e-6, atol=1e-7)


@pytest.mark.skipif(find_compiler() is None, reason="no C compiler")
def test_compiled_twin_agrees_with_the_vm(safe):
    model, _ = safe
    compiled = model.compiled()
    assert compiled.function.is_a("External") and compiled.state_names == model.state_names
    assert model.compiled() is compiled  # built once
    af = model.airframe
    point = uavdyn.trim(af, 25.0)
    rng = np.random.default_rng(0)
    for _ in range(5):
        z = model.initial_state(point.x, point.u) + rng.normal(0.0, 0.05, model.nx)
        np.testing.assert_allclose(np.array(compiled(z, point.u, af.p, DT)),
                                   np.array(model(z, point.u, af.p, DT)), rtol=0, atol=1e-12)


def test_a_step_size_policy_is_enforced_by_every_rollout(identified):
    tied = uavdyn.physics_step(identified, dt=0.01)
    point = uavdyn.trim(identified, 25.0)
    z0 = tied.initial_state(point.x, point.u)
    controls = np.tile(point.u, (10, 1))
    with pytest.raises(StepUseError, match="step size 0.02 s but it is made for 0.01 s"):
        uavdyn.free_run(tied, z0, controls, identified.p, 0.02)
    lenient = uavdyn.physics_step(identified, dt=0.01)
    lenient = DiscreteModel(lenient.function, lenient.layout, dt=0.01, strict=False,
                            airframe=identified)
    with pytest.warns(StepUseWarning, match="made for 0.01 s"):
        uavdyn.free_run(lenient, z0, controls, identified.p, 0.02)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        uavdyn.free_run(tied, z0, controls, identified.p, 0.01)
    with pytest.raises(TypeError, match="give a DiscreteModel"):
        Solver("bare", tied.function, 0.01)
    with pytest.raises(ValueError, match="has 6 states but the layout names 4"):
        DiscreteModel(tied.function, uavdyn.physics_step(uavdyn.load_airframe("aerosonde"))
                      .layout)


@pytest.mark.parametrize("which", ["physics", "hybrid"])
def test_the_same_object_goes_into_free_run_mpc_monte_carlo_and_c(which, identified, safe,
                                                                  tmp_path):
    model = uavdyn.physics_step(identified) if which == "physics" else safe[0]
    af = model.airframe
    point = uavdyn.trim(af, 25.0)
    # free run from trim: the physics holds its trim; the correction (not zero at the
    # physics' trim) moves it a little, not away
    z0 = model.initial_state(point.x, point.u)
    traj = uavdyn.free_run(model, z0, np.tile(point.u, (100, 1)), af.p, DT)
    np.testing.assert_allclose(traj[-1, :4], point.x, atol=1e-6 if which == "physics" else 0.01)
    # MPC: one real-time iteration from a pitch offset
    mpc = build_controller(model, point.u, MPCConfig(horizon=10, dt=0.05, mode="rti",
                                                     compile=False))
    x0 = np.concatenate([point.x + [0.0, 0.0, 0.0, 0.02], [100.0]])
    result = mpc.solve(x0, point.u, point.x[3], 100.0, 25.0)
    assert result.success and mpc.nx == model.nx + 1
    # Monte Carlo: a short study flies the object itself
    disp = tmp_path / "d.toml"
    disp.write_text('[params.mass]\ndist = "uniform"\nlow = -0.1\nhigh = 0.1\n')
    study = run_study(build_spec(af, load_dispersions(disp, af), runs=4, duration=1.0,
                                 dt=DT, chunk_size=4, model=model), progress=False)
    assert np.all(np.isfinite(study.history)) and study.spec.given is model
    # C bundle: the spec is the model's own
    spec = model_bundle_spec("m", model, point, DT, example_steps=10)
    assert spec.state_names == model.state_names and len(spec.x0) == model.nx
    np.testing.assert_allclose(spec.x0, z0)
    folder = export_bundle(model, spec, tmp_path / "bundle")
    header = (folder / "m.h").read_text()
    assert f"x = [{', '.join(model.state_names)}]" in header


def test_monte_carlo_refuses_a_model_it_cannot_fly(identified, tmp_path):
    model = uavdyn.physics_step(identified)
    disp = tmp_path / "d.toml"
    disp.write_text('[params.mass]\ndist = "uniform"\nlow = -0.1\nhigh = 0.1\n')
    d = load_dispersions(disp, identified)
    with pytest.raises(MonteCarloError, match="is compiled"):
        build_spec(identified, d, runs=2, duration=1.0, model=model.compiled())
    quad = uavdyn.load_airframe("f450")
    with pytest.raises(MonteCarloError, match="is a fixed_wing step"):
        build_spec(quad, load_dispersions(disp, quad), runs=2, duration=1.0, model=model)
    with pytest.raises(MonteCarloError, match="either weights or model"):
        build_spec(identified, d, runs=2, duration=1.0, model=model, weights="shipped")
    assert math.isfinite(DT)


def test_a_departure_from_the_physical_ranges_is_never_silent(tmp_path, capsys):
    """A quadrotor pitch step tumbles open loop: the free run of the model stops with a
    DivergenceError naming the time and the state as soon as a body state leaves the ranges
    the dataset loader enforces (|theta| <= pi here), and uavdyn simulate exits 2 with that
    line instead of writing a CSV it could not load back."""
    from uavdyn.cli import main
    from uavdyn.integrate import DivergenceError, check_departure
    from uavdyn.model import state_limits

    af = uavdyn.load_airframe("f450")
    model = uavdyn.physics_step(af)
    point = uavdyn.trim(af, 0.0)
    controls = np.tile(point.u, (3000, 1))
    controls[:, 1] += 0.1
    with pytest.raises(DivergenceError, match=r"departed at t = .* theta = .* outside the "
                                              r"physical range") as err:
        uavdyn.free_run(model, point.x, controls, af.p, DT)
    loose = uavdyn.free_run(model, point.x, controls, af.p, DT, check=False)
    k = int(np.argmax(np.abs(loose[:, 3]) > np.pi))
    assert k > 0 and err.value.time == pytest.approx(k * DT)  # the first sample beyond pi
    # the check itself on a written-out trajectory: the first state beyond its limit
    traj = np.zeros((10, 4))
    traj[6, 2] = state_limits("fixed_wing")["q"] * 1.01
    traj[8, 0] = 200.0
    with pytest.raises(DivergenceError, match=r"t = 0.600 s \(sample 6\): q = "):
        check_departure(traj, np.arange(10) * 0.1, "fixed_wing")
    out = tmp_path / "tumble.csv"
    code = main(["simulate", "--airframe", "f450", "--input", "step", "--channel", "1",
                 "--amplitude", "0.1", "--duration", "30", "--out", str(out)])
    err_lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and not out.exists()
    assert len(err_lines) == 1 and "departed at t =" in err_lines[0] and "theta" in err_lines[0]


def test_evaluation_flags_a_free_run_that_leaves_the_physical_ranges(f450):
    """A quadrotor replayed open loop with a constant pitch command tumbles: evaluate's free
    run says when and which state left the ranges (flagged, not raised; the table counts it),
    while the short-horizon modes are still scored."""
    from uavdyn.evaluation import Solver, evaluate_trajectory
    from uavdyn.linear import trim
    from uavdyn.model import first_departure

    point = trim(f450)
    n = 1001
    time = 0.01 * np.arange(n)
    states = np.tile(point.x[:4], (n, 1))
    controls = np.tile([point.u[0], 0.3], (n, 1))
    res = evaluate_trajectory(Solver("f450", uavdyn.physics_step(f450), 0.01), time, states,
                              controls, f450.p)
    dep = res["free_run_departure"]
    pred = res["free_run"][0]
    left = first_departure(pred, "multirotor")
    assert left is not None and dep["state"] == left.state
    assert dep["time_s"] == pytest.approx(res["free_run_time"][left.index])
    assert 0.0 < dep["time_s"] < time[-1]
    assert "one_step" in res and "horizon_1s" in res
    from types import SimpleNamespace

    from uavdyn.experiments.report import table1_lines
    from uavdyn.experiments.tables import _accuracy_row

    cand = SimpleNamespace(label="f450 @ 0.01 s", solver=SimpleNamespace(dt=0.01),
                           physics="nominal")
    row = _accuracy_row(cand, {"hover_tilt": res})
    assert row["departed"] == {"hover_tilt": dep}
    text = "\n".join(table1_lines({"table1": {"flight data": {"sorties": ["hover_tilt"],
                                                                "rows": [row]}}}))
    assert f"free run of hover_tilt: departed at t = {dep['time_s']:.2f} s" in text


def test_step_rows_is_the_step_from_each_row_and_refuses_a_time_taking_formulation():
    """One mapped call over rows (the trainer example, non-preset) equals the step called row
    by row; a formulation that takes time has no single t for the rows and is refused."""
    trainer = uavdyn.load_airframe("examples/trainer.toml")
    model = uavdyn.physics_step(trainer)
    x0 = np.asarray(model.initial_state(np.array([[15.0, 1.0, 0.0, 0.05]]),
                                        np.array([[-0.05, 0.5]]), None, DT))[0]
    rng = np.random.default_rng(3)
    z = x0 + rng.normal(0.0, [0.5, 0.2, 0.1, 0.02] + [0.01] * (len(x0) - 4), (7, len(x0)))
    u = np.column_stack([rng.uniform(-0.1, 0.1, 7), rng.uniform(0.3, 0.8, 7)])
    rows = model.step_rows(z, u, model.p, DT)
    one_by_one = np.array([np.asarray(model(z[i], u[i], model.p, DT)).ravel()
                           for i in range(7)])
    assert rows.shape == z.shape
    np.testing.assert_allclose(rows, one_by_one, rtol=1e-12, atol=1e-14)
    from uavdyn.learned import shipped_weights
    paper = uavdyn.hybrid_step(shipped_weights("aerosonde", "paper"),
                               uavdyn.load_airframe("aerosonde"), compile=False)
    with pytest.raises(ValueError, match="takes time"):
        paper.step_rows(np.zeros((2, paper.nx)), np.zeros((2, paper.nu)), paper.p, 0.005)
