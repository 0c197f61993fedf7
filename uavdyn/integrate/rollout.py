"""Rollouts of any discrete model or step Function: one ``mapaccum`` loop over a per-sample
Function that holds its sub-steps, the :class:`EvalGrid` that relates a solver step to a log
interval, and numeric free runs that report divergence instead of returning it silently.

A step has inputs ``(x, u, p, dt)`` and, when it depends on time, a fifth input named ``t``
(time since the start of the sortie). A :class:`uavdyn.integrate.DiscreteModel` also knows the
step size and time range it is valid for: every rollout here enforces them.
"""

from __future__ import annotations

import ctypes
import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.integrate.c_loop import NativeRollout, write_loop_source
from uavdyn.integrate.codegen import compile_function
from uavdyn.integrate.discrete import DiscreteModel, StepUseError, model_function
from uavdyn.model import first_departure, sortie_params


class GridError(ValueError):
    """A solver step does not fit the sample interval of the data."""


# A state beyond this magnitude (or not finite) has diverged (SPEC section 9): every rollout
# of the library (free runs, Monte-Carlo runs) reports it with its time.
DIVERGENCE_BOUND = 1e6
# Pitch error (rad) past which a free run has left the data: its error says nothing any more
# (the evaluation's divergence flag, the trainer's free-run guard, the report's departures).
DEPARTURE_RAD = 0.5


class DivergenceError(RuntimeError):
    """A rollout left the finite (or physical) range; ``time`` says when."""

    def __init__(self, message: str, time: float):
        super().__init__(message)
        self.time = time


def check_use(step: DiscreteModel | ca.Function, dt: float, t_start: float = 0.0,
              t_end: float = 0.0) -> None:
    """:meth:`DiscreteModel.check_use` of a model; a bare Function passes unchecked."""
    if isinstance(step, DiscreteModel):
        step.check_use(dt, t_start, t_end)


def takes_time(step: DiscreteModel | ca.Function) -> bool:
    """Whether ``step`` has a time input (named ``t``)."""
    return "t" in model_function(step).name_in()


def substeps_for(sample_dt: float, max_dt: float, at_least: int = 1) -> int:
    """Solver steps per log interval so that each is at most ``max_dt``: the log's own rate is
    kept (no resampling) and the step stays small enough for a stiff model at a slow log
    (a 10 Hz log with one 0.1 s RK4 step per sample would go unstable on a well-damped
    short period)."""
    return max(int(at_least), int(math.ceil(sample_dt / max_dt - 1e-9)))


def fitting_steps(sample_dt: float, wanted: tuple[float, ...]) -> tuple[float, ...]:
    """Each of the ``wanted`` solver steps, or where it neither divides the log interval nor is
    a whole multiple of it, the nearest step that does (a whole fraction of the interval at
    or below it, or the multiple nearest it); duplicates removed, order kept."""
    out: list[float] = []
    for dt in wanted:
        try:
            EvalGrid(sample_dt, dt)
        except GridError:
            dt = (sample_dt / substeps_for(sample_dt, dt) if dt < sample_dt
                  else sample_dt * max(1, round(dt / sample_dt)))
        if not any(abs(dt - d) <= 1e-12 * d for d in out):
            out.append(dt)
    return tuple(out)


@dataclass(frozen=True)
class EvalGrid:
    """How a solver step ``dt`` sits on data logged every ``sample_dt``.

    ``substeps`` solver steps per log interval when ``dt`` divides it (controls held over the
    interval), or one solver step every ``stride`` log intervals when ``dt`` is a multiple of
    it (the solver samples the logged control at its own step start). Exactly one of the two
    is greater than 1 unless ``dt == sample_dt``.

    Raises
    ------
    GridError
        If ``dt`` neither divides ``sample_dt`` nor is a whole multiple of it.
    """

    sample_dt: float
    dt: float

    def __post_init__(self) -> None:
        for key in ("sample_dt", "dt"):
            value = getattr(self, key)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise GridError(f"{key} must be a positive finite number of seconds, got {value}")
        _ = (self.substeps, self.stride)  # raises GridError if dt does not fit

    @property
    def substeps(self) -> int:
        if self.dt > self.sample_dt * (1 + 1e-9):
            return 1
        n = round(self.sample_dt / self.dt)
        if n < 1 or abs(n * self.dt - self.sample_dt) > 1e-9 * self.sample_dt:
            raise GridError(f"solver step {self.dt:g} s must divide the log interval "
                            f"{self.sample_dt:g} s or be a whole multiple of it")
        return int(n)

    @property
    def stride(self) -> int:
        if self.dt <= self.sample_dt * (1 + 1e-9):
            return 1
        n = round(self.dt / self.sample_dt)
        if abs(n * self.sample_dt - self.dt) > 1e-9 * self.dt:
            raise GridError(f"solver step {self.dt:g} s must divide the log interval "
                            f"{self.sample_dt:g} s or be a whole multiple of it")
        return int(n)

    @property
    def interval(self) -> float:
        """Time between two compared grid points (s)."""
        return self.stride * self.sample_dt


