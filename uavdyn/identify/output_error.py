"""Output-error identification of named physical parameters from flight data.

The model's RK step is rolled out over short windows, each restarted from a recorded state
(multiple shooting on data: closed-loop flights and marginally stable airframes stay fit-able),
and the chosen entries of ``p`` minimise the weighted squared difference between predicted and
recorded states. The NLP is solved with CasADi ``nlpsol`` (IPOPT) using exact Jacobians and the
Gauss-Newton Hessian ``J^T J``; standard errors are the Cramer-Rao bound from that Hessian with
the residual variance estimated per state after the fit. Residuals of real data are correlated
in time, so these standard errors are optimistic; the report says so.
"""

from __future__ import annotations

import math
import os
import tempfile
import time
from dataclasses import dataclass, field
from itertools import combinations

import casadi as ca
import numpy as np
from tqdm import tqdm

from uavdyn.airframes import BOUNDS, Airframe
from uavdyn.flightdata import Sortie
from uavdyn.integrate import EvalGrid, compile_function, find_compiler, rk4_step, rollout
from uavdyn.model import build_model, uses_alpha_dot
from uavdyn.model.build import ALPHA_DOT_KEYS

STATE_WEIGHT_FLOOR = 1e-6
CORRELATION_FLAG = 0.9


class IdentifyError(ValueError):
    """An identification request cannot be carried out; the message says which parameter or
    which data and why."""


@dataclass(frozen=True)
class Estimate:
    """One identified parameter."""

    name: str
    nominal: float
    value: float
    std_error: float

    @property
    def relative_change(self) -> float:
        return (self.value - self.nominal) / self.nominal if self.nominal else math.nan


@dataclass
class Windows:
    """Data windows: start states ``x0 (W, nx)``, controls ``u (W, L, nu)`` held per sample,
    recorded states after each sample ``y (W, L, nx)`` and the sortie each came from."""

    x0: np.ndarray
    u: np.ndarray
    y: np.ndarray
    sortie: list[str]

    @property
    def count(self) -> int:
        return len(self.x0)


@dataclass
class IdentificationResult:
    """Estimates, their uncertainty and the fit they give (see :func:`identify`)."""

    airframe: Airframe
    estimates: list[Estimate]
    correlation: np.ndarray
    flagged_pairs: list[tuple[str, str, float]]
    state_sigma: np.ndarray
    cost_initial: float
    cost_final: float
    iterations: int
    seconds: float
    window_s: float
    dt: float
    fit: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "airframe": self.airframe.name,
            "estimates": [{"name": e.name, "nominal": e.nominal, "value": e.value,
                           "std_error": e.std_error, "relative_change": e.relative_change}
                          for e in self.estimates],
            "correlation": self.correlation.tolist(),
            "flagged_pairs": [list(p) for p in self.flagged_pairs],
            "state_sigma": self.state_sigma.tolist(), "cost_initial": self.cost_initial,
            "cost_final": self.cost_final, "iterations": self.iterations,
            "seconds": self.seconds, "window_s": self.window_s, "dt": self.dt, "fit": self.fit,
            "note": "standard errors are Cramer-Rao bounds from the Gauss-Newton Hessian with "
                    "white residuals assumed; correlated residuals make them optimistic",
        }


def make_windows(sorties: list[Sortie], window_samples: int, stride: int = 1) -> Windows:
    """Non-overlapping windows of ``window_samples`` grid intervals (every ``stride`` log
    samples) from every sortie, each starting at a recorded state."""
    x0, u, y, names = [], [], [], []
    for s in sorties:
        states, controls = s.states[::stride], s.controls[::stride]
        for k in range(0, len(states) - window_samples, window_samples):
            x0.append(states[k])
            u.append(controls[k:k + window_samples])
            y.append(states[k + 1:k + window_samples + 1])
            names.append(s.name)
    if not x0:
        raise IdentifyError(f"no window of {window_samples} samples fits in the given sorties")
    return Windows(np.array(x0), np.array(u), np.array(y), names)


