"""Shared fixtures: the preset airframes and their trim points (built once per session).

The real-log tests (``test_ulog.py``) read ``../shared/data/flightlogs``, which only the
development machines have: they are collected only where it exists, so a fresh clone runs every
collected test and skips none for a missing file. The importers are tested everywhere on
synthetic logs with known content (``test_ulog_synthetic.py``)."""

from pathlib import Path

import pytest

from uavdyn.airframes import load_airframe
from uavdyn.linear import trim

REAL_LOGS = Path(__file__).resolve().parents[2] / "shared" / "data" / "flightlogs"
collect_ignore = [] if REAL_LOGS.is_dir() else ["test_ulog.py"]


@pytest.fixture(scope="session")
def aerosonde():
    return load_airframe("aerosonde")


@pytest.fixture(scope="session")
def f450():
    return load_airframe("f450")


@pytest.fixture(scope="session")
def aerosonde_trim(aerosonde):
    return trim(aerosonde, 25.0)


@pytest.fixture(scope="session")
def f450_hover(f450):
    return trim(f450, 0.0)
