"""The README pipeline's training and evaluation over several training seeds and training
options (issue 40): is a change of `uavdyn train`'s defaults better than the spread between
training runs, on data the change was not made on?

For each seed and each ``--option`` set, ``uavdyn train --seed S OPTIONS`` on the dataset and
identified airframe, then ``uavdyn evaluate``; per test sortie the 1 s pitch ratio corrected /
identified, the sorties worse by more than 2 %, and per option (a list, in the order given)
the geometric mean over every seed's sorties and the paired difference of the seeds' mean
log ratios (with its t statistic) against the first option.

    python analysis/pipeline_seeds.py --airframe examples/x500.toml --identified id.toml \\
        --dataset flights --seeds 0 1 2 3 4 \\
        --option "--damping-weight 0" --option "--damping-weight 10" --out seeds.json

The dataset and identified file are the README's steps (``uavdyn generate-data``, ``split``,
``identify``); nothing here is tuned to them.
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import sys
import tempfile
from pathlib import Path

import numpy as np

from uavdyn.cli import main as uavdyn

WORSE_BY = 0.02


def train_and_evaluate(args: argparse.Namespace, seed: int, option: str, work: Path) -> dict:
    """One training run and its evaluation: per test sortie the 1 s ratio, whether it was
    kept."""
    weights = work / f"s{seed}.npz"
    train = ["train", "--airframe", str(args.identified), "--dataset", str(args.dataset),
             "--out", str(weights), "--quiet", "--seed", str(seed), *shlex.split(option)]
    if uavdyn(train) != 0:
        raise SystemExit(f"error: uavdyn {' '.join(train)} failed")
    history = json.loads((work / f"s{seed}_history.json").read_text())
    evaluation = work / f"s{seed}_eval.json"
    evaluate = ["evaluate", "--airframe", str(args.airframe), "--identified",
                str(args.identified), "--weights", str(weights), "--dataset",
                str(args.dataset), "--out", str(evaluation)]
    if uavdyn(evaluate) != 0:
        raise SystemExit(f"error: uavdyn {' '.join(evaluate)} failed")
    sorties = json.loads(evaluation.read_text())["per_sortie"][0]["sorties"]
    ratios = {s["sortie"]: float(s["horizon_1s_ratio"]) for s in sorties}
    return {"seed": seed, "kept": bool(history.get("kept", True)),
            "best_epoch": history.get("best_epoch"), "train_seconds": history.get("seconds"),
            "ratio_1s": ratios,
            "worse": [k for k, r in ratios.items() if r > 1.0 + WORSE_BY]}


def summarise(runs: list[dict]) -> dict:
    """Geometric mean ratio over every run's sorties, the sorties worse, and each seed's mean
    log ratio."""
    logs = [[math.log(r) for r in run["ratio_1s"].values()] for run in runs]
    return {"geomean_ratio": float(np.exp(np.mean(np.concatenate(logs)))),
            "n_worse": sum(len(run["worse"]) for run in runs),
            "n_sorties": sum(len(run["ratio_1s"]) for run in runs),
            "seed_mean_log_ratio": [float(np.mean(v)) for v in logs]}


def paired(base: dict, other: dict) -> dict:
    """The seeds' mean log ratios of ``other`` minus ``base``: mean, standard error, t (None
    where there is no spread: one seed, or ``other`` is ``base``)."""
    d = np.subtract(other["seed_mean_log_ratio"], base["seed_mean_log_ratio"])
    se = float(np.std(d, ddof=1) / math.sqrt(len(d))) if len(d) > 1 else 0.0
    return {"mean_log_difference": float(np.mean(d)), "standard_error": se,
            "t": float(np.mean(d) / se) if se > 0 else None}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--airframe", required=True, type=Path, help="the nominal airframe file")
    ap.add_argument("--identified", required=True, type=Path, help="uavdyn identify's file")
    ap.add_argument("--dataset", required=True, type=Path, help="the split dataset folder")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--option", action="append", required=True,
                    help="uavdyn train options of one configuration (repeat; the first is "
                         "the base of the paired differences)")
    ap.add_argument("--out", required=True, type=Path, help="result JSON")
    args = ap.parse_args(argv)
    result = {"command": "python analysis/pipeline_seeds.py "
                         + " ".join(shlex.quote(a) for a in (argv or sys.argv[1:])),
              "worse_by_more_than": WORSE_BY, "options": []}
    for option in args.option:
        runs = []
        for seed in args.seeds:
            with tempfile.TemporaryDirectory() as tmp:
                runs.append(train_and_evaluate(args, seed, option, Path(tmp)))
            print(f"{option!r} seed {seed}: " + ", ".join(
                f"{k} {v:.3f}" for k, v in runs[-1]["ratio_1s"].items()), flush=True)
        result["options"].append({"option": option, "runs": runs, **summarise(runs)})
    base = result["options"][0]
    for entry in result["options"]:
        entry["against_first"] = paired(base, entry)
        t = entry["against_first"]["t"]
        print(f"{entry['option']!r}: geometric mean ratio {entry['geomean_ratio']:.3f}, "
              f"{entry['n_worse']} of {entry['n_sorties']} sorties worse by more than "
              f"{100 * WORSE_BY:.0f} %" + ("" if t is None else
                                          f", paired t against the first {t:.2f}"))
    tmp = args.out.with_name(args.out.name + ".tmp")
    tmp.write_text(json.dumps(result, indent=1))
    tmp.replace(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
