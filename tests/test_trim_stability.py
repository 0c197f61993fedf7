"""Trim points are true equilibria; infeasible requests say why; modes match analytic values
and the classical approximations (Lanchester phugoid, short-period approximation)."""

import math

import numpy as np
import pytest

from uavdyn.linear import TrimError, linearise, mode_table, modes, stall_speed, trim
from uavdyn.model import build_model


@pytest.mark.parametrize("name, airspeed, gamma", [
    ("aerosonde", 25.0, 0.0), ("aerosonde", 20.0, 0.0), ("aerosonde", 30.0, 0.0),
    ("aerosonde", 25.0, math.radians(5)), ("aerosonde", 25.0, math.radians(-3)),
    ("f450", 0.0, 0.0), ("f450", 10.0, 0.0), ("f450", 5.0, math.radians(10)),
])
def test_trim_is_an_equilibrium(name, airspeed, gamma, request):
    af = request.getfixturevalue(name)
    point = trim(af, airspeed, gamma)
    xdot = np.array(build_model(af).f(point.x, point.u, af.p)).ravel()
    assert np.abs(xdot).max() < 1e-9
    assert point.residual < 1e-9
    assert math.isclose(math.hypot(point.x[0], point.x[1]), airspeed, abs_tol=1e-12)
    if airspeed > 0:  # flight-path angle = theta - alpha
        assert math.isclose(point.x[3] - point.alpha, gamma, abs_tol=1e-12)


def test_trim_errors_say_why(aerosonde, f450):
    v_stall = stall_speed(aerosonde)[0]
    with pytest.raises(TrimError, match=r"below the stall speed 11\.\d\d m/s"):
        trim(aerosonde, 0.9 * v_stall)
    with pytest.raises(TrimError,
                       match=r"needs throttle = 1\.\d+, outside \[0, 1\] \(thrust limit\)"):
        trim(aerosonde, 40.0)
    with pytest.raises(TrimError, match=r"needs elevator = .*\(control limit\)"):
        trim(aerosonde, 14.0)
    with pytest.raises(TrimError, match="zero airspeed"):
        trim(aerosonde, 0.0)
    with pytest.raises(TrimError, match="airspeed must be a finite number >= 0"):
        trim(aerosonde, float("nan"))
    with pytest.raises(TrimError, match="flight-path angle"):
        trim(aerosonde, 25.0, 2.0)
    with pytest.raises(TrimError, match="thrust limit|outside the envelope"):
        trim(f450, 45.0)
    with pytest.raises(TrimError, match="hover has no flight-path angle"):
        trim(f450, 0.0, 0.1)


def test_aerosonde_modes_match_classical_approximations(aerosonde, aerosonde_trim):
    A, B = linearise(aerosonde, aerosonde_trim)
    found = {m.name: m for m in modes(A, aerosonde.kind, B)}
    assert set(found) == {"short period", "phugoid"}
    sp, ph = found["short period"], found["phugoid"]
    eig = np.linalg.eigvals(A)
    for m in (sp, ph):
        assert np.min(np.abs(eig - m.eigenvalue)) < 1e-10
        assert m.stable
        assert math.isclose(m.time_to_half, math.log(2) / -m.eigenvalue.real)
        assert math.isclose(m.period, 2 * math.pi / m.eigenvalue.imag)
    # Lanchester: phugoid frequency ~ sqrt(2) g / V (Etkin & Reid, Dynamics of Flight, 3rd ed.)
    lanchester = math.sqrt(2) * aerosonde.params.gravity / aerosonde_trim.airspeed
    assert abs(ph.natural_frequency / lanchester - 1) < 0.15
    # short-period approximation: the (w, q) block of A alone (constant speed)
    approx = np.linalg.eigvals(A[1:3, 1:3])
    assert abs(abs(approx[0]) / sp.natural_frequency - 1) < 0.05
    table = mode_table(list(found.values()))
    assert "short period" in table and "phugoid" in table


def test_quadrotor_hover_modes_are_the_analytic_ones(f450, f450_hover):
    """At hover: speed subsidence -k_u/m, pitch subsidence -c_q/Jy, two neutral modes."""
    A, B = linearise(f450, f450_hover)
    found = modes(A, f450.kind, B)
    P = f450.params
    got = sorted(m.eigenvalue.real for m in found)
    np.testing.assert_allclose(got, sorted([-P.drag_linear / P.mass, -P.pitch_damping / P.Jy,
                                            0.0, 0.0]), atol=1e-12)
    names = {m.name for m in found}
    assert "speed subsidence" in names and "pitch subsidence" in names
