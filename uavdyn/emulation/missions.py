"""Mission profiles for the flight-data emulator: named, parameterised, seeded flight plans
(survey legs, inspection, loiter, aggressive manoeuvres, system identification, high alpha).

A mission turns ``(airframe, duration, sample rate, random generator)`` into a
:class:`FlightPlan`: the initial trim state and, for every log interval, the autopilot's
references and gains (:data:`uavdyn.emulator.REFERENCE_NAMES`). Feed-forward controls and pitch
references come from baseline-model trim points, so the autopilot only corrects what the truth
model does differently. Randomness comes only from the ``rng`` passed in (seeded by the caller),
so a plan is reproducible.

Every number a mission flies comes from the airframe's envelope
(:func:`uavdyn.emulation.envelope.envelope`):

* speeds: the fixed-wing missions are designed at a 25 m/s cruise and fly
  ``cruise * design / 25`` (``cruise``: the airframe's nominal airspeed), clipped into its
  speed range (``1.3 x`` the stall speed or the lowest level trim, to the fastest level trim
  with the throttle within its limits); the multirotor's design ground speeds are clipped to its
  forward-flight range (pitch within 0.5 rad, collective within its limits);
* altitude changes: at most what the airframe climbs at full thrust over the change's ramp;
* commands: full power, idle and full nose-up elevator are the ends of the command travel (the
  file's ``[limits]``, else the kind's physical range); the fixed wing's elevator excitation
  gives the angle-of-attack perturbation the design gives the Aerosonde (scaled by the ratio of
  the static ``|C_m_delta_e / C_m_alpha|``); excitation amplitudes and collective punches are
  scaled to fit the travel the file's ``[limits]`` allow (a control the file does not limit
  keeps its amplitude and saturates at its physical range, as before). The autopilot
  saturates every command at the travel and rate limits (:mod:`uavdyn.emulation.autopilot`).

A mission the envelope cannot hold raises :class:`MissionUnflyable` saying why. For the
Aerosonde (cruise 25 m/s) and the F450 every derived number equals the design value, so their
plans are the ones of the shipped datasets.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.emulation.emulator import REFERENCE_NAMES
from uavdyn.emulation.envelope import (
    MIN_FORWARD_MPS,
    Envelope,
    MissionError,
    MissionUnflyable,
    envelope,
    speed_range,
    trim_schedule,
)
from uavdyn.integrate.inputs import chirp, doublet, multistep_3211
from uavdyn.linear import trim

__all__ = ["DEFAULT_ALTITUDE", "GAINS", "MISSIONS", "FlightPlan", "MissionError",
           "MissionUnflyable", "missions_for", "piecewise", "plan_mission", "speed_range",
           "trim_schedule", "unflyable_missions"]

# Default autopilot gains (see uavdyn.emulator.autopilot), tuned on the presets.
GAINS = {
    # K_theta, K_q, K_speed, K_h, K_hdot
    "fixed_wing": np.array([1.0, 0.15, 0.06, 0.015, 0.03]),
    "multirotor": np.array([0.9, 0.2, 0.06, 0.12, 0.08]),
}
DEFAULT_ALTITUDE = {"fixed_wing": 150.0, "multirotor": 30.0}
REF = {name: i for i, name in enumerate(REFERENCE_NAMES)}


@dataclass
class FlightPlan:
    """Everything the emulator needs for one sortie besides turbulence and noise."""

    mission: str
    kind: str
    x0: np.ndarray          # baseline state [u, w, q, theta] at t = 0
    u0: np.ndarray          # controls at t = 0 (actuator positions)
    altitude: float
    references: np.ndarray  # N x len(REFERENCE_NAMES)
    params: dict = field(default_factory=dict)  # the drawn mission parameters (JSON-friendly)


def piecewise(t: np.ndarray, knots: list[tuple[float, float]], ramp: float = 0.0
              ) -> np.ndarray:
    """A schedule through ``(time, value)`` knots: held values, optionally with linear ramps
    of ``ramp`` seconds into each new value."""
    out = np.full_like(t, knots[0][1], dtype=float)
    for (t0, v0), (t1, v1) in zip(knots[:-1], knots[1:]):
        del t0
        if ramp > 0:
            frac = np.clip((t - t1) / ramp, 0.0, 1.0)
            out = np.where(t >= t1, v0 + frac * (v1 - v0), out)
        else:
            out = np.where(t >= t1, v1, out)
    return out


def _base_references(airframe: Airframe, t: np.ndarray, speed: np.ndarray,
                     altitude: np.ndarray) -> np.ndarray:
    """Closed-loop references tracking ``speed`` and ``altitude`` with trim feed-forward."""
    theta, ctrl = trim_schedule(airframe, speed)
    ref = np.zeros((len(t), len(REFERENCE_NAMES)))
    ref[:, REF["ff0"]], ref[:, REF["ff1"]] = ctrl[:, 0], ctrl[:, 1]
    ref[:, REF["theta_ref"]] = theta
    ref[:, REF["speed_ref"]] = speed
    ref[:, REF["h_ref"]] = altitude
    ref[:, REF["K_theta"]:] = GAINS[airframe.kind]
    return ref


def _legs(rng: np.random.Generator, duration: float, t_min: float, t_max: float,
          start: float = 0.0) -> list[float]:
    """Random segment start times covering [start, duration)."""
    times, t = [], start
    while t < duration:
        times.append(t)
        t += float(rng.uniform(t_min, t_max))
    return times


def _plan(airframe: Airframe, name: str, ref: np.ndarray, speed0: float, altitude: float,
          params: dict) -> FlightPlan:
    theta, ctrl = trim_schedule(airframe, np.array([speed0]))
    x0 = trim(airframe, abs(speed0)).x.copy()
    if speed0 < 0:  # backwards multirotor flight: mirror image of the forward trim
        x0 *= np.array([-1.0, 1.0, -1.0, -1.0])
    return FlightPlan(mission=name, kind=airframe.kind, x0=x0, u0=ctrl[0], altitude=altitude,
                      references=ref, params=params)


def _flyable(airframe: Airframe, mission: str, forward: bool = False) -> Envelope:
    """The airframe's envelope, or :class:`MissionUnflyable` if it cannot hold ``mission``
    (``forward``: a multirotor mission with forward legs needs ``MIN_FORWARD_MPS``)."""
    env = envelope(airframe)
    env.require(mission)
    fast = env.speed_range[1]
    if forward and airframe.kind == "multirotor" and fast < MIN_FORWARD_MPS:
        raise MissionUnflyable(
            f"mission '{mission}' cannot be flown: its forward legs need a level trim at "
            f"{MIN_FORWARD_MPS:g} m/s; the fastest with the pitch within 0.5 rad and the "
            f"collective within its limits is {fast:g} m/s")
    return env


def _altitude_amplitude(env: Envelope, design: float, ramp: float) -> float:
    """A design altitude half-range, capped at what the airframe climbs in one ramp."""
    return min(design, env.climb_rate * ramp)


# ----------------------------------------------------------------------------- missions


def survey(airframe: Airframe, t: np.ndarray, rng: np.random.Generator,
           leg_s: tuple[float, float] = (10.0, 20.0)) -> FlightPlan:
    """Mapping legs: cruise legs at a drawn speed and altitude, joined by speed/altitude
    changes (multirotor: stop, hover, fly the next leg back the other way)."""
    env = _flyable(airframe, "survey", forward=True)
    T = float(t[-1]) + 1.0
    h0 = DEFAULT_ALTITUDE[airframe.kind]
    starts = _legs(rng, T, *leg_s)
    if airframe.kind == "fixed_wing":
        speeds = rng.uniform(env.design_speed(20.0), env.design_speed(30.0), len(starts))
        amp = _altitude_amplitude(env, 30.0, 8.0)
        alts = h0 + rng.uniform(-amp, amp, len(starts))
        speed = piecewise(t, list(zip(starts, speeds)), ramp=4.0)
        alt = piecewise(t, list(zip(starts, alts)), ramp=8.0)
    else:
        v_leg = rng.uniform(env.design_speed(4.0), env.design_speed(12.0), len(starts))
        amp = _altitude_amplitude(env, 5.0, 4.0)
        knots, alt_knots, direction = [], [], 1.0
        for k, s in enumerate(starts):
            cruise_end = s + 0.7 * (starts[k + 1] - s if k + 1 < len(starts) else leg_s[0])
            knots += [(s, direction * v_leg[k]), (cruise_end, 0.0)]
            alt_knots.append((s, h0 + rng.uniform(-amp, amp)))
            direction = -direction
        speed = piecewise(t, knots, ramp=3.0)
        alt = piecewise(t, alt_knots, ramp=4.0)
        speeds = v_leg
    ref = _base_references(airframe, t, speed, alt)
    return _plan(airframe, "survey", ref, float(speed[0]), float(alt[0]),
                 {"leg_starts_s": [round(s, 3) for s in starts],
                  "leg_speeds_mps": [round(float(v), 3) for v in speeds]})


def inspection(airframe: Airframe, t: np.ndarray, rng: np.random.Generator,
               hold_s: tuple[float, float] = (3.0, 8.0)) -> FlightPlan:
    """Inspection: hover at a point, move slowly (0.5-3 m/s, either way) to the next, change
    height, hover again (multirotor only)."""
    if airframe.kind != "multirotor":
        raise MissionError("mission 'inspection' (hover and move) needs a multirotor")
    env = _flyable(airframe, "inspection")
    T = float(t[-1]) + 1.0
    h0 = DEFAULT_ALTITUDE[airframe.kind]
    amp = _altitude_amplitude(env, 4.0, 2.0)
    starts = _legs(rng, T, *hold_s)
    knots, alt_knots = [], []
    for k, s in enumerate(starts):
        moving = k % 2 == 1
        v = float(rng.choice([-1, 1]) * rng.uniform(env.design_speed(0.5),
                                                    env.design_speed(3.0))) if moving else 0.0
        knots.append((s, v))
        alt_knots.append((s, h0 + (rng.uniform(-amp, amp) if not moving else 0.0)))
    speed = piecewise(t, knots, ramp=1.5)
    alt = piecewise(t, alt_knots, ramp=2.0)
    ref = _base_references(airframe, t, speed, alt)
    return _plan(airframe, "inspection", ref, 0.0, float(alt[0]),
                 {"segment_starts_s": [round(s, 3) for s in starts],
                  "segment_speeds_mps": [round(v, 3) for _, v in knots]})


def loiter(airframe: Airframe, t: np.ndarray, rng: np.random.Generator) -> FlightPlan:
    """Loiter / station keeping: constant speed (fixed wing, at 0.76-0.92 of its cruise) or
    hover (multirotor), with slow small altitude wander as a pilot would hold it."""
    env = _flyable(airframe, "loiter")
    h0 = DEFAULT_ALTITUDE[airframe.kind]
    if airframe.kind == "fixed_wing":
        v0 = float(rng.uniform(env.design_speed(19.0), env.design_speed(23.0)))
    else:
        v0 = float(rng.uniform(env.design_speed(-0.5), env.design_speed(0.5)))
    amp, period = float(rng.uniform(0.5, 3.0)), float(rng.uniform(15.0, 40.0))
    phase = float(rng.uniform(0, 2 * np.pi))
    alt = h0 + amp * np.sin(2 * np.pi * t / period + phase)
    # Station keeping: slow speed corrections around the loiter speed, inside the envelope.
    lo, hi = env.speed_range
    room = min(v0 - lo, hi - v0) if airframe.kind == "fixed_wing" else hi - abs(v0)
    v_amp = min(float(rng.uniform(0.3, 1.5)) * env.speed_scale, max(room, 0.0))
    speed = v0 + v_amp * np.sin(2 * np.pi * t / (0.7 * period)) * (1 - np.exp(-t / 5.0))
    ref = _base_references(airframe, t, speed, alt)
    return _plan(airframe, "loiter", ref, v0, float(alt[0]),
                 {"speed_mps": round(v0, 3), "altitude_wander_m": round(amp, 3),
                  "speed_wander_mps": round(v_amp, 3),
                  "period_s": round(period, 3)})


def aggressive(airframe: Airframe, t: np.ndarray, rng: np.random.Generator,
               gap_s: tuple[float, float] = (3.0, 6.0)) -> FlightPlan:
    """Aggressive manoeuvres: large pitch-attitude steps and pulses flown by the attitude loop
    with the outer loops off, full-power/idle throttle or collective punches, fast speed
    reversals (multirotor)."""
    env = _flyable(airframe, "aggressive")
    T = float(t[-1]) + 1.0
    h0 = DEFAULT_ALTITUDE[airframe.kind]
    kind = airframe.kind
    v0 = env.design_speed(25.0) if kind == "fixed_wing" else 0.0
    ref = _base_references(airframe, t, np.full_like(t, v0), np.full_like(t, h0))
    theta0 = ref[0, REF["theta_ref"]]
    (t_lo, t_hi) = env.bounds[1] if kind == "fixed_wing" else env.bounds[0]
    starts = _legs(rng, T, *gap_s, start=2.0)
    events = []
    for s in starts:
        width = float(rng.uniform(0.6, 1.8))
        sel = (t >= s) & (t < s + width)
        if kind == "fixed_wing":
            amp = float(rng.choice([-1, 1]) * rng.uniform(math.radians(8), math.radians(20)))
            ref[sel, REF["theta_ref"]] = theta0 + amp
            ref[sel, REF["K_h"]] = ref[sel, REF["K_hdot"]] = 0.0
            ref[sel, REF["ff1"]] = t_hi if amp > 0 else t_lo + 0.1 * (t_hi - t_lo)
            ref[sel, REF["K_speed"]] = 0.0
        else:
            amp = float(rng.choice([-1, 1]) * rng.uniform(math.radians(12), math.radians(30)))
            ref[sel, REF["theta_ref"]] = amp
            ref[sel, REF["K_speed"]] = 0.0
            hover = float(ref[0, REF["ff0"]])
            punch = float(rng.uniform(-0.12, 0.2))
            if env.limited[0]:  # the punch stays inside the file's collective travel
                punch = min(max(punch, t_lo - hover), t_hi - hover)
            ref[sel, REF["ff0"]] += punch
        events.append({"t_s": round(s, 3), "width_s": round(width, 3),
                       "pitch_deg": round(math.degrees(amp), 2)})
    return _plan(airframe, "aggressive", ref, v0, h0, {"events": events})


def _sysid_amplitude(env: Envelope, kind: str, thrust_channel: bool,
                     rng: np.random.Generator) -> float:
    """The amplitude of one system-identification input (unsigned): the design value, the
    fixed wing's elevator scaled to the same angle-of-attack perturbation
    (:attr:`Envelope.elevator_scale`)."""
    if kind == "fixed_wing":
        return math.radians(rng.uniform(2.0, 6.0)) * env.elevator_scale \
            if not thrust_channel else float(rng.uniform(0.1, 0.25))
    return float(rng.uniform(0.05, 0.2)) if not thrust_channel else \
        float(rng.uniform(0.03, 0.08))


def _sysid(airframe: Airframe, t: np.ndarray, rng: np.random.Generator, signal: str
           ) -> FlightPlan:
    """System-identification inputs on the pitch channel (and sometimes the thrust channel),
    repeated with trim holds between; the fixed wing flies them open loop (autopilot off during
    the input), the multirotor with its attitude loop on (excitation added to its command).
    Amplitudes are scaled to fit the travel of the file's [limits] around the trim."""
    name = f"sysid_{signal}"
    kind = airframe.kind
    env = _flyable(airframe, name, forward=True)
    T = float(t[-1]) + 1.0
    h0 = DEFAULT_ALTITUDE[kind]
    v0 = float(rng.uniform(env.design_speed(20.0), env.design_speed(28.0))) \
        if kind == "fixed_wing" else float(rng.uniform(0, env.design_speed(6.0)))
    ref = _base_references(airframe, t, np.full_like(t, v0), np.full_like(t, h0))
    gap = 8.0 if signal != "chirp" else 4.0
    starts = _legs(rng, T - 4.0, gap + 6.0, gap + 10.0, start=2.0)
    inputs = []
    for s in starts:
        channel = 1 if kind == "multirotor" else 0
        if rng.uniform() < 0.25:
            channel = 1 - channel  # thrust channel now and then
        thrust_channel = (channel == 1) if kind == "fixed_wing" else (channel == 0)
        amp = _sysid_amplitude(env, kind, thrust_channel, rng)
        amp *= float(rng.choice([-1, 1]))
        amp = env.fit(channel, float(ref[0, REF["ff0"] + channel]), amp)
        if signal == "doublet":
            width = float(rng.uniform(0.3, 1.0))
            sig, length = doublet(t, amp, s, width), 2 * width
        elif signal == "3211":
            unit = float(rng.uniform(0.2, 0.5))
            sig, length = multistep_3211(t, amp, s, unit), 7 * unit
        else:
            length = float(min(rng.uniform(10.0, 16.0), T - s - 1.0))
            sig = chirp(t, amp, s, length, 0.1, float(rng.uniform(1.5, 3.0)))
        if kind == "fixed_wing":
            window = (t >= s) & (t < s + length + 2.0)
            ref[window, REF["K_theta"]:] = 0.0  # hands off: open-loop response
        ref[:, REF["ff0"] + channel] += sig
        inputs.append({"t_s": round(s, 3), "length_s": round(length, 3),
                       "channel": channel, "amplitude": round(amp, 5)})
    return _plan(airframe, name, ref, v0, h0, {"signal": signal, "inputs": inputs,
                                               "speed_mps": round(v0, 3)})


