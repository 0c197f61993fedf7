"""Shared fixtures: the preset airframes and their trim points (built once per session).

The real-log tests (``test_ulog.py``) read the trimmed real logs shipped in
``tests/data/reallogs`` (``tests/reallogs.py``), so every clone collects and runs them; the
importers are also tested on synthetic logs with known content (``test_ulog_synthetic.py``)."""

import os

import pytest

from uavdyn.airframes import load_airframe
from uavdyn.linear import trim

# A machine running one test process per CPU can take longer than the default 30 s for a large
# compile; the library would then fall back to CasADi's virtual machine for the rest of that
# process (its designed behaviour, tested with its own limit in test_codegen_cache.py), and the
# tests after it would no longer exercise compiled code.
os.environ.setdefault("UAVDYN_CC_TIMEOUT", "600")


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
