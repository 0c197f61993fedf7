"""Benchmark of ``uavdyn identify`` on the emulated datasets of the shipped recipes: nominal
physics vs identified physics (RK4 at dt = 0.005 s), pitch RMSE on the TEST split, calm and
turbulent separately, for 1 s predictions restarted from recorded states and for whole-sortie
free runs; with the wall time of the identification. Prints JSON (``--out`` writes it too).

The identification uses the train split (validation only scores it); the test split is never
seen. Usage: ``python analysis/bench_identify.py [--airframes fixed_wing quadrotor] [--out F]``.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time
from pathlib import Path

import numpy as np

from uavdyn.airframes import load_airframe
from uavdyn.evaluation import Solver, evaluate_trajectory
from uavdyn.experiments.reproduce import ReproduceConfig, dataset_for
from uavdyn.identify import identify
from uavdyn.integrate import rk4_step
from uavdyn.model import build_model

PARAMS = {  # what is identified per airframe kind (aerodynamic/propulsive, not geometry)
    "fixed_wing": ["C_m_alpha", "C_m_q", "C_m_0", "C_m_delta_e", "C_L_alpha", "C_D_0"],
    "multirotor": ["pitch_mix", "pitch_damping", "drag_linear", "CdA_x", "CdA_z", "c_T"],
}
DT = 0.005


def _rmse(pairs: list[tuple[np.ndarray, np.ndarray]]) -> float:
    err = np.concatenate([(a[:, 3] - b[:, 3]) for a, b in pairs])
    with np.errstate(over="ignore", invalid="ignore"):
        value = float(np.sqrt(np.mean(err**2)))
    return value if math.isfinite(value) and value < 1e3 else math.inf


def score(airframe, p: np.ndarray, sorties) -> dict:
    """Pitch RMSE at 1 s and free run per condition (pooled) and per sortie."""
    solver = Solver("RK4", rk4_step(build_model(airframe).f), DT)
    groups: dict[str, dict[str, list]] = {}
    per_sortie = []
    for s in sorties:
        target = s.true_states if s.true_states is not None else s.states
        res = evaluate_trajectory(solver, s.time, target, s.controls, p)
        cond = s.meta.get("condition", "") or "unknown"
        g = groups.setdefault(cond, {"horizon_1s": [], "free_run": []})
        row = {"sortie": s.name, "condition": cond}
        for mode in ("horizon_1s", "free_run"):
            g[mode].append(res[mode])
            row[mode] = _rmse([res[mode]])
        per_sortie.append(row)
    pooled = {cond: {mode: _rmse(pairs) for mode, pairs in g.items()}
              for cond, g in groups.items()}
    return {"pooled": pooled, "per_sortie": per_sortie}


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--airframes", nargs="+", default=["fixed_wing", "quadrotor"])
    parser.add_argument("--cache", default=None, help="dataset cache folder")
    parser.add_argument("--out", default=None, help="also write the JSON here")
    args = parser.parse_args(argv)
    report = {"dt": DT, "target": "noise-free true states of the test split",
              "machine": {"python": platform.python_version(),
                          "machine": platform.machine()}, "airframes": []}
    for name in args.airframes:
        ds = dataset_for(name, ReproduceConfig(cache=args.cache, progress=False))
        nominal = load_airframe(name)
        t0 = time.perf_counter()
        result = identify(nominal, ds.train, ds.validation, PARAMS[nominal.kind],
                          progress=False)
        wall = time.perf_counter() - t0
        entry = {
            "airframe": nominal.name, "kind": nominal.kind, "params": PARAMS[nominal.kind],
            "n_train": len(ds.train), "n_validation": len(ds.validation),
            "n_test": len(ds.test), "identify_wall_s": wall,
            "identify": result.to_dict(),
            "test_nominal": score(nominal, nominal.p, ds.test),
            "test_identified": score(nominal, result.airframe.p, ds.test),
        }
        report["airframes"].append(entry)
    text = json.dumps(report, indent=2, default=float)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")
    return report


if __name__ == "__main__":
    main()
