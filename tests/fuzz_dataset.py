"""Malformed flight-data inputs (run by ``tests/test_fuzz.py``): manifests that are not JSON,
not an object, wrongly typed, nested absurdly or oversized; manifest paths that escape the
dataset folder (``..``, absolute, symbolic links); special files (FIFO, /dev/zero, folders);
CSV files that are truncated, binary, ragged, non-numeric, non-finite, out of order or
physically impossible.

Each case writes one valid two-sortie multirotor dataset into its folder and breaks one thing.
Escape cases point at ``SENTINEL_outside.csv`` in the folder's parent: a VALID sortie, so a
loader that followed the escape would load it and succeed, and the case would fail.
Random cases are seeded, so the list is the same on every run.
"""

from __future__ import annotations

import json
import os
import random
from collections.abc import Callable
from pathlib import Path

import numpy as np
from fuzz_common import Case

from uavdyn.flightdata import FlightDataError, load_dataset

HEADER = "time,u,w,q,theta,collective,pitch_cmd"
FW_HEADER = "time,u,w,q,theta,elevator,throttle"
RATE = 100.0
ROWS = 101                      # 1 s at 100 Hz
SENTINEL = "SENTINEL_outside.csv"
SEED = 20240611


def valid_rows(n: int = ROWS, rate: float = RATE, phase: float = 0.0) -> np.ndarray:
    """A consistent multirotor sortie (theta = integral of q; everything in range)."""
    t = np.arange(n) / rate
    theta = 0.1 * np.sin(t + phase)
    q = 0.1 * np.cos(t + phase)
    return np.column_stack([t, 2 + 0 * t, 0.1 + 0 * t, q, theta, 0.6 + 0 * t,
                            0.1 * np.sin(t + phase)])


def csv_text(rows: np.ndarray, header: str = HEADER, newline: str = "\n") -> str:
    lines = [header] + [",".join(repr(float(v)) for v in r) for r in rows]
    return newline.join(lines) + newline


def base_manifest() -> dict:
    return {"airframe": "f450", "kind": "multirotor", "sample_rate_hz": RATE,
            "source": "fuzz case", "sorties": [
                {"file": "s0.csv", "true_file": "s0_true.csv", "mission": "loiter",
                 "duration_s": 1.0, "split": "train", "rows": ROWS},
                {"file": "s1.csv", "mission": "survey", "duration_s": 1.0, "split": "test"}]}


def write_dataset(folder: Path, manifest: dict | None = None) -> Path:
    """The valid dataset every case starts from; returns the folder."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "s0.csv").write_text(csv_text(valid_rows()))
    (folder / "s0_true.csv").write_text(csv_text(valid_rows()))
    (folder / "s1.csv").write_text(csv_text(valid_rows(phase=0.5)))
    write_manifest(folder, base_manifest() if manifest is None else manifest)
    return folder


def write_manifest(folder: Path, manifest: object) -> None:
    (folder / "manifest.json").write_text(json.dumps(manifest, indent=1))


def write_sentinel(folder: Path) -> Path:
    """A valid sortie OUTSIDE the case folder: loading it would make the load succeed."""
    path = folder.parent / SENTINEL
    if not path.exists():
        tmp = folder.parent / f".{SENTINEL}.{os.getpid()}.tmp"
        tmp.write_text(csv_text(valid_rows()))
        os.replace(tmp, path)
    return path


def load(path: Path) -> object:
    return load_dataset(path)


def cli(path: Path, out: Path) -> list[str]:
    return ["evaluate", "--airframe", "f450", "--dataset", str(path), "--out",
            str(out / "m.json")]


def _case(name: str, build: Callable[[Path], Path], names: str | None,
          tags: tuple[str, ...] = ()) -> Case:
    return Case(name=f"dataset: {name}", build=build, load=load, error=FlightDataError,
                cli=cli, names=names, tags=tags)


# ----------------------------------------------------------------------------- builders


def manifest_case(name: str, mutate: Callable[[dict], object], names: str = "manifest.json",
                  tags: tuple[str, ...] = ()) -> Case:
    """Valid dataset, then the manifest replaced by ``mutate(manifest)`` (or its return)."""

    def build(folder: Path) -> Path:
        write_dataset(folder)
        manifest = base_manifest()
        result = mutate(manifest)
        write_manifest(folder, manifest if result is None else result)
        return folder

    return _case(name, build, names, tags)


def sortie_case(name: str, key: str, value: object, index: int = 0,
                names: str | None = None) -> Case:
    def mutate(m: dict) -> None:
        m["sorties"][index][key] = value

    return manifest_case(f"sorties[{index}].{key} = {value!r:.40}", mutate,
                         names or "manifest.json", ("manifest", "types"))


def raw_manifest_case(name: str, data: bytes | Callable[[], bytes],
                      tags: tuple[str, ...] = ("manifest",)) -> Case:
    def build(folder: Path) -> Path:
        write_dataset(folder)
        (folder / "manifest.json").write_bytes(data() if callable(data) else data)
        return folder

    return _case(name, build, "manifest.json", tags)


def csv_case(name: str, data: bytes | str | Callable[[], bytes | str], file: str = "s0.csv",
             tags: tuple[str, ...] = ("csv",)) -> Case:
    """Valid dataset, then one listed CSV file's content replaced."""

    def build(folder: Path) -> Path:
        write_dataset(folder)
        content = data() if callable(data) else data
        target = folder / file
        if isinstance(content, str):
            target.write_bytes(content.encode("utf-8"))
        else:
            target.write_bytes(content)
        return folder

    return _case(name, build, file, tags)


