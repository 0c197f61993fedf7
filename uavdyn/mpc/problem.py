"""The tracking problem both MPC modes solve: prediction stage, least-squares residuals, soft
state constraints, control and rate bounds, and the states the controller carries itself.

One definition serves the full SQP (:class:`uavdyn.mpc.tracking.TrackingMPC`, ``nlpsol``) and
the real-time iteration (:class:`uavdyn.mpc.rti.RTIController`), so that both converge to the
same optimum.

MPC state ``[u, w, q, theta, h, extra...]``: the step's body state, the altitude (trapezoidal
integral of ``h_dot = u sin(theta) - w cos(theta)``), then the step's extra states (actuator
lags, delay buffers, the correction's command memory). The extra states are filters of the
controller's own commands: it carries them itself (at rest on the previous command after a
reset, then advanced by each applied command).

Well-defined predictions: the prediction evaluates the step at a *guarded* body state, a C1
airspeed floor on the forward body velocity of a fixed wing (identity above the floor plus its
width), so that no trial point of an SQP or a QP step can reach ``V = 0`` where the
aerodynamics divide by the airspeed. The learned correction is already bounded and gated to
exactly zero outside its training envelope (:mod:`uavdyn.learned.envelope`). State bounds are
soft: one non-negative slack per bounded quantity over the whole horizon, with an exact (L1)
and a quadratic penalty, so the QP is never infeasible because of a state bound.

Cost (identical in both modes): the sum over the horizon of
``w_theta (theta - theta_ref)^2 + w_h (h - h_ref)^2 + w_speed (speed - speed_ref)^2`` at the
predicted states ``x_1..x_N``, plus ``w_du (u_k - u_{k-1})^2 + w_u (u_k - u_trim)^2`` per control
and ``w_slack_l1 s + w_slack_l2 s^2`` per slack. Speed is the airspeed ``sqrt(u^2 + w^2)`` of a
fixed wing and the forward body velocity ``u`` of a multirotor (hover has no airspeed
direction).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from uavdyn.airframes import has_pitch_authority
from uavdyn.integrate import DiscreteModel
from uavdyn.model import CONTROL_BOUNDS

DEFAULT_RATE_LIMITS = {"fixed_wing": (1.0, 1.0), "multirotor": (2.0, 4.0)}  # per second
MODES = ("sqp", "rti")


@dataclass
class MPCConfig:
    """Horizon, step, weights, bounds and solver of a tracking MPC.

    Attributes
    ----------
    horizon : int
        Prediction intervals ``N``.
    dt : float
        MPC interval (s); one call of the prediction step per interval.
    w_theta, w_h, w_speed : float
        Default tracking weights (a scenario overrides them per solve).
    w_du, w_u : tuple of float
        Control-rate and control-deviation weights per control.
    control_bounds, rate_limits :
        Override the airframe's (or kind's) actuator travel and rates (per second).
    soft_bounds : dict, optional
        ``{state index: (low, high)}`` of the soft state bounds (default
        :func:`default_soft_bounds`).
    w_slack_l1, w_slack_l2 : float
        Exact and quadratic slack penalties.
    mode : str
        ``"sqp"`` (full Gauss-Newton SQP with line search,
        :class:`uavdyn.mpc.rti.SQPController`) or ``"rti"`` (one QP per step,
        :class:`uavdyn.mpc.rti.RTIController`); :func:`uavdyn.mpc.build_controller` reads it.
    solver : str
        NLP solver of the ``nlpsol`` reference controller :class:`uavdyn.mpc.TrackingMPC`:
        ``"sqp"`` (sqpmethod + qrqp, exact Hessian) or ``"ipopt"``.
    qp_solver : str
        CasADi ``conic`` plugin of the condensed QP (chosen by measurement: ``docs/mpc.md``).
    compile : bool
        Compile the QP and merit Functions to C (cached on disk).
    max_iter : int
        Iteration limit of the ``nlpsol`` reference controller.
    sqp_tol : float
        Full SQP: converged when the plan changes by less than this (max abs).
    sqp_max_iter : int
        Full (Gauss-Newton) SQP iteration limit: a cold start before a large step in the
        references needs up to ~100 iterations at horizon 50 (measured), warm starts a few;
        at the limit the last plan is applied only if it lowered the merit.
    solver_options : dict
        Extra options for ``nlpsol`` (full SQP) or ``conic`` (RTI).
    """

    horizon: int = 20
    dt: float = 0.05
    w_theta: float = 100.0
    w_h: float = 1.0
    w_speed: float = 1.0
    w_du: tuple[float, float] = (10.0, 10.0)
    w_u: tuple[float, float] = (0.1, 0.1)
    control_bounds: tuple[tuple[float, float], tuple[float, float]] | None = None
    rate_limits: tuple[float, float] | None = None
    soft_bounds: dict[int, tuple[float, float]] | None = None
    w_slack_l1: float = 1e3
    w_slack_l2: float = 1e3
    mode: str = "sqp"
    solver: str = "sqp"
    qp_solver: str = "daqp"
    compile: bool = True
    max_iter: int = 50
    sqp_tol: float = 1e-4
    sqp_max_iter: int = 200
    solver_options: dict = field(default_factory=dict)


def default_soft_bounds(kind: str, speed_trim: float) -> dict[int, tuple[float, float]]:
    """Soft bounds on MPC-state indices: pitch within +-30 deg for both kinds; a fixed wing's
    forward body velocity within 0.6..1.6 x its trim airspeed, a multirotor's within +-10 m/s."""
    pitch = (-math.radians(30.0), math.radians(30.0))
    if kind == "fixed_wing":
        return {0: (0.6 * speed_trim, 1.6 * speed_trim), 3: pitch}
    return {0: (-10.0, 10.0), 3: pitch}


