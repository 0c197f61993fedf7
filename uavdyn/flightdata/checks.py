"""Consistency checks of sortie arrays (values, time, ranges, controls, kinematics).

Every check raises a :class:`FlightDataError` naming the first offending data row and column:
finite values, enough rows, strictly increasing and uniform time, physical ranges, controls
within bounds, and the pitch-plane kinematics ``d theta/dt ~ q``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from uavdyn.flightdata.errors import FlightDataError
from uavdyn.flightdata.sortie import csv_columns
from uavdyn.model import (
    CONTROL_BOUNDS,
    CONTROL_NAMES,
    first_departure,
)

CONTROL_TOLERANCE = 1e-9
TIME_TOLERANCE = 1e-3    # allowed relative deviation of each interval from the nominal one
KINEMATIC_WINDOW_S = 1.0
KINEMATIC_TOLERANCE = 0.05  # rad, plus 10 % of the pitch travelled in the window
MIN_ROWS = 3             # two intervals: the least that lets "uniform time" be checked


def _check_finite(path: str | Path, table: np.ndarray, columns: tuple[str, ...]) -> None:
    """Every value of ``table`` (data rows, columns named by ``columns``) is finite; else a
    :class:`FlightDataError` names the first that is not, with its data row and column."""
    bad = np.argwhere(~np.isfinite(table))
    if len(bad):
        r, c = bad[0]
        raise FlightDataError(f"value {table[r, c]} is not finite", path, int(r) + 1,
                              columns[c])


def _running_integral(time: np.ndarray, rate: np.ndarray, absolute: bool = False
                      ) -> np.ndarray:
    """Trapezoid integral of ``rate`` from the first sample to each sample (0 at the first);
    with ``absolute`` each interval's trapezoid counts unsigned (the travel, not the change)."""
    pair = rate[1:] + rate[:-1]
    if absolute:
        pair = np.abs(pair)
    return np.concatenate([[0.0], np.cumsum(0.5 * pair * np.diff(time))])


def check_values(path: str | Path, kind: str, time: np.ndarray, states: np.ndarray,
                 controls: np.ndarray, sample_rate_hz: float | None = None,
                 kinematic: bool = True) -> None:
    """Consistency checks of one sortie's arrays, so that bad data never reaches a model.

    Finite values, at least :data:`MIN_ROWS` rows, strictly increasing and uniform time,
    physical ranges, controls within bounds and, if ``kinematic``, d theta/dt against q.

    Parameters
    ----------
    path : str or Path
        What to name in messages (the file, or a description of generated data).
    kind : str
        ``fixed_wing`` or ``multirotor``.
    time, states, controls : ndarray
        ``N``, ``N x 4`` and ``N x 2`` arrays in the CSV column order.
    sample_rate_hz : float, optional
        The time column must match this rate.
    kinematic : bool
        Also check d theta/dt against q (default).

    Raises
    ------
    FlightDataError
        The first problem, naming ``path``, the data row and the column.
    """
    lateral = controls.ndim == 2 and controls.shape[1] > 2
    columns = csv_columns(kind, lateral)
    _check_finite(path, np.column_stack([time, states, controls]), columns)
    if len(time) < MIN_ROWS:
        raise FlightDataError(f"only {len(time)} data row(s); a sortie needs at least "
                              f"{MIN_ROWS} (need at least 2 for a sample interval, {MIN_ROWS} "
                              "to check that time is uniform)", path)
    steps = np.diff(time)
    nonpos = np.flatnonzero(steps <= 0)
    if len(nonpos):
        k = int(nonpos[0]) + 1
        raise FlightDataError(f"time {float(time[k])!r} s is not greater than the previous "
                              f"row's {float(time[k - 1])!r} s (time must strictly increase)",
                              path, k + 1,
                              "time")
    nominal = float(np.median(steps))
    if sample_rate_hz is not None:
        if abs(nominal * sample_rate_hz - 1.0) > TIME_TOLERANCE:
            raise FlightDataError(f"median sample interval {nominal:.6g} s does not match the "
                                  f"manifest's sample_rate_hz {sample_rate_hz:g}", path,
                                  column="time")
        nominal = 1.0 / sample_rate_hz
    off = np.flatnonzero(np.abs(steps - nominal) > TIME_TOLERANCE * nominal)
    if len(off):
        k = int(off[0]) + 1
        raise FlightDataError(f"time step {steps[k - 1]:.6g} s from the previous row differs "
                              f"from the nominal {nominal:.6g} s by more than "
                              f"{TIME_TOLERANCE:.1%} (time must be uniform)", path, k + 1, "time")
    departure = first_departure(states, kind)  # physical ranges (units slip-ups land outside)
    if departure is not None:
        raise FlightDataError(f"value {departure.describe()} (wrong units, e.g. degrees or "
                              "km/h?)", path, departure.index + 1, departure.state)
    for j, (name, (lo, hi)) in enumerate(zip(CONTROL_NAMES[kind], CONTROL_BOUNDS[kind])):
        out = np.flatnonzero((controls[:, j] < lo - CONTROL_TOLERANCE)
                             | (controls[:, j] > hi + CONTROL_TOLERANCE))
        if len(out):
            r = int(out[0])
            raise FlightDataError(f"value {controls[r, j]:.6g} is outside the control range "
                                  f"[{lo:g}, {hi:g}]", path, r + 1, name)
    if kinematic:
        check_kinematics(path, time, pitch_kinematics(states, controls))


