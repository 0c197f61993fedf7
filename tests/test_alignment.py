"""Alignment of the evaluation code: physics RK4 scored against its own fine-step reference
must show only RK4's truncation error (below 1e-8 rad in pitch) in every mode. An off-by-one
between predicted and target samples, a control applied one interval early or late, or a
window restarted from the wrong state would show as errors of order 1e-4 rad or more."""

import numpy as np
import pytest

from uavdyn.airframes import load_airframe
from uavdyn.evaluation import MODES, Solver, evaluate_trajectory, fine_reference
from uavdyn.integrate import physics_step
from uavdyn.linear import trim


def doublets(airframe, duration=20.0, dt=0.01):
    """Trim, then alternating doublets on the pitch control (elevator or pitch command)."""
    point = trim(airframe)
    t = np.arange(int(round(duration / dt)) + 1) * dt
    U = np.tile(point.u, (len(t), 1))
    col, amp = (0, 0.02) if airframe.kind == "fixed_wing" else (1, 0.05)
    for k, start in enumerate(np.arange(1.0, duration - 2.0, 3.0)):
        sign = (-1) ** k
        U[(t >= start) & (t < start + 0.5), col] += sign * amp
        U[(t >= start + 0.5) & (t < start + 1.0), col] -= sign * amp
    return t, point.x, U


@pytest.mark.parametrize("name", ["aerosonde", "f450"])
@pytest.mark.parametrize("dt", [0.005, 0.01])
def test_physics_scored_against_its_own_reference_is_exact_to_truncation(name, dt):
    af = load_airframe(name)
    t, x0, U = doublets(af)
    ref = fine_reference(af, t, x0, U, af.p)
    solver = Solver("rk4", physics_step(af), dt)
    res = evaluate_trajectory(solver, t, ref, U, af.p)
    assert "refused" not in res
    for mode in MODES:
        pred, target = res[mode]
        assert pred.shape == target.shape
        rmse = float(np.sqrt(np.mean((pred[..., 3] - target[..., 3]) ** 2)))
        assert rmse <= 1e-8, (mode, rmse)
    # the same comparison one sample out of step is far off: the check can fail
    pred, target = res["free_run"]
    shifted = float(np.sqrt(np.mean((pred[1:, 3] - target[:-1, 3]) ** 2)))
    assert shifted > 1e-5
