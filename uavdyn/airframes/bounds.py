"""Physical bounds of airframe parameters (:data:`BOUNDS`) and the checks of values against them."""

from __future__ import annotations

import math
from dataclasses import dataclass

from uavdyn.airframes.errors import AirframeError, _short


@dataclass(frozen=True)
class Bound:
    """Allowed range of one parameter: ``low < x`` (or ``<=`` if not ``low_open``) and
    ``x <= high`` (or ``<`` if ``high_open``), in ``unit``; ``why`` says where it comes from."""

    low: float
    high: float
    unit: str = ""
    why: str = ""
    low_open: bool = True
    high_open: bool = False

    def describe(self) -> str:
        """The interval in mathematical notation, e.g. ``(0, 100000] kg``."""
        text = (f"{'(' if self.low_open else '['}{self.low:g}, {self.high:g}"
                f"{')' if self.high_open else ']'}")
        return f"{text} {self.unit}".strip()

    def violation(self, value: float) -> str | None:
        """What is wrong with ``value`` (None if it is within the bound)."""
        if value < self.low or (self.low_open and value == self.low):
            return f"must be {'>' if self.low_open else '>='} {self.low:g}"
        if value > self.high or (self.high_open and value == self.high):
            return f"must be {'<' if self.high_open else '<='} {self.high:g}"
        return None


def _b(low: float, high: float, unit: str = "", why: str = "", low_open: bool = True,
       high_open: bool = False) -> Bound:
    return Bound(low, high, unit, why, low_open, high_open)


_COEFF = _b(-1e3, 1e3, "", "aerodynamic/propeller coefficient: finite, |x| < 1e3",
            low_open=True, high_open=True)
# Sizes by meaning, per kind (issue 42: a quadrotor arm of 1e-300 m loaded and trimmed, since
# hover needs no pitch authority). Each floor is below the smallest vehicle of its kind that
# flies (a 1 g micro air vehicle, a nano quadrotor's 5 mm arm), each ceiling above the largest.
_MASS = _b(1e-3, 1e5, "kg", "from a 1 g micro air vehicle to a 100 t aircraft",
           low_open=False)
_JY = _b(1e-9, 1e6, "kg m^2", "from a 1 g micro air vehicle (~1e-8) to a 100 t aircraft "
                              "(~1e6 kg m^2)", low_open=False)
_RHO = _b(0, 2.0, "kg/m^3", "sea-level ISA is 1.225; 2 is beyond any atmosphere flown in")
_G = _b(9.0, 10.5, "m/s^2", "Earth's surface gravity is 9.78-9.83 m/s^2", low_open=False)
_SPAN = _b(0.01, 100, "m", "wing span: from a 1 cm micro air vehicle to beyond any aircraft "
                           "(80 m)", low_open=False, high_open=True)
_CHORD = _b(1e-3, 20, "m", "mean aerodynamic chord: from 1 mm to beyond any aircraft's "
                           "(~12 m)", low_open=False)
_AREA = _b(1e-4, 1e3, "m^2", "wing area: from 1 cm^2 to beyond a 747's 511 m^2",
           low_open=False)
_PROP = _b(5e-3, 10, "m", "propeller diameter: from 5 mm to beyond the largest (~6 m)",
           low_open=False)
_MR_MASS = _b(1e-3, 1e4, "kg", "multirotor mass: from a 1 g nano quadrotor to beyond the "
                               "heaviest cargo multirotors (~2 t)", low_open=False)
_MR_JY = _b(1e-9, 1e5, "kg m^2", "multirotor pitch inertia: from a 1 g nano quadrotor (~1e-8) "
                                 "to beyond the heaviest (~1e3 kg m^2)", low_open=False)
_ARM = _b(5e-3, 10, "m", "centre-to-motor distance: from a nano quadrotor's 5 mm to beyond "
                         "the largest multirotors (~4 m)", low_open=False)
_ALPHA_DOT = _b(-100, 100, "1/rad", "alpha-dot derivative (times alpha_dot c/2V): conventional "
                                    "aircraft have |x| < ~20 (e.g. C_m_alpha_dot -5 to -15)",
                low_open=False)
_TAU = _b(0, 10, "s", "first-order time constant; 0 = no lag (no actuator state)",
          low_open=False)
_SLEW = _b(0, 10, "s per unit", "actuator slew time, 1 / its rate limit (s/rad for the "
                                "elevator, s per full throttle); 0 = no rate limit",
           low_open=False)
# The closed-form alpha-dot divides by 1 + rho S c C_L_alpha_dot / (4 m) (the alpha-dot lift
# acts like an added mass); below this the "added mass" would more than double alpha_dot.
ALPHA_DOT_DENOMINATOR_MIN = 0.5

