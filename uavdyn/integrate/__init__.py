"""Integration: explicit RK steps from a Butcher tableau, the discrete model object
(:class:`DiscreteModel`), the physics step on the augmented state (actuator lags, transport
delays), the CVODES reference step, rollouts with ``mapaccum``, the
evaluation grid, input profiles and the compile-to-C cache."""

from uavdyn.integrate.augmented import (
    actuator_rest,
    advance_actuators,
    augmented_rk_step,
    memory_state_names,
    memory_update,
    physics_function,
)
from uavdyn.integrate.codegen import (
    CacheError,
    CodegenWarning,
    CompileError,
    CompileTimeout,
    cache_dir,
    compile_function,
    find_compiler,
    generate_c,
)
from uavdyn.integrate.discrete import (
    DiscreteModel,
    StateLayout,
    StepUseError,
    StepUseWarning,
    actuator_history,
    augment_states,
    body_model,
    model_function,
    physics_step,
    step_jacobians,
)
from uavdyn.integrate.rollout import (
    DEPARTURE_RAD,
    DIVERGENCE_BOUND,
    DivergenceError,
    EvalGrid,
    GridError,
    check_delay_grid,
    check_departure,
    check_finite,
    check_use,
    compiled_rollout,
    fitting_steps,
    free_run,
    predict_windows,
    rollout,
    simulate,
    sortie_free_run,
    sortie_p,
    step_states,
    substeps_for,
    takes_time,
    window_rollouts,
)
from uavdyn.integrate.start_fit import estimate_start
from uavdyn.integrate.steps import (
    STEP_INPUTS,
    reference_step,
    rk4_numpy,
    rk4_step,
    rk_step,
    substepped,
)
from uavdyn.integrate.tableau import EULER, HEUN, RK4, ButcherTableau, explicit_rk_step

__all__ = ["actuator_history", "actuator_rest", "advance_actuators", "augment_states",
           "augmented_rk_step", "memory_state_names", "memory_update", "physics_function",
           "physics_step", "DiscreteModel", "StateLayout", "body_model", "model_function",
           "step_jacobians",
           "CacheError", "CodegenWarning", "CompileError", "CompileTimeout", "cache_dir",
           "compile_function",
           "find_compiler", "generate_c", "DEPARTURE_RAD", "DIVERGENCE_BOUND",
           "DivergenceError", "EvalGrid", "GridError", "fitting_steps", "substeps_for",
           "StepUseError", "StepUseWarning", "check_delay_grid", "check_departure",
           "check_finite", "check_use",
           "estimate_start",
           "predict_windows", "window_rollouts", "sortie_free_run", "sortie_p",
           "step_states",
           "free_run", "rollout", "compiled_rollout",
           "simulate", "takes_time", "STEP_INPUTS", "reference_step", "rk4_numpy", "rk4_step",
           "rk_step", "substepped", "EULER", "HEUN", "RK4", "ButcherTableau", "explicit_rk_step"]
