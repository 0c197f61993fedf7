"""``uavdyn montecarlo --controller lqr|mpc``: a controller in the loop of every dispersed run,
each tracking the ``--scenario`` reference in its gusts, in chunks (Dask with ``--workers`` or
``--scheduler``, resumable) (:mod:`uavdyn.montecarlo.controlled_study`); writes the per-run
table, the drivers of the worst runs and a summary. The option relations of the controller
study live here: the batch study's options are refused with it, the deprecated ``--mpc
SCENARIO`` is turned into ``--controller mpc --scenario SCENARIO``."""

from __future__ import annotations

import argparse
import sys
import warnings
from dataclasses import replace
from pathlib import Path

from uavdyn.airframes import load_airframe
from uavdyn.cli.common import CliError
from uavdyn.montecarlo import load_dispersions
from uavdyn.montecarlo.controlled_study import ControlledSpec, run_controlled_study
from uavdyn.mpc import MPCConfig, scenario

DEFAULT_SCENARIO = "pitch-step"
DEFAULT_CHUNK_SIZE = 25  # about 5 s of the C MPC per chunk at 20 s runs: a fine unit of resume
MAX_INTERVALS = 100_000  # control intervals per run
# what the batch study's options are by default: with --controller any other value is ignored
BATCH_DEFAULTS = {"mission": "doublet", "dt": 0.01, "history_dt": 0.1, "threads": 1}
BATCH_FLAGS = ("vector_math", "workers_write")


def resolve_controller(args: argparse.Namespace) -> str:
    """The controller asked for (``none``, ``lqr``, ``mpc``) after the deprecated spellings,
    refusing the combinations that contradict each other or would be ignored.

    Raises
    ------
    CliError
        Naming both options.
    """
    controller = args.controller
    if args.mpc is not None:
        if controller not in (None, "mpc"):
            raise CliError(f"--mpc {args.mpc} contradicts --controller {controller}; give "
                           f"--controller mpc --scenario {args.mpc}")
        if args.scenario not in (None, args.mpc):
            raise CliError(f"--mpc {args.mpc} contradicts --scenario {args.scenario}")
        controller, args.scenario = "mpc", args.mpc
    controller = controller or "none"
    if args.closed_loop and controller != "none":
        raise CliError(f"--closed-loop is the batch study's LQR (regulation about trim under "
                       f"--mission); --controller {controller} flies its own controller: give "
                       "one of them")
    if controller == "none":
        _refuse_given(args, {n: None for n in ("scenario", "mpc_backend")},
                      "applies to --controller lqr|mpc only")
        return controller
    _refuse_given(args, {n: False for n in BATCH_FLAGS},
                  f"applies to the batch study, not to --controller {controller}")
    _refuse_given(args, BATCH_DEFAULTS,
                  f"applies to the batch study, not to --controller {controller} (the "
                  "--scenario sets the reference, the controller the interval)")
    if controller == "lqr":
        _refuse_given(args, {n: None for n in ("weights", "mpc_backend")},
                      "applies to --controller mpc, not to --controller lqr")
    if args.mpc is not None:  # after the refusals: a refused command says one line
        print(f"note: --mpc SCENARIO is deprecated; give --controller mpc --scenario "
              f"{args.mpc}", file=sys.stderr)
    return controller


def cmd_montecarlo_controller(args: argparse.Namespace, controller: str) -> int:
    """Fly ``controller`` on ``--runs`` dispersed airframes tracking the ``--scenario``."""
    airframe = load_airframe(args.airframe)
    sc = scenario(airframe.kind, args.scenario or DEFAULT_SCENARIO)
    if args.duration is not None:
        dt = MPCConfig().dt
        steps = round(args.duration / dt)
        if not 1 <= steps <= MAX_INTERVALS:
            raise CliError(f"--duration {args.duration:g} s is {steps:.4g} control intervals "
                           f"of {dt:g} s; 1 to {MAX_INTERVALS} are allowed with --controller")
        sc = replace(sc, duration=float(args.duration))
    if sc.start >= sc.duration:
        raise CliError(f"--duration {sc.duration:g} s ends before the {sc.name} starts "
                       f"({sc.start:g} s)")
    dispersions = load_dispersions(args.dispersions, airframe)
    seed = args.seed if args.seed is not None else (dispersions.seed or 0)
    weights = None if args.weights in (None, "shipped") else str(Path(args.weights).resolve())
    weights = "shipped" if args.weights == "shipped" else weights
    source = str(Path(args.airframe).resolve()) if Path(args.airframe).is_file() \
        else str(args.airframe)  # a file: the same for Dask workers started elsewhere
    spec = ControlledSpec(source, weights, airframe, dispersions, controller, sc,
                          runs=args.runs, seed=seed,
                          chunk_size=args.chunk_size or DEFAULT_CHUNK_SIZE,
                          airspeed=args.airspeed, backend=args.mpc_backend or "auto")

    def progress(done: int, total: int) -> None:
        if not args.no_progress:
            print(f"\r  chunk {done}/{total}", end="" if done < total else "\n",
                  file=sys.stderr, flush=True)

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RuntimeWarning)
        try:
            study = run_controlled_study(spec, args.out, workers=args.workers,
                                         scheduler=args.scheduler, force=args.force,
                                         progress=progress)
        except KeyboardInterrupt:
            print(f"finished chunks are kept in {args.out}/chunks; run the same command "
                  "again to resume", file=sys.stderr)
            raise
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    from uavdyn.montecarlo.controlled import describe

    lines = describe(study.runs)
    print(f"wrote {args.out}/ (runs.csv, drivers.json, summary.md): {args.runs} runs x "
          f"{sc.duration:g} s, {study.controller}; {study.runs_computed} computed in "
          f"{study.wall_s:.1f} s; {len(study.reused)} chunk(s) reused")
    for line in lines[:5]:
        print(f"  {line}")
    return 0


def _refuse_given(args, defaults: dict, why: str) -> None:
    """One line for the first option given away from its default (``name -> default``;
    a flag's default False) where it does not apply."""
    for name, default in defaults.items():
        value = getattr(args, name)
        if (bool(value) if default is False else value != default):
            raise CliError(f"--{name.replace('_', '-')} {why}")
