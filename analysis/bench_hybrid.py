"""Benchmark of the hybrid step: cost per compiled step inside a ``mapaccum`` rollout against the
plain RK4 step, and the free-run pitch accuracy each network reaches, for every width,
activation and formulation considered. Prints JSON (and writes it with ``--out``).

Accuracy: free-run pitch RMSE (rad) at dt = 0.005 s against calm flight data — the test split of
``--dataset`` (calm sorties only) or, without it, perturbed-model stand-in sorties
(:func:`uavdyn.learned.data.synthetic_sorties`, seeds disjoint from training). The default
network is the shipped weight file; the other variants are trained here (torch) with
``--train-seconds`` each, on the same data source, and cached in ``--cache``
(``--retrain`` to redo).

Timings are medians of ``--repeats`` runs on a shared 2-core machine: expect up to 60 % noise.
Usage: ``python analysis/bench_hybrid.py [--airframe aerosonde] [--dataset DIR] [--out F]``.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from uavdyn.airframes import load_airframe
from uavdyn.evaluation import sortie_free_run
from uavdyn.integrate import compile_function, rk4_step, rollout
from uavdyn.learned import hybrid_step, load_weights, shipped_weights
from uavdyn.model import build_model

DT = 0.005
N_TIMING = 4000
VARIANTS = [("improved", "relu", 8), ("improved", "relu", 16), ("improved", "relu", 32),
            ("improved", "tanh", 8), ("improved", "tanh", 16),
            ("paper", "relu", 16), ("hypersolver", "relu", 16)]


def median_us_per_step(fn, args, repeats: int) -> float:
    fn(*args)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(*args)
        times.append(time.perf_counter() - t0)
    return statistics.median(times) / N_TIMING * 1e6


def pitch_errors(step, sorties, p, dt: float = DT) -> dict:
    """Pooled free-run pitch RMSE against measured and (if logged) true states."""
    meas, true = [], []
    for s in sorties:
        theta = sortie_free_run(step, s, p, dt)[:, 3]
        meas.append(theta - s.states[:, 3])
        if getattr(s, "true_states", None) is not None:
            true.append(theta - s.true_states[:, 3])
    out = {"vs_data": float(np.sqrt(np.mean(np.concatenate(meas) ** 2)))}
    if true:
        out["vs_true_states"] = float(np.sqrt(np.mean(np.concatenate(true) ** 2)))
    return out


def load_sorties(args, airframe):
    if args.dataset:
        from uavdyn.flightdata import load_dataset

        ds = load_dataset(args.dataset)
        calm = [s for s in ds.test if s.meta.get("condition", "calm") == "calm"]
        if not calm:
            raise SystemExit(f"{args.dataset}: no calm sorties in the test split")
        return ds.train, ds.validation, calm, f"dataset {args.dataset} (calm test sorties)"
    from uavdyn.learned.data import split_sorties, synthetic_sorties

    train_val = synthetic_sorties(airframe, 20, seed=0, duration=20.0)
    tr, va, _ = split_sorties(train_val, seed=0)
    test = synthetic_sorties(airframe, 8, seed=1000, duration=20.0)
    return tr, va, test, "perturbed-model stand-in sorties (uavdyn.learned.data.synthetic_sorties)"


def windows(sorties, seconds: float | None):
    """Cut sorties into consecutive free-run windows of ``seconds`` (None: whole sorties).
    Needed for the multirotor, whose open-loop replay of closed-loop flights diverges."""
    if not seconds:
        return sorties
    from dataclasses import replace

    out = []
    for s in sorties:
        m = int(round(seconds / s.dt))
        for k in range(0, len(s.time) - m, m):
            sl = slice(k, k + m + 1)
            true = None if s.true_states is None else s.true_states[sl]
            out.append(replace(s, name=f"{s.name}@{k}", time=s.time[sl],
                               states=s.states[sl], controls=s.controls[sl], true_states=true))
    return out


def variant_net(args, airframe, formulation, activation, width, tr, va):
    cache = Path(args.cache) / f"{airframe.name}_{formulation}_{activation}{width}.npz"
    if cache.exists() and not args.retrain:
        return load_weights(cache, airframe), "cached"
    from uavdyn.learned import save_weights
    from uavdyn.learned.train import TrainConfig, train

    cfg = TrainConfig(formulation=formulation, activation=activation, hidden=width, dt=DT,
                      max_seconds=args.train_seconds, progress=False)
    result = train(tr, va, airframe, cfg)
    save_weights(result.net, cache)
    return result.net, "trained"


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--airframe", default="aerosonde")
    parser.add_argument("--dataset", default=None, help="dataset folder (default: stand-in)")
    parser.add_argument("--weights", default=None,
                        help="default network (default: the shipped weights of the airframe)")
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--train-seconds", type=float, default=60.0,
                        help="training budget per variant (default 60 s)")
    parser.add_argument("--cache", default="results/bench_hybrid")
    parser.add_argument("--retrain", action="store_true")
    parser.add_argument("--no-variants", action="store_true",
                        help="time and score the default network only")
    parser.add_argument("--window-s", type=float, default=None,
                        help="free-run windows of this many seconds (default: whole sorties)")
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)

    af = load_airframe(args.airframe)
    tr, va, test, source = load_sorties(args, af)
    test = windows(test, args.window_s)
    rk4 = rk4_step(build_model(af).f)
    u_timing = np.repeat(test[0].controls[:N_TIMING // 2], 2, axis=0)[:N_TIMING]
    if len(u_timing) < N_TIMING:
        u_timing = np.vstack([u_timing, np.tile(u_timing[-1], (N_TIMING - len(u_timing), 1))])
    x0 = test[0].states[0]
    rk4_sim = compile_function(rollout(rk4, N_TIMING))
    rk4_us = median_us_per_step(rk4_sim, [x0, u_timing.T, af.p, DT], args.repeats)

    def cost(step, formulation):
        sim = compile_function(rollout(step, N_TIMING))
        extra = [0.0] if formulation == "paper" else []
        return median_us_per_step(sim, [x0, u_timing.T, af.p, DT, *extra], args.repeats)

    physics = pitch_errors(rk4, test, af.p)
    physics_2dt = pitch_errors(rk4, test, af.p, 2 * DT)
    weights = Path(args.weights) if args.weights else shipped_weights(af.name)
    net = load_weights(weights, af)
    step = hybrid_step(net, af, compile=False)
    hybrid_us = cost(step, net.formulation)
    hybrid = pitch_errors(step, test, af.p)
    report = {
        "airframe": af.name, "dt": DT, "accuracy_data": source, "n_test_sorties": len(test),
        "free_run": f"windows of {args.window_s:g} s" if args.window_s else "whole sorties",
        "timing": f"median of {args.repeats} runs of a compiled {N_TIMING}-step mapaccum "
                  "rollout; shared 2-core machine: up to 60 % run-to-run noise",
        "default_network": net.describe(), "default_weights": str(weights),
        "default_trained_on": net.info.get("data_source", net.info.get("train_sorties_source")),
        "rk4_us_per_step": rk4_us, "hybrid_us_per_step": hybrid_us,
        "cost_ratio": hybrid_us / rk4_us,
        "pitch_rmse_physics_rad": physics["vs_data"], "pitch_rmse_hybrid_rad": hybrid["vs_data"],
        "rmse_reduction": physics["vs_data"] / hybrid["vs_data"],
        "targets": {"cost_ratio_max": 3.0, "rmse_reduction_min": 5.0},
        "pitch_rmse_physics_at_2dt_rad": physics_2dt["vs_data"],
    }
    if "vs_true_states" in physics:
        report["pitch_rmse_physics_vs_true_rad"] = physics["vs_true_states"]
        report["pitch_rmse_hybrid_vs_true_rad"] = hybrid["vs_true_states"]

    variants = []
    if not args.no_variants:
        for formulation, activation, width in VARIANTS:
            vnet, how = variant_net(args, af, formulation, activation, width, tr, va)
            vstep = hybrid_step(vnet, af, compile=False)
            us = cost(vstep, formulation)
            err = pitch_errors(vstep, test, af.p)
            # step-size transfer: the same network run at twice its training step
            err2 = pitch_errors(vstep, test, af.p, 2 * DT)
            variants.append({
                "formulation": formulation, "activation": activation, "width": width,
                "weights": how, "us_per_step": us, "cost_ratio": us / rk4_us,
                "pitch_rmse_rad": err["vs_data"],
                "rmse_reduction": physics["vs_data"] / err["vs_data"],
                "pitch_rmse_at_2dt_rad": err2["vs_data"],
                "best_val_loss": vnet.info.get("best_val_total"),
                "initial_val_loss": vnet.info.get("initial_val_total"),
                "epochs": vnet.info.get("epochs_run"),
                **({"pitch_rmse_vs_true_rad": err["vs_true_states"]}
                   if "vs_true_states" in err else {})})
            print(json.dumps(variants[-1]), file=sys.stderr)
    report["variants"] = variants
    report["machine"] = {"python": platform.python_version(), "machine": platform.machine()}
    text = json.dumps(report, indent=2)
    print(text)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(text + "\n")
    return report


if __name__ == "__main__":
    main()
