"""The package's shape and its single sources of maths: no import cycle between or inside the
sub-packages, nothing imported from ``training``/``analysis``, no import-path tricks, no torch
or matplotlib on ``import uavdyn``; one RK routine that is the classical RK4; one MLP forward
and one formulation code that agree across CasADi, NumPy and torch; time as a named input."""

import ast
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
from test_correction import random_net

from uavdyn.integrate import (
    RK4,
    ButcherTableau,
    StepUseError,
    explicit_rk_step,
    free_run,
    rk4_step,
    takes_time,
)
from uavdyn.learned import FORMULATIONS, hybrid_step, shipped_correction, shipped_weights
from uavdyn.model import NUMPY_OPS, build_model, make_rhs

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "uavdyn"


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> set[str]:
    """Every module named by an import statement anywhere in the file (also in functions)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f"{node.module}.{a.name}" for a in node.names)
    return names


def _graph(level: int) -> dict[str, set[str]]:
    """Import graph of uavdyn at ``level`` name components (2: sub-packages, 3: modules)."""
    modules = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        src = ".".join(name.split(".")[:level])
        for imp in _imports(path):
            if not imp.startswith("uavdyn."):
                continue
            dst = ".".join(imp.split(".")[:level])
            if dst in modules or any(m.startswith(dst + ".") for m in modules):
                if dst != src and not src.startswith(dst + ".") and not dst.startswith(src + "."):
                    graph.setdefault(src, set()).add(dst)
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n):
        state[n] = 1
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in state:
                found = visit(m)
                if found:
                    return found
        state[n] = 2
        stack.pop()
        return None

    for n in sorted(graph):
        if n not in state:
            found = visit(n)
            if found:
                return found
    return None


def test_cycle_finder_finds_a_planted_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": {"c"}}) is None


@pytest.mark.parametrize("level", [2, 3])
def test_import_graph_has_no_cycle(level):
    graph = _graph(level)
    assert len(graph) >= (10 if level == 2 else 20)  # the graph really was built
    assert _cycle(graph) is None, f"import cycle: {' -> '.join(_cycle(graph))}"


def test_arrows_point_one_way_along_the_spec_chain():
    """model -> integrate -> learned -> evaluation -> experiments -> cli: nothing imports a
    later one."""
    chain = ["uavdyn.model", "uavdyn.integrate", "uavdyn.learned", "uavdyn.evaluation",
             "uavdyn.experiments", "uavdyn.cli"]
    graph = _graph(2)
    for i, pkg in enumerate(chain):
        later = set(chain[i + 1:])
        assert not (graph.get(pkg, set()) & later), f"{pkg} imports {graph[pkg] & later}"


def test_package_never_imports_training_or_analysis():
    for path in PACKAGE.rglob("*.py"):
        bad = {i for i in _imports(path) if i.split(".")[0] in ("training", "analysis")}
        assert not bad, f"{path.relative_to(ROOT)} imports {bad}"


def test_no_sys_path_manipulation():
    needle = "sys." + "path"
    for folder in ("uavdyn", "tests", "analysis", "training"):
        for path in (ROOT / folder).rglob("*.py"):
            assert needle not in path.read_text(), f"{path.relative_to(ROOT)} uses {needle}"


def test_import_uavdyn_loads_no_torch_and_no_matplotlib():
    code = ("import sys, uavdyn, uavdyn.learned, uavdyn.evaluation, uavdyn.mpc; "
            "print(sorted(m for m in ('torch', 'matplotlib') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "[]"


# ------------------------------------------------------------------ one RK routine


def test_tableau_rk4_is_the_classical_formula(aerosonde, aerosonde_trim):
    rhs = make_rhs("fixed_wing", ops=NUMPY_OPS)
    rng = np.random.default_rng(0)
    step = rk4_step(build_model(aerosonde).f)
    for _ in range(50):
        x = aerosonde_trim.x + rng.normal(size=4) * [3, 2, 0.5, 0.2]
        u = aerosonde_trim.u + rng.normal(size=2) * [0.05, 0.1]
        dt = rng.uniform(0.001, 0.05)

        def f(xx, u=u):
            return rhs(xx, u, aerosonde.p)

        k1 = f(x)
        k2 = f(x + dt / 2 * k1)
        k3 = f(x + dt / 2 * k2)
        k4 = f(x + dt * k3)
        classical = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        scale = np.abs(classical).max()
        assert np.abs(explicit_rk_step(RK4, f, x, dt) - classical).max() <= 1e-15 * scale
        got = np.array(step(x, u, aerosonde.p, dt)).ravel()
        assert np.abs(got - classical).max() <= 1e-15 * scale


def test_tableau_checks_its_own_consistency():
    with pytest.raises(ValueError, match="weights b sum"):
        ButcherTableau("bad", 1, ((0.0,),), (0.5,), (0.0,))
    with pytest.raises(ValueError, match="row sum"):
        ButcherTableau("bad", 2, ((0.0, 0.0), (1.0, 0.0)), (0.5, 0.5), (0.0, 0.5))
    with pytest.raises(ValueError, match="not explicit"):
        ButcherTableau("bad", 2, ((0.0, 1.0), (1.0, 0.0)), (0.5, 0.5), (1.0, 1.0))


# ------------------------------------------------------- one MLP forward, one formulation


@pytest.mark.parametrize("formulation", sorted(FORMULATIONS))
@pytest.mark.parametrize("activation", ["relu", "tanh"])
def test_network_and_step_agree_in_casadi_numpy_torch(formulation, activation, aerosonde,
                                                      aerosonde_trim):
    torch = pytest.importorskip("torch")
    from uavdyn.model import torch_ops

    net = random_net(aerosonde, formulation, activation, seed=5)
    if formulation == "hypersolver":  # g is scaled by dt**5: make its effect visible
        net = replace(net, out_scale=net.out_scale * 1e9)
    form = FORMULATIONS[formulation]
    rng = np.random.default_rng(2)
    n = 1000
    inp = net.in_mean[:, None] + net.in_scale[:, None] * rng.uniform(-3, 3, (net.n_in, n))
    y_np = net.forward(inp, NUMPY_OPS)
    y_torch = net.forward(torch.as_tensor(inp), torch_ops()).numpy()
    sym = ca.SX.sym("inp", net.n_in)
    y_ca = np.array(ca.Function("net", [sym], [net.casadi(sym)]).map(n)(inp))
    scale = max(1.0, np.abs(y_np).max())
    assert np.abs(y_torch - y_np).max() <= 1e-12 * scale
    assert np.abs(y_ca - y_np).max() <= 1e-12 * scale
    # the formulation's step, evaluated with each namespace
    x = aerosonde_trim.x[:, None] + rng.normal(size=(4, n)) * np.array([[3, 2, 0.5, 0.2]]).T
    u = aerosonde_trim.u[:, None] + rng.normal(size=(2, n)) * np.array([[0.05, 0.1]]).T
    t = rng.uniform(0, 60, (1, n))
    dt = 0.005
    x_np = form.step(make_rhs("fixed_wing", ops=NUMPY_OPS), x, u, aerosonde.p, dt,
                     lambda z: net.forward(z, NUMPY_OPS), NUMPY_OPS, t)
    T = torch.as_tensor
    x_t = form.step(make_rhs("fixed_wing", ops=torch_ops()), T(x), T(u), T(aerosonde.p), dt,
                    lambda z: net.forward(z, torch_ops()), torch_ops(), T(t)).numpy()
    step = hybrid_step(net, aerosonde, compile=False)
    args = [x, u, aerosonde.p, dt] + ([t] if form.takes_time else [])
    x_ca = np.array(step.function.map(n)(*args))
    assert np.abs(x_t - x_np).max() <= 1e-12 * np.abs(x_np).max()
    assert np.abs(x_ca - x_np).max() <= 1e-12 * np.abs(x_np).max()
    phys = np.array(rk4_step(build_model(aerosonde).f).map(n)(x, u, aerosonde.p, dt))
    assert np.abs(x_np - phys).max() > 1e-8  # the network really acts


# ---------------------------------------------------------------- time as a named input


def test_paper_step_takes_time_by_name_and_refuses_other_dt_and_times(aerosonde,
                                                                    aerosonde_trim):
    step = hybrid_step(shipped_weights("aerosonde", "paper"), aerosonde, compile=False)
    assert takes_time(step) and step.takes_time and step.function.name_in()[-1] == "t"
    assert step.dt == 0.005 and step.t_range == (0.0, 30.0)
    controls = np.tile(aerosonde_trim.u, (100, 1))
    with pytest.raises(StepUseError, match=r"step size 0\.01 s but it is made for 0\.005"):
        free_run(step, aerosonde_trim.x, controls, aerosonde.p, 0.01)
    with pytest.raises(StepUseError, match=r"times 29\.9\.\.30\.4 s but it was trained on "
                                           r"0\.\.30 s"):
        free_run(step, aerosonde_trim.x, controls, aerosonde.p, 0.005, t0=29.9)
    lenient = hybrid_step(shipped_weights("aerosonde", "paper"), aerosonde, compile=False,
                          strict=False)
    with pytest.warns(UserWarning, match="made for 0.005"):
        free_run(lenient, aerosonde_trim.x, controls, aerosonde.p, 0.01)
    weights, identified = shipped_correction("aerosonde")
    improved = hybrid_step(weights, identified, compile=False)
    assert not takes_time(improved) and improved.dt is None
    z0 = improved.initial_state(aerosonde_trim.x, aerosonde_trim.u)
    free_run(improved, z0, controls, identified.p, 0.01)  # any dt is fine


def test_paper_step_sees_time_since_sortie_start(aerosonde, aerosonde_trim):
    """A sortie whose time column starts at 1000 s gives the same predictions as the same
    sortie starting at 0 (evaluation feeds time since the start of the sortie)."""
    from uavdyn.evaluation import Solver, evaluate_trajectory

    step = hybrid_step(shipped_weights("aerosonde", "paper"), aerosonde, compile=False)
    rng = np.random.default_rng(1)
    n = 501
    time = np.arange(n) * 0.01
    controls = aerosonde_trim.u + np.column_stack([0.03 * np.sin(time), 0.0 * time])
    states = free_run(rk4_step(build_model(aerosonde).f), aerosonde_trim.x, controls[:-1],
                      aerosonde.p, 0.005, 2)
    states = states + rng.normal(size=states.shape) * 1e-3
    solver = Solver("paper", step, 0.005)
    a = evaluate_trajectory(solver, time, states, controls, aerosonde.p)
    b = evaluate_trajectory(solver, time + 1000.0, states, controls, aerosonde.p)
    for mode in ("one_step", "horizon_1s", "free_run"):  # equal but for the rounding of the
        np.testing.assert_allclose(a[mode][0], b[mode][0], rtol=0, atol=1e-12)  # shifted stamps
    # and time matters to this network: shifting the data by 10 s inside it changes it
    x10 = free_run(step, states[0], controls[:100], aerosonde.p, 0.005, 2, t0=10.0)
    x0 = free_run(step, states[0], controls[:100], aerosonde.p, 0.005, 2, t0=0.0)
    assert np.abs(x10 - x0).max() > 1e-6


def test_modes_hybrid_refuses_a_time_dependent_map_in_one_line(capsys):
    from uavdyn.cli import main

    code = main(["modes", "--airframe", "aerosonde", "--hybrid", "--weights",
                 str(shipped_weights("aerosonde", "paper"))])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "takes time t as an input" in err[0], err
    assert main(["modes", "--airframe", "aerosonde", "--hybrid", "--dt", "0.01"]) == 0
