"""Model-predictive pitch-attitude and altitude tracking with any step Function (the hybrid
step, or physics-only RK4 for comparison) as the prediction model.

Multiple shooting with CasADi ``nlpsol``: states ``[u, w, q, theta, h]`` over the horizon
(altitude from the trapezoidal integral of ``h_dot = u sin(theta) - w cos(theta)``), control
and control-rate bounds, warm start from the shifted previous solution. The NLP is built once
and called many times with the initial state, previous control and references as parameters.

A prediction step on the augmented state (actuator lags, transport delays:
:func:`uavdyn.integrate.physics_step`) adds its actuator and delay-buffer states after ``h``.
They are not measured: the controller knows its own past commands, so it carries them itself
(at rest on the previous command after a reset, then advanced by each applied command). Delays
count calls of the step, here one per MPC interval.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.emulation import Emulator, open_loop_references
from uavdyn.integrate import actuator_rest, advance_actuators, physics_step
from uavdyn.model import CONTROL_BOUNDS, ModelStructure, structure_of

DEFAULT_RATE_LIMITS = {"fixed_wing": (1.0, 1.0), "multirotor": (2.0, 4.0)}  # per second
# Softplus sharpness replacing ReLU in a hybrid prediction model: SQP stalls on ReLU kinks
# (measured: 5 % of closed-loop solves hit the iteration limit), softplus k=30 solves them all.
RELU_SMOOTHING = 30.0


@dataclass
class MPCConfig:
    """Horizon, step, weights and bounds; defaults suit the presets at their trim points."""

    horizon: int = 20
    dt: float = 0.05
    w_theta: float = 100.0
    w_h: float = 1.0
    w_speed: float = 1.0
    w_du: tuple[float, float] = (10.0, 10.0)
    w_u: tuple[float, float] = (0.1, 0.1)
    control_bounds: tuple[tuple[float, float], tuple[float, float]] | None = None
    rate_limits: tuple[float, float] | None = None  # control units per second
    solver: str = "sqp"  # "sqp" (sqpmethod + qrqp) or "ipopt"
    max_iter: int = 50
    solver_options: dict = field(default_factory=dict)


@dataclass
class MPCResult:
    """One solve: the control to apply and how the solver did."""

    u: np.ndarray
    success: bool
    solve_time_s: float
    iterations: int
    status: str
    predicted_states: np.ndarray  # [u, w, q, theta, h, actuator/buffer states...] x (N+1)
    predicted_controls: np.ndarray


class TrackingMPC:
    """Pitch-attitude + altitude (+ airspeed) tracking MPC for one airframe and step model."""

    def __init__(self, step: ca.Function, kind: str | Airframe, p: np.ndarray,
                 u_trim: np.ndarray, config: MPCConfig | None = None,
                 structure: ModelStructure | None = None):
        """``kind`` is an airframe kind or an :class:`Airframe`: given an airframe, its own
        ``[limits]`` (actuator travel and rates) replace the kind's defaults wherever the config
        leaves ``control_bounds``/``rate_limits`` unset, so the MPC never plans beyond them.

        A ``step`` on the augmented state needs its layout: ``structure``, or by default the
        airframe's (``structure_of(kind)``).

        Raises
        ------
        ValueError
            On a bad configuration, or an augmented step without a matching structure.
        """
        self.config = cfg = config or MPCConfig()
        if cfg.horizon < 1:
            raise ValueError(f"horizon must be >= 1, got {cfg.horizon}")
        if not cfg.dt > 0:
            raise ValueError(f"dt must be > 0, got {cfg.dt}")
        if cfg.solver not in ("sqp", "ipopt"):
            raise ValueError(f"solver must be 'sqp' or 'ipopt', got {cfg.solver!r}")
        airframe = kind if isinstance(kind, Airframe) else None
        self.kind: str = airframe.kind if airframe is not None else kind  # type: ignore[assignment]
        self.p = np.asarray(p, float)
        self.u_trim = np.asarray(u_trim, float)
        bounds = (airframe.control_bounds() if airframe is not None
                  else CONTROL_BOUNDS[self.kind])
        rates = DEFAULT_RATE_LIMITS[self.kind]
        own = airframe.rate_limits() if airframe is not None else None
        if own is not None:  # a rate the file leaves out keeps the kind's default
            rates = tuple(d if r is None else r for r, d in zip(own, rates))
        self.bounds = np.array(cfg.control_bounds or bounds, float)
        self.rates = np.array(cfg.rate_limits or rates, float)
        nz = step.size1_in(0)
        if nz != 4:
            if structure is None and airframe is not None:
                structure = structure_of(airframe)
            if structure is None or structure.nx() != nz:
                have = ("no structure" if structure is None
                        else f"a structure of {structure.nx()} states")
                raise ValueError(f"prediction step '{step.name()}' has {nz} states and {have}: "
                                 "give the Airframe (or structure=) of its augmented state")
        self.structure = structure if nz != 4 else None
        self.n_extra = nz - 4
        self._build(step)
        self._warm: tuple[np.ndarray, np.ndarray] | None = None
        self._actuators: np.ndarray | None = None  # carried actuator/buffer states

    def _build(self, step: ca.Function) -> None:
        cfg, N = self.config, self.config.horizon
        nx, nu = 5 + self.n_extra, 2
        X = ca.SX.sym("X", nx, N + 1)
        U = ca.SX.sym("U", nu, N)
        # parameters: x0 (5 + extra), u_prev (2), theta_ref (N), h_ref (N), speed_ref (1)
        x0, u_prev = ca.SX.sym("x0", nx), ca.SX.sym("u_prev", nu)
        theta_ref, h_ref, v_ref = ca.SX.sym("theta_ref", N), ca.SX.sym("h_ref", N), \
            ca.SX.sym("v_ref")
        weights = ca.SX.sym("weights", 3)  # w_theta, w_h, w_speed: set per solve
        p = ca.DM(self.p)
        dt = cfg.dt
        g, lbg, ubg = [X[:, 0] - x0], [0.0] * nx, [0.0] * nx
        J = 0
        for k in range(N):
            xk, uk, xn = X[:4, k], U[:, k], X[:4, k + 1]
            zk, zn = ca.vertcat(xk, X[5:, k]), ca.vertcat(xn, X[5:, k + 1])
            g.append(zn - step(zk, uk, p, dt))
            hdot = lambda s: s[0] * ca.sin(s[3]) - s[1] * ca.cos(s[3])  # noqa: E731
            g.append(X[4, k + 1] - X[4, k] - dt / 2 * (hdot(xk) + hdot(xn)))
            lbg += [0.0] * nx
            ubg += [0.0] * nx
            du = uk - (u_prev if k == 0 else U[:, k - 1])
            g.append(du)
            lbg += list(-self.rates * dt)
            ubg += list(self.rates * dt)
            speed = ca.sqrt(xn[0] ** 2 + xn[1] ** 2)
            J += weights[0] * (xn[3] - theta_ref[k]) ** 2
            J += weights[1] * (X[4, k + 1] - h_ref[k]) ** 2 + weights[2] * (speed - v_ref) ** 2
            J += cfg.w_du[0] * du[0] ** 2 + cfg.w_du[1] * du[1] ** 2
            J += sum(cfg.w_u[i] * (uk[i] - self.u_trim[i]) ** 2 for i in range(nu))
        w = ca.vertcat(ca.vec(X), ca.vec(U))
        par = ca.vertcat(x0, u_prev, theta_ref, h_ref, v_ref, weights)
        nlp = {"x": w, "f": J, "g": ca.vertcat(*g), "p": par}
        if cfg.solver == "ipopt":
            opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                    "ipopt.max_iter": cfg.max_iter, "ipopt.warm_start_init_point": "yes"}
            name = "ipopt"
        else:
            opts = {"qpsol": "qrqp", "print_time": False, "print_header": False,
                    "print_iteration": False, "print_status": False, "max_iter": cfg.max_iter,
                    "qpsol_options": {"print_iter": False, "print_header": False,
                                      "error_on_fail": False},
                    "error_on_fail": False, "tol_pr": 1e-8, "tol_du": 1e-6}
            name = "sqpmethod"
        opts.update(cfg.solver_options)
        self.solver = ca.nlpsol("tracking_mpc", name, nlp, opts)
        lbx = np.full(w.shape[0], -np.inf)
        ubx = np.full(w.shape[0], np.inf)
        off = nx * (N + 1)
        for k in range(N):
            for i in range(nu):
                lbx[off + k * nu + i], ubx[off + k * nu + i] = self.bounds[i]
        self.lbx, self.ubx = lbx, ubx
        self.lbg, self.ubg = np.array(lbg), np.array(ubg)
        self.nx, self.nu, self.N = nx, nu, N

    @property
    def last_actuators(self) -> np.ndarray | None:
        """The actuator/buffer states the last solve started from (None: none yet)."""
        return None if self._actuators is None else self._actuators.copy()

    def actuator_states(self, u_prev) -> np.ndarray:
        """The actuator/delay-buffer states at this solve, from the controller's own commands:
        at rest on ``u_prev`` after a reset, else the last solve's advanced by ``u_prev`` (the
        command applied over the interval since)."""
        if self.structure is None:
            raise ValueError("the prediction step carries no actuator or delay states")
        if self._actuators is None:
            return actuator_rest(self.structure, u_prev)
        return advance_actuators(self.structure, self._actuators, u_prev, self.p,
                                 self.config.dt)

    def solve(self, x0: np.ndarray, u_prev: np.ndarray, theta_ref, h_ref, speed_ref: float,
              weights: tuple[float, float, float] | None = None,
              actuators: np.ndarray | None = None) -> MPCResult:
        """Solve from state ``x0 = [u, w, q, theta, h]`` with references over the horizon
        (scalars are held constant); ``weights`` = (pitch, altitude, speed) overrides the
        config for this solve (e.g. altitude weight 0 for a pure pitch-attitude step).
        Returns the first control of the optimal sequence.

        An augmented prediction step starts from the actuator/buffer states the controller
        carries (:meth:`actuator_states`; call once per MPC interval with ``u_prev`` the command
        applied over the last one), or from ``actuators`` when given."""
        cfg = self.config
        weights = weights if weights is not None else (cfg.w_theta, cfg.w_h, cfg.w_speed)
        N = self.N
        x0 = np.asarray(x0, float)
        if x0.shape != (5,):
            raise ValueError(f"x0 must be [u, w, q, theta, h] (5 values), got shape {x0.shape}")
        if self.n_extra:
            extra = (self.actuator_states(u_prev) if actuators is None
                     else np.asarray(actuators, float).ravel())
            if extra.shape != (self.n_extra,):
                raise ValueError(f"actuators must be {self.n_extra} values "
                                 f"{self.structure.state_names()[4:]}, got {extra.shape}")
            self._actuators = extra
            x0 = np.concatenate([x0, extra])
        theta_ref = np.broadcast_to(np.asarray(theta_ref, float), (N,))
        h_ref = np.broadcast_to(np.asarray(h_ref, float), (N,))
        par = np.concatenate([x0, u_prev, theta_ref, h_ref, [speed_ref], weights])
        if self._warm is None:
            Xw = np.tile(x0[:, None], (1, N + 1))
            Uw = np.tile(np.asarray(u_prev, float)[:, None], (1, N))
        else:
            Xp, Up = self._warm
            Xw = np.hstack([Xp[:, 1:], Xp[:, -1:]])
            Xw[:, 0] = x0
            Uw = np.hstack([Up[:, 1:], Up[:, -1:]])
        w0 = np.concatenate([Xw.ravel(order="F"), Uw.ravel(order="F")])
        t0 = time.perf_counter()
        sol = self.solver(x0=w0, p=par, lbx=self.lbx, ubx=self.ubx, lbg=self.lbg, ubg=self.ubg)
        elapsed = time.perf_counter() - t0
        stats = self.solver.stats()
        w = np.array(sol["x"]).ravel()
        X = w[: self.nx * (N + 1)].reshape((self.nx, N + 1), order="F")
        U = w[self.nx * (N + 1):].reshape((self.nu, N), order="F")
        success = bool(stats.get("success", False))
        status = str(stats.get("return_status", ""))
        finite = bool(np.all(np.isfinite(X)) and np.all(np.isfinite(U)))
        if not finite:  # a diverged prediction is a failed solve, never a warm start
            success, status = False, f"non-finite prediction ({status})"
            self._warm = None
        else:
            self._warm = (X, U)
        return MPCResult(u=U[:, 0].copy(), success=success, solve_time_s=elapsed,
                         iterations=int(stats.get("iter_count", -1)), status=status,
                         predicted_states=X, predicted_controls=U)

    def reset(self) -> None:
        """Forget the warm start and the carried actuator states (e.g. before a new
        scenario)."""
        self._warm = None
        self._actuators = None


@dataclass
class ClosedLoopResult:
    """A closed-loop flight of the MPC on a plant: states, controls, references, solver stats."""

    time: np.ndarray
    states: np.ndarray  # N+1 x 5: u, w, q, theta, h
    controls: np.ndarray  # N x 2
    theta_ref: np.ndarray
    h_ref: np.ndarray
    solve_times_s: np.ndarray
    success: np.ndarray

    def rmse(self, which: str = "theta", t_from: float = 0.0) -> float:
        idx = 3 if which == "theta" else 4
        ref = self.theta_ref if which == "theta" else self.h_ref
        mask = self.time[1:] >= t_from
        return float(np.sqrt(np.mean((self.states[1:, idx][mask] - ref[mask]) ** 2)))


def fly_closed_loop(mpc: TrackingMPC, plant_step, x0: np.ndarray, u0: np.ndarray,
                    n_steps: int, theta_ref, h_ref, speed_ref: float,
                    weights: tuple[float, float, float] | None = None) -> ClosedLoopResult:
    """Fly ``n_steps`` MPC intervals. ``plant_step(x_plant, u) -> (x_plant_next, y)`` advances
    the plant (e.g. the emulator) by one MPC interval and returns its ``[u, w, q, theta, h]``;
    ``theta_ref(t)``, ``h_ref(t)`` give the references at time t (callables). The output of a
    failed (or non-finite) solve is never applied: the previous control is held."""
    dt, N = mpc.config.dt, mpc.config.horizon
    mpc.reset()
    xp, y = plant_step(x0, None)
    u = np.asarray(u0, float)
    ys, us, ths, hs, times, ok = [y], [], [], [], [], []
    for k in range(n_steps):
        t_pred = (k + 1 + np.arange(N)) * dt
        res = mpc.solve(y, u, theta_ref(t_pred), h_ref(t_pred), speed_ref, weights)
        if res.success:  # a failed solve is never applied: the last control is held instead
            u = res.u
        times.append(res.solve_time_s)
        ok.append(res.success)
        xp, y = plant_step(xp, u)
        ys.append(y)
        us.append(u)
        ths.append(float(theta_ref(np.array([(k + 1) * dt]))[0]))
        hs.append(float(h_ref(np.array([(k + 1) * dt]))[0]))
    return ClosedLoopResult(time=np.arange(n_steps + 1) * dt, states=np.array(ys),
                            controls=np.array(us), theta_ref=np.array(ths), h_ref=np.array(hs),
                            solve_times_s=np.array(times), success=np.array(ok))


def emulator_plant(emulator, dt: float):
    """Wrap an :class:`uavdyn.emulator.Emulator` as a ``plant_step`` for
    :func:`fly_closed_loop`: each MPC interval flies ``dt`` seconds of the calm emulator with
    the control held (actuator lag, unsteady aerodynamics and all), full state fed back."""

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


def step_plant(step: ca.Function, p, dt: float):
    """Wrap a step with position states (``physics_step(airframe, with_position=True)``:
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
        z_next = np.array(step(z, u, p, dt)).ravel()
        return z_next, observe(z_next)

    return plant


def physics_plant(airframe: Airframe, dt: float, p=None, substeps: int = 1):
    """:func:`step_plant` of the airframe's own physics (actuator lags, delays and all) with
    ``substeps`` RK steps per MPC interval; ``p`` defaults to ``airframe.p``."""
    step = physics_step(airframe, with_position=True, substeps=substeps)
    return step_plant(step, airframe.p if p is None else p, dt)


@dataclass(frozen=True)
class Scenario:
    """A closed-loop test: pitch step (altitude free) or climb (altitude ramp)."""

    name: str
    duration: float
    pitch_step_deg: float = 0.0
    climb_rate: float = 0.0
    start: float = 0.5

    def weights(self) -> tuple[float, float, float]:
        return (100.0, 0.0, 1.0) if self.pitch_step_deg else (1.0, 1.0, 1.0)

    def references(self, theta_trim: float, h0: float):
        def theta_ref(t):
            return theta_trim + np.where(t >= self.start, np.radians(self.pitch_step_deg), 0.0)

        def h_ref(t):
            return h0 + self.climb_rate * np.clip(t - self.start, 0.0, None)

        return theta_ref, h_ref

    @property
    def tracked(self) -> str:
        return "theta" if self.pitch_step_deg else "h"


SCENARIOS = (Scenario("pitch step +5 deg", 8.0, pitch_step_deg=5.0),
             Scenario("climb 2 m/s", 10.0, climb_rate=2.0))


def run_scenario(scenario: Scenario, prediction_step: ca.Function, airframe, point,
                 config: MPCConfig, altitude: float = 100.0) -> ClosedLoopResult:
    """Fly one scenario on the calm emulator with the given prediction model."""

    emulator = Emulator(airframe)
    x0 = emulator.initial_state(point.x, point.u, altitude)
    mpc = TrackingMPC(prediction_step, airframe, airframe.p, point.u, config)
    theta_ref, h_ref = scenario.references(point.x[3], altitude)
    n = int(round(scenario.duration / config.dt))
    return fly_closed_loop(mpc, emulator_plant(emulator, config.dt), x0, point.u, n, theta_ref,
                           h_ref, float(np.hypot(point.x[0], point.x[1])), scenario.weights())
