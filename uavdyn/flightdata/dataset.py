"""Loading a flight dataset (a folder of ``manifest.json`` and sortie CSVs, or one CSV).

The SPEC section 3 interchange format: a folder with ``manifest.json`` (:mod:`.manifest`) and
one CSV per sortie (:mod:`.csvio`); every file is checked on loading (:mod:`.checks`) and the
sorties can be preprocessed (:mod:`.preprocess`) and exported again.

Reading is defensive (SPEC section 9): every file a manifest names must resolve inside the
dataset folder (no absolute paths, no ``..``, no symbolic link whose target leaves the folder);
a file is ``stat``-ed before it is opened, so a FIFO, a device or a folder is refused without
being opened, and files larger than :data:`MANIFEST_MAX_BYTES` / :data:`CSV_MAX_BYTES` are
refused before any byte is read. Every problem raises :class:`FlightDataError` on one line.

The names of the modules this one was split into stay importable from here.
"""

from __future__ import annotations

import math
import os
import stat
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import numpy as np

from uavdyn.flightdata.checks import (
    CONTROL_TOLERANCE,
    KINEMATIC_TOLERANCE,
    KINEMATIC_WINDOW_S,
    MIN_ROWS,
    TIME_TOLERANCE,
    check_kinematics,
    check_values,
    kinematic_residual,
)
from uavdyn.flightdata.csvio import (
    CSV_MAX_BYTES,
    MAX_CELL_CHARS,
    MAX_COLUMNS,
    MAX_LINE_CHARS,
    _load_csv,
    export,
    read_csv,
    write_csv,
)
from uavdyn.flightdata.errors import FlightDataError, _short
from uavdyn.flightdata.manifest import (
    MANIFEST_MAX_BYTES,
    MANIFEST_MAX_DEPTH,
    MANIFEST_MAX_SORTIES,
    SAMPLE_RATE_MAX_HZ,
    _manifest_in,
    read_manifest,
    write_manifest,
)
from uavdyn.flightdata.noise import excess_rmse, pitch_noise_std, white_noise_std
from uavdyn.flightdata.preprocess import Normalisation, lowpass, normalisation
from uavdyn.flightdata.sortie import SPLIT_NAMES, Sortie, csv_columns
from uavdyn.model import PITCH_LIMIT, PITCH_RATE_LIMIT, SPEED_LIMIT
from uavdyn.safefiles import describe_mode, os_reason

__all__ = [
    "CONTROL_TOLERANCE", "CSV_MAX_BYTES", "KINEMATIC_TOLERANCE", "KINEMATIC_WINDOW_S",
    "MANIFEST_MAX_BYTES", "MANIFEST_MAX_DEPTH", "MANIFEST_MAX_SORTIES", "MAX_CELL_CHARS",
    "MAX_COLUMNS", "MAX_LINE_CHARS", "MIN_ROWS", "PITCH_LIMIT", "PITCH_RATE_LIMIT",
    "SAMPLE_RATE_MAX_HZ", "SPEED_LIMIT", "SPLIT_NAMES", "TIME_TOLERANCE", "Dataset",
    "FlightDataError", "Normalisation", "Sortie", "check_kinematics", "check_values",
    "csv_columns", "excess_rmse", "export", "kinematic_residual", "load_dataset", "lowpass",
    "normalisation", "pitch_noise_std", "read_csv", "read_manifest", "white_noise_std",
    "write_csv", "write_manifest",
]


@dataclass
class Dataset:
    """A loaded dataset: its manifest and sorties (in manifest order), split by sortie."""

    path: Path
    manifest: dict
    sorties: list[Sortie]

    @property
    def kind(self) -> str:
        """``fixed_wing`` or ``multirotor`` (from the manifest)."""
        return self.manifest["kind"]

    @property
    def sample_rate_hz(self) -> float:
        """Log rate (Hz) from the manifest."""
        return float(self.manifest["sample_rate_hz"])

    @property
    def splits(self) -> dict[str, list[str]]:
        """Sortie names per split (``unsplit`` for sorties the manifest gives no split)."""
        out: dict[str, list[str]] = {name: [] for name in SPLIT_NAMES}
        for s in self.sorties:
            out.setdefault(s.split or "unsplit", []).append(s.name)
        return out

    def split(self, name: str) -> list[Sortie]:
        """The sorties of one split, in manifest order."""
        if name not in SPLIT_NAMES:
            raise ValueError(f"unknown split '{name}'; expected one of {SPLIT_NAMES}")
        return [s for s in self.sorties if s.split == name]

    @property
    def train(self) -> list[Sortie]:
        """Training sorties (the only ones normalisation statistics come from)."""
        return self.split("train")

    @property
    def validation(self) -> list[Sortie]:
        """Validation sorties (model selection, early stopping)."""
        return self.split("validation")

    @property
    def test(self) -> list[Sortie]:
        """Held-out test sorties (final figures only)."""
        return self.split("test")

    @property
    def lateral(self) -> bool:
        """Whether the sorties carry the recorded lateral inputs (turning flight)."""
        return bool(self.sorties) and self.sorties[0].lateral

    def normalisation(self) -> Normalisation:
        """Normalisation statistics from the training split only (never validation/test)."""
        return normalisation(self.train)

    def lowpass(self, cutoff_hz: float, order: int = 4) -> Dataset:
        """A copy with every sortie's measured states low-pass filtered (zero phase)."""
        return Dataset(self.path, dict(self.manifest, lowpass_hz=cutoff_hz),
                       [lowpass(s, cutoff_hz, order) for s in self.sorties])

    def export(self, folder: str | Path) -> Path:
        """Write the dataset (manifest + CSVs, true states too where present) to ``folder``."""
        folder = Path(folder)
        entries = []
        for s in self.sorties:
            entry = dict(s.meta.get("manifest_entry", {}))
            entry.update(file=f"{s.name}.csv", mission=s.mission, duration_s=s.duration)
            write_csv(s, folder / entry["file"])
            if s.true_states is not None:
                entry["true_file"] = f"{s.name}_true.csv"
                export(s, folder / entry["true_file"], true_states=True)
            entries.append(entry)
        extra = {k: v for k, v in self.manifest.items()
                 if k not in ("airframe", "kind", "sample_rate_hz", "source", "sorties")}
        return write_manifest(folder, self.manifest.get("airframe", ""), self.kind,
                              self.sample_rate_hz, self.manifest.get("source", ""), entries,
                              **extra)


