"""A PX4 ULog as a six-degree-of-freedom :class:`FlightLog` (for cutting into segments).

Channels, by the conventions of :mod:`uavdyn.flightdata.ulog`: attitude from
``vehicle_attitude.q``; body rates from ``vehicle_angular_velocity.xyz``, else
``vehicle_attitude.rollspeed/pitchspeed/yawspeed``, else ``sensor_combined.gyro_rad``; NED
velocities of ``vehicle_local_position`` rotated into body axes, with the wind estimate
(``wind`` or ``wind_estimate``) removed where the log has one, else ``u`` from the airspeed
sensor (``airspeed_validated`` or ``airspeed``) where it has one, else ground relative;
altitude from ``vehicle_global_position.alt``, else ``vehicle_local_position.ref_alt - z``;
in air from ``vehicle_land_detected.landed``. Grid samples inside a topic's gap are NaN.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from uavdyn.flightdata.attitude import (
    pitch_from_quaternion,
    roll_from_quaternion,
    rotation_matrices,
)
from uavdyn.flightdata.control_map import ChannelMap, check_channel, override
from uavdyn.flightdata.errors import FlightDataError
from uavdyn.flightdata.fast_grid import fastest_grid, gyro_aided_attitude
from uavdyn.flightdata.flightlog import FlightLog
from uavdyn.flightdata.import_checks import _as_path
from uavdyn.flightdata.resample import (
    _hold,
    _quaternions_on_grid,
    commands_on_grid,
    hold_on_grid,
    in_gap,
    states_on_grid,
)
from uavdyn.flightdata.ulog import (
    _check_ulog_options,
    _controls,
    _mean_rate,
    _state_topics,
    _Topics,
    _ulog_grid,
    _vehicle_kind,
    ulog_speed_check,
)
from uavdyn.flightdata.ulog_format import _read_ulog, log_content, topic_names
from uavdyn.model import CONTROL_BOUNDS, CONTROL_NAMES

RATE_SOURCES = (("vehicle_angular_velocity", ["xyz[0]", "xyz[1]", "xyz[2]"]),
                ("vehicle_attitude", ["rollspeed", "pitchspeed", "yawspeed"]),
                ("sensor_combined", ["gyro_rad[0]", "gyro_rad[1]", "gyro_rad[2]"]))
WIND_SOURCES = (("wind", ["windspeed_north", "windspeed_east"]),
                ("wind_estimate", ["windspeed_north", "windspeed_east"]))
AIRSPEED_SOURCES = (("airspeed_validated", ["true_airspeed_m_s"]),
                    ("airspeed", ["true_airspeed_m_s"]))

ALTITUDE_SOURCES = (("vehicle_global_position", ["alt"]),
                    ("vehicle_local_position", ["ref_alt", "z"]))  # ref_alt - z


def default_ulog_maps(kind: str, sources: dict[str, str]) -> dict[str, ChannelMap]:
    """The maps :func:`uavdyn.flightdata.ulog.import_ulog` applies, stated as ChannelMaps."""
    if kind == "fixed_wing":
        max_defl = CONTROL_BOUNDS["fixed_wing"][0][1]
        return {"elevator": ChannelMap("elevator", "actuator_controls_1.control[1]", -1.0, 1.0,
                                       max_defl, -max_defl),
                "throttle": ChannelMap("throttle", "actuator_controls_1.control[3]", 0.0, 1.0,
                                       0.0, 1.0)}
    return {name: ChannelMap(name, sources[name], 0.0, 1.0, 0.0, 1.0)
            for name in CONTROL_NAMES["multirotor"]}


def _first(topics: _Topics, options, optional: bool = False) -> tuple[str, tuple] | None:
    """The first topic of ``options`` (name, fields) present: its description and samples.
    An ``optional`` channel (wind, airspeed, altitude) with non-finite samples is left out,
    not refused: the flight is still usable without it."""
    for topic, fields in options:
        try:
            got = topics.get(topic, fields)
        except FlightDataError:
            if not optional:
                raise
            got = None
        if got is not None:
            return f"{topic}.{'/'.join(fields)}", got
    return None


def _user_control(topics: _Topics, grid: np.ndarray, m: ChannelMap, path: Path) -> np.ndarray:
    """A control read from the field the user's map names (``topic.field``), held on the grid."""
    topic, _, name = m.source.partition(".")
    got = topics.get(topic, [name]) if name else None
    if got is None:
        raise FlightDataError(f"control map for {m.control}: no field '{m.source}' in this log "
                              "(give TOPIC.FIELD, e.g. actuator_outputs.output[1])", path,
                              column=m.control)
    return m.apply(hold_on_grid(grid, got[0], got[1][:, 0]))


