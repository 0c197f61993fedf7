"""``analysis/knockout_residuals.py``: a model's one-step pitch-acceleration error along true
states is zero for the model that flew them and, for a model whose pitching moment differs
by a constant, that moment over the inertia (checked at a held trim, where it is the analytic
``dC_m qbar S c / Jy``); held trims are steady windows. A model's pitch damping is the
linearisation's and moves with ``C_m_q`` as the analytic derivative says; fed the true pitch
rate, a model differing by a constant moment flies as it does, one differing in damping
does not."""


from pathlib import Path

import numpy as np
import pytest
from analysis_scripts import load_script

from uavdyn.airframes import load_airframe
from uavdyn.flightdata.sortie import Sortie
from uavdyn.integrate import physics_step
from uavdyn.linear import trim

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


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


def _doublet_flight(airframe, dt: float, n: int) -> Sortie:
    """The airframe's own flight from trim through an elevator doublet (its true states)."""
    point = trim(airframe, 20.0)
    step = physics_step(airframe)
    controls = np.tile(np.asarray(point.u, float), (n, 1))
    controls[n // 5:2 * n // 5, 0] += 0.05
    controls[2 * n // 5:3 * n // 5, 0] -= 0.05
    z = step.initial_state(np.asarray(point.x, float)[None], controls[:1], None, dt)[0]
    body = [z[:4]]
    for k in range(n - 1):
        z = np.asarray(step(z, controls[k], airframe.p, dt)).ravel()
        body.append(z[:4])
    body = np.array(body)
    return Sortie("doublet", airframe.kind, np.arange(n) * dt, body.copy(), controls,
                  "doublet", {"condition": "calm"}, body)


def test_pitch_damping_is_the_analytic_derivative(residuals):
    """At a held trim: the physics' pitch damping is the linearisation's ``A[q, q]``, and
    a change of ``C_m_q`` moves it by ``dC_m_q rho V S c^2 / (4 Jy)``."""
    from uavdyn.linear import linearise

    airframe = load_airframe(EXAMPLES / "trainer.toml")
    dt, speed, d_cmq = 1e-4, 14.0, -4.0
    sortie = _held_trim(airframe, speed, dt, 50)
    got = residuals.pitch_damping(physics_step(airframe), sortie)
    A, _ = linearise(airframe, trim(airframe, speed), actuators=False)
    np.testing.assert_allclose(got, A[2, 2], rtol=1e-3)
    more = airframe.replace(C_m_q=airframe.params.C_m_q + d_cmq)
    moved = residuals.pitch_damping(physics_step(more), sortie) - got
    P = airframe.params
    V = float(np.hypot(*sortie.true_states[0, :2]))
    np.testing.assert_allclose(moved, d_cmq * P.rho * V * P.S_wing * P.c**2 / (4 * P.Jy),
                               rtol=3e-3)  # the step's second-order term: dt A[q, q] ~ 1.4e-3


def test_rate_feedback_separates_a_damping_change_from_a_moment_offset(residuals):
    """Fed the true pitch rate, a model that differs from (a) by a constant moment flies as
    it does (its difference does not depend on the rate), one that differs by its pitch
    damping does not; a model equal to (a) gives (a)'s figures exactly."""
    airframe = load_airframe(EXAMPLES / "trainer.toml")
    dt = 0.02
    sortie = _doublet_flight(airframe, dt, 400)
    a = physics_step(airframe)
    same = residuals.rate_feedback({"a": a, "corrected": a}, sortie)
    assert same["a"] == same["corrected"]  # (restarts hold the actuators at the command)
    assert same["true_rate"] == pytest.approx(same["a"], rel=1e-9)
    offset = physics_step(airframe.replace(C_m_0=airframe.params.C_m_0 + 0.003))
    got = residuals.rate_feedback({"a": a, "corrected": offset}, sortie)
    assert got["corrected"] > 1e-3
    assert got["true_rate"] == pytest.approx(got["corrected"], rel=1e-3)
    damped = physics_step(airframe.replace(C_m_q=airframe.params.C_m_q - 10.0))
    got = residuals.rate_feedback({"a": a, "corrected": damped}, sortie)
    assert got["corrected"] > 1e-4
    assert abs(got["true_rate"] - got["corrected"]) > 0.05 * got["corrected"]
