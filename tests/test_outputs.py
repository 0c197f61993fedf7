"""Nothing half-written, divergence never silent: output folders and files are renamed into
place only when complete; a foreign folder is refused without --force and keeps its own files
with it; an interrupted generate-data or train leaves the earlier output intact; simulate checks
its inputs; the legacy F450 hybrid from hover stays bounded or raises with the time."""

import json
import os
from pathlib import Path

import pytest
from interrupting import interrupt_when, uavdyn_child
from test_correction import random_net

from uavdyn.airframes import load_airframe
from uavdyn.cli import main
from uavdyn.emulation import Recipe, generate_dataset
from uavdyn.emulation.fingerprint import compare_fingerprints, dataset_fingerprint
from uavdyn.flightdata import load_dataset
from uavdyn.learned import save_weights
from uavdyn.outputs import (
    MARKER,
    REGISTRY,
    OutputError,
    atomic_file,
    output_folder,
    record_outputs,
)


def test_atomic_file_keeps_the_old_file_until_the_new_one_is_complete(tmp_path):
    target = tmp_path / "a.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError), atomic_file(target) as tmp:
        tmp.write_text("half")
        assert target.read_text() == "old"
        raise RuntimeError("interrupted")
    assert target.read_text() == "old" and os.listdir(tmp_path) == ["a.txt"]
    with atomic_file(target) as tmp:
        tmp.write_text("new")
    assert target.read_text() == "new" and os.listdir(tmp_path) == ["a.txt"]


def test_output_folder_refuses_foreign_replaces_own_and_force_keeps_user_files(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "mine.txt").write_text("user data")
    with pytest.raises(OutputError, match="not a uavdyn output.*--force"):
        with output_folder(out, "export-c"):
            pass
    with output_folder(out, "export-c", force=True) as tmp:
        (tmp / "a.c").write_text("1")
        (tmp / "b.c").write_text("1")
    assert (out / "mine.txt").read_text() == "user data" and (out / "a.c").exists()
    # a second forced run of the same command removes its stale file b.c, never mine.txt
    with output_folder(out, "export-c", force=True) as tmp:
        (tmp / "a.c").write_text("2")
    assert sorted(os.listdir(out)) == [MARKER, "a.c", "mine.txt"]
    # a folder holding only an earlier output of the same command is replaced whole
    own = tmp_path / "own"
    with output_folder(own, "reproduce") as tmp:
        (tmp / "x.json").write_text("1")
    with output_folder(own, "reproduce") as tmp:
        (tmp / "y.json").write_text("2")
    assert sorted(os.listdir(own)) == [MARKER, "y.json"]
    with pytest.raises(OutputError, match="output of 'uavdyn reproduce'"):
        with output_folder(own, "generate-data"):
            pass
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".")]  # no temp left over


@pytest.mark.slow
def test_interrupted_generate_data_leaves_the_old_dataset_unchanged(tmp_path):
    out = tmp_path / "data"
    generate_dataset(Recipe(airframe="quadrotor", sorties=6, duration_s=4.0, seed=0,
                            split={"train": 1.0, "validation": 0.0, "test": 0.0}), out,
                     workers=1, progress=False)
    before = dataset_fingerprint(out)
    proc = uavdyn_child(["generate-data", "--airframe", "quadrotor", "--sorties", "60",
                         "--duration", "20", "--seed", "1", "--workers", "1", "--no-progress",
                         "--out", str(out)])

    def some_sorties_written(_stderr: str) -> bool:
        partial = [p for p in tmp_path.iterdir() if p.name.startswith(".data.partial")]
        return bool(partial) and len(list(partial[0].glob("*.csv"))) >= 4

    _, err = interrupt_when(proc, some_sorties_written)
    assert proc.returncode == 130 and "interrupted" in err.strip().splitlines()[-1], err[-500:]
    after = compare_fingerprints(dataset_fingerprint(out), before)
    assert after.matches(0.0), after.describe()
    assert len(load_dataset(out).sorties) == 6
    assert [p.name for p in tmp_path.iterdir()] == ["data"]  # the partial folder is gone