def read_ulog_flight(path: str | Path, rate_hz: float | None = None, kind: str | None = None,
                     pitch_mix: float = 0.1, name: str | None = None,
                     control_maps: list[ChannelMap] | None = None) -> FlightLog:
    """Read a PX4 ULog file as a six-degree-of-freedom flight on a uniform grid.

    Parameters
    ----------
    path : str or Path
        The ``.ulg`` file.
    rate_hz : float, optional
        Grid rate; default the attitude topic's own rate (rounded to 1 Hz), or, where the
        body-rate topic is faster, its rate (at most 100 Hz) with roll and pitch between the
        attitude samples from the integrated gyro (:mod:`uavdyn.flightdata.fast_grid`;
        ``meta['grid']`` says which).
    kind : {'fixed_wing', 'multirotor'}, optional
        Default from the log's MAV_TYPE.
    pitch_mix : float
        Motor-output pitch mixing (multirotor logs with only motor commands).
    name : str, optional
        Flight name (default the file stem).
    control_maps : list of ChannelMap, optional
        Replace the default map of a control; ``source`` is ``topic.field``.

    Returns
    -------
    FlightLog

    Raises
    ------
    FlightDataError
        One line naming the file and topic for anything missing or malformed.
    """
    path = _as_path(path, "path")
    _check_ulog_options(path, rate_hz, kind, pitch_mix, "auto", name, {})  # name included
    ulog, truncated_at, _, framing = _read_ulog(path, False)
    topics = _Topics(ulog, path, framing.offsets)
    kind = kind or _vehicle_kind(ulog)
    att, _, vel, sources = _state_topics(topics, path)
    rates = _first(topics, RATE_SOURCES)
    if rates is None:
        raise FlightDataError("no body-rate topic (vehicle_angular_velocity, vehicle_attitude "
                              "roll/pitch/yawspeed or sensor_combined.gyro_rad)", path,
                              column="p,q,r")
    sources["p,q,r"] = rates[0]
    controls, control_sources = _controls(topics, kind, float(pitch_mix), path)
    _check_controls(controls, control_sources, kind, control_maps, path)
    gyro_topic = rates[0].split(".")[0]
    choice = fastest_grid({"vehicle_attitude": att[0], gyro_topic: rates[1][0],
                           "vehicle_local_position": vel[0]}, (gyro_topic,), "vehicle_attitude",
                          max(1.0, round(_mean_rate(att[0]))), rate_hz)
    own = rate_hz is None and not choice.gyro_aided   # the attitude's own rate, as always
    grid, rate_hz = _ulog_grid([att, rates[1], vel, controls], None if own else choice.rate_hz,
                               path)
    quat = _quaternions_on_grid(grid, *att)
    pqr = states_on_grid(grid, *rates[1])
    v_ned = states_on_grid(grid, *vel)
    wind = _first(topics, WIND_SOURCES, optional=True)
    airspeed = _first(topics, AIRSPEED_SOURCES, optional=True)
    reference = "ground"
    if wind is not None:
        v_ned[:, :2] -= states_on_grid(grid, *wind[1])
        reference, sources["wind"] = "air", wind[0]
    v_body = np.einsum("nji,nj->ni", rotation_matrices(quat), v_ned)
    va = None
    if airspeed is not None:
        va = states_on_grid(grid, *airspeed[1])[:, 0]
        sources["airspeed"] = airspeed[0]
        if reference == "ground":
            with np.errstate(invalid="ignore"):
                v_body[:, 0] = np.sqrt(np.maximum(va**2 - v_body[:, 2] ** 2, 0.0))
            reference = "airspeed"
    att_nan = in_gap(grid, att[0])
    roll, pitch = roll_from_quaternion(quat), pitch_from_quaternion(quat)
    if choice.gyro_aided:   # the velocities stay rotated by the interpolated quaternion
        roll, pitch = gyro_aided_attitude(grid, att[0], roll_from_quaternion(att[1]),
                                          pitch_from_quaternion(att[1]), *pqr.T)
    channels = {"roll": roll, "pitch": pitch, "p": pqr[:, 0], "q": pqr[:, 1], "r": pqr[:, 2],
                "u": v_body[:, 0], "v": v_body[:, 1], "w": v_body[:, 2]}
    for key in ("roll", "pitch"):
        channels[key][att_nan] = np.nan
    maps = override(default_ulog_maps(kind, control_sources), control_maps)
    ctrl = commands_on_grid(grid, *controls)
    for j, control in enumerate(CONTROL_NAMES[kind]):
        if control_maps and any(m.control == control for m in control_maps):
            ctrl[:, j] = _user_control(topics, grid, maps[control], path)
    meta = {"file": str(path), "start_time_s": float(grid[0]) + topics.origin_us * 1e-6,
            "rate_hz": rate_hz, "sources": sources, "control_sources": control_sources,
            "control_map": {k: m.describe() for k, m in maps.items()},
            "grid": choice.reason,
            "resampling": f"topics aligned on a uniform {rate_hz:g} Hz grid (meta['grid']): "
                          + ("roll and pitch gyro-aided between the attitude samples, "
                             if choice.gyro_aided else "") + "states linear, quaternions "
                          "normalised, controls held; NaN in topic gaps",
            "topic_rates_hz": {"attitude": round(_mean_rate(att[0]), 1),
                               "body_rates": round(_mean_rate(rates[1][0]), 1),
                               "velocity": round(_mean_rate(vel[0]), 1)},
            "truncated_at_byte": truncated_at,
            "speed_check": ulog_speed_check(topics, grid, channels,
                                            sources.get("airspeed", sources["u,w"]), path),
            **log_content(ulog, ["vehicle_attitude", gyro_topic, "vehicle_local_position",
                                 *topic_names(control_sources.values())])}
    return FlightLog(name=name or path.stem, kind=kind, time=grid - grid[0], channels=channels,
                     controls=ctrl, velocity_reference=reference, source="PX4 ULog",
                     altitude_m=_altitude(topics, grid, meta), airspeed=va,
                     airborne=_airborne(topics, grid, meta), meta=meta)


