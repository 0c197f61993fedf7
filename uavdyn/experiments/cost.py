"""Cost of the models and solvers: the paper's Table 3, the work-precision diagram and every
timing ratio of the report, all from ONE interleaved timing run on one input segment.

Every configuration is a free run of the first ``segment_s`` seconds of one sortie, driven by
the logged commands held over each log interval (zero-order hold on the log grid), timed by
:func:`uavdyn.evaluation.interleaved_timing` (min and median of ``repeats`` timed calls, inputs
converted to CasADi once, outside the timed region). Accuracy is computed once, outside the
timing, on the same segment: pitch RMSE against the flight data (free run for a fixed wing,
1 s predictions restarted from the recorded state for a multirotor: :func:`flight_mode`) and
free-run pitch RMSE against the nominal model's fine-step reference. The figures are drawn by
:mod:`uavdyn.experiments.figures` with the other figures of the report.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.integrate

from uavdyn.airframes import Airframe
from uavdyn.emulation import Emulator, open_loop_references
from uavdyn.evaluation import (
    Solver,
    Timing,
    error_stats,
    evaluate_trajectory,
    fine_reference,
    interleaved_timing,
    ratio,
)
from uavdyn.experiments.common import flight_mode, free_run_runner, refusal, target_states
from uavdyn.flightdata import Sortie
from uavdyn.integrate import (
    DiscreteModel,
    GridError,
    StepUseError,
    body_model,
    physics_step,
    reference_step,
    rollout,
)
from uavdyn.model import build_model, numpy_rhs, sortie_params, structure_of

NOMINAL = "nominal physics"
NOMINAL_VM = "nominal physics (CasADi VM)"
CVODES = "CVODES"
EMULATOR = "emulator (truth model)"
RK4_DTS = (0.01, 0.005, 0.0025, 0.001, 0.0005)
VM_DTS = (0.005, 0.001)
MODEL_DTS = (0.02, 0.01, 0.005, 0.0025)
CVODES_TOLS = (1e-6, 1e-8, 1e-10)
SCIPY_RUNS = (("RK45", 1e-3), ("RK45", 1e-6), ("DOP853", 1e-8))
SCIPY_ATOL_FACTOR = 1e-2  # atol = rtol * factor (states of order 1-30)
EMULATOR_DT = 0.001  # the emulator's internal RK4 step
# Table 3: the paper's rows (RK4 at 0.001 and 0.0005 s, the models at 0.005 s) and every other
# solver that matters: the nominal physics and each model at the log interval and 0.005 s, the
# CasADi VM, CVODES at 1e-8, scipy RK45 at rtol 1e-6, DOP853 at 1e-8 and the emulator.
TABLE3_RK4_DTS = (0.01, 0.005, 0.001, 0.0005)
TABLE3_MODEL_DTS = (0.01, 0.005)
TABLE3_CVODES_TOL = 1e-8
TABLE3_SCIPY = (("RK45", 1e-6), ("DOP853", 1e-8))
HARNESS = "interleaved, min and median of N repeats, inputs converted outside the timed region"
FAMILY_ORDER = (NOMINAL, NOMINAL_VM, CVODES, "scipy RK45", "scipy DOP853", EMULATOR)


@dataclass
class _Point:
    """One timed configuration before timing: its callable and its accuracy."""

    label: str
    family: str
    setting: str
    dt: float | None
    compiled: bool
    run: Callable[[], object]
    airframe: str
    in_table3: bool
    tol: float | None = None
    flight: float | None = None
    reference: float | None = None
    note: str | None = None


def _segment(sortie: Sortie, segment_s: float | None) -> int:
    """Number of log intervals of the timed segment (the whole sortie for None or more)."""
    n = len(sortie.time) - 1
    if segment_s is None:
        return n
    if not (segment_s > 0):
        raise ValueError(f"segment_s must be positive or None, got {segment_s}")
    return min(n, int(round(segment_s / sortie.dt)))


def _theta_rmse(pred: np.ndarray, target: np.ndarray) -> float:
    return error_stats(pred, target)["theta_rmse"]


def _step_accuracy(solver: Solver, time: np.ndarray, truth: np.ndarray, ref: np.ndarray,
                   controls: np.ndarray, p: np.ndarray, mode: str
                   ) -> tuple[float | None, float | None, str | None]:
    """(vs flight in ``mode``, free run vs reference, why a value is missing) via the same
    evaluation code as Table 1."""
    flight = evaluate_trajectory(solver, time, truth, controls, p)
    free = evaluate_trajectory(solver, time, ref, controls, p)
    why = [f"{m}: {r}" for res in (flight, free) for m, r in res.get("refused", {}).items()]
    return (_theta_rmse(*flight[mode]) if mode in flight else None,
            _theta_rmse(*free["free_run"]) if "free_run" in free else None,
            "; ".join(why) or None)


def _sim_accuracy(simulate: Callable[[np.ndarray, np.ndarray], np.ndarray], time: np.ndarray,
                  truth: np.ndarray, ref: np.ndarray, controls: np.ndarray, mode: str,
                  whole: np.ndarray) -> tuple[float, float]:
    """The same two accuracies for a solver that is not a step Function (scipy, emulator):
    ``simulate(x0, controls)`` returns ``len(controls) + 1`` body states, the first ``x0``;
    ``whole`` is its free run of the segment. Windows as in ``evaluate_trajectory``."""
    vs_ref = _theta_rmse(whole[1:], ref[1:])
    if mode == "free_run":
        return _theta_rmse(whole[1:], truth[1:]), vs_ref
    n_len = int(round(1.0 / float(np.median(np.diff(time)))))  # 1 s windows
    starts = np.arange(0, len(time) - n_len, n_len)
    if not len(starts):
        return math.nan, vs_ref
    pred = np.concatenate([simulate(truth[k], controls[k:k + n_len + 1])[1:n_len + 1]
                           for k in starts])
    target = np.concatenate([truth[k + 1:k + n_len + 1] for k in starts])
    return _theta_rmse(pred, target), vs_ref


def _scipy_simulator(rhs, p: np.ndarray, sample_dt: float, method: str, rtol: float):
    atol = rtol * SCIPY_ATOL_FACTOR

    def simulate(x0: np.ndarray, controls: np.ndarray) -> np.ndarray:
        """One ``solve_ivp`` call per log interval, the command held over it (rows of
        ``controls`` past the last interval are ignored)."""
        n = len(controls) - 1 if len(controls) > 1 else 1
        out = np.empty((n + 1, len(x0)))
        x = out[0] = x0
        for k in range(n):
            u = controls[k]
            sol = scipy.integrate.solve_ivp(lambda t, y, u=u: rhs(y, u, p), (0.0, sample_dt), x,
                                            method=method, rtol=rtol, atol=atol)
            x = out[k + 1] = sol.y[:, -1]
        return out

    return simulate


def _bar_total(progress, n: int) -> None:
    owner = getattr(progress, "__self__", None)  # tqdm's bound ``update``: size the bar
    if owner is not None and hasattr(owner, "total"):
        owner.total = n
        if hasattr(owner, "refresh"):
            owner.refresh()


@dataclass(frozen=True)
class _Segment:
    """The timed and scored stretch of the sortie: what every configuration runs on."""

    name: str
    time: np.ndarray
    truth: np.ndarray
    controls: np.ndarray  # N+1 rows: row n is never applied (states at t_0..t_n)
    sample_dt: float
    altitude: float | None
    mode: str  # how accuracy against the flight data is measured (:func:`flight_mode`)
    reference: np.ndarray  # the nominal model's fine-step free run

    @property
    def applied(self) -> np.ndarray:
        """The commands applied (one per log interval), contiguous."""
        return np.ascontiguousarray(self.controls[:-1])

    @property
    def x0(self) -> np.ndarray:
        return self.truth[0]

    @property
    def duration(self) -> float:
        return float(self.time[-1] - self.time[0])


def _segment_of(nominal: Airframe, sortie: Sortie, segment_s: float | None) -> _Segment:
    n = _segment(sortie, segment_s)
    time, truth = sortie.time[:n + 1], target_states(sortie)[:n + 1]
    controls = sortie.controls[:n + 1]
    ref = fine_reference(nominal, time, truth[0], controls,
                         sortie_params(nominal, sortie.altitude_m))
    return _Segment(sortie.name, time, truth, controls, sortie.dt, sortie.altitude_m,
                    flight_mode(nominal.kind), ref)


def _step_points(seg: _Segment, family: str, step: DiscreteModel, af: Airframe, dts,
                 compiled: bool, table_dts) -> tuple[list[_Point], list[dict]]:
    """A discrete model's free runs at every step size of ``dts`` it accepts (compiled
    rollouts, or the CasADi VM), and the step sizes it refuses with the reason."""
    p = sortie_params(af, seg.altitude)
    points, missing = [], []
    for dt in dts:
        why = refusal(step, dt, seg.duration)
        if why is None:
            try:
                run = free_run_runner(step, seg.x0, seg.applied, p, seg.sample_dt, dt,
                                      compiled)
            except (GridError, StepUseError, ValueError) as exc:
                why = str(exc)
        if why is not None:  # reported missing with the reason, never dropped
            missing.append({"family": family, "dt": dt, "compiled": compiled, "missing": why})
            continue
        flight, vs_ref, note = _step_accuracy(Solver(family, step, dt), seg.time, seg.truth,
                                              seg.reference, seg.controls, p, seg.mode)
        points.append(_Point(f"{family} @ {dt:g} s", family, f"dt {dt:g} s", dt, compiled,
                             run, af.name, dt in table_dts, flight=flight, reference=vs_ref,
                             note=note))
    return points, missing


def _reference_solver_points(seg: _Segment, nominal: Airframe
                             ) -> tuple[list[_Point], list[dict]]:
    """CVODES at :data:`CVODES_TOLS` and scipy at :data:`SCIPY_RUNS` on the rigid body, or
    all of them missing where the airframe has actuator lags or delays."""
    structure = structure_of(nominal)
    if structure.augmented:  # CVODES and scipy integrate the rigid body on the logged commands
        why = ("the reference solvers integrate the rigid body on the logged commands; "
               f"airframe '{nominal.name}' has actuator lags or delays")
        return [], ([{"family": CVODES, "dt": None, "tol": t, "missing": why}
                     for t in CVODES_TOLS] +
                    [{"family": f"scipy {m}", "dt": None, "tol": r, "missing": why}
                     for m, r in SCIPY_RUNS])
    p_nom = sortie_params(nominal, seg.altitude)
    f = build_model(nominal).f
    u_dm, p_dm, x_dm = ca.DM(seg.applied.T), ca.DM(p_nom), ca.DM(seg.x0)
    points = []
    for tol in CVODES_TOLS:
        cv_step = reference_step(f, tol=tol)
        cv = rollout(cv_step, len(seg.applied))

        def run_cvodes(cv=cv) -> np.ndarray:
            return np.asarray(cv(x_dm, u_dm, p_dm, seg.sample_dt))

        flight, vs_ref, note = _step_accuracy(
            Solver(CVODES, body_model(cv_step, nominal.kind), seg.sample_dt), seg.time,
            seg.truth, seg.reference, seg.controls, p_nom, seg.mode)
        points.append(_Point(f"CVODES (tol {tol:g})", CVODES, f"tol {tol:g}", None, False,
                             run_cvodes, nominal.name, tol == TABLE3_CVODES_TOL, tol=tol,
                             flight=flight, reference=vs_ref, note=note))
    rhs = numpy_rhs(structure)
    for method, rtol in SCIPY_RUNS:
        sim = _scipy_simulator(rhs, p_nom, seg.sample_dt, method, rtol)

        def run_scipy(sim=sim) -> np.ndarray:
            return sim(seg.x0, seg.controls)

        flight, vs_ref = _sim_accuracy(sim, seg.time, seg.truth, seg.reference, seg.controls,
                                       seg.mode, run_scipy())
        points.append(_Point(f"scipy {method} (rtol {rtol:g})", f"scipy {method}",
                             f"rtol {rtol:g}, atol {rtol * SCIPY_ATOL_FACTOR:g}", None,
                             False, run_scipy, nominal.name, (method, rtol) in TABLE3_SCIPY,
                             tol=rtol, flight=flight, reference=vs_ref))
    return points, []


def _emulator_point(seg: _Segment, nominal: Airframe) -> _Point:
    """The emulator (the truth model) replaying the logged commands open loop."""
    emulator = Emulator(nominal)
    # the emulator's default when no altitude is logged
    emu_alt = 100.0 if seg.altitude is None else seg.altitude

    def emulate(x: np.ndarray, c: np.ndarray) -> np.ndarray:
        xe = emulator.initial_state(x, c[0], emu_alt)
        return emulator.fly(xe, open_loop_references(c)).true_states[:, :len(x)]

    xe0 = emulator.initial_state(seg.x0, seg.controls[0], emu_alt)
    refs = open_loop_references(seg.controls)

    def run_emulator() -> np.ndarray:
        return emulator.fly(xe0, refs).true_states

    flight, vs_ref = _sim_accuracy(emulate, seg.time, seg.truth, seg.reference, seg.controls,
                                   seg.mode, run_emulator()[:, :seg.truth.shape[1]])
    return _Point(f"{EMULATOR} (RK4 @ {EMULATOR_DT:g} s)", EMULATOR,
                  f"RK4 @ {EMULATOR_DT:g} s + actuators, unsteady aero", EMULATOR_DT, True,
                  run_emulator, nominal.name, True, flight=flight, reference=vs_ref,
                  note="times the emulator's own input handling too")


def _point_row(pt: _Point, timing: Timing, mode: str) -> dict:
    return {"label": pt.label, "family": pt.family, "setting": pt.setting, "dt": pt.dt,
            "tol": pt.tol, "compiled": pt.compiled, "airframe": pt.airframe,
            "min_ms": timing.min_ms, "median_ms": timing.median_ms,
            "theta_rmse_vs_flight": pt.flight, "flight_mode": mode,
            "theta_rmse_vs_reference": pt.reference, "in_table3": pt.in_table3,
            "note": pt.note}


def cost_study(nominal: Airframe, sortie: Sortie,
               models: Mapping[str, tuple[ca.Function, Airframe]], repeats: int = 15,
               segment_s: float | None = 10.0, compiled_vm: bool = True,
               progress: Callable[[], None] | None = None) -> dict:
    """Table 3, the work-precision points and the timing ratios from one interleaved run.

    Families (each a free run of the same segment, same zero-order-held inputs):

    - ``"nominal physics"``: the nominal airframe's compiled RK4 rollout at
      :data:`RK4_DTS`; ``"nominal physics (CasADi VM)"`` the same at :data:`VM_DTS`
      (``compiled_vm``);
    - every model of ``models`` (compiled rollout) at each of :data:`MODEL_DTS` it accepts; a
      step size it refuses is listed under ``missing`` with the reason;
    - ``"CVODES"`` (one integrator call per log interval, CasADi VM) at :data:`CVODES_TOLS`;
      ``"scipy RK45"``/``"scipy DOP853"`` (``solve_ivp`` per log interval, NumPy right-hand
      side) at :data:`SCIPY_RUNS`; the emulator (the truth model) once.

    Parameters
    ----------
    nominal : Airframe
        The nominal airframe (its fine-step RK4 is the reference).
    sortie : Sortie
        One (test) sortie; its first ``segment_s`` seconds are timed.
    models : Mapping[str, tuple[casadi.Function, Airframe]]
        Label (e.g. ``"identified physics"``, ``"corrected"``) -> (step Function, the airframe
        whose parameters it runs on). A label containing ``"physics"`` is a physics baseline.
    repeats : int
        Timed calls per configuration (15 by default; fewer only for tests/quick runs).
    segment_s : float or None
        Seconds from the sortie start that are timed and scored; None: the whole sortie.
    compiled_vm : bool
        Also time the nominal RK4 rollout in the CasADi VM.
    progress : callable, optional
        Called once per timed call (e.g. a tqdm bar's ``update``; the bar's ``total`` is set
        to the number of timed calls).

    Returns
    -------
    dict
        JSON-able: ``sortie``, ``segment_s`` (the seconds actually timed), ``grid``,
        ``repeats``, ``harness``, ``points`` (one dict per configuration: ``label``,
        ``family``, ``setting``, ``dt``, ``tol``, ``compiled``, ``airframe``, ``min_ms``,
        ``median_ms``, ``theta_rmse_vs_flight``, ``flight_mode``, ``theta_rmse_vs_reference``,
        ``in_table3``, ``note``), ``flight_mode``, ``missing`` (``family``, ``dt``,
        ``compiled`` or ``tol``, ``missing``: the reason) and ``ratios``: ``definition``,
        ``vs_physics_same_dt`` (``model``, ``dt``, ``baseline``, ``median``, ``min``),
        ``vs_fine_rk4`` (``model``, ``baseline``, ``median``, ``min``) and
        ``vs_fastest_model`` (``reference``: the fastest model point; ``points``: ``label``,
        ``median``, ``min`` for every point). Each ratio is ``time(a) / time(b)`` of the
        medians (``median``) and of the minima (``min``) of this one harness run.

    Raises
    ------
    ValueError
        If ``segment_s`` is not positive, or ``repeats < 1``.
    """
    seg = _segment_of(nominal, sortie, segment_s)
    rk4 = physics_step(nominal)
    families = [(NOMINAL, rk4, nominal, RK4_DTS, True, TABLE3_RK4_DTS)]
    if compiled_vm:
        families.append((NOMINAL_VM, rk4, nominal, VM_DTS, False, VM_DTS))
    families += [(label, step, af, MODEL_DTS, True, TABLE3_MODEL_DTS)
                 for label, (step, af) in models.items()]
    points: list[_Point] = []
    missing: list[dict] = []
    for family in families:
        pts, gone = _step_points(seg, *family)
        points += pts
        missing += gone
    pts, gone = _reference_solver_points(seg, nominal)
    points += pts
    missing += gone
    points.append(_emulator_point(seg, nominal))

    _bar_total(progress, len(points) * repeats)
    timings = interleaved_timing({pt.label: pt.run for pt in points}, repeats,
                                 progress=progress)
    return {"sortie": sortie.name, "segment_s": seg.duration,
            "grid": (f"logged commands held over each {seg.sample_dt:g} s log interval (ZOH on "
                     "the log grid); a step longer than the interval samples the command at "
                     "its own step start"),
            "repeats": repeats, "harness": HARNESS.replace("N repeats", f"{repeats} repeats"),
            "flight_mode": seg.mode,
            "points": [_point_row(pt, timings[pt.label], seg.mode) for pt in points],
            "missing": missing, "ratios": _ratios(points, timings, models)}


def _ratios(points: list[_Point], timings: dict[str, Timing], models: Mapping) -> dict:
    """The timing ratios quoted by the report, each ``{"median": .., "min": ..}`` from the one
    harness run (``a / b`` of medians and of minima):

    - ``vs_physics_same_dt``: every model point against each physics baseline at the same
      ``dt`` (the nominal physics, and every model whose label contains ``"physics"``);
    - ``vs_fine_rk4``: every model that is not a physics baseline against the nominal physics
      at 0.001 s and 0.0005 s (the paper's comparison);
    - ``vs_fastest_model``: every point against the model point with the smallest median
      (named in ``reference``).
    """
    by = {(pt.family, pt.dt, pt.compiled): pt for pt in points}

    def pair(a: _Point, b: _Point) -> dict:
        ta, tb = timings[a.label], timings[b.label]
        return {"median": ratio(ta, tb, "median"), "min": ratio(ta, tb, "min")}

    physics = [NOMINAL] + [m for m in models if "physics" in m]
    same, fine = [], []
    model_points = [pt for pt in points if pt.family in models]
    for pt in model_points:
        for base in physics:
            b = by.get((base, pt.dt, True))
            if b is not None and b is not pt:
                same.append({"model": pt.family, "dt": pt.dt, "baseline": b.label,
                             **pair(pt, b)})
        if "physics" not in pt.family:
            for dt in (0.001, 0.0005):
                b = by.get((NOMINAL, dt, True))
                if b is not None:
                    fine.append({"model": pt.label, "baseline": b.label, **pair(pt, b)})
    out = {"definition": "time(a) / time(b) from the one interleaved run: 'median' of the "
                         "medians, 'min' of the minima",
           "vs_physics_same_dt": same, "vs_fine_rk4": fine}
    if model_points:
        fastest = min(model_points, key=lambda pt: timings[pt.label].median_s)
        out["vs_fastest_model"] = {
            "reference": {"label": fastest.label, "family": fastest.family, "dt": fastest.dt},
            "points": [{"label": pt.label, **pair(pt, fastest)} for pt in points]}
    return out
