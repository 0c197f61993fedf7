"""Flight-data emulation: a richer truth model, wind and turbulence, autopilot, missions and the
seeded dataset generator."""

from uavdyn.emulation.datagen import Recipe, generate_dataset, shipped_recipe
from uavdyn.emulation.emulator import (
    REFERENCE_NAMES,
    WIND_NAMES,
    Emulator,
    dryden_gusts,
    gust_span,
    open_loop_references,
    wind_in_body,
)
from uavdyn.emulation.envelope import Envelope, envelope
from uavdyn.emulation.missions import (
    MISSIONS,
    MissionError,
    MissionUnflyable,
    missions_for,
    plan_mission,
    unflyable_missions,
)

__all__ = ["Recipe", "generate_dataset", "shipped_recipe", "REFERENCE_NAMES", "WIND_NAMES",
           "Emulator", "dryden_gusts", "gust_span", "wind_in_body", "open_loop_references",
           "Envelope", "envelope", "MISSIONS", "MissionError", "MissionUnflyable",
           "missions_for", "plan_mission", "unflyable_missions"]
