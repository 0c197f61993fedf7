"""Benchmark of the exported C controller (``uavdyn export-c --mpc``) beside the Python one, in
one run: the Aerosonde hybrid (shipped correction, exact ReLU) at horizon 20, the pitch step
against the exported physics step. The bundle is exported and built with ``make bench``; its
harness flies the closed loop ``--repeats`` times and times every ``mpc_step`` and its phases
(linearisation, condensing, QP) with ``clock_gettime(CLOCK_MONOTONIC)``, and the whole step's
thread CPU time (``CLOCK_THREAD_CPUTIME_ID``: without the time other processes held the core):
median, p99, max.
The Python controller flies the same closed loop (its per-solve wall times, same statistics)
and its solves are replayed in the project's timing harness
(:func:`uavdyn.evaluation.timing.interleaved_timing`). The two closed loops' largest
difference and the machine load before and after are recorded. Prints JSON.

The controller is measured twice: with the condensing generated from its matrix graph (the
default, ``c``) and expanded to scalar code (``--condensing sx``, ``c_sx``).

Usage: ``python analysis/bench_mpc_c.py [--repeats 20] [--no-sx] [--out FILE]``
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np

from uavdyn.deploy.mpc_bundle import example_closed_loop, export_mpc_bundle, python_closed_loop
from uavdyn.evaluation.timing import interleaved_timing
from uavdyn.mpc import MPCConfig, RTIController, TrackingProblem
from uavdyn.mpc.study import prediction_models

ACADOS_TARGET_MS = 0.21  # the issue's figure for tuned acados' C on this problem (not re-measured)


def load() -> list[float]:
    return [round(v, 2) for v in os.getloadavg()]


def stats_us(seconds) -> dict:
    t = np.asarray(seconds, float) * 1e6
    return {"median_us": float(np.median(t)), "p99_us": float(np.percentile(t, 99)),
            "max_us": float(np.max(t)), "min_us": float(np.min(t)), "solves": int(len(t))}


def c_side(problem, example, folder: Path, repeats: int, condensing: str = "mx"
           ) -> tuple[dict, np.ndarray, np.ndarray]:
    """Export (``condensing`` as in :func:`export_mpc_bundle`), build, run the example (closed
    loop) and the timing harness."""
    out = export_mpc_bundle(problem, example, folder / f"mpc_{condensing}",
                            condensing=condensing)
    t0 = time.perf_counter()
    subprocess.run(["make", "-C", str(out), "example", "bench"], check=True,
                   capture_output=True)
    build_s = time.perf_counter() - t0
    csv = subprocess.run([str(out / "example")], check=True, capture_output=True,
                         text=True).stdout.strip().splitlines()[1:]
    rows = [r.split(",") for r in csv]
    states = np.array([[float(v) for v in r[1:6]] for r in rows])
    controls = np.array([[float(v) for v in r[6:8]] for r in rows[:-1]])
    timing = json.loads(subprocess.run([str(out / "bench"), str(repeats)], check=True,
                                       capture_output=True, text=True).stdout)
    timing["build_s"] = build_s
    timing["cflags"] = "-std=c99 -O2 -Wall -Wextra -Werror -O3 -DMPC_TIMING (make bench)"
    timing["generated_c_bytes"] = sum(f.stat().st_size for f in out.glob("mpc_*.c")
                                      if f.name != "mpc_rti.c")
    timing["condensing_code"] = condensing
    return timing, states, controls


def python_side(problem, example, repeats: int) -> tuple[dict, np.ndarray, np.ndarray]:
    """The Python controller on the same closed loop: per-solve wall times over ``repeats``
    flights, and its solves replayed in the timing harness."""
    mpc = RTIController(problem)
    times, cpu, solves = [], [], []
    real_solve = mpc.solve

    def keep(*args, **kwargs):  # the thread's CPU time of each solve, and its arguments
        solves.append((args, kwargs))
        t0 = time.thread_time()
        out = real_solve(*args, **kwargs)
        cpu.append(time.thread_time() - t0)
        return out

    mpc.solve = keep
    res = None
    for _ in range(repeats):
        res = python_closed_loop(problem, example, mpc)
        times.extend(res.solve_times_s)
    mpc.solve = real_solve
    solves = solves[:example.steps]

    def replay():
        mpc.reset()
        for args, kwargs in solves:
            real_solve(*args, **kwargs)

    harness = interleaved_timing({"python_rti_replay": replay}, repeats=15)["python_rti_replay"]
    out = {**stats_us(times), "cpu": stats_us(cpu),
           "harness_replay_per_solve_us": {"min": harness.min_s / len(solves) * 1e6,
                                           "median": harness.median_s / len(solves) * 1e6,
                                           "repeats": harness.repeats},
           "what": "RTIController.solve wall time (perf_counter) over the closed-loop flights "
                   "(cpu: the thread's CPU time, time.thread_time, of the same solves); the "
                   "harness replays the first flight's solves in order (reset first)"}
    return out, res.states, res.controls


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20, help="closed loops timed")
    parser.add_argument("--out", default=None, help="JSON file")
    parser.add_argument("--no-sx", dest="sx", action="store_false",
                        help="skip the scalar-code condensing (its build takes minutes)")
    args = parser.parse_args()
    if shutil.which("make") is None or shutil.which("cc") is None:
        raise SystemExit("bench_mpc_c needs make and a C compiler (cc)")
    before = load()
    setup = prediction_models("aerosonde", mode="rti", models=("hybrid",))
    model = setup.models["hybrid"]
    config = MPCConfig(horizon=20, mode="rti")
    problem = TrackingProblem(model.model, model.trim.u, config,
                              speed_trim=max(model.trim.airspeed, 1.0))
    example = example_closed_loop(setup.plant_airframe, config.dt)
    with tempfile.TemporaryDirectory() as tmp:
        c, c_states, c_controls = c_side(problem, example, Path(tmp), args.repeats)
        c_sx, sx_states, sx_controls = (c_side(problem, example, Path(tmp), args.repeats, "sx")
                                        if args.sx else (None, None, None))
    py, py_states, py_controls = python_side(problem, example, args.repeats)
    after = load()
    doc = {
        "benchmark": "bench_mpc_c", "casadi": ca.__version__, "cpu_count": os.cpu_count(),
        "problem": {"prediction": model.description, "horizon": config.horizon,
                    "dt": config.dt, "scenario": example.scenario.name,
                    "plant": f"RK4 physics step of {setup.plant_airframe.name} (exported)",
                    "solves_per_flight": example.steps, "qp_variables": problem.nu * problem.N
                    + problem.ns},
        "c": c, "c_sx": c_sx, "python": py,
        "c_median_speedup_over_python": py["median_us"] / c["mpc_step"]["median_us"],
        "closed_loop_max_abs_diff": {
            "states": float(np.max(np.abs(c_states - py_states))),
            "controls": float(np.max(np.abs(c_controls - py_controls))),
            **({} if sx_states is None else {
                "states_sx": float(np.max(np.abs(sx_states - py_states))),
                "controls_sx": float(np.max(np.abs(sx_controls - py_controls)))})},
        "acados_target_ms": ACADOS_TARGET_MS,
        "acados_note": "the issue's figure for tuned acados' generated C on this problem; "
                       "acados is not installed here, so it is not re-measured in this run",
        "load_before": before, "load_after": after,
    }
    text = json.dumps(doc, indent=2)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
