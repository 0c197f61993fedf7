"""Air density: the standard atmosphere (``atmosphere = "isa"``), per sortie or at the h state.

Truths: the ISA tables (ICAO Doc 7488 / US Standard Atmosphere 1976), the hydrostatic equation
integrated numerically from the standard's temperature profile, finite differences, and the
same airframe with its density set by hand.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
from test_tables import airframe_file

from uavdyn.airframes import load_airframe
from uavdyn.linear import trim
from uavdyn.model import (
    NUMPY_OPS,
    build_model,
    isa_density,
    isa_density_ratio,
    sortie_params,
)

# Standard-atmosphere densities (kg/m^3) at the altitudes of the usual tables. Up to 11 km the
# tabulated values (geometric or geopotential altitude: they differ by 0.2 % at 11 km) agree
# with the model to 1e-3; at 15 and 20 km (lower stratosphere, isothermal at 216.65 K) the
# density is the standard's tabulated pressure over R_air T: 12044.6 Pa and 5474.89 Pa at
# geopotential 15 and 20 km (US Standard Atmosphere 1976, table I), R_air = 287.05287 J/(kg K).
R_AIR = 287.05287
ISA_TABLE = [(-1000.0, 1.3470), (0.0, 1.2250), (1000.0, 1.1117), (2000.0, 1.0066),
             (5000.0, 0.7364), (11000.0, 0.3639), (15000.0, 12044.6 / (R_AIR * 216.65)),
             (20000.0, 5474.89 / (R_AIR * 216.65))]


@pytest.mark.parametrize("altitude, density", ISA_TABLE)
def test_isa_density_matches_the_standard_table(altitude, density):
    assert isa_density(altitude) == pytest.approx(density, rel=1e-3)
    assert isa_density(altitude, sea_level=1.0) == pytest.approx(density / 1.225, rel=1e-3)


def test_isa_density_solves_the_hydrostatic_equation():
    """``dp/dh = -rho g`` with the ideal gas ``rho = p M / (R T)`` and the standard's
    temperature profile (-6.5 K/km to 11 km, then 216.65 K), integrated by RK4 in steps of
    10 m: the density ratio ``(p / T) / (p0 / T0)`` at every altitude equals the closed form."""
    g, molar, gas = 9.80665, 0.0289644, 8.3144598

    def temperature(h):
        return 288.15 - 0.0065 * min(h, 11000.0)

    def slope(h):  # d ln p / dh
        return -g * molar / (gas * temperature(h))

    step, log_p, heights, ratios = 10.0, 0.0, [0.0], [1.0]
    h = 0.0
    while h < 20000.0 - 1e-9:  # 11000 is a step boundary: each RK step sees a smooth T(h)
        k1 = slope(h)
        k2 = slope(h + step / 2)
        k4 = slope(h + step)
        log_p += step / 6 * (k1 + 4 * k2 + k4)  # k2 = k3: the slope does not depend on p
        h += step
        heights.append(h)
        ratios.append(math.exp(log_p) * 288.15 / temperature(h))
    heights, ratios = np.array(heights), np.array(ratios)
    model = isa_density_ratio(heights, NUMPY_OPS)
    assert np.abs(model / ratios - 1).max() < 1e-9
    assert ratios[-1] < 0.08  # it really went up to 20 km


def test_isa_ratio_is_clamped_continuous_and_the_same_in_every_backend():
    torch = pytest.importorskip("torch")
    from uavdyn.model import torch_ops

    ratio = isa_density_ratio
    assert float(ratio(-5000.0, NUMPY_OPS)) == float(ratio(-1000.0, NUMPY_OPS))
    assert float(ratio(30000.0, NUMPY_OPS)) == float(ratio(20000.0, NUMPY_OPS))
    below, above = ratio(11000.0 - 1e-6, NUMPY_OPS), ratio(11000.0 + 1e-6, NUMPY_OPS)
    assert abs(below - above) < 1e-10
    rng = np.random.default_rng(0)
    h = rng.uniform(-2000.0, 25000.0, 2000)
    expected = ratio(h, NUMPY_OPS)
    got_t = ratio(torch.as_tensor(h), torch_ops()).numpy()
    hs = ca.SX.sym("h")
    fun = ca.Function("r", [hs], [ratio(hs), ca.jacobian(ratio(hs), hs)])
    got_ca, slope = (np.array(r).ravel() for r in fun.map(len(h))(h))
    assert np.abs(got_t - expected).max() <= 1e-15
    assert np.abs(got_ca - expected).max() <= 1e-15
    # the slope away from the kinks equals a central difference
    inside = (np.abs(h - 11000.0) > 1.0) & (h > -999.0) & (h < 19999.0)
    fd = (ratio(h + 0.5, NUMPY_OPS) - ratio(h - 0.5, NUMPY_OPS)) / 1.0
    assert np.abs(slope[inside] - fd[inside]).max() <= 1e-6 * np.abs(fd[inside]).max()
    assert np.all(slope[~((h > -1000.0) & (h < 20000.0))] == 0.0)


@pytest.mark.parametrize("base", ["aerosonde", "f450"])
def test_sortie_params_scale_rho_only_for_isa(base, tmp_path):
    constant = load_airframe(base)
    isa = airframe_file(tmp_path, f"{base}_isa", base=base, atmosphere="isa")
    i = constant.param_names.index("rho")
    for altitude in (None, 0.0, 1500.0, 6000.0):
        assert np.array_equal(sortie_params(constant, altitude), constant.p)
    assert np.array_equal(sortie_params(isa, None), isa.p)
    for altitude in (0.0, 762.0, 1828.8, 6000.0):
        p = sortie_params(isa, altitude)
        expected = isa.p[i] * isa_density(altitude, 1.0)
        assert p[i] == pytest.approx(expected, rel=1e-15)
        assert np.array_equal(np.delete(p, i), np.delete(isa.p, i))
    assert sortie_params(isa, 3000.0)[i] < 0.75 * isa.p[i]  # about -26 % at 3 km
    assert isa.p[i] == constant.p[i]  # the airframe itself is not changed


def _states(kind: str, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    if kind == "fixed_wing":
        x = np.array([[25.0, 1.2, 0.0, 0.05]]).T + rng.normal(size=(4, n)) * np.array(
            [[3.0, 2.0, 0.5, 0.2]]).T
        u = np.vstack([rng.uniform(-0.3, 0.3, n), rng.uniform(0.2, 1.0, n)])
    else:
        x = rng.normal(size=(4, n)) * np.array([[4.0, 2.0, 0.5, 0.2]]).T
        u = np.vstack([rng.uniform(0.3, 0.9, n), rng.uniform(-0.5, 0.5, n)])
    return x, u


@pytest.mark.parametrize("base", ["aerosonde", "f450"])
def test_h_state_density_equals_the_per_sortie_density(base, tmp_path):
    """The with-position model of an ISA airframe at a constant ``h`` is the 4-state model with
    that sortie's parameters; the constant-atmosphere model does not depend on ``h``."""
    isa = airframe_file(tmp_path, f"{base}_isa", base=base, atmosphere="isa")
    constant = load_airframe(base)
    n = 400
    x, u = _states(isa.kind, n, 3)
    body = build_model(isa).forces.map(n)
    with_h = build_model(isa, with_position=True).forces.map(n)
    plain_h = build_model(constant, with_position=True).forces.map(n)
    reference = [np.array(r) for r in build_model(constant).forces.map(n)(x, u, constant.p)]
    for altitude in (0.0, 500.0, 3000.0, 9000.0):
        x6 = np.vstack([x, np.full((1, n), 100.0), np.full((1, n), altitude)])
        expected = [np.array(r) for r in body(x, u, sortie_params(isa, altitude))]
        got = [np.array(r) for r in with_h(x6, u, isa.p)]
        for e, g in zip(expected[:3], got[:3]):  # X, Z, M
            assert np.abs(g - e).max() <= 1e-12 * np.abs(e).max()
        assert np.abs(expected[0] - reference[0]).max() > 0 or altitude == 0.0
        flat = [np.array(r) for r in plain_h(x6, u, constant.p)]
        for e, g in zip(reference[:3], flat[:3]):
            assert np.array_equal(g, e)


