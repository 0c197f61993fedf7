"""Every option value is checked when the command line is parsed, and refused in one line naming
the option and its allowed range (exit code 2, nothing written, no work done); relations
between options, and between an option and the data, are refused right after parsing naming
both. An airframe of another kind than the dataset's is refused by every command that takes
both (train, identify, evaluate), in one line naming both kinds.

The whole list (every option of every command, each invalid value) is the probe
``analysis/probe_cli_options.py`` and its table ``docs/benchmarks/cli_option_probe.md``; these
tests keep a representative subset."""

import math
import re
from pathlib import Path

import numpy as np
import pytest

from uavdyn.airframes import load_airframe
from uavdyn.cli import main
from uavdyn.flightdata import Sortie, write_csv, write_manifest
from uavdyn.linear import trim


def steady_dataset(folder: Path, airframe: str = "aerosonde", seconds: float = 2.0,
                   rate: float = 50.0) -> Path:
    """Two sorties of steady trimmed flight (train and validation): a valid dataset of the
    airframe's kind, written without the emulator."""
    af = load_airframe(airframe)
    point = trim(af)
    t = np.arange(int(round(seconds * rate)) + 1) / rate
    Path(folder).mkdir(parents=True, exist_ok=True)
    entries = []
    for i, split in enumerate(("train", "validation")):
        name = f"steady_{i}.csv"
        write_csv(Sortie(name=f"steady_{i}", kind=af.kind, time=t,
                         states=np.tile(point.x, (len(t), 1)),
                         controls=np.tile(point.u, (len(t), 1)), mission="steady"),
                  Path(folder) / name)
        entries.append({"file": name, "mission": "steady", "duration_s": float(t[-1]),
                        "split": split})
    write_manifest(folder, airframe=af.name, kind=af.kind, sample_rate_hz=rate,
                   source="steady trimmed flight (test)", sorties=entries)
    return Path(folder)


def one_line_error(capsys, command: str) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(f"uavdyn {command}: error: "), err
    return err[0]


def names(line: str, option: str) -> bool:
    return re.search(rf"(?<![\w-]){re.escape(option)}(?![\w-])", line) is not None


