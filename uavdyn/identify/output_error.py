"""Output-error identification of named physical parameters from flight data.

The model's discrete step (:func:`uavdyn.integrate.physics_step`: RK sub-steps per log sample,
actuator lags as augmented states) is rolled out over short windows, each restarted from a
recorded state (multiple shooting on data: closed-loop flights and marginally stable airframes
stay fit-able), and the chosen entries of ``p`` minimise the weighted squared difference between
predicted and recorded body states ``(u, w, q, theta)``. The least squares are solved by a
bounded Levenberg-Marquardt method on exact Jacobians (:mod:`uavdyn.identify.problem`: one
compiled per-window Function mapped over the windows). Standard errors
(:mod:`uavdyn.identify.uncertainty`): the Cramer-Rao bound (white residuals assumed, optimistic
on real data) and the one corrected for the residuals' autocorrelation and for how the sorties
pull the estimate apart, the one to use; collinear groups and intervals spanning zero are
flagged as not determined by the data, with the excitation that would determine them.

What each kind of name means:

* a parameter of ``p`` (coefficients, ``rho``, table values ``C_m_table_2_1``, time constants
  ``tau_*``): continuous, inside its physical range (and any bounds the caller gives). A time
  constant whose nominal value is 0 (no lag) starts from the best of :data:`TAU_GRID` on the
  cost and stays in :data:`TAU_BOUNDS`. Each window's lag states start from the exact lag
  recursion over the commands before it, in the same CasADi graph, so the Jacobian with
  respect to the time constant is exact too. A slew time ``slew_*`` (1 / an actuator's rate
  limit) at 0 (no rate limit) starts the same way from the best of :data:`SLEW_GRID`.
* ``delay_<control>``: an integer transport delay in samples, found by a coordinate search over
  ``0..max_delay`` on the cost, then re-checked at +-1 after the continuous fit. A delay is
  data to the fit (the commands shifted by it), so every candidate uses the one compiled graph.
* With ``atmosphere = "isa"`` each sortie's density is ``rho`` times the standard-atmosphere
  ratio at its manifest ``altitude_m``; fitting ``rho`` fits the sea-level density.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from itertools import combinations

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.flightdata import Sortie
from uavdyn.identify.consistency import compare_halves
from uavdyn.identify.errors import IdentifyError
from uavdyn.identify.excitation import excitation_for, refuse_unexcited
from uavdyn.identify.problem import COMPILE_FLAGS, _check_excitation, _Problem
from uavdyn.identify.result import DEFAULT_SUBSTEPS, Estimate, IdentificationResult
from uavdyn.identify.search import RECHECK_STEPS, SEARCH_ROUNDS, _recheck_delays, _search
from uavdyn.identify.uncertainty import estimate_uncertainty, undetermined
from uavdyn.identify.unknowns import (
    DELAY_PREFIX,
    TAU_BOUNDS,
    TAU_GRID,
    TAU_NAMES,
    TAU_SCALE,
    Unknowns,
    _at_bound,
    _check_request,
    control_names,
    project_inside,
    scaled_unknowns,
)
from uavdyn.identify.windows import (
    N_BODY,
    Windows,
    fit_summary,
    physics_windows,
    training_windows,
    window_density_ratios,
)
from uavdyn.integrate import EvalGrid, substeps_for
from uavdyn.model import LAG_PARAMS, ModelStructure, structure_of

__all__ = ["COMPILE_FLAGS", "CORRELATION_FLAG", "DEFAULT_SUBSTEPS", "DELAY_PREFIX",
           "PREROLL_GROWTH", "PREROLL_MIN_S", "PREROLL_TAUS", "RECHECK_STEPS",
           "REWEIGHT_FLOOR", "REWEIGHT_PASSES",
           "SEARCH_ROUNDS", "STATE_WEIGHT_FLOOR", "TAU_BOUNDS", "TAU_GRID", "TAU_NAMES",
           "TAU_SCALE", "Estimate", "IdentificationResult", "control_names", "identify",
           "measurement_noise"]

STATE_WEIGHT_FLOOR = 1e-6
CORRELATION_FLAG = 0.9
PREROLL_TAUS = 8.0       # the lag pre-roll covers this many time constants (exp(-8) = 3e-4) ...
PREROLL_MIN_S = 1.0      # ... and at least this long
PREROLL_GROWTH = 4.0     # the first pre-roll covers lags up to this many times their start
HALF_ITERATIONS = 30     # the halves start from the whole fit: a few steps move them
REWEIGHT_PASSES = 1      # refits with each state weighted by its residual after the fit ...
REWEIGHT_FLOOR = 1e-3    # ... down to this fraction of the nominal model's residual


def measurement_noise(sorties: list[Sortie]) -> np.ndarray:
    """Per-state standard deviation of white measurement noise, from the second differences
    of the logged states (``var(d2 y) = 6 sigma^2`` for white noise; a smooth flight signal adds
    little at logging rates), floored so noise-free data pin the start states."""
    d2 = np.concatenate([np.diff(s.states, 2, axis=0) for s in sorties])
    sigma = np.sqrt(np.mean(d2**2, axis=0) / 6.0)
    return np.maximum(sigma, 1e-9 * (1.0 + np.abs(np.concatenate([s.states for s in sorties]))
                                     .max(axis=0)))


def identify(airframe: Airframe, train: list[Sortie], validation: list[Sortie],
             names: list[str], window_s: float = 1.0, dt: float | None = None,
             relative_bound: float | None = None,
             bounds: dict[str, tuple[float, float]] | None = None, max_iterations: int = 60,
             estimate_x0: bool = True, max_windows: int | None = 120, max_delay: int = 5,
             substeps: int | None = None, progress: bool = True,
             check_halves: bool = True, preroll: int | None = None, screen: bool = True
             ) -> IdentificationResult:
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
    relative_bound : float, optional
        Keep each parameter with a nonzero nominal value within ``(1 +- relative_bound) x``
        it (sign kept). Default: no such bound; every parameter stays inside its physical
        range only (the schema's bound by its meaning and sign convention: a coefficient may
        change sign, a time constant is >= 0 (:data:`TAU_BOUNDS`), a share lies in [0, 1];
        table values: the table's value limit).
    bounds : dict, optional
        ``name -> (low, high)`` narrowing a parameter's range (the nominal value inside it).
    max_iterations : int
        Iteration limit of the bounded Levenberg-Marquardt solver (per solve).
    estimate_x0 : bool
        Estimate each window's initial body state too (recorded state as its measurement);
        without it, sensor noise in the start states biases the estimates.
    max_windows : int, optional
        Use at most this many windows, evenly spread over the training data (the cost of a
        Gauss-Newton iteration grows with them; None: all).
    max_delay : int
        Largest delay (samples) the search tries.
    substeps : int, optional
        RK steps per log sample (default: the log interval in whole sub-steps of at most
        ``MAX_DEFAULT_DT``, at least 2; ``dt`` overrides it).
    progress : bool
        Show a progress bar over the solver iterations.
    screen : bool
        Refuse, before fitting, a parameter whose signal the train data do not move above
        its noise (:func:`~uavdyn.identify.excitation.unexcited`; default True).
    check_halves : bool
        With four or more training sorties, also fit each half of them (alternate sorties,
        :func:`uavdyn.identify.consistency.compare_halves`): a parameter the halves disagree on
        beyond their standard errors is flagged, and its corrected standard error is at least
        half the difference.
    preroll : int, optional
        Samples of lag pre-roll before each window (default: enough for the time constants,
        with room to grow); never shorter than the lags need.

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
    # turning-flight sorties carry the lateral inputs: the model takes them too
    airframe = airframe.for_inputs(bool(train) and train[0].lateral)
    continuous, searched = _check_request(airframe, names, train, max_delay)
    if screen:
        refuse_unexcited(continuous, train)
    fit = _prepare(airframe, train, continuous, searched, window_s, dt, substeps,
                   max_windows, relative_bound, bounds, estimate_x0, preroll)
    outcome = _solve(fit, max_delay, max_iterations, progress)
    fitted, estimates, corr, flagged, sigma_w, diagnostics = _estimates(fit, outcome, names,
                                                                        max_delay)
    summary = {"train": fit_summary(airframe, fitted, train, fit.interval, fit.substeps,
                                     fit.L, fit.stride),
               "validation": fit_summary(airframe, fitted, validation, fit.interval,
                                          fit.substeps, fit.L, fit.stride)
               if validation else None,
               "solver_status": outcome.stats.get("return_status", "no continuous parameter"),
               "windows": fit.windows.count, "window_samples": fit.L,
               **fit.envelope,
               "preroll_samples": fit.problem.M}
    r = outcome.r
    result = IdentificationResult(
        airframe=fitted, estimates=estimates, correlation=corr, flagged_pairs=flagged,
        state_sigma=1.0 / fit.weights * sigma_w, cost_initial=outcome.cost_initial,
        cost_final=0.5 * float(r @ r), iterations=outcome.iterations,
        seconds=time.perf_counter() - t_start, window_s=fit.L * fit.interval,
        dt=fit.interval / fit.substeps, fit=summary, substeps=fit.substeps,
        search=outcome.log, diagnostics=diagnostics)
    if check_halves and continuous and len(train) >= 4:
        compare_halves(identify, result, train, continuous, max(1, fit.windows.count // 2),
                      {"window_s": window_s, "dt": dt, "bounds": bounds,
                       "max_iterations": min(max_iterations, HALF_ITERATIONS),
                       "estimate_x0": estimate_x0,
                       "substeps": substeps, "progress": False, "check_halves": False,
                       "preroll": fit.problem.M or None})
        result.seconds = time.perf_counter() - t_start
    return result


@dataclass
class _Fit:
    """What the stages of one identification share: the request, the training windows on the
    time grid, the scaled unknowns, the state weights and the compiled problem (rebuilt when
    the lag pre-roll grows), with its data vectors cached per delay candidate."""

    airframe: Airframe
    continuous: list[str]
    searched: list[str]
    structure: ModelStructure
    windows: Windows
    L: int
    interval: float
    substeps: int
    stride: int
    unknowns: Unknowns
    rho_index: int | None
    ratios: np.ndarray
    noise: np.ndarray
    weights: np.ndarray
    weights_nominal: np.ndarray
    estimate_x0: bool
    envelope: dict = field(default_factory=dict)
    problem: _Problem | None = None
    data_cache: dict[tuple, np.ndarray] = field(default_factory=dict)

    @property
    def controls(self) -> tuple[str, ...]:
        return control_names(self.airframe.kind)

    def new_problem(self, preroll: int) -> _Problem:
        """The problem with a lag pre-roll of ``preroll`` samples (the data cache keys on it)."""
        self.problem = _Problem(self.structure, self.unknowns.index, self.windows.count,
                                self.L, preroll, self.interval, self.substeps, self.rho_index,
                                self.estimate_x0)
        return self.problem

    def data_for(self, d) -> np.ndarray:
        """The data vector of the current problem with the commands delayed by ``d``."""
        key = (tuple(d), self.problem.M)
        if key not in self.data_cache:
            u = self.unknowns
            self.data_cache[key] = self.problem.pack(self.windows, self.structure, d,
                                                     self.ratios, self.weights, self.noise,
                                                     u.p_nom, u.scale)
        return self.data_cache[key]

    def with_dx(self, th: np.ndarray) -> np.ndarray:
        """The unknowns with the recorded start states."""
        return np.concatenate([th, np.zeros(self.problem.n_dx)])

    def taus_of(self, th: np.ndarray) -> np.ndarray:
        """The structure's time constants at the scaled unknowns ``th``; a rate-limited
        actuator's at least the one whose pre-roll also covers a slew over its full travel."""
        p = self.unknowns.p_of(th)
        bounds = self.airframe.control_bounds()
        return np.array([max(p[i], 0.0 if k is None else p[k] * (bounds[c][1] - bounds[c][0])
                             / PREROLL_TAUS)
                         for c, i, k in zip(self.structure.lag_indices,
                                            self.structure.tau_indices,
                                            self.structure.slew_indices)])


