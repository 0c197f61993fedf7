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

from uavdyn.integrators import rk4_step
from uavdyn.model import build_model

METRIC_STATES = {"theta": 3, "q": 2, "u": 0}
MODES = ("one_step", "horizon_1s", "free_run")


@dataclass(frozen=True)
class Solver:
    """A named step Function at a step size (``time_input`` for the paper formulation)."""

    name: str
    step: ca.Function
    dt: float

    @property
    def time_input(self) -> bool:
        return self.step.n_in() == 5


def grid(sample_dt: float, dt: float) -> tuple[int, int]:
    """(sub-steps per log interval, log intervals per solver step) for a solver step ``dt``."""
    if dt <= sample_dt * (1 + 1e-9):
        sub = int(round(sample_dt / dt))
        if sub < 1 or abs(sub * dt - sample_dt) > 1e-9 * sample_dt:
            raise ValueError(f"solver step {dt:g} s must divide the log interval {sample_dt:g} s")
        return sub, 1
    stride = int(round(dt / sample_dt))
    if abs(stride * sample_dt - dt) > 1e-9 * dt:
        raise ValueError(f"solver step {dt:g} s must be a multiple of the log interval "
                         f"{sample_dt:g} s")
    return 1, stride


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


def _window_function(step: ca.Function, n_steps: int, n_windows: int) -> ca.Function:
    """``n_windows`` independent rollouts of ``n_steps`` (``map`` over a ``mapaccum``)."""
    key = (id(step), step.name(), n_steps, n_windows)
    if key not in _window_cache:
        from uavdyn.hybrid import hybrid_rollout

        _window_cache[key] = (step, hybrid_rollout(step, n_steps).map(n_windows))
    return _window_cache[key][1]


def predict_windows(solver: Solver, x0s: np.ndarray, controls: np.ndarray, t0s: np.ndarray,
                    p: np.ndarray, sample_dt: float) -> tuple[np.ndarray, int]:
    """Roll ``solver`` from each start state ``x0s[k]`` through ``controls[k]`` (``K x L x nu``,
    one row per log interval). Returns the predicted states at the solver's grid points
    (``K x L/stride x nx``) and the stride in log intervals."""
    sub, stride = grid(sample_dt, solver.dt)
    K, L, nu = controls.shape
    if L % stride:
        raise ValueError(f"window of {L} log intervals is not a multiple of the stride {stride}")
    U = controls[:, ::stride, :]
    if sub > 1:
        U = np.repeat(U, sub, axis=1)
    n = U.shape[1]
    F = _window_function(solver.step, n, K)
    args = [np.asarray(x0s, float).T, U.reshape(K * n, nu).T, np.asarray(p, float),
            solver.dt]
    if solver.time_input:
        args.append(np.asarray(t0s, float).reshape(1, K))
    out = np.asarray(F(*args))  # nx x (K*n)
    out = out.T.reshape(K, n, -1)[:, sub - 1::sub, :]
    return out, stride


def evaluate_trajectory(solver: Solver, time: np.ndarray, states: np.ndarray,
                        controls: np.ndarray, p: np.ndarray, horizon_s: float = 1.0
                        ) -> dict[str, np.ndarray]:
    """Predictions of one solver on one target trajectory (states ``N x 4`` at the log times,
    ``controls`` row k held over [t_k, t_k+1)). Returns, per mode, ``(predicted, target)``
    arrays of matching shape, plus the free-run time axis."""
    sample_dt = float(np.median(np.diff(time)))
    N = len(time)
    _, stride = grid(sample_dt, solver.dt)
    results: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    # one step (one solver step, from every recorded state on the solver's grid)
    starts = np.arange(0, N - stride, stride)
    pred, _ = predict_windows(solver, states[starts], controls[starts][:, None, :].repeat(
        stride, axis=1) if stride == 1 else np.stack([controls[k:k + stride] for k in starts]),
        time[starts], p, sample_dt)
    results["one_step"] = (pred[:, 0, :], states[starts + stride])
    # 1 s horizon: windows restarted from the recorded state every horizon
    L = int(round(horizon_s / sample_dt))
    L -= L % stride
    starts = np.arange(0, N - L, L)
    if len(starts):
        pred, _ = predict_windows(solver, states[starts],
                                  np.stack([controls[k:k + L] for k in starts]), time[starts], p,
                                  sample_dt)
        idx = starts[:, None] + stride * (1 + np.arange(L // stride))[None, :]
        results["horizon_1s"] = (pred.reshape(-1, pred.shape[-1]),
                                 states[idx].reshape(-1, states.shape[1]))
        results["horizon_1s_time"] = time[idx].reshape(-1)
    # free run: the whole sortie from its first state
    L = (N - 1) - (N - 1) % stride
    pred, _ = predict_windows(solver, states[:1], controls[None, :L], time[:1], p, sample_dt)
    idx = stride * (1 + np.arange(L // stride))
    results["free_run"] = (pred[0], states[idx])
    results["free_run_time"] = time[idx]
    return results


def fine_reference(kind: str, time: np.ndarray, x0: np.ndarray, controls: np.ndarray,
                   p: np.ndarray, substeps: int = 20) -> np.ndarray:
    """The baseline model's fine-step reference trajectory (RK4 at ``sample_dt/substeps`` on
    the logged zero-order-held controls), ``N x 4`` at the log times."""
    from uavdyn.hybrid import free_run

    sample_dt = float(np.median(np.diff(time)))
    step = rk4_step(build_model(kind).f)
    return free_run(step, x0, controls[:-1], p, sample_dt / substeps, substeps)


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
