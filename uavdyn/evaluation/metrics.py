"""Validation metrics: one-step, 1 s-horizon and free-run errors of any step Function (physics
RK4 or hybrid) against a target trajectory (the emulated/recorded flight data, or the fine-step
reference of the baseline model), on the logged zero-order-held control grid.

A solver step ``dt`` smaller than the log interval runs ``sample_dt/dt`` sub-steps per logged
control; a larger ``dt`` (e.g. 0.02 s on 100 Hz data) samples the logged control at its own
step start and is compared at its own grid points only. Every table says which.

A :class:`uavdyn.integrate.DiscreteModel` with extra states (actuator lags, transport delays,
a correction's command memory) is restarted from a recorded body state with the extra states
that the recorded commands imply (:meth:`DiscreteModel.initial_state`). Errors are always
computed on the body states. Delays count calls of the
step, so a step with delays is used at the log interval (finer RK: ``physics_step(...,
substeps=k)``) and refused at any other step size.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.integrate import (
    DEPARTURE_RAD,
    DIVERGENCE_BOUND,
    DiscreteModel,
    EvalGrid,
    StepUseError,
    body_model,
    check_finite,
    free_run,
    physics_step,
    predict_windows,
    rk4_step,
    sortie_free_run,
    step_states,
)
from uavdyn.interrupts import check_interrupted
from uavdyn.model import ModelStructure, build_model, first_departure, structure_of

METRIC_STATES = {"theta": 3, "q": 2, "u": 0}
MODES = ("one_step", "horizon_1s", "free_run")


@dataclass(frozen=True)
class Solver:
    """A named discrete model at a step size (a bare step Function is wrapped as a model on
    the 4 body states, usable at any step size)."""

    name: str
    model: DiscreteModel
    dt: float

    def __post_init__(self) -> None:
        if not isinstance(self.model, DiscreteModel):
            raise TypeError(f"solver '{self.name}': give a DiscreteModel (uavdyn.physics_step, "
                            f"uavdyn.hybrid_step), got {type(self.model).__name__}")

    @property
    def time_input(self) -> bool:
        return self.model.takes_time


def error_stats(predicted: np.ndarray, target: np.ndarray) -> dict[str, float]:
    """RMSE, MAE and maximum absolute error of pitch, pitch rate and forward speed."""
    out = {}
    for name, i in METRIC_STATES.items():
        with np.errstate(over="ignore", invalid="ignore"):
            err = predicted[..., i] - target[..., i]
            err = np.where(np.abs(err) <= DIVERGENCE_BOUND, err, np.inf)  # diverged: infinite
        if not np.all(np.isfinite(err)):
            out.update({f"{name}_rmse": float("inf"), f"{name}_mae": float("inf"),
                        f"{name}_max": float("inf")})
            continue
        out[f"{name}_rmse"] = float(np.sqrt(np.mean(err**2)))
        out[f"{name}_mae"] = float(np.mean(np.abs(err)))
        out[f"{name}_max"] = float(np.max(np.abs(err)))
    return out


def solver_windows(solver: Solver, x0s: np.ndarray, controls: np.ndarray, t0s: np.ndarray,
                   p: np.ndarray, sample_dt: float) -> tuple[np.ndarray, int]:
    """:func:`uavdyn.integrate.predict_windows` of a solver on logged data: each window's
    commands are one row per log interval (``K x L x nu``); a solver step longer than the log
    interval samples every ``stride``-th command. Returns the predicted states at the
    solver's grid points (``K x L/stride x nx``) and the stride. ``x0s`` are the step's own
    states (:func:`step_states`)."""
    g = EvalGrid(sample_dt, solver.dt)
    K, L, _ = controls.shape
    if np.shape(x0s)[-1] != solver.model.nx:
        raise ValueError(f"start states have {np.shape(x0s)[-1]} columns, step "
                         f"'{solver.model.name}' has {solver.model.nx} states (augment "
                         "recorded states with step_states)")
    if L % g.stride:
        raise ValueError(f"window of {L} log intervals is not a multiple of the stride "
                         f"{g.stride}")
    pred = predict_windows(solver.model, x0s, controls[:, ::g.stride, :], p, solver.dt,
                           g.substeps, t0s)
    return pred, g.stride


def evaluate_trajectory(solver: Solver, time: np.ndarray, states: np.ndarray,
                        controls: np.ndarray, p: np.ndarray, horizon_s: float = 1.0
                        ) -> dict[str, np.ndarray]:
    """Predictions of one solver on one target trajectory (states ``N x 4`` at the log times,
    ``controls`` row k held over [t_k, t_k+1)). Returns, per mode, ``(predicted, target)``
    arrays of matching shape, plus the free-run time axis and, when the free run leaves the
    physical ranges (:func:`uavdyn.model.first_departure`), ``"free_run_departure"`` (time,
    state, text). A mode the step refuses (outside its trained step size or time range;
    delays at another step size) is absent and its reason is under ``"refused"``. A model with
    extra states restarts from the recorded states with the actuator/buffer/memory states of
    the recorded commands; predictions are its body states."""
    sample_dt = float(np.median(np.diff(time)))
    N = len(time)
    grid = EvalGrid(sample_dt, solver.dt)
    stride = grid.stride
    time = time - time[0]  # a time input is always time since the start of the sortie
    results: dict = {}
    refused: dict[str, str] = {}
    nb = states.shape[1]
    try:
        z = step_states(solver.model, states, controls, p, grid)
    except StepUseError as exc:
        return {"refused": {mode: str(exc) for mode in MODES}}

    def one_step() -> None:  # one solver step from every recorded state on the solver's grid
        starts = np.arange(0, N - stride, stride)
        pred, _ = solver_windows(solver, z[starts],
                                  np.stack([controls[k:k + stride] for k in starts]),
                                  time[starts], p, sample_dt)
        results["one_step"] = (pred[:, 0, :nb], states[starts + stride])

    def horizon() -> None:  # windows restarted from the recorded state every horizon
        windows = _horizon_windows(solver, z, time, states, controls, p, grid, horizon_s)
        if windows is not None:
            results["horizon_1s"], results["horizon_1s_time"] = windows[:2], windows[2]

    def whole() -> None:  # the whole sortie from its first state
        L = (N - 1) - (N - 1) % stride
        pred, _ = solver_windows(solver, z[:1], controls[None, :L], time[:1], p,
                                  sample_dt)
        idx = stride * (1 + np.arange(L // stride))
        results["free_run"] = (pred[0, :, :nb], states[idx])
        results["free_run_time"] = time[idx]
        departure = first_departure(pred[0, :, :nb], solver.model.kind)
        if departure is not None:  # flagged, not raised: the table counts it
            results["free_run_departure"] = {
                "time_s": float(time[idx][departure.index]), "state": departure.state,
                "what": departure.describe()}

    for mode, run in (("one_step", one_step), ("horizon_1s", horizon), ("free_run", whole)):
        check_interrupted()  # a Ctrl-C CasADi swallowed (evaluate, reproduce: every sortie)
        try:
            run()
        except StepUseError as exc:  # outside the step's trained dt / time range: missing
            refused[mode] = str(exc)
    if refused:
        results["refused"] = refused
    return results


def _horizon_windows(solver: Solver, z: np.ndarray, time: np.ndarray, states: np.ndarray,
                     controls: np.ndarray, p, grid: EvalGrid, horizon_s: float
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Windows of ``horizon_s`` restarted from the recorded (augmented) state ``z`` at the
    start of every window: ``(predicted, target, time)`` at the solver's grid points inside
    the windows, or None when the sortie is shorter than one window or the horizon shorter
    than one solver step."""
    N, nb = len(time), states.shape[1]
    L = int(round(horizon_s / grid.sample_dt))
    L -= L % grid.stride
    if L <= 0:
        return None
    starts = np.arange(0, N - L, L)
    if not len(starts):
        return None
    pred, _ = solver_windows(solver, z[starts], np.stack([controls[k:k + L] for k in starts]),
                              time[starts], p, grid.sample_dt)
    idx = starts[:, None] + grid.stride * (1 + np.arange(L // grid.stride))[None, :]
    return pred[..., :nb].reshape(-1, nb), states[idx].reshape(-1, nb), time[idx].reshape(-1)


def horizon_predictions(solver: Solver, time: np.ndarray, states: np.ndarray,
                        controls: np.ndarray, p: np.ndarray, horizons_s
                        ) -> dict[float, tuple[np.ndarray, np.ndarray]]:
    """Prediction error against horizon: for every horizon H, windows of H restarted from
    the recorded state every H (as the ``horizon_1s`` mode of :func:`evaluate_trajectory`),
    ``{H: (predicted, target)}`` body states at the solver's grid points inside the windows.
    A horizon shorter than one solver step or longer than the sortie is absent.

    Raises
    ------
    StepUseError
        If the step refuses this step size or time range (then no horizon can be scored).
    """
    sample_dt = float(np.median(np.diff(time)))
    grid = EvalGrid(sample_dt, solver.dt)
    time = time - time[0]
    z = step_states(solver.model, states, controls, p, grid)
    out = {}
    for h in horizons_s:
        windows = _horizon_windows(solver, z, time, states, controls, p, grid, float(h))
        if windows is not None:
            out[float(h)] = windows[:2]
    return out


def fine_reference(kind: str | Airframe | ModelStructure, time: np.ndarray, x0: np.ndarray,
                   controls: np.ndarray, p: np.ndarray, substeps: int = 20) -> np.ndarray:
    """The baseline model's fine-step reference trajectory (RK4 at ``sample_dt/substeps`` on
    the logged zero-order-held controls), ``N x 4`` at the log times.

    ``kind`` is a kind name (its generic model), or an airframe (or structure): its own
    physics step (:func:`uavdyn.integrate.physics_step`); with actuator lags or delays, one
    call per log sample with ``substeps`` RK steps inside, started with the actuators at rest
    on the first command, and the body states returned. A reference that leaves the physical
    ranges (an open-loop replay of a closed-loop flight of an unstable airframe) is returned
    as it is: the comparisons against it say so (their divergence flags); only a non-finite
    one raises :class:`uavdyn.integrate.DivergenceError`."""
    sample_dt = float(np.median(np.diff(time)))
    fine = sample_dt / substeps
    if isinstance(kind, str):
        model, z0, dt, n = body_model(rk4_step(build_model(kind).f), kind), x0, fine, substeps
    else:
        structure = kind if isinstance(kind, ModelStructure) else structure_of(kind)
        if structure.augmented:  # one call per log sample, the RK sub-steps inside
            model = physics_step(structure, substeps=substeps)
            z0 = model.initial_state(np.asarray(x0, float).ravel(),
                                     np.asarray(controls, float)[:1], p, sample_dt)
            dt, n = sample_dt, 1
        else:
            model, z0, dt, n = physics_step(structure), x0, fine, substeps
    traj = free_run(model, z0, controls[:-1], p, dt, n, check=False)
    check_finite(traj, time[0] + sample_dt * np.arange(len(traj)), "fine reference")
    return traj[:, :4]


def pitch_rmse(model: DiscreteModel, sorties, p, dt: float) -> float:
    """Free-run pitch RMSE (rad) over all samples of ``sorties`` (pooled); ``p`` as for
    :func:`sortie_free_run`."""
    errs = [sortie_free_run(model, s, p, dt)[:, 3] - s.states[:, 3] for s in sorties]
    return float(np.sqrt(np.mean(np.concatenate(errs) ** 2)))


def pooled_stats(pairs: list[tuple[np.ndarray, np.ndarray]]) -> dict[str, float]:
    """Error statistics pooled over several (predicted, target) pairs."""
    pred = np.concatenate([a.reshape(-1, a.shape[-1]) for a, _ in pairs])
    target = np.concatenate([b.reshape(-1, b.shape[-1]) for _, b in pairs])
    return error_stats(pred, target)


def error_growth(time: np.ndarray, predicted: np.ndarray, target: np.ndarray,
                 divergence_rad: float = DEPARTURE_RAD) -> dict[str, float | bool]:
    """Pitch-error growth of a free run: slope of a straight-line fit of |error| against time
    (rad/s) up to divergence, maximum error before divergence (after it the error says nothing:
    a diverged run is reported as diverged, with its time), and a divergence flag with its time
    (error above ``divergence_rad`` or a non-finite state)."""
    with np.errstate(over="ignore", invalid="ignore"):
        err = np.abs(predicted[:, 3] - target[:, 3])
    bad = ~np.isfinite(err) | (err > divergence_rad)
    k_div = int(np.argmax(bad)) if bad.any() else len(err)
    finite = np.isfinite(err) & (err <= DIVERGENCE_BOUND)
    upto = slice(0, max(k_div, 2))
    ok = finite[upto]
    t, e = (time - time[0])[upto][ok], err[upto][ok]
    slope = float(np.polyfit(t, e, 1)[0]) if len(t) > 1 else 0.0
    return {"slope_rad_per_s": slope,
            "max_error_rad": float(e.max()) if len(e) else float("nan"),
            "diverged": bool(bad.any()),
            "time_to_divergence_s": float(time[k_div] - time[0]) if bad.any() else None}
