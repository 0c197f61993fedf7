"""The exported MPC: the dense QP solver against CasADi's QP solvers (random strictly convex QPs
with active bounds and general constraints, degenerate ones, the MPC's own QPs), and the C
bundle built with make from an empty folder, its example's closed loop equal to the Python
controller's to 1e-9."""

import ctypes
import json
import shutil
import subprocess
from importlib import resources

import casadi as ca
import numpy as np
import pytest

from uavdyn.deploy.mpc_bundle import (
    CSV_COLUMNS,
    example_closed_loop,
    export_mpc_bundle,
    python_closed_loop,
    rest_indices,
)
from uavdyn.mpc import MPCConfig, RTIController, TrackingProblem
from uavdyn.mpc.study import prediction_models

CC = shutil.which("cc") or shutil.which("gcc")
MAKE = shutil.which("make")
needs_cc = pytest.mark.skipif(CC is None, reason="no C compiler (cc/gcc): the C export "
                              "cannot be built here")
needs_make = pytest.mark.skipif(CC is None or MAKE is None,
                                reason="no C compiler or no make: the bundle cannot be built")


class _Solver(ctypes.Structure):
    _fields_ = [("n", ctypes.c_int), ("m", ctypes.c_int), ("w", ctypes.c_void_p),
                ("iw", ctypes.c_void_p), ("max_iter", ctypes.c_int), ("tol", ctypes.c_double),
                ("iterations", ctypes.c_int), ("n_active", ctypes.c_int)]


@pytest.fixture(scope="module")
def qp_dense(tmp_path_factory):
    """``solve(H, g, A, lba, uba, lbx, ubx) -> (status, z, cost)`` of csrc/qp_dense.c, built
    as a shared library."""
    if CC is None:
        pytest.skip("no C compiler (cc/gcc): the QP solver cannot be built here")
    folder = tmp_path_factory.mktemp("qp_dense")
    src = resources.files("uavdyn.deploy.csrc")
    for name in ("qp_dense.c", "qp_dense.h"):
        (folder / name).write_text(src.joinpath(name).read_text())
    lib_path = folder / "libqpd.so"
    subprocess.run([CC, "-std=c99", "-O2", "-fPIC", "-shared", "-Wall", "-Wextra", "-Werror",
                    str(folder / "qp_dense.c"), "-o", str(lib_path), "-lm"], check=True)
    lib = ctypes.CDLL(str(lib_path))
    dp = ctypes.POINTER(ctypes.c_double)

    def solve(H, g, A, lba, uba, lbx, ubx):
        n, m = len(g), len(lba)
        rw = np.zeros(3 * n * n + m + 10 * n + 8)
        iw = np.zeros(3 * n + m + 4, dtype=np.int32)
        s = _Solver()
        lib.qpd_init(ctypes.byref(s), n, m, rw.ctypes.data_as(dp),
                     iw.ctypes.data_as(ctypes.POINTER(ctypes.c_int)))
        arrays = [np.asfortranarray(a, dtype=float) for a in
                  (H, g, np.reshape(A, (m, n)), lba, uba, lbx, ubx)]
        z, cost = np.zeros(n), ctypes.c_double()
        status = lib.qpd_solve(ctypes.byref(s), *[a.ctypes.data_as(dp) for a in arrays],
                               z.ctypes.data_as(dp), ctypes.byref(cost))
        return status, z, cost.value

    return solve


def _casadi(solver, H, g, A, lba, uba, lbx, ubx):
    opts = {"error_on_fail": False} if solver == "daqp" else {"printLevel": "none",
                                                               "error_on_fail": False}
    qp = ca.conic("ref", solver, {"h": ca.DM(H).sparsity(), "a": ca.DM(A).sparsity()}, opts)
    sol = qp(h=H, g=g, a=A, lba=lba, uba=uba, lbx=lbx, ubx=ubx)
    return bool(qp.stats()["success"]), np.asarray(sol["x"]).ravel()


