"""Build the CasADi Functions of an airframe's model: ``f(x, u, p) -> x_dot``, forces, alpha_dot
and Jacobians, with the parameters kept symbolic (input ``p``)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import casadi as ca
import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.model.atmosphere import isa_density_ratio
from uavdyn.model.equations import (
    FORCE_NAMES,
    as_structure,
    body_forces,
    fixed_wing_alpha_dot,
    make_rhs,
)
from uavdyn.model.ops import NUMPY_OPS
from uavdyn.model.structure import ALPHA_DOT_KEYS, ModelStructure, structure_of

__all__ = ["ALPHA_DOT_KEYS", "LongitudinalModel", "build_model", "numpy_rhs", "sortie_params",
           "uses_alpha_dot"]


@dataclass(frozen=True)
class LongitudinalModel:
    """CasADi Functions of one model structure; parameters stay symbolic (input ``p``).

    ``f`` is the rigid body at the effective (actuator-side) controls; actuator lags and delays
    are added by the discrete step (:func:`uavdyn.integrate.physics_step`)."""

    structure: ModelStructure
    with_position: bool
    f: ca.Function
    forces: ca.Function
    jacobians: ca.Function
    alpha_dot: ca.Function | None = None  # (x, u, p) -> alpha_dot (rad/s), exact

    @property
    def kind(self) -> str:
        return self.structure.kind

    @property
    def state_names(self) -> tuple[str, ...]:
        return self.structure.body_state_names(self.with_position)

    @property
    def control_names(self) -> tuple[str, ...]:
        return self.structure.control_names

    @property
    def param_names(self) -> tuple[str, ...]:
        return self.structure.param_names

    @property
    def nx(self) -> int:
        return len(self.state_names)

    @property
    def nu(self) -> int:
        return self.structure.nu

    @property
    def np(self) -> int:
        return len(self.param_names)


def uses_alpha_dot(airframe: Airframe) -> bool:
    """Whether a fixed wing sets any alpha-dot key (the model then carries those terms)."""
    return airframe.kind == "fixed_wing" and any(
        getattr(airframe.params, k, 0.0) != 0.0 for k in ALPHA_DOT_KEYS)


def build_model(kind: str | Airframe | ModelStructure, with_position: bool = False,
                alpha_dot: bool | None = None) -> LongitudinalModel:
    """Build (once per structure, then cached) the symbolic model.

    Parameters
    ----------
    kind : str, Airframe or ModelStructure
        A kind name (fixed wing: with the alpha-dot terms), an airframe (its values decide the
        structure: tables, alpha-dot terms, atmosphere) or a structure.
    with_position : bool
        Append the ``[x_n, h]`` states.
    alpha_dot : bool, optional
        Override whether the fixed-wing alpha-dot terms are carried. Without them the graph is
        smaller; with keys at 0 the numbers are the same either way.
    """
    if isinstance(kind, Airframe):
        kind = structure_of(kind)
    return _build_model(as_structure(kind, alpha_dot), bool(with_position))


@cache
def _build_model(structure: ModelStructure, with_position: bool) -> LongitudinalModel:
    nx = 6 if with_position else 4
    x = ca.SX.sym("x", nx)
    u = ca.SX.sym("u", structure.nu)
    p = ca.SX.sym("p", structure.np)
    X, Z, M, alpha, V, thrust = body_forces(structure, x, u, p, with_position=with_position)
    xdot = make_rhs(structure, with_position)(x, u, p)
    f = ca.Function("f", [x, u, p], [xdot], ["x", "u", "p"], ["xdot"])
    forces = ca.Function("forces", [x, u, p], [X, Z, M, alpha, V, thrust], ["x", "u", "p"],
                         list(FORCE_NAMES))
    if structure.kind == "fixed_wing" and structure.alpha_dot:  # the closed form they use
        alpha_rate = fixed_wing_alpha_dot(x, u, p, structure=structure,
                                          with_position=with_position)
    else:  # kinematics of alpha = atan2(w, u)
        alpha_rate = (x[0] * xdot[1] - x[1] * xdot[0]) / (x[0] ** 2 + x[1] ** 2)
    alpha_rate_fn = ca.Function("alpha_dot", [x, u, p], [alpha_rate], ["x", "u", "p"],
                                ["alpha_dot"])
    jac = ca.Function(
        "jacobians", [x, u, p],
        [ca.jacobian(xdot, x), ca.jacobian(xdot, u), ca.jacobian(xdot, p)],
        ["x", "u", "p"], ["A", "B", "dfdp"],
    )
    return LongitudinalModel(structure=structure, with_position=with_position, f=f,
                             forces=forces, jacobians=jac, alpha_dot=alpha_rate_fn)


def numpy_rhs(kind: str | ModelStructure, with_position: bool = False):
    """The same equations evaluated with plain NumPy: ``rhs(x, u, p) -> x_dot`` (arrays)."""
    return make_rhs(kind, with_position, NUMPY_OPS)


def sortie_params(airframe: Airframe, altitude_m: float | None = None) -> np.ndarray:
    """The parameter vector for one sortie: ``airframe.p``, with ``atmosphere = "isa"`` its
    density scaled to the sortie's altitude (manifest ``altitude_m``; None: sea level)."""
    p = airframe.p
    if airframe.atmosphere == "isa" and altitude_m is not None:
        i = airframe.param_names.index("rho")
        p[i] = p[i] * float(isa_density_ratio(float(altitude_m), NUMPY_OPS))
    return p
