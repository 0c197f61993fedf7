"""The data commands: ``generate-data`` (the emulator) and ``import-log`` (real logs)."""

from __future__ import annotations

import argparse
from dataclasses import asdict
from pathlib import Path

import numpy as np

from uavdyn.airframes import list_presets, load_airframe
from uavdyn.cli.common import (
    FRACTION,
    MAX_SORTIE_ROWS,
    SEED,
    STEP,
    WORKERS,
    CliError,
    add_force,
    airframe_name,
    check_sortie_rows,
    count,
    existing_file,
    existing_path,
    file_to_write,
    folder_to_write,
    name_list,
    number,
    positive,
    refuse_unused,
    seconds,
)
from uavdyn.emulation.datagen import Recipe, generate_dataset
from uavdyn.emulation.fingerprint import (
    DEFAULT_TOLERANCE,
    compare_fingerprints,
    dataset_fingerprint,
    read_fingerprint,
    shipped_reference,
    write_fingerprint,
)
from uavdyn.emulation.missions import missions_for
from uavdyn.flightdata import (
    import_alfa,
    import_ulog,
    write_csv,
    write_manifest,
)
from uavdyn.flightdata.manifest import MANIFEST_MAX_SORTIES
from uavdyn.outputs import check_output_folder, output_folder

MAX_RATE_HZ = 1000.0         # a log grid rate: no logged topic is faster
MISSIONS = tuple(dict.fromkeys(missions_for("fixed_wing") + missions_for("multirotor")))


def cmd_generate_data(args: argparse.Namespace) -> int:
    """Generate an emulated flight-data set (manifest.json + CSVs) from a recipe and options."""
    refuse_unused(args, ("--tolerance",), args.verify is not None, "with --verify")
    if args.verify == "shipped" and not args.recipe:
        raise CliError("--verify shipped compares with the reference shipped for --recipe: "
                       "give --recipe, or --verify FILE")
    recipe = Recipe.from_json(args.recipe) if args.recipe else Recipe()
    overrides = {"airframe": args.airframe, "sorties": args.sorties, "seed": args.seed,
                 "duration_s": args.duration, "sample_rate_hz": args.rate,
                 "internal_dt_s": args.internal_dt, "turbulent_fraction": args.turbulent_fraction,
                 "noise_scale": args.noise_scale, "missions": args.missions}
    values = asdict(recipe)
    values.update({k: v for k, v in overrides.items() if v is not None})
    recipe = Recipe(**values)
    _check_recipe(recipe)
    tolerance = DEFAULT_TOLERANCE if args.tolerance is None else args.tolerance
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
        message = comparison.describe(tolerance)
        if not comparison.matches(tolerance):
            raise CliError(f"dataset {args.out} differs from the reference: {message}")
        print(f"dataset matches the reference: {message}")
    return 0


def _check_recipe(recipe: Recipe) -> None:
    """The relations of the options (or the recipe's values they override): the log rows of
    a sortie, the emulator step against the log interval, the missions against the kind."""
    check_sortie_rows(recipe.duration_s, recipe.sample_rate_hz, "--rate")
    substeps = round(1.0 / (recipe.sample_rate_hz * recipe.internal_dt_s))
    if substeps < 1 or abs(substeps * recipe.internal_dt_s * recipe.sample_rate_hz - 1) > 1e-9:
        raise CliError(f"--internal-dt {recipe.internal_dt_s:g} s must divide the log interval "
                       f"of --rate {recipe.sample_rate_hz:g} Hz ({1 / recipe.sample_rate_hz:g} "
                       "s) a whole number of times")
    kind = load_airframe(recipe.airframe).kind
    wrong = [m for m in recipe.missions if m not in missions_for(kind)]
    if wrong:
        raise CliError(f"--missions {', '.join(wrong)} do not apply to the {kind} --airframe "
                       f"{recipe.airframe}; choose from {', '.join(missions_for(kind))}")


