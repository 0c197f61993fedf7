"""Per-airframe control and rate limits (the optional ``[limits]`` table): a real airframe's own
actuator travel is respected by trim, the tracking MPC and ``uavdyn simulate``; absent, the
kind's defaults hold and the presets are unchanged."""

from __future__ import annotations

import json
import math
import re
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from uavdyn.airframes import CONTROL_RANGES, AirframeError, load_airframe, to_toml_dict
from uavdyn.cli import main
from uavdyn.integrate import body_model, physics_step
from uavdyn.linear.trim import TrimError, trim
from uavdyn.model import CONTROL_BOUNDS, CONTROL_NAMES
from uavdyn.mpc import MPCConfig, TrackingMPC
from uavdyn.mpc.tracking import DEFAULT_RATE_LIMITS

# Trim elevators of the preset (today's values): 20 m/s needs -0.269 rad, 25 m/s -0.124 rad.
PRESET_TRIMS = {("aerosonde", 20.0): (-0.26888587, 0.62939486),
                ("aerosonde", 25.0): (-0.12382981, 0.77350105)}


@pytest.fixture(scope="module")
def limited(tmp_path_factory) -> Path:
    """The Aerosonde preset as a user's TOML file with elevator travel +-0.14 rad."""
    text = resources.files("uavdyn.airframes").joinpath("aerosonde.toml").read_text()
    text, n = re.subn(r'(?m)^name = "aerosonde"$', 'name = "stiff_elevator"', text)
    assert n == 1
    text += "\n[limits]\nelevator = [-0.14, 0.14]  # rad\nelevator_rate = 2.0\n"
    path = tmp_path_factory.mktemp("limits") / "stiff_elevator.toml"
    path.write_text(text)
    return path


def test_file_with_limits_loads_and_round_trips(limited, tmp_path):
    af = load_airframe(limited)
    assert af.limits == {"elevator": (-0.14, 0.14), "elevator_rate": 2.0}
    assert af.control_bounds() == ((-0.14, 0.14), (0.0, 1.0))
    assert af.rate_limits() == (2.0, None)
    assert af.param_hash() == load_airframe("aerosonde").param_hash()  # not parameters of p
    data = to_toml_dict(af)
    assert data["limits"] == {"elevator": [-0.14, 0.14], "elevator_rate": 2.0}
    again = tmp_path / "again.json"
    again.write_text(json.dumps(data))
    assert load_airframe(again).limits == af.limits


def test_the_loader_knows_the_model_control_ranges():
    """The airframe loader's copy of the control table (it may not import the model) agrees."""
    for kind, table in CONTROL_RANGES.items():
        assert tuple(n for n, _ in table) == CONTROL_NAMES[kind]
        assert tuple(r for _, r in table) == CONTROL_BOUNDS[kind]


def test_presets_keep_the_kind_defaults():
    for name in ("aerosonde", "f450"):
        af = load_airframe(name)
        assert af.limits == {} and af.rate_limits() is None
        assert af.control_bounds() == CONTROL_BOUNDS[af.kind]
        assert "limits" not in to_toml_dict(af)
    for (name, speed), u in PRESET_TRIMS.items():
        np.testing.assert_allclose(trim(load_airframe(name), speed).u, u, atol=1e-7)
    np.testing.assert_allclose(trim(load_airframe("f450"), 0.0).u[1], 0.0, atol=1e-9)


def test_trim_respects_the_elevator_limit(limited):
    af = load_airframe(limited)
    with pytest.raises(TrimError) as info:
        trim(af, 20.0)
    msg = str(info.value)
    assert "limits.elevator" in msg and "[-0.14, 0.14]" in msg and "\n" not in msg
    point = trim(af, 25.0)  # inside the travel: same trim as the preset
    np.testing.assert_allclose(point.u, PRESET_TRIMS[("aerosonde", 25.0)], atol=1e-7)
    trim(load_airframe("aerosonde"), 20.0)  # the preset trims fine there


