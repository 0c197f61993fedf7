"""The trimmed real flight logs shipped with the tests (``tests/data/reallogs``).

They are trimmed copies of public logs (PX4/pyulog samples, an ALFA fixed-wing sequence), with
the sources, licences and what was removed in ``tests/data/reallogs/README.md``; they import
to the same arrays as the originals. ``make_trimmed.py`` there regenerates them.
"""

from __future__ import annotations

from pathlib import Path

REAL_LOGS: Path = Path(__file__).resolve().parent / "data" / "reallogs"
ALFA_SEQUENCE = "alfa_carbonZ_2018-07-18-15-53-31_1_engine_failure"
ULOG_NAMES = ("px4_sitl_hover.ulg", "px4_vtol_ground_run.ulg")


def alfa_folder() -> Path:
    """The shipped ALFA sequence folder (10 MAVROS topic CSVs, every row, fewer columns)."""
    return REAL_LOGS / ALFA_SEQUENCE


def ulog(name: str) -> Path:
    """The shipped trimmed PX4 ULog ``name`` (one of :data:`ULOG_NAMES`)."""
    if name not in ULOG_NAMES:
        raise ValueError(f"no shipped ULog {name!r}; shipped: {', '.join(ULOG_NAMES)}")
    return REAL_LOGS / name


def ulogs() -> list[Path]:
    """All shipped trimmed PX4 ULogs."""
    return [ulog(n) for n in ULOG_NAMES]
