"""Validation metrics: one-step, 1 s-horizon and free-run errors of any step Function (physics
RK4 or hybrid) against a target trajectory (the emulated/recorded flight data, or the fine-step
reference of the baseline model), on the logged zero-order-held control grid.

A solver step ``dt`` smaller than the log interval runs ``sample_dt/dt`` sub-steps per logged
control; a larger ``dt`` (e.g. 0.02 s on 100 Hz data) samples the logged control at its own
step start and is compared at its own grid points only. Every table says which.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from uavdyn.integrate import (
    EvalGrid,
    GridError,
    StepUseError,
    check_use,
    free_run,
    rk4_step,
    rollout,
    takes_time,
)
from uavdyn.model import build_model

METRIC_STATES = {"theta": 3, "q": 2, "u": 0}
MODES = ("one_step", "horizon_1s", "free_run")


@dataclass(frozen=True)
class Solver:
    """A named step Function at a step size (a time-dependent step takes its named ``t``)."""

    name: str
    step: ca.Function
    dt: float

    @property
    def time_input(self) -> bool:
        return takes_time(self.step)


def error_stats(predicted: np.ndarray, target: np.ndarray) -> dict[str, float]:
    """RMSE, MAE and maximum absolute error of pitch, pitch rate and forward speed."""
    out = {}
    for name, i in METRIC_STATES.items():
        with np.errstate(over="ignore", invalid="ignore"):
            err = predicted[..., i] - target[..., i]
            err = np.where(np.abs(err) < 1e100, err, np.inf)  # a diverged run is infinite
        if not np.all(np.isfinite(err)):
            out.update({f"{name}_rmse": float("inf"), f"{name}_mae": float("inf"),
                        f"{name}_max": float("inf")})
            continue
        out[f"{name}_rmse"] = float(np.sqrt(np.mean(err**2)))
        out[f"{name}_mae"] = float(np.mean(np.abs(err)))
        out[f"{name}_max"] = float(np.max(np.abs(err)))
    return out


_window_cache: dict = {}


def _window_function(step: ca.Function, n_samples: int, substeps: int, n_windows: int
                     ) -> ca.Function:
    """``n_windows`` independent rollouts (``map`` over the one ``mapaccum`` rollout)."""
    key = (id(step), step.name(), n_samples, substeps, n_windows)
    if key not in _window_cache:
        _window_cache[key] = (step, rollout(step, n_samples, substeps).map(n_windows))
    return _window_cache[key][1]


def predict_windows(solver: Solver, x0s: np.ndarray, controls: np.ndarray, t0s: np.ndarray,
                    p: np.ndarray, sample_dt: float) -> tuple[np.ndarray, int]:
    """Roll ``solver`` from each start state ``x0s[k]`` through ``controls[k]`` (``K x L x nu``,
    one row per log interval); ``t0s`` are the start times since the sortie start. Returns the
    predicted states at the solver's grid points (``K x L/stride x nx``) and the stride."""
    g = EvalGrid(sample_dt, solver.dt)
    K, L, nu = controls.shape
    if L % g.stride:
        raise ValueError(f"window of {L} log intervals is not a multiple of the stride "
                         f"{g.stride}")
    U = controls[:, ::g.stride, :]
    n = U.shape[1]
    t0s = np.asarray(t0s, float).reshape(K)
    check_use(solver.step, solver.dt, float(t0s.min()), float(t0s.max()) + L * sample_dt)
    F = _window_function(solver.step, n, g.substeps, K)
    args = [np.asarray(x0s, float).T, U.reshape(K * n, nu).T, np.asarray(p, float),
            float(solver.dt)]
    if solver.time_input:
        args.append(t0s.reshape(1, K))
    out = np.asarray(F(*args))  # nx x (K*n)
    return out.T.reshape(K, n, -1), g.stride


