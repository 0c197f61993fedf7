"""Every length, inertia and mass of an airframe file has a range by its meaning, per kind
(issue 42): a quadrotor arm of 1e-300 m used to load and trim (hover needs no pitch
authority)."""

import json
import warnings
from pathlib import Path

import pytest

from uavdyn.airframes import AirframeError, load_airframe, to_toml_dict

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _file(tmp_path: Path, preset: str, name: str, value: float) -> Path:
    data = to_toml_dict(load_airframe(preset))
    data["params"][name]["value"] = value
    path = tmp_path / "plane.json"
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize(("preset", "name", "value"), [
    ("f450", "arm", 1e-300), ("f450", "arm", 1e-4), ("f450", "arm", 50.0),
    ("f450", "mass", 1e-9), ("f450", "mass", 5e4), ("f450", "Jy", 1e-300),
    ("aerosonde", "mass", 1e-9), ("aerosonde", "Jy", 1e-300), ("aerosonde", "b", 1e-300),
    ("aerosonde", "c", 1e-300), ("aerosonde", "S_wing", 1e-300),
    ("aerosonde", "D_prop", 1e-300), ("aerosonde", "D_prop", 50.0),
])
def test_a_size_outside_its_kinds_range_is_refused_by_name(tmp_path, preset, name, value):
    path = _file(tmp_path, preset, name, value)
    with pytest.raises(AirframeError, match=rf"parameter '{name}' must be .*got {value!r}"):
        load_airframe(path)


@pytest.mark.parametrize("source", ["aerosonde", "f450", str(EXAMPLES / "trainer.toml"),
                                    str(EXAMPLES / "x500.toml"),
                                    str(EXAMPLES / "alfa_t28.toml")])
def test_presets_and_examples_still_load_without_a_warning(source):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_airframe(source, strict=True)


@pytest.mark.parametrize(("name", "value"), [("Jx", 1e-300), ("Jz", 1e-300)])
def test_a_given_lateral_inertia_has_the_same_floor(tmp_path, name, value):
    data = to_toml_dict(load_airframe("aerosonde"))
    data["params"][name] = {"value": value}
    path = tmp_path / "plane.json"
    path.write_text(json.dumps(data))
    with pytest.raises(AirframeError, match=rf"parameter '{name}' must be 0 \(not given\) or"):
        load_airframe(path)
    data["params"][name] = {"value": 0.0}  # 0: not given, as before
    path.write_text(json.dumps(data))
    load_airframe(path)
