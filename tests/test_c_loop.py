"""Rollouts as a plain C loop around the step (``uavdyn.integrate.compiled_rollout``): the same
states as CasADi's ``mapaccum`` rollout in the VM, to the last bit or round-off, for a lagged
physics step with sub-steps, the shipped hybrid step and a time-dependent step; NumPy in and
out; wrong input sizes refused; without a compiler, the VM rollout itself."""

import casadi as ca
import numpy as np
import pytest

from uavdyn.integrate import compiled_rollout, find_compiler, physics_step, rollout
from uavdyn.integrate.c_loop import NativeRollout, generated_body
from uavdyn.learned.hybrid import hybrid_step, shipped_correction, shipped_identified
from uavdyn.linear import trim

needs_cc = pytest.mark.skipif(find_compiler() is None, reason="no C compiler")


def _doublets(u0: np.ndarray, n: int) -> np.ndarray:
    controls = np.tile(u0, (n, 1))
    phase = np.arange(n) % 100
    controls[phase < 10, 0] += 0.03
    controls[(phase >= 10) & (phase < 20), 0] -= 0.03
    controls[phase >= 60, 1] = np.clip(controls[phase >= 60, 1] + 0.2, 0, 1)
    return controls


@needs_cc
@pytest.mark.parametrize("substeps", [1, 3])
def test_physics_loop_equals_the_vm_rollout(aerosonde, substeps):
    af = aerosonde.replace(tau_elevator=0.03, tau_throttle=0.2, slew_throttle=0.5)
    model = physics_step(af)
    point = trim(af, 22.0)
    x0 = np.asarray(model.initial_state(point.x, point.u, af.p, 0.01), float).ravel()
    controls = _doublets(point.u, 400)
    native = compiled_rollout(model, len(controls), substeps)
    assert isinstance(native, NativeRollout)
    got = native(x0, controls.T, af.p, 0.005)
    assert isinstance(got, np.ndarray) and got.shape == (len(x0), len(controls))
    expected = np.array(rollout(model.function, len(controls), substeps)(
        x0, controls.T, af.p, 0.005))
    np.testing.assert_allclose(got, expected, rtol=1e-13, atol=1e-13)
    # u given as a C-ordered nu x N array (a copy on the way in) gives the same
    np.testing.assert_array_equal(native(x0, np.ascontiguousarray(controls.T), af.p, 0.005),
                                  got)


@needs_cc
def test_hybrid_loop_equals_the_vm_rollout():
    airframe = shipped_identified("aerosonde")
    weights, _ = shipped_correction("aerosonde")
    model = hybrid_step(weights, airframe, compile=False)
    point = trim(airframe, 25.0)
    p = np.asarray(airframe.p, float)
    x0 = np.asarray(model.initial_state(point.x, point.u, p, 0.01), float).ravel()
    controls = _doublets(point.u, 300)
    got = compiled_rollout(model, len(controls))(x0, controls.T, p, 0.01)
    expected = np.array(rollout(model.function, len(controls))(x0, controls.T, p, 0.01))
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)


@needs_cc
def test_a_time_dependent_step_gets_the_elapsed_time():
    x, u, p, dt, t = (ca.SX.sym(n) for n in ("x", "u", "p", "dt", "t"))
    step = ca.Function("timed", [x, u, p, dt, t], [x + dt * (u + p * ca.sin(t))],
                       ["x", "u", "p", "dt", "t"], ["x_next"])
    n, h, t0 = 50, 0.1, 0.3
    controls = np.linspace(0, 1, n)[None, :]
    got = compiled_rollout(step, n, substeps=2)(1.0, controls, 2.0, h, t0)
    # the same sum by hand: sub-step j of sample k starts at t0 + (2k + j) h
    xs, value = [], 1.0
    for k in range(n):
        for j in range(2):
            value += h * (controls[0, k] + 2.0 * np.sin(t0 + (2 * k + j) * h))
        xs.append(value)
    np.testing.assert_allclose(got.ravel(), xs, rtol=1e-13)


@needs_cc
def test_wrong_input_sizes_are_refused(aerosonde):
    model = physics_step(aerosonde)
    native = compiled_rollout(model, 10)
    with pytest.raises(ValueError, match="input 1 has 18 values, expected 20"):
        native(np.zeros(4), np.zeros((2, 9)), aerosonde.p, 0.01)
    with pytest.raises(TypeError, match="takes 4 inputs"):
        native(np.zeros(4), np.zeros((2, 10)), aerosonde.p)


def test_without_a_compiler_it_is_the_vm_rollout(aerosonde, monkeypatch):
    monkeypatch.setenv("UAVDYN_CC", "")
    sim = compiled_rollout(physics_step(aerosonde), 20, warn=False)
    assert isinstance(sim, ca.Function) and sim.is_a("MXFunction")


def test_the_loop_calls_the_generated_body_directly():
    source = ("CASADI_SYMBOL_EXPORT int r_step(const casadi_real** arg, casadi_real** res, "
              "casadi_int* iw, casadi_real* w, int mem){\n  return casadi_f3(arg, res, iw, w, "
              "mem);\n}\n")
    assert generated_body(source, "r_step") == "casadi_f3"
    assert generated_body("int other(void);", "r_step") == "r_step"  # not found: the export
