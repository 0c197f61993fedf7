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

import importlib

__version__ = "0.5.0"

# what ``import uavdyn`` offers, each loaded on first use (PEP 562): the package itself stays
# light, so the command line can load its heavy modules where Ctrl-C is still caught
_EXPORTS = {"Airframe": "airframes", "load_airframe": "airframes", "perturb": "airframes",
            "build_model": "model", "trim": "linear", "DiscreteModel": "integrate",
            "physics_step": "integrate", "rk4_step": "integrate", "rollout": "integrate",
            "reference_step": "integrate", "simulate": "integrate", "free_run": "integrate",
            "hybrid_step": "learned"}
_SUBPACKAGES = frozenset({"airframes", "model", "linear", "integrate", "flightdata", "emulation",
                          "identify", "learned", "evaluation", "mpc", "montecarlo", "deploy",
                          "experiments", "cli", "interrupts", "outputs", "safefiles"})
__all__ = ["Airframe", "load_airframe", "perturb", "build_model", "trim", "DiscreteModel",
           "physics_step", "hybrid_step", "rk4_step",
           "rollout", "reference_step", "simulate", "free_run", "__version__"]


def __getattr__(name: str):
    """An export or a sub-package, imported when first asked for."""
    if name in _EXPORTS:
        value = getattr(importlib.import_module(f"uavdyn.{_EXPORTS[name]}"), name)
    elif name in _SUBPACKAGES:
        value = importlib.import_module(f"uavdyn.{name}")
    else:
        raise AttributeError(f"module 'uavdyn' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS) | _SUBPACKAGES)
