"""The data commands: ``generate-data`` (the emulator) and ``import-log`` (real logs)."""

from __future__ import annotations

import argparse
import math
from dataclasses import asdict
from pathlib import Path

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
from uavdyn.cli.split_command import add_split_options, split_options_from
from uavdyn.emulation.datagen import Recipe, generate_dataset
from uavdyn.emulation.emulator import TRUTH_DEFAULTS
from uavdyn.emulation.fingerprint import (
    DEFAULT_TOLERANCE,
    compare_fingerprints,
    dataset_fingerprint,
    read_fingerprint,
    shipped_reference,
    write_fingerprint,
)
from uavdyn.emulation.missions import missions_for
from uavdyn.flightdata import read_alfa_flight, read_dataflash, read_sixdof_csv
from uavdyn.flightdata.campaign import find_logs, on_one_rate
from uavdyn.flightdata.control_map import parse_channel_map
from uavdyn.flightdata.errors import FlightDataError
from uavdyn.flightdata.flightlog import FlightLog
from uavdyn.flightdata.log_dataset import SUMMARY_FILE as LOG_SUMMARY
from uavdyn.flightdata.log_dataset import plan_log_dataset, write_log_dataset
from uavdyn.flightdata.manifest import MANIFEST_MAX_SORTIES
from uavdyn.flightdata.segments import SegmentRules
from uavdyn.flightdata.ulog_flight import read_ulog_flight
from uavdyn.outputs import (
    check_output_files,
    check_output_folder,
    output_folder,
    single_outputs,
)

MAX_RATE_HZ = 1000.0         # a log grid rate: no logged topic is faster
LONGITUDINAL_CONTROLS = ("elevator", "throttle", "collective", "pitch_cmd")
MISSIONS = tuple(dict.fromkeys(missions_for("fixed_wing") + missions_for("multirotor")))


def control_map(text: str):
    """``--control-map`` value, refused at parse time with the reason."""
    try:
        m = parse_channel_map(text)
    except FlightDataError as exc:
        raise argparse.ArgumentTypeError(exc.reason) from None
    if m.control not in LONGITUDINAL_CONTROLS:
        raise argparse.ArgumentTypeError(f"{m.control!r} is not a control of the longitudinal "
                                         f"model ({', '.join(LONGITUDINAL_CONTROLS)})")
    return m


def truth_range(key: str) -> tuple[float | None, float | None, bool, str]:
    """The physical range of the truth parameter ``key``: ``(low, high, low_open, what)``
    (None: unbounded); the coefficients ``C_*`` take either sign."""
    if key.startswith("tau_"):
        return 0.0, None, False, "a time constant >= 0 s"
    if key.startswith("rate_"):
        return 0.0, None, True, "a rate limit > 0"
    if key == "eta_slipstream":
        return 0.0, 1.0, False, "a share 0..1"
    if key == "v_induced":
        return 0.0, None, True, "a speed > 0 m/s"
    if key.startswith("k_"):
        return 0.0, None, False, "a gain >= 0"
    return None, None, False, "a finite number"


def truth_values(text: str) -> dict[str, float]:
    """``--truth`` value: ``KEY=VALUE[,KEY=VALUE...]``, each key a truth-model parameter of
    some airframe kind (:data:`~uavdyn.emulation.truth.TRUTH_DEFAULTS`), each once, each value a
    finite number in the key's physical range (:func:`truth_range`; the kind is checked once
    the airframe is known)."""
    known = tuple(dict.fromkeys(k for table in TRUTH_DEFAULTS.values() for k in table))
    out: dict[str, float] = {}
    for item in text.split(","):
        key, sep, value = (part.strip() for part in item.partition("="))
        if not sep or not key:
            raise argparse.ArgumentTypeError(f"must be KEY=VALUE[,KEY=VALUE...], got {text!r}")
        if key not in known:
            raise argparse.ArgumentTypeError(f"unknown truth parameter {key!r}; known: "
                                             f"{', '.join(known)}")
        if key in out:
            raise argparse.ArgumentTypeError(f"names truth parameter {key!r} twice")
        try:
            parsed = float(value)
        except ValueError:
            parsed = math.nan
        if not math.isfinite(parsed):
            raise argparse.ArgumentTypeError(f"truth parameter {key!r} must be a finite "
                                             f"number, got {value!r}")
        low, high, low_open, what = truth_range(key)
        if (low is not None and (parsed < low or low_open and parsed == low)) or (
                high is not None and parsed > high):
            raise argparse.ArgumentTypeError(f"truth parameter {key!r} must be {what}, got "
                                             f"{value!r}")
        out[key] = parsed
    return out


