"""A generic six-degree-of-freedom CSV (any autopilot) read into a :class:`FlightLog`.

For logs no dedicated importer reads: the user exports one CSV with a header row, SI units
and radians (the columns are listed in ``docs/flightlog_formats.md`` and :data:`COLUMNS`).
Stamps may be irregular; every channel is resampled onto one uniform grid (states linear,
controls held) and an empty cell or a long pause in the stamps becomes NaN on the grid rather
than an invented value, so the segmenter cuts there.

The resampling that keeps gaps is :mod:`uavdyn.flightdata.resample`'s, shared with the other
readers.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from uavdyn.flightdata.attitude import body_from_euler, rotate_to_body
from uavdyn.flightdata.control_map import ChannelMap, check_channel, override_maps
from uavdyn.flightdata.csvio import CSV_MAX_BYTES, MAX_COLUMNS, MAX_LINE_CHARS, parse_number
from uavdyn.flightdata.errors import FlightDataError, _short
from uavdyn.flightdata.files import _read_text
from uavdyn.flightdata.flightlog import FlightLog
from uavdyn.flightdata.import_checks import _as_path, check_reader_options
from uavdyn.flightdata.resample import _grid, hold_on_grid, interp_on_grid
from uavdyn.model import CONTROL_NAMES

REQUIRED = ("time", "roll", "pitch", "p", "q", "r")
BODY_VELOCITY = ("u", "v", "w")
NED_VELOCITY = ("vn", "ve", "vd")
WIND = ("wind_n", "wind_e", "wind_d")
OPTIONAL = ("yaw", "airspeed", "altitude_m", "airborne") + WIND
COLUMNS = REQUIRED + BODY_VELOCITY + NED_VELOCITY + OPTIONAL
"""Every column name the generic CSV gives a meaning to (controls come from the maps)."""

PITCH_LIMIT_RAD = np.pi / 2 + 1e-6   # |pitch| beyond this is no Euler pitch (degrees given?)

_HEADER_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_.\[\]]{0,63}")


def _grid_rate(t: np.ndarray, rate_hz: float | None) -> tuple[float, str]:
    """The grid rate and how it was chosen: ``rate_hz`` or the median interval's rate (made
    a whole number when it is one to 1 ppm, so a 50 Hz log is gridded at exactly 50 Hz)."""
    if rate_hz is not None:
        return float(rate_hz), f"rate_hz = {float(rate_hz):g} Hz given"
    median = float(np.median(np.diff(t)))
    rate = 1.0 / median
    if abs(rate - round(rate)) <= 1e-6 * rate:
        rate = float(round(rate))
    return rate, f"{rate:.6g} Hz, the rate of the median stamp interval {median:.6g} s"


# --- the CSV ------------------------------------------------------------------------------

def _header(line: str, path: Path) -> list[str]:
    """The column names of the first line (not echoed when it is no header)."""
    fields = [h.strip(" \t") for h in line.split(",")] if len(line) <= MAX_LINE_CHARS else []
    if not 2 <= len(fields) <= MAX_COLUMNS or not all(_HEADER_NAME.fullmatch(h) for h in fields):
        raise FlightDataError("not a six-degree-of-freedom CSV: the first line is not a "
                              "comma-separated list of column names (time, roll, pitch, p, q, "
                              "r, ...)", path, line=1)
    for h in fields:
        if fields.count(h) > 1:
            raise FlightDataError("duplicated column in the header", path, line=1, column=h)
    return fields


def _parse(lines: list[str], header: list[str], wanted: list[str], path: Path
           ) -> dict[str, np.ndarray]:
    """The ``wanted`` columns as floats, an empty cell (or ``nan``) as NaN; anything else
    that is not a finite number is refused with its row and column."""
    idx = [header.index(c) for c in wanted]
    out = np.empty((len(lines), len(wanted)))
    for r, line in enumerate(lines, start=1):
        if not line.strip():
            raise FlightDataError("blank line inside the data", path, r)
        if len(line) > MAX_LINE_CHARS:
            raise FlightDataError(f"line of {len(line)} characters, more than the "
                                  f"{MAX_LINE_CHARS} a data row may have", path, r)
        cells = line.split(",")
        if len(cells) != len(header):
            raise FlightDataError(f"has {len(cells)} fields, the header has {len(header)}",
                                  path, r)
        for j, c in enumerate(idx):
            cell = cells[c].strip(" \t")
            if cell == "":
                out[r - 1, j] = np.nan
                continue
            try:
                value = parse_number(cell)
            except ValueError:
                raise FlightDataError(f"cannot read {_short(cell, 24)} as a number (an empty "
                                      "cell is a gap)", path, r, wanted[j]) from None
            if np.isinf(value):   # 'nan' is a gap like an empty cell; infinity is no value
                raise FlightDataError(f"non-finite value {cell!r} (leave the cell empty for "
                                      "a gap)", path, r, wanted[j])
            out[r - 1, j] = value
    return {c: out[:, j] for j, c in enumerate(wanted)}


def _read_columns(path: Path, kind: str, control_maps: list[ChannelMap] | None
                  ) -> tuple[dict[str, np.ndarray], dict[str, ChannelMap], list[str]]:
    """The columns used (by name), the control maps and the header's unused columns."""
    text, _ = _read_text(path, path, CSV_MAX_BYTES, "a CSV file", "CSV", "", False)
    if not text.strip():
        raise FlightDataError("empty file: expected a header row and data rows", path)
    if not text.isascii():
        raise FlightDataError("non-ASCII character: the CSV holds plain ASCII column names "
                              "and numbers", path)
    lines = [s[:-1] if s.endswith("\r") else s for s in text.split("\n")]
    while lines and not lines[-1].strip():
        lines.pop()
    header = _header(lines[0], path)
    if len(lines) < 3:
        raise FlightDataError("fewer than 2 data rows after the header", path)
    wanted = _wanted_columns(header, kind, path)
    maps = override_maps({c: ChannelMap(c, c, 0.0, 1.0, 0.0, 1.0) for c in CONTROL_NAMES[kind]},
                         control_maps, path)
    for m in maps.values():
        if m.source not in header:
            raise FlightDataError(f"no column '{m.source}' for the {m.control} control (its "
                                  f"map reads that column); the header has "
                                  f"{_short(','.join(header), 200)}", path, line=1,
                                  column=m.source)
    wanted += [m.source for m in maps.values() if m.source not in wanted]
    data = _parse(lines[1:], header, wanted, path)
    for m in maps.values():
        check_channel(m, data[m.source], path)
    unused = [h for h in header if h not in wanted]
    return data, maps, unused


