"""Flight-data emulator: a "truth" model deliberately richer than the baseline model, flown by a
simple autopilot and logged like a real flight log (noise-free true states kept beside measured).

The baseline model (:mod:`uavdyn.model`) is reused, not copied: the emulator evaluates the
baseline force functions at the *air-relative* state and with the *actual* actuator positions,
and adds what the baseline lacks. Exactly what differs from the baseline:

Both kinds
    * Turbulence: Dryden gusts ``[u_g, w_g, q_g]`` (MIL-F-8785C forms with Beard & McLain's
      low-altitude scales, intensity multiplier settable, 0 = calm) plus an optional mean head
      wind. They enter through the air-relative velocity ``u - u_g, w - w_g, q - q_g`` at which
      the forces are evaluated; the kinematics use the inertial velocities.
    * Actuator dynamics: each commanded input passes a smooth position limit, then a
      first-order lag whose rate is smoothly limited (``rate * tanh(error / (tau * rate))``).
    * Sensor noise: Gaussian white noise on every logged state and a constant gyro bias per
      sortie; the logged controls are the commands (exact, zero-order hold per log interval).
    * Logging at ``sample_rate_hz`` (100 Hz default); integration by RK4 at ``internal_dt``
      (1 ms default) inside one compiled ``mapaccum`` rollout.

Fixed wing (extra states: elevator, throttle, alpha filter, separation)
    * Elevator servo lag 0.04 s, rate limit 3 rad/s; throttle (engine/propeller spool) lag
      0.25 s, rate limit 2 /s.
    * Unsteady aerodynamics: ``C_L_alphadot`` and ``C_m_alphadot`` terms, with alpha-dot taken
      from a first-order filtered derivative of the air-relative alpha (filter state). They add
      to the airframe's own optional ``C_L_alpha_dot``/``C_m_alpha_dot`` (0 in the presets),
      which the emulator applies with the same filtered air-relative alpha-dot (gusts included)
      instead of the baseline's gust-blind closed form.
    * Dynamic stall: the baseline's static stall blend ``sigma(alpha)`` becomes a lagged flow-
      separation state (Goman-Khrabrov form) ``tau1 sigma_dot = sigma_static(alpha - tau2
      alpha_dot) - sigma`` (stall hysteresis), and a nose-down pitch break ``C_m_stall sigma``.
      In steady attached flow all extra terms vanish, so baseline trim points are also trim
      points of the calm emulator.

Multirotor (extra states: front and rear rotor speeds, in throttle units)
    * Mixer saturation: each rotor pair's throttle ``collective +- pitch_mix * pitch_cmd`` is
      limited to [0, 1] (the baseline does not limit the mix).
    * Motor spin-up: first-order lag 0.04 s up / 0.08 s down (no active braking), rate
      limited.
    * Airspeed-dependent rotors: axial-inflow thrust change (less thrust in climb), effective
      translational lift in forward flight, rotor drag proportional to rotor speed (replacing
      the baseline's constant ``drag_linear``), and a blade-flapping pitch moment
      proportional to rotor speed times forward airspeed.

All extra numbers are engineering estimates (marked as such in :data:`TRUTH_DEFAULTS`); they
are chosen to be plausible for the preset airframe classes, not identified from data.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cache

import casadi as ca
import numpy as np
import scipy.linalg

from uavdyn.airframes import Airframe, param_names
from uavdyn.integrate import compile_function, rk4_step
from uavdyn.model import (
    CONTROL_BOUNDS,
    fixed_wing_forces,
    multirotor_forces,
    rigid_body_rates,
    rotor_thrust,
    stall_blend,
    symbolic_params,
)

# Per-interval reference/gain rows fed to the autopilot (see :func:`autopilot`).
REFERENCE_NAMES = ("ff0", "ff1", "theta_ref", "speed_ref", "h_ref",
                   "K_theta", "K_q", "K_speed", "K_h", "K_hdot")
GUST_NAMES = ("u_g", "w_g", "q_g")
EXTRA_STATE_NAMES = {
    "fixed_wing": ("elevator_act", "throttle_act", "alpha_filt", "sigma_sep"),
    "multirotor": ("rotor_front", "rotor_rear"),
}
BODY_STATE_NAMES = ("u", "w", "q", "theta", "x_n", "h")
AUX_NAMES = ("alpha_air", "V_air", "act0", "act1")

# Truth-model extras (engineering estimates, [EST]), in the order of the parameter vector.
TRUTH_DEFAULTS: dict[str, dict[str, float]] = {
    "fixed_wing": {
        "tau_elevator": 0.04,      # s, small hobby/UAV servo
        "rate_elevator": 3.0,      # rad/s (~170 deg/s)
        "tau_throttle": 0.25,      # s, engine + 20 in propeller spool-up
        "rate_throttle": 2.0,      # 1/s
        "tau_alpha": 0.02,         # s, alpha-dot filter time constant
        "C_L_alphadot": 1.5,       # per rad (with c/2V), typical small-UAV value
        "C_m_alphadot": -6.0,      # per rad (with c/2V), downwash lag at the tail
        "tau_sep": 0.12,           # s, Goman-Khrabrov separation lag (tau1 ~ 15 c/V)
        "tau_hyst": 0.03,          # s, Goman-Khrabrov hysteresis delay (tau2 ~ 4 c/V)
        "C_m_stall": -0.3,         # nose-down pitch break when separated
    },
    "multirotor": {
        "tau_motor_up": 0.04,      # s, ESC + 10 in propeller spin-up
        "tau_motor_down": 0.08,    # s, spin-down without active braking
        "rate_motor": 8.0,         # throttle units per s
        "k_axial": 6.0e-4,         # N per (rad/s) per (m/s) axial inflow, per rotor
        "k_etl": 0.08,             # relative translational-lift gain
        "v_induced": 5.2,          # m/s, hover induced velocity (momentum theory, 10 in)
        "k_rotor_drag": 2.2e-4,    # N per (rad/s) per (m/s), all four rotors summed
        "k_flap": 5.0e-6,          # N m per (rad/s) per (m/s), blade-flapping moment
    },
}
SATURATION_SHARPNESS = 400.0  # 1/unit: soft limits are within 1e-60 of identity 0.35 units in


@dataclass(frozen=True)
class SensorNoise:
    """Standard deviations of the white measurement noise and of the per-sortie gyro bias."""

    u: float = 0.05       # m/s (EKF velocity estimate)
    w: float = 0.05       # m/s
    q: float = 0.005      # rad/s (filtered gyro)
    theta: float = 0.002  # rad (~0.1 deg)
    gyro_bias: float = 0.002  # rad/s

    def scaled(self, factor: float) -> SensorNoise:
        """All standard deviations times ``factor`` (0 gives noise-free logs)."""
        return SensorNoise(self.u * factor, self.w * factor, self.q * factor,
                           self.theta * factor, self.gyro_bias * factor)


def soft_clip(x, lo: float, hi: float, k: float = SATURATION_SHARPNESS):
    """Smooth (analytic) limit of ``x`` to (lo, hi): two softplus ramps. Smoothness keeps RK4
    fourth order where a hard ``fmin/fmax`` would drop it to first order at the corners."""
    def softplus(z):
        return ca.fmax(z, 0) + ca.log1p(ca.exp(-k * ca.fabs(z))) / k
    return lo + softplus(x - lo) - softplus(x - hi)


def rate_limited_lag(actual, command, tau, rate):
    """First-order lag with a smooth rate limit: ``rate * tanh((command - actual)/(tau*rate))``
    (slope 1/tau for small errors, saturating at +-rate)."""
    return rate * ca.tanh((command - actual) / (tau * rate))


def truth_param_names(kind: str) -> tuple[str, ...]:
    """Names of the truth-model extras for ``kind`` (order of the extra parameter vector)."""
    param_names(kind)
    return tuple(TRUTH_DEFAULTS[kind])


def _with_param(p, kind: str, **values):
    """A copy of the symbolic parameter vector with some entries replaced (how the baseline
    force functions are reused for attached-flow-only, flat-plate-only or drag-free forces)."""
    names = param_names(kind)
    entries = [p[i] for i in range(len(names))]
    for key, value in values.items():
        entries[names.index(key)] = value
    return ca.vertcat(*entries)


def _fixed_wing_rates(x, cmd, gust, p, e):
    """Continuous dynamics of the fixed-wing emulator (10 states)."""
    P = symbolic_params("fixed_wing", p)
    body, elev, thr, alpha_f, sigma = x[:6], x[6], x[7], x[8], x[9]
    x_air = ca.vertcat(x[0] - gust[0], x[1] - gust[1], x[2] - gust[2], x[3])
    act = ca.vertcat(elev, thr)
    # Attached-flow-only and flat-plate-only forces from the baseline model: the baseline force
    # is linear in its static blend sigma(alpha), so any blend is (1-s) F_att + s F_plate.
    # alpha0 = +-3 rad puts the baseline's own sigmoid at 0 or 1 for every |alpha| < 1.6 rad.
    # The baseline's own alpha-dot terms are switched off here and applied below with the
    # filtered air-relative alpha-dot (summed with the truth extras), so they count once.
    no_ad = {"C_L_alpha_dot": 0.0, "C_m_alpha_dot": 0.0}
    Xa, Za, Ma, alpha, V, _ = fixed_wing_forces(
        x_air, act, _with_param(p, "fixed_wing", alpha0=3.0, **no_ad), alpha_dot=False)
    Xp, Zp, _, _, _, _ = fixed_wing_forces(
        x_air, act, _with_param(p, "fixed_wing", alpha0=-3.0, **no_ad), alpha_dot=False)
    alpha_dot = (alpha - alpha_f) / e["tau_alpha"]
    qbar_S = 0.5 * P.rho * V**2 * P.S_wing
    c_2V = P.c / (2 * V)
    d_lift = qbar_S * (P.C_L_alpha_dot + e["C_L_alphadot"]) * c_2V * alpha_dot
    X = (1 - sigma) * Xa + sigma * Xp + d_lift * ca.sin(alpha)
    Z = (1 - sigma) * Za + sigma * Zp - d_lift * ca.cos(alpha)
    M = Ma + qbar_S * P.c * ((P.C_m_alpha_dot + e["C_m_alphadot"]) * c_2V * alpha_dot
                             + e["C_m_stall"] * sigma)
    sigma_target = stall_blend(alpha - e["tau_hyst"] * alpha_dot, P.M_blend, P.alpha0)
    (e_lo, e_hi), (t_lo, t_hi) = CONTROL_BOUNDS["fixed_wing"]
    rates = rigid_body_rates(body, X, Z, M, P.mass, P.Jy, P.gravity, with_position=True)
    extra = ca.vertcat(
        rate_limited_lag(elev, soft_clip(cmd[0], e_lo, e_hi), e["tau_elevator"],
                         e["rate_elevator"]),
        rate_limited_lag(thr, soft_clip(cmd[1], t_lo, t_hi), e["tau_throttle"],
                         e["rate_throttle"]),
        alpha_dot,
        (sigma_target - sigma) / e["tau_sep"],
    )
    return ca.vertcat(rates, extra), ca.vertcat(alpha, V, elev, thr)


def _multirotor_rates(x, cmd, gust, p, e):
    """Continuous dynamics of the quadrotor emulator (8 states)."""
    P = symbolic_params("multirotor", p)
    body, s_front, s_rear = x[:6], x[6], x[7]
    x_air = ca.vertcat(x[0] - gust[0], x[1] - gust[1], x[2] - gust[2], x[3])
    # Baseline forces with the actual rotor speeds (as equivalent throttles), without its
    # constant rotor-drag term (replaced below by a rotor-speed-dependent one).
    u_eff = ca.vertcat((s_front + s_rear) / 2, (s_front - s_rear) / (2 * P.pitch_mix))
    X0, Z0, M0, alpha, V, _ = multirotor_forces(x_air, u_eff,
                                                _with_param(p, "multirotor", drag_linear=0.0))
    u_air, w_air = x_air[0], x_air[1]
    lever = P.arm * math.sqrt(0.5)
    d_thrust, omega_sum = [], 0
    for s in (s_front, s_rear):
        T = rotor_thrust(P, s)
        omega = ca.sqrt(T / P.c_T + 1e-9)
        etl = e["k_etl"] * u_air**2 / (u_air**2 + e["v_induced"] ** 2)
        # Pairs of two rotors: axial inflow (w_air > 0: air comes from below, more thrust).
        d_thrust.append(2 * (T * etl + e["k_axial"] * omega * w_air))
        omega_sum = omega_sum + 2 * omega
    X = X0 - e["k_rotor_drag"] * omega_sum * u_air
    Z = Z0 - (d_thrust[0] + d_thrust[1])
    M = M0 + (d_thrust[0] - d_thrust[1]) * lever + e["k_flap"] * omega_sum * u_air
    rates = rigid_body_rates(body, X, Z, M, P.mass, P.Jy, P.gravity, with_position=True)
    mix_front = soft_clip(cmd[0] + P.pitch_mix * cmd[1], 0.0, 1.0)
    mix_rear = soft_clip(cmd[0] - P.pitch_mix * cmd[1], 0.0, 1.0)

    def spin(s, c):
        # Smoothly switch between spin-up and spin-down time constants.
        up = 0.5 * (1 + ca.tanh(50 * (c - s)))
        tau = up * e["tau_motor_up"] + (1 - up) * e["tau_motor_down"]
        return rate_limited_lag(s, c, tau, e["rate_motor"])

    extra = ca.vertcat(spin(s_front, mix_front), spin(s_rear, mix_rear))
    return ca.vertcat(rates, extra), ca.vertcat(alpha, V, s_front, s_rear)


def autopilot(kind: str, x, ref, gust):
    """Discrete autopilot evaluated once per log interval (the command is then held): pitch
    attitude PD with an outer speed loop and an altitude loop; gains come with the references,
    so a mission can schedule them (all zero = open-loop feed-forward ``ff0, ff1``)."""
    u, w, q, theta, h = x[0], x[1], x[2], x[3], x[5]
    ff0, ff1, theta_ref, speed_ref, h_ref, k_th, k_q, k_sp, k_h, k_hd = (
        ref[i] for i in range(len(REFERENCE_NAMES)))
    h_dot = u * ca.sin(theta) - w * ca.cos(theta)
    if kind == "fixed_wing":
        airspeed = ca.sqrt((u - gust[0]) ** 2 + (w - gust[1]) ** 2)  # what a pitot tube sees
        theta_cmd = soft_clip(theta_ref + k_h * (h_ref - h) - k_hd * h_dot, -0.6, 1.2, 50.0)
        elevator = ff0 - k_th * (theta_cmd - theta) + k_q * q
        throttle = ff1 + k_sp * (speed_ref - airspeed)
        cmd = ca.vertcat(elevator, throttle)
    else:
        ground_speed = u * ca.cos(theta) + w * ca.sin(theta)
        theta_cmd = soft_clip(theta_ref - k_sp * (speed_ref - ground_speed), -0.6, 0.6, 50.0)
        pitch_cmd = ff1 + k_th * (theta_cmd - theta) - k_q * q
        collective = ff0 + k_h * (h_ref - h) - k_hd * h_dot
        cmd = ca.vertcat(collective, pitch_cmd)
    lo = [b[0] for b in CONTROL_BOUNDS[kind]]
    hi = [b[1] for b in CONTROL_BOUNDS[kind]]
    return ca.vertcat(*(soft_clip(cmd[i], lo[i], hi[i]) for i in range(2)))


@cache
def _emulator_expressions(kind: str):
    """Symbols and expressions of the emulator's dynamics, built once per kind."""
    n_p, n_e = len(param_names(kind)), len(truth_param_names(kind))
    nx = 6 + len(EXTRA_STATE_NAMES[kind])
    x, v, pe = ca.SX.sym("x", nx), ca.SX.sym("v", 5), ca.SX.sym("pe", n_p + n_e)
    e = {name: pe[n_p + i] for i, name in enumerate(truth_param_names(kind))}
    rates = _fixed_wing_rates if kind == "fixed_wing" else _multirotor_rates
    xdot, aux = rates(x, v[:2], v[2:], pe[:n_p], e)
    return x, v, pe, xdot, aux