@pytest.mark.slow
def test_interrupted_train_keeps_the_old_weights_and_history(tmp_path, aerosonde):
    pytest.importorskip("torch")
    weights = save_weights(random_net(aerosonde), tmp_path / "w.npz")
    history = tmp_path / "w_history.json"
    history.write_text(json.dumps({"history": [{"epoch": 0}]}))
    old_w, old_h = weights.read_bytes(), history.read_text()
    record_outputs(weights, history, command="train")  # an earlier run's: may be replaced
    data = tmp_path / "data"
    generate_dataset(Recipe(airframe="aerosonde", sorties=6, duration_s=10.0, seed=0,
                            missions=["sysid_doublet", "sysid_3211", "sysid_chirp"],
                            split={"train": 0.5, "validation": 0.5, "test": 0.0}),
                     data, workers=1, progress=False)
    # patience as long as the epochs: the compiled trainer would otherwise stop early, and the
    # interrupt could land after the new outputs were committed (all three new: also correct)
    proc = uavdyn_child(["train", "--airframe", "aerosonde", "--dataset", str(data),
                         "--epochs", "500", "--patience", "500", "--max-seconds", "120",
                         "--out", str(weights)])
    # Ctrl-C once a few epochs ran (their progress lines on stderr: tqdm writes the rate as
    # "epoch/s", or as "s/epoch" once an epoch takes longer than a second on a loaded machine)
    _, err = interrupt_when(
        proc, lambda stderr: stderr.count("epoch/s") + stderr.count("s/epoch") >= 3)
    assert proc.returncode == 130 and "interrupted" in err.strip().splitlines()[-1], err[-500:]
    assert weights.read_bytes() == old_w and history.read_text() == old_h
    assert sorted(p.name for p in tmp_path.iterdir()) == [REGISTRY, "data", "w.npz",
                                                           "w_history.json"]


def test_train_refuses_to_overwrite_a_file_that_is_not_its_output(tmp_path, capsys):
    pytest.importorskip("torch")
    victim = tmp_path / "notes.npz"
    victim.write_text("my notes")
    assert main(["train", "--airframe", "aerosonde", "--epochs", "1", "--out",
                 str(victim)]) == 2
    assert "was not written by uavdyn" in capsys.readouterr().err
    assert victim.read_text() == "my notes"


