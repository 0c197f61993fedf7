"""The physical ranges of the body states: what no flight of a UAV of the kind leaves. The
dataset loader refuses records outside them (a unit slip) and every rollout of the library
reports a state leaving them as a departure with its time (a model that has left its
validity, however finite its numbers)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uavdyn.model.structure import STATE_NAMES

SPEED_LIMIT = {"fixed_wing": 100.0, "multirotor": 50.0}  # |u|, |w| in m/s
PITCH_RATE_LIMIT = 10.0  # rad/s (573 deg/s)
PITCH_LIMIT = math.pi    # rad
STATE_UNITS = {"u": "m/s", "w": "m/s", "q": "rad/s", "theta": "rad"}


def state_limits(kind: str) -> dict[str, float]:
    """``name -> largest |value|`` of each body state ``u, w, q, theta`` for ``kind``."""
    return {"u": SPEED_LIMIT[kind], "w": SPEED_LIMIT[kind], "q": PITCH_RATE_LIMIT,
            "theta": PITCH_LIMIT}


@dataclass(frozen=True)
class Departure:
    """The first sample of a trajectory outside the physical ranges."""

    index: int
    state: str
    value: float
    limit: float

    def describe(self) -> str:
        unit = STATE_UNITS[self.state]
        return (f"{self.state} = {self.value:.6g} {unit} is outside the physical range "
                f"[-{self.limit:g}, {self.limit:g}] {unit}")


def first_departure(states: np.ndarray, kind: str) -> Departure | None:
    """The first sample (row) of ``states`` (``N x >= 4``, body states first) whose body state
    is outside :func:`state_limits` (a non-finite value counts as outside), or None."""
    states = np.atleast_2d(np.asarray(states, float))
    limits = state_limits(kind)
    first = None
    with np.errstate(invalid="ignore"):
        for j, name in enumerate(STATE_NAMES):
            bad = np.flatnonzero(~(np.abs(states[:, j]) <= limits[name]))
            if len(bad) and (first is None or bad[0] < first.index):
                k = int(bad[0])
                first = Departure(k, name, float(states[k, j]), limits[name])
    return first
