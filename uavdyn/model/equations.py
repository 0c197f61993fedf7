"""The nonlinear longitudinal equations of motion, written once against an ``ops`` namespace.

State ``x = [u, w, q, theta]`` (body-axis velocities m/s, pitch rate rad/s, pitch angle rad),
optionally followed by ``[x_n, h]`` (north position and altitude, m). Controls: fixed wing
``[elevator (rad), throttle (0..1)]``; multirotor ``[collective (0..1), pitch_cmd (-1..1)]``.
Parameters enter as the symbolic vector ``p`` (order: :func:`uavdyn.airframes.param_names`).

Equations (SPEC section 2; the paper's ``q_dot = M/I_y - g sin(theta)`` is a typo)::

    u_dot = X/m - g sin(theta) - q w        w_dot = Z/m + g cos(theta) + q u
    q_dot = M/I_y                           theta_dot = q

Alpha-dot derivatives (optional fixed-wing keys ``C_L_alpha_dot``, ``C_m_alpha_dot``) are solved
exactly, not lagged. With ``alpha = atan2(w, u)``, ``alpha_dot = (u w_dot - w u_dot) / V^2``.
The alpha-dot lift ``L_ad = qbar S C_L_alpha_dot c/(2V) alpha_dot`` enters ``X`` as
``+L_ad sin(alpha)`` and ``Z`` as ``-L_ad cos(alpha)``, so it changes
``u w_dot - w u_dot`` by ``-L_ad (u cos(alpha) + w sin(alpha)) / m = -L_ad V / m``::

    alpha_dot = A0 - L_ad / (m V) = A0 / (1 + rho S c C_L_alpha_dot / (4 m))

where ``A0`` is alpha_dot from the forces without the alpha-dot terms (a linear relation solved
in closed form; the factor does not depend on V). The moment then gets
``qbar S c C_m_alpha_dot (c/(2V)) alpha_dot``. At their default 0 both terms are exactly 0.0.

Power effects (optional key ``eta_slipstream``, >= 0): the tail sits partly in the propeller
slipstream, whose fully developed dynamic pressure exceeds the free stream's by ``T / A_disk``
(momentum theory, ``A_disk = pi D_prop^2 / 4``, ``T`` the model's thrust). The elevator's lift
and moment see ``qbar_tail = qbar + eta_slipstream T / A_disk``::

    L = qbar S C_L + eta_slipstream (T / A_disk) S C_L_delta_e delta_e
    M = qbar S c C_m + eta_slipstream (T / A_disk) S c C_m_delta_e delta_e

(``C_L``, ``C_m`` the full coefficients, their ``delta_e`` terms at ``qbar``).

Reynolds-number effects (optional keys ``C_D_Re``, ``C_m_Re``, units (m/s)^0.5): laminar skin
friction scales as ``Re^-1/2``, so at fixed alpha drag and moment vary with airspeed::

    Delta C_D = C_D_Re / sqrt(V_g)        Delta C_m = C_m_Re / sqrt(V_g)
    V_g = max(V, V_RE_FLOOR)              (V_RE_FLOOR = 1 m/s: finite as V -> 0)

At their default 0 all three add exactly 0.0 (the increments are appended to the sums, so the
forces are bit-for-bit those without them).

Turning flight (a structure with ``lateral``): the recorded bank angle ``phi``, roll and yaw
rates ``p``, ``r`` and sideslip ``beta`` are inputs after the controls (the state stays
``[u, w, q, theta]``), with ``v = sqrt(u^2 + w^2) tan(beta)`` the side velocity; the rigid-body
6-DoF equations restricted to the longitudinal states, the lateral variables given::

    u_dot = X/m - g sin(theta) - q w + r v
    w_dot = Z/m + g cos(theta) cos(phi) + q u - p v
    q_dot = (M + (Jz - Jx) p r + Jxz (r^2 - p^2)) / Jy
    theta_dot = q cos(phi) - r sin(phi)
    x_n_dot = u cos(theta) + (v sin(phi) + w cos(phi)) sin(theta)   (along the heading)
    h_dot = u sin(theta) - v sin(phi) cos(theta) - w cos(phi) cos(theta)

``X``, ``Z``, ``M`` are the pitch-plane forces of ``(u, w, q)`` as without (no sideslip or
lateral-rate aerodynamics). A level coordinated turn is then an equilibrium with
``q = omega sin(phi) cos(theta)``, ``r = omega cos(phi) cos(theta)``,
``p = -omega sin(theta)``, ``omega = g tan(phi) / V``: the normal load factor ``1/cos(phi)``.
With every lateral input 0 each added term is exactly 0.0 (so the same numbers as the
wings-level model to round-off); a structure without ``lateral`` builds the wings-level graph.
"""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

