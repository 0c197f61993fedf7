"""The longitudinal model: ``ops`` namespaces, forces per airframe kind, rigid-body equations,
and :func:`build_model` turning them into CasADi Functions of ``(x, u, p)``."""

from uavdyn.model.atmosphere import isa_density, isa_density_ratio
from uavdyn.model.build import (
    LongitudinalModel,
    build_model,
    numpy_rhs,
    sortie_params,
    uses_alpha_dot,
)
from uavdyn.model.equations import (
    CONTROL_BOUNDS,
    CONTROL_NAMES,
    FORCE_MODELS,
    FORCE_NAMES,
    air_density,
    body_forces,
    fixed_wing_alpha_dot,
    fixed_wing_forces,
    lateral_inputs,
    make_rhs,
    multirotor_forces,
    propeller_thrust,
    rigid_body_rates,
    rotor_thrust,
    stall_blend,
    symbolic_params,
    translational_accelerations,
)
from uavdyn.model.interpolation import interp1, interp2
from uavdyn.model.ops import CASADI_OPS, NUMPY_OPS, torch_ops
from uavdyn.model.ranges import (
    PITCH_LIMIT,
    PITCH_RATE_LIMIT,
    SPEED_LIMIT,
    Departure,
    first_departure,
    state_limits,
)
from uavdyn.model.structure import (
    LAG_PARAMS,
    LATERAL_INPUT_NAMES,
    POSITION_STATE_NAMES,
    SLEW_PARAMS,
    STATE_NAMES,
    ModelStructure,
    structure_of,
)

__all__ = ["LongitudinalModel", "build_model", "numpy_rhs", "uses_alpha_dot", "sortie_params",
           "isa_density", "isa_density_ratio", "air_density", "body_forces", "interp1",
           "interp2", "LAG_PARAMS", "LATERAL_INPUT_NAMES", "SLEW_PARAMS", "ModelStructure",
           "structure_of",
           "CONTROL_BOUNDS",
           "CONTROL_NAMES",
           "FORCE_MODELS", "FORCE_NAMES", "fixed_wing_alpha_dot", "fixed_wing_forces",
           "multirotor_forces", "propeller_thrust", "rotor_thrust", "POSITION_STATE_NAMES",
           "STATE_NAMES", "lateral_inputs", "make_rhs", "rigid_body_rates", "stall_blend",
           "symbolic_params",
           "translational_accelerations", "CASADI_OPS", "NUMPY_OPS", "torch_ops", "PITCH_LIMIT",
           "PITCH_RATE_LIMIT", "SPEED_LIMIT", "Departure", "first_departure", "state_limits"]