def soft_floor(v, low: float, width: float):
    """C1 floor: ``v`` above ``low + width``, ``low`` below ``low - width``, a quadratic blend
    between (CasADi or NumPy)."""
    d = v - low
    if isinstance(v, (ca.SX, ca.MX, ca.DM)):
        blend = (d + width) ** 2 / (4 * width)
        return low + ca.if_else(d >= width, d, ca.if_else(d <= -width, 0 * d, blend))
    d = np.asarray(d, float)
    return low + np.where(d >= width, d, np.where(d <= -width, 0.0, (d + width) ** 2
                                                   / (4 * width)))


class TrackingProblem:
    """The tracking problem of one airframe and prediction step (see the module docstring).

    Parameters
    ----------
    model : DiscreteModel
        The prediction model (:func:`uavdyn.physics_step`, :func:`uavdyn.hybrid_step` with
        ``compile=False``): its Function is inlined into the MPC's own Functions; its
        airframe's ``[limits]`` (actuator travel and rates) replace the kind's defaults
        wherever the config leaves ``control_bounds``/``rate_limits`` unset.
    u_trim : array
        Trim command (the ``w_u`` term's target).
    config : MPCConfig
    p : array, optional
        Parameter vector of the step (default: the model's airframe's).
    speed_trim : float, optional
        Trim airspeed (m/s) for the default soft bounds and airspeed floor (default: the
        airframe's nominal airspeed, else 25).

    Raises
    ------
    ValueError
        On a bad configuration, a compiled step, or a model without an airframe and ``p``.
    """

    def __init__(self, model: DiscreteModel, u_trim, config: MPCConfig, p=None,
                 speed_trim: float | None = None):
        cfg = self.config = config
        if cfg.horizon < 1:
            raise ValueError(f"horizon must be >= 1, got {cfg.horizon}")
        if not (cfg.dt > 0 and math.isfinite(cfg.dt)):
            raise ValueError(f"dt must be > 0, got {cfg.dt}")
        if cfg.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {cfg.mode!r}")
        if cfg.solver not in ("sqp", "ipopt"):
            raise ValueError(f"solver must be 'sqp' or 'ipopt', got {cfg.solver!r}")
        step = model.function
        if not step.is_a("SXFunction"):
            raise ValueError(f"prediction step '{step.name()}' must be an uncompiled SX Function "
                             "(e.g. hybrid_step(..., compile=False)): the MPC inlines and "
                             "compiles it itself")
        if model.layout.with_position:
            raise ValueError(f"prediction model '{model.name}' carries position states: the "
                             "MPC adds its own altitude state; build it without position")
        model.check_use(cfg.dt)
        airframe = model.airframe
        if airframe is not None and not has_pitch_authority(airframe):
            raise ValueError(f"airframe '{airframe.name}' has no pitch authority (pitch_mix or "
                             "C_m_delta_e is 0): the MPC cannot control its pitch")
        self.model = model
        self.kind: str = model.kind
        self.p = np.asarray(model.p if p is None else p, float)
        self.u_trim = np.asarray(u_trim, float)
        bounds = airframe.control_bounds() if airframe is not None else CONTROL_BOUNDS[self.kind]
        rates = DEFAULT_RATE_LIMITS[self.kind]
        own = airframe.rate_limits() if airframe is not None else None
        if own is not None:  # a rate the file leaves out keeps the kind's default
            rates = tuple(d if r is None else r for r, d in zip(own, rates))
        self.bounds = np.array(cfg.control_bounds or bounds, float)
        self.rates = np.array(cfg.rate_limits or rates, float)
        nz = model.nx
        self.step = step
        self.n_extra = nz - 4
        self.nx, self.nu, self.N = 5 + self.n_extra, 2, cfg.horizon
        if speed_trim is None:
            speed_trim = airframe.nominal_airspeed if airframe is not None else 25.0
        v = float(speed_trim)
        self.speed_trim = v
        soft = cfg.soft_bounds if cfg.soft_bounds is not None else default_soft_bounds(
            self.kind, v)
        self.soft_index = tuple(sorted(soft))
        self.soft_low = np.array([soft[i][0] for i in self.soft_index], float)
        self.soft_high = np.array([soft[i][1] for i in self.soft_index], float)
        self.ns = len(self.soft_index)
        # airspeed floor of the prediction (fixed wing): far below the soft bound
        self.floor = (max(0.25 * v, 2.0), max(0.05 * v, 0.5)) if self.kind == "fixed_wing" \
            else None
        self._build_symbolic()

    # ---- symbolic pieces -------------------------------------------------------------------
    def _build_symbolic(self) -> None:
        nx, nu, dt = self.nx, self.nu, self.config.dt
        x, u = ca.SX.sym("x", nx), ca.SX.sym("u", nu)
        body = [x[i] for i in range(4)]
        if self.floor is not None:
            body[0] = soft_floor(body[0], *self.floor)
        z = ca.vertcat(*body, x[5:])
        z_next = self.step(z, u, ca.DM(self.p), dt)
        xn = ca.vertcat(x[:4] + (z_next[:4] - z[:4]), z_next[4:])  # raw state + guarded increment

        def hdot(s):
            return s[0] * ca.sin(s[3]) - s[1] * ca.cos(s[3])

        h_next = x[4] + dt / 2 * (hdot(x) + hdot(xn))
        x_next = ca.vertcat(xn[:4], h_next, xn[4:])
        self.stage = ca.Function("mpc_stage", [x, u], [x_next], ["x", "u"], ["x_next"])
        # tracked outputs of a predicted state and their references/weights
        ref, w = ca.SX.sym("ref", 3), ca.SX.sym("w", 3)
        speed = ca.sqrt(x[0] ** 2 + x[1] ** 2) if self.kind == "fixed_wing" else x[0]
        y = ca.vertcat(x[3], x[4], speed)
        r = ca.sqrt(w) * (y - ref)
        c = ca.vertcat(*[x[i] for i in self.soft_index])
        self.output = ca.Function("mpc_output", [x, ref, w], [r, c], ["x", "ref", "w"],
                                  ["r", "c"])
        self.output_jac = ca.Function("mpc_output_jac", [x, ref, w],
                                      [r, ca.jacobian(r, x), c, ca.jacobian(c, x)],
                                      ["x", "ref", "w"], ["r", "Jr", "c", "Jc"])
        # reverse mode: the network's output is 3 wide, its input the whole state and command
        # (measured: 28 % fewer instructions than the default forward-mode Jacobian)
        rev = ca.Function("mpc_stage_rev", [x, u], [x_next], ["x", "u"], ["x_next"],
                          {"ad_weight": 1.0, "ad_weight_sp": 1.0})
        jac = rev.factory("mpc_stage_jac_ad", ["x", "u"],
                          ["x_next", "jac:x_next:x", "jac:x_next:u"])
        self.stage_jac = ca.Function("mpc_stage_jac", [x, u], jac(x, u), ["x", "u"],
                                     ["x_next", "A", "B"])

    def control_residual_matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``r_u = D vec(U) + E u_prev + e`` of the control terms (constant matrices)."""
        N, nu, cfg = self.N, self.nu, self.config
        sdu, su = np.sqrt(np.asarray(cfg.w_du, float)), np.sqrt(np.asarray(cfg.w_u, float))
        D = np.zeros((2 * nu * N, nu * N))
        E = np.zeros((2 * nu * N, nu))
        e = np.zeros(2 * nu * N)
        for k in range(N):
            for i in range(nu):
                r_du, r_u = 2 * nu * k + i, 2 * nu * k + nu + i
                D[r_du, nu * k + i] = sdu[i]
                if k == 0:
                    E[r_du, i] = -sdu[i]
                else:
                    D[r_du, nu * (k - 1) + i] = -sdu[i]
                D[r_u, nu * k + i] = su[i]
                e[r_u] = -su[i] * self.u_trim[i]
        return D, E, e

    def rate_matrix(self) -> tuple[np.ndarray, np.ndarray]:
        """``R vec(U) + F u_prev`` = the control increments over the horizon."""
        N, nu = self.N, self.nu
        R = np.zeros((nu * N, nu * N))
        F = np.zeros((nu * N, nu))
        for k in range(N):
            for i in range(nu):
                R[nu * k + i, nu * k + i] = 1.0
                if k == 0:
                    F[i, i] = -1.0
                else:
                    R[nu * k + i, nu * (k - 1) + i] = -1.0
        return R, F

    def rate_bounds(self) -> np.ndarray:
        """Largest control increment per interval, tiled over the horizon."""
        return np.tile(self.rates * self.config.dt, self.N)

    def rollout(self, x0, U) -> np.ndarray:
        """Predicted MPC states ``nx x (N+1)`` from ``x0`` under the plan ``U`` (``nu x N``)."""
        X = [np.asarray(x0, float)]
        for k in range(np.shape(U)[1]):
            X.append(np.array(self.stage(X[-1], U[:, k])).ravel())
        return np.array(X).T

    def cost(self, X, U, u_prev, refs, weights, slack=None) -> float:
        """The tracking cost of a plan (both modes minimise this)."""
        D, E, e = self.control_residual_matrices()
        ru = D @ np.asarray(U, float).ravel(order="F") + E @ np.asarray(u_prev, float) + e
        J = float(ru @ ru)
        for k in range(self.N):
            r = np.array(self.output(X[:, k + 1], refs[:, k], weights)[0]).ravel()
            J += float(r @ r)
        if slack is not None:
            s = np.asarray(slack, float)
            J += float(self.config.w_slack_l1 * s.sum() + self.config.w_slack_l2 * (s @ s))
        return J

    def merit_function(self, name: str = "mpc_merit") -> ca.Function:
        """``(x0, U, u_prev, refs, w) -> J``: the cost of the plan ``U`` rolled out through the
        nonlinear prediction from ``x0``, each soft bound's slack at the least value that
        satisfies it over the horizon (the exact-penalty merit of the SQP line search)."""
        N, nx, nu = self.N, self.nx, self.nu
        x0, U = ca.MX.sym("x0", nx), ca.MX.sym("U", nu, N)
        u_prev, refs, w = ca.MX.sym("u_prev", nu), ca.MX.sym("refs", 3, N), ca.MX.sym("w", 3)
        X = self.stage.mapaccum("mpc_merit_roll", N)(x0, U)
        r, c = self.output.map(N)(X, refs, ca.repmat(w, 1, N))
        D, E, e = self.control_residual_matrices()
        ru = ca.mtimes(ca.DM(D), ca.vec(U)) + ca.mtimes(ca.DM(E), u_prev) + ca.DM(e)
        J = ca.sumsqr(r) + ca.sumsqr(ru)
        for i in range(self.ns):
            viol = ca.vertcat(0, (self.soft_low[i] - c[i, :]).T, (c[i, :] - self.soft_high[i]).T)
            si = ca.mmax(viol)
            J += self.config.w_slack_l1 * si + self.config.w_slack_l2 * si ** 2
        return ca.Function(name, [x0, U, u_prev, refs, w], [J],
                           ["x0", "U", "u_prev", "refs", "w"], ["J"])

