"""Missions from the airframe: the example airframes load cleanly, the missions fly inside the
airframe's own envelope and [limits] with the file's actuator lags (recorded in the manifest),
a mission the airframe cannot fly is left out with one line, and the presets' derived numbers
are their design values (so the shipped datasets do not change)."""

import dataclasses
import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest

from uavdyn.airframes import load_airframe
from uavdyn.emulation import (
    REFERENCE_NAMES,
    MissionUnflyable,
    envelope,
    missions_for,
    plan_mission,
    unflyable_missions,
)
from uavdyn.emulation.datagen import Recipe, flyable_recipe, generate_dataset
from uavdyn.linear import stall_speed, trim

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
REF = {name: i for i, name in enumerate(REFERENCE_NAMES)}


@pytest.fixture(scope="module")
def trainer():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no plausibility warning
        return load_airframe(EXAMPLES / "trainer.toml", strict=True)


@pytest.fixture(scope="module")
def x500():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return load_airframe(EXAMPLES / "x500.toml", strict=True)


def test_example_airframes_trim_and_have_their_modes(trainer, x500):
    from uavdyn.linear import linearise, modes

    point = trim(trainer)
    assert point.airspeed == 14.0
    found = modes(linearise(trainer, point)[0], trainer.kind)
    assert all(m.stable for m in found)
    assert {"short period", "phugoid"} <= {m.name for m in found}
    hover = trim(x500)
    assert 0.5 < hover.u[0] < 0.8  # hover collective of a thrust-to-weight ~2 quadrotor
    assert all(m.eigenvalue.real <= 1e-9 for m in modes(linearise(x500, hover)[0], x500.kind))
    for af in (trainer, x500):
        assert all(af.sources.get(n) for n in af.param_names)  # a source for every number


def test_trainer_envelope_comes_from_stall_and_thrust(trainer):
    env = envelope(trainer)
    lo, hi = env.speed_range
    assert lo == pytest.approx(1.3 * stall_speed(trainer)[0])
    trim(trainer, hi)  # the fastest speed trims, half a metre per second more does not
    with pytest.raises(ValueError, match="throttle"):
        trim(trainer, hi + 0.5)
    assert env.cruise == 14.0 and env.climb_rate > 3.0
    assert env.bounds[0] == (-0.35, 0.35) and env.rates == (5.0, None)


@pytest.mark.parametrize("mission", missions_for("fixed_wing"))
def test_trainer_plans_stay_in_its_envelope_and_travel(trainer, mission):
    """Reference speeds inside the trainer's envelope, feed-forward elevator inside its
    [limits] (before the autopilot's own saturation), for several draws."""
    lo, hi = envelope(trainer).speed_range
    for seed in range(3):
        plan = plan_mission(mission, trainer, 40.0, 100.0, np.random.default_rng(seed))
        speed = plan.references[:, REF["speed_ref"]]
        assert lo - 1e-9 <= speed.min() and speed.max() <= hi + 1e-9, mission
        ff = plan.references[:, REF["ff0"]]
        assert -0.35 - 1e-9 <= ff.min() and ff.max() <= 0.35 + 1e-9, mission


def test_presets_derive_their_design_values(aerosonde, f450):
    """The presets' envelopes give back every design number exactly: the shipped recipes'
    plans (and so their datasets) are those of the reference fingerprints."""
    env = envelope(aerosonde)
    assert env.cruise == 25.0 and env.elevator_scale == 1.0 and env.speed_scale == 1.0
    for v in (19.0, 20.0, 23.0, 24.0, 25.0, 28.0, 30.0):
        assert env.design_speed(v) == v
    assert env.climb_rate * 8.0 > 30.0 and not any(env.limited)
    quad = envelope(f450)
    for v in (-0.5, 0.5, 3.0, 4.0, 6.0, 12.0):
        assert quad.design_speed(v) == v
    assert quad.climb_rate * 2.0 > 5.0 and not any(quad.limited)


def test_unflyable_missions_are_named_with_why(trainer, x500):
    # a sortie too short for a stall cycle
    assert list(unflyable_missions(trainer, missions_for("fixed_wing"), 10.0, 100.0)) == \
        ["high_alpha"]
    # a quadrotor so draggy it cannot trim at 2 m/s within 0.5 rad of pitch
    draggy = x500.replace(drag_linear=8.0)
    assert envelope(draggy).speed_range[1] < 2.0
    why = unflyable_missions(draggy, missions_for("multirotor"), 20.0, 100.0)
    assert sorted(why) == ["survey", "sysid_3211", "sysid_chirp", "sysid_doublet"]
    assert "forward legs need a level trim at 2 m/s" in why["survey"]
    with pytest.raises(MissionUnflyable, match="mission 'survey' cannot be flown"):
        plan_mission("survey", draggy, 20.0, 100.0, np.random.default_rng(0))
    # a trainer whose throttle cannot hold level flight 30 % above the stall speed
    weak = dataclasses.replace(trainer, limits={**trainer.limits, "throttle": (0.0, 0.46)})
    assert "no level trim between 1.3 x the stall speed" in envelope(weak).problem
    assert list(unflyable_missions(weak, ["loiter"], 20.0, 100.0)) == ["loiter"]


