"""Per-sortie spread of an error: pooled RMSE from per-sortie sums, a bootstrap interval over
sorties, and paired comparisons of two models sortie by sortie.

A pooled figure hides which sorties carry it; the sortie is the unit of independent data (the
samples inside one sortie are strongly correlated), so intervals resample whole sorties. Every
figure here is recomputed from ``(sum of squared errors, sample count)`` per sortie, which the
report stores: a reader can recompute the headline from the per-sortie table.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

BOOTSTRAP_RESAMPLES = 2000
BOOTSTRAP_SEED = 20261124


@dataclass(frozen=True)
class SortieError:
    """One sortie's error of one model: sum of squared pitch errors and sample count; a
    non-finite sum means the prediction diverged (non-finite or out of range)."""

    sortie: str
    sse: float
    n: int

    @property
    def finite(self) -> bool:
        return math.isfinite(self.sse)

    @property
    def rmse(self) -> float:
        return math.sqrt(self.sse / self.n) if self.finite and self.n else math.inf


@dataclass(frozen=True)
class PooledError:
    """Pooled RMSE over the finite sorties of a group, with its bootstrap interval over those
    sorties, and how many sorties diverged (left out of the pooled figure, counted here)."""

    rmse: float
    low: float
    high: float
    sorties: int
    diverged: int
    level: float = 0.95

    def to_dict(self) -> dict:
        return {"rmse": self.rmse, "ci_low": self.low, "ci_high": self.high,
                "sorties": self.sorties, "diverged": self.diverged, "level": self.level}


def squared_error(predicted: np.ndarray, target: np.ndarray, column: int = 3,
                  limit: float = 1e3) -> tuple[float, int]:
    """``(sum of squared errors, count)`` of one state column; inf if any error is non-finite
    or beyond ``limit`` (a diverged prediction has no meaningful error)."""
    with np.errstate(over="ignore", invalid="ignore"):
        err = np.asarray(predicted)[..., column] - np.asarray(target)[..., column]
        err = err.reshape(-1)
        if not np.all(np.isfinite(err)) or np.any(np.abs(err) > limit):
            return math.inf, int(err.size)
        return float(np.sum(err**2)), int(err.size)


def pooled_rmse(errors: Sequence[SortieError]) -> float:
    """sqrt(sum of squared errors / samples) over the finite sorties (nan if none)."""
    finite = [e for e in errors if e.finite]
    n = sum(e.n for e in finite)
    return math.sqrt(sum(e.sse for e in finite) / n) if n else math.nan


def pooled_with_interval(errors: Sequence[SortieError], level: float = 0.95,
                         resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED
                         ) -> PooledError:
    """Pooled RMSE and its percentile bootstrap interval, resampling whole sorties with
    replacement (``resamples`` draws, fixed ``seed``: the same table gives the same interval).

    Parameters
    ----------
    errors
        One :class:`SortieError` per sortie of the group.
    level
        Coverage of the interval.

    Returns
    -------
    PooledError
        Diverged sorties are excluded from the figure and counted in ``diverged``.
    """
    finite = [e for e in errors if e.finite]
    diverged = len(errors) - len(finite)
    if not finite:
        return PooledError(math.nan, math.nan, math.nan, len(errors), diverged, level)
    sse = np.array([e.sse for e in finite])
    n = np.array([e.n for e in finite], float)
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, len(finite), size=(resamples, len(finite)))
    boot = np.sqrt(sse[draws].sum(axis=1) / n[draws].sum(axis=1))
    tail = (1.0 - level) / 2.0 * 100.0
    low, high = np.percentile(boot, [tail, 100.0 - tail])
    return PooledError(pooled_rmse(finite), float(low), float(high), len(errors), diverged,
                       level)


@dataclass(frozen=True)
class PairedComparison:
    """Model B against model A sortie by sortie: the ratio B/A of per-sortie RMSE, how many
    sorties B is worse on (and by more than ``tolerance``), and where B diverges but A not."""

    ratios: dict[str, float]
    worse: tuple[str, ...]
    worse_beyond_tolerance: tuple[str, ...]
    new_divergence: tuple[str, ...]
    tolerance: float

    def to_dict(self) -> dict:
        return {"ratios": self.ratios, "worse": list(self.worse),
                "worse_beyond_tolerance": list(self.worse_beyond_tolerance),
                "new_divergence": list(self.new_divergence), "tolerance": self.tolerance}


def compare_paired(a: Sequence[SortieError], b: Sequence[SortieError], tolerance: float = 0.10
                   ) -> PairedComparison:
    """Sortie-by-sortie comparison of ``b`` (e.g. the corrected model) against ``a`` (e.g. the
    identified physics); both lists cover the same sorties.

    Raises
    ------
    ValueError
        If the two lists are not about the same sorties in the same order.
    """
    if [e.sortie for e in a] != [e.sortie for e in b]:
        raise ValueError("paired comparison needs the same sorties in the same order")
    ratios, worse, beyond, new_div = {}, [], [], []
    for ea, eb in zip(a, b):
        if not eb.finite:
            ratios[ea.sortie] = math.inf
            if ea.finite:
                new_div.append(ea.sortie)
            continue
        if not ea.finite:
            ratios[ea.sortie] = 0.0
            continue
        ratio = eb.rmse / ea.rmse if ea.rmse > 0 else (math.inf if eb.rmse > 0 else 1.0)
        ratios[ea.sortie] = ratio
        if ratio > 1.0:
            worse.append(ea.sortie)
        if ratio > 1.0 + tolerance:
            beyond.append(ea.sortie)
    return PairedComparison(ratios, tuple(worse), tuple(beyond), tuple(new_div), tolerance)


@dataclass(frozen=True)
class ErrorShare:
    """The share of model A's pooled error that model B removes, ``(A - B) / (A - R)``, with
    its bootstrap interval over sorties: R is 0 (the share of A's error removed) or a
    reference model's pooled error (the share of the gap from A down to R that B recovers).
    ``share`` is None where the gap is within noise (below ``min_gap`` of A); ``left_out``
    counts the bootstrap draws whose gap was, which the interval does not cover."""

    share: float | None
    low: float
    high: float
    sorties: int
    left_out: int = 0
    resamples: int = BOOTSTRAP_RESAMPLES
    level: float = 0.95

    def to_dict(self) -> dict:
        return {"share": self.share, "ci_low": self.low, "ci_high": self.high,
                "sorties": self.sorties, "draws_left_out": self.left_out,
                "resamples": self.resamples, "level": self.level}


def error_share(base: Sequence[SortieError], model: Sequence[SortieError],
                reference: Sequence[SortieError] | None = None, level: float = 0.95,
                resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED,
                min_gap: float = 0.0) -> ErrorShare:
    """:class:`ErrorShare` of ``model`` against ``base`` (and ``reference``), over the sorties
    finite in all of them; each bootstrap draw resamples whole sorties once for every model.
    A gap ``A - R`` not above ``min_gap * A`` has no share (within noise): the point figure is
    None, a draw is left out of the interval.

    Raises
    ------
    ValueError
        If the lists are not about the same sorties in the same order.
    """
    lists = [base, model] + ([reference] if reference is not None else [])
    if any([e.sortie for e in other] != [e.sortie for e in base] for other in lists[1:]):
        raise ValueError("an error share needs the same sorties in the same order")
    keep = [i for i in range(len(base)) if all(errs[i].finite for errs in lists)]
    if not keep:
        return ErrorShare(None, math.nan, math.nan, 0, 0, resamples, level)
    sse = np.array([[errs[i].sse for i in keep] for errs in lists])
    n = np.array([base[i].n for i in keep], float)

    def shares(index: np.ndarray) -> np.ndarray:
        rmse = np.sqrt(sse[:, index].sum(axis=-1) / n[index].sum(axis=-1))
        gap = rmse[0] - (rmse[2] if reference is not None else 0.0)
        ok = (gap > min_gap * rmse[0]) & (gap > 0)
        return np.where(ok, (rmse[0] - rmse[1]) / np.where(ok, gap, 1.0), np.nan)

    point = float(shares(np.arange(len(keep))))
    draws = np.random.default_rng(seed).integers(0, len(keep), size=(resamples, len(keep)))
    boot = shares(draws)
    boot = boot[np.isfinite(boot)]
    tail = (1.0 - level) / 2.0 * 100.0
    low, high = (np.percentile(boot, [tail, 100.0 - tail]) if len(boot)
                 else (math.nan, math.nan))
    return ErrorShare(point if math.isfinite(point) else None, float(low), float(high),
                      len(keep), resamples - len(boot), resamples, level)