def cmd_import_log(args: argparse.Namespace) -> int:
    """Import a PX4 ULog file or an ALFA folder into a one-sortie interchange dataset."""
    source = Path(args.log)
    fmt = args.format
    if fmt == "auto":
        fmt = "alfa" if source.is_dir() else "ulog"
    if (fmt == "alfa") != source.is_dir():
        raise CliError(f"--format {fmt} reads {'a folder' if fmt == 'alfa' else 'a file'}, but "
                       f"the log {source} is {'a folder' if source.is_dir() else 'a file'}")
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
    p.add_argument("--recipe", default=None, type=existing_file("recipe file"),
                   help="JSON recipe (e.g. data/datagen_quadrotor.json); options given here "
                        "override it")
    p.add_argument("--airframe", default=None, type=airframe_name,
                   help=f"preset ({', '.join(list_presets())}, quadrotor, fixed_wing) or "
                        "parameter file (default quadrotor)")
    p.add_argument("--sorties", type=count(MANIFEST_MAX_SORTIES, "sorties"), default=None,
                   help=f"number of sorties, 1..{MANIFEST_MAX_SORTIES} (default 100)")
    p.add_argument("--seed", type=SEED, default=None, help="random seed >= 0 (default 0)")
    p.add_argument("--duration", type=seconds(name="duration"), default=None,
                   help=f"seconds per sortie (60; at most {MAX_SORTIE_ROWS} log rows at "
                        "--rate)")
    p.add_argument("--rate", type=positive(MAX_RATE_HZ, "rate", "Hz"), default=None,
                   help=f"log rate in Hz, up to {MAX_RATE_HZ:g} (default 100)")
    p.add_argument("--internal-dt", type=STEP, default=None,
                   help="emulator RK4 step in s, dividing the log interval (default 0.001)")
    p.add_argument("--missions", default=None, type=name_list("mission", MISSIONS),
                   help="comma-separated mission names (default: all for the airframe kind)")
    p.add_argument("--turbulent-fraction", type=FRACTION, default=None,
                   help="fraction of turbulent sorties, 0..1 (default 0.5)")
    p.add_argument("--noise-scale", type=number(0.0, 100.0, name="scale"), default=None,
                   help="sensor-noise multiplier, 0..100 (default 1, 0 = noise-free logs)")
    p.add_argument("--workers", type=WORKERS, default=None,
                   help="worker processes, 1..64 (default: all cores)")
    p.add_argument("--out", required=True, type=folder_to_write, help="output folder")
    p.add_argument("--verify", default=None, metavar="FINGERPRINT",
                   type=existing_file("fingerprint file", also=("shipped",)),
                   help="compare the values with a reference fingerprint JSON (by tolerance, "
                        "not bytes); 'shipped': the reference shipped for --recipe")
    p.add_argument("--tolerance", type=number(0.0, name="tolerance"), default=None,
                   help="largest allowed absolute difference for --verify, >= 0 (default "
                        f"{DEFAULT_TOLERANCE:g})")
    p.add_argument("--write-fingerprint", default=None, metavar="FINGERPRINT",
                   type=file_to_write, help="write the dataset's value fingerprint (JSON)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_generate_data)


def add_import_log(sub) -> None:
    """Register ``import-log``."""
    p = sub.add_parser("import-log", help="import a PX4 ULog file or an ALFA folder as a "
                       "one-sortie interchange dataset")
    add_force(p)
    p.add_argument("log", type=existing_path, help="the .ulg file or ALFA sequence folder")
    p.add_argument("--format", choices=["auto", "ulog", "alfa"], default="auto",
                   help="auto: a folder is ALFA, a file is ULog")
    p.add_argument("--rate", type=positive(MAX_RATE_HZ, "rate", "Hz"), default=None,
                   help=f"grid rate in Hz, up to {MAX_RATE_HZ:g} (default: the attitude "
                        "topic's rate for ULog, 10 Hz for ALFA)")
    p.add_argument("--out", required=True, type=folder_to_write, help="output dataset folder")
    p.set_defaults(func=cmd_import_log)