def test_simulate_checks_amplitude_duration_and_folders(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    for argv, message in (
            (["--amplitude", "2"], "outside its limits"),
            (["--duration", "1e7"], "rows, more than"),
            (["--out", "/nonexistent_uavdyn_dir/x.csv"], "will not create folder"),
            (["--dt", "nan"], "argument --dt: must be a finite number")):
        assert main(["simulate", "--airframe", "aerosonde", *argv]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], err
    assert not Path("/nonexistent_uavdyn_dir").exists()
    assert main(["simulate", "--airframe", "aerosonde", "--out", "sub/x.csv"]) == 0
    assert (tmp_path / "sub" / "x.csv").exists()


def test_evaluate_checks_its_output_before_the_work(tmp_path, monkeypatch, capsys):
    """An output that could not be written is refused when the command line is parsed, before
    the dataset is even read (its manifest here is broken: the output's error must come
    first), and nothing is created; an output that is a folder is refused too."""
    monkeypatch.chdir(tmp_path)
    broken = tmp_path / "broken_dataset"
    broken.mkdir()
    (broken / "manifest.json").write_text("{}")
    for out, message in (("/nonexistent_uavdyn_dir/e.json", "will not create folder"),
                         (str(tmp_path), "is a folder, not a file")):
        assert main(["evaluate", "--airframe", "aerosonde", "--dataset", str(broken),
                     "--out", out]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "argument --out" in err[0] and message in err[0], err
    assert not Path("/nonexistent_uavdyn_dir").exists()
    assert main(["evaluate", "--airframe", "aerosonde", "--dataset", str(broken),
                 "--out", "sub/e.json"]) == 2
    assert "broken_dataset" in capsys.readouterr().err
    assert not (tmp_path / "sub").exists()


def test_an_interrupt_during_a_forced_commit_never_leaves_a_mix(tmp_path, monkeypatch):
    """--force into a folder that is not a uavdyn output used to move the new files in one by
    one: an interrupt between two moves left new sorties beside the old manifest, a mixed
    dataset that loads as valid. Now the new folder (with the user's own files) is swapped in
    whole: interrupted at every rename in turn, the folder is all old or all new, and the
    user's files are kept."""
    import uavdyn.outputs as outputs

    def build(folder, tag):
        with output_folder(folder, "generate-data", force=True) as tmp:
            for name in ("manifest.json", "s1.csv", "s2.csv"):
                (tmp / name).write_text(tag)

    real_replace = os.replace
    outcomes = set()
    for n in range(1, 12):
        folder = tmp_path / f"run{n}"
        folder.mkdir()
        for name in ("manifest.json", "s1.csv", "s2.csv", "notes.txt"):  # a foreign folder
            (folder / name).write_text("old" if name != "notes.txt" else "mine")
        calls = {"n": 0}

        def flaky(src, dst, calls=calls, n=n):
            calls["n"] += 1
            if calls["n"] == n:
                raise KeyboardInterrupt
            return real_replace(src, dst)

        monkeypatch.setattr(outputs.os, "replace", flaky)
        try:
            build(folder, "new")
            outcomes.add("completed")
        except KeyboardInterrupt:
            outcomes.add("interrupted")
        monkeypatch.setattr(outputs.os, "replace", real_replace)
        contents = {p.read_text() for p in folder.iterdir()
                    if p.name in ("manifest.json", "s1.csv", "s2.csv")}
        assert contents in ({"old"}, {"new"}), (n, contents)
        assert (folder / "notes.txt").read_text() == "mine"
        if contents == {"new"}:
            assert (folder / MARKER).exists()
    assert outcomes == {"completed", "interrupted"}


def _flaky_replace(monkeypatch, n: int) -> None:
    """``os.replace`` raising KeyboardInterrupt at its ``n``-th call (every module's: one os)."""
    real = os.replace
    calls = {"n": 0}

    def flaky(src, dst):
        calls["n"] += 1
        if calls["n"] == n:
            raise KeyboardInterrupt
        return real(src, dst)

    monkeypatch.setattr(os, "replace", flaky)


def test_atomic_files_put_a_set_in_place_all_or_none(tmp_path, monkeypatch):
    """Interrupted at every rename in turn, the three files are all old or all new (one of
    them new where there was none before), and no temporary file is left."""
    from uavdyn.outputs import atomic_files

    outcomes = set()
    for n in range(1, 10):
        folder = tmp_path / f"run{n}"
        folder.mkdir()
        paths = [folder / "w.npz", folder / "w_history.json", folder / "w_history.png"]
        for p in paths[:2]:
            p.write_text("old")
        _flaky_replace(monkeypatch, n)
        try:
            with atomic_files(*paths) as tmps:
                for t in tmps:
                    t.write_text("new")
            outcomes.add("completed")
        except KeyboardInterrupt:
            outcomes.add("interrupted")
        monkeypatch.undo()
        found = [p.read_text() if p.exists() else None for p in paths]
        assert found in (["old", "old", None], ["new"] * 3), (n, found)
        assert sorted(os.listdir(folder)) == sorted(p.name for p in paths if p.exists())
    assert outcomes == {"completed", "interrupted"}
    with pytest.raises(OutputError, match="same file"):
        with atomic_files(tmp_path / "a", tmp_path / "." / "a"):
            pass


@pytest.mark.slow  # eleven (fake) training runs
def test_an_interrupted_train_commit_leaves_the_old_pair_or_the_new_pair(tmp_path, monkeypatch,
                                                                        capsys):
    """train wrote the weights and the loss history as separate renames: an interrupt between
    them left new weights beside the old history. Now the weights, history JSON and PNG are
    one output: interrupted at every rename in turn (os.replace raising KeyboardInterrupt at
    its n-th call, the trainer replaced by one that returns at once), the three files are the
    old set or the new set, and the history's network is the weights' own."""
    pytest.importorskip("torch")
    from test_cli_options import _fake_trainer, steady_dataset

    from uavdyn.learned import load_weights

    _fake_trainer(monkeypatch)
    data = steady_dataset(tmp_path / "data")
    real_replace = os.replace
    monkeypatch.chdir(tmp_path)
    outcomes = set()
    for n in range(1, 12):
        folder = tmp_path / f"run{n}"
        folder.mkdir()
        old_net = random_net(load_airframe("aerosonde"), "paper", seed=7)
        weights = save_weights(old_net, folder / "w.npz")
        history, png = folder / "w_history.json", folder / "w_history.png"
        history.write_text(json.dumps({"history": [{"epoch": 0}], "network": old_net.describe(),
                                       "tag": "old"}))
        png.write_bytes(b"old png")
        old = (weights.read_bytes(), history.read_text(), png.read_bytes())
        _flaky_replace(monkeypatch, n)
        code = main(["train", "--airframe", "aerosonde", "--dataset", str(data), "--formulation",
                     "paper", "--epochs", "1", "--quiet", "--out", str(weights),
                     "--force"])  # hand-made old files: not an earlier run's
        monkeypatch.setattr(os, "replace", real_replace)
        outcomes.add({0: "completed", 130: "interrupted"}[code])
        now = (weights.read_bytes(), history.read_text(), png.read_bytes())
        if now != old:  # all three new, and they belong together
            assert all(a != b for a, b in zip(now, old)), (n, "a mix of old and new files")
            assert json.loads(now[1])["network"] == load_weights(weights).describe()
            assert now[2].startswith(b"\x89PNG")
        assert sorted(set(os.listdir(folder)) - {REGISTRY}) == [
            "w.npz", "w_history.json", "w_history.png"], n
    capsys.readouterr()
    assert outcomes == {"completed", "interrupted"}
