"""Malformed airframe parameter files (run by ``tests/test_fuzz.py``): files that are not TOML
or JSON, truncated, binary, oversized, special (FIFO, /dev/zero, folder); wrong top-level
shapes, unknown/missing/duplicated keys, values of the wrong type (a boolean or a string is not
a number), non-finite or physically absurd values, and a ``name`` that is not an identifier
(it is used in file names: ``../../../escaped`` must never reach a command that writes).

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
    return out