@dataclass
class _Outcome:
    """The solved fit: unknowns ``z``, delays, residual and Jacobian there, and its history."""

    z: np.ndarray
    delays: list[int]
    r: np.ndarray
    J: object  # scipy.sparse matrix
    cost_initial: float
    iterations: int
    stats: dict
    log: list[dict]


MAX_DEFAULT_DT = 0.005  # default RK step: the log interval in whole sub-steps of at most this


def _time_grid(train: list[Sortie], dt: float | None, substeps: int | None
               ) -> tuple[float, int, int]:
    """The log interval of the data, the RK steps per grid interval and the grid's stride in
    log samples (``dt`` longer than the log interval: several samples per step)."""
    sample_dt = float(np.median(np.diff(train[0].time)))
    if dt is not None:
        grid = EvalGrid(sample_dt, dt)
        S, stride = grid.substeps, grid.stride
    else:
        S, stride = int(substeps or substeps_for(sample_dt, MAX_DEFAULT_DT, DEFAULT_SUBSTEPS)), 1
        if S < 1:
            raise IdentifyError(f"substeps must be >= 1, got {substeps}")
    return sample_dt, S, stride


def _nominal_weights(airframe: Airframe, windows: Windows, interval: float, substeps: int
                     ) -> np.ndarray:
    """State weights: the nominal model's residual RMS per state (puts every state on one
    scale)."""
    resid0 = (physics_windows(airframe, windows, interval, substeps)
              - windows.y).reshape(-1, N_BODY)
    with np.errstate(all="ignore"):
        rms0 = np.sqrt(np.nanmean(np.where(np.abs(resid0) < 1e6, resid0, np.nan)**2, axis=0))
    return 1.0 / np.maximum(np.nan_to_num(rms0, nan=1.0), STATE_WEIGHT_FLOOR)


