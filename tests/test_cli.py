"""The command line: every command has --help, works on presets and user files, and reports
bad input as one line with a non-zero exit code."""

import json

import numpy as np
import pytest

from uavdyn.airframes import load_airframe, to_toml_dict
from uavdyn.cli import main

COMMANDS = ["airframes", "trim", "modes", "simulate", "export-c", "montecarlo"]


@pytest.mark.parametrize("command", COMMANDS)
def test_help(command, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([command, "--help"])
    assert exit_info.value.code == 0
    assert "usage: uavdyn " + command in capsys.readouterr().out


def test_airframes_and_modes(capsys):
    assert main(["airframes"]) == 0
    out = capsys.readouterr().out
    assert "aerosonde" in out and "f450" in out
    assert main(["modes", "--airframe", "aerosonde"]) == 0
    out = capsys.readouterr().out
    assert "short period" in out and "phugoid" in out
    assert main(["modes", "--airframe", "quadrotor", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert len(data["A"]) == 4 and data["modes"]


def test_trim_json(capsys):
    assert main(["trim", "--airframe", "aerosonde", "--airspeed", "22", "--gamma-deg", "3"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["airspeed_mps"] == 22 and data["residual"] < 1e-9


def test_simulate_writes_interchange_csv(tmp_path, capsys):
    out = tmp_path / "doublet.csv"
    assert main(["simulate", "--airframe", "aerosonde", "--input", "3211", "--dt", "0.01",
                 "--duration", "3", "--out", str(out)]) == 0
    header = out.read_text().splitlines()[0]
    assert header == "time,u,w,q,theta,elevator,throttle"
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    assert data.shape == (301, 7)
    np.testing.assert_allclose(np.diff(data[:, 0]), 0.01, atol=1e-12)
    assert np.ptp(data[:, 5]) > 0.05  # the 3-2-1-1 input is there
    assert np.ptp(data[:, 4]) > 1e-3  # and the aircraft responded


def test_user_parameter_file(tmp_path, capsys):
    data = to_toml_dict(load_airframe("f450"))
    data["name"] = "heavy_quad"
    data["params"]["mass"]["value"] = 2.0
    path = tmp_path / "heavy.json"
    path.write_text(json.dumps(data))
    assert main(["trim", "--airframe", str(path), "--airspeed", "0"]) == 0
    heavy = json.loads(capsys.readouterr().out)
    assert main(["trim", "--airframe", "f450", "--airspeed", "0"]) == 0
    light = json.loads(capsys.readouterr().out)
    assert heavy["airframe"] == "heavy_quad" and heavy["collective"] > light["collective"]


@pytest.mark.parametrize("argv, message", [
    (["trim", "--airframe", "nosuch"], "neither a preset"),
    (["trim", "--airspeed", "5"], "below the stall speed"),
    (["simulate", "--dt", "-1"], "argument --dt: must be a finite number with 1e-06 <= dt"),
    (["simulate", "--duration", "nan"], "argument --duration: must be a finite number with "
                                        "duration > 0 s, got 'nan'"),
])
def test_errors_are_one_line(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and err.count("\n") == 0 and err.startswith("uavdyn ")


def test_export_c_writes_a_bundle(tmp_path, capsys):
    out = tmp_path / "bundle"
    assert main(["export-c", "--airframe", "aerosonde", "--real", "float", "--rollout", "50",
                 "--out", str(out)]) == 0
    assert {"uav_step.h", "uav_step.c", "uav_step_generated.c", "main.c", "Makefile"} <= {
        f.name for f in out.iterdir()}
    header = (out / "uav_step.h").read_text()
    assert "#define UAV_STEP_ROLLOUT_STEPS 50" in header and "float" in header
    assert main(["export-c", "--rollout", "-1"]) == 2


def test_export_c_warns_when_the_step_is_too_stiff_for_its_dt(tmp_path, capsys):
    # pitch damping 12 on the X500: q_dot = -553 q, stable under one RK4 step below 5.0 ms
    data = to_toml_dict(load_airframe("examples/x500.toml"))
    data["params"]["pitch_damping"]["value"] = 12.0
    path = tmp_path / "stiff.json"
    path.write_text(json.dumps(data))
    assert main(["export-c", "--airframe", str(path), "--dt", "0.01",
                 "--out", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    assert "warning: the exported step diverges" in err and "--dt 0.00" in err
    assert main(["export-c", "--airframe", str(path), "--dt", "0.004",
                 "--out", str(tmp_path / "b")]) == 0
    assert "diverges" not in capsys.readouterr().err
