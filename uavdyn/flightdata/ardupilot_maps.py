"""The default control maps of an ArduPilot DataFlash log: which logged field feeds each
airframe control and how (a servo PWM to the elevator's radians from the log's SERVOn
parameters, the throttle as a fraction or a percentage, the pitch controller's output).

What the log does not say is assumed and stated in the note of each map: the elevator's
deflection at full servo travel (``ELEVATOR_DEFLECTION_RAD``) and, without servo parameters,
that servo 2 is the elevator (ArduPlane's default)."""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import numpy as np

from uavdyn.flightdata.control_map import ChannelMap, override_maps
from uavdyn.flightdata.errors import FlightDataError
from uavdyn.model import CONTROL_NAMES

ELEVATOR_DEFLECTION_RAD = 0.35       # assumed elevator deflection at full servo travel
ELEVATOR_FUNCTION = 19               # SERVOn_FUNCTION of an elevator output
SERVO_DEFAULTS = {"MIN": 1100.0, "MAX": 1900.0, "TRIM": 1500.0, "REVERSED": 0.0}
PERCENT_LIMIT = 1.5                  # a throttle above this is a percentage, not a fraction
MAX_SERVOS = 32
RCOU_CHANNELS = 14                   # RCOU logs C1..C14


class Scan(Protocol):
    """What the maps read from a scanned log (:class:`uavdyn.flightdata.ardupilot._Scan`)."""

    series: dict
    params: dict

    def param(self, name: str) -> float | None: ...

    def has(self, message: str, name: str | None = None) -> bool: ...


def _elevator_map(scan: Scan, path: Path) -> tuple[ChannelMap, str]:
    """The default elevator map from the servo parameters (see module docstring)."""
    functions = {n: scan.param(f"SERVO{n}_FUNCTION") for n in range(1, MAX_SERVOS + 1)}
    if not any(v is not None for v in functions.values()):
        n, note = 2, ("no SERVOn_FUNCTION parameters in the log: servo 2 assumed to be the "
                      "elevator (ArduPlane's default)")
    else:
        elevators = [k for k, v in functions.items() if v == ELEVATOR_FUNCTION]
        if not elevators:
            raise FlightDataError(
                "no servo output has SERVOn_FUNCTION = 19 (elevator): elevons or a V-tail mix "
                "pitch with roll; give the elevator's map (--control-map "
                "elevator=RCOU.C2:1100:1900:0.35:-0.35)", path, column="elevator")
        n = elevators[0]
        note = f"SERVO{n}_FUNCTION = 19 (elevator)" + (
            f"; servos {elevators[1:]} are elevators too, ignored" if len(elevators) > 1 else "")
    if n > RCOU_CHANNELS:
        raise FlightDataError(f"the elevator is servo {n}, beyond RCOU's C1..C14: give its map",
                              path, column="elevator")
    p = {}
    for key, default in SERVO_DEFAULTS.items():
        value = scan.param(f"SERVO{n}_{key}")
        p[key] = default if value is None else value
        if value is None:
            note += f"; SERVO{n}_{key} not in the log, {default:g} assumed"
        elif len(set(scan.params[f"SERVO{n}_{key}"])) > 1:
            note += f"; SERVO{n}_{key} changed during the log, last value {value:g} used"
    lo, hi, trim = p["MIN"], p["MAX"], p["TRIM"]
    if not lo < trim < hi:
        raise FlightDataError(f"SERVO{n}_MIN/TRIM/MAX = {lo:g}/{trim:g}/{hi:g} are not "
                              "increasing: give the elevator's map", path, column="elevator")
    nose_up_at_max = p["REVERSED"] == 0     # ArduPlane: a positive output pitches nose up
    d = ELEVATOR_DEFLECTION_RAD
    v_lo, v_hi = (d, -d) if nose_up_at_max else (-d, d)
    source = f"RCOU.C{n}"
    if abs(trim - (lo + hi) / 2) <= 1.0:
        m = ChannelMap("elevator", source, lo, hi, v_lo, v_hi)
    elif hi - trim >= trim - lo:
        m = ChannelMap("elevator", source, trim, hi, 0.0, v_hi)
    else:
        m = ChannelMap("elevator", source, lo, trim, v_lo, 0.0)
    note += (f"; PWM {lo:g}/{trim:g}/{hi:g} us, reversed {int(p['REVERSED'])}: the trim PWM "
             f"is 0 rad and full travel +-{d:g} rad (assumed, not in the log; positive = "
             "trailing edge down), linear through trim and the farther end")
    return m, note


def _throttle_map(control: str, scan: Scan) -> tuple[ChannelMap, str]:
    """``CTUN.ThO`` (``ThrOut`` in old logs) as a fraction: percent when its values say so."""
    name = "ThrOut" if not scan.has("CTUN", "ThO") and scan.has("CTUN", "ThrOut") else "ThO"
    source = f"CTUN.{name}"
    values = scan.series["CTUN"][1][name] if scan.has("CTUN", name) else np.zeros(0)
    peak = float(np.nanmax(np.abs(values))) if np.isfinite(values).any() else 0.0
    if peak > PERCENT_LIMIT:
        return (ChannelMap(control, source, 0.0, 100.0, 0.0, 1.0),
                f"{source} read as percent (its largest value {peak:g} > {PERCENT_LIMIT:g}; "
                "ArduPlane logs percent)")
    return (ChannelMap(control, source, 0.0, 1.0, 0.0, 1.0),
            f"{source} read as a fraction 0..1 (its largest value {peak:g} <= "
            f"{PERCENT_LIMIT:g}; ArduCopter logs a fraction)")


def default_maps(kind: str, scan: Scan, given: list[ChannelMap] | None, path: Path
                  ) -> tuple[dict[str, ChannelMap], dict[str, str]]:
    """The default maps (those the user replaced are not inferred) and a note on each."""
    replaced = {m.control for m in given or []}
    maps: dict[str, ChannelMap] = {}
    notes: dict[str, str] = {}
    for control in CONTROL_NAMES[kind]:
        if control in replaced:
            maps[control] = next(m for m in given if m.control == control)
            notes[control] = "given by the user"
        elif control == "elevator":
            maps[control], notes[control] = _elevator_map(scan, path)
        elif control in ("throttle", "collective"):
            maps[control], notes[control] = _throttle_map(control, scan)
        else:  # pitch_cmd
            maps[control] = ChannelMap(control, "RATE.POut", -1.0, 1.0, -1.0, 1.0)
            notes[control] = ("RATE.POut, the pitch rate controller's normalised output "
                              "(positive nose up), used as it is")
    return override_maps(maps, given, path), notes