def rollout(step: DiscreteModel | ca.Function, n_samples: int, substeps: int = 1,
            name: str = "rollout") -> ca.Function:
    """``n_samples`` sample intervals of ``substeps`` steps each, as one MX Function
    ``(x0, u[nu x N], p, dt[, t0]) -> x[nx x N]`` (states at the end of each interval).

    Control column ``k`` is held over interval ``k``; ``dt`` is the step size (the interval is
    ``substeps * dt``); a time-dependent step gets ``t0 + elapsed time``. Built with
    ``mapaccum``, so it is a loop in the generated C, never ``N`` unrolled copies.

    Raises
    ------
    ValueError
        If ``n_samples`` or ``substeps`` is smaller than 1.
    """
    if n_samples < 1 or substeps < 1:
        raise ValueError(f"n_samples and substeps must be >= 1, got {n_samples}, {substeps}")
    step = model_function(step)
    timed = takes_time(step)
    nx, nu, n_p = (step.size1_in(i) for i in range(3))
    # one sub-step on z = [x; t]
    x, u, p, dt, t = (ca.MX.sym("x", nx), ca.MX.sym("u", nu), ca.MX.sym("p", n_p),
                      ca.MX.sym("dt"), ca.MX.sym("t"))
    x_next = step(x, u, p, dt, t) if timed else step(x, u, p, dt)
    z = ca.vertcat(x, t) if timed else x
    z_next = ca.vertcat(x_next, t + dt) if timed else x_next
    sub = ca.Function("substep", [z, u, p, dt], [z_next])
    if substeps > 1:
        inner = sub.mapaccum("substeps", substeps)
        z_end = inner(z, ca.repmat(u, 1, substeps), ca.repmat(p, 1, substeps),
                      ca.repmat(dt, 1, substeps))[:, -1]
    else:
        z_end = sub(z, u, p, dt)
    # Parameters and step size ride in the accumulator so they are not copied N times.
    acc_in = ca.vertcat(z, p, dt)
    body = ca.Function("sample", [acc_in, u], [ca.vertcat(z_end, p, dt)])
    acc = body.mapaccum("samples", n_samples)
    X0, U, P, DT, T0 = (ca.MX.sym("x0", nx), ca.MX.sym("u", nu, n_samples), ca.MX.sym("p", n_p),
                        ca.MX.sym("dt"), ca.MX.sym("t0"))
    Z = acc(ca.vertcat(X0, *([T0] if timed else []), P, DT), U)
    inputs, names = [X0, U, P, DT], ["x0", "u", "p", "dt"]
    if timed:
        inputs, names = [*inputs, T0], [*names, "t0"]
    return ca.Function(name, inputs, [Z[:nx, :]], names, ["x"])


def compiled_rollout(step: DiscreteModel | ca.Function, n_samples: int, substeps: int = 1,
                     name: str = "rollout", warn: bool = True) -> NativeRollout | ca.Function:
    """:func:`rollout` compiled as a plain C loop around the step's generated code
    (:mod:`uavdyn.integrate.c_loop`: no per-sample copies of the state, parameters and step
    size, so a sample costs what the step costs), cached like every compiled Function, and
    called on NumPy buffers (:class:`~uavdyn.integrate.c_loop.NativeRollout`: it returns NumPy
    arrays).
    Without a compiler it is the ``mapaccum`` rollout in the CasADi VM; a step that is itself
    compiled (an ``External``) is looped in the VM around its compiled code."""
    function = model_function(step)
    sim = rollout(function, n_samples, substeps, name)
    if function.is_a("External"):
        return sim
    return compile_function(
        sim, warn=warn, opener=lambda n, path: NativeRollout(ctypes.CDLL(path), n, sim),
        source=lambda folder, n: write_loop_source(function, n_samples, substeps, n, folder))


_WINDOW_FUNCTIONS: dict = {}


