"""The correction's input and output designs (issue 40): ``physical`` inputs are what the
physics says they are (angle of attack, airspeed, q c/2V, alpha-dot c/2V against finite
differences of the physics' own flight, the thrust coefficient), a ``coefficient`` output is
scaled by dynamic pressure as an aerodynamic force is, the weight file keeps the design, and
torch, the CasADi VM and compiled C give the same step on the non-preset airframes."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from uavdyn.airframes import load_airframe
from uavdyn.integrate import StateLayout, find_compiler, physics_step
from uavdyn.learned import CorrectionNet, hybrid_step, load_weights, save_weights
from uavdyn.learned.envelope import Envelope
from uavdyn.learned.formulations import CorrectionLayout, network_inputs
from uavdyn.learned.torch_model import TorchCorrection
from uavdyn.learned.weights import WeightFileError
from uavdyn.linear import trim
from uavdyn.model import propeller_thrust, structure_of, symbolic_params

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
DT, MEMORY = 0.01, (0.05, 0.2)


def _airframe(file: str):
    airframe = load_airframe(EXAMPLES / file)
    if airframe.kind == "fixed_wing":  # lagged actuators: features read the actuator states
        airframe = airframe.replace(tau_elevator=0.05, tau_throttle=0.2)
    return airframe


def _without_lags(airframe):
    """The airframe without actuator states: its controls act at once, so the physics' step
    from a state is its flight."""
    return airframe.replace(**{k: 0.0 for k in ("tau_elevator", "tau_throttle",
                                                "slew_elevator", "slew_throttle")})


def _net(airframe, layout: CorrectionLayout, centre: np.ndarray, seed: int) -> CorrectionNet:
    rng = np.random.default_rng(seed)
    sizes = [layout.n_inputs, 8, 8, 8, 3]
    scale = np.maximum(0.2 * np.abs(centre), 0.05)
    return CorrectionNet(
        formulation="improved", activation="relu", kind=airframe.kind,
        airframe_hash=airframe.param_hash(), dt=DT,
        weights=tuple(rng.normal(0, 1.5 / math.sqrt(a), (b, a))
                      for a, b in zip(sizes[:-1], sizes[1:])),
        biases=tuple(rng.normal(0, 0.2, n) for n in sizes[1:]),
        in_mean=centre, in_scale=scale, out_mean=np.zeros(3),
        out_scale=np.array([0.01, 0.02, 0.005]) if layout.output == "coefficient"
        else np.array([0.3, 0.5, 1.0]),
        n_state=layout.n_state, memory_tau=MEMORY,
        envelope=Envelope(centre - 3 * scale, centre + 3 * scale, scale),
        out_bound=np.array([0.05, 0.1, 0.02]) if layout.output == "coefficient"
        else np.array([2.0, 3.0, 5.0]), inputs=layout.inputs, output=layout.output,
        skip=rng.normal(0, 0.5, (3, layout.n_inputs)))


def _states(airframe, point, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    layout = StateLayout(structure_of(airframe), MEMORY)
    z0 = layout.states(np.asarray(point.x, float)[None], np.asarray(point.u)[None],
                       airframe.p, DT)[0]
    kick = np.concatenate([[0.5, 0.4, 0.1, 0.03], np.full(len(z0) - 4, 0.02)])
    return z0 + kick * rng.normal(size=(n, len(z0))), \
        np.asarray(point.u) + 0.02 * rng.normal(size=(n, 2))


@pytest.mark.parametrize("file, speed, output", [("trainer.toml", None, "coefficient"),
                                                 ("x500.toml", 2.0, "acceleration")])
def test_weight_file_keeps_the_design_and_torch_vm_and_c_agree(file, speed, output, tmp_path):
    airframe = _airframe(file)
    point = trim(airframe, speed)
    layout = CorrectionLayout(structure_of(airframe), MEMORY, inputs="physical", output=output)
    Z, U = _states(airframe, point, 25, 1)
    centre = network_inputs(layout, Z, U, airframe.p)[0].mean(axis=0)
    net = load_weights(save_weights(_net(airframe, layout, centre, 2), tmp_path / "w.npz"),
                       airframe)
    assert (net.inputs, net.output) == ("physical", output) and net.skip.shape == (3, net.n_in)
    assert net.n_in == layout.n_inputs == len(layout.input_names())
    vm = hybrid_step(net, airframe, compile=False)
    module = TorchCorrection.from_net(net, structure_of(airframe))
    with torch.no_grad():
        got = module.step(torch.as_tensor(Z), torch.as_tensor(U), torch.as_tensor(airframe.p),
                          DT).numpy()
    want = np.array([np.array(vm.function(z, u, airframe.p, DT)).ravel() for z, u in zip(Z, U)])
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12)
    plain = physics_step(airframe)
    moved = [np.abs(w[:4] - np.array(plain.function(z[:plain.nx], u, airframe.p, DT))
                    .ravel()[:4]).max() for z, u, w in zip(Z, U, want)]
    assert max(moved) > 1e-6  # the correction acts on these states
    if find_compiler() is not None:
        compiled = hybrid_step(net, airframe)
        c_out = np.array([np.array(compiled.function(z, u, airframe.p, DT)).ravel()
                          for z, u in zip(Z, U)])
        np.testing.assert_allclose(c_out, want, rtol=1e-10, atol=1e-12)


def test_physical_inputs_are_the_physics_own_variables():
    """alpha, V, q c/2V and the thrust coefficient from their definitions; alpha-dot c/2V
    against a central difference of alpha along the physics' own flight (the correction
    reads the physics at the step's start: a causal alpha-dot without a filter)."""
    airframe = _without_lags(load_airframe(EXAMPLES / "trainer.toml"))
    point = trim(airframe)
    structure = structure_of(airframe)
    layout = CorrectionLayout(structure, (), inputs="physical", output="coefficient")
    rng = np.random.default_rng(3)
    X = np.asarray(point.x) + np.array([1.0, 0.8, 0.2, 0.05]) * rng.normal(size=(6, 4))
    U = np.asarray(point.u) + 0.03 * rng.normal(size=(6, 2))
    inp, gains = network_inputs(layout, X, U, airframe.p)
    assert layout.input_names()[:5] == ("alpha", "V", "q_hat", "alpha_dot_hat", "C_thrust")
    P = symbolic_params("fixed_wing", airframe.p)
    V = np.hypot(X[:, 0], X[:, 1])
    qbar = 0.5 * P.rho * V**2
    np.testing.assert_allclose(inp[:, 0], np.arctan2(X[:, 1], X[:, 0]), rtol=1e-14)
    np.testing.assert_allclose(inp[:, 1], V, rtol=1e-14)
    np.testing.assert_allclose(inp[:, 2], X[:, 2] * P.c / (2 * V), rtol=1e-13)
    thrust = np.array([propeller_thrust(P, v, t) for v, t in zip(V, U[:, 1])])
    np.testing.assert_allclose(inp[:, 4], thrust / (qbar * P.S_wing), rtol=1e-12)
    np.testing.assert_allclose(inp[:, 5:], U, rtol=0, atol=0)
    np.testing.assert_allclose(gains[:, 0], qbar * P.S_wing / P.mass, rtol=1e-14)
    np.testing.assert_allclose(gains[:, 2], qbar * P.S_wing * P.c / P.Jy, rtol=1e-14)
    step = physics_step(airframe).function
    h = 1e-4
    for x, u, ad_hat, v in zip(X, U, inp[:, 3], V):
        ahead = np.array(step(x, u, airframe.p, h)).ravel()
        behind = np.array(step(x, u, airframe.p, -h)).ravel()
        alpha_dot = (math.atan2(ahead[1], ahead[0]) - math.atan2(behind[1], behind[0])) / (2 * h)
        assert ad_hat == pytest.approx(alpha_dot * P.c / (2 * v), rel=1e-5, abs=1e-10)


