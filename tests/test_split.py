"""Train/validation/test split by whole sortie (uavdyn.flightdata.split, uavdyn split)."""

from __future__ import annotations

import json
import os
from collections import Counter

import numpy as np
import pytest

from uavdyn.cli.app import main
from uavdyn.flightdata import FlightDataError, Sortie, load_dataset, write_csv, write_manifest
from uavdyn.flightdata.split import SplitError, assign_split, split_dataset


def entries(n: int, durations=None, starts=None) -> list[dict]:
    out = []
    for i in range(n):
        e = {"file": f"s{i:02d}.csv", "mission": "doublet",
             "duration_s": 3.0 if durations is None else durations[i]}
        if starts is not None:
            e["source_start_s"] = starts[i]
        out.append(e)
    return out


def make_dataset(folder, n: int = 6, duration: float = 3.0, starts=None):
    """A tiny valid fixed-wing dataset: steady level sorties at 10 Hz."""
    t = np.round(np.arange(0.0, duration + 1e-9, 0.1), 10)
    rows = len(t)
    sorties = []
    for i in range(n):
        name = f"seg{i:02d}"
        s = Sortie(name, "fixed_wing", t, np.tile([20.0, 1.0, 0.0, 0.05], (rows, 1)),
                   np.tile([0.0, 0.5], (rows, 1)))
        write_csv(s, folder / f"{name}.csv")
        entry = {"file": f"{name}.csv", "mission": "level", "duration_s": float(t[-1])}
        if starts is not None:
            entry["source_start_s"] = starts[i]
        sorties.append(entry)
    write_manifest(folder, "aerosonde", "fixed_wing", 10.0, "test", sorties)
    return folder


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


# ------------------------------------------------------------------------ by sortie

@pytest.mark.parametrize("n, expected", [(10, (7, 2, 1)), (20, (14, 3, 3)), (3, (1, 1, 1)),
                                         (7, (5, 1, 1)), (100, (70, 15, 15))])
def test_by_sortie_counts(n, expected):
    names = assign_split(entries(n), seed=3)
    counts = Counter(names)
    assert (counts["train"], counts["validation"], counts["test"]) == expected
    assert len(names) == n and set(names) <= {"train", "validation", "test"}


def test_by_sortie_deterministic_per_seed_and_seeds_differ():
    e = entries(20)
    assert assign_split(e, seed=5) == assign_split(e, seed=5)
    splits = {tuple(assign_split(e, seed=s)) for s in range(6)}
    assert len(splits) > 1
    assert all(Counter(s) == Counter(assign_split(e, seed=0)) for s in splits)


def test_every_sortie_assigned_exactly_once(tmp_path):
    make_dataset(tmp_path, n=9)
    parts = split_dataset(tmp_path, seed=11)
    files = [f for names in parts.values() for f in names]
    assert sorted(files) == sorted(f"seg{i:02d}.csv" for i in range(9))
    assert len(files) == len(set(files)) == 9


def test_zero_fraction_leaves_part_empty():
    names = assign_split(entries(5), fractions=(0.8, 0.2, 0.0))
    assert Counter(names) == Counter(train=4, validation=1)
    names = assign_split(entries(2), fractions=(0.5, 0.0, 0.5))
    assert Counter(names) == Counter(train=1, test=1)
    assert assign_split(entries(1), fractions=(1, 0, 0)) == ["train"]


def test_too_few_sorties_refused_naming_the_empty_part():
    with pytest.raises(SplitError) as info:
        assign_split(entries(2))
    msg = str(info.value)
    assert "'test' would be empty" in msg and "\n" not in msg
    assert msg.startswith("2 sorties cannot fill train 0.7, validation 0.15, test 0.15")
    assert "--fractions with 0 for test" in msg
    with pytest.raises(SplitError, match="'validation' and 'test' would be empty"):
        assign_split(entries(1))
    with pytest.raises(SplitError, match="'test' would be empty"):
        assign_split(entries(1), by="time-block", fractions=(0.5, 0, 0.5))
    with pytest.raises(SplitError, match="0 sorties"):
        assign_split([])
    assert isinstance(SplitError("x"), FlightDataError)