from uavdyn.airframes import CONTROL_RANGES, param_names
from uavdyn.model.atmosphere import isa_density_ratio
from uavdyn.model.interpolation import interp1, interp2
from uavdyn.model.ops import CASADI_OPS
from uavdyn.model.structure import ModelStructure

# Control names and physical ranges per kind: one table, kept with the airframe schema (which
# checks an airframe's own limits against it).
CONTROL_NAMES = {kind: tuple(n for n, _ in ranges) for kind, ranges in CONTROL_RANGES.items()}
CONTROL_BOUNDS = {kind: tuple(b for _, b in ranges) for kind, ranges in CONTROL_RANGES.items()}
FORCE_NAMES = ("X", "Z", "M", "alpha", "V", "thrust")
# Airspeed floor (m/s) of the Reynolds terms' 1/sqrt(V): keeps them finite (and their
# derivatives bounded) as V -> 0; every flyable airspeed is far above it.
V_RE_FLOOR = 1.0


def symbolic_params(kind: str, p) -> SimpleNamespace:
    """Name the entries of a symbolic parameter vector so equations read like the textbook."""
    return SimpleNamespace(**{name: p[i] for i, name in enumerate(param_names(kind))})


def as_structure(kind: str | ModelStructure, alpha_dot: bool | None = None) -> ModelStructure:
    """A structure for a kind name (fixed wing: with the alpha-dot terms unless told not)."""
    if isinstance(kind, ModelStructure):
        if alpha_dot is None or alpha_dot == kind.alpha_dot:
            return kind
        return replace(kind, alpha_dot=bool(alpha_dot) and kind.kind == "fixed_wing")
    param_names(kind)  # validates the kind
    return ModelStructure(kind, alpha_dot=kind == "fixed_wing" and alpha_dot is not False)


def _table(structure: ModelStructure, name: str, p, axis_values: dict, ops):
    """The value of table ``name`` at the named axis values (None: the airframe has none)."""
    slices = structure.table_slices()
    if name not in slices:
        return None
    axes, start, stop = slices[name]
    values = [p[i] for i in range(start, stop)]
    if len(axes) == 1:
        return interp1(axes[0][1], values, axis_values[axes[0][0]], ops)
    return interp2(axes[0][1], axes[1][1], values, axis_values[axes[0][0]],
                   axis_values[axes[1][0]], ops)


def air_density(P: SimpleNamespace, x, structure: ModelStructure, with_position: bool,
                ops=CASADI_OPS):
    """Density the aerodynamics see: ``rho``, or with ``atmosphere = "isa"`` and an ``h`` state,
    the sea-level ``rho`` scaled by the ISA ratio at ``h`` (without an h state the caller scales
    ``rho`` per sortie: :func:`uavdyn.model.sortie_params`)."""
    if structure.isa and with_position:
        return P.rho * isa_density_ratio(x[5], ops)
    return P.rho


def stall_blend(alpha, M, alpha0, ops=CASADI_OPS):
    """Beard & McLain sigmoid (eq. 4.10): 0 for attached flow, 1 past +-alpha0."""
    e_minus = ops.exp(-M * (alpha - alpha0))
    e_plus = ops.exp(M * (alpha + alpha0))
    return (1 + e_minus + e_plus) / ((1 + e_minus) * (1 + e_plus))


def propeller_thrust(P: SimpleNamespace, Va, throttle, ops=CASADI_OPS):
    """McLain's motor/propeller model: motor speed from the torque balance, then thrust from
    the C_T fit in advance ratio (closed form, smooth in Va and throttle)."""
    two_pi = 2 * ops.pi
    KQ = 60.0 / (two_pi * P.KV_rpm_per_volt)
    V_in = P.V_max * throttle
    a = P.rho * P.D_prop**5 * P.C_Q0 / two_pi**2
    b = P.rho * P.D_prop**4 * P.C_Q1 * Va / two_pi + KQ**2 / P.R_motor
    c = P.rho * P.D_prop**3 * P.C_Q2 * Va**2 - KQ * V_in / P.R_motor + KQ * P.i0
    omega = (-b + ops.sqrt(b**2 - 4 * a * c)) / (2 * a)
    return (P.rho * P.D_prop**4 * P.C_T0 * omega**2 / two_pi**2
            + P.rho * P.D_prop**3 * P.C_T1 * Va * omega / two_pi
            + P.rho * P.D_prop**2 * P.C_T2 * Va**2)


