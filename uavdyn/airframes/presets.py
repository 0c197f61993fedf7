"""The airframes shipped with the package, and the perturbed copies of robustness studies."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable

from uavdyn.airframes.airframe import Airframe
from uavdyn.airframes.errors import AirframeError

PRESETS = {"aerosonde": "aerosonde.toml", "f450": "f450.toml"}
ALIASES = {"fixed_wing": "aerosonde", "fixedwing": "aerosonde", "quadrotor": "f450",
           "multirotor": "f450"}

# What the +15 % robustness scenario perturbs: stability derivatives and mass terms.
PERTURBATION_KEYS: dict[str, tuple[str, ...]] = {
    "fixed_wing": (
        "mass", "Jy", "C_L_alpha", "C_L_q", "C_L_delta_e", "C_m_alpha", "C_m_q", "C_m_delta_e",
        "C_L_alpha_dot", "C_m_alpha_dot",  # 0 in the presets, so 0 after scaling
    ),
    "multirotor": ("mass", "Jy", "drag_linear", "pitch_damping", "c_T"),
}


def list_presets() -> list[str]:
    """Names of the airframes shipped with the package."""
    return sorted(PRESETS)


def perturb(airframe: Airframe, scale: float = 1.15,
            names: Iterable[str] | None = None) -> Airframe:
    """Scale parameters (default: the kind's stability derivatives and mass terms) by ``scale``;
    the paper's robustness scenario is ``scale=1.15``."""
    chosen = tuple(names) if names is not None else PERTURBATION_KEYS[airframe.kind]
    unknown = [n for n in chosen if n not in airframe.param_names]
    if unknown:
        raise AirframeError(f"perturb: unknown parameter(s) {unknown} for kind '{airframe.kind}'")
    values = dict(zip(airframe.param_names, airframe.p))
    new = airframe.replace(**{n: values[n] * scale for n in chosen})
    return dataclasses.replace(new, name=f"{airframe.name}*{scale:g}")
