"""The ``uavdyn montecarlo`` command: argparse wiring and one thin function over
:mod:`uavdyn.montecarlo`.

Errors are :class:`uavdyn.montecarlo.MonteCarloError` / :class:`DispersionError` (``ValueError``
subclasses), which ``uavdyn.cli.app`` prints as one line with exit code 2.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from uavdyn.airframes import KINDS, list_presets, load_airframe
from uavdyn.cli.common import (
    AIRSPEED,
    SEED,
    STEP,
    THREADS,
    WORKERS,
    CliError,
    airframe_name,
    count,
    existing_file,
    folder_to_write,
    seconds,
)
from uavdyn.learned import shipped_correction
from uavdyn.montecarlo import (
    MonteCarloError,
    build_spec,
    input_names,
    load_dispersions,
    run_study,
)
from uavdyn.montecarlo.dispersions import shipped_dispersions
from uavdyn.montecarlo.report import departure_warning
from uavdyn.montecarlo.spec import MAX_STEPS
from uavdyn.mpc.scenarios import SCENARIO_NAMES
from uavdyn.outputs import check_output_folder

COMMAND = "montecarlo"
MAX_RUNS = 1_000_000
MAX_CHUNK_SIZE = 100_000
# memory (measured, aerosonde_pm15): a chunk takes ~100 B per run-step (0.7 GB peak for 1000
# runs x 6000 steps, 2.1 GB for 200 x 100 000); the envelopes hold 5 signals x 8 B per sample
MAX_CHUNK_RUN_STEPS = 10_000_000  # runs x steps of one chunk (~1 GB)
MAX_HISTORY_SAMPLES = 10_000_000  # runs x envelope samples of the study (~0.4 GB)
INPUTS = tuple(dict.fromkeys(name for kind in KINDS for name in input_names(kind)))


def mission_input(text: str) -> str:
    """A mission or profile name (of either kind) or an existing CSV file."""
    if text in INPUTS or Path(text).is_file():
        return text
    what = "a folder" if Path(text).is_dir() else "neither a mission or profile nor a file"
    raise argparse.ArgumentTypeError(f"{text!r} is {what}; give one of {', '.join(INPUTS)} or "
                                     "a recorded interchange CSV")


def scheduler_address(text: str) -> str:
    """A Dask scheduler address ``[protocol://]host:port`` (port 1..65535)."""
    found = re.fullmatch(r"(?:[a-z][a-z0-9+.-]*://)?(\[[0-9a-fA-F:]+\]|[\w.-]+):(\d{1,5})", text)
    if not found or not 1 <= int(found.group(2)) <= 65535:
        raise argparse.ArgumentTypeError(f"must be a scheduler address [protocol://]host:port "
                                         f"(port 1..65535), got {text!r}")
    return text


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
    p.add_argument("--airframe", default="aerosonde", type=airframe_name,
                   help=f"preset name ({', '.join(list_presets())}) or path of a TOML/JSON "
                        "parameter file (default aerosonde)")
    p.add_argument("--weights", default=None,
                   type=existing_file("weight file", also=("shipped",)),
                   help="weight file of a hybrid study ('shipped' = the preset's shipped safe "
                        "correction, run on the identified airframe it was trained on); "
                        "default: the physics RK4 step")
    p.add_argument("--runs", type=count(MAX_RUNS, "runs"), default=1000,
                   help=f"number of runs, 1..{MAX_RUNS} (default 1000)")
    p.add_argument("--duration", type=seconds(name="duration"), default=None,
                   help=f"seconds per run (default 60, at most {MAX_STEPS} steps of --dt; "
                        "with --controller: the scenario's, at most 100000 intervals)")
    p.add_argument("--dispersions", required=True,
                   type=existing_file("dispersion file", also=shipped_dispersions()),
                   help="dispersion file (TOML; format in docs/montecarlo.md) or the name of "
                        f"a shipped example ({', '.join(shipped_dispersions())})")
    p.add_argument("--controller", default=None, choices=("none", "lqr", "mpc"),
                   help="none (default): the batch study (open loop, or --closed-loop); lqr "
                        "or mpc: that controller in the loop of every run, tracking the "
                        "--scenario reference on its dispersed airframe in its gusts, in "
                        "chunks (--workers, --scheduler, resumable); writes runs.csv, "
                        "drivers.json (which dispersion drives the worst runs), summary.md")
    p.add_argument("--scenario", default=None, choices=SCENARIO_NAMES,
                   help="with --controller: the reference each run tracks (default "
                        "pitch-step; references in docs/mpc.md), over --duration")
    p.add_argument("--mpc-backend", default=None, choices=("auto", "c", "python"),
                   help="with --controller mpc: auto (default) the exported C controller where "
                        "a C compiler is found, else the Python one with a warning; c or "
                        "python to choose (the same outcomes to round-off)")
    p.add_argument("--closed-loop", action="store_true",
                   help="batch study: fly every run with an LQR state feedback about its own "
                        "trim under --mission (the gain of the model linearised at the "
                        "nominal trim, stated in the summary); default open loop (an "
                        "unstable airframe departs). Deprecated: --controller lqr flies the "
                        "LQR tracking a --scenario reference")
    p.add_argument("--vector-math", action="store_true",
                   help="evaluate the maths functions of four runs in one call of glibc's "
                        "vector library (x86-64 with AVX2, glibc 2.35+): about 1.5x faster, "
                        "each run equal to the default's to round-off, not to the last bit")
    p.add_argument("--mission", default="doublet", type=mission_input,
                   help="command input: a mission or profile (fixed wing: "
                        f"{', '.join(input_names('fixed_wing'))}; multirotor adds inspection) "
                        "or a recorded interchange CSV; added to each run's trim command, "
                        "zero-order held (default doublet)")
    p.add_argument("--dt", type=STEP, default=0.01, help="RK4 step in s, 1e-6..1 (default "
                   "0.01)")
    p.add_argument("--airspeed", type=AIRSPEED, default=None,
                   help="nominal trim airspeed in m/s before dispersion, 0..100 (default: the "
                        "airframe's)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=WORKERS, default=1,
                       help="worker processes: 1 (default) runs in this process, more start a "
                            "Dask LocalCluster (needs dask[distributed])")
    where.add_argument("--scheduler", default=None, metavar="ADDRESS", type=scheduler_address,
                       help="run the chunks on an existing Dask cluster (e.g. "
                            "tcp://host:8786)")
    p.add_argument("--workers-write", action="store_true",
                   help="with --scheduler: the cluster's workers see --out at the same path "
                        "(shared file system) and write their chunk files themselves; by "
                        "default the client writes them (a LocalCluster's workers always do)")
    p.add_argument("--threads", type=THREADS, default=1,
                   help="CasADi threads per chunk (default 1)")
    p.add_argument("--chunk-size", type=count(MAX_CHUNK_SIZE, "runs"), default=None,
                   help="runs per chunk: one task, one file, the unit of resume (default 200, "
                        "25 with --controller; chunk-size x steps per run at most "
                        f"{MAX_CHUNK_RUN_STEPS})")
    p.add_argument("--seed", type=SEED, default=None,
                   help="study seed >= 0 (default: the dispersion file's, else 0)")
    p.add_argument("--history-dt", type=seconds(name="history-dt"), default=0.1,
                   help="interval of the envelope samples in s, from --dt to --duration "
                        f"(default 0.1; runs x samples at most {MAX_HISTORY_SAMPLES})")
    p.add_argument("--out", required=True, type=folder_to_write, help="output folder")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--mpc", default=None, choices=SCENARIO_NAMES,
                   help="deprecated spelling of --controller mpc --scenario SCENARIO")
    p.set_defaults(func=cmd_montecarlo)
    return p


