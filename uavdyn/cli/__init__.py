"""The ``uavdyn`` command line: argparse wiring only, one thin function per command.

This module is the console script's entry point and imports nothing heavy itself: Ctrl-C while
the commands' modules load ends the program with one line, like Ctrl-C at any later moment.
"""

from __future__ import annotations

import argparse
import sys

__all__ = ["build_parser", "main"]


def main(argv: list[str] | None = None) -> int:
    """Run ``uavdyn`` with ``argv`` (:func:`uavdyn.cli.app.main`): the exit code."""
    try:
        from uavdyn.cli.app import main as run
    except KeyboardInterrupt:
        print("uavdyn: interrupted", file=sys.stderr)
        return 130
    return run(argv)


def build_parser() -> argparse.ArgumentParser:
    """The ``uavdyn`` parser with every subcommand registered."""
    from uavdyn.cli.app import build_parser as build
    return build()