def _prepare(airframe: Airframe, train: list[Sortie], continuous: list[str],
             searched: list[str], window_s: float, dt: float | None, substeps: int | None,
             max_windows: int | None, relative_bound: float | None,
             bounds: dict[str, tuple[float, float]] | None, estimate_x0: bool,
             preroll: int | None = None) -> _Fit:
    """Everything the fit needs before its first solve, ending with the compiled problem."""
    sample_dt, S, stride = _time_grid(train, dt, substeps)
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
    envelope: dict = {}
    w_train = training_windows(airframe, train, L, stride, max_windows, envelope)
    weights = _nominal_weights(airframe, w_train, interval, S)
    unknowns = scaled_unknowns(airframe, continuous, relative_bound, bounds)
    rho_index = airframe.param_names.index("rho") if airframe.atmosphere == "isa" else None
    fit = _Fit(airframe, continuous, searched, structure, w_train, L, interval, S, stride,
               unknowns, rho_index, window_density_ratios(w_train, airframe),
               measurement_noise(train)[:N_BODY], weights, weights, estimate_x0, envelope)
    # room for a fitted lag PREROLL_GROWTH times the start (extended after the fit if longer:
    # a recompile)
    tau_top = PREROLL_GROWTH * max([0.0, *fit.taus_of(unknowns.theta0)])
    if preroll is not None:  # the caller's length, where it covers the starting lags
        tau_top /= PREROLL_GROWTH
    need = _preroll_samples(tau_top, interval)
    fit.new_problem(max(need, preroll or 0) if structure.n_actuator else 0)
    return fit


