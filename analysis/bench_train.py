"""Benchmark of the safe trainer (issue 32, item 3): ``uavdyn train``'s training run on an
11 x 30 s fixed-wing dataset the model cannot reproduce, with the window rollouts and their
gradients in compiled CasADi code (the default) and in torch (the route before), printed as
JSON (and written with ``--out``).

Usage: ``python analysis/bench_train.py [--routes compiled,torch] [--out
docs/benchmarks/bench_train.json]``.

The data: the emulator flies ``--truth``'s scaled copy of the model airframe (default: the
non-preset trainer, ``examples/trainer.toml``, with ``C_m_alpha`` x 1.25, ``C_m_q`` x 0.7,
``C_D_0`` x 1.4, ``C_L_alpha`` x 0.92), 16 sorties of 30 s at 100 Hz, split by sortie 11 / 3 / 2
(seed 1); the correction trains on the unscaled model file, at the trainer's defaults (the
same :class:`~uavdyn.learned.safe.SafeConfig` as ``uavdyn train``), one thread. Each route
records its wall and CPU time, epochs run, why it stopped, the best epoch, whether the
correction was kept and its validation figures; the routes' per-epoch validation pitch errors
are compared.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from uavdyn.airframes import load_airframe
from uavdyn.emulation.datagen import Recipe, generate_dataset
from uavdyn.flightdata import load_dataset
from uavdyn.flightdata.split import split_dataset
from uavdyn.identify.report import airframe_toml
from uavdyn.learned.safe import SafeConfig, train_safe

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_TRUTH = "C_m_alpha=1.25,C_m_q=0.7,C_D_0=1.4,C_L_alpha=0.92"


def _load() -> list[float]:
    return [round(v, 2) for v in os.getloadavg()]


def _scales(text: str) -> dict[str, float]:
    pairs = (item.split("=") for item in text.split(",") if item)
    return {name.strip(): float(value) for name, value in pairs}


def _dataset(model_file: Path, scales: dict[str, float], sorties: int, duration: float,
             seed: int, folder: Path) -> Path:
    """The truth's airframe file and its dataset, split by sortie."""
    model = load_airframe(model_file)
    truth = model.replace(**{n: model.params.__dict__[n] * f for n, f in scales.items()})
    truth_file = folder / "truth.toml"
    truth_file.write_text(airframe_toml(truth, [f"truth of bench_train: {model.name} with "
                                                f"{scales}"]))
    data = folder / "flights"
    generate_dataset(Recipe(airframe=str(truth_file), sorties=sorties, seed=seed,
                            duration_s=duration), data, progress=False)
    split_dataset(data, seed=1)
    return data


def _route(name: str, data: Path, model_file: Path) -> dict:
    ds = load_dataset(data)
    airframe = load_airframe(model_file)
    load_before = _load()
    t0, cpu0 = time.perf_counter(), time.process_time()
    result = train_safe(ds.train, ds.validation, airframe,
                        SafeConfig(compiled=name == "compiled", progress=False))
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    seconds = [row["seconds"] for row in result.history]
    v = result.validation
    return {
        "route": name, "wall_s": round(wall, 1), "cpu_s": round(cpu, 1),
        "epochs_run": len(result.history) - 1, "stopped": result.stopped,
        "best_epoch": result.best_epoch, "kept": result.kept, "reason": result.reason,
        "seconds_before_epoch_1": round(seconds[0], 2),
        "seconds_per_epoch_mean": round(float(np.mean(np.diff(seconds))), 3)
        if len(seconds) > 1 else None,
        "seconds_after_last_epoch": round(wall - seconds[-1], 2),
        "validation_1s_pitch_rmse_rad": {"physics": v.get("physics_theta_rmse"),
                                         "corrected": v.get("corrected_theta_rmse"),
                                         "ratio": v.get("ratio"),
                                         "sortie_ratio_worst": v.get("sortie_ratio_worst")},
        "val_theta_rmse_per_epoch": [row["val_theta_rmse"] for row in result.history],
        "load_average_1_5_15_before": load_before, "load_average_after": _load(),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--airframe", default=str(ROOT / "examples" / "trainer.toml"))
    parser.add_argument("--truth", default=DEFAULT_TRUTH,
                        help="NAME=FACTOR,... scaling the model's parameters for the emulator")
    parser.add_argument("--sorties", type=int, default=16)
    parser.add_argument("--duration", type=float, default=30.0)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--routes", default="compiled,torch")
    parser.add_argument("--out", default=None, help="also write the JSON here")
    args = parser.parse_args(argv)
    model_file = Path(args.airframe)
    doc: dict = {
        "benchmark": "safe trainer", "command": "python analysis/bench_train.py "
        + " ".join(argv if argv is not None else sys.argv[1:]),
        "model_airframe": str(model_file.relative_to(ROOT) if model_file.is_relative_to(ROOT)
                              else model_file),
        "truth_scales": _scales(args.truth), "sorties": args.sorties,
        "duration_s": args.duration, "seed": args.seed, "split": "by sortie, seed 1",
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, {platform.python_version()}",
        "note": "one route at a time, nothing else of ours on the machine; load beside each",
    }
    with tempfile.TemporaryDirectory() as tmp:
        data = _dataset(model_file, doc["truth_scales"], args.sorties, args.duration,
                        args.seed, Path(tmp))
        ds = load_dataset(data)
        doc["split_sizes"] = {k: len(getattr(ds, k)) for k in ("train", "validation", "test")}
        doc["routes"] = [_route(name, data, model_file) for name in args.routes.split(",")]
    curves = [r.pop("val_theta_rmse_per_epoch") for r in doc["routes"]]
    if len(curves) == 2:
        n = min(len(c) for c in curves)
        doc["val_theta_rmse_max_difference_common_epochs"] = float(
            np.max(np.abs(np.subtract(curves[0][:n], curves[1][:n]))))
        doc["common_epochs"] = n - 1
        doc["wall_ratio"] = round(doc["routes"][1]["wall_s"] / doc["routes"][0]["wall_s"], 1)
    text = json.dumps(doc, indent=2)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
