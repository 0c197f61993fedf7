"""Rate-limited actuators (``slew_<control>`` = 1 / the rate limit): the augmented step's exact
solution of the slewing lag against a fine integration of its ODE (the emulator's actuator
model), its limits (no rate limit: the plain lag; no lag: a pure rate limiter), its derivative
at zero error (the lag's, so trims linearise as before), CasADi vs NumPy vs torch vs compiled
C, and identification recovering a rate limit and its lag from flights the model flew."""

import casadi as ca
import numpy as np
import pytest

from uavdyn.flightdata import Sortie
from uavdyn.identify import identify
from uavdyn.integrate import augment_states, compile_function, find_compiler, physics_step, rollout
from uavdyn.integrate.augmented import SLEW_TAU_FLOOR, augmented_rk_step, slew_toward
from uavdyn.linear import trim
from uavdyn.model import CASADI_OPS, NUMPY_OPS, make_rhs, structure_of, torch_ops

T = 0.01


def _ode(a0: float, command: float, elapsed: float, tau: float, slew: float,
         steps: int = 4000) -> float:
    """Fine RK4 of ``a' = tanh(slew (c - a) / tau) / slew`` (``(c - a)/tau`` without a slew)."""
    def f(a):
        e = command - a
        return np.tanh(slew * e / tau) / slew if slew > 0 else e / tau
    a, h = a0, elapsed / steps
    for _ in range(steps):
        k1 = f(a)
        k2 = f(a + h / 2 * k1)
        k3 = f(a + h / 2 * k2)
        a += h / 6 * (k1 + 2 * k2 + 2 * k3 + h * 0 + f(a + h * k3))
    return a


@pytest.mark.parametrize("a0, command, elapsed, tau, slew", [
    (0.0, 1.0, 0.1, 0.1, 0.5),       # a full step: at the rate limit
    (0.3, -0.2, 0.05, 0.03, 0.2),    # downwards, partly limited
    (0.5, 0.5001, 0.1, 0.1, 0.5),    # a small step: the plain lag
    (0.9, 0.1, 2.0, 0.1, 0.5),       # long after: settled on the command
    (0.0, 1.0, 0.001, 0.1, 3.0),     # a slow actuator, a short interval
    (-0.1, 0.25, 0.02, 0.004, 1.5),  # a fast lag behind a slow rate limit
])
def test_slewing_lag_is_the_exact_solution_of_its_ode(a0, command, elapsed, tau, slew):
    got = float(slew_toward(a0, command, elapsed, tau, slew, NUMPY_OPS))
    assert got == pytest.approx(_ode(a0, command, elapsed, tau, slew), abs=1e-11)


def test_without_a_rate_limit_it_is_the_lag_and_without_a_lag_a_rate_limiter():
    rng = np.random.default_rng(3)
    for _ in range(20):
        a0, c = rng.uniform(-1, 1, 2)
        t, tau = rng.uniform(0.001, 0.3), rng.uniform(0.01, 0.3)
        plain = c + (a0 - c) * np.exp(-t / tau)
        assert float(slew_toward(a0, c, t, tau, 0.0, NUMPY_OPS)) == pytest.approx(
            plain, abs=1e-13)
    # tau -> 0: the actuator moves at 1/slew until it reaches the command, then holds it (a
    # time constant of 0 is SLEW_TAU_FLOOR inside the rate-limited lag: exact to about
    # floor / slew)
    for t in (0.05, 0.2, 0.3, 0.6):
        got = float(slew_toward(0.2, 0.8, t, 0.0, 0.5, NUMPY_OPS))
        assert got == pytest.approx(min(0.2 + t / 0.5, 0.8), abs=4 * SLEW_TAU_FLOOR / 0.5)


def test_derivatives_are_the_finite_differences_and_the_lags_at_zero_error():
    a, c, t, tau, s = (ca.SX.sym(n) for n in ("a", "c", "t", "tau", "s"))
    out = slew_toward(a, c, t, tau, s, CASADI_OPS)
    f = ca.Function("f", [a, c, t, tau, s], [out])
    jac = ca.Function("j", [a, c, t, tau, s], [ca.jacobian(out, ca.vertcat(a, c, tau, s))])
    rng = np.random.default_rng(4)
    for point in [(0.2, 0.2, 0.1, 0.1, 0.5)] + [
            (*rng.uniform(-1, 1, 2), rng.uniform(0.01, 0.2), rng.uniform(0.02, 0.3),
             rng.uniform(0.05, 2.0)) for _ in range(10)]:
        J = np.array(jac(*point)).ravel()
        assert np.all(np.isfinite(J))
        fd = []
        for k in (0, 1, 3, 4):
            up, down = list(point), list(point)
            up[k] += 1e-6
            down[k] -= 1e-6
            fd.append((float(f(*up)) - float(f(*down))) / 2e-6)
        np.testing.assert_allclose(J, fd, rtol=1e-5, atol=1e-7)
    # at zero error the slope is the lag's: a trim linearises as with the plain lag
    J = np.array(jac(0.2, 0.2, 0.1, 0.1, 0.5)).ravel()
    assert J[0] == pytest.approx(np.exp(-1.0), rel=1e-12)
    assert J[1] == pytest.approx(1 - np.exp(-1.0), rel=1e-12)