def sysid_doublet(airframe: Airframe, t: np.ndarray, rng: np.random.Generator) -> FlightPlan:
    """Doublets on the pitch (sometimes thrust) channel; see :func:`_sysid`."""
    return _sysid(airframe, t, rng, "doublet")


def sysid_3211(airframe: Airframe, t: np.ndarray, rng: np.random.Generator) -> FlightPlan:
    """3-2-1-1 multisteps on the pitch (sometimes thrust) channel; see :func:`_sysid`."""
    return _sysid(airframe, t, rng, "3211")


def sysid_chirp(airframe: Airframe, t: np.ndarray, rng: np.random.Generator) -> FlightPlan:
    """Frequency sweeps (0.1 Hz to 1.5-3 Hz) on the pitch (sometimes thrust) channel."""
    return _sysid(airframe, t, rng, "chirp")


def high_alpha(airframe: Airframe, t: np.ndarray, rng: np.random.Generator) -> FlightPlan:
    """High angle of attack (fixed wing): zoom climb at full power, then idle and full nose-up
    elevator hands-off while the speed bleeds away, so alpha passes 20 deg into the stall;
    recovery by nose-down pitch and full power, then climb back; repeated while time allows.
    Full power, idle and full nose-up elevator are the ends of the command travel."""
    if airframe.kind != "fixed_wing":
        raise MissionError("mission 'high_alpha' is for fixed-wing airframes")
    env = _flyable(airframe, "high_alpha")
    T = float(t[-1]) + 1.0
    if T < 16.0:
        raise MissionUnflyable("mission 'high_alpha' needs a duration of at least 16 s")
    h0 = DEFAULT_ALTITUDE["fixed_wing"]
    v0 = float(rng.uniform(env.design_speed(24.0), env.design_speed(28.0)))
    ref = _base_references(airframe, t, np.full_like(t, v0), np.full_like(t, h0))
    e_lo = env.bounds[0][0]
    full, idle = env.bounds[1][1], env.bounds[1][0]
    cycles, s = [], 2.0
    while s + 14.0 <= T:
        zoom = float(rng.uniform(2.5, 4.0))
        zoom_pitch = math.radians(rng.uniform(42.0, 58.0))
        hold = float(rng.uniform(4.0, 6.0))
        elevator = float(e_lo * rng.uniform(0.85, 1.0))
        recover = 5.0
        z = (t >= s) & (t < s + zoom)
        ref[z, REF["theta_ref"]] = zoom_pitch
        ref[z, REF["K_h"]] = ref[z, REF["K_hdot"]] = ref[z, REF["K_speed"]] = 0.0
        ref[z, REF["ff1"]] = full
        hd = (t >= s + zoom) & (t < s + zoom + hold)
        ref[hd, REF["K_theta"]:] = 0.0
        ref[hd, REF["ff0"]], ref[hd, REF["ff1"]] = elevator, idle
        rc = (t >= s + zoom + hold) & (t < s + zoom + hold + recover)
        ref[rc, REF["theta_ref"]] = math.radians(-15.0)
        ref[rc, REF["K_h"]] = ref[rc, REF["K_hdot"]] = ref[rc, REF["K_speed"]] = 0.0
        ref[rc, REF["ff1"]] = full
        cycles.append({"t_s": round(s, 3), "zoom_s": round(zoom, 3),
                       "zoom_pitch_deg": round(math.degrees(zoom_pitch), 2),
                       "hold_s": round(hold, 3), "elevator_rad": round(elevator, 4)})
        s += zoom + hold + recover + float(rng.uniform(6.0, 10.0))
    return _plan(airframe, "high_alpha", ref, v0, h0, {"cycles": cycles})


