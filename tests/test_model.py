"""The CasADi model against independent truths: finite differences, the NumPy evaluation of
the same equations, kinematic identities, and the validity domain past stall."""

import math

import numpy as np
import pytest

from uavdyn.model import build_model, numpy_rhs

RNG = np.random.default_rng(1234)


def random_states(kind, n):
    if kind == "fixed_wing":
        V = RNG.uniform(15, 35, n)
        alpha = RNG.uniform(-0.3, 0.6, n)  # includes the stall blending region
        return np.column_stack([V * np.cos(alpha), V * np.sin(alpha), RNG.uniform(-1, 1, n),
                                RNG.uniform(-0.5, 0.5, n)]), \
            np.column_stack([RNG.uniform(-0.4, 0.4, n), RNG.uniform(0.1, 1.0, n)])
    return np.column_stack([RNG.uniform(-8, 8, n), RNG.uniform(-3, 3, n), RNG.uniform(-2, 2, n),
                            RNG.uniform(-0.8, 0.8, n)]), \
        np.column_stack([RNG.uniform(0.3, 0.9, n), RNG.uniform(-1, 1, n)])


def central_difference(fun, z, rel=1e-6):
    cols = []
    for i in range(len(z)):
        h = rel * max(1.0, abs(z[i]))
        zp, zm = z.copy(), z.copy()
        zp[i] += h
        zm[i] -= h
        cols.append((fun(zp) - fun(zm)) / (2 * h))
    return np.column_stack(cols)


@pytest.mark.parametrize("name", ["aerosonde", "f450"])
def test_jacobians_match_central_differences(name, request):
    af = request.getfixturevalue(name)
    model = build_model(af)
    f = lambda x, u, p: np.array(model.f(x, u, p)).ravel()  # noqa: E731
    xs, us = random_states(af.kind, 8)
    for x, u in zip(xs, us):
        A, B, P = (np.array(m) for m in model.jacobians(x, u, af.p))
        for exact, fd in (
            (A, central_difference(lambda z, u=u: f(z, u, af.p), x)),
            (B, central_difference(lambda z, x=x: f(x, z, af.p), u)),
            (P, central_difference(lambda z, x=x, u=u: f(x, u, z), af.p.copy())),
        ):
            scale = np.abs(exact).max()
            np.testing.assert_allclose(exact, fd, rtol=1e-6, atol=1e-6 * scale)


@pytest.mark.parametrize("name", ["aerosonde", "f450"])
def test_numpy_evaluation_equals_casadi(name, request):
    af = request.getfixturevalue(name)
    model = build_model(af)
    rhs = numpy_rhs(af.kind)
    xs, us = random_states(af.kind, 50)
    for x, u in zip(xs, us):
        np.testing.assert_allclose(rhs(x, u, af.p), np.array(model.f(x, u, af.p)).ravel(),
                                   rtol=1e-13, atol=1e-12)


def test_gravity_only_kinematics(f450):
    """Rotors off, no motion: free fall along the vertical, expressed in body axes."""
    model = build_model(f450)
    theta = 0.3
    xdot = np.array(model.f([0, 0, 0, theta], [0.0, 0.0], f450.p)).ravel()
    g = f450.params.gravity
    np.testing.assert_allclose(xdot, [-g * math.sin(theta), g * math.cos(theta), 0, 0],
                               atol=1e-12)


def test_position_states_follow_flight_path(aerosonde):
    model = build_model(aerosonde, with_position=True)
    V, alpha, gamma = 25.0, 0.05, 0.1
    x = [V * math.cos(alpha), V * math.sin(alpha), 0.2, alpha + gamma, 0.0, 100.0]
    xdot = np.array(model.f(x, [0.0, 0.5], aerosonde.p)).ravel()
    assert model.nx == 6
    np.testing.assert_allclose(xdot[4:], [V * math.cos(gamma), V * math.sin(gamma)], rtol=1e-12)
    np.testing.assert_allclose(xdot[3], 0.2)


def test_fixed_wing_defined_past_stall(aerosonde):
    """alpha over [-90, 90] deg: finite everywhere, lift falls past the stall angle."""
    model = build_model(aerosonde)
    alphas = np.radians(np.linspace(-90, 90, 361))
    lift = []
    for a in alphas:
        x = [20 * math.cos(a), 20 * math.sin(a), 0.0, 0.0]
        X, Z, M, alpha, V, T = (float(v) for v in model.forces(x, [0.0, 0.5], aerosonde.p))
        assert all(math.isfinite(v) for v in (X, Z, M, T))
        assert math.isclose(alpha, a, abs_tol=1e-12) and math.isclose(V, 20.0)
        xdot = np.array(model.f(x, [0.0, 0.5], aerosonde.p)).ravel()
        assert np.all(np.isfinite(xdot))
        # lift = component of the aerodynamic force normal to the velocity
        lift.append(-(Z * math.cos(a) - (X - T) * math.sin(a)))
    lift = np.array(lift)
    i_max = int(np.argmax(lift))
    assert 15 < math.degrees(alphas[i_max]) < 30
    assert lift[np.searchsorted(alphas, math.radians(45))] < 0.7 * lift[i_max]
