"""What the ``uavdyn`` commands share: the user-facing error, the airframe, trim and
--force options, and the correction a ``--hybrid`` command runs."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from uavdyn.airframes import list_presets, load_airframe
from uavdyn.learned import WeightFileError, shipped_correction
from uavdyn.linear import trim


class CliError(Exception):
    """A user-facing error: printed as one line, exit code 2."""


def add_airframe(parser: argparse.ArgumentParser, default: str | None = "aerosonde") -> None:
    """``--airframe``: a preset or the user's own file (required when ``default`` is None)."""
    parser.add_argument("--airframe", default=default, required=default is None,
                        help=f"preset name ({', '.join(list_presets())}) or path of a "
                             "TOML/JSON parameter file")


def add_trim_args(parser: argparse.ArgumentParser) -> None:
    """``--airspeed`` and ``--gamma-deg`` of a trim point."""
    parser.add_argument("--airspeed", type=float, default=None,
                        help="trim airspeed in m/s (default: the airframe's nominal; 0 = hover)")
    parser.add_argument("--gamma-deg", type=float, default=0.0,
                        help="flight-path angle in degrees, climb positive (default 0)")


def trim_from_args(args: argparse.Namespace):
    """The airframe of ``--airframe`` and its trim at ``--airspeed``/``--gamma-deg``."""

    airframe = load_airframe(args.airframe)
    return airframe, trim(airframe, args.airspeed, math.radians(args.gamma_deg))


def add_force(p: argparse.ArgumentParser) -> None:
    """``--force``: write into a folder that is not this command's earlier output."""
    p.add_argument("--force", action="store_true",
                   help="write into a non-empty output that is not an earlier result of this "
                        "command (replaces only this command's files)")


def correction(args: argparse.Namespace, airframe):
    """The weights of a ``--hybrid``/``--model hybrid`` command and the airframe they run on:
    ``--weights`` on ``--airframe``, or for a preset the shipped safe correction on the
    identified airframe it was trained on."""
    if args.weights:
        weights = Path(args.weights)
        if not weights.is_file():
            raise CliError(f"no weight file {weights}; give --weights FILE")
        return weights, airframe
    if args.airframe not in list_presets():
        raise CliError(f"no shipped correction for the airframe file {args.airframe}; give "
                       "--weights FILE (trained on this airframe with uavdyn train)")
    try:
        weights, identified = shipped_correction(airframe.name)
    except WeightFileError as exc:
        raise CliError(str(exc)) from None
    print(f"(shipped correction {weights.name} on {identified.name}, the identified airframe "
          "it was trained on)", file=sys.stderr)
    return weights, identified
