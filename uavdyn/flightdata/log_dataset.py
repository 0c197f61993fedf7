"""A real flight log as an interchange dataset: its longitudinal segments, one sortie each, with a
split, provenance in the manifest, and a summary (text and timeline figure) of what was kept.

Used by ``uavdyn import-log``; callable from Python the same way::

    flight = read_ulog_flight("flight.ulg")
    result = write_log_dataset(flight, "data/flight", SegmentRules(max_roll_deg=8))
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from uavdyn.flightdata.csvio import write_csv
from uavdyn.flightdata.flightlog import FlightLog
from uavdyn.flightdata.manifest import write_manifest
from uavdyn.flightdata.segments import SegmentReport, SegmentRules, find_segments, segment_sorties
from uavdyn.flightdata.split import assign_split
from uavdyn.flightdata.timeline import draw_timeline

SUMMARY_FILE = "import_summary.txt"
TIMELINE_FILE = "import_timeline.png"
ENTRY_KEYS = ("source_file", "source_start_s", "source_end_s", "flight_time_s", "cut",
              "altitude_m", "velocity_reference")


@dataclass(frozen=True)
class LogDataset:
    """A log cut into segments with a split, before (:func:`plan_log_dataset`) or after
    (:func:`write_log_dataset`) it is written: the segmenter's report, the sorties, each one's
    manifest entry and split, and the summary lines (``import_summary.txt``)."""

    flight: FlightLog
    report: SegmentReport
    sorties: list
    entries: list[dict]
    splits: list[str]
    lines: list[str]
    split_rule: dict


def plan_log_dataset(flight: FlightLog, rules: SegmentRules | None = None,
                     split: dict | None = None) -> LogDataset:
    """Cut ``flight`` into segments and assign their split, writing nothing (so a log with no
    usable segment, or a split that cannot be filled, is refused before any output exists).

    Parameters
    ----------
    flight : FlightLog
        The imported log.
    rules : SegmentRules, optional
        The segment thresholds (defaults stated in :class:`SegmentRules`).
    split : dict, optional
        ``by``, ``fractions``, ``seed`` for :func:`uavdyn.flightdata.split.assign_split`
        (default by sortie, 0.7/0.15/0.15, seed 0).

    Returns
    -------
    LogDataset

    Raises
    ------
    FlightDataError
        No usable segment (one line saying what was missing), or a split that would leave a
        part empty (naming it).
    """
    report = find_segments(flight, rules)
    sorties = segment_sorties(report)
    entries = [{"file": f"{s.name}.csv", "mission": s.mission,
                "duration_s": round(s.duration, 6),
                **{k: s.meta[k] for k in ENTRY_KEYS if k in s.meta}} for s in sorties]
    splits = assign_split(entries, **(split or {}))
    for entry, part in zip(entries, splits):
        entry["split"] = part
    lines = report.lines() + [f"  split: {_split_counts(splits, sorties)}"]
    lines += [f"  control map: {text}" for text in flight.meta.get("control_map", {}).values()]
    return LogDataset(flight, report, sorties, entries, splits, lines, _split_rule(split))


def write_log_dataset(flight: FlightLog | LogDataset, folder: str | Path,
                      rules: SegmentRules | None = None, split: dict | None = None
                      ) -> LogDataset:
    """Write a log's segments as a dataset into ``folder`` (which the caller swaps into place
    atomically): one CSV per segment, ``manifest.json``, ``import_summary.txt`` and
    ``import_timeline.png``.

    Parameters
    ----------
    flight : FlightLog or LogDataset
        The imported log (cut here with ``rules`` and ``split``), or the result of
        :func:`plan_log_dataset`.
    folder : str or Path
        An empty folder to fill.
    rules, split
        As for :func:`plan_log_dataset` (ignored for a planned dataset).

    Returns
    -------
    LogDataset
    """
    planned = flight if isinstance(flight, LogDataset) else plan_log_dataset(flight, rules,
                                                                             split)
    folder = Path(folder)
    log = planned.flight
    for s, entry in zip(planned.sorties, planned.entries):
        write_csv(s, folder / entry["file"])
    write_manifest(folder, airframe="", kind=log.kind, sample_rate_hz=round(1.0 / log.dt, 9),
                   source=f"uavdyn import-log ({log.source}) of "
                          f"{Path(str(log.meta.get('file', log.name))).name}",
                   sorties=planned.entries, velocity_reference=log.velocity_reference,
                   control_map=log.meta.get("control_map", {}),
                   channel_sources=log.meta.get("sources", {}),
                   resampling=log.meta.get("resampling", ""),
                   segmentation=planned.report.as_dict(), split_rule=planned.split_rule)
    (folder / SUMMARY_FILE).write_text("\n".join(planned.lines) + "\n")
    draw_timeline(planned.report, folder / TIMELINE_FILE, planned.splits)
    return planned


def _split_rule(split: dict | None) -> dict:
    """The split options as recorded in the manifest (defaults filled in)."""
    rule = {"by": "sortie", "fractions": [0.7, 0.15, 0.15], "seed": 0}
    rule.update({k: list(v) if isinstance(v, tuple) else v for k, v in (split or {}).items()})
    return rule


def _split_counts(splits: list[str], sorties: list) -> str:
    """``train 2 (18.3 s), validation 1 (5.0 s), test 1 (5.4 s)``."""
    parts = []
    for part in ("train", "validation", "test"):
        durations = [s.duration for s, p in zip(sorties, splits) if p == part]
        parts.append(f"{part} {len(durations)} ({sum(durations):.1f} s)")
    return ", ".join(parts)
