"""ArduPilot DataFlash ``.bin`` logs read (with the optional pymavlink) into a :class:`FlightLog`.

Messages read (ArduPilot's own names; instance 0 of instanced messages, i.e. those with an
``I`` or ``C`` field, is taken):

* attitude ``ATT.Roll/Pitch/Yaw`` (degrees), else the backup AHRS ``AHR2``;
* body rates ``IMU.GyrX/GyrY/GyrZ`` (rad/s, FRD);
* NED velocity ``XKF1.VN/VE/VD`` (EKF3), else ``NKF1`` (EKF2), else ``GPS.Spd/GCrs/VZ``;
  rotated into body axes with roll, pitch and yaw;
* the EKF wind ``XKF2.VWN/VWE`` (else ``NKF2``) is subtracted (velocity reference ``air``);
  without it, ``u`` comes from ``ARSP.Airspeed`` as ``sqrt(Va^2 - w^2)`` (``airspeed``),
  else velocities stay ground relative (``ground``);
* controls: fixed wing elevator from the servo output ``RCOU.C<n>`` of the servo whose
  ``SERVOn_FUNCTION`` is 19 (elevator; servo 2 when the log has no parameters), mapped with
  that servo's ``SERVOn_MIN/MAX/TRIM/REVERSED`` to +-0.35 rad (an assumption: the deflection
  at full travel is not in the log), throttle ``CTUN.ThO`` (percent in ArduPlane, a fraction
  in ArduCopter: told from its values); multirotor collective ``CTUN.ThO``, pitch_cmd
  ``RATE.POut`` (the pitch rate controller's output, -1..1);
* altitude ``POS.Alt`` (AMSL), else ``BARO.Alt`` (relative to the ground at boot; said in
  ``meta``); in air ``STAT.isFlying``.

Everything that was inferred rather than read is stated in ``meta`` (``control_map_notes``,
``vehicle``, ``altitude_reference``).
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from uavdyn.flightdata.ardupilot_maps import default_maps
from uavdyn.flightdata.attitude import body_from_euler, rotate_to_body
from uavdyn.flightdata.control_map import ChannelMap, check_channel
from uavdyn.flightdata.errors import FlightDataError
from uavdyn.flightdata.fast_grid import fastest_grid, gyro_aided_attitude
from uavdyn.flightdata.flightlog import FlightLog
from uavdyn.flightdata.import_checks import MAX_RATE_HZ, _as_path, check_reader_options
from uavdyn.flightdata.resample import _grid, hold_on_grid, interp_on_grid
from uavdyn.model import CONTROL_NAMES
from uavdyn.safefiles import UnreadableFile, stat_regular

PYMAVLINK_HINT = "reading ArduPilot .bin logs needs pymavlink: pip install 'uavdyn[ardupilot]'"
MAX_DATAFLASH_BYTES = 4 * 2**30      # larger files are refused before pymavlink maps them
DATAFLASH_HEAD = b"\xa3\x95"         # every DataFlash message starts with these two bytes
VEHICLE_BUILDS = {1: "Rover", 2: "ArduCopter", 3: "ArduPlane", 4: "AntennaTracker",
                  7: "ArduSub", 12: "Blimp", 13: "Helicopter"}     # VER.BU
VEHICLE_KINDS = {"ArduPlane": "fixed_wing", "ArduCopter": "multirotor"}
INSTANCE_FIELDS = ("I", "C")         # instance (sensor, EKF core) fields; 0 is taken
MESSAGES: dict[str, tuple[str, ...]] = {
    "ATT": ("Roll", "Pitch", "Yaw"), "AHR2": ("Roll", "Pitch", "Yaw"),
    "IMU": ("GyrX", "GyrY", "GyrZ"),
    "XKF1": ("VN", "VE", "VD"), "NKF1": ("VN", "VE", "VD"),
    "XKF2": ("VWN", "VWE"), "NKF2": ("VWN", "VWE"),
    "GPS": ("Status", "Spd", "GCrs", "VZ"), "ARSP": ("Airspeed",),
    "CTUN": ("ThO", "ThrOut", "NavPitch", "ThH"), "RCOU": tuple(f"C{i}" for i in range(1, 15)),
    "RATE": ("POut",), "POS": ("Alt",), "BARO": ("Alt",), "STAT": ("isFlying",),
}
GPS_3D_FIX = 3                       # GPS.Status below this: no velocity (a gap)
MAX_STAMP_US = 2**62                 # a larger TimeUS (146,000 years) is corrupt data


@dataclass
class _Scan:
    """What one pass over the log collected: per message, stamps (s since boot) and fields."""

    series: dict[str, tuple[np.ndarray, dict[str, np.ndarray]]] = field(default_factory=dict)
    params: dict[str, list[float]] = field(default_factory=dict)
    texts: list[str] = field(default_factory=list)
    builds: list[int] = field(default_factory=list)
    parser_messages: list[str] = field(default_factory=list)

    def has(self, message: str, name: str | None = None) -> bool:
        """The message has usable samples (and the field ``name``)."""
        got = self.series.get(message)
        return got is not None and len(got[0]) >= 2 and (name is None or name in got[1])

    def param(self, name: str) -> float | None:
        """The parameter's last logged value, or None."""
        values = self.params.get(name)
        return values[-1] if values else None


