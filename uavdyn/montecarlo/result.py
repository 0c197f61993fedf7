"""The outcome of a Monte-Carlo study as one typed object (what ``run_study`` returns and
the report writes)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from uavdyn.montecarlo.spec import StudySpec
from uavdyn.montecarlo.statistics import Envelopes, Exceedance, RunTable


@dataclass
class MonteCarloResult:
    """The outcome of a study, usable from Python.

    Attributes
    ----------
    spec : StudySpec
        The study.
    table : RunTable
        One row per run (``table["max_abs_pitch_deg"]`` etc.).
    history : numpy.ndarray
        ``runs x len(SIGNALS) x len(spec.history_time)`` envelope samples (float32, SI).
    envelopes : Envelopes
        Percentile envelopes (5/50/95 %).
    exceedance : list of Exceedance
        Probabilities with Wilson intervals.
    wall_s : float
        Wall time of this call (s).
    computed, reused : tuple of int
        Chunks computed now and taken from an earlier run.
    folder : Path or None
        Where the files are (None: in memory only).
    files : dict of str to str
        Written files by name.
    workers, threads : int
        Dask workers (1: this process) and CasADi threads per chunk.
    scheduler : str or None
        Scheduler address of a remote cluster.
    """

    spec: StudySpec
    table: RunTable
    history: np.ndarray
    envelopes: Envelopes
    exceedance: list[Exceedance]
    wall_s: float
    computed: tuple[int, ...]
    reused: tuple[int, ...]
    folder: Path | None = None
    files: dict[str, str] = field(default_factory=dict)
    workers: int = 1
    threads: int = 1
    scheduler: str | None = None

    @property
    def runs_computed(self) -> int:
        """Runs flown by this call (not taken from reused chunks)."""
        return sum(np.subtract(*reversed(self.spec.chunk_runs(c))) for c in self.computed)

    @property
    def runs_per_s(self) -> float:
        """Computed runs per second of wall time."""
        return self.runs_computed / self.wall_s if self.wall_s > 0 else float("nan")

    def exceedance_of(self, event_start: str) -> Exceedance:
        """The first exceedance whose event text starts with ``event_start``."""
        for e in self.exceedance:
            if e.event.startswith(event_start):
                return e
        raise KeyError(f"no exceedance '{event_start}'; have "
                       f"{', '.join(e.event for e in self.exceedance)}")
