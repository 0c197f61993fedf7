"""The output-error least squares: one compiled per-window Function (prediction and its
sensitivities) mapped over the windows, the residual and its sparse Jacobian assembled from
it, and the bounded Levenberg-Marquardt solve (:mod:`uavdyn.identify.lm`).

Only one window's rollout (a ``mapaccum`` loop over its samples) and its forward
sensitivities are generated as C; the windows are a ``map`` over that (two threads), so the
library's size does not grow with the number of windows or samples (SPEC 4: never unroll
thousands of steps)."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import scipy.sparse as sp

from uavdyn.identify.errors import IdentifyError
from uavdyn.identify.lm import solve_bounded
from uavdyn.identify.windows import (
    COMPILE_FLAGS,
    N_BODY,
    Windows,
    window_commands,
    window_function,
    window_preroll,
)
from uavdyn.integrate import compile_function
from uavdyn.integrate.augmented import physics_function
from uavdyn.interrupts import CheckedBar
from uavdyn.model import ModelStructure

MAP_THREADS = 2
CHUNK = 32  # windows per call of the mapped Function (the last chunk padded): one library
            # serves any number of windows


class _Problem:
    """The weighted residual of one window set as a function of ``z = [theta; dx]`` and the
    data: ``p = p_ref + scale * theta`` for the chosen parameters, and each window starts from
    ``x0_recorded + noise * dx`` (its initial body state is estimated too, with the recorded
    one as a measurement of standard deviation ``noise``: noisy start states would otherwise
    bias the estimates) and its lag states from the pre-roll.

    Everything data-dependent (windows, delayed commands, density ratios, weights, noise,
    ``p_ref``, ``scale``, which parameters are fitted) is an input, so the compiled code
    depends only on the model structure, the number of unknowns and the shape of the windows,
    and is reused across delay candidates, parameter choices and runs (the disk cache)."""

    def __init__(self, structure: ModelStructure, index: list[int], n_windows: int, L: int,
                 preroll: int, sample_dt: float, substeps: int, rho_index: int | None,
                 estimate_x0: bool):
        step = physics_function(structure, substeps=substeps)
        n_p, n_lag = structure.np, structure.n_actuator
        self.index, self.n_theta = index, len(index)
        self.estimate_x0 = estimate_x0
        self.n_dx = N_BODY * n_windows if estimate_x0 else 0
        self.W, self.L, self.M, self.n_lag, self.n_p = n_windows, L, preroll, n_lag, n_p
        window = window_function(step, structure, rho_index, L, preroll, sample_dt)
        theta = ca.MX.sym("theta", self.n_theta)
        dx = ca.MX.sym("dx", N_BODY)
        p_ref, scale = ca.MX.sym("p_ref", n_p), ca.MX.sym("scale", self.n_theta)
        noise, ratio, x0 = ca.MX.sym("noise", N_BODY), ca.MX.sym("ratio"), ca.MX.sym("x0", N_BODY)
        u = ca.MX.sym("u", structure.nu, L)
        v = ca.MX.sym("v", n_lag, preroll)
        select = ca.MX.sym("select", n_p, self.n_theta)  # which entries of p theta moves
        p = p_ref + ca.mtimes(select, scale * theta) if self.n_theta else p_ref
        start = x0 + dx * noise if estimate_x0 else x0
        args = [p, ratio, start, *([v] if n_lag else []), u]
        y = window(*args)
        unknowns = ca.vertcat(theta, dx) if estimate_x0 else theta
        inputs = [theta, dx, p_ref, scale, select, noise, ratio, x0, v, u]
        names = ["theta", "dx", "p_ref", "scale", "select", "noise", "ratio", "x0", "v", "u"]
        self._inputs = names
        one = ca.Function("oe_window", inputs, [y], names, ["y"])
        with_jac = ca.Function("oe_window_jac", inputs,
                               [y, ca.jacobian(ca.vec(y), unknowns)], names, ["y", "dy"])
        self.n_chunks = -(-n_windows // CHUNK)
        self._widths = {n: one.size2_in(i) for i, n in enumerate(names)}
        self.predict = compile_function(one.map(CHUNK, "thread", MAP_THREADS),
                                        flags=COMPILE_FLAGS, warn=False)
        self.sensitivities = compile_function(with_jac.map(CHUNK, "thread", MAP_THREADS),
                                              flags=COMPILE_FLAGS, warn=False)
        self._prior = sp.hstack([sp.csr_matrix((self.n_dx, self.n_theta)),
                                 sp.identity(self.n_dx, format="csr")]).tocsr()

    def pack(self, windows: Windows, structure: ModelStructure, delays, ratios: np.ndarray,
             weights: np.ndarray, noise: np.ndarray, p_ref: np.ndarray, scale: np.ndarray
             ) -> dict:
        """The data of the windows with the commands delayed by ``d``, as the mapped
        Function's inputs (one column block per window)."""
        W, L, M = self.W, self.L, self.M
        v = (window_preroll(windows, M, delays, structure.lag_indices).reshape(W * M, -1).T
             if self.n_lag else np.zeros((0, W * M)))
        select = np.zeros((self.n_p, self.n_theta))
        select[self.index, np.arange(self.n_theta)] = 1.0
        per_window = {
            "p_ref": np.tile(p_ref[:, None], (1, W)), "scale": np.tile(scale[:, None], (1, W)),
            "select": np.tile(select, (1, W)),
            "noise": np.tile(noise[:, None], (1, W)), "ratio": ratios[None, :],
            "x0": windows.x0.T, "v": v,
            "u": window_commands(windows, delays).reshape(W * L, -1).T}
        padded = {k: self._pad(a, self._widths[k]) for k, a in per_window.items()}
        return {**padded, "y": windows.y.reshape(W * L, -1).T,
                "weights": np.asarray(weights, float), "window_weights": np.ones(W)}

    def _pad(self, a: np.ndarray, width: int) -> np.ndarray:
        """Column blocks of ``width`` per window, the last window repeated up to whole
        chunks."""
        extra = self.n_chunks * CHUNK - self.W
        if not extra or not a.size:
            return a if a.size else np.zeros((a.shape[0], self.n_chunks * CHUNK * width))
        return np.hstack([a, np.tile(a[:, -width:], (1, extra))])

    def _call(self, func: ca.Function, z: np.ndarray, data: dict) -> dict[str, np.ndarray]:
        """``func`` (mapped over a chunk) over every chunk; outputs of the real windows."""
        theta = np.tile(z[:self.n_theta, None], (1, self.W))
        dx = (z[self.n_theta:].reshape(self.W, N_BODY).T if self.estimate_x0
              else np.zeros((N_BODY, self.W)))
        args = {"theta": self._pad(theta, 1), "dx": self._pad(dx, 1),
                **{k: data[k] for k in self._inputs[2:]}}
        outs: dict[str, list] = {}
        for c in range(self.n_chunks):
            part = {k: a[:, c * CHUNK * self._widths[k]:(c + 1) * CHUNK * self._widths[k]]
                    for k, a in args.items()}
            for name, value in func(**part).items():
                outs.setdefault(name, []).append(value.full())
        result = {}
        for name, blocks in outs.items():
            full = np.hstack(blocks)
            result[name] = full[:, :full.shape[1] // (self.n_chunks * CHUNK) * self.W]
        return result

    def residual(self, z: np.ndarray, data: dict) -> np.ndarray:
        """The weighted residual: ``(predicted - recorded) * weights`` (sample-major, the body
        states per sample, window after window), then the start-state prior ``dx``, then (where
        ``data`` has a ``"prior"``) the parameters' prior ``prior * theta`` (a weight per
        parameter) or ``prior @ theta`` (rows), centred on the file's values (``theta = 0``)."""
        pred = self._call(self.predict, z, data)["y"]
        r = ((pred - data["y"]) * self._sample_weights(data)).ravel(order="F")
        return np.concatenate([r, z[self.n_theta:], *self._prior_rows(z, data)])

    def _sample_weights(self, data: dict) -> np.ndarray:
        """Each residual's weight: its state's times its window's (``N_BODY x W*L``)."""
        return data["weights"][:, None] * np.repeat(data["window_weights"], self.L)[None, :]

    def _prior_rows(self, z: np.ndarray, data: dict) -> list[np.ndarray]:
        """The parameters' prior residual (:meth:`residual`), if ``data`` has one: a weight per
        parameter, or a matrix of rows (combinations of the parameters held near the file's
        values)."""
        prior = data.get("prior")
        if prior is None:
            return []
        prior = np.asarray(prior, float)
        theta = z[:self.n_theta]
        return [prior @ theta if prior.ndim == 2 else prior * theta]

    def cost(self, z: np.ndarray, data: dict) -> float:
        r = self.residual(z, data)
        with np.errstate(over="ignore", invalid="ignore"):
            value = 0.5 * float(r @ r)
        return value if math.isfinite(value) else math.inf

    def evaluate(self, z: np.ndarray, data: dict):
        """Residual (dense) and Jacobian (SciPy sparse, CSR) at ``z``."""
        out = self._call(self.sensitivities, z, data)
        pred, dy = out["y"], out["dy"]
        w = data["weights"]
        r = np.concatenate([((pred - data["y"]) * self._sample_weights(data)).ravel(order="F"),
                            z[self.n_theta:], *self._prior_rows(z, data)])
        rows = N_BODY * self.L
        n_u = self.n_theta + (N_BODY if self.estimate_x0 else 0)
        blocks = (dy.reshape(rows, self.W, n_u) * np.tile(w, self.L)[:, None, None]
                  * data["window_weights"][None, :, None])
        theta_part = blocks[:, :, :self.n_theta].transpose(1, 0, 2).reshape(-1, self.n_theta)
        parts = [sp.csr_matrix(theta_part)]
        if self.estimate_x0:
            dx_part = sp.block_diag([blocks[:, k, self.n_theta:] for k in range(self.W)],
                                    format="csr")
            J = sp.vstack([sp.hstack([parts[0], dx_part]), self._prior], format="csr")
        else:
            J = parts[0]
        if data.get("prior") is not None:  # the parameters' prior rows, after all others
            prior = np.asarray(data["prior"], float)
            rows = sp.csr_matrix(prior) if prior.ndim == 2 else sp.diags(prior)
            J = sp.vstack([J, sp.hstack([rows, sp.csr_matrix((rows.shape[0], self.n_dx))])],
                          format="csr")
        return r, J

    def solve(self, z0: np.ndarray, data: dict, lower: np.ndarray, upper: np.ndarray,
              max_iterations: int, progress: bool) -> tuple[np.ndarray, dict]:
        """Bounded Levenberg-Marquardt from ``z0`` (:func:`uavdyn.identify.lm.solve_bounded`)."""
        with CheckedBar(total=max_iterations, desc="identify (iterations)", unit="it",
                        leave=False, disable=not progress) as bar:
            out = solve_bounded(lambda z: self.evaluate(z, data),
                                lambda z: self.cost(z, data), z0, lower, upper,
                                max_iterations, bar.update)
        return out.z, {"iter_count": out.iterations, "return_status": out.status}


def _check_excitation(problem: _Problem, names: list[str], z: np.ndarray, data: np.ndarray
                      ) -> None:
    """Refuse parameters whose column of the Jacobian is (numerically) zero at the start."""
    r0, J0 = problem.evaluate(z, data)
    Jt = J0[:, :problem.n_theta]
    col = np.sqrt(np.asarray(Jt.multiply(Jt).sum(axis=0))).ravel()
    # a 100 % change moving the weighted residuals by < 1e-6 (RMS, in units of the nominal
    # model's error) is no excitation at all
    dead = [n for n, c in zip(names, col) if not c / math.sqrt(J0.shape[0]) > 1e-6]
    if dead:
        raise IdentifyError(f"the training data do not excite parameter(s) {dead}: their "
                            "effect on the predicted states is zero")