def fixed_wing_forces(x, u, p, ops=CASADI_OPS, alpha_dot: bool = True,
                      structure: ModelStructure | None = None, with_position: bool = False):
    """Body-axis aerodynamic + propulsive force X, Z (N) and pitching moment M (N m), with
    alpha (rad), airspeed V (m/s) and thrust (N).

    Lift, drag and moment coefficients follow Beard & McLain ch. 4: attached-flow lift
    (with the paper's quadratic term) blended to Newtonian flat-plate lift/drag past stall so the
    model is defined over alpha in [-90, 90] deg; parabolic drag polar; linear moment; the
    optional alpha-dot terms solved exactly (module docstring). ``x`` needs theta (``x[3]``):
    alpha_dot depends on the whole acceleration, gravity included. ``alpha_dot=False`` leaves
    the terms out of the graph (an airframe whose alpha-dot keys are 0: same numbers, a cheaper
    step). ``structure`` adds breakpoint tables (a ``C_L``/``C_D``/``C_m`` table replaces the
    attached-flow polynomial, lift curve, drag polar or static moment; a ``thrust`` table the
    motor model) and the ISA density at the ``h`` state (``with_position``).
    """
    return _fixed_wing_terms(x, u, p, ops, alpha_dot, structure, with_position)[:6]


def fixed_wing_alpha_dot(x, u, p, ops=CASADI_OPS, structure: ModelStructure | None = None,
                         with_position: bool = False):
    """The exact alpha_dot (rad/s) of the closed form, the value the alpha-dot terms use."""
    return _fixed_wing_terms(x, u, p, ops, True, structure, with_position)[6]


def _fixed_wing_terms(x, u, p, ops, with_alpha_dot: bool = True,
                      structure: ModelStructure | None = None, with_position: bool = False):
    """Forces, moment and the closed-form alpha_dot of the fixed wing (see the callers)."""
    structure = structure or ModelStructure("fixed_wing", alpha_dot=with_alpha_dot)
    P = symbolic_params("fixed_wing", p)
    ub, wb, q = x[0], x[1], x[2]
    elevator, throttle = u[0], u[1]
    V = ops.sqrt(ub**2 + wb**2)
    alpha = ops.atan2(wb, ub)
    rho = air_density(P, x, structure, with_position, ops)
    P = SimpleNamespace(**{**vars(P), "rho": rho})
    qbar = 0.5 * rho * V**2
    q_hat = P.c * q / (2 * V)
    sigma = stall_blend(alpha, P.M_blend, P.alpha0, ops)
    aspect = P.b**2 / P.S_wing
    axis = {"alpha": alpha, "elevator": elevator, "airspeed": V, "throttle": throttle}
    CL_attached = _table(structure, "C_L", p, axis, ops)
    if CL_attached is None:
        CL_attached = P.C_L_0 + P.C_L_alpha * alpha + P.C_L_alpha2 * alpha**2
    sin_a, cos_a = ops.sin(alpha), ops.cos(alpha)
    CL_plate = 2 * ops.sign(alpha) * sin_a**2 * cos_a
    CD_attached = _table(structure, "C_D", p, axis, ops)
    if CD_attached is None:
        CD_attached = P.C_D_0 + CL_attached**2 / (ops.pi * P.e * aspect)
    CD_plate = P.C_D_0 + 2 * ops.fabs(sin_a) ** 3
    # Reynolds-number terms (module docstring), appended last: exactly + 0.0 at their default.
    inv_sqrt_V = 1 / ops.sqrt(ops.fmax(V, V_RE_FLOOR))
    CL = (1 - sigma) * CL_attached + sigma * CL_plate + P.C_L_q * q_hat + P.C_L_delta_e * elevator
    CD = ((1 - sigma) * CD_attached + sigma * CD_plate + P.C_D_q * q_hat
          + P.C_D_delta_e * elevator + P.C_D_Re * inv_sqrt_V)
    Cm_static = _table(structure, "C_m", p, axis, ops)
    if Cm_static is None:
        Cm_static = P.C_m_0 + P.C_m_alpha * alpha
    Cm = Cm_static + P.C_m_q * q_hat + P.C_m_delta_e * elevator + P.C_m_Re * inv_sqrt_V
    thrust = _table(structure, "thrust", p, axis, ops)
    if thrust is None:
        thrust = propeller_thrust(P, V, throttle, ops)
    # Power effects: the slipstream's extra dynamic pressure on the elevator (module docstring).
    dq_tail = P.eta_slipstream * thrust / (0.25 * ops.pi * P.D_prop**2)
    lift = qbar * P.S_wing * CL + dq_tail * P.S_wing * P.C_L_delta_e * elevator
    drag = qbar * P.S_wing * CD
    X0 = -drag * cos_a + lift * sin_a + thrust
    Z0 = -drag * sin_a - lift * cos_a
    M0 = qbar * P.S_wing * P.c * Cm + dq_tail * P.S_wing * P.c * P.C_m_delta_e * elevator
    if not with_alpha_dot:
        return X0, Z0, M0, alpha, V, thrust, None
    # Exact alpha-dot terms: A0 from the forces without them, then the closed form.
    u_dot0, w_dot0 = translational_accelerations(x, X0, Z0, P.mass, P.gravity, ops,
                                                 lateral_inputs(structure, u))
    alpha_dot0 = (ub * w_dot0 - wb * u_dot0) / V**2
    alpha_dot = alpha_dot0 / (1 + rho * P.S_wing * P.c * P.C_L_alpha_dot / (4 * P.mass))
    ad_hat = P.c * alpha_dot / (2 * V)
    lift_ad = qbar * P.S_wing * P.C_L_alpha_dot * ad_hat
    X = X0 + lift_ad * sin_a
    Z = Z0 - lift_ad * cos_a
    M = M0 + qbar * P.S_wing * P.c * P.C_m_alpha_dot * ad_hat
    return X, Z, M, alpha, V, thrust, alpha_dot