@cache
def emulator_rhs(kind: str) -> ca.Function:
    """The emulator's continuous dynamics ``(x, v=[cmd; gust], pe=[p; truth]) -> (xdot)`` as
    an SX Function with the RK4-step signature of :mod:`uavdyn.integrators`."""
    x, v, pe, xdot, _ = _emulator_expressions(kind)
    return ca.Function("emulator_f", [x, v, pe], [xdot], ["x", "u", "p"], ["xdot"])


@cache
def emulator_aux(kind: str) -> ca.Function:
    """``(x, v, pe) -> [alpha_air, V_air, actuator0, actuator1]`` for logging."""
    x, v, pe, _, aux = _emulator_expressions(kind)
    return ca.Function("emulator_aux", [x, v, pe], [aux])


@cache
def log_interval_step(kind: str, substeps: int) -> ca.Function:
    """One log interval: autopilot command (held), then ``substeps`` RK4 steps of the emulator.
    Signature ``(z=[x; pe; dt_log], r=[ref; gust]) -> (z_next, cmd, aux)`` for ``mapaccum``."""
    f = emulator_rhs(kind)
    step = rk4_step(f, "emulator_rk4")
    nx, n_pe = f.size1_in(0), f.size1_in(2)
    z = ca.SX.sym("z", nx + n_pe + 1)
    r = ca.SX.sym("r", len(REFERENCE_NAMES) + len(GUST_NAMES))
    x, pe, dt_log = z[:nx], z[nx:nx + n_pe], z[-1]
    gust = r[len(REFERENCE_NAMES):]
    cmd = autopilot(kind, x, r[:len(REFERENCE_NAMES)], gust)
    v = ca.vertcat(cmd, gust)
    aux = emulator_aux(kind)(x, v, pe)
    h = dt_log / substeps
    xk = x
    for _ in range(substeps):
        xk = step(xk, v, pe, h)
    return ca.Function("emulator_interval", [z, r], [ca.vertcat(xk, pe, dt_log), cmd, aux],
                       ["z", "r"], ["z_next", "cmd", "aux"])


