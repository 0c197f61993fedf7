"""``uavdyn mpc``: writes histories, statistics and a PNG into a fresh folder, refuses a foreign
non-empty folder and bad options with one-line errors."""

import argparse
import csv
import json
import re

import numpy as np
import pytest

from uavdyn.cli.mpc import HISTORY_COLUMNS, add_parser, cmd_mpc
from uavdyn.outputs import OutputError


def _args(argv):
    parser = argparse.ArgumentParser(prog="uavdyn")
    add_parser(parser.add_subparsers(dest="command"))
    return parser.parse_args(["mpc", *argv])


def test_mpc_command_writes_histories_stats_and_figure(tmp_path, capsys):
    out = tmp_path / "run"
    args = _args(["--airframe", "aerosonde", "--scenario", "pitch-step", "--rti",
                  "--horizon", "8", "--model", "physics", "--out", str(out)])
    assert cmd_mpc(args) == 0
    assert (out / "mpc.png").stat().st_size > 1000
    stats = json.loads((out / "stats.json").read_text())
    assert stats["mode"] == "rti" and stats["horizon"] == 8 and stats["tracked"] == "theta"
    phys = stats["models"]["physics"]
    assert phys["success_rate"] == 1.0 and phys["fallback_held"] == 0
    assert phys["tracking_rmse"] < 0.01 and phys["solve_ms_median"] > 0
    rows = list(csv.reader((out / "history_physics.csv").open()))
    assert tuple(rows[0]) == HISTORY_COLUMNS and len(rows) == 1 + 161  # 8 s at 0.05 s
    theta = np.array([float(r[4]) for r in rows[1:]])
    assert theta.max() > theta[0] + np.radians(4.0)  # the 5 deg step was flown
    assert "wrote" in capsys.readouterr().out
    # the same command may replace its own output; a foreign folder is refused
    assert cmd_mpc(args) == 0
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(OutputError, match="not a uavdyn output"):
        cmd_mpc(_args(["--scenario", "climb", "--out", str(foreign)]))


@pytest.mark.parametrize("argv, match", [
    (["--horizon", "0"], "argument --horizon: must be a whole number with 1 <= intervals <= 200"),
    (["--dt", "0.015"], "argument --dt: .*a multiple of 0.01 s, got '0.015'"),
    (["--dt", "nan"], "argument --dt: must be a finite number"),
    (["--weights", "missing.npz"], "argument --weights: no weight file missing.npz"),
    (["--model", "physics", "--weights", __file__], "--weights applies only with --model"),
])
def test_mpc_command_refuses_bad_options(tmp_path, argv, match, capsys):
    """Refused when parsed (or, for a relation, before any work): one line naming the option,
    exit code 2, nothing written."""
    from uavdyn.cli.app import main

    assert main(["mpc", "--scenario", "climb", "--out", str(tmp_path / "x"), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.search(match, err[0]), err
    assert not (tmp_path / "x").exists()


def test_main_prints_one_line_errors(tmp_path, capsys):
    """Through ``uavdyn``'s own parser: a bad option is one line on stderr with exit code 2, no
    traceback."""
    from uavdyn.cli.app import main

    code = main(["mpc", "--scenario", "climb", "--horizon", "0", "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "argument --horizon: must be" in err
