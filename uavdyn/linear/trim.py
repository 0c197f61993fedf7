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
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache, lru_cache

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


def static_lift_coefficient(airframe: Airframe, alphas, airspeed, p: np.ndarray | None = None
                            ) -> np.ndarray:
    """The model's static lift coefficient (elevator 0, no pitch rate, no alpha-dot) at each
    angle of attack, from its own forces (a ``C_L`` table where the airframe has one):
    ``C_L = ((X - T) sin(alpha) - Z cos(alpha)) / (qbar S)``, evaluated with NumPy.

    ``p`` may hold one parameter vector per column (``np x m``, ``airspeed`` one per column):
    the result is then ``len(alphas) x m``, each column that airframe's curve (every operation
    is element-wise)."""
    structure = dataclasses.replace(body_structure(airframe), alpha_dot=False)
    p = airframe.p if p is None else np.asarray(p, float)
    alphas = np.asarray(alphas, float)
    if p.ndim == 2:
        alphas = alphas[:, None]
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
    speed at which its own maximum holds the weight (fixed-point iteration); any other lift
    curve does not depend on the airspeed and is evaluated once."""
    return tuple(float(v) for v in stall_speeds([airframe], n_grid, altitude_m)[0])


def stall_speeds(airframes: Sequence[Airframe], n_grid: int = 2001,
                 altitude_m: float | None = None) -> np.ndarray:
    """:func:`stall_speed` of many fixed wings of one structure (a Monte-Carlo chunk's dispersed
    airframes), their lift curves evaluated side by side: ``len(airframes) x 3`` rows of
    ``(stall speed, alpha at C_L max, C_L max)``, each the same iteration as one airframe's.

    Raises
    ------
    ValueError
        If the airframes differ in structure (kind, tables, atmosphere).
    """
    if not airframes:
        return np.empty((0, 3))
    first = airframes[0]
    structure = body_structure(first)
    if any(body_structure(a) != structure for a in airframes[1:]):
        raise ValueError("stall_speeds needs airframes of one structure (kind, tables, "
                         "atmosphere); call it once per structure")
    p = np.column_stack([sortie_params(a, altitude_m) for a in airframes])
    names = first.param_names
    rho, S = p[names.index("rho")], p[names.index("S_wing")]
    i_mass, i_g = names.index("mass"), names.index("gravity")
    alphas = np.linspace(0.0, 1.2, n_grid)
    V = np.array([a.nominal_airspeed or 20.0 for a in airframes])
    out = np.empty((len(airframes), 3))
    active = np.arange(len(airframes))  # columns still iterating
    lift_table = structure.table_slices().get("C_L")
    iterations = 100 if lift_table and any(name == "airspeed" for name, _ in lift_table[0]) \
        else 1
    for _ in range(iterations):
        cl = static_lift_coefficient(first, alphas, V[active], p[:, active])
        i = np.argmax(cl, axis=0)
        cl_max = cl[i, np.arange(len(active))]
        v_stall = np.sqrt(2 * p[i_mass, active] * p[i_g, active]
                          / (rho[active] * S[active] * cl_max))
        out[active] = np.column_stack([v_stall, alphas[i], cl_max])
        done = np.abs(v_stall - V[active]) <= 1e-12 * V[active]
        V[active] = v_stall
        active = active[~done]
        if not active.size:
            break
    return out


def _initial_guess(airframe: Airframe, V: float, gamma: float, rho: float) -> np.ndarray:
    P = airframe.params
    if airframe.kind == "fixed_wing":
        cl = P.mass * P.gravity * math.cos(gamma) / (0.5 * rho * V**2 * P.S_wing)
        alpha = (cl - P.C_L_0) / P.C_L_alpha
        elevator = -(P.C_m_0 + P.C_m_alpha * alpha) / P.C_m_delta_e
        return np.array([alpha, elevator, 0.7])
    omega = math.sqrt(P.mass * P.gravity / (4 * P.c_T))
    return np.array([-0.05 if V > 0 else 0.0, (omega - P.omega_b) / P.C_R, 0.0])


def step_inputs(airframe: Airframe, u) -> np.ndarray:
    """A trim command as the input of ``airframe``'s step: with lateral inputs (turning
    flight) the controls followed by ``phi = p = r = beta = 0`` (trims are wings level)."""
    u = np.asarray(u, float).ravel()
    return np.concatenate([u, np.zeros(4)]) if airframe.lateral and u.size == 2 else u


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
    outcome = trim_many([airframe], [airspeed], gamma, altitude_m)[0]
    if isinstance(outcome, TrimError):
        raise outcome
    return outcome


def trim_many(airframes: Sequence[Airframe], airspeeds: Sequence[float | None],
              gamma: float = 0.0, altitude_m: float | None = None
              ) -> list[TrimPoint | TrimError]:
    """:func:`trim` of many airframes (a Monte-Carlo chunk's dispersed airframes), the stall
    curves and Newton solves of one structure evaluated together: per airframe its trim point
    or the :class:`TrimError` that :func:`trim` would raise, the same numbers as one by one.

    Parameters
    ----------
    airframes : sequence of Airframe
        The airframes (any mix of structures: each structure is solved in one call).
    airspeeds : sequence of float or None
        One airspeed per airframe (m/s; None: its nominal airspeed).
    gamma, altitude_m :
        As for :func:`trim`, shared.
    """
    if len(airspeeds) != len(airframes):
        raise ValueError(f"{len(airspeeds)} airspeeds for {len(airframes)} airframes")
    # trims are wings level: an airframe taking lateral inputs is trimmed with them at zero
    airframes = [a.for_inputs(False) for a in airframes]
    outcomes: list[TrimPoint | TrimError | None] = [None] * len(airframes)
    speeds = np.zeros(len(airframes))
    groups: dict[ModelStructure, list[int]] = {}
    for j, (airframe, airspeed) in enumerate(zip(airframes, airspeeds)):
        try:
            speeds[j] = _checked_request(airframe, airspeed, gamma, altitude_m)
        except TrimError as exc:
            outcomes[j] = exc
            continue
        groups.setdefault(body_structure(airframe), []).append(j)
    for structure, members in groups.items():
        found = _trim_group(structure, [airframes[j] for j in members], speeds[members], gamma,
                            altitude_m)
        for j, outcome in zip(members, found):
            outcomes[j] = outcome
    return outcomes


def _checked_request(airframe: Airframe, airspeed: float | None, gamma: float,
                     altitude_m: float | None) -> float:
    """The airspeed of a well-formed request (TrimError for one no airframe can fly)."""
    V = airframe.nominal_airspeed if airspeed is None else float(airspeed)
    if not math.isfinite(V) or V < 0:
        raise TrimError(f"airspeed must be a finite number >= 0, got {airspeed}")
    if altitude_m is not None and not math.isfinite(altitude_m):
        raise TrimError(f"altitude must be a finite number of metres, got {altitude_m}")
    if not math.isfinite(gamma) or abs(gamma) >= math.pi / 2:
        raise TrimError(f"flight-path angle gamma must be in (-90, 90) deg, got {gamma} rad")
    if airframe.kind == "fixed_wing" and V <= 0:
        raise TrimError("a fixed wing cannot trim at zero airspeed")
    if airframe.kind != "fixed_wing" and gamma != 0.0 and V == 0.0:
        raise TrimError("hover has no flight-path angle: use gamma = 0 with airspeed 0")
    return V


def _trim_group(structure: ModelStructure, airframes: list[Airframe], speeds: np.ndarray,
                gamma: float, altitude_m: float | None) -> list[TrimPoint | TrimError]:
    """Trim airframes of one body structure: stall limits, then one mapped Newton solve."""
    outcomes: list[TrimPoint | TrimError | None] = [None] * len(airframes)
    alpha_max: list[float | None] = [None] * len(airframes)
    solve: list[int] = []
    stall = stall_speeds(airframes, altitude_m=altitude_m) \
        if structure.kind == "fixed_wing" else None
    for k, airframe in enumerate(airframes):
        try:
            if stall is not None:
                v_stall, alpha_max[k], cl_max = (float(v) for v in stall[k])
                needed = v_stall * math.sqrt(math.cos(gamma))
                if speeds[k] < needed:
                    raise TrimError(
                        f"airspeed {speeds[k]:g} m/s is below the stall speed {needed:.2f} "
                        f"m/s (C_L max {cl_max:.3f} at alpha "
                        f"{math.degrees(alpha_max[k]):.1f} deg)")
            if not has_pitch_authority(airframe):
                which = "pitch_mix" if airframe.kind == "multirotor" else "C_m_delta_e"
                raise TrimError(
                    f"airframe '{airframe.name}': parameter '{which}' = 0 gives the pitch "
                    "command no authority over the pitching moment; nothing can hold a trim "
                    "(check the file)")
        except TrimError as exc:
            outcomes[k] = exc
            continue
        solve.append(k)
    if not solve:
        return outcomes
    p = np.column_stack([sortie_params(airframes[k], altitude_m) for k in solve])
    pars = np.vstack([speeds[solve], np.full(len(solve), gamma), p])
    rho = p[airframes[0].param_names.index("rho")]
    guess = np.column_stack([_initial_guess(airframes[k], speeds[k], gamma, float(rho[i]))
                             for i, k in enumerate(solve)])
    g, solver = _mapped_trim_functions(structure, len(solve))
    z = np.array(solver(guess, pars)).reshape(3, len(solve))
    residuals = np.max(np.abs(np.array(g(z, pars)).reshape(3, len(solve))), axis=0)
    for i, k in enumerate(solve):
        try:
            outcomes[k] = _point(airframes[k], speeds[k], gamma, altitude_m, z[:, i],
                                          float(residuals[i]), alpha_max[k])
        except TrimError as exc:
            outcomes[k] = exc
    return outcomes


@lru_cache(maxsize=32)
def _mapped_trim_functions(structure: ModelStructure, n: int
                           ) -> tuple[ca.Function, ca.Function]:
    """:func:`_trim_functions` over ``n`` columns (each column the single call's numbers)."""
    g, solver = _trim_functions(structure)
    return (g, solver) if n == 1 else (g.map(n), solver.map(n))


def _point(airframe: Airframe, V: float, gamma: float, altitude_m: float | None,
           z: np.ndarray, residual: float, alpha_max: float | None) -> TrimPoint:
    """The trim point of a Newton solution, or TrimError for one outside the envelope."""
    names = CONTROL_NAMES[airframe.kind]
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
    return TrimPoint(airframe=airframe.name, kind=airframe.kind, airspeed=float(V),
                     gamma=float(gamma), x=x, u=np.array(z[1:], float), residual=residual,
                     altitude_m=None if altitude_m is None else float(altitude_m))
