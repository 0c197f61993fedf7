"""Output-error identification of named physical parameters from flight data.

The model's discrete step (:func:`uavdyn.integrate.physics_step`: RK sub-steps per log sample,
actuator lags as augmented states) is rolled out over short windows, each restarted from a
recorded state (multiple shooting on data: closed-loop flights and marginally stable airframes
stay fit-able), and the chosen entries of ``p`` minimise the weighted squared difference between
predicted and recorded body states ``(u, w, q, theta)``. The NLP is solved with CasADi
``nlpsol`` (IPOPT) using exact Jacobians and the Gauss-Newton Hessian ``J^T J``; standard errors
are the Cramer-Rao bound from that Hessian with the residual variance estimated per state after
the fit. Residuals of real data are correlated in time, so these standard errors are optimistic;
the report says so.

What each kind of name means:

* a parameter of ``p`` (coefficients, ``rho``, table values ``C_m_table_2_1``, time constants
  ``tau_*``): continuous, inside the schema's bounds and ``(1 +- relative_bound)`` of a
  nonzero nominal value. A time constant whose nominal value is 0 (no lag) starts from the best
  of :data:`TAU_GRID` on the cost and stays in :data:`TAU_BOUNDS`. Each window's lag states
  start from the exact lag recursion over the commands before it, in the same CasADi graph, so
  the Jacobian with respect to the time constant is exact too.
* ``delay_<control>``: an integer transport delay in samples, found by a coordinate search over
  ``0..max_delay`` on the cost, then re-checked at +-1 after the continuous fit. A delay is
  data to the fit (the commands shifted by it), so every candidate uses the one compiled graph.
* With ``atmosphere = "isa"`` each sortie's density is ``rho`` times the standard-atmosphere
  ratio at its manifest ``altitude_m``; fitting ``rho`` fits the sea-level density.
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

from uavdyn.airframes import BOUNDS, CONTROL_RANGES, DELAY_MAX_SAMPLES, Airframe
from uavdyn.airframes.tables import VALUE_LIMITS
from uavdyn.flightdata import Sortie
from uavdyn.identify.errors import IdentifyError
from uavdyn.identify.windows import (
    N_BODY,
    Windows,
    make_windows,
    predict_windows,
    window_function,
)
from uavdyn.integrate import EvalGrid, compile_function, find_compiler
from uavdyn.integrate.augmented import physics_step
from uavdyn.model import LAG_PARAMS, ModelStructure, structure_of

STATE_WEIGHT_FLOOR = 1e-6
CORRELATION_FLAG = 0.9
DELAY_PREFIX = "delay_"
TAU_NAMES = frozenset(t for lags in LAG_PARAMS.values() for t in lags.values())
TAU_GRID = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5)   # s, start candidates of a time constant at 0
TAU_BOUNDS = (1e-3, 10.0)                       # s, a fitted time constant stays inside
TAU_SCALE = 0.1                                 # s, unit of the unknown of a tau fitted from 0
PREROLL_TAUS = 8.0       # the lag pre-roll covers this many time constants (exp(-8) = 3e-4) ...
PREROLL_MIN_S = 1.0      # ... and at least this long
DEFAULT_SUBSTEPS = 2     # RK steps per log sample (dt = half the log interval)
REWEIGHT_PASSES = 1      # refits with each state weighted by its residual after the fit ...
REWEIGHT_FLOOR = 1e-3    # ... down to this fraction of the nominal model's residual
RECHECK_STEPS = 4        # Gauss-Newton steps at a neighbouring delay before comparing costs
SEARCH_ROUNDS = 3        # rounds of the delay / tau start coordinate search
IPOPT_TOL = 1e-9  # on the gradient of the cost (unit: weighted residual ~ its noise)
COMPILE_FLAGS = ("-O1", "-fPIC", "-shared")


@dataclass(frozen=True)
class Estimate:
    """One identified parameter (``searched``: an integer delay found by search, in samples,
    whose standard error is 0 by convention)."""

    name: str
    nominal: float
    value: float
    std_error: float
    searched: bool = False
    at_bound: str = ""  # "lower"/"upper" where the estimate ended on a bound of the fit


    @property
    def relative_change(self) -> float:
        return (self.value - self.nominal) / self.nominal if self.nominal else math.nan


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
    substeps: int = DEFAULT_SUBSTEPS
    search: list[dict] = field(default_factory=list)

    def to_dict(self) -> dict:
        def number(v: float):
            return None if not math.isfinite(v) else v

        names = [e.name for e in self.estimates if not e.searched]
        return {
            "airframe": self.airframe.name,
            "estimates": [{"name": e.name, "nominal": e.nominal, "value": e.value,
                           "std_error": e.std_error,
                           "relative_change": number(e.relative_change),
                           **({"searched": True} if e.searched else {}),
                           **({"at_bound": e.at_bound} if e.at_bound else {})}
                          for e in self.estimates],
            "correlation_names": names,
            "correlation": self.correlation.tolist(),
            "flagged_pairs": [list(p) for p in self.flagged_pairs],
            "state_sigma": self.state_sigma.tolist(), "cost_initial": self.cost_initial,
            "cost_final": self.cost_final, "iterations": self.iterations,
            "seconds": self.seconds, "window_s": self.window_s, "dt": self.dt,
            "substeps": self.substeps, "search": self.search, "fit": self.fit,
            "note": "standard errors are Cramer-Rao bounds from the Gauss-Newton Hessian with "
                    "white residuals assumed; correlated residuals make them optimistic; "
                    "delays are searched integers (standard error 0 by convention)",
        }


def measurement_noise(sorties: list[Sortie]) -> np.ndarray:
    """Per-state standard deviation of white measurement noise, from the second differences
    of the logged states (``var(d2 y) = 6 sigma^2`` for white noise; a smooth flight signal adds
    little at logging rates), floored so noise-free data pin the start states."""
    d2 = np.concatenate([np.diff(s.states, 2, axis=0) for s in sorties])
    sigma = np.sqrt(np.mean(d2**2, axis=0) / 6.0)
    return np.maximum(sigma, 1e-9 * (1.0 + np.abs(np.concatenate([s.states for s in sorties]))
                                     .max(axis=0)))


def control_names(kind: str) -> tuple[str, ...]:
    return tuple(n for n, _ in CONTROL_RANGES[kind])


def _check_request(airframe: Airframe, names: list[str], sorties: list[Sortie],
                   max_delay: int) -> tuple[list[str], list[str]]:
    """Split ``names`` into parameters of ``p`` and searched delays (control names)."""
    if not names:
        raise IdentifyError("no parameter named: give at least one with --params")
    if len(set(names)) != len(names):
        raise IdentifyError(f"parameter named twice in {names}")
    controls = control_names(airframe.kind)
    delay_names = [DELAY_PREFIX + c for c in controls]
    bad_delays = [n for n in names if n.startswith(DELAY_PREFIX) and n not in delay_names]
    if bad_delays:
        raise IdentifyError(f"{bad_delays} not a delay of the {airframe.kind} model; valid "
                            f"delays: {', '.join(delay_names)}")
    unknown = [n for n in names if n not in airframe.param_names and n not in delay_names]
    if unknown:
        raise IdentifyError(f"parameter(s) {unknown} are not in the {airframe.kind} model of "
                            f"'{airframe.name}'; choose from "
                            f"{', '.join(airframe.param_names + tuple(delay_names))}")
    if (isinstance(max_delay, bool) or not isinstance(max_delay, int)
            or not 1 <= max_delay <= DELAY_MAX_SAMPLES):
        raise IdentifyError(f"max_delay must be a whole number of samples in "
                            f"[1, {DELAY_MAX_SAMPLES}], got {max_delay!r}")
    if not sorties:
        raise IdentifyError("no training sorties")
    wrong = [s.name for s in sorties if s.kind != airframe.kind]
    if wrong:
        raise IdentifyError(f"sortie(s) {wrong[:3]} are of another kind than airframe "
                            f"'{airframe.name}' ({airframe.kind})")
    continuous = [n for n in names if n not in delay_names]
    searched = [n[len(DELAY_PREFIX):] for n in names if n in delay_names]
    return continuous, searched


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
        step = physics_step(structure, substeps=substeps)
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
        v = windows.preroll(M, delays, structure.lag_indices) if self.n_lag else None
        blocks = {
            "x0": windows.x0.T, "u": windows.controls(delays).reshape(W * L, -1).T,
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


def identify(airframe: Airframe, train: list[Sortie], validation: list[Sortie],
             names: list[str], window_s: float = 1.0, dt: float | None = None,
             relative_bound: float = 0.9, max_iterations: int = 60,
             estimate_x0: bool = True, max_windows: int | None = 120, max_delay: int = 5,
             substeps: int | None = None, progress: bool = True) -> IdentificationResult:
    """Fit the parameters ``names`` of ``airframe`` to ``train`` sorties by output error.

    Parameters
    ----------
    airframe : Airframe
        The starting (nominal) model; its other parameters, delays and lags stay fixed.
    train, validation : list of Sortie
        Sorties of the airframe's kind on one sample rate; validation scores the fit (pitch
        RMSE per sortie, nominal vs identified, with each airframe's own augmented step).
    names : list of str
        Entries of ``airframe.param_names`` to estimate, and ``delay_<control>`` for integer
        transport delays to search (module docstring).
    window_s : float
        Length of the prediction windows, each restarted from a recorded state.
    dt : float, optional
        RK step; must divide the log interval when the model has lags or delays (default:
        ``substeps``).
    relative_bound : float
        Each parameter with a nonzero nominal value stays within ``(1 +- relative_bound) x``
        it (sign kept); every one inside the schema's physical bounds (table values: the
        table's value limit; time constants: :data:`TAU_BOUNDS`).
    max_iterations : int
        IPOPT iteration limit (per solve).
    estimate_x0 : bool
        Estimate each window's initial body state too (recorded state as its measurement);
        without it, sensor noise in the start states biases the estimates.
    max_windows : int, optional
        Use at most this many windows, evenly spread over the training data (the cost of a
        Gauss-Newton iteration grows with them; None: all).
    max_delay : int
        Largest delay (samples) the search tries.
    substeps : int, optional
        RK steps per log sample (default 2; ``dt`` overrides it).
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
    continuous, searched = _check_request(airframe, names, train, max_delay)
    sample_dt = float(np.median(np.diff(train[0].time)))
    if dt is not None:
        grid = EvalGrid(sample_dt, dt)
        S, stride = grid.substeps, grid.stride
    else:
        S, stride = int(substeps or DEFAULT_SUBSTEPS), 1
        if S < 1:
            raise IdentifyError(f"substeps must be >= 1, got {substeps}")
    interval = stride * sample_dt
    controls = control_names(airframe.kind)
    # Delays are data here (the commands shifted), so the graph has no delay buffers.
    base = airframe.with_delays(**{c: 0 for c in controls})
    structure = structure_of(base, continuous)
    delays = list(airframe.delay_samples())
    if stride > 1 and (structure.n_actuator or any(delays) or searched):
        raise IdentifyError(f"the RK step {dt:g} s is longer than the log interval "
                            f"{sample_dt:g} s, but lags and delays act per log sample: give a "
                            "step that divides the log interval")
    L = max(1, int(round(window_s / interval)))
    w_train = make_windows(train, L, stride)
    if max_windows is not None and w_train.count > max_windows:
        keep = np.unique(np.linspace(0, w_train.count - 1, max_windows).round().astype(int))
        w_train = w_train.subset(keep)
    # weights: the nominal model's residual RMS per state (puts every state on one scale)
    resid0 = (predict_windows(airframe, w_train, interval, S) - w_train.y).reshape(-1, N_BODY)
    with np.errstate(all="ignore"):
        rms0 = np.sqrt(np.nanmean(np.where(np.abs(resid0) < 1e6, resid0, np.nan)**2, axis=0))
    weights = 1.0 / np.maximum(np.nan_to_num(rms0, nan=1.0), STATE_WEIGHT_FLOOR)
    weights_nominal = weights
    noise = measurement_noise(train)[:N_BODY]

    index = [airframe.param_names.index(n) for n in continuous]
    p_nom = airframe.p
    is_tau = np.array([n in TAU_NAMES for n in continuous], bool)
    from_zero = [j for j, n in enumerate(continuous) if is_tau[j] and p_nom[index[j]] == 0]
    scale = np.where(np.abs(p_nom[index]) > 0, np.abs(p_nom[index]),
                     np.where(is_tau, TAU_SCALE, 1.0)) if continuous else np.zeros(0)
    theta = np.zeros(len(continuous))
    guess = TAU_GRID[len(TAU_GRID) // 2]
    theta[from_zero] = guess / TAU_SCALE
    lo_theta, hi_theta = _theta_bounds(airframe, continuous, p_nom, scale, relative_bound)
    rho_index = airframe.param_names.index("rho") if airframe.atmosphere == "isa" else None
    ratios = w_train.density_ratios(airframe)

    def taus_of(th: np.ndarray) -> np.ndarray:
        p = p_nom.copy()
        p[index] = p_nom[index] + scale * th
        return p[list(structure.tau_indices)]

    tau_top = max([0.0, *taus_of(theta)])  # extended after the fit if the lag came out longer
    M = _preroll_samples(tau_top, interval) if structure.n_actuator else 0

    problem = _Problem(structure, index, w_train.count, L, M, interval, S, rho_index,
                       estimate_x0)
    data_cache: dict[tuple, np.ndarray] = {}

    def data_for(d) -> np.ndarray:
        key = (tuple(d), problem.M)
        if key not in data_cache:
            data_cache[key] = problem.pack(w_train, structure, d, ratios, weights, noise, p_nom,
                                           scale)
        return data_cache[key]

    def with_dx(th: np.ndarray) -> np.ndarray:  # the unknowns with the recorded start states
        return np.concatenate([th, np.zeros(problem.n_dx)])

    try:
        if continuous:
            _check_excitation(problem, continuous, with_dx(theta), data_for(delays))
        search_log: list[dict] = []
        theta, delays = _search(problem, data_for, with_dx, theta, delays, searched,
                                from_zero, continuous, scale, max_delay, lo_theta, hi_theta,
                                controls, search_log)
        lower = np.concatenate([lo_theta, np.full(problem.n_dx, -np.inf)])
        upper = np.concatenate([hi_theta, np.full(problem.n_dx, np.inf)])
        # a lag fitted on a searched control trades against its delay (one sample ~ T of tau)
        lag_shift = {c: [(j, interval / scale[j]) for j, n in enumerate(continuous)
                         if n == LAG_PARAMS[airframe.kind].get(c)] for c in searched}
        z = with_dx(theta)
        cost_initial = problem.cost(z, data_for(delays))
        iterations, stats = 0, {}
        for pass_ in range(REWEIGHT_PASSES + 1):
            for _ in range(2 * max_delay + 3):  # fit; re-check delays at +-1; refit on a gain
                if continuous:
                    z, stats = problem.solve(z, data_for(delays), lower, upper, max_iterations,
                                             progress)
                    iterations += int(stats.get("iter_count", 0))
                cost = problem.cost(z, data_for(delays))
                if structure.n_actuator:  # the pre-roll must cover the fitted lags
                    need = _preroll_samples(max(taus_of(z[:problem.n_theta])), interval)
                    if need > problem.M:
                        problem.close()
                        problem = _Problem(structure, index, w_train.count, L, need, interval,
                                           S, rho_index, estimate_x0)
                        search_log.append({"step": "pre-roll extended", "samples": need})
                        continue
                moved = _recheck_delays(problem, data_for, z, cost, delays, searched,
                                        controls, max_delay, lag_shift, lower, upper,
                                        search_log)
                if moved is None:
                    break
                delays, z = moved
            # Weight each state by its own residual after the fit (not the nominal model's
            # error): optimal weights for the estimate, and the ones the Cramer-Rao bound
            # below assumes; refit once if they changed.
            r = np.asarray(problem.residual(z, data_for(delays))).ravel()
            rms = np.sqrt(np.mean((r[:r.size - problem.n_dx].reshape(-1, N_BODY)
                                   / weights) ** 2, axis=0))
            floor = REWEIGHT_FLOOR / weights_nominal
            new = 1.0 / np.maximum(rms, floor)
            if (pass_ == REWEIGHT_PASSES or np.all(rms <= floor)  # noise-free: fit exact
                    or np.max(np.abs(np.log(new / weights))) < 0.1):
                break
            weights = new
            data_cache.clear()
            search_log.append({"step": "re-weighted", "weights": weights.tolist()})
        data = data_for(delays)
        r, J = problem.evaluate(z, data)
    finally:
        problem.close()
    theta = z[:problem.n_theta]
    sigma_w, cov_theta = _covariance(r, J, problem.n_theta, problem.n_dx, continuous)
    std = np.sqrt(np.maximum(np.diag(cov_theta), 0.0)) * scale
    d = np.sqrt(np.maximum(np.diag(cov_theta), 1e-300))
    corr = cov_theta / np.outer(d, d)
    flagged = [(continuous[i], continuous[j], float(corr[i, j]))
               for i, j in combinations(range(len(continuous)), 2)
               if abs(corr[i, j]) >= CORRELATION_FLAG]
    p_fit = p_nom.copy()
    p_fit[index] = p_nom[index] + scale * theta
    fitted = airframe.replace(**{n: float(p_fit[i]) for n, i in zip(continuous, index)})
    if searched:
        fitted = fitted.with_delays(**{c: int(delays[controls.index(c)]) for c in searched})
    by_name = {n: Estimate(n, float(p_nom[i]), float(p_fit[i]), float(s),
                           at_bound=_at_bound(theta[j], lo_theta[j], hi_theta[j]))
               for j, (n, i, s) in enumerate(zip(continuous, index, std))}
    nominal_delays = airframe.delay_samples()
    for c in searched:
        k = controls.index(c)
        by_name[DELAY_PREFIX + c] = Estimate(DELAY_PREFIX + c, float(nominal_delays[k]),
                                             float(delays[k]), 0.0, searched=True,
                                             at_bound="upper" if delays[k] == max_delay
                                             else "")
    estimates = [by_name[n] for n in names]
    fit = {"train": _fit_summary(airframe, fitted, train, interval, S, L, stride),
           "validation": _fit_summary(airframe, fitted, validation, interval, S, L, stride)
           if validation else None,
           "solver_status": stats.get("return_status", "no continuous parameter"),
           "windows": w_train.count, "window_samples": L, "preroll_samples": problem.M}
    return IdentificationResult(
        airframe=fitted, estimates=estimates, correlation=corr, flagged_pairs=flagged,
        state_sigma=1.0 / weights * sigma_w, cost_initial=cost_initial,
        cost_final=0.5 * float(r @ r), iterations=iterations,
        seconds=time.perf_counter() - t_start, window_s=L * interval, dt=interval / S,
        fit=fit, substeps=S, search=search_log)


def _covariance(r: np.ndarray, J, n_theta: int, n_dx: int, names: list[str]
                ) -> tuple[np.ndarray, np.ndarray]:
    """Per-state residual sigma (weighted units) after the fit and the Cramer-Rao covariance
    of the scaled unknowns ``theta`` (from the Gauss-Newton Hessian of all of ``z``, so the
    start states' uncertainty is accounted for)."""
    per_state = r[:r.size - n_dx].reshape(-1, N_BODY)
    dof = max(1.0, per_state.shape[0] - (n_theta + n_dx) / N_BODY)
    sigma_w = np.sqrt(np.sum(per_state**2, axis=0) / dof)
    if not n_theta:
        return sigma_w, np.zeros((0, 0))
    row_scale = np.concatenate([np.tile(1.0 / np.maximum(sigma_w, 1e-300), per_state.shape[0]),
                                np.ones(n_dx)])
    Jw = J.multiply(row_scale[:, None]).tocsc()
    try:
        cov = np.linalg.inv((Jw.T @ Jw).toarray())
    except np.linalg.LinAlgError:
        raise IdentifyError(f"the data cannot tell parameters {names} apart (singular "
                            "Gauss-Newton Hessian): fit fewer of them") from None
    return sigma_w, cov[:n_theta, :n_theta]


def _at_bound(value: float, low: float, high: float) -> str:
    """Which bound an estimate ended on, if any: within 1e-4 of the allowed range in the fit's
    units (the nominal value's magnitude; 1 for a parameter whose nominal value is 0), a range
    counted as at most 2 units so a zero-nominal parameter's wide physical range (e.g. 0..1e3)
    does not flag a small but clearly interior estimate."""
    span = 1e-4 * max(min(high - low, 2.0) if math.isfinite(high - low) else 1.0, 1e-300)
    return "lower" if value - low <= span else "upper" if high - value <= span else ""


def _preroll_samples(tau: float, interval: float) -> int:
    return int(math.ceil(max(PREROLL_MIN_S, PREROLL_TAUS * tau) / interval))


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


def _search(problem: _Problem, data_for, with_dx, theta: np.ndarray, delays: list[int],
            searched: list[str], from_zero: list[int], names: list[str], scale: np.ndarray,
            max_delay: int, lo: np.ndarray, hi: np.ndarray, controls: tuple[str, ...],
            log: list[dict]) -> tuple[np.ndarray, list[int]]:
    """Coordinate search on the cost (start states as recorded, continuous parameters at their
    start values) over each searched delay in ``0..max_delay`` and each time constant fitted
    from 0 over :data:`TAU_GRID`, until a round changes nothing."""
    theta, delays = theta.copy(), list(delays)
    for round_ in range(SEARCH_ROUNDS):
        changed = False
        for c in searched:
            k = controls.index(c)
            costs = []
            for d in range(max_delay + 1):
                trial = list(delays)
                trial[k] = d
                costs.append(problem.cost(with_dx(theta), data_for(trial)))
            finite = [v for v in costs if math.isfinite(v)]
            if round_ == 0 and (not finite or max(finite) - min(finite)
                                <= 1e-12 * max(abs(min(finite)), 1e-300)):
                raise IdentifyError(f"the training data do not excite parameter(s) "
                                    f"['{DELAY_PREFIX}{c}']: the cost is the same for every "
                                    f"delay 0..{max_delay} (is the {c} command ever moved?)")
            best = int(np.argmin(costs))
            log.append({"step": f"search {DELAY_PREFIX}{c}", "round": round_,
                        "costs": costs, "chosen": best})
            changed |= best != delays[k]
            delays[k] = best
        for j in from_zero:
            costs = []
            for tau in TAU_GRID:
                trial = theta.copy()
                trial[j] = min(max(tau / scale[j], lo[j]), hi[j])
                costs.append(problem.cost(with_dx(trial), data_for(delays)))
            best = float(TAU_GRID[int(np.argmin(costs))])
            log.append({"step": f"start {names[j]}", "round": round_, "grid": list(TAU_GRID),
                        "costs": costs, "chosen": best})
            changed |= not math.isclose(best / scale[j], theta[j])
            theta[j] = min(max(best / scale[j], lo[j]), hi[j])
        if not changed or not (searched and from_zero):
            break
    return theta, delays


def _recheck_delays(problem: _Problem, data_for, z: np.ndarray, cost: float, delays: list[int],
                    searched: list[str], controls: tuple[str, ...], max_delay: int,
                    lag_shift: dict[str, list[tuple[int, float]]], lower: np.ndarray,
                    upper: np.ndarray, log: list[dict]
                    ) -> tuple[list[int], np.ndarray] | None:
    """Re-check each searched delay at +-1 after the fit: a neighbour is compared at its own
    best continuous values, approximated by a few Gauss-Newton steps from the fitted ones (a
    lag fitted on the same control, whose time constant trades against the delay, starts
    shifted by one sample the other way); while a neighbour lowers the cost, the walk goes on
    in that direction. Returns the improved delays and unknowns (to refit from), or None when
    the fitted delays stand."""
    best, best_z, best_cost = list(delays), z, cost
    for c in searched:
        k = controls.index(c)
        for direction in (-1, 1):
            here, here_z, moved = best[k], best_z, False
            while 0 <= here + direction <= max_delay:
                trial = list(best)
                trial[k] = here + direction
                start = here_z.copy()
                for j, unit in lag_shift.get(c, ()):
                    start[j] = min(max(start[j] - direction * unit, lower[j]), upper[j])
                data = data_for(trial)
                z_try, value = _gauss_newton(problem, start, data, lower, upper, RECHECK_STEPS)
                at_fit = problem.cost(here_z, data)
                if at_fit < value:
                    z_try, value = here_z, at_fit
                log.append({"step": f"re-check {DELAY_PREFIX}{c}", "delay": trial[k],
                            "cost": value, "fitted_cost": best_cost})
                if not value < best_cost * (1 - 1e-9):
                    break
                best, best_z, best_cost, moved = trial, z_try, value, True
                here, here_z = trial[k], z_try
            if moved:
                break  # this control moved one way: the other way is uphill
    return None if best == list(delays) else (best, best_z)


def _gauss_newton(problem: _Problem, z: np.ndarray, data: np.ndarray, lower: np.ndarray,
                  upper: np.ndarray, iterations: int = 6) -> tuple[np.ndarray, float]:
    """A few bounded Levenberg-Marquardt steps on the cost (for comparing delay candidates at
    their own best continuous values without a full solve)."""
    z = np.clip(z, lower, upper)
    r, J = problem.evaluate(z, data)
    cost = 0.5 * float(r @ r)
    if not math.isfinite(cost):
        return z, math.inf
    mu = 1e-6
    for _ in range(iterations):
        H = (J.T @ J).toarray()
        g = J.T @ r
        diag = np.maximum(np.diag(H), 1e-12 * max(float(np.max(np.diag(H))), 1e-300))
        for _ in range(10):
            try:
                step = np.linalg.solve(H + mu * np.diag(diag), -g)
            except np.linalg.LinAlgError:
                step = None
            if step is not None:
                z_new = np.clip(z + step, lower, upper)
                value = problem.cost(z_new, data)
                if value < cost:
                    break
            mu *= 10.0
        else:
            break
        converged = cost - value <= 1e-12 * cost
        z, cost, mu = z_new, value, max(mu / 10.0, 1e-9)
        if converged:
            break
        r, J = problem.evaluate(z, data)
    return z, cost


def _bound(airframe: Airframe, name: str) -> tuple[float, float]:
    """The physical range of a parameter: the schema's bound, a table's value limit, or
    :data:`TAU_BOUNDS` for a time constant."""
    if name in TAU_NAMES:
        return TAU_BOUNDS
    if name in BOUNDS[airframe.kind]:
        bound = BOUNDS[airframe.kind][name]
        return bound.low, bound.high
    table = name.split("_table_")[0]
    if table in VALUE_LIMITS:
        return -VALUE_LIMITS[table], VALUE_LIMITS[table]
    return -math.inf, math.inf


def _theta_bounds(airframe: Airframe, names: list[str], p_nom: np.ndarray, scale: np.ndarray,
                  relative_bound: float) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the scaled unknowns: within ``(1 +- relative_bound)`` of a nonzero nominal
    value (sign kept), and always inside the physical range (:func:`_bound`; the only bound for
    a parameter whose nominal value is 0, such as an unset alpha-dot derivative or lag)."""
    lo = np.empty(len(names))
    hi = np.empty(len(names))
    for j, name in enumerate(names):
        p0 = p_nom[airframe.param_names.index(name)]
        low, high = _bound(airframe, name)
        if p0 != 0:
            low = max(low, p0 - relative_bound * abs(p0))
            high = min(high, p0 + relative_bound * abs(p0))
        lo[j], hi[j] = (low - p0) / scale[j], (high - p0) / scale[j]
    return lo, hi


def _fit_summary(nominal: Airframe, fitted: Airframe, sorties: list[Sortie], interval: float,
                 substeps: int, L: int, stride: int) -> dict:
    """Pitch RMSE over the windows of each sortie, nominal vs fitted airframe (each with its
    own discrete step: lags, delays and sortie densities included)."""
    per = []
    for s in sorties:
        try:
            w = make_windows([s], L, stride)
        except IdentifyError:
            continue  # a sortie shorter than one window
        row = {"sortie": s.name, "condition": s.meta.get("condition", "")}
        for label, af in (("nominal", nominal), ("identified", fitted)):
            err = predict_windows(af, w, interval, substeps)[..., 3] - w.y[..., 3]
            with np.errstate(all="ignore"):
                value = float(np.sqrt(np.mean(err**2)))
            row[f"theta_rmse_{label}"] = value if math.isfinite(value) else math.inf
        per.append(row)
    pooled = {label: float(np.sqrt(np.mean([r[f"theta_rmse_{label}"] ** 2 for r in per])))
              if per else math.nan for label in ("nominal", "identified")}
    return {"per_sortie": per, "theta_rmse": pooled}


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
