"""Plausibility of an airframe's values as a whole: ratios that every real airframe of its kind
keeps (wing loading, aspect ratio, pitch inertia radius against the span or the rotor arm,
derivatives per radian), so a unit slip (a mass in grams, a derivative per degree, an inertia
in kg cm^2) is named at load instead of surfacing later as a failed trim.

Each finding names the parameter and the likely slip. They are warnings by default (a user's
unusual airframe may be real) and errors with ``strict``.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

from uavdyn.airframes.errors import AirframeError

DEG = 180.0 / math.pi


class AirframePlausibilityWarning(UserWarning):
    """An airframe value is outside what real airframes of its kind have (likely a unit slip)."""


@dataclass(frozen=True)
class Finding:
    """One implausible value: the parameter to look at and what looks wrong with it."""

    parameter: str
    message: str


def _outside(value: float, low: float, high: float) -> bool:
    return not (low <= value <= high)


def _fixed_wing(p) -> list[Finding]:
    out = []
    loading = p.mass * p.gravity / p.S_wing
    if _outside(loading, 5.0, 6000.0):
        hint = ("mass in grams?" if loading > 6000.0 else "mass or wing area in other units?")
        out.append(Finding("mass", f"wing loading mass * gravity / S_wing = {loading:.3g} N/m^2 "
                                   f"is outside 5-6000 N/m^2 of real aircraft ({hint})"))
    aspect = p.b ** 2 / p.S_wing
    if _outside(aspect, 1.0, 50.0):
        out.append(Finding("b", f"aspect ratio b^2 / S_wing = {aspect:.3g} is outside 1-50 (span "
                                "or wing area in other units?)"))
    radius = math.sqrt(p.Jy / p.mass)
    if _outside(radius / p.b, 0.02, 1.0):
        out.append(Finding("Jy", f"pitch inertia radius sqrt(Jy / mass) = {radius:.3g} m is "
                                 f"{radius / p.b:.3g} x the span b (real aircraft: 0.02-1; Jy "
                                 "in kg cm^2, or mass in grams?)"))
    for name, floor, typical in (("C_L_alpha", 1.0, "2-7"), ("C_m_alpha", 0.05, "0.2-5"),
                                 ("C_m_q", 1.0, "5-60"), ("C_m_delta_e", 0.05, "0.2-3")):
        value = getattr(p, name)
        if 0.0 < abs(value) < floor:
            out.append(Finding(name, f"|{name}| = {abs(value):.3g} per rad is below {floor:g} "
                                     f"(real airframes: {typical} per rad); per degree? (x "
                                     f"{DEG:.2f} = {value * DEG:.3g} per rad)"))
    return out


def _fixed_wing_authority(airframe) -> list[Finding]:
    if has_pitch_authority(airframe):
        return []
    return [Finding("C_m_delta_e", "C_m_delta_e = 0 and no C_m table over the elevator: the "
                                   "elevator has no pitch authority")]


def _multirotor(p) -> list[Finding]:
    out = []
    radius = math.sqrt(p.Jy / p.mass)
    ratio = radius / p.arm
    if ratio > 3.0:
        out.append(Finding("arm", f"the arm {p.arm:.3g} m is {1 / ratio:.3g} x the pitch inertia "
                                  f"radius sqrt(Jy / mass) = {radius:.3g} m (real multirotors: "
                                  "0.33-10; arm in km, or Jy in g m^2?)"))
    elif ratio < 0.1:
        out.append(Finding("Jy", f"pitch inertia radius sqrt(Jy / mass) = {radius:.3g} m is "
                                 f"{ratio:.3g} x the arm (real multirotors: 0.1-3; Jy in kg cm^2, "
                                 "mass in grams, or arm in mm?)"))
    if p.pitch_mix == 0.0:
        out.append(Finding("pitch_mix", "pitch_mix = 0: pitch_cmd does not change the rotors' "
                                        "thrusts (no pitch authority)"))
    return out


def plausibility_findings(airframe) -> list[Finding]:
    """The implausible values of ``airframe`` (empty for a plausible one)."""
    if airframe.kind == "fixed_wing":
        return _fixed_wing(airframe.params) + _fixed_wing_authority(airframe)
    return _multirotor(airframe.params)


def check_plausible(airframe, strict: bool = False) -> None:
    """Warn about (or with ``strict`` refuse) every implausible value of ``airframe``.

    Raises
    ------
    AirframeError
        With ``strict``, naming the airframe's origin and the first implausible parameter.
    """
    for finding in plausibility_findings(airframe):
        text = (f"{airframe.origin or airframe.name}: parameter '{finding.parameter}': "
                f"{finding.message}")
        if strict:
            raise AirframeError(text + " (refused with --strict)")
        warnings.warn(text, AirframePlausibilityWarning, stacklevel=3)


def has_pitch_authority(airframe) -> bool:
    """Whether the airframe's pitch command moves its pitching moment at all (a fixed wing's
    elevator through ``C_m_delta_e`` or a ``C_m`` table over the elevator)."""
    p = airframe.params
    if airframe.kind == "multirotor":
        return p.pitch_mix != 0.0
    table = airframe.tables.get("C_m")
    over_elevator = table is not None and any(name == "elevator" for name, _ in table.axes)
    return p.C_m_delta_e != 0.0 or over_elevator
