"""Long rollouts against the tight C loop of the same step (issue 32, item 1), in one run.

For the shipped identified Aerosonde's physics step and its hybrid step (the shipped safe
correction on top), each at its trim with a doublet every 5 s, 100 000 samples of 0.01 s:

* ``c_loop``: the step's CasADi-generated C called in a plain C loop by a small harness
  compiled with the library's flags (the floor: what a C programmer would write);
* ``compiled_rollout``: :func:`uavdyn.integrate.compiled_rollout` called from Python on NumPy
  arrays (what the library's free runs, ``simulate`` and the evaluation use);
* ``mapaccum``: the previous route, CasADi's compiled ``mapaccum`` rollout called on NumPy
  arrays.

Per sample in microseconds, the median of ``--repeats`` calls each; the ratios are to the C
loop of the same run. The states of the two library routes are compared too (max abs
difference). Prints JSON; ``--out`` also writes it.

The C loops of the physics and the hybrid step are compiled into one program that runs them in
turn, pass after pass (``--repeats`` passes), and ``hybrid_over_physics_c_loop`` is the median
of the passes' ratios (each pass's pair under the same load; the ratios are listed). The C
loop at the trim holds the trim command (no doublet), so an exact-hover trim keeps the physics
at zero velocity and pitch, where the C library's ``sin``/``cos`` take their shortcut; with
``--dataset`` both steps are also timed on recorded flight (back-to-back ``--window-s``
windows of the ``--split`` sorties, each started from its records, the recorded commands
applied: ``hybrid_over_physics_c_loop_recorded``), the states a prediction meets.

With ``--jsbsim`` (the ``jsbsim`` package installed) JSBSim's bundled Cessna 172 is timed per
simulated second beside them (:func:`jsbsim_anchor`), the anchor a user would pick otherwise.

Usage: ``python analysis/bench_rollout.py [--samples 100000] [--repeats 7] [--jsbsim]
[--airframe FILE --weights FILE [--airspeed V]] [--dataset DIR [--split test] [--window-s 1]]
[--out FILE]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from uavdyn.evaluation.c_loop import CLoop, LoopWork, recorded_workload


def library_us(call, args, n: int, repeats: int) -> tuple[float, np.ndarray]:
    """Median us per sample of ``call(*args)`` and its (last) states."""
    out = np.asarray(call(*args))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = np.asarray(call(*args))
        times.append((time.perf_counter() - t0) / n * 1e6)
    return statistics.median(times), out


def c_loop_times(models: dict, point, p: np.ndarray, dt: float, n: int, flights: list | None,
                 window_s: float, passes: int) -> tuple[dict, dict]:
    """Every model's step in one C program (:class:`CLoop`), timed in turn pass after pass:
    at the trim under the held trim command (``"trim"``) and, with ``flights``, over their
    recorded windows (``"recorded"``). Returns the median us per step of each
    ``(label, workload)`` and, per workload, the per-pass ratios hybrid / physics."""
    keys, works = [], []
    for label, model in models.items():
        x0 = np.asarray(model.initial_state(point.x, point.u, p, dt), float).ravel()
        keys.append((label, "trim"))
        works.append(LoopWork(model.function, x0, point.u, p, dt, n))
        if flights is not None:
            work = recorded_workload(model, flights, window_s, p)
            keys.append((label, "recorded"))
            works.append(LoopWork(model.function, work.starts, work.controls, p,
                                  flights[0].dt, work.steps))
    with CLoop(works) as loop:
        run = loop.run(passes)
    where = {key: i for i, key in enumerate(keys)}
    medians = {key: float(run.us_per_step[i]) for key, i in where.items()}
    ratios = {work: [float(r) for r in run.ratios(where[("hybrid", work)],
                                                  where[("physics", work)])]
              for work in ("trim", "recorded") if ("hybrid", work) in where}
    return medians, ratios


def jsbsim_anchor(simulated_s: float, repeats: int) -> dict:
    """JSBSim's bare ``run()`` loop (the Python binding, one call per step) on its bundled
    Cessna 172 (``c172x``: full six degrees of freedom, engine, gear, systems) at its default
    step, trimmed in level flight, for ``simulated_s`` simulated seconds: median us per
    simulated second. An anchor per simulated second, not a like-for-like model; JSBSim is an
    optional tool here (``pip install jsbsim``), never a dependency."""
    import jsbsim

    fdm = jsbsim.FGFDMExec(None)
    fdm.set_debug_level(0)
    scratch = tempfile.mkdtemp()  # the model's own output directive writes a CSV there
    fdm.set_output_path(scratch)
    fdm.load_model("c172x")
    fdm.disable_output()
    fdm["ic/h-sl-ft"], fdm["ic/vc-kts"], fdm["ic/gamma-deg"] = 3000, 100, 0
    fdm.run_ic()
    fdm["propulsion/set-running"] = -1
    dt = fdm.get_delta_t()
    steps = int(round(simulated_s / dt))
    times = []
    for _ in range(repeats):
        fdm.run_ic()
        t0 = time.perf_counter()
        for _ in range(steps):
            fdm.run()
        times.append((time.perf_counter() - t0) / (steps * dt) * 1e6)
    del fdm
    shutil.rmtree(scratch, ignore_errors=True)
    return {"model": "c172x", "version": jsbsim.__version__, "dt": dt,
            "us_per_simulated_second": statistics.median(times)}


def _cpu_model() -> str:
    """The CPU's model name (Linux), else what the platform module says."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--samples", type=int, default=100_000)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--out", help="also write the JSON here")
    ap.add_argument("--airframe", help="airframe file the weights were trained on (default: "
                    "the shipped identified Aerosonde)")
    ap.add_argument("--weights", help="correction weight file (default: the shipped one)")
    ap.add_argument("--airspeed", type=float, default=None,
                    help="trim airspeed in m/s (default 25, the Aerosonde's; the airframe's "
                         "own nominal speed with --airframe)")
    ap.add_argument("--dataset", help="also time both steps' C loops on recorded flight: "
                    "back-to-back windows of this dataset's --split sorties, each started "
                    "from its records and driven by the recorded commands")
    ap.add_argument("--split", default="test", help="the dataset's split to use (default test)")
    ap.add_argument("--window-s", type=float, default=1.0,
                    help="window length in seconds for --dataset (default 1)")
    ap.add_argument("--jsbsim", action="store_true",
                    help="also time JSBSim's c172x per simulated second (needs jsbsim)")
    args = ap.parse_args()

    from uavdyn.airframes import load_airframe
    from uavdyn.integrate import compile_function, compiled_rollout, physics_step, rollout
    from uavdyn.learned import load_weights
    from uavdyn.learned.hybrid import hybrid_step, shipped_correction, shipped_identified
    from uavdyn.linear import trim

    if (args.airframe is None) != (args.weights is None):
        ap.error("--airframe and --weights go together (weights are tied to an airframe)")
    if args.airframe is None:
        airframe = shipped_identified("aerosonde")
        weights, _ = shipped_correction("aerosonde")
        speed = 25.0 if args.airspeed is None else args.airspeed
    else:
        airframe, weights, speed = load_airframe(args.airframe), args.weights, args.airspeed
    dt, n = 0.01, args.samples
    flights = None
    if args.dataset:
        from uavdyn.flightdata import load_dataset
        flights = load_dataset(args.dataset).split(args.split)
        if not flights:
            ap.error(f"--dataset {args.dataset} has no {args.split} sorties")
    point = trim(airframe, speed)
    models = {"physics": physics_step(airframe),
              "hybrid": hybrid_step(weights, airframe, compile=False)}
    p = np.asarray(airframe.p, float)
    c_times, ratios = c_loop_times(models, point, p, dt, n, flights, args.window_s,
                                   args.repeats)
    results = {}
    for label, model in models.items():
        function = model.function
        x0 = np.asarray(model.initial_state(point.x, point.u, p, dt), float).ravel()
        controls = np.tile(point.u, (n, 1))
        phase = np.arange(n) % 500
        controls[phase < 25, 0] += 0.02  # an elevator doublet every 5 s
        controls[(phase >= 25) & (phase < 50), 0] -= 0.02
        floor = c_times[(label, "trim")]
        native = compiled_rollout(function, n)
        old = compile_function(rollout(function, n))
        call_args = (x0, controls.T, p, dt)
        t_native, x_native = library_us(native, call_args, n, args.repeats)
        t_old, x_old = library_us(old, call_args, n, args.repeats)
        results[label] = {
            "states": function.size1_in(0), "c_loop_us_per_sample": floor,
            "compiled_rollout_us_per_sample": t_native, "mapaccum_us_per_sample": t_old,
            "compiled_rollout_over_c_loop": t_native / floor,
            "mapaccum_over_c_loop": t_old / floor,
            "max_abs_difference": float(np.max(np.abs(x_native - x_old)))}
        if flights is not None:
            results[label]["c_loop_recorded_us_per_step"] = c_times[(label, "recorded")]
    anchor = None
    if args.jsbsim:
        anchor = jsbsim_anchor(n * dt, 3)
        for r in results.values():  # uavdyn per simulated second: per sample / dt
            r["compiled_rollout_us_per_simulated_second"] = r[
                "compiled_rollout_us_per_sample"] / dt
            r["jsbsim_over_compiled_rollout_per_simulated_second"] = (
                anchor["us_per_simulated_second"] / r["compiled_rollout_us_per_simulated_second"])
    out = {"airframe": args.airframe or "aerosonde (shipped identified)",
           "weights": str(args.weights or "shipped"), "samples": n, "dt": dt,
           "hybrid_over_physics_c_loop": statistics.median(ratios["trim"]),
           "hybrid_over_physics_c_loop_passes": ratios["trim"],
           "hybrid_over_physics_compiled_rollout": (
               results["hybrid"]["compiled_rollout_us_per_sample"]
               / results["physics"]["compiled_rollout_us_per_sample"]),
           **({"hybrid_over_physics_c_loop_recorded": statistics.median(ratios["recorded"]),
               "hybrid_over_physics_c_loop_recorded_passes": ratios["recorded"],
               "recorded": {"dataset": args.dataset, "split": args.split,
                            "sorties": len(flights), "window_s": args.window_s}}
              if flights is not None else {}),
           "network": load_weights(weights, airframe).describe(),
           "jsbsim": anchor,
           "repeats": args.repeats, "results": results,
           "machine": {"platform": platform.platform(), "cpu": _cpu_model(),
                       "cpus": os.cpu_count(), "load_1min_after": os.getloadavg()[0]},
           "command": "python analysis/bench_rollout.py"
           + (f" --airframe {args.airframe} --weights {args.weights}" if args.airframe else "")
           + (f" --airspeed {args.airspeed:g}" if args.airspeed is not None else "")
           + (f" --dataset {args.dataset} --split {args.split} --window-s {args.window_s:g}"
              if args.dataset else "")
           + (" --jsbsim" if args.jsbsim else "")}
    print(json.dumps(out, indent=2))
    if args.out:
        Path(args.out).write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
