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


def test_network_parts_add_up_to_what_the_hybrid_step_adds(residuals):
    """The network's pitch acceleration split into its linear path and its hidden layers
    sums to what the CasADi hybrid step adds to the physics step over one step (over dt; the
    residual is held over the RK4 step, so up to the damping's effect within it); without a
    linear path the linear part is zero and the hidden part unchanged."""
    import dataclasses

    import torch

    from uavdyn.learned.formulations import CorrectionLayout, network_inputs
    from uavdyn.learned.hybrid import hybrid_step
    from uavdyn.learned.torch_model import TorchCorrection
    from uavdyn.model import structure_of

    airframe = load_airframe(EXAMPLES / "trainer.toml")
    dt = 5e-4  # the physics' pitch damping (about -40 1/s) acts on the held residual
    sortie = _doublet_flight(airframe, dt, 1000)  # within the step: dt |M_q| / 2 = 1 %
    structure = structure_of(airframe)
    layout = CorrectionLayout(structure, (), inputs="physical", output="coefficient")
    phys = physics_step(airframe)
    z = phys.initial_state(sortie.true_states[:-1], sortie.controls[:-1], None, dt)
    inp, _ = network_inputs(layout, z, sortie.controls[:-1], phys.p)
    model = TorchCorrection("fixed_wing", "improved", 6, "relu", inp.mean(axis=0),
                            inp.std(axis=0) + 1e-6, np.full(3, 2e-3), dt, seed=2,
                            structure=structure, layout=layout, linear=True)
    gen = torch.Generator().manual_seed(4)
    with torch.no_grad():
        model.layers[-1].weight.normal_(0.0, 0.5, generator=gen)
        model.skip.normal_(0.0, 0.5, generator=gen)
    net = model.export(airframe.param_hash())
    hybrid = hybrid_step(net, airframe, compile=False)
    parts = residuals.network_parts(net, hybrid, sortie)
    added = (hybrid.step_rows(z, sortie.controls[:-1], hybrid.p, dt)[:, 2]
             - phys.step_rows(z, sortie.controls[:-1], phys.p, dt)[:, 2]) / dt
    total = parts["network_linear"] + parts["network_hidden"]
    assert np.ptp(parts["network_linear"]) > 1e-3 and np.ptp(parts["network_hidden"]) > 1e-3
    np.testing.assert_allclose(added, total, rtol=2e-2, atol=1e-3 * np.abs(total).max())
    assert np.all(parts["network_gate"] == 1.0)
    without = residuals.network_parts(dataclasses.replace(net, skip=None), hybrid, sortie)
    assert np.all(without["network_linear"] == 0.0)
    np.testing.assert_allclose(without["network_hidden"], parts["network_hidden"], rtol=1e-12)
