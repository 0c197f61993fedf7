"""Parameter dataclasses of each airframe kind: the names and order of the parameter vector."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, fields
from typing import Union

from uavdyn.airframes.errors import AirframeError, _short

KINDS = ("fixed_wing", "multirotor")


@dataclass(frozen=True)
class FixedWingParams:
    """Longitudinal parameters of a fixed-wing aircraft (SI units, radians)."""

    mass: float
    Jy: float
    S_wing: float
    b: float
    c: float
    rho: float
    e: float
    gravity: float
    C_L_0: float
    C_L_alpha: float
    C_L_alpha2: float
    C_L_q: float
    C_L_delta_e: float
    C_D_0: float
    C_D_q: float
    C_D_delta_e: float
    C_m_0: float
    C_m_alpha: float
    C_m_q: float
    C_m_delta_e: float
    M_blend: float
    alpha0: float
    D_prop: float
    KV_rpm_per_volt: float
    R_motor: float
    i0: float
    V_max: float
    C_Q2: float
    C_Q1: float
    C_Q0: float
    C_T2: float
    C_T1: float
    C_T0: float
    # Optional (default = absent = no effect); see OPTIONAL_PARAMS.
    C_L_alpha_dot: float = 0.0
    C_m_alpha_dot: float = 0.0
    tau_elevator: float = 0.0
    tau_throttle: float = 0.0
    slew_elevator: float = 0.0
    slew_throttle: float = 0.0
    eta_slipstream: float = 0.0
    C_D_Re: float = 0.0
    C_m_Re: float = 0.0
    # Turning-flight inertias (kg m^2): read only with lateral inputs; see LATERAL_PARAMS.
    Jx: float = 0.0
    Jz: float = 0.0
    Jxz: float = 0.0


@dataclass(frozen=True)
class MultirotorParams:
    """Pitch-plane parameters of an X-frame quadrotor (SI units, radians)."""

    mass: float
    Jy: float
    arm: float
    c_T: float
    C_R: float
    omega_b: float
    rho: float
    gravity: float
    CdA_x: float
    CdA_z: float
    drag_linear: float
    pitch_damping: float
    pitch_mix: float
    # Optional (default = absent = no effect); see OPTIONAL_PARAMS.
    tau_rotor: float = 0.0
    k_inflow: float = 0.0
    M_u: float = 0.0
    M_0: float = 0.0
    # Turning-flight inertias (kg m^2): read only with lateral inputs; see LATERAL_PARAMS.
    Jx: float = 0.0
    Jz: float = 0.0
    Jxz: float = 0.0


ParamsType = Union[FixedWingParams, MultirotorParams]  # noqa: UP007 (runtime alias, py3.10)
PARAM_CLASSES: dict[str, type] = {"fixed_wing": FixedWingParams, "multirotor": MultirotorParams}

# The roll/yaw inertias the turning-flight terms need (SPEC section 2, lateral inputs): optional
# keys of every kind, outside ``p`` (and the hash) unless the model takes lateral inputs, where
# they follow the table values (:attr:`uavdyn.airframes.Airframe.param_names`).
LATERAL_PARAMS = ("Jx", "Jz", "Jxz")

# Optional parameters per kind and their defaults: the dataclass fields that have a default. A
# file may leave them out; at their default they change nothing (see Airframe.param_hash).
OPTIONAL_PARAMS: dict[str, dict[str, float]] = {
    kind: {f.name: f.default for f in fields(cls)
           if f.default is not dataclasses.MISSING and f.name not in LATERAL_PARAMS}
    for kind, cls in PARAM_CLASSES.items()}


_PARAM_NAMES = {kind: tuple(f.name for f in fields(cls) if f.name not in LATERAL_PARAMS)
                for kind, cls in PARAM_CLASSES.items()}


def param_names(kind: str) -> tuple[str, ...]:
    """Names of the parameter vector ``p`` for an airframe kind, in order."""
    if not isinstance(kind, str) or kind not in PARAM_CLASSES:
        raise AirframeError(f"unknown airframe kind {_short(kind)}; expected one of {KINDS}")
    return _PARAM_NAMES[kind]
