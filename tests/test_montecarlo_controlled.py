"""Monte Carlo with the MPC in the loop: dispersed airframes and gusts fly the pitch step, the
runs are reproducible, and the dispersion that drives the worst runs is named."""

from dataclasses import replace

import numpy as np
import pytest

from uavdyn.integrate import physics_step
from uavdyn.montecarlo import MonteCarloError, parse_dispersions
from uavdyn.montecarlo.controlled import (
    OUTCOMES,
    describe,
    fly_controlled_runs,
    gusty_plant,
)
from uavdyn.mpc import MPCConfig, scenario
from uavdyn.mpc.study import prediction_models


@pytest.fixture(scope="module")
def setup():
    study = prediction_models("aerosonde", mode="rti", models=("physics",))
    controller = study.models["physics"].controller(MPCConfig(horizon=20, mode="rti"))
    airframe = study.plant_airframe
    dispersions = parse_dispersions({
        "params": {"C_m_alpha": {"dist": "uniform", "low": -0.4, "high": 0.4},
                   "mass": {"dist": "uniform", "low": -0.002, "high": 0.002}},
        "initial": {"q": {"dist": "uniform", "low": -0.01, "high": 0.01}},
        "gust": {"intensity": {"dist": "uniform", "low": 0.0, "high": 0.2}}}, airframe)
    sc = replace(scenario("fixed_wing", "pitch-step"), duration=3.0)
    return controller, airframe, dispersions, sc


def test_the_dispersion_that_drives_the_worst_runs_is_named(setup):
    controller, airframe, dispersions, sc = setup
    result = fly_controlled_runs(controller, airframe, dispersions, sc, runs=24, seed=3)
    assert result.columns[:len(OUTCOMES)] == OUTCOMES
    assert result.table.shape == (24, len(OUTCOMES) + 4)
    assert np.all(result.column("trim_ok") == 1) and np.all(result.column("departed") == 0)
    assert np.all(result.column("failed_solves") == 0)
    assert np.all(np.isfinite(result.column("tracking_rmse")))
    # the +-40 % pitch stiffness, not the +-0.2 % mass nor the light gusts, drives the error
    top = result.drivers[0]
    assert top.column == "params.C_m_alpha" and top.explained > 0.3
    others = {d.column: d.explained for d in result.drivers[1:]}
    assert max(others.values()) < top.explained
    assert result.column("gust.intensity").max() > 0  # the runs did fly gusts
    worst = result.worst_runs()
    err = result.column("tracking_rmse")
    assert len(worst) == 2 and err[worst[0]] == err.max()
    lines = describe(result)
    assert "24 runs of the pitch-step" in lines[0] and "params.C_m_alpha" in lines[2]
    # reproducible from (seed, run) alone: a run flown alone is the same run
    again = fly_controlled_runs(controller, airframe, dispersions, sc, runs=2, seed=3)
    timed = result.columns.index("median_solve_ms")  # wall time: the one column that varies
    np.testing.assert_array_equal(np.delete(again.table, timed, 1),
                                  np.delete(result.table[:2], timed, 1))


def test_gusty_plant_without_gusts_is_the_physics_step(setup):
    _, airframe, _, _ = setup
    plant = gusty_plant(airframe, 0.05, None)
    step = physics_step(airframe)
    z = np.r_[np.asarray(physics_step(airframe).initial_state(
        [24.9, 1.2, 0.01, 0.05], [-0.12, 0.78], airframe.p, 0.05), float), 100.0]
    plant(z, None)
    z1, y1 = plant(z, np.array([-0.12, 0.78]))
    ref = np.asarray(step.function(z[:-1], [-0.12, 0.78], airframe.p, 0.05)).ravel()
    np.testing.assert_allclose(z1[:-1], ref, rtol=0, atol=1e-12)
    assert y1.shape == (5,) and y1[4] != 100.0


def test_controller_of_another_kind_is_refused(setup):
    controller, _, _, sc = setup
    from uavdyn.airframes import load_airframe

    f450 = load_airframe("f450")
    with pytest.raises(MonteCarloError, match="fixed_wing"):
        fly_controlled_runs(controller, f450, parse_dispersions({}, f450), sc, runs=1)


def test_cli_flies_the_mpc_runs_and_refuses_batch_options(tmp_path, capsys):
    import json

    from uavdyn.cli import main

    out = tmp_path / "mc_mpc"
    # the deprecated spelling still works: --controller mpc --scenario pitch-step
    assert main(["montecarlo", "--mpc", "pitch-step", "--dispersions", "aerosonde_gusty",
                 "--runs", "3", "--duration", "3", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert "3 runs of the pitch-step" in captured.out and "deprecated" in captured.err
    rows = (out / "runs.csv").read_text().strip().splitlines()
    assert rows[0].split(",")[:len(OUTCOMES)] == list(OUTCOMES) and len(rows) == 4
    drivers = json.loads((out / "drivers.json").read_text())
    assert drivers["runs"] == 3 and len(drivers["drivers"]) == 8
    assert drivers["summary"]["departed"] == 0
    assert "RTI MPC, horizon 20" in (out / "summary.md").read_text()
    for extra, message in ((["--closed-loop"], "--closed-loop is the batch study's LQR"),
                           (["--mission", "3211"], "--mission applies to the batch study"),
                           (["--dt", "0.02"], "--dt applies to the batch study"),
                           (["--vector-math"], "--vector-math applies to the batch study"),
                           (["--controller", "lqr"], "contradicts --controller lqr")):
        assert main(["montecarlo", "--mpc", "pitch-step", "--dispersions", "aerosonde_gusty",
                     "--runs", "3", "--out", str(tmp_path / "x"), *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert message in err[-1] and "Traceback" not in "".join(err)