def check_sizes(args: argparse.Namespace) -> None:
    """The relations of the sizes: steps per run, a chunk's and the envelopes' memory, the
    envelope interval between the step and the run."""
    steps = round(args.duration / args.dt)
    if not 1 <= steps <= MAX_STEPS:
        raise CliError(f"--duration {args.duration:g} s at --dt {args.dt:g} s is {steps:.4g} "
                       f"steps per run; 1 to {MAX_STEPS} are allowed")
    if args.chunk_size * steps > MAX_CHUNK_RUN_STEPS:
        raise CliError(f"--chunk-size {args.chunk_size} x {steps} steps per run (--duration "
                       f"{args.duration:g} s at --dt {args.dt:g} s) is "
                       f"{args.chunk_size * steps:.4g} run-steps in one chunk, more than "
                       f"{MAX_CHUNK_RUN_STEPS} (memory); give a smaller --chunk-size")
    if not args.dt * (1 - 1e-9) <= args.history_dt <= args.duration:
        raise CliError(f"--history-dt {args.history_dt:g} s must lie between --dt "
                       f"{args.dt:g} s and --duration {args.duration:g} s")
    samples = args.runs * (steps // max(1, round(args.history_dt / args.dt)) + 1)
    if samples > MAX_HISTORY_SAMPLES:
        raise CliError(f"--runs {args.runs} x {samples // args.runs} envelope samples "
                       f"(--duration / --history-dt) is {samples:.4g}, more than "
                       f"{MAX_HISTORY_SAMPLES} (memory); give fewer --runs or a longer "
                       "--history-dt")


def cmd_montecarlo(args: argparse.Namespace) -> int:
    """Run (or resume) a Monte-Carlo study and print where its results are."""
    from uavdyn.cli.montecarlo_controller import cmd_montecarlo_controller, resolve_controller

    controller = resolve_controller(args)
    if controller != "none":
        return cmd_montecarlo_controller(args, controller)
    if args.closed_loop:
        print("note: --closed-loop is deprecated (the batch study's LQR about trim); "
              "--controller lqr flies the LQR tracking a --scenario reference", file=sys.stderr)
    if args.duration is None:
        args.duration = 60.0
    if args.chunk_size is None:
        args.chunk_size = 200
    if args.workers_write and args.scheduler is None:
        raise MonteCarloError("--workers-write applies to --scheduler (a LocalCluster's "
                              "workers write their chunk files anyway)")
    check_sizes(args)
    check_output_folder(args.out, COMMAND, args.force)  # before any work
    airframe, weights = load_airframe(args.airframe), args.weights
    if args.mission in INPUTS and args.mission not in input_names(airframe.kind):
        raise CliError(f"--mission {args.mission} is not an input of the {airframe.kind} "
                       f"--airframe {args.airframe}; choose from "
                       f"{', '.join(input_names(airframe.kind))} or a CSV")
    if weights == "shipped":  # the shipped safe correction, on the airframe it was trained on
        weights, airframe = shipped_correction(airframe.name)
    dispersions = load_dispersions(args.dispersions, airframe)
    spec = build_spec(airframe, dispersions, runs=args.runs, duration=args.duration,
                      dt=args.dt, mission=args.mission, weights=weights, seed=args.seed,
                      chunk_size=args.chunk_size, history_dt=args.history_dt,
                      airspeed=args.airspeed, closed_loop=args.closed_loop,
                      vector_math=args.vector_math)
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
    warning = departure_warning(result)
    if warning:
        print(f"  {warning}")
    print(f"summary: {result.files.get('summary.md')}")
    return 0
