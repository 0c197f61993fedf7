"""Real flight logs as an interchange dataset: their longitudinal segments, one sortie each,
with a split, provenance in the manifest (every source log: its file, format, rate, how it was
resampled and which segments came from it), and a summary (text and one timeline figure per
log) of what was kept.

Used by ``uavdyn import-log``; callable from Python the same way::

    flight = read_ulog_flight("flight.ulg")
    result = write_log_dataset(flight, "data/flight", SegmentRules(max_roll_deg=8))

or, for a campaign of several logs on one rate (:mod:`uavdyn.flightdata.campaign`)::

    flights, rate = on_one_rate([read_ulog_flight(p) for p in paths])
    write_log_dataset(flights, "data/campaign", split={"by": "log"}, rate_note=rate.reason)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from uavdyn.flightdata.csvio import write_csv
from uavdyn.flightdata.errors import FlightDataError
from uavdyn.flightdata.flightlog import FlightLog
from uavdyn.flightdata.manifest import write_manifest
from uavdyn.flightdata.segments import (
    SegmentReport,
    SegmentRules,
    find_segments,
    lateral_record,
    segment_sorties,
)
from uavdyn.flightdata.split import assign_split, split_rule
from uavdyn.flightdata.timeline import draw_timeline

SUMMARY_FILE = "import_summary.txt"
TIMELINE_FILE = "import_timeline.png"
ENTRY_KEYS = ("source_file", "source_start_s", "source_end_s", "flight_time_s", "cut",
              "altitude_m", "velocity_reference")


@dataclass(frozen=True)
class LogDataset:
    """Logs cut into segments with a split, before (:func:`plan_log_dataset`) or after
    (:func:`write_log_dataset`) they are written: each log's segmenter report (None for a
    log with no usable segment, whose reason is in ``logs``), the sorties, each one's
    manifest entry and split, the per-log records of the manifest (``logs``), and the summary
    lines (``import_summary.txt``)."""

    flights: list[FlightLog]
    reports: list[SegmentReport | None]
    sorties: list
    entries: list[dict]
    splits: list[str]
    lines: list[str]
    split_rule: dict
    logs: list[dict] = field(default_factory=list)

    @property
    def flight(self) -> FlightLog:
        """The first (for a single log, the only) flight."""
        return self.flights[0]

    @property
    def report(self) -> SegmentReport | None:
        """The first flight's segmenter report."""
        return self.reports[0]

    def timeline_files(self) -> list[str]:
        """The figure of each log with segments: ``import_timeline.png`` for one log,
        ``import_timeline_<log>.png`` for each of several."""
        if len(self.flights) == 1:
            return [TIMELINE_FILE]
        return [f"import_timeline_{f.name}.png" for f, r in zip(self.flights, self.reports)
                if r is not None]


def _cut(flights: list[FlightLog], rules: SegmentRules | None
         ) -> tuple[list[SegmentReport | None], list[str]]:
    """Each flight's segments; a log without any is kept out with its reason, unless every
    log is without (then the first one's refusal, naming the others)."""
    reports: list[SegmentReport | None] = []
    reasons: list[str] = []
    for flight in flights:
        try:
            reports.append(find_segments(flight, rules))
            reasons.append("")
        except FlightDataError as exc:
            if len(flights) == 1:
                raise
            reports.append(None)
            reasons.append(exc.reason)
    if all(r is None for r in reports):
        raise FlightDataError(f"none of the {len(flights)} logs has a usable segment; "
                              f"{flights[0].name}: {reasons[0]}", flights[0].meta.get("file"))
    return reports, reasons