def _solve(fit: _Fit, max_delay: int, max_iterations: int, progress: bool) -> _Outcome:
    """Search the start, fit, re-check the delays, and refit once with each state weighted by
    its own residual after the fit (not the nominal model's error): optimal weights for the
    estimate, and the ones the Cramer-Rao bound assumes."""
    log: list[dict] = []
    u = fit.unknowns
    delays = list(fit.airframe.delay_samples())
    if fit.continuous:
        _check_excitation(fit.problem, fit.continuous, fit.with_dx(u.theta0),
                          fit.data_for(delays))
    theta, delays = _search(fit.problem, fit.data_for, fit.with_dx, u.theta0, delays,
                            fit.searched, u.from_zero, fit.continuous, u.scale, max_delay,
                            u.lo, u.hi, fit.controls, log)
    lower = np.concatenate([u.lo, np.full(fit.problem.n_dx, -np.inf)])
    upper = np.concatenate([u.hi, np.full(fit.problem.n_dx, np.inf)])
    z = fit.with_dx(theta)
    cost_initial = fit.problem.cost(z, fit.data_for(delays))
    iterations, stats = 0, {}
    for pass_ in range(REWEIGHT_PASSES + 1):
        z, delays, iterations, stats = _fit_and_recheck(
            fit, z, delays, lower, upper, max_delay, max_iterations, progress, iterations,
            stats, log)
        rms, floor, new = _residual_weights(fit, z, delays)
        if (pass_ == REWEIGHT_PASSES or np.all(rms <= floor)  # noise-free: fit exact
                or np.max(np.abs(np.log(new / fit.weights))) < 0.1):
            break
        fit.weights = new
        fit.data_cache.clear()
        log.append({"step": "re-weighted", "weights": fit.weights.tolist()})
    r, J = fit.problem.evaluate(z, fit.data_for(delays))
    return _Outcome(z, delays, r, J, cost_initial, iterations, stats, log)


