"""uavdyn: nonlinear longitudinal UAV flight dynamics in CasADi, with a compiled RK4 and a
learned-residual correction that lives in the same compiled CasADi Function.

Typical use::

    import uavdyn
    af = uavdyn.load_airframe("aerosonde")
    model = uavdyn.build_model(af)          # CasADi f(x, u, p) -> x_dot, Jacobians
    point = uavdyn.trim(af, airspeed=25.0)
    step = uavdyn.rk4_step(model.f)         # (x, u, p, dt) -> x_next

Sub-packages, each importing only those before it: ``airframes``, ``model``, ``linear``,
``integrate``, ``flightdata``, ``emulation``, ``learned``, ``evaluation``, ``mpc``, ``deploy``,
``experiments``, ``cli``. torch and matplotlib are imported only where they are used.
"""

from uavdyn.airframes import Airframe, load_airframe, perturb
from uavdyn.integrate import free_run, reference_step, rk4_step, rollout, simulate
from uavdyn.linear import trim
from uavdyn.model import build_model

__version__ = "0.2.0"
__all__ = ["Airframe", "load_airframe", "perturb", "build_model", "trim", "rk4_step",
           "rollout", "reference_step", "simulate", "free_run", "__version__"]
