"""The emulator's truth dynamics: wind and gusts, actuators, unsteady aerodynamics, rotors."""

from __future__ import annotations

import math
from functools import cache

import casadi as ca

from uavdyn.airframes import param_names
from uavdyn.model import (
    CASADI_OPS,
    CONTROL_BOUNDS,
    LATERAL_INPUT_NAMES,
    fixed_wing_forces,
    multirotor_forces,
    rigid_body_rates,
    rotor_thrust,
    stall_blend,
    symbolic_params,
)

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
        # Power and Reynolds-number effects, added to the airframe's own optional keys of the
        # same names (uavdyn.model.equations). Default 0 (absent: every existing dataset,
        # fingerprint and reference stays bit-for-bit the same); realistic values: eta 0.5-1
        # for a tractor with the tail in the slipstream, C_D_Re ~ 0.05 and C_m_Re ~ -0.05
        # (m/s)^0.5 for a small UAV at 15-30 m/s.
        "eta_slipstream": 0.0,     # share of the tail in the slipstream (extra eta T/A_disk)
        "C_D_Re": 0.0,             # (m/s)^0.5, Delta C_D = C_D_Re / sqrt(V)
        "C_m_Re": 0.0,             # (m/s)^0.5, Delta C_m = C_m_Re / sqrt(V)
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


def airframe_truth(airframe) -> dict[str, float]:
    """The truth-model extras an airframe file sets itself: its actuator lags and rate limits.

    Fixed wing: ``tau_elevator`` and ``tau_throttle`` (where non-zero) are the servo and
    engine lags; the actuator rates are 1 / ``slew_elevator`` and 1 / ``slew_throttle`` (the
    model's own rate limits, where non-zero), else ``[limits]`` ``elevator_rate`` and
    ``throttle_rate``.
    Multirotor: ``tau_rotor`` (where non-zero) is the spin-up lag; spin-down keeps the
    emulator's ratio (no active braking: ``tau_motor_down / tau_motor_up`` of
    :data:`TRUTH_DEFAULTS`). Everything else keeps the emulator's defaults."""
    P, out = airframe.params, {}
    if airframe.kind == "fixed_wing":
        for name in ("tau_elevator", "tau_throttle"):
            if getattr(P, name) > 0:
                out[name] = float(getattr(P, name))
        for control in ("elevator", "throttle"):
            slew = getattr(P, f"slew_{control}")
            rate = 1.0 / slew if slew > 0 else airframe.limits.get(f"{control}_rate")
            if rate is not None:
                out[f"rate_{control}"] = float(rate)
    elif P.tau_rotor > 0:
        defaults = TRUTH_DEFAULTS["multirotor"]
        out["tau_motor_up"] = float(P.tau_rotor)
        out["tau_motor_down"] = float(P.tau_rotor) * (defaults["tau_motor_down"]
                                                      / defaults["tau_motor_up"])
    return out


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


def _fixed_wing_rates(x, cmd, gust, p, e, lateral=None, inertias=None):
    """Continuous dynamics of the fixed-wing emulator (10 states); ``gust`` is
    ``[u_g, w_g, q_g, W_x, W_z]`` (:func:`air_relative`); ``lateral`` = ``(phi, p, r, beta)``
    prescribed and ``inertias`` = ``(Jx, Jz, Jxz)`` add the turning-flight terms of
    :mod:`uavdyn.model.equations` to the rigid body (turning flight)."""
    P = symbolic_params("fixed_wing", p)
    body, elev, thr, alpha_f, sigma = x[:6], x[6], x[7], x[8], x[9]
    x_air = air_relative(x, gust)
    act = ca.vertcat(elev, thr)
    # Attached-flow-only and flat-plate-only forces from the baseline model: the baseline force
    # is linear in its static blend sigma(alpha), so any blend is (1-s) F_att + s F_plate.
    # alpha0 = +-3 rad puts the baseline's own sigmoid at 0 or 1 for every |alpha| < 1.6 rad.
    # The baseline's own alpha-dot terms are switched off here and applied below with the
    # filtered air-relative alpha-dot (summed with the truth extras), so they count once.
    # The power and Reynolds terms are the baseline's, flown at the file's value + the extra.
    base = {"C_L_alpha_dot": 0.0, "C_m_alpha_dot": 0.0,
             **{k: getattr(P, k) + e[k] for k in ("eta_slipstream", "C_D_Re", "C_m_Re")}}
    Xa, Za, Ma, alpha, V, _ = fixed_wing_forces(
        x_air, act, _with_param(p, "fixed_wing", alpha0=3.0, **base), alpha_dot=False)
    Xp, Zp, _, _, _, _ = fixed_wing_forces(
        x_air, act, _with_param(p, "fixed_wing", alpha0=-3.0, **base), alpha_dot=False)
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
    rates = rigid_body_rates(body, X, Z, M, P.mass, P.Jy, P.gravity, with_position=True,
                             lateral=lateral, inertias=inertias)
    extra = ca.vertcat(
        rate_limited_lag(elev, soft_clip(cmd[0], e_lo, e_hi), e["tau_elevator"],
                         e["rate_elevator"]),
        rate_limited_lag(thr, soft_clip(cmd[1], t_lo, t_hi), e["tau_throttle"],
                         e["rate_throttle"]),
        alpha_dot,
        (sigma_target - sigma) / e["tau_sep"],
    )
    return ca.vertcat(rates, extra), ca.vertcat(alpha, V, elev, thr)