def cmd_generate_data(args: argparse.Namespace) -> int:
    """Generate an emulated flight-data set (manifest.json + CSVs) from a recipe and options."""
    refuse_unused(args, ("--tolerance",), args.verify is not None, "with --verify")
    if args.verify == "shipped" and not args.recipe:
        raise CliError("--verify shipped compares with the reference shipped for --recipe: "
                       "give --recipe, or --verify FILE")
    if args.write_fingerprint:
        check_output_files(args.write_fingerprint, force=args.force)  # before any work
    recipe = Recipe.from_json(args.recipe) if args.recipe else Recipe()
    overrides = {"airframe": args.airframe, "sorties": args.sorties, "seed": args.seed,
                 "duration_s": args.duration, "sample_rate_hz": args.rate,
                 "internal_dt_s": args.internal_dt, "turbulent_fraction": args.turbulent_fraction,
                 "noise_scale": args.noise_scale, "missions": args.missions}
    values = asdict(recipe)
    values.update({k: v for k, v in overrides.items() if v is not None})
    if args.truth:
        kind = load_airframe(values["airframe"]).kind
        wrong = [k for k in args.truth if k not in TRUTH_DEFAULTS[kind]]
        if wrong:
            raise CliError(f"--truth: {', '.join(wrong)} is not a truth parameter of {kind} "
                           f"(known: {', '.join(TRUTH_DEFAULTS[kind])})")
        values["truth"] = {**values["truth"], **args.truth}
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
        with single_outputs(args.write_fingerprint, command="generate-data",
                            force=args.force):
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
    """Import one log or a campaign of several (files and folders, one format), cut them into
    longitudinal segments and write them as one dataset on one grid rate with a split, a
    summary and a timeline figure per log."""
    refuse_unused(args, ("--max-bank",), args.turns, "with --turns")
    refuse_unused(args, ("--max-roll", "--max-yaw-rate"), not args.turns,
                  "without --turns (with --turns the log is cut by --max-bank)")
    sources = find_logs(args.log, args.format)
    check_output_folder(args.out, "import-log", args.force)
    flights, rate = on_one_rate([_read_flight(s.path, s.format, args) for s in sources],
                                args.rate)
    given = {k: v for k, v in (("max_roll_deg", args.max_roll),
                               ("max_yaw_rate_deg_s", args.max_yaw_rate),
                               ("max_bank_deg", args.max_bank)) if v is not None}
    rules = SegmentRules(max_sideslip_deg=args.max_sideslip, min_duration_s=args.min_duration,
                         min_speed_m_s=args.min_speed, kinematic=not args.no_kinematic_check,
                         turns=args.turns, **given)
    said = rate.reason if len(flights) > 1 or args.rate else ""  # one log: its own line
    planned = plan_log_dataset(flights, rules, split_options_from(args), said)  # refusals first
    with output_folder(args.out, "import-log", args.force) as tmp:
        written = write_log_dataset(planned, tmp)
    for line in written.lines:
        print(line)
    logs = f" from {len(flights)} logs" if len(flights) > 1 else ""
    print(f"wrote {args.out}/ ({len(written.splits)} segment sorties{logs} at "
          f"{rate.rate_hz:.6g} Hz, {LOG_SUMMARY} and {', '.join(written.timeline_files())})")
    return 0


def _read_flight(source: Path, fmt: str, args: argparse.Namespace) -> FlightLog:
    """The log as a six-degree-of-freedom flight at its own rate (the campaign's rate is
    applied after: :func:`~uavdyn.flightdata.campaign.on_one_rate`)."""
    maps = args.control_map or None
    try:
        flight = _read_format(source, fmt, args.kind, maps)
    except FlightDataError as exc:
        if exc.reason.startswith("control map"):  # the option's value, not the log, is wrong
            raise CliError(f"--control-map: {exc.reason}") from None
        raise
    return flight


def _read_format(source: Path, fmt: str, kind: str | None, maps: list | None) -> FlightLog:
    """The log read by its format's reader."""
    if fmt == "alfa":
        if kind not in (None, "fixed_wing"):
            raise CliError("--kind multirotor: an ALFA folder is a fixed-wing flight")
        return read_alfa_flight(source, control_maps=maps)
    if fmt == "ulog":
        return read_ulog_flight(source, kind=kind, control_maps=maps)
    if fmt == "ardupilot":
        return read_dataflash(source, kind=kind, control_maps=maps)
    if kind is None:
        raise CliError("--format csv needs --kind fixed_wing or multirotor (the columns of the "
                       "controls differ)")
    return read_sixdof_csv(source, kind=kind, control_maps=maps)


