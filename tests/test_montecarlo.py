"""Monte-Carlo studies (issue 15): the same numbers on 1 worker, 2 threads and a 2-worker Dask
LocalCluster; resume after a killed run recomputes only the missing chunks; exceedance
probabilities with a known analytic answer inside their Wilson intervals; bad dispersion files
refused with one line naming the file and key; divergence flagged with its time.

Results are compared bitwise (``numpy.array_equal``): every run is the same compiled code on the
same inputs, whatever the thread, process or chunk it runs in.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
from scipy.special import ndtr
from scipy.stats import truncnorm

from uavdyn.airframes import load_airframe
from uavdyn.cli.montecarlo import add_parser
from uavdyn.integrate import free_run, physics_step
from uavdyn.learned import shipped_correction, shipped_weights
from uavdyn.linear import trim
from uavdyn.model import build_model, structure_of
from uavdyn.montecarlo import (
    SIGNALS,
    DispersionError,
    Distribution,
    MonteCarloError,
    build_spec,
    envelopes,
    load_dispersions,
    parse_dispersions,
    run_function,
    run_study,
    wilson_interval,
)
from uavdyn.montecarlo.chunks import chunk_path

GUSTY = """
seed = 3
[params.mass]
dist = "truncnormal"
sd = 0.05
low = -0.15
high = 0.15
[params.C_m_alpha]
dist = "uniform"
low = -0.15
high = 0.15
[initial]
theta = { dist = "normal", sd = 0.02 }
[trim]
airspeed = { dist = "uniform", low = -2.0, high = 2.0 }
[gust]
intensity = { dist = "uniform", low = 0.0, high = 1.5 }
"""


@pytest.fixture(scope="module")
def aerosonde():
    return load_airframe("aerosonde")


def _dispersions(tmp_path, text, airframe, name="d.toml"):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return load_dispersions(path, airframe)


def _same(a, b):
    return (np.array_equal(a.table.data, b.table.data, equal_nan=True)
            and np.array_equal(a.history, b.history, equal_nan=True))


# ----------------------------------------------------------------------------- engines


@pytest.mark.slow
def test_identical_on_one_worker_two_threads_and_dask(tmp_path, aerosonde):
    pytest.importorskip("distributed")
    disp = _dispersions(tmp_path, GUSTY, aerosonde)
    spec = build_spec(aerosonde, disp, runs=45, duration=3.0, dt=0.01, chunk_size=15)
    one = run_study(spec, progress=False)
    threads = run_study(spec, threads=2, progress=False)
    files = []
    dask = run_study(spec, out=tmp_path / "dask", workers=2, progress=False,
                     on_chunk=lambda r: files.append(r.file))
    assert one.table.data.shape == (45, len(one.table.columns))
    assert np.all(one.table["trim_ok"] == 1) and not np.any(one.table["diverged"] == 1)
    assert np.all(np.isfinite(one.history))
    assert _same(one, threads) and _same(one, dask)  # bitwise
    # the LocalCluster's workers wrote their chunk files themselves, and those verify: a
    # resume in this process reuses every one of them
    assert sorted(files) == [str(chunk_path((tmp_path / "dask").resolve(), c))
                             for c in range(3)]
    resumed = run_study(spec, out=tmp_path / "dask", progress=False)
    assert resumed.computed == () and resumed.reused == (0, 1, 2) and _same(one, resumed)
    # every run depends on (seed, run) only: another chunking gives the same rows
    rechunked = run_study(build_spec(aerosonde, disp, runs=45, duration=3.0, dt=0.01,
                                     chunk_size=7), progress=False)
    assert _same(one, rechunked)
    # and the gusts, parameters and initial states really vary from run to run
    assert np.unique(one.table["params.mass"]).size == 45
    assert np.ptp(one.table["max_abs_pitch_deg"]) > 0.1


@pytest.mark.slow
def test_scheduler_address_client_or_worker_writes(tmp_path, aerosonde):
    """On a cluster given by its address the client writes the chunk files (the workers may
    not see the folder) unless told the workers do; either way they verify on resume."""
    distributed = pytest.importorskip("distributed")
    spec = build_spec(aerosonde, _dispersions(tmp_path, GUSTY, aerosonde), runs=20,
                      duration=1.0, dt=0.01, chunk_size=10)
    reference = run_study(spec, progress=False)
    # a worker thread of this process, two threads: chunks take turns (CasADi graph building
    # is not thread-safe)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=None) as cl:
        for workers_write in (None, True):
            out, stored = tmp_path / f"mc_{workers_write}", []
            found = run_study(spec, out=out, scheduler=cl.scheduler_address,
                              workers_write=workers_write, progress=False,
                              on_chunk=stored.append)
            assert _same(found, reference)
            by_worker = [r.file is not None for r in stored]
            assert by_worker == [bool(workers_write)] * 2
            assert run_study(spec, out=out, progress=False).reused == (0, 1)


def test_envelopes_the_same_on_threads():
    rng = np.random.default_rng(1)
    history = rng.standard_normal((301, len(SIGNALS), 97)).astype(np.float32)
    history[3, :, 50:] = np.nan  # a diverged run: NaN from then on
    time = np.arange(97) * 0.1
    for keep in (np.ones(301, bool), rng.random(301) < 0.7):
        one, three = envelopes(history, time, keep), envelopes(history, time, keep, threads=3)
        assert np.array_equal(one.values, three.values, equal_nan=True)  # bitwise
        rows = history[keep, 2, :].astype(float) * (180 / np.pi)
        assert np.array_equal(one.band("alpha"), np.percentile(rows, (5, 50, 95), axis=0),
                              equal_nan=True)


def test_without_dask_a_clear_error(tmp_path, aerosonde, monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    spec = build_spec(aerosonde, _dispersions(tmp_path, GUSTY, aerosonde), runs=4,
                      duration=0.1, chunk_size=2)
    with pytest.raises(MonteCarloError, match=r"needs Dask: pip install"):
        run_study(spec, workers=2, progress=False)


def test_runs_match_the_library_rollout(tmp_path, aerosonde):
    """Each run is the library's own compiled rollout of the dispersed airframe from its trim
    (uavdyn.integrate.free_run), and its statistics are those of that trajectory."""
    disp = load_dispersions("aerosonde_pm15", aerosonde)
    spec = build_spec(aerosonde, disp, runs=4, duration=4.0, dt=0.01, mission="3211",
                      chunk_size=4, history_dt=0.5)
    result = run_study(spec, progress=False)
    forces = build_model(aerosonde).forces
    for k in range(4):
        drawn = {n: result.table[f"params.{n}"][k] for n in disp.params}
        airframe = aerosonde.replace(**drawn)
        point = trim(airframe, 25.0)
        controls = point.u + spec.deviations
        traj = free_run(physics_step(airframe), point.x, controls, airframe.p, 0.01)
        np.testing.assert_allclose(result.history[k, 0], traj[::50, 3], rtol=1e-6)  # float32
        assert result.table["max_abs_pitch_deg"][k] == pytest.approx(
            np.degrees(np.abs(traj[:, 3]).max()), abs=1e-10)
        Z = np.array([float(forces(x, u, airframe.p)[1])
                      for x, u in zip(traj, np.vstack([controls[:1], controls]))])
        n = -Z / (airframe.params.mass * airframe.params.gravity)
        assert result.table["max_load_factor"][k] == pytest.approx(n.max(), abs=1e-10)


# ----------------------------------------------------------------------------- resume


KILL_SCRIPT = """
import os, signal, sys
from uavdyn.airframes import load_airframe
from uavdyn.montecarlo import build_spec, load_dispersions, run_study
af = load_airframe("aerosonde")
spec = build_spec(af, load_dispersions(sys.argv[1], af), runs=50, duration=1.0, dt=0.01,
                  chunk_size=10)