# option values refused when parsed: (argv, the option, what the message states)
BAD_VALUES = [
    (["trim", "--airspeed", "1e308"], "--airspeed", "0 <= airspeed <= 100 m/s"),
    (["trim", "--gamma-deg", "90"], "--gamma-deg", "-90 < gamma < 90 deg"),
    (["trim", "--airframe", "no_such_preset"], "--airframe", "neither a preset"),
    (["modes", "--hybrid", "--weights", "."], "--weights", "is a folder"),
    (["simulate", "--dt", "nan"], "--dt", "1e-06 <= dt <= 1 s"),
    (["simulate", "--duration", "0"], "--duration", "duration > 0 s"),
    (["simulate", "--amplitude", "inf"], "--amplitude", "a finite number"),
    (["simulate", "--channel", "2"], "--channel", "invalid choice"),
    (["generate-data", "--out", "x", "--sorties", "0"], "--sorties", "1 <= sorties <= 100000"),
    (["generate-data", "--out", "x", "--turbulent-fraction", "1.5"], "--turbulent-fraction",
     "0 <= fraction <= 1"),
    (["generate-data", "--out", "x", "--workers", "100000"], "--workers",
     "1 <= workers <= 64"),
    (["generate-data", "--out", "x", "--rate", "0"], "--rate", "0 < rate <= 1000 Hz"),
    (["generate-data", "--out", "x", "--missions", "nope"], "--missions", "unknown mission"),
    (["export-c", "--rollout", "-1"], "--rollout", "0 <= steps <= 50000"),
    (["export-c", "--rollout", "1000000"], "--rollout", "0 <= steps <= 50000"),
    (["export-c", "--name", "int"], "--name", "C identifier"),
    (["import-log", "missing.ulg", "--out", "x"], "log", "no file or folder"),
    (["identify", "--dataset", "missing", "--params", "C_m_q", "--out", "a.toml"], "--dataset",
     "no dataset"),
    (["identify", "--dataset", "{DS}", "--params", "C_m_q,C_m_q", "--out", "a.toml"],
     "--params", "twice"),
    (["identify", "--dataset", "{DS}", "--params", "C_m_q", "--out", "a.toml", "--max-delay",
      "0"], "--max-delay", "1 <= samples <= 50"),
    (["reproduce", "--cost-repeats", "0"], "--cost-repeats", "1 <= repeats <= 1000"),
    (["train", "--epochs", "0"], "--epochs", "1 <= epochs <= 100000"),
    (["train", "--hidden", "100000"], "--hidden", "1 <= width <= 1024"),
    (["train", "--lr", "-1"], "--lr", "0 < lr <= 1"),
    (["train", "--max-seconds", "inf"], "--max-seconds", "0 < budget <= 604800 s"),
    (["train", "--stability-margin", "1.5"], "--stability-margin", "0 <= fraction <= 1"),
    (["train", "--seed", "-1"], "--seed", "0 <= seed <= 9223372036854775807"),
    (["train", "--memory-tau", "0"], "--memory-tau", "0 < tau <= 10 s"),
    (["montecarlo", "--dispersions", "aerosonde_pm15", "--out", "x", "--runs", "0"], "--runs",
     "1 <= runs <= 1000000"),
    (["montecarlo", "--dispersions", "aerosonde_pm15", "--out", "x", "--scheduler", "nonsense"],
     "--scheduler", "host:port"),
    (["montecarlo", "--dispersions", "aerosonde_pm15", "--out", "x", "--mission", "nope"],
     "--mission", "neither a mission"),
    (["mpc", "--scenario", "climb", "--out", "x", "--horizon", "201"], "--horizon",
     "1 <= intervals <= 200"),
    (["mpc", "--scenario", "climb", "--out", "x", "--dt", "0.015"], "--dt",
     "a multiple of 0.01 s"),
    (["generate-data", "--out", "x", "--truth", "tau_elevator=-0.04"], "--truth",
     "a time constant >= 0 s"),
    (["generate-data", "--out", "x", "--truth", "rate_elevator=0"], "--truth",
     "a rate limit > 0"),
    (["generate-data", "--out", "x", "--truth", "eta_slipstream=2"], "--truth",
     "a share 0..1"),
    (["design-input", "--airframe", "aerosonde", "--out", "x", "--rate", "5"], "--rate",
     "10 <= rate <= 1000 Hz"),
]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return steady_dataset(tmp_path_factory.mktemp("data") / "steady")


@pytest.mark.parametrize("argv, option, states", BAD_VALUES,
                         ids=[f"{a[0]} {o} {a[a.index(o) + 1] if o in a else a[1]}"
                              for a, o, _ in BAD_VALUES])
