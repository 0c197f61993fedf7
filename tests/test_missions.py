"""Mission profiles: every mission flies on every airframe kind it applies to, the high-alpha
profile really stalls the fixed wing, plans are seeded, misuse is refused."""

import math

import numpy as np
import pytest

from uavdyn.emulation import (
    MISSIONS,
    REFERENCE_NAMES,
    Emulator,
    MissionError,
    missions_for,
    plan_mission,
)
from uavdyn.flightdata import check_values

CASES = [(af, m) for af, kind in (("aerosonde", "fixed_wing"), ("f450", "multirotor"))
         for m in missions_for(kind)]


def test_at_least_six_missions_cover_the_required_kinds():
    assert len(MISSIONS) >= 6
    for required in ("survey", "inspection", "loiter", "aggressive", "sysid_doublet",
                     "sysid_3211", "sysid_chirp", "high_alpha"):
        assert required in MISSIONS
    assert "high_alpha" in missions_for("fixed_wing")
    assert "inspection" in missions_for("multirotor")


@pytest.mark.parametrize("airframe_name, mission", CASES)
def test_every_mission_flies(airframe_name, mission, request):
    """30 s of each mission with sensor noise: finite, physically plausible, consistent logs
    (the loader's checks, kinematics included), and the aircraft actually moves."""
    af = request.getfixturevalue(airframe_name)
    rng = np.random.default_rng(11)
    plan = plan_mission(mission, af, 30.0, 100.0, rng)
    assert plan.references.shape == (3001, len(REFERENCE_NAMES))
    em = Emulator(af)
    fl = em.fly(em.initial_state(plan.x0, plan.u0, plan.altitude), plan.references, rng=rng)
    assert np.all(np.isfinite(fl.true_states)) and np.all(np.isfinite(fl.controls))
    check_values(f"{airframe_name}-{mission}", af.kind, fl.time, fl.measured_states,
                 fl.controls, 100.0)
    assert np.ptp(fl.true_states[:, 3]) > math.radians(0.5)
    assert fl.aux["h"].min() > 0  # never flies into the ground


def test_high_alpha_reaches_past_20_degrees(aerosonde):
    em = Emulator(aerosonde)
    peaks = []
    for seed in range(4):
        plan = plan_mission("high_alpha", aerosonde, 30.0, 100.0, np.random.default_rng(seed))
        fl = em.fly(em.initial_state(plan.x0, plan.u0, plan.altitude), plan.references,
                    noise_scale=0.0)
        peaks.append(math.degrees(fl.alpha_air.max()))
        # the separation state leaves attached flow (~1e-9) for partly separated flow
        assert fl.aux["emulator_states"][:, 9].max() > 1e-3
    print(f"\nhigh_alpha peak air-relative alpha per seed (deg): "
          f"{', '.join(f'{p:.1f}' for p in peaks)}")
    assert min(peaks) > 20.0


def test_plans_are_seeded(f450):
    a = plan_mission("survey", f450, 60.0, 100.0, np.random.default_rng(3))
    b = plan_mission("survey", f450, 60.0, 100.0, np.random.default_rng(3))
    c = plan_mission("survey", f450, 60.0, 100.0, np.random.default_rng(4))
    np.testing.assert_array_equal(a.references, b.references)
    assert a.params == b.params
    assert not np.array_equal(a.references, c.references)


def test_inspection_hovers_and_moves(f450):
    plan = plan_mission("inspection", f450, 60.0, 100.0, np.random.default_rng(0))
    speed = plan.references[:, REFERENCE_NAMES.index("speed_ref")]
    assert np.mean(speed == 0.0) > 0.2
    assert np.abs(speed).max() >= 0.5


def test_sysid_signals_are_in_the_references(aerosonde):
    for name in ("sysid_doublet", "sysid_3211", "sysid_chirp"):
        plan = plan_mission(name, aerosonde, 60.0, 100.0, np.random.default_rng(1))
        assert plan.params["signal"] == name.split("_")[1]
        ff = plan.references[:, :2]
        assert np.ptp(ff[:, 0]) > math.radians(1) or np.ptp(ff[:, 1]) > 0.05


def test_mission_misuse_is_refused(aerosonde, f450):
    with pytest.raises(MissionError, match="does not apply to multirotor"):
        plan_mission("high_alpha", f450, 30.0, 100.0, np.random.default_rng(0))
    with pytest.raises(MissionError, match="does not apply to fixed_wing"):
        plan_mission("inspection", aerosonde, 30.0, 100.0, np.random.default_rng(0))
    with pytest.raises(MissionError, match="unknown mission 'barrel_roll'"):
        plan_mission("barrel_roll", aerosonde, 30.0, 100.0, np.random.default_rng(0))
    with pytest.raises(MissionError, match="at least 16 s"):
        plan_mission("high_alpha", aerosonde, 10.0, 100.0, np.random.default_rng(0))
