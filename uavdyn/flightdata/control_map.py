"""How a logged command becomes the airframe's control: a stated, overridable linear map.

A log records what the autopilot sent (a servo PWM in microseconds, a normalised command in
[-1, 1], a throttle in [0, 1]); the model wants the airframe's own convention (elevator in
radians, positive trailing edge down; throttle or collective in [0, 1]; pitch command in
[-1, 1]). Which PWM is full up elevator is a fact of the user's aircraft, not of the log, so
every importer states the map it used (recorded in the manifest) and the user can override it:
``--control-map elevator=RCOU.C2:1100:1900:0.35:-0.35``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from uavdyn.flightdata.csvio import parse_number
from uavdyn.flightdata.errors import FlightDataError
from uavdyn.model import CONTROL_BOUNDS, CONTROL_NAMES


@dataclass(frozen=True)
class ChannelMap:
    """``control = value_low + (raw - raw_low) * (value_high - value_low) / (raw_high -
    raw_low)``: the raw reading ``raw_low`` gives ``value_low``, ``raw_high`` gives
    ``value_high`` (so a reversed servo is a map with the values swapped).

    Attributes
    ----------
    control : str
        The airframe control it feeds (``elevator``, ``throttle``, ``collective``,
        ``pitch_cmd``).
    source : str
        The logged field read, in the format's own naming (``RCOU.C2``, ``field.channels1``,
        a CSV column).
    raw_low, raw_high, value_low, value_high : float
        Two points of the line; ``raw_low != raw_high``.
    """

    control: str
    source: str
    raw_low: float
    raw_high: float
    value_low: float
    value_high: float

    def __post_init__(self) -> None:
        numbers = (self.raw_low, self.raw_high, self.value_low, self.value_high)
        if not all(math.isfinite(v) for v in numbers):
            raise FlightDataError(f"control map of {self.control}: every number must be "
                                  f"finite, got {numbers}")
        if self.raw_low == self.raw_high:
            raise FlightDataError(f"control map of {self.control}: the two raw readings are "
                                  f"both {self.raw_low:g}")

    def apply(self, raw: np.ndarray) -> np.ndarray:
        """The control for each raw reading."""
        slope = (self.value_high - self.value_low) / (self.raw_high - self.raw_low)
        return self.value_low + (np.asarray(raw, dtype=float) - self.raw_low) * slope

    def describe(self) -> str:
        """One line for the manifest and the import summary."""
        return (f"{self.control} = {self.source} mapped linearly, {self.raw_low:g} -> "
                f"{self.value_low:g}, {self.raw_high:g} -> {self.value_high:g}")

    def as_dict(self) -> dict:
        """The map as JSON-ready values."""
        return {"source": self.source, "raw": [self.raw_low, self.raw_high],
                "value": [self.value_low, self.value_high]}


def parse_channel_map(text: str) -> ChannelMap:
    """``CONTROL=SOURCE:RAW_LOW:RAW_HIGH:VALUE_LOW:VALUE_HIGH`` as a :class:`ChannelMap`.

    Raises
    ------
    FlightDataError
        One line saying which part of ``text`` is wrong.
    """
    control, sep, rest = text.partition("=")
    if not sep or not control:
        raise FlightDataError(f"control map {text!r}: expected CONTROL=SOURCE:RAW_LOW:RAW_HIGH:"
                              "VALUE_LOW:VALUE_HIGH")
    parts = rest.rsplit(":", 4)
    if len(parts) != 5 or not parts[0]:
        raise FlightDataError(f"control map {text!r}: expected CONTROL=SOURCE:RAW_LOW:RAW_HIGH:"
                              "VALUE_LOW:VALUE_HIGH (five fields after '=')")
    try:
        numbers = [parse_number(v.strip(" \t")) for v in parts[1:]]
    except ValueError:
        raise FlightDataError(f"control map {text!r}: RAW_LOW, RAW_HIGH, VALUE_LOW, VALUE_HIGH "
                              "must be numbers") from None
    return ChannelMap(control.strip(), parts[0].strip(), *numbers)


def override(defaults: dict[str, ChannelMap], given: list[ChannelMap] | None
             ) -> dict[str, ChannelMap]:
    """The format's default maps with the user's replacing those of the same control.

    Raises
    ------
    FlightDataError
        A given map for a control the airframe kind does not have.
    """
    maps = dict(defaults)
    for m in given or []:
        if m.control not in maps:
            raise FlightDataError(f"control map for {m.control!r}: this log's controls are "
                                  f"{', '.join(maps)}")
        maps[m.control] = m
    return maps


def override_maps(defaults: dict[str, ChannelMap], given: list[ChannelMap] | None,
                  path: Path) -> dict[str, ChannelMap]:
    """:func:`override` with the file named in its refusal (a map for a control the
    airframe kind does not have)."""
    try:
        return override(defaults, given)
    except FlightDataError as exc:
        raise FlightDataError(exc.reason, path, column=exc.column) from None


PWM_RANGE_US = (800.0, 2200.0)
"""What an RC servo or ESC pulse can be (us); a map whose raw points lie inside this range reads
a PWM channel, and its readings must lie in it (or between the map's own points if wider)."""
CHANNEL_SLACK = 1e-6   # relative slack on the control limits (float32 rounding of a logged 1.0)


def _is_pwm(m: ChannelMap) -> bool:
    """Whether the map reads a servo pulse width (both raw points are plausible PWM)."""
    lo, hi = PWM_RANGE_US
    return all(lo <= v <= hi for v in (m.raw_low, m.raw_high))


def check_channel(m: ChannelMap, raw: np.ndarray, path: str | Path, *, rows: bool = True,
                  times: np.ndarray | None = None, column: str | None = None) -> None:
    """Refuse a logged reading the channel cannot hold, before it is resampled.

    A PWM channel (:func:`_is_pwm`) holds :data:`PWM_RANGE_US` (widened to the map's own
    points); every control holds its airframe-kind range after the map (throttle and
    collective are shares 0..1, the elevator +-30 deg, the pitch command -1..1:
    :data:`uavdyn.model.CONTROL_BOUNDS`). A throttle of 5 or a pulse of 3000 us is a unit or
    logging fault, not a flight condition, so it is refused rather than cut out later.

    Parameters
    ----------
    m : ChannelMap
        The map the readings go through.
    raw : ndarray
        The logged readings in file order (NaN, an empty cell, is skipped).
    path : str or Path
        The file named in the message.
    rows : bool
        Name the reading as data row ``k + 1`` (a CSV) rather than as sample ``k + 1``.
    times : ndarray, optional
        Sample times (s) quoted with a sample (formats without rows).
    column : str, optional
        The field named (default ``m.source``).

    Raises
    ------
    FlightDataError
        One line naming the file, the row or sample, the field and the limit.
    """
    raw = np.asarray(raw, dtype=float)
    limits = []
    if _is_pwm(m):
        lo = min(PWM_RANGE_US[0], m.raw_low, m.raw_high)
        hi = max(PWM_RANGE_US[1], m.raw_low, m.raw_high)
        limits.append((raw, lo, hi, f"{lo:g}-{hi:g} us, what a servo pulse can be"))
    bounds = {n: b for kind in CONTROL_NAMES for n, b in zip(CONTROL_NAMES[kind],
                                                              CONTROL_BOUNDS[kind])}
    if m.control in bounds:
        lo, hi = bounds[m.control]
        slack = CHANNEL_SLACK * max(1.0, hi - lo)
        share = " (a share of full power)" if lo == 0.0 and hi == 1.0 else ""
        limits.append((m.apply(raw), lo - slack, hi + slack,
                       f"{m.control} {lo:g}..{hi:g}{share} through the map {m.raw_low:g} -> "
                       f"{m.value_low:g}, {m.raw_high:g} -> {m.value_high:g}"))
    for values, lo, hi, what in limits:
        bad = np.flatnonzero((values < lo) | (values > hi))
        if not len(bad):
            continue
        k = int(bad[0])
        where = {"row": k + 1} if rows else {}
        at = "" if rows else f" (sample {k + 1}" + (
            f", t = {times[k]:.3f} s)" if times is not None else ")")
        raise FlightDataError(f"value {raw[k]:g}{at} is outside what the channel can hold: "
                              f"{what}", path, column=column or m.source, **where)
