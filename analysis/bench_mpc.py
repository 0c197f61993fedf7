"""Benchmark of the tracking MPC: solve time per step (median, max) at horizon 20 and 50 and
closed-loop tracking RMSE, hybrid vs physics-only prediction, flying the calm emulator.
Prints JSON. Usage: ``python analysis/bench_mpc.py [--airframe aerosonde] [--out FILE]``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from uavdyn.airframes import load_airframe
from uavdyn.linear import trim
from uavdyn.mpc.study import fly_all, prediction_models, summarise


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--airframe", default="aerosonde")
    parser.add_argument("--weights", default=None)
    parser.add_argument("--dt", type=float, default=0.05)
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    af = load_airframe(args.airframe)
    point = trim(af)
    models = prediction_models(af, args.weights)
    result = {"airframe": af.name, "dt": args.dt, "solver": "sqpmethod + qrqp (no JIT)"}
    for horizon in (20, 50):
        runs = fly_all(af, point, models, horizon, args.dt)
        summary = summarise(runs)
        times = {m: np.concatenate([r.solve_times_s for (s, mm), (_, r) in runs.items()
                                    if mm == m]) for m in models}
        for m in models:
            result[f"median_ms_h{horizon}_{m}"] = float(np.median(times[m]) * 1e3)
            result[f"max_ms_h{horizon}_{m}"] = float(np.max(times[m]) * 1e3)
        result[f"median_ms_h{horizon}"] = result[f"median_ms_h{horizon}_hybrid"]
        result[f"max_ms_h{horizon}"] = result[f"max_ms_h{horizon}_hybrid"]
        result[f"scenarios_h{horizon}"] = summary
        if horizon == 20:
            pitch = summary["pitch step +5 deg"]
            result["tracking_rmse_hybrid"] = pitch["hybrid"]["tracking_rmse"]
            result["tracking_rmse_physics"] = pitch["physics"]["tracking_rmse"]
            result["tracking_rmse_unit"] = "rad, pitch step, from the step on"
    text = json.dumps(result, indent=2)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
