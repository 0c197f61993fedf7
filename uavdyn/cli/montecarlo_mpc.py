"""``uavdyn montecarlo --mpc SCENARIO``: the real-time-iteration MPC in the loop of every run
(:mod:`uavdyn.montecarlo.controlled`), one run after the other; writes the per-run table, the
drivers of the worst runs and a summary."""

from __future__ import annotations

import argparse
import csv
import json

import numpy as np

from uavdyn.cli.common import CliError
from uavdyn.montecarlo import load_dispersions
from uavdyn.montecarlo.controlled import describe, fly_controlled_runs
from uavdyn.mpc import MPCConfig, scenario
from uavdyn.mpc.study import prediction_models
from uavdyn.outputs import output_folder

COMMAND = "montecarlo"
HORIZON = 20
# what the batch study's options are by default: with --mpc any other value would be ignored
BATCH_DEFAULTS = {"mission": "doublet", "duration": 60.0, "dt": 0.01, "chunk_size": 200,
                  "history_dt": 0.1, "workers": 1, "threads": 1}
BATCH_FLAGS = ("closed_loop", "vector_math", "workers_write", "scheduler")


def check_mpc_options(args: argparse.Namespace) -> None:
    """Refuse a batch-study option given with ``--mpc`` (it would be ignored)."""
    for name in BATCH_FLAGS:
        if getattr(args, name) not in (None, False):
            raise CliError(f"--{name.replace('_', '-')} applies to the batch study, not to "
                           "--mpc (the MPC runs fly one after the other in this process)")
    for name, default in BATCH_DEFAULTS.items():
        if getattr(args, name) != default:
            raise CliError(f"--{name.replace('_', '-')} applies to the batch study, not to "
                           f"--mpc (the scenario sets the duration, the MPC the interval)")


def cmd_montecarlo_mpc(args: argparse.Namespace) -> int:
    """Fly the MPC on ``--runs`` dispersed airframes through the ``--mpc`` scenario."""
    check_mpc_options(args)
    which = "physics" if args.weights is None else "hybrid"
    weights = None if args.weights in (None, "shipped") else args.weights
    setup = prediction_models(args.airframe, weights, mode="rti", models=(which,))
    if which not in setup.models:
        raise CliError(f"no hybrid prediction for {args.airframe}: "
                       f"{setup.missing.get(which, 'no correction')}")
    model = setup.models[which]
    controller = model.controller(MPCConfig(horizon=HORIZON, mode="rti"))
    plant = setup.plant_airframe
    dispersions = load_dispersions(args.dispersions, plant)
    seed = args.seed if args.seed is not None else (dispersions.seed or 0)
    sc = scenario(plant.kind, args.mpc)
    result = fly_controlled_runs(controller, plant, dispersions, sc, args.runs, seed,
                                 airspeed=args.airspeed)
    lines = describe(result)
    with output_folder(args.out, COMMAND, args.force) as tmp:
        with open(tmp / "runs.csv", "w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(result.columns)
            writer.writerows([[f"{v:.17g}" for v in row] for row in result.table])
        (tmp / "drivers.json").write_text(json.dumps({
            "scenario": sc.name, "prediction": model.description, "horizon": HORIZON,
            "runs": args.runs, "seed": seed, "worst_runs": result.worst_runs().tolist(),
            "drivers": [vars(d) for d in result.drivers]}, indent=2, default=float) + "\n")
        (tmp / "summary.md").write_text(
            f"# MPC in the loop: {sc.name}, {args.runs} runs\n\nRTI MPC, horizon {HORIZON}, "
            f"prediction {model.description}; plant: dispersed {plant.name} "
            f"({args.dispersions}), seed {seed}.\n\n" + "\n".join(f"- {line}" for line in lines)
            + "\n")
    print(f"wrote {args.out}/ (runs.csv, drivers.json, summary.md)")
    for line in lines[:3]:
        print(f"  {line}")
    departed = int(np.nansum(result.column("departed")))
    if departed:
        print(f"  {departed} run(s) departed (ranked worst)")
    return 0
