"""Hardened loaders (SPEC section 9): the dataset loader reads only regular files inside the
dataset folder, bounded in size and checked before they are opened, and reports every problem
as one ``FlightDataError`` line naming the file and the row, column or manifest key; the
airframe loader types and range-checks every value against a documented bounds table and
refuses a ``name`` that is not an identifier. File opens are watched with an audit hook, so
"refused without opening it" is checked, not assumed."""

from __future__ import annotations

import contextlib
import json
import math
import os
import sys
import threading
from collections.abc import Callable, Iterator
from importlib import resources
from pathlib import Path

import fuzz_airframe
import fuzz_dataset
import numpy as np
import pytest
from fuzz_dataset import (
    HEADER,
    SENTINEL,
    base_manifest,
    csv_text,
    valid_rows,
    write_dataset,
    write_manifest,
    write_sentinel,
)

import uavdyn.airframes as airframes
import uavdyn.flightdata.csvio as csvio
import uavdyn.flightdata.dataset as dataset
import uavdyn.flightdata.manifest as manifest
from uavdyn.airframes import (
    BOUNDS,
    OPTIONAL_PARAMS,
    AirframeError,
    list_presets,
    load_airframe,
    param_names,
    perturb,
    to_toml_dict,
)
from uavdyn.cli import main
from uavdyn.flightdata import FlightDataError, load_dataset, read_csv, read_manifest

tomllib = airframes.tomllib  # the standard library's on 3.11+, tomli on 3.10

# ----------------------------------------------------------------------------- helpers

_RECORDING: list[list[str]] = []


def _audit(event: str, args: tuple) -> None:
    if event == "open" and _RECORDING and isinstance(args[0], (str, bytes, os.PathLike)):
        try:
            _RECORDING[-1].append(os.path.realpath(os.fsdecode(args[0])))
        except (TypeError, ValueError):
            pass


sys.addaudithook(_audit)  # permanent, but it only records inside `opened()`


@contextlib.contextmanager
def opened() -> Iterator[list[str]]:
    """Record the (resolved) path of every file opened in this process meanwhile."""
    record: list[str] = []
    _RECORDING.append(record)
    try:
        yield record
    finally:
        _RECORDING.remove(record)


def _with_timeout(call: Callable[[], object], unblock: Path | None = None,
                  seconds: float = 20.0) -> BaseException | None:
    """Run ``call`` in a thread: a loader that opened a FIFO would block for ever. Returns the
    exception raised (None if none); fails if the call is still running after ``seconds``."""
    result: dict[str, BaseException | None] = {}

    def run() -> None:
        try:
            call()
            result["exc"] = None
        except BaseException as exc:  # noqa: BLE001 - handed back to the test
            result["exc"] = exc

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(seconds)
    if thread.is_alive():
        if unblock is not None:  # release the blocked reader, then fail
            fd = os.open(unblock, os.O_WRONLY | os.O_NONBLOCK)
            os.close(fd)
        pytest.fail(f"the loader blocked for more than {seconds} s")
    return result["exc"]


def _fails(call: Callable[[], object], error: type = FlightDataError) -> str:
    with pytest.raises(error) as info:
        call()
    message = str(info.value)
    assert "\n" not in message
    return message


def _inside(path: str, folder: Path) -> bool:
    real = os.path.realpath(folder)
    return os.path.commonpath([real, path]) == real


@pytest.fixture
def ds(tmp_path: Path) -> Path:
    """A valid two-sortie dataset in its own folder, with the sentinel in the parent."""
    folder = write_dataset(tmp_path / "ds")
    write_sentinel(folder)
    return folder


def _manifest_with(folder: Path, change: Callable[[dict], None]) -> None:
    m = base_manifest()
    change(m)
    write_manifest(folder, m)


# ----------------------------------------------------------------------------- the premise


def test_fixture_dataset_and_sentinel_are_valid(ds):
    """The fuzz cases' premise: the base dataset loads, and so would the sentinel."""
    loaded = load_dataset(ds)
    assert [s.name for s in loaded.sorties] == ["s0", "s1"]
    assert loaded.sorties[0].true_states is not None
    sentinel = ds.parent / SENTINEL
    assert load_dataset(sentinel).sorties[0].time.shape == (fuzz_dataset.ROWS,)
    assert read_manifest(ds / "manifest.json")["kind"] == "multirotor"


