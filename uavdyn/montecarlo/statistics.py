"""Statistics of a Monte-Carlo study: the per-run table, percentile envelopes of the time
histories, and exceedance probabilities with Wilson score intervals."""

from __future__ import annotations

import io
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtri

from uavdyn.montecarlo.batch import SIGNALS

ENVELOPE_PERCENTILES = (5.0, 50.0, 95.0)
SIGNAL_LABELS = {"theta": ("pitch angle", "deg"), "q": ("pitch rate", "deg/s"),
                 "alpha": ("angle of attack", "deg"), "airspeed": ("airspeed", "m/s"),
                 "load_factor": ("load factor", "-")}
_DEGREES = ("theta", "q", "alpha")


def wilson_interval(successes: int, trials: int, confidence: float = 0.95
                    ) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion.

    Parameters
    ----------
    successes, trials : int
        Events counted and runs (``0 <= successes <= trials``).
    confidence : float
        Two-sided confidence level in (0, 1).

    Returns
    -------
    (float, float)
        Lower and upper bounds; ``(0, 1)`` when ``trials`` is 0.

    Raises
    ------
    ValueError
        For counts out of range or a confidence outside (0, 1).
    """
    if not (0 <= successes <= trials) or not (0 < confidence < 1):
        raise ValueError(f"need 0 <= successes <= trials and 0 < confidence < 1, got "
                         f"{successes}, {trials}, {confidence}")
    if trials == 0:
        return 0.0, 1.0
    z = float(ndtri(0.5 + confidence / 2))
    p = successes / trials
    denominator = 1 + z**2 / trials
    centre = (p + z**2 / (2 * trials)) / denominator
    half = z * math.sqrt(p * (1 - p) / trials + z**2 / (4 * trials**2)) / denominator
    low = 0.0 if successes == 0 else max(0.0, centre - half)  # exact ends, no round-off
    high = 1.0 if successes == trials else min(1.0, centre + half)
    return low, high


@dataclass(frozen=True)
class RunTable:
    """One row per run, named columns (see :data:`uavdyn.montecarlo.chunks.RESULT_COLUMNS`;
    ``t_diverged_s`` is NaN for a run that did not diverge, outcome columns are NaN for a run
    whose dispersed airframe did not trim, ``trim_ok`` = 0)."""

    columns: tuple[str, ...]
    data: np.ndarray

    def __len__(self) -> int:
        return int(self.data.shape[0])

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.data[:, self.columns.index(name)]
        except ValueError:
            raise KeyError(f"no column '{name}'; columns: {', '.join(self.columns)}") from None

    def csv_text(self) -> str:
        """The table as CSV text (header row, 17 significant digits, empty cell for NaN)."""
        buf = io.StringIO()
        buf.write(",".join(self.columns) + "\n")
        integer = {"run", "trim_ok", "diverged"}
        for row in self.data:
            cells = []
            for name, v in zip(self.columns, row):
                if math.isnan(v):
                    cells.append("")
                elif name in integer:
                    cells.append(str(int(v)))
                else:
                    cells.append(f"{v:.17g}")
            buf.write(",".join(cells) + "\n")
        return buf.getvalue()

    def to_pandas(self):
        """A ``pandas.DataFrame`` of the table (needs pandas)."""
        import pandas as pd  # optional, for notebooks

        return pd.DataFrame(self.data, columns=list(self.columns))


@dataclass(frozen=True)
class Envelopes:
    """Percentile envelopes of the time histories over the runs that trimmed and did not
    diverge.

    Attributes
    ----------
    time : numpy.ndarray
        Sample times (s).
    signals : tuple of str
        :data:`uavdyn.montecarlo.batch.SIGNALS`.
    percentiles : tuple of float
        Default 5, 50, 95.
    values : numpy.ndarray
        ``len(signals) x len(percentiles) x len(time)``, display units (angles in degrees,
        rates in deg/s, airspeed m/s, load factor).
    n_runs : int
        Runs the envelopes are taken over.
    """

    time: np.ndarray
    signals: tuple[str, ...]
    percentiles: tuple[float, ...]
    values: np.ndarray
    n_runs: int

    def band(self, signal: str) -> np.ndarray:
        """``len(percentiles) x len(time)`` of one signal."""
        return self.values[self.signals.index(signal)]

    def csv_text(self) -> str:
        """Long-form CSV: ``time_s`` then ``<signal>_p<percentile>`` columns."""
        names = [f"{s}_p{p:g}" for s in self.signals for p in self.percentiles]
        rows = np.column_stack([self.time] + [self.values[i, j] for i in range(
            len(self.signals)) for j in range(len(self.percentiles))])
        lines = [",".join(["time_s"] + names)]
        lines += [",".join("" if math.isnan(v) else f"{v:.9g}" for v in row) for row in rows]
        return "\n".join(lines) + "\n"


def envelopes(history: np.ndarray, time: np.ndarray, keep: np.ndarray,
              percentiles: tuple[float, ...] = ENVELOPE_PERCENTILES, threads: int = 1
              ) -> Envelopes:
    """Percentiles over runs of ``history`` (``runs x signals x time``, SI units) for the runs
    in the boolean mask ``keep``; NaN where no run is kept.

    Parameters
    ----------
    history : numpy.ndarray
        ``runs x len(SIGNALS) x len(time)``.
    time : numpy.ndarray
        Sample times (s).
    keep : numpy.ndarray
        Boolean mask of the runs to take.
    percentiles : tuple of float
        In [0, 100].
    threads : int
        Threads sharing the work, each on its own slice of sample times (NumPy's selection
        runs without the GIL); every sample's percentiles are computed alone, so the numbers
        do not depend on it.

    Returns
    -------
    Envelopes
    """
    rows = np.flatnonzero(keep)
    every = len(rows) == history.shape[0]
    values = np.full((len(SIGNALS), len(percentiles), len(time)), np.nan)

    def fill(span: slice) -> None:
        for i, signal in enumerate(SIGNALS):  # one signal at a time: bounded memory
            scale = 180 / math.pi if signal in _DEGREES else 1.0
            block = history[:, i, span] if every else history[rows, i, span]
            values[i, :, span] = np.percentile(block.astype(float) * scale, percentiles,
                                               axis=0)

    if len(rows):
        edges = np.linspace(0, len(time), max(1, min(threads, len(time))) + 1).astype(int)
        spans = [slice(a, b) for a, b in zip(edges[:-1], edges[1:])]
        if len(spans) == 1:
            fill(spans[0])
        else:
            with ThreadPoolExecutor(len(spans), thread_name_prefix="uavdyn-envelopes") as pool:
                list(pool.map(fill, spans))
    return Envelopes(np.asarray(time, float), SIGNALS, tuple(percentiles), values, len(rows))


@dataclass(frozen=True)
class Exceedance:
    """Probability of one event over the runs, with its Wilson interval.

    Attributes
    ----------
    event : str
        What was counted, e.g. ``|pitch| > 30 deg``.
    column : str
        The table column it is read from.
    threshold : float
        In the column's units.
    count, runs : int
        Runs with the event, runs considered.
    probability, low, high : float
        ``count / runs`` and the interval at ``confidence``.
    confidence : float
        Two-sided level of the interval.
    """

    event: str
    column: str
    threshold: float
    count: int
    runs: int
    probability: float
    low: float
    high: float
    confidence: float

    def as_dict(self) -> dict:
        return dict(vars(self))


def exceedances(table: RunTable, limits: tuple[float, float, float, float],
                confidence: float = 0.95) -> list[Exceedance]:
    """Exceedance probabilities of every active limit, of any limit, of divergence and of a
    failed trim.

    A run counts for a limit when it passed it at any sample before diverging, or when it
    diverged (a divergence is a failure whatever the limit). Limit and divergence
    probabilities are over the runs that trimmed; the trim failure over all runs.
    """
    pitch, alpha, speed, load = limits
    trimmed = table["trim_ok"] == 1
    n = int(trimmed.sum())
    diverged = (table["diverged"] == 1) & trimmed
    checks = []
    if math.isfinite(pitch):
        checks.append((f"|pitch| > {math.degrees(pitch):.4g} deg", "max_abs_pitch_deg",
                       math.degrees(pitch), lambda v, t: v > t))
    if math.isfinite(alpha):
        checks.append((f"alpha > {math.degrees(alpha):.4g} deg", "max_alpha_deg",
                       math.degrees(alpha), lambda v, t: v > t))
    if math.isfinite(speed):
        checks.append((f"airspeed < {speed:.4g} m/s", "min_airspeed_mps", speed,
                       lambda v, t: v < t))
    if math.isfinite(load):
        checks.append((f"load factor > {load:.4g}", "max_load_factor", load,
                       lambda v, t: v > t))
    out, any_event = [], diverged.copy()
    for event, column, threshold, beyond in checks:
        with np.errstate(invalid="ignore"):
            hit = trimmed & (beyond(table[column], threshold) | diverged)
        any_event |= hit
        out.append(_exceedance(event, column, threshold, int(hit.sum()), n, confidence))
    if checks:
        out.append(_exceedance("any limit (or divergence)", "", math.nan,
                               int(any_event.sum()), n, confidence))
    out.append(_exceedance("diverged", "diverged", 0.5, int(diverged.sum()), n, confidence))
    out.append(_exceedance("trim failed", "trim_ok", 0.5, int((~trimmed).sum()), len(table),
                           confidence))
    return out


def _exceedance(event: str, column: str, threshold: float, count: int, runs: int,
                confidence: float) -> Exceedance:
    low, high = wilson_interval(count, runs, confidence)
    return Exceedance(event, column, threshold, count, runs,
                      count / runs if runs else math.nan, low, high, confidence)


def column_percentiles(table: RunTable, columns: tuple[str, ...],
                       percentiles: tuple[float, ...] = ENVELOPE_PERCENTILES
                       ) -> dict[str, list[float]]:
    """Percentiles of some table columns over the runs that trimmed and did not diverge."""
    keep = (table["trim_ok"] == 1) & (table["diverged"] == 0)
    out = {}
    for c in columns:
        values = table[c][keep]
        out[c] = (np.percentile(values, percentiles).tolist() if len(values)
                  else [math.nan] * len(percentiles))
    return out
