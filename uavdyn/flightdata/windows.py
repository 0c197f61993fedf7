"""Windows of recorded flight: stretches of ``length`` samples cut from sorties, each restarted
from the recorded state at its first sample (what identification fits, what the safe trainer
and the evaluation predict over)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavdyn.flightdata.errors import FlightDataError
from uavdyn.flightdata.sortie import Sortie


@dataclass(frozen=True)
class Windows:
    """Windows of ``length`` samples: ``starts[w] = (sortie index, first sample)`` into
    ``sorties``. Row ``k`` of a window's commands is held over its sample ``k``; its targets
    are the recorded states after each sample."""

    sorties: list[Sortie]
    starts: np.ndarray
    length: int

    @property
    def count(self) -> int:
        return len(self.starts)

    @property
    def sortie_index(self) -> np.ndarray:
        """Index into ``sorties`` of each window's sortie ``(W,)``."""
        return np.asarray(self.starts, int).reshape(-1, 2)[:, 0]

    @property
    def sortie(self) -> list[str]:
        """The name of the sortie of each window."""
        return [self.sorties[i].name for i, _ in self.starts]

    def subset(self, keep) -> Windows:
        return Windows(self.sorties, self.starts[np.asarray(keep, int)], self.length)

    @property
    def x0(self) -> np.ndarray:
        """Recorded body state at each window start ``(W, 4)``."""
        return np.array([self.sorties[i].states[k] for i, k in self.starts])

    @property
    def y(self) -> np.ndarray:
        """Recorded body states after each sample ``(W, L, 4)``."""
        L = self.length
        return np.array([self.sorties[i].states[k + 1:k + L + 1] for i, k in self.starts])

    @property
    def u(self) -> np.ndarray:
        """Recorded commands, row k held over sample k ``(W, L, nu)``."""
        L = self.length
        return np.array([self.sorties[i].controls[k:k + L] for i, k in self.starts])

    @property
    def t0(self) -> np.ndarray:
        """Time of each window start since its sortie's start ``(W,)`` (s)."""
        return np.array([self.sorties[i].time[k] - self.sorties[i].time[0]
                         for i, k in self.starts])


def make_windows(sorties: list[Sortie], length: int, stride: int = 1,
                 every: int | None = None) -> Windows:
    """Windows of ``length`` grid intervals starting every ``every`` intervals (default:
    ``length``, back to back) in every sortie, on the grid of every ``stride``-th log sample.

    Raises
    ------
    FlightDataError
        If no window fits in the sorties.
    """
    every = length if every is None else every
    if length < 1 or every < 1 or stride < 1:
        raise FlightDataError(f"window length, spacing and stride must be >= 1, got {length}, "
                              f"{every}, {stride}")
    grid = [s if stride == 1 else Sortie(s.name, s.kind, s.time[::stride], s.states[::stride],
                                         s.controls[::stride], s.mission, s.meta)
            for s in sorties]
    starts = [(i, k) for i, s in enumerate(grid)
              for k in range(0, len(s.states) - length, every)]
    if not starts:
        raise FlightDataError(f"no window of {length} samples fits in the given sorties")
    return Windows(grid, np.array(starts, dtype=int), int(length))