stored = []
def killed_after_two(result):
    stored.append(result.index)
    if len(stored) == 2:
        os.kill(os.getpid(), signal.SIGKILL)  # a hard kill, no clean-up of any kind
run_study(spec, out=sys.argv[2], progress=False, on_chunk=killed_after_two)
"""


@pytest.mark.slow
def test_resume_after_kill_recomputes_only_missing_chunks(tmp_path, aerosonde):
    dispersion_file = tmp_path / "d.toml"
    dispersion_file.write_text(GUSTY)
    out = tmp_path / "study"
    script = tmp_path / "kill.py"
    script.write_text(KILL_SCRIPT)
    proc = subprocess.run([sys.executable, str(script), str(dispersion_file), str(out)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == -9, proc.stderr[-2000:]
    written = sorted(p.name for p in (out / "chunks").glob("chunk_*.npz"))
    assert written == ["chunk_000000.npz", "chunk_000001.npz"]
    # what a writer killed mid-file leaves behind: a temporary sibling of a dead process
    stale = out / "chunks" / ".chunk_000002.npz.tmp-999999999-1-0123abcd"
    stale.write_bytes(b"half a zip")
    spec = build_spec(aerosonde, load_dispersions(dispersion_file, aerosonde), runs=50,
                      duration=1.0, dt=0.01, chunk_size=10)
    seen = []
    resumed = run_study(spec, out=out, progress=False, on_chunk=lambda r: seen.append(r.index))
    assert resumed.reused == (0, 1) and resumed.computed == (2, 3, 4) and seen == [2, 3, 4]
    assert not stale.exists()
    assert _same(resumed, run_study(spec, progress=False))  # as if never interrupted
    # a corrupted chunk does not verify and is recomputed, alone
    path = chunk_path(out, 3)
    path.write_bytes(path.read_bytes()[:-100])
    again = run_study(spec, out=out, progress=False)
    assert again.computed == (3,) and _same(again, resumed)
    # raising --runs extends the study: only the new chunk is computed
    more = build_spec(aerosonde, load_dispersions(dispersion_file, aerosonde), runs=55,
                      duration=1.0, dt=0.01, chunk_size=10)
    extended = run_study(more, out=out, progress=False)
    assert extended.computed == (5,)
    assert np.array_equal(extended.table.data[:50], resumed.table.data, equal_nan=True)
    for name in ("summary.csv", "envelopes.csv", "results.json", "summary.md",
                 "figures/envelopes.png", "figures/distributions.png"):
        assert (out / name).is_file()
    assert len((out / "summary.csv").read_text().splitlines()) == 56
    # another study into the same folder is refused
    other = build_spec(aerosonde, load_dispersions(dispersion_file, aerosonde), runs=50,
                       duration=1.0, dt=0.01, chunk_size=10, seed=4)
    with pytest.raises(MonteCarloError, match="holds another Monte-Carlo study"):
        run_study(other, out=out, progress=False)


# ----------------------------------------------------------------------------- statistics


def test_wilson_interval_known_values():
    # textbook values (Wilson 1927; e.g. Newcombe 1998, Table I) at 95 %
    np.testing.assert_allclose(wilson_interval(0, 10), (0.0, 0.27753), atol=5e-5)
    np.testing.assert_allclose(wilson_interval(5, 10), (0.23659, 0.76341), atol=5e-5)
    np.testing.assert_allclose(wilson_interval(81, 263), (0.25530, 0.36621), atol=5e-5)
    assert wilson_interval(10, 10)[1] == 1.0
    with pytest.raises(ValueError):
        wilson_interval(3, 2)


@pytest.mark.slow
def test_exceedance_with_known_probability_inside_interval(tmp_path, aerosonde):
    """Initial pitch offsets ~ N(0, 0.05 rad) and trim speeds ~ U(22, 28) m/s over one 1 ms
    step (in which the airspeed moves by < 5e-3 m/s and the pitch by ~1e-9 rad, shifting either
    probability by < 1e-3, far inside the interval): P(|theta| > 0.1 rad) and
    P(airspeed < 24 m/s) = 1/3 follow from the distributions alone."""
    disp = _dispersions(tmp_path, """
        seed = 11
        [initial]
        theta = { dist = "normal", sd = 0.05 }
        [trim]
        airspeed = { dist = "uniform", low = -3.0, high = 3.0 }
        [limits]
        pitch_deg = 5.729577951308232
        airspeed_min_mps = 24.0
        alpha_deg = false
        load_factor_max = false
        """, aerosonde)
    spec = build_spec(aerosonde, disp, runs=1500, duration=0.001, dt=0.001, mission="none",
                      chunk_size=500)
    result = run_study(spec, progress=False)
    assert np.all(result.table["trim_ok"] == 1)
    # the trim pitch depends (weakly) on the drawn speed: average the analytic answer over
    # the drawn speeds' trims
    theta_trim = np.array([trim(aerosonde, v).x[3] for v in np.linspace(22.0, 28.0, 61)])
    p_pitch = float(np.mean(ndtr((-0.1 - theta_trim) / 0.05) + 1 - ndtr((0.1 - theta_trim)
                                                                        / 0.05)))
    pitch = result.exceedance_of("|pitch|")
    assert pitch.low <= p_pitch <= pitch.high, (p_pitch, pitch)
    speed = result.exceedance_of("airspeed")
    assert speed.low <= 1 / 3 <= speed.high, speed
    assert 0.1 < p_pitch < 0.3 and speed.runs == 1500  # a case far from 0 and 1
    # the columns the events are read from are the drawn quantities themselves
    np.testing.assert_allclose(result.table["min_airspeed_mps"],
                               result.table["trim_airspeed_mps"], atol=5e-3)


def test_divergence_is_flagged_with_its_time(aerosonde):
    """A step that doubles the pitch angle (forces do not depend on it) takes it from 0.01 rad
    out of the physical range |theta| <= pi at step 9 (0.01 * 2**9 = 5.12): the run departs,
    reports t = 0.09 s and its statistics stop at step 8 (finite numbers beyond the range are a
    tumbling model's nonsense, not statistics)."""
    x, u = ca.SX.sym("x", 4), ca.SX.sym("u", 2)
    p, dt = ca.SX.sym("p", len(aerosonde.p)), ca.SX.sym("dt")
    doubling = ca.Function("doubling", [x, u, p, dt], [ca.vertcat(x[:3], 2 * x[3])])
    point = trim(aerosonde)
    run = run_function(doubling, aerosonde, structure_of(aerosonde), 40, 10, False)
    x0 = np.array([*point.x[:3], 0.01])
    stats, hist = run(x0, point.u, aerosonde.p, np.zeros((2, 40)), 0.01,
                      [np.inf, np.inf, -np.inf, np.inf])
    stats, hist = np.asarray(stats).ravel(), np.asarray(hist)
    assert stats[-1] == pytest.approx(0.09, abs=1e-12)
    assert stats[0] == 0.01 * 2**8  # max |theta| before the departure, exactly
    assert hist.shape == (5, 5) and hist[0, 2] == 0.01 * 2**20


# ----------------------------------------------------------------------------- sampling


def test_draws_reproducible_from_seed_and_run(tmp_path, aerosonde):
    disp = _dispersions(tmp_path, GUSTY, aerosonde)
    a, b = disp.sample(3, 17), disp.sample(3, 17)
    assert a == b and a != disp.sample(3, 18) and a != disp.sample(4, 17)
    assert set(a.offsets) == {"params.mass", "params.C_m_alpha", "initial.theta",
                              "trim.airspeed", "gust.intensity"}


def test_truncated_normal_matches_scipy():
    dist = Distribution("truncnormal", mean=0.1, sd=0.2, low=-0.1, high=0.2)
    rng = np.random.default_rng(0)
    draws = np.array([dist.draw(rng) for _ in range(20000)])
    ref = truncnorm((-0.1 - 0.1) / 0.2, (0.2 - 0.1) / 0.2, loc=0.1, scale=0.2)
    assert draws.min() >= -0.1 and draws.max() <= 0.2
    assert abs(draws.mean() - ref.mean()) < 4 * ref.std() / math.sqrt(len(draws))
    assert abs(draws.std() - ref.std()) < 0.02 * ref.std()


# ----------------------------------------------------------------------------- bad files


@pytest.mark.parametrize("text, key", [
    ("[params.mass]\ndist = 'uniform'\nlow = -0.1\n", "params.mass.high"),
    ("[params.mass]\ndist = 'normal'\nsd = 0\n", "params.mass.sd"),
    ("[params.mass]\ndist = 'gamma'\nsd = 0.1\n", "params.mass.dist"),
    ("[params.mass]\ndist = 'uniform'\nlow = 0.2\nhigh = 0.1\n", "params.mass.low"),
    ("[params.mas]\ndist = 'normal'\nsd = 0.1\n", "params.mas"),
    ("[params.mass]\ndist = 'normal'\nsd = 0.1\nlow = 0\n", "params.mass.low"),
    ("[params.mass]\ndist = 'uniform'\nlow = -20\nhigh = 0\nrelative = false\n", "params.mass"),
    ("[params.C_L_alpha_dot]\ndist = 'normal'\nsd = 0.1\n", "params.C_L_alpha_dot"),
    ("[params.mass]\ndist = 'uniform'\nlow = -1.5\nhigh = 0\n", "params.mass.low"),
    ("[initial.h]\ndist = 'normal'\nsd = 0.1\n", "initial.h"),
    ("[gust]\nintensity = -1\n", "gust.intensity"),
    ("[gust]\nintensity = { dist = 'normal', sd = 1.0 }\n", "gust.intensity"),
    ("[limits]\nload_factor_max = 'high'\n", "limits.load_factor_max"),
    ("[limits]\nbank_deg = 30\n", "limits.bank_deg"),
    ("seed = -1\n", "seed"),
    ("sede = 1\n", "sede"),
    ("[params.mass]\ndist = 'truncnormal'\nsd = 0.01\nlow = 0.5\nhigh = 0.6\n", "params.mass"),
])
def test_bad_dispersion_file_names_file_and_key(tmp_path, aerosonde, text, key):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(DispersionError) as info:
        load_dispersions(path, aerosonde)
    message = str(info.value)
    assert str(path) in message and f"'{key}'" in message and "\n" not in message


def test_unreadable_dispersion_files(tmp_path, aerosonde):
    with pytest.raises(DispersionError, match="file not found"):
        load_dispersions(tmp_path / "missing.toml", aerosonde)
    bad = tmp_path / "bad.toml"
    bad.write_text("[params.mass\n")
    with pytest.raises(DispersionError, match="not valid TOML"):
        load_dispersions(bad, aerosonde)
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)
    with pytest.raises(DispersionError, match="FIFO"):
        load_dispersions(fifo, aerosonde)
    with pytest.raises(DispersionError, match="not a parameter of airframe"):
        parse_dispersions({"params": {"arm": {"dist": "normal", "sd": 0.1}}}, aerosonde)


