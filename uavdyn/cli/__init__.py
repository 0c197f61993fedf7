"""The ``uavdyn`` command line: argparse wiring only, one thin function per command."""

from uavdyn.cli.main import build_parser, main

__all__ = ["build_parser", "main"]
