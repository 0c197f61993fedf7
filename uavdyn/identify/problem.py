"""The output-error NLP: compiled residual and Jacobian, Gauss-Newton Hessian, IPOPT solve."""

from __future__ import annotations

import math
import os
import tempfile

import casadi as ca
import numpy as np
from tqdm import tqdm

from uavdyn.identify.windows import (
    N_BODY,
    Windows,
    window_commands,
    window_function,
    window_preroll,
)
from uavdyn.integrate import compile_function, find_compiler
from uavdyn.integrate.augmented import physics_function
from uavdyn.model import ModelStructure

IPOPT_TOL = 1e-9  # on the gradient of the cost (unit: weighted residual ~ its noise)
COMPILE_FLAGS = ("-O1", "-fPIC", "-shared")


class _Problem:
    """The weighted residual of one window set as CasADi Functions of the decision vector
    ``z = [theta; dx]`` and the data: ``p = p_ref + scale * theta`` for the chosen parameters,
    and each window starts from ``x0_recorded + noise * dx`` (its initial body state is
    estimated too, with the recorded one as a measurement of standard deviation ``noise``: noisy
    start states would otherwise bias the estimates) and its lag states from the pre-roll.

    Everything data-dependent (windows, delayed commands, density ratios, weights, noise,
    ``p_ref``, ``scale``) is an input, so the compiled code depends only on the shape of the
    problem and is reused across delay candidates (and from the disk cache across runs)."""

    def __init__(self, structure: ModelStructure, index: list[int], n_windows: int, L: int,
                 preroll: int, sample_dt: float, substeps: int, rho_index: int | None,
                 estimate_x0: bool):
        step = physics_function(structure, substeps=substeps)
        nu, n_p = structure.nu, structure.np
        n_lag = structure.n_actuator
        W = n_windows
        self.index, self.n_theta = index, len(index)
        self.n_dx = N_BODY * W if estimate_x0 else 0
        self.W, self.L, self.M, self.n_lag, self.n_p = W, L, preroll, n_lag, n_p
        window = window_function(step, n_p, structure.tau_indices, rho_index, L, preroll,
                                 sample_dt)
        mapped = window.map(W, "thread", 2)
        z = ca.MX.sym("z", self.n_theta + self.n_dx)
        theta, dx = z[:self.n_theta], z[self.n_theta:]
        self.layout = [("x0", N_BODY, W), ("u", nu, L * W), ("v", n_lag, preroll * W),
                       ("y", N_BODY, L * W), ("ratio", 1, W), ("weights", N_BODY, 1),
                       ("noise", N_BODY, 1), ("p_ref", n_p, 1), ("scale", self.n_theta, 1)]
        n_data = sum(r * c for _, r, c in self.layout)
        data = ca.MX.sym("data", n_data)
        part, offset = {}, 0
        for name, rows, cols in self.layout:
            part[name] = ca.reshape(data[offset:offset + rows * cols], rows, cols)
            offset += rows * cols
        p = part["p_ref"]
        if self.n_theta:
            delta = ca.MX(n_p, 1)
            delta[index] = part["scale"] * theta
            p = p + delta
        start = part["x0"]
        if estimate_x0:
            start = start + ca.reshape(dx, N_BODY, W) * ca.repmat(part["noise"], 1, W)
        args = [ca.repmat(p, 1, W), part["ratio"], start]
        if n_lag:
            args.append(part["v"])
        pred = mapped(*args, part["u"])
        r = ca.vertcat(ca.vec((pred - part["y"]) * ca.repmat(part["weights"], 1, L * W)), dx)
        J = ca.jacobian(r, z)
        # -O1: as fast as -O3 here, and compiles in two thirds of the time
        self.residual = compile_function(ca.Function("oe_residual", [z, data], [r]),
                                         flags=COMPILE_FLAGS, warn=False)
        self.jacobian = compile_function(ca.Function("oe_jacobian", [z, data], [r, J]),
                                         flags=COMPILE_FLAGS, warn=False)
        self.hess = _GaussNewtonHessian(self.jacobian, self.n_theta + self.n_dx, n_data)
        self.nlp = {"x": z, "p": data, "f": 0.5 * ca.sumsqr(r)}
        self._solver = None
        self._bar: _IterationBar | None = None
        self._jit_dir: tempfile.TemporaryDirectory | None = None

    def pack(self, windows: Windows, structure: ModelStructure, delays, ratios: np.ndarray,
             weights: np.ndarray, noise: np.ndarray, p_ref: np.ndarray, scale: np.ndarray
             ) -> np.ndarray:
        """The data vector for the windows with the commands delayed by ``delays``."""
        W, L, M = self.W, self.L, self.M
        v = window_preroll(windows, M, delays, structure.lag_indices) if self.n_lag else None
        blocks = {
            "x0": windows.x0.T, "u": window_commands(windows, delays).reshape(W * L, -1).T,
            "v": v.reshape(W * M, -1).T if v is not None else np.zeros((0, 0)),
            "y": windows.y.reshape(W * L, -1).T, "ratio": ratios[None, :],
            "weights": weights[:, None], "noise": noise[:, None], "p_ref": p_ref[:, None],
            "scale": scale[:, None]}
        return np.concatenate([np.asarray(blocks[name], float).ravel(order="F")
                               for name, _, _ in self.layout])

    def cost(self, z: np.ndarray, data: np.ndarray) -> float:
        r = np.asarray(self.residual(z, data)).ravel()
        value = 0.5 * float(r @ r)
        return value if math.isfinite(value) else math.inf

    def evaluate(self, z: np.ndarray, data: np.ndarray):
        """Residual (dense) and Jacobian (scipy sparse) at ``z``."""
        r, J = self.jacobian(z, data)
        return np.asarray(r).ravel(), J.sparse()

    def solve(self, z0: np.ndarray, data: np.ndarray, lower: np.ndarray, upper: np.ndarray,
              max_iterations: int, progress: bool) -> tuple[np.ndarray, dict]:
        """IPOPT from ``z0`` (the solver is built, and JIT-compiled, once per problem)."""
        if self._solver is None:
            self._bar = _IterationBar(len(z0), len(data))
            options = {"hess_lag": self.hess, "ipopt.print_level": 0, "print_time": False,
                       "ipopt.max_iter": max_iterations, "ipopt.tol": IPOPT_TOL,
                       "ipopt.mu_init": 1e-4, "ipopt.acceptable_iter": 2,
                       "ipopt.acceptable_tol": 1e-4, "ipopt.acceptable_obj_change_tol": 1e-10,
                       "ipopt.sb": "yes", "iteration_callback": self._bar}
            self._jit_dir = tempfile.TemporaryDirectory(prefix="uavdyn-identify-")
            if find_compiler() is not None:  # the NLP's functions as C (10x faster)
                options.update({"jit": True, "compiler": "shell",
                                "jit_options": {"flags": list(COMPILE_FLAGS[:1]), "verbose": False,
                                                "directory": self._jit_dir.name + os.sep}})
            cwd = os.getcwd()
            os.chdir(self._jit_dir.name)  # CasADi writes its JIT source into the working folder
            try:
                self._solver = ca.nlpsol("oe", "ipopt", self.nlp, options)
            finally:
                os.chdir(cwd)
        self._bar.start(max_iterations if progress else None)
        try:
            sol = self._solver(x0=z0, p=data, lbx=lower, ubx=upper)
        finally:
            self._bar.stop()
        return np.array(sol["x"]).ravel(), self._solver.stats()

    def close(self) -> None:
        self._solver = None
        if self._jit_dir is not None:
            self._jit_dir.cleanup()
            self._jit_dir = None



