"""Build the CasADi Functions of an airframe kind: ``f(x, u, p) -> x_dot``, forces, alpha_dot
and Jacobians, with the parameters kept symbolic (input ``p``)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import casadi as ca

from uavdyn.airframes import Airframe, param_names
from uavdyn.model.equations import (
    CONTROL_NAMES,
    FORCE_MODELS,
    FORCE_NAMES,
    POSITION_STATE_NAMES,
    STATE_NAMES,
    fixed_wing_alpha_dot,
    fixed_wing_forces,
    make_rhs,
)
from uavdyn.model.ops import NUMPY_OPS


@dataclass(frozen=True)
class LongitudinalModel:
    """CasADi Functions of one airframe kind; parameters stay symbolic (input ``p``)."""

    kind: str
    with_position: bool
    f: ca.Function
    forces: ca.Function
    jacobians: ca.Function
    alpha_dot: ca.Function | None = None  # (x, u, p) -> alpha_dot (rad/s), exact

    @property
    def state_names(self) -> tuple[str, ...]:
        return STATE_NAMES + (POSITION_STATE_NAMES if self.with_position else ())

    @property
    def control_names(self) -> tuple[str, ...]:
        return CONTROL_NAMES[self.kind]

    @property
    def param_names(self) -> tuple[str, ...]:
        return param_names(self.kind)

    @property
    def nx(self) -> int:
        return len(self.state_names)

    @property
    def nu(self) -> int:
        return 2

    @property
    def np(self) -> int:
        return len(self.param_names)


ALPHA_DOT_KEYS = ("C_L_alpha_dot", "C_m_alpha_dot")


def uses_alpha_dot(airframe: Airframe) -> bool:
    """Whether a fixed wing sets any alpha-dot key (the model then carries those terms)."""
    return airframe.kind == "fixed_wing" and any(
        getattr(airframe.params, k, 0.0) != 0.0 for k in ALPHA_DOT_KEYS)


def build_model(kind: str | Airframe, with_position: bool = False,
                alpha_dot: bool | None = None) -> LongitudinalModel:
    """Build (once, then cached) the symbolic model of an airframe kind.

    Parameters
    ----------
    kind : str or Airframe
        The kind, or an airframe (then its alpha-dot keys decide ``alpha_dot``).
    with_position : bool
        Append the ``[x_n, h]`` states.
    alpha_dot : bool, optional
        Carry the fixed-wing alpha-dot terms (default: for an airframe, whether it sets them;
        for a kind, yes). Without them the graph is smaller; with keys at 0 the numbers are
        the same either way.
    """
    if isinstance(kind, Airframe):
        alpha_dot = uses_alpha_dot(kind) if alpha_dot is None else alpha_dot
        kind = kind.kind
    alpha_dot = (kind == "fixed_wing") and (True if alpha_dot is None else bool(alpha_dot))
    return _build_model(kind, bool(with_position), alpha_dot)


@cache
def _build_model(kind: str, with_position: bool, alpha_dot: bool) -> LongitudinalModel:
    names = param_names(kind)  # validates kind
    nx = 6 if with_position else 4
    x = ca.SX.sym("x", nx)
    u = ca.SX.sym("u", 2)
    p = ca.SX.sym("p", len(names))
    forces_of = FORCE_MODELS[kind]
    if kind == "fixed_wing":
        X, Z, M, alpha, V, thrust = fixed_wing_forces(x, u, p, alpha_dot=alpha_dot)
    else:
        X, Z, M, alpha, V, thrust = forces_of(x, u, p)
    xdot = make_rhs(kind, with_position, alpha_dot=alpha_dot)(x, u, p)
    f = ca.Function("f", [x, u, p], [xdot], ["x", "u", "p"], ["xdot"])
    forces = ca.Function("forces", [x, u, p], [X, Z, M, alpha, V, thrust], ["x", "u", "p"],
                         list(FORCE_NAMES))
    if kind == "fixed_wing" and alpha_dot:  # the closed form the alpha-dot terms use
        alpha_rate = fixed_wing_alpha_dot(x, u, p)
    else:  # kinematics of alpha = atan2(w, u)
        alpha_rate = (x[0] * xdot[1] - x[1] * xdot[0]) / (x[0] ** 2 + x[1] ** 2)
    alpha_rate_fn = ca.Function("alpha_dot", [x, u, p], [alpha_rate], ["x", "u", "p"],
                                ["alpha_dot"])
    jac = ca.Function(
        "jacobians", [x, u, p],
        [ca.jacobian(xdot, x), ca.jacobian(xdot, u), ca.jacobian(xdot, p)],
        ["x", "u", "p"], ["A", "B", "dfdp"],
    )
    return LongitudinalModel(kind=kind, with_position=with_position, f=f, forces=forces,
                             jacobians=jac, alpha_dot=alpha_rate_fn)


def numpy_rhs(kind: str, with_position: bool = False):
    """The same equations evaluated with plain NumPy: ``rhs(x, u, p) -> x_dot`` (arrays)."""
    return make_rhs(kind, with_position, NUMPY_OPS)
