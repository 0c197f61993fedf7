"""Resampling of logged topics onto one uniform time grid (linear for states, held controls).

Stray samples are cut first (:func:`main_block`); the grid spans the time the topics share;
states are interpolated linearly (quaternions sign-continuous and normalised) and controls,
which are commands, are held (zero-order hold).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from uavdyn.flightdata.errors import FlightDataError

MAX_GRID_ROWS = 20_000_000          # grids that would need more rows than this are refused
HOLD_TOLERANCE_S = 1e-7             # a sample 0.1 us "after" a grid instant is at it (rounding)


def main_block(t: np.ndarray, gap_factor: float = 50.0, min_gap_s: float = 1.0) -> np.ndarray:
    """Indices of the longest contiguous run of samples (PX4 logs carry stray samples).

    Parameters
    ----------
    t : ndarray
        Sample times (any unit consistent with ``min_gap_s``; microseconds are divided by
        the caller where needed). Zero times are never kept.
    gap_factor, min_gap_s : float
        A gap longer than ``max(min_gap_s, gap_factor x median step)`` splits the samples.

    Returns
    -------
    ndarray
        Indices into ``t`` of the longest run, in time order.
    """
    t = np.asarray(t, float)
    idx = np.flatnonzero(t > 0)
    if len(idx) < 2:
        return idx
    order = idx[np.argsort(t[idx], kind="stable")]
    ts = t[order]
    steps = np.diff(ts)
    positive = steps[steps > 0]
    median = float(np.median(positive)) if len(positive) else 0.0
    limit = max(min_gap_s, gap_factor * median)
    cuts = np.flatnonzero(steps > limit)
    bounds = np.concatenate([[0], cuts + 1, [len(ts)]])
    k = int(np.argmax(np.diff(bounds)))
    return order[bounds[k]:bounds[k + 1]]


def _grid(t0: float, t1: float, rate_hz: float, path: Path) -> np.ndarray:
    """The uniform grid ``t0 + k / rate_hz`` over ``[t0, t1]`` (at least 2, at most
    MAX_GRID_ROWS rows)."""
    rows = (t1 - t0) * rate_hz
    if rows + 1 > MAX_GRID_ROWS:
        raise FlightDataError(f"the common time span {t1 - t0:.6g} s at rate_hz {rate_hz:g} "
                              f"would need {rows:.3g} rows, above the limit of {MAX_GRID_ROWS}; "
                              "pass a lower rate_hz", path, column="time")
    n = int(math.floor(rows + 1e-9)) + 1
    if n < 2:
        raise FlightDataError(f"the common time span {t1 - t0:.6g} s holds fewer than 2 "
                              f"samples at rate_hz {rate_hz:g}", path, column="time")
    return t0 + np.arange(n) / rate_hz


def _interp(t_grid: np.ndarray, t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Each column of ``v`` (sampled at ``t``) linearly interpolated at ``t_grid``."""
    return np.column_stack([np.interp(t_grid, t, v[:, j]) for j in range(v.shape[1])])