def _multirotor_rates(x, cmd, gust, p, e, lateral=None, inertias=None):
    """Continuous dynamics of the quadrotor emulator (8 states); ``gust`` is
    ``[u_g, w_g, q_g, W_x, W_z]`` (:func:`air_relative`); ``lateral``, ``inertias`` as for
    :func:`_fixed_wing_rates`."""
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
    rates = rigid_body_rates(body, X, Z, M, P.mass, P.Jy, P.gravity, with_position=True,
                             lateral=lateral, inertias=inertias)
    mix_front = soft_clip(cmd[0] + P.pitch_mix * cmd[1], 0.0, 1.0)
    mix_rear = soft_clip(cmd[0] - P.pitch_mix * cmd[1], 0.0, 1.0)

    def spin(s, c):
        # Smoothly switch between spin-up and spin-down time constants.
        up = 0.5 * (1 + ca.tanh(50 * (c - s)))
        tau = up * e["tau_motor_up"] + (1 - up) * e["tau_motor_down"]
        return rate_limited_lag(s, c, tau, e["rate_motor"])

    extra = ca.vertcat(spin(s_front, mix_front), spin(s_rear, mix_rear))
    return ca.vertcat(rates, extra), ca.vertcat(alpha, V, s_front, s_rear)


@cache
def _emulator_expressions(kind: str, with_wind: bool = True, lateral: bool = False):
    """Symbols and expressions of the emulator's dynamics, built once per kind. ``v`` is
    ``[cmd (2); gust (3); wind (2)]``, or ``[cmd; gust]`` with the wind zero; ``lateral``
    appends the prescribed ``[phi, p, r, beta]`` to ``v`` and ``[Jx, Jz, Jxz]`` to ``pe``
    (turning flight: the truth integrates the longitudinal equations with the bank and
    turn-rate terms, the lateral motion given)."""
    n_p, n_e = len(param_names(kind)), len(truth_param_names(kind))
    nx = 6 + len(EXTRA_STATE_NAMES[kind])
    n_d = len(GUST_NAMES) + (len(WIND_NAMES) if with_wind else 0)
    n_lat = len(LATERAL_INPUT_NAMES) if lateral else 0
    x, v = ca.SX.sym("x", nx), ca.SX.sym("v", 2 + n_d + n_lat)
    pe = ca.SX.sym("pe", n_p + n_e + (3 if lateral else 0))
    e = {name: pe[n_p + i] for i, name in enumerate(truth_param_names(kind))}
    rates = _fixed_wing_rates if kind == "fixed_wing" else _multirotor_rates
    disturbance = v[2:2 + n_d] if with_wind else ca.vertcat(v[2:2 + n_d], 0, 0)
    if lateral:
        k = 2 + n_d
        lat = (v[k], v[k + 1], v[k + 2], v[k + 3])
        j = n_p + n_e
        xdot, aux = rates(x, v[:2], disturbance, pe[:n_p], e, lat, (pe[j], pe[j + 1],
                                                                     pe[j + 2]))
    else:
        xdot, aux = rates(x, v[:2], disturbance, pe[:n_p], e)
    return x, v, pe, xdot, aux


@cache
def emulator_rhs(kind: str, with_wind: bool = False, lateral: bool = False) -> ca.Function:
    """The emulator's continuous dynamics ``(x, v, pe=[p; truth]) -> (xdot)`` as an SX
    Function with the RK4-step signature of :mod:`uavdyn.integrators`: ``v = [cmd; gust]``
    (calm mean wind), or with ``with_wind`` ``v = [cmd; gust; W_x; W_z]`` (inertial wind);
    ``lateral`` as in :func:`_emulator_expressions`."""
    x, v, pe, xdot, _ = _emulator_expressions(kind, with_wind, lateral)
    return ca.Function("emulator_f", [x, v, pe], [xdot], ["x", "u", "p"], ["xdot"])


@cache
def emulator_aux(kind: str, with_wind: bool = False, lateral: bool = False) -> ca.Function:
    """``(x, v, pe) -> [alpha_air, V_air, actuator0, actuator1]`` for logging (``v`` as in
    :func:`emulator_rhs`)."""
    x, v, pe, _, aux = _emulator_expressions(kind, with_wind, lateral)
    return ca.Function("emulator_aux", [x, v, pe], [aux])