def test_impossible_draw_stops_the_study(tmp_path, aerosonde):
    disp = _dispersions(tmp_path, "[params.mass]\ndist = 'normal'\nsd = 3.0\n", aerosonde)
    spec = build_spec(aerosonde, disp, runs=20, duration=0.05, chunk_size=20)
    with pytest.raises(MonteCarloError, match=r"run \d+ drew an impossible airframe.*mass"):
        run_study(spec, progress=False)


# ----------------------------------------------------------------------------- models, CLI


def test_hybrid_study_runs_the_shipped_correction(tmp_path, aerosonde):
    weights, identified = shipped_correction("aerosonde")
    disp = _dispersions(tmp_path, GUSTY, identified)
    physics = run_study(build_spec(identified, disp, runs=6, duration=2.0, chunk_size=6),
                        progress=False)
    hybrid = run_study(build_spec(identified, disp, runs=6, duration=2.0, chunk_size=6,
                                  weights=weights), progress=False)
    assert hybrid.spec.model.startswith("hybrid (aerosonde_safe.npz")
    assert np.all(np.isfinite(hybrid.history))
    assert not np.array_equal(physics.history, hybrid.history)  # the correction acts
    with pytest.raises(MonteCarloError, match="takes time t"):
        build_spec(aerosonde, disp, runs=2, duration=1.0, dt=0.005,
                   weights=shipped_weights("aerosonde", "paper"))


