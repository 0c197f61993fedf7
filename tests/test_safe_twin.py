"""The safe trainer's compiled twin (``uavdyn.learned.safe.twin``, issue 32): on a non-preset
fixed wing with lagged actuators and a non-preset quadrotor, with a gated (with and without
the steady box) and bounded network and command memory, its window free runs equal torch's
and its loss gradient equals torch's autograd, to round-off; after the final checks rescale
the outputs and the bound, it still follows the model."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from uavdyn.airframes import load_airframe
from uavdyn.integrate import find_compiler
from uavdyn.learned import CorrectionNet
from uavdyn.learned.envelope import Envelope, SteadyBox
from uavdyn.learned.formulations import CorrectionLayout, network_inputs
from uavdyn.learned.safe.data import WindowTensors
from uavdyn.learned.safe.scoring import WindowLoss, torch_rollout
from uavdyn.learned.safe.twin import CompiledTwin
from uavdyn.learned.stability import TrimSample, stability_penalty
from uavdyn.learned.torch_model import TorchCorrection
from uavdyn.linear import trim
from uavdyn.model import structure_of

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
DT, MEMORY, H, W = 0.01, (0.05, 0.2), 40, 5
pytestmark = pytest.mark.skipif(find_compiler() is None, reason="no C compiler")


def _model(airframe, point, seed: int, inputs: str = "state",
           output: str = "acceleration", linear: bool = False,
           steady: bool = False) -> TorchCorrection:
    structure = structure_of(airframe)
    n_state = structure.nx() + 2 * len(MEMORY)
    layout = CorrectionLayout(structure, MEMORY, inputs=inputs, output=output)
    n_in = layout.n_inputs
    rng = np.random.default_rng(seed)
    sizes = [n_in, 6, 6, 6, 3]
    weights = tuple(rng.normal(0, 2.0 / math.sqrt(a), (b, a))
                    for a, b in zip(sizes[:-1], sizes[1:]))
    biases = tuple(rng.normal(0, 0.3, n) for n in sizes[1:])
    z_trim = np.asarray(structure_layout_state(airframe, point), float)
    centre = network_inputs(layout, z_trim[None], np.asarray(point.u)[None], airframe.p)[0][0]
    width = np.concatenate([[3.0, 1.0, 0.5, 0.2], np.full(n_in - 4, 0.1)])
    if inputs == "physical" and airframe.kind == "fixed_wing":  # alpha, V, q c/2V, ...
        width = np.concatenate([[0.1, 3.0, 0.02, 0.02], np.full(n_in - 4, 0.1)])
    elif inputs == "physical":  # u, w, q, thrust per weight, rotor speed times u, w; ...
        width = np.concatenate([[3.0, 1.0, 0.5, 0.2, 3.0, 1.0], np.full(n_in - 6, 0.1)])
    net = CorrectionNet(
        formulation="improved", activation="relu", kind=airframe.kind,
        airframe_hash=airframe.param_hash(), dt=DT, weights=weights, biases=biases,
        in_mean=centre, in_scale=width, out_mean=np.zeros(3), out_scale=np.array([0.5, 2, 3]),
        n_state=n_state, memory_tau=MEMORY,
        envelope=Envelope(centre - width, centre + width, 0.5 * width,
                          _steady_box(centre, width) if steady else None),
        out_bound=np.array([1.0, 3.0, 2.0]), inputs=inputs, output=output,
        skip=rng.normal(0, 0.3, (3, n_in)) if linear else None)
    return TorchCorrection.from_net(net, structure)


def _steady_box(centre: np.ndarray, width: np.ndarray) -> SteadyBox:
    """A steady box a third of the envelope's width about the trim, the pitch-rate input
    (third) free and weighing the steadiness over a twentieth of its width: the windows'
    pitch rates cross from steady to manoeuvring."""
    inv_fade = 1.0 / (0.2 * width)
    inv_fade[2] = 0.0
    rate = np.zeros(len(width))
    rate[2] = 1.0 / (0.05 * width[2])
    return SteadyBox(centre - 0.3 * width, centre + 0.3 * width, inv_fade, rate)


def structure_layout_state(airframe, point):
    from uavdyn.integrate import StateLayout

    layout = StateLayout(structure_of(airframe), MEMORY)
    return layout.states(np.asarray(point.x, float), point.u, airframe.p, DT)[0]


def _windows(airframe, point, seed: int) -> WindowTensors:
    rng = np.random.default_rng(seed)
    z_trim = np.asarray(structure_layout_state(airframe, point), float)
    z0 = z_trim + np.concatenate([[0.5, 0.3, 0.05, 0.02], np.zeros(len(z_trim) - 4)]) \
        * rng.normal(size=(W, len(z_trim)))
    u = point.u + 0.03 * rng.normal(size=(W, H, 2))
    y = np.tile(point.x, (W, H, 1)) + 0.05 * rng.normal(size=(W, H, 4))
    p = np.tile(airframe.p, (W, 1)) * (1 + 0.01 * rng.normal(size=(W, len(airframe.p))))
    t = (torch.as_tensor(a) for a in (z0, u, y, p, rng.uniform(0.5, 2.0, W)))
    return WindowTensors(*t)


@pytest.mark.parametrize("file, speed, inputs, output, linear, steady", [
    ("trainer.toml", None, "state", "acceleration", False, False),
    ("trainer.toml", None, "physical", "coefficient", True, True),
    ("x500.toml", 0.0, "state", "acceleration", True, False),
    ("x500.toml", 0.0, "physical", "acceleration", False, True)])
def test_twin_free_runs_and_gradients_equal_torchs(file, speed, inputs, output, linear, steady):
    airframe = load_airframe(EXAMPLES / file)
    if airframe.kind == "fixed_wing":  # lagged, rate-limited actuators: an augmented state
        airframe = airframe.replace(tau_elevator=0.04, tau_throttle=0.15, slew_throttle=0.5)
    point = trim(airframe, speed)
    model = _model(airframe, point, 7, inputs, output, linear, steady)
    assert (model.skip is not None) == linear
    assert (model.envelope.steady is not None) == steady
    D = _windows(airframe, point, 4)
    scale, growth = np.array([1.0, 0.5, 0.1, 0.05]), np.linspace(1.0, 3.0, H)
    twin = CompiledTwin(model, H, DT, scale, growth)
    with torch.no_grad():
        expected = torch_rollout(model, D.z0, D.u, D.p.T, DT).numpy()
    np.testing.assert_allclose(twin.predict(model, D), expected, rtol=1e-11, atol=1e-11)
    if steady:  # the steady box changes these windows' flight (the test is not vacuous)
        with torch.no_grad():
            plain = torch_rollout(_model(airframe, point, 7, inputs, output, linear),
                                  D.z0, D.u, D.p.T, DT).numpy()
        assert np.max(np.abs(plain - expected)) > 1e-6

    loss = WindowLoss(torch.as_tensor(scale), torch.as_tensor(growth), 0.3, DT)
    model.zero_grad()
    value = loss(model, D)
    value.backward()
    got_value, flat = twin.loss_and_grad(model, D, 0.3)
    grads = twin.unflatten(flat)
    assert got_value == pytest.approx(float(value.detach()), rel=1e-11)
    # a layer whose units the windows leave dead has a gradient of round-off only: the
    # tolerance is relative to the largest gradient of any weight
    scale_all = max(np.abs(param.grad.numpy()).max() for param in model.parameters())
    for param, grad in zip(model.parameters(), grads):
        np.testing.assert_allclose(grad, param.grad.numpy(), rtol=1e-8, atol=1e-10 * scale_all)
    assert any(np.abs(g).max() > 0 for g in grads)

    # the stability penalty at two trims held to abscissas they exceed (a complex pair and a
    # real eigenvalue can lead): value and gradient against torch's eigenvalues' autograd
    trims = [TrimSample(0.0, 0.0, np.asarray(structure_layout_state(airframe, pt), float),
                        np.asarray(pt.u, float), np.asarray(airframe.p, float))
             for pt in (point, trim(airframe, speed, gamma=0.05) if speed is None
                       else trim(airframe, 3.0))]
    targets = [-40.0, -25.0]
    model.zero_grad()
    pen = stability_penalty(model, trims, targets, DT)
    pen.backward()
    got_pen, pen_flat = twin.penalty_and_grad(model, trims, targets, DT)
    assert float(pen.detach()) > 0 and got_pen == pytest.approx(float(pen.detach()), rel=1e-10)
    for param, grad in zip(model.parameters(), twin.unflatten(pen_flat)):
        np.testing.assert_allclose(grad, param.grad.numpy(), rtol=1e-7,
                                   atol=1e-9 * np.abs(param.grad.numpy()).max())

    # the final checks scale the outputs and the bound: the twin reads both at each call
    with torch.no_grad():
        model.out_scale.mul_(0.5)
    model.layout = dataclasses.replace(model.layout, bound=model.layout.bound * 0.5)
    with torch.no_grad():
        expected = torch_rollout(model, D.z0, D.u, D.p.T, DT).numpy()
    np.testing.assert_allclose(twin.predict(model, D), expected, rtol=1e-11, atol=1e-11)


def test_a_short_training_run_is_the_same_on_both_routes(tmp_path):
    """Two epochs on emulated data with a pitch-moment error: the compiled route's history
    (losses, validation errors, penalty) equals torch's to round-off, epoch by epoch, and both
    end the same way."""
    from emulated_data import emulated_dataset

    from uavdyn.flightdata import load_dataset
    from uavdyn.learned.safe import SafeConfig, train_safe

    airframe = load_airframe(EXAMPLES / "trainer.toml")
    truth = airframe.replace(C_m_0=airframe.params.C_m_0 + 0.01,
                             C_m_q=airframe.params.C_m_q * 0.8)
    sorties = load_dataset(emulated_dataset(tmp_path / "data", truth, 6, 6.0)).sorties
    results = [train_safe(sorties[:4], sorties[4:], airframe,
                          SafeConfig(epochs=2, batches_per_epoch=2, batch_windows=6,
                                     horizon_s=1.0, progress=False, memory_tau=(0.1,),
                                     compiled=compiled))
               for compiled in (True, False)]
    compiled, torch_route = results
    assert len(compiled.history) == len(torch_route.history) == 3
    for a, b in zip(compiled.history, torch_route.history):
        for key in ("val_theta_rmse", "train_loss_fixed", "val_loss_fixed", "train_loss",
                    "stability_penalty"):
            if key in a:
                assert a[key] == pytest.approx(b[key], rel=1e-7, abs=1e-12), key
    assert (compiled.kept, compiled.best_epoch, compiled.stopped) == \
        (torch_route.kept, torch_route.best_epoch, torch_route.stopped)