# ----------------------------------------------------------------------------- path escapes


@pytest.mark.parametrize("key", ["file", "true_file"])
@pytest.mark.parametrize("value", ["../" + SENTINEL, "sub/../../" + SENTINEL,
                                   "../../../../etc/passwd", "..", "a/../s0.csv"])
def test_dotdot_is_refused(ds, key, value):
    _manifest_with(ds, lambda m: m["sorties"][0].update({key: value}))
    with opened() as files:
        msg = _fails(lambda: load_dataset(ds))
    assert f"sorties[0].{key}" in msg and "'..'" in msg and "manifest.json" in msg
    assert all(_inside(f, ds) for f in files), files


@pytest.mark.parametrize("key", ["file", "true_file"])
def test_absolute_paths_are_refused(ds, key):
    for value in (str(ds.parent / SENTINEL), "/etc/passwd", "/dev/zero", "C:/data/s0.csv",
                  str(ds / "s0.csv")):  # even one that points inside: absolute is refused
        _manifest_with(ds, lambda m, v=value: m["sorties"][0].update({key: v}))
        with opened() as files:
            msg = _fails(lambda: load_dataset(ds))
        assert f"sorties[0].{key}" in msg and "absolute path" in msg, msg
        assert all(_inside(f, ds) for f in files), files


def test_escaping_symlinks_are_refused(ds):
    (ds / "s0.csv").unlink()
    os.symlink(f"../{SENTINEL}", ds / "s0.csv")
    with opened() as files:
        msg = _fails(lambda: load_dataset(ds))
    assert "sorties[0].file" in msg and "outside the dataset folder" in msg
    assert not any(SENTINEL in f for f in files)
    # a chain of links that ends outside, and a folder link to the parent
    (ds / "s0.csv").unlink()
    os.symlink(f"../{SENTINEL}", ds / "hop.csv")
    os.symlink("hop.csv", ds / "s0.csv")
    assert "outside the dataset folder" in _fails(lambda: load_dataset(ds))
    (ds / "s0.csv").unlink()
    (ds / "s0.csv").write_text(csv_text(valid_rows()))
    os.symlink("..", ds / "up")
    _manifest_with(ds, lambda m: m["sorties"][1].update(file=f"up/{SENTINEL}"))
    assert "sorties[1].file" in _fails(lambda: load_dataset(ds))
    # the manifest itself
    (ds / "manifest.json").unlink()
    os.symlink(f"../{SENTINEL}", ds / "manifest.json")
    with opened() as files:
        msg = _fails(lambda: load_dataset(ds))
    assert "manifest.json" in msg and "outside the dataset folder" in msg
    assert not any(SENTINEL in f for f in files)


def test_symlinks_inside_the_folder_are_followed(tmp_path):
    real = write_dataset(tmp_path / "real")
    (real / "data").mkdir()
    os.replace(real / "s1.csv", real / "data" / "s1_recorded.csv")
    os.symlink("data/s1_recorded.csv", real / "s1.csv")
    loaded = load_dataset(real)
    np.testing.assert_array_equal(loaded.sorties[1].to_array(), valid_rows(phase=0.5))
    os.symlink(real, tmp_path / "alias")  # the folder given may itself be a link
    assert len(load_dataset(tmp_path / "alias").sorties) == 2


def test_sentinel_is_never_opened_by_any_escape_case(tmp_path):
    """Every fuzz case tagged 'escape' fails without opening the (valid) sentinel."""
    escapes = [c for c in fuzz_dataset.cases() if "escape" in c.tags]
    assert len(escapes) >= 8
    for k, case in enumerate(escapes):
        folder = tmp_path / f"c{k}" / "case"
        folder.parent.mkdir()
        path = case.build(folder)
        assert (folder.parent / SENTINEL).exists()
        with opened() as files:
            msg = _fails(lambda p=path, c=case: c.load(p))
        assert case.names in msg, (case.name, msg)
        assert not any(SENTINEL in f or f.startswith("/etc/") for f in files), case.name


# ----------------------------------------------------------------------------- special files


