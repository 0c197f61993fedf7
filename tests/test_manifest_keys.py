"""Manifest keys (issue 42): a typo in a key ('spilt' for 'split', 'altitude' for 'altitude_m')
used to load without a word, and an altitude of 1e9 m was accepted. Every key a uavdyn
command writes must still load."""

import json
from pathlib import Path

import pytest

from uavdyn.flightdata import FlightDataError, read_manifest


def _manifest(tmp_path: Path, entry: dict | None = None, **top) -> Path:
    (tmp_path / "a.csv").write_text("time,u,w,q,theta,elevator,throttle\n")
    sortie = {"file": "a.csv", "mission": "m", "duration_s": 1.0, **(entry or {})}
    path = tmp_path / "manifest.json"
    path.write_text(json.dumps({"airframe": "aerosonde", "kind": "fixed_wing",
                                "sample_rate_hz": 100.0, "source": "test",
                                "sorties": [sortie], **top}))
    return path


@pytest.mark.parametrize(("entry", "top", "message"), [
    ({"spilt": "test"}, {}, r"sorties\[0\]: unknown key 'spilt'; did you mean 'split'\?"),
    ({"altitude": 100.0}, {}, r"sorties\[0\]: unknown key 'altitude'; did you mean "
                              r"'altitude_m'\?"),
    ({}, {"sample_rate": 100}, r"unknown key 'sample_rate'; did you mean 'sample_rate_hz'\?"),
    ({}, {"zzz": 1}, r"unknown key 'zzz'; known keys: airframe, kind"),
    ({"altitude_m": 1e9}, {}, r"sorties\[0\]\.altitude_m: 1000000000\.0 m is outside "
                              r"-500\.\.20000 m"),
    ({"altitude_m": -1e6}, {}, r"sorties\[0\]\.altitude_m: -1000000\.0 m is outside"),
])
def test_unknown_keys_and_impossible_altitudes_are_refused(tmp_path, entry, top, message):
    path = _manifest(tmp_path, entry, **top)
    with pytest.raises(FlightDataError, match=message) as caught:
        read_manifest(path)
    assert "\n" not in str(caught.value) and str(path) in str(caught.value)


def test_every_key_uavdyn_writes_is_known(tmp_path):
    from uavdyn.flightdata.log_dataset import ENTRY_KEYS
    from uavdyn.flightdata.manifest import SORTIE_KEYS

    assert set(ENTRY_KEYS) <= set(SORTIE_KEYS)
    read_manifest(_manifest(tmp_path, {"altitude_m": 1500.0, "split": "train"},
                            logs=[], split_rule={}, lowpass_hz=5.0))
