"""Actuator limits and transport delays of an airframe file: the ``[limits]`` and ``[delays]``."""

from __future__ import annotations

import math

from uavdyn.airframes.errors import AirframeError, _short
from uavdyn.airframes.tables import number_value

DELAY_MAX_SAMPLES = 50
RATE_SUFFIX = "_rate"
# Each kind's controls in model order with their physical ranges (elevator: the usual +-30 deg
# surface travel). The one table: uavdyn.model.CONTROL_NAMES/CONTROL_BOUNDS are derived from it.
CONTROL_RANGES: dict[str, tuple[tuple[str, tuple[float, float]], ...]] = {
    "fixed_wing": (("elevator", (-0.5236, 0.5236)), ("throttle", (0.0, 1.0))),
    "multirotor": (("collective", (0.0, 1.0)), ("pitch_cmd", (-1.0, 1.0))),
}


def _unknown_key(origin: str, table: str, key: str, kind: str, allowed) -> AirframeError:
    """The error for a key a table of the kind does not have (the key shown as written)."""
    shown = key if key.isprintable() and len(key) <= 40 else _short(key, 30)
    return AirframeError(f"{origin}: unknown key '{table}.{shown}' for kind '{kind}'; expected "
                         f"any of {list(allowed)}")


def _parse_delays(raw: object, kind: str, origin: str) -> dict[str, int]:
    """The ``[delays]`` table: a whole number of samples (0..DELAY_MAX_SAMPLES) per control."""
    if not isinstance(raw, dict):
        raise AirframeError(f"{origin}: key 'delays' must be a table, got {_short(raw)}")
    names = [n for n, _ in CONTROL_RANGES[kind]]
    out: dict[str, int] = {}
    for key in sorted(raw, key=str):
        value = raw[key]
        if key not in names:
            raise _unknown_key(origin, "delays", key, kind, names)
        if isinstance(value, bool) or not isinstance(value, int) \
                or not 0 <= value <= DELAY_MAX_SAMPLES:
            raise AirframeError(f"{origin}: key 'delays.{key}' must be a whole number of samples "
                                f"in [0, {DELAY_MAX_SAMPLES}], got {_short(value)}")
        if value:  # a zero delay is no delay (kept out, so a file round-trips equal)
            out[key] = int(value)
    return out


def _limit_number(value: object, key: str, origin: str) -> float:
    """One number of ``[limits]``: typed (no boolean or string) and finite."""
    number = number_value(value)
    if number is None:
        raise AirframeError(f"{origin}: key 'limits.{key}' must hold numbers, got "
                            f"{_short(value)}")
    if not math.isfinite(number):
        raise AirframeError(f"{origin}: key 'limits.{key}' must be finite, got {_short(value)}")
    return number


def _parse_limits(raw: object, kind: str, origin: str) -> dict[str, tuple[float, float] | float]:
    """The ``[limits]`` table checked against the kind's control names and physical ranges:
    an airframe may narrow an actuator's travel, never widen it past what the model allows."""
    if not isinstance(raw, dict):
        raise AirframeError(f"{origin}: key 'limits' must be a table, got {_short(raw)}")
    ranges = dict(CONTROL_RANGES[kind])
    names = tuple(ranges)
    allowed = list(names) + [n + RATE_SUFFIX for n in names]
    out: dict[str, tuple[float, float] | float] = {}
    for key in sorted(raw, key=str):
        value = raw[key]
        if key not in allowed:
            raise _unknown_key(origin, "limits", key, kind, allowed)
        if key.endswith(RATE_SUFFIX):
            rate = _limit_number(value, key, origin)
            if not rate > 0:
                raise AirframeError(f"{origin}: key 'limits.{key}' must be a positive rate "
                                    f"(per second), got {_short(value)}")
            out[key] = rate
            continue
        if not isinstance(value, list) or len(value) != 2:
            raise AirframeError(f"{origin}: key 'limits.{key}' must be a [low, high] pair, got "
                                f"{_short(value)}")
        low, high = (_limit_number(v, key, origin) for v in value)
        if not low < high:
            raise AirframeError(f"{origin}: key 'limits.{key}' needs low < high, got "
                                f"[{low:g}, {high:g}]")
        p_low, p_high = ranges[key]
        if low < p_low or high > p_high:
            raise AirframeError(f"{origin}: key 'limits.{key}' = [{low:g}, {high:g}] is wider "
                                f"than the physical range [{p_low:g}, {p_high:g}] of a {kind} "
                                "(an airframe may narrow it, never widen it)")
        out[key] = (low, high)
    return out
