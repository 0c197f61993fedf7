"""Linear analysis: trim, linearisation and modes (continuous model and discrete maps)."""

from uavdyn.linear.modes import (
    DiscreteModeComparison,
    Mode,
    discrete_map_modes,
    linear_state_names,
    linearise,
    mode_table,
    modes,
    participation,
)
from uavdyn.linear.trim import (
    TrimError,
    TrimPoint,
    point_params,
    stall_speed,
    stall_speeds,
    static_lift_coefficient,
    trim,
    trim_many,
    trim_state,
)

__all__ = ["DiscreteModeComparison", "Mode", "discrete_map_modes", "linear_state_names",
           "linearise", "mode_table", "modes", "participation", "TrimError", "TrimPoint",
           "point_params", "stall_speed", "stall_speeds", "static_lift_coefficient", "trim",
           "trim_many", "trim_state"]