def measurement_noise(sorties: list[Sortie]) -> np.ndarray:
    """Per-state standard deviation of white measurement noise, from the second differences
    of the logged states (``var(d2 y) = 6 sigma^2`` for white noise; a smooth flight signal adds
    little at logging rates), floored so noise-free data pin the start states."""
    d2 = np.concatenate([np.diff(s.states, 2, axis=0) for s in sorties])
    sigma = np.sqrt(np.mean(d2**2, axis=0) / 6.0)
    return np.maximum(sigma, 1e-9 * (1.0 + np.abs(np.concatenate([s.states for s in sorties]))
                                     .max(axis=0)))


def _check_request(airframe: Airframe, names: list[str], sorties: list[Sortie]) -> None:
    if not names:
        raise IdentifyError("no parameter named: give at least one with --params")
    unknown = [n for n in names if n not in airframe.param_names]
    if unknown:
        raise IdentifyError(f"parameter(s) {unknown} are not in the {airframe.kind} model of "
                            f"'{airframe.name}'; choose from {', '.join(airframe.param_names)}")
    if len(set(names)) != len(names):
        raise IdentifyError(f"parameter named twice in {names}")
    if not sorties:
        raise IdentifyError("no training sorties")
    wrong = [s.name for s in sorties if s.kind != airframe.kind]
    if wrong:
        raise IdentifyError(f"sortie(s) {wrong[:3]} are of another kind than airframe "
                            f"'{airframe.name}' ({airframe.kind})")


class _Problem:
    """The weighted residual of one window set as CasADi Functions of the decision vector
    ``z = [theta; dx]``: ``p = p0 + scale * theta`` for the chosen parameters, and each window
    starts from ``x0_recorded + noise * dx`` (its initial state is estimated too, with the
    recorded one as a measurement of standard deviation ``noise``: noisy start states would
    otherwise bias the estimates)."""

    def __init__(self, airframe: Airframe, names: list[str], grid: EvalGrid, n_samples: int,
                 n_windows: int, weights: np.ndarray, noise: np.ndarray, estimate_x0: bool):
        model = _model(airframe, names)
        step = rk4_step(model.f)
        index = [airframe.param_names.index(n) for n in names]
        p0 = airframe.p
        scale = np.where(np.abs(p0[index]) > 0, np.abs(p0[index]), 1.0)
        self.index, self.p0, self.scale = index, p0, scale
        self.n_theta = len(names)
        self.n_dx = model.nx * n_windows if estimate_x0 else 0
        sim = rollout(step, n_samples, grid.substeps).map(n_windows, "thread", 2)
        z = ca.MX.sym("z", self.n_theta + self.n_dx)
        theta, dx = z[:self.n_theta], z[self.n_theta:]
        X0 = ca.MX.sym("X0", model.nx, n_windows)
        U = ca.MX.sym("U", model.nu, n_samples * n_windows)
        Y = ca.MX.sym("Y", model.nx, n_samples * n_windows)
        p = ca.MX(ca.DM(p0))
        for j, i in enumerate(index):
            p[i] = p0[i] + scale[j] * theta[j]
        w = ca.DM(weights)
        start = X0 + ca.reshape(dx, model.nx, n_windows) * ca.DM(noise) if estimate_x0 else X0
        pred = sim(start, U, ca.repmat(p, 1, n_windows), grid.dt)
        r = ca.vertcat(ca.vec((pred - Y) * w), dx)
        J = ca.jacobian(r, z)
        self.jacobian = compile_function(ca.Function("oe_jacobian", [z, X0, U, Y], [r, J]),
                                         warn=False)
        # NLP: f = 0.5 |r|^2 with the Gauss-Newton Hessian as the Lagrangian Hessian
        data = ca.vertcat(ca.vec(X0), ca.vec(U), ca.vec(Y))
        sigma = ca.MX.sym("sigma")
        lam_g = ca.MX.sym("lam_g", 0)
        self.hess = ca.Function("hess_gn", [z, data, sigma, lam_g],
                                [ca.triu(sigma * ca.mtimes(J.T, J))])
        self.nlp = {"x": z, "p": data, "f": 0.5 * ca.sumsqr(r)}

    def pack(self, w: Windows) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        W, L, _ = w.u.shape
        return (w.x0.T, w.u.reshape(W * L, -1).T, w.y.reshape(W * L, -1).T)

    def evaluate(self, z: np.ndarray, w: Windows):
        """Residual (dense) and Jacobian (scipy sparse) at ``z``."""
        r, J = self.jacobian(z, *self.pack(w))
        return np.asarray(r).ravel(), J.sparse()

    def params(self, theta: np.ndarray) -> np.ndarray:
        p = self.p0.copy()
        p[self.index] = self.p0[self.index] + self.scale * theta
        return p


