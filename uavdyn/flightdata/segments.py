"""Longitudinal segments: the stretches of a six-degree-of-freedom flight the pitch-plane model
holds on.

The longitudinal model assumes wings level, no yaw rate and no sideslip: in a banked turn
``d theta/dt = q cos(phi) - r sin(phi)`` is not ``q`` and the lift is not in the pitch plane.
:func:`find_segments` marks every grid sample against the stated rules (:class:`SegmentRules`,
each threshold an option), keeps the maximal runs where all hold that are long enough to fit
on, checks the pitch-plane kinematics and physical ranges on each, and says for every cut why
it was made. A flight with no usable segment is refused with one line saying what was missing.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from uavdyn.flightdata.checks import check_values
from uavdyn.flightdata.errors import FlightDataError
from uavdyn.flightdata.flightlog import FlightLog
from uavdyn.flightdata.sortie import Sortie
from uavdyn.model import CONTROL_BOUNDS, CONTROL_NAMES, STATE_NAMES, state_limits

CONTROL_SLACK = 1e-9
SIDESLIP_MIN_SPEED = 3.0  # m/s: below it (hover, ground) the sideslip angle means nothing


@dataclass(frozen=True)
class SegmentRules:
    """Where the longitudinal model holds (defaults stated; each is an ``import-log`` option).

    Attributes
    ----------
    max_roll_deg : float
        Wings level: ``|roll|`` at most this (default 10 deg).
    max_yaw_rate_deg_s : float
        ``|r|`` at most this (default 10 deg/s).
    max_sideslip_deg : float
        ``|atan2(v, u)|`` at most this, checked only where the velocities are air relative
        (a ground-relative sideslip is the wind's crab angle, not the aircraft's).
    min_duration_s : float
        Shortest segment kept (default 5 s: a few short-period and pitch-response times).
    min_speed_m_s : float or None
        Fixed wing: below this body speed it is not flying (the airborne test where the log
        has no in-air flag); default 5 m/s for a fixed wing, none for a multirotor.
    kinematic : bool
        Check ``d theta/dt ~ q`` on each segment and drop those that fail (default True).
    turns : bool
        Keep turning and climbing flight (issue 41 item 2): the bank, roll and yaw rates and
        sideslip become recorded inputs of each sortie (columns ``phi, p, r, beta``), so the
        wings-level rules (``max_roll_deg``, ``max_yaw_rate_deg_s``) are not applied; cut only
        where the data are unusable (gaps, ground, invalid values) or ``|roll|`` exceeds
        ``max_bank_deg``. The kinematic check is then ``d theta/dt ~ q cos(phi) - r sin(phi)``.
    max_bank_deg : float
        With ``turns``: the stated bank limit (default 60 deg).
    """

    max_roll_deg: float = 10.0
    max_yaw_rate_deg_s: float = 10.0
    max_sideslip_deg: float = 10.0
    min_duration_s: float = 5.0
    min_speed_m_s: float | None = None
    kinematic: bool = True
    turns: bool = False
    max_bank_deg: float = 60.0

    def __post_init__(self) -> None:
        for key in ("max_roll_deg", "max_yaw_rate_deg_s", "max_sideslip_deg", "min_duration_s",
                    "max_bank_deg"):
            value = getattr(self, key)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise FlightDataError(f"segment rule {key} must be a positive number, got "
                                      f"{value!r}")
        if self.max_bank_deg >= 90.0:
            raise FlightDataError(f"segment rule max_bank_deg must be below 90 deg, got "
                                  f"{self.max_bank_deg!r}")
        if self.min_speed_m_s is not None and not (math.isfinite(self.min_speed_m_s)
                                                   and self.min_speed_m_s >= 0):
            raise FlightDataError(f"segment rule min_speed_m_s must be >= 0, got "
                                  f"{self.min_speed_m_s!r}")

    def speed_floor(self, kind: str) -> float:
        """The body-speed floor for ``kind`` (the stated default where none was given)."""
        if self.min_speed_m_s is not None:
            return float(self.min_speed_m_s)
        return 5.0 if kind == "fixed_wing" else 0.0


@dataclass(frozen=True)
class Segment:
    """One kept stretch: grid rows ``start..stop-1`` of the flight, and why it begins and ends
    where it does (the rule that failed just outside it, or the log's start or end)."""

    start: int
    stop: int
    start_s: float
    end_s: float
    cut_before: str
    cut_after: str

    @property
    def duration(self) -> float:
        return self.end_s - self.start_s


@dataclass
class SegmentReport:
    """What :func:`find_segments` kept and dropped, and the share of the flight each rule
    excluded (for the summary and the refusal)."""

    flight: FlightLog
    rules: SegmentRules
    kept: list[Segment]
    dropped: list[tuple[Segment, str]] = field(default_factory=list)
    excluded: dict[str, float] = field(default_factory=dict)
    longest_ok_s: float = 0.0
    unchecked: list[str] = field(default_factory=list)

    @property
    def kept_s(self) -> float:
        return float(sum(s.duration for s in self.kept))

    def lines(self) -> list[str]:
        """The import summary as text lines."""
        f = self.flight
        out = [f"{f.name}: {f.duration:.1f} s at {1 / f.dt:.4g} Hz ({f.source}; velocities "
               f"{_REFERENCE_TEXT[f.velocity_reference]})",
               f"kept {len(self.kept)} segment(s), {self.kept_s:.1f} s "
               f"({100 * self.kept_s / max(f.duration, 1e-12):.0f} % of the flight)"]
        for rule, share in self.excluded.items():
            out.append(f"  excluded by {rule}: {_percent(share)} of the flight")
        for s in self.kept:
            out.append(f"  kept {s.start_s:7.2f}-{s.end_s:7.2f} s ({s.duration:5.1f} s): "
                       f"cut before by {s.cut_before}, after by {s.cut_after}")
        for s, why in self.dropped:
            out.append(f"  dropped {s.start_s:7.2f}-{s.end_s:7.2f} s: {why}")
        for what in self.unchecked:
            out.append(f"  not checked: {what}")
        return out

    def as_dict(self) -> dict:
        """JSON-ready record for the manifest."""
        return {"rules": asdict(self.rules),
                "speed_floor_m_s": self.rules.speed_floor(self.flight.kind),
                "excluded_share": {k: round(v, 4) for k, v in self.excluded.items()},
                "dropped": [{"start_s": s.start_s, "end_s": s.end_s, "why": why}
                            for s, why in self.dropped],
                "not_checked": self.unchecked}


_REFERENCE_TEXT = {"air": "air relative (the log's wind estimate removed)",
                   "airspeed": "u from the airspeed sensor, v and w ground relative",
                   "ground": "ground relative: no airspeed sensor or wind estimate"}


def rule_masks(flight: FlightLog, rules: SegmentRules) -> tuple[dict[str, np.ndarray], list[str]]:
    """Per rule, which samples break it (True = excluded), and the rules the log cannot check.

    The names are the reasons a summary shows: ``on the ground``, ``banked above X deg``, ...
    """
    c = flight.channels
    masks: dict[str, np.ndarray] = {}
    unchecked: list[str] = []
    with np.errstate(invalid="ignore"):
        if flight.airborne is not None:
            masks["on the ground (the log's in-air flag)"] = ~flight.airborne.astype(bool)
        floor = rules.speed_floor(flight.kind)
        if floor > 0:
            masks[f"slower than {floor:g} m/s"] = np.hypot(c["u"], c["w"]) < floor
        if rules.turns:  # turning flight is used: only beyond the stated bank limit
            masks[f"banked above {rules.max_bank_deg:g} deg (the turning-flight limit)"] = (
                np.abs(c["roll"]) > math.radians(rules.max_bank_deg))
        else:
            masks[f"banked above {rules.max_roll_deg:g} deg"] = (
                np.abs(c["roll"]) > math.radians(rules.max_roll_deg))
            masks[f"yaw rate above {rules.max_yaw_rate_deg_s:g} deg/s"] = (
                np.abs(c["r"]) > math.radians(rules.max_yaw_rate_deg_s))
        if flight.velocity_reference == "air":  # undefined near zero speed (a hover)
            masks[f"sideslip above {rules.max_sideslip_deg:g} deg"] = (
                (np.abs(np.arctan2(c["v"], c["u"])) > math.radians(rules.max_sideslip_deg))
                & (np.hypot(c["u"], c["v"]) > SIDESLIP_MIN_SPEED))
        else:
            unchecked.append("sideslip (the velocities are not air relative)")
        if flight.airborne is None and floor == 0:
            unchecked.append("airborne (the log has no in-air flag; give --min-speed)")
        lateral = ([c["p"]] + ([c["v"]] if flight.velocity_reference == "air" else [])
                   if rules.turns else [])  # what the lateral inputs are made of
        used = np.column_stack([flight.states(), c["roll"], c["r"], flight.controls, *lateral])
        masks["sensor gap or invalid value"] = ~np.all(np.isfinite(used), axis=1)
        limits = state_limits(flight.kind)
        states = flight.states()
        out = np.zeros(len(flight.time), bool)
        for j, name in enumerate(STATE_NAMES):
            out |= np.abs(states[:, j]) > limits[name]
        masks["outside the model's physical ranges"] = out
        ctrl = np.zeros(len(flight.time), bool)
        for j, (lo, hi) in enumerate(CONTROL_BOUNDS[flight.kind]):
            ctrl |= (flight.controls[:, j] < lo - CONTROL_SLACK) | (
                flight.controls[:, j] > hi + CONTROL_SLACK)
        masks["a control outside its range " + "/".join(CONTROL_NAMES[flight.kind])] = ctrl
    return masks, unchecked


def _percent(share: float) -> str:
    """A share as a percentage a reader can trust: never '0 %' for a nonzero share."""
    return f"{100 * share:.0f} %" if share >= 0.005 else f"{100 * share:.2g} %"


def _runs(ok: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs of True as ``(start, stop)`` row pairs."""
    edges = np.diff(np.concatenate([[0], ok.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist()))


def _why(masks: dict[str, np.ndarray], row: int, n: int, end: str) -> str:
    """The rules broken at ``row`` (just outside a run), or the log's start or end."""
    if row < 0 or row >= n:
        return end
    broken = [name for name, m in masks.items() if m[row]]
    return " and ".join(broken) if broken else "unknown"


def find_segments(flight: FlightLog, rules: SegmentRules | None = None) -> SegmentReport:
    """Cut ``flight`` into the stretches the longitudinal model holds on.

    Parameters
    ----------
    flight : FlightLog
        A six-degree-of-freedom log on its uniform grid.
    rules : SegmentRules, optional
        Thresholds (default :class:`SegmentRules`).

    Returns
    -------
    SegmentReport
        The kept segments (each at least ``min_duration_s``, passing the value checks and,
        with ``rules.kinematic``, the pitch-plane kinematics), the dropped ones with their
        reason, and the share of the flight each rule excluded.

    Raises
    ------
    FlightDataError
        No usable segment: one line saying which rules excluded how much of the flight and
        the longest stretch where all held.
    """
    rules = rules or SegmentRules()
    masks, unchecked = rule_masks(flight, rules)
    n = len(flight.time)
    ok = ~np.any(np.column_stack(list(masks.values())), axis=1)
    dt = flight.dt
    report = SegmentReport(flight, rules, kept=[], unchecked=unchecked,
                           excluded={k: float(m.mean()) for k, m in masks.items() if m.any()})
    runs = _runs(ok)
    report.longest_ok_s = max(((b - a - 1) * dt for a, b in runs), default=0.0)
    for a, b in runs:
        seg = Segment(a, b, float(flight.time[a]), float(flight.time[b - 1]),
                      _why(masks, a - 1, n, "the start of the log"),
                      _why(masks, b, n, "the end of the log"))
        if seg.duration < rules.min_duration_s - 1e-9:
            continue
        problem = _segment_problem(flight, seg, rules)
        if problem:
            report.dropped.append((seg, problem))
        else:
            report.kept.append(seg)
    if not report.kept:
        raise FlightDataError(_refusal(report), flight.meta.get("file"))
    return report


def _segment_problem(flight: FlightLog, seg: Segment, rules: SegmentRules) -> str | None:
    """Why a candidate segment cannot be a sortie (failed value or kinematic check), or None."""
    sl = slice(seg.start, seg.stop)
    time = flight.time[sl] - flight.time[seg.start]
    controls = (segment_inputs(flight) if rules.turns else flight.controls)[sl]
    try:
        check_values(f"segment {seg.start_s:.2f}-{seg.end_s:.2f} s", flight.kind, time,
                     flight.states()[sl], controls, kinematic=rules.kinematic)
    except FlightDataError as exc:
        return exc.reason
    return None


def _refusal(report: SegmentReport) -> str:
    """One line: no usable segment, what excluded how much, and the longest usable stretch."""
    rules = report.rules
    parts = [f"{name} for {_percent(share)} of the flight"
             for name, share in sorted(report.excluded.items(), key=lambda kv: -kv[1])]
    line = f"no longitudinal segment of at least {rules.min_duration_s:g} s in this log"
    if parts:
        line += ": " + "; ".join(parts)
    line += (f"; the longest stretch where every rule held is {report.longest_ok_s:.1f} s "
             f"(< {rules.min_duration_s:g} s)" if not report.dropped else "")
    if report.dropped:
        line += "; " + "; ".join(f"segment {s.start_s:.1f}-{s.end_s:.1f} s dropped: {why}"
                                 for s, why in report.dropped[:3])
    return line + " (the thresholds are options of import-log)"


def sideslip(flight: FlightLog) -> np.ndarray:
    """The sideslip ``beta = atan2(v, sqrt(u^2 + w^2))`` (rad) where the velocities are air
    relative; 0 otherwise (a ground-relative ``v`` is the wind's crab, not sideslip)."""
    c = flight.channels
    if flight.velocity_reference != "air":
        return np.zeros(len(flight.time))
    return np.arctan2(c["v"], np.hypot(c["u"], c["w"]))


def segment_inputs(flight: FlightLog) -> np.ndarray:
    """The controls followed by the recorded lateral inputs ``phi, p, r, beta`` (``N x 6``):
    what a turning-flight sortie feeds the model."""
    c = flight.channels
    return np.column_stack([flight.controls, c["roll"], c["p"], c["r"], sideslip(flight)])


LATERAL_SOURCES = {"phi": "roll", "p": "p", "r": "r",
                   "beta": "atan2(v, sqrt(u^2 + w^2)) of the air-relative velocities"}


def lateral_record(flight: FlightLog) -> dict[str, str]:
    """Which log channel fed each lateral input (for the manifest)."""
    out = dict(LATERAL_SOURCES)
    if flight.velocity_reference != "air":
        out["beta"] = ("0: the velocities are not air relative (a ground-relative v is the "
                       "wind's crab angle)")
    return out


def segment_sorties(report: SegmentReport) -> list[Sortie]:
    """Each kept segment as a :class:`Sortie` (time from 0; its provenance in ``meta``); with
    ``rules.turns`` its controls end with the lateral inputs (:func:`segment_inputs`)."""
    f = report.flight
    inputs = segment_inputs(f) if report.rules.turns else f.controls
    out = []
    for k, seg in enumerate(report.kept, start=1):
        sl = slice(seg.start, seg.stop)
        meta = {"source_file": str(f.meta.get("file", "")),
                "source_start_s": round(seg.start_s + float(f.meta.get("start_time_s", 0.0)), 6),
                "source_end_s": round(seg.end_s + float(f.meta.get("start_time_s", 0.0)), 6),
                "flight_time_s": [round(seg.start_s, 6), round(seg.end_s, 6)],
                "cut": {"before": seg.cut_before, "after": seg.cut_after},
                "velocity_reference": f.velocity_reference}
        if f.altitude_m is not None and np.all(np.isfinite(f.altitude_m[sl])):
            meta["altitude_m"] = round(float(np.mean(f.altitude_m[sl])), 1)
        out.append(Sortie(name=f"{f.name}_s{k:02d}", kind=f.kind,
                          time=f.time[sl] - f.time[seg.start], states=f.states()[sl].copy(),
                          controls=inputs[sl].copy(), mission="log segment", meta=meta))
    return out
