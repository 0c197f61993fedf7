"""Benchmark of the safe correction (issue 12) on the emulated datasets of the shipped recipes:
identify the physics on the train split, train the safe correction on top of it (train and
validation splits), then on the TEST split, calm and turbulent separately: 1 s-horizon and
free-run pitch RMSE of identified physics vs corrected (against the noise-free states), the
ratio per sortie with every sortie where the correction is worse flagged, divergences, the
stability check at trims over the training envelope, and the cost of the compiled hybrid step
against the compiled physics step on the same state (one interleaved timing harness).

Usage: ``python analysis/bench_hybrid.py [--airframes fixed_wing quadrotor] [--out F]
[--epochs N] [--weights-dir DIR]``. Prints JSON; ``--out`` writes it too.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import platform
import sys
import time
from pathlib import Path

import casadi as ca
import numpy as np

from uavdyn.airframes import load_airframe
from uavdyn.evaluation import Solver, evaluate_trajectory, interleaved_timing, ratio
from uavdyn.experiments.common import IDENTIFY_PARAMS, identification_sorties
from uavdyn.experiments.reproduce import ReproduceConfig, dataset_for
from uavdyn.identify import identify
from uavdyn.identify.report import airframe_toml
from uavdyn.integrate import compile_function, physics_step, rollout
from uavdyn.learned import hybrid_step, load_weights, save_weights
from uavdyn.learned.safe import SafeConfig, SafeResult, train_safe, write_safe_history
from uavdyn.model import sortie_params

PRESET = {"fixed_wing": "aerosonde", "quadrotor": "f450"}
N_TIMING = 2000


def _rmse(err: np.ndarray) -> float:
    with np.errstate(over="ignore", invalid="ignore"):
        value = float(np.sqrt(np.mean(err**2)))
    return value if math.isfinite(value) and value < 1e3 else math.inf


def score(solver: Solver, airframe, sorties) -> list[dict]:
    rows = []
    for s in sorties:
        p = sortie_params(airframe, s.altitude_m)
        res = evaluate_trajectory(solver, s.time, s.true_states if s.true_states is not None
                                  else s.states, s.controls, p)
        row = {"sortie": s.name, "condition": s.meta.get("condition", "") or "unknown"}
        for mode in ("horizon_1s", "free_run"):
            if mode in res:
                pred, targ = res[mode]
                row[mode] = _rmse(pred[..., 3] - targ[..., 3])
            else:
                row[mode] = None
                row.setdefault("refused", {})[mode] = res.get("refused", {}).get(mode)
        rows.append(row)
    return rows


def cost_ratio(step, physics, z0, u, p, dt: float, repeats: int = 15) -> dict:
    """µs per step of both compiled steps inside a mapaccum rollout of ``N_TIMING`` steps, timed
    by the one interleaved harness (:func:`uavdyn.evaluation.interleaved_timing`: min and
    median of ``repeats`` timed calls, inputs converted to CasADi outside the timed region).
    ``physics_us_per_step``, ``hybrid_us_per_step`` and ``ratio`` are medians; the ``_min``
    keys are the minima."""
    runs = {}
    for name, st, x0 in (("physics", physics, z0[:physics.nx]), ("hybrid", step, z0)):
        f = compile_function(rollout(st, N_TIMING))
        args = [ca.DM(x0), ca.DM(np.tile(u[:, None], (1, N_TIMING))), ca.DM(p), dt]
        runs[name] = lambda f=f, args=args: f(*args)
    t = interleaved_timing(runs, repeats)
    out: dict = {}
    for stat, suffix in (("median", ""), ("median", "_median"), ("min", "_min")):
        for name in ("physics", "hybrid"):
            out[f"{name}_us_per_step{suffix}"] = t[name].stat_s(stat) / N_TIMING * 1e6
        out[f"ratio{suffix}"] = ratio(t["hybrid"], t["physics"], stat)
    return {**out, "repeats": repeats, "steps": N_TIMING,
            "harness": "interleaved, min and median of the repeats, inputs converted outside"}


def run_airframe(name: str, args) -> dict:
    nominal = load_airframe(PRESET[name])
    ds = dataset_for(name, ReproduceConfig(cache=args.cache, progress=False))
    t0 = time.perf_counter()
    saved = Path(args.weights_dir or ".") / f"{nominal.name}_safe.npz"
    toml = saved.with_name(f"{nominal.name}_identified.toml")
    if args.reuse and toml.exists():  # the airframe the saved weights were trained on
        fitted = load_airframe(toml)
        identified = {n: getattr(fitted.params, n) for n in IDENTIFY_PARAMS[nominal.kind]}
    else:
        fit_on, _ = identification_sorties(ds.train)
        ident = identify(nominal, fit_on, ds.validation, list(IDENTIFY_PARAMS[nominal.kind]),
                         progress=False)
        fitted = ident.airframe
        identified = {e.name: e.value for e in ident.estimates}
    t_ident = time.perf_counter() - t0
    cfg = SafeConfig(epochs=args.epochs, progress=not args.quiet, max_seconds=args.max_seconds)
    t0 = time.perf_counter()
    history = saved.with_name(saved.stem + "_history.json")
    if args.reuse and not saved.exists() and history.exists():  # a run that kept nothing
        doc = json.loads(history.read_text())
        result = SafeResult(None, False, doc["reason"], doc["history"], cfg, doc["best_epoch"],
                            doc["seconds"], doc["validation"])
        stability = doc.get("stability")
    elif args.reuse and saved.exists():  # the weights of an earlier run on the same data
        doc = json.loads(history.read_text())
        net = load_weights(saved, fitted)
        result = SafeResult(net, True, doc["reason"], doc["history"], cfg, doc["best_epoch"],
                            doc["seconds"], doc["validation"])
        stability = doc["stability"]
    else:
        result = train_safe(ds.train, ds.validation, fitted, cfg)
        stability = result.stability.to_dict() if result.stability else None
    t_train = time.perf_counter() - t0
    out: dict = {"airframe": nominal.name, "dataset": str(ds.path),
                 "identified": identified, "weights": str(saved) if args.reuse else None,
                 "identify_seconds": t_ident, "train_seconds": t_train,
                 "kept": result.kept, "reason": result.reason,
                 "validation": result.validation,
                 "stability": stability}
    if args.weights_dir and not args.reuse:  # --reuse reads the folder, never writes it
        folder = Path(args.weights_dir)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / f"{nominal.name}_identified.toml").write_text(airframe_toml(
            fitted, [f"{nominal.name} identified by analysis/bench_hybrid.py on {ds.path.name}"]))
        write_safe_history(result, folder / f"{nominal.name}_safe_history.json")
        if result.net is not None:
            save_weights(result.net, folder / f"{nominal.name}_safe.npz")
    sample_dt = float(np.median(np.diff(ds.test[0].time)))
    physics = physics_step(fitted)
    rows_p = score(Solver("identified physics", physics, sample_dt), fitted, ds.test)
    per_sortie = []
    if result.net is not None:
        step = hybrid_step(result.net, fitted, compile=False)
        rows_h = score(Solver("corrected", step, sample_dt), fitted, ds.test)
        for rp, rh in zip(rows_p, rows_h):
            row = {"sortie": rp["sortie"], "condition": rp["condition"]}
            for mode in ("horizon_1s", "free_run"):
                a, b = rp[mode], rh[mode]
                row[f"{mode}_physics"], row[f"{mode}_corrected"] = a, b
                row[f"{mode}_ratio"] = (b / a if a and b is not None and math.isfinite(a)
                                        and a > 0 else None)
            row["worse_at_1s"] = bool(row["horizon_1s_ratio"] is not None
                                      and row["horizon_1s_ratio"] > 1.0)
            row["diverged_where_physics_did_not"] = bool(
                rh["free_run"] is not None and not math.isfinite(rh["free_run"])
                and rp["free_run"] is not None and math.isfinite(rp["free_run"]))
            per_sortie.append(row)
        z0 = step.initial_state(ds.test[0].states[0], ds.test[0].controls[:1], fitted.p,
                                sample_dt)
        out["cost"] = cost_ratio(step, physics, z0, ds.test[0].controls[0], fitted.p,
                                 sample_dt)
        bare = dataclasses.replace(result.net, envelope=None, out_bound=None)
        out["cost_without_gate_and_bound"] = cost_ratio(
            hybrid_step(bare, fitted, compile=False), physics, z0, ds.test[0].controls[0],
            fitted.p, sample_dt)
    else:
        per_sortie = [{"sortie": r["sortie"], "condition": r["condition"],
                       "horizon_1s_physics": r["horizon_1s"],
                       "free_run_physics": r["free_run"]} for r in rows_p]
    groups: dict = {}
    for row in per_sortie:
        groups.setdefault(row["condition"], []).append(row)
    pooled = {}
    for cond, rows in groups.items():
        entry = {"sorties": len(rows)}
        for mode in ("horizon_1s", "free_run"):
            for which in ("physics", "corrected"):
                vals = [r.get(f"{mode}_{which}") for r in rows]
                if any(v is None for v in vals):
                    continue
                entry[f"{mode}_{which}"] = (math.sqrt(float(np.mean(np.square(vals))))
                                            if all(math.isfinite(v) for v in vals)
                                            else math.inf)
            ratios = [r.get(f"{mode}_ratio") for r in rows if r.get(f"{mode}_ratio")]
            if ratios:
                entry[f"{mode}_ratio_min_median_max"] = [float(np.min(ratios)),
                                                          float(np.median(ratios)),
                                                          float(np.max(ratios))]
        entry["worse_at_1s"] = sum(bool(r.get("worse_at_1s")) for r in rows)
        entry["worse_by_more_than_10pct_at_1s"] = sum(
            1 for r in rows if (r.get("horizon_1s_ratio") or 0) > 1.1)
        entry["diverged_where_physics_did_not"] = sum(
            bool(r.get("diverged_where_physics_did_not")) for r in rows)
        pooled[cond] = entry
    out["pooled"] = pooled
    out["per_sortie"] = per_sortie
    return out


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--airframes", nargs="+", default=["fixed_wing", "quadrotor"],
                        choices=sorted(PRESET))
    parser.add_argument("--epochs", type=int, default=SafeConfig.epochs)
    parser.add_argument("--max-seconds", type=float, default=3600.0)
    parser.add_argument("--cache", default=None, help="dataset cache folder")
    parser.add_argument("--weights-dir", default=None, help="keep weights and histories here")
    parser.add_argument("--out", default=None)
    parser.add_argument("--reuse", action="store_true",
                        help="use the weights already in --weights-dir (no training)")
    parser.add_argument("--quiet", action="store_true")
    parser.add_argument("--markdown", default=None, help="also write the README table here")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    result = {"command": "python analysis/bench_hybrid.py " + " ".join(
        sys.argv[1:] if argv is None else argv), "machine": platform.processor() or
        platform.machine(), "airframes": [run_airframe(a, args) for a in args.airframes]}
    text = json.dumps(result, indent=2, default=str)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(text + "\n")
    print(text)
    if args.markdown:
        Path(args.markdown).write_text(markdown(result))
    return result


def markdown(result: dict) -> str:
    """The README's table of a benchmark result (``--markdown FILE``): per airframe and test
    group, the ladder identified physics -> corrected at 1 s and free run, the sorties where
    the correction is worse, and the cost of the step."""
    rows = ["| airframe | test group | 1 s: identified physics -> corrected (ratio) | sorties "
            "worse at 1 s (by > 10 %) | free run: identified -> corrected | diverged where "
            "physics did not | step cost vs physics |", "|---|---|---|---|---|---|---|"]

    def g(v):
        return "n/a" if v is None else ("diverged" if not math.isfinite(v) else f"{v:.3g}")

    for af in result["airframes"]:
        cost = af.get("cost")
        first = True
        for cond, e in af.get("pooled", {}).items():
            p1, c1 = e.get("horizon_1s_physics"), e.get("horizon_1s_corrected")
            ratio = f" ({c1 / p1:.2f})" if p1 and c1 is not None and math.isfinite(c1) else ""
            cost_text = (f"{cost['ratio']:.2f}x ({cost['hybrid_us_per_step']:.2f} vs "
                         f"{cost['physics_us_per_step']:.2f} us)" if cost and first else "")
            rows.append(f"| {af['airframe']} | {cond} ({e['sorties']}) | {g(p1)} -> {g(c1)}"
                        f"{ratio} | {e.get('worse_at_1s', 'n/a')} "
                        f"({e.get('worse_by_more_than_10pct_at_1s', 'n/a')}) of {e['sorties']} | "
                        f"{g(e.get('free_run_physics'))} -> {g(e.get('free_run_corrected'))} | "
                        f"{e.get('diverged_where_physics_did_not', 'n/a')} | {cost_text} |")
            first = False
        if not af.get("kept"):
            rows.append(f"| {af['airframe']} | - | correction not kept: {af['reason']} | | | | |")
    return "\n".join(rows) + "\n"


if __name__ == "__main__":
    main()
