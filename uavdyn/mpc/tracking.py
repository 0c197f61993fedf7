"""Model-predictive pitch-attitude, altitude and speed tracking with any step Function (the
hybrid step, or the physics RK4 step for comparison) as the prediction model: the ``nlpsol``
controller, the closed loop, plants and scenarios.

:class:`TrackingMPC` solves the :class:`uavdyn.mpc.problem.TrackingProblem` with CasADi
``nlpsol`` (sqpmethod + qrqp with the exact Hessian, or IPOPT) by multiple shooting,
warm-started from the shifted previous plan: the independent reference. The controllers the
command and the benchmark fly (:func:`build_controller`, by ``config.mode``) work on the compiled
condensed QP of :mod:`uavdyn.mpc.rti`: one QP per step (``"rti"``) or Gauss-Newton SQP to
convergence (``"sqp"``). All follow the status policy of :mod:`uavdyn.mpc.policy`: a failed
solve is never applied.

A prediction step on an augmented state (actuator lags, delay buffers, command memory) adds
those states after ``h``; the controller carries them itself from its own commands. Delays
count calls of the step, here one per MPC interval.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.emulation import open_loop_references
from uavdyn.integrate import DiscreteModel, physics_step
from uavdyn.interrupts import check_interrupted, interruptible
from uavdyn.model import first_departure
from uavdyn.mpc.policy import HELD, SHIFTED, SOLVED, Controller, MPCResult, SolveOutcome
from uavdyn.mpc.problem import DEFAULT_RATE_LIMITS, MPCConfig, TrackingProblem

# Softplus sharpness replacing ReLU in a hybrid prediction model of the full SQP: SQP stalls on
# ReLU kinks (measured: 5 % of closed-loop solves hit the iteration limit), softplus k=30 solved
# them all then. The 3 x 5 F450 correction still needs more than the 200 iterations in a few
# solves of bench_mpc's horizon-50 speed step (Gauss-Newton, which leaves out the network's
# curvature, converges linearly there: about 245 iterations, measured); those apply their last
# plan, which lowered the merit (uavdyn.mpc.rti.SQPController). The real-time iteration
# predicts with the exact ReLU network (one QP per step has no line search to stall).
RELU_SMOOTHING = 30.0

__all__ = ["DEFAULT_RATE_LIMITS", "RELU_SMOOTHING", "ClosedLoopResult", "MPCConfig", "MPCResult",
           "TrackingMPC", "build_controller", "emulator_plant", "fly_closed_loop",
           "physics_plant", "step_plant"]


class TrackingMPC(Controller):
    """Full-SQP tracking MPC (pitch attitude, altitude, speed) for one airframe and step model.

    Parameters
    ----------
    model : DiscreteModel
        Prediction model with an uncompiled SX Function (:func:`uavdyn.physics_step`,
        :func:`uavdyn.hybrid_step` with ``compile=False``); its airframe's ``[limits]``
        (actuator travel and rates) replace the kind's defaults wherever the config leaves
        ``control_bounds``/``rate_limits`` unset, so the MPC never plans beyond them.
    u_trim : array
        Trim command.
    config : MPCConfig, optional
    p : array, optional
        Parameters of the step (default: the model's airframe's).
    speed_trim : float, optional
        Trim airspeed (default soft bounds, airspeed floor).

    Raises
    ------
    ValueError
        On a bad configuration or a compiled step.
    """

    def __init__(self, model: DiscreteModel, u_trim, config: MPCConfig | None = None,
                 p=None, speed_trim: float | None = None):
        problem = TrackingProblem(model, u_trim, config or MPCConfig(), p, speed_trim)
        self._build(problem)
        super().__init__(problem)

    def _build(self, problem: TrackingProblem) -> None:
        cfg, N, nx, nu, ns = problem.config, problem.N, problem.nx, problem.nu, problem.ns
        X, U, s = ca.SX.sym("X", nx, N + 1), ca.SX.sym("U", nu, N), ca.SX.sym("s", ns)
        x0, u_prev = ca.SX.sym("x0", nx), ca.SX.sym("u_prev", nu)
        refs, w = ca.SX.sym("refs", 3, N), ca.SX.sym("w", 3)
        D, E, e = problem.control_residual_matrices()
        R, F = problem.rate_matrix()
        ru = ca.mtimes(ca.DM(D), ca.vec(U)) + ca.mtimes(ca.DM(E), u_prev) + ca.DM(e)
        J = ca.sumsqr(ru) + cfg.w_slack_l1 * ca.sum1(s) + cfg.w_slack_l2 * ca.sumsqr(s)
        g, lbg, ubg = [X[:, 0] - x0], [np.zeros(nx)], [np.zeros(nx)]
        for k in range(N):
            g.append(X[:, k + 1] - problem.stage(X[:, k], U[:, k]))
            lbg.append(np.zeros(nx))
            ubg.append(np.zeros(nx))
        rb = problem.rate_bounds()
        g.append(ca.mtimes(ca.DM(R), ca.vec(U)) + ca.mtimes(ca.DM(F), u_prev))
        lbg.append(-rb)
        ubg.append(rb)
        for k in range(N):
            r, c = problem.output(X[:, k + 1], refs[:, k], w)
            J += ca.sumsqr(r)
            g += [c + s, c - s]
            lbg += [problem.soft_low, np.full(ns, -np.inf)]
            ubg += [np.full(ns, np.inf), problem.soft_high]
        wvar = ca.vertcat(ca.vec(X), ca.vec(U), s)
        par = ca.vertcat(x0, u_prev, ca.vec(refs), w)
        nlp = {"x": wvar, "f": J, "g": ca.vertcat(*g), "p": par}
        if cfg.solver == "ipopt":
            opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                    "ipopt.max_iter": cfg.max_iter, "ipopt.warm_start_init_point": "yes"}
            name = "ipopt"
        else:
            opts = {"qpsol": "qrqp", "print_time": False, "print_header": False,
                    "print_iteration": False, "print_status": False, "max_iter": cfg.max_iter,
                    "qpsol_options": {"print_iter": False, "print_header": False,
                                      "print_info": False, "error_on_fail": False},
                    "error_on_fail": False, "tol_pr": 1e-8, "tol_du": 1e-6}
            name = "sqpmethod"
        opts.update(cfg.solver_options)
        self.solver = ca.nlpsol("tracking_mpc", name, nlp, opts)
        n_x = nx * (N + 1)
        self.lbx = np.concatenate([np.full(n_x, -np.inf),
                                   np.tile(problem.bounds[:, 0], N), np.zeros(ns)])
        self.ubx = np.concatenate([np.full(n_x, np.inf),
                                   np.tile(problem.bounds[:, 1], N), np.full(ns, np.inf)])
        self.lbg, self.ubg = np.concatenate(lbg), np.concatenate(ubg)

    def _warm_states(self, x0: np.ndarray) -> np.ndarray:
        N = self.N
        if self._plan_X is None or self._age + 1 >= N:
            Xw = np.tile(x0[:, None], (1, N + 1))
        else:
            s = self._age + 1
            Xw = np.hstack([self._plan_X[:, s:], np.repeat(self._plan_X[:, -1:], s, axis=1)])
        Xw[:, 0] = x0
        return Xw

    def _solve(self, x0, u_prev, refs, weights) -> SolveOutcome:
        N, nx, nu = self.N, self.nx, self.nu
        Uw, Xw = self.warm_plan(u_prev), self._warm_states(x0)
        w0 = np.concatenate([Xw.ravel(order="F"), Uw.ravel(order="F"),
                             np.zeros(self.problem.ns)])
        par = np.concatenate([x0, u_prev, refs.ravel(order="F"), weights])
        with interruptible():  # Ipopt would end the solve on Ctrl-C and the loop fly on
            sol = self.solver(x0=w0, p=par, lbx=self.lbx, ubx=self.ubx, lbg=self.lbg,
                              ubg=self.ubg)
        stats = self.solver.stats()
        w = np.asarray(sol["x"]).ravel()
        X = w[:nx * (N + 1)].reshape((nx, N + 1), order="F")
        U = w[nx * (N + 1):nx * (N + 1) + nu * N].reshape((nu, N), order="F")
        return SolveOutcome(U, X, bool(stats.get("success", False)),
                            str(stats.get("return_status", "")),
                            int(stats.get("iter_count", -1)), w[nx * (N + 1) + nu * N:])


def build_controller(model: DiscreteModel, u_trim, config: MPCConfig, p=None,
                     speed_trim: float | None = None) -> Controller:
    """The controller of ``config.mode``: :class:`uavdyn.mpc.rti.SQPController` (``"sqp"``,
    full Gauss-Newton SQP) or :class:`uavdyn.mpc.rti.RTIController` (``"rti"``), both on the
    compiled condensed QP; arguments as for :class:`TrackingMPC` (the ``nlpsol`` reference)."""
    from uavdyn.mpc.rti import RTIController, SQPController

    problem = TrackingProblem(model, u_trim, config, p, speed_trim)
    return RTIController(problem) if config.mode == "rti" else SQPController(problem)


@dataclass
class ClosedLoopResult:
    """A closed-loop flight of an MPC on a plant.

    Attributes
    ----------
    time : ndarray
        ``n + 1`` times (s).
    states : ndarray
        ``(n + 1) x 5`` measured ``[u, w, q, theta, h]``.
    controls : ndarray
        ``n x 2`` applied controls (row k held over interval k).
    theta_ref, h_ref, speed_ref : ndarray
        References at times ``1..n``.
    speed : ndarray
        The tracked speed at times ``0..n`` (airspeed of a fixed wing, ``u`` of a multirotor).
    solve_times_s : ndarray
        Wall time of each MPC step.
    success : ndarray of bool
        Whether each solve succeeded.
    source : ndarray of str
        Where each applied control came from (``solved``, ``shifted``, ``held``).
    departure : str or None
        When the plant left the physical ranges (:func:`uavdyn.model.first_departure`): the
        time and the state. The flight stops at that sample.
    status : ndarray of str or None
        Each solve's status (the solver's, or the policy's for a non-finite plan).
    """

    time: np.ndarray
    states: np.ndarray
    controls: np.ndarray
    theta_ref: np.ndarray
    h_ref: np.ndarray
    speed_ref: np.ndarray
    speed: np.ndarray
    solve_times_s: np.ndarray
    success: np.ndarray
    source: np.ndarray
    departure: str | None = None
    status: np.ndarray | None = None

    def rmse(self, which: str = "theta", t_from: float = 0.0) -> float:
        """Tracking RMSE of ``"theta"`` (rad), ``"h"`` (m) or ``"speed"`` (m/s) over times
        ``>= t_from``."""
        got = {"theta": self.states[1:, 3], "h": self.states[1:, 4], "speed": self.speed[1:]}
        ref = {"theta": self.theta_ref, "h": self.h_ref, "speed": self.speed_ref}
        if which not in got:
            raise ValueError(f"which must be 'theta', 'h' or 'speed', got {which!r}")
        mask = self.time[1:] >= t_from
        return float(np.sqrt(np.mean((got[which][mask] - ref[which][mask]) ** 2)))

    def counts(self) -> dict[str, int]:
        """Applied controls by source: ``{"solved": .., "shifted": .., "held": ..}``."""
        return {s: int(np.sum(self.source == s)) for s in (SOLVED, SHIFTED, HELD)}


def _speed(kind: str, y: np.ndarray) -> float:
    return float(np.hypot(y[0], y[1])) if kind == "fixed_wing" else float(y[0])


def fly_closed_loop(mpc: Controller, plant_step: Callable, x0, u0, n_steps: int,
                    theta_ref: Callable, h_ref: Callable, speed_ref,
                    weights: tuple[float, float, float] | None = None) -> ClosedLoopResult:
    """Fly ``n_steps`` MPC intervals.

    Parameters
    ----------
    mpc : Controller
        A :class:`TrackingMPC` or :class:`uavdyn.mpc.rti.RTIController` (reset first).
    plant_step : callable
        ``plant_step(x_plant, u) -> (x_plant_next, y)`` advances the plant (e.g. the
        emulator) by one MPC interval and returns its ``[u, w, q, theta, h]``; ``u=None``
        only observes.
    x0, u0 :
        Plant start state and the command applied before the first solve.
    theta_ref, h_ref : callable
        References at times ``t`` (arrays).
    speed_ref : float or callable
        Speed reference (constant or of time).
    weights : tuple, optional
        (pitch, altitude, speed) tracking weights.

    Returns
    -------
    ClosedLoopResult
        What was flown; the control of a failed solve is never applied (the policy's
        fallback is, and each step's source is recorded). A plant leaving the physical
        ranges ends the flight there, with ``departure`` saying when and how.
    """
    dt, N = mpc.config.dt, mpc.config.horizon
    v_ref = speed_ref if callable(speed_ref) else (lambda t: np.full_like(t, float(speed_ref)))
    mpc.reset()
    xp, y = plant_step(x0, None)
    u = np.asarray(u0, float)
    ys, us, times, ok, src, status = [y], [], [], [], [], []
    departure = None
    for k in range(n_steps):
        check_interrupted()  # a Ctrl-C CasADi swallowed in the last step
        t_pred = (k + 1 + np.arange(N)) * dt
        res = mpc.solve(y, u, theta_ref(t_pred), h_ref(t_pred), v_ref(t_pred), weights)
        u = res.u
        times.append(res.solve_time_s)
        ok.append(res.success)
        src.append(res.source)
        status.append(res.status)
        xp, y = plant_step(xp, u)
        ys.append(y)
        us.append(u)
        left = first_departure(np.asarray(y)[None, :4], mpc.kind)
        if left is not None:  # the plant has left any flight: stop, flagged
            departure = f"departed at t = {(k + 1) * dt:.3f} s: {left.describe()}"
            break
    t = np.arange(len(ys)) * dt
    states = np.array(ys)
    return ClosedLoopResult(time=t, states=states, controls=np.array(us),
                            theta_ref=np.asarray(theta_ref(t[1:]), float),
                            h_ref=np.asarray(h_ref(t[1:]), float),
                            speed_ref=np.asarray(v_ref(t[1:]), float),
                            speed=np.array([_speed(mpc.kind, s) for s in states]),
                            solve_times_s=np.array(times), success=np.array(ok, bool),
                            source=np.array(src), departure=departure,
                            status=np.array(status))


def emulator_plant(emulator, dt: float):
    """Wrap an :class:`uavdyn.emulation.Emulator` as a ``plant_step`` for
    :func:`fly_closed_loop`: each MPC interval flies ``dt`` seconds of the calm emulator with
    the control held (actuator lag, unsteady aerodynamics and all), full state fed back.

    Raises
    ------
    ValueError
        If ``dt`` is not a multiple of the emulator's log interval.
    """
    n = round(dt * emulator.sample_rate_hz)
    if n < 1 or abs(n / emulator.sample_rate_hz - dt) > 1e-9:
        raise ValueError(f"MPC dt {dt} s must be a multiple of the emulator log interval "
                         f"{emulator.dt_log} s")

    def observe(xe):
        return np.array([xe[0], xe[1], xe[2], xe[3], xe[5]])

    def step(xe, u):
        if u is None:
            return xe, observe(xe)
        flight = emulator.fly(xe, open_loop_references(np.tile(u, (n + 1, 1))))
        xe_next = flight.aux["emulator_states"][n]
        return xe_next, observe(xe_next)

    return step


def step_plant(step: DiscreteModel, p, dt: float):
    """Wrap a model with position states (``physics_step(airframe, with_position=True)``:
    ``[u, w, q, theta, x_n, h, actuator/buffer states...]``) as a ``plant_step`` for
    :func:`fly_closed_loop`: one call per MPC interval, ``[u, w, q, theta, h]`` fed back. Its
    initial state is the whole step state, e.g. ``trim_state(airframe, point, True)``."""
    p = np.asarray(p, float)

    def observe(z):
        return np.array([z[0], z[1], z[2], z[3], z[5]])

    def plant(z, u):
        z = np.asarray(z, float).ravel()
        if u is None:
            return z, observe(z)
        z_next = np.array(step.function(z, u, p, dt)).ravel()
        return z_next, observe(z_next)

    return plant


def physics_plant(airframe: Airframe, dt: float, p=None, substeps: int = 1):
    """:func:`step_plant` of the airframe's own physics (actuator lags, delays and all) with
    ``substeps`` RK steps per MPC interval; ``p`` defaults to ``airframe.p``."""
    step = physics_step(airframe, with_position=True, substeps=substeps)
    return step_plant(step, airframe.p if p is None else p, dt)