def plan_log_dataset(flights: FlightLog | list[FlightLog], rules: SegmentRules | None = None,
                     split: dict | None = None, rate_note: str = "") -> LogDataset:
    """Cut the flight(s) into segments and assign their split, writing nothing (so logs with
    no usable segment, or a split that cannot be filled, are refused before any output
    exists).

    Parameters
    ----------
    flights : FlightLog or list of FlightLog
        The imported log, or a campaign's logs on one rate (in flight order; distinct names,
        see :func:`uavdyn.flightdata.campaign.on_one_rate`).
    rules : SegmentRules, optional
        The segment thresholds (defaults stated in :class:`SegmentRules`).
    split : dict, optional
        ``by``, ``fractions``, ``seed`` for :func:`uavdyn.flightdata.split.assign_split`
        (default by sortie, seed 0, the default fractions for the number of segments).
    rate_note : str
        How the grid rate was chosen (a line of the summary), e.g.
        :attr:`uavdyn.flightdata.campaign.CampaignRate.reason`.

    Returns
    -------
    LogDataset

    Raises
    ------
    FlightDataError
        No usable segment in any log (one line saying what was missing), or a split that
        would leave a part empty (naming it). A campaign log without a usable segment is
        not refused: the summary and the manifest say why it gave none.
    """
    flights = [flights] if isinstance(flights, FlightLog) else list(flights)
    reports, reasons = _cut(flights, rules)
    sorties, entries, logs = [], [], []
    for flight, report, reason in zip(flights, reports, reasons):
        cut = segment_sorties(report) if report is not None else []
        sorties += cut
        entries += [{"file": f"{s.name}.csv", "mission": s.mission,
                     "duration_s": round(s.duration, 6), "log": flight.name,
                     **{k: s.meta[k] for k in ENTRY_KEYS if k in s.meta}} for s in cut]
        logs.append(log_record(flight, report, [f"{s.name}.csv" for s in cut], reason))
    options = dict(split or {})
    options.setdefault("fractions", None)
    rule = split_rule(entries, **options)
    splits = assign_split(entries, rule["by"], rule["fractions"], rule["seed"])
    for entry, part in zip(entries, splits):
        entry["split"] = part
    lines = [f"grid: {rate_note}"] if rate_note else []
    for flight, report, reason in zip(flights, reports, reasons):
        lines += report.lines() if report is not None else [f"{flight.name}: no segment "
                                                            f"kept: {reason}"]
        own = flight.meta.get("own_rate_hz")
        if own and abs(own * flight.dt - 1.0) > 1e-6:
            lines += [f"  logged at {own:.6g} Hz, resampled to {1 / flight.dt:.6g} Hz"]
        lines += [f"  control map: {text}" for text in control_map_text(flight.meta)]
        lines += content_lines(flight.meta)
        if report is not None and report.rules.turns:
            fed = lateral_record(flight)
            lines += ["  turning flight used: the model's lateral inputs are "
                      + "; ".join(f"{k} = {v}" for k, v in fed.items())]
        lines += [f"  grid: {flight.meta['grid']}"] if flight.meta.get("grid") else []
    lines += [f"split: {_split_counts(splits, sorties)} (by {rule['by']}"
              + (f"; {rule['note']})" if rule.get("note") else ")")]
    if len(flights) > 1:
        lines += [_used_share(flights, sorties)]
    return LogDataset(flights, reports, sorties, entries, splits, lines, rule, logs)


CONTENT_KEYS = ("messages_read", "dropouts", "warnings", "speed_check")


def content_lines(meta: dict) -> list[str]:
    """What a reader recorded of the log's content, as summary lines: the data messages
    read per topic (a cut ULog is shorter, not refused: the counts show it), the speed
    check's fit, and each warning (a topic ending early, logger dropouts).

    Parameters
    ----------
    meta : dict
        A flight's ``meta`` (keys :data:`CONTENT_KEYS`, each optional).

    Returns
    -------
    list of str
        Indented lines for ``import_summary.txt`` (none for a reader that records nothing).
    """
    lines = []
    if meta.get("messages_read"):
        lines += ["  messages read: " + ", ".join(f"{k} {v}" for k, v in
                                                   meta["messages_read"].items())]
    fit = (meta.get("speed_check") or {}).get("u") or {}
    if fit.get("scale") is not None:
        lines += [f"  speed u against the accelerometer: x {fit['scale']:.3g} +- "
                  f"{fit['standard_error']:.2g} (1 = m/s; {fit['windows']} windows)"]
    return lines + [f"  warning: {w}" for w in meta.get("warnings", [])]


def control_map_text(meta: dict) -> list[str]:
    """Each control's map as a sentence (``elevator = RCOU.C2 mapped linearly, ...``):
    ``meta['control_map_text']`` where a reader wrote one, else ``meta['control_map']``'s
    values where they are already sentences."""
    text = meta.get("control_map_text") or meta.get("control_map") or {}
    return [v for v in text.values() if isinstance(v, str)]


