"""Step Functions: explicit RK steps generated from the CasADi model (one tableau routine), and
a tight-tolerance CVODES reference step with the same signature.

Every step Function has the signature ``(x, u, p, dt) -> x_next`` with the control held constant
over the step (zero-order hold), so solvers are always compared on the same input grid.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from uavdyn.integrate.tableau import RK4, ButcherTableau, explicit_rk_step

STEP_INPUTS = ["x", "u", "p", "dt"]


def _step_symbols(f: ca.Function, sym=ca.SX):
    nx, nu, n_p = (f.size1_in(i) for i in range(3))
    return sym.sym("x", nx), sym.sym("u", nu), sym.sym("p", n_p), sym.sym("dt")


def rk_step(f: ca.Function, tableau: ButcherTableau = RK4, name: str | None = None
            ) -> ca.Function:
    """Explicit RK step of ``f(x, u, p)`` with the control held over the step, as one SX
    Function ``(x, u, p, dt) -> x_next``.

    Parameters
    ----------
    f : casadi.Function
        Right-hand side ``(x, u, p) -> x_dot``.
    tableau : ButcherTableau
        The method (default classical RK4).
    name : str, optional
        Function name (default ``"<tableau>_step"``).
    """
    x, u, p, dt = _step_symbols(f)
    x_next = explicit_rk_step(tableau, lambda xx: f(xx, u, p), x, dt)
    return ca.Function(name or f"{tableau.name}_step", [x, u, p, dt], [x_next], STEP_INPUTS,
                       ["x_next"])


def rk4_step(f: ca.Function, name: str = "rk4_step") -> ca.Function:
    """Classical RK4 step of ``f(x, u, p)`` as one SX Function ``(x, u, p, dt) -> x_next``."""
    return rk_step(f, RK4, name)


def substepped(step: ca.Function, substeps: int, name: str | None = None) -> ca.Function:
    """A step of size dt made of ``substeps`` steps of dt/substeps (a finer solver on the same
    zero-order-held control grid)."""
    if substeps < 1:
        raise ValueError(f"substeps must be >= 1, got {substeps}")
    x, u, p, dt = _step_symbols(step, ca.MX)
    inner = step.mapaccum(f"{step.name()}_sub", substeps)
    xs = inner(x, ca.repmat(u, 1, substeps), ca.repmat(p, 1, substeps),
               ca.repmat(dt / substeps, 1, substeps))
    return ca.Function(name or f"{step.name()}_x{substeps}", [x, u, p, dt], [xs[:, -1]],
                       STEP_INPUTS, ["x_next"])


def reference_step(f: ca.Function, tol: float = 1e-12, name: str = "cvodes_step") -> ca.Function:
    """CVODES (BDF/Adams, variable step) over one zero-order-held step at tight tolerance, as a
    Function with the RK4 step's signature. Time is rescaled to [0, 1] so ``dt`` is an input."""
    x, u, p, dt = _step_symbols(f)
    dae = {"x": x, "p": ca.vertcat(u, p, dt), "ode": dt * f(x, u, p)}
    opts = {"abstol": tol, "reltol": tol, "max_num_steps": 200000}
    integ = ca.integrator(f"{name}_integrator", "cvodes", dae, 0.0, 1.0, opts)
    X, U, P, DT = _step_symbols(f, ca.MX)
    xf = integ(x0=X, p=ca.vertcat(U, P, DT))["xf"]
    return ca.Function(name, [X, U, P, DT], [xf], STEP_INPUTS, ["x_next"])


def rk4_numpy(rhs, x0, controls, p, dt: float) -> np.ndarray:
    """Plain Python/NumPy RK4 loop (the baseline a user would write by hand) with the same
    tableau code as the CasADi step; returns the ``(N+1) x nx`` trajectory, ``x0`` first.
    ``rhs`` is e.g. :func:`uavdyn.model.numpy_rhs`."""
    controls = np.atleast_2d(np.asarray(controls, dtype=float))
    p = np.asarray(p, dtype=float)
    out = np.empty((controls.shape[0] + 1, len(x0)))
    x = out[0] = np.asarray(x0, dtype=float)
    for k, u in enumerate(controls):
        x = out[k + 1] = explicit_rk_step(RK4, lambda xx, u=u: rhs(xx, u, p), x, dt)
    return out