def test_h_state_jacobian_is_the_density_gradient(aerosonde_trim, tmp_path):
    """d f / d h of the with-position ISA model = d f / d rho times rho0 d ratio / dh (the
    closed form's derivative, troposphere), and a central difference agrees."""
    isa = airframe_file(tmp_path, "isa_jac", atmosphere="isa")
    model6 = build_model(isa, with_position=True)
    model4 = build_model(isa)
    i_rho = isa.param_names.index("rho")
    lapse, exponent = 0.0065 / 288.15, 9.80665 * 0.0289644 / (8.3144598 * 0.0065) - 1
    for altitude in (200.0, 2500.0, 7000.0):
        x6 = np.concatenate([aerosonde_trim.x + [1.0, 0.5, 0.1, 0.02], [0.0, altitude]])
        u = aerosonde_trim.u + [0.02, 0.05]
        A = np.array(model6.jacobians(x6, u, isa.p)[0])
        dfdp = np.array(model4.jacobians(x6[:4], u, sortie_params(isa, altitude))[2])
        d_ratio = -exponent * lapse * (1 - lapse * altitude) ** (exponent - 1)
        expected = dfdp[:, i_rho] * isa.p[i_rho] * d_ratio
        assert np.abs(expected).max() > 1e-6
        assert np.abs(A[:4, 5] - expected).max() <= 1e-10 * np.abs(expected).max()

        def f(h, x6=x6, u=u):
            return np.array(model6.f(np.concatenate([x6[:5], [h]]), u, isa.p)).ravel()

        fd = (f(altitude + 1.0) - f(altitude - 1.0)) / 2.0
        assert np.abs(A[:, 5] - fd).max() <= 1e-6 * np.abs(fd).max()


def test_trim_at_altitude_equals_the_airframe_with_that_density(tmp_path):
    isa = airframe_file(tmp_path, "isa_trim", atmosphere="isa")
    for altitude in (0.0, 2000.0, 4500.0):
        rho = isa.params.rho * isa_density(altitude, 1.0)
        by_hand = load_airframe("aerosonde").replace(rho=rho)
        a, b = trim(isa, 25.0, altitude_m=altitude), trim(by_hand, 25.0)
        np.testing.assert_allclose(a.x, b.x, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(a.u, b.u, rtol=1e-12, atol=1e-12)
        assert a.altitude_m == altitude
    # thinner air: a higher angle of attack for the same airspeed
    assert trim(isa, 25.0, altitude_m=4500.0).alpha > trim(isa, 25.0, altitude_m=0.0).alpha