def _import_dfreader(path: Path):
    """pymavlink's DataFlash reader module, or the install hint."""
    try:
        from pymavlink import DFReader
    except ImportError:
        raise FlightDataError(PYMAVLINK_HINT, path) from None
    return DFReader


def _check_file(path: Path) -> None:
    """A regular file of at most MAX_DATAFLASH_BYTES starting with the DataFlash header."""
    try:
        stat_regular(path, MAX_DATAFLASH_BYTES, "an ArduPilot .bin log")
    except UnreadableFile as exc:
        raise FlightDataError(exc.reason, path) from None
    with open(path, "rb") as f:
        head = f.read(2)
    if not head:
        raise FlightDataError("empty file: expected an ArduPilot DataFlash .bin log", path)
    if head != DATAFLASH_HEAD:
        raise FlightDataError("not an ArduPilot DataFlash .bin log (it does not start with "
                              "the message header bytes 0xA3 0x95)", path)


def _map_sources(control_maps: list[ChannelMap] | None, path: Path) -> dict[str, set[str]]:
    """The ``MESSAGE.FIELD`` each given control map reads, by message."""
    out: dict[str, set[str]] = {}
    for m in control_maps or []:
        message, _, name = m.source.partition(".")
        if not message or not name or "." in name:
            raise FlightDataError(f"control map for {m.control}: source {m.source!r} is not "
                                  "MESSAGE.FIELD (e.g. RCOU.C2)", path, column=m.control)
        out.setdefault(message, set()).add(name)
    return out


@contextlib.contextmanager
def _captured(lines: list[str]):
    """pymavlink's complaints appended to ``lines`` instead of reaching the terminal: it
    prints them from Python and, in its C indexer, with fprintf to the stderr descriptor
    (thousands of lines for a corrupt log)."""
    text = io.StringIO()
    with tempfile.TemporaryFile() as sink:
        try:
            sys.stderr.flush()
            saved = os.dup(2)
        except (OSError, ValueError):   # no usable stderr descriptor: Python capture only
            saved = None
        if saved is not None:
            os.dup2(sink.fileno(), 2)
        try:
            with contextlib.redirect_stdout(text), contextlib.redirect_stderr(text):
                yield
        finally:
            if saved is not None:
                os.dup2(saved, 2)
                os.close(saved)
            sink.seek(0)
            raw = sink.read(1 << 16).decode("utf-8", "replace")
            lines.extend(s for s in (text.getvalue() + raw).splitlines() if s.strip())


def _scan(path: Path, wanted: dict[str, tuple[str, ...]]) -> _Scan:
    """One pass of pymavlink over the log collecting the ``wanted`` fields (instance 0), the
    parameters, the firmware text and build type; pymavlink's printed complaints are kept
    (the first 20) in ``parser_messages``."""
    dfreader = _import_dfreader(path)
    rows: dict[str, tuple[list, list, list[str], str | None]] = {}
    scan = _Scan()
    noise: list[str] = []
    try:
        with _captured(noise):
            reader = dfreader.DFReader_binary(str(path), zero_time_base=True)
            try:
                _collect(reader, wanted, rows, scan, path)
            finally:
                reader.close()
    except FlightDataError:
        raise
    except Exception as exc:  # pymavlink raises anything on a corrupt file
        raise FlightDataError(f"pymavlink cannot parse it as a DataFlash log "
                              f"({type(exc).__name__})", path) from None
    scan.parser_messages = noise[:20]
    for message, (stamps, values, names, _) in rows.items():
        scan.series[message] = _finish(message, stamps, values, names, path)
    return scan