@pytest.mark.parametrize("fractions", [(0.7, 0.2, 0.2), (0.5, 0.5), (1.2, -0.1, -0.1),
                                       (float("nan"), 0.5, 0.5), ("a", 0.5, 0.5)])
def test_bad_fractions_refused(fractions):
    with pytest.raises(SplitError, match="fractions"):
        assign_split(entries(5), fractions=fractions)


def test_bad_rule_and_seed_refused():
    with pytest.raises(SplitError, match="rule"):
        assign_split(entries(5), by="sample")
    with pytest.raises(SplitError, match="seed"):
        assign_split(entries(5), seed=-1)


# ------------------------------------------------------------------------ time block

def test_time_block_follows_source_start_order():
    starts = [30.0, 0.0, 50.0, 10.0, 20.0, 40.0, 60.0, 70.0, 80.0, 90.0]
    names = assign_split(entries(10, starts=starts), by="time-block")
    by_time = [names[i] for i in np.argsort(starts)]
    assert by_time == ["train"] * 7 + ["validation"] * 2 + ["test"]
    # seed plays no part in a time-block split
    assert assign_split(entries(10, starts=starts), by="time-block", seed=9) == names


def test_time_block_manifest_order_without_source_start():
    names = assign_split(entries(4), by="time-block", fractions=(0.5, 0.25, 0.25))
    assert names == ["train", "train", "validation", "test"]


def test_time_block_cuts_at_cumulative_duration():
    # durations 40, 30, 10, 12, 8 (total 100): train ends nearest 70 s, validation nearest 85
    durations = [40.0, 30.0, 10.0, 12.0, 8.0]
    names = assign_split(entries(5, durations), by="time-block")
    assert names == ["train", "train", "validation", "test", "test"]
    # a tie (80 or 90 s for 85) goes to the earlier part, as largest-remainder rounding does
    names = assign_split(entries(5, [40.0, 30.0, 10.0, 10.0, 10.0]), by="time-block")
    assert names == ["train", "train", "validation", "validation", "test"]
    # one long first sortie still leaves validation and test a sortie each
    names = assign_split(entries(3, [100.0, 5.0, 5.0]), by="time-block")
    assert names == ["train", "validation", "test"]
    names = assign_split(entries(4, [10.0, 10.0, 10.0, 70.0]), by="time-block",
                         fractions=(0.3, 0.0, 0.7))
    assert names == ["train", "train", "train", "test"]


def test_time_block_refuses_partial_source_start():
    e = entries(4, starts=[0.0, 10.0, 20.0, 30.0])
    del e[2]["source_start_s"]
    with pytest.raises(SplitError, match=r"sorties\[2\]"):
        assign_split(e, by="time-block")


# ------------------------------------------------------------------------ dataset folder

def test_split_dataset_writes_manifest_and_load_dataset_agrees(tmp_path):
    make_dataset(tmp_path, n=6, starts=[25.0 - 5.0 * i for i in range(6)])  # last flown first
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.suffix == ".csv"}
    parts = split_dataset(tmp_path, by="time-block", fractions=(0.5, 0.25, 0.25))
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["split_rule"] == {"by": "time-block", "fractions": [0.5, 0.25, 0.25],
                                      "seed": 0}
    assert manifest["sorties"][5]["source_start_s"] == 0.0  # extra keys kept
    ds = load_dataset(tmp_path)
    for name in ("train", "validation", "test"):
        assert [f"{s.name}.csv" for s in ds.split(name)] == parts[name]
    assert parts == {"train": ["seg03.csv", "seg04.csv", "seg05.csv"],
                     "validation": ["seg01.csv", "seg02.csv"], "test": ["seg00.csv"]}
    after = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.suffix == ".csv"}
    assert after == before
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([*before, "manifest.json"])


def test_failed_rename_leaves_old_manifest_intact(tmp_path, monkeypatch):
    make_dataset(tmp_path, n=5)
    old = (tmp_path / "manifest.json").read_bytes()

    def broken(src, dst):
        raise OSError("disk went away")

    monkeypatch.setattr(os, "replace", broken)
    with pytest.raises(OSError, match="disk went away"):
        split_dataset(tmp_path)
    monkeypatch.undo()
    assert (tmp_path / "manifest.json").read_bytes() == old
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["manifest.json"] + [f"seg{i:02d}.csv" for i in range(5)])