def _hold(t_grid: np.ndarray, t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Zero-order hold: the last sample at or before each grid time (the first before it).

    A sample counts as "at" a grid time within HOLD_TOLERANCE_S: ``t0 + k / rate`` and
    ``stamp * 1e-6`` of the very same instant can differ by an ulp, and the hold must not
    then fall back to the previous command (stamps are whole microseconds, so 0.1 us never
    lets a genuinely later sample in)."""
    i = np.clip(np.searchsorted(t, t_grid + HOLD_TOLERANCE_S, side="right") - 1, 0, len(t) - 1)
    return v[i]


def _quaternions_on_grid(t_grid: np.ndarray, t: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Quaternions made sign-continuous (q and -q are one attitude), interpolated and
    normalised."""
    dots = np.einsum("ij,ij->i", q[1:], q[:-1])
    signs = np.cumprod(np.concatenate([[1.0], np.where(dots < 0, -1.0, 1.0)]))
    qi = _interp(t_grid, t, q * signs[:, None])
    return qi / np.linalg.norm(qi, axis=1, keepdims=True)


GAP_FACTOR = 5.0      # a topic's interval longer than this many median intervals is a gap
MIN_GAP_S = 0.5       # ... and never shorter than this


def in_gap(t_grid: np.ndarray, t: np.ndarray, gap_factor: float = GAP_FACTOR,
           min_gap_s: float = MIN_GAP_S) -> np.ndarray:
    """Which grid times fall inside a gap of the topic sampled at ``t`` (or outside its span):
    there the interpolated value is invented, so the segmenter must cut. A gap is an interval
    longer than ``max(min_gap_s, gap_factor x median interval)``."""
    t = np.asarray(t, float)
    out = (t_grid < t[0]) | (t_grid > t[-1])
    if len(t) < 2:
        return out | True
    steps = np.diff(t)
    limit = max(min_gap_s, gap_factor * float(np.median(steps)))
    for k in np.flatnonzero(steps > limit):
        out |= (t_grid > t[k]) & (t_grid < t[k + 1])
    return out


def _missing_runs(missing: np.ndarray) -> list[tuple[int, int]]:
    """``(first, last)`` sample index of each run of True in ``missing``."""
    edges = np.diff(np.concatenate([[0], missing.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1))


def _snapped(grid: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Grid times within HOLD_TOLERANCE_S of a stamp moved onto it: ``t0 + k / rate`` and a
    stamp of the same instant can differ by an ulp, which must not open a gap."""
    if not len(t):
        return grid
    i = np.clip(np.searchsorted(t, grid), 1, len(t) - 1) if len(t) > 1 else np.zeros(
        len(grid), int)
    near = t[i] if len(t) == 1 else np.where(np.abs(grid - t[i - 1]) < np.abs(grid - t[i]),
                                             t[i - 1], t[i])
    return np.where(np.abs(grid - near) <= HOLD_TOLERANCE_S, near, grid)


def gap_mask(grid: np.ndarray, t: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Grid points whose value would be invented: inside a long pause of the stamps ``t`` or
    outside them (:func:`in_gap`), or strictly between the valid neighbours of a sample that
    has no value (NaN: an empty cell, a value the log marked invalid)."""
    missing = ~np.isfinite(values)
    grid = _snapped(grid, t)
    valid_t = t[~missing]
    out = in_gap(grid, valid_t) if len(valid_t) else np.ones(len(grid), bool)
    for first, last in _missing_runs(missing):
        lo = t[first - 1] if first > 0 else -np.inf
        hi = t[last + 1] if last + 1 < len(t) else np.inf
        out |= (grid > lo) & (grid < hi)
    return out


def interp_on_grid(grid: np.ndarray, t: np.ndarray, values: np.ndarray,
                   angle: bool = False) -> np.ndarray:
    """A state sampled at ``t`` linearly interpolated on the grid, NaN where :func:`gap_mask`
    says it would be invented. ``angle=True`` unwraps first (a yaw crossing +-pi must not
    swing through zero) and wraps the result back to [-pi, pi)."""
    values = np.asarray(values, float)
    ok = np.isfinite(values)
    if ok.sum() < 2:
        return np.full(len(grid), np.nan)
    v = np.unwrap(values[ok]) if angle else values[ok]
    out = np.interp(grid, t[ok], v)
    if angle:
        out = (out + np.pi) % (2 * np.pi) - np.pi
    out[gap_mask(grid, t, values)] = np.nan
    return out


def hold_on_grid(grid: np.ndarray, t: np.ndarray, values: np.ndarray) -> np.ndarray:
    """A command sampled at ``t`` held (zero-order) on the grid: NaN where the held sample is
    NaN or the stamps pause (:func:`in_gap`)."""
    values = np.asarray(values, float)
    out = _hold(grid, t, values[:, None])[:, 0]
    out[in_gap(_snapped(grid, t), t)] = np.nan
    return out


def states_on_grid(grid: np.ndarray, t: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Each column of ``values`` (``N x k`` sampled at ``t``) by :func:`interp_on_grid`."""
    return np.column_stack([interp_on_grid(grid, t, values[:, j])
                            for j in range(values.shape[1])])


def commands_on_grid(grid: np.ndarray, t: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Each column of ``values`` (``N x k`` sampled at ``t``) by :func:`hold_on_grid`."""
    return np.column_stack([hold_on_grid(grid, t, values[:, j])
                            for j in range(values.shape[1])])
