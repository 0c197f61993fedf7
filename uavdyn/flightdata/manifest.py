"""The dataset manifest (``manifest.json``): reading and validating it, and writing it.

Every file a manifest names must resolve inside the dataset folder (no absolute paths, no
``..``, no symbolic link whose target leaves the folder); a manifest larger than
:data:`MANIFEST_MAX_BYTES` or nested deeper than :data:`MANIFEST_MAX_DEPTH` is refused.
"""

from __future__ import annotations

import difflib
import json
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path, PurePosixPath, PureWindowsPath

from uavdyn.flightdata.errors import FlightDataError, _short
from uavdyn.flightdata.files import _read_text
from uavdyn.flightdata.sortie import SPLIT_NAMES
from uavdyn.model import CONTROL_NAMES
from uavdyn.safefiles import DuplicateKey, no_duplicate_keys

# Resource bounds, checked before anything is read.
MANIFEST_MAX_BYTES = 10 * 2**20   # manifest.json
MANIFEST_MAX_DEPTH = 32           # nesting of JSON objects/arrays in the manifest
MANIFEST_MAX_SORTIES = 100_000
SAMPLE_RATE_MAX_HZ = 1e5

_IDENTIFIER = re.compile(r"[A-Za-z0-9_.-]{1,64}")         # manifest 'airframe'

# Every key a manifest may carry (what uavdyn's writers put there); any other is refused with
# the nearest known one named, so a typo ('spilt', 'altitude') is not silently ignored.
REQUIRED_KEYS = ("airframe", "kind", "sample_rate_hz", "source", "sorties")
TOP_KEYS = REQUIRED_KEYS + (
    "columns", "splits", "true_states", "controls", "velocities",  # generate-data, design-input
    "emulator", "truth", "recipe",                                  # the emulator's record
    "logs", "split_rule",                                           # import-log, split
    "lowpass_hz",                                                   # Dataset.lowpass + export
    "notes",                                       # the author's own remarks (JSON has no #)
)
ENTRY_REQUIRED_KEYS = ("file", "mission", "duration_s")
SORTIE_KEYS = ENTRY_REQUIRED_KEYS + (
    "split", "true_file", "condition", "altitude_m", "rows",
    # generate-data and design-input --emulate
    "turbulence_intensity", "mean_wind_mps", "wind_inertial_mps", "seed", "draws",
    "max_alpha_air_deg", "mission_params", "sign",
    # import-log (uavdyn.flightdata.log_dataset.ENTRY_KEYS and the log it came from)
    "log", "source_file", "source_start_s", "source_end_s", "flight_time_s", "cut",
    "velocity_reference", "notes",
)
ALTITUDE_RANGE_M = (-500.0, 20000.0)  # the Dead Sea shore to the ISA's stratosphere base