# The schema's physical bounds, per kind and parameter (every parameter has one).
BOUNDS: dict[str, dict[str, Bound]] = {
    "fixed_wing": {
        "mass": _MASS, "Jy": _JY, "S_wing": _AREA, "b": _SPAN, "c": _CHORD, "rho": _RHO,
        "e": _b(0, 1.5, "", "Oswald efficiency: 1 for an elliptic wing, up to ~1.2 with "
                            "winglets"),
        "gravity": _G,
        "C_L_0": _COEFF, "C_L_alpha": _COEFF, "C_L_alpha2": _COEFF, "C_L_q": _COEFF,
        "C_L_delta_e": _COEFF,
        "C_D_0": _b(0, 10, "", "zero-lift drag coefficient: >= 0, a flat plate is ~2",
                    low_open=False),
        "C_D_q": _COEFF, "C_D_delta_e": _COEFF, "C_m_0": _COEFF, "C_m_alpha": _COEFF,
        "C_m_q": _COEFF, "C_m_delta_e": _COEFF,
        "M_blend": _b(0, 100, "1/rad", "stall-blend sharpness (50 in [BM]); up to 100 keeps "
                                       "exp(M (|alpha| + alpha0)) finite for |alpha| <= pi"),
        "alpha0": _b(0, math.pi / 2, "rad", "stall-blend angle, within +-90 deg"),
        "D_prop": _PROP,
        "KV_rpm_per_volt": _b(0, 1e5, "rpm/V", "motor velocity constant; small motors are "
                                                "~1e4"),
        "R_motor": _b(0, 1e3, "ohm", "motor winding resistance"),
        "i0": _b(0, 1e3, "A", "no-load current, >= 0", low_open=False),
        "V_max": _b(0, 1e4, "V", "battery voltage"),
        "C_Q2": _COEFF, "C_Q1": _COEFF, "C_Q0": _COEFF,
        "C_T2": _COEFF, "C_T1": _COEFF, "C_T0": _COEFF,
        "C_L_alpha_dot": _ALPHA_DOT, "C_m_alpha_dot": _ALPHA_DOT,
        "tau_elevator": _TAU, "tau_throttle": _TAU,
        "slew_elevator": _SLEW, "slew_throttle": _SLEW,
        "eta_slipstream": _b(0, 3, "", "share of the tail in the propeller slipstream (adds "
                                       "eta T/A_disk to the elevator's qbar); 0 = none, 0.5-1 "
                                       "for a tractor with the tail in it", low_open=False),
        "C_D_Re": _b(0, 2, "(m/s)^0.5", "Reynolds drag, Delta C_D = C_D_Re/sqrt(V) (laminar "
                                        "skin friction ~ Re^-1/2): >= 0, ~0.05 for a small "
                                        "UAV", low_open=False),
        "C_m_Re": _b(-2, 2, "(m/s)^0.5", "Reynolds pitching moment, Delta C_m = C_m_Re/sqrt(V)"
                                         ": either sign, |x| ~ 0.05 for a small UAV",
                     low_open=False),
    },
    "multirotor": {
        "mass": _MR_MASS, "Jy": _MR_JY, "arm": _ARM,
        "c_T": _b(0, 1e3, "N/(rad/s)^2", "rotor thrust coefficient (1e-5 for an F450)",
                  high_open=True),
        "C_R": _b(0, 1e5, "rad/s", "throttle-to-rotor-speed slope (1148 for an F450)"),
        "omega_b": _b(-1e5, 1e5, "rad/s", "throttle-to-rotor-speed offset", high_open=True),
        "rho": _RHO, "gravity": _G,
        "CdA_x": _b(0, 1e3, "m^2", "drag area, >= 0", low_open=False),
        "CdA_z": _b(0, 1e3, "m^2", "drag area, >= 0", low_open=False),
        "drag_linear": _b(0, 1e6, "N s/m", "linear (rotor) drag, >= 0", low_open=False),
        "pitch_damping": _b(0, 1e6, "N m s/rad", "pitch damping, >= 0", low_open=False),
        "pitch_mix": _b(0, 1, "", "mixer share of pitch_cmd in a rotor's throttle (0..1)",
                        low_open=False),
        "tau_rotor": _TAU,
        "k_inflow": _b(0, 1e3, "N s^2/(rad m)", "thrust loss per rotor speed and axial inflow "
                                                  "speed, >= 0", low_open=False),
        "M_u": _b(-1e3, 1e3, "N s", "speed-stability pitching moment per forward airspeed "
                                    "(blade flapping; > 0 nose-up)", high_open=True),
        "M_0": _b(-1e4, 1e4, "N m", "constant pitching moment (e.g. centre-of-gravity offset)",
                  high_open=True),
    },
}

# The signs physics gives some derivatives by their meaning and this project's sign convention
# (elevator positive trailing edge down, a nose-down moment; q positive nose up). A fit keeps
# them (:func:`sign_range`); a file may hold any value inside BOUNDS. Multirotor: its damping
# and drag parameters already have their sign in BOUNDS (>= 0); M_u and M_0 take either sign.
@dataclass(frozen=True)
class Sign:
    """The sign a derivative has by meaning: ``+1`` (> 0) or ``-1`` (< 0), why, and whether an
    airframe file's ``relaxed_stability = true`` lifts it."""

    sign: int
    why: str
    relaxable: bool = False