class _GaussNewtonHessian(ca.Callback):
    """IPOPT's Lagrangian Hessian ``sigma * triu(J^T J)`` from the compiled Jacobian (sparse
    product in SciPy: several times faster than the same product in the NLP's own graph)."""

    def __init__(self, jacobian: ca.Function, n_z: int, n_data: int):
        ca.Callback.__init__(self)
        self.jacobian = jacobian
        self.n_z, self.n_data = n_z, n_data
        ones = ca.DM(jacobian.sparsity_out(1), 1.0)  # positive: no entry cancels in J^T J
        self.pattern = ca.triu(ca.mtimes(ones.T, ones)).sparsity()
        self.rows, self.cols = (np.array(a) for a in self.pattern.get_triplet())
        self.construct("hess_gn", {})

    def get_n_in(self):
        return 4

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return ("x", "p", "lam_f", "lam_g")[i]

    def get_name_out(self, i):
        return "hess"

    def get_sparsity_in(self, i):
        return (ca.Sparsity.dense(self.n_z, 1), ca.Sparsity.dense(self.n_data, 1),
                ca.Sparsity.dense(1, 1), ca.Sparsity(0, 1))[i]

    def get_sparsity_out(self, i):
        return self.pattern

    def eval(self, arg):
        J = self.jacobian(arg[0], arg[1])[1].sparse()
        H = (J.T @ J).tocsr()
        values = np.asarray(H[self.rows, self.cols]).ravel() * float(arg[2])
        return [ca.DM(self.pattern, values)]


class _IterationBar(ca.Callback):
    """An IPOPT iteration callback driving a tqdm bar while one is started."""

    def __init__(self, n_x: int, n_p: int):
        ca.Callback.__init__(self)
        self.sizes = {"x": n_x, "lam_x": n_x, "lam_p": n_p, "f": 1, "g": 0, "lam_g": 0}
        self.bar = None
        self.construct("identify_progress", {})

    def start(self, total: int | None) -> None:
        """Show a bar of ``total`` iterations (None: no bar)."""
        self.bar = None if total is None else tqdm(
            total=total, desc="identify (IPOPT iterations)", unit="it", leave=False)

    def stop(self) -> None:
        if self.bar is not None:
            self.bar.close()
        self.bar = None

    def get_n_in(self):
        return ca.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return ca.nlpsol_out(i)

    def get_name_out(self, i):
        return "ret"

    def get_sparsity_in(self, i):
        n = self.sizes.get(ca.nlpsol_out(i), 0)
        return ca.Sparsity.dense(n, 1) if n else ca.Sparsity(0, 0)

    def eval(self, arg):
        if self.bar is not None:
            self.bar.update()
        return [0]
