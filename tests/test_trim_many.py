"""Trims of many airframes at once (``trim_many``, ``stall_speeds``: a Monte-Carlo chunk's
dispersed airframes): every airframe gets bit for bit the point, or the error message, of its
own ``trim``; each point is an equilibrium of its own airframe's model; stall speeds scale with
the square root of the mass (the static lift coefficient does not depend on the mass)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from uavdyn.airframes import load_airframe
from uavdyn.linear import TrimError, TrimPoint, stall_speed, stall_speeds, trim, trim_many
from uavdyn.model import build_model

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _dispersed(airframe, n: int, seed: int) -> list:
    rng = np.random.default_rng(seed)
    names = ["mass", "Jy"] + (["C_L_alpha", "C_m_alpha", "C_m_delta_e"]
                              if airframe.kind == "fixed_wing" else ["c_T", "pitch_mix"])
    return [airframe.replace(**{name: float(getattr(airframe.params, name))
                                * (1 + rng.uniform(-0.3, 0.3)) for name in names})
            for _ in range(n)]


def test_trim_many_gives_each_airframe_its_own_trim_bit_for_bit():
    trainer = load_airframe(EXAMPLES / "trainer.toml")
    x500 = load_airframe(EXAMPLES / "x500.toml")
    airframes = _dispersed(trainer, 24, 1) + _dispersed(x500, 12, 2)  # two structures, mixed
    rng = np.random.default_rng(3)
    speeds = [None if j % 7 == 0 else float(rng.uniform(0.0, 35.0)) for j in range(36)]
    outcomes = trim_many(airframes, speeds)
    kinds = {"point": 0, "error": 0}
    for airframe, speed, outcome in zip(airframes, speeds, outcomes):
        try:
            own = trim(airframe, speed)
        except TrimError as exc:
            kinds["error"] += 1
            assert isinstance(outcome, TrimError) and str(outcome) == str(exc)
            continue
        kinds["point"] += 1
        assert isinstance(outcome, TrimPoint)
        np.testing.assert_array_equal(outcome.x, own.x)
        np.testing.assert_array_equal(outcome.u, own.u)
        assert outcome.residual == own.residual
        xdot = np.array(build_model(airframe).f(outcome.x, outcome.u, airframe.p)).ravel()
        assert np.abs(xdot).max() < 1e-9  # an equilibrium of its own airframe
    assert kinds["point"] >= 10 and kinds["error"] >= 5  # both outcomes exercised


def test_stall_speeds_equal_one_by_one_and_scale_with_the_root_of_the_mass():
    trainer = load_airframe(EXAMPLES / "trainer.toml")
    factors = [0.7, 1.0, 1.3, 2.0]
    heavier = [trainer.replace(mass=trainer.params.mass * k) for k in factors]
    together = stall_speeds(heavier)
    for airframe, row in zip(heavier, together):
        assert tuple(row) == stall_speed(airframe)
    base = together[1, 0]
    for k, row in zip(factors, together):
        assert row[0] == pytest.approx(base * math.sqrt(k), rel=1e-12)
        assert row[1] == together[1, 1]  # the lift curve's maximum does not move


def test_stall_speeds_and_trim_many_refuse_what_they_cannot_do(aerosonde, f450):
    with pytest.raises(ValueError, match="one structure"):
        stall_speeds([aerosonde, f450])
    with pytest.raises(ValueError, match="2 airspeeds for 1 airframes"):
        trim_many([aerosonde], [20.0, 25.0])
    assert stall_speeds([]).shape == (0, 3) and trim_many([], []) == []
    out = trim_many([aerosonde, f450], [float("nan"), 0.0])
    assert isinstance(out[0], TrimError) and "finite" in str(out[0])
    assert isinstance(out[1], TrimPoint)  # hover