def window_rollouts(step: DiscreteModel | ca.Function, n_samples: int, substeps: int = 1,
                    n_windows: int = 1, threads: int = 1) -> ca.Function:
    """``n_windows`` independent rollouts of ``n_samples`` intervals (``map`` of the one
    ``mapaccum`` :func:`rollout`, over ``threads`` threads): inputs ``(x0[nx x W],
    u[nu x W*N], p[np x W or 1], dt[, t0[1 x W]])``, output ``x[nx x W*N]``. Built once per
    step and shape in a process."""
    function = model_function(step)
    key = (id(function), function.name(), n_samples, substeps, n_windows, threads)
    if key not in _WINDOW_FUNCTIONS:
        sim = rollout(function, n_samples, substeps)
        mapped = sim.map(n_windows, "thread", threads) if threads > 1 else sim.map(n_windows)
        _WINDOW_FUNCTIONS[key] = (function, mapped)  # the step is kept: its id stays its own
    return _WINDOW_FUNCTIONS[key][1]


def predict_windows(step: DiscreteModel | ca.Function, z0s, controls, p, dt: float,
                    substeps: int = 1, t0s=None, threads: int = 1) -> np.ndarray:
    """Windowed prediction: the step restarted from each start state and rolled through its
    window's commands.

    Parameters
    ----------
    step : DiscreteModel or casadi.Function
        The step (a model is refused outside its step size and time range).
    z0s : array_like, shape (W, nx)
        The step's state at each window start.
    controls : array_like, shape (W, L, nu)
        Commands, row k held over interval k of the window.
    p : array_like, shape (np,) or (W, np)
        Parameters, shared or per window.
    dt : float
        Step size (s); each interval is ``substeps`` steps.
    t0s : array_like, shape (W,), optional
        Start times since the sortie start (a time-dependent step needs them).
    threads : int
        CasADi ``thread`` map over the windows.

    Returns
    -------
    ndarray, shape (W, L, nx)
        The states at the end of each interval (not finite where a window diverged).
    """
    controls = np.asarray(controls, float)
    W, L, nu = controls.shape
    t0s = np.zeros(W) if t0s is None else np.asarray(t0s, float).reshape(W)
    check_use(step, dt, float(t0s.min()), float(t0s.max()) + L * substeps * dt)
    F = window_rollouts(step, L, substeps, W, threads)
    p = np.asarray(p, float)
    args = [np.asarray(z0s, float).T, controls.reshape(W * L, nu).T,
            p.T if p.ndim == 2 else p, float(dt)]
    if takes_time(step):
        args.append(t0s.reshape(1, W))
    with np.errstate(all="ignore"):
        out = np.asarray(F(*args))
    return out.T.reshape(W, L, -1)


def check_finite(traj: np.ndarray, time: np.ndarray, what: str = "rollout",
                 bound: float = DIVERGENCE_BOUND) -> None:
    """Raise :class:`DivergenceError` at the first non-finite (or ``|x| > bound``) sample."""
    bad = ~np.all(np.isfinite(traj) & (np.abs(traj) <= bound), axis=1)
    if bad.any():
        k = int(np.argmax(bad))
        raise DivergenceError(f"{what} diverged at t = {time[k]:.3f} s (sample {k}): state "
                              f"non-finite or beyond {bound:g}", float(time[k]))


def check_departure(traj: np.ndarray, time: np.ndarray, kind: str, what: str = "rollout"
                    ) -> None:
    """Raise :class:`DivergenceError` at the first sample whose body states (the first four
    columns) leave the physical ranges of ``kind`` (:func:`uavdyn.model.first_departure`, the
    ranges the dataset loader enforces), naming the time and the state."""
    departure = first_departure(traj[:, :4], kind)
    if departure is not None:
        k = departure.index
        raise DivergenceError(f"{what} departed at t = {time[k]:.3f} s (sample {k}): "
                              f"{departure.describe()}", float(time[k]))


def free_run(step: DiscreteModel | ca.Function, x0, controls, p, dt: float, substeps: int = 1,
             t0: float = 0.0, compile: bool = True, check: bool = True) -> np.ndarray:
    """Open-loop replay of ``controls`` (``N x nu``, row k held over one interval of
    ``substeps * dt``): the ``(N+1) x nx`` states at the interval ends, ``x0`` first.

    Parameters
    ----------
    step : DiscreteModel or casadi.Function
        A step ``(x, u, p, dt[, t])``; a model is refused outside its step size and time range.
    x0, controls, p : array_like
        Initial state, controls per interval, parameters.
    dt : float
        Step size (s).
    substeps : int
        Steps per control interval.
    t0 : float
        Time of ``x0`` since the start of the sortie (for a time-dependent step).
    compile : bool
        Compile the rollout to C (cached) first; a step that is itself compiled (an
        ``External``) is looped in the CasADi VM around its compiled code.
    check : bool
        Raise :class:`DivergenceError` on a non-finite or exploding state, and for a
        :class:`DiscreteModel` on body states leaving the physical ranges of its kind
        (:func:`check_departure`).
    """
    controls = np.atleast_2d(np.asarray(controls, dtype=float))
    x0 = np.asarray(x0, float).ravel()
    check_use(step, dt, t0, t0 + controls.shape[0] * substeps * dt)
    sim = (compiled_rollout(step, controls.shape[0], substeps) if compile
           else rollout(step, controls.shape[0], substeps))
    args = [x0, controls.T, np.asarray(p, float), float(dt)]
    if takes_time(step):
        args.append(float(t0))
    with np.errstate(all="ignore"):
        traj = np.vstack([x0.reshape(1, -1), np.array(sim(*args)).T])
    if check:
        time = t0 + substeps * dt * np.arange(len(traj))
        check_finite(traj, time, "free run")
        if isinstance(step, DiscreteModel):
            check_departure(traj, time, step.kind, "free run")
    return traj