def test_a_bad_option_value_is_one_line_naming_the_option(argv, option, states, dataset,
                                                           tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    argv = [a.replace("{DS}", str(dataset)) for a in argv]
    assert main(argv) == 2
    line = one_line_error(capsys, argv[0])
    assert names(line, option) and f"argument {option}:" in line and states in line, line
    assert list(tmp_path.iterdir()) == []  # nothing written


# relations: (argv, the options the message names, what it says)
RELATIONS = [
    (["simulate", "--dt", "0.5", "--duration", "0.2"], ("--dt", "--duration"),
     "at least one --dt step"),
    (["simulate", "--dt", "1e-6", "--duration", "1000"], ("--duration", "--dt"),
     "more than the 2000000"),
    (["simulate", "--input", "none", "--amplitude", "0.01"], ("--amplitude", "--input"),
     "applies only"),
    (["modes", "--dt", "0.01"], ("--dt", "--hybrid"), "applies only with --hybrid"),
    (["export-c", "--model", "rk4", "--weights", __file__], ("--weights", "--model"),
     "applies only"),
    (["generate-data", "--out", "x", "--rate", "300"], ("--internal-dt", "--rate"),
     "must divide the log interval"),
    (["generate-data", "--out", "x", "--duration", "1e6"], ("--duration", "--rate"),
     "more than 50000 (memory)"),
    (["generate-data", "--out", "x", "--tolerance", "1e-6"], ("--tolerance", "--verify"),
     "applies only"),
    (["generate-data", "--out", "x", "--airframe", "f450", "--missions", "high_alpha"],
     ("--missions", "--airframe"), "do not apply to the multirotor"),
    (["train", "--dt", "0.01"], ("--dt", "--formulation"), "applies only"),
    (["train", "--formulation", "paper", "--horizon", "1"], ("--horizon", "--formulation"),
     "applies only"),
    (["train", "--formulation", "paper", "--stability-trims", "gate"],
     ("--stability-trims", "--formulation"), "applies only"),
    (["train", "--memory-tau", *["0.1"] * 9], ("--memory-tau",), "at most 8"),
    (["train", "--out", "w.npz", "--history", "w.npz"], ("--history", "--out"),
     "must not be"),
    (["montecarlo", "--dispersions", "aerosonde_pm15", "--out", "x", "--duration", "1e6",
      "--dt", "1e-6"], ("--duration", "--dt"), "1 to 10000000 are allowed"),
    (["montecarlo", "--dispersions", "aerosonde_pm15", "--out", "x", "--duration", "10000",
      "--chunk-size", "100000"], ("--chunk-size", "--duration"), "more than 10000000 (memory)"),
    (["montecarlo", "--dispersions", "aerosonde_pm15", "--out", "x", "--history-dt", "100"],
     ("--history-dt", "--duration"), "must lie between"),
    (["montecarlo", "--dispersions", "aerosonde_pm15", "--out", "x", "--mission",
      "inspection"], ("--mission", "--airframe"), "not an input of the fixed_wing"),
    (["mpc", "--scenario", "climb", "--out", "x", "--model", "physics", "--weights", __file__],
     ("--weights", "--model"), "applies only"),
    (["reproduce", "--no-identify"], ("--no-identify", "--retrain"), "applies only"),
    (["import-log", __file__, "--out", "x", "--max-bank", "30"], ("--max-bank", "--turns"),
     "applies only"),
    (["import-log", __file__, "--out", "x", "--turns", "--max-roll", "5"],
     ("--max-roll", "--turns"), "applies only"),
    (["import-log", __file__, "--out", "x", "--turns", "--max-yaw-rate", "5"],
     ("--max-yaw-rate", "--turns"), "applies only"),
    (["design-input", "--airframe", "aerosonde", "--out", "x", "--duration", "600", "--rate",
      "1000"], ("--duration", "--rate"), "more than 50000 (memory)"),
    (["design-input", "--airframe", "f450", "--out", "x", "--alpha-deg", "5"],
     ("--alpha-deg", "--airframe"), "a fixed wing's elevator input"),
    (["design-input", "--airframe", "aerosonde", "--out", "x", "--duration", "5",
      "--mode-hz", "0.01"], ("--duration", "--mode-hz"), "too short"),
    (["design-input", "--airframe", "aerosonde", "--out", "x", "--airspeed", "0"],
     ("--airspeed", "--airframe"), "no trim"),
]


@pytest.mark.parametrize("argv, options, says", RELATIONS,
                         ids=[" ".join(a[:1] + list(o)) for a, o, _ in RELATIONS])
def test_a_broken_relation_is_one_line_naming_both_options(argv, options, says, tmp_path,
                                                           monkeypatch, capsys):
    if "--history" in argv:  # checked where train knows both paths, after importing torch
        pytest.importorskip("torch")
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    line = one_line_error(capsys, argv[0])
    assert all(names(line, o) for o in options) and says in line, line
    assert list(tmp_path.iterdir()) == []


def test_identify_relations_to_the_data(dataset, tmp_path, monkeypatch, capsys):
    """A window longer than the sorties and a cut-off above half the log rate are refused
    naming the option and the dataset, before any fit."""
    monkeypatch.chdir(tmp_path)
    base = ["identify", "--dataset", str(dataset), "--params", "C_m_q", "--out", "a.toml"]
    for extra, option, says in ((["--window", "1000"], "--window", "longer than every train"),
                                (["--lowpass-hz", "40"], "--lowpass-hz", "below half the log"),
                                (["--dt", "0.03"], "--dt", "does not fit the log interval")):
        assert main([*base, *extra]) == 2
        line = one_line_error(capsys, "identify")
        assert names(line, option) and names(line, "--dataset") and says in line, line
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow  # imports torch
def test_train_horizons_no_longer_than_the_data(dataset, tmp_path, monkeypatch, capsys):
    pytest.importorskip("torch")
    monkeypatch.chdir(tmp_path)
    base = ["train", "--dataset", str(dataset), "--out", "w.npz"]
    for extra, option in ((["--horizon", "100"], "--horizon"),
                          (["--formulation", "paper", "--rollout-horizon", "1000"],
                           "--rollout-horizon")):
        assert main([*base, *extra]) == 2
        line = one_line_error(capsys, "train")
        assert names(line, option) and names(line, "--dataset") and "longer than" in line, line
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------- airframe kind vs dataset

def _fake_trainer(monkeypatch):
    """The legacy trainer replaced by one that returns at once (the check under test comes
    before it; on code without the check, the command 'trains' and exits 0)."""
    from test_correction import random_net

    from uavdyn.learned import command
    from uavdyn.learned.train import TrainResult

    def fake(tr, va, airframe, cfg):
        history = [{"epoch": 0, "train_one_step": 1.0, "val_one_step": 1.0,
                    "train_rollout": 1.0, "val_rollout": 1.0, "val_total": 1.0}]
        return TrainResult(net=random_net(airframe, cfg.formulation), history=history,
                           config=cfg, best_epoch=0, seconds=0.0, stopped="epochs")

    monkeypatch.setattr(command, "train", fake)


@pytest.mark.parametrize("command", ["train", "identify", "evaluate"])
def test_an_airframe_of_another_kind_than_the_dataset_is_refused(command, dataset, tmp_path,
                                                                 monkeypatch, capsys):
    """A multirotor airframe on a fixed-wing dataset: one line naming both kinds and both
    options, before any work (train used to train on it)."""
    monkeypatch.chdir(tmp_path)
    argv = {"train": ["train", "--formulation", "paper", "--epochs", "1", "--out", "w.npz"],
            "identify": ["identify", "--params", "mass", "--out", "a.toml"],
            "evaluate": ["evaluate", "--all-sorties", "--out", "m.json"]}[command]
    if command == "train":
        pytest.importorskip("torch")
        _fake_trainer(monkeypatch)
    assert main([*argv, "--airframe", "f450", "--dataset", str(dataset)]) == 2
    line = one_line_error(capsys, command)
    assert "multirotor" in line and "fixed_wing" in line, line
    assert names(line, "--airframe") and names(line, "--dataset"), line
    assert list(tmp_path.iterdir()) == []


def test_a_refusal_states_the_memory_bound(tmp_path, monkeypatch, capsys):
    """Memory-sized options are bounded and the refusal says by how much."""
    monkeypatch.chdir(tmp_path)
    assert main(["montecarlo", "--dispersions", "aerosonde_pm15", "--out", "x", "--runs",
                 "1000000", "--duration", "60", "--history-dt", "0.01"]) == 2
    line = one_line_error(capsys, "montecarlo")
    assert "more than 10000000 (memory)" in line and names(line, "--runs"), line
    assert math.isfinite(float(re.search(r"is ([\d.e+]+)", line).group(1)))
