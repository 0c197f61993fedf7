"""Output-error identification of named physical parameters from flight data.

The model's discrete step (:func:`uavdyn.integrate.physics_step`: RK sub-steps per log sample,
actuator lags as augmented states) is rolled out over short windows, each restarted from a
recorded state (multiple shooting on data: closed-loop flights and marginally stable airframes
stay fit-able), and the chosen entries of ``p`` minimise the weighted squared difference between
predicted and recorded body states ``(u, w, q, theta)``: each state weighted by its residual
level, and, after the first fit, each sortie by its own (maximum likelihood with a noise level
per sortie: a calm flight's small residuals count as much as they say, instead of being
drowned by a turbulent flight's, whose unmeasured gusts would otherwise bias every estimate
toward what absorbs them). The least squares are solved by a
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

import dataclasses
import math
import time
from itertools import combinations

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.flightdata import Sortie
from uavdyn.identify.consistency import compare_halves
from uavdyn.identify.errors import IdentifyError
from uavdyn.identify.excitation import excitation_for, refuse_unexcited
from uavdyn.identify.fallback import keep_file_values
from uavdyn.identify.fitstate import (
    PREROLL_MIN_S,
    PREROLL_TAUS,
    STATE_WEIGHT_FLOOR,
    _Fit,
    _nominal_weights,
    _Outcome,
    _preroll_samples,
    _time_grid,
    measurement_noise,
)
from uavdyn.identify.freerun import free_run_check, stiffness_check
from uavdyn.identify.prior import (
    check_prior_sd,
    posterior,
    prior_precision,
    prior_share,
    prior_weights,
    with_data_verdicts,
)
from uavdyn.identify.problem import COMPILE_FLAGS, _check_excitation
from uavdyn.identify.result import DEFAULT_SUBSTEPS, Estimate, IdentificationResult
from uavdyn.identify.search import RECHECK_STEPS, SEARCH_ROUNDS, _recheck_delays, _search
from uavdyn.identify.uncertainty import (
    constrained,
    estimate_uncertainty,
    physical_combination,
    undetermined,
)
from uavdyn.identify.unknowns import (
    DELAY_PREFIX,
    TAU_BOUNDS,
    TAU_GRID,
    TAU_NAMES,
    TAU_SCALE,
    _at_bound,
    _check_request,
    control_names,
    project_inside,
    scaled_unknowns,
)
from uavdyn.identify.weighting import (
    REWEIGHT_FLOOR,
    hold_rows,
    per_sortie_weights,
    residual_weights,
    sortie_weights,
    window_residuals,
)
from uavdyn.identify.windows import (
    N_BODY,
    fit_summary,
    training_windows,
    window_density_ratios,
)
from uavdyn.model import LAG_PARAMS, structure_of

__all__ = ["COMPILE_FLAGS", "CORRELATION_FLAG", "DEFAULT_SUBSTEPS", "DELAY_PREFIX",
           "PREROLL_GROWTH", "PREROLL_MIN_S", "PREROLL_TAUS", "RECHECK_STEPS",
           "REWEIGHT_FLOOR", "REWEIGHT_PASSES",
           "SEARCH_ROUNDS", "STATE_WEIGHT_FLOOR", "TAU_BOUNDS", "TAU_GRID", "TAU_NAMES",
           "TAU_SCALE", "Estimate", "IdentificationResult", "control_names", "identify",
           "measurement_noise"]

CORRELATION_FLAG = 0.9
PREROLL_GROWTH = 4.0     # the first pre-roll covers lags up to this many times their start
HALF_ITERATIONS = 30     # the halves start from the whole fit: a few steps move them
REWEIGHT_PASSES = 1      # refits with each state weighted by its residual after the fit ...
SORTIE_WEIGHTS = True    # ... and each sortie by its own residual level


def identify(airframe: Airframe, train: list[Sortie], validation: list[Sortie],
             names: list[str], window_s: float = 1.0, dt: float | None = None,
             relative_bound: float | None = None,
             bounds: dict[str, tuple[float, float]] | None = None, max_iterations: int = 60,
             estimate_x0: bool = True, max_windows: int | None = 120, max_delay: int = 5,
             substeps: int | None = None, progress: bool = True,
             check_halves: bool = True, preroll: int | None = None, screen: bool = True,
             prior_sd: float | None = None, keep_undetermined: bool = False,
             free_run: bool = True, hold: list[dict[str, float]] | None = None
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
        range only (the schema's bound by its meaning and sign convention: the derivatives
        of :data:`uavdyn.airframes.SIGNS` keep their physical sign, other coefficients may
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
        its noise (:func:`~uavdyn.identify.excitation.screen_excitation`; default True); a
        signal that moves above its noise but less than the advisory floor is fitted and
        listed in ``result.fit["excitation_advice"]``.
    check_halves : bool
        With four or more training sorties, also fit each half of them (alternate sorties,
        :func:`uavdyn.identify.consistency.compare_halves`): a parameter the halves disagree on
        beyond their standard errors is flagged, and its corrected standard error is at least
        half the difference.
    preroll : int, optional
        Samples of lag pre-roll before each window (default: enough for the time constants,
        with room to grow); never shorter than the lags need.
    prior_sd : float, optional
        A Gaussian prior on each fitted parameter around the file's value with this relative
        standard deviation (none on a parameter whose file value is 0): the estimate is the
        maximum a posteriori, its standard errors the posterior's, each estimate says the
        prior's share of the information
        (:mod:`uavdyn.identify.prior`). A parameter the data do not determine is then fitted
        under the prior. Default: no prior.
    keep_undetermined : bool
        False (default): a parameter the data do not determine (interval spanning zero,
        collinear, on a bound; under a prior: on a bound) keeps the airframe file's value and
        the others are refitted with it fixed (:mod:`uavdyn.identify.fallback`). True: the
        raw fit, every value as fitted (flagged).
    free_run : bool
        Fly each train sortie open loop from its first state with the nominal and the
        identified model and record which depart (:mod:`uavdyn.identify.freerun`; default).
    hold : list of dict, optional
        Combinations of the parameters held at the file's values, each ``{name: c}`` for
        ``sum c * (p - p_file) = 0`` (a fit's ``diagnostics["weak_directions"]``, the
        combinations its data could not determine): the fit is constrained to them, the
        standard errors are the constrained ones (:mod:`uavdyn.identify.fallback`).

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
    if prior_sd is not None:
        prior_sd = check_prior_sd(prior_sd)
    advice = refuse_unexcited(continuous, train) if screen else []
    fit = _prepare(airframe, train, continuous, searched, window_s, dt, substeps,
                   max_windows, relative_bound, bounds, estimate_x0, preroll)
    held = hold_rows(fit, hold) if hold else None
    outcome = _solve(fit, max_delay, max_iterations, progress)
    if held is not None:  # the held rows are not data
        n_data = outcome.r.size - held.shape[0]
        outcome = dataclasses.replace(outcome, r=outcome.r[:n_data], J=outcome.J[:n_data])
    result = _result(fit, outcome, names, max_delay, train, validation, t_start,
                     held=held)
    if check_halves and continuous and len(train) >= 4:
        compare_halves(identify, result, train, continuous, max(1, fit.windows.count // 2),
                      {"window_s": window_s, "dt": dt, "bounds": bounds,
                       "max_iterations": min(max_iterations, HALF_ITERATIONS),
                       "estimate_x0": estimate_x0, "keep_undetermined": True,
                       "free_run": False, "substeps": substeps, "progress": False,
                       "check_halves": False, "preroll": fit.problem.M or None})
    if prior_sd is not None and continuous:
        result = _with_prior(fit, outcome, result, prior_sd, names, max_delay, train,
                             validation, max_iterations, progress, t_start)
    if not keep_undetermined:
        result = keep_file_values(
            identify, result, airframe, train, validation, names,
            {"window_s": window_s, "dt": dt, "relative_bound": relative_bound,
             "bounds": bounds, "max_iterations": max_iterations, "estimate_x0": estimate_x0,
             "max_windows": max_windows, "max_delay": max_delay, "substeps": substeps,
             "progress": progress, "check_halves": check_halves, "preroll": preroll,
             "screen": False, "prior_sd": prior_sd})
    if advice:
        result.fit["excitation_advice"] = advice
    if free_run:
        result.fit["free_run"] = free_run_check(airframe, result.airframe, train,
                                                result.substeps)
        result.fit["step_stiffness"] = stiffness_check(
            result.airframe, float(np.median(np.diff(train[0].time))))
    result.seconds = time.perf_counter() - t_start
    return result


def _result(fit: _Fit, outcome: _Outcome, names: list[str], max_delay: int,
            train: list[Sortie], validation: list[Sortie], t_start: float,
            prior: np.ndarray | None = None, held: np.ndarray | None = None
            ) -> IdentificationResult:
    """The result of a solved fit: estimates, their uncertainty (with a ``prior``, the
    precision of each scaled unknown's prior: the posterior's; with ``held`` combinations, the
    constrained one; whether the data determine each parameter: the data's at the estimate)
    and the fit per split."""
    airframe = fit.airframe
    fitted, estimates, corr, flagged, sigma_w, diagnostics = _estimates(
        fit, outcome, names, max_delay, prior, held)
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
    return IdentificationResult(
        airframe=fitted, estimates=estimates, correlation=corr, flagged_pairs=flagged,
        state_sigma=1.0 / fit.weights * sigma_w, cost_initial=outcome.cost_initial,
        cost_final=0.5 * float(r @ r), iterations=outcome.iterations,
        seconds=time.perf_counter() - t_start, window_s=fit.L * fit.interval,
        dt=fit.interval / fit.substeps, fit=summary, substeps=fit.substeps,
        search=outcome.log, diagnostics=diagnostics)


def _with_prior(fit: _Fit, outcome: _Outcome, data_only: IdentificationResult,
                rel_sd: float, names: list[str], max_delay: int, train: list[Sortie],
                validation: list[Sortie], max_iterations: int, progress: bool,
                t_start: float) -> IdentificationResult:
    """The maximum a posteriori fit from the data-only one (:mod:`uavdyn.identify.prior`):
    the prior's rows added to the least squares, refitted from the data-only estimate, the
    posterior covariance, and each estimate with the data's verdict and the prior's pull."""
    u = fit.unknowns
    by_name = {e.name: e for e in data_only.estimates}
    data = [by_name[n] for n in fit.continuous]
    precision = prior_precision(u.p_nom[u.index], rel_sd)
    fit.prior = prior_weights(np.array([e.std_error_corrected for e in data]),
                              np.array([e.std_error for e in data]), precision)
    fit.data_cache.clear()
    log = [*outcome.log, {"step": "prior", "relative_sd": rel_sd,
                          "weights": fit.prior.tolist()}]
    lower = np.concatenate([u.lo, np.full(fit.problem.n_dx, -np.inf)])
    upper = np.concatenate([u.hi, np.full(fit.problem.n_dx, np.inf)])
    z, delays, iterations, stats = _fit_and_recheck(
        fit, outcome.z, list(outcome.delays), lower, upper, max_delay, max_iterations,
        progress, 0, {}, log)
    r, J = fit.problem.evaluate(z, fit.data_for(delays))
    n_data = r.size - fit.problem.n_theta  # the prior's rows are not data
    outcome_map = _Outcome(z, delays, r[:n_data], J[:n_data], outcome.cost_initial,
                           outcome.iterations + iterations, stats, log)
    result = _result(fit, outcome_map, names, max_delay, train, validation, t_start,
                     precision)
    result.estimates = with_data_verdicts(result.estimates, data_only.estimates)
    result.diagnostics["data_only"] = data_only.to_dict()["estimates"]
    return result


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
    its own residual after the fit (not the nominal model's error) and each sortie by its own
    residual level: optimal weights for the estimate, and the ones the Cramer-Rao bound
    assumes."""
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
        resid = window_residuals(fit, z, delays)
        rms, floor, new = residual_weights(fit, resid)
        per_sortie = sortie_weights(fit, resid) if SORTIE_WEIGHTS else None
        moved = (per_sortie is not None and fit.window_weights is None
                 and np.max(np.abs(np.log(per_sortie))) >= 0.1)
        if (pass_ == REWEIGHT_PASSES or np.all(rms <= floor)  # noise-free: fit exact
                or (np.max(np.abs(np.log(new / fit.weights))) < 0.1 and not moved)):
            break
        fit.weights = new
        if per_sortie is not None:
            fit.window_weights = per_sortie
        fit.data_cache.clear()
        log.append({"step": "re-weighted", "weights": fit.weights.tolist(),
                    "sortie_weights": per_sortie_weights(fit)})
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


def _estimates(fit: _Fit, outcome: _Outcome, names: list[str], max_delay: int,
               prior: np.ndarray | None = None, held: np.ndarray | None = None
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
    std_data = np.sqrt(np.maximum(np.diag(cov_c), 0.0)) * u.scale  # what the data say
    share = np.full(len(continuous), math.nan)
    if prior is not None and continuous:  # the posterior (uavdyn.identify.prior)
        cov_cr, cov_post = posterior(cov_cr, prior), posterior(cov_c, prior)
        share = np.where(prior > 0, prior_share(cov_c, cov_post), math.nan)
        cov_c = cov_post
    if held is not None and continuous:  # the held combinations carry no variance
        cov_cr, cov_c = constrained(cov_cr, held), constrained(cov_c, held)
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
        why, group = undetermined(n, float(p_fit[i]), float(std_data[j]), groups)
        by_name[n] = Estimate(n, float(u.p_nom[i]), float(p_fit[i]), float(std[j]),
                              at_bound=_at_bound(theta[j], u.lo[j], u.hi[j]),
                              std_error_corrected=float(std_c[j]), undetermined=why,
                              excitation=excitation_for(n, group) if why else "",
                              prior_share=float(share[j]))
    nominal_delays = fit.airframe.delay_samples()
    for c in fit.searched:
        k = controls.index(c)
        by_name[DELAY_PREFIX + c] = Estimate(DELAY_PREFIX + c, float(nominal_delays[k]),
                                             float(delays[k]), 0.0, searched=True,
                                             at_bound="upper" if delays[k] == max_delay
                                             else "", std_error_corrected=0.0)
    diagnostics = {} if unc is None else unc.diagnostics(continuous, std, std_c)
    if unc is not None and len(unc.weak_directions):
        diagnostics["weak_directions"] = [physical_combination(a, continuous, u.scale)
                                          for a in unc.weak_directions]
    if held is not None:
        diagnostics["held_at_file_values"] = [physical_combination(a, continuous, u.scale)
                                              for a in held]
    return fitted, [by_name[n] for n in names], corr, flagged, sigma_w, diagnostics