def write_manifest(folder: str | Path, airframe: str, kind: str, sample_rate_hz: float,
                   source: str, sorties: list[dict], **extra) -> Path:
    """Write ``manifest.json``: ``sorties`` entries need ``file``, ``mission``, ``duration_s``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    manifest = {"airframe": airframe, "kind": kind, "sample_rate_hz": sample_rate_hz,
                "source": source, "sorties": sorties, **extra}
    path = folder / "manifest.json"
    path.write_text(json.dumps(manifest, indent=2, sort_keys=False) + "\n")
    return path


def _inside(folder_real: str, name: object, key: str, manifest: Path, folder: Path
            ) -> tuple[Path, str]:
    """Check that manifest value ``name`` (at ``key``) names a file inside the dataset folder.

    Returns the path to show in messages (``folder / name``) and the resolved path to read.
    Absolute paths and any ``..`` component are refused outright; a symbolic link is followed
    only if its resolved target stays inside the (resolved) folder."""
    if not isinstance(name, str):
        raise FlightDataError(f"{key}: expected a file name (string), got "
                              f"{type(name).__name__}", manifest)
    if not name or not name.strip():
        raise FlightDataError(f"{key}: empty file name", manifest)
    if len(name) > 1024 or not name.isprintable():
        raise FlightDataError(f"{key}: file name {_short(name)} is too long or has "
                              "non-printable characters", manifest)
    if "\\" in name:
        raise FlightDataError(f"{key}: file name {_short(name)} has a backslash; use '/' "
                              "between folders", manifest)
    if PurePosixPath(name).is_absolute() or PureWindowsPath(name).drive:
        raise FlightDataError(f"{key}: absolute path {_short(name)} refused: a manifest may "
                              "only name files inside the dataset folder", manifest)
    if ".." in PurePosixPath(name).parts:
        raise FlightDataError(f"{key}: path {_short(name)} has a '..' component, refused: a "
                              "manifest may only name files inside the dataset folder", manifest)
    shown = folder / name
    real = os.path.realpath(os.path.join(folder_real, name))
    if os.path.commonpath([folder_real, real]) != folder_real:
        raise FlightDataError(f"{key}: {_short(name)} is a symbolic link (or lies under one) "
                              "whose target is outside the dataset folder: refused", manifest)
    return shown, real


def _json_type(value: object) -> str:
    """The JSON name of a parsed value's type (what a manifest author recognises)."""
    if isinstance(value, bool):
        return "boolean"
    if value is None:
        return "null"
    return {dict: "object", list: "array", str: "string", int: "number",
            float: "number"}.get(type(value), type(value).__name__)


def _depth(value: object) -> int:
    """Nesting depth of objects/arrays (iterative: a deep value cannot exhaust the stack)."""
    deepest, stack = 0, [(value, 1)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, (dict, list)):
            deepest = max(deepest, depth)
            if depth > MANIFEST_MAX_DEPTH:
                break
            stack.extend((v, depth + 1) for v in (item.values() if isinstance(item, dict)
                                                  else item))
    return deepest


