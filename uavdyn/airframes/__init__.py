"""Airframe parameters as data: typed dataclasses loaded from TOML/JSON files with sources.

Parameters enter the CasADi model as a symbolic vector ``p`` whose order is the field order of
the dataclass of the airframe's kind, so Jacobians with respect to parameters come for free and a
perturbed airframe is just another ``p``.

File schema (TOML or JSON; unknown keys are errors, so a typo never passes silently)::

    name = "my_plane"          # identifier [A-Za-z0-9_-], at most 64 characters: it is used
                               # in file names (weights, results), so it may not be a path
    kind = "fixed_wing"        # or "multirotor"
    description = "..."        # optional string
    nominal_airspeed = 25.0    # optional, m/s, in [0, NOMINAL_AIRSPEED_MAX]
    [params.mass]              # every parameter of the kind, each either a bare number or
    value = 11.0               # a table with 'value' and an optional 'source' string
    source = "where the number comes from"

Optional parameters (:data:`OPTIONAL_PARAMS`) may be left out; absent, they take their documented
default, which changes nothing (the model, ``param_hash`` and every result are those of a file
without the key). Fixed wing: ``C_L_alpha_dot`` and ``C_m_alpha_dot`` (per rad, multiplied by
``alpha_dot c / (2 V)`` like the q-derivatives; default 0.0), solved exactly in the model.

Optional ``[limits]`` table (absent: the kind's physical ranges, ``uavdyn.model.CONTROL_BOUNDS``,
and the MPC's default rates): a real airframe's own actuator travel and rate, which may narrow but
never widen the kind's physical range. Not parameters of ``p``, so ``param_hash`` ignores them::

    [limits]
    elevator = [-0.14, 0.14]   # a [low, high] pair per control name of the kind (low < high)
    throttle = [0.0, 1.0]      # fixed wing: elevator, throttle; multirotor: collective, pitch_cmd
    elevator_rate = 1.0        # '<control>_rate': a positive rate in control units per second

Fixed wing also: ``tau_elevator``, ``tau_throttle`` (s, first-order actuator lag; the throttle
lag is the engine's power lag in front of the thrust model or table). Multirotor: ``tau_rotor``
(s, rotor-speed lag of both commands: rotor speed is linear in them) and ``k_inflow`` (thrust loss
``k_inflow * omega * v_axial`` with the climb speed through the disc). A time constant of 0 means
no lag and no actuator state. Multirotor pitching moments a rotor craft has besides the rotors'
thrust difference: ``M_u`` (N m per m/s, the speed-stability derivative: blade flapping tilts
the rotor discs back in forward flight, a nose-up moment ``M_u * u``) and ``M_0`` (N m, a constant
moment, e.g. a centre of gravity off the rotors' centre); the autopilot holds them with a
steady pitch command, which a model without them reads as missing control authority.

Optional model structure (absent: none of it)::

    atmosphere = "isa"         # rho is then the sea-level density, scaled by the standard
                               # atmosphere at each sortie's manifest 'altitude_m' (or the h state)
    [delays]
    elevator = 2               # integer transport delay per control, in samples of the step
    [tables.C_L]               # breakpoint tables (see uavdyn.airframes.tables)
    alpha = [-0.2, 0.0, 0.2]
    values = [-0.9, 0.23, 1.35]

Every value is typed (a boolean or a string is not a number) and range-checked against
:data:`BOUNDS`, a table of honest physical limits per parameter (generous enough for any real
airframe from a micro quadrotor to a 100 t aircraft, tight enough that unit slips such as grams
for kilograms or degrees for radians, and absurd values such as 1e308, are caught at load time
with the parameter named, not later inside a solver). Files are ``stat``-ed before they are
opened: only regular files of at most :data:`AIRFRAME_MAX_BYTES` are read.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import re
import sys
from collections.abc import Iterable
from dataclasses import dataclass, field, fields
from importlib import resources
from pathlib import Path
from typing import Union

import numpy as np

from uavdyn.airframes.tables import (
    VALUE_LIMITS,
    Table,
    TableError,
    number_value,
    parse_tables,
)
from uavdyn.safefiles import DuplicateKey, UnreadableFile, no_duplicate_keys, read_regular

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

KINDS = ("fixed_wing", "multirotor")
AIRFRAME_MAX_BYTES = 2**20          # a parameter file with sources is a few kB
NOMINAL_AIRSPEED_MAX = 150.0        # m/s; the flight-data speed limit is 100 m/s
NAME_PATTERN = re.compile(r"[A-Za-z0-9_-]{1,64}")
TOP_LEVEL_KEYS = ("name", "kind", "params", "description", "nominal_airspeed", "limits",
                  "delays", "atmosphere", "tables")
ATMOSPHERES = ("constant", "isa")
DELAY_MAX_SAMPLES = 50
RATE_SUFFIX = "_rate"
# Each kind's controls in model order with their physical ranges (elevator: the usual +-30 deg
# surface travel). The one table: uavdyn.model.CONTROL_NAMES/CONTROL_BOUNDS are derived from it.
CONTROL_RANGES: dict[str, tuple[tuple[str, tuple[float, float]], ...]] = {
    "fixed_wing": (("elevator", (-0.5236, 0.5236)), ("throttle", (0.0, 1.0))),
    "multirotor": (("collective", (0.0, 1.0)), ("pitch_cmd", (-1.0, 1.0))),
}
PARAM_ENTRY_KEYS = ("value", "source")



class AirframeError(ValueError):
    """A parameter file is malformed; the one-line message names the file and the key."""

    def __init__(self, message: str) -> None:
        super().__init__(" ".join(message.split()))


def _display(path: str | Path) -> str:
    """A path as it can appear on one line of a message (non-printable characters escaped)."""
    text = str(path)
    return text if text.isprintable() else repr(text)[1:-1]


def _short(value: object, limit: int = 40) -> str:
    """A short printable repr of a value for a message (never a whole file's content)."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + "..."


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


ParamsType = Union[FixedWingParams, MultirotorParams]  # noqa: UP007 (runtime alias, py3.10)
PARAM_CLASSES: dict[str, type] = {"fixed_wing": FixedWingParams, "multirotor": MultirotorParams}

# Optional parameters per kind and their defaults: the dataclass fields that have a default. A
# file may leave them out; at their default they change nothing (see Airframe.param_hash).
OPTIONAL_PARAMS: dict[str, dict[str, float]] = {
    kind: {f.name: f.default for f in fields(cls) if f.default is not dataclasses.MISSING}
    for kind, cls in PARAM_CLASSES.items()}


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
_MASS = _b(0, 1e5, "kg", "a 100 t aircraft is far beyond any UAV")
_JY = _b(0, 1e6, "kg m^2", "pitch inertia of a 100 t aircraft is ~1e6 kg m^2")
_RHO = _b(0, 2.0, "kg/m^3", "sea-level ISA is 1.225; 2 is beyond any atmosphere flown in")
_G = _b(9.0, 10.5, "m/s^2", "Earth's surface gravity is 9.78-9.83 m/s^2", low_open=False)
_LENGTH = _b(0, 100, "m", "lengths are positive and shorter than 100 m", high_open=True)
_ALPHA_DOT = _b(-100, 100, "1/rad", "alpha-dot derivative (times alpha_dot c/2V): conventional "
                                    "aircraft have |x| < ~20 (e.g. C_m_alpha_dot -5 to -15)",
                low_open=False)
_TAU = _b(0, 10, "s", "first-order time constant; 0 = no lag (no actuator state)",
          low_open=False)
# The closed-form alpha-dot divides by 1 + rho S c C_L_alpha_dot / (4 m) (the alpha-dot lift
# acts like an added mass); below this the "added mass" would more than double alpha_dot.
ALPHA_DOT_DENOMINATOR_MIN = 0.5

# The schema's physical bounds, per kind and parameter (every parameter has one).
BOUNDS: dict[str, dict[str, Bound]] = {
    "fixed_wing": {
        "mass": _MASS, "Jy": _JY,
        "S_wing": _b(0, 1e3, "m^2", "wing area; a 747 has 511 m^2"),
        "b": _LENGTH, "c": _LENGTH, "rho": _RHO,
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
        "D_prop": _LENGTH,
        "KV_rpm_per_volt": _b(0, 1e5, "rpm/V", "motor velocity constant; small motors are "
                                                "~1e4"),
        "R_motor": _b(0, 1e3, "ohm", "motor winding resistance"),
        "i0": _b(0, 1e3, "A", "no-load current, >= 0", low_open=False),
        "V_max": _b(0, 1e4, "V", "battery voltage"),
        "C_Q2": _COEFF, "C_Q1": _COEFF, "C_Q0": _COEFF,
        "C_T2": _COEFF, "C_T1": _COEFF, "C_T0": _COEFF,
        "C_L_alpha_dot": _ALPHA_DOT, "C_m_alpha_dot": _ALPHA_DOT,
        "tau_elevator": _TAU, "tau_throttle": _TAU,
    },
    "multirotor": {
        "mass": _MASS, "Jy": _JY, "arm": _LENGTH,
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

# Keys that must be strictly positive / non-negative (derived from BOUNDS; kept for callers).
POSITIVE_KEYS: dict[str, tuple[str, ...]] = {
    kind: tuple(n for n, b in table.items() if b.low == 0 and b.low_open)
    for kind, table in BOUNDS.items()}
NONNEGATIVE_KEYS: dict[str, tuple[str, ...]] = {
    kind: tuple(n for n, b in table.items() if b.low == 0 and not b.low_open)
    for kind, table in BOUNDS.items()}


# What the +15 % robustness scenario perturbs: stability derivatives and mass terms.
PERTURBATION_KEYS: dict[str, tuple[str, ...]] = {
    "fixed_wing": (
        "mass", "Jy", "C_L_alpha", "C_L_q", "C_L_delta_e", "C_m_alpha", "C_m_q", "C_m_delta_e",
        "C_L_alpha_dot", "C_m_alpha_dot",  # 0 in the presets, so 0 after scaling
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
    # The file's [limits] as parsed: control -> (low, high), '<control>_rate' -> rate (1/s).
    limits: dict[str, tuple[float, float] | float] = field(default_factory=dict)
    # Integer transport delay per control, in samples of the discrete step (absent: 0).
    delays: dict[str, int] = field(default_factory=dict)
    # "constant": rho as given; "isa": rho is the sea-level density, scaled by the standard
    # atmosphere at the sortie's altitude (manifest 'altitude_m') or at the h state.
    atmosphere: str = "constant"
    tables: dict[str, Table] = field(default_factory=dict)

    @property
    def param_names(self) -> tuple[str, ...]:
        """Names of ``p``: the kind's parameters, then the values of each table (sorted by
        table name, row-major)."""
        return param_names(self.kind) + tuple(
            n for name in sorted(self.tables) for n in self.tables[name].value_names())

    @property
    def p(self) -> np.ndarray:
        """The numeric parameter vector in model order."""
        core = [getattr(self.params, n) for n in param_names(self.kind)]
        table_values = [v for name in sorted(self.tables) for v in self.tables[name].values]
        return np.array(core + table_values, dtype=float)

    def delay_samples(self) -> tuple[int, ...]:
        """The transport delay of each control in model order (samples of the step)."""
        return tuple(int(self.delays.get(n, 0)) for n, _ in CONTROL_RANGES[self.kind])

    def control_bounds(self) -> tuple[tuple[float, float], ...]:
        """The (low, high) of each control in model order: the file's ``[limits]`` where set,
        else the kind's physical range (so trim, MPC and simulate respect the real actuator)."""
        return tuple(tuple(map(float, self.limits.get(n, b)))  # type: ignore[arg-type]
                     for n, b in CONTROL_RANGES[self.kind])

    def rate_limits(self) -> tuple[float | None, ...] | None:
        """Per-control rate limits (per second) from ``[limits]``, None for a control without
        one; None if the file sets no rate at all (the caller keeps its own defaults)."""
        rates = tuple(self.limits.get(n + RATE_SUFFIX) for n, _ in CONTROL_RANGES[self.kind])
        if all(r is None for r in rates):
            return None
        return tuple(None if r is None else float(r) for r in rates)  # type: ignore[arg-type]

    def param_hash(self) -> str:
        """Short hash of kind + parameter values, used to tie trained weights to an airframe.

        Hashed: every core parameter, and an optional parameter only where it differs from its
        default, so adding an optional key to the schema leaves existing hashes (and the weight
        files tied to them) valid while any value that changes the model changes the hash."""
        optional = OPTIONAL_PARAMS[self.kind]
        core = [repr(float(getattr(self.params, n))) for n in param_names(self.kind)
                if n not in optional]
        doc: dict = {"kind": self.kind, "p": core}
        changed = {n: repr(float(getattr(self.params, n))) for n, default in optional.items()
                   if getattr(self.params, n) != default}
        if changed:
            doc["optional"] = changed
        # model structure beyond p, hashed only where set (existing hashes stay valid)
        delays = {k: v for k, v in sorted(self.delays.items()) if v}
        if delays:
            doc["delays"] = delays
        if self.atmosphere != "constant":
            doc["atmosphere"] = self.atmosphere
        if self.tables:
            doc["tables"] = {n: [list(map(list, (b for _, b in t.axes))),
                                 [a for a, _ in t.axes], [repr(v) for v in t.values]]
                             for n, t in sorted(self.tables.items())}
        return hashlib.sha256(json.dumps(doc).encode()).hexdigest()[:16]

    def replace(self, **changes: float) -> Airframe:
        """A copy with some parameter values changed (typed and range-checked like a file)."""
        origin = self.origin or self.name
        unknown = set(changes) - set(self.param_names)
        if unknown:
            raise AirframeError(f"unknown parameter(s) {sorted(unknown)} for kind '{self.kind}'")
        numbers = {k: _as_number(v, k, origin) for k, v in changes.items()}
        values = dataclasses.asdict(self.params)
        values.update({k: v for k, v in numbers.items() if k in values})
        _check_values(values, self.kind, origin)
        tables = dict(self.tables)
        for name, table in self.tables.items():
            names = table.value_names()
            if any(n in numbers for n in names):
                new = [numbers.get(n, v) for n, v in zip(names, table.values)]
                bad = [n for n, v in zip(names, new)
                       if not (math.isfinite(v) and abs(v) < VALUE_LIMITS[name])]
                if bad:
                    raise AirframeError(f"{origin}: table value '{bad[0]}' must be finite and "
                                        f"within +-{VALUE_LIMITS[name]:g}")
                tables[name] = table.with_values(new)
        return dataclasses.replace(self, params=PARAM_CLASSES[self.kind](**values),
                                   tables=tables)

    def with_delays(self, **delays: int) -> Airframe:
        """A copy with some controls' transport delays (samples) changed."""
        checked = _parse_delays({**self.delays, **delays}, self.kind, self.origin or self.name)
        return dataclasses.replace(self, delays=checked)


def param_names(kind: str) -> tuple[str, ...]:
    """Names of the parameter vector ``p`` for an airframe kind, in order."""
    if not isinstance(kind, str) or kind not in PARAM_CLASSES:
        raise AirframeError(f"unknown airframe kind {_short(kind)}; expected one of {KINDS}")
    return tuple(f.name for f in fields(PARAM_CLASSES[kind]))


def list_presets() -> list[str]:
    """Names of the airframes shipped with the package."""
    return sorted(PRESETS)


def _read_file(path: Path, origin: str) -> str:
    """The text of a parameter file: a regular file (checked before opening it, so a FIFO or
    device is never opened; :func:`uavdyn.safefiles.read_regular`) of at most
    :data:`AIRFRAME_MAX_BYTES`, UTF-8."""
    try:
        raw = read_regular(path, AIRFRAME_MAX_BYTES, "a TOML or JSON parameter file")
    except UnreadableFile as exc:
        if exc.missing:
            presets = ", ".join(list_presets() + sorted(ALIASES))
            raise AirframeError(f"airframe '{origin}' is neither a preset ({presets}) nor an "
                                "existing parameter file") from None
        raise AirframeError(f"{origin}: {exc.reason}") from None
    if raw.startswith(b"\xef\xbb\xbf"):
        raw = raw[3:]
    nul = raw.find(b"\x00")
    if nul >= 0:
        raise AirframeError(f"{origin}: not a text file (NUL byte at offset {nul}); expected a "
                            "TOML or JSON parameter file")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise AirframeError(f"{origin}: not a UTF-8 text file (byte 0x{raw[exc.start]:02x} at "
                            f"offset {exc.start}); expected a TOML or JSON parameter file"
                            ) from None
    if not text.strip():
        raise AirframeError(f"{origin}: empty file; expected a TOML or JSON parameter file")
    return text


_TOML_WHERE = re.compile(r"\s*\(at (line \d+, column \d+|end of document)\)\s*$")


def _decode(text: str, is_json: bool, origin: str) -> object:
    """Parse TOML or JSON; a parse error names the file and the line."""
    fmt = "JSON" if is_json else "TOML"
    try:
        if is_json:
            return json.loads(text, object_pairs_hook=no_duplicate_keys)
        return tomllib.loads(text)
    except json.JSONDecodeError as exc:
        where, msg = f"line {exc.lineno}, column {exc.colno}", exc.msg
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        found = _TOML_WHERE.search(msg)
        where = found.group(1) if found else "unknown line"
        msg = msg[:found.start()] if found else msg
    except DuplicateKey as exc:
        where, msg = "", f"key {_short(str(exc.args[0]))} appears twice in one object"
    except RecursionError:
        where, msg = "", "nested too deeply"
    except ValueError as exc:  # e.g. an integer with more digits than Python converts
        where = ""
        msg = "a number has too many digits" if "digits" in str(exc) else type(exc).__name__
    where = f"{where}: " if where else ""
    raise AirframeError(f"{origin}: cannot parse parameter file as {fmt}: {where}{msg}")


def load_airframe(name_or_path: str | Path) -> Airframe:
    """Load a preset by name or a user's own TOML/JSON parameter file of the same schema.

    Parameters
    ----------
    name_or_path : str or Path
        A preset (``aerosonde``, ``f450``, or the aliases ``quadrotor``/``fixed_wing``) or the
        path of a parameter file (``.json`` is read as JSON, anything else as TOML).

    Returns
    -------
    Airframe

    Raises
    ------
    AirframeError
        On one line naming the file and the key: unreadable, oversized or special files,
        parse errors (with the line), unknown or missing keys, wrong types, values outside
        :data:`BOUNDS`, a ``name`` that is not an identifier.
    """
    if isinstance(name_or_path, str):
        key = ALIASES.get(name_or_path, name_or_path)
        if key in PRESETS:
            text = resources.files(__package__).joinpath(PRESETS[key]).read_text()
            return _parse(tomllib.loads(text), origin=f"preset '{key}'")
    elif not isinstance(name_or_path, os.PathLike):
        raise AirframeError(f"airframe must be a preset name or a file path, got "
                            f"{type(name_or_path).__name__}")
    path = Path(name_or_path)
    origin = _display(path)
    if "\x00" in str(path):
        raise AirframeError(f"{origin}: invalid path (NUL byte)")
    text = _read_file(path, origin)
    return _parse(_decode(text, path.suffix.lower() == ".json", origin), origin=origin)


def _kind_of(value: object) -> str:
    """The file-format name of a parsed value's type, as a file's author would say it."""
    if isinstance(value, bool):
        return "a boolean"
    if value is None:
        return "null"
    return {list: "an array", str: "a string", int: "a number", float: "a number"}.get(
        type(value), type(value).__name__)


def _key_list(keys: Iterable[object], limit: int = 5) -> str:
    """``['a', 'b']`` with each key shortened (a key may be anything a file holds)."""
    keys = sorted(str(k) for k in keys)
    shown = [_short(k, 30) for k in keys[:limit]]
    return "[" + ", ".join(shown + (["..."] if len(keys) > limit else [])) + "]"


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


def _parse(data: dict, origin: str) -> Airframe:
    """Build an :class:`Airframe` from parsed TOML/JSON, checking keys, types and bounds."""
    if not isinstance(data, dict):
        raise AirframeError(f"{origin}: the top level must be a table (JSON object), not "
                            f"{_kind_of(data)}")
    for key in ("name", "kind", "params"):
        if key not in data:
            raise AirframeError(f"{origin}: missing top-level key '{key}'")
    kind = data["kind"]
    if not isinstance(kind, str):
        raise AirframeError(f"{origin}: key 'kind' must be a string, got {_short(kind)}")
    if kind not in PARAM_CLASSES:
        raise AirframeError(f"{origin}: key 'kind' is {_short(kind)}; expected one of {KINDS}")
    extra_top = set(data) - set(TOP_LEVEL_KEYS)
    if extra_top:
        raise AirframeError(f"{origin}: unknown top-level key(s) {_key_list(extra_top)}")
    name = data["name"]
    if not isinstance(name, str) or not NAME_PATTERN.fullmatch(name):
        raise AirframeError(f"{origin}: key 'name' is {_short(name)}; it must be an identifier "
                            "of letters, digits, '_' and '-' (at most 64 characters), because "
                            "it is used in file names")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise AirframeError(f"{origin}: key 'description' must be a string, got "
                            f"{_short(description)}")
    raw = data["params"]
    if not isinstance(raw, dict):
        raise AirframeError(f"{origin}: key 'params' must be a table of parameters, got "
                            f"{_short(raw)}")
    names = param_names(kind)
    unknown = set(raw) - set(names)
    if unknown:
        raise AirframeError(f"{origin}: unknown parameter key(s) {_key_list(unknown)} for kind "
                            f"'{kind}'")
    optional = OPTIONAL_PARAMS[kind]
    missing = [n for n in names if n not in raw and n not in optional]
    if missing:
        raise AirframeError(f"{origin}: missing parameter key(s) {missing}")
    values: dict[str, float] = {}
    sources: dict[str, str] = {}
    for name_ in names:
        if name_ not in raw:
            values[name_] = float(optional[name_])
            sources[name_] = f"optional key not set: default {optional[name_]!r} (no effect)"
            continue
        entry = raw[name_]
        if isinstance(entry, dict):
            if "value" not in entry:
                raise AirframeError(f"{origin}: parameter '{name_}' has no 'value'")
            extra = set(entry) - set(PARAM_ENTRY_KEYS)
            if extra:
                raise AirframeError(f"{origin}: parameter '{name_}': unknown key(s) "
                                    f"{_key_list(extra)}; expected {list(PARAM_ENTRY_KEYS)}")
            source = entry.get("source", "")
            if not isinstance(source, str):
                raise AirframeError(f"{origin}: parameter '{name_}': 'source' must be a "
                                    f"string, got {_short(source)}")
            value, sources[name_] = entry["value"], source
        else:
            value, sources[name_] = entry, ""
        values[name_] = _as_number(value, name_, origin)
    _check_values(values, kind, origin)
    nominal = data.get("nominal_airspeed", 0.0)
    if (isinstance(nominal, bool) or not isinstance(nominal, (int, float))
            or not 0 <= nominal <= NOMINAL_AIRSPEED_MAX):  # NaN fails the comparison too
        raise AirframeError(f"{origin}: key 'nominal_airspeed' must be a number of m/s in "
                            f"[0, {NOMINAL_AIRSPEED_MAX:g}], got {_short(nominal)}")
    limits = _parse_limits(data["limits"], kind, origin) if "limits" in data else {}
    delays = _parse_delays(data["delays"], kind, origin) if "delays" in data else {}
    atmosphere = data.get("atmosphere", "constant")
    if not isinstance(atmosphere, str) or atmosphere not in ATMOSPHERES:
        raise AirframeError(f"{origin}: key 'atmosphere' is {_short(atmosphere)}; expected one "
                            f"of {ATMOSPHERES}")
    try:
        tables = parse_tables(data["tables"], kind, origin) if "tables" in data else {}
    except TableError as exc:
        raise AirframeError(str(exc)) from None
    return Airframe(
        name=name, kind=kind, params=PARAM_CLASSES[kind](**values), sources=sources,
        description=description, nominal_airspeed=float(nominal), origin=origin, limits=limits,
        delays=delays, atmosphere=atmosphere, tables=tables,
    )


def _unknown_key(origin: str, table: str, key: str, kind: str, allowed) -> AirframeError:
    """The error for a key a table of the kind does not have (the key shown as written)."""
    shown = key if key.isprintable() and len(key) <= 40 else _short(key, 30)
    return AirframeError(f"{origin}: unknown key '{table}.{shown}' for kind '{kind}'; expected "
                         f"any of {list(allowed)}")


def _parse_delays(raw: object, kind: str, origin: str) -> dict[str, int]:
    """The ``[delays]`` table: a whole number of samples (0..DELAY_MAX_SAMPLES) per control."""
    if not isinstance(raw, dict):
        raise AirframeError(f"{origin}: key 'delays' must be a table, got {_short(raw)}")
    names = [n for n, _ in CONTROL_RANGES[kind]]
    out: dict[str, int] = {}
    for key in sorted(raw, key=str):
        value = raw[key]
        if key not in names:
            raise _unknown_key(origin, "delays", key, kind, names)
        if isinstance(value, bool) or not isinstance(value, int) \
                or not 0 <= value <= DELAY_MAX_SAMPLES:
            raise AirframeError(f"{origin}: key 'delays.{key}' must be a whole number of samples "
                                f"in [0, {DELAY_MAX_SAMPLES}], got {_short(value)}")
        if value:  # a zero delay is no delay (kept out, so a file round-trips equal)
            out[key] = int(value)
    return out


def _limit_number(value: object, key: str, origin: str) -> float:
    """One number of ``[limits]``: typed (no boolean or string) and finite."""
    number = number_value(value)
    if number is None:
        raise AirframeError(f"{origin}: key 'limits.{key}' must hold numbers, got "
                            f"{_short(value)}")
    if not math.isfinite(number):
        raise AirframeError(f"{origin}: key 'limits.{key}' must be finite, got {_short(value)}")
    return number


def _parse_limits(raw: object, kind: str, origin: str) -> dict[str, tuple[float, float] | float]:
    """The ``[limits]`` table checked against the kind's control names and physical ranges:
    an airframe may narrow an actuator's travel, never widen it past what the model allows."""
    if not isinstance(raw, dict):
        raise AirframeError(f"{origin}: key 'limits' must be a table, got {_short(raw)}")
    ranges = dict(CONTROL_RANGES[kind])
    names = tuple(ranges)
    allowed = list(names) + [n + RATE_SUFFIX for n in names]
    out: dict[str, tuple[float, float] | float] = {}
    for key in sorted(raw, key=str):
        value = raw[key]
        if key not in allowed:
            raise _unknown_key(origin, "limits", key, kind, allowed)
        if key.endswith(RATE_SUFFIX):
            rate = _limit_number(value, key, origin)
            if not rate > 0:
                raise AirframeError(f"{origin}: key 'limits.{key}' must be a positive rate "
                                    f"(per second), got {_short(value)}")
            out[key] = rate
            continue
        if not isinstance(value, list) or len(value) != 2:
            raise AirframeError(f"{origin}: key 'limits.{key}' must be a [low, high] pair, got "
                                f"{_short(value)}")
        low, high = (_limit_number(v, key, origin) for v in value)
        if not low < high:
            raise AirframeError(f"{origin}: key 'limits.{key}' needs low < high, got "
                                f"[{low:g}, {high:g}]")
        p_low, p_high = ranges[key]
        if low < p_low or high > p_high:
            raise AirframeError(f"{origin}: key 'limits.{key}' = [{low:g}, {high:g}] is wider "
                                f"than the physical range [{p_low:g}, {p_high:g}] of a {kind} "
                                "(an airframe may narrow it, never widen it)")
        out[key] = (low, high)
    return out


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
    if kind == "fixed_wing":
        denominator = alpha_dot_denominator(values)
        if not denominator >= ALPHA_DOT_DENOMINATOR_MIN:
            raise AirframeError(
                f"{origin}: parameter 'C_L_alpha_dot' = {values['C_L_alpha_dot']!r} makes the "
                f"alpha-dot factor 1 + rho S c C_L_alpha_dot / (4 mass) = {denominator:.3g}, "
                f"below {ALPHA_DOT_DENOMINATOR_MIN:g}: a negative alpha-dot lift that large "
                "is not a physical airframe (the closed form would amplify alpha_dot "
                f"{1 / max(denominator, 1e-300):.3g}-fold)")


def alpha_dot_denominator(values: dict[str, float]) -> float:
    """``1 + rho S c C_L_alpha_dot / (4 m)``: the alpha-dot lift moves w_dot, hence alpha_dot,
    so the exact alpha_dot is the one computed without it divided by this factor."""
    return 1.0 + (values["rho"] * values["S_wing"] * values["c"] * values["C_L_alpha_dot"]
                  / (4.0 * values["mass"]))


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


def to_toml_dict(airframe: Airframe) -> dict:
    """The airframe in the file schema (for writing a user's own copy to edit)."""
    out = {
        "name": airframe.name, "kind": airframe.kind, "description": airframe.description,
        "nominal_airspeed": airframe.nominal_airspeed,
        "params": {n: {"value": getattr(airframe.params, n), "source": airframe.sources.get(n, "")}
                   for n in param_names(airframe.kind)},
    }
    if airframe.limits:  # written only when set, so a preset's copy is unchanged
        out["limits"] = {k: list(v) if isinstance(v, tuple) else v
                         for k, v in airframe.limits.items()}
    if any(airframe.delays.values()):
        out["delays"] = {k: v for k, v in airframe.delays.items() if v}
    if airframe.atmosphere != "constant":
        out["atmosphere"] = airframe.atmosphere
    if airframe.tables:
        out["tables"] = {n: t.to_file() for n, t in sorted(airframe.tables.items())}
    return out
