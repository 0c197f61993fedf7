"""The data commands: ``generate-data`` (the emulator) and ``import-log`` (real logs)."""

from __future__ import annotations

import argparse
from dataclasses import asdict
from pathlib import Path

import numpy as np

from uavdyn.airframes import list_presets
from uavdyn.cli.common import CliError, add_force
from uavdyn.emulation.datagen import Recipe, generate_dataset
from uavdyn.emulation.fingerprint import (
    DEFAULT_TOLERANCE,
    compare_fingerprints,
    dataset_fingerprint,
    read_fingerprint,
    shipped_reference,
    write_fingerprint,
)
from uavdyn.flightdata import (
    import_alfa,
    import_ulog,
    write_csv,
    write_manifest,
)
from uavdyn.outputs import check_output_folder, output_folder


def cmd_generate_data(args: argparse.Namespace) -> int:
    """Generate an emulated flight-data set (manifest.json + CSVs) from a recipe and options."""


    recipe = Recipe.from_json(args.recipe) if args.recipe else Recipe()
    overrides = {"airframe": args.airframe, "sorties": args.sorties, "seed": args.seed,
                 "duration_s": args.duration, "sample_rate_hz": args.rate,
                 "internal_dt_s": args.internal_dt, "turbulent_fraction": args.turbulent_fraction,
                 "noise_scale": args.noise_scale,
                 "missions": args.missions.split(",") if args.missions else None}
    values = asdict(recipe)
    values.update({k: v for k, v in overrides.items() if v is not None})
    recipe = Recipe(**values)
    if args.workers is not None and args.workers < 1:
        raise CliError(f"--workers must be >= 1, got {args.workers}")
    manifest = generate_dataset(recipe, args.out, workers=args.workers, force=args.force,
                                progress=not args.no_progress)
    print(f"wrote {manifest} ({recipe.sorties} sorties x {recipe.duration_s:g} s at "
          f"{recipe.sample_rate_hz:g} Hz, seed {recipe.seed})")
    if args.write_fingerprint or args.verify:
        found = dataset_fingerprint(args.out)
    if args.write_fingerprint:
        print(f"wrote {write_fingerprint(found, args.write_fingerprint)}")
    if args.verify:
        reference = (shipped_reference(Path(args.recipe).stem) if args.verify == "shipped"
                     and args.recipe else read_fingerprint(args.verify))
        comparison = compare_fingerprints(found, reference)
        message = comparison.describe(args.tolerance)
        if not comparison.matches(args.tolerance):
            raise CliError(f"dataset {args.out} differs from the reference: {message}")
        print(f"dataset matches the reference: {message}")
    return 0


def cmd_import_log(args: argparse.Namespace) -> int:
    """Import a PX4 ULog file or an ALFA folder into a one-sortie interchange dataset."""
    source = Path(args.log)
    fmt = args.format
    if fmt == "auto":
        fmt = "alfa" if source.is_dir() else "ulog"
    check_output_folder(args.out, "import-log", args.force)
    if fmt == "ulog":
        sortie = import_ulog(source, **({"rate_hz": args.rate} if args.rate else {}))
    else:
        sortie = import_alfa(source, **({"rate_hz": args.rate} if args.rate else {}))
    name = "".join(c if c.isalnum() or c in "_-" else "_" for c in sortie.name)[:64] or "log"
    with output_folder(args.out, "import-log", args.force) as tmp:
        write_csv(sortie, tmp / f"{name}.csv")
        write_manifest(tmp, airframe="", kind=sortie.kind,
                       sample_rate_hz=round(1.0 / float(np.median(np.diff(sortie.time))), 9),
                       source=f"uavdyn import-log ({fmt}) of {source.name}",
                       sorties=[{"file": f"{name}.csv", "mission": sortie.mission,
                                 "duration_s": sortie.duration}])
    print(f"wrote {args.out}/ ({sortie.kind}, {len(sortie.time)} rows, "
          f"{sortie.duration:.1f} s from {source.name})")
    return 0


def add_generate_data(sub) -> None:
    """Register ``generate-data``."""
    p = sub.add_parser("generate-data", help="generate an emulated flight-data set (SPEC 3 "
                       "format: manifest.json + one CSV per sortie)")
    add_force(p)
    p.add_argument("--recipe", default=None,
                   help="JSON recipe (e.g. data/datagen_quadrotor.json); options given here "
                        "override it")
    p.add_argument("--airframe", default=None,
                   help=f"preset ({', '.join(list_presets())}, quadrotor, fixed_wing) or "
                        "parameter file (default quadrotor)")
    p.add_argument("--sorties", type=int, default=None, help="number of sorties (default 100)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    p.add_argument("--duration", type=float, default=None, help="seconds per sortie (60)")
    p.add_argument("--rate", type=float, default=None, help="log rate in Hz (default 100)")
    p.add_argument("--internal-dt", type=float, default=None,
                   help="emulator RK4 step in s (default 0.001)")
    p.add_argument("--missions", default=None,
                   help="comma-separated mission names (default: all for the airframe kind)")
    p.add_argument("--turbulent-fraction", type=float, default=None,
                   help="fraction of turbulent sorties (default 0.5)")
    p.add_argument("--noise-scale", type=float, default=None,
                   help="sensor-noise multiplier (default 1, 0 = noise-free logs)")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes (default: all cores)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--verify", default=None, metavar="FINGERPRINT",
                   help="compare the values with a reference fingerprint JSON (by tolerance, "
                        "not bytes)")
    p.add_argument("--tolerance", type=float, default=DEFAULT_TOLERANCE,
                   help="largest allowed absolute difference for --verify (default 1e-9)")
    p.add_argument("--write-fingerprint", default=None, metavar="FINGERPRINT",
                   help="write the dataset's value fingerprint (JSON)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_generate_data)


def add_import_log(sub) -> None:
    """Register ``import-log``."""
    p = sub.add_parser("import-log", help="import a PX4 ULog file or an ALFA folder as a "
                       "one-sortie interchange dataset")
    add_force(p)
    p.add_argument("log", help="the .ulg file or ALFA sequence folder")
    p.add_argument("--format", choices=["auto", "ulog", "alfa"], default="auto",
                   help="auto: a folder is ALFA, a file is ULog")
    p.add_argument("--rate", type=float, default=None, help="grid rate in Hz (default: the "
                   "attitude topic's rate for ULog, 10 Hz for ALFA)")
    p.add_argument("--out", required=True, help="output dataset folder")
    p.set_defaults(func=cmd_import_log)