def rows_case(name: str, change: Callable[[np.ndarray], np.ndarray | None],
              file: str = "s0.csv") -> Case:
    """Valid numbers, changed by ``change`` (in place or returned), written back."""

    def data() -> str:
        rows = valid_rows()
        out = change(rows)
        return csv_text(rows if out is None else out)

    return csv_case(name, data, file, ("csv", "values"))


def lines_case(name: str, change: Callable[[list[str]], None], file: str = "s0.csv") -> Case:
    """The valid CSV's lines (header = lines[0]) edited in place."""

    def data() -> str:
        lines = csv_text(valid_rows()).splitlines()
        change(lines)
        return "\n".join(lines) + "\n"

    return csv_case(name, data, file, ("csv", "text"))


def special_case(name: str, make: Callable[[Path, Path], None], file: str = "s0.csv",
                 names: str | None = None, tags: tuple[str, ...] = ("special",)) -> Case:
    """Valid dataset, then ``make(folder, folder / file)`` replaces one file (link, FIFO...)."""

    def build(folder: Path) -> Path:
        write_dataset(folder)
        target = folder / file
        if target.exists() or target.is_symlink():
            target.unlink()
        make(folder, target)
        return folder

    return _case(name, build, names or file, tags)


def direct_case(name: str, make: Callable[[Path], None], file: str = "one.csv",
                tags: tuple[str, ...] = ("direct",)) -> Case:
    """``load_dataset`` given a path (not a folder) that ``make`` creates."""

    def build(folder: Path) -> Path:
        folder.mkdir(parents=True, exist_ok=True)
        target = folder / file
        make(target)
        return target

    return _case(name, build, file, tags)


def _set(row: int, col: int, value: float) -> Callable[[np.ndarray], None]:
    def change(rows: np.ndarray) -> None:
        rows[row, col] = value
    return change


def _cell(row: int, col: int, text: str) -> Callable[[list[str]], None]:
    def change(lines: list[str]) -> None:
        cells = lines[row].split(",")
        cells[col] = text
        lines[row] = ",".join(cells)
    return change


def _symlink(target: str | Path) -> Callable[[Path, Path], None]:
    def make(folder: Path, path: Path) -> None:
        os.symlink(target, path)
    return make


def _to_sentinel(folder: Path, path: Path) -> None:
    write_sentinel(folder)
    os.symlink(os.path.join("..", SENTINEL), path)


def _chain_to_sentinel(folder: Path, path: Path) -> None:
    write_sentinel(folder)
    os.symlink(os.path.join("..", SENTINEL), folder / "hop.csv")
    os.symlink("hop.csv", path)


def _fifo(folder: Path, path: Path) -> None:
    os.mkfifo(path)


def _folder(folder: Path, path: Path) -> None:
    path.mkdir()
    (path / "inner.csv").write_text(csv_text(valid_rows()))


def _loop(folder: Path, path: Path) -> None:
    os.symlink("loop_b.csv", path)
    os.symlink(path.name, folder / "loop_b.csv")


