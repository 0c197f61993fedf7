"""The hybrid step: torch forward, CasADi VM and compiled C agree to 1e-10 (float64) for every
formulation; its Jacobians equal central finite differences; rollouts match repeated steps;
the shipped weights load for their airframe and are refused for another."""

import casadi as ca
import numpy as np
import pytest
from test_correction import random_net

from uavdyn.integrate import compile_function, find_compiler, rk4_step, rollout
from uavdyn.learned import (
    WeightFileError,
    hybrid_jacobian,
    hybrid_step,
    load_weights,
    shipped_correction,
    shipped_identified,
    shipped_weights,
)
from uavdyn.linear import trim
from uavdyn.model import build_model


def in_range_inputs(point, kind, n, seed=0):
    """Random states/controls around trim, within the flight envelope of the data."""
    rng = np.random.default_rng(seed)
    if kind == "fixed_wing":
        dx = rng.uniform(-1, 1, (n, 4)) * [6.0, 3.0, 1.0, 0.4]
        du = rng.uniform(-1, 1, (n, 2)) * [0.15, 0.2]
    else:
        dx = rng.uniform(-1, 1, (n, 4)) * [3.0, 2.0, 1.0, 0.4]
        du = rng.uniform(-1, 1, (n, 2)) * [0.1, 0.3]
    x = point.x + dx
    u = point.u + du
    dt = rng.uniform(0.002, 0.02, n)
    t = rng.uniform(0.0, 60.0, n)
    return x, u, dt, t


def _scale_net(net, point, control_ref):
    """A random network with realistic normalisation around the trim point."""
    from dataclasses import replace

    if net.formulation == "paper":
        mean = np.concatenate([[30.0], point.x])
        scale = np.array([17.0, 3.0, 1.5, 0.5, 0.2])
    else:
        mean = np.concatenate([point.x, control_ref])
        scale = np.array([3.0, 1.5, 0.5, 0.2, 0.1, 0.1])
    out_scale = {"improved": np.full(3, 0.3), "paper": np.full(4, 1e-3),
                 "hypersolver": np.full(4, 1e6)}[net.formulation]
    return replace(net, in_mean=mean, in_scale=scale, out_scale=out_scale,
                   out_mean=np.zeros(net.n_out))


@pytest.mark.parametrize("airframe_name", ["aerosonde", "f450"])
@pytest.mark.parametrize("formulation", ["improved", "paper", "hypersolver"])
def test_torch_vm_and_c_agree(airframe_name, formulation, request):
    torch = pytest.importorskip("torch")
    from uavdyn.learned.torch_model import TorchCorrection

    af = request.getfixturevalue(airframe_name)
    point = request.getfixturevalue("aerosonde_trim" if airframe_name == "aerosonde"
                                    else "f450_hover")
    net = _scale_net(random_net(af, formulation, "relu", 16, seed=3), point, point.u)
    x, u, dt, t = in_range_inputs(point, af.kind, 1000)
    module = TorchCorrection.from_net(net)
    T = lambda a: torch.as_tensor(a, dtype=torch.float64)  # noqa: E731
    with torch.no_grad():
        inp = np.column_stack([t, x]) if formulation == "paper" else np.column_stack([x, u])
        y_torch = module(T(inp)).numpy()
        # one dt per sample: the torch step broadcasts a (B, 1) step size
        x_torch = module.step(T(x), T(u), T(af.p), T(dt[:, None]), T(t)).numpy()

    # the correction alone
    sym = ca.SX.sym("inp", net.n_in)
    corr = ca.Function("corr", [sym], [net.casadi(sym)]).map(1000)
    y_vm = np.array(corr(inp.T)).T
    tol = 1e-10 * max(1.0, np.abs(y_torch).max())
    np.testing.assert_allclose(y_vm, y_torch, rtol=0, atol=tol)

    step = hybrid_step(net, af, compile=False)
    args = [x.T, u.T, af.p, dt[None, :]] + ([t[None, :]] if formulation == "paper" else [])
    x_vm = np.array(step.function.map(1000)(*args)).T
    np.testing.assert_allclose(x_vm, x_torch, rtol=0, atol=1e-10)
    # the correction really acts (else the comparison would be vacuous)
    x_phys = np.array(rk4_step(build_model(af).f).map(1000)(x.T, u.T, af.p, dt[None, :])).T
    assert np.abs(x_vm - x_phys).max() > 1e-6
    if find_compiler() is not None:
        y_c = np.array(compile_function(corr)(inp.T)).T
        np.testing.assert_allclose(y_c, y_torch, rtol=0, atol=tol)
        x_c = np.array(compile_function(step.function.map(1000))(*args)).T
        np.testing.assert_allclose(x_c, x_torch, rtol=0, atol=1e-10)
        single = hybrid_step(net, af, compile=True)
        np.testing.assert_allclose(np.array(single(*[a if np.ndim(a) < 2 else a[:, :1]
                                                     for a in args])).ravel(),
                                   x_torch[0], rtol=0, atol=1e-10)


def _central_fd(fun, z, h):
    cols = []
    for i in range(len(z)):
        e = np.zeros_like(z)
        e[i] = h[i]
        cols.append((fun(z + e) - fun(z - e)) / (2 * h[i]))
    return np.column_stack(cols)


