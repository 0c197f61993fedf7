"""Malformed airframe parameter files (run by ``tests/test_fuzz.py``): files that are not TOML
or JSON, truncated, binary, oversized, special (FIFO, /dev/zero, folder); wrong top-level
shapes, unknown/missing/duplicated keys, values of the wrong type (a boolean or a string is not
a number), non-finite or physically absurd values, and a ``name`` that is not an identifier
(it is used in file names: ``../../../escaped`` must never reach a command that writes);
malformed model structure (``[tables]``, ``[delays]``, ``atmosphere``, the optional lag and
inflow parameters), each refused in one line naming the file and the key (:data:`KEYED_CASES`,
which ``tests/test_tables.py`` also reads).

Each case starts from the F450 preset written in TOML or JSON inside its folder and breaks one
thing. Random cases are seeded, so the list is the same on every run.
"""

from __future__ import annotations

import json
import math
import os
import random
from collections.abc import Callable
from pathlib import Path

from fuzz_common import Case

from uavdyn.airframes import AirframeError, load_airframe, to_toml_dict

SEED = 20240612


def base(kind: str = "multirotor") -> dict:
    """The preset of ``kind`` in the file schema (a valid file once written)."""
    return to_toml_dict(load_airframe("f450" if kind == "multirotor" else "aerosonde"))


def _toml_value(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string is a valid TOML basic string
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {_toml_value(v)}"
                               for k, v in value.items()) + "}"
    raise TypeError(f"no TOML form for {value!r}")


def toml_text(data: dict) -> str:
    """A minimal TOML writer for this schema (top-level scalars, then ``[params.X]`` tables)."""
    lines = [f"{json.dumps(k)} = {_toml_value(v)}" for k, v in data.items() if k != "params"]
    params = data.get("params")
    if isinstance(params, dict):
        for name, entry in params.items():
            if isinstance(entry, dict):
                lines.append(f"[params.{json.dumps(name)}]")
                lines += [f"{json.dumps(k)} = {_toml_value(v)}" for k, v in entry.items()]
            else:
                lines.append(f"params.{json.dumps(name)} = {_toml_value(entry)}")
    elif "params" in data:
        lines.insert(0, f"params = {_toml_value(params)}")
    return "\n".join(lines) + "\n"


def load(path: Path) -> object:
    return load_airframe(path)


def cli(path: Path, out: Path) -> list[str]:
    return ["trim", "--airframe", str(path)]


def _case(name: str, build: Callable[[Path], Path], names: str | None = None,
          tags: tuple[str, ...] = ()) -> Case:
    return Case(name=f"airframe: {name}", build=build, load=load, error=AirframeError,
                cli=cli, names=names, tags=tags)


def raw_case(name: str, data: bytes | Callable[[], bytes], suffix: str = ".toml",
             tags: tuple[str, ...] = ("raw",)) -> Case:
    def build(folder: Path) -> Path:
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"plane{suffix}"
        path.write_bytes(data() if callable(data) else data)
        return path

    return _case(name, build, tags=tags)


def data_case(name: str, mutate: Callable[[dict], object], fmt: str = "json",
              kind: str = "multirotor", tags: tuple[str, ...] = ("schema",)) -> Case:
    """The preset, changed by ``mutate`` (in place, or its non-None return), as TOML or JSON."""

    def build(folder: Path) -> Path:
        folder.mkdir(parents=True, exist_ok=True)
        data = base(kind)
        result = mutate(data)
        data = data if result is None else result
        path = folder / f"plane.{fmt}"
        path.write_text(json.dumps(data) if fmt == "json" else toml_text(data))
        return path

    return _case(f"{name} ({fmt})", build, tags=tags)


def special_case(name: str, make: Callable[[Path], None], file: str = "plane.toml") -> Case:
    def build(folder: Path) -> Path:
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / file
        make(path)
        return path

    return _case(name, build, tags=("special",))


def _param(name: str, value: object) -> Callable[[dict], None]:
    def mutate(d: dict) -> None:
        d["params"][name]["value"] = value
    return mutate


def _top(key: str, value: object) -> Callable[[dict], None]:
    def mutate(d: dict) -> None:
        d[key] = value
    return mutate