def test_a_constant_coefficient_is_a_force_that_grows_with_dynamic_pressure():
    """A network whose only output is a constant dC_m: its pitch acceleration is
    qbar S c dC_m / Jy at every airspeed (the step's residual, held over the step, against
    the physics' step at two airspeeds)."""
    airframe = _without_lags(load_airframe(EXAMPLES / "trainer.toml"))
    structure = structure_of(airframe)
    layout = CorrectionLayout(structure, (), inputs="physical", output="coefficient")
    n_in, d_cm = layout.n_inputs, 0.004
    weights = tuple(np.zeros(s) for s in ((4, n_in), (4, 4), (4, 4), (3, 4)))
    net = CorrectionNet(
        formulation="improved", activation="relu", kind="fixed_wing",
        airframe_hash=airframe.param_hash(), dt=DT, weights=weights,
        biases=(np.zeros(4), np.zeros(4), np.zeros(4), np.array([0.0, 0.0, d_cm])),
        in_mean=np.zeros(n_in), in_scale=np.ones(n_in), out_mean=np.zeros(3),
        out_scale=np.ones(3), n_state=layout.n_state, inputs="physical", output="coefficient")
    hybrid, plain = hybrid_step(net, airframe, compile=False), physics_step(airframe)
    P = symbolic_params("fixed_wing", airframe.p)
    h = 1e-6  # a tiny step: the increment is the rate times h
    for speed in (13.0, 21.0):
        point = trim(airframe, speed)
        x, u = np.asarray(point.x), np.asarray(point.u)
        dq = (np.array(hybrid.function(x, u, airframe.p, h)).ravel()[2]
              - np.array(plain.function(x, u, airframe.p, h)).ravel()[2]) / h
        qbar = 0.5 * P.rho * speed**2
        assert dq == pytest.approx(qbar * P.S_wing * P.c * d_cm / P.Jy, rel=1e-4)


