"""Trim: the state and controls for steady flight (level or climbing at an airspeed, hover or
constant-speed forward flight), solved with a CasADi Newton rootfinder.

Both kinds share one parameterisation: unknowns ``z = [alpha, u1, u2]`` with
``x = [V cos(alpha), V sin(alpha), 0, alpha + gamma]``, residual ``[u_dot, w_dot, q_dot] = 0``.
An infeasible request (below stall, beyond the thrust or control limits: the airframe's own
``[limits]`` where its file sets them, else the kind's physical range) raises
:class:`TrimError` saying which limit and by how much.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache

import casadi as ca
import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.model import CONTROL_NAMES, NUMPY_OPS, build_model, stall_blend

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

    @property
    def alpha(self) -> float:
        return math.atan2(self.x[1], self.x[0]) if self.airspeed > 0 else 0.0

    def as_dict(self) -> dict:
        names = ("u", "w", "q", "theta")
        out = {"airframe": self.airframe, "airspeed_mps": self.airspeed,
               "gamma_rad": self.gamma, "alpha_rad": self.alpha, "residual": self.residual}
        out.update({n: float(v) for n, v in zip(names, self.x)})
        out.update({n: float(v) for n, v in zip(CONTROL_NAMES[self.kind], self.u)})
        return out


@cache
def _trim_functions(kind: str) -> tuple[ca.Function, ca.Function]:
    model = build_model(kind)
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


def stall_speed(airframe: Airframe, n_grid: int = 2001) -> tuple[float, float, float]:
    """Level-flight stall speed (m/s) from the maximum of the static lift curve, with the
    angle of attack (rad) and lift coefficient at that maximum."""
    P = airframe.params
    alphas = np.linspace(0.0, 1.2, n_grid)

    sigma = stall_blend(alphas, P.M_blend, P.alpha0, NUMPY_OPS)
    cl = ((1 - sigma) * (P.C_L_0 + P.C_L_alpha * alphas + P.C_L_alpha2 * alphas**2)
          + sigma * 2 * np.sin(alphas) ** 2 * np.cos(alphas))
    i = int(np.argmax(cl))
    v_stall = math.sqrt(2 * P.mass * P.gravity / (P.rho * P.S_wing * cl[i]))
    return v_stall, float(alphas[i]), float(cl[i])


def _initial_guess(airframe: Airframe, V: float, gamma: float) -> np.ndarray:
    P = airframe.params
    if airframe.kind == "fixed_wing":
        cl = P.mass * P.gravity * math.cos(gamma) / (0.5 * P.rho * V**2 * P.S_wing)
        alpha = (cl - P.C_L_0) / P.C_L_alpha
        elevator = -(P.C_m_0 + P.C_m_alpha * alpha) / P.C_m_delta_e
        return np.array([alpha, elevator, 0.7])
    omega = math.sqrt(P.mass * P.gravity / (4 * P.c_T))
    return np.array([-0.05 if V > 0 else 0.0, (omega - P.omega_b) / P.C_R, 0.0])


def trim(airframe: Airframe, airspeed: float | None = None, gamma: float = 0.0) -> TrimPoint:
    """Trim ``airframe`` at ``airspeed`` (m/s; default its nominal speed) and flight-path angle
    ``gamma`` (rad, climb positive). Quadrotor: airspeed 0 is hover."""
    V = airframe.nominal_airspeed if airspeed is None else float(airspeed)
    if not math.isfinite(V) or V < 0:
        raise TrimError(f"airspeed must be a finite number >= 0, got {airspeed}")
    if not math.isfinite(gamma) or abs(gamma) >= math.pi / 2:
        raise TrimError(f"flight-path angle gamma must be in (-90, 90) deg, got {gamma} rad")
    names = CONTROL_NAMES[airframe.kind]
    alpha_max = None
    if airframe.kind == "fixed_wing":
        if V <= 0:
            raise TrimError("a fixed wing cannot trim at zero airspeed")
        v_stall, alpha_max, cl_max = stall_speed(airframe)
        needed = v_stall * math.sqrt(math.cos(gamma))
        if V < needed:
            raise TrimError(
                f"airspeed {V:g} m/s is below the stall speed {needed:.2f} m/s "
                f"(C_L max {cl_max:.3f} at alpha {math.degrees(alpha_max):.1f} deg)")
    elif gamma != 0.0 and V == 0.0:
        raise TrimError("hover has no flight-path angle: use gamma = 0 with airspeed 0")
    g, solver = _trim_functions(airframe.kind)
    pars = np.concatenate([[V, gamma], airframe.p])
    z = np.array(solver(_initial_guess(airframe, V, gamma), pars)).ravel()
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
                     x=x, u=z[1:].copy(), residual=residual)
