"""The one timing harness of the project: wall time of several configurations measured
interleaved (every round calls each configuration once, in a rotated order), reported as the
minimum and the median of the timed calls; every timing ratio the project quotes is computed from
these results with :func:`ratio`.

What is timed is exactly the callable: convert inputs (NumPy to ``casadi.DM``, stacking,
compiling, building the rollout) *before* building it, so that the timed region holds the
computation only. Warm-up calls (untimed) absorb first-call costs (lazy compilation, caches).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass

import numpy as np

MIN_REPEATS = 15
STATS = ("min", "median")


@dataclass(frozen=True)
class Timing:
    """Wall time of one configuration: minimum and median over ``repeats`` timed calls (s).

    The minimum is the least disturbed call (the cost on a quiet machine); the median is the
    typical call on the machine as it was. Report both.
    """

    name: str
    min_s: float
    median_s: float
    repeats: int

    @property
    def min_ms(self) -> float:
        return self.min_s * 1e3

    @property
    def median_ms(self) -> float:
        return self.median_s * 1e3

    def stat_s(self, stat: str) -> float:
        """The statistic ``stat`` (``"min"`` or ``"median"``) in seconds.

        Raises
        ------
        ValueError
            For any other statistic.
        """
        if stat not in STATS:
            raise ValueError(f"stat must be one of {STATS}, got {stat!r}")
        return self.min_s if stat == "min" else self.median_s

    def to_dict(self) -> dict:
        """JSON-able: name, repeats, seconds and milliseconds of both statistics."""
        return {**asdict(self), "min_ms": self.min_ms, "median_ms": self.median_ms}


def interleaved_timing(runs: Mapping[str, Callable[[], object]], repeats: int = MIN_REPEATS, *,
                       warmup: int = 1, progress: Callable[[], None] | None = None
                       ) -> dict[str, Timing]:
    """Time every callable of ``runs`` interleaved, ``repeats`` timed calls each.

    Round ``r`` calls every configuration once, starting at configuration ``r mod n`` of the
    insertion order (a rotation), so no configuration always runs first or right after the
    same neighbour. ``warmup`` untimed rounds (same rotation) come first. Only the call itself
    is inside the timed region (``time.perf_counter`` around it); data conversion belongs
    outside the callables (see the module docstring).

    Parameters
    ----------
    runs : Mapping[str, Callable[[], object]]
        Configuration name -> a callable without arguments doing the work once.
    repeats : int
        Timed calls per configuration: 15 by default; fewer only when a caller asks for them
        explicitly (tests, quick runs), and every :class:`Timing` records how many it has.
    warmup : int
        Untimed calls per configuration before the timed rounds.
    progress : callable, optional
        Called once after every timed call (e.g. ``tqdm.update``).

    Returns
    -------
    dict[str, Timing]
        Per configuration (same order as ``runs``): minimum and median wall time.

    Raises
    ------
    ValueError
        If ``runs`` is empty, ``repeats < 1`` or ``warmup < 0``.
    """
    names = list(runs)
    if not names:
        raise ValueError("nothing to time: runs is empty")
    if isinstance(repeats, bool) or not isinstance(repeats, int) or repeats < 1:
        raise ValueError(f"repeats must be a positive integer, got {repeats!r}")
    if isinstance(warmup, bool) or not isinstance(warmup, int) or warmup < 0:
        raise ValueError(f"warmup must be >= 0, got {warmup}")
    n = len(names)
    times: dict[str, list[float]] = {k: [] for k in names}
    for r in range(warmup + repeats):
        timed = r >= warmup
        for k in range(n):
            name = names[(r + k) % n]
            fn = runs[name]
            if not timed:
                fn()
                continue
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
            if progress is not None:
                progress()
    return {k: Timing(k, float(np.min(v)), float(np.median(v)), len(v))
            for k, v in times.items()}


def ratio(a: Timing, b: Timing, stat: str = "median") -> float:
    """``a / b`` of one statistic (``"median"`` or ``"min"``) of two timings of the harness.

    Raises
    ------
    ValueError
        For an unknown statistic.
    """
    den = b.stat_s(stat)
    return a.stat_s(stat) / den if den > 0 else math.inf
