"""Linear analysis: trim, linearisation and modes (continuous model and discrete maps)."""

from uavdyn.linear.modes import (
    DiscreteModeComparison,
    Mode,
    discrete_map_modes,
    linearise,
    mode_table,
    modes,
    participation,
)
from uavdyn.linear.trim import TrimError, TrimPoint, stall_speed, trim

__all__ = ["DiscreteModeComparison", "Mode", "discrete_map_modes", "linearise", "mode_table",
           "modes", "participation", "TrimError", "TrimPoint", "stall_speed", "trim"]