def test_refused_split_leaves_manifest_untouched(tmp_path):
    make_dataset(tmp_path, n=2)
    old = (tmp_path / "manifest.json").read_bytes()
    with pytest.raises(SplitError, match="'test' would be empty"):
        split_dataset(tmp_path)
    assert (tmp_path / "manifest.json").read_bytes() == old


# ------------------------------------------------------------------------ by mission

def flights(missions: int, per_mission: int) -> list[dict]:
    """Entries cycling through ``missions`` missions, conditions alternating per mission."""
    out = []
    for i in range(missions * per_mission):
        out.append({"file": f"s{i:02d}.csv", "mission": f"m{i % missions}",
                    "condition": "calm" if (i // missions) % 2 else "turbulent",
                    "duration_s": 30.0})
    return out


@pytest.mark.parametrize("missions, per_mission", [(7, 3), (7, 4), (3, 5), (1, 10)])
def test_by_mission_counts_equal_by_sortie(missions, per_mission):
    e = flights(missions, per_mission)
    for seed in range(5):
        assert Counter(assign_split(e, "mission", seed=seed)) == Counter(assign_split(e))


def test_by_mission_spreads_each_mission_over_the_parts():
    # 7 missions x 3 sorties at 0.7/0.15/0.15: 15/3/3. Each mission keeps two sorties in
    # train and its third goes to validation or test (or train, once): no part holds two
    # sorties of one mission outside train. A random split does (checked over seeds).
    e = flights(7, 3)
    random_doubles = 0
    for seed in range(20):
        parts = assign_split(e, "mission", seed=seed)
        for name in ("validation", "test"):
            missions = [x["mission"] for x, p in zip(e, parts) if p == name]
            assert len(missions) == len(set(missions)) == 3
        train = Counter(x["mission"] for x, p in zip(e, parts) if p == "train")
        assert set(train) == {f"m{i}" for i in range(7)} and min(train.values()) >= 2
        plain = assign_split(e, "sortie", seed=seed)
        random_doubles += any(len(m) != len(set(m)) for m in (
            [x["mission"] for x, p in zip(e, plain) if p == name]
            for name in ("validation", "test")))
    assert random_doubles > 0


def test_by_mission_gives_each_part_both_conditions_where_it_can():
    # 2 missions x 10 sorties, half calm: 14/3/3; every part gets both conditions in most
    # seeds, and train always does.
    e = flights(2, 10)
    both = 0
    for seed in range(20):
        parts = assign_split(e, "mission", seed=seed)
        conditions = {name: {x["condition"] for x, p in zip(e, parts) if p == name}
                      for name in ("train", "validation", "test")}
        assert conditions["train"] == {"calm", "turbulent"}
        both += conditions["validation"] == conditions["test"] == {"calm", "turbulent"}
    assert both >= 10
    # 7 missions x 3 (two turbulent, one calm each): one sortie per mission leaves train,
    # and a swap within a mission gives validation and test both conditions in every seed,
    # mission shares and counts unchanged
    e = flights(7, 3)
    for seed in range(20):
        parts = assign_split(e, "mission", seed=seed)
        for name in ("validation", "test"):
            assert {x["condition"] for x, p in zip(e, parts) if p == name} == {
                "calm", "turbulent"}, (seed, name)
            missions = [x["mission"] for x, p in zip(e, parts) if p == name]
            assert len(set(missions)) == 3
        assert Counter(parts) == Counter(assign_split(e))


def test_by_mission_deterministic_per_seed_and_without_labels_still_splits():
    e = flights(7, 3)
    assert assign_split(e, "mission", seed=4) == assign_split(e, "mission", seed=4)
    assert len({tuple(assign_split(e, "mission", seed=s)) for s in range(6)}) > 1
    bare = [{k: v for k, v in x.items() if k not in ("mission", "condition")} for x in e]
    assert Counter(assign_split(bare, "mission", seed=2)) == Counter(assign_split(bare))


# ------------------------------------------------------------------------ CLI

def test_cli_end_to_end(tmp_path, capsys):
    folder = make_dataset(tmp_path / "data", n=6)
    assert main(["split", str(folder), "--fractions", "0.5,0.25,0.25", "--seed", "4"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[:3] == ["train: 3 sorties, 9.0 s", "validation: 2 sorties, 6.0 s",
                       "test: 1 sortie, 3.0 s"]
    assert out[3].startswith("wrote ") and "manifest.json" in out[3]
    ds = load_dataset(folder)
    expected = split_dataset(tmp_path / "data", fractions=(0.5, 0.25, 0.25), seed=4)
    assert {name: [f"{s.name}.csv" for s in ds.split(name)]
            for name in ("train", "validation", "test")} == expected
    assert len(ds.train) == 3 and len(ds.validation) == 2 and len(ds.test) == 1
    assert main(["split", str(folder), "--by", "time-block"]) == 0
    assert [s.name for s in load_dataset(folder).test] == ["seg05"]
    assert main(["split", str(folder), "--by", "mission", "--seed", "1"]) == 0
    assert "split by mission, seed 1" in capsys.readouterr().out
    assert json.loads((folder / "manifest.json").read_text())["split_rule"]["by"] == "mission"


def test_cli_too_few_sorties_one_line(tmp_path, capsys):
    folder = make_dataset(tmp_path / "data", n=2)
    assert main(["split", str(folder), "--fractions", "0.7,0.15,0.15"]) == 2
    line = one_line_error(capsys)
    assert line.startswith("uavdyn split: error:") and "'test' would be empty" in line


@pytest.mark.parametrize("n, expected", [(1, ["train"]), (2, ["train", "test"])])
def test_cli_default_fractions_for_one_or_two_sorties_are_stated_not_refused(
        tmp_path, capsys, n, expected):
    """Without --fractions, 1 sortie goes to train and 2 to train and test (time-block: the
    later one held out); the manifest and the printed line say why."""
    folder = make_dataset(tmp_path / "data", n=n, starts=[10.0 * (n - i) for i in range(n)])
    assert main(["split", str(folder), "--by", "time-block"]) == 0
    out = capsys.readouterr().out
    manifest = json.loads((folder / "manifest.json").read_text())
    by_start = sorted(manifest["sorties"], key=lambda e: e["source_start_s"])
    assert [e["split"] for e in by_start] == expected
    assert "needs 3" in manifest["split_rule"]["note"] and "needs 3" in out
    assert main(["split", str(folder), "--fractions", "0.7,0.15,0.15"]) == 2


@pytest.mark.parametrize("extra, option", [
    (["--fractions", "0.5,0.5,0.5"], "--fractions"),
    (["--fractions", "0.5,0.5"], "--fractions"),
    (["--fractions", "1.2,-0.1,-0.1"], "--fractions"),
    (["--fractions", "a,b,c"], "--fractions"),
    (["--seed", "-1"], "--seed"),
    (["--seed", "1.5"], "--seed"),
    (["--by", "sample"], "--by"),
])
def test_cli_bad_options_refused(tmp_path, capsys, extra, option):
    folder = make_dataset(tmp_path / "data", n=4)
    old = (folder / "manifest.json").read_bytes()
    assert main(["split", str(folder), *extra]) == 2
    line = one_line_error(capsys)
    assert option in line
    assert (folder / "manifest.json").read_bytes() == old


def test_cli_dataset_must_be_a_folder_with_manifest(tmp_path, capsys):
    assert main(["split", str(tmp_path / "nowhere")]) == 2
    assert "DATASET" in one_line_error(capsys)
    assert main(["split", str(tmp_path)]) == 2
    assert "manifest.json" in one_line_error(capsys)


def test_split_options_helpers():
    import argparse

    from uavdyn.cli.split_command import add_split_options, split_options_from

    parser = argparse.ArgumentParser()
    add_split_options(parser)
    args = parser.parse_args([])
    assert (args.split_by, args.fractions, args.seed) == (None, None, None)
    assert split_options_from(args) == {"by": "sortie", "fractions": None, "seed": 0}
    args = parser.parse_args(["--split-by", "time-block", "--fractions", "0.6,0.4,0",
                              "--seed", "2"])
    assert split_options_from(args) == {"by": "time-block", "fractions": (0.6, 0.4, 0.0),
                                        "seed": 2}
    assert assign_split(entries(5), **split_options_from(args)).count("test") == 0
