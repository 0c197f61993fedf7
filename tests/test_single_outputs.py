"""Single output files obey the output folders' rule (issue 42): a file uavdyn did not write is
never overwritten without ``--force`` (``simulate --out notes.toml`` used to overwrite a user's
file). uavdyn's own earlier output, unchanged since, may be replaced."""

import json
from pathlib import Path

import pytest

from uavdyn.cli import main

USER_TEXT = "# my notes, not a uavdyn output\nkeep = true\n"


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def _refused(err: str, path: Path) -> None:
    assert err.count("\n") == 1 and str(path) in err and "--force" in err, err
    assert "Traceback" not in err


def _simulate(out: Path, *extra: str) -> list[str]:
    return ["simulate", "--airframe", "aerosonde", "--input", "doublet", "--duration", "2",
            "--out", str(out), *extra]


def test_simulate_refuses_a_users_file_and_replaces_its_own(tmp_path, capsys):
    notes = tmp_path / "notes.toml"
    notes.write_text(USER_TEXT)
    code, _, err = _run(capsys, *_simulate(notes))
    assert code == 2 and notes.read_text() == USER_TEXT
    _refused(err, notes)
    own = tmp_path / "sim.csv"
    assert _run(capsys, *_simulate(own))[0] == 0
    assert _run(capsys, *_simulate(own, "--amplitude", "0.02"))[0] == 0  # its own: replaced
    own.write_text(own.read_text() + "\n")  # changed since uavdyn wrote it: the user's now
    code, _, err = _run(capsys, *_simulate(own))
    assert code == 2
    _refused(err, own)
    assert _run(capsys, *_simulate(notes, "--force"))[0] == 0
    assert notes.read_text().startswith("time,")


def _dataset(tmp_path: Path, capsys) -> Path:
    data = tmp_path / "data"
    data.mkdir()
    assert _run(capsys, *_simulate(data / "a.csv"))[0] == 0
    (data / "manifest.json").write_text(json.dumps({
        "airframe": "aerosonde", "kind": "fixed_wing", "sample_rate_hz": 100.0,
        "source": "test", "sorties": [{"file": "a.csv", "mission": "m", "duration_s": 2.0,
                                       "split": "train"}]}))
    return data


def test_identify_refuses_a_users_airframe_file(tmp_path, capsys):
    data = _dataset(tmp_path, capsys)
    mine = tmp_path / "mine.toml"  # a loadable airframe, but the user's own file
    mine.write_text((Path(__file__).resolve().parents[1] / "examples" / "trainer.toml")
                    .read_text())
    before = mine.read_text()
    code, _, err = _run(capsys, "identify", "--airframe", "aerosonde", "--dataset", str(data),
                        "--params", "C_m_q", "--out", str(mine), "--quiet")
    assert code == 2 and mine.read_text() == before
    _refused(err, mine)


def test_evaluate_and_fingerprint_refuse_a_users_file(tmp_path, capsys):
    data = _dataset(tmp_path, capsys)
    mine = tmp_path / "metrics.json"
    mine.write_text(json.dumps({"command": "evaluate", "mine": True}))
    code, _, err = _run(capsys, "evaluate", "--airframe", "aerosonde", "--dataset", str(data),
                        "--out", str(mine), "--all-sorties")
    assert code == 2 and json.loads(mine.read_text())["mine"]
    _refused(err, mine)
    finger = tmp_path / "finger.json"
    finger.write_text(USER_TEXT)
    code, _, err = _run(capsys, "generate-data", "--airframe", "aerosonde", "--sorties", "1",
                        "--duration", "2", "--out", str(tmp_path / "gen"),
                        "--write-fingerprint", str(finger), "--no-progress")
    assert code == 2 and finger.read_text() == USER_TEXT and not (tmp_path / "gen").exists()
    _refused(err, finger)


def test_train_refuses_a_users_weight_path(tmp_path, capsys):
    pytest.importorskip("torch")
    data = _dataset(tmp_path, capsys)
    mine = tmp_path / "w.npz"  # valid weights, but the user's copy: not this run's to replace
    shipped = Path(__file__).resolve().parents[1] / "uavdyn/learned/shipped/aerosonde_safe.npz"
    mine.write_bytes(shipped.read_bytes())
    code, _, err = _run(capsys, "train", "--airframe", "aerosonde", "--dataset", str(data),
                        "--out", str(mine), "--epochs", "1")
    assert code == 2 and mine.read_bytes() == shipped.read_bytes()
    _refused(err, mine)


def test_the_rule_itself(tmp_path):
    from uavdyn.outputs import OutputError, check_output_files, record_outputs

    empty, mine, own = tmp_path / "empty.png", tmp_path / "mine.png", tmp_path / "own.png"
    empty.write_bytes(b"")
    mine.write_bytes(b"\x89PNG user")
    own.write_bytes(b"\x89PNG uavdyn")
    check_output_files(empty, tmp_path / "new.png")   # empty or absent: nothing to lose
    with pytest.raises(OutputError, match="mine.png.*--force"):
        check_output_files(mine)
    check_output_files(mine, force=True)
    record_outputs(own, command="test")
    check_output_files(own)
    own.write_bytes(b"\x89PNG edited")
    with pytest.raises(OutputError, match="own.png"):
        check_output_files(own)