def rotor_thrust(P: SimpleNamespace, throttle, v_axial=0.0, ops=CASADI_OPS):
    """Thrust of one rotor from its throttle: w = max(C_R*sigma + w_b, 0),
    T = max(c_T w^2 - k_inflow w v_axial, 0) with the axial inflow (climb) speed ``v_axial``
    through the disc (momentum theory, linearised; ``k_inflow = 0``: static thrust)."""
    omega = ops.fmax(P.C_R * throttle + P.omega_b, 0)
    return ops.fmax(P.c_T * omega**2 - P.k_inflow * omega * v_axial, 0)


def multirotor_forces(x, u, p, ops=CASADI_OPS, structure: ModelStructure | None = None,
                      with_position: bool = False):
    """Body-axis force X, Z (N) and moment M (N m) of an X-frame quadrotor in the pitch plane:
    front pair and rear pair of rotors (thrust lost to axial inflow), body drag (linear rotor
    drag + quadratic parasite), pitch damping, a speed-stability moment ``M_u u`` and a constant
    moment ``M_0``."""
    P = symbolic_params("multirotor", p)
    if structure is not None:
        P = SimpleNamespace(**{**vars(P), "rho": air_density(P, x, structure, with_position,
                                                               ops)})
    ub, wb, q = x[0], x[1], x[2]
    collective, pitch_cmd = u[0], u[1]
    v_axial = -wb  # body z points down, the rotors push up: climbing air comes from above
    t_front = rotor_thrust(P, collective + P.pitch_mix * pitch_cmd, v_axial, ops)
    t_rear = rotor_thrust(P, collective - P.pitch_mix * pitch_cmd, v_axial, ops)
    thrust = 2 * (t_front + t_rear)
    lever = P.arm * ops.sqrt(0.5)
    X = -P.drag_linear * ub - 0.5 * P.rho * P.CdA_x * ops.fabs(ub) * ub
    Z = -thrust - 0.5 * P.rho * P.CdA_z * ops.fabs(wb) * wb
    M = 2 * (t_front - t_rear) * lever - P.pitch_damping * q + P.M_0 + P.M_u * ub
    V = ops.sqrt(ub**2 + wb**2)
    alpha = ops.atan2(wb, ub)
    return X, Z, M, alpha, V, thrust


FORCE_MODELS = {"fixed_wing": fixed_wing_forces, "multirotor": multirotor_forces}


def lateral_inputs(structure: ModelStructure | None, u) -> tuple | None:
    """``(phi, p, r, beta)`` from the inputs ``u`` of a structure with lateral inputs, else
    None."""
    if structure is None or not structure.lateral:
        return None
    k = structure.lateral_slice.start
    return u[k], u[k + 1], u[k + 2], u[k + 3]