def _random_qp(rng, degenerate: bool):
    """A strictly convex QP with a feasible point, bounds and general constraints that bind;
    ``degenerate``: rows equal to unit vectors or to multiples of other rows, equalities."""
    n, m = int(rng.integers(2, 30)), int(rng.integers(1, 40))
    M = rng.normal(size=(n, n))
    H = M @ M.T + 0.1 * np.eye(n)
    g = rng.normal(size=n) * (20 if degenerate else 5)
    A = rng.normal(size=(m, n))
    x0 = rng.normal(size=n) * 0.1
    lbx, ubx = x0 - rng.uniform(0.0, 1, n), x0 + rng.uniform(0.0, 1, n)
    if degenerate:
        for r in range(m):
            if rng.random() < 0.3:
                A[r] = 0
                A[r, rng.integers(n)] = 1.0
            elif rng.random() < 0.2 and r > 0:
                A[r] = A[rng.integers(r)] * rng.choice([1, -2])
    else:
        lbx[rng.random(n) < 0.3], ubx[rng.random(n) < 0.3] = -np.inf, np.inf
    ax = A @ x0
    lba, uba = ax - rng.uniform(0.0, 0.5, m), ax + rng.uniform(0.0, 0.5, m)
    if degenerate:
        eq = rng.random(m) < 0.1
        lba[eq] = uba[eq] = ax[eq]
    else:
        lba[rng.random(m) < 0.3], uba[rng.random(m) < 0.3] = -np.inf, np.inf
    return H, g, A, lba, uba, lbx, ubx


def test_qp_solver_matches_daqp_on_random_qps(qp_dense):
    rng = np.random.default_rng(1)
    active = 0
    for _ in range(150):
        qp = _random_qp(rng, degenerate=False)
        status, z, _ = qp_dense(*qp)
        ok, ref = _casadi("daqp", *qp)
        assert ok and status == 0
        assert np.max(np.abs(z - ref)) < 1e-10
        active += int(np.any(np.isclose(z, qp[5]) | np.isclose(z, qp[6])))
    assert active > 50  # bounds do bind


def test_qp_solver_on_degenerate_qps(qp_dense):
    """Dependent active normals (a constraint equal to a bound, repeated rows, equalities):
    the solution of daqp where it succeeds, else of qpOASES."""
    rng = np.random.default_rng(2)
    for _ in range(150):
        qp = _random_qp(rng, degenerate=True)
        status, z, _ = qp_dense(*qp)
        assert status == 0
        ok, ref = _casadi("daqp", *qp)
        if not ok:
            ok, ref = _casadi("qpoases", *qp)
        assert ok
        assert np.max(np.abs(z - ref)) < 1e-9


def test_qp_solver_reports_infeasible_and_bad_data(qp_dense):
    box = (np.eye(2), np.zeros(2), np.array([[1.0, 1.0]]), np.array([3.0]), np.array([np.inf]),
           np.array([-1.0, -1.0]), np.array([1.0, 1.0]))
    assert qp_dense(*box)[0] == 2
    not_convex = (-np.eye(2),) + box[1:]
    assert qp_dense(*not_convex)[0] == 1
    nan = box[:1] + (np.array([np.nan, 0.0]),) + box[2:]
    assert qp_dense(*nan)[0] == 4


@pytest.fixture(scope="module")
def aerosonde_problem():
    """The Aerosonde hybrid (shipped correction, exact ReLU) at horizon 20 and its plant."""
    setup = prediction_models("aerosonde", mode="rti")
    model = setup.models["hybrid"]
    cfg = MPCConfig(horizon=20, mode="rti")
    problem = TrackingProblem(model.model, model.trim.u, cfg,
                              speed_trim=max(model.trim.airspeed, 1.0))
    return problem, example_closed_loop(setup.plant_airframe, cfg.dt)


class _Recorded:
    def __init__(self, function):
        self.function, self.calls = function, []

    def call(self, args):
        self.calls.append(list(args))
        return self.function.call(args)