def identify(airframe: Airframe, train: list[Sortie], validation: list[Sortie],
             names: list[str], window_s: float = 1.0, dt: float | None = None,
             relative_bound: float = 0.9, max_iterations: int = 60,
             estimate_x0: bool = True, max_windows: int | None = 120,
             progress: bool = True) -> IdentificationResult:
    """Fit the parameters ``names`` of ``airframe`` to ``train`` sorties by output error.

    Parameters
    ----------
    airframe : Airframe
        The starting (nominal) model; its other parameters stay fixed.
    train, validation : list of Sortie
        Sorties of the airframe's kind on one sample rate; validation scores the fit.
    names : list of str
        Parameters of ``airframe.param_names`` to estimate.
    window_s : float
        Length of the prediction windows, each restarted from a recorded state.
    dt : float, optional
        RK4 step (default: half the log interval).
    relative_bound : float
        Each parameter stays within ``(1 +- relative_bound) x`` its nominal value (sign kept)
        and inside the schema's physical bounds (the only bound where the nominal value is 0).
    max_iterations : int
        IPOPT iteration limit.
    estimate_x0 : bool
        Estimate each window's initial state too (recorded state as its measurement); without
        it, sensor noise in the start states biases the estimates.
    max_windows : int, optional
        Use at most this many windows, evenly spread over the training data (the cost of a
        Gauss-Newton iteration grows with them; None: all).
    progress : bool
        Show a progress bar over the solver iterations.

    Returns
    -------
    IdentificationResult

    Raises
    ------
    IdentifyError
        For a parameter not in the model, data that do not excite a parameter (named), or
        parameters the data cannot tell apart.
    """
    t_start = time.perf_counter()
    _check_request(airframe, names, train)
    sample_dt = float(np.median(np.diff(train[0].time)))
    grid = EvalGrid(sample_dt, dt if dt is not None else sample_dt / 2)
    L = max(1, int(round(window_s / grid.interval)))
    w_train = make_windows(train, L, grid.stride)
    if max_windows is not None and w_train.count > max_windows:
        keep = np.unique(np.linspace(0, w_train.count - 1, max_windows).round().astype(int))
        w_train = Windows(w_train.x0[keep], w_train.u[keep], w_train.y[keep],
                          [w_train.sortie[k] for k in keep])
    nominal = rk4_step(_model(airframe, names).f)
    # weights: the nominal model's residual RMS per state (puts every state on one scale)
    sim0 = rollout(nominal, L, grid.substeps).map(w_train.count, "thread", 2)
    pred0 = np.array(sim0(w_train.x0.T, w_train.u.reshape(-1, w_train.u.shape[-1]).T,
                          np.tile(airframe.p[:, None], (1, w_train.count)), grid.dt))
    resid0 = pred0 - w_train.y.reshape(-1, w_train.y.shape[-1]).T
    weights = 1.0 / np.maximum(np.sqrt(np.mean(resid0**2, axis=1)), STATE_WEIGHT_FLOOR)
    noise = measurement_noise(train)
    problem = _Problem(airframe, names, grid, L, w_train.count, weights[:, None],
                       noise[:, None], estimate_x0)
    n_z = problem.n_theta + problem.n_dx
    data = np.concatenate([a.ravel(order="F") for a in problem.pack(w_train)])
    r0, J0 = problem.evaluate(np.zeros(n_z), w_train)
    col = np.sqrt(np.asarray(J0[:, :problem.n_theta].multiply(J0[:, :problem.n_theta])
                             .sum(axis=0))).ravel()
    # a 100 % change moving the weighted residuals by < 1e-6 (RMS, in units of the nominal
    # model's error) is no excitation at all
    dead = [n for n, c in zip(names, col) if not c / math.sqrt(J0.shape[0]) > 1e-6]
    if dead:
        raise IdentifyError(f"the training data do not excite parameter(s) {dead}: their "
                            "effect on the predicted states is zero")
    lo_theta, hi_theta = _theta_bounds(airframe, names, problem, relative_bound)
    lower = np.concatenate([lo_theta, np.full(problem.n_dx, -np.inf)])
    upper = np.concatenate([hi_theta, np.full(problem.n_dx, np.inf)])
    options = {"hess_lag": problem.hess, "ipopt.print_level": 0, "print_time": False,
               "ipopt.max_iter": max_iterations, "ipopt.tol": 1e-10, "ipopt.sb": "yes"}
    jit_dir = tempfile.TemporaryDirectory(prefix="uavdyn-identify-")
    if find_compiler() is not None:  # the NLP's functions as C (seconds to build, 10x faster)
        options.update({"jit": True, "compiler": "shell",
                        "jit_options": {"flags": ["-O1"], "verbose": False,
                                        "directory": jit_dir.name + os.sep}})
    bar = _IterationBar(n_z, len(data), max_iterations) if progress else None
    if bar is not None:  # kept alive by this frame for as long as the solver runs
        options["iteration_callback"] = bar
    cwd = os.getcwd()
    os.chdir(jit_dir.name)  # CasADi writes its JIT source into the working folder
    try:
        solver = ca.nlpsol("oe", "ipopt", problem.nlp, options)
    finally:
        os.chdir(cwd)
    sol = solver(x0=np.zeros(n_z), p=data, lbx=lower, ubx=upper)
    if bar is not None:
        bar.close()
    stats = solver.stats()
    del solver
    jit_dir.cleanup()
    z = np.array(sol["x"]).ravel()
    theta = z[:problem.n_theta]
    r, J = problem.evaluate(z, w_train)
    # residual variance per state after the fit -> Cramer-Rao covariance of all of z
    n_state = len(weights)
    n_out = r.size - problem.n_dx
    per_state = r[:n_out].reshape(-1, n_state)
    dof = max(1.0, per_state.shape[0] - n_z / n_state)
    sigma_w = np.sqrt(np.sum(per_state**2, axis=0) / dof)
    row_scale = np.concatenate([np.tile(1.0 / sigma_w, per_state.shape[0]),
                                np.ones(problem.n_dx)])
    Jw = J.multiply(row_scale[:, None]).tocsc()
    H = (Jw.T @ Jw).toarray()
    try:
        cov = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        raise IdentifyError(f"the data cannot tell parameters {names} apart (singular "
                            "Gauss-Newton Hessian): fit fewer of them") from None
    cov_theta = cov[:problem.n_theta, :problem.n_theta]
    std = np.sqrt(np.maximum(np.diag(cov_theta), 0.0)) * problem.scale
    d = np.sqrt(np.maximum(np.diag(cov_theta), 1e-300))
    corr = cov_theta / np.outer(d, d)
    flagged = [(names[i], names[j], float(corr[i, j]))
               for i, j in combinations(range(len(names)), 2)
               if abs(corr[i, j]) >= CORRELATION_FLAG]
    p_fit = problem.params(theta)
    fitted = airframe.replace(**{n: float(p_fit[i]) for n, i in zip(names, problem.index)})
    estimates = [Estimate(n, float(airframe.p[i]), float(p_fit[i]), float(s))
                 for n, i, s in zip(names, problem.index, std)]
    fit = {"train": _fit_summary(airframe, fitted, train, grid, L, names),
           "validation": _fit_summary(airframe, fitted, validation, grid, L, names)
           if validation else None,
           "solver_status": stats.get("return_status"), "windows": w_train.count,
           "window_samples": L}
    return IdentificationResult(
        airframe=fitted, estimates=estimates, correlation=corr, flagged_pairs=flagged,
        state_sigma=1.0 / weights * sigma_w, cost_initial=0.5 * float(r0 @ r0),
        cost_final=0.5 * float(r @ r), iterations=int(stats.get("iter_count", 0)),
        seconds=time.perf_counter() - t_start, window_s=L * grid.interval, dt=grid.dt, fit=fit)