def test_cli_command_writes_results_and_resumes(tmp_path, capsys):
    disp = tmp_path / "d.toml"
    disp.write_text(GUSTY)
    parser = argparse.ArgumentParser(prog="uavdyn")
    add_parser(parser.add_subparsers(dest="command"))
    out = tmp_path / "mc"
    argv = ["montecarlo", "--airframe", "aerosonde", "--runs", "30", "--duration", "2",
            "--dispersions", str(disp), "--mission", "sysid_doublet", "--dt", "0.01",
            "--chunk-size", "10", "--out", str(out), "--no-progress"]
    args = parser.parse_args(argv)
    assert args.func(args) == 0
    text = capsys.readouterr().out
    assert "30 computed" in text and "P(|pitch| > 30 deg)" in text
    assert len((out / "summary.csv").read_text().splitlines()) == 31
    assert "# Monte-Carlo study: aerosonde, 30 runs x 2 s" in (out / "summary.md").read_text()
    args = parser.parse_args(argv)
    assert args.func(args) == 0
    text = capsys.readouterr().out
    assert "0 computed" in text and "3 chunk(s) reused" in text
    bad = tmp_path / "bad.toml"
    bad.write_text("[params.mass]\ndist = 'normal'\n")
    args = parser.parse_args([*argv[:8], str(bad), *argv[9:]])
    with pytest.raises(DispersionError, match=r"bad.toml: key 'params.mass.sd' is required"):
        args.func(args)
    with pytest.raises(SystemExit):  # --workers and --scheduler exclude each other
        parser.parse_args([*argv, "--workers", "2", "--scheduler", "tcp://x:1"])
    args = parser.parse_args([*argv, "--workers-write"])  # meant for --scheduler only
    with pytest.raises(MonteCarloError, match="--workers-write applies to --scheduler"):
        args.func(args)
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "mine.txt").write_text("user data")
    args = parser.parse_args([*argv[:-2], str(foreign), "--no-progress"])
    with pytest.raises(ValueError, match="not a uavdyn output"):
        args.func(args)