@pytest.mark.parametrize("activation", ["relu", "tanh"])
@pytest.mark.parametrize("formulation", ["improved", "paper"])
def test_jacobian_equals_central_differences(activation, formulation, aerosonde,
                                             aerosonde_trim):
    net = _scale_net(random_net(aerosonde, formulation, activation, 16, seed=5), aerosonde_trim,
                     aerosonde_trim.u)
    jac = hybrid_jacobian(net, aerosonde)
    step = hybrid_step(net, aerosonde, compile=False)
    x, u, dt, t = in_range_inputs(aerosonde_trim, "fixed_wing", 40, seed=2)
    # steps ~1e-5 of each variable's range: truncation (h^2) and round-off (eps/h) both < 1e-9
    hx = np.array([6.0, 3.0, 1.0, 0.4]) * 1e-5
    hu = np.array([0.15, 0.2]) * 1e-5
    checked = 0
    for k in range(len(x)):
        extra = [t[k]] if formulation == "paper" else []
        if activation == "relu" and _near_kink(net, x[k], u[k], dt[k], t[k], step, hx, hu):
            continue  # a ReLU kink inside the stencil: FD is not a derivative there
        _, A, B = (np.array(v) for v in jac(x[k], u[k], aerosonde.p, dt[k], *extra))
        def fx(z, k=k, extra=extra):
            return np.array(step(z, u[k], aerosonde.p, dt[k], *extra)).ravel()

        def fu(z, k=k, extra=extra):
            return np.array(step(x[k], z, aerosonde.p, dt[k], *extra)).ravel()

        np.testing.assert_allclose(A, _central_fd(fx, x[k], hx), rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(B, _central_fd(fu, u[k], hu), rtol=1e-6, atol=1e-9)
        checked += 1
    assert checked >= 20


def _near_kink(net, x, u, dt, t, step, hx, hu):
    """True if some ReLU pre-activation changes sign within the FD stencil."""
    def pre_acts(inp):
        z = (inp - net.in_mean) / net.in_scale
        out = []
        for w, b in zip(net.weights[:-1], net.biases[:-1]):
            z = z @ w.T + b
            out.append(z.copy())
            z = np.maximum(z, 0)
        return np.concatenate(out)

    def net_input(xx, uu):
        if net.formulation == "paper":
            base = np.array(rk4_step(build_model(net.kind).f)(xx, uu, PARAMS[net.kind], dt))
            return np.concatenate([[t], base.ravel()])
        return np.concatenate([xx, uu])

    ref = np.sign(pre_acts(net_input(x, u)))
    for i in range(4):
        for s in (-1, 1):
            e = np.zeros(4)
            e[i] = s * hx[i]
            if np.any(np.sign(pre_acts(net_input(x + e, u))) != ref):
                return True
    for i in range(2):
        for s in (-1, 1):
            e = np.zeros(2)
            e[i] = s * hu[i]
            if np.any(np.sign(pre_acts(net_input(x, u + e))) != ref):
                return True
    return False


PARAMS: dict = {}


@pytest.fixture(autouse=True)
def _params(aerosonde, f450):
    PARAMS.update(fixed_wing=aerosonde.p, multirotor=f450.p)


def test_rollout_equals_repeated_steps_and_jacobian_is_nlp_ready(aerosonde, aerosonde_trim):
    for formulation in ("improved", "paper"):
        net = _scale_net(random_net(aerosonde, formulation, "relu", 8, seed=7), aerosonde_trim,
                         aerosonde_trim.u)
        step = hybrid_step(net, aerosonde, compile=False)
        n = 30
        U = np.tile(aerosonde_trim.u, (n, 1)).T + 0.02
        args = [aerosonde_trim.x, U, aerosonde.p, 0.01] + ([1.5] if formulation == "paper"
                                                           else [])
        traj = np.array(compile_function(rollout(step, n))(*args))
        x = aerosonde_trim.x.copy()
        for k in range(n):
            extra = [1.5 + 0.01 * k] if formulation == "paper" else []
            x = np.array(step(x, U[:, k], aerosonde.p, 0.01, *extra)).ravel()
            np.testing.assert_allclose(traj[:, k], x, rtol=0, atol=1e-11)
    # the improved step inside an NLP: find the elevator that holds q = 0 for one step
    net = _scale_net(random_net(aerosonde, "improved", "tanh", 8, seed=8), aerosonde_trim,
                     aerosonde_trim.u)
    step = hybrid_step(net, aerosonde, compile=False)
    de = ca.SX.sym("de")
    x_next = step(aerosonde_trim.x, ca.vertcat(de, aerosonde_trim.u[1]), aerosonde.p, 0.01)
    solver = ca.nlpsol("s", "ipopt", {"x": de, "f": x_next[2] ** 2},
                       {"ipopt.print_level": 0, "print_time": False})
    sol = solver(x0=aerosonde_trim.u[0])
    assert solver.stats()["success"]
    q = np.array(step(aerosonde_trim.x, [float(sol["x"]), aerosonde_trim.u[1]], aerosonde.p,
                      0.01))[2]
    assert abs(q) < 1e-7


@pytest.mark.parametrize("name", ["aerosonde", "f450"])
def test_shipped_weights_load_and_refuse_other_airframes(name, request):
    """The default shipped weights are the safe correction on the identified airframe; the
    nominal preset (another parameter hash) is refused."""
    path = shipped_weights(name)
    af = shipped_identified(name)
    assert path == shipped_correction(name)[0]
    net = load_weights(path, af)
    assert net.formulation == "improved" and net.envelope is not None
    model = hybrid_step(path, af)
    point = trim(af, af.nominal_airspeed if af.kind == "fixed_wing" else 0.0)
    z = model.initial_state(point.x, point.u, af.p)
    assert z.shape == (model.nx,)
    assert np.all(np.isfinite(np.array(model(z, point.u, af.p, net.dt))))
    with pytest.raises(WeightFileError, match="another airframe"):
        hybrid_step(path, request.getfixturevalue(name))
    with pytest.raises(WeightFileError, match="no shipped weights of formulation"):
        shipped_weights(name, "improved")