def test_a_coefficient_output_needs_a_fixed_wing(tmp_path):
    airframe = load_airframe(EXAMPLES / "x500.toml")
    with pytest.raises(ValueError, match="needs a fixed wing"):
        CorrectionLayout(structure_of(airframe), (), inputs="physical", output="coefficient")
    with pytest.raises(ValueError, match="key .inputs. is .aero."):
        CorrectionLayout(structure_of(airframe), (), inputs="aero")
    layout = CorrectionLayout(structure_of(airframe), (), inputs="physical")
    n_in = layout.n_inputs
    with pytest.raises(WeightFileError, match="key 'output' is 'coefficient'"):
        CorrectionNet(formulation="improved", activation="relu", kind="multirotor",
                      airframe_hash=airframe.param_hash(), dt=DT,
                      weights=tuple(np.zeros(s) for s in ((4, n_in), (4, 4), (4, 4), (3, 4))),
                      biases=(np.zeros(4),) * 3 + (np.zeros(3),), in_mean=np.zeros(n_in),
                      in_scale=np.ones(n_in), out_mean=np.zeros(3), out_scale=np.ones(3),
                      inputs="physical", output="coefficient")


def test_a_weight_file_with_an_unknown_design_is_refused_naming_file_and_key(tmp_path):
    airframe = load_airframe(EXAMPLES / "trainer.toml")
    layout = CorrectionLayout(structure_of(airframe), MEMORY, inputs="physical",
                              output="coefficient")
    path = save_weights(_net(airframe, layout, np.ones(layout.n_inputs), 4), tmp_path / "w.npz")
    content = dict(np.load(path))
    content["inputs"] = np.array("aero")
    bad = tmp_path / "bad.npz"
    np.savez(bad, **content)
    with pytest.raises(WeightFileError, match=r"bad\.npz: key 'inputs' is 'aero'"):
        load_weights(bad, airframe)


def test_a_format_5_multirotor_file_with_physical_inputs_is_refused_with_the_reason(tmp_path):
    """Format 6 added the rotor-speed difference to a multirotor's physical inputs: a format-5
    file of that design was trained on other inputs; it is refused, not misread. A format-5
    fixed-wing file of the same design still loads."""
    for file, output, refused in (("x500.toml", "acceleration", True),
                                  ("trainer.toml", "coefficient", False)):
        airframe = load_airframe(EXAMPLES / file)
        layout = CorrectionLayout(structure_of(airframe), MEMORY, inputs="physical",
                                  output=output)
        path = save_weights(_net(airframe, layout, np.ones(layout.n_inputs), 4),
                            tmp_path / f"{airframe.name}.npz")
        content = dict(np.load(path))
        content["format_version"] = np.array(5)
        old = tmp_path / f"{airframe.name}_v5.npz"
        np.savez(old, **content)
        if refused:
            with pytest.raises(WeightFileError, match=r"_v5\.npz: a format-5 multirotor "
                               r"correction with 'physical' inputs .* retrain it"):
                load_weights(old, airframe)
        else:
            assert load_weights(old, airframe).n_in == layout.n_inputs


def test_train_refuses_a_coefficient_output_for_a_multirotor_in_one_line(tmp_path, capsys):
    from emulated_data import emulated_dataset

    from uavdyn.cli.app import main

    airframe = load_airframe(EXAMPLES / "x500.toml")
    data = emulated_dataset(tmp_path / "data", airframe, 4, 4.0)
    out = tmp_path / "w.npz"
    code = main(["train", "--airframe", str(EXAMPLES / "x500.toml"), "--dataset", str(data),
                 "--output", "coefficient", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and not out.exists()
    assert len(err) == 1 and "--output coefficient on multirotor airframe" in err[0]
    assert "needs a fixed wing" in err[0]