def _theta_bounds(airframe: Airframe, names: list[str], problem: _Problem,
                  relative_bound: float) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the scaled unknowns: within ``(1 +- relative_bound)`` of a nonzero nominal
    value (sign kept), and always inside the airframe schema's physical bounds (the only bound
    for a parameter whose nominal value is 0, such as an unset alpha-dot derivative)."""
    lo = np.empty(len(names))
    hi = np.empty(len(names))
    for j, name in enumerate(names):
        p0 = problem.p0[problem.index[j]]
        bound = BOUNDS[airframe.kind][name]
        low, high = (bound.low - p0) / problem.scale[j], (bound.high - p0) / problem.scale[j]
        if p0 != 0:
            low, high = max(low, -relative_bound), min(high, relative_bound)
        lo[j], hi[j] = low, high
    return lo, hi


def _model(airframe: Airframe, names: list[str]):
    """The airframe's model, with the alpha-dot terms when they are set or being fitted."""
    return build_model(airframe, alpha_dot=uses_alpha_dot(airframe)
                       or any(n in ALPHA_DOT_KEYS for n in names))


def _fit_summary(nominal: Airframe, fitted: Airframe, sorties: list[Sortie], grid: EvalGrid,
                 L: int, names: list[str]) -> dict:
    """Pitch RMSE over the windows of each sortie, nominal vs fitted parameters."""
    per = []
    step = rk4_step(_model(nominal, names).f)
    for s in sorties:
        w = make_windows([s], L, grid.stride)
        sim = rollout(step, L, grid.substeps).map(w.count)
        row = {"sortie": s.name, "condition": s.meta.get("condition", "")}
        for label, af in (("nominal", nominal), ("identified", fitted)):
            pred = np.array(sim(w.x0.T, w.u.reshape(-1, w.u.shape[-1]).T,
                                np.tile(af.p[:, None], (1, w.count)), grid.dt))
            err = pred[3] - w.y.reshape(-1, w.y.shape[-1]).T[3]
            row[f"theta_rmse_{label}"] = float(np.sqrt(np.mean(err**2)))
        per.append(row)
    pooled = {label: float(np.sqrt(np.mean([r[f"theta_rmse_{label}"] ** 2 for r in per])))
              for label in ("nominal", "identified")}
    return {"per_sortie": per, "theta_rmse": pooled}


class _IterationBar(ca.Callback):
    """An IPOPT iteration callback driving a tqdm bar."""

    def __init__(self, n_x: int, n_p: int, max_iterations: int):
        ca.Callback.__init__(self)
        self.sizes = {"x": n_x, "lam_x": n_x, "lam_p": n_p, "f": 1, "g": 0, "lam_g": 0}
        self.bar = tqdm(total=max_iterations, desc="identify (IPOPT iterations)", unit="it",
                        leave=False)
        self.construct("identify_progress", {})

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
        self.bar.update()
        return [0]

    def close(self) -> None:
        self.bar.close()
