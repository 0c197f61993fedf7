"""The in-memory sortie type and the interchange-format columns of each airframe kind."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from uavdyn.flightdata.errors import FlightDataError
from uavdyn.model import CONTROL_NAMES, LATERAL_INPUT_NAMES, STATE_NAMES

SPLIT_NAMES = ("train", "validation", "test")


def csv_columns(kind: str, lateral: bool = False) -> tuple[str, ...]:
    """The interchange-format header for an airframe kind; ``lateral`` appends the optional
    recorded turning-flight columns ``phi, p, r, beta`` (SPEC section 3)."""
    if not isinstance(kind, str) or kind not in CONTROL_NAMES:
        raise FlightDataError(f"unknown airframe kind {kind!r}; expected one of "
                              f"{tuple(CONTROL_NAMES)}")
    return (("time",) + STATE_NAMES + CONTROL_NAMES[kind]
            + (LATERAL_INPUT_NAMES if lateral else ()))


@dataclass
class Sortie:
    """One flight: uniformly sampled time, states ``N x 4`` and controls ``N x 2``, or
    ``N x 6`` with the recorded lateral inputs ``phi, p, r, beta`` of turning flight after the
    controls (:attr:`lateral`); ``true_states`` (optional) are the noise-free states of an
    emulated flight."""

    name: str
    kind: str
    time: np.ndarray
    states: np.ndarray
    controls: np.ndarray
    mission: str = ""
    meta: dict = field(default_factory=dict)
    true_states: np.ndarray | None = None

    @property
    def dt(self) -> float:
        """Median sample interval (s)."""
        return float(np.median(np.diff(self.time)))

    @property
    def duration(self) -> float:
        """Last minus first time stamp (s)."""
        return float(self.time[-1] - self.time[0])

    @property
    def altitude_m(self) -> float | None:
        """The sortie's altitude for the standard atmosphere (manifest ``altitude_m``; None if
        the data do not give one)."""
        entry = self.meta.get("manifest_entry", {}) or {}
        value = entry.get("altitude_m", self.meta.get("altitude_m"))
        return None if value is None else float(value)

    @property
    def split(self) -> str:
        """``train``/``validation``/``test`` as recorded in the manifest ('' if none)."""
        return str(self.meta.get("split", ""))

    @property
    def lateral(self) -> bool:
        """Whether the sortie carries the lateral inputs (turning flight) after its controls."""
        return self.controls.ndim == 2 and self.controls.shape[1] == 2 + len(
            LATERAL_INPUT_NAMES)

    def to_array(self) -> np.ndarray:
        """``N x 7`` (``N x 11`` with lateral inputs) table in the CSV column order (time,
        states, controls, then phi, p, r, beta)."""
        return np.column_stack([self.time, self.states, self.controls])