def _fit_and_recheck(fit: _Fit, z: np.ndarray, delays: list[int], lower: np.ndarray,
                     upper: np.ndarray, max_delay: int, max_iterations: int, progress: bool,
                     iterations: int, stats: dict, log: list[dict]
                     ) -> tuple[np.ndarray, list[int], int, dict]:
    """Fit; extend the lag pre-roll if the fitted lags outgrew it; re-check the searched delays
    at +-1 and refit from a better neighbour, until the delays stand."""
    # a lag fitted on a searched control trades against its delay (one sample ~ T of tau)
    lag_shift = {c: [(j, fit.interval / fit.unknowns.scale[j])
                     for j, n in enumerate(fit.continuous)
                     if n == LAG_PARAMS[fit.airframe.kind].get(c)] for c in fit.searched}
    for _ in range(2 * max_delay + 3):  # fit; re-check delays at +-1; refit on a gain
        if fit.continuous:
            z, stats = fit.problem.solve(z, fit.data_for(delays), lower, upper,
                                         max_iterations, progress)
            iterations += int(stats.get("iter_count", 0))
        cost = fit.problem.cost(z, fit.data_for(delays))
        if fit.structure.n_actuator:  # the pre-roll must cover the fitted lags
            need = _preroll_samples(max(fit.taus_of(z[:fit.problem.n_theta])), fit.interval)
            if need > fit.problem.M:
                fit.new_problem(need)
                log.append({"step": "pre-roll extended", "samples": need})
                continue
        moved = _recheck_delays(fit.problem, fit.data_for, z, cost, delays, fit.searched,
                                fit.controls, max_delay, lag_shift, lower, upper, log)
        if moved is None:
            break
        delays, z = moved
    return z, delays, iterations, stats


