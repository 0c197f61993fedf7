"""The timing harness of the benchmarks (``uavdyn.evaluation.c_loop``): several steps in one C
program compute what a plain Python loop over the same steps computes (window restarts, a
command per step or a held one), one timing per pass and step; the recorded-flight workload
starts each window from the step's own state at its first record; bad shapes are refused."""

import casadi as ca
import numpy as np
import pytest

from uavdyn.evaluation.c_loop import CLoop, LoopWork, recorded_workload
from uavdyn.flightdata import Sortie
from uavdyn.integrate import find_compiler, physics_step
from uavdyn.linear import trim

needs_cc = pytest.mark.skipif(find_compiler() is None, reason="no C compiler")


def _decay_step() -> ca.Function:
    """x_next = x + dt (u - p x) on a 2-vector with a 2-vector command."""
    x, u, p, dt = ca.SX.sym("x", 2), ca.SX.sym("u", 2), ca.SX.sym("p"), ca.SX.sym("dt")
    return ca.Function("decay", [x, u, p, dt], [x + dt * (u - p * x)])


def _by_hand(starts, controls, p, dt, n):
    """The last state of ``n`` steps of :func:`_decay_step`, windows restarted."""
    starts = np.atleast_2d(starts)
    controls = np.atleast_2d(controls)
    window = n // len(starts)
    x = None
    for k in range(n):
        if k % window == 0:
            x = starts[k // window].copy()
        x = x + dt * (controls[k % len(controls)] - p * x)
    return x


@needs_cc
def test_two_steps_in_one_program_compute_what_python_computes():
    rng = np.random.default_rng(3)
    starts = rng.normal(size=(4, 2))
    controls = rng.normal(size=(40, 2))
    held = np.array([0.5, -1.0])
    works = [LoopWork(_decay_step(), starts, controls, 0.7, 0.05, 40),
             LoopWork(_decay_step(), np.array([1.0, 2.0]), held, 0.3, 0.1, 25)]
    with CLoop(works) as loop:
        run = loop.run(3)
    assert run.pass_us.shape == (3, 2) and np.all(run.pass_us > 0)
    np.testing.assert_allclose(run.final_states[0], _by_hand(starts, controls, 0.7, 0.05, 40),
                               rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(run.final_states[1],
                               _by_hand(np.array([1.0, 2.0]), held, 0.3, 0.1, 25),
                               rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(run.ratios(1, 0), run.pass_us[:, 1] / run.pass_us[:, 0])


@needs_cc
def test_shapes_that_do_not_fit_are_refused():
    with pytest.raises(ValueError, match="multiple of m"):
        CLoop([LoopWork(_decay_step(), np.zeros((3, 2)), np.zeros(2), 1.0, 0.1, 10)])
    with pytest.raises(ValueError, match="controls must be"):
        CLoop([LoopWork(_decay_step(), np.zeros(2), np.zeros((7, 2)), 1.0, 0.1, 10)])


def test_recorded_windows_start_from_the_steps_own_state(aerosonde):
    af = aerosonde.replace(tau_elevator=0.05, tau_throttle=0.2)  # extra (actuator) states
    model = physics_step(af)
    point = trim(af, 22.0)
    n, dt = 230, 0.01
    rng = np.random.default_rng(1)
    states = np.tile(point.x, (n, 1)) + 0.01 * rng.normal(size=(n, 4))
    controls = np.tile(point.u, (n, 1)) + 0.01 * rng.normal(size=(n, 2))
    sortie = Sortie("s", "fixed_wing", np.arange(n) * dt, states, controls)
    work = recorded_workload(model, [sortie, sortie], 1.0, af.p)
    assert work.window == 100
    assert work.starts.shape == (4, model.function.size1_in(0))  # 2 windows per sortie
    own = np.asarray(model.initial_state(states, controls, af.p, dt), float)
    np.testing.assert_array_equal(work.starts[1], own[100])
    np.testing.assert_array_equal(work.controls[:200], controls[:200])
    np.testing.assert_array_equal(work.controls[200:], controls[:200])
    with pytest.raises(ValueError, match="longer than one window"):
        recorded_workload(model, [sortie], 5.0, af.p)
    wrong = Sortie("m", "multirotor", sortie.time, states, controls[:, :1].repeat(3, axis=1))
    with pytest.raises(ValueError, match="sortie m: 3 command columns"):
        recorded_workload(model, [wrong], 1.0, af.p)
