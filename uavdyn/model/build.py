"""Build the CasADi Functions of an airframe kind: ``f(x, u, p) -> x_dot``, forces and
Jacobians, with the parameters kept symbolic (input ``p``)."""

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


def build_model(kind: str | Airframe, with_position: bool = False) -> LongitudinalModel:
    """Build (once, then cached) the symbolic model of an airframe kind."""
    if isinstance(kind, Airframe):
        kind = kind.kind
    return _build_model(kind, bool(with_position))


@cache
def _build_model(kind: str, with_position: bool) -> LongitudinalModel:
    names = param_names(kind)  # validates kind
    nx = 6 if with_position else 4
    x = ca.SX.sym("x", nx)
    u = ca.SX.sym("u", 2)
    p = ca.SX.sym("p", len(names))
    X, Z, M, alpha, V, thrust = FORCE_MODELS[kind](x, u, p)
    xdot = make_rhs(kind, with_position)(x, u, p)
    f = ca.Function("f", [x, u, p], [xdot], ["x", "u", "p"], ["xdot"])
    forces = ca.Function("forces", [x, u, p], [X, Z, M, alpha, V, thrust], ["x", "u", "p"],
                         list(FORCE_NAMES))
    jac = ca.Function(
        "jacobians", [x, u, p],
        [ca.jacobian(xdot, x), ca.jacobian(xdot, u), ca.jacobian(xdot, p)],
        ["x", "u", "p"], ["A", "B", "dfdp"],
    )
    return LongitudinalModel(kind=kind, with_position=with_position, f=f, forces=forces,
                             jacobians=jac)


def numpy_rhs(kind: str, with_position: bool = False):
    """The same equations evaluated with plain NumPy: ``rhs(x, u, p) -> x_dot`` (arrays)."""
    return make_rhs(kind, with_position, NUMPY_OPS)