def test_qp_solver_matches_daqp_on_the_mpc_qps(qp_dense, aerosonde_problem):
    problem, example = aerosonde_problem
    mpc = RTIController(problem)
    mpc._step = rec = _Recorded(mpc._step)
    python_closed_loop(problem, example, mpc)
    worst = 0.0
    for args in rec.calls:
        data = [np.array(ca.densify(o)) for o in mpc.qp_data.call(args)[:7]]
        H, g, A, lba, uba, lbx, ubx = (d if d.shape[1] > 1 else d.ravel() for d in data)
        status, z, _ = qp_dense(H, g, A, lba, uba, lbx, ubx)
        ref = np.asarray(mpc.qp(h=H, g=g, a=A, lba=lba, uba=uba, lbx=lbx, ubx=ubx)["x"]).ravel()
        assert status == 0
        worst = max(worst, float(np.max(np.abs(z - ref))))
    assert len(rec.calls) == example.steps
    assert worst < 1e-10


def _read_csv(text: str):
    lines = text.strip().splitlines()
    assert tuple(lines[0].split(",")) == CSV_COLUMNS
    rows = [line.split(",") for line in lines[1:]]
    states = np.array([[float(v) for v in r[1:6]] for r in rows])
    controls = np.array([[float(v) for v in r[6:8]] for r in rows[:-1]])
    return states, controls, [int(r[8]) for r in rows[:-1]]


@needs_make
def test_bundle_builds_from_an_empty_folder_and_flies_as_python(tmp_path, aerosonde_problem):
    problem, example = aerosonde_problem
    out = export_mpc_bundle(problem, example, tmp_path / "mpc")
    built = subprocess.run([MAKE, "-C", str(out), "example"], capture_output=True, text=True)
    assert built.returncode == 0, built.stderr[-2000:]
    assert "-Werror" in (out / "Makefile").read_text()
    text = subprocess.run([str(out / "example")], capture_output=True, text=True,
                          check=True).stdout
    states, controls, sources = _read_csv(text)
    res = python_closed_loop(problem, example)
    assert states.shape == res.states.shape and controls.shape == res.controls.shape
    assert np.max(np.abs(states - res.states)) < 1e-9
    assert np.max(np.abs(controls - res.controls)) < 1e-9
    assert sources == [0] * example.steps and res.counts()["solved"] == example.steps
    # the pitch step was flown: the pitch rose by about the 5 deg step
    assert np.degrees(states[-1, 3] - states[0, 3]) == pytest.approx(5.0, abs=1.0)
    generated = (out / "mpc_generated.c").read_text() + (out / "mpc_rti.c").read_text()
    assert "malloc" not in generated and "casadi.h" not in generated
    # the timing harness: wall and CPU time of the whole step and of its three phases
    subprocess.run([MAKE, "-C", str(out), "bench"], check=True, capture_output=True)
    timing = json.loads(subprocess.run([str(out / "bench"), "1"], capture_output=True,
                                       text=True, check=True).stdout)
    assert timing["solves"] == example.steps and timing["workspace_bytes"] > 0
    for phase in ("mpc_step", "linearisation", "condensing", "qp", "mpc_step_cpu"):
        assert 0 < timing[phase]["median_us"] <= timing[phase]["p99_us"] \
            <= timing[phase]["max_us"]


@needs_make
def test_float_bundle_builds_and_tracks(tmp_path, aerosonde_problem):
    problem, example = aerosonde_problem
    out = export_mpc_bundle(problem, example, tmp_path / "mpc_float", real="float")
    subprocess.run([MAKE, "-C", str(out), "example"], check=True, capture_output=True)
    text = subprocess.run([str(out / "example")], capture_output=True, text=True,
                          check=True).stdout
    states, _, sources = _read_csv(text)
    res = python_closed_loop(problem, example)
    assert sum(s == 0 for s in sources) >= 0.9 * example.steps
    assert np.max(np.abs(states[:, 3] - res.states[:, 3])) < 1e-3  # rad


