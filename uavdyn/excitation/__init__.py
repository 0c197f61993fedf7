"""Flight-test input design: the excitation a user should fly to identify the parameters they
want (3-2-1-1, doublets and Schroeder multisines timed from the airframe's own modes, inside its
``[limits]``), written as a CSV schedule and as ArduPilot SYSID-mode parameters where they
exist, with the standard errors the model predicts such a flight would give."""

from uavdyn.excitation.design import (
    SIGNALS,
    DesignError,
    ExcitationDesign,
    design_input,
    pitch_mode,
)
from uavdyn.excitation.predict import emulate_design, predict_errors
from uavdyn.excitation.signals import relative_peak_factor, schroeder_multisine

__all__ = ["SIGNALS", "DesignError", "ExcitationDesign", "design_input", "emulate_design",
           "pitch_mode", "predict_errors", "relative_peak_factor", "schroeder_multisine"]