def test_recipe_without_a_flyable_mission_is_refused_and_one_line_per_skip(trainer, x500):
    draggy = x500.replace(drag_linear=8.0)
    recipe = Recipe(airframe="x500", sorties=4, duration_s=20.0,
                    missions=["survey", "loiter", "sysid_chirp"])
    with pytest.warns(UserWarning) as caught:
        kept, skipped = flyable_recipe(recipe, draggy)
    assert kept.missions == ["loiter"] and sorted(skipped) == ["survey", "sysid_chirp"]
    lines = [str(w.message) for w in caught]
    assert len(lines) == 2 and all("\n" not in line for line in lines)
    assert "mission 'survey' cannot be flown" in lines[0] and "skipped" in lines[0]
    with pytest.raises(ValueError, match="can fly none of the missions survey, sysid_chirp"):
        flyable_recipe(Recipe(airframe="x500", missions=["survey", "sysid_chirp"]), draggy)
    unchanged, none = flyable_recipe(Recipe(airframe="trainer", duration_s=20.0), trainer)
    assert unchanged.missions == [] and none == {}


@pytest.mark.slow
def test_trainer_dataset_inside_its_envelope_limits_and_lags(tmp_path):
    """A small calm dataset of the example trainer: airspeeds inside its envelope, the logged
    elevator inside its [limits] and rate, the file's lags in the manifest; the stall mission
    (which needs 16 s) left out with one warning line."""
    out = tmp_path / "trainer"
    recipe = Recipe(airframe=str(EXAMPLES / "trainer.toml"), sorties=6, duration_s=6.0,
                    turbulent_fraction=0.0,
                    split={"train": 1.0, "validation": 0.0, "test": 0.0})
    with pytest.warns(UserWarning, match="mission 'high_alpha' needs a duration of at least "
                                         "16 s; skipped"):
        generate_dataset(recipe, out, workers=1, progress=False)
    manifest = json.loads((out / "manifest.json").read_text())
    truth = manifest["truth"]
    assert truth["tau_elevator"] == 0.03 and truth["tau_throttle"] == 0.1
    assert truth["rate_elevator"] == 5.0
    assert truth["sources"]["tau_elevator"] == "airframe file"
    assert truth["sources"]["tau_alpha"] == "emulator default"
    assert truth["command_bounds"]["elevator"] == [-0.35, 0.35]
    assert list(truth["missions_skipped"]) == ["high_alpha"]
    lo, hi = truth["speed_range_mps"]
    assert {e["mission"] for e in manifest["sorties"]} == set(missions_for("fixed_wing")) - \
        {"high_alpha"}
    for entry in manifest["sorties"]:
        data = np.loadtxt(out / entry["true_file"], delimiter=",", skiprows=1)
        airspeed = np.hypot(data[:, 1], data[:, 2])
        assert lo <= airspeed.min() and airspeed.max() <= hi, entry["mission"]
        elevator = data[:, 5]
        assert -0.35 <= elevator.min() and elevator.max() <= 0.35
        assert np.abs(np.diff(elevator)).max() <= 5.0 * 0.01 + 1e-12
    assert math.isclose(manifest["sorties"][0]["duration_s"], 6.0)


@pytest.mark.slow
def test_cli_skips_an_unflyable_mission_in_one_line_and_writes_the_rest(tmp_path, x500,
                                                                         capsys):
    from uavdyn.airframes import to_toml_dict
    from uavdyn.cli.app import main

    draggy = to_toml_dict(x500.replace(drag_linear=8.0))
    path = tmp_path / "draggy.json"
    path.write_text(json.dumps(draggy))
    args = ["generate-data", "--airframe", str(path), "--sorties", "2", "--duration", "3",
            "--workers", "1", "--no-progress", "--missions"]
    assert main(args + ["survey,loiter", "--out", str(tmp_path / "ds")]) == 0
    err = capsys.readouterr().err.splitlines()
    named = [line for line in err if "survey" in line]
    assert len(named) == 1 and "cannot be flown" in named[0] and "skipped" in named[0]
    manifest = json.loads((tmp_path / "ds" / "manifest.json").read_text())
    assert {e["mission"] for e in manifest["sorties"]} == {"loiter"}
    assert "survey" in manifest["truth"]["missions_skipped"]
    assert main(args + ["survey,sysid_chirp", "--out", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "can fly none of the missions survey, sysid_chirp" in err[0]
    assert not (tmp_path / "none").exists()
