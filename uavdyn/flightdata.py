"""Flight data: the in-memory sortie type and the SPEC section 3 interchange format (a folder
with ``manifest.json`` and one CSV per sortie).

CSV header: fixed wing ``time,u,w,q,theta,elevator,throttle``; multirotor
``time,u,w,q,theta,collective,pitch_cmd``. SI units, radians, body axes (x forward, z down).
Row k's controls are held over [t_k, t_k+1) (zero-order hold).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from uavdyn.model import CONTROL_NAMES, STATE_NAMES


class FlightDataError(ValueError):
    """A flight-data file is malformed; the message names file, row and column."""


def csv_columns(kind: str) -> tuple[str, ...]:
    """The interchange-format header for an airframe kind."""
    if kind not in CONTROL_NAMES:
        raise FlightDataError(f"unknown airframe kind '{kind}'; expected one of "
                              f"{tuple(CONTROL_NAMES)}")
    return ("time",) + STATE_NAMES + CONTROL_NAMES[kind]


@dataclass
class Sortie:
    """One flight: uniformly sampled time, states ``N x 4`` and controls ``N x 2``."""

    name: str
    kind: str
    time: np.ndarray
    states: np.ndarray
    controls: np.ndarray
    mission: str = ""
    meta: dict = field(default_factory=dict)

    @property
    def dt(self) -> float:
        return float(np.median(np.diff(self.time)))

    @property
    def duration(self) -> float:
        return float(self.time[-1] - self.time[0])

    def to_array(self) -> np.ndarray:
        return np.column_stack([self.time, self.states, self.controls])


def write_csv(sortie: Sortie, path: str | Path) -> Path:
    """Write one sortie in the interchange CSV format (17 significant digits: lossless)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    header = ",".join(csv_columns(sortie.kind))
    np.savetxt(path, sortie.to_array(), delimiter=",", header=header, comments="", fmt="%.17g")
    return path


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