def test_the_study_key_covers_every_field_that_changes_a_run(tmp_path, aerosonde):
    """Resuming after an edit of the airframe's limits reused every chunk (the key hashed the
    parameters only). The key now hashes the whole airframe and the step Function: changing
    any one of these makes another study, and a resume into the old folder is refused."""
    disp = _dispersions(tmp_path, '[params.mass]\ndist = "uniform"\nlow = -0.1\nhigh = 0.1\n',
                        aerosonde)

    def limited(**limits):
        return dataclasses.replace(aerosonde, limits={**aerosonde.limits, **limits})

    def spec(af=aerosonde, **kw):
        args = dict(runs=4, duration=1.0, dt=0.01, chunk_size=4)
        args.update(kw)
        return build_spec(af, disp, **args)

    base = spec()
    assert spec().key == base.key  # and it is stable
    variants = {
        "elevator travel": spec(limited(elevator=(-0.13, 0.13))),
        "elevator rate": spec(limited(elevator_rate=0.5)),
        "throttle travel": spec(limited(throttle=(0.1, 0.9))),
        "elevator lag": spec(aerosonde.replace(tau_elevator=0.05)),
        "elevator delay": spec(aerosonde.with_delays(elevator=2)),
        "a coefficient": spec(aerosonde.replace(C_m_q=-30.0)),
        "mission": spec(mission="3211"),
        "step size": spec(dt=0.005),
        "seed": spec(seed=7),
        "airspeed": spec(airspeed=22.0),
        "chunk size": spec(chunk_size=2),
        "vector math": dataclasses.replace(base, vector_math=True),
    }
    keys = {name: v.key for name, v in variants.items()}
    assert all(k != base.key for k in keys.values()), keys
    assert len(set(keys.values())) == len(keys)
    out = tmp_path / "study"
    run_study(base, out, progress=False)
    with pytest.raises(MonteCarloError, match="holds another Monte-Carlo study"):
        run_study(variants["elevator travel"], out, progress=False)
    # the runs numbers were unchanged by renaming the airframe: same key
    assert spec(dataclasses.replace(aerosonde, name="my copy")).key == base.key


