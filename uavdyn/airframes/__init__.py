"""Airframe parameters as data: typed dataclasses loaded from TOML/JSON files with sources.

Parameters enter the CasADi model as a symbolic vector ``p`` whose order is the field order of
the dataclass of the airframe's kind, so Jacobians with respect to parameters come for free and a
perturbed airframe is just another ``p``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import sys
from collections.abc import Iterable
from dataclasses import dataclass, fields
from importlib import resources
from pathlib import Path
from typing import Union

import numpy as np

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

KINDS = ("fixed_wing", "multirotor")


class AirframeError(ValueError):
    """A parameter file is malformed; the message names the file and the key."""


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


ParamsType = Union[FixedWingParams, MultirotorParams]  # noqa: UP007 (runtime alias, py3.10)
PARAM_CLASSES: dict[str, type] = {"fixed_wing": FixedWingParams, "multirotor": MultirotorParams}

# Keys that must be strictly positive (a zero or negative value makes the model meaningless).
POSITIVE_KEYS: dict[str, tuple[str, ...]] = {
    "fixed_wing": (
        "mass", "Jy", "S_wing", "b", "c", "rho", "e", "gravity", "M_blend", "alpha0",
        "D_prop", "KV_rpm_per_volt", "R_motor", "V_max",
    ),
    "multirotor": ("mass", "Jy", "arm", "c_T", "C_R", "rho", "gravity"),
}
NONNEGATIVE_KEYS: dict[str, tuple[str, ...]] = {
    "fixed_wing": ("C_D_0", "i0"),
    "multirotor": ("CdA_x", "CdA_z", "drag_linear", "pitch_damping", "pitch_mix"),
}

# What the +15 % robustness scenario perturbs: stability derivatives and mass terms.
PERTURBATION_KEYS: dict[str, tuple[str, ...]] = {
    "fixed_wing": (
        "mass", "Jy", "C_L_alpha", "C_L_q", "C_L_delta_e", "C_m_alpha", "C_m_q", "C_m_delta_e",
    ),
    "multirotor": ("mass", "Jy", "drag_linear", "pitch_damping", "c_T"),
}

PRESETS = {"aerosonde": "aerosonde.toml", "f450": "f450.toml"}
ALIASES = {"fixed_wing": "aerosonde", "fixedwing": "aerosonde", "quadrotor": "f450",
           "multirotor": "f450"}


@dataclass(frozen=True)
class Airframe:
    """A named airframe: its kind, typed parameters, and the source of every number."""

    name: str
    kind: str
    params: ParamsType
    sources: dict[str, str]
    description: str = ""
    nominal_airspeed: float = 0.0
    origin: str = ""

    @property
    def param_names(self) -> tuple[str, ...]:
        return param_names(self.kind)

    @property
    def p(self) -> np.ndarray:
        """The numeric parameter vector in model order."""
        return np.array([getattr(self.params, n) for n in self.param_names], dtype=float)

    def param_hash(self) -> str:
        """Short hash of kind + parameter values, used to tie trained weights to an airframe."""
        text = json.dumps({"kind": self.kind, "p": [repr(float(v)) for v in self.p]})
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def replace(self, **changes: float) -> Airframe:
        """A copy with some parameter values changed (validated)."""
        unknown = set(changes) - set(self.param_names)
        if unknown:
            raise AirframeError(f"unknown parameter(s) {sorted(unknown)} for kind '{self.kind}'")
        values = dataclasses.asdict(self.params)
        values.update({k: float(v) for k, v in changes.items()})
        _check_values(values, self.kind, self.origin or self.name)
        return dataclasses.replace(self, params=PARAM_CLASSES[self.kind](**values))


def param_names(kind: str) -> tuple[str, ...]:
    """Names of the parameter vector ``p`` for an airframe kind, in order."""
    if kind not in PARAM_CLASSES:
        raise AirframeError(f"unknown airframe kind '{kind}'; expected one of {KINDS}")
    return tuple(f.name for f in fields(PARAM_CLASSES[kind]))


def list_presets() -> list[str]:
    """Names of the airframes shipped with the package."""
    return sorted(PRESETS)


def load_airframe(name_or_path: str | Path) -> Airframe:
    """Load a preset by name (``aerosonde``, ``f450``, or ``quadrotor``/``fixed_wing``) or a
    user's own TOML/JSON parameter file of the same schema."""
    key = str(name_or_path)
    key = ALIASES.get(key, key)
    if key in PRESETS:
        text = resources.files(__package__).joinpath(PRESETS[key]).read_text()
        return _parse(tomllib.loads(text), origin=f"preset '{key}'")
    path = Path(name_or_path)
    if not path.exists():
        raise AirframeError(
            f"airframe '{name_or_path}' is neither a preset ({', '.join(list_presets())}) "
            "nor an existing parameter file"
        )
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(path.read_text())
        else:
            data = tomllib.loads(path.read_text())
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        raise AirframeError(f"{path}: cannot parse parameter file: {exc}") from exc
    return _parse(data, origin=str(path))