@cache
def emulator_rollout(kind: str, n_intervals: int, substeps: int, compiled: bool = True
                     ) -> ca.Function:
    """ONE Function for a whole sortie: ``(x0, pe, dt_log, R[13 x N]) -> (X[nx x N+1],
    CMD[2 x N], AUX[4 x N])`` built with ``mapaccum`` (a loop in the generated C) and compiled
    (cached on disk by content hash)."""
    body = log_interval_step(kind, substeps)
    nx = 6 + len(EXTRA_STATE_NAMES[kind])
    n_pe = body.size1_in(0) - nx - 1
    acc = body.mapaccum("emulator_acc", n_intervals)
    x0, pe, dt = ca.MX.sym("x0", nx), ca.MX.sym("pe", n_pe), ca.MX.sym("dt")
    R = ca.MX.sym("R", body.size1_in(1), n_intervals)
    Z, CMD, AUX = acc(ca.vertcat(x0, pe, dt), R)
    X = ca.horzcat(x0, Z[:nx, :])
    func = ca.Function(f"emulator_{kind}_{n_intervals}_{substeps}", [x0, pe, dt, R],
                       [X, CMD, AUX], ["x0", "pe", "dt", "R"], ["X", "cmd", "aux"])
    return compile_function(func) if compiled else func