def _wanted_columns(header: list[str], kind: str, path: Path) -> list[str]:
    """The state and optional columns present, with the required ones checked."""
    accepted = (f"required {', '.join(REQUIRED)}; velocities either {', '.join(BODY_VELOCITY)}"
                f" (body) or {', '.join(NED_VELOCITY)} with yaw (NED); controls "
                f"{', '.join(CONTROL_NAMES[kind])}; optional yaw, airspeed, altitude_m, "
                f"airborne, {', '.join(WIND)}")
    for c in REQUIRED:
        if c not in header:
            raise FlightDataError(f"missing column '{c}' ({accepted})", path, line=1, column=c)
    if all(c in header for c in BODY_VELOCITY):
        velocity = list(BODY_VELOCITY)
    elif all(c in header for c in NED_VELOCITY):
        velocity = list(NED_VELOCITY)
    else:
        gone = [c for c in BODY_VELOCITY if c not in header] if any(
            c in header for c in BODY_VELOCITY) else [c for c in NED_VELOCITY if c not in header]
        raise FlightDataError(f"missing velocity column '{gone[0]}' ({accepted})", path,
                              line=1, column=gone[0])
    wind = [c for c in WIND if c in header]
    if wind and len(wind) < 3:
        gone = next(c for c in WIND if c not in header)
        raise FlightDataError(f"missing column '{gone}': the wind needs all of "
                              f"{', '.join(WIND)}", path, line=1, column=gone)
    if (velocity[0] == "vn" or wind) and "yaw" not in header:
        why = "NED velocities vn, ve, vd" if velocity[0] == "vn" else "the wind columns"
        raise FlightDataError(f"missing column 'yaw': {why} are rotated into body axes with "
                              f"roll, pitch and yaw ({accepted})", path, line=1, column="yaw")
    optional = [c for c in ("yaw", "airspeed", "altitude_m", "airborne") if c in header]
    return list(REQUIRED) + velocity + optional + wind


def _check_time(t: np.ndarray, path: Path) -> None:
    """Every row has a time, and times strictly increase."""
    empty = np.flatnonzero(np.isnan(t))
    if len(empty):
        raise FlightDataError("empty time cell (every row needs a time)", path,
                              int(empty[0]) + 1, "time")
    back = np.flatnonzero(np.diff(t) <= 0)
    if len(back):
        k = int(back[0]) + 1
        raise FlightDataError(f"time {t[k]:.9g} s is not after the previous row's "
                              f"{t[k - 1]:.9g} s (times must strictly increase)", path, k + 1,
                              "time")


def _check_angles(data: dict[str, np.ndarray], path: Path) -> None:
    """Pitch must be an Euler pitch in radians; airborne 0 or 1."""
    pitch = data["pitch"]
    bad = np.flatnonzero(np.abs(np.nan_to_num(pitch)) > PITCH_LIMIT_RAD)
    if len(bad):
        raise FlightDataError(f"pitch {pitch[bad[0]]:.6g} is outside [-pi/2, pi/2] rad (angles "
                              "are in radians)", path, int(bad[0]) + 1, "pitch")
    if "airborne" in data:
        a = data["airborne"]
        bad = np.flatnonzero(np.isfinite(a) & (a != 0) & (a != 1))
        if len(bad):
            raise FlightDataError(f"airborne must be 0 or 1, got {a[bad[0]]:g}", path,
                                  int(bad[0]) + 1, "airborne")