def test_fifo_is_refused_without_blocking(ds, tmp_path):
    (ds / "s1.csv").unlink()
    os.mkfifo(ds / "s1.csv")
    with opened() as files:
        exc = _with_timeout(lambda: load_dataset(ds), unblock=ds / "s1.csv")
    assert isinstance(exc, FlightDataError) and "FIFO" in str(exc) and "s1.csv" in str(exc)
    assert "sorties[1].file" in str(exc)
    assert os.path.realpath(ds / "s1.csv") not in files
    # given directly, as a manifest, and as an airframe file
    os.mkfifo(tmp_path / "pipe.csv")
    exc = _with_timeout(lambda: load_dataset(tmp_path / "pipe.csv"), tmp_path / "pipe.csv")
    assert isinstance(exc, FlightDataError) and "FIFO" in str(exc)
    exc = _with_timeout(lambda: read_csv(tmp_path / "pipe.csv"), tmp_path / "pipe.csv")
    assert isinstance(exc, FlightDataError) and "FIFO" in str(exc)
    (ds / "manifest.json").unlink()
    os.mkfifo(ds / "manifest.json")
    exc = _with_timeout(lambda: load_dataset(ds), ds / "manifest.json")
    assert isinstance(exc, FlightDataError) and "manifest.json" in str(exc)
    os.mkfifo(tmp_path / "plane.toml")
    with opened() as files:
        exc = _with_timeout(lambda: load_airframe(tmp_path / "plane.toml"),
                            tmp_path / "plane.toml")
    assert isinstance(exc, AirframeError) and "FIFO" in str(exc)
    assert os.path.realpath(tmp_path / "plane.toml") not in files


def test_dev_zero_is_refused_without_reading(ds, tmp_path):
    if not os.path.exists("/dev/zero"):
        pytest.skip("no /dev/zero")
    with opened() as files:
        msg = _fails(lambda: read_csv("/dev/zero"))
        assert "character device" in msg and "/dev/zero" in msg
        os.symlink("/dev/zero", tmp_path / "zero.csv")
        assert "character device" in _fails(lambda: load_dataset(tmp_path / "zero.csv"))
        assert "character device" in _fails(lambda: load_airframe(tmp_path / "zero.csv"),
                                            AirframeError)
        (ds / "s0.csv").unlink()
        os.symlink("/dev/zero", ds / "s0.csv")  # in a manifest: outside the folder anyway
        assert "sorties[0].file" in _fails(lambda: load_dataset(ds))
    assert "/dev/zero" not in files


def test_folder_where_a_file_is_expected(ds):
    (ds / "s1.csv").unlink()
    (ds / "s1.csv").mkdir()
    msg = _fails(lambda: load_dataset(ds))
    assert "s1.csv: is a folder" in msg and "sorties[1].file" in msg
    assert "is a folder" in _fails(lambda: read_csv(ds / "s1.csv"))


def test_size_bounds_are_checked_before_reading(ds, tmp_path, monkeypatch):
    assert dataset.MANIFEST_MAX_BYTES == 10 * 2**20 and dataset.CSV_MAX_BYTES == 512 * 2**20
    big = tmp_path / "big.csv"
    with open(big, "wb") as f:  # sparse: no disk space used
        f.write((HEADER + "\n").encode())
        f.truncate(dataset.CSV_MAX_BYTES + 1)
    with opened() as files:
        msg = _fails(lambda: load_dataset(big))
    assert "more than the 536870912-byte limit" in msg and str(os.path.realpath(big)) \
        not in files
    monkeypatch.setattr(csvio, "CSV_MAX_BYTES", 1000)  # read where it is used
    msg = _fails(lambda: load_dataset(ds))
    assert "s0.csv" in msg and "1000-byte limit" in msg
    monkeypatch.setattr(manifest, "MANIFEST_MAX_BYTES", 100)  # read where it is used
    msg = _fails(lambda: load_dataset(ds))
    assert "manifest.json" in msg and "100-byte limit" in msg
    plane = tmp_path / "plane.json"
    plane.write_text(json.dumps(to_toml_dict(load_airframe("f450"))))
    monkeypatch.setattr(airframes.loader, "AIRFRAME_MAX_BYTES", 100)  # read where it is used
    assert "100-byte limit" in _fails(lambda: load_airframe(plane), AirframeError)


# ----------------------------------------------------------------------------- manifest


def _four_sorties(folder: Path) -> dict:
    for k in range(2, 4):
        (folder / f"s{k}.csv").write_text(csv_text(valid_rows(phase=k)))
    m = base_manifest()
    m["sorties"] += [{"file": f"s{k}.csv", "mission": "loiter", "duration_s": 1.0}
                     for k in range(2, 4)]
    return m


