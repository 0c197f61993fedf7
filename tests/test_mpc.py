"""The tracking MPC flies the emulator (the "real aircraft") through a pitch step and a climb;
every solve succeeds and the tracked quantity settles."""

import math

import numpy as np
import pytest

from uavdyn.emulation import Emulator
from uavdyn.integrate import rk4_step
from uavdyn.model import build_model
from uavdyn.mpc import MPCConfig, TrackingMPC, emulator_plant, fly_closed_loop


@pytest.fixture(scope="module")
def setup(aerosonde, aerosonde_trim):
    emulator = Emulator(aerosonde)
    x0 = emulator.initial_state(aerosonde_trim.x, aerosonde_trim.u, 100.0)
    mpc = TrackingMPC(rk4_step(build_model(aerosonde).f), aerosonde.kind, aerosonde.p,
                      aerosonde_trim.u, MPCConfig(horizon=20, dt=0.05))
    return mpc, emulator_plant(emulator, 0.05), x0


def test_pitch_step_settles_on_the_emulator(setup, aerosonde_trim):
    mpc, plant, x0 = setup
    step = math.radians(5.0)

    def theta_ref(t):
        return aerosonde_trim.x[3] + np.where(t >= 0.5, step, 0.0)

    result = fly_closed_loop(mpc, plant, x0, aerosonde_trim.u, 80, theta_ref,
                             lambda t: np.full_like(t, 100.0), 25.0, weights=(100.0, 0.0, 1.0))
    assert result.success.all()
    err = np.abs(result.states[1:, 3] - result.theta_ref)
    assert err[result.time[1:] >= 3.0].max() < math.radians(0.2)  # settled within 0.2 deg
    assert result.states[:, 3].max() > aerosonde_trim.x[3] + 0.9 * step  # and it did move
    # control bounds and rate bounds hold
    assert np.all(np.abs(np.diff(result.controls[:, 0])) <= mpc.rates[0] * 0.05 + 1e-9)
    assert np.all(result.controls[:, 1] <= 1 + 1e-9) and np.all(result.controls[:, 1] >= -1e-9)


def test_climb_tracks_altitude_ramp(setup, aerosonde_trim):
    mpc, plant, x0 = setup

    def h_ref(t):
        return 100.0 + 2.0 * np.clip(t - 0.5, 0.0, None)

    result = fly_closed_loop(mpc, plant, x0, aerosonde_trim.u, 100, lambda t: 0 * t + 0.05,
                             h_ref, 25.0, weights=(1.0, 1.0, 1.0))
    assert result.success.all()
    assert result.states[-1, 4] > 108.0  # climbed (ramp reaches 109 m at t = 5 s)
    assert result.rmse("h", t_from=2.0) < 0.5


def test_bad_configuration(aerosonde, aerosonde_trim):
    step = rk4_step(build_model(aerosonde).f)
    with pytest.raises(ValueError, match="horizon must be >= 1"):
        TrackingMPC(step, aerosonde.kind, aerosonde.p, aerosonde_trim.u, MPCConfig(horizon=0))
    with pytest.raises(ValueError, match="solver must be 'sqp' or 'ipopt'"):
        TrackingMPC(step, aerosonde.kind, aerosonde.p, aerosonde_trim.u, MPCConfig(solver="x"))
    mpc = TrackingMPC(step, aerosonde.kind, aerosonde.p, aerosonde_trim.u, MPCConfig(horizon=3))
    with pytest.raises(ValueError, match=r"x0 must be \[u, w, q, theta, h\]"):
        mpc.solve(aerosonde_trim.x, aerosonde_trim.u, 0.0, 100.0, 25.0)


def test_hybrid_prediction_model_solves(aerosonde, aerosonde_trim):
    """The hybrid step (shipped weights, ReLU smoothed for SQP) inside the MPC: every solve
    succeeds and the pitch settles."""
    from uavdyn.learned import hybrid_step, shipped_weights
    from uavdyn.mpc import RELU_SMOOTHING

    step = hybrid_step(shipped_weights("aerosonde"), aerosonde, compile=False,
                       relu_smoothing=RELU_SMOOTHING)
    emulator = Emulator(aerosonde)
    x0 = emulator.initial_state(aerosonde_trim.x, aerosonde_trim.u, 100.0)
    mpc = TrackingMPC(step, aerosonde.kind, aerosonde.p, aerosonde_trim.u,
                      MPCConfig(horizon=20, dt=0.05))
    result = fly_closed_loop(mpc, emulator_plant(emulator, 0.05), x0, aerosonde_trim.u, 40,
                             lambda t: aerosonde_trim.x[3] + np.where(t >= 0.5, 0.05, 0.0),
                             lambda t: np.full_like(t, 100.0), 25.0, weights=(100.0, 0.0, 1.0))
    assert result.success.all()
    assert abs(result.states[-1, 3] - result.theta_ref[-1]) < math.radians(0.3)


def test_a_diverged_prediction_is_a_failed_solve_and_never_applied(aerosonde, aerosonde_trim):
    """A prediction model that returns NaN makes every solve fail; the closed loop then holds
    the last applied control instead of applying the solver's output."""
    import casadi as ca

    x, u, p, dt = (ca.SX.sym("x", 4), ca.SX.sym("u", 2), ca.SX.sym("p", len(aerosonde.p)),
                   ca.SX.sym("dt"))
    broken = ca.Function("broken", [x, u, p, dt], [x + np.nan * (u[0] + 1.0)],
                         ["x", "u", "p", "dt"], ["x_next"])
    mpc = TrackingMPC(broken, aerosonde.kind, aerosonde.p, aerosonde_trim.u,
                      MPCConfig(horizon=5, dt=0.05, max_iter=3))
    x0 = np.append(aerosonde_trim.x, 100.0)
    res = mpc.solve(x0, aerosonde_trim.u, aerosonde_trim.x[3], 100.0, 25.0)
    assert not res.success

    def plant(xp, uu):
        return x0, x0  # a plant that stays at trim

    u0 = aerosonde_trim.u + [0.01, 0.0]
    result = fly_closed_loop(mpc, plant, x0, u0, 4, lambda t: 0 * t + aerosonde_trim.x[3],
                             lambda t: 0 * t + 100.0, 25.0)
    assert not result.success.any()
    np.testing.assert_array_equal(result.controls, np.tile(u0, (4, 1)))
