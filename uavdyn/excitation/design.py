"""The input a user should fly: signal timing from the airframe's own pitch mode, amplitudes
inside its ``[limits]``, laid out over a sortie as a schedule of control increments about trim.

Timing (:mod:`uavdyn.excitation.signals`): a fixed wing's inputs are flown hands-off (open
loop), so they are timed from its open-loop **short period** (trim, linearise, modes); a
multirotor's are injected at the mixer with its attitude loop on (the only way one is flown),
so they are timed from the **closed-loop pitch-attitude mode** of the model with the
emulator's attitude and speed loops (:data:`uavdyn.emulation.missions.GAINS`); a user whose
own autopilot differs gives the mode's frequency (``mode_hz``).

Amplitudes: a fixed wing's elevator input is scaled so the linearised airframe's open-loop
angle-of-attack response to it peaks at ``alpha_deg`` (a short pulse moves alpha far less than
the static ``|C_m_alpha / C_m_delta_e|`` ratio says); a multirotor's pitch command is 0.1 (the
middle of the emulator's system-identification inputs). Either is then cut to 80 % of the
travel the file's ``[limits]`` leave about trim (a multirotor's also to what its rotor mix can
hold) and, where the file sets a rate limit, to a full reversal slewed in half the shortest
pulse.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import expm

from uavdyn.airframes import Airframe
from uavdyn.emulation.missions import GAINS
from uavdyn.excitation.signals import (
    DOUBLET_RULE,
    RULE_3211,
    relative_peak_factor,
    schroeder_multisine,
)
from uavdyn.integrate.inputs import doublet, multistep_3211
from uavdyn.linear import linear_state_names, linearise, modes, trim

SIGNALS = ("mixed", "3211", "doublet", "multisine")
CONTROLS = {"fixed_wing": ("elevator", "throttle"), "multirotor": ("collective", "pitch_cmd")}
PITCH_CHANNEL = {"fixed_wing": 0, "multirotor": 1}
LIMIT_SHARE = 0.8       # share of the travel about trim an input may use
LEAD_S = 2.0            # trim hold at the start of each sortie
SETTLE_CYCLES = 4.0     # hands-off after each input: the mode's envelope down to exp(-4) ...
SETTLE_S = (1.0, 3.0)   # ... within these bounds (s)
GAP_S = 1.0             # autopilot back on before the next input
MULTIROTOR_AMPLITUDE = 0.1
MOMENT_PARAMS = {"fixed_wing": ("C_m_alpha", "C_m_q", "C_m_delta_e", "C_m_0"),
                 "multirotor": ("pitch_mix", "pitch_damping", "M_u", "M_0")}


class DesignError(ValueError):
    """An input design that cannot be made (named option and why, one line)."""


@dataclass(frozen=True)
class PitchMode:
    """The mode the inputs are timed from."""

    name: str
    natural_frequency: float  # rad/s
    damping: float
    source: str


@dataclass
class ExcitationDesign:
    """A designed flight-test input: one sortie's schedule of control increments about trim.

    Attributes
    ----------
    time : ndarray
        Log times of one sortie (s).
    increments : ndarray
        ``N x 2`` increments of the two controls about trim (the airframe's control units).
    hands_off : ndarray
        ``N`` booleans: the autopilot off (open-loop response).
    events : list of dict
        Each input: start (s), signal, sign, length (s).
    """

    airframe: str
    kind: str
    signal: str
    controls: tuple[str, str]
    channel: int
    speed: float
    trim_controls: tuple[float, float]
    mode: PitchMode
    rule: str
    unit_s: float
    amplitude: float
    amplitude_why: str
    band_hz: tuple[float, float]
    time: np.ndarray
    increments: np.ndarray
    hands_off: np.ndarray
    events: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def duration_s(self) -> float:
        return float(self.time[-1])

    @property
    def sample_rate_hz(self) -> float:
        return 1.0 / float(self.time[1] - self.time[0])

    def peak_factor(self) -> float | None:
        """The multisine's relative peak factor over its first period (None for the
        multisteps)."""
        if self.signal != "multisine":
            return None
        e = self.events[0]
        on = (self.time >= e["t_s"]) & (self.time < e["t_s"] + e["period_s"])
        return relative_peak_factor(self.increments[on, self.channel])

    def summary(self) -> dict:
        """The design as plain JSON-friendly data (no schedule arrays)."""
        return {
            "airframe": self.airframe, "kind": self.kind, "signal": self.signal,
            "channel": self.controls[self.channel], "trim_speed_mps": self.speed,
            "trim_controls": dict(zip(self.controls, self.trim_controls)),
            "timed_from": {"mode": self.mode.name,
                           "natural_frequency_rad_s": self.mode.natural_frequency,
                           "natural_frequency_hz": self.mode.natural_frequency / (2 * math.pi),
                           "damping": self.mode.damping if math.isfinite(self.mode.damping)
                           else None, "source": self.mode.source},
            "timing_rule": self.rule, "time_step_s": self.unit_s,
            "amplitude": self.amplitude, "amplitude_rule": self.amplitude_why,
            "band_hz": list(self.band_hz), "sortie_duration_s": self.duration_s,
            "sample_rate_hz": self.sample_rate_hz, "events": self.events,
            "relative_peak_factor": self.peak_factor(),
            "notes": self.notes}


def pitch_mode(airframe: Airframe, speed: float, mode_hz: float | None = None) -> PitchMode:
    """The mode the pitch inputs are timed from (module docstring).

    Raises
    ------
    DesignError
        If the model has no such mode (give ``mode_hz``).
    """
    if mode_hz is not None:
        return PitchMode("given", 2 * math.pi * mode_hz, math.nan, "--mode-hz")
    point = trim(airframe, speed)
    A, B = linearise(airframe, point)
    names = linear_state_names(airframe)
    if airframe.kind == "fixed_wing":
        found = [m for m in modes(A, airframe.kind, B, names) if m.name == "short period"]
        source = f"open-loop short period at {speed:g} m/s (trim, linearise, modes)"
    else:
        k_th, k_q, k_sp = GAINS["multirotor"][:3]
        K = np.zeros(A.shape[0])
        K[2], K[3] = -k_q, -k_th  # pitch_cmd = k_th (k_sp u - theta) - k_q q about trim
        K[0] = k_th * k_sp * math.cos(point.x[3])
        K[1] = k_th * k_sp * math.sin(point.x[3])
        closed = A + np.outer(B[:, 1], K)
        found = [m for m in modes(closed, airframe.kind, None, names)
                 if "actuator" not in m.name and m.dominant_state in ("q", "theta")
                 and m.natural_frequency > 0]
        found.sort(key=lambda m: -m.natural_frequency)
        source = ("closed-loop pitch attitude with the emulator's attitude and speed loops "
                  f"(K_theta {k_th:g}, K_q {k_q:g}, K_speed {k_sp:g}) at {speed:g} m/s")
    if not found:
        raise DesignError(f"--airframe {airframe.name}: the model has no pitch mode to time the "
                          "inputs from at this speed; give --mode-hz")
    m = found[0]
    return PitchMode(m.name, float(m.natural_frequency), float(m.damping), source)


def _caps(airframe: Airframe, channel: int, trim_u: np.ndarray, unit_s: float
          ) -> tuple[float, str]:
    """The largest amplitude the limits allow and why (module docstring)."""
    lo, hi = airframe.control_bounds()[channel]
    room = min(hi - trim_u[channel], trim_u[channel] - lo)
    caps = [(LIMIT_SHARE * room, f"{LIMIT_SHARE:.0%} of the [limits] travel about trim "
             f"({lo:g}..{hi:g}, trim {trim_u[channel]:.4g})")]
    if airframe.kind == "multirotor":
        c, mix = trim_u[0], airframe.params.pitch_mix
        caps.append((LIMIT_SHARE * (min(c, 1.0 - c) / mix - abs(trim_u[1])),
                     f"{LIMIT_SHARE:.0%} of what the rotor mix holds (collective {c:.3g}, "
                     f"pitch_mix {mix:g})"))
    rates = airframe.rate_limits()
    if rates and rates[channel] and math.isfinite(unit_s):
        caps.append((0.25 * rates[channel] * unit_s, f"a full reversal slewed in half the "
                     f"{unit_s:g} s pulse at the {rates[channel]:g}/s rate limit"))
    cap, why = min(caps, key=lambda c: c[0])
    if cap <= 0:
        raise DesignError(f"--airframe {airframe.name}: the trim leaves no travel for inputs "
                          f"on {CONTROLS[airframe.kind][channel]} ({why})")
    return cap, why


def alpha_response(airframe: Airframe, point, channel: int, u: np.ndarray, dt: float
                   ) -> np.ndarray:
    """The linearised airframe's open-loop angle-of-attack change (rad) to the increments
    ``u`` on ``channel`` (zero-order hold over ``dt``), from trim."""
    A, B = linearise(airframe, point)
    n = A.shape[0]
    E = expm(np.block([[A, B[:, [channel]]], [np.zeros((1, n + 1))]]) * dt)
    Ad, Bd = E[:n, :n], E[:n, n:]
    x = np.zeros(n)
    out = np.empty(len(u))
    u0, w0 = point.x[0], point.x[1]
    for k, uk in enumerate(u):
        out[k] = (u0 * x[1] - w0 * x[0]) / (u0**2 + w0**2)
        x = Ad @ x + Bd[:, 0] * uk
    return out


def _wanted(airframe: Airframe, point, channel: int, unit_input: np.ndarray, dt: float,
            alpha_deg: float) -> tuple[float, str]:
    """The amplitude the rule asks for, before the limits."""
    if airframe.kind != "fixed_wing":
        return MULTIROTOR_AMPLITUDE, "the emulator's system-identification pitch input"
    peak = float(np.max(np.abs(alpha_response(airframe, point, channel, unit_input, dt))))
    return math.radians(alpha_deg) / peak, (
        f"a peak angle-of-attack change of {alpha_deg:g} deg in the linearised open-loop "
        f"response ({math.degrees(peak):.3g} deg per rad of elevator)")


def _layout(t: np.ndarray, signal: str, kind: str, unit_3211: float, unit_doublet: float,
            amplitude: float, band: tuple[float, float], settle: float
            ) -> tuple[np.ndarray, np.ndarray, list[dict]]:
    """The pitch-channel schedule over one sortie: inputs of alternating sign after a trim
    lead-in, each followed by its hands-off response and a gap (fixed wing)."""
    T = float(t[-1])
    u, hands = np.zeros_like(t), np.zeros(len(t), bool)
    events = []
    if signal == "multisine":
        length = T - LEAD_S - 1.0
        period = min(10.0, length)
        u = schroeder_multisine(t, amplitude, band, period, LEAD_S, length)
        hands[(t >= LEAD_S) & (t < LEAD_S + length)] = kind == "fixed_wing"
        events.append({"t_s": LEAD_S, "signal": "multisine", "length_s": round(length, 3),
                       "period_s": period})
        return u, hands, events
    order = {"3211": ["3211"], "doublet": ["doublet"], "mixed": ["3211", "doublet"]}[signal]
    s, k, sign = LEAD_S, 0, 1.0
    while True:
        name = order[k % len(order)]
        length = 7 * unit_3211 if name == "3211" else 2 * unit_doublet
        if s + length + settle > T - 0.5:
            break
        u += multistep_3211(t, sign * amplitude, s, unit_3211) if name == "3211" else \
            doublet(t, sign * amplitude, s, unit_doublet)
        if kind == "fixed_wing":
            hands[(t >= s) & (t < s + length + settle)] = True
        events.append({"t_s": round(s, 4), "signal": name, "sign": int(sign),
                       "length_s": round(length, 4)})
        s += length + settle + GAP_S
        k += 1
        if name == order[-1]:
            sign = -sign
    return u, hands, events


def _size(airframe: Airframe, point, channel: int, signal: str, unit_input: np.ndarray,
          events: list[dict], dt: float, shortest: float, alpha_deg: float,
          amplitude: float | None) -> tuple[float, str]:
    """The amplitude of the unit-amplitude schedule ``unit_input`` and why: the rule (a fixed
    wing's peak alpha over its first inputs), cut to the limits; a given ``amplitude`` is
    checked against them (module docstring)."""
    cap, why_cap = _caps(airframe, channel, point.u,
                         math.inf if signal == "multisine" else shortest)
    rates = airframe.rate_limits()
    if signal == "multisine" and rates and rates[channel]:
        slope = float(np.max(np.abs(np.diff(unit_input)))) / dt  # per unit amplitude
        if LIMIT_SHARE * rates[channel] / slope < cap:
            cap = LIMIT_SHARE * rates[channel] / slope
            why_cap = f"slewing at {LIMIT_SHARE:.0%} of the {rates[channel]:g}/s rate limit"
    if amplitude is not None:
        if amplitude > cap:
            raise DesignError(f"--amplitude {amplitude:g} exceeds {cap:.4g}: {why_cap}")
        return amplitude, "given (--amplitude)"
    first = events[min(1, len(events) - 1)]
    window = np.arange(len(unit_input)) * dt < first["t_s"] + first["length_s"] + 1.0
    want, why = _wanted(airframe, point, channel, unit_input[window], dt, alpha_deg)
    if want > cap:
        return cap, f"{why}, cut to {why_cap}"
    return want, why


def design_input(airframe: Airframe, signal: str = "mixed", duration_s: float = 20.0,
                 sample_rate_hz: float = 100.0, speed: float | None = None,
                 alpha_deg: float = 3.0, amplitude: float | None = None,
                 mode_hz: float | None = None) -> ExcitationDesign:
    """Design the pitch-channel excitation of one sortie for ``airframe``.

    Parameters
    ----------
    airframe : Airframe
        The user's airframe (its model gives the modes, its ``[limits]`` the travel).
    signal : str
        ``mixed`` (3-2-1-1 and doublets alternating, each sign), ``3211``, ``doublet`` or
        ``multisine`` (Schroeder-phased, over ``f/3 .. 3 f`` of the timing mode).
    duration_s, sample_rate_hz : float
        One sortie's length and the log rate of the schedule.
    speed : float, optional
        Trim speed (default the airframe's nominal airspeed; a multirotor's 0 is hover).
    alpha_deg : float
        A fixed wing's target static angle-of-attack change (deg).
    amplitude : float, optional
        The input amplitude in the control's units, instead of the rule.
    mode_hz : float, optional
        Time the inputs from this frequency (Hz) instead of the model's mode.

    Returns
    -------
    ExcitationDesign

    Raises
    ------
    DesignError
        For an unknown signal, a sortie too short for one input, an amplitude beyond the
        limits or an airframe without a pitch mode (the message names the option).
    """
    if signal not in SIGNALS:
        raise DesignError(f"--signal {signal}: expected one of {', '.join(SIGNALS)}")
    kind = airframe.kind
    speed = float(airframe.nominal_airspeed if speed is None else speed)
    point = trim(airframe, speed)
    mode = pitch_mode(airframe, speed, mode_hz)
    w = mode.natural_frequency
    dt = 1.0 / sample_rate_hz
    snap = lambda x: max(dt, round(x / dt) * dt)  # noqa: E731  whole log intervals
    unit_3211, unit_doublet = snap(RULE_3211 / w), snap(DOUBLET_RULE / w)
    f = w / (2 * math.pi)
    band = (f / 3.0, min(3.0 * f, sample_rate_hz / 5.0))
    channel = PITCH_CHANNEL[kind]
    settle = 2.0 if not math.isfinite(mode.damping) or mode.damping <= 0 else \
        float(np.clip(SETTLE_CYCLES / (mode.damping * w), *SETTLE_S))
    n = int(round(duration_s * sample_rate_hz)) + 1
    t = np.arange(n) * dt
    unit_input, hands, events = _layout(t, signal, kind, unit_3211, unit_doublet, 1.0, band,
                                        settle)
    if not events:
        timed = f" timed from --mode-hz {mode_hz:g}" if mode_hz is not None else ""
        raise DesignError(f"--duration {duration_s:g} s is too short for one {signal} input"
                          f"{timed} with its {LEAD_S:g} s lead-in and {settle:.3g} s response")
    amp, why = _size(airframe, point, channel, signal, unit_input, events, dt,
                     unit_doublet if signal == "doublet" else unit_3211, alpha_deg, amplitude)
    u = amp * unit_input
    increments = np.zeros((n, 2))
    increments[:, channel] = u
    rule = {"3211": f"3-2-1-1 time step {RULE_3211:g}/omega_n = {unit_3211:g} s",
            "doublet": f"doublet pulse width {DOUBLET_RULE:g}/omega_n = {unit_doublet:g} s",
            "mixed": f"3-2-1-1 time step {RULE_3211:g}/omega_n = {unit_3211:g} s, doublet "
                     f"pulse width {DOUBLET_RULE:g}/omega_n = {unit_doublet:g} s",
            "multisine": f"Schroeder multisine over f/3..3f = {band[0]:.3g}..{band[1]:.3g} Hz"}
    notes = [] if kind == "fixed_wing" else [
        "inputs are added to the pitch command with the attitude loop on (injected at the "
        "mixer): the loop opposes them, so pitch_mix and pitch_damping are seen through it"]
    return ExcitationDesign(
        airframe=airframe.name, kind=kind, signal=signal, controls=CONTROLS[kind],
        channel=channel, speed=speed, trim_controls=(float(point.u[0]), float(point.u[1])),
        mode=mode, rule=rule[signal] + " (Jategaonkar 2015, ch. 2)"
        if signal != "multisine" else rule[signal] + " (Morelli 2003)",
        unit_s=unit_3211 if signal in ("3211", "mixed") else unit_doublet
        if signal == "doublet" else 1.0 / band[1],
        amplitude=float(amp), amplitude_why=why, band_hz=band, time=t,
        increments=increments, hands_off=hands, events=events, notes=notes)