def _velocities(data: dict[str, np.ndarray], t: np.ndarray, grid: np.ndarray,
                att: dict[str, np.ndarray], sources: dict[str, str]
                ) -> tuple[np.ndarray, str]:
    """Body ``u, v, w`` on the grid and their reference (air, airspeed or ground)."""
    ned = "vn" in data
    names = NED_VELOCITY if ned else BODY_VELOCITY
    v = np.column_stack([interp_on_grid(grid, t, data[c]) for c in names])
    dcm = body_from_euler(att["roll"], att["pitch"], att["yaw"]) if "yaw" in att else None
    body = rotate_to_body(dcm, v) if ned else v
    sources["u,v,w"] = ("vn, ve, vd rotated into body axes by roll, pitch, yaw" if ned
                        else "u, v, w")
    if "wind_n" in data:
        wind = np.column_stack([interp_on_grid(grid, t, data[c]) for c in WIND])
        body = body - rotate_to_body(dcm, wind)
        sources["u,v,w"] += " minus the wind wind_n, wind_e, wind_d (rotated into body axes)"
        return body, "air"
    if "airspeed" in data:
        va = interp_on_grid(grid, t, data["airspeed"])
        with np.errstate(invalid="ignore"):
            body[:, 0] = np.sqrt(np.maximum(va ** 2 - body[:, 2] ** 2, 0.0))
        body[np.isnan(va), 0] = np.nan
        sources["u,v,w"] += "; u = sqrt(airspeed^2 - w^2)"
        return body, "airspeed"
    return body, "ground"


def read_sixdof_csv(path: str | Path, kind: str, rate_hz: float | None = None,
                    control_maps: list[ChannelMap] | None = None,
                    name: str | None = None) -> FlightLog:
    """Read a generic six-degree-of-freedom CSV (any autopilot) into a :class:`FlightLog`.

    Parameters
    ----------
    path : str or Path
        The CSV: a header row, then one row per stamp (SI units, radians, FRD body, NED).
    kind : {'fixed_wing', 'multirotor'}
        The airframe; its controls (``elevator, throttle`` or ``collective, pitch_cmd``) are
        read from columns of those names unless ``control_maps`` say otherwise.
    rate_hz : float, optional
        Grid rate; default the rate of the median stamp interval.
    control_maps : list of ChannelMap, optional
        Replace the identity map of a control; ``source`` is the column read (e.g. a servo
        PWM column with its two calibration points).
    name : str, optional
        Flight name (default the file stem).

    Returns
    -------
    FlightLog
        States interpolated linearly and controls held on the grid; NaN where a cell was
        empty or the stamps pause longer than ``max(0.5 s, 5 x median interval)``.

    Raises
    ------
    FlightDataError
        One line naming the file (and row and column) for a bad option, a missing column,
        a cell that is not a number, times that do not increase.
    """
    path = _as_path(path, "path")
    check_reader_options(path, kind, rate_hz, control_maps, name, kind_required=True)
    data, maps, unused = _read_columns(path, kind, control_maps)
    t = data["time"]
    _check_time(t, path)
    _check_angles(data, path)
    rate, how = _grid_rate(t, rate_hz)
    grid = _grid(float(t[0]), float(t[-1]), rate, path)
    att = {c: interp_on_grid(grid, t, data[c], angle=c != "pitch")
           for c in ("roll", "pitch", "yaw") if c in data}
    sources = {c: c for c in ("roll", "pitch", "p", "q", "r")}
    body, reference = _velocities(data, t, grid, att, sources)
    channels = {"roll": att["roll"], "pitch": att["pitch"],
                **{c: interp_on_grid(grid, t, data[c]) for c in ("p", "q", "r")},
                "u": body[:, 0], "v": body[:, 1], "w": body[:, 2]}
    controls = np.column_stack([hold_on_grid(grid, t, maps[c].apply(data[maps[c].source]))
                                for c in CONTROL_NAMES[kind]])
    optional = {c: interp_on_grid(grid, t, data[c]) if c in data else None
                for c in ("airspeed", "altitude_m")}
    airborne = None
    if "airborne" in data:
        airborne = hold_on_grid(grid, t, data["airborne"]) == 1.0   # a gap is not airborne
    for c in ("airspeed", "altitude_m", "airborne"):
        if c in data:
            sources[c] = c
    meta = {"file": str(path), "start_time_s": float(grid[0]), "rate_hz": rate,
            "sources": sources, "control_map": {c: m.as_dict() for c, m in maps.items()},
            "control_map_text": {c: m.describe() for c, m in maps.items()},
            "resampling": f"rows resampled onto a uniform grid at {how}: states linearly "
                          "interpolated (angles unwrapped), controls held (zero-order); NaN "
                          "next to an empty cell and inside pauses of the stamps longer than "
                          "max(0.5 s, 5 x median interval)",
            "rows": len(t), "unused_columns": unused}
    return FlightLog(name=name or path.stem, kind=kind, time=grid - grid[0], channels=channels,
                     controls=controls, velocity_reference=reference,
                     source="six-degree-of-freedom CSV", altitude_m=optional["altitude_m"],
                     airspeed=optional["airspeed"], airborne=airborne, meta=meta)