def _check_controls(controls: tuple, sources: dict[str, str], kind: str,
                    user_maps: list[ChannelMap] | None, path: Path) -> None:
    """The controls the default maps give (those no user map replaces) within what their
    channel holds (:func:`~uavdyn.flightdata.control_map.check_channel`: a throttle share
    0..1, the elevator and pitch-command limits), named by their logged source; a pitch
    command inferred from the motor outputs (an assumed mix) is not a logged channel and is
    left to the segmenter."""
    replaced = {m.control for m in user_maps or []}
    for j, control in enumerate(CONTROL_NAMES[kind]):
        if sources[control].startswith("(front"):
            continue   # a pitch command inferred from the motor mix is no logged channel
        if control not in replaced:
            check_channel(ChannelMap(control, sources[control], 0.0, 1.0, 0.0, 1.0),
                          controls[1][:, j], path, rows=False, times=controls[0])


def _altitude(topics: _Topics, grid: np.ndarray, meta: dict) -> np.ndarray | None:
    """Altitude above mean sea level on the grid, or None."""
    found = _first(topics, ALTITUDE_SOURCES, optional=True)
    if found is None:
        return None
    meta["sources"]["altitude_m"] = found[0]
    vals = states_on_grid(grid, *found[1])
    return vals[:, 0] - vals[:, 1] if vals.shape[1] == 2 else vals[:, 0]


ARMED = 2  # vehicle_status.arming_state ARMING_STATE_ARMED


def _airborne(topics: _Topics, grid: np.ndarray, meta: dict) -> np.ndarray | None:
    """In air on the grid (held): the land detector's flag, else armed (a disarmed vehicle is
    not flying), else None."""
    found = _first(topics, (("vehicle_land_detected", ["landed"]),), optional=True)
    if found is not None:
        meta["sources"]["airborne"] = "not vehicle_land_detected.landed"
        return _hold(grid, *found[1])[:, 0] < 0.5
    found = _first(topics, (("vehicle_status", ["arming_state"]),), optional=True)
    if found is not None:
        meta["sources"]["airborne"] = "vehicle_status.arming_state == ARMED (no land detector)"
        return _hold(grid, *found[1])[:, 0] == ARMED
    return None
