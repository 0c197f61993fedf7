"""Tracking MPC with any step Function (physics or hybrid) as its prediction model: full SQP
and real-time iteration, a status policy that never applies a failed solve, closed-loop
scenarios and studies."""

from uavdyn.mpc.policy import SOURCES, Controller, MPCResult
from uavdyn.mpc.problem import DEFAULT_RATE_LIMITS, MPCConfig, TrackingProblem
from uavdyn.mpc.rti import QP_SOLVERS, RTIController, SQPController
from uavdyn.mpc.scenarios import SCENARIO_NAMES, SCENARIOS, Scenario, run_scenario, scenario
from uavdyn.mpc.tracking import (
    RELU_SMOOTHING,
    ClosedLoopResult,
    TrackingMPC,
    build_controller,
    emulator_plant,
    fly_closed_loop,
    physics_plant,
    step_plant,
)

__all__ = ["DEFAULT_RATE_LIMITS", "QP_SOLVERS", "RELU_SMOOTHING", "SCENARIO_NAMES", "SCENARIOS",
           "SOURCES", "ClosedLoopResult", "Controller", "MPCConfig", "MPCResult",
           "RTIController", "SQPController", "Scenario", "TrackingMPC", "TrackingProblem",
           "build_controller",
           "emulator_plant", "fly_closed_loop", "physics_plant", "run_scenario", "scenario",
           "step_plant"]
