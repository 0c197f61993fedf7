"""A six-degree-of-freedom flight log on one uniform grid: what every importer produces.

A real flight rolls, yaws and sits on the ground; the longitudinal model holds only on some of
it. The importers (PX4 ULog, ALFA folders, ArduPilot DataFlash, the generic CSV) therefore do
not write sorties directly: each reads its format into a :class:`FlightLog` (attitude, body
rates, body velocities, controls already in the airframe's convention, altitude, airspeed and
an airborne flag where the log has them), and :mod:`uavdyn.flightdata.segments` cuts that into
the wings-level stretches the model can be fitted on.

Samples a sensor did not cover (a gap in its topic, a value the log marks invalid) are NaN in
that channel, never interpolated across, so the segmenter can cut there.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from uavdyn.flightdata.errors import FlightDataError
from uavdyn.model import CONTROL_NAMES

CHANNELS = ("roll", "pitch", "p", "q", "r", "u", "v", "w")
"""The attitude (rad), body-rate (rad/s, FRD) and body-velocity (m/s, FRD) channels."""

VELOCITY_REFERENCES = ("air", "airspeed", "ground")
"""How ``u, v, w`` relate to the air: ``air`` (the log's wind estimate removed), ``airspeed``
(``u`` from the airspeed sensor, ``sqrt(Va^2 - w^2)``, with ``v, w`` ground relative) or
``ground`` (ground relative: no airspeed sensor and no wind estimate in the log)."""


@dataclass
class FlightLog:
    """One flight on a uniform time grid, in aircraft conventions (FRD body, NED world).

    Attributes
    ----------
    name : str
        Used to name the segments (``<name>_s01`` ...).
    kind : {'fixed_wing', 'multirotor'}
        Which airframe convention ``controls`` follow.
    time : ndarray
        Uniform grid, s from the grid's first sample.
    channels : dict of str to ndarray
        Every name of :data:`CHANNELS`, each ``N`` values (NaN where the sensor gave none).
    controls : ndarray
        ``N x 2`` in the airframe's command convention (``CONTROL_NAMES[kind]``).
    velocity_reference : str
        One of :data:`VELOCITY_REFERENCES`.
    source : str
        The format, e.g. ``'PX4 ULog'``.
    altitude_m : ndarray, optional
        Altitude above mean sea level (m) for the atmosphere; None if the log has none.
    airspeed : ndarray, optional
        Airspeed sensor (m/s); None if the log has none.
    airborne : ndarray of bool, optional
        The log's own in-air flag (land detector, ``isFlying``); None if it has none.
    meta : dict
        Provenance: the file, ``start_time_s`` (the grid's first sample in the log's clock),
        the source of each channel, the control mapping, how the log was resampled.
    """

    name: str
    kind: str
    time: np.ndarray
    channels: dict[str, np.ndarray]
    controls: np.ndarray
    velocity_reference: str
    source: str
    altitude_m: np.ndarray | None = None
    airspeed: np.ndarray | None = None
    airborne: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.time)
        if self.kind not in CONTROL_NAMES:
            raise FlightDataError(f"unknown airframe kind {self.kind!r}; expected one of "
                                  f"{tuple(CONTROL_NAMES)}")
        if self.velocity_reference not in VELOCITY_REFERENCES:
            raise FlightDataError(f"velocity reference {self.velocity_reference!r} is not one "
                                  f"of {VELOCITY_REFERENCES}")
        missing = [c for c in CHANNELS if c not in self.channels]
        if missing:
            raise FlightDataError(f"flight log {self.name}: no channel {', '.join(missing)}")
        arrays = {**self.channels, "controls": self.controls, "altitude_m": self.altitude_m,
                  "airspeed": self.airspeed, "airborne": self.airborne}
        for key, value in arrays.items():
            if value is not None and len(value) != n:
                raise FlightDataError(f"flight log {self.name}: channel {key} has {len(value)} "
                                      f"samples, the time grid {n}")

    @property
    def dt(self) -> float:
        """The grid interval (s)."""
        return float(self.time[1] - self.time[0]) if len(self.time) > 1 else float("nan")

    @property
    def duration(self) -> float:
        """Grid span (s)."""
        return float(self.time[-1] - self.time[0]) if len(self.time) else 0.0

    def states(self) -> np.ndarray:
        """``N x 4`` longitudinal states ``u, w, q, theta`` (the interchange format's order)."""
        c = self.channels
        return np.column_stack([c["u"], c["w"], c["q"], c["pitch"]])


ANTI_ALIAS_FRACTION = 0.4   # low-pass cut-off as a fraction of the new rate (0.8 x Nyquist)
ANTI_ALIAS_ORDER = 4


def _lowpass_finite_runs(values: np.ndarray, cutoff_hz: float, rate_hz: float) -> np.ndarray:
    """Zero-phase Butterworth low-pass of each finite run of ``values`` separately (a gap is
    never bridged; a run too short to filter is kept as it is)."""
    from scipy.signal import butter, filtfilt

    b, a = butter(ANTI_ALIAS_ORDER, cutoff_hz / (rate_hz / 2))
    out = values.copy()
    finite = np.isfinite(values)
    edges = np.diff(np.concatenate([[0], finite.astype(np.int8), [0]]))
    for start, stop in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):
        if stop - start > 3 * (max(len(a), len(b)) + 1):
            out[start:stop] = filtfilt(b, a, values[start:stop])
    return out


def resample_flight(flight: FlightLog, rate_hz: float) -> FlightLog:
    """``flight`` on a uniform grid at ``rate_hz``: a lower rate is low-pass filtered first
    (zero-phase Butterworth, order 4, cut-off 0.4 x the new rate, so nothing above the new
    Nyquist frequency folds back), states interpolated linearly, controls and flags held; a
    higher rate is interpolated only (it adds no information). Gaps stay gaps. The method is
    recorded in ``meta['resampling']``."""
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise FlightDataError(f"resampling rate must be a positive number of Hz, got {rate_hz!r}")
    old_rate = 1.0 / flight.dt
    if abs(rate_hz - old_rate) <= 1e-9 * old_rate:
        return flight
    grid = np.arange(0.0, flight.duration + 1e-9 / rate_hz, 1.0 / rate_hz)
    down = rate_hz < old_rate
    cutoff = ANTI_ALIAS_FRACTION * rate_hz

    def state(values: np.ndarray | None) -> np.ndarray | None:
        if values is None:
            return None
        smooth = _lowpass_finite_runs(values, cutoff, old_rate) if down else values
        out = np.interp(grid, flight.time, smooth)
        gap = np.interp(grid, flight.time, (~np.isfinite(values)).astype(float)) > 0
        out[gap] = np.nan
        return out

    held = np.clip(np.searchsorted(flight.time, grid + 1e-9, side="right") - 1, 0,
                   len(flight.time) - 1)
    channels = {k: state(v) for k, v in flight.channels.items()}
    method = (f"low-pass filtered (zero-phase Butterworth order {ANTI_ALIAS_ORDER}, cut-off "
              f"{cutoff:g} Hz) then " if down else "") + \
        (f"resampled from {old_rate:.6g} Hz to {rate_hz:g} Hz: states linear, controls and "
         "flags held; gaps kept")
    meta = {**flight.meta, "rate_hz": float(rate_hz),
            "resampling": flight.meta.get("resampling", "") + "; then " + method}
    return FlightLog(flight.name, flight.kind, grid, channels, flight.controls[held],
                     flight.velocity_reference, flight.source, state(flight.altitude_m),
                     state(flight.airspeed),
                     None if flight.airborne is None else flight.airborne[held], meta)