# ----------------------------------------------------------------------------- turbulence


def dryden_gusts(rng: np.random.Generator, n: int, dt: float, airspeed: float,
                 intensity: float = 1.0, wingspan: float = 1.0,
                 sigma_u: float = 1.06, sigma_w: float = 0.7,
                 L_u: float = 200.0, L_w: float = 50.0) -> np.ndarray:
    """``n x 3`` body-axis gusts ``[u_g, w_g, q_g]`` sampled every ``dt`` from the Dryden
    spectra (MIL-F-8785C forms; default scales are Beard & McLain's low-altitude light
    turbulence, times ``intensity``). The shaping filters are discretised exactly (Van Loan),
    so the sampled sequence has the continuous spectra's covariance at any ``dt``.

    ``airspeed`` is the frozen-turbulence convection speed (for a hovering multirotor use the
    mean wind speed plus a floor); ``q_g = d w_g/dt / V`` approximates the pitch-rate gust."""
    if n < 1 or not (dt > 0):
        raise ValueError(f"need n >= 1 and dt > 0, got n={n}, dt={dt}")
    if intensity == 0.0:
        return np.zeros((n, 3))
    if intensity < 0 or not (airspeed > 0):
        raise ValueError(f"need intensity >= 0 and airspeed > 0, got {intensity}, {airspeed}")
    V = float(airspeed)
    su, sw = sigma_u * intensity, sigma_w * intensity
    a_u, a_w = V / L_u, V / L_w
    # States: [x_u, x_w1, x_w2]; u_g = c_u x_u; w_g = c_w (x_w1 * b + x_w2 ...), controllable
    # canonical form of sw sqrt(3V/(pi L_w)) (s + V/(sqrt3 L_w)) / (s + V/L_w)^2 (unit white).
    A = np.array([[-a_u, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -a_w**2, -2 * a_w]])
    B = np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 1.0]])
    k_u = su * math.sqrt(2 * V / (math.pi * L_u))
    k_w = sw * math.sqrt(3 * V / (math.pi * L_w))
    C = np.array([[k_u, 0.0, 0.0],
                  [0.0, k_w * a_w / math.sqrt(3), k_w],
                  [0.0, -k_w * a_w**2, k_w * (a_w / math.sqrt(3) - 2 * a_w)]])
    C[2] /= V  # q_g ~ w_g_dot / V (pitch-plane gust gradient along the airframe)
    # Van Loan: discrete transition and process-noise covariance for unit-intensity white
    # noise (two-sided PSD pi, matching the 1/pi in the gains above).
    m = A.shape[0]
    Qc = math.pi * B @ B.T
    F = np.zeros((2 * m, 2 * m))
    F[:m, :m], F[:m, m:], F[m:, m:] = -A, Qc, A.T
    G = scipy.linalg.expm(F * dt)
    Ad = G[m:, m:].T
    Qd = Ad @ G[:m, m:]
    Qd = 0.5 * (Qd + Qd.T)
    L = np.linalg.cholesky(Qd + 1e-15 * np.eye(m))
    # Start in the stationary distribution (solve the discrete Lyapunov equation).
    P0 = scipy.linalg.solve_discrete_lyapunov(Ad, Qd)
    s = np.linalg.cholesky(P0 + 1e-15 * np.eye(m)) @ rng.standard_normal(m)
    noise = rng.standard_normal((n, m)) @ L.T
    out = np.empty((n, 3))
    for k in range(n):
        out[k] = C @ s
        s = Ad @ s + noise[k]
    return out


