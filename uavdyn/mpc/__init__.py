"""Tracking MPC with any step Function (physics or hybrid) as its prediction model."""

from uavdyn.mpc.tracking import (
    RELU_SMOOTHING,
    SCENARIOS,
    ClosedLoopResult,
    MPCConfig,
    MPCResult,
    Scenario,
    TrackingMPC,
    emulator_plant,
    fly_closed_loop,
    physics_plant,
    run_scenario,
    step_plant,
)

__all__ = ["RELU_SMOOTHING", "SCENARIOS", "ClosedLoopResult", "MPCConfig", "MPCResult",
           "Scenario", "TrackingMPC", "emulator_plant", "fly_closed_loop", "physics_plant",
           "run_scenario", "step_plant"]
