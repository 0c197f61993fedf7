"""Shared fixtures: the preset airframes and their trim points (built once per session).

The real-log tests (``test_ulog.py``) read the trimmed real logs shipped in
``tests/data/reallogs`` (``tests/reallogs.py``), so every clone collects and runs them; the
importers are also tested on synthetic logs with known content (``test_ulog_synthetic.py``)."""

import pytest

from uavdyn.airframes import load_airframe
from uavdyn.linear import trim


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
