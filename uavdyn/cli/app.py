"""The ``uavdyn`` command line: one subcommand per step of the pipeline.

Errors are reported as one readable line on stderr with a non-zero exit code (a bad option
value when the command line is parsed, naming the option and its allowed range); ``--help``
works on every command. Every ``--airframe`` takes a preset name or the path of a parameter file.
"""

from __future__ import annotations

import argparse
import sys
import warnings

from uavdyn import __version__
from uavdyn.airframes import AirframeError
from uavdyn.cli import data_commands, fit_commands, model_commands, pipeline_commands
from uavdyn.cli.common import CliError, OneLineParser
from uavdyn.cli.design_command import add_design_input
from uavdyn.cli.montecarlo import add_parser as add_montecarlo_parser
from uavdyn.cli.mpc import add_parser as add_mpc_parser
from uavdyn.cli.split_command import add_split
from uavdyn.integrate import CompileError, DivergenceError
from uavdyn.interrupts import ctrl_c_remembered, stands_for_interrupt
from uavdyn.linear import TrimError

# the subcommands in the order ``uavdyn --help`` lists them
REGISTER = (model_commands.add_airframes, model_commands.add_trim, model_commands.add_modes,
            model_commands.add_simulate, data_commands.add_generate_data,
            model_commands.add_export_c, data_commands.add_import_log, add_split,
            fit_commands.add_identify, add_design_input, pipeline_commands.add_reproduce,
            pipeline_commands.add_evaluate, fit_commands.add_train, add_montecarlo_parser,
            add_mpc_parser)


def build_parser() -> argparse.ArgumentParser:
    """The ``uavdyn`` parser with every subcommand registered."""
    parser = OneLineParser(
        prog="uavdyn", description="Nonlinear longitudinal UAV flight dynamics with a "
        "learned-residual, compiled RK4 integrator.")
    parser.add_argument("--version", action="version", version=f"uavdyn {__version__}")
    parser.add_argument("--debug", action="store_true",
                        help="show the Python traceback of an unexpected error")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for register in REGISTER:
        register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run ``uavdyn`` with ``argv``: the exit code; errors and warnings as one line each on
    stderr (``--debug``: the traceback and Python's own warning format)."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # a refused option value (one line printed): its exit code
        if exc.code in (0, None):  # --help, --version
            raise
        return exc.code if isinstance(exc.code, int) else 2
    with warnings.catch_warnings():
        if not args.debug:
            warnings.showwarning = _one_line_warning(args.command)
        return _run(args)


def _one_line_warning(command: str):
    """A ``warnings.showwarning`` that prints ``uavdyn <command>: warning: <message>``."""
    def show(message, category, filename, lineno, file=None, line=None) -> None:
        print(f"uavdyn {command}: warning: {_one_line(message)}", file=sys.stderr)
    return show


def _run(args: argparse.Namespace) -> int:
    with ctrl_c_remembered():  # long loops re-raise a Ctrl-C that a library swallowed
        try:
            return int(args.func(args) or 0)
        except KeyboardInterrupt:
            return _interrupted(args.command)
        except Exception as exc:
            if stands_for_interrupt(exc):  # Ctrl-C as CasADi renders or garbles it
                return _interrupted(args.command)
            if args.debug:
                raise
            if isinstance(exc, (CliError, AirframeError, TrimError, FileNotFoundError,
                                ValueError, DivergenceError, CompileError)):
                print(f"uavdyn {args.command}: error: {_one_line(exc)}", file=sys.stderr)
            else:  # an internal error: one line, the traceback on request
                print(f"uavdyn {args.command}: internal error: {type(exc).__name__}: "
                      f"{_one_line(exc)} (run with --debug for the traceback)", file=sys.stderr)
            return 2


def _interrupted(command: str) -> int:
    print(f"uavdyn {command}: interrupted", file=sys.stderr)
    return 130


def _one_line(exc: BaseException | Warning | str) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


if __name__ == "__main__":
    sys.exit(main())