def evaluate_trajectory(solver: Solver, time: np.ndarray, states: np.ndarray,
                        controls: np.ndarray, p: np.ndarray, horizon_s: float = 1.0
                        ) -> dict[str, np.ndarray]:
    """Predictions of one solver on one target trajectory (states ``N x 4`` at the log times,
    ``controls`` row k held over [t_k, t_k+1)). Returns, per mode, ``(predicted, target)``
    arrays of matching shape, plus the free-run time axis. A mode the step refuses (outside
    its trained step size or time range) is absent and its reason is under ``"refused"``."""
    sample_dt = float(np.median(np.diff(time)))
    N = len(time)
    stride = EvalGrid(sample_dt, solver.dt).stride
    time = time - time[0]  # a time input is always time since the start of the sortie
    results: dict = {}
    refused: dict[str, str] = {}

    def one_step() -> None:  # one solver step from every recorded state on the solver's grid
        starts = np.arange(0, N - stride, stride)
        pred, _ = predict_windows(solver, states[starts],
                                  np.stack([controls[k:k + stride] for k in starts]),
                                  time[starts], p, sample_dt)
        results["one_step"] = (pred[:, 0, :], states[starts + stride])

    def horizon() -> None:  # windows restarted from the recorded state every horizon
        L = int(round(horizon_s / sample_dt))
        L -= L % stride
        starts = np.arange(0, N - L, L)
        if not len(starts):
            return
        pred, _ = predict_windows(solver, states[starts],
                                  np.stack([controls[k:k + L] for k in starts]), time[starts], p,
                                  sample_dt)
        idx = starts[:, None] + stride * (1 + np.arange(L // stride))[None, :]
        results["horizon_1s"] = (pred.reshape(-1, pred.shape[-1]),
                                 states[idx].reshape(-1, states.shape[1]))
        results["horizon_1s_time"] = time[idx].reshape(-1)

    def whole() -> None:  # the whole sortie from its first state
        L = (N - 1) - (N - 1) % stride
        pred, _ = predict_windows(solver, states[:1], controls[None, :L], time[:1], p,
                                  sample_dt)
        idx = stride * (1 + np.arange(L // stride))
        results["free_run"] = (pred[0], states[idx])
        results["free_run_time"] = time[idx]

    for mode, run in (("one_step", one_step), ("horizon_1s", horizon), ("free_run", whole)):
        try:
            run()
        except StepUseError as exc:  # outside the step's trained dt / time range: missing
            refused[mode] = str(exc)
    if refused:
        results["refused"] = refused
    return results


def fine_reference(kind: str, time: np.ndarray, x0: np.ndarray, controls: np.ndarray,
                   p: np.ndarray, substeps: int = 20) -> np.ndarray:
    """The baseline model's fine-step reference trajectory (RK4 at ``sample_dt/substeps`` on
    the logged zero-order-held controls), ``N x 4`` at the log times."""
    sample_dt = float(np.median(np.diff(time)))
    step = rk4_step(build_model(kind).f)
    return free_run(step, x0, controls[:-1], p, sample_dt / substeps, substeps)


def sortie_free_run(step: ca.Function, sortie, p, dt: float) -> np.ndarray:
    """Free run of ``step`` through a logged sortie from its first state with its controls
    (``dt`` must divide the sample interval): states at the sample times, ``N x nx``. A
    time-dependent step sees the time since the sortie start."""
    sample_dt = float(np.median(np.diff(sortie.time)))
    g = EvalGrid(sample_dt, dt)
    if g.stride != 1:
        raise GridError(f"dt {dt:g} s must divide the sample interval {sample_dt:g} s of "
                        f"sortie '{sortie.name}'")
    return free_run(step, sortie.states[0], sortie.controls[:-1], p, dt, g.substeps, t0=0.0,
                    compile=not step.is_a("External"))


def pitch_rmse(step: ca.Function, sorties, p, dt: float) -> float:
    """Free-run pitch RMSE (rad) over all samples of ``sorties`` (pooled)."""
    errs = [sortie_free_run(step, s, p, dt)[:, 3] - s.states[:, 3] for s in sorties]
    return float(np.sqrt(np.mean(np.concatenate(errs) ** 2)))


def pooled_stats(pairs: list[tuple[np.ndarray, np.ndarray]]) -> dict[str, float]:
    """Error statistics pooled over several (predicted, target) pairs."""
    pred = np.concatenate([a.reshape(-1, a.shape[-1]) for a, _ in pairs])
    target = np.concatenate([b.reshape(-1, b.shape[-1]) for _, b in pairs])
    return error_stats(pred, target)


def error_growth(time: np.ndarray, predicted: np.ndarray, target: np.ndarray,
                 divergence_rad: float = 0.5) -> dict[str, float | bool]:
    """Pitch-error growth of a free run: slope of a straight-line fit of |error| against time
    (rad/s) up to divergence, maximum error over the finite part, and a divergence flag with its
    time (error above ``divergence_rad`` or a non-finite state)."""
    with np.errstate(over="ignore", invalid="ignore"):
        err = np.abs(predicted[:, 3] - target[:, 3])
    bad = ~np.isfinite(err) | (err > divergence_rad)
    k_div = int(np.argmax(bad)) if bad.any() else len(err)
    finite = np.isfinite(err) & (err < 1e100)
    upto = slice(0, max(k_div, 2))
    ok = finite[upto]
    t, e = (time - time[0])[upto][ok], err[upto][ok]
    slope = float(np.polyfit(t, e, 1)[0]) if len(t) > 1 else 0.0
    return {"slope_rad_per_s": slope,
            "max_error_rad": float(err[finite].max()) if finite.any() else float("nan"),
            "diverged": bool(bad.any()),
            "time_to_divergence_s": float(time[k_div] - time[0]) if bad.any() else None}