def side_velocity(x, beta, ops=CASADI_OPS):
    """``v = sqrt(u^2 + w^2) tan(beta)`` (m/s): the body side velocity of sideslip ``beta``
    (``beta = asin(v / |V|)``)."""
    return ops.sqrt(x[0] ** 2 + x[1] ** 2) * ops.sin(beta) / ops.cos(beta)


def translational_accelerations(x, X, Z, mass, g, ops=CASADI_OPS, lateral=None):
    """``(u_dot, w_dot)`` given body forces: written once, used by the rigid body and by the
    alpha-dot closed form (which needs the acceleration without the alpha-dot force).
    ``lateral`` = ``(phi, p, r, beta)`` adds the turning-flight terms (module docstring)."""
    ub, wb, q, theta = x[0], x[1], x[2], x[3]
    if lateral is None:
        return (X / mass - g * ops.sin(theta) - q * wb,
                Z / mass + g * ops.cos(theta) + q * ub)
    phi, pr, rr, beta = lateral
    v = side_velocity(x, beta, ops)
    return (X / mass - g * ops.sin(theta) - q * wb + rr * v,
            Z / mass + g * ops.cos(theta) * ops.cos(phi) + q * ub - pr * v)


def rigid_body_rates(x, X, Z, M, mass, Jy, g, with_position: bool, ops=CASADI_OPS,
                     lateral=None, inertias=None):
    """Longitudinal rigid-body kinematics and dynamics given body forces and moment; with
    ``lateral`` = ``(phi, p, r, beta)`` and ``inertias`` = ``(Jx, Jz, Jxz)`` those of turning
    flight (module docstring)."""
    ub, wb, q, theta = x[0], x[1], x[2], x[3]
    u_dot, w_dot = translational_accelerations(x, X, Z, mass, g, ops, lateral)
    if lateral is None:
        rates = [u_dot, w_dot, M / Jy, q]
        if with_position:
            rates += [ub * ops.cos(theta) + wb * ops.sin(theta),
                      ub * ops.sin(theta) - wb * ops.cos(theta)]
        return ops.vertcat(*rates)
    phi, pr, rr, beta = lateral
    Jx, Jz, Jxz = inertias
    sin_phi, cos_phi = ops.sin(phi), ops.cos(phi)
    q_dot = (M + (Jz - Jx) * pr * rr + Jxz * (rr**2 - pr**2)) / Jy
    rates = [u_dot, w_dot, q_dot, q * cos_phi - rr * sin_phi]
    if with_position:
        v = side_velocity(x, beta, ops)
        sin_t, cos_t = ops.sin(theta), ops.cos(theta)
        rates += [ub * cos_t + (v * sin_phi + wb * cos_phi) * sin_t,
                  ub * sin_t - (v * sin_phi + wb * cos_phi) * cos_t]
    return ops.vertcat(*rates)


def body_forces(structure: ModelStructure, x, u, p, ops=CASADI_OPS,
                with_position: bool = False):
    """``(X, Z, M, alpha, V, thrust)`` of a structure's airframe kind at the effective
    (actuator-side) controls ``u``."""
    if structure.kind == "fixed_wing":
        return fixed_wing_forces(x, u, p, ops, structure.alpha_dot, structure, with_position)
    return multirotor_forces(x, u, p, ops, structure, with_position)


def make_rhs(kind: str | ModelStructure, with_position: bool = False, ops=CASADI_OPS,
             alpha_dot: bool | None = None):
    """``rhs(x, u, p) -> x_dot`` of the rigid body, evaluated with ``ops`` (feature-first), at
    the effective (actuator-side) controls ``u``. ``kind`` is a kind name or a
    :class:`ModelStructure`; ``alpha_dot=False`` builds the fixed wing without its (then zero)
    alpha-dot terms."""
    structure = as_structure(kind, alpha_dot)
    names = param_names(structure.kind)
    i_mass, i_jy, i_g = (names.index(n) for n in ("mass", "Jy", "gravity"))

    if not structure.lateral:
        def rhs(x, u, p):
            X, Z, M = body_forces(structure, x, u, p, ops, with_position)[:3]
            return rigid_body_rates(x, X, Z, M, p[i_mass], p[i_jy], p[i_g], with_position, ops)

        return rhs
    i_j = structure.lateral_param_indices

    def rhs_lateral(x, u, p):
        X, Z, M = body_forces(structure, x, u, p, ops, with_position)[:3]
        return rigid_body_rates(x, X, Z, M, p[i_mass], p[i_jy], p[i_g], with_position, ops,
                                lateral_inputs(structure, u), tuple(p[i] for i in i_j))

    return rhs_lateral
