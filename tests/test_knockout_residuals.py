"""``analysis/knockout_residuals.py``: a model's one-step pitch-acceleration error along true
states is zero for the model that flew them and, for a model whose pitching moment differs
by a constant, that moment over the inertia (checked at a held trim, where it is the analytic
``dC_m qbar S c / Jy``); held trims are steady windows."""


import numpy as np
import pytest
from analysis_scripts import load_script

from uavdyn.airframes import load_airframe
from uavdyn.flightdata.sortie import Sortie
from uavdyn.integrate import physics_step
from uavdyn.linear import trim


@pytest.fixture(scope="module")
def residuals():
    load_script("bench_knockout")
    return load_script("knockout_residuals")


def _held_trim(airframe, speed: float, dt: float, n: int) -> Sortie:
    point = trim(airframe, speed)
    body = np.tile(np.asarray(point.x, float), (n, 1))
    controls = np.tile(np.asarray(point.u, float), (n, 1))
    return Sortie("held", airframe.kind, np.arange(n) * dt, body.copy(), controls,
                  "trim", {"condition": "calm"}, body)


def test_one_step_error_is_the_moment_difference_over_inertia(residuals):
    airframe = load_airframe("aerosonde")
    dt, speed, d_cm = 1e-4, 25.0, 0.002
    sortie = _held_trim(airframe, speed, dt, 4000)
    same = residuals.one_step_errors(physics_step(airframe), sortie)
    assert np.max(np.abs(same)) < 1e-6  # the trim's own model holds it
    shifted = airframe.replace(C_m_0=airframe.params.C_m_0 + d_cm)
    got = residuals.one_step_errors(physics_step(shifted), sortie)
    V = float(np.hypot(*sortie.true_states[0, :2]))
    P = airframe.params
    expected = d_cm * 0.5 * P.rho * V**2 * P.S_wing * P.c / P.Jy
    np.testing.assert_allclose(got, expected, rtol=1e-3)  # the pitch damping over one step: 3e-4
    rows = residuals.windows(sortie, {"a": same, "b": got}, 0.1)
    assert len(rows) == 4 and all(r["steady"] for r in rows)
    assert rows[0]["airspeed_mps"] == pytest.approx(V)
    assert rows[0]["mean_b"] == pytest.approx(expected, rel=1e-3)
