"""Airframe files: presets load with a source for every number; bad files fail with the key."""

import json
import math

import numpy as np
import pytest

from uavdyn.airframes import (
    AirframeError,
    list_presets,
    load_airframe,
    param_names,
    perturb,
    to_toml_dict,
)


@pytest.mark.parametrize("name", ["aerosonde", "f450"])
def test_presets_load_with_sources(name):
    af = load_airframe(name)
    assert af.p.shape == (len(param_names(af.kind)),)
    assert np.all(np.isfinite(af.p))
    missing = [k for k in af.param_names if not af.sources.get(k, "").strip()]
    assert missing == [], f"parameters without a cited source: {missing}"


def test_aliases_and_listing():
    assert list_presets() == ["aerosonde", "f450"]
    assert load_airframe("quadrotor").name == "f450"
    assert load_airframe("fixed_wing").name == "aerosonde"


def _write(tmp_path, data, name="plane.json"):
    path = tmp_path / name
    path.write_text(json.dumps(data))
    return path


def test_user_file_round_trip(tmp_path, aerosonde):
    data = to_toml_dict(aerosonde)
    data["name"] = "my_plane"
    data["params"]["mass"]["value"] = 12.5
    af = load_airframe(_write(tmp_path, data))
    assert af.name == "my_plane" and af.params.mass == 12.5
    assert af.param_hash() != aerosonde.param_hash()


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda d: d["params"].update(wingspan={"value": 1.0}),
         "unknown parameter key(s) ['wingspan']"),
        (lambda d: d["params"].pop("Jy"), "missing parameter key(s) ['Jy']"),
        (lambda d: d["params"]["mass"].update(value=0.0),
         "parameter 'mass' must be >= 0.001, got 0.0"),
        (lambda d: d["params"]["Jy"].update(value=-1.0),
         "parameter 'Jy' must be >= 1e-09, got -1.0"),
        (lambda d: d["params"]["S_wing"].update(value=0), "parameter 'S_wing' must be >= 0.0001"),
        (lambda d: d["params"]["C_m_q"].update(value=float("nan")),
         "parameter 'C_m_q' is not finite"),
        (lambda d: d["params"]["c"].update(value="0.2"), "parameter 'c' must be a number"),
        (lambda d: d.update(kind="helicopter"), "key 'kind' is 'helicopter'"),
        (lambda d: d.pop("kind"), "missing top-level key 'kind'"),
        (lambda d: d.update(colour="red"), "unknown top-level key(s) ['colour']"),
    ],
)
def test_bad_parameter_files_name_the_key(tmp_path, aerosonde, mutate, message):
    data = to_toml_dict(aerosonde)
    mutate(data)
    path = tmp_path / "bad.json"
    # json.dumps writes NaN as a bare token, which Python's json reads back as nan
    path.write_text(json.dumps(data))
    with pytest.raises(AirframeError) as err:
        load_airframe(path)
    assert message in str(err.value)
    assert str(path) in str(err.value)


def test_toml_nan_and_parse_errors(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text('name = "x"\nkind = "multirotor"\n[params\n')
    with pytest.raises(AirframeError, match="cannot parse parameter file"):
        load_airframe(path)


def test_unknown_airframe_name():
    with pytest.raises(AirframeError, match="neither a preset"):
        load_airframe("no_such_plane")


def test_perturb_scales_only_chosen_keys(aerosonde):
    pert = perturb(aerosonde, 1.15)
    changed = {n for n, a, b in zip(aerosonde.param_names, aerosonde.p, pert.p) if a != b}
    assert changed == {"mass", "Jy", "C_L_alpha", "C_L_q", "C_L_delta_e", "C_m_alpha", "C_m_q",
                       "C_m_delta_e"}
    assert math.isclose(pert.params.mass, 1.15 * aerosonde.params.mass)
    assert math.isclose(pert.params.C_m_alpha, 1.15 * aerosonde.params.C_m_alpha)
    only = perturb(aerosonde, 0.5, names=["S_wing"])
    assert only.params.S_wing == 0.5 * aerosonde.params.S_wing
    with pytest.raises(AirframeError, match="unknown parameter"):
        perturb(aerosonde, 1.1, names=["wingspan"])
    with pytest.raises(AirframeError, match="'mass' must be >= 0.001"):
        perturb(aerosonde, -1.0, names=["mass"])


SLIPS = [  # (preset, parameter, value as a unit slip would write it, parameter named)
    ("aerosonde", "mass", 13500.0, "mass"),            # grams
    ("aerosonde", "Jy", 1e-6, "Jy"),   # inside its range (1e-300 is refused outright)
    ("aerosonde", "Jy", 1.135e4, "Jy"),                # kg cm^2
    ("aerosonde", "C_m_alpha", -2.74 / 57.3, "C_m_alpha"),   # per degree
    ("aerosonde", "C_m_delta_e", -0.99 / 57.3, "C_m_delta_e"),
    ("aerosonde", "C_L_alpha", 5.61 / 57.3, "C_L_alpha"),
    ("f450", "mass", 1400.0, "Jy"),                    # grams: the inertia radius collapses
    ("f450", "Jy", 1e-8, "Jy"),
    ("f450", "arm", 0.005, "arm"),     # mm written as m, say; 1e-300 is refused outright
    ("f450", "pitch_mix", 0.0, "pitch_mix"),
]


@pytest.mark.parametrize("preset, key, value, named", SLIPS)
def test_implausible_values_warn_naming_the_parameter_and_refuse_when_strict(
        tmp_path, preset, key, value, named):
    """Values inside their bounds but impossible together (a mass in grams, a derivative per
    degree, an inertia of 1e-300) used to load silently; the failure came later from trim
    without naming the parameter."""
    import warnings

    from uavdyn.airframes import AirframeError, AirframePlausibilityWarning, load_airframe

    data = to_toml_dict(load_airframe(preset))
    data["params"][key]["value"] = value
    path = _write(tmp_path, data)
    with pytest.warns(AirframePlausibilityWarning) as caught:
        load_airframe(path)
    assert any(f"parameter '{named}'" in str(w.message) for w in caught), caught
    with pytest.raises(AirframeError, match=f"parameter '{named}'.*--strict"):
        load_airframe(path, strict=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for name in ("aerosonde", "f450"):  # the presets are plausible
            load_airframe(name, strict=True)


def test_no_pitch_authority_is_refused_where_pitch_must_be_controlled(tmp_path):
    import warnings

    from uavdyn.airframes import load_airframe
    from uavdyn.linear import TrimError, trim

    data = to_toml_dict(load_airframe("f450"))
    data["params"]["pitch_mix"]["value"] = 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        af = load_airframe(_write(tmp_path, data))
    with pytest.raises(TrimError, match="'pitch_mix' = 0"):
        trim(af, 5.0)