@pytest.mark.parametrize("change, expected", [
    (lambda m: m["sorties"][3].update(file=7), "sorties[3].file: expected a string, got number"),
    (lambda m: m["sorties"][3].update(file="../x.csv"), "sorties[3].file: path '../x.csv'"),
    (lambda m: m["sorties"][3].update(duration_s=True),
     "sorties[3].duration_s: expected a number, got boolean"),
    (lambda m: m["sorties"][3].update(duration_s=float("nan")), "sorties[3].duration_s: nan"),
    (lambda m: m["sorties"][3].update(mission=None), "sorties[3].mission: expected a string"),
    (lambda m: m["sorties"][3].update(split="holdout"), "sorties[3].split"),
    (lambda m: m["sorties"][3].update(rows=True), "sorties[3].rows"),
    (lambda m: m["sorties"].__setitem__(3, "s3.csv"), "sorties[3] must be an object"),
    (lambda m: m["sorties"][3].update(file="s1.csv"),
     "sorties[3].file: 's1.csv' is the same file as sorties[1].file"),
    (lambda m: m["sorties"][3].update(file="sub/s2.csv"),
     "sortie name 's2' (the file name without extension) is already used by sorties[2].file"),
    (lambda m: m.update(sample_rate_hz=True), "key 'sample_rate_hz': expected a positive number"),
    (lambda m: m.update(sample_rate_hz=float("inf")), "key 'sample_rate_hz': inf is not a finite"),
    (lambda m: m.update(sample_rate_hz=-100), "key 'sample_rate_hz': -100.0 is not a positive"),
    (lambda m: m.update(sorties={"file": "s0.csv"}), "key 'sorties' must be a non-empty array"),
    (lambda m: m.update(sorties=[]), "got an empty array"),
    (lambda m: m.update(kind=["multirotor"]), "key 'kind': expected a string, got array"),
    (lambda m: m.update(airframe="../../../escaped"), "key 'airframe': '../../../escaped' is not"),
    (lambda m: m.update(airframe=".f450"), "key 'airframe': '.f450' is not an airframe name"),
    (lambda m: m.update(source=None), "key 'source': expected a string, got null"),
])
def test_manifest_values_are_typed_and_named_by_key_path(ds, change, expected):
    m = _four_sorties(ds)
    change(m)
    write_manifest(ds, m)
    msg = _fails(lambda: load_dataset(ds))
    assert expected in msg and "manifest.json" in msg, msg
    assert _fails(lambda: read_manifest(ds / "manifest.json")) == msg


def test_manifest_optional_values_are_checked_and_extra_keys_kept(ds):
    m = _four_sorties(ds)
    m["sorties"][2].update(altitude_m=120.0, condition="calm", rows=fuzz_dataset.ROWS)
    m["recipe"] = {"seed": 3}
    write_manifest(ds, m)
    loaded = load_dataset(ds)
    assert loaded.manifest["recipe"] == {"seed": 3}
    assert loaded.sorties[2].meta["condition"] == "calm"
    m["sorties"][2]["rows"] = 100
    write_manifest(ds, m)
    msg = _fails(lambda: load_dataset(ds))
    assert "s2.csv" in msg and "rows 100 (sorties[2].rows)" in msg and "101 data rows" in msg
    m["airframe"] = ""  # "not stated" (what a single-CSV dataset exports) is allowed
    m["sorties"][2]["rows"] = fuzz_dataset.ROWS
    write_manifest(ds, m)
    assert load_dataset(ds).manifest["airframe"] == ""


@pytest.mark.parametrize("raw, expected", [
    (b"", "empty file"),
    (b"\xff\xfe{\x00}", "not a text JSON file"),
    (b'{"a": 1,\n "a": 2}', "key 'a' appears twice"),
    (b"[" * 50000 + b"]" * 50000, "nested too deeply"),
    (b'{"airframe": "f450",\n "kind": }', "line 2, column 10: invalid JSON"),
    (b'{"x": ' + b"7" * 5000 + b"}", "a number has too many digits"),
    (b"[1, 2]", "must be a JSON object, not array"),
])
def test_manifest_json_problems(ds, raw, expected):
    (ds / "manifest.json").write_bytes(raw)
    msg = _fails(lambda: load_dataset(ds))
    assert expected in msg and "manifest.json" in msg