def _solve(mpc: TrackingMPC, point) -> np.ndarray:
    x0 = np.array([point.x[0], point.x[1], point.x[2] - 0.3, point.x[3] - 0.1, 100.0])
    result = mpc.solve(x0, point.u, point.x[3] + math.radians(10.0), 100.0, 25.0,
                       weights=(100.0, 0.0, 1.0))
    assert np.all(np.isfinite(result.predicted_controls))
    return result.predicted_controls


def test_mpc_never_commands_beyond_the_airframe_limit(limited):
    af = load_airframe(limited)
    point = trim(af, 25.0)
    step = physics_step(af)
    cfg = MPCConfig(horizon=20, dt=0.05)
    mpc = TrackingMPC(step, point.u, cfg)
    assert mpc.kind == "fixed_wing"
    np.testing.assert_allclose(mpc.bounds, [[-0.14, 0.14], [0.0, 1.0]])
    np.testing.assert_allclose(mpc.rates, [2.0, DEFAULT_RATE_LIMITS["fixed_wing"][1]])
    U = _solve(mpc, point)
    assert np.all(np.abs(U[0]) <= 0.14 + 1e-9)
    assert np.abs(U[0]).max() > 0.13  # the limit is active, not merely unreached
    # The same request on a model without the airframe (the kind's bounds) goes past 0.14 rad.
    free = TrackingMPC(body_model(step.function, af.kind), point.u, cfg, p=af.p)
    np.testing.assert_allclose(free.bounds, CONTROL_BOUNDS["fixed_wing"])
    assert np.abs(_solve(free, point)[0]).max() > 0.14


def test_simulate_refuses_an_amplitude_beyond_the_limit(limited, tmp_path, capsys):
    argv = ["simulate", "--airframe", str(limited), "--duration", "2", "--out",
            str(tmp_path / "out.csv")]
    assert main(argv + ["--amplitude", "0.2"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "limits.elevator" in err and "[-0.14, 0.14]" in err
    assert main(argv + ["--amplitude", "0.01"]) == 0


@pytest.mark.parametrize("limits, key, words", [
    ({"aileron": [-0.1, 0.1]}, "limits.aileron", "unknown key"),
    ({"elevator": [0.1, 0.1]}, "limits.elevator", "low < high"),
    ({"elevator": [0.2, -0.2]}, "limits.elevator", "low < high"),
    ({"elevator": [-0.6, 0.3]}, "limits.elevator", "wider than the physical range"),
    ({"throttle": [0.0, 1.5]}, "limits.throttle", "wider than the physical range"),
    ({"elevator": [float("nan"), 0.1]}, "limits.elevator", "finite"),
    ({"elevator": "+-0.14"}, "limits.elevator", "[low, high] pair"),
    ({"elevator": ["-0.14", 0.14]}, "limits.elevator", "numbers"),
    ({"elevator": [True, 0.14]}, "limits.elevator", "numbers"),
    ({"elevator": [-0.1, 0.0, 0.1]}, "limits.elevator", "[low, high] pair"),
    ({"elevator_rate": -1.0}, "limits.elevator_rate", "positive rate"),
    ({"elevator_rate": 0}, "limits.elevator_rate", "positive rate"),
    ({"elevator_rate": "fast"}, "limits.elevator_rate", "numbers"),
    ({"elevator_rate": float("inf")}, "limits.elevator_rate", "finite"),
    ({"collective": [0.0, 1.0]}, "limits.collective", "unknown key"),
    ([1, 2], "'limits'", "table"),
])
def test_malformed_limits_are_refused(tmp_path, limits, key, words):
    data = to_toml_dict(load_airframe("aerosonde"))
    data["limits"] = limits
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(AirframeError) as info:
        load_airframe(path)
    msg = str(info.value)
    assert str(path) in msg and key in msg and words in msg and "\n" not in msg


def test_multirotor_limits(tmp_path):
    data = to_toml_dict(load_airframe("f450"))
    data["limits"] = {"pitch_cmd": [-0.5, 0.5], "collective_rate": 3}
    path = tmp_path / "quad.json"
    path.write_text(json.dumps(data))
    af = load_airframe(path)
    assert af.control_bounds() == ((0.0, 1.0), (-0.5, 0.5))
    assert af.rate_limits() == (3.0, None)
