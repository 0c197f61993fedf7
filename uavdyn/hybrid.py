"""The hybrid step: the physics RK4 step plus the learned correction as ONE CasADi Function
``(x, u, p, dt) -> x_next`` (``paper`` formulation: ``(x, u, p, dt, t)``), compiled to C, with
``mapaccum`` rollouts and exact Jacobians for ``nlpsol``/``Opti``.

No torch at run time: the network comes from a weight file through :mod:`uavdyn.correction`.
"""

from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np

from uavdyn.correction import (
    HYPERSOLVER_ORDER,
    CorrectionNet,
    WeightFileError,
    load_weights,
    mlp_expression,
)
from uavdyn.integrators import STEP_INPUTS, rk4_step
from uavdyn.model import build_model

WEIGHTS_DIR = Path(__file__).resolve().parents[1] / "data" / "weights"


def shipped_weights(airframe_name: str) -> Path:
    """Path of the shipped default weights for a preset (``aerosonde`` or ``f450``)."""
    return WEIGHTS_DIR / f"{airframe_name}_improved.npz"


def _rk4_with_residual(f: ca.Function, x, u, p, dt, accel):
    """RK4 of ``f(x, u, p) + [accel; 0]``: the learned residual acceleration acts on u, w, q
    only, so ``theta_dot = q`` is untouched."""
    extra = ca.vertcat(accel, ca.SX.zeros(x.numel() - accel.numel()))

    def rhs(xx):
        return f(xx, u, p) + extra

    k1 = rhs(x)
    k2 = rhs(x + dt / 2 * k1)
    k3 = rhs(x + dt / 2 * k2)
    k4 = rhs(x + dt * k3)
    return x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def hybrid_step(net: CorrectionNet | str | Path, airframe=None, compile: bool = True,
                name: str = "hybrid_step", relu_smoothing: float | None = None
                ) -> ca.Function:
    """Build the hybrid step of ``net`` (a :class:`CorrectionNet` or a weight-file path).

    ``airframe`` (optional) is checked against the weights' airframe hash when loading a file.
    The result is one SX Function (one C function when ``compile``), so its Jacobians are exact
    and it can be embedded in ``rollout``/``Opti``/``nlpsol`` like the plain RK4 step.
    ``relu_smoothing`` (see :func:`uavdyn.correction.mlp_expression`) is for optimisers only.
    """
    if not isinstance(net, CorrectionNet):
        net = load_weights(net, airframe)
    elif airframe is not None and airframe.param_hash() != net.airframe_hash:
        raise WeightFileError(f"correction network key 'airframe_hash' is {net.airframe_hash} "
                              f"but airframe '{airframe.name}' has {airframe.param_hash()}")
    f = build_model(net.kind).f
    nx, nu, n_p = (f.size1_in(i) for i in range(3))
    x, u, p, dt = ca.SX.sym("x", nx), ca.SX.sym("u", nu), ca.SX.sym("p", n_p), ca.SX.sym("dt")
    if net.formulation == "improved":
        accel = mlp_expression(net, ca.vertcat(x, u), relu_smoothing)
        x_next = _rk4_with_residual(f, x, u, p, dt, accel)
        inputs, names = [x, u, p, dt], list(STEP_INPUTS)
    else:
        base = rk4_step(f)(x, u, p, dt)
        if net.formulation == "paper":
            t = ca.SX.sym("t")
            x_next = base + mlp_expression(net, ca.vertcat(t, base), relu_smoothing)
            inputs, names = [x, u, p, dt, t], [*STEP_INPUTS, "t"]
        else:  # hypersolver
            x_next = base + dt**HYPERSOLVER_ORDER * mlp_expression(net, ca.vertcat(x, u),
                                                                   relu_smoothing)
            inputs, names = [x, u, p, dt], list(STEP_INPUTS)
    step = ca.Function(name, inputs, [x_next], names, ["x_next"])
    if compile:
        from uavdyn.codegen import compile_function

        step = compile_function(step)
    return step