def test_manifest_nesting_bound(ds):
    m = base_manifest()
    value: object = 1
    for _ in range(dataset.MANIFEST_MAX_DEPTH):
        value = [value]
    m["notes"] = value  # depth MAX_DEPTH + 1 counting the top object
    write_manifest(ds, m)
    assert "nested too deeply" in _fails(lambda: load_dataset(ds))
    m["notes"] = value[0]
    write_manifest(ds, m)
    load_dataset(ds)


# ----------------------------------------------------------------------------- CSV content


def test_non_csv_content_is_never_echoed(tmp_path):
    secret = "root:x:0:0:root:/root:/bin/bash"
    (tmp_path / "passwd.csv").write_text(secret + "\nother:x:1:1::/:/bin/sh\n")
    msg = _fails(lambda: read_csv(tmp_path / "passwd.csv"))
    assert "not a CSV file with the expected header" in msg
    assert "root" not in msg.replace(str(tmp_path), "") and "bin/bash" not in msg
    (tmp_path / "wide.csv").write_text("k," * 100000 + "\n1,2\n")
    msg = _fails(lambda: read_csv(tmp_path / "wide.csv"))
    assert len(msg) < len(str(tmp_path)) + 300
    rows = csv_text(valid_rows()).splitlines()
    rows[5] = rows[5].replace(rows[5].split(",")[2], "TOKEN_" + "z" * 500, 1)
    (tmp_path / "cell.csv").write_text("\n".join(rows) + "\n")
    msg = _fails(lambda: read_csv(tmp_path / "cell.csv"))
    assert "column 'w'" in msg and "TOKEN_" in msg and "z" * 60 not in msg
    (tmp_path / "bin.csv").write_bytes(b"\x7fELF\x02\x01\x01" + bytes(range(256)))
    msg = _fails(lambda: read_csv(tmp_path / "bin.csv"))
    assert "not a text CSV file" in msg and "ELF" not in msg


def test_bom_and_crlf_are_accepted_exactly(tmp_path):
    rows = valid_rows()
    for name, data in [("bom.csv", b"\xef\xbb\xbf" + csv_text(rows).encode()),
                       ("crlf.csv", csv_text(rows, newline="\r\n").encode()),
                       ("both.csv", b"\xef\xbb\xbf" + csv_text(rows, newline="\r\n").encode())]:
        (tmp_path / name).write_bytes(data)
        np.testing.assert_array_equal(read_csv(tmp_path / name).to_array(), rows)
    (tmp_path / "cr.csv").write_text(csv_text(rows, newline="\r"))  # old Mac: no line ends
    assert "not a CSV file with the expected header" in _fails(
        lambda: read_csv(tmp_path / "cr.csv"))


@pytest.mark.parametrize("edit, expected", [
    (lambda ls: ls[:1], "no data rows after the header"),
    (lambda ls: ls[:3], "only 2 data row(s); a sortie needs at least 3"),
    (lambda ls: [""] + ls[1:], "not a CSV file with the expected header"),
    (lambda ls: ls[:1] + ls[1:4] + ls[3:], "data row 4 (CSV line 5), column 'time': time"),
    (lambda ls: ["time,w,u,q,theta,collective,pitch_cmd"] + ls[1:], "columns out of order"),
    (lambda ls: ls[:6] + [ls[6] + ",0"] + ls[7:], "data row 6 (CSV line 7): has 8 fields"),
    (lambda ls: ls[:6] + [ls[6].replace("0.6", "nan")] + ls[7:],
     "data row 6 (CSV line 7), column 'collective': value nan is not finite"),
    (lambda ls: ls[:6] + [ls[6].replace("0.6", "0.6 # ok")] + ls[7:],
     "column 'collective': cannot read '0.6 # ok' as a number"),
    (lambda ls: ls[:6] + [ls[6].replace("0.6", "0.\u0666")] + ls[7:],
     "data row 6 (CSV line 7): non-ASCII character U+0666"),
    (lambda ls: ls[:6] + [ls[6].replace("0.6", "6e-1_0")] + ls[7:], "cannot read '6e-1_0'"),
])
def test_csv_content_problems(tmp_path, edit, expected):
    lines = csv_text(valid_rows()).splitlines()
    (tmp_path / "bad.csv").write_text("\n".join(edit(lines)) + "\n")
    msg = _fails(lambda: read_csv(tmp_path / "bad.csv"))
    assert expected in msg and "bad.csv" in msg, msg


