"""Flight-data emulator: a "truth" model deliberately richer than the baseline model, flown by a
simple autopilot and logged like a real flight log (noise-free true states kept beside measured).

The baseline model (:mod:`uavdyn.model`) is reused, not copied: the emulator evaluates the
baseline force functions at the *air-relative* state and with the *actual* actuator positions,
and adds what the baseline lacks. Exactly what differs from the baseline:

Both kinds
    * Wind: a mean wind ``[W_x, W_z]`` in the inertial frame (x forward/north, z down; a head
      wind has ``W_x < 0``, an updraft ``W_z < 0``), held over each log interval and rotated
      into body axes with the *current* pitch angle inside the dynamics
      (:func:`wind_in_body`), plus Dryden turbulence ``[u_g, w_g, q_g]`` in body axes as the
      MIL spec defines it (MIL-F-8785C forms with Beard & McLain's low-altitude scales,
      intensity multiplier settable, 0 = calm; the pitch-rate gust filtered with the airframe's
      span, :func:`dryden_gusts`). Both enter through the air-relative velocity
      ``u - u_w - u_g, w - w_w - w_g, q - q_g`` at which the aerodynamics, the propulsion and
      the autopilot's pitot tube are evaluated; the kinematics use the inertial velocities.
    * Actuator dynamics: each commanded input passes a smooth position limit, then a
      first-order lag whose rate is smoothly limited (``rate * tanh(error / (tau * rate))``).
    * Sensor noise: Gaussian white noise on every logged state and a constant gyro bias per
      sortie; the logged controls are the commands (exact, zero-order hold per log interval).
    * What is logged (``true_states`` and ``measured_states``, the interchange format's
      ``u, w, q, theta``): the **air-relative** body velocities ``u, w`` (inertial minus wind
      minus gust, what the aerodynamics see; SPEC section 3) and the **inertial** pitch rate and
      attitude ``q, theta`` (gyro, attitude), so ``d theta/dt = q`` holds in the log. The
      inertial (ground-relative) velocities stay in ``aux["emulator_states"][:, :2]``. In calm
      air the two coincide bit for bit.
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
    CASADI_OPS,
    CONTROL_BOUNDS,
    NUMPY_OPS,
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
WIND_NAMES = ("W_x", "W_z")  # inertial mean wind (m/s): x forward/north, z down
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

# Span used for the Dryden pitch-rate gust filter of a multirotor (no wing): the lateral rotor-
# tip-to-tip extent 2 arm cos(45 deg) + D of an X frame, with D the propeller diameter below.
MULTIROTOR_PROP_DIAMETER_M = 0.254  # [EST] 10 in propellers of the F450 class (as v_induced)


def gust_span(airframe: Airframe) -> float:
    """The span ``b`` (m) of the Dryden pitch-rate gust filter for ``airframe``: the wing span
    ``b`` of a fixed wing; for a multirotor the lateral rotor-tip-to-tip extent of an X frame,
    ``2 arm cos(45 deg) + D`` with ``D`` = :data:`MULTIROTOR_PROP_DIAMETER_M` (0.572 m for the
    F450 preset's arm of 0.225 m)."""
    P = airframe.params
    if airframe.kind == "fixed_wing":
        return float(P.b)
    return float(2 * P.arm * math.cos(math.pi / 4) + MULTIROTOR_PROP_DIAMETER_M)


def wind_in_body(theta, wind_x, wind_z, ops=CASADI_OPS):
    """Inertial wind ``[W_x, W_z]`` (x forward/north, z down) in body axes at pitch ``theta``:
    ``u_w = cos(theta) W_x - sin(theta) W_z``, ``w_w = sin(theta) W_x + cos(theta) W_z``.
    Written once against an ``ops`` namespace (CasADi in the dynamics, NumPy for the log)."""
    c, s = ops.cos(theta), ops.sin(theta)
    return c * wind_x - s * wind_z, s * wind_x + c * wind_z


def air_relative(x, disturbance):
    """Air-relative ``[u, w, q, theta]`` of the emulator state ``x`` under ``disturbance`` =
    ``[u_g, w_g, q_g, W_x, W_z]`` (body gusts, inertial wind): inertial minus wind (rotated
    with the current pitch) minus gust; ``theta`` unchanged."""
    u_w, w_w = wind_in_body(x[3], disturbance[3], disturbance[4])
    return ca.vertcat(x[0] - u_w - disturbance[0], x[1] - w_w - disturbance[1],
                      x[2] - disturbance[2], x[3])


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
    """Continuous dynamics of the fixed-wing emulator (10 states); ``gust`` is
    ``[u_g, w_g, q_g, W_x, W_z]`` (:func:`air_relative`)."""
    P = symbolic_params("fixed_wing", p)
    body, elev, thr, alpha_f, sigma = x[:6], x[6], x[7], x[8], x[9]
    x_air = air_relative(x, gust)
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
    """Continuous dynamics of the quadrotor emulator (8 states); ``gust`` is
    ``[u_g, w_g, q_g, W_x, W_z]`` (:func:`air_relative`)."""
    P = symbolic_params("multirotor", p)
    body, s_front, s_rear = x[:6], x[6], x[7]
    x_air = air_relative(x, gust)
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
    so a mission can schedule them (all zero = open-loop feed-forward ``ff0, ff1``).
    ``gust`` is ``[u_g, w_g, q_g, W_x, W_z]``: the fixed wing's speed loop uses the pitot
    (air-relative) airspeed, the multirotor's the ground speed (inertial)."""
    u, w, q, theta, h = x[0], x[1], x[2], x[3], x[5]
    ff0, ff1, theta_ref, speed_ref, h_ref, k_th, k_q, k_sp, k_h, k_hd = (
        ref[i] for i in range(len(REFERENCE_NAMES)))
    h_dot = u * ca.sin(theta) - w * ca.cos(theta)
    if kind == "fixed_wing":
        x_air = air_relative(x, gust)
        airspeed = ca.sqrt(x_air[0] ** 2 + x_air[1] ** 2)  # what a pitot tube sees
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
def _emulator_expressions(kind: str, with_wind: bool = True):
    """Symbols and expressions of the emulator's dynamics, built once per kind. ``v`` is
    ``[cmd (2); gust (3); wind (2)]``, or ``[cmd; gust]`` with the wind zero."""
    n_p, n_e = len(param_names(kind)), len(truth_param_names(kind))
    nx = 6 + len(EXTRA_STATE_NAMES[kind])
    n_v = 2 + len(GUST_NAMES) + (len(WIND_NAMES) if with_wind else 0)
    x, v, pe = ca.SX.sym("x", nx), ca.SX.sym("v", n_v), ca.SX.sym("pe", n_p + n_e)
    e = {name: pe[n_p + i] for i, name in enumerate(truth_param_names(kind))}
    rates = _fixed_wing_rates if kind == "fixed_wing" else _multirotor_rates
    disturbance = v[2:] if with_wind else ca.vertcat(v[2:], 0, 0)
    xdot, aux = rates(x, v[:2], disturbance, pe[:n_p], e)
    return x, v, pe, xdot, aux


@cache
def emulator_rhs(kind: str, with_wind: bool = False) -> ca.Function:
    """The emulator's continuous dynamics ``(x, v, pe=[p; truth]) -> (xdot)`` as an SX
    Function with the RK4-step signature of :mod:`uavdyn.integrators`: ``v = [cmd; gust]``
    (calm mean wind), or with ``with_wind`` ``v = [cmd; gust; W_x; W_z]`` (inertial wind)."""
    x, v, pe, xdot, _ = _emulator_expressions(kind, with_wind)
    return ca.Function("emulator_f", [x, v, pe], [xdot], ["x", "u", "p"], ["xdot"])


@cache
def emulator_aux(kind: str, with_wind: bool = False) -> ca.Function:
    """``(x, v, pe) -> [alpha_air, V_air, actuator0, actuator1]`` for logging (``v`` as in
    :func:`emulator_rhs`)."""
    x, v, pe, _, aux = _emulator_expressions(kind, with_wind)
    return ca.Function("emulator_aux", [x, v, pe], [aux])


@cache
def log_interval_step(kind: str, substeps: int) -> ca.Function:
    """One log interval: autopilot command (held), then ``substeps`` RK4 steps of the emulator.
    Signature ``(z=[x; pe; dt_log], r=[ref; gust; wind]) -> (z_next, cmd, aux)`` for
    ``mapaccum``; gust and inertial wind are held over the interval, the wind's body components
    follow the pitch inside every RK4 stage."""
    f = emulator_rhs(kind, with_wind=True)
    step = rk4_step(f, "emulator_rk4")
    nx, n_pe = f.size1_in(0), f.size1_in(2)
    z = ca.SX.sym("z", nx + n_pe + 1)
    r = ca.SX.sym("r", len(REFERENCE_NAMES) + len(GUST_NAMES) + len(WIND_NAMES))
    x, pe, dt_log = z[:nx], z[nx:nx + n_pe], z[-1]
    disturbance = r[len(REFERENCE_NAMES):]
    cmd = autopilot(kind, x, r[:len(REFERENCE_NAMES)], disturbance)
    v = ca.vertcat(cmd, disturbance)
    aux = emulator_aux(kind, with_wind=True)(x, v, pe)
    h = dt_log / substeps
    xk = x
    for _ in range(substeps):
        xk = step(xk, v, pe, h)
    return ca.Function("emulator_interval", [z, r], [ca.vertcat(xk, pe, dt_log), cmd, aux],
                       ["z", "r"], ["z_next", "cmd", "aux"])


@cache
def emulator_rollout(kind: str, n_intervals: int, substeps: int, compiled: bool = True
                     ) -> ca.Function:
    """ONE Function for a whole sortie: ``(x0, pe, dt_log, R[15 x N]) -> (X[nx x N+1],
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


def dryden_filter(airspeed: float, intensity: float = 1.0, wingspan: float = 1.0,
                  sigma_u: float = 1.06, sigma_w: float = 0.7, L_u: float = 200.0,
                  L_w: float = 50.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Continuous state space ``(A, B, C)`` of the Dryden shaping filters driven by white noise
    of two-sided PSD ``pi`` (unit-intensity in the MIL normalisation): states
    ``[x_u, x_w1, x_w2, z_q]``, outputs ``[u_g, w_g, q_g]``, inputs ``[n_u, n_w]``.

    * ``H_u(s) = sigma_u sqrt(2V/(pi L_u)) / (s + V/L_u)``
    * ``H_w(s) = sigma_w sqrt(3V/(pi L_w)) (s + V/(sqrt3 L_w)) / (s + V/L_w)^2`` (controllable
      canonical form, states ``x_w1, x_w2``)
    * ``H_q(s) = -(s/V) / (1 + T s) H_w(s)`` with ``T = 4 b/(pi V)`` (MIL-F-8785C; the span
      ``b`` is ``wingspan``). Sign: Etkin's ``q_g = -d w_g/d x`` makes ``q - q_g`` the
      air-relative pitch rate (a gust field with ``d w_g/d x > 0`` meets the nose with more
      downward air than the tail, as a nose-up rotation would); frozen turbulence flown through
      at ``V`` gives ``d/dx = (1/V) d/dt``. Realised without a derivative: ``s/(1+Ts) =
      (1 - 1/(1+Ts))/T``, so ``q_g = -(w_g - z_q)/(V T)`` with ``T z_q' = w_g - z_q``.
    """
    V = float(airspeed)
    su, sw = sigma_u * intensity, sigma_w * intensity
    a_u, a_w = V / L_u, V / L_w
    k_u = su * math.sqrt(2 * V / (math.pi * L_u))
    k_w = sw * math.sqrt(3 * V / (math.pi * L_w))
    c_w = np.array([k_w * a_w / math.sqrt(3), k_w])  # w_g = c_w . [x_w1, x_w2]
    T = 4 * wingspan / (math.pi * V)
    A = np.zeros((4, 4))
    A[0, 0] = -a_u
    A[1:3, 1:3] = [[0.0, 1.0], [-a_w**2, -2 * a_w]]
    A[3, 1:3], A[3, 3] = c_w / T, -1.0 / T
    B = np.zeros((4, 2))
    B[0, 0], B[2, 1] = 1.0, 1.0
    C = np.zeros((3, 4))
    C[0, 0] = k_u
    C[1, 1:3] = c_w
    C[2, 1:3], C[2, 3] = -c_w / (V * T), 1.0 / (V * T)
    return A, B, C


def dryden_gusts(rng: np.random.Generator, n: int, dt: float, airspeed: float,
                 intensity: float = 1.0, wingspan: float = 1.0,
                 sigma_u: float = 1.06, sigma_w: float = 0.7,
                 L_u: float = 200.0, L_w: float = 50.0) -> np.ndarray:
    """``n x 3`` body-axis gusts ``[u_g, w_g, q_g]`` sampled every ``dt`` from the Dryden
    spectra (MIL-F-8785C forms, :func:`dryden_filter`; default scales are Beard & McLain's
    low-altitude light turbulence, times ``intensity``). The shaping filters are discretised
    exactly (Van Loan) and started in their stationary distribution, so the sampled sequence
    has the continuous spectra's covariance at any ``dt``.

    ``airspeed`` is the frozen-turbulence convection speed, i.e. the airspeed at which the
    vehicle flies through the air mass (for a hovering multirotor use the mean wind speed
    plus a floor). ``wingspan`` (m) sets the pitch-rate gust's extra first-order filter,
    time constant ``4 b/(pi V)``: take it from the airframe (:func:`gust_span`).

    The random stream is drawn so that ``u_g, w_g`` do not depend on ``wingspan``: the
    pitch-rate filter's noise comes after theirs."""
    if n < 1 or not (dt > 0):
        raise ValueError(f"need n >= 1 and dt > 0, got n={n}, dt={dt}")
    if intensity == 0.0:
        return np.zeros((n, 3))
    if intensity < 0 or not (airspeed > 0) or not (wingspan > 0):
        raise ValueError(f"need intensity >= 0, airspeed > 0 and wingspan > 0, got "
                         f"{intensity}, {airspeed}, {wingspan}")
    A, B, C = dryden_filter(airspeed, intensity, wingspan, sigma_u, sigma_w, L_u, L_w)
    # Van Loan: discrete transition and process-noise covariance for white noise of two-sided
    # PSD pi (matching the 1/pi in the gains).
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
    P0 = 0.5 * (P0 + P0.T)
    # Lower-triangular factors and z_q last: the first three states use only the first three
    # normals of each row, drawn in the same order as without the pitch-rate filter.
    e0 = rng.standard_normal(m - 1)
    e = rng.standard_normal((n, m - 1))
    e0 = np.concatenate([e0, rng.standard_normal(1)])
    e = np.hstack([e, rng.standard_normal((n, 1))])
    s = np.linalg.cholesky(P0 + 1e-15 * np.eye(m)) @ e0
    noise = e @ L.T
    out = np.empty((n, 3))
    for k in range(n):
        out[k] = C @ s
        s = Ad @ s + noise[k]
    return out


# ----------------------------------------------------------------------------- emulator


@dataclass
class EmulatedFlight:
    """What one emulated sortie produced: true and measured states at the log rate, commanded
    controls (held over each interval), the disturbances, and auxiliary truth (air-relative
    alpha, airspeed, actuator positions, position, the full inertial emulator state).

    ``true_states`` and ``measured_states`` are ``[u, w, q, theta]`` with **air-relative**
    ``u, w`` (inertial minus wind minus gust, body axes) and **inertial** ``q, theta``; the
    inertial body velocities are ``aux["emulator_states"][:, :2]``. ``gusts`` (``N x 3``, body
    axes) and ``wind`` (``N x 2``, inertial ``[W_x, W_z]``) are the values held over each log
    interval."""

    time: np.ndarray
    true_states: np.ndarray
    measured_states: np.ndarray
    controls: np.ndarray
    gusts: np.ndarray
    aux: dict = field(default_factory=dict)
    wind: np.ndarray | None = None

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

    def initial_state(self, x: np.ndarray, u: np.ndarray, altitude: float,
                      wind: np.ndarray | None = None) -> np.ndarray:
        """Full emulator state from a baseline state ``[u, w, q, theta]`` and controls (e.g. a
        trim point): actuators at the controls, filters at their steady values.

        Without ``wind`` the velocities of ``x`` become the inertial ones (calm air: the same).
        With an inertial ``wind = [W_x, W_z]`` they are taken as air-relative: the state starts
        in equilibrium with the moving air mass (e.g. a trim point flown in a steady wind), its
        inertial velocity being ``x[:2]`` plus the wind rotated into body axes."""
        x = np.asarray(x, float)
        body = x[:4].copy()
        if wind is not None:
            wind = np.asarray(wind, float).reshape(-1)
            if wind.shape != (len(WIND_NAMES),) or not np.all(np.isfinite(wind)):
                raise ValueError(f"wind must be finite [W_x, W_z], got {wind}")
            u_w, w_w = wind_in_body(x[3], wind[0], wind[1], NUMPY_OPS)
            body[0], body[1] = x[0] + u_w, x[1] + w_w
        if self.kind == "fixed_wing":
            P = self.airframe.params
            alpha = math.atan2(x[1], x[0])
            sigma = float(stall_blend(alpha, P.M_blend, P.alpha0))
            extra = [u[0], u[1], alpha, sigma]
        else:
            mix = self.airframe.params.pitch_mix
            extra = [u[0] + mix * u[1], u[0] - mix * u[1]]
        return np.concatenate([body, [0.0, altitude], extra])

    def fly(self, x0: np.ndarray, references: np.ndarray, gusts: np.ndarray | None = None,
            rng: np.random.Generator | None = None, noise_scale: float = 1.0, *,
            wind: np.ndarray | None = None) -> EmulatedFlight:
        """Fly one sortie. ``references`` is ``N x 10`` (:data:`REFERENCE_NAMES`, row k held over
        log interval k); ``gusts`` ``N x 3`` body-axis turbulence or None (none); ``wind`` the
        inertial mean wind ``[W_x, W_z]`` (m/s, x forward/north, z down: a head wind of 5 m/s
        is ``[-5, 0]``), constant or ``N x 2`` (row k held over interval k), or None (calm).
        ``x0`` is the full inertial emulator state (:meth:`initial_state`). Logged: N rows at
        t_k = k dt_log, states at t_k (``u, w`` air-relative, ``q, theta`` inertial) and the
        command held over [t_k, t_k+1). Noise needs ``rng``."""
        references = np.atleast_2d(np.asarray(references, float))
        n = references.shape[0]
        if references.shape[1] != len(REFERENCE_NAMES):
            raise ValueError(f"references must be N x {len(REFERENCE_NAMES)}, got "
                             f"{references.shape}")
        gusts = np.zeros((n, 3)) if gusts is None else np.asarray(gusts, float)
        if gusts.shape != (n, 3):
            raise ValueError(f"gusts must be {n} x 3, got {gusts.shape}")
        if wind is None:
            wind = np.zeros((n, len(WIND_NAMES)))
        else:
            wind = np.asarray(wind, float)
            if wind.shape == (len(WIND_NAMES),):
                wind = np.tile(wind, (n, 1))
            if wind.shape != (n, len(WIND_NAMES)):
                raise ValueError(f"wind must be [W_x, W_z] or {n} x 2, got {wind.shape}")
        if not (np.all(np.isfinite(gusts)) and np.all(np.isfinite(wind))):
            raise ValueError("gusts and wind must be finite")
        func = emulator_rollout(self.kind, n, self.substeps, self.compiled)
        R = np.hstack([references, gusts, wind]).T
        X, CMD, AUX = func(np.asarray(x0, float), self.pe, self.dt_log, R)
        X, CMD, AUX = np.asarray(X).T[:n], np.asarray(CMD).T, np.asarray(AUX).T
        # Logged velocities are air-relative (what the aerodynamics see), at the same instant
        # and with the same held gust and wind as the interval's aerodynamics.
        u_w, w_w = wind_in_body(X[:, 3], wind[:, 0], wind[:, 1], NUMPY_OPS)
        true = X[:, :4].copy()
        true[:, 0] = X[:, 0] - u_w - gusts[:, 0]
        true[:, 1] = X[:, 1] - w_w - gusts[:, 1]
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
                              controls=CMD, gusts=gusts, aux=aux, wind=wind)


def open_loop_references(controls: np.ndarray) -> np.ndarray:
    """References that make the autopilot pass ``controls`` (``N x 2``) straight through (all
    gains zero): for comparing the emulator with the baseline model on the same inputs."""
    controls = np.atleast_2d(np.asarray(controls, float))
    ref = np.zeros((controls.shape[0], len(REFERENCE_NAMES)))
    ref[:, :2] = controls
    return ref
