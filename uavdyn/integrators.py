"""Symbolic integrators: an RK4 step generated from the CasADi model, ``mapaccum`` rollouts,
and a tight-tolerance CVODES reference step with the same signature.

Every step Function has the signature ``(x, u, p, dt) -> x_next`` with the control held constant
over the step (zero-order hold), so solvers are always compared on the same input grid.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

STEP_INPUTS = ["x", "u", "p", "dt"]


def _step_symbols(f: ca.Function, sym=ca.SX):
    nx, nu, n_p = (f.size1_in(i) for i in range(3))
    return sym.sym("x", nx), sym.sym("u", nu), sym.sym("p", n_p), sym.sym("dt")


def rk4_step(f: ca.Function, name: str = "rk4_step") -> ca.Function:
    """Classical RK4 step of ``f(x, u, p)`` as one SX Function ``(x, u, p, dt) -> x_next``."""
    x, u, p, dt = _step_symbols(f)
    k1 = f(x, u, p)
    k2 = f(x + dt / 2 * k1, u, p)
    k3 = f(x + dt / 2 * k2, u, p)
    k4 = f(x + dt * k3, u, p)
    x_next = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return ca.Function(name, [x, u, p, dt], [x_next], STEP_INPUTS, ["x_next"])


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


def rollout(step: ca.Function, n_steps: int, name: str = "rollout") -> ca.Function:
    """``n_steps`` steps as one MX Function ``(x0, u[nu x N], p, dt) -> x[nx x N]`` (states after
    each step) built with ``mapaccum``: a loop in the generated C, not N unrolled copies."""
    if n_steps < 1:
        raise ValueError(f"n_steps must be >= 1, got {n_steps}")
    nx, nu, n_p = (step.size1_in(i) for i in range(3))
    x0, U, p, dt = ca.MX.sym("x0", nx), ca.MX.sym("u", nu, n_steps), ca.MX.sym("p", n_p), \
        ca.MX.sym("dt")
    # Fold parameters and step size into the accumulated state so they are not copied N times.
    z = ca.SX.sym("z", nx + n_p + 1)
    uk = ca.SX.sym("uk", nu)
    xz, pz, dtz = z[:nx], z[nx:nx + n_p], z[nx + n_p]
    body = ca.Function("body", [z, uk], [ca.vertcat(step(xz, uk, pz, dtz), pz, dtz), ])
    # Only the state rows are wanted as output: a second function extracts them per step.
    acc = body.mapaccum("acc", n_steps)
    Z = acc(ca.vertcat(x0, p, dt), U)
    return ca.Function(name, [x0, U, p, dt], [Z[:nx, :]], ["x0", "u", "p", "dt"], ["x"])


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


def simulate(step: ca.Function, x0, controls, p, dt: float) -> np.ndarray:
    """Numeric rollout: returns the trajectory ``(N+1) x nx`` including ``x0``; ``controls`` is
    ``N x nu`` (row k held over step k)."""
    controls = np.atleast_2d(np.asarray(controls, dtype=float))
    n = controls.shape[0]
    traj = np.asarray(rollout(step, n)(np.asarray(x0, float), controls.T, np.asarray(p, float),
                                       dt))
    return np.vstack([np.asarray(x0, float).reshape(1, -1), traj.T])


def rk4_numpy(rhs, x0, controls, p, dt: float) -> np.ndarray:
    """Plain Python/NumPy RK4 loop (the baseline a user would write by hand), same signature
    and output as :func:`simulate`; ``rhs`` is e.g. :func:`uavdyn.model.numpy_rhs`."""
    controls = np.atleast_2d(np.asarray(controls, dtype=float))
    p = np.asarray(p, dtype=float)
    out = np.empty((controls.shape[0] + 1, len(x0)))
    x = out[0] = np.asarray(x0, dtype=float)
    for k, u in enumerate(controls):
        k1 = rhs(x, u, p)
        k2 = rhs(x + dt / 2 * k1, u, p)
        k3 = rhs(x + dt / 2 * k2, u, p)
        k4 = rhs(x + dt * k3, u, p)
        x = out[k + 1] = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return out
