"""The ``uavdyn montecarlo`` command: argparse wiring and one thin function over
:mod:`uavdyn.montecarlo`.

Errors are :class:`uavdyn.montecarlo.MonteCarloError` / :class:`DispersionError` (``ValueError``
subclasses), which ``uavdyn.cli.main`` prints as one line with exit code 2.
"""

from __future__ import annotations

import argparse
import sys

from uavdyn.airframes import list_presets, load_airframe
from uavdyn.learned import shipped_correction
from uavdyn.montecarlo import (
    MonteCarloError,
    build_spec,
    input_names,
    load_dispersions,
    run_study,
)
from uavdyn.outputs import check_output_folder

COMMAND = "montecarlo"


def add_parser(sub) -> argparse.ArgumentParser:
    """Register ``montecarlo`` on the ``uavdyn`` sub-parsers ``sub``; returns its parser."""
    p = sub.add_parser(
        COMMAND, help="dispersed Monte-Carlo study: batched compiled runs, percentile "
        "envelopes, exceedance probabilities; resumable; on Dask with --workers/--scheduler",
        description="Fly N dispersed copies of an airframe (parameters, initial state, trim "
        "speed, Dryden gusts: see --dispersions) through one command input, in chunks of "
        "runs evaluated by one compiled CasADi Function each. Writes a per-run table, "
        "envelopes, exceedance probabilities with Wilson intervals, figures and a Markdown "
        "summary under --out; re-running the same command resumes from the finished chunks.")
    p.add_argument("--force", action="store_true",
                   help="write into a non-empty folder that is not this study's output "
                        "(replaces only montecarlo files; discards another study's chunks)")
    p.add_argument("--airframe", default="aerosonde",
                   help=f"preset name ({', '.join(list_presets())}) or path of a TOML/JSON "
                        "parameter file (default aerosonde)")
    p.add_argument("--weights", default=None,
                   help="weight file of a hybrid study ('shipped' = the preset's shipped safe "
                        "correction, run on the identified airframe it was trained on); "
                        "default: the physics RK4 step")
    p.add_argument("--runs", type=int, default=1000, help="number of runs (default 1000)")
    p.add_argument("--duration", type=float, default=60.0, help="seconds per run (default 60)")
    p.add_argument("--dispersions", required=True,
                   help="dispersion file (TOML; e.g. data/dispersions/aerosonde_pm15.toml; "
                        "format in docs/montecarlo.md)")
    p.add_argument("--mission", default="doublet",
                   help="command input: a mission or profile (fixed wing: "
                        f"{', '.join(input_names('fixed_wing'))}; multirotor adds inspection) "
                        "or a recorded interchange CSV; added to each run's trim command, "
                        "zero-order held (default doublet)")
    p.add_argument("--dt", type=float, default=0.01, help="RK4 step in s (default 0.01)")
    p.add_argument("--airspeed", type=float, default=None,
                   help="nominal trim airspeed in m/s before dispersion (default: the "
                        "airframe's)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=1,
                       help="worker processes: 1 (default) runs in this process, more start a "
                            "Dask LocalCluster (needs dask[distributed])")
    where.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="run the chunks on an existing Dask cluster (e.g. "
                            "tcp://host:8786)")
    p.add_argument("--workers-write", action="store_true",
                   help="with --scheduler: the cluster's workers see --out at the same path "
                        "(shared file system) and write their chunk files themselves; by "
                        "default the client writes them (a LocalCluster's workers always do)")
    p.add_argument("--threads", type=int, default=1,
                   help="CasADi threads per chunk (default 1)")
    p.add_argument("--chunk-size", type=int, default=200,
                   help="runs per chunk: one task, one file, the unit of resume (default 200)")
    p.add_argument("--seed", type=int, default=None,
                   help="study seed (default: the dispersion file's, else 0)")
    p.add_argument("--history-dt", type=float, default=0.1,
                   help="interval of the envelope samples in s (default 0.1)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_montecarlo)
    return p


def cmd_montecarlo(args: argparse.Namespace) -> int:
    """Run (or resume) a Monte-Carlo study and print where its results are."""
    for name in ("runs", "workers", "threads", "chunk_size"):
        value = getattr(args, name)
        if value is not None and value < 1:
            raise MonteCarloError(f"--{name.replace('_', '-')} must be >= 1, got {value}")
    if args.workers_write and args.scheduler is None:
        raise MonteCarloError("--workers-write applies to --scheduler (a LocalCluster's "
                              "workers write their chunk files anyway)")
    if args.seed is not None and args.seed < 0:
        raise MonteCarloError(f"--seed must be >= 0, got {args.seed}")
    check_output_folder(args.out, COMMAND, args.force)  # before any work
    airframe, weights = load_airframe(args.airframe), args.weights
    if weights == "shipped":  # the shipped safe correction, on the airframe it was trained on
        weights, airframe = shipped_correction(airframe.name)
    dispersions = load_dispersions(args.dispersions, airframe)
    spec = build_spec(airframe, dispersions, runs=args.runs, duration=args.duration,
                      dt=args.dt, mission=args.mission, weights=weights, seed=args.seed,
                      chunk_size=args.chunk_size, history_dt=args.history_dt,
                      airspeed=args.airspeed)
    try:
        result = run_study(spec, out=args.out, workers=args.workers, threads=args.threads,
                           scheduler=args.scheduler, progress=not args.no_progress,
                           force=args.force,
                           workers_write=True if args.workers_write else None)
    except KeyboardInterrupt:
        print(f"finished chunks are kept in {args.out}/chunks; run the same command again to "
              "resume", file=sys.stderr)
        raise
    table = result.table
    print(f"wrote {args.out}/ ({len(table)} runs x {spec.duration:g} s, {spec.model}; "
          f"{result.runs_computed} computed in {result.wall_s:.1f} s, "
          f"{result.runs_per_s:.0f} runs/s; {len(result.reused)} chunk(s) reused)")
    for e in result.exceedance:
        print(f"  P({e.event}) = {e.probability:.4g}  [{e.low:.4g}, {e.high:.4g}]  "
              f"({e.count}/{e.runs})")
    print(f"summary: {result.files.get('summary.md')}")
    return 0