def check_delay_grid(model: DiscreteModel, grid: EvalGrid) -> None:
    """Refuse a step with transport delays at a step size other than the log interval (its
    delays count calls of the step).

    Raises
    ------
    StepUseError
        Naming the step, the log interval and the step size.
    """
    if model.structure.n_buffer and (grid.substeps != 1 or grid.stride != 1):
        raise StepUseError(
            f"step '{model.name}' carries transport delays counted in calls of the step: use "
            f"it at the log interval {grid.sample_dt:g} s, not {grid.dt:g} s (finer RK inside: "
            "physics_step(..., substeps=k))")


def step_states(model: DiscreteModel, states: np.ndarray, controls: np.ndarray, p,
                grid: EvalGrid) -> np.ndarray:
    """The states ``model`` runs on at every recorded sample (:meth:`DiscreteModel.
    initial_state`: the recorded body states with the actuator, buffer and memory states the
    recorded commands imply, at rest on the first command).

    Raises
    ------
    StepUseError
        If the model has transport delays and ``grid.dt`` is not the log interval.
    """
    check_delay_grid(model, grid)
    return model.initial_state(np.atleast_2d(np.asarray(states, float)), controls, p,
                               grid.sample_dt)


def sortie_p(sortie, p) -> np.ndarray:
    """The parameter vector for ``sortie``: ``p`` itself, or for an airframe its parameters at
    the sortie's altitude (:func:`uavdyn.model.sortie_params`, manifest ``altitude_m``)."""
    if isinstance(p, Airframe):
        return np.asarray(sortie_params(p, sortie.altitude_m), float)
    return np.asarray(p, float)


def sortie_free_run(model: DiscreteModel, sortie, p, dt: float, body0=None,
                    check: bool = True) -> np.ndarray:
    """The free run of a logged sortie: ``model`` replays the sortie's commands open loop
    from its first state (``dt`` must divide the sample interval; the extra states start at
    rest on the first command). A time-dependent step sees the time since the sortie start.

    Parameters
    ----------
    model : DiscreteModel
        The step.
    sortie : Sortie
        The logged flight (``time``, ``states``, ``controls``, ``altitude_m``).
    p : array_like or Airframe
        Parameters, or an airframe (:func:`sortie_p`).
    dt : float
        Step size (s).
    body0 : array_like, optional
        The body state to start from (default the first record, e.g. a fitted start:
        :func:`uavdyn.integrate.start_fit.estimate_start`).
    check : bool
        Raise :class:`DivergenceError` on a non-finite, exploding or departed state (else
        return it).

    Returns
    -------
    ndarray, shape (N, 4)
        Body states at the sample times, the start first.

    Raises
    ------
    GridError
        If ``dt`` does not divide the sample interval.
    StepUseError
        If the step has transport delays and ``dt`` is not the sample interval.
    DivergenceError
        If the run leaves the finite range (with ``check``).
    """
    sample_dt = float(np.median(np.diff(sortie.time)))
    g = EvalGrid(sample_dt, dt)
    if g.stride != 1:
        raise GridError(f"dt {dt:g} s must divide the sample interval {sample_dt:g} s of "
                        f"sortie '{sortie.name}'")
    p = sortie_p(sortie, p)
    start = sortie.states[:1] if body0 is None else np.asarray(body0, float).reshape(1, -1)
    z0 = step_states(model, start, sortie.controls[:1], p, g)[0]
    traj = free_run(model, z0, sortie.controls[:-1], p, dt, g.substeps, t0=0.0,
                    compile=not model.function.is_a("External"), check=check)
    return traj[:, :sortie.states.shape[1]]


def simulate(step: DiscreteModel | ca.Function, x0, controls, p, dt: float,
             check: bool = True) -> np.ndarray:
    """Numeric rollout: the ``(N+1) x nx`` trajectory including ``x0``; ``controls`` is
    ``N x nu`` (row k held over step k). Raises :class:`DivergenceError` if it diverges."""
    return free_run(step, x0, controls, p, dt, compile=False, check=check)
