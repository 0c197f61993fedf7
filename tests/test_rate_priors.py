"""Priors on how the correction depends on the pitch rate, on a non-preset fixed wing and a
non-preset quadrotor. The damping prior (``SafeConfig.damping_weight``): the hybrid's pitch
damping the penalty reads equals a central finite difference of the torch step in the pitch
rate, the physics it is compared with equals the CasADi physics step, and the hinge lets a
correction weaken the physics' damping but not turn it positive (a hand-set pitch-rate
feedback). Rates seen only linearly (``SafeConfig.rates_linear``): the output's slope in a
rate is one constant."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from test_safe_twin import DT, _model, _windows

from uavdyn.airframes import load_airframe
from uavdyn.integrate import physics_step
from uavdyn.learned.safe.epochs import damping_penalty
from uavdyn.linear import trim
from uavdyn.model import structure_of

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
CASES = [("trainer.toml", None, "physical", "coefficient", 1.0),
         ("x500.toml", 0.0, "physical", "acceleration", -1.0)]


def _finite_difference_damping(step, D, h: float = 1e-5) -> np.ndarray:
    """``(d q_next / d q - 1) / dt`` of ``step`` at the windows' first steps, central."""
    u0, p = D.u[:, 0], D.p.T
    up, down = D.z0.clone(), D.z0.clone()
    up[:, 2] += h
    down[:, 2] -= h
    with torch.no_grad():
        slope = (step(up, u0, p, DT)[:, 2] - step(down, u0, p, DT)[:, 2]) / (2 * h)
    return ((slope - 1.0) / DT).numpy()


def _setup(file, speed, inputs, output, seed=7):
    airframe = load_airframe(EXAMPLES / file)
    point = trim(airframe, speed)
    return airframe, _model(airframe, point, seed, inputs, output), _windows(airframe, point, 4)


@pytest.mark.parametrize("file, speed, inputs, output, sign", CASES)
def test_the_penalty_is_the_hinge_of_finite_difference_damping(file, speed, inputs, output,
                                                               sign):
    airframe, model, D = _setup(file, speed, inputs, output)
    with torch.no_grad():  # a sign that makes the random network reverse the damping
        model.out_scale.mul_(sign)
    hybrid = _finite_difference_damping(model.step, D)
    physics = _finite_difference_damping(model.step_without_network, D)
    expected = np.mean(np.maximum(hybrid - np.maximum(physics, 0.0), 0.0))
    assert expected > 0.0  # not vacuous
    got = damping_penalty(model, D, DT)
    assert float(got.detach()) == pytest.approx(expected, rel=1e-5)
    model.zero_grad()
    got.backward()  # it trains the network
    assert max(float(prm.grad.abs().max()) for prm in model.parameters()) > 0.0


@pytest.mark.parametrize("file, speed, inputs, output, sign", CASES)
def test_the_step_without_network_is_the_physics_step(file, speed, inputs, output, sign):
    airframe, model, D = _setup(file, speed, inputs, output)
    n_phys = structure_of(airframe).nx()
    physics = physics_step(structure_of(airframe))
    u0 = D.u[:, 0].numpy()
    with torch.no_grad():
        got = model.step_without_network(D.z0, D.u[:, 0], D.p.T, DT).numpy()[:, :n_phys]
    want = np.array([np.asarray(physics(z[:n_phys], u, p, DT)).ravel()
                     for z, u, p in zip(D.z0.numpy(), u0, D.p.numpy())])
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


def test_weakening_the_damping_costs_nothing_reversing_it_does():
    """A network that adds ``g`` to d(q_dot)/dq (its linear path, the other outputs zero):
    no penalty while the hybrid's damping stays negative, then the excess."""
    airframe, model, D = _setup("x500.toml", 0.0, "physical", "acceleration")
    physics = _finite_difference_damping(model.step_without_network, D)
    assert np.all(physics < 0.0)
    with torch.no_grad():
        for layer in model.layers:
            layer.weight.zero_()
            layer.bias.zero_()
        model.skip = torch.nn.Parameter(torch.zeros((3, model.in_mean.numel()),
                                                    dtype=torch.float64))
    q_input = 2  # u, w, q, ...: the pitch rate is the third physical input
    scale = float(model.in_scale[q_input]) / float(model.out_scale[2])
    penalties = []
    for gain in (0.5 * float(-physics.max()), 2.0 * float(-physics.min())):
        with torch.no_grad():
            model.skip[2, q_input] = gain * scale
        hybrid = _finite_difference_damping(model.step, D)
        np.testing.assert_allclose(hybrid - physics, gain, rtol=1e-2)  # RK4's coupling
        expected = np.mean(np.maximum(hybrid, 0.0))
        penalties.append(float(damping_penalty(model, D, DT).detach()))
        assert penalties[-1] == pytest.approx(expected, rel=1e-5, abs=1e-12)
    assert penalties[0] == 0.0 and penalties[1] > 0.5 * float(-physics.min())


