"""Shared fixtures: the preset airframes and their trim points (built once per session)."""

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
