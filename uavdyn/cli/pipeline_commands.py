"""The pipeline commands: ``reproduce`` (the validation report) and ``evaluate`` (any dataset)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from uavdyn.airframes import load_airframe
from uavdyn.cli.common import (
    MAX_SORTIE_ROWS,
    CliError,
    add_airframe,
    add_force,
    airframe_name,
    check_dataset_fits,
    check_sortie_rows,
    count,
    dataset_path,
    existing_file,
    file_to_write,
    folder_to_write,
    refuse_unused,
    seconds,
)
from uavdyn.emulation.datagen import shipped_recipe
from uavdyn.experiments.report import headline_lines, headline_table
from uavdyn.experiments.reproduce import (
    ReproduceConfig,
    _json,
    cache_lines,
    evaluate_dataset,
    evaluation_markdown,
    run,
)
from uavdyn.flightdata.manifest import MANIFEST_MAX_SORTIES
from uavdyn.outputs import atomic_files, check_output_file, check_output_files, single_outputs

MAX_COST_REPEATS = 1000
MAX_DATASET_ROWS = 5_000_000  # the pipeline holds its whole dataset and the predictions on it
RECIPES = ("datagen_quadrotor", "datagen_fixed_wing")


def cmd_reproduce(args: argparse.Namespace) -> int:
    """The validation pipeline: dataset, weights, Tables 1-4, figures, report."""

    refuse_unused(args, ("--no-identify",), args.retrain, "with --retrain")
    for recipe in (shipped_recipe(name) for name in RECIPES):
        sorties = args.sorties or recipe.sorties
        duration = args.duration or recipe.duration_s
        check_sortie_rows(duration, recipe.sample_rate_hz, "the recipe's rate")
        rows = sorties * (duration * recipe.sample_rate_hz + 1)
        if rows > MAX_DATASET_ROWS:
            raise CliError(f"--sorties {sorties} x --duration {duration:g} s at the recipe's "
                           f"{recipe.sample_rate_hz:g} Hz is {rows:.4g} log rows, more than "
                           f"{MAX_DATASET_ROWS} (memory: the pipeline holds the whole dataset)")
    config = ReproduceConfig(airframes=tuple(args.airframes), out=args.out, quick=args.quick,
                             retrain=args.retrain, cache=args.cache,
                             cost_repeats=args.cost_repeats, sorties=args.sorties,
                             duration_s=args.duration, force=args.force,
                             identify=not args.no_identify,
                             save_trajectories=args.save_trajectories)
    result = run(config)
    print(reproduce_summary(result, args.out, args.cache))
    return 0


def reproduce_summary(result: dict, out: str | Path, cache: str | Path | None) -> str:
    """What ``uavdyn reproduce`` prints at the end: the headline table (from ``result``), the
    report it wrote, and where its caches are and how big."""
    return "\n".join(["", *headline_table(result), "",
                      f"report: {Path(out) / 'report.md'} ({result['wall_s']:.0f} s, "
                      f"{result['size_bytes'] / 1e6:.1f} MB written; free runs, spread, "
                      "figures and Tables 1-4 there)", *cache_lines(cache)])


def cmd_evaluate(args: argparse.Namespace) -> int:
    """Table 1 and Table 4 for any dataset folder, as JSON and Markdown."""

    out = Path(args.out)
    md, png = out.with_suffix(".md"), out.with_suffix(".png")
    for path in (out, md, png):
        check_output_file(path)  # before the work, not after it
    check_output_files(out, md, png, force=args.force)
    airframe = load_airframe(args.airframe)
    check_dataset_fits(airframe, args.dataset)
    identified = load_airframe(args.identified) if args.identified else None
    result = evaluate_dataset(airframe, args.dataset, args.weights or [],
                              identified=identified, all_sorties=args.all_sorties)
    result["command"] = "evaluate"
    written = (out, md, *([png] if result.get("ladder") else []))
    with single_outputs(*written, command="evaluate", force=args.force), \
            atomic_files(*written) as tmps:
        tmps[0].write_text(json.dumps(result, indent=2, default=_json) + "\n")
        tmps[1].write_text(evaluation_markdown(result, png.name, out.name))
        if result.get("ladder"):
            from uavdyn.experiments.figures import per_sortie_figure

            per_sortie_figure(result, tmps[2])
    for line in headline_lines(result) if result.get("ladder") else []:
        print(line.replace("**", ""))
    print(f"wrote {out}, {md}" + (f" and {png}" if result.get("ladder") else ""))
    return 0


def add_reproduce(sub) -> None:
    """Register ``reproduce``."""
    p = sub.add_parser("reproduce", help="run the validation pipeline (Tables 1-4, figures, "
                       "report) on the shipped recipe and weights")
    add_force(p)
    p.add_argument("--airframes", nargs="+", default=["quadrotor", "fixed_wing"],
                   choices=["quadrotor", "fixed_wing"], help="which airframes (default both)")
    p.add_argument("--out", default="results", type=folder_to_write,
                   help="output folder (default results/)")
    p.add_argument("--quick", action="store_true", help="tiny configuration (seconds)")
    p.add_argument("--no-identify", action="store_true",
                   help="with --retrain: skip the identification (then no identified physics "
                        "and no correction rung)")
    p.add_argument("--retrain", action="store_true",
                   help="identify the physics and train the networks here (needs torch) "
                        "instead of using the shipped identified airframe and weights")
    p.add_argument("--cache", default=None, type=folder_to_write,
                   help="dataset cache folder (default: user cache)")
    p.add_argument("--cost-repeats", type=count(MAX_COST_REPEATS, "repeats"), default=15,
                   help=f"interleaved timing repeats, 1..{MAX_COST_REPEATS} (default 15)")
    p.add_argument("--save-trajectories", action="store_true",
                   help="also write every Table 1 prediction as compressed npz (large)")
    p.add_argument("--sorties", type=count(MANIFEST_MAX_SORTIES, "sorties"), default=None,
                   help=f"override the recipe's count (1..{MANIFEST_MAX_SORTIES})")
    p.add_argument("--duration", type=seconds(name="duration"), default=None,
                   help="override the recipe's sortie duration (s; at most "
                        f"{MAX_SORTIE_ROWS} log rows per sortie, {MAX_DATASET_ROWS} in all)")
    p.set_defaults(func=cmd_reproduce)


def add_evaluate(sub) -> None:
    """Register ``evaluate``."""
    p = sub.add_parser("evaluate", help="Table 1 and Table 4 metrics on any dataset folder")
    add_force(p)
    add_airframe(p, default=None)
    p.add_argument("--dataset", required=True, type=dataset_path,
                   help="dataset folder (manifest.json + CSVs)")
    p.add_argument("--identified", default=None, type=airframe_name,
                   help="airframe file fitted by 'uavdyn identify': adds the identified-physics "
                        "rung (weights trained on it are run on it)")
    p.add_argument("--weights", nargs="*", default=None, type=existing_file("weight file"),
                   help="weight file(s) of the hybrid")
    p.add_argument("--all-sorties", action="store_true",
                   help="score every sortie of a dataset without a test split (the result "
                        "says so; they may include sorties a model was fitted on)")
    p.add_argument("--out", default="results/metrics.json", type=file_to_write,
                   help="JSON output (Markdown beside)")
    p.set_defaults(func=cmd_evaluate)
