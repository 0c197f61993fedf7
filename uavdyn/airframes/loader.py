"""Reading and writing airframe parameter files (TOML/JSON): the file schema and its checks.

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
lag is the engine's power lag in front of the thrust model or table) and ``slew_elevator``,
``slew_throttle`` (1 / the actuator's rate limit, s per unit; 0 = none). Multirotor: ``tau_rotor``
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
    relaxed_stability = true   # statically unstable by design: identification lets C_m_alpha
                               # take either sign (default false: C_m_alpha < 0 in a fit;
                               # uavdyn.airframes.bounds.SIGNS)
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

import json
import os
import re
import sys
from collections.abc import Iterable
from importlib import resources
from pathlib import Path

from uavdyn.airframes.airframe import Airframe
from uavdyn.airframes.bounds import _as_number, _check_values
from uavdyn.airframes.errors import AirframeError, _display, _short
from uavdyn.airframes.limits import _parse_delays, _parse_limits
from uavdyn.airframes.params import (
    KINDS,
    LATERAL_PARAMS,
    OPTIONAL_PARAMS,
    PARAM_CLASSES,
    param_names,
)
from uavdyn.airframes.plausibility import check_plausible
from uavdyn.airframes.presets import ALIASES, PRESETS, list_presets
from uavdyn.airframes.tables import TableError, parse_tables
from uavdyn.safefiles import DuplicateKey, UnreadableFile, no_duplicate_keys, read_regular

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

AIRFRAME_MAX_BYTES = 2**20          # a parameter file with sources is a few kB
NOMINAL_AIRSPEED_MAX = 150.0        # m/s; the flight-data speed limit is 100 m/s
NAME_PATTERN = re.compile(r"[A-Za-z0-9_-]{1,64}")
TOP_LEVEL_KEYS = ("name", "kind", "params", "description", "nominal_airspeed", "limits",
                  "delays", "atmosphere", "tables", "relaxed_stability")
ATMOSPHERES = ("constant", "isa")
PARAM_ENTRY_KEYS = ("value", "source")


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


def load_airframe(name_or_path: str | Path, strict: bool = False) -> Airframe:
    """Load a preset by name or a user's own TOML/JSON parameter file of the same schema.

    Values within their bounds but implausible as a whole (a mass in grams, a derivative per
    degree: :mod:`uavdyn.airframes.plausibility`) give one
    :class:`~uavdyn.airframes.plausibility.AirframePlausibilityWarning` each, naming the
    parameter and the likely slip, or an error with ``strict``.

    Parameters
    ----------
    name_or_path : str or Path
        A preset (``aerosonde``, ``f450``, or the aliases ``quadrotor``/``fixed_wing``) or the
        path of a parameter file (``.json`` is read as JSON, anything else as TOML).
    strict : bool
        Refuse implausible values instead of warning.

    Returns
    -------
    Airframe

    Raises
    ------
    AirframeError
        On one line naming the file and the key: unreadable, oversized or special files,
        parse errors (with the line), unknown or missing keys, wrong types, values outside
        :data:`BOUNDS`, a ``name`` that is not an identifier; with ``strict``, implausible
        values.
    """
    airframe = _load(name_or_path)
    check_plausible(airframe, strict)
    return airframe


def _load(name_or_path: str | Path) -> Airframe:
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


def _parse(data: dict, origin: str) -> Airframe:
    """Build an :class:`Airframe` from parsed TOML/JSON, checking keys, types and bounds."""
    kind, name, description = _parse_top(data, origin)
    values, sources = _parse_params(data["params"], kind, origin)
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
    relaxed = data.get("relaxed_stability", False)
    if not isinstance(relaxed, bool):
        raise AirframeError(f"{origin}: key 'relaxed_stability' must be true or false, got "
                            f"{_short(relaxed)}")
    try:
        tables = parse_tables(data["tables"], kind, origin) if "tables" in data else {}
    except TableError as exc:
        raise AirframeError(str(exc)) from None
    return Airframe(
        name=name, kind=kind, params=PARAM_CLASSES[kind](**values), sources=sources,
        description=description, nominal_airspeed=float(nominal), origin=origin, limits=limits,
        delays=delays, atmosphere=atmosphere, tables=tables, relaxed_stability=relaxed,
    )


def _parse_top(data: object, origin: str) -> tuple[str, str, str]:
    """The file's ``kind``, ``name`` and ``description``, with the top level's keys checked."""
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
    return kind, name, description


def _parse_params(raw: object, kind: str, origin: str
                  ) -> tuple[dict[str, float], dict[str, str]]:
    """The ``params`` table: every parameter of the kind as a typed value within its bound, and
    its source (an optional parameter left out takes its default)."""
    if not isinstance(raw, dict):
        raise AirframeError(f"{origin}: key 'params' must be a table of parameters, got "
                            f"{_short(raw)}")
    names = param_names(kind) + LATERAL_PARAMS
    unknown = set(raw) - set(names)
    if unknown:
        raise AirframeError(f"{origin}: unknown parameter key(s) {_key_list(unknown)} for kind "
                            f"'{kind}'")
    optional = {**OPTIONAL_PARAMS[kind], **dict.fromkeys(LATERAL_PARAMS, 0.0)}
    missing = [n for n in names if n not in raw and n not in optional]
    if missing:
        raise AirframeError(f"{origin}: missing parameter key(s) {missing}")
    values: dict[str, float] = {}
    sources: dict[str, str] = {}
    for name_ in names:
        if name_ not in raw:
            values[name_] = float(optional[name_])
            sources[name_] = (f"optional key not set: default {optional[name_]!r} (no effect)"
                              if name_ not in LATERAL_PARAMS else
                              "optional key not set (needed only with turning-flight inputs)")
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
    return values, sources


def to_toml_dict(airframe: Airframe) -> dict:
    """The airframe in the file schema (for writing a user's own copy to edit)."""
    out = {
        "name": airframe.name, "kind": airframe.kind, "description": airframe.description,
        "nominal_airspeed": airframe.nominal_airspeed,
        "params": {n: {"value": getattr(airframe.params, n), "source": airframe.sources.get(n, "")}
                   for n in param_names(airframe.kind)},
    }
    for n in LATERAL_PARAMS:  # written only when set, so a preset's copy is unchanged
        if getattr(airframe.params, n) != 0.0:
            out["params"][n] = {"value": getattr(airframe.params, n),
                                "source": airframe.sources.get(n, "")}
    if airframe.limits:  # written only when set, so a preset's copy is unchanged
        out["limits"] = {k: list(v) if isinstance(v, tuple) else v
                         for k, v in airframe.limits.items()}
    if any(airframe.delays.values()):
        out["delays"] = {k: v for k, v in airframe.delays.items() if v}
    if airframe.atmosphere != "constant":
        out["atmosphere"] = airframe.atmosphere
    if airframe.relaxed_stability:
        out["relaxed_stability"] = True
    if airframe.tables:
        out["tables"] = {n: t.to_file() for n, t in sorted(airframe.tables.items())}
    return out