def _collect(reader, wanted: dict[str, tuple[str, ...]], rows: dict, scan: _Scan,
             path: Path) -> None:
    """The loop of :func:`_scan`: ``rows[message] = (stamps_us, values, fields, instance)``."""
    types = set(wanted) | {"PARM", "VER", "MSG"}
    while True:
        m = reader.recv_match(type=types, strict=True)
        if m is None:
            return
        kind = m.get_type()
        if kind == "PARM":
            scan.params.setdefault(str(m.Name), []).append(float(m.Value))
            continue
        if kind == "VER":
            if "BU" in m.fmt.colhash:
                scan.builds.append(int(m.BU))
            continue
        if kind == "MSG":
            scan.texts.append(str(getattr(m, "Message", "")))
            if kind not in wanted:
                continue
        if kind not in rows:
            cols = m.fmt.colhash
            if "TimeUS" not in cols:
                raise FlightDataError(f"message {kind} has no TimeUS field (logs stamped in "
                                      "milliseconds, before ArduPilot 3.3, are not read)", path,
                                      column=kind)
            instance = next((f for f in INSTANCE_FIELDS if f in cols), None)
            rows[kind] = ([], [], [f for f in wanted[kind] if f in cols], instance)
        stamps, values, names, instance = rows[kind]
        if instance is not None and getattr(m, instance) != 0:
            continue
        stamp = int(m.TimeUS)
        if not 0 <= stamp < MAX_STAMP_US:
            raise FlightDataError(f"corrupt TimeUS {stamp} in message {kind}", path,
                                  column=f"{kind}.TimeUS")
        stamps.append(stamp)
        values.append([float(getattr(m, f)) for f in names])