def pitch_kinematics(states: np.ndarray, controls: np.ndarray) -> np.ndarray:
    """``states`` with ``q`` replaced by the Euler pitch rate ``q cos(phi) - r sin(phi)`` where
    the controls carry the lateral inputs (turning flight), else ``states`` itself."""
    if controls.ndim != 2 or controls.shape[1] <= 2:
        return states
    phi, r = controls[:, 2], controls[:, 4]
    out = np.array(states, dtype=float, copy=True)
    out[:, 2] = states[:, 2] * np.cos(phi) - r * np.sin(phi)
    return out


def kinematic_residual(time: np.ndarray, states: np.ndarray,
                       window_s: float = KINEMATIC_WINDOW_S) -> tuple[np.ndarray, np.ndarray]:
    """Per window of ``window_s`` seconds (half-overlapping): the pitch change minus the
    trapezoid integral of q, and the pitch travelled (integral of ``|q|``). Start indices are
    the first return value's index times the hop; see :func:`check_kinematics`."""
    theta, q = states[:, 3], states[:, 2]
    cum = _running_integral(time, q)
    cum_abs = _running_integral(time, q, absolute=True)
    n = len(time)
    width = max(1, int(round(window_s / float(np.median(np.diff(time))))))
    width = min(width, n - 1)
    starts = np.arange(0, n - width, max(1, width // 2))
    if len(starts) == 0:
        starts = np.array([0])
    ends = starts + width
    diff = (theta[ends] - theta[starts]) - (cum[ends] - cum[starts])
    travel = cum_abs[ends] - cum_abs[starts]
    return np.column_stack([starts, ends, diff]), travel


def check_kinematics(path: str | Path, time: np.ndarray, states: np.ndarray,
                     window_s: float = KINEMATIC_WINDOW_S,
                     tolerance: float = KINEMATIC_TOLERANCE) -> None:
    """d theta/dt ~ q: over every window the pitch change must match the integrated pitch rate
    within ``tolerance`` rad plus 10 % of the pitch travelled (noise and gyro bias of valid
    logs pass; pitch in degrees, q in deg/s or a flipped sign do not)."""
    windows, travel = kinematic_residual(time, states, window_s)
    allowed = tolerance + 0.1 * travel
    bad = np.flatnonzero(np.abs(windows[:, 2]) > allowed)
    if len(bad):
        i = int(bad[0])
        a, b, d = int(windows[i, 0]), int(windows[i, 1]), windows[i, 2]
        raise FlightDataError(
            f"kinematic inconsistency over data rows {a + 1}-{b + 1} (t = {time[a]:.3f}-"
            f"{time[b]:.3f} s): the pitch change differs from the integral of q by {d:.4g} rad "
            f"(allowed {allowed[i]:.3g} rad); theta and q disagree (units or sign?)", path,
            b + 1, "theta")
