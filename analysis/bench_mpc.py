"""Benchmark of the tracking MPC on the calm emulator: solve time per step (median and max over
successful solves, success rate, fallbacks) and closed-loop tracking RMSE per scenario, hybrid
vs physics prediction, full SQP and real-time iteration (RTI), horizons 20 and 50, for each
preset; the QP-solver measurement behind the RTI's choice; controller start-up with a cold and
a warm compile cache; machine load before and after. Prints JSON.

Usage: ``python analysis/bench_mpc.py [--airframe aerosonde f450] [--out FILE]
[--markdown FILE]`` (or ``--from-json FILE --markdown FILE``: the tables of an earlier run).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np

from uavdyn.integrate import codegen, physics_step
from uavdyn.mpc import SCENARIO_NAMES, MPCConfig, RTIController, scenario
from uavdyn.mpc.rti import _QUIET, QP_SOLVERS
from uavdyn.mpc.scenarios import run_scenario
from uavdyn.mpc.study import (
    PredictionModel,
    StudySetup,
    fly_all,
    pooled,
    prediction_models,
    summarise,
)

HORIZONS = (20, 50)
MODES = ("sqp", "rti")


@contextlib.contextmanager
def c_output_to_stderr():
    """Send what C libraries print to stdout (qpOASES's banner) to stderr, so stdout stays
    the JSON."""
    sys.stdout.flush()
    saved = os.dup(1)
    os.dup2(2, 1)
    try:
        yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)


def load() -> list[float]:
    return [round(v, 2) for v in os.getloadavg()]


def suffix(mode: str) -> str:
    return "_rti" if mode == "rti" else ""


def record_qps(model, plant, plant_trim, horizon: int) -> tuple[list, ca.Function]:
    """The condensed QPs an RTI controller solves flying the pitch step (its arguments)."""
    mpc = model.controller(MPCConfig(horizon=horizon, mode="rti"))
    assert isinstance(mpc, RTIController)
    step = _Recorded(mpc._step)
    mpc._step = step
    run_scenario(scenario(plant.kind, "pitch-step"), mpc, plant, plant_trim)
    qps = [[ca.DM(a) for a in mpc.qp_data.call(args)[:7]] for args in step.calls]
    return qps, mpc.qp_data


def measure_qp_solvers(qps: list, func: ca.Function, budget_s: float = 15.0) -> dict:
    """Each QP solver on the same recorded QPs, once each in flight order (as in the closed
    loop: a solver that hot-starts from its previous QP may do so): median/max solve time
    (us), success rate and largest difference from daqp's solution. A solver stops after
    ``budget_s`` seconds (``measured`` says how many QPs it solved)."""
    out, ref = {}, None
    for name in QP_SOLVERS:
        try:
            qp = ca.conic("bench_qp", name, {"h": func.sparsity_out(0),
                                             "a": func.sparsity_out(2)},
                          dict(_QUIET.get(name, {})))
        except RuntimeError as exc:
            out[name] = {"error": " ".join(str(exc).split())[-200:]}
            continue
        defaults = [ca.DM()] * (qp.n_in() - 7)
        times, ok, sols = [], [], []
        for args in qps:
            t0 = time.perf_counter()
            sol = qp.call(args + defaults)
            times.append((time.perf_counter() - t0) * 1e6)
            ok.append(bool(qp.stats().get("success", False)))
            sols.append(np.asarray(sol[0]).ravel())
            if sum(times) > budget_s * 1e6:
                break
        if name == "daqp":
            ref = sols
        diff = (max(float(np.max(np.abs(a - b))) for a, b in zip(sols, ref))
                if ref is not None else None)
        out[name] = {"measured": len(times),
                     "median_us": float(np.median(times)), "max_us": float(np.max(times)),
                     "success_rate": float(np.mean(ok)), "max_abs_diff_from_daqp": diff}
    return out


def startup(model, horizon: int) -> dict:
    """Construction of an RTI controller with an empty cache (gcc builds the library) and
    then with the cache warm (the verified library is loaded)."""
    old = os.environ.get(codegen.CACHE_ENV)
    with tempfile.TemporaryDirectory() as tmp:
        os.environ[codegen.CACHE_ENV] = tmp
        try:
            t0 = time.perf_counter()
            model.controller(MPCConfig(horizon=horizon, mode="rti"))
            t1 = time.perf_counter()
            model.controller(MPCConfig(horizon=horizon, mode="rti"))
            t2 = time.perf_counter()
        finally:
            if old is None:
                os.environ.pop(codegen.CACHE_ENV, None)
            else:
                os.environ[codegen.CACHE_ENV] = old
    return {"cold_cache_s": t1 - t0, "warm_cache_s": t2 - t1}


class _Recorded:
    """A Function (or conic) whose calls are recorded and forwarded."""

    def __init__(self, function):
        self.function, self.calls = function, []

    def call(self, args):
        self.calls.append(list(args))
        return self.function.call(args)

    def __getattr__(self, name):
        return getattr(self.function, name)


def _replay_seconds(calls, call, repeats: int = 5) -> float:
    """Median over ``repeats`` of the time of ``call`` on every recorded argument list."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for args in calls:
            call(args)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def rti_split(model, plant, plant_trim, horizon: int = 20) -> dict:
    """Where an RTI solve's time goes, in one harness: the pitch step flown once with the
    solves recorded, then replayed (the controller reset, every solve in order, median of 5
    replays): the whole ``solve`` per call, the compiled QP-data call alone and the QP
    solver alone on the recorded arguments; the glue is the rest (conversions, the call
    into the solver, warm start, carried states, policy)."""
    mpc = model.controller(MPCConfig(horizon=horizon, mode="rti"))
    solves, step = [], _Recorded(mpc._step)
    real_solve = mpc.solve

    def keep(*args, **kwargs):
        solves.append((args, kwargs))
        return real_solve(*args, **kwargs)

    mpc.solve = keep
    run_scenario(scenario(plant.kind, "pitch-step"), mpc, plant, plant_trim)
    mpc.solve, mpc._step = real_solve, step

    def replay(_):
        mpc.reset()
        for args, kwargs in solves:
            real_solve(*args, **kwargs)

    replay(None)  # once with the recorder in place, then timed without it
    mpc._step = step.function
    whole = _replay_seconds([None], replay)
    n = len(solves)
    packed = step.calls[:n]
    qps = [list(mpc.qp_data.call(args)[:7]) + mpc._defaults for args in packed]
    data_s = _replay_seconds(packed, mpc.qp_data.call)
    qp_s = _replay_seconds(qps, mpc.qp.call)
    lin, lin_args = _linearisation_alone(mpc.problem, packed)
    lin_s = _replay_seconds(lin_args, lin.call)
    per = 1e6 / n
    return {"solves": n, "solve_us": round(whole * per, 1), "qp_data_us": round(data_s * per, 1),
            "of_which_linearisation_us": round(lin_s * per, 1),
            "qp_solve_us": round(qp_s * per, 1),
            "glue_us": round((whole - data_s - qp_s) * per, 1),
            "what": "pitch-step solves replayed in order, median of 5 replays, per solve; "
                    "the linearisation alone: the compiled rollout with every stage "
                    "Jacobian (the QP data's first piece, before condensing) on the same "
                    "plans, called the same way"}


def _linearisation_alone(problem, packed: list) -> tuple[ca.Function, list]:
    """The QP data's stage linearisation as a compiled Function of its own (``x0`` and the
    plan in one vector, like the QP data), with its arguments cut from the recorded calls."""
    N, nx, nu = problem.N, problem.nx, problem.nu
    v = ca.MX.sym("v", nx + nu * N)
    rollout = problem.stage_jac.mapaccum("mpc_roll", N)(v[:nx], ca.reshape(v[nx:], nu, N))
    lin = codegen.compile_function(ca.Function(f"mpc_linearisation_{problem.kind}_n{N}", [v],
                                               list(rollout)))
    return lin, [[a[0][:nx + nu * N]] for a in packed]


def bench_airframe(name: str, log) -> dict:
    result: dict = {"airframe": name, "scenarios": list(SCENARIO_NAMES), "runs": {}}
    setups = {mode: prediction_models(name, mode=mode) for mode in MODES}
    plant = setups["rti"].plant_airframe
    result["plant"] = f"calm emulator of {plant.name}"
    result["prediction"] = {f"{m}{suffix(mode)}": s.models[m].description
                            for mode, s in setups.items() for m in s.models}
    result["missing"] = setups["rti"].missing  # model -> why it is not flown
    result["dt"] = 0.05
    result["scenario_definitions"] = {
        n: {k: v for k, v in vars(scenario(plant.kind, n)).items()}
        for n in SCENARIO_NAMES}
    for horizon in HORIZONS:
        for mode in MODES:
            tag = f"h{horizon}{suffix(mode)}"
            t0 = time.perf_counter()
            runs = fly_all(setups[mode], MPCConfig(horizon=horizon, mode=mode),
                           progress=lambda m: log(f"{name}: {m}"))
            summary = summarise(runs)
            result["runs"][tag] = summary
            for model in ("hybrid", "physics"):
                key = f"h{horizon}_{model}{suffix(mode)}"
                if model not in setups[mode].models:
                    for what in ("median_ms", "max_ms", "p95_ms", "success_rate",
                                 "failed_solves", "iteration_limit_solves", "fallbacks",
                                 "tracking_rmse"):
                        result[f"{what}_{key}"] = None
                    continue
                stats = pooled(runs, model)
                result[f"median_ms_{key}"] = stats["median_ms"]
                result[f"max_ms_{key}"] = stats["max_ms"]
                result[f"p95_ms_{key}"] = stats["p95_ms"]
                result[f"success_rate_{key}"] = stats["success_rate"]
                result[f"failed_solves_{key}"] = stats["failed_solves"]
                result[f"iteration_limit_solves_{key}"] = stats["iteration_limit_solves"]
                result[f"fallbacks_{key}"] = stats["fallback_shifted"] + stats["fallback_held"]
                result[f"tracking_rmse_{key}"] = {sc: summary[sc][model]["tracking_rmse"]
                                                  for sc in SCENARIO_NAMES}
            result[f"lost_control_{tag}"] = {
                m: [sc for sc in SCENARIO_NAMES if summary[sc][m]["lost_control"]]
                for m in setups[mode].models}
            result[f"hybrid_better_{tag}"] = None if "hybrid" in setups[mode].missing else {
                sc: (summary[sc]["hybrid"]["tracking_rmse"] is not None
                     and summary[sc]["physics"]["tracking_rmse"] is not None
                     and summary[sc]["hybrid"]["tracking_rmse"]
                     < summary[sc]["physics"]["tracking_rmse"])
                for sc in SCENARIO_NAMES}
            result[f"wall_s_{tag}"] = time.perf_counter() - t0
    # the headline tracking figures: RTI at horizon 20 (what runs in real time)
    result["tracking_rmse_hybrid"] = result["tracking_rmse_h20_hybrid_rti"]
    result["tracking_rmse_physics"] = result["tracking_rmse_h20_physics_rti"]
    result["tracking_rmse_unit"] = {sc: scenario(plant.kind, sc).unit for sc in SCENARIO_NAMES}
    result["tracking_rmse_note"] = ("RMSE of the tracked quantity (pitch-step: pitch, climb: "
                                    "altitude, speed-step: speed) from the step on; null: the "
                                    "flight diverged")
    # diagnostic: the preset's nominal physics (the emulator's own baseline parameters) as the
    # prediction, RTI at horizon 20: separates the controller from the identified model
    nominal = PredictionModel("nominal_physics", physics_step(plant), setups["rti"].plant_trim,
                              f"RK4 of {plant.name} (nominal)")
    diag = StudySetup(plant, setups["rti"].plant_trim, {"nominal_physics": nominal},
                      setups["rti"].weights)
    runs = fly_all(diag, MPCConfig(horizon=20, mode="rti"),
                   progress=lambda m: log(f"{name}: diagnostic {m}"))
    summary = summarise(runs)
    result["diagnostic_nominal_physics_rti_h20"] = {
        "prediction": nominal.description,
        "tracking_rmse": {sc: summary[sc]["nominal_physics"]["tracking_rmse"]
                          for sc in SCENARIO_NAMES},
        "lost_control": [sc for sc in SCENARIO_NAMES
                         if summary[sc]["nominal_physics"]["lost_control"]],
        "success_rate": pooled(runs, "nominal_physics")["success_rate"]}
    log(f"{name}: QP solvers on recorded RTI QPs")
    models = setups["rti"].models
    first = models.get("hybrid") or models["physics"]
    result["qp_solvers"] = {"prediction": first.name}
    for horizon in HORIZONS:
        qps, func = record_qps(first, plant, setups["rti"].plant_trim, horizon)
        result["qp_solvers"][f"h{horizon}"] = {"qps": len(qps),
                                               **measure_qp_solvers(qps, func)}
    log(f"{name}: where an RTI h20 solve's time goes")
    result["rti_h20_split"] = rti_split(first, plant, setups["rti"].plant_trim)
    log(f"{name}: start-up with a cold and a warm cache")
    result[f"startup_rti_h20_{first.name}"] = startup(first, 20)
    return result


def markdown(results: list[dict]) -> str:
    lines = ["# bench_mpc", ""]
    for r in results:
        lines += [f"## {r['airframe']} ({r['plant']}; MPC dt {r['dt']} s)", "",
                  "| horizon | mode | prediction | median / max solve (ms) | success | "
                  "at the iteration limit | fallbacks | "
                  + " | ".join(f"{s} RMSE ({r['tracking_rmse_unit'][s]})"
                               for s in r["scenarios"]) + " |",
                  "|---" * (7 + len(r["scenarios"])) + "|"]
        for h in HORIZONS:
            for mode in MODES:
                for m in ("hybrid", "physics"):
                    k = f"h{h}_{m}{suffix(mode)}"
                    if r[f"success_rate_{k}"] is None:
                        lines.append(f"| {h} | {mode.upper()} | {m} | not flown (below) |")
                        continue
                    med, mx = r[f"median_ms_{k}"], r[f"max_ms_{k}"]
                    times = "-" if med is None else f"{med:.3g} / {mx:.3g}"
                    lost = r[f"lost_control_h{h}{suffix(mode)}"][m]
                    rm = [("diverged" if v is None else f"{v:.4g}"
                           + (" (lost control)" if sc in lost else ""))
                          for sc, v in r[f"tracking_rmse_{k}"].items()]
                    limited = r.get(f"iteration_limit_solves_{k}", "-")
                    lines.append(f"| {h} | {mode.upper()} | {m} | {times} | "
                                 f"{r[f'success_rate_{k}']:.1%} | {limited} | "
                                 f"{r[f'fallbacks_{k}']} | " + " | ".join(rm) + " |")
        diag = r["diagnostic_nominal_physics_rti_h20"]
        lines += [""] + [f"Not flown: {m}: {why}" for m, why in r["missing"].items()]
        lines += ["", f"Diagnostic, RTI horizon 20 with the nominal {r['airframe']} physics as "
                      "the prediction: " + ", ".join(
                          f"{s} {'diverged' if v is None else f'{v:.4g}'}"
                          for s, v in diag["tracking_rmse"].items())
                  + f" ({diag['success_rate']:.1%} solved).", "",
                  f"Load average before/after: {r.get('load_before')} / "
                  f"{r.get('load_after')}", ""]
        lines += _split_lines(r) + _solver_lines(r)
    return "\n".join(lines) + "\n"


def _split_lines(r: dict) -> list[str]:
    split = r.get("rti_h20_split")
    if not split:
        return []
    return [f"Where an RTI h20 solve's time goes ({split['what']}): whole solve "
            f"{split['solve_us']:.0f} us = QP data {split['qp_data_us']:.0f} us + QP solve "
            f"{split['qp_solve_us']:.0f} us + glue {split['glue_us']:.0f} us.", ""]


def _solver_lines(r: dict) -> list[str]:
    """The QP solvers on the recorded RTI QPs: median / max us per horizon."""
    found = r.get("qp_solvers")
    if not found:
        return []
    horizons = [k for k in found if k.startswith("h")]
    lines = [f"QP solvers on the recorded RTI QPs ({found['prediction']} prediction):", "",
             "| solver | " + " | ".join(f"{h} median / max (us)" for h in horizons) + " |",
             "|---" * (1 + len(horizons)) + "|"]
    for name in found[horizons[0]]:
        if name == "qps":
            continue
        cells = []
        for h in horizons:
            e = found[h].get(name, {})
            if "error" in e:
                cells.append("refused (its message is in the JSON)")
                continue
            cell = f"{e['median_us']:.0f} / {e['max_us']:.0f}"
            if e.get("success_rate", 1.0) < 1.0:
                cell += f" ({e['success_rate']:.0%} solved)"
            if (e.get("max_abs_diff_from_daqp") or 0.0) > 1e-6:
                cell += f" (off by {e['max_abs_diff_from_daqp']:.1g})"
            if e.get("measured", found[h]["qps"]) < found[h]["qps"]:
                cell += f" [{e['measured']} QPs]"
            cells.append(cell)
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines + [""]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--airframe", nargs="+", default=["aerosonde", "f450"])
    parser.add_argument("--out", default=None, help="JSON file")
    parser.add_argument("--markdown", default=None, help="Markdown table file")
    parser.add_argument("--from-json", default=None,
                        help="write --markdown from this JSON of an earlier run (no run)")
    args = parser.parse_args()
    if args.from_json:
        results = list(json.loads(Path(args.from_json).read_text())["presets"].values())
        Path(args.markdown or "/dev/stdout").write_text(markdown(results))
        return

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    results = []
    with c_output_to_stderr():
        for name in args.airframe:
            before = load()
            r = bench_airframe(name, log)
            r["load_before"], r["load_after"] = before, load()
            r["cpu_count"] = os.cpu_count()
            results.append(r)
    doc = {"benchmark": "bench_mpc", "casadi": ca.__version__,
           "presets": {r["airframe"]: r for r in results}}
    text = json.dumps(doc, indent=2, default=float)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")
    if args.markdown:
        Path(args.markdown).write_text(markdown(results))


if __name__ == "__main__":
    main()