def _residual_weights(fit: _Fit, z: np.ndarray, delays: list[int]
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each state's residual RMS after the fit (unweighted), its floor, and the weights it
    gives."""
    r = np.asarray(fit.problem.residual(z, fit.data_for(delays))).ravel()
    rms = np.sqrt(np.mean((r[:r.size - fit.problem.n_dx].reshape(-1, N_BODY)
                           / fit.weights) ** 2, axis=0))
    floor = REWEIGHT_FLOOR / fit.weights_nominal
    return rms, floor, 1.0 / np.maximum(rms, floor)


def _estimates(fit: _Fit, outcome: _Outcome, names: list[str], max_delay: int
               ) -> tuple[Airframe, list[Estimate], np.ndarray, list[tuple[str, str, float]],
                          np.ndarray, dict]:
    """The fitted airframe, the estimates in the order of ``names`` (each projected onto its
    bounds), the correlation of the continuous ones, the strongly correlated pairs, the
    residual sigma per state and the diagnostics (:mod:`uavdyn.identify.uncertainty`)."""
    u, continuous, controls = fit.unknowns, fit.continuous, fit.controls
    theta = np.clip(outcome.z[:fit.problem.n_theta], u.lo, u.hi)  # round-off may overshoot
    if continuous:
        unc = estimate_uncertainty(outcome.J, outcome.r, fit.problem.n_theta, fit.windows.count,
                                   fit.L, fit.estimate_x0, fit.interval,
                                   np.array([i for i, _ in fit.windows.starts]))
        cov_cr, cov_c, sigma_w = unc.cramer_rao, unc.corrected, unc.residual_sigma
    else:
        unc = None
        cov_cr = cov_c = np.zeros((0, 0))
        sigma_w = np.sqrt(np.mean(outcome.r.reshape(-1, N_BODY) ** 2, axis=0))
    std = np.sqrt(np.maximum(np.diag(cov_cr), 0.0)) * u.scale
    std_c = np.sqrt(np.maximum(np.diag(cov_c), 0.0)) * u.scale
    d = np.sqrt(np.maximum(np.diag(cov_c), 1e-300))
    corr = cov_c / np.outer(d, d)
    flagged = [(continuous[i], continuous[j], float(corr[i, j]))
               for i, j in combinations(range(len(continuous)), 2)
               if abs(corr[i, j]) >= CORRELATION_FLAG]
    p_fit = fit.unknowns.p_of(theta)
    p_fit[u.index] = [project_inside(fit.airframe, n, v)
                      for n, v in zip(continuous, p_fit[u.index])]
    fitted = fit.airframe.replace(**{n: float(p_fit[i]) for n, i in zip(continuous, u.index)})
    delays = outcome.delays
    if fit.searched:
        fitted = fitted.with_delays(**{c: int(delays[controls.index(c)]) for c in fit.searched})
    groups = [[continuous[j] for j in g] for g in (unc.collinear_groups if unc else [])]
    by_name = {}
    for j, (n, i) in enumerate(zip(continuous, u.index)):
        why, group = undetermined(n, float(p_fit[i]), float(std_c[j]), groups)
        by_name[n] = Estimate(n, float(u.p_nom[i]), float(p_fit[i]), float(std[j]),
                              at_bound=_at_bound(theta[j], u.lo[j], u.hi[j]),
                              std_error_corrected=float(std_c[j]), undetermined=why,
                              excitation=excitation_for(n, group) if why else "")
    nominal_delays = fit.airframe.delay_samples()
    for c in fit.searched:
        k = controls.index(c)
        by_name[DELAY_PREFIX + c] = Estimate(DELAY_PREFIX + c, float(nominal_delays[k]),
                                             float(delays[k]), 0.0, searched=True,
                                             at_bound="upper" if delays[k] == max_delay
                                             else "", std_error_corrected=0.0)
    diagnostics = {} if unc is None else unc.diagnostics(continuous, std, std_c)
    return fitted, [by_name[n] for n in names], corr, flagged, sigma_w, diagnostics


def _preroll_samples(tau: float, interval: float) -> int:
    """Samples of lag pre-roll for a time constant ``tau``, rounded up to a power of two (a
    few lengths only: each is a compiled library)."""
    need = math.ceil(max(PREROLL_MIN_S, PREROLL_TAUS * tau) / interval)
    return 1 << (int(need) - 1).bit_length()