def add_generate_data(sub) -> None:
    """Register ``generate-data``."""
    p = sub.add_parser("generate-data", help="generate an emulated flight-data set (SPEC 3 "
                       "format: manifest.json + one CSV per sortie)")
    add_force(p)
    p.add_argument("--recipe", default=None, type=existing_file("recipe file"),
                   help="JSON recipe (e.g. uavdyn/emulation/recipes/datagen_quadrotor.json in "
                        "the source tree); options given here "
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
    p.add_argument("--truth", type=truth_values, default=None, metavar="KEY=VALUE[,...]",
                   help="truth-model overrides added to the recipe's, e.g. "
                        "eta_slipstream=0.8,C_D_Re=0.05,C_m_Re=-0.05 (power and Reynolds "
                        "effects the baseline lacks; keys: uavdyn.emulation.truth.TRUTH_DEFAULTS)")
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
    p = sub.add_parser("import-log", help="cut real flight logs (PX4 ULog, ALFA folder, "
                       "ArduPilot .bin, six-degree-of-freedom CSV; one log or a campaign of "
                       "several) into wings-level longitudinal segments and write them as "
                       "one dataset with a split")
    add_force(p)
    p.add_argument("log", type=existing_path, nargs="+",
                   help="the .ulg/.bin/.csv files or ALFA folders, or folders holding them "
                        "(one format; a folder's logs in name order; the order given is the "
                        "flight order --split-by log uses)")
    p.add_argument("--format", choices=["auto", "ulog", "alfa", "ardupilot", "csv"],
                   default="auto", help="auto: a folder with ALFA topics is ALFA, a file by "
                   "its suffix (.ulg, .bin, .csv)")
    p.add_argument("--kind", choices=["fixed_wing", "multirotor"], default=None,
                   help="the airframe kind (default: from the log; required for csv)")
    p.add_argument("--rate", type=positive(MAX_RATE_HZ, "rate", "Hz"), default=None,
                   help=f"resample every log to this rate in Hz, up to {MAX_RATE_HZ:g}, "
                        "low-pass filtered first when lower (default: the logs' own rate; "
                        "logs at different rates go to the lowest of them)")
    p.add_argument("--max-roll", type=positive(90.0, "angle", "deg"), default=None,
                   help="wings level: |roll| at most this, deg (default 10)")
    p.add_argument("--max-yaw-rate", type=positive(360.0, "rate", "deg/s"), default=None,
                   help="|yaw rate| at most this, deg/s (default 10)")
    p.add_argument("--max-sideslip", type=positive(90.0, "angle", "deg"), default=10.0,
                   help="|sideslip| at most this, deg; checked only with air-relative "
                        "velocities (default 10)")
    p.add_argument("--min-duration", type=positive(3600.0, "duration", "s"), default=5.0,
                   help="shortest segment kept, s (default 5)")
    p.add_argument("--min-speed", type=number(0.0, 200.0, name="speed"), default=None,
                   help="not flying below this body speed, m/s (default 5 for a fixed wing, "
                        "none for a multirotor; the log's in-air flag also applies)")
    p.add_argument("--turns", action="store_true",
                   help="keep turning and climbing flight: the bank, roll and yaw rates and "
                        "sideslip become recorded inputs (columns phi, p, r, beta) of the "
                        "model, and the log is cut only where unusable or beyond --max-bank "
                        "(--max-roll and --max-yaw-rate then do not apply; the airframe file "
                        "needs Jx, Jz, Jxz)")
    p.add_argument("--max-bank", type=positive(89.0, "angle", "deg"), default=None,
                   help="with --turns: |roll| at most this, deg (default 60)")
    p.add_argument("--no-kinematic-check", action="store_true",
                   help="keep segments whose pitch and pitch rate disagree (not advised)")
    p.add_argument("--control-map", action="append", type=control_map, default=None,
                   metavar="CONTROL=SOURCE:RAW_LOW:RAW_HIGH:VALUE_LOW:VALUE_HIGH",
                   help="map a logged field linearly to a control, e.g. "
                        "elevator=RCOU.C2:1100:1900:0.35:-0.35 (repeatable; see "
                        "docs/flightlog_formats.md)")
    add_split_options(p)
    p.add_argument("--out", required=True, type=folder_to_write, help="output dataset folder")
    p.set_defaults(func=cmd_import_log)
