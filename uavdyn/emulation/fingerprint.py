"""Reproducibility of generated datasets across machines, by values and not bytes: a compact
fingerprint (sampled rows and column sums of every CSV) and the distance between two of them.

Vectorised ``libm`` routines differ in the last bits between CPUs, so two machines produce CSVs
that differ in the last printed digits; a byte checksum would call that a different dataset.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

SAMPLED_ROWS = 11
DEFAULT_TOLERANCE = 1e-9
RECIPES = "uavdyn.emulation.recipes"


class FingerprintError(ValueError):
    """A fingerprint file is missing or malformed; the message names the file and key."""


def _csv_values(path: Path) -> tuple[list[str], np.ndarray]:
    with open(path) as fh:
        header = fh.readline().strip().split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return header, data


def dataset_fingerprint(folder: str | Path) -> dict:
    """``{file: {"rows", "columns", "sums", "sampled"}}`` for every CSV of a dataset folder,
    plus the manifest's sortie list; ``sampled`` holds ``SAMPLED_ROWS`` evenly spaced rows."""
    folder = Path(folder)
    files = {}
    for path in sorted(folder.glob("*.csv")):
        header, data = _csv_values(path)
        rows = np.unique(np.linspace(0, len(data) - 1, SAMPLED_ROWS).round().astype(int))
        files[path.name] = {"rows": int(len(data)), "columns": header,
                            "sums": data.sum(axis=0).tolist(),
                            "sampled": data[rows].tolist()}
    manifest = json.loads((folder / "manifest.json").read_text())
    return {"format": "uavdyn dataset fingerprint 1",
            "sorties": [(e.get("file"), e.get("split"), e.get("mission"), e.get("condition"))
                        for e in manifest.get("sorties", [])],
            "files": files}


@dataclass(frozen=True)
class FingerprintComparison:
    """How far a dataset is from a reference fingerprint."""

    max_abs_difference: float     # over sampled values (column sums scaled by row count)
    worst: str                    # "file column" where it occurs
    structural: tuple[str, ...]   # missing files, different rows/columns/sortie list

    def matches(self, tolerance: float = DEFAULT_TOLERANCE) -> bool:
        return not self.structural and self.max_abs_difference <= tolerance

    def describe(self, tolerance: float = DEFAULT_TOLERANCE) -> str:
        if self.structural:
            return f"different structure: {self.structural[0]}" + (
                f" (+{len(self.structural) - 1} more)" if len(self.structural) > 1 else "")
        verdict = "within" if self.matches(tolerance) else "beyond"
        return (f"largest difference {self.max_abs_difference:.3g} ({self.worst}), {verdict} "
                f"the tolerance {tolerance:g}")


def compare_fingerprints(found: dict, reference: dict) -> FingerprintComparison:
    """Distance of ``found`` from ``reference`` (both from :func:`dataset_fingerprint`)."""
    structural = []
    if [tuple(s) for s in found["sorties"]] != [tuple(s) for s in reference["sorties"]]:
        structural.append("the manifest's sortie list differs")
    worst, where = 0.0, ""
    for name, ref in reference["files"].items():
        got = found["files"].get(name)
        if got is None:
            structural.append(f"{name} is missing")
            continue
        if got["rows"] != ref["rows"] or got["columns"] != ref["columns"]:
            structural.append(f"{name}: {got['rows']} rows {got['columns']} instead of "
                              f"{ref['rows']} rows {ref['columns']}")
            continue
        diff = np.abs(np.asarray(got["sampled"]) - np.asarray(ref["sampled"]))
        sums = np.abs(np.asarray(got["sums"]) - np.asarray(ref["sums"])) / max(ref["rows"], 1)
        per_column = np.maximum(diff.max(axis=0), sums)
        k = int(np.argmax(per_column))
        if per_column[k] > worst:
            worst, where = float(per_column[k]), f"{name} column {ref['columns'][k]}"
    for name in found["files"]:
        if name not in reference["files"]:
            structural.append(f"{name} is not in the reference")
    return FingerprintComparison(worst, where, tuple(structural))


def read_fingerprint(path: str | Path) -> dict:
    """Read a fingerprint JSON file, checking its keys."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FingerprintError(f"{path}: not a readable fingerprint file ({exc})") from None
    for key in ("format", "sorties", "files"):
        if not isinstance(doc, dict) or key not in doc:
            raise FingerprintError(f"{path}: missing key '{key}'")
    return doc


def write_fingerprint(doc: dict, path: str | Path) -> Path:
    """Write a fingerprint atomically (temporary sibling, then rename)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(doc, indent=1) + "\n")
    tmp.replace(path)
    return path


def shipped_reference(recipe_name: str) -> dict:
    """The reference fingerprint shipped for a recipe (``datagen_quadrotor`` ...)."""
    res = resources.files(RECIPES).joinpath(f"{recipe_name}.fingerprint.json")
    return read_fingerprint(Path(str(res)))
