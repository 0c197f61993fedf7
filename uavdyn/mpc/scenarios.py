"""Closed-loop test scenarios of the tracking MPC (pitch step, climb, speed step) for each
airframe kind, and one function that flies a scenario on the calm emulator.

References start from the measured initial state (trim) and step or ramp at ``start``. The
tracked quantity is the one the scenario is about (pitch, altitude or speed); its RMSE from
``start`` on is the scenario's tracking error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.emulation import Emulator
from uavdyn.linear import TrimPoint
from uavdyn.mpc.policy import Controller
from uavdyn.mpc.tracking import ClosedLoopResult, emulator_plant, fly_closed_loop

SCENARIO_NAMES = ("pitch-step", "climb", "speed-step")
UNITS = {"theta": "rad", "h": "m", "speed": "m/s"}


@dataclass(frozen=True)
class Scenario:
    """A closed-loop test: a pitch step, an altitude ramp or a speed step.

    Attributes
    ----------
    name : str
        ``pitch-step``, ``climb`` or ``speed-step``.
    duration : float
        Seconds flown.
    tracked : str
        ``theta``, ``h`` or ``speed``: the quantity whose RMSE scores the scenario.
    weights : tuple of float
        (pitch, altitude, speed) tracking weights.
    pitch_step_deg, climb_rate, speed_step : float
        Step in the pitch reference (deg), altitude ramp (m/s), step in the speed reference.
    start : float
        When the step or ramp starts (s).
    """

    name: str
    duration: float
    tracked: str
    weights: tuple[float, float, float]
    pitch_step_deg: float = 0.0
    climb_rate: float = 0.0
    speed_step: float = 0.0
    start: float = 0.5

    def references(self, theta0: float, h0: float, speed0: float):
        """``(theta_ref(t), h_ref(t), speed_ref(t))`` from the initial pitch, altitude and
        speed."""
        on = self.start

        def theta_ref(t):
            return theta0 + np.where(t >= on, np.radians(self.pitch_step_deg), 0.0)

        def h_ref(t):
            return h0 + self.climb_rate * np.clip(t - on, 0.0, None)

        def speed_ref(t):
            return speed0 + np.where(t >= on, self.speed_step, 0.0)

        return theta_ref, h_ref, speed_ref

    @property
    def unit(self) -> str:
        return UNITS[self.tracked]


SCENARIOS: dict[str, dict[str, Scenario]] = {
    "fixed_wing": {
        "pitch-step": Scenario("pitch-step", 8.0, "theta", (100.0, 0.0, 1.0),
                               pitch_step_deg=5.0),
        "climb": Scenario("climb", 10.0, "h", (1.0, 1.0, 1.0), climb_rate=2.0),
        "speed-step": Scenario("speed-step", 10.0, "speed", (1.0, 1.0, 10.0),
                               speed_step=3.0),
    },
    "multirotor": {
        "pitch-step": Scenario("pitch-step", 4.0, "theta", (100.0, 1.0, 0.0),
                               pitch_step_deg=3.0),
        "climb": Scenario("climb", 8.0, "h", (1.0, 1.0, 1.0), climb_rate=1.0),
        "speed-step": Scenario("speed-step", 8.0, "speed", (10.0, 1.0, 1.0),
                               speed_step=1.0),
    },
}


def scenario(kind: str, name: str) -> Scenario:
    """The scenario ``name`` of an airframe kind.

    Raises
    ------
    ValueError
        For an unknown scenario name.
    """
    if name not in SCENARIO_NAMES:
        raise ValueError(f"unknown scenario '{name}'; expected one of {SCENARIO_NAMES}")
    return SCENARIOS[kind][name]


def run_scenario(sc: Scenario, mpc: Controller, plant_airframe: Airframe,
                 plant_trim: TrimPoint, altitude: float = 100.0,
                 emulator: Emulator | None = None) -> ClosedLoopResult:
    """Fly one scenario with the controller ``mpc`` (reset first) on the calm emulator of
    ``plant_airframe``, started at its trim ``plant_trim`` at ``altitude``; ``emulator``
    reuses one already built.

    Raises
    ------
    ValueError
        If the MPC interval is not a multiple of the emulator's log interval.
    """
    emulator = emulator or Emulator(plant_airframe)
    x0 = emulator.initial_state(plant_trim.x, plant_trim.u, altitude)
    speed0 = (float(np.hypot(plant_trim.x[0], plant_trim.x[1]))
              if plant_airframe.kind == "fixed_wing" else float(plant_trim.x[0]))
    theta_ref, h_ref, speed_ref = sc.references(float(plant_trim.x[3]), altitude, speed0)
    n = int(round(sc.duration / mpc.config.dt))
    return fly_closed_loop(mpc, emulator_plant(emulator, mpc.config.dt), x0, plant_trim.u, n,
                           theta_ref, h_ref, speed_ref, sc.weights)
