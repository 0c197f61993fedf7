"""Benchmark of ``uavdyn identify`` on the emulated datasets of the shipped recipes: nominal
physics vs identified physics, pitch RMSE on the TEST split, calm and turbulent separately, for
1 s predictions restarted from recorded states and for whole-sortie free runs; with the wall
time of each identification.

Two fits per airframe: the pipeline's list (``physics``: :data:`IDENTIFY_PARAMS`, coefficients,
lags and the kind's unsteady/rotor terms), and the same plus the integer transport delays the
kind has (``physics+actuators``: fixed wing ``delay_elevator``; quadrotor ``delay_collective``,
``delay_pitch_cmd``); each on all train sorties and on the calm ones only (the model has no
gusts: turbulent sorties pull the estimates). Every model is scored by its own discrete step
(RK4, 2 sub-steps per 100 Hz sample, i.e. dt = 0.005 s; lags and delay buffers as augmented
states rebuilt from the logged commands). Also the wall time of one identification with the
lag and delay names on 20 training sorties (``timing_20_sorties``; the issue's budget: under 2
minutes on 2 cores).

The identification uses the train split (validation only scores it); the test split is never
seen. Usage: ``python analysis/bench_identify.py [--airframes fixed_wing quadrotor] [--out F]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import time
from pathlib import Path

import numpy as np

from uavdyn.airframes import load_airframe
from uavdyn.experiments.common import IDENTIFY_PARAMS
from uavdyn.experiments.reproduce import ReproduceConfig, dataset_for
from uavdyn.identify import identify, make_windows, physics_windows
from uavdyn.integrate import physics_step, sortie_free_run

PARAMS = {kind: list(names) for kind, names in IDENTIFY_PARAMS.items()}  # the pipeline's lists
ACTUATORS = {  # the transport delays each kind has in the model structure
    "fixed_wing": ["delay_elevator"],
    "multirotor": ["delay_collective", "delay_pitch_cmd"],
}
SUBSTEPS = 2   # RK4 steps per log sample (dt = 0.005 s at 100 Hz)
HORIZON_S = 1.0
TIMING_SORTIES = 20


def _rmse(err: np.ndarray) -> float:
    with np.errstate(over="ignore", invalid="ignore"):
        value = float(np.sqrt(np.mean(err**2)))
    return value if math.isfinite(value) and value < 1e3 else math.inf


def condition(sortie) -> str:
    return str(sortie.meta.get("condition", "") or "unknown")


def score(airframe, sorties) -> dict:
    """Pitch RMSE at 1 s and free run per condition (pooled) and per sortie, against the
    noise-free true states (restarts from true states too)."""
    groups: dict[str, dict[str, list]] = {}
    per_sortie = []
    for s in sorties:
        target = s if s.true_states is None else dataclasses.replace(s, states=s.true_states)
        L = int(round(HORIZON_S / s.dt))
        w = make_windows([target], L)
        horizon = (physics_windows(airframe, w, s.dt, SUBSTEPS) - w.y)[..., 3].ravel()
        free = (sortie_free_run(physics_step(airframe, substeps=SUBSTEPS), target, airframe,
                                target.dt, check=False)[1:, 3] - target.states[1:, 3])
        cond = condition(s)
        g = groups.setdefault(cond, {"horizon_1s": [], "free_run": []})
        g["horizon_1s"].append(horizon)
        g["free_run"].append(free)
        per_sortie.append({"sortie": s.name, "condition": cond, "horizon_1s": _rmse(horizon),
                           "free_run": _rmse(free)})
    pooled = {cond: {mode: _rmse(np.concatenate(errs)) for mode, errs in g.items()}
              for cond, g in groups.items()}
    return {"pooled": pooled, "per_sortie": per_sortie}


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--airframes", nargs="+", default=["fixed_wing", "quadrotor"])
    parser.add_argument("--cache", default=None, help="dataset cache folder")
    parser.add_argument("--out", default=None, help="also write the JSON here")
    args = parser.parse_args(argv)
    report = {"dt": None, "substeps_per_sample": SUBSTEPS,
              "target": "noise-free true states of the test split",
              "machine": {"python": platform.python_version(), "machine": platform.machine(),
                          "cpus": os.cpu_count()}, "airframes": []}
    for name in args.airframes:
        ds = dataset_for(name, ReproduceConfig(cache=args.cache, progress=False))
        nominal = load_airframe(name)
        report["dt"] = ds.train[0].dt / SUBSTEPS
        entry = {"airframe": nominal.name, "kind": nominal.kind, "n_train": len(ds.train),
                 "n_validation": len(ds.validation), "n_test": len(ds.test),
                 "test_nominal": score(nominal, ds.test), "fits": []}
        for train_on in ("all", "calm"):
            train = [s for s in ds.train if train_on == "all" or condition(s) == "calm"]
            validation = [s for s in ds.validation if train_on == "all"
                          or condition(s) == "calm"]
            for label, names in (("physics", PARAMS[nominal.kind]),
                                 ("physics+actuators",
                                  PARAMS[nominal.kind] + ACTUATORS[nominal.kind])):
                t0 = time.perf_counter()
                result = identify(nominal, train, validation, names, progress=False)
                wall = time.perf_counter() - t0
                entry["fits"].append({"fit": label, "train_sorties": train_on,
                                      "n_train": len(train), "params": names,
                                      "identify_wall_s": wall, "identify": result.to_dict(),
                                      "test_identified": score(result.airframe, ds.test)})
        names = PARAMS[nominal.kind] + ACTUATORS[nominal.kind]
        t0 = time.perf_counter()
        identify(nominal, ds.train[:TIMING_SORTIES], ds.validation, names, progress=False)
        entry["timing_20_sorties"] = {"sorties": TIMING_SORTIES, "params": names,
                                      "identify_wall_s": time.perf_counter() - t0}
        report["airframes"].append(entry)
    text = json.dumps(report, indent=2, default=float)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")
    return report


if __name__ == "__main__":
    main()
