"""The ``uavdyn mpc`` command: argparse wiring and one thin function over :mod:`uavdyn.mpc`
that flies one closed-loop scenario on the calm emulator and writes its time histories (CSV),
solve-time statistics (JSON) and a figure (PNG).

Option values are checked when parsed (:mod:`uavdyn.cli.common`); the relation of the options
(a :class:`~uavdyn.cli.common.CliError`), weight-file and output-folder errors are
``uavdyn.cli.app``'s one line with exit code 2.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from pathlib import Path

import numpy as np

from uavdyn.airframes import list_presets
from uavdyn.cli.common import (
    airframe_name,
    count,
    existing_file,
    folder_to_write,
    number,
    refuse_unused,
)
from uavdyn.model import CONTROL_NAMES
from uavdyn.mpc import SCENARIO_NAMES, MPCConfig, scenario
from uavdyn.mpc.study import (
    flight_outcome,
    fly_all,
    prediction_models,
    solve_statistics,
    startup_seconds,
)
from uavdyn.outputs import check_output_folder, output_folder

COMMAND = "mpc"
MAX_HORIZON = 200
LOG_INTERVAL = 0.01  # the calm emulator's log interval (s)
MAX_DT = 1.0
HISTORY_COLUMNS = ("time", "u", "w", "q", "theta", "h", "speed", "theta_ref", "h_ref",
                   "speed_ref", "control_1", "control_2", "solve_ms", "success", "source",
                   "status")


def add_parser(sub) -> argparse.ArgumentParser:
    """Register ``mpc`` on the ``uavdyn`` sub-parsers ``sub``; returns its parser."""
    p = sub.add_parser(
        COMMAND, help="fly a closed-loop tracking MPC (hybrid or physics prediction, full SQP "
        "or real-time iteration) on the calm emulator; write histories, solve statistics, PNG",
        description="Fly one scenario (pitch step, climb or speed step) with the tracking MPC "
        "on the calm emulator of the airframe (the 'real aircraft'). The hybrid prediction is "
        "the preset's shipped safe correction on the identified airframe it was trained on, "
        "or --weights trained on --airframe; the physics prediction is the RK4 step of the "
        "same airframe without the correction. A failed solve is never applied (shifted "
        "previous plan, then the last control; counted). Writes history_<model>.csv, "
        "stats.json and mpc.png under --out.")
    p.add_argument("--airframe", default="aerosonde", type=airframe_name,
                   help=f"preset name ({', '.join(list_presets())}) or path of an airframe "
                        "file (default aerosonde)")
    p.add_argument("--plant", default=None, type=airframe_name,
                   help="preset name or airframe file the calm emulator flies as the real "
                        "aircraft (default: --airframe's emulator): e.g. the truth an "
                        "identified --airframe was fitted to")
    p.add_argument("--weights", default=None, type=existing_file("weight file"),
                   help="weight file trained on --airframe (default: the preset's shipped safe "
                        "correction)")
    p.add_argument("--scenario", required=True, choices=SCENARIO_NAMES,
                   help="closed-loop test (references: docs/mpc.md)")
    p.add_argument("--horizon", type=count(MAX_HORIZON, "intervals"), default=20,
                   help=f"prediction intervals, 1..{MAX_HORIZON} (default 20)")
    p.add_argument("--dt", type=number(LOG_INTERVAL, MAX_DT, name="dt", unit="s",
                                       multiple_of=LOG_INTERVAL), default=0.05,
                   help=f"MPC interval in s, a multiple of the emulator's {LOG_INTERVAL:g} s "
                        f"log interval up to {MAX_DT:g} (default 0.05)")
    p.add_argument("--rti", action="store_true",
                   help="real-time iteration (one QP per step, compiled and cached) instead "
                        "of the full SQP")
    p.add_argument("--model", choices=("hybrid", "physics", "both"), default="both",
                   help="prediction model(s) to fly (default both, for the comparison)")
    p.add_argument("--force", action="store_true",
                   help="write into a non-empty folder that is not this command's output")
    p.add_argument("--out", required=True, type=folder_to_write, help="output folder")
    p.set_defaults(func=cmd_mpc)
    return p


def _check(args: argparse.Namespace) -> None:
    """The relation of the options (their values are checked when parsed)."""
    refuse_unused(args, ("--weights",), args.model != "physics",
                  "with --model hybrid or both")


def _control_bounds(setup, config: MPCConfig, models) -> dict:
    """``{control name: (low, high)}`` the controller clips to (the config's, else the
    prediction airframe's; :class:`uavdyn.mpc.problem.TrackingProblem`)."""
    airframe = setup.models[models[0]].airframe if models else setup.plant_airframe
    bounds = config.control_bounds or airframe.control_bounds()
    return dict(zip(CONTROL_NAMES[setup.plant_airframe.kind], bounds))


def _write_history(path: Path, res) -> None:
    n = len(res.controls)
    with path.open("w", newline="") as fh:
        out = csv.writer(fh)
        out.writerow(HISTORY_COLUMNS)
        for k in range(n + 1):
            last = k == n  # the final state has no control or solve after it
            row = [res.time[k], *res.states[k], res.speed[k]]
            row += (["", "", ""] if k == 0 else
                    [res.theta_ref[k - 1], res.h_ref[k - 1], res.speed_ref[k - 1]])
            row += (["", "", "", "", "", ""] if last else
                    [*res.controls[k], res.solve_times_s[k] * 1e3, int(res.success[k]),
                     res.source[k], "" if res.status is None else res.status[k]])
            out.writerow([f"{v:.10g}" if isinstance(v, (float, np.floating)) else v
                          for v in row])


def _plot(path: Path, sc, results: dict, title: str, bounds: dict) -> None:
    """The closed-loop responses: the tracked signal against its reference, each control with
    its bounds (``{control name: (low, high)}``), and the solve times."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    idx = {"theta": 3, "h": 4}
    names = list(bounds)
    fig, axes = plt.subplots(2 + len(names), 1, figsize=(8, 2.3 * (2 + len(names)) + 0.6),
                             sharex=True, constrained_layout=True)
    ax, bx = axes[0], axes[-1]
    styles = {"hybrid": "r-", "physics": "b--"}
    scale = math.degrees(1.0) if sc.tracked == "theta" else 1.0
    ref, ref_time = None, None
    for name, res in results.items():
        style = styles.get(name, "g-")
        y = res.speed if sc.tracked == "speed" else res.states[:, idx[sc.tracked]]
        ref = {"theta": res.theta_ref, "h": res.h_ref, "speed": res.speed_ref}[sc.tracked]
        ref_time = res.time[1:]
        ax.plot(res.time, y * scale, style, label=f"closed loop, {name} prediction")
        for cx, j in zip(axes[1:-1], range(len(names))):
            cx.step(res.time[:-1], res.controls[:, j], style, where="post", lw=1,
                    label=f"applied, {name} prediction")
        ok = res.success
        bx.plot(res.time[:-1][ok], res.solve_times_s[ok] * 1e3, style[0] + ".",
                ms=3, label=f"{name} ({ok.mean():.1%} solved)")
        if (~ok).any():
            bx.plot(res.time[:-1][~ok], res.solve_times_s[~ok] * 1e3, "kx", ms=5,
                    label=f"{name}: failed (fallback applied)")
    if ref is not None:
        ax.plot(ref_time, ref * scale, "k:", label="reference")
    ax.set_ylabel({"theta": "pitch (deg)", "h": "altitude (m)", "speed": "airspeed (m/s)"}
                  [sc.tracked])
    ax.set_title(title, fontsize=9, wrap=True)
    for cx, name in zip(axes[1:-1], names):
        for k, limit in enumerate(bounds[name]):
            cx.axhline(limit, color="k", ls="--", lw=0.8,
                       label="control bounds" if k == 0 else None)
        cx.set_ylabel(name + (" (rad)" if name in ("elevator", "pitch_cmd") else " (0-1)"
                              if name in ("throttle", "collective") else ""))
    bx.set_ylabel("solve time (ms)")
    bx.set_xlabel("time (s)")
    for a in axes:
        a.grid(alpha=0.3)
        a.legend(fontsize=7, loc="best")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def cmd_mpc(args: argparse.Namespace) -> int:
    """Fly one scenario closed loop and write its outputs (see the module docstring)."""
    _check(args)
    check_output_folder(args.out, COMMAND, args.force)  # before any work
    mode = "rti" if args.rti else "sqp"
    models = ("hybrid", "physics") if args.model == "both" else (args.model,)
    setup = prediction_models(args.airframe, args.weights, mode, models, plant=args.plant)
    config = MPCConfig(horizon=args.horizon, dt=args.dt, mode=mode)
    sc = scenario(setup.plant_airframe.kind, args.scenario)
    print(f"(prediction: {'; '.join(m.description for m in setup.models.values())}; plant: "
          f"calm emulator of {setup.plant_airframe.name})", file=sys.stderr)
    for name, why in setup.missing.items():
        print(f"(no {name} prediction: {why})", file=sys.stderr)
    models = tuple(m for m in models if m in setup.models)
    runs = fly_all(setup, config, (args.scenario,),
                   progress=lambda msg: print(f"flying {msg} ...", file=sys.stderr))
    results = {m: runs[(args.scenario, m)][1] for m in models}
    stats = {
        "command": "uavdyn mpc", "airframe": args.airframe,
        "scenario": args.scenario, "tracked": sc.tracked, "unit": sc.unit,
        "mode": mode, "horizon": args.horizon, "dt": args.dt,
        "qp_solver": config.qp_solver if mode == "rti" else "sqpmethod + qrqp",
        "plant": f"calm emulator of {setup.plant_airframe.name}",
        "missing": setup.missing, "models": {}}
    for name, res in results.items():
        stats["models"][name] = {
            "prediction": setup.models[name].description, **flight_outcome(res, sc),
            **solve_statistics(res)}
        if mode == "rti":  # the library is in the cache now: a second start loads it
            stats["models"][name]["startup_s_cached"] = startup_seconds(setup.models[name],
                                                                        config)
    title = (f"Closed-loop response: {args.scenario} on the calm emulator of "
             f"{setup.plant_airframe.name}, tracking MPC ({mode.upper()}, horizon "
             f"{args.horizon} x {args.dt:g} s) with "
             f"{' and '.join(f'{m} ({setup.models[m].description})' for m in models)} "
             "prediction")
    with output_folder(args.out, COMMAND, args.force) as tmp:
        for name, res in results.items():
            _write_history(tmp / f"history_{name}.csv", res)
        (tmp / "stats.json").write_text(json.dumps(stats, indent=2) + "\n")
        _plot(tmp / "mpc.png", sc, results, title, _control_bounds(setup, config, models))
    for name, s in stats["models"].items():
        rmse = (s["departure"] or "diverged" if s["tracking_rmse"] is None
                else f"{s['tracking_rmse']:.4g} {sc.unit}")
        med = "-" if s["solve_ms_median"] is None else f"{s['solve_ms_median']:.3g}"
        mx = "-" if s["solve_ms_max"] is None else f"{s['solve_ms_max']:.3g}"
        print(f"  {name}: tracking RMSE {rmse}; solves {s['success_rate']:.1%} succeeded "
              f"(median {med} ms, max {mx} ms"
              + (f"; {s['iteration_limit_solves']} applied at the iteration limit, their "
                 "merit lowered" if s["iteration_limit_solves"] else "")
              + f"); fallbacks {s['fallback_shifted']} shifted, {s['fallback_held']} held")
    print(f"wrote {args.out}/ (history_*.csv, stats.json, mpc.png)")
    departed = [name for name, s in stats["models"].items() if s["departure"]]
    if departed:
        print(f"error: the closed loop with {' and '.join(departed)} prediction left the "
              "physical ranges (see above; the flight up to then is written)", file=sys.stderr)
        return 1
    return 0
