"""A flight-test campaign: the logs named on one command line found, checked to be of one
format and kind, named apart, and put on one grid rate, so that they import as one dataset.

``uavdyn import-log LOG [LOG ...]`` uses it; from Python::

    sources = find_logs(["day1/", "day2/flight3.csv"])
    flights = [read_sixdof_csv(s.path, kind="fixed_wing") for s in sources]
    flights, rate = on_one_rate(flights)          # the lowest log rate unless one is given
    planned = plan_log_dataset(flights, split={"by": "log", "fractions": None, "seed": 0})

The rate rule: a stated rate if one is given; else the logs' own rate if they share one; else
the lowest of their rates, every faster log low-pass filtered and resampled to it
(:func:`~uavdyn.flightdata.flightlog.resample_flight`), so no sample is invented.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path

from uavdyn.flightdata.errors import FlightDataError
from uavdyn.flightdata.flightlog import FlightLog, resample_flight

LOG_SUFFIXES = {".ulg": "ulog", ".bin": "ardupilot", ".csv": "csv"}
FORMAT_NAMES = {"ulog": "a PX4 ULog", "alfa": "an ALFA folder", "ardupilot": "an ArduPilot "
                "DataFlash log", "csv": "a six-degree-of-freedom CSV"}
ALFA_MARKER = "-mavros-imu-data.csv"   # every ALFA sequence folder has this topic
MAX_LOGS = 1000
RATE_MATCH = 1e-6                      # two rates closer than this (relative) are one rate


@dataclass(frozen=True)
class LogSource:
    """One log of a campaign: its path and the format it is read as."""

    path: Path
    format: str


@dataclass(frozen=True)
class CampaignRate:
    """The one grid rate of a campaign and why it was chosen (a sentence for the summary)."""

    rate_hz: float
    reason: str


def is_alfa_folder(path: Path) -> bool:
    """Whether ``path`` is a folder holding an ALFA ``*-mavros-imu-data.csv`` topic."""
    try:
        return path.is_dir() and any(p.name.endswith(ALFA_MARKER) for p in path.iterdir())
    except OSError:
        return False


def _file_format(path: Path, fmt: str) -> str:
    """The format of a log file: ``fmt`` when given, else by its suffix."""
    if fmt == "alfa":
        raise FlightDataError("--format alfa reads a folder, but this log is a file", path)
    if fmt != "auto":
        return fmt
    found = LOG_SUFFIXES.get(path.suffix.lower())
    if found is None:
        raise FlightDataError("cannot tell the format from the name (.ulg, .bin, .csv or an "
                              "ALFA folder): give --format", path)
    return found


def _folder_logs(folder: Path, fmt: str) -> list[LogSource]:
    """An ALFA folder as one log, else the logs directly in the folder (files by suffix, ALFA
    sub-folders), in name order."""
    if fmt in ("auto", "alfa") and is_alfa_folder(folder):
        return [LogSource(folder, "alfa")]
    try:
        children = sorted(folder.iterdir(), key=lambda p: p.name)
    except OSError as exc:
        raise FlightDataError(f"cannot list the folder ({exc.strerror or exc})",
                              folder) from None
    found = []
    for child in children:
        if child.is_dir():
            if fmt in ("auto", "alfa") and is_alfa_folder(child):
                found.append(LogSource(child, "alfa"))
        elif child.is_file() and child.suffix.lower() in LOG_SUFFIXES and (
                fmt == "auto" or LOG_SUFFIXES[child.suffix.lower()] == fmt):
            found.append(LogSource(child, LOG_SUFFIXES[child.suffix.lower()]))
    if not found:
        wanted = ("an ALFA sequence folder" if fmt == "alfa" else
                  f"no {fmt} log" if fmt != "auto" else
                  "no log (.ulg, .bin, .csv files or ALFA sequence folders)")
        raise FlightDataError(f"is not a log and holds {wanted} directly inside it"
                              if fmt != "alfa" else f"is not {wanted} and holds none", folder)
    return found


def find_logs(paths: list[str | Path], fmt: str = "auto") -> list[LogSource]:
    """The logs named by files and folders, in the order given (a folder's logs in name
    order), each once, all of one format.

    Parameters
    ----------
    paths : list of str or Path
        Log files (``.ulg``, ``.bin``, ``.csv``), ALFA sequence folders, or folders holding
        such logs directly inside them.
    fmt : {'auto', 'ulog', 'alfa', 'ardupilot', 'csv'}
        ``auto``: an ALFA folder by its topics, a file by its suffix.

    Returns
    -------
    list of LogSource

    Raises
    ------
    FlightDataError
        One line naming the path: no such file, a format that cannot be told, a folder with
        no log, a log named twice, more than :data:`MAX_LOGS` logs, or two formats mixed (the
        control maps and ``--kind`` of one command apply to one format's fields).
    """
    found: list[LogSource] = []
    for text in paths:
        path = Path(text)
        if not path.exists():
            raise FlightDataError("no such file or folder", path)
        found += _folder_logs(path, fmt) if path.is_dir() else [
            LogSource(path, _file_format(path, fmt))]
    seen: dict[str, Path] = {}
    for source in found:
        real = os.path.realpath(source.path)
        if real in seen:
            raise FlightDataError(f"is named twice (also as {seen[real]}): each log is "
                                  "imported once", source.path)
        seen[real] = source.path
    if len(found) > MAX_LOGS:
        raise FlightDataError(f"{len(found)} logs, more than the {MAX_LOGS} one dataset takes",
                              Path(paths[0]))
    other = next((s for s in found if s.format != found[0].format), None)
    if other is not None:
        first = found[0]
        raise FlightDataError(
            f"is {FORMAT_NAMES[other.format]} but {first.path} is {FORMAT_NAMES[first.format]}: "
            "one import reads one format (its --control-map and --kind name that format's "
            "fields); import each format into its own dataset", other.path)
    return found


def unique_names(names: list[str]) -> list[str]:
    """``names`` made distinct by appending ``-2``, ``-3`` ... to a repeated one (segments
    are named ``<log>_sNN``, so two logs called ``flight`` must not share names)."""
    out: list[str] = []
    for name in names:
        candidate, k = name, 2
        while candidate in out:
            candidate, k = f"{name}-{k}", k + 1
        out.append(candidate)
    return out


def campaign_rate(rates: list[float], requested: float | None = None) -> CampaignRate:
    """The one grid rate of logs at ``rates``: ``requested`` if given, else their shared
    rate, else the lowest (resampling down is filtered; up would invent samples).

    Parameters
    ----------
    rates : list of float
        Each log's own grid rate (Hz).
    requested : float, optional
        A stated rate (``--rate``).

    Returns
    -------
    CampaignRate
    """
    listed = ", ".join(f"{r:.6g}" for r in dict.fromkeys(rates))
    if requested is not None:
        return CampaignRate(float(requested), f"{float(requested):g} Hz given (--rate; the "
                                              f"logs' own: {listed} Hz)")
    low = min(rates)
    if all(abs(r - low) <= RATE_MATCH * low for r in rates):
        own = "the log's own rate" if len(rates) == 1 else "the logs' own rate"
        return CampaignRate(low, f"{low:.6g} Hz, {own}")
    return CampaignRate(low, f"{low:.6g} Hz, the lowest of the logs' rates ({listed} Hz): the "
                             "faster logs low-pass filtered and resampled to it (--rate "
                             "chooses another)")


def on_one_rate(flights: list[FlightLog], rate_hz: float | None = None
                ) -> tuple[list[FlightLog], CampaignRate]:
    """The flights named apart (:func:`unique_names`) and on one grid rate
    (:func:`campaign_rate`), each resampled by :func:`resample_flight` where its rate differs.

    Parameters
    ----------
    flights : list of FlightLog
        The campaign's logs, in flight order.
    rate_hz : float, optional
        A stated rate.

    Returns
    -------
    flights : list of FlightLog
        Each with ``meta['own_rate_hz']`` (its rate as read).
    rate : CampaignRate

    Raises
    ------
    FlightDataError
        If the flights are not all of one airframe kind (the dataset has one).
    """
    if not flights:
        raise FlightDataError("no log to import")
    odd = next((f for f in flights if f.kind != flights[0].kind), None)
    if odd is not None:
        raise FlightDataError(f"is a {odd.kind} log but {flights[0].name} is a "
                              f"{flights[0].kind}: one dataset holds one airframe kind",
                              odd.meta.get("file", odd.name))
    rate = campaign_rate([1.0 / f.dt for f in flights], rate_hz)
    out = []
    for flight, name in zip(flights, unique_names([f.name for f in flights])):
        meta = {**flight.meta, "own_rate_hz": round(1.0 / flight.dt, 9)}
        named = dataclasses.replace(flight, name=name, meta=meta)
        out.append(resample_flight(named, rate.rate_hz))
    return out, rate