def _number(value: object, key: str, path: Path) -> float:
    """A finite JSON number (a boolean is not a number, nor is a numeric string)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise FlightDataError(f"{key}: expected a number, got {_json_type(value)}", path)
    try:
        number = float(value)
    except OverflowError:
        raise FlightDataError(f"{key}: an integer of {value.bit_length()} bits is too large "
                              "to be a finite number", path) from None
    if not math.isfinite(number):
        raise FlightDataError(f"{key}: {number!r} is not a finite number", path)
    return number


def _string(value: object, key: str, path: Path) -> str:
    if not isinstance(value, str):
        raise FlightDataError(f"{key}: expected a string, got {_json_type(value)}", path)
    return value


def _parse_json(shown: Path, real: str | Path) -> object:
    text, _ = _read_text(shown, real, MANIFEST_MAX_BYTES, "a JSON manifest", "JSON", "", True)
    if not text.strip():
        raise FlightDataError("empty file: expected a JSON object (the dataset manifest)", shown)
    try:
        return json.loads(text, object_pairs_hook=no_duplicate_keys)
    except json.JSONDecodeError as exc:
        raise FlightDataError(f"line {exc.lineno}, column {exc.colno}: invalid JSON: "
                              f"{exc.msg}", shown) from None
    except DuplicateKey as exc:
        raise FlightDataError(f"key {_short(str(exc.args[0]))} appears twice in one JSON "
                              "object (which one is meant is ambiguous)", shown) from None
    except RecursionError:
        raise FlightDataError(f"JSON nested too deeply (at most {MANIFEST_MAX_DEPTH} levels)",
                              shown) from None
    except ValueError as exc:  # e.g. an integer with more digits than Python converts
        reason = "a number has too many digits" if "digits" in str(exc) else type(exc).__name__
        raise FlightDataError(f"invalid JSON: {reason}", shown) from None


def _known_keys(obj: dict, known: tuple[str, ...], where: str, path: Path) -> None:
    """Refuse the first key of ``obj`` not in ``known``, naming the nearest known key."""
    for key in obj:
        if key not in known:
            near = difflib.get_close_matches(str(key), known, n=1, cutoff=0.6)
            hint = f"; did you mean '{near[0]}'?" if near else \
                f"; known keys: {', '.join(known)}"
            raise FlightDataError(f"{where + ': ' if where else ''}unknown key "
                                  f"{_short(str(key))}{hint}", path)


def _validate_manifest(manifest: object, path: Path) -> dict:
    """Keys, JSON types and ranges of a parsed manifest (not yet its file paths)."""
    if not isinstance(manifest, dict):
        raise FlightDataError(f"the manifest must be a JSON object, not {_json_type(manifest)}",
                              path)
    if _depth(manifest) > MANIFEST_MAX_DEPTH:
        raise FlightDataError(f"JSON nested too deeply (at most {MANIFEST_MAX_DEPTH} levels)",
                              path)
    for key in REQUIRED_KEYS:
        if key not in manifest:
            raise FlightDataError(f"missing key '{key}'", path)
    _known_keys(manifest, TOP_KEYS, "", path)
    airframe = _string(manifest["airframe"], "key 'airframe'", path)
    if airframe and (not _IDENTIFIER.fullmatch(airframe) or airframe.startswith(".")):
        raise FlightDataError(f"key 'airframe': {_short(airframe)} is not an airframe name "
                              "(letters, digits, '_', '-', '.', not starting with '.', at most "
                              "64 characters)", path)
    kind = _string(manifest["kind"], "key 'kind'", path)
    if kind not in CONTROL_NAMES:
        raise FlightDataError(f"key 'kind': {_short(kind)} is not one of "
                              f"{tuple(CONTROL_NAMES)}", path)
    rate = manifest["sample_rate_hz"]
    if isinstance(rate, bool) or not isinstance(rate, (int, float)):
        raise FlightDataError(f"key 'sample_rate_hz': expected a positive number, got "
                              f"{_json_type(rate)}", path)
    rate = _number(rate, "key 'sample_rate_hz'", path)
    if not 0 < rate <= SAMPLE_RATE_MAX_HZ:
        raise FlightDataError(f"key 'sample_rate_hz': {rate!r} is not a positive number of "
                              f"at most {SAMPLE_RATE_MAX_HZ:g} Hz", path)
    _string(manifest["source"], "key 'source'", path)
    sorties = manifest["sorties"]
    if not isinstance(sorties, list) or not sorties:
        raise FlightDataError(f"key 'sorties' must be a non-empty array of objects, got "
                              f"{_json_type(sorties) if sorties != [] else 'an empty array'}",
                              path)
    if len(sorties) > MANIFEST_MAX_SORTIES:
        raise FlightDataError(f"key 'sorties' lists {len(sorties)} sorties, more than "
                              f"{MANIFEST_MAX_SORTIES}", path)
    for i, entry in enumerate(sorties):
        where = f"sorties[{i}]"
        if not isinstance(entry, dict):
            raise FlightDataError(f"{where} must be an object, not {_json_type(entry)}", path)
        for key in ENTRY_REQUIRED_KEYS:
            if key not in entry:
                raise FlightDataError(f"{where}: missing key '{key}'", path)
        _known_keys(entry, SORTIE_KEYS, where, path)
        _string(entry["file"], f"{where}.file", path)
        _string(entry["mission"], f"{where}.mission", path)
        if _number(entry["duration_s"], f"{where}.duration_s", path) < 0:
            raise FlightDataError(f"{where}.duration_s: {entry['duration_s']!r} is negative",
                                  path)
        if "split" in entry:
            split = _string(entry["split"], f"{where}.split", path)
            if split not in SPLIT_NAMES:
                raise FlightDataError(f"{where}: split {_short(split)} is not one of "
                                      f"{SPLIT_NAMES} (key {where}.split)", path)
        if entry.get("true_file") is not None:
            _string(entry["true_file"], f"{where}.true_file", path)
        if "condition" in entry:
            _string(entry["condition"], f"{where}.condition", path)
        if "altitude_m" in entry:
            altitude = _number(entry["altitude_m"], f"{where}.altitude_m", path)
            low, high = ALTITUDE_RANGE_M
            if not low <= altitude <= high:
                raise FlightDataError(f"{where}.altitude_m: {entry['altitude_m']!r} m is "
                                      f"outside {low:g}..{high:g} m above mean sea level",
                                      path)
        if "rows" in entry:
            rows = entry["rows"]
            if isinstance(rows, bool) or not isinstance(rows, int) or rows < 0:
                got = f"{rows!r}" if isinstance(rows, int) and not isinstance(rows, bool) \
                    and rows < 0 else _json_type(rows)
                raise FlightDataError(f"{where}.rows: expected a whole number >= 0, got {got}",
                                      path)
    return manifest


@dataclass(frozen=True)
class _Entry:
    """Where one manifest sortie's files are: shown in messages, and resolved for reading."""

    index: int
    shown: Path
    real: str
    true_shown: Path | None
    true_real: str | None