def hybrid_jacobian(net: CorrectionNet | str | Path, airframe=None, compile: bool = True,
                    name: str = "hybrid_jacobian") -> ca.Function:
    """``(x, u, p, dt[, t]) -> (x_next, A = dx_next/dx, B = dx_next/du)`` by exact algorithmic
    differentiation of the hybrid step, compiled to C like the step itself.

    A compiled step (``casadi.external``) carries no derivative code, so solvers should either
    embed the uncompiled SX step (``hybrid_step(..., compile=False)``; CasADi differentiates it
    exactly and ``nlpsol`` can ``jit`` it) or use this function for linearisation.
    """
    step = hybrid_step(net, airframe, compile=False)
    args = [ca.SX.sym(step.name_in(i), step.sparsity_in(i)) for i in range(step.n_in())]
    x_next = step(*args)
    jac = ca.Function(name, args, [x_next, ca.jacobian(x_next, args[0]),
                                   ca.jacobian(x_next, args[1])],
                      [step.name_in(i) for i in range(step.n_in())], ["x_next", "A", "B"])
    if compile:
        from uavdyn.codegen import compile_function

        jac = compile_function(jac)
    return jac


def hybrid_rollout(step: ca.Function, n_steps: int, name: str = "hybrid_rollout") -> ca.Function:
    """``n_steps`` hybrid steps with ``mapaccum``: ``(x0, u[nu x N], p, dt) -> x[nx x N]``, and for
    the ``paper`` step (5 inputs) ``(x0, u, p, dt, t0) -> x`` with ``t_k = t0 + k dt``."""
    if step.n_in() == 4:
        from uavdyn.integrators import rollout

        return rollout(step, n_steps, name)
    if n_steps < 1:
        raise ValueError(f"n_steps must be >= 1, got {n_steps}")
    nx, nu, n_p = (step.size1_in(i) for i in range(3))
    z = ca.SX.sym("z", nx + n_p + 2)  # [x, p, dt, t] carried through the loop
    uk = ca.SX.sym("uk", nu)
    xz, pz, dtz, tz = z[:nx], z[nx:nx + n_p], z[nx + n_p], z[nx + n_p + 1]
    body = ca.Function("body", [z, uk], [ca.vertcat(step(xz, uk, pz, dtz, tz), pz, dtz,
                                                    tz + dtz)])
    acc = body.mapaccum("acc", n_steps)
    x0, U = ca.MX.sym("x0", nx), ca.MX.sym("u", nu, n_steps)
    p, dt, t0 = ca.MX.sym("p", n_p), ca.MX.sym("dt"), ca.MX.sym("t0")
    Z = acc(ca.vertcat(x0, p, dt, t0), U)
    return ca.Function(name, [x0, U, p, dt, t0], [Z[:nx, :]], ["x0", "u", "p", "dt", "t0"],
                       ["x"])


def free_run(step: ca.Function, x0, controls, p, dt: float, substeps: int = 1,
             t0: float = 0.0, compile: bool = True) -> np.ndarray:
    """Open-loop replay of logged controls (``N x nu``, row k held over one sample interval of
    ``substeps * dt``): returns the ``(N+1) x nx`` states at the sample times, ``x0`` first."""
    controls = np.atleast_2d(np.asarray(controls, dtype=float))
    if substeps < 1:
        raise ValueError(f"substeps must be >= 1, got {substeps}")
    U = np.repeat(controls, substeps, axis=0).T
    sim = hybrid_rollout(step, U.shape[1])
    if compile:
        from uavdyn.codegen import compile_function

        sim = compile_function(sim)
    args = [np.asarray(x0, float), U, np.asarray(p, float), float(dt)]
    if step.n_in() == 5:
        args.append(float(t0))
    traj = np.array(sim(*args))[:, substeps - 1::substeps]
    return np.vstack([np.asarray(x0, float).reshape(1, -1), traj.T])


def sortie_free_run(step: ca.Function, sortie, p, dt: float) -> np.ndarray:
    """Free run of ``step`` through a logged sortie from its first state with its controls
    (``dt`` must divide the sample interval): states at the sample times, ``N x nx``. A
    ``paper`` step sees the sortie's own time stamps as its time input."""
    sample_dt = float(np.median(np.diff(sortie.time)))
    substeps = int(round(sample_dt / dt))
    if substeps < 1 or abs(substeps * dt - sample_dt) > 1e-9 * max(1.0, sample_dt):
        raise ValueError(f"dt {dt:g} s must divide the sample interval {sample_dt:g} s of "
                         f"sortie '{sortie.name}'")
    return free_run(step, sortie.states[0], sortie.controls[:-1], p, dt, substeps,
                    t0=float(sortie.time[0]), compile=not step.is_a("External"))


def pitch_rmse(step: ca.Function, sorties, p, dt: float) -> float:
    """Free-run pitch RMSE (rad) over all samples of ``sorties`` (pooled)."""
    errs = [sortie_free_run(step, s, p, dt)[:, 3] - s.states[:, 3] for s in sorties]
    return float(np.sqrt(np.mean(np.concatenate(errs) ** 2)))