def log_record(flight: FlightLog, report: SegmentReport | None, files: list[str],
               reason: str = "") -> dict:
    """One source log as the manifest's ``logs`` records it: name, file, format, its own
    rate and the dataset's, the time it spans and kept, the segments cut from it, the
    velocity reference, channel sources, control maps, resampling and segmentation (or why
    it gave no segment). The channels it recorded (``channels``) say what a later import
    could add as recorded columns (bank angle, roll and yaw rate, sideslip)."""
    meta = flight.meta
    record = {"name": flight.name, "file": str(meta.get("file", flight.name)),
              "format": flight.source, "own_rate_hz": meta.get("own_rate_hz",
                                                               round(1.0 / flight.dt, 9)),
              "rate_hz": round(1.0 / flight.dt, 9), "duration_s": round(flight.duration, 6),
              "kept_s": round(report.kept_s, 6) if report is not None else 0.0,
              "segments": files, "velocity_reference": flight.velocity_reference,
              "channels": sorted(flight.channels), "channel_sources": meta.get("sources", {}),
              "control_map": meta.get("control_map", {}),
              "resampling": meta.get("resampling", "")}
    if meta.get("grid"):
        record["grid"] = meta["grid"]
    record.update({k: meta[k] for k in CONTENT_KEYS if meta.get(k) is not None})
    if report is not None:
        record["segmentation"] = report.as_dict()
        if report.rules.turns:  # the channels fed to the model as recorded inputs
            record["lateral_inputs"] = lateral_record(flight)
    else:
        record["no_segment"] = reason
    return record


def _used_share(flights: list[FlightLog], sorties: list) -> str:
    """``campaign: 4 logs, 1234.5 s, 1050.0 s kept in 12 segments (85 %)``."""
    total = sum(f.duration for f in flights)
    kept = sum(s.duration for s in sorties)
    return (f"campaign: {len(flights)} logs, {total:.1f} s, {kept:.1f} s kept in "
            f"{len(sorties)} segment{'' if len(sorties) == 1 else 's'} "
            f"({100 * kept / max(total, 1e-12):.0f} % of the flight "
            "time)")


def write_log_dataset(flights: FlightLog | list[FlightLog] | LogDataset, folder: str | Path,
                      rules: SegmentRules | None = None, split: dict | None = None,
                      rate_note: str = "") -> LogDataset:
    """Write logs' segments as a dataset into ``folder`` (which the caller swaps into place
    atomically): one CSV per segment, ``manifest.json`` (with a ``logs`` record per source
    log), ``import_summary.txt`` and the timeline figure(s) (:meth:`LogDataset.timeline_files`).

    Parameters
    ----------
    flights : FlightLog, list of FlightLog or LogDataset
        The imported log(s) (cut here with ``rules`` and ``split``), or the result of
        :func:`plan_log_dataset`.
    folder : str or Path
        An empty folder to fill.
    rules, split, rate_note
        As for :func:`plan_log_dataset` (ignored for a planned dataset).

    Returns
    -------
    LogDataset
    """
    planned = flights if isinstance(flights, LogDataset) else plan_log_dataset(
        flights, rules, split, rate_note)
    folder = Path(folder)
    for s, entry in zip(planned.sorties, planned.entries):
        write_csv(s, folder / entry["file"])
    first = planned.flight
    names = ", ".join(Path(str(f.meta.get("file", f.name))).name for f in planned.flights)
    write_manifest(folder, airframe="", kind=first.kind, sample_rate_hz=round(1.0 / first.dt, 9),
                   source=f"uavdyn import-log ({first.source}) of {names}",
                   sorties=planned.entries, logs=planned.logs, split_rule=planned.split_rule)
    (folder / SUMMARY_FILE).write_text("\n".join(planned.lines) + "\n")
    figures = iter(planned.timeline_files())
    for flight, report in zip(planned.flights, planned.reports):
        if report is not None:
            mine = [p for p, e in zip(planned.splits, planned.entries) if e["log"] == flight.name]
            draw_timeline(report, folder / next(figures), mine)
    return planned


def _split_counts(splits: list[str], sorties: list) -> str:
    """``train 2 (18.3 s), validation 1 (5.0 s), test 1 (5.4 s)``."""
    parts = []
    for part in ("train", "validation", "test"):
        durations = [s.duration for s, p in zip(sorties, splits) if p == part]
        parts.append(f"{part} {len(durations)} ({sum(durations):.1f} s)")
    return ", ".join(parts)
