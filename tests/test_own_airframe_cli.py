"""A user's own airframe file through the commands that used to need a shipped correction:
export-c, mpc (with a plant apart from the model) and a closed-loop Monte-Carlo study, on the
repository's example airframes (examples/trainer.toml, examples/x500.toml)."""

import json
from pathlib import Path

import pytest

from uavdyn.cli import main

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
TRAINER, X500 = str(EXAMPLES / "trainer.toml"), str(EXAMPLES / "x500.toml")


def test_export_c_of_an_airframe_file_without_weights_is_its_physics(tmp_path, capsys):
    out = tmp_path / "bundle"
    assert main(["export-c", "--airframe", TRAINER, "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "exporting its physics step" in err
    header = (out / "uav_step.h").read_text()
    assert "elevator_actuator" in header and "_memory_" not in header  # the file's lags


@pytest.mark.slow
def test_mpc_flies_the_file_and_a_plant_apart_from_it(tmp_path, capsys):
    """No weights: the physics prediction alone; --plant: the emulator of another airframe
    (the trainer with +15 % C_m_alpha), named in the output, tracks differently."""
    import tomllib

    doc = tomllib.loads(Path(TRAINER).read_text())
    doc["params"]["C_m_alpha"]["value"] *= 1.15
    doc["name"] = "trainer_truth"
    truth = tmp_path / "truth.json"
    truth.write_text(json.dumps(doc))
    rmse = {}
    for label, extra in (("matched", []), ("truth", ["--plant", str(truth)])):
        out = tmp_path / label
        code = main(["mpc", "--airframe", TRAINER, "--scenario", "pitch-step", "--model",
                     "physics", "--rti", "--horizon", "10", "--out", str(out), *extra])
        assert code == 0, capsys.readouterr().err
        stats = json.loads((out / "stats.json").read_text())
        assert stats["plant"].endswith("trainer2m" if label == "matched" else "trainer_truth")
        rmse[label] = stats["models"]["physics"]["tracking_rmse"]
    assert rmse["truth"] != pytest.approx(rmse["matched"], rel=1e-3), rmse


@pytest.mark.slow
def test_a_closed_loop_study_of_the_x500_states_its_feedback(tmp_path, capsys):
    out = tmp_path / "mc"
    code = main(["montecarlo", "--airframe", X500, "--dispersions", "f450_pm15", "--runs",
                 "20", "--duration", "10", "--closed-loop", "--no-progress", "--out",
                 str(out)])
    assert code == 0, capsys.readouterr().err
    summary = (out / "summary.md").read_text()
    assert "closed loop: u = trim + deviation - K (x - trim)" in summary
    assert "departed or diverged 0" in summary