MissionFunction = Callable[[Airframe, np.ndarray, np.random.Generator], FlightPlan]
MISSIONS: dict[str, tuple[MissionFunction, tuple[str, ...]]] = {
    "survey": (survey, ("fixed_wing", "multirotor")),
    "inspection": (inspection, ("multirotor",)),
    "loiter": (loiter, ("fixed_wing", "multirotor")),
    "aggressive": (aggressive, ("fixed_wing", "multirotor")),
    "sysid_doublet": (sysid_doublet, ("fixed_wing", "multirotor")),
    "sysid_3211": (sysid_3211, ("fixed_wing", "multirotor")),
    "sysid_chirp": (sysid_chirp, ("fixed_wing", "multirotor")),
    "high_alpha": (high_alpha, ("fixed_wing",)),
}


def missions_for(kind: str) -> list[str]:
    """The mission names an airframe kind can fly."""
    return [name for name, (_, kinds) in MISSIONS.items() if kind in kinds]


def plan_mission(name: str, airframe: Airframe, duration: float, sample_rate_hz: float,
                 rng: np.random.Generator) -> FlightPlan:
    """Draw a flight plan of mission ``name`` with ``duration * sample_rate_hz + 1`` log rows.

    Raises
    ------
    MissionError
        For an unknown mission, one of another airframe kind or a bad duration or rate.
    MissionUnflyable
        If the airframe's envelope (or the duration) cannot hold the mission (a
        :class:`MissionError`; the message names the mission and why).
    """
    if name not in MISSIONS:
        raise MissionError(f"unknown mission '{name}'; expected one of {sorted(MISSIONS)}")
    func, kinds = MISSIONS[name]
    if airframe.kind not in kinds:
        raise MissionError(f"mission '{name}' does not apply to {airframe.kind} airframes "
                           f"(it is for {', '.join(kinds)})")
    if not (duration > 0 and sample_rate_hz > 0):
        raise MissionError(f"duration and sample rate must be positive, got {duration}, "
                           f"{sample_rate_hz}")
    n = int(round(duration * sample_rate_hz)) + 1
    t = np.arange(n) / sample_rate_hz
    return func(airframe, t, rng)


def unflyable_missions(airframe: Airframe, missions: list[str], duration: float,
                       sample_rate_hz: float) -> dict[str, str]:
    """``{mission: why}`` for each of ``missions`` the airframe cannot fly in ``duration``
    seconds (its envelope cannot hold it: :class:`MissionUnflyable`); the others are left
    out. Whether a mission can be flown does not depend on the random draw."""
    out = {}
    for name in missions:
        try:
            plan_mission(name, airframe, duration, sample_rate_hz, np.random.default_rng(0))
        except MissionUnflyable as exc:
            out[name] = str(exc)
    return out
