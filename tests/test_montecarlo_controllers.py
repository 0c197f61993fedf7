"""Controller-in-the-loop Monte Carlo in chunks: the C controller equals the Python one run for
run, LQR and MPC fly the same dispersed airframes and gusts, a study resumes from its chunks,
and the CLI's controller options refuse what they would ignore."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from uavdyn.integrate.compiler import find_compiler
from uavdyn.montecarlo import MonteCarloError, parse_dispersions
from uavdyn.montecarlo.controlled import OUTCOMES, fly_controlled_runs
from uavdyn.montecarlo.controlled_study import (
    ControlledSpec,
    build_controller,
    chunk_path,
    run_controlled_study,
)
from uavdyn.mpc import scenario

TRAINER = str(Path(__file__).resolve().parents[1] / "examples" / "trainer.toml")
# outcomes that are wall times, not results
TIMED = ("median_solve_ms",)


@pytest.fixture(scope="module")
def spec():
    from uavdyn.airframes import load_airframe

    airframe = load_airframe(TRAINER)
    dispersions = parse_dispersions({
        "params": {"C_m_alpha": {"dist": "uniform", "low": -0.15, "high": 0.15},
                   "C_m_delta_e": {"dist": "uniform", "low": -0.15, "high": 0.15}},
        "gust": {"intensity": {"dist": "uniform", "low": 0.0, "high": 2.0}}}, airframe)
    sc = replace(scenario("fixed_wing", "pitch-step"), duration=2.0)
    return ControlledSpec(TRAINER, None, airframe, dispersions, "mpc", sc,
                          runs=5, seed=2, chunk_size=2, backend="python")


def _results(table, columns):
    keep = [i for i, c in enumerate(columns) if c not in TIMED]
    return table[:, keep]


@pytest.mark.skipif(find_compiler() is None, reason="no C compiler")
def test_c_controller_flies_the_runs_of_the_python_controller(spec):
    python = build_controller(spec, "python")
    c = build_controller(spec, "c")
    assert type(c).__name__ == "CMPCController"
    args = (spec.plant, spec.dispersions, spec.scenario, 3, spec.seed)
    a = fly_controlled_runs(python, *args)
    b = fly_controlled_runs(c, *args)
    assert np.all(a.column("departed") == 0) and np.all(np.isfinite(a.column("tracking_rmse")))
    np.testing.assert_allclose(_results(b.table, b.columns), _results(a.table, a.columns),
                               rtol=0, atol=1e-9)


def test_lqr_and_mpc_fly_the_same_draws_and_the_lqr_respects_the_limits(spec):
    lqr = build_controller(replace_controller(spec, "lqr"))
    mpc = build_controller(spec)
    a = fly_controlled_runs(lqr, spec.plant, spec.dispersions, spec.scenario, 3, spec.seed)
    b = fly_controlled_runs(mpc, spec.plant, spec.dispersions, spec.scenario, 3, spec.seed)
    drawn = len(OUTCOMES)
    np.testing.assert_array_equal(a.table[:, drawn:], b.table[:, drawn:])
    assert np.all(a.column("failed_solves") == 0) and np.all(a.column("departed") == 0)
    assert np.all((a.column("bound_share") >= 0) & (a.column("rate_share") <= 1))
    assert not np.array_equal(a.column("tracking_rmse"), b.column("tracking_rmse"))


def replace_controller(spec: ControlledSpec, controller: str) -> ControlledSpec:
    return ControlledSpec(spec.airframe_source, None, spec.plant, spec.dispersions, controller,
                          spec.scenario, runs=spec.runs, seed=spec.seed,
                          chunk_size=spec.chunk_size, backend=spec.backend)


def test_study_in_chunks_resumes_and_equals_the_runs_flown_at_once(spec, tmp_path):
    out = tmp_path / "study"
    first = run_controlled_study(spec, out)
    assert first.runs_computed == 5 and first.reused == []
    assert sorted(p.name for p in (out / "chunks").iterdir()) == [
        f"ctrl_00000{i}.npz" for i in range(3)]
    whole = fly_controlled_runs(build_controller(spec), spec.plant, spec.dispersions,
                                spec.scenario, 5, spec.seed)
    cols = first.runs.columns
    np.testing.assert_array_equal(_results(first.runs.table, cols),
                                  _results(whole.table, cols))
    # a lost chunk is flown again, the others are reused; a damaged one is not trusted
    chunk_path(out, 1).unlink()
    with np.load(chunk_path(out, 2)) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["table"][0, 3] += 1e-3  # a changed result under the old digest
    with open(chunk_path(out, 2), "wb") as fh:
        np.savez(fh, **arrays)
    again = run_controlled_study(spec, out)
    assert again.reused == [0] and again.runs_computed == 3
    np.testing.assert_array_equal(_results(again.runs.table, cols),
                                  _results(first.runs.table, cols))
    for name in ("runs.csv", "drivers.json", "summary.md", "study.json"):
        assert (out / name).is_file()
    other = replace_controller(spec, "lqr")
    with pytest.raises(MonteCarloError, match="another Monte-Carlo study"):
        run_controlled_study(other, out)


def test_cli_controller_options(tmp_path, capsys):
    from uavdyn.cli import main

    base = ["montecarlo", "--airframe", TRAINER, "--dispersions",
            "trainer_pm15_gusty", "--runs", "2", "--duration", "1", "--no-progress"]
    assert main([*base, "--controller", "lqr", "--out", str(tmp_path / "lqr")]) == 0
    assert "2 runs x 1 s, LQR" in capsys.readouterr().out
    for extra, message in ((["--scenario", "climb"], "--scenario applies to --controller"),
                           (["--controller", "lqr", "--mpc-backend", "c"],
                            "--mpc-backend applies to --controller mpc"),
                           (["--controller", "lqr", "--weights", "shipped"],
                            "--weights applies to --controller mpc"),
                           (["--controller", "mpc", "--threads", "2"],
                            "--threads applies to the batch study"),
                           (["--controller", "mpc", "--duration", "0.3"],
                            "ends before the pitch-step starts")):
        argv = [*base[:-3], "--no-progress"] if "--duration" in extra else base
        assert main([*argv, *extra, "--out", str(tmp_path / "x")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], err