def _manifest_files(manifest: dict, path: Path, folder: Path) -> list[_Entry]:
    """Resolve every file the manifest names inside ``folder``; no file is listed twice and
    no two sorties share a name (the file stem)."""
    folder_real = os.path.realpath(folder)
    entries: list[_Entry] = []
    seen: dict[str, str] = {}
    names: dict[str, str] = {}
    for i, entry in enumerate(manifest["sorties"]):
        resolved = []
        for key in ("file", "true_file"):
            if key == "true_file" and entry.get(key) is None:
                resolved.append((None, None))
                continue
            where = f"sorties[{i}].{key}"
            shown, real = _inside(folder_real, entry[key], where, path, folder)
            if real in seen:
                raise FlightDataError(f"{where}: {_short(entry[key])} is the same file as "
                                      f"{seen[real]}; every file may be listed once", path)
            seen[real] = where
            resolved.append((shown, real))
        name = PurePosixPath(entry["file"]).stem
        if name in names:
            raise FlightDataError(f"sorties[{i}].file: sortie name {_short(name)} (the file "
                                  f"name without extension) is already used by {names[name]}",
                                  path)
        names[name] = f"sorties[{i}].file"
        (shown, real), (tshown, treal) = resolved
        entries.append(_Entry(i, shown, real, tshown, treal))
    return entries


def _manifest_in(path: Path) -> tuple[dict, list[_Entry]]:
    """Read and validate the manifest ``path`` and resolve the files it lists."""
    folder = path.parent
    if not os.path.lexists(path):
        raise FlightDataError("no manifest.json in the dataset folder", path)
    folder_real = os.path.realpath(folder)
    real = os.path.realpath(path)
    if os.path.commonpath([folder_real, real]) != folder_real:
        raise FlightDataError("is a symbolic link whose target is outside the dataset "
                              "folder: refused", path)
    manifest = _validate_manifest(_parse_json(path, real), path)
    return manifest, _manifest_files(manifest, path, folder)


def read_manifest(path: str | Path) -> dict:
    """Read and validate a dataset's ``manifest.json``.

    Checks the JSON (size, encoding, nesting, duplicated keys), the required keys and their
    types and ranges, and that every file it names (``file``, ``true_file``) resolves inside
    the manifest's folder; the CSV files themselves are not read.

    Parameters
    ----------
    path : str or Path
        The ``manifest.json`` file.

    Returns
    -------
    dict
        The manifest as parsed.

    Raises
    ------
    FlightDataError
        On one line naming the manifest and the key (e.g. ``sorties[3].file``).
    """
    return _manifest_in(Path(path))[0]