@pytest.fixture(scope="module")
def slewed(aerosonde):
    return aerosonde.replace(tau_elevator=0.03, tau_throttle=0.1, slew_elevator=0.2,
                             slew_throttle=0.5)


def test_the_structure_carries_the_rate_limits(aerosonde, slewed):
    s = structure_of(slewed)
    assert s.slewed == ("elevator", "throttle") and s.lagged == ("elevator", "throttle")
    names = slewed.param_names
    assert s.slew_indices == (names.index("slew_elevator"), names.index("slew_throttle"))
    assert structure_of(aerosonde).slewed == ()
    fitting = structure_of(aerosonde, ("slew_throttle",))
    assert fitting.slewed == ("throttle",) and fitting.lagged == ("throttle",)


def test_numpy_torch_and_compiled_steps_equal_casadi(slewed):
    torch = pytest.importorskip("torch")
    structure = structure_of(slewed)
    step = physics_step(slewed, substeps=2)
    point = trim(slewed, 22.0)
    rng = np.random.default_rng(8)
    B = 6
    Z = np.vstack([point.x[:, None] + rng.normal(0, 0.05, (4, B)),
                   point.u[:, None] + rng.normal(0, 0.2, (2, B))])
    U = point.u[:, None] + rng.normal(0, 0.3, (2, B))  # large steps: at the rate limits
    expected = np.column_stack([np.array(step(Z[:, k], U[:, k], slewed.p, T)).ravel()
                                for k in range(B)])
    got_np = augmented_rk_step(structure, make_rhs(structure, False, NUMPY_OPS), Z, U,
                               slewed.p, T, ops=NUMPY_OPS, substeps=2)
    np.testing.assert_allclose(got_np, expected, rtol=1e-12, atol=1e-12)
    ops = torch_ops()
    got_t = augmented_rk_step(structure, make_rhs(structure, False, ops), torch.as_tensor(Z),
                              torch.as_tensor(U), torch.as_tensor(slewed.p), T, ops=ops,
                              substeps=2)
    np.testing.assert_allclose(got_t.numpy(), expected, rtol=1e-12, atol=1e-12)
    if find_compiler() is not None:
        compiled = compile_function(step.function)
        got_c = np.column_stack([np.array(compiled(Z[:, k], U[:, k], slewed.p, T)).ravel()
                                 for k in range(B)])
        np.testing.assert_allclose(got_c, expected, rtol=1e-12, atol=1e-12)


def _flights(truth, n: int) -> list[Sortie]:
    """Open-loop flights of ``truth``: throttle steps of several sizes (small ones show the
    lag, large ones the rate limit) and an elevator doublet."""
    out = []
    for i in range(n):
        point = trim(truth, 21.0 + 1.5 * i)
        t = np.arange(801) * T
        u = np.tile(point.u, (len(t), 1))
        for start, size in ((0.5, 0.05), (2.0, -0.4), (3.5, 0.45), (5.0, 0.1), (6.5, -0.3)):
            u[:, 1] += np.where((t > start) & (t < start + 1.0), size * (1 - 0.2 * i), 0.0)
        u[:, 1] = np.clip(u[:, 1], 0.0, 1.0)
        u[:, 0] += np.where((t > 1.0) & (t < 1.3), 0.02, 0.0) - np.where(
            (t > 1.3) & (t < 1.6), 0.02, 0.0)
        structure = structure_of(truth)
        z0 = augment_states(structure, point.x[None], u[:1], truth.p, T)[0]
        z = np.array(rollout(physics_step(truth, substeps=2), len(t) - 1)(
            z0, u[:-1].T, truth.p, T)).T
        x = np.vstack([point.x, z[:, :4]])
        out.append(Sortie(f"s{i}", "fixed_wing", t, x, u, "sysid"))
    return out


@pytest.mark.slow
def test_identification_recovers_a_rate_limit_and_its_lag(aerosonde):
    truth = aerosonde.replace(tau_throttle=0.1, slew_throttle=0.5)
    start = aerosonde.replace(tau_throttle=0.25)  # the rate limit fitted from none
    flights = _flights(truth, 3)
    result = identify(start, flights, [], ["tau_throttle", "slew_throttle", "C_D_0"],
                      progress=False, check_halves=False, max_windows=None, substeps=2)
    got = {e.name: e.value for e in result.estimates}
    assert got["slew_throttle"] == pytest.approx(0.5, rel=5e-3)
    assert got["tau_throttle"] == pytest.approx(0.1, rel=5e-3)
    assert got["C_D_0"] == pytest.approx(aerosonde.params.C_D_0, rel=5e-3)
    # without the rate limit the same flights fit a lag that is not the truth's
    lag_only = identify(start, flights, [], ["tau_throttle", "C_D_0"], progress=False,
                        check_halves=False, max_windows=None, substeps=2)
    assert lag_only.estimates[0].value > 0.12
