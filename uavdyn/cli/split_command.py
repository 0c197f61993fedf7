"""The ``split`` command: assign a dataset's sorties to train, validation and test.

Also the split options another command reuses (``import-log`` splits the segments it writes):
:func:`add_split_options` and :func:`split_options_from`.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from uavdyn.cli.common import SEED
from uavdyn.flightdata.manifest import read_manifest
from uavdyn.flightdata.sortie import SPLIT_NAMES
from uavdyn.flightdata.split import (
    DEFAULT_FRACTIONS,
    FRACTION_TOLERANCE,
    SPLIT_RULES,
    split_dataset,
)

_DEFAULT_TEXT = ",".join(f"{f:g}" for f in DEFAULT_FRACTIONS)


def fractions_text(text: str) -> tuple[float, float, float]:
    """``TRAIN,VALIDATION,TEST``: three finite numbers >= 0 summing to 1 (an argparse type)."""
    parts = [p.strip() for p in text.split(",")]
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"must be three comma-separated numbers TRAIN,"
                                         f"VALIDATION,TEST (e.g. {_DEFAULT_TEXT}), got "
                                         f"{text!r}")
    if any(v < 0 for v in values):
        raise argparse.ArgumentTypeError(f"each fraction must be >= 0, got {text!r}")
    if abs(sum(values) - 1.0) > FRACTION_TOLERANCE:
        raise argparse.ArgumentTypeError(f"the fractions must sum to 1, got {text!r} (sum "
                                         f"{sum(values):.6g})")
    return values  # type: ignore[return-value]


fractions_text.__name__ = "fractions"


def dataset_folder(text: str) -> str:
    """An existing dataset folder: one holding a ``manifest.json`` file (an argparse type)."""
    path = Path(text)
    if not path.exists():
        raise argparse.ArgumentTypeError(f"no dataset folder {text}")
    if not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is not a folder (give the dataset folder, "
                                         "the one holding manifest.json)")
    if not (path / "manifest.json").is_file():
        raise argparse.ArgumentTypeError(f"{text} has no manifest.json: not a dataset folder "
                                         "(make one with uavdyn generate-data or uavdyn "
                                         "import-log)")
    return text


def _add_options(parser: argparse.ArgumentParser, by_flag: str) -> None:
    """The rule (``by_flag``), ``--fractions`` and ``--seed``; None stands for the default."""
    parser.add_argument(by_flag, dest="split_by", choices=SPLIT_RULES, default=None,
                        help="sortie: whole sorties at random (seeded); time-block: "
                             "consecutive blocks in flight order, the later flight held out; "
                             "log: whole logs of a campaign in import order, the later "
                             "logs held out; mission: whole sorties at random, every part "
                             "given each mission (and calm/turbulent condition) in "
                             "proportion (default sortie)")
    parser.add_argument("--fractions", type=fractions_text, default=None,
                        metavar="TRAIN,VALIDATION,TEST",
                        help="shares of train, validation and test (sortie counts, or "
                             "duration for time-block and log), each >= 0, summing to 1; 0 "
                             f"leaves that part empty (default {_DEFAULT_TEXT} from 3 "
                             "sorties or logs; 2 give train and test, 1 gives train)")
    parser.add_argument("--seed", type=SEED, default=None,
                        help="seed of the random sortie order (default 0)")


def add_split_options(parser: argparse.ArgumentParser) -> None:
    """Add ``--split-by``, ``--fractions`` and ``--seed`` to another command's parser.

    The values land in ``split_by``, ``fractions`` and ``seed`` (None when not given, so the
    command can tell); :func:`split_options_from` turns them into :func:`assign_split`'s
    keyword arguments.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The command's parser.
    """
    _add_options(parser, "--split-by")


def split_options_from(args: argparse.Namespace) -> dict:
    """The keyword arguments of :func:`uavdyn.flightdata.split.assign_split` (``by``,
    ``fractions``, ``seed``) from the parsed split options, defaults filled in (``fractions``
    None when not given: the default for the number of sorties,
    :func:`uavdyn.flightdata.split.default_fractions`).

    Parameters
    ----------
    args : argparse.Namespace
        Parsed by a parser given :func:`add_split_options` (or the ``split`` command's).

    Returns
    -------
    dict
    """
    return {"by": args.split_by or "sortie",
            "fractions": args.fractions,
            "seed": 0 if args.seed is None else args.seed}


def cmd_split(args: argparse.Namespace) -> int:
    """Split the dataset, then print each part's sorties and duration and the file written."""
    options = split_options_from(args)
    split_dataset(args.dataset, **options)
    path = Path(args.dataset) / "manifest.json"
    totals = {name: [0, 0.0] for name in SPLIT_NAMES}
    manifest = read_manifest(path)
    for entry in manifest["sorties"]:
        totals[entry["split"]][0] += 1
        totals[entry["split"]][1] += float(entry["duration_s"])
    for name, (n, seconds) in totals.items():
        print(f"{name}: {n} sortie{'' if n == 1 else 's'}, {seconds:.1f} s")
    seeded = options["by"] in ("sortie", "mission")
    rule = options["by"] + (f", seed {options['seed']}" if seeded else "")
    note = manifest.get("split_rule", {}).get("note")
    print(f"wrote {path} (split by {rule}{'; ' + note if note else ''})")
    return 0


def add_split(sub) -> None:
    """Register ``split``."""
    p = sub.add_parser("split", help="assign a dataset's sorties to train, validation and test "
                       "(whole sorties; recorded in its manifest.json)")
    p.add_argument("dataset", type=dataset_folder, metavar="DATASET",
                   help="the dataset folder (holding manifest.json)")
    _add_options(p, "--by")
    p.set_defaults(func=cmd_split)
