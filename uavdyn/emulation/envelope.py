"""The flight envelope the missions are drawn from: level-trim speeds between a margin above the
stall speed and the thrust limit (fixed wing), hover and the forward-flight range that trims
(multirotor), the steepest steady climb, and the command travel and rates of the airframe's
own ``[limits]``.

Everything here is a pure function of the airframe (its parameters, ``[limits]`` and nominal
airspeed): the baseline model's trim points, cached per airframe so every mission and every
sortie of a dataset reads the same table. A mission the envelope cannot hold raises
:class:`MissionUnflyable` with the reason (the dataset generator skips it and says why).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.linear import TrimError, stall_speed, trim
from uavdyn.linear.trim import body_structure
from uavdyn.model import CONTROL_NAMES, NUMPY_OPS, body_forces


class MissionError(ValueError):
    """Unknown mission, a mission flown by the wrong airframe kind, or bad parameters."""


class MissionUnflyable(MissionError):
    """The airframe's envelope (or the sortie's duration) cannot hold the mission; the message
    names the mission and why."""


STALL_MARGIN = 1.3        # lowest fixed-wing mission speed: 1.3 x the stall speed
TILT_MAX_RAD = 0.5        # multirotor forward flight: level trim pitch within 0.5 rad (the
#                           autopilot clips its attitude command at 0.6 rad: 0.1 rad to correct)
MIN_FORWARD_MPS = 2.0     # a multirotor that cannot trim this fast does not fly forward legs
TRIM_GRID_MPS = 0.5       # the trim table's speed step
REFERENCE_CRUISE_MPS = 25.0   # fixed-wing missions are designed at this cruise (the Aerosonde's)
# The Aerosonde's static angle of attack per elevator, |C_m_delta_e / C_m_alpha|: the fixed-wing
# excitation amplitudes are designed for it (2-6 deg elevator, 0.7-2.2 deg of alpha).
REFERENCE_ALPHA_PER_ELEVATOR = 0.99 / 2.74
CLIMB_GAMMA_MAX_RAD = math.radians(60.0)


@dataclass(frozen=True)
class TrimTable:
    """Level baseline trim over the speed grid: speeds that trim, their pitch and controls."""

    speeds: np.ndarray
    thetas: np.ndarray
    controls: np.ndarray


@dataclass(frozen=True)
class Envelope:
    """What the missions of one airframe may fly.

    ``speed_range`` is the fixed wing's airspeed range (the lowest level trim or
    ``STALL_MARGIN`` x the stall speed, whichever is higher, to the fastest level trim with the
    throttle within its limits), or the multirotor's ground-speed range (hover to the fastest
    level trim with the pitch within ``TILT_MAX_RAD`` and the collective within its limits).
    ``problem`` says why no mission can be flown (None when the envelope exists)."""

    kind: str
    speed_range: tuple[float, float]
    cruise: float               # m/s: the fixed wing's nominal airspeed inside the range; 0 hover
    stall_speed: float | None   # m/s (fixed wing)
    climb_rate: float           # m/s: steepest steady climb at cruise (or vertical) at full thrust
    bounds: tuple[tuple[float, float], ...]   # command travel per control
    rates: tuple[float | None, ...]           # command rate limit per control (None: none)
    limited: tuple[bool, ...]                 # whether the file's [limits] set the travel
    problem: str | None = None
    elevator_scale: float = 1.0   # fixed wing: factor of the design elevator excitation

    @property
    def speed_scale(self) -> float:
        """Fixed wing: cruise / REFERENCE_CRUISE_MPS, the factor of the missions' design
        speeds (1 for the Aerosonde); 1 for a multirotor."""
        return self.cruise / REFERENCE_CRUISE_MPS if self.kind == "fixed_wing" else 1.0

    def design_speed(self, value: float) -> float:
        """A mission's design speed flown by this airframe: fixed wing, scaled by its cruise
        (``cruise * value / 25``, exact for the Aerosonde) and clipped into the speed range;
        multirotor, the value (sign kept) with its size clipped to the forward range."""
        lo, hi = self.speed_range
        if self.kind == "fixed_wing":
            return min(max(self.cruise * value / REFERENCE_CRUISE_MPS, lo), hi)
        return math.copysign(min(abs(value), hi), value)

    def room(self, channel: int, centre: float) -> float:
        """Travel left either side of ``centre`` on ``channel`` inside the file's [limits]
        (infinite for a control the file does not limit: the command saturates instead)."""
        if not self.limited[channel]:
            return math.inf
        lo, hi = self.bounds[channel]
        return max(min(hi - centre, centre - lo), 0.0)

    def fit(self, channel: int, centre: float, amplitude: float) -> float:
        """``amplitude`` scaled down (sign kept) so ``centre +- amplitude`` fits the file's
        travel of ``channel``."""
        return math.copysign(min(abs(amplitude), self.room(channel, centre)), amplitude)

    def require(self, mission: str) -> None:
        """Raise :class:`MissionUnflyable` if no mission can be flown."""
        if self.problem:
            raise MissionUnflyable(f"mission '{mission}' cannot be flown: {self.problem}")

    def as_dict(self) -> dict:
        """JSON-friendly summary (what the dataset manifest records)."""
        names = CONTROL_NAMES[self.kind]
        return {
            "speed_range_mps": [round(v, 6) for v in self.speed_range],
            "speed": "airspeed" if self.kind == "fixed_wing" else "ground speed",
            "cruise_mps": round(self.cruise, 6),
            "stall_speed_mps": None if self.stall_speed is None else round(self.stall_speed, 6),
            "climb_rate_mps": round(self.climb_rate, 6),
            "command_bounds": {n: list(b) for n, b in zip(names, self.bounds)},
            "command_bounds_from": {n: "airframe [limits]" if lim else "physical range"
                                    for n, lim in zip(names, self.limited)},
            "command_rate_limits": dict(zip(names, self.rates)),
            "elevator_excitation_scale": round(self.elevator_scale, 6),
            "problem": self.problem,
        }


_TABLES: dict[tuple, TrimTable] = {}
_ENVELOPES: dict[tuple, Envelope] = {}


def _key(airframe: Airframe) -> tuple:
    """What a trim depends on: the parameters (hash), the [limits] and the nominal speed."""
    return (airframe.kind, airframe.param_hash(), repr(sorted(airframe.limits.items())),
            float(airframe.nominal_airspeed))


def trim_table(airframe: Airframe) -> TrimTable:
    """Level baseline trims on a 0.5 m/s grid from 0 to max(36, 2 x nominal) m/s (the
    airframe's own [limits] apply), cached per airframe."""
    key = _key(airframe)
    if key not in _TABLES:
        top = max(36.0, 2.0 * float(airframe.nominal_airspeed))
        ok_v, thetas, ctrls = [], [], []
        for v in np.arange(0.0, top, TRIM_GRID_MPS):
            try:
                tp = trim(airframe, float(v))
            except TrimError:
                continue
            ok_v.append(v)
            thetas.append(tp.x[3])
            ctrls.append(tp.u)
        _TABLES[key] = TrimTable(np.array(ok_v), np.array(thetas), np.array(ctrls))
    return _TABLES[key]


def envelope(airframe: Airframe) -> Envelope:
    """The mission envelope of ``airframe`` (cached per airframe)."""
    key = _key(airframe)
    if key not in _ENVELOPES:
        _ENVELOPES[key] = (_fixed_wing_envelope if airframe.kind == "fixed_wing"
                           else _multirotor_envelope)(airframe, trim_table(airframe))
    return _ENVELOPES[key]


def _commands(airframe: Airframe) -> dict:
    names = CONTROL_NAMES[airframe.kind]
    rates = airframe.rate_limits() or (None,) * len(names)
    return {"bounds": airframe.control_bounds(), "rates": tuple(rates),
            "limited": tuple(n in airframe.limits for n in names)}


def _fixed_wing_envelope(airframe: Airframe, table: TrimTable) -> Envelope:
    v_stall = stall_speed(airframe)[0]
    commands = _commands(airframe)
    if len(table.speeds) == 0:
        return Envelope("fixed_wing", (0.0, 0.0), 0.0, v_stall, 0.0, **commands,
                        problem="no level trim at any speed (check the thrust, the elevator "
                                "and the [limits])")
    lo = max(float(table.speeds[0]), STALL_MARGIN * v_stall)
    hi = float(table.speeds[-1])
    if lo > hi:
        return Envelope("fixed_wing", (lo, hi), 0.0, v_stall, 0.0, **commands,
                        problem=f"no level trim between {STALL_MARGIN:g} x the stall speed "
                                f"({lo:.1f} m/s) and the fastest level trim with the throttle "
                                f"within its limits ({hi:.1f} m/s)")
    cruise = float(airframe.nominal_airspeed) or 0.5 * (lo + hi)
    cruise = min(max(cruise, lo), hi)
    return Envelope("fixed_wing", (lo, hi), cruise, v_stall, _climb_rate(airframe, cruise),
                    **commands, elevator_scale=_elevator_scale(airframe))


def _elevator_scale(airframe: Airframe) -> float:
    """``REFERENCE_ALPHA_PER_ELEVATOR / |C_m_delta_e / C_m_alpha|``: the elevator excitation
    that gives the airframe the angle-of-attack perturbation the design gives the Aerosonde
    (exactly 1 for it). 1 where the static ratio means nothing (a ``C_m`` table, a statically
    unstable or neutral airframe, no elevator power)."""
    P = airframe.params
    if "C_m" in airframe.tables or P.C_m_alpha >= 0.0 or P.C_m_delta_e == 0.0:
        return 1.0
    return REFERENCE_ALPHA_PER_ELEVATOR / abs(P.C_m_delta_e / P.C_m_alpha)


def _climb_rate(airframe: Airframe, speed: float) -> float:
    """``speed sin(gamma)`` of the steepest steady climb that trims at ``speed`` (bisection
    on the flight-path angle; the throttle within its limits)."""
    def trims(gamma: float) -> bool:
        try:
            trim(airframe, speed, gamma)
        except TrimError:
            return False
        return True

    lo, hi = 0.0, CLIMB_GAMMA_MAX_RAD
    if not trims(lo):
        return 0.0
    if trims(hi):
        return speed * math.sin(hi)
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if trims(mid) else (lo, mid)
    return speed * math.sin(lo)


def _multirotor_envelope(airframe: Airframe, table: TrimTable) -> Envelope:
    commands = _commands(airframe)
    if len(table.speeds) == 0 or table.speeds[0] != 0.0:
        return Envelope("multirotor", (0.0, 0.0), 0.0, None, 0.0, **commands,
                        problem="no hover trim with the collective within its limits")
    fast = 0.0
    for v, theta in zip(table.speeds, table.thetas):
        if abs(theta) > TILT_MAX_RAD or v - fast > TRIM_GRID_MPS + 1e-9:
            break  # too steep a tilt, or a speed that does not trim between
        fast = float(v)
    return Envelope("multirotor", (0.0, fast), 0.0, None,
                    _vertical_climb_rate(airframe, commands["bounds"][0][1]), **commands)


def _vertical_climb_rate(airframe: Airframe, collective: float) -> float:
    """Steady vertical climb speed (m/s) at ``collective``: thrust (axial-inflow loss
    included) equals weight plus body drag (bisection up to 50 m/s)."""
    structure = body_structure(airframe)
    P = airframe.params

    def excess(climb: float) -> float:
        x = [0.0, -climb, 0.0, 0.0]
        _, Z, _, _, _, _ = body_forces(structure, x, [collective, 0.0], airframe.p, NUMPY_OPS)
        return -float(Z) - P.mass * P.gravity

    lo, hi = 0.0, 50.0
    if excess(lo) <= 0.0:
        return 0.0
    if excess(hi) > 0.0:
        return hi
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if excess(mid) > 0.0 else (lo, mid)
    return lo


def trim_schedule(airframe: Airframe, speed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pitch and controls of level baseline trim at each (signed, for multirotors) speed."""
    table = trim_table(airframe)
    v, th, ct = table.speeds, table.thetas, table.controls
    s = np.asarray(speed, float)
    a = np.clip(np.abs(s), v[0], v[-1])
    sign = np.where(s < 0, -1.0, 1.0) if airframe.kind == "multirotor" else 1.0
    theta = sign * np.interp(a, v, th)
    ctrl = np.column_stack([np.interp(a, v, ct[:, 0]), sign * np.interp(a, v, ct[:, 1])])
    return theta, ctrl


def speed_range(airframe: Airframe) -> tuple[float, float]:
    """Lowest and highest speed (m/s) at which the baseline model trims in level flight (the
    whole trim table; the missions fly :attr:`Envelope.speed_range`, inside it)."""
    table = trim_table(airframe)
    return float(table.speeds[0]), float(table.speeds[-1])