def _without(key: str) -> Callable[[dict], None]:
    def mutate(d: dict) -> None:
        del d[key]
    return mutate


def _entry(name: str, entry: object) -> Callable[[dict], None]:
    def mutate(d: dict) -> None:
        d["params"][name] = entry
    return mutate


def _sparse(size: int) -> Callable[[Path], None]:
    def make(path: Path) -> None:
        with open(path, "wb") as f:
            f.write(b'name = "big"\n')
            f.truncate(size)
    return make


def _folder(path: Path) -> None:
    path.mkdir()
    (path / "plane.toml").write_text(toml_text(base()))


def cases() -> list[Case]:
    """The airframe loader cases (seeded: the same list on every run)."""
    rng = random.Random(SEED)
    valid_toml = toml_text(base()).encode()
    valid_json = json.dumps(base(), indent=1).encode()
    out: list[Case] = [
        raw_case("empty TOML file", b""),
        raw_case("whitespace-only JSON file", b"  \n\n", ".json"),
        raw_case("NUL byte in TOML", lambda: valid_toml.replace(b"\n", b"\n\x00", 1)),
        raw_case("not UTF-8", lambda: valid_toml.replace(b"f450", b"f\xe950", 1)),
        raw_case("TOML syntax error", b'name = "x"\nkind = "multirotor"\n[params\n'),
        raw_case("TOML duplicated key", lambda: valid_toml.replace(
            b'"kind" = "multirotor"', b'"kind" = "multirotor"\n"kind" = "fixed_wing"', 1)),
        raw_case("TOML integer of 400 digits for mass", lambda: valid_toml.replace(
            b'"value" = 1.4', b'"value" = ' + b"9" * 400, 1)),
        raw_case("TOML nested arrays 100000 deep",
                 b'description = ' + b"[" * 100000 + b"]" * 100000 + b"\n"),
        raw_case("JSON syntax error", b'{"name": "x",\n "kind": }', ".json"),
        raw_case("JSON top level is an array", b"[1, 2, 3]", ".json"),
        raw_case("JSON top level is a string", b'"f450"', ".json"),
        raw_case("JSON duplicated key", lambda: valid_json.replace(
            b'"kind": "multirotor"', b'"kind": "multirotor", "kind": "fixed_wing"', 1), ".json"),
        raw_case("JSON integer of 5000 digits for mass", lambda: valid_json.replace(
            b'"value": 1.4', b'"value": ' + b"9" * 5000, 1), ".json"),
        raw_case("JSON nested 100000 deep",
                 b'{"name": ' + b"[" * 100000 + b"]" * 100000 + b"}", ".json"),
        raw_case("TOML text in a .json file", valid_toml, ".json"),
        raw_case("JSON text in a .toml file", valid_json, ".toml"),
        raw_case("1 MB single line", b"x" * 2**20),
        special_case("path is a folder", _folder),
        special_case("path is a FIFO", lambda p: os.mkfifo(p)),
        special_case("path symlink to /dev/zero", lambda p: os.symlink("/dev/zero", p)),
        special_case("file of 2 MB (sparse)", _sparse(2 * 2**20)),
        special_case("path does not exist", lambda p: None, "missing.toml"),
        special_case("dangling symlink", lambda p: os.symlink("gone.toml", p)),
    ]
    end = valid_toml.rindex(b"[params")  # before the last table: a parameter is missing
    for _ in range(5):
        cut = rng.randrange(1, end)
        out.append(raw_case(f"TOML truncated at byte {cut}", valid_toml[:cut],
                            tags=("raw", "truncation")))
    end = valid_json.rindex(b"}")
    for _ in range(3):
        cut = rng.randrange(1, end)
        out.append(raw_case(f"JSON truncated at byte {cut}", valid_json[:cut], ".json",
                            ("raw", "truncation")))
    for k in range(4):
        blob = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 600)))
        out.append(raw_case(f"random bytes #{k}", blob, (".toml", ".json")[k % 2],
                            ("raw", "random")))

    for key in ("name", "kind", "params"):
        out.append(data_case(f"without '{key}'", _without(key), "toml"))
    for key, value, fmt in [
        ("name", "../../../escaped", "toml"), ("name", "", "json"), ("name", "a b", "toml"),
        ("name", 1, "json"), ("name", "x" * 100, "toml"), ("name", "a/b", "json"),
        ("name", "..", "toml"), ("name", "f450\n", "json"), ("name", None, "json"),
        ("kind", ["multirotor"], "json"), ("kind", "helicopter", "toml"), ("kind", 1, "toml"),
        ("params", 1, "json"), ("params", [1, 2], "json"),
        ("nominal_airspeed", True, "toml"), ("nominal_airspeed", "25", "toml"),
        ("nominal_airspeed", -1.0, "json"), ("nominal_airspeed", 1e9, "json"),
        ("nominal_airspeed", math.nan, "toml"),
        ("description", 5, "toml"), ("colour", "red", "toml"),
    ]:
        out.append(data_case(f"{key} = {value!r:.30}", _top(key, value), fmt))
    for name, value, fmt in [
        ("mass", "1.4", "toml"), ("mass", True, "toml"), ("mass", None, "json"),
        ("mass", [1.4], "json"), ("mass", {"kg": 1.4}, "json"),
        ("mass", math.nan, "json"), ("Jy", math.inf, "toml"), ("arm", -math.inf, "toml"),
        ("mass", 1e308, "toml"), ("mass", 0.0, "json"), ("mass", 1400.0 * 1e3, "json"),
        ("Jy", -1.0, "toml"), ("rho", 1e6, "json"), ("rho", 0.0, "toml"),
        ("gravity", 1.0, "json"), ("gravity", 98.0665, "toml"), ("arm", 1000.0, "json"),
        ("c_T", 1e5, "toml"), ("C_R", -1148.0, "json"), ("pitch_mix", 2.0, "toml"),
        ("CdA_x", -0.02, "json"), ("drag_linear", 1e300, "json"),
    ]:
        out.append(data_case(f"params.{name} = {value!r:.30}", _param(name, value), fmt))
    for name, value in [("alpha0", 3.0), ("e", 5.0), ("M_blend", 1e4), ("C_T0", 1e5),
                        ("C_m_q", -1e3), ("C_D_0", -0.01), ("S_wing", 0.0),
                        ("KV_rpm_per_volt", 1e9), ("b", 150.0), ("V_max", math.inf)]:
        out.append(data_case(f"fixed wing params.{name} = {value!r}", _param(name, value),
                             "toml", "fixed_wing"))
    out += [
        data_case("unknown parameter", lambda d: d["params"].update(wingspan={"value": 1.0}),
                  "toml"),
        data_case("missing parameter", lambda d: d["params"].pop("Jy") and None, "json"),
        data_case("fixed-wing parameters under kind multirotor", lambda d: dict(
            base("fixed_wing"), kind="multirotor"), "toml"),
        data_case("parameter entry without value", _entry("mass", {"source": "x"}), "toml"),
        data_case("parameter entry with an unknown key",
                  _entry("mass", {"value": 1.4, "unit": "kg"}), "json"),
        data_case("parameter source is a number", _entry("mass", {"value": 1.4, "source": 5}),
                  "toml"),
        data_case("parameter entry is a string", _entry("mass", "1.4 kg"), "json"),
        data_case("parameter entry is an array", _entry("mass", [1.4]), "toml"),
    ]
    out += [keyed_case(*case) for case in KEYED_CASES]
    return out