def _sparse(size: int) -> Callable[[Path, Path], None]:
    def make(folder: Path, path: Path) -> None:
        with open(path, "wb") as f:
            f.write((HEADER + "\n").encode())
            f.truncate(size)
    return make


def _subdir_link_to_parent(folder: Path) -> Path:
    write_dataset(folder)
    write_sentinel(folder)
    os.symlink("..", folder / "up")
    m = base_manifest()
    m["sorties"][0]["file"] = f"up/{SENTINEL}"
    del m["sorties"][0]["true_file"]
    write_manifest(folder, m)
    return folder


def _escape(value: Callable[[Path], str], key: str = "file") -> Callable[[Path], Path]:
    def build(folder: Path) -> Path:
        write_dataset(folder)
        write_sentinel(folder)
        m = base_manifest()
        m["sorties"][0][key] = value(folder)
        if key == "file":
            del m["sorties"][0]["true_file"]
        write_manifest(folder, m)
        return folder
    return build


def _nested(depth: int) -> Callable[[dict], None]:
    def mutate(m: dict) -> None:
        value: object = "leaf"
        for _ in range(depth):
            value = [value]
        m["notes"] = value
    return mutate


def _without(key: str) -> Callable[[dict], None]:
    def mutate(m: dict) -> None:
        del m[key]
    return mutate


def _top(key: str, value: object) -> Callable[[dict], None]:
    def mutate(m: dict) -> None:
        m[key] = value
    return mutate


def _drop_sortie_key(key: str) -> Callable[[dict], None]:
    def mutate(m: dict) -> None:
        del m["sorties"][1][key]
    return mutate


def _entries(*files: tuple[str, str | None]) -> Callable[[dict], None]:
    """Replace the sortie list by entries with these (file, true_file) pairs."""
    def mutate(m: dict) -> None:
        m["sorties"] = [dict({"file": f, "mission": "loiter", "duration_s": 1.0},
                             **({"true_file": t} if t else {})) for f, t in files]
    return mutate


def _manifest_json() -> str:
    return json.dumps(base_manifest(), indent=1)


# ----------------------------------------------------------------------------- the cases