def _finish(message: str, stamps: list[int], values: list, names: list[str], path: Path
            ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Stamps (s) and field arrays of one message: going back in time is refused (a corrupt
    or spliced log), a repeated stamp keeps its first sample."""
    t_us = np.asarray(stamps, dtype=np.int64)
    back = np.flatnonzero(np.diff(t_us) < 0)
    if len(back):
        k = int(back[0]) + 1
        raise FlightDataError(f"TimeUS of {message} goes backwards at its sample {k + 1} "
                              f"({int(t_us[k])} us after {int(t_us[k - 1])} us): the log is "
                              "corrupt or spliced", path, column=f"{message}.TimeUS")
    keep = np.concatenate([[True], np.diff(t_us) > 0]) if len(t_us) else np.zeros(0, bool)
    vals = np.asarray(values, dtype=float).reshape(len(t_us), len(names))[keep]
    return t_us[keep] * 1e-6, {n: vals[:, j] for j, n in enumerate(names)}


def _vehicle_kind(scan: _Scan, path: Path) -> tuple[str, str]:
    """The airframe kind and how it was told: VER's build type, the firmware line of MSG,
    else the messages only one vehicle writes."""
    for bu in scan.builds:
        vehicle = VEHICLE_BUILDS.get(bu, f"build type {bu}")
        if vehicle in VEHICLE_KINDS:
            return VEHICLE_KINDS[vehicle], f"VER.BU = {bu} ({vehicle})"
        raise FlightDataError(f"the log is from {vehicle} (VER.BU = {bu}); uavdyn models "
                              "fixed-wing and multirotor aircraft: pass kind to read it as "
                              "one", path, column="VER.BU")
    for text in scan.texts:
        for vehicle, kind in VEHICLE_KINDS.items():
            if vehicle in text:
                return kind, f"firmware message '{vehicle}' in MSG"
    if scan.has("STAT", "isFlying") or scan.has("CTUN", "NavPitch"):
        return "fixed_wing", "inferred: STAT.isFlying or CTUN.NavPitch (ArduPlane messages)"
    if scan.has("RATE") or scan.has("CTUN", "ThH"):
        return "multirotor", "inferred: RATE or CTUN.ThH (ArduCopter messages)"
    raise FlightDataError("cannot tell fixed wing from multirotor (no VER, no firmware MSG, "
                          "no STAT/RATE): pass kind", path)


def _field(scan: _Scan, source: str, what: str, path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Stamps and values of ``MESSAGE.FIELD``, or one line naming what is missing."""
    message, _, name = source.partition(".")
    if not scan.has(message):
        raise FlightDataError(f"no {message} message (at least 2 samples) in the log: {what} "
                              f"needs {source}", path, column=source)
    t, fields = scan.series[message]
    if name not in fields:
        raise FlightDataError(f"message {message} has no field {name}: {what} needs {source}",
                              path, column=source)
    return t, fields[name]


def _attitude(scan: _Scan, path: Path) -> str:
    """The attitude message: ATT, else AHR2."""
    for message in ("ATT", "AHR2"):
        if scan.has(message) and all(f in scan.series[message][1] for f in MESSAGES[message]):
            return message
    raise FlightDataError("no ATT message (attitude Roll, Pitch, Yaw) and no AHR2 in the log",
                          path, column="ATT")


def _ned_velocity(scan: _Scan, path: Path) -> tuple[str, np.ndarray, np.ndarray]:
    """The NED velocity samples: the EKF's (XKF1, NKF1) else the GPS's (no fix is a gap)."""
    for message in ("XKF1", "NKF1"):
        if scan.has(message) and all(f in scan.series[message][1] for f in ("VN", "VE", "VD")):
            t, f = scan.series[message]
            return f"{message}.VN/VE/VD", t, np.column_stack([f["VN"], f["VE"], f["VD"]])
    if scan.has("GPS") and all(f in scan.series["GPS"][1] for f in ("Spd", "GCrs", "VZ")):
        t, f = scan.series["GPS"]
        course = np.radians(f["GCrs"])
        v = np.column_stack([f["Spd"] * np.cos(course), f["Spd"] * np.sin(course), f["VZ"]])
        if "Status" in f:
            v[f["Status"] < GPS_3D_FIX] = np.nan
        return "GPS.Spd/GCrs/VZ (no 3D fix = gap)", t, v
    raise FlightDataError("no velocity message: XKF1 (EKF3), NKF1 (EKF2) or GPS", path,
                          column="XKF1")


def _attitude_rate(att_t: np.ndarray) -> float:
    """The attitude message's mean rate rounded to 1 Hz (the grid when no gyro is faster)."""
    return max(1.0, float(round((len(att_t) - 1) / (att_t[-1] - att_t[0]))))


def _grid_for(spans: list[np.ndarray], att_t: np.ndarray, rate_hz: float | None, path: Path
              ) -> tuple[np.ndarray, float]:
    """The grid over the time every required message covers, at ``rate_hz`` or the attitude
    message's own rate rounded to 1 Hz."""
    t0, t1 = max(t[0] for t in spans), min(t[-1] for t in spans)
    if not t1 > t0:
        raise FlightDataError("the attitude, gyro, velocity and control messages share no time "
                              "span", path, column="TimeUS")
    if rate_hz is None:
        rate_hz = _attitude_rate(att_t)
        if rate_hz > MAX_RATE_HZ:
            raise FlightDataError(f"the attitude rate {rate_hz:g} Hz is above {MAX_RATE_HZ:g} "
                                  "Hz (corrupt stamps?): pass rate_hz", path, column="TimeUS")
    return _grid(t0, t1, float(rate_hz), path), float(rate_hz)


def read_dataflash(path: str | Path, kind: str | None = None, rate_hz: float | None = None,
                   control_maps: list[ChannelMap] | None = None,
                   name: str | None = None) -> FlightLog:
    """Read an ArduPilot DataFlash ``.bin`` log into a six-degree-of-freedom FlightLog.

    Parameters
    ----------
    path : str or Path
        The ``.bin`` log (as written to the SD card or downloaded over MAVLink).
    kind : {'fixed_wing', 'multirotor'}, optional
        Default from the log: VER's build type, the firmware line (ArduPlane/ArduCopter),
        else which messages it has.
    rate_hz : float, optional
        Grid rate; default ATT's own rate rounded to 1 Hz, or, where IMU is faster, IMU's
        (at most 100 Hz) with roll and pitch between the ATT samples from the integrated
        gyro (:mod:`uavdyn.flightdata.fast_grid`; ``meta['grid']`` says which).
    control_maps : list of ChannelMap, optional
        Replace a default control map; ``source`` is ``MESSAGE.FIELD`` (e.g. ``RCOU.C2``).
    name : str, optional
        Flight name (default the file stem).

    Returns
    -------
    FlightLog
        ``meta`` holds the source of each channel, the control maps and the notes on what
        was assumed (elevator deflection, throttle scale, altitude reference).

    Raises
    ------
    FlightDataError
        One line naming the file (and the message) for a bad option, a file that is no
        DataFlash log, a missing message or field, stamps going backwards; the install hint
        when pymavlink is missing.
    """
    path = _as_path(path, "path")
    check_reader_options(path, kind, rate_hz, control_maps, name)
    _import_dfreader(path)
    _check_file(path)
    wanted = dict(MESSAGES)
    for message, names in _map_sources(control_maps, path).items():
        wanted[message] = tuple(dict.fromkeys(wanted.get(message, ()) + tuple(sorted(names))))
    scan = _scan(path, wanted)
    vehicle = "given (option kind)"
    if kind is None:
        kind, vehicle = _vehicle_kind(scan, path)
    att = _attitude(scan, path)
    gyro = [_field(scan, f"IMU.{f}", "the body rates", path) for f in MESSAGES["IMU"]]
    vel_source, vel_t, v_ned = _ned_velocity(scan, path)
    maps, notes = default_maps(kind, scan, control_maps, path)
    raw = {c: _field(scan, maps[c].source, f"the {c} control", path) for c in maps}
    for c, (t_raw, values) in raw.items():
        check_channel(maps[c], values, path, rows=False, times=t_raw)
    att_t = scan.series[att][0]
    choice = fastest_grid({att: att_t, "IMU": gyro[0][0], vel_source.split(".")[0]: vel_t},
                          ("IMU",), att, _attitude_rate(att_t), rate_hz)
    own = rate_hz is None and not choice.gyro_aided
    grid, rate_hz = _grid_for([att_t, gyro[0][0], vel_t] + [r[0] for r in raw.values()],
                              att_t, None if own else choice.rate_hz, path)
    angles = {c: interp_on_grid(grid, att_t, np.radians(scan.series[att][1][f]),
                                angle=c != "pitch")
              for c, f in (("roll", "Roll"), ("pitch", "Pitch"), ("yaw", "Yaw"))}
    pqr = {c: interp_on_grid(grid, *g) for c, g in zip("pqr", gyro)}
    if choice.gyro_aided:   # yaw (for the velocities) stays interpolated
        gap = np.isnan(angles["roll"]) | np.isnan(angles["pitch"])
        angles["roll"], angles["pitch"] = gyro_aided_attitude(
            grid, att_t, np.radians(scan.series[att][1]["Roll"]),
            np.radians(scan.series[att][1]["Pitch"]), pqr["p"], pqr["q"], pqr["r"])
        angles["roll"][gap] = angles["pitch"][gap] = np.nan
    sources = {"roll, pitch": f"{att}.Roll/Pitch (deg)", "p, q, r": "IMU.GyrX/GyrY/GyrZ"}
    body, reference, airspeed = _body_velocity(scan, grid, angles, vel_source, vel_t, v_ned,
                                               sources)
    channels = {"roll": angles["roll"], "pitch": angles["pitch"], **pqr,
                "u": body[:, 0], "v": body[:, 1], "w": body[:, 2]}
    controls = np.column_stack([hold_on_grid(grid, raw[c][0], maps[c].apply(raw[c][1]))
                                for c in CONTROL_NAMES[kind]])
    meta = {"file": str(path), "start_time_s": float(grid[0]), "rate_hz": rate_hz,
            "vehicle": vehicle, "sources": sources, "grid": choice.reason,
            "control_map": {c: m.as_dict() for c, m in maps.items()},
            "control_map_text": {c: m.describe() for c, m in maps.items()},
            "control_map_notes": notes,
            "resampling": f"messages aligned on a uniform grid at {rate_hz:g} Hz over the span "
                          "the attitude, gyro, velocity and control messages share: states "
                          "linear (angles unwrapped), controls held; NaN inside a message's "
                          "gaps (longer than max(0.5 s, 5 x its median interval))",
            "message_rates_hz": {m: round(float((len(t) - 1) / (t[-1] - t[0])), 1)
                                 for m, (t, _) in scan.series.items() if len(t) >= 2
                                 and t[-1] > t[0]},
            "parser_messages": scan.parser_messages}
    return FlightLog(name=name or path.stem, kind=kind, time=grid - grid[0], channels=channels,
                     controls=controls, velocity_reference=reference,
                     source="ArduPilot DataFlash", altitude_m=_altitude(scan, grid, meta),
                     airspeed=airspeed, airborne=_airborne(scan, grid, meta), meta=meta)


def _body_velocity(scan: _Scan, grid: np.ndarray, angles: dict[str, np.ndarray],
                   vel_source: str, vel_t: np.ndarray, v_ned: np.ndarray,
                   sources: dict[str, str]) -> tuple[np.ndarray, str, np.ndarray | None]:
    """Body ``u, v, w`` on the grid, their reference, and the airspeed sensor (or None)."""
    v = np.column_stack([interp_on_grid(grid, vel_t, v_ned[:, j]) for j in range(3)])
    sources["u, v, w"] = f"{vel_source} rotated into body axes by {sources['roll, pitch']}/Yaw"
    airspeed = None
    if scan.has("ARSP", "Airspeed"):
        t, f = scan.series["ARSP"]
        airspeed = interp_on_grid(grid, t, f["Airspeed"])
        sources["airspeed"] = "ARSP.Airspeed (instance 0)"
    wind = next((m for m in ("XKF2", "NKF2") if scan.has(m, "VWN") and scan.has(m, "VWE")),
                None)
    dcm = body_from_euler(angles["roll"], angles["pitch"], angles["yaw"])
    if wind is not None:
        t, f = scan.series[wind]
        v[:, 0] -= interp_on_grid(grid, t, f["VWN"])
        v[:, 1] -= interp_on_grid(grid, t, f["VWE"])
        sources["u, v, w"] += f", minus the EKF wind {wind}.VWN/VWE (vertical wind 0)"
        return rotate_to_body(dcm, v), "air", airspeed
    body = rotate_to_body(dcm, v)
    if airspeed is not None:
        with np.errstate(invalid="ignore"):
            body[:, 0] = np.sqrt(np.maximum(airspeed ** 2 - body[:, 2] ** 2, 0.0))
        body[np.isnan(airspeed), 0] = np.nan
        sources["u, v, w"] += "; u = sqrt(ARSP.Airspeed^2 - w^2), v, w ground relative"
        return body, "airspeed", airspeed
    return body, "ground", airspeed


def _altitude(scan: _Scan, grid: np.ndarray, meta: dict) -> np.ndarray | None:
    """POS.Alt (AMSL), else BARO.Alt (relative to the ground at boot), else None."""
    if scan.has("POS", "Alt"):
        meta["sources"]["altitude_m"] = "POS.Alt"
        meta["altitude_reference"] = "AMSL (POS.Alt)"
        return interp_on_grid(grid, scan.series["POS"][0], scan.series["POS"][1]["Alt"])
    if scan.has("BARO", "Alt"):
        meta["sources"]["altitude_m"] = "BARO.Alt (instance 0)"
        meta["altitude_reference"] = ("relative to the barometer's zero at boot (BARO.Alt), "
                                      "NOT above mean sea level: no POS message in the log")
        return interp_on_grid(grid, scan.series["BARO"][0], scan.series["BARO"][1]["Alt"])
    meta["altitude_reference"] = "none (no POS or BARO message)"
    return None


def _airborne(scan: _Scan, grid: np.ndarray, meta: dict) -> np.ndarray | None:
    """STAT.isFlying held on the grid (a gap counts as not flying), else None."""
    if not scan.has("STAT", "isFlying"):
        return None
    meta["sources"]["airborne"] = "STAT.isFlying"
    t, f = scan.series["STAT"]
    return hold_on_grid(grid, t, f["isFlying"]) >= 0.5