def _table(name: str, entry: object) -> Callable[[dict], None]:
    def mutate(d: dict) -> None:
        d.setdefault("tables", {})[name] = entry
    return mutate


def _tables(value: object) -> Callable[[dict], None]:
    return _top("tables", value)


def _delay(control: str, value: object) -> Callable[[dict], None]:
    def mutate(d: dict) -> None:
        d.setdefault("delays", {})[control] = value
    return mutate


def _bad_values(name: str, key: str, index: int, value: object,
                entry: dict | None = None) -> Callable[[dict], None]:
    """A valid table (default: C_L over three alphas) with one number replaced."""
    def mutate(d: dict) -> None:
        table = json.loads(json.dumps(entry or GOOD_TABLE))
        table[key][index] = value
        d.setdefault("tables", {})[name] = table
    return mutate


def _optional(name: str, value: object) -> Callable[[dict], None]:
    return _entry(name, {"value": value})


GOOD_TABLE = {"alpha": [-0.2, 0.0, 0.2], "values": [-0.9, 0.23, 1.35]}
GOOD_2D = {"alpha": [-0.2, 0.0, 0.2], "elevator": [-0.3, 0.3],
           "values": [[0.5, 0.3], [0.1, -0.2], [-0.3, -0.6]]}
GOOD_THRUST = {"airspeed": [0.0, 20.0], "throttle": [0.0, 1.0], "values": [[0.0, 50.0],
                                                                              [0.0, 30.0]]}