@pytest.mark.parametrize("name", ["aerosonde_pm15", "aerosonde_gusty", "f450_pm15",
                                  "trainer_pm15_gusty"])
def test_the_projects_dispersion_files_run_a_two_run_study_to_the_end(name, tmp_path):
    """Two runs of a narrow dispersion can agree to the last digits in a metric; the histogram
    of that metric used to crash the report (numpy cannot bin a zero-width range) after the
    chunks were written."""

    from uavdyn.airframes import load_airframe

    af = load_airframe(name.split("_")[0] if not name.startswith("trainer") else
                       Path(__file__).resolve().parents[1] / "examples" / "trainer.toml")
    disp = load_dispersions(name, af)  # shipped package data, addressed by name
    out = tmp_path / "out"
    run_study(build_spec(af, disp, runs=2, duration=1.0, dt=0.01, chunk_size=2), out,
              progress=False)
    assert (out / "figures" / "distributions.png").stat().st_size > 1000
    assert (out / "summary.md").is_file()


def test_shipped_dispersion_files_are_addressed_by_name_from_any_folder(tmp_path, monkeypatch,
                                                                         aerosonde):
    """From a wheel install the README's example named a file of the source tree; the
    examples are package data now, loaded by name wherever the command runs."""
    from uavdyn.montecarlo.dispersions import DispersionError, shipped_dispersions

    monkeypatch.chdir(tmp_path)
    assert {"aerosonde_pm15", "aerosonde_gusty", "f450_pm15"} <= set(shipped_dispersions())
    disp = load_dispersions("aerosonde_pm15", aerosonde)
    assert "mass" in disp.params and "aerosonde_pm15" in disp.origin
    with pytest.raises(DispersionError, match="aerosonde_pm1:.*shipped example: "
                                              "aerosonde_gusty, aerosonde_pm15"):
        load_dispersions("aerosonde_pm1", aerosonde)