def _stat_given(path: Path) -> os.stat_result:
    try:
        return os.stat(path)
    except FileNotFoundError:
        raise FlightDataError("no such file or folder", path) from None
    except OSError as exc:
        raise FlightDataError(os_reason(exc), path) from None
    except ValueError:
        raise FlightDataError("invalid path (NUL byte)", path) from None


def load_dataset(path: str | Path, check: bool = True, lowpass_hz: float | None = None,
                 load_true: bool = True) -> Dataset:
    """Load a dataset folder (``manifest.json`` + CSVs) or one CSV file, checking everything.

    Every file a manifest names must resolve inside the dataset folder and be a regular file
    within the size bounds (see the module docstring); each CSV passes :func:`check_values`.

    Parameters
    ----------
    path : str or Path
        The dataset folder, its ``manifest.json``, or a single CSV file.
    check : bool
        Run the consistency checks of :func:`check_values` on every file (default).
    lowpass_hz : float, optional
        Zero-phase low-pass filter of the measured states (Hz).
    load_true : bool
        Also read each sortie's ``true_file`` (noise-free states), if the manifest has one.

    Returns
    -------
    Dataset

    Raises
    ------
    FlightDataError
        Any problem, on one line naming the file and the row, column or manifest key.
    """
    path = Path(path)
    if lowpass_hz is not None and (isinstance(lowpass_hz, bool)
                                   or not isinstance(lowpass_hz, (int, float))
                                   or not 0 < lowpass_hz < math.inf):
        raise FlightDataError(f"lowpass_hz must be a positive number of Hz, got {lowpass_hz!r}",
                              path)
    st = _stat_given(path)
    if stat.S_ISREG(st.st_mode) and path.name != "manifest.json":
        s = read_csv(path, check=check)
        rate = 1.0 / s.dt
        manifest = {"airframe": "", "kind": s.kind, "sample_rate_hz": rate,
                    "source": f"single CSV {path.name}",
                    "sorties": [{"file": path.name, "mission": "", "duration_s": s.duration}]}
        ds = Dataset(path, manifest, [s])
        return ds.lowpass(lowpass_hz) if lowpass_hz else ds
    if not (stat.S_ISDIR(st.st_mode) or stat.S_ISREG(st.st_mode)):
        raise FlightDataError(f"is {describe_mode(st.st_mode)}, not a dataset folder or a CSV "
                              "file: refused without opening it", path)
    folder = path if stat.S_ISDIR(st.st_mode) else path.parent
    manifest, entries = _manifest_in(folder / "manifest.json")
    kind, rate = manifest["kind"], float(manifest["sample_rate_hz"])
    sorties = []
    for where, entry in zip(entries, manifest["sorties"]):
        i, file = where.index, where.shown
        s = _load_csv(file, where.real, kind, rate, check, PurePosixPath(entry["file"]).stem,
                      f"sorties[{i}].file")
        if abs(s.duration - float(entry["duration_s"])) > 1.5 / rate:
            raise FlightDataError(f"the manifest says duration_s {entry['duration_s']!r} "
                                  f"(sorties[{i}].duration_s) but the file spans "
                                  f"{s.duration:.6g} s", file, column="time")
        if "rows" in entry and entry["rows"] != len(s.time):
            raise FlightDataError(f"the manifest says rows {entry['rows']} (sorties[{i}].rows) "
                                  f"but the file has {len(s.time)} data rows", file)
        if load_true and where.true_shown is not None:
            tfile = where.true_shown
            t = _load_csv(tfile, where.true_real, kind, rate, check, None,
                          f"sorties[{i}].true_file")
            if len(t.time) != len(s.time) or not np.array_equal(t.time, s.time):
                raise FlightDataError(f"time column differs from its measured file "
                                      f"{_short(entry['file'])} (sorties[{i}].true_file)",
                                      tfile, column="time")
            if not np.array_equal(t.controls, s.controls):
                r = int(np.flatnonzero(np.any(t.controls != s.controls, axis=1))[0]) + 1
                raise FlightDataError(f"controls differ from its measured file "
                                      f"{_short(entry['file'])} (sorties[{i}].true_file)",
                                      tfile, r)
            s.true_states = t.states
        s.mission = entry["mission"]
        s.meta.update(split=entry.get("split", ""), condition=entry.get("condition", ""),
                      manifest_entry=entry)
        sorties.append(s)
    mixed = [s.name for s in sorties if s.lateral != sorties[0].lateral]
    if mixed:
        raise FlightDataError(f"sortie {mixed[0]} {'has' if sorties[0].lateral else 'lacks'} "
                              "the lateral columns phi, p, r, beta and "
                              f"{sorties[0].name} {'lacks' if sorties[0].lateral else 'has'} "
                              "them: a dataset's sorties all have them or none",
                              folder / "manifest.json")
    ds = Dataset(folder, manifest, sorties)
    return ds.lowpass(lowpass_hz) if lowpass_hz else ds