# ----------------------------------------------------------------------------- emulator


@dataclass
class EmulatedFlight:
    """What one emulated sortie produced: true and measured states at the log rate, commanded
    controls (held over each interval), and auxiliary truth (air-relative alpha, airspeed,
    actuator positions, altitude)."""

    time: np.ndarray
    true_states: np.ndarray
    measured_states: np.ndarray
    controls: np.ndarray
    gusts: np.ndarray
    aux: dict = field(default_factory=dict)

    @property
    def alpha_air(self) -> np.ndarray:
        """Air-relative angle of attack (rad) at each log time (what the wing sees)."""
        return self.aux["alpha_air"]


class Emulator:
    """The truth model of one airframe. Build once, fly many sorties (the compiled rollout is
    cached per sortie length)."""

    def __init__(self, airframe: Airframe, truth: dict[str, float] | None = None,
                 sample_rate_hz: float = 100.0, internal_dt: float = 1e-3,
                 noise: SensorNoise | None = None, compiled: bool = True) -> None:
        if not (sample_rate_hz > 0) or not (internal_dt > 0):
            raise ValueError("sample_rate_hz and internal_dt must be positive")
        substeps = round(1.0 / (sample_rate_hz * internal_dt))
        if substeps < 1 or abs(substeps * internal_dt * sample_rate_hz - 1) > 1e-9:
            raise ValueError(f"internal_dt {internal_dt} s must divide the log interval "
                             f"{1 / sample_rate_hz} s")
        if airframe.kind == "multirotor" and airframe.params.pitch_mix <= 0:
            raise ValueError("the multirotor emulator needs pitch_mix > 0")
        values = dict(TRUTH_DEFAULTS[airframe.kind])
        unknown = set(truth or {}) - set(values)
        if unknown:
            raise ValueError(f"unknown truth parameter(s) {sorted(unknown)} for "
                             f"{airframe.kind}; expected {sorted(values)}")
        values.update({k: float(v) for k, v in (truth or {}).items()})
        self.airframe = airframe
        self.kind = airframe.kind
        self.truth = values
        self.sample_rate_hz = float(sample_rate_hz)
        self.internal_dt = float(internal_dt)
        self.substeps = int(substeps)
        self.noise = noise if noise is not None else SensorNoise()
        self.compiled = compiled

    @property
    def dt_log(self) -> float:
        """Log interval (s): the autopilot's and the log's sample time."""
        return 1.0 / self.sample_rate_hz

    @property
    def pe(self) -> np.ndarray:
        """Baseline parameters followed by the truth extras (the emulator's ``p``)."""
        return np.concatenate([self.airframe.p, [self.truth[k] for k in
                                                 truth_param_names(self.kind)]])

    @property
    def state_names(self) -> tuple[str, ...]:
        """Names of the emulator's full state (body states, position, extra states)."""
        return BODY_STATE_NAMES + EXTRA_STATE_NAMES[self.kind]

    def initial_state(self, x: np.ndarray, u: np.ndarray, altitude: float) -> np.ndarray:
        """Full emulator state from a baseline state ``[u, w, q, theta]`` and controls (e.g. a
        trim point): actuators at the controls, filters at their steady values."""
        x = np.asarray(x, float)
        if self.kind == "fixed_wing":
            P = self.airframe.params
            alpha = math.atan2(x[1], x[0])
            sigma = float(stall_blend(alpha, P.M_blend, P.alpha0))
            extra = [u[0], u[1], alpha, sigma]
        else:
            mix = self.airframe.params.pitch_mix
            extra = [u[0] + mix * u[1], u[0] - mix * u[1]]
        return np.concatenate([x[:4], [0.0, altitude], extra])

    def fly(self, x0: np.ndarray, references: np.ndarray, gusts: np.ndarray | None = None,
            rng: np.random.Generator | None = None, noise_scale: float = 1.0
            ) -> EmulatedFlight:
        """Fly one sortie. ``references`` is ``N x 10`` (:data:`REFERENCE_NAMES`, row k held over
        log interval k); ``gusts`` ``N x 3`` or None (calm). Logged: N rows at t_k = k dt_log,
        states at t_k and the command held over [t_k, t_k+1). Noise needs ``rng``."""
        references = np.atleast_2d(np.asarray(references, float))
        n = references.shape[0]
        if references.shape[1] != len(REFERENCE_NAMES):
            raise ValueError(f"references must be N x {len(REFERENCE_NAMES)}, got "
                             f"{references.shape}")
        gusts = np.zeros((n, 3)) if gusts is None else np.asarray(gusts, float)
        if gusts.shape != (n, 3):
            raise ValueError(f"gusts must be {n} x 3, got {gusts.shape}")
        func = emulator_rollout(self.kind, n, self.substeps, self.compiled)
        R = np.hstack([references, gusts]).T
        X, CMD, AUX = func(np.asarray(x0, float), self.pe, self.dt_log, R)
        X, CMD, AUX = np.asarray(X).T[:n], np.asarray(CMD).T, np.asarray(AUX).T
        true = X[:, :4].copy()
        measured = true.copy()
        if noise_scale > 0 and rng is not None:
            ns = self.noise.scaled(noise_scale)
            sig = np.array([ns.u, ns.w, ns.q, ns.theta])
            measured = true + rng.standard_normal(true.shape) * sig
            measured[:, 2] += ns.gyro_bias * rng.standard_normal()
        time = np.arange(n) * self.dt_log
        aux = {name: AUX[:, i] for i, name in enumerate(AUX_NAMES)}
        aux["x_n"], aux["h"] = X[:, 4], X[:, 5]
        aux["emulator_states"] = X
        return EmulatedFlight(time=time, true_states=true, measured_states=measured,
                              controls=CMD, gusts=gusts, aux=aux)


def open_loop_references(controls: np.ndarray) -> np.ndarray:
    """References that make the autopilot pass ``controls`` (``N x 2``) straight through (all
    gains zero): for comparing the emulator with the baseline model on the same inputs."""
    controls = np.atleast_2d(np.asarray(controls, float))
    ref = np.zeros((controls.shape[0], len(REFERENCE_NAMES)))
    ref[:, :2] = controls
    return ref