def test_a_closed_loop_study_keeps_an_unstable_airframe_inside_its_ranges(tmp_path, aerosonde):
    """With C_m_alpha = +1 the fixed wing is statically unstable (a real pole at +1.4 1/s):
    flown open loop every run departs, and the summary says so in one line; flown closed loop
    (an LQR at the nominal trim, stated with its gain) no run departs and the pitch stays
    within a few degrees of trim."""
    import warnings

    from uavdyn.montecarlo.report import departure_warning, summary_markdown

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a positive C_m_alpha is flagged as implausible
        unstable = aerosonde.replace(C_m_alpha=1.0)
    disp = _dispersions(tmp_path, '[params.mass]\ndist = "uniform"\nlow = -0.1\nhigh = 0.1\n',
                        unstable)
    results = {}
    for closed in (False, True):
        spec = build_spec(unstable, disp, runs=8, duration=10.0, dt=0.01, chunk_size=8,
                          closed_loop=closed)
        results[closed] = run_study(spec, progress=False)
    open_loop, closed_loop = results[False], results[True]
    assert open_loop.table["diverged"].sum() == 8
    assert "8 of 8 runs departed flown open loop" in summary_markdown(open_loop)
    assert closed_loop.table["diverged"].sum() == 0 and departure_warning(closed_loop) is None
    assert np.nanmax(closed_loop.table["max_abs_pitch_deg"]) < 10.0
    assert closed_loop.spec.feedback.shape == (2, 4) and open_loop.spec.key != \
        closed_loop.spec.key
    assert "closed loop: u = trim + deviation - K (x - trim)" in summary_markdown(closed_loop)
