"""Trim: the state and controls for steady flight (level or climbing at an airspeed, hover or
constant-speed forward flight), solved with a CasADi Newton rootfinder.

Both kinds share one parameterisation: unknowns ``z = [alpha, u1, u2]`` with
``x = [V cos(alpha), V sin(alpha), 0, alpha + gamma]``, residual ``[u_dot, w_dot, q_dot] = 0``.
An infeasible request (below stall, beyond the thrust or control limits: the airframe's own
``[limits]`` where its file sets them, else the kind's physical range) raises
:class:`TrimError` saying which limit and by how much.

The residual is the airframe's own model (its structure: breakpoint tables, alpha-dot terms,
atmosphere; ``altitude_m`` scales an ISA airframe's density). In steady flight every actuator
sits at its command and every delay buffer is full of it: :func:`trim_state` is the augmented
state of the discrete step (:func:`uavdyn.integrate.physics_step`) at a trim point.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import cache

import casadi as ca
import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.airframes.plausibility import has_pitch_authority
from uavdyn.integrate import StateLayout
from uavdyn.model import (
    CONTROL_NAMES,
    NUMPY_OPS,
    ModelStructure,
    body_forces,
    build_model,
    sortie_params,
    structure_of,
)

RESIDUAL_TOL = 1e-9


class TrimError(ValueError):
    """No steady flight exists for the request; the message says why."""


@dataclass(frozen=True)
class TrimPoint:
    """A trimmed flight condition."""

    airframe: str
    kind: str
    airspeed: float
    gamma: float
    x: np.ndarray
    u: np.ndarray
    residual: float
    altitude_m: float | None = None  # the ISA altitude it was trimmed at (None: sea level)

    @property
    def alpha(self) -> float:
        return math.atan2(self.x[1], self.x[0]) if self.airspeed > 0 else 0.0

    def as_dict(self) -> dict:
        names = ("u", "w", "q", "theta")
        out = {"airframe": self.airframe, "airspeed_mps": self.airspeed,
               "gamma_rad": self.gamma, "alpha_rad": self.alpha, "residual": self.residual}
        out.update({n: float(v) for n, v in zip(names, self.x)})
        out.update({n: float(v) for n, v in zip(CONTROL_NAMES[self.kind], self.u)})
        if self.altitude_m is not None:
            out["altitude_m"] = self.altitude_m
        return out


def point_params(airframe: Airframe, point: TrimPoint) -> np.ndarray:
    """The parameter vector a trim point was solved with (an ISA airframe's density at the
    point's altitude)."""
    return sortie_params(airframe, point.altitude_m)


def body_structure(airframe: Airframe | ModelStructure) -> ModelStructure:
    """An airframe's structure without its actuator lags and delays: the rigid body's model,
    shared by every airframe that differs only in those."""
    structure = (airframe if isinstance(airframe, ModelStructure) else structure_of(airframe))
    return dataclasses.replace(structure, lagged=(), slewed=(), delays=())


def trim_state(airframe: Airframe, point: TrimPoint, with_position: bool = False,
               fitting=(), memory_tau: tuple[float, ...] = ()) -> np.ndarray:
    """The augmented state of the discrete step at a trim point: the body state, then every
    actuator at its trim command and every delay buffer full of it (the step's layout:
    ``structure_of(airframe, fitting).state_names(with_position)``). Without lags and delays
    it is ``point.x`` (with position: ``x_n = 0`` and ``h`` the point's altitude or 0).

    Parameters
    ----------
    airframe : Airframe
        The trimmed airframe.
    point : TrimPoint
        Its trim point.
    with_position : bool
        Include the ``[x_n, h]`` states.
    fitting : sequence of str
        Parameters about to be identified (as for the step: their actuator states are kept).
    memory_tau : tuple of float
        Time constants of a learned correction's command memory: one state per time constant
        and command, appended at the trim command (at rest, like the actuators).
    """
    layout = StateLayout(structure_of(airframe, fitting), tuple(memory_tau), with_position)
    x = np.asarray(point.x, float)
    if with_position:
        x = np.concatenate([x, [0.0, point.altitude_m or 0.0]])
    return layout.states(x, point.u, point_params(airframe, point), 1.0)[0]


@cache
def _trim_functions(structure: ModelStructure) -> tuple[ca.Function, ca.Function]:
    """Residual and Newton solver of one body structure (built once per structure)."""
    model = build_model(structure)
    z = ca.SX.sym("z", 3)
    pars = ca.SX.sym("pars", 2 + model.np)  # V, gamma, p
    V, gamma, p = pars[0], pars[1], pars[2:]
    alpha = z[0]
    x = ca.vertcat(V * ca.cos(alpha), V * ca.sin(alpha), 0, alpha + gamma)
    residual = model.f(x, z[1:], p)[:3]
    g = ca.Function("trim_residual", [z, pars], [residual])
    solver = ca.rootfinder("trim_solver", "newton", g,
                           {"abstol": 1e-13, "max_iter": 100, "error_on_fail": False,
                            "show_eval_warnings": False})
    return g, solver


def static_lift_coefficient(airframe: Airframe, alphas, airspeed: float,
                            p: np.ndarray | None = None) -> np.ndarray:
    """The model's static lift coefficient (elevator 0, no pitch rate, no alpha-dot) at each
    angle of attack, from its own forces (a ``C_L`` table where the airframe has one):
    ``C_L = ((X - T) sin(alpha) - Z cos(alpha)) / (qbar S)``, evaluated with NumPy."""
    structure = dataclasses.replace(body_structure(airframe), alpha_dot=False)
    p = airframe.p if p is None else np.asarray(p, float)
    alphas = np.asarray(alphas, float)
    zeros = np.zeros_like(alphas)
    x = [airspeed * np.cos(alphas), airspeed * np.sin(alphas), zeros, zeros]
    X, Z, _, _, _, thrust = body_forces(structure, x, [0.0, 0.0], p, NUMPY_OPS)
    names = airframe.param_names
    rho, S = p[names.index("rho")], p[names.index("S_wing")]
    lift = (X - thrust) * np.sin(alphas) - Z * np.cos(alphas)
    return lift / (0.5 * rho * airspeed**2 * S)


def stall_speed(airframe: Airframe, n_grid: int = 2001, altitude_m: float | None = None
                ) -> tuple[float, float, float]:
    """Level-flight stall speed (m/s) from the maximum of the model's static lift curve
    (:func:`static_lift_coefficient`, over alpha in [0, 1.2] rad), with the angle of attack
    (rad) and lift coefficient at that maximum. A lift table over airspeed is solved for the
    speed at which its own maximum holds the weight (fixed-point iteration)."""
    P = airframe.params
    p = sortie_params(airframe, altitude_m)
    rho = p[airframe.param_names.index("rho")]
    alphas = np.linspace(0.0, 1.2, n_grid)
    V = airframe.nominal_airspeed or 20.0
    for _ in range(100):
        cl = static_lift_coefficient(airframe, alphas, V, p)
        i = int(np.argmax(cl))
        v_stall = math.sqrt(2 * P.mass * P.gravity / (rho * P.S_wing * cl[i]))
        if abs(v_stall - V) <= 1e-12 * V:
            break
        V = v_stall
    return v_stall, float(alphas[i]), float(cl[i])


def _initial_guess(airframe: Airframe, V: float, gamma: float, rho: float) -> np.ndarray:
    P = airframe.params
    if airframe.kind == "fixed_wing":
        cl = P.mass * P.gravity * math.cos(gamma) / (0.5 * rho * V**2 * P.S_wing)
        alpha = (cl - P.C_L_0) / P.C_L_alpha
        elevator = -(P.C_m_0 + P.C_m_alpha * alpha) / P.C_m_delta_e
        return np.array([alpha, elevator, 0.7])
    omega = math.sqrt(P.mass * P.gravity / (4 * P.c_T))
    return np.array([-0.05 if V > 0 else 0.0, (omega - P.omega_b) / P.C_R, 0.0])


def trim(airframe: Airframe, airspeed: float | None = None, gamma: float = 0.0,
         altitude_m: float | None = None) -> TrimPoint:
    """Trim ``airframe`` at ``airspeed`` (m/s; default its nominal speed) and flight-path angle
    ``gamma`` (rad, climb positive). Quadrotor: airspeed 0 is hover.

    Parameters
    ----------
    airframe : Airframe
        The airframe (its structure: tables, alpha-dot terms, atmosphere).
    airspeed : float, optional
        m/s (default the airframe's nominal airspeed).
    gamma : float
        Flight-path angle (rad).
    altitude_m : float, optional
        Altitude for an ``atmosphere = "isa"`` airframe (None: the sea-level ``rho``);
        recorded in the point.

    Raises
    ------
    TrimError
        If no steady flight exists (the message names the limit).
    """
    V = airframe.nominal_airspeed if airspeed is None else float(airspeed)
    if not math.isfinite(V) or V < 0:
        raise TrimError(f"airspeed must be a finite number >= 0, got {airspeed}")
    if altitude_m is not None and not math.isfinite(altitude_m):
        raise TrimError(f"altitude must be a finite number of metres, got {altitude_m}")
    if not math.isfinite(gamma) or abs(gamma) >= math.pi / 2:
        raise TrimError(f"flight-path angle gamma must be in (-90, 90) deg, got {gamma} rad")
    names = CONTROL_NAMES[airframe.kind]
    alpha_max = None
    if airframe.kind == "fixed_wing":
        if V <= 0:
            raise TrimError("a fixed wing cannot trim at zero airspeed")
        v_stall, alpha_max, cl_max = stall_speed(airframe, altitude_m=altitude_m)
        needed = v_stall * math.sqrt(math.cos(gamma))
        if V < needed:
            raise TrimError(
                f"airspeed {V:g} m/s is below the stall speed {needed:.2f} m/s "
                f"(C_L max {cl_max:.3f} at alpha {math.degrees(alpha_max):.1f} deg)")
    elif gamma != 0.0 and V == 0.0:
        raise TrimError("hover has no flight-path angle: use gamma = 0 with airspeed 0")
    if not has_pitch_authority(airframe):
        which = "pitch_mix" if airframe.kind == "multirotor" else "C_m_delta_e"
        raise TrimError(f"airframe '{airframe.name}': parameter '{which}' = 0 gives the pitch "
                        "command no authority over the pitching moment; nothing can hold a "
                        "trim (check the file)")
    p = sortie_params(airframe, altitude_m)
    g, solver = _trim_functions(body_structure(airframe))
    pars = np.concatenate([[V, gamma], p])
    guess = _initial_guess(airframe, V, gamma, float(p[airframe.param_names.index("rho")]))
    z = np.array(solver(guess, pars)).ravel()
    residual = float(np.max(np.abs(np.array(g(z, pars)))))
    if not np.all(np.isfinite(z)) or residual > RESIDUAL_TOL:
        raise TrimError(f"no trim found at airspeed {V:g} m/s, gamma {gamma:g} rad "
                        f"(Newton residual {residual:.2e}): the request is outside the envelope")
    alpha = float(z[0])
    if alpha_max is not None and alpha > alpha_max:
        raise TrimError(f"trim at {V:g} m/s needs alpha {math.degrees(alpha):.1f} deg, past the "
                        f"stall angle {math.degrees(alpha_max):.1f} deg")
    for i, (lo, hi) in enumerate(airframe.control_bounds()):  # the airframe's own [limits]
        value = float(z[1 + i])
        if value < lo - 1e-12 or value > hi + 1e-12:
            limit = "thrust limit" if names[i] in ("throttle", "collective") else "control limit"
            if names[i] in airframe.limits:
                limit += f": limits.{names[i]} of airframe '{airframe.name}'"
            raise TrimError(f"trim at {V:g} m/s, gamma {gamma:g} rad needs {names[i]} = "
                            f"{value:.4g}, outside [{lo:g}, {hi:g}] ({limit})")
    x = np.array([V * math.cos(alpha), V * math.sin(alpha), 0.0, alpha + gamma])
    return TrimPoint(airframe=airframe.name, kind=airframe.kind, airspeed=V, gamma=float(gamma),
                     x=x, u=z[1:].copy(), residual=residual,
                     altitude_m=None if altitude_m is None else float(altitude_m))
