"""uavdyn: nonlinear longitudinal UAV flight dynamics in CasADi, with a compiled RK4 and a
learned-residual correction that lives in the same compiled CasADi Function.

Typical use::

    import uavdyn
    af = uavdyn.load_airframe("aerosonde")
    point = uavdyn.trim(af, airspeed=25.0)
    model = uavdyn.physics_step(af)         # DiscreteModel: (x, u, p, dt) -> x_next
    model.state_names                       # body, then actuator/delay states of the airframe
    x0 = model.initial_state(point.x, point.u)
    traj = uavdyn.free_run(model, x0, [point.u] * 100, af.p, 0.01)

``uavdyn.hybrid_step(weights, airframe)`` gives the same object with a learned correction;
``uavdyn.rk4_step(f)`` is the bare RK4 of a right-hand side (it knows no actuator states).

Sub-packages, each importing only those before it: ``airframes``, ``model``, ``linear``,
``integrate``, ``flightdata``, ``emulation``, ``learned``, ``evaluation``, ``mpc``, ``deploy``,
``experiments``, ``cli``. torch and matplotlib are imported only where they are used.
"""

from uavdyn.airframes import Airframe, load_airframe, perturb
from uavdyn.integrate import (
    DiscreteModel,
    free_run,
    physics_step,
    reference_step,
    rk4_step,
    rollout,
    simulate,
)
from uavdyn.learned import hybrid_step
from uavdyn.linear import trim
from uavdyn.model import build_model

__version__ = "0.5.0"
__all__ = ["Airframe", "load_airframe", "perturb", "build_model", "trim", "DiscreteModel",
           "physics_step", "hybrid_step", "rk4_step",
           "rollout", "reference_step", "simulate", "free_run", "__version__"]