def test_three_rows_is_the_minimum(tmp_path):
    (tmp_path / "three.csv").write_text(csv_text(valid_rows(3)))
    assert len(read_csv(tmp_path / "three.csv").time) == 3


# ----------------------------------------------------------------------------- airframes


@pytest.mark.parametrize("name", ["aerosonde", "f450"])
def test_presets_load_unchanged_and_inside_their_bounds(name):
    af = load_airframe(name)
    text = resources.files("uavdyn.airframes").joinpath(f"{name}.toml").read_text()
    data = tomllib.loads(text)
    assert af.name == data["name"] and af.nominal_airspeed == data["nominal_airspeed"]
    for key in af.param_names:
        default = {"value": OPTIONAL_PARAMS[af.kind].get(key)}  # optional keys may be absent
        assert getattr(af.params, key) == float(data["params"].get(key, default)["value"]), key
        assert BOUNDS[af.kind][key].violation(getattr(af.params, key)) is None, key


def test_bounds_table_covers_every_parameter_and_says_why():
    for kind in ("fixed_wing", "multirotor"):
        assert set(BOUNDS[kind]) == set(param_names(kind))
        for key, bound in BOUNDS[kind].items():
            assert bound.why and bound.low < bound.high, key
            assert math.isfinite(bound.low) and math.isfinite(bound.high), key
    assert BOUNDS["fixed_wing"]["mass"].describe() == "[0.001, 100000] kg"
    assert BOUNDS["multirotor"]["gravity"].describe() == "[9, 10.5] m/s^2"


def _plane(tmp_path: Path, change: Callable[[dict], None], fmt: str = "json",
           kind: str = "f450") -> Path:
    data = to_toml_dict(load_airframe(kind))
    change(data)
    path = tmp_path / f"plane.{fmt}"
    text = json.dumps(data) if fmt == "json" else fuzz_airframe.toml_text(data)
    path.write_text(text)
    return path


@pytest.mark.parametrize("name", ["../../../escaped", "/tmp/x", "a b", "", "..", "x" * 65,
                                  "f450.toml", "é"])
def test_name_must_be_an_identifier(tmp_path, name):
    path = _plane(tmp_path, lambda d: d.update(name=name), "toml")
    msg = _fails(lambda: load_airframe(path), AirframeError)
    assert str(path) in msg and "key 'name'" in msg and "identifier" in msg


def test_identifier_names_load(tmp_path):
    path = _plane(tmp_path, lambda d: d.update(name="My-quad_2"))
    assert load_airframe(path).name == "My-quad_2"


@pytest.mark.parametrize("change, expected", [
    (lambda d: d["params"]["mass"].update(value=1e308), "parameter 'mass' must be <= 10000"),
    (lambda d: d["params"]["rho"].update(value=1e6), "parameter 'rho' must be <= 2"),
    (lambda d: d["params"]["gravity"].update(value=1.62), "parameter 'gravity' must be >= 9"),
    (lambda d: d["params"]["arm"].update(value=100.0), "parameter 'arm' must be <= 10"),
    (lambda d: d["params"]["pitch_mix"].update(value=-0.1), "parameter 'pitch_mix' must be >= 0"),
    (lambda d: d["params"]["mass"].update(value=True),
     "parameter 'mass' must be a number, got True"),
    (lambda d: d["params"]["mass"].update(value="1.4"), "parameter 'mass' must be a number"),
    (lambda d: d["params"]["mass"].update(value=float("inf")), "parameter 'mass' is not finite"),
    (lambda d: d.update(nominal_airspeed=True), "key 'nominal_airspeed' must be a number"),
    (lambda d: d.update(nominal_airspeed=float("nan")), "key 'nominal_airspeed'"),
    (lambda d: d.update(description=["x"]), "key 'description' must be a string"),
    (lambda d: d["params"]["mass"].update(unit="kg"), "parameter 'mass': unknown key(s) ['unit']"),
    (lambda d: d["params"]["mass"].update(source=3), "parameter 'mass': 'source' must be a string"),
    (lambda d: d.update(kind=["multirotor"]), "key 'kind' must be a string"),
    (lambda d: d.update(params=[1]), "key 'params' must be a table"),
    (lambda d: d.update(extra=1), "unknown top-level key(s) ['extra']"),
])
@pytest.mark.parametrize("fmt", ["json", "toml"])
def test_airframe_values_are_typed_and_bounded(tmp_path, change, expected, fmt):
    path = _plane(tmp_path, change, fmt)
    msg = _fails(lambda: load_airframe(path), AirframeError)
    assert expected in msg and str(path) in msg, msg