def _parse(data: dict, origin: str) -> Airframe:
    for key in ("name", "kind", "params"):
        if key not in data:
            raise AirframeError(f"{origin}: missing top-level key '{key}'")
    kind = data["kind"]
    if kind not in PARAM_CLASSES:
        raise AirframeError(f"{origin}: key 'kind' is '{kind}'; expected one of {KINDS}")
    allowed_top = {"name", "kind", "params", "description", "nominal_airspeed"}
    extra_top = set(data) - allowed_top
    if extra_top:
        raise AirframeError(f"{origin}: unknown top-level key(s) {sorted(extra_top)}")
    raw = data["params"]
    names = param_names(kind)
    unknown = sorted(set(raw) - set(names))
    if unknown:
        raise AirframeError(f"{origin}: unknown parameter key(s) {unknown} for kind '{kind}'")
    missing = [n for n in names if n not in raw]
    if missing:
        raise AirframeError(f"{origin}: missing parameter key(s) {missing}")
    values: dict[str, float] = {}
    sources: dict[str, str] = {}
    for name in names:
        entry = raw[name]
        if isinstance(entry, dict):
            if "value" not in entry:
                raise AirframeError(f"{origin}: parameter '{name}' has no 'value'")
            value, sources[name] = entry["value"], str(entry.get("source", ""))
        else:
            value, sources[name] = entry, ""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise AirframeError(f"{origin}: parameter '{name}' must be a number, got {value!r}")
        values[name] = float(value)
    _check_values(values, kind, origin)
    nominal = data.get("nominal_airspeed", 0.0)
    if not isinstance(nominal, (int, float)) or not math.isfinite(nominal) or nominal < 0:
        raise AirframeError(f"{origin}: 'nominal_airspeed' must be a finite number >= 0")
    return Airframe(
        name=str(data["name"]), kind=kind, params=PARAM_CLASSES[kind](**values), sources=sources,
        description=str(data.get("description", "")), nominal_airspeed=float(nominal),
        origin=origin,
    )


def _check_values(values: dict[str, float], kind: str, origin: str) -> None:
    for name, value in values.items():
        if not math.isfinite(value):
            raise AirframeError(f"{origin}: parameter '{name}' is not finite ({value})")
    for name in POSITIVE_KEYS[kind]:
        if values[name] <= 0:
            raise AirframeError(f"{origin}: parameter '{name}' must be > 0, got {values[name]}")
    for name in NONNEGATIVE_KEYS[kind]:
        if values[name] < 0:
            raise AirframeError(f"{origin}: parameter '{name}' must be >= 0, got {values[name]}")


def perturb(airframe: Airframe, scale: float = 1.15,
            names: Iterable[str] | None = None) -> Airframe:
    """Scale parameters (default: the kind's stability derivatives and mass terms) by ``scale``;
    the paper's robustness scenario is ``scale=1.15``."""
    chosen = tuple(names) if names is not None else PERTURBATION_KEYS[airframe.kind]
    unknown = [n for n in chosen if n not in airframe.param_names]
    if unknown:
        raise AirframeError(f"perturb: unknown parameter(s) {unknown} for kind '{airframe.kind}'")
    new = airframe.replace(**{n: getattr(airframe.params, n) * scale for n in chosen})
    return dataclasses.replace(new, name=f"{airframe.name}*{scale:g}")


def to_toml_dict(airframe: Airframe) -> dict:
    """The airframe in the file schema (for writing a user's own copy to edit)."""
    return {
        "name": airframe.name, "kind": airframe.kind, "description": airframe.description,
        "nominal_airspeed": airframe.nominal_airspeed,
        "params": {n: {"value": getattr(airframe.params, n), "source": airframe.sources.get(n, "")}
                   for n in airframe.param_names},
    }
