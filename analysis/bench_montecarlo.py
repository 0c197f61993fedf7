"""Benchmark of Monte-Carlo studies (issues 15 and 32): 10,000 runs x 60 s of the Aerosonde
with +-15 % dispersions of its stability derivatives and mass terms at dt 0.01 s, physics and
hybrid (the shipped safe correction on the identified Aerosonde it was trained on), on 1 and 2
workers, against a sequential Python loop over the library's single-run C loop
(``compiled_rollout``); printed as JSON (and written with ``--out``).

Usage: ``python analysis/bench_montecarlo.py [--runs 10000] [--duration 60] [--loop-runs 200]
[--no-vector-math] [--out docs/benchmarks/bench_montecarlo.json]``.

Every study is timed as the command runs it (``run_study`` into a fresh output folder: chunk
files, table, envelopes, figures, summary), with the compile cache already filled (the compile
time is measured once, apart). The sequential loop is timed on ``--loop-runs`` runs and
extrapolated linearly to ``--runs`` (its per-run cost does not depend on the run count); its
statistics are checked against the batched runs'. Each configuration also records where its
wall time went: until the first chunk was stored, from the first to the last, and after the last
(statistics and files). ``loop_costs`` times, in one harness, a chunk's compiled loop alone per
run-step against the single-run C loop of the same step per step. ``vector_math`` repeats the
studies on 1 and 2 workers with the chunk loop's maths functions in glibc's vector library
(``--vector-math``) and records how far its table lies from the bit-for-bit route's.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from uavdyn.integrate import compiled_rollout
from uavdyn.integrate.lanes import vector_math_unavailable
from uavdyn.learned import hybrid_step, shipped_correction
from uavdyn.linear import point_params, trim
from uavdyn.model import NUMPY_OPS, body_forces
from uavdyn.montecarlo import build_spec, load_dispersions, run_study
from uavdyn.montecarlo.chunks import compiled_batch

ROOT = Path(__file__).resolve().parents[1]
DISPERSIONS = "aerosonde_pm15"  # shipped with the package (uavdyn/montecarlo/shipped/)
TARGETS_S = {"physics": 20.0, "hybrid": 25.0}  # issue 32, on 2 workers


def _load() -> list[float]:
    return [round(v, 2) for v in os.getloadavg()]


def _study(spec, workers: int, threads: int, tmp: Path, label: str) -> dict:
    load_before = _load()
    out = tmp / label
    arrivals: list[float] = []
    t0, cpu0 = time.perf_counter(), time.process_time()
    result = run_study(spec, out=out, workers=workers, threads=threads, progress=False,
                       on_chunk=lambda _: arrivals.append(time.perf_counter()))
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    table = result.table
    chunk_wall = [w for w, _ in _chunk_seconds(out)]
    return {
        "workers": workers, "threads": threads,
        "engine": "Dask LocalCluster" if workers > 1 else "this process",
        "wall_s": round(wall, 2), "runs_per_s": round(spec.runs / wall, 1),
        "us_per_run_step": round(wall / (spec.runs * spec.n_steps) * 1e6, 4),
        "chunk_wall_s_sum": round(sum(chunk_wall), 2),
        "chunk_cpu_s_sum": round(sum(c for _, c in _chunk_seconds(out)), 2),
        "cpu_s_this_process": round(cpu, 2),
        # where the wall time goes: up to the first stored chunk (start-up, Dask cluster and
        # worker imports included, plus that chunk), between the first and the last, and after
        # the last (statistics, table, figures, summary: serial)
        "first_chunk_stored_after_s": round(arrivals[0] - t0, 2),
        "first_to_last_chunk_s": round(arrivals[-1] - arrivals[0], 2),
        "after_last_chunk_s": round(t0 + wall - arrivals[-1], 2),
        "serial_s_beyond_chunk_compute": round(wall - sum(chunk_wall), 2)
        if workers == 1 and threads == 1 else None,
        "diverged": int(np.sum(table["diverged"] == 1)),
        "trim_failed": int(np.sum(table["trim_ok"] == 0)),
        "max_abs_pitch_deg_p50_p95": [round(float(np.percentile(
            table["max_abs_pitch_deg"], q)), 4) for q in (50, 95)],
        "load_average_1_5_15_before": load_before, "load_average_after": _load(),
        "_result": result,
    }


def _chunk_seconds(folder: Path) -> list[tuple[float, float]]:
    """(wall, CPU) seconds each chunk took where it was computed."""
    out = []
    for path in sorted((folder / "chunks").glob("chunk_*.npz")):
        with np.load(path, allow_pickle=False) as z:
            out.append((float(z["seconds"][0]), float(z["seconds"][1])))
    return out


def _median_seconds(call, repeats: int = 3) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        call()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def _loop_costs(spec, n_runs: int) -> dict:
    """One harness: the chunk's compiled loop alone (``n_runs`` runs from the nominal trim:
    step, signals, statistics, history) per run-step, against the library's single-run C
    loop of the same step (``compiled_rollout``: the step alone) per step."""
    point = trim(spec.airframe, spec.airspeed)
    p = point_params(spec.airframe, point)
    model = spec.discrete_model()
    x0 = model.layout.states(np.asarray(point.x, float)[:4], point.u, p, spec.dt)[0]
    u0 = np.asarray(point.u, float)
    args = [np.tile(x0[:, None], (1, n_runs)), np.tile(u0[:, None], (1, n_runs)),
            np.tile(p[:, None], (1, n_runs)), spec.deviations.T]
    args += [np.zeros((3, spec.n_steps * n_runs))] if spec.gusts else []
    args += [spec.dt, np.asarray(spec.limits, float)]
    args += [np.tile(np.asarray(point.x, float)[:4, None], (1, n_runs))] \
        if spec.feedback is not None else []
    batch = compiled_batch(spec, n_runs, 1)
    batch(*args)
    batched = _median_seconds(lambda: batch(*args)) / (n_runs * spec.n_steps)
    sim = compiled_rollout(model, spec.n_steps)
    bounds = np.asarray(spec.airframe.control_bounds(), float)
    controls = np.clip(u0 + spec.deviations, bounds[:, 0], bounds[:, 1]).T
    sim(x0, controls, p, spec.dt)
    single = _median_seconds(lambda: [sim(x0, controls, p, spec.dt) for _ in range(20)]) \
        / (20 * spec.n_steps)
    return {"chunk_loop_us_per_run_step": round(batched * 1e6, 4),
            "single_run_c_loop_us_per_step": round(single * 1e6, 4),
            "chunk_loop_over_single_run_c_loop": round(batched / single, 3),
            "what": f"{n_runs} runs from the nominal trim, median of 3 calls; the chunk loop "
                    "also evaluates each sample's signals, statistics and history, the "
                    "single-run loop (uavdyn.integrate.compiled_rollout) the step alone"}


def _vector_math(spec, reference, tmp: Path, model: str) -> dict:
    """The same study with ``vector_math`` (glibc's libmvec) on 1 and 2 workers, its chunk
    loop's cost, and how far its table lies from the bit-for-bit route's (``reference``)."""
    why = vector_math_unavailable()
    if why:
        return {"available": False, "why": why}
    vector = dataclasses.replace(spec, vector_math=True)
    compiled_batch(vector, spec.chunk_size, 1)
    one = _study(vector, 1, 1, tmp, f"{model}_1_vector")
    two = _study(vector, 2, 1, tmp, f"{model}_2_vector")
    found = one.pop("_result").table.data
    two.pop("_result")
    ref = reference.table.data
    finite = np.isfinite(ref)
    rel = np.abs(found - ref)[finite] / np.maximum(np.abs(ref[finite]), np.finfo(float).tiny)
    return {"available": True, "one_worker": one, "two_workers": two,
            "meets_target_on_two_workers": two["wall_s"] <= TARGETS_S[model],
            "loop_costs": _loop_costs(vector, spec.chunk_size),
            "table_max_relative_difference_to_bitwise_route": float(rel.max()),
            "same_runs_trimmed_and_diverged": bool(np.array_equal(np.isnan(found),
                                                                  np.isnan(ref)))}


def _sequential_loop(spec, runs: int, step) -> tuple[float, np.ndarray]:
    """What a user would write: per run, draw, trim, one call of the compiled single-run
    rollout, NumPy statistics. Returns (wall s, max |pitch| in deg per run)."""
    sim = compiled_rollout(step, spec.n_steps)
    structure = spec.structure
    airframe0 = spec.airframe
    names = airframe0.param_names
    i_m, i_g = names.index("mass"), names.index("gravity")
    max_pitch = np.empty(runs)
    t0 = time.perf_counter()
    for run in range(runs):
        draw = spec.dispersions.sample(spec.seed, run)
        airframe = airframe0.replace(**draw.params(spec.dispersions, airframe0))
        point = trim(airframe, spec.airspeed)
        p = airframe.p
        controls = point.u + spec.deviations
        # the step's whole state at trim: actuators, buffers and command memory at rest
        z0 = step.initial_state(point.x, point.u, p, spec.dt)
        x = sim(z0, controls.T, p, spec.dt)[:4]
        x = np.hstack([point.x[:, None], x])
        if not np.all(np.isfinite(x)):
            raise RuntimeError(f"run {run} diverged in the sequential loop")
        u = np.hstack([controls[:1].T, controls.T])
        _, Z, _, alpha, V, _ = body_forces(structure, x, u, p, NUMPY_OPS)
        n = -Z / (p[i_m] * p[i_g])
        max_pitch[run] = np.degrees(np.abs(x[3]).max())
        _ = (alpha.max(), V.min(), n.max(), n.min())
    return time.perf_counter() - t0, max_pitch


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10_000)
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--dt", type=float, default=0.01)
    parser.add_argument("--chunk-size", type=int, default=200)
    parser.add_argument("--loop-runs", type=int, default=200,
                        help="runs of the sequential loop, extrapolated to --runs")
    parser.add_argument("--skip-hybrid", action="store_true")
    parser.add_argument("--no-threads", dest="threads", action="store_false",
                        help="skip the 1-worker, 2-thread configuration")
    parser.add_argument("--no-vector-math", dest="vector_math", action="store_false",
                        help="skip the vector-math configurations")
    parser.add_argument("--out", default=None, help="also write the JSON here")
    parser.add_argument("--shared", action="store_true",
                        help="say in the JSON that another job shared the machine")
    args = parser.parse_args(argv)
    # the shipped safe correction and the identified Aerosonde it was trained on: both models
    # fly the same airframe, so the ratio is the cost of the correction alone
    weights, airframe = shipped_correction("aerosonde")
    dispersions = load_dispersions(DISPERSIONS, airframe)
    doc: dict = {
        "benchmark": "montecarlo", "airframe": "aerosonde", "runs": args.runs,
        "duration_s": args.duration, "dt_s": args.dt, "steps_per_run": None,
        "dispersions": DISPERSIONS,
        "dispersed": dispersions.describe(), "input": "doublet (2 deg elevator at 1 s)",
        "chunk_size": args.chunk_size, "cpu_count": os.cpu_count(),
        "targets_s": TARGETS_S,
        "timed": "run_study into a fresh output folder (chunk files, table, envelopes, figures, "
                 "summary), compile cache filled beforehand; Dask LocalCluster start-up "
                 "included in the 2-worker times",
        "note": ("2-core machine shared with another job during the measurement: timings are "
                 "noisy" if args.shared else "no other job of ours ran on the machine")
                + "; load averages are recorded beside each",
        "model_airframe": airframe.name,
    }
    models = {"physics": None}
    if not args.skip_hybrid:
        try:
            hybrid_step(weights, airframe, compile=False)
            models["hybrid"] = weights
        except Exception as exc:  # reported, never faked
            doc["hybrid_error"] = f"{type(exc).__name__}: {exc}"
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        for model, weights in models.items():
            spec = build_spec(airframe, dispersions, runs=args.runs, duration=args.duration,
                              dt=args.dt, weights=weights, chunk_size=args.chunk_size)
            doc["steps_per_run"] = spec.n_steps
            entry: dict = {"model": spec.model}
            t0 = time.perf_counter()
            for n in sorted({spec.chunk_runs(c)[1] - spec.chunk_runs(c)[0]
                             for c in range(spec.n_chunks)}):
                compiled_batch(spec, n, 1)
            entry["build_and_compile_s"] = round(time.perf_counter() - t0, 2)
            one = _study(spec, 1, 1, tmp, f"{model}_1")
            threads = _study(spec, 1, 2, tmp, f"{model}_1x2") if args.threads else None
            two = _study(spec, 2, 1, tmp, f"{model}_2")
            reference = one.pop("_result")
            same = True
            for other in (threads, two):
                if other is not None:
                    found = other.pop("_result")
                    same &= (np.array_equal(reference.table.data, found.table.data,
                                            equal_nan=True)
                             and np.array_equal(reference.history, found.history,
                                                equal_nan=True))
            entry.update({"one_worker": one, "one_worker_two_threads": threads,
                          "two_workers": two,
                          "ratio_two_workers_to_one": round(one["wall_s"] / two["wall_s"], 2),
                          "ratio_two_threads_to_one": round(one["wall_s"] / threads["wall_s"], 2)
                          if threads else None,
                          "all_configurations_bitwise_identical": bool(same),
                          "best_wall_s": min(e["wall_s"] for e in (one, threads, two) if e)})
            entry["meets_target_on_two_workers"] = two["wall_s"] <= TARGETS_S[model]
            entry["loop_costs"] = _loop_costs(spec, args.chunk_size)
            entry["vector_math"] = _vector_math(spec, reference, tmp, model) \
                if args.vector_math else None
            loop_runs = min(args.loop_runs, args.runs)
            step = spec.discrete_model()
            loop_wall, loop_pitch = _sequential_loop(spec, loop_runs, step)
            extrapolated = loop_wall * args.runs / loop_runs
            batched = reference.table["max_abs_pitch_deg"][:loop_runs]
            entry["sequential_loop"] = {
                "runs_measured": loop_runs, "wall_s_measured": round(loop_wall, 2),
                "wall_s_extrapolated_to_runs": round(extrapolated, 1),
                "extrapolated": loop_runs < args.runs,
                "max_abs_pitch_max_difference_deg": float(np.max(np.abs(loop_pitch - batched))),
                "what": "per run: draw, Airframe.replace, trim, one call of the compiled "
                        "single-run rollout (uavdyn.integrate.compiled_rollout), NumPy "
                        "statistics",
                "ratio_loop_to_one_worker": round(extrapolated / one["wall_s"], 2),
                "ratio_loop_to_two_workers": round(extrapolated / two["wall_s"], 2)}
            doc[model] = entry
            print(f"{model}: 1 worker {one['wall_s']} s, 2 workers {two['wall_s']} s, loop "
                  f"{extrapolated:.0f} s (extrapolated)", file=sys.stderr)
    text = json.dumps(doc, indent=2, default=lambda v: None if isinstance(v, float) and
                      math.isnan(v) else str(v))
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
