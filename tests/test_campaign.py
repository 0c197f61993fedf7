"""A flight-test campaign in one ``import-log`` call (issue 41 items 1 and 6).

Synthetic six-degree-of-freedom flights (:mod:`tests.campaign_flights`: coordinated turns of
20-45 deg, climbs, wind, turbulence, noise) written as the generic CSV at 50 Hz and 20 Hz are
imported together; the segments are checked against the flights' known bank-angle crossings,
the split by log against the later flight's segments, the resampling against an analytic
signal; the refusals (mixed formats, a log named twice, an empty folder) are one line each
and leave nothing behind.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.campaign_flights import campaign_flight, write_campaign
from uavdyn.cli.app import main
from uavdyn.flightdata import FlightDataError, load_dataset
from uavdyn.flightdata.campaign import campaign_rate, find_logs, on_one_rate, unique_names
from uavdyn.flightdata.flightlog import FlightLog

MAX_ROLL = 10.0


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """Three 150 s flights: two at 50 Hz in a folder, the third (the later flight) at 20 Hz
    beside it."""
    root = tmp_path_factory.mktemp("campaign")
    flights = [campaign_flight(1, 150.0, 50.0), campaign_flight(2, 150.0, 50.0),
               campaign_flight(3, 150.0, 20.0)]
    paths = write_campaign(root / "day1", flights[:2])
    paths += write_campaign(root, flights[2:], stem="later")
    return root, flights, paths


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_one_call_imports_a_folder_and_a_file_at_mixed_rates_on_one_stated_rate(
        campaign, tmp_path, capsys):
    root, flights, paths = campaign
    out = tmp_path / "ds"
    code, text, err = _run(capsys, "import-log", str(root / "day1"), str(paths[2]),
                           "--kind", "fixed_wing", "--split-by", "log", "--out", str(out))
    assert code == 0, err
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["sample_rate_hz"] == 20.0
    assert "grid: 20 Hz, the lowest of the logs' rates (50, 20 Hz)" in text
    logs = manifest["logs"]
    assert [g["name"] for g in logs] == ["flight1_50hz", "flight2_50hz", "later1_20hz"]
    assert [g["own_rate_hz"] for g in logs] == [50.0, 50.0, 20.0]
    assert all(g["rate_hz"] == 20.0 and g["format"] == "six-degree-of-freedom CSV"
               for g in logs)
    assert [g["file"] for g in logs] == [str(p) for p in paths]
    assert "Butterworth" in logs[0]["resampling"] and "logged at 50 Hz" in text
    for g in logs:   # every segment named by its log, listed once under it
        mine = [e["file"] for e in manifest["sorties"] if e["log"] == g["name"]]
        assert mine == g["segments"] and all(f.startswith(g["name"] + "_s") for f in mine)
        assert {"roll", "p", "r", "v"} <= set(g["channels"])
    assert sum(len(g["segments"]) for g in logs) == len(manifest["sorties"])
    # the later flight (the last log) is the test set, exactly its segments
    ds = load_dataset(out)
    assert [s.name + ".csv" for s in ds.test] == logs[2]["segments"]
    assert {e["split"] for e in manifest["sorties"] if e["log"] == "flight1_50hz"} == {"train"}
    assert manifest["split_rule"]["by"] == "log"
    for name in ("flight1_50hz", "flight2_50hz", "later1_20hz"):
        assert (out / f"import_timeline_{name}.png").stat().st_size > 10_000


def test_segments_match_the_known_bank_crossings_of_every_flight(campaign, tmp_path, capsys):
    """Each kept segment lies inside a stretch where the true bank is <= 10 deg, its ends
    within one grid sample (plus the roll noise's 10 ms) of the analytic crossings, on the
    inside; every such stretch long enough is kept."""
    root, flights, paths = campaign
    out = tmp_path / "ds"
    code, _, err = _run(capsys, "import-log", *map(str, paths), "--kind", "fixed_wing",
                        "--out", str(out))
    assert code == 0, err
    manifest = json.loads((out / "manifest.json").read_text())
    sample, noise = 1 / manifest["sample_rate_hz"], 0.01
    for flight, log in zip(flights, manifest["logs"]):
        truth = flight.within_bank(MAX_ROLL)
        kept = [e["flight_time_s"] for e in manifest["sorties"] if e["log"] == log["name"]]
        assert len(kept) == len([iv for iv in truth if iv[1] - iv[0] >= 5.0])
        for (start, end), (lo, hi) in zip(kept, [iv for iv in truth if iv[1] - iv[0] >= 5.0]):
            assert lo - noise <= start <= lo + sample + noise
            assert hi - sample - noise <= end <= hi + noise
        level = sum(hi - lo for lo, hi in flight.level)
        inside = sum(max(0.0, min(b, d) - max(a, c)) for a, b in kept for c, d in flight.level)
        assert inside / level > 0.999    # every truly wings-level second is kept


def test_resampling_to_the_campaign_rate_keeps_the_analytic_signal():
    """A 0.4 Hz pitch oscillation logged at 50 Hz, put on a 20 Hz campaign grid, is the
    analytic signal at the 20 Hz times (the anti-alias filter passes it); the 20 Hz log is
    untouched."""
    def log(rate: float, name: str) -> FlightLog:
        t = np.arange(0, 60 + 1e-9, 1 / rate)
        theta = 0.1 * np.sin(2 * np.pi * 0.4 * t)
        channels = {c: np.zeros_like(t) for c in ("roll", "p", "r", "v")}
        channels.update(pitch=theta, q=np.gradient(theta, t), u=np.full_like(t, 15.0),
                        w=np.full_like(t, 1.0))
        return FlightLog(name, "fixed_wing", t, channels, np.tile([0.0, 0.5], (len(t), 1)),
                         "air", "test", meta={"file": name})

    fast, slow = log(50.0, "a"), log(20.0, "a")
    (a, b), rate = on_one_rate([fast, slow])
    assert rate.rate_hz == 20.0 and "lowest" in rate.reason
    assert b is not slow or b.dt == pytest.approx(0.05)
    assert [a.name, b.name] == ["a", "a-2"] and a.meta["own_rate_hz"] == 50.0
    inner = slice(20, -20)   # away from the filter's edge transients
    np.testing.assert_allclose(a.channels["pitch"][inner],
                               0.1 * np.sin(2 * np.pi * 0.4 * a.time)[inner], atol=2e-4)
    np.testing.assert_array_equal(b.channels["pitch"], slow.channels["pitch"])
    assert campaign_rate([50.0, 50.0]).reason == "50 Hz, the logs' own rate"
    assert campaign_rate([50.0, 20.0], 25.0).rate_hz == 25.0


def test_one_segment_log_imports_with_a_stated_split(tmp_path, capsys):
    """A short flight with a single wings-level stretch imports without --fractions: its one
    segment goes to train and the summary and manifest say why."""
    path = write_campaign(tmp_path, [campaign_flight(7, 18.0, 50.0)])[0]
    out = tmp_path / "one"
    code, text, err = _run(capsys, "import-log", str(path), "--kind", "fixed_wing",
                           "--out", str(out))
    assert code == 0, err
    manifest = json.loads((out / "manifest.json").read_text())
    assert [e["split"] for e in manifest["sorties"]] == ["train"]
    assert manifest["split_rule"]["fractions"] == [1.0, 0.0, 0.0]
    assert "1 sortie: train only" in manifest["split_rule"]["note"]
    assert "split: train 1" in text and "needs 3" in text
    assert (out / "import_timeline.png").exists()
    # the control map is printed as a sentence, not a Python dict
    maps = [line for line in text.splitlines() if "control map" in line]
    assert maps and all("{" not in line and "mapped linearly" in line for line in maps)


def test_two_logs_split_by_log_give_train_then_test(campaign, tmp_path, capsys):
    root, flights, paths = campaign
    out = tmp_path / "two"
    code, text, err = _run(capsys, "import-log", str(paths[1]), str(paths[0]), "--kind",
                           "fixed_wing", "--split-by", "log", "--out", str(out))
    assert code == 0, err
    manifest = json.loads((out / "manifest.json").read_text())
    parts = {e["log"]: e["split"] for e in manifest["sorties"]}
    assert parts == {"flight2_50hz": "train", "flight1_50hz": "test"}   # the order given
    assert "2 logs: train and test" in text
    code, _, err = _run(capsys, "import-log", str(paths[0]), str(paths[1]), "--kind",
                        "fixed_wing", "--split-by", "log", "--fractions", "0.7,0.15,0.15",
                        "--out", str(tmp_path / "refused"))
    assert code == 2 and "2 logs cannot fill" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "refused").exists()


def test_refusals_are_one_line_and_write_nothing(campaign, tmp_path, capsys):
    root, flights, paths = campaign
    ulog = tmp_path / "x.ulg"
    ulog.write_bytes(b"ULog")
    (tmp_path / "empty").mkdir()
    cases = [([str(paths[0]), str(ulog)], "is a PX4 ULog but"),
             ([str(paths[0]), str(paths[0])], "is named twice"),
             ([str(root / "day1"), str(paths[0])], "is named twice"),
             ([str(tmp_path / "empty")], "holds no log")]
    for logs, message in cases:
        out = tmp_path / "out"
        code, _, err = _run(capsys, "import-log", *logs, "--kind", "fixed_wing", "--out",
                            str(out))
        assert code == 2 and message in err, err
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
        assert not out.exists()


def test_find_logs_and_unique_names(campaign, tmp_path):
    root, flights, paths = campaign
    found = find_logs([root / "day1", paths[2]])
    assert [s.path for s in found] == paths and {s.format for s in found} == {"csv"}
    assert unique_names(["flight", "flight", "x", "flight"]) == ["flight", "flight-2", "x",
                                                                 "flight-3"]
    with pytest.raises(FlightDataError, match="cannot tell the format"):
        find_logs([tmp_path / "x.txt"] if (tmp_path / "x.txt").write_text("a") else [])
    other = FlightLog("m", "multirotor", np.arange(3.0), {c: np.zeros(3) for c in (
        "roll", "pitch", "p", "q", "r", "u", "v", "w")}, np.zeros((3, 2)), "ground", "t")
    fixed = FlightLog("f", "fixed_wing", np.arange(3.0), dict(other.channels),
                      np.zeros((3, 2)), "ground", "t")
    with pytest.raises(FlightDataError, match="one dataset holds one airframe kind"):
        on_one_rate([fixed, other])


def test_a_log_without_a_segment_is_recorded_with_its_reason_not_dropped(campaign, tmp_path,
                                                                         capsys):
    """A 4 s log (shorter than the 5 s minimum segment) in a campaign: the others import, the
    manifest lists it with no segment and why, the summary says so; a campaign with no usable
    log at all is refused in one line and writes nothing."""
    root, flights, paths = campaign
    short = write_campaign(tmp_path / "short", [campaign_flight(9, 4.0, 50.0)], stem="short")[0]
    out = tmp_path / "ds"
    code, text, err = _run(capsys, "import-log", str(paths[0]), str(short), "--kind",
                           "fixed_wing", "--out", str(out))
    assert code == 0, err
    manifest = json.loads((out / "manifest.json").read_text())
    record = manifest["logs"][1]
    assert record["name"] == "short1_50hz" and record["segments"] == [] and record["kept_s"] == 0
    assert "no longitudinal segment of at least 5 s" in record["no_segment"]
    assert "short1_50hz: no segment kept: no longitudinal segment" in text
    assert {e["log"] for e in manifest["sorties"]} == {"flight1_50hz"}
    assert not (out / "import_timeline_short1_50hz.png").exists()
    other = write_campaign(tmp_path / "other", [campaign_flight(10, 4.0, 50.0)])[0]
    code, _, err = _run(capsys, "import-log", str(short), str(other), "--kind", "fixed_wing",
                        "--out", str(tmp_path / "none"))
    assert code == 2 and "none of the 2 logs has a usable segment" in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "none").exists()