def test_rest_state_is_a_selection_of_the_command(aerosonde_problem):
    problem, _ = aerosonde_problem
    idx = rest_indices(problem)
    u = np.array([0.1, 0.7])
    assert np.array_equal(problem.model.layout.rest(u), u[idx])


def test_bundle_refuses_a_plant_without_position(tmp_path, aerosonde_problem):
    from dataclasses import replace

    from uavdyn.integrate import physics_step

    problem, example = aerosonde_problem
    bad = replace(example, plant=physics_step(problem.model.airframe))
    with pytest.raises(ValueError, match="position"):
        export_mpc_bundle(problem, bad, tmp_path / "x")
    with pytest.raises(ValueError, match="real"):
        export_mpc_bundle(problem, example, tmp_path / "y", real="half")


def test_cli_exports_the_controller_and_refuses_model_options(tmp_path, capsys):
    from uavdyn.cli import main

    out = tmp_path / "cli_mpc"
    assert main(["export-c", "--mpc", "--model", "rk4", "--horizon", "8", "--out",
                 str(out)]) == 0
    said = capsys.readouterr().out
    assert "horizon 8 x 0.05 s" in said and "make -C" in said
    assert "#define MPC_N 8" in (out / "mpc_config.h").read_text()
    assert (out / "qp_dense.c").is_file() and (out / "main.c").is_file()
    assert main(["export-c", "--horizon", "8", "--out", str(tmp_path / "a")]) == 2
    assert main(["export-c", "--mpc", "--rollout", "5", "--out", str(tmp_path / "b")]) == 2
    assert "--horizon applies only with --mpc" in capsys.readouterr().err


@needs_make
@pytest.mark.slow
def test_scalar_condensing_bundle_flies_as_python(tmp_path, aerosonde_problem):
    """``condensing="sx"``: the condensing expanded to scalar code in its own file, built at
    -O1; the same closed loop to 1e-9."""
    problem, example = aerosonde_problem
    out = export_mpc_bundle(problem, example, tmp_path / "mpc_sx", condensing="sx")
    assert (out / "mpc_condense.c").is_file()
    assert "mpc_gen_cond(" not in (out / "mpc_generated.c").read_text()
    subprocess.run([MAKE, "-C", str(out), "example"], check=True, capture_output=True)
    text = subprocess.run([str(out / "example")], capture_output=True, text=True,
                          check=True).stdout
    states, controls, _ = _read_csv(text)
    res = python_closed_loop(problem, example)
    assert np.max(np.abs(states - res.states)) < 1e-9
    assert np.max(np.abs(controls - res.controls)) < 1e-9
    with pytest.raises(ValueError, match="condensing"):
        export_mpc_bundle(problem, example, tmp_path / "z", condensing="qr")


@needs_make
def test_prediction_without_carried_states_flies_as_python(tmp_path):
    """The nominal Aerosonde physics has no actuator lags: no carried states in C either."""
    from uavdyn.airframes import load_airframe
    from uavdyn.integrate import physics_step
    from uavdyn.linear import trim

    airframe = load_airframe("aerosonde")
    model, point = physics_step(airframe), trim(airframe)
    assert model.layout.n_extra == 0
    config = MPCConfig(horizon=10, mode="rti")
    problem = TrackingProblem(model, point.u, config, speed_trim=point.airspeed)
    example = example_closed_loop(airframe, config.dt)
    out = export_mpc_bundle(problem, example, tmp_path / "mpc")
    subprocess.run([MAKE, "-C", str(out), "example"], check=True, capture_output=True)
    states, controls, _ = _read_csv(subprocess.run([str(out / "example")], capture_output=True,
                                                   text=True, check=True).stdout)
    res = python_closed_loop(problem, example)
    assert np.max(np.abs(states - res.states)) < 1e-9
    assert np.max(np.abs(controls - res.controls)) < 1e-9