SIGNS: dict[str, dict[str, Sign]] = {
    "fixed_wing": {
        "C_L_alpha": Sign(+1, "lift-curve slope: lift grows with angle of attack (> 0)"),
        "C_m_q": Sign(-1, "pitch damping: a pitch rate makes a moment against it (< 0)"),
        "C_m_delta_e": Sign(-1, "elevator effectiveness: a positive elevator (trailing edge "
                                "down) pitches the nose down (< 0)"),
        "C_m_alpha": Sign(-1, "static stability: a nose-up angle of attack makes a nose-down "
                              "moment (< 0; an airframe file declaring relaxed_stability = "
                              "true lets it take either sign)", relaxable=True),
    },
    "multirotor": {},
}


def sign_range(kind: str, name: str, relaxed_stability: bool = False
               ) -> tuple[float, float] | None:
    """The open half-line ``(0, inf)`` or ``(-inf, 0)`` a derivative's sign keeps it in
    (:data:`SIGNS`), or None where its sign is free (also a relaxable one under
    ``relaxed_stability``)."""
    sign = SIGNS.get(kind, {}).get(name)
    if sign is None or (sign.relaxable and relaxed_stability):
        return None
    return (0.0, math.inf) if sign.sign > 0 else (-math.inf, 0.0)


# Keys that must be strictly positive / non-negative (derived from BOUNDS; kept for callers).
POSITIVE_KEYS: dict[str, tuple[str, ...]] = {
    kind: tuple(n for n, b in table.items() if b.low > 0 or (b.low == 0 and b.low_open))
    for kind, table in BOUNDS.items()}
NONNEGATIVE_KEYS: dict[str, tuple[str, ...]] = {
    kind: tuple(n for n, b in table.items() if b.low == 0 and not b.low_open)
    for kind, table in BOUNDS.items()}


def alpha_dot_denominator(values: dict[str, float]) -> float:
    """``1 + rho S c C_L_alpha_dot / (4 m)``: the alpha-dot lift moves w_dot, hence alpha_dot,
    so the exact alpha_dot is the one computed without it divided by this factor."""
    return 1.0 + (values["rho"] * values["S_wing"] * values["c"] * values["C_L_alpha_dot"]
                  / (4.0 * values["mass"]))


def _as_number(value: object, name: str, origin: str) -> float:
    """A parameter value as float: a bool or a string is not a number; an integer too large
    for a float is not finite."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise AirframeError(f"{origin}: parameter '{name}' must be a number, got "
                            f"{_short(value)}")
    try:
        return float(value)
    except OverflowError:
        raise AirframeError(f"{origin}: parameter '{name}' is not finite (an integer of "
                            f"{value.bit_length()} bits)") from None


def _check_values(values: dict[str, float], kind: str, origin: str) -> None:
    """Every value finite and within its :data:`BOUNDS` entry (the message names the key)."""
    for name, value in values.items():
        if not math.isfinite(value):
            raise AirframeError(f"{origin}: parameter '{name}' is not finite ({value})")
    for name, bound in BOUNDS[kind].items():
        problem = bound.violation(values[name])
        if problem:
            raise AirframeError(f"{origin}: parameter '{name}' {problem}, got {values[name]!r} "
                                f"(allowed {bound.describe()}: {bound.why})")
    _check_lateral_inertias(values, origin)
    if kind == "fixed_wing":
        denominator = alpha_dot_denominator(values)
        if not denominator >= ALPHA_DOT_DENOMINATOR_MIN:
            raise AirframeError(
                f"{origin}: parameter 'C_L_alpha_dot' = {values['C_L_alpha_dot']!r} makes the "
                f"alpha-dot factor 1 + rho S c C_L_alpha_dot / (4 mass) = {denominator:.3g}, "
                f"below {ALPHA_DOT_DENOMINATOR_MIN:g}: a negative alpha-dot lift that large "
                "is not a physical airframe (the closed form would amplify alpha_dot "
                f"{1 / max(denominator, 1e-300):.3g}-fold)")


def _check_lateral_inertias(values: dict[str, float], origin: str) -> None:
    """The optional roll/yaw inertias (turning-flight inputs): ``Jx``, ``Jz`` 0 (not given) or
    within the pitch inertia's range and, where
    both are given, a positive-definite roll/yaw inertia ``Jxz^2 < Jx Jz``."""
    jx, jz, jxz = (values.get(k, 0.0) for k in ("Jx", "Jz", "Jxz"))
    for name, value in (("Jx", jx), ("Jz", jz)):
        if value != 0.0 and not _JY.low <= value <= _JY.high:
            raise AirframeError(f"{origin}: parameter '{name}' must be 0 (not given) or in "
                                f"[{_JY.low:g}, {_JY.high:g}] kg m^2 ({_JY.why}), got "
                                f"{value!r}")
    if jx > 0.0 and jz > 0.0 and not jxz * jxz < jx * jz:
        raise AirframeError(f"{origin}: parameter 'Jxz' = {jxz!r} makes the roll/yaw inertia "
                            f"not positive definite (need Jxz^2 < Jx Jz = {jx * jz:.4g})")