def test_fixed_wing_bounds(tmp_path):
    for key, value, expected in [("alpha0", 2.0, "must be <= 1.5708"),
                                 ("M_blend", 500.0, "must be <= 100"),
                                 ("C_m_q", -2000.0, "must be > -1000"),
                                 ("C_D_0", -0.01, "must be >= 0")]:
        path = _plane(tmp_path, lambda d, k=key, v=value: d["params"][k].update(value=v),
                      "toml", "aerosonde")
        assert f"parameter '{key}' {expected}" in _fails(lambda p=path: load_airframe(p),
                                                          AirframeError)


def test_parse_errors_name_file_and_line(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\nkind = "multirotor"\n[params\n')
    msg = _fails(lambda: load_airframe(bad), AirframeError)
    assert str(bad) in msg and "as TOML: line 3" in msg
    bad = tmp_path / "bad.json"
    bad.write_text('{"name": "x",\n "kind": }')
    msg = _fails(lambda: load_airframe(bad), AirframeError)
    assert str(bad) in msg and "as JSON: line 2, column 10" in msg
    bad.write_text('{"name": "a", "name": "b"}')
    assert "key 'name' appears twice" in _fails(lambda: load_airframe(bad), AirframeError)
    bad.write_bytes(b"\xff\xfe\x00")
    assert "not a text file" in _fails(lambda: load_airframe(bad), AirframeError)
    assert "is a folder" in _fails(lambda: load_airframe(tmp_path), AirframeError)
    assert "a preset name or a file path" in _fails(lambda: load_airframe(3), AirframeError)


def test_replace_and_perturb_are_checked_too():
    af = load_airframe("aerosonde")
    assert "parameter 'mass' must be a number" in _fails(lambda: af.replace(mass=True),
                                                         AirframeError)
    assert "parameter 'rho' must be <= 2" in _fails(lambda: af.replace(rho=3.0), AirframeError)
    assert perturb(af, 1.15).params.mass == pytest.approx(11.0 * 1.15)
    assert list_presets() == ["aerosonde", "f450"]


# ----------------------------------------------------------------------------- CLI and fuzz


def test_cli_refuses_escapes_on_one_line(ds, tmp_path, capsys, monkeypatch):
    _manifest_with(ds, lambda m: m["sorties"][0].update(file=f"../{SENTINEL}"))
    monkeypatch.chdir(tmp_path)  # the output may be created here: the dataset's error is tested
    out = tmp_path / "out"
    assert main(["evaluate", "--airframe", "f450", "--dataset", str(ds), "--out",
                 str(out / "m.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "sorties[0].file" in err and "Traceback" not in err
    assert not out.exists()
    plane = _plane(tmp_path, lambda d: d.update(name="../../../escaped"), "toml")
    assert main(["trim", "--airframe", str(plane)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "key 'name'" in err


def test_fuzz_case_lists(tmp_path):
    """Enough seeded cases, unique names, the right error types, and builders that write only
    inside their folder (plus the sentinel beside it)."""
    data_cases, frame_cases = fuzz_dataset.cases(), fuzz_airframe.cases()
    assert len(data_cases) >= 90 and len(frame_cases) >= 40
    assert [c.name for c in fuzz_dataset.cases()] == [c.name for c in data_cases]  # seeded
    for cases, error in ((data_cases, FlightDataError), (frame_cases, AirframeError)):
        assert len({c.name for c in cases}) == len(cases)
        assert all(c.error is error and c.cli is not None for c in cases)
    for k, case in enumerate(data_cases + frame_cases):
        root = tmp_path / f"c{k}"
        root.mkdir()
        path = case.build(root / "case")
        assert set(os.listdir(root)) <= {"case", SENTINEL}, case.name
        assert Path(os.path.abspath(path)).is_relative_to(root / "case"), case.name