@pytest.mark.parametrize("file, kind_rates", [("trainer.toml", ("q_hat", "alpha_dot_hat")),
                                              ("x500.toml", ("q",))])
def test_rates_seen_only_linearly_move_the_output_by_one_constant(file, kind_rates):
    """``SafeConfig.rates_linear``: the hidden layers do not see the rate inputs, before and
    after an optimiser step, so the output's slope in a rate is the same at every input row
    (a stability derivative), while it still varies with the other inputs."""
    from uavdyn.learned.formulations import CorrectionLayout, rate_inputs
    from uavdyn.learned.torch_model import TorchCorrection

    airframe = load_airframe(EXAMPLES / file)
    layout = CorrectionLayout(structure_of(airframe), (0.05, 0.2), inputs="physical")
    rates = rate_inputs(layout)
    assert tuple(layout.input_names()[i] for i in rates) == kind_rates
    n_in = layout.n_inputs
    model = TorchCorrection(airframe.kind, "improved", 6, "relu", np.zeros(n_in),
                            np.ones(n_in), np.ones(3), DT, seed=3, structure=layout.structure,
                            layout=layout, linear=True, linear_only=rates)
    rng = np.random.default_rng(5)
    rows = torch.as_tensor(rng.normal(size=(64, n_in)))
    opt = torch.optim.Adam(model.parameters(), lr=0.05)
    first = model.layers[0].weight.detach().clone()
    for _ in range(3):  # make the network's output nonlinear and the step touch every weight
        opt.zero_grad()
        torch.sum(torch.sin(3.0 * rows[:, :1]) * model(rows)).backward()
        opt.step()
        model.hold_linear_only()
    weight = model.layers[0].weight.detach()
    assert torch.all(weight[:, list(rates)] == 0.0)
    assert torch.any(weight != first)  # it trained
    h = 1e-6
    for i in rates:
        up, down = rows.clone(), rows.clone()
        up[:, i] += h
        down[:, i] -= h
        with torch.no_grad():
            slope = ((model(up) - model(down)) / (2 * h)).numpy()
        np.testing.assert_allclose(slope, np.broadcast_to(slope[0], slope.shape),
                                   rtol=1e-6, atol=1e-9)
    other = next(i for i in range(n_in) if i not in rates)
    up = rows.clone()
    up[:, other] += h
    with torch.no_grad():
        slope = ((model(up) - model(rows)) / h).numpy()
    assert np.ptp(slope, axis=0).max() > 1e-3  # the hidden layers still act on the others


def test_rates_seen_only_linearly_need_the_linear_path():
    from uavdyn.learned.torch_model import TorchCorrection

    with pytest.raises(ValueError, match="linear path"):
        TorchCorrection("multirotor", "improved", 4, "relu", np.zeros(6), np.ones(6),
                        np.ones(3), DT, linear=False, linear_only=(2,))


@pytest.mark.parametrize("gain", [0.0, 3.0])
def test_map_pitch_damping_moves_by_a_pitch_feedback_gain(gain):
    """``uavdyn.learned.stability.map_pitch_damping`` (``uavdyn evaluate``'s
    ``damping_reversed``): a hand-set network ``q_dot += gain q`` moves the CasADi hybrid
    map's pitch damping from the physics' by ``gain`` at every state of a sortie; the
    physics' own is the linearisation's ``A[q, q]`` at trim."""
    from test_safe_correction import MEMORY, _pitch_feedback_net

    from uavdyn.integrate import StateLayout
    from uavdyn.learned import hybrid_step
    from uavdyn.learned.stability import map_pitch_damping
    from uavdyn.linear import linearise

    airframe = load_airframe(EXAMPLES / "trainer.toml")
    point = trim(airframe, 14.0)
    rng = np.random.default_rng(2)
    x = np.asarray(point.x, float) + np.array([0.5, 0.2, 0.05, 0.02]) * rng.normal(size=(20, 4))
    u = np.tile(np.asarray(point.u, float), (20, 1))
    layout = StateLayout(structure_of(airframe), MEMORY)
    z = np.array([layout.states(xi, ui, airframe.p, DT)[0] for xi, ui in zip(x, u)])
    hybrid = hybrid_step(_pitch_feedback_net(airframe, gain), airframe, compile=False)
    step = 1e-4  # a short step: the map's damping is the rate's derivative to O(dt A g)
    got = map_pitch_damping(hybrid, z, u, airframe.p, step)
    structure = structure_of(airframe)
    physics = physics_step(structure)
    own = map_pitch_damping(physics, z[:, :structure.nx()], u, airframe.p, step)
    np.testing.assert_allclose(got - own, gain, rtol=1e-2, atol=1e-5)
    z_trim = StateLayout(structure, ()).states(point.x, point.u, airframe.p, step)[0]
    at_trim = map_pitch_damping(physics, np.atleast_2d(z_trim), np.asarray(point.u)[None],
                                airframe.p, step)
    A, _ = linearise(airframe, point, actuators=False)
    assert at_trim[0] == pytest.approx(A[2, 2], rel=2e-3)