# (description, mutate, key the message must name, format, kind): the structure keys.
KEYED_CASES: list[tuple[str, Callable[[dict], object], str, str, str]] = [
    ("breakpoints repeated", _table("C_L", {"alpha": [-0.2, 0.1, 0.1], "values": [0, 1, 2]}),
     "tables.C_L.alpha", "toml", "fixed_wing"),
    ("breakpoints decreasing", _table("C_D", {"alpha": [0.2, 0.0, -0.2],
                                              "values": [0.1, 0.05, 0.1]}),
     "tables.C_D.alpha", "json", "fixed_wing"),
    ("one breakpoint", _table("C_L", {"alpha": [0.0], "values": [0.2]}), "tables.C_L.alpha",
     "toml", "fixed_wing"),
    ("no breakpoint", _table("C_L", {"alpha": [], "values": []}), "tables.C_L.alpha", "json",
     "fixed_wing"),
    ("201 breakpoints", _table("C_m", {"alpha": [i * 0.01 - 1.0 for i in range(201)],
                                       "values": [0.0] * 201}),
     "tables.C_m.alpha", "json", "fixed_wing"),
    ("alpha breakpoints in degrees", _table("C_L", {"alpha": [-10.0, 0.0, 10.0],
                                                    "values": [-0.3, 0.2, 0.9]}),
     "tables.C_L.alpha", "toml", "fixed_wing"),
    ("breakpoints are a string", _table("C_L", {"alpha": "-0.2, 0, 0.2", "values": [0, 1, 2]}),
     "tables.C_L.alpha", "toml", "fixed_wing"),
    ("breakpoint is a string", _bad_values("C_L", "alpha", 1, "0.0"), "tables.C_L.alpha[1]",
     "json", "fixed_wing"),
    ("breakpoint is a boolean", _bad_values("C_L", "alpha", 0, True), "tables.C_L.alpha[0]",
     "toml", "fixed_wing"),
    ("breakpoint is inf", _bad_values("C_L", "alpha", 2, math.inf), "tables.C_L.alpha[2]",
     "toml", "fixed_wing"),
    ("breakpoint is nan", _bad_values("C_L", "alpha", 1, math.nan), "tables.C_L.alpha[1]",
     "toml", "fixed_wing"),
    ("value is nan", _bad_values("C_L", "values", 1, math.nan), "tables.C_L.values[1]",
     "toml", "fixed_wing"),
    ("value is -inf", _bad_values("C_D", "values", 0, -math.inf), "tables.C_D.values[0]",
     "toml", "fixed_wing"),
    ("value is an integer of 400 digits", _bad_values("C_L", "values", 2, 10**400),
     "tables.C_L.values[2]", "json", "fixed_wing"),
    ("value is a boolean", _bad_values("C_m", "values", 0, False), "tables.C_m.values[0]",
     "toml", "fixed_wing"),
    ("value is a string", _bad_values("C_L", "values", 1, "0.23"), "tables.C_L.values[1]",
     "json", "fixed_wing"),
    ("value is null", _bad_values("C_L", "values", 1, None), "tables.C_L.values[1]",
     "json", "fixed_wing"),
    ("value beyond the coefficient limit", _bad_values("C_L", "values", 1, 2000.0),
     "tables.C_L.values", "toml", "fixed_wing"),
    ("too few values", _table("C_L", {"alpha": [-0.2, 0.0, 0.2], "values": [0.0, 1.0]}),
     "tables.C_L.values", "toml", "fixed_wing"),
    ("too many values", _table("C_L", {"alpha": [-0.2, 0.0, 0.2], "values": [0, 1, 2, 3]}),
     "tables.C_L.values", "json", "fixed_wing"),
    ("1-D values given as rows", _table("C_L", {"alpha": [-0.2, 0.0, 0.2],
                                                "values": [[0.0, 1.0, 2.0]]}),
     "tables.C_L.values[0]", "toml", "fixed_wing"),
    ("2-D table with too few rows", _table("C_m", dict(GOOD_2D, values=GOOD_2D["values"][:2])),
     "tables.C_m.values", "toml", "fixed_wing"),
    ("2-D table with too many rows", _table(
        "C_m", dict(GOOD_2D, values=GOOD_2D["values"] + [[0.0, 0.0]])),
     "tables.C_m.values", "json", "fixed_wing"),
    ("2-D table with a short row", _table(
        "C_m", dict(GOOD_2D, values=[[0.5, 0.3], [0.1], [-0.3, -0.6]])),
     "tables.C_m.values[1]", "toml", "fixed_wing"),
    ("2-D table with flat values", _table(
        "C_m", dict(GOOD_2D, values=[0.5, 0.3, 0.1, -0.2, -0.3, -0.6])),
     "tables.C_m.values", "json", "fixed_wing"),
    ("2-D table value is nan", _table(
        "C_L", dict(GOOD_2D, values=[[0.5, 0.3], [0.1, math.nan], [-0.3, -0.6]])),
     "tables.C_L.values[1][1]", "toml", "fixed_wing"),
    ("2-D table with both second axes", _table(
        "C_m", dict(GOOD_2D, airspeed=[10.0, 30.0])), "tables.C_m", "toml", "fixed_wing"),
    ("elevator breakpoints in degrees", _table(
        "C_m", dict(GOOD_2D, elevator=[-20.0, 20.0])), "tables.C_m.elevator", "toml",
     "fixed_wing"),
    ("unknown table name", _table("C_Y", GOOD_TABLE), "tables.C_Y", "toml", "fixed_wing"),
    ("unknown axis name", _table("C_L", dict(GOOD_TABLE, mach=[0.1, 0.2])), "tables.C_L.mach",
     "json", "fixed_wing"),
    ("thrust table over alpha", _table("thrust", GOOD_TABLE), "tables.thrust.alpha", "toml",
     "fixed_wing"),
    ("C_L table over throttle", _table("C_L", dict(GOOD_TABLE, throttle=[0.0, 1.0])),
     "tables.C_L.throttle", "toml", "fixed_wing"),
    ("table without values", _table("C_D", {"alpha": [0.0, 0.1]}), "tables.C_D.values",
     "toml", "fixed_wing"),
    ("table without its first axis", _table("C_D", {"values": [0.0, 0.1]}),
     "tables.C_D.alpha", "json", "fixed_wing"),
    ("thrust table without throttle", _table(
        "thrust", {"airspeed": [0.0, 20.0], "values": [10.0, 5.0]}),
     "tables.thrust.throttle", "toml", "fixed_wing"),
    ("thrust table with negative airspeed", _table(
        "thrust", dict(GOOD_THRUST, airspeed=[-5.0, 20.0])), "tables.thrust.airspeed", "json",
     "fixed_wing"),
    ("thrust table with throttle in percent", _table(
        "thrust", dict(GOOD_THRUST, throttle=[0.0, 100.0])), "tables.thrust.throttle", "toml",
     "fixed_wing"),
    ("thrust value beyond 1e7 N", _table(
        "thrust", dict(GOOD_THRUST, values=[[0.0, 1e8], [0.0, 30.0]])),
     "tables.thrust.values", "json", "fixed_wing"),
    ("a table is an array", _table("C_L", [[-0.2, 0.0], [0.23, 1.35]]), "tables.C_L", "toml",
     "fixed_wing"),
    ("tables is a number", _tables(5), "'tables'", "toml", "fixed_wing"),
    ("tables on a multirotor", _table("C_L", GOOD_TABLE), "'tables'", "toml", "multirotor"),
    ("delay is a fraction", _delay("elevator", 1.5), "delays.elevator", "toml", "fixed_wing"),
    ("delay is a float", _delay("throttle", 2.0), "delays.throttle", "json", "fixed_wing"),
    ("delay is negative", _delay("elevator", -1), "delays.elevator", "toml", "fixed_wing"),
    ("delay above 50 samples", _delay("elevator", 51), "delays.elevator", "json",
     "fixed_wing"),
    ("delay of 10**30 samples", _delay("collective", 10**30), "delays.collective", "json",
     "multirotor"),
    ("delay is a boolean", _delay("pitch_cmd", True), "delays.pitch_cmd", "toml",
     "multirotor"),
    ("delay is a string", _delay("elevator", "2"), "delays.elevator", "toml", "fixed_wing"),
    ("delay is nan", _delay("elevator", math.nan), "delays.elevator", "toml", "fixed_wing"),
    ("delay of an unknown control", _delay("rudder", 1), "delays.rudder", "toml",
     "fixed_wing"),
    ("delay of the other kind's control", _delay("elevator", 1), "delays.elevator", "json",
     "multirotor"),
    ("delays is a number", _top("delays", 2), "'delays'", "toml", "fixed_wing"),
    ("atmosphere in capitals", _top("atmosphere", "ISA"), "'atmosphere'", "toml",
     "fixed_wing"),
    ("atmosphere unknown", _top("atmosphere", "standard"), "'atmosphere'", "json",
     "multirotor"),
    ("atmosphere is a boolean", _top("atmosphere", True), "'atmosphere'", "toml",
     "fixed_wing"),
    ("atmosphere is an array", _top("atmosphere", ["isa"]), "'atmosphere'", "json",
     "fixed_wing"),
    ("tau_elevator negative", _optional("tau_elevator", -0.05), "'tau_elevator'", "toml",
     "fixed_wing"),
    ("tau_throttle of 20 s", _optional("tau_throttle", 20.0), "'tau_throttle'", "json",
     "fixed_wing"),
    ("tau_elevator is a string", _optional("tau_elevator", "0.05"), "'tau_elevator'", "toml",
     "fixed_wing"),
    ("tau_rotor is nan", _optional("tau_rotor", math.nan), "'tau_rotor'", "toml",
     "multirotor"),
    ("tau_rotor is a boolean", _optional("tau_rotor", True), "'tau_rotor'", "json",
     "multirotor"),
    ("k_inflow negative", _optional("k_inflow", -1e-4), "'k_inflow'", "toml", "multirotor"),
    ("k_inflow is inf", _optional("k_inflow", math.inf), "'k_inflow'", "toml", "multirotor"),
    ("M_u is nan", _optional("M_u", math.nan), "'M_u'", "toml", "multirotor"),
    ("M_0 is a string", _optional("M_0", "0.1"), "'M_0'", "json", "multirotor"),
    ("M_u on a fixed wing", _optional("M_u", 0.01), "M_u", "toml", "fixed_wing"),
    ("tau_rotor on a fixed wing", _optional("tau_rotor", 0.05), "tau_rotor", "toml",
     "fixed_wing"),
    ("k_inflow on a fixed wing", _optional("k_inflow", 1e-4), "k_inflow", "json",
     "fixed_wing"),
    ("tau_elevator on a multirotor", _optional("tau_elevator", 0.05), "tau_elevator", "toml",
     "multirotor"),
]


def _load_naming_file(path: Path) -> object:
    """``load_airframe``, and the error must name the file as well as the key."""
    try:
        return load_airframe(path)
    except AirframeError as exc:
        if path.name not in str(exc):
            raise AssertionError(f"message does not name {path.name}: {exc}") from exc
        raise


def keyed_case(name: str, mutate: Callable[[dict], object], key: str, fmt: str,
               kind: str) -> Case:
    """A structure case: the message must name ``key`` and the file."""
    case = data_case(f"{kind} {name}", mutate, fmt, kind, tags=("schema", "structure"))
    case.names = key
    case.load = _load_naming_file
    return case