def cases() -> list[Case]:
    """The flight-data loader cases (seeded: the same list on every run)."""
    rng = random.Random(SEED)
    out: list[Case] = []

    # --- the manifest as a file
    out += [
        _case("no manifest.json in the folder", lambda f: (f.mkdir(parents=True,
                                                                  exist_ok=True), f)[1],
              "manifest.json", ("manifest",)),
        raw_manifest_case("manifest empty", b""),
        raw_manifest_case("manifest whitespace only", b" \n\t\n"),
        raw_manifest_case("manifest is JSON null", b"null"),
        raw_manifest_case("manifest is a JSON array", b"[]"),
        raw_manifest_case("manifest is a JSON string", b'"dataset"'),
        raw_manifest_case("manifest is a JSON number", b"42"),
        raw_manifest_case("manifest not UTF-8", lambda: b"\xff\xfe" + _manifest_json()
                          .encode("utf-16-le")),
        raw_manifest_case("manifest with a NUL byte", lambda: _manifest_json().encode()
                          .replace(b'"source"', b'"sou\x00rce"')),
        raw_manifest_case("manifest duplicated top-level key", lambda: _manifest_json().encode()
                          .replace(b'"kind": "multirotor"',
                                   b'"kind": "multirotor", "kind": "fixed_wing"')),
        raw_manifest_case("manifest duplicated key in a sortie", lambda: _manifest_json()
                          .encode().replace(b'"file": "s1.csv"',
                                            b'"file": "s1.csv", "file": "s0.csv"')),
        raw_manifest_case("manifest NaN sample rate", lambda: _manifest_json().encode()
                          .replace(b'"sample_rate_hz": 100.0', b'"sample_rate_hz": NaN')),
        raw_manifest_case("manifest Infinity duration", lambda: _manifest_json().encode()
                          .replace(b'"duration_s": 1.0', b'"duration_s": Infinity', 1)),
        raw_manifest_case("manifest 1e999 sample rate", lambda: _manifest_json().encode()
                          .replace(b'"sample_rate_hz": 100.0', b'"sample_rate_hz": 1e999')),
        raw_manifest_case("manifest integer of 5000 digits", lambda: _manifest_json().encode()
                          .replace(b'"sample_rate_hz": 100.0',
                                   b'"sample_rate_hz": ' + b"9" * 5000)),
        raw_manifest_case("manifest nested 100000 deep",
                          lambda: b'{"sorties": ' + b"[" * 100000 + b"]" * 100000 + b"}"),
        raw_manifest_case("manifest 1 MB key on one line",
                          lambda: b'{"' + b"k" * 2**20 + b'": 1}'),
        manifest_case("manifest nested 40 deep (valid JSON)", _nested(40)),
    ]
    text = _manifest_json().encode()
    end = text.rindex(b"}")
    for _ in range(8):
        cut = rng.randrange(1, end)
        out.append(raw_manifest_case(f"manifest truncated at byte {cut}",
                                     text[:cut], ("manifest", "truncation")))
    for k in range(5):
        blob = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 400)))
        out.append(raw_manifest_case(f"manifest random bytes #{k}", blob,
                                     ("manifest", "random")))
    out += [
        special_case("manifest is a folder", _folder, "manifest.json"),
        special_case("manifest is a FIFO", _fifo, "manifest.json"),
        special_case("manifest symlink to /dev/zero", _symlink("/dev/zero"), "manifest.json"),
        special_case("manifest symlink outside the folder", _to_sentinel, "manifest.json"),
        special_case("manifest 11 MB (sparse)", _sparse(11 * 2**20), "manifest.json"),
    ]

    # --- manifest keys and types
    for key in ("airframe", "kind", "sample_rate_hz", "source", "sorties"):
        out.append(manifest_case(f"manifest without '{key}'", _without(key)))
    for key, value in [
        ("airframe", 1), ("airframe", None), ("airframe", "../../../escaped"),
        ("airframe", ".hidden"), ("airframe", "a/b"), ("airframe", "x" * 100),
        ("airframe", ["f450"]),
        ("kind", 1), ("kind", "helicopter"), ("kind", ["multirotor"]), ("kind", None),
        ("kind", {"multirotor": 1}),
        ("sample_rate_hz", "100"), ("sample_rate_hz", True), ("sample_rate_hz", -1),
        ("sample_rate_hz", 0), ("sample_rate_hz", None), ("sample_rate_hz", [100]),
        ("sample_rate_hz", 1e6), ("sample_rate_hz", 50.0),
        ("source", 1), ("source", None),
        ("sorties", {}), ("sorties", []), ("sorties", "s0.csv"), ("sorties", [1]),
        ("sorties", [None]), ("sorties", [["s0.csv"]]),
    ]:
        out.append(manifest_case(f"manifest {key} = {value!r:.40}", _top(key, value),
                                 "s0.csv" if value == 50.0 else "manifest.json",
                                 ("manifest", "types")))
    for key in ("file", "mission", "duration_s"):
        out.append(manifest_case(f"sorties[1] without '{key}'", _drop_sortie_key(key)))
    for key, value in [
        ("file", 1), ("file", None), ("file", ""), ("file", "   "), ("file", "a\x00b.csv"),
        ("file", "s0\n.csv"), ("file", "C:\\data\\s0.csv"), ("file", "sub\\s0.csv"),
        ("file", "x" * 2000), ("file", "."), ("file", "nowhere.csv"),
        ("mission", 2), ("mission", None),
        ("duration_s", "1"), ("duration_s", True), ("duration_s", None), ("duration_s", -1),
        ("duration_s", 60.0),
        ("split", "holdout"), ("split", 1),
        ("true_file", 1), ("true_file", ""), ("true_file", "s1.csv"),
        ("true_file", "missing_true.csv"),
        ("condition", 5), ("altitude_m", "high"),
        ("rows", "101"), ("rows", -1), ("rows", True), ("rows", 50),
    ]:
        names = "s0.csv" if (key, value) in (("duration_s", 60.0), ("rows", 50)) else None
        names = "missing_true.csv" if value == "missing_true.csv" else names
        names = "nowhere.csv" if value == "nowhere.csv" else names
        names = "sorties[0].file" if (key, value) == ("file", ".") else names
        out.append(sortie_case(key, key, value, names=names))
    out += [
        manifest_case("sortie file listed twice", _entries(("s0.csv", None), ("s0.csv", None))),
        manifest_case("same file spelled './s0.csv'",
                      _entries(("s0.csv", None), ("./s0.csv", None))),
        manifest_case("a sortie's true file is its own file",
                      _entries(("s0.csv", "s0.csv"), ("s1.csv", None))),
        manifest_case("two sorties with the same name (s1.csv, a/s1.csv)",
                      _entries(("a/s1.csv", None), ("s1.csv", None))),
    ]

    # --- escapes: every one points at a VALID sortie outside the folder
    out += [
        _case("file '../SENTINEL_outside.csv'", _escape(lambda f: f"../{SENTINEL}"),
              "sorties[0].file", ("escape",)),
        _case("file 'sub/../../SENTINEL_outside.csv'",
              _escape(lambda f: f"sub/../../{SENTINEL}"), "sorties[0].file", ("escape",)),
        _case("file is an absolute path", _escape(lambda f: str(f.parent / SENTINEL)),
              "sorties[0].file", ("escape",)),
        _case("file '/etc/passwd'", _escape(lambda f: "/etc/passwd"), "sorties[0].file",
              ("escape",)),
        _case("file '../../../../etc/passwd'", _escape(lambda f: "../../../../etc/passwd"),
              "sorties[0].file", ("escape",)),
        _case("true_file escapes with '..'", _escape(lambda f: f"../{SENTINEL}", "true_file"),
              "sorties[0].true_file", ("escape",)),
        _case("true_file is an absolute path",
              _escape(lambda f: str(f.parent / SENTINEL), "true_file"),
              "sorties[0].true_file", ("escape",)),
        special_case("sortie file symlink outside the folder", _to_sentinel,
                     names="sorties[0].file", tags=("escape", "symlink")),
        special_case("sortie file symlink chain leaving the folder", _chain_to_sentinel,
                     names="sorties[0].file", tags=("escape", "symlink")),
        special_case("true file symlink outside the folder", _to_sentinel, "s0_true.csv",
                     names="sorties[0].true_file", tags=("escape", "symlink")),
        _case("file under a folder symlink to the parent", _subdir_link_to_parent,
              "sorties[0].file", ("escape", "symlink")),
    ]

    # --- special files where a CSV is expected
    out += [
        special_case("sortie file is a FIFO", _fifo),
        special_case("sortie file is a folder", _folder),
        special_case("sortie file symlink to /dev/zero", _symlink("/dev/zero"),
                     names="sorties[0].file"),
        special_case("sortie file symlink loop", _loop),
        special_case("sortie file dangling symlink", _symlink("gone.csv")),
        special_case("sortie file 600 MB (sparse)", _sparse(600 * 2**20)),
        direct_case("CSV path is a FIFO", lambda p: os.mkfifo(p)),
        direct_case("CSV path symlink to /dev/zero", lambda p: os.symlink("/dev/zero", p)),
        direct_case("CSV path 600 MB (sparse)", lambda p: _sparse(600 * 2**20)(p.parent, p)),
        direct_case("dataset path is an empty folder", lambda p: p.mkdir(), "empty_folder"),
    ]

    # --- CSV contents
    passwd = "root:x:0:0:root:/root:/bin/bash\ndaemon:x:1:1:daemon:/usr/sbin:/usr/sbin/nologin\n"
    out += [
        csv_case("CSV empty", ""),
        csv_case("CSV whitespace only", "  \n\n \n"),
        csv_case("CSV header only", HEADER + "\n"),
        csv_case("CSV header and 1 row", lambda: csv_text(valid_rows(1))),
        csv_case("CSV header and 2 rows", lambda: csv_text(valid_rows(2))),
        csv_case("CSV is a passwd file", passwd),
        csv_case("CSV is prose", "This is a flight report.\nNo data here.\n"),
        csv_case("CSV without a header", lambda: csv_text(valid_rows()).split("\n", 1)[1]),
        csv_case("CSV with a NUL byte", lambda: csv_text(valid_rows()).encode()
                 .replace(b"\n", b"\n\x00", 1)),
        csv_case("CSV not UTF-8", lambda: csv_text(valid_rows()).encode().replace(
            b"0.6", b"0\xe96", 1)),
        csv_case("CSV with an Arabic-Indic digit", lambda: csv_text(valid_rows()).replace(
            "0.6", "0.\u0666", 1)),
        csv_case("CSV with lone CR line ends", lambda: csv_text(valid_rows(), newline="\r")),
        csv_case("CSV header of 1 MB on one line", lambda: "a," * 2**19 + "\n"
                 + csv_text(valid_rows()).split("\n", 1)[1]),
        csv_case("CSV header of 200 columns", lambda: ",".join(f"c{k}" for k in range(200))
                 + "\n" + csv_text(valid_rows()).split("\n", 1)[1]),
        csv_case("CSV fixed-wing header in a multirotor dataset",
                 lambda: csv_text(valid_rows(), FW_HEADER)),
        csv_case("CSV missing column", lambda: csv_text(np.delete(valid_rows(), 3, axis=1),
                                                        "time,u,w,theta,collective,pitch_cmd")),
        csv_case("CSV extra column", lambda: csv_text(np.column_stack(
            [valid_rows(), np.zeros(ROWS)]), HEADER + ",wind")),
        csv_case("CSV columns out of order",
                 lambda: csv_text(valid_rows(), "time,w,u,q,theta,collective,pitch_cmd")),
        csv_case("CSV duplicated column",
                 lambda: csv_text(valid_rows(), "time,u,w,q,theta,collective,collective")),
        lines_case("CSV blank line inside", lambda ls: ls.insert(30, "")),
        lines_case("CSV row with an extra field", lambda ls: ls.__setitem__(9, ls[9] + ",1.0")),
        lines_case("CSV row with a missing field",
                   lambda ls: ls.__setitem__(9, ls[9].rsplit(",", 1)[0])),
        lines_case("CSV trailing comment on a row",
                   lambda ls: ls.__setitem__(12, ls[12] + " # note")),
        lines_case("CSV 1 MB number", _cell(20, 2, "1" * 2**20)),
        lines_case("CSV 1 MB line of commas", lambda ls: ls.__setitem__(20, "," * 2**20)),
    ]
    for text in ("abc", "", " ", "0x10", "1_0", "--1", "1e", "1.2.3", "NULL", "+-0",
                 "'0.1'", "1,5"):
        row = rng.randrange(1, ROWS)
        col = rng.randrange(0, 7)
        out.append(lines_case(f"CSV cell {text!r} at row {row} column {col}",
                              _cell(row, col, text)))
    for k, value in enumerate([np.nan, np.inf, -np.inf, np.nan, np.inf, 1e999]):
        row, col = rng.randrange(ROWS), rng.randrange(7)
        out.append(rows_case(f"CSV {value} at row {row + 1} column {col} (#{k})",
                             _set(row, col, value)))
    full = csv_text(valid_rows()).encode()
    for _ in range(6):
        cut = rng.randrange(len(HEADER) // 2, int(0.8 * len(full)))
        out.append(csv_case(f"CSV truncated at byte {cut}", full[:cut],
                            tags=("csv", "truncation")))
    for k in range(5):
        blob = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 2000)))
        out.append(csv_case(f"CSV random bytes #{k}", blob, tags=("csv", "random")))
    out += [
        rows_case("CSV duplicated time stamp", lambda r: r.__setitem__((50, 0), r[49, 0])),
        rows_case("CSV time decreasing", lambda r: r[::-1].copy()),
        rows_case("CSV time not uniform", lambda r: r.__setitem__(
            (slice(60, None), 0), r[60:, 0] + 0.004)),
        rows_case("CSV logged at 50 Hz in a 100 Hz dataset",
                  lambda r: r.__setitem__((slice(None), 0), r[:, 0] * 2)),
        rows_case("CSV u of 1000 m/s", _set(10, 1, 1000.0)),
        rows_case("CSV pitch in degrees", lambda r: r.__setitem__(
            (slice(None), 4), np.degrees(r[:, 4]) + 5)),
        rows_case("CSV collective of 2", _set(7, 5, 2.0)),
        rows_case("CSV pitch rate sign flipped", lambda r: r.__setitem__(
            (slice(None), 3), -r[:, 3])),
        rows_case("true file time differs", lambda r: r.__setitem__(
            (slice(None), 0), r[:, 0] + 1.0), "s0_true.csv"),
        rows_case("true file controls differ", _set(40, 5, 0.7), "s0_true.csv"),
        rows_case("CSV one row of a huge time", _set(100, 0, 1e300)),
    ]
    return out
