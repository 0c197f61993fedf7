"""The controller Monte Carlo of issue 43: ``uavdyn montecarlo --controller mpc`` and
``--controller lqr`` on the same dispersed airframes and gusts (the 2 m trainer of
``examples/trainer.toml``, +-15 % stability derivatives and mass terms, Dryden gusts of random
intensity: ``trainer_pm15_gusty``), each run tracking the pitch step over ``--duration``.

Runs each command in a subprocess (wall time and load average before and after), reads its
``drivers.json`` and writes ``<out>.json`` (every figure and both sensitivity tables) and
``<out>.md`` (the tables side by side). Run from the repository root::

    python analysis/montecarlo_controllers.py --runs 1000 --duration 20 --workers 2 \\
        --out docs/benchmarks/montecarlo_controllers
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CONTROLLERS = ("mpc", "lqr")


def run_one(controller: str, args: argparse.Namespace, folder: Path) -> dict:
    """Run one command; its figures, wall time and load."""
    argv = ["montecarlo", "--airframe", args.airframe, "--controller", controller,
            "--runs", str(args.runs), "--duration", f"{args.duration:g}",
            "--dispersions", args.dispersions, "--workers", str(args.workers),
            "--no-progress", "--force", "--out", str(folder / controller)]
    before = [round(v, 2) for v in os.getloadavg()]
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", "import sys; from uavdyn.cli import main; "
                           "sys.exit(main(sys.argv[1:]))", *argv], cwd=ROOT,
                          capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"uavdyn {' '.join(argv)} failed: {done.stderr.strip()}")
    doc = json.loads((folder / controller / "drivers.json").read_text())
    return {"command": "uavdyn " + " ".join(argv[:-1] + ["DIR"]), "wall_s": wall,
            "per_run_s": wall / args.runs, "load_before": before,
            "load_after": [round(v, 2) for v in os.getloadavg()],
            "controller": doc["controller_description"], "summary": doc["summary"],
            "worst_runs": doc["worst_runs"][:10], "drivers": doc["drivers"],
            "stdout": done.stdout.strip().splitlines()[:1]}


def markdown(doc: dict) -> str:
    """The two studies' figures and sensitivity tables."""
    c = doc["config"]
    lines = [f"# Controller Monte Carlo: {c['runs']} runs x {c['duration']:g} s, "
             f"{c['airframe']}, `{c['dispersions']}`", "",
             f"Produced by `{doc['produced_by']}` on {doc['machine']}.", "",
             "| controller | wall (s) | per run (s) | load before/after | departed | "
             "failed solves | fallbacks | tracking RMSE p50 / p95 / max (rad) | "
             "on a bound | on a rate limit |", "|---|---|---|---|---|---|---|---|---|---|"]
    for name in CONTROLLERS:
        if name not in doc["studies"]:
            continue
        s = doc["studies"][name]
        f = s["summary"]
        lines.append(
            f"| {name.upper()} | {s['wall_s']:.1f} | {s['per_run_s']:.3f} | "
            f"{s['load_before'][0]:.1f} / {s['load_after'][0]:.1f} | {f['departed']} | "
            f"{f['failed_solves']} ({f['runs_with_failed_solves']} runs) | {f['fallbacks']} | "
            f"{f['tracking_rmse_p50']:.4f} / {f['tracking_rmse_p95']:.4f} / "
            f"{f['tracking_rmse_max']:.4f} | {f['bound_share_mean']:.2%} | "
            f"{f['rate_share_mean']:.2%} |")
    for name in CONTROLLERS:
        if name not in doc["studies"]:
            continue
        s = doc["studies"][name]
        lines += ["", f"## Sensitivity: {name.upper()} ({s['controller']})", "",
                  "| dispersed quantity | explains (share of error-rank variance) | "
                  "rank correlation | worst 10 % shift (sd) |", "|---|---|---|---|"]
        lines += [f"| {d['column']} | {d['explained']:.2f} | {d['spearman']:+.2f} | "
                  f"{d['worst_shift_sd']:+.2f} |" for d in s["drivers"]]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--airframe", default="examples/trainer.toml")
    parser.add_argument("--dispersions", default="trainer_pm15_gusty")
    parser.add_argument("--runs", type=int, default=1000)
    parser.add_argument("--duration", type=float, default=20.0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--controllers", default="mpc,lqr")
    parser.add_argument("--work", default="results/montecarlo_controllers",
                        help="folder of the studies' outputs")
    parser.add_argument("--out", required=True, help="output stem (.json and .md)")
    args = parser.parse_args()
    folder = Path(args.work)
    studies = {c: run_one(c, args, folder) for c in args.controllers.split(",")}
    doc = {"analysis": "montecarlo_controllers",
           "produced_by": "python analysis/montecarlo_controllers.py --runs "
                          f"{args.runs} --duration {args.duration:g} --workers {args.workers} "
                          f"--out {args.out}",
           "machine": f"{platform.machine()}, {os.cpu_count()} cores, shared (load stated)",
           "config": {"airframe": args.airframe, "dispersions": args.dispersions,
                      "runs": args.runs, "duration": args.duration, "workers": args.workers,
                      "scenario": "pitch-step"},
           "studies": studies}
    stem = Path(args.out)
    stem.parent.mkdir(parents=True, exist_ok=True)
    for suffix, text in ((".json", json.dumps(doc, indent=2) + "\n"), (".md", markdown(doc))):
        tmp = stem.with_name(f".{stem.name}{suffix}.tmp")
        tmp.write_text(text)
        os.replace(tmp, stem.with_name(stem.name + suffix))
    print(markdown(doc))


if __name__ == "__main__":
    main()
