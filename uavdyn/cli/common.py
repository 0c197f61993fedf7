"""What the ``uavdyn`` commands share: the user-facing error, the one-line argument parser, the
option-value validators every command uses, the airframe, trim and --force options, the
airframe-against-dataset check and the correction a ``--hybrid`` command runs.

Every option value is checked when the command line is parsed: a validator below is the
option's argparse ``type`` and raises :class:`argparse.ArgumentTypeError` with the allowed
range, so the refusal is one line naming the option (``uavdyn <command>: error: argument
--dt: ...``). Relations between options (a step no longer than the run, an option that only
applies with another one) are checked by the command right after parsing, with a
:class:`CliError` naming both options.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
import warnings
from collections.abc import Callable, Iterable
from pathlib import Path

from uavdyn.airframes import ALIASES, AirframeError, list_presets, load_airframe
from uavdyn.learned import WeightFileError, shipped_correction
from uavdyn.linear import trim
from uavdyn.outputs import OutputError, check_output_file


class CliError(Exception):
    """A user-facing error: printed as one line, exit code 2."""


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line, ``uavdyn <command>: error: <message>``
    (argparse's own prints the usage first); exit code 2. Sub-parsers inherit the class."""

    def error(self, message: str):  # noqa: D102 - argparse's hook
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())} (see {self.prog} "
                     "--help)\n")


# ------------------------------------------------------------------------ value validators

SEED_MAX = 2**63 - 1
STEP_MIN, STEP_MAX = 1e-6, 1.0   # an RK4 step of the body dynamics (s)
MAX_WORKERS = 64                 # processes (each one a Python with CasADi: ~0.2 GB)
MAX_THREADS = 256
# log rows of one generated sortie: the emulator's run peaked at 0.4 GB for 50 000 rows and
# 3 GB for 100 000 (measured, aerosonde, 100 Hz log, 1 kHz internal step)
MAX_SORTIE_ROWS = 50_000


def number(low: float | None = None, high: float | None = None, *, integer: bool = False,
           low_open: bool = False, high_open: bool = False, name: str = "value",
           unit: str = "", multiple_of: float | None = None) -> Callable[[str], float | int]:
    """An argparse ``type``: a finite number (``integer``: a whole number) in the range
    ``low .. high`` (``low_open``/``high_open``: excluded), optionally a multiple of
    ``multiple_of``; the refusal states the range."""
    allowed = _range_text(low, high, low_open, high_open, name, unit, integer, multiple_of)

    def parse(text: str) -> float | int:
        try:
            value = int(text) if integer else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {text!r}") from None
        ok = math.isfinite(value) and not (
            low is not None and (value < low or low_open and value == low)) and not (
            high is not None and (value > high or high_open and value == high))
        if ok and multiple_of is not None:
            ok = abs(round(value / multiple_of) * multiple_of - value) <= 1e-9 * multiple_of
        if not ok:
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {text!r}")
        return value

    parse.__name__ = name
    return parse


def _range_text(low, high, low_open, high_open, name, unit, integer, multiple_of) -> str:
    what = "a whole number" if integer else "a finite number"
    unit = f" {unit}" if unit else ""
    low, high = (None if x is None else str(x) if integer else f"{x:g}" for x in (low, high))
    if low is not None and high is not None:
        span = (f"{low} {'<' if low_open else '<='} {name} {'<' if high_open else '<='} "
                f"{high}{unit}")
    elif low is not None:
        span = f"{name} {'>' if low_open else '>='} {low}{unit}"
    elif high is not None:
        span = f"{name} {'<' if high_open else '<='} {high}{unit}"
    else:
        return what + unit
    step = f", a multiple of {multiple_of:g}{unit}" if multiple_of else ""
    return f"{what} with {span}{step}"


def positive(high: float | None = None, name: str = "value", unit: str = ""
             ) -> Callable[[str], float]:
    """A positive, finite number (at most ``high``)."""
    return number(0.0, high, low_open=True, name=name, unit=unit)


def seconds(high: float | None = None, name: str = "seconds") -> Callable[[str], float]:
    """A positive, finite duration in s (at most ``high``)."""
    return positive(high, name, "s")


def count(high: int, name: str = "count") -> Callable[[str], int]:
    """A whole number from 1 to ``high``."""
    return number(1, high, integer=True, name=name)


STEP = number(STEP_MIN, STEP_MAX, name="dt", unit="s")
FRACTION = number(0.0, 1.0, name="fraction")
SEED = number(0, SEED_MAX, integer=True, name="seed")
WORKERS = number(1, MAX_WORKERS, integer=True, name="workers")
THREADS = number(1, MAX_THREADS, integer=True, name="threads")
AIRSPEED = number(0.0, 100.0, name="airspeed", unit="m/s")  # the models' speed range
GAMMA_DEG = number(-90.0, 90.0, low_open=True, high_open=True, name="gamma", unit="deg")


def existing_file(what: str = "file", also: Iterable[str] = ()) -> Callable[[str], str]:
    """An existing regular file (or one of the words ``also``)."""
    words = tuple(also)

    def parse(text: str) -> str:
        if text in words:
            return text
        path = Path(text)
        if path.is_dir():
            raise argparse.ArgumentTypeError(f"{text} is a folder, not a {what}")
        if not path.is_file():
            alt = f" ({' or '.join(repr(w) for w in words)} or a file)" if words else ""
            raise argparse.ArgumentTypeError(f"no {what} {text}{alt}")
        return text

    parse.__name__ = what
    return parse


def existing_path(text: str) -> str:
    """An existing file or folder."""
    if not Path(text).exists():
        raise argparse.ArgumentTypeError(f"no file or folder {text}")
    return text


def dataset_path(text: str) -> str:
    """A dataset: a folder with a ``manifest.json``, the manifest itself or one CSV file."""
    path = Path(text)
    if path.is_dir() and not (path / "manifest.json").is_file():
        raise argparse.ArgumentTypeError(f"{text} is a folder without a manifest.json, not a "
                                         "dataset (make one with uavdyn generate-data or "
                                         "uavdyn import-log)")
    if not path.exists():
        raise argparse.ArgumentTypeError(f"no dataset {text} (a folder with manifest.json, "
                                         "or a CSV file)")
    return text


def airframe_name(text: str) -> str:
    """A preset name (or alias) or a readable airframe file (loaded here to check it; its
    plausibility warnings come when the command loads it)."""
    if text in list_presets() or text in ALIASES:
        return text
    if not Path(text).exists():
        raise argparse.ArgumentTypeError(
            f"{text!r} is neither a preset ({', '.join(list_presets() + sorted(ALIASES))}) "
            "nor a file")
    if Path(text).is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a folder, not an airframe file")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            load_airframe(text)
    except AirframeError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def file_to_write(text: str) -> str:
    """A file to write: not a folder, its parent a folder (or creatable inside the current
    folder)."""
    if not text:
        raise argparse.ArgumentTypeError("must be a file path, got ''")
    try:
        check_output_file(text)
    except OutputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    except OSError as exc:  # a parent that is a file, a name too long
        raise argparse.ArgumentTypeError(f"{text}: {exc.strerror or exc}") from None
    return text


def folder_to_write(text: str) -> str:
    """A folder to write: not an existing file, and no file among its parents."""
    path = Path(text)
    if not text:
        raise argparse.ArgumentTypeError("must be a folder path, got ''")
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} exists and is not a folder")
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise argparse.ArgumentTypeError(f"{text}: its parent {parent} is not a "
                                                 "folder")
            break
    return text


def name_list(what: str, known: Iterable[str] | None = None) -> Callable[[str], list[str]]:
    """A comma-separated list of names (no empty or repeated entry; each in ``known``)."""
    allowed = tuple(known) if known is not None else None

    def parse(text: str) -> list[str]:
        names = [n.strip() for n in text.split(",")]
        if not text.strip() or any(not n for n in names):
            raise argparse.ArgumentTypeError(f"must be comma-separated {what} names, got "
                                             f"{text!r}")
        if len(set(names)) != len(names):
            raise argparse.ArgumentTypeError(f"names a {what} twice: {text!r}")
        unknown = [n for n in names if allowed is not None and n not in allowed]
        if unknown:
            raise argparse.ArgumentTypeError(f"unknown {what} {', '.join(unknown)}; choose from "
                                             f"{', '.join(allowed)}")
        return names

    parse.__name__ = what
    return parse


def bound_list(text: str) -> dict[str, tuple[float, float]]:
    """``NAME=LOW:HIGH[,NAME=LOW:HIGH...]``: finite numbers, LOW < HIGH, each name once."""
    out: dict[str, tuple[float, float]] = {}
    for item in text.split(","):
        name, sep, rng = item.strip().partition("=")
        low, colon, high = rng.partition(":")
        try:
            lo, hi = float(low), float(high)
        except ValueError:
            lo = hi = math.nan
        if not (sep and colon and name.strip()) or not (math.isfinite(lo) and math.isfinite(hi)):
            raise argparse.ArgumentTypeError(f"must be NAME=LOW:HIGH with finite numbers, "
                                             f"comma-separated; got {item.strip()!r}")
        if not lo < hi:
            raise argparse.ArgumentTypeError(f"{name.strip()}: LOW {lo:g} must be below HIGH "
                                             f"{hi:g}")
        if name.strip() in out:
            raise argparse.ArgumentTypeError(f"bounds for {name.strip()} given twice")
        out[name.strip()] = (lo, hi)
    return out


C_KEYWORDS = frozenset(
    "auto break case char const continue default do double else enum extern float for goto "
    "if inline int long register restrict return short signed sizeof static struct switch "
    "typedef union unsigned void volatile while main".split())


def c_identifier(text: str) -> str:
    """A C identifier (letters, digits, ``_``; not starting with a digit; not a keyword)."""
    if not re.fullmatch(r"[A-Za-z_]\w{0,63}", text) or text in C_KEYWORDS:
        raise argparse.ArgumentTypeError(f"must be a C identifier of at most 64 letters, digits "
                                         f"or _ (not a C keyword), got {text!r}")
    return text


# ------------------------------------------------------------------------ relations

def given(args: argparse.Namespace, option: str) -> bool:
    """Whether ``--option`` was given (its default is None or False)."""
    value = getattr(args, option.lstrip("-").replace("-", "_"))
    return value is not None and value is not False


def refuse_unused(args: argparse.Namespace, options: Iterable[str], applies: bool,
                  when: str) -> None:
    """Refuse, naming it and ``when``, an option given where it would be ignored."""
    if applies:
        return
    for option in options:
        if given(args, option):
            raise CliError(f"{option} applies only {when}; it would be ignored here")


def check_dataset_fits(airframe, dataset: str, lowpass_hz: float | None = None) -> None:
    """Refuse, from the dataset's manifest alone (before any sortie is read), an
    ``--airframe`` of another kind than the ``--dataset``'s flights, and a ``--lowpass-hz``
    at or above half its log rate."""
    from uavdyn.flightdata import read_csv, read_manifest

    path = Path(dataset)
    if path.is_dir() or path.name == "manifest.json":
        manifest = read_manifest(path / "manifest.json" if path.is_dir() else path)
        kind, rate = manifest["kind"], float(manifest["sample_rate_hz"])
    else:
        sortie = read_csv(path, check=False)
        kind, rate = sortie.kind, 1.0 / sortie.dt
    if kind != airframe.kind:
        raise CliError(f"--airframe '{airframe.name}' is a {airframe.kind} airframe but "
                       f"--dataset {dataset} holds {kind} flights: give an airframe of the "
                       "dataset's kind")
    if lowpass_hz is not None and lowpass_hz >= rate / 2:
        raise CliError(f"--lowpass-hz {lowpass_hz:g} must be below half the log rate of "
                       f"--dataset {dataset} ({rate:g} Hz: below {rate / 2:g} Hz)")


def check_sortie_rows(duration: float, rate_hz: float, rate: str) -> None:
    """Refuse a generated sortie of more than :data:`MAX_SORTIE_ROWS` log rows (``--duration``
    at the log rate named ``rate``: an option or the recipe's)."""
    rows = duration * rate_hz + 1
    if rows > MAX_SORTIE_ROWS:
        raise CliError(f"--duration {duration:g} s at {rate} {rate_hz:g} Hz is {rows:.4g} log "
                       f"rows per sortie, more than {MAX_SORTIE_ROWS} (memory)")


# ------------------------------------------------------------------------ shared options

def add_airframe(parser: argparse.ArgumentParser, default: str | None = "aerosonde") -> None:
    """``--airframe``: a preset or the user's own file (required when ``default`` is None)."""
    parser.add_argument("--airframe", default=default, required=default is None,
                        type=airframe_name,
                        help=f"preset name ({', '.join(list_presets())}) or path of a "
                             "TOML/JSON parameter file")


def add_trim_args(parser: argparse.ArgumentParser) -> None:
    """``--airspeed`` and ``--gamma-deg`` of a trim point."""
    parser.add_argument("--airspeed", type=AIRSPEED, default=None,
                        help="trim airspeed in m/s, 0..100 (default: the airframe's nominal; "
                             "0 = hover)")
    parser.add_argument("--gamma-deg", type=GAMMA_DEG, default=0.0,
                        help="flight-path angle in degrees, climb positive, -90..90 "
                             "(default 0)")


def trim_from_args(args: argparse.Namespace):
    """The airframe of ``--airframe`` and its trim at ``--airspeed``/``--gamma-deg``."""

    airframe = load_airframe(args.airframe)
    return airframe, trim(airframe, args.airspeed, math.radians(args.gamma_deg))


def add_force(p: argparse.ArgumentParser, single: bool = False) -> None:
    """``--force``: write into a folder that is not this command's earlier output, or (with
    ``single``) over an output file uavdyn did not write
    (:func:`uavdyn.outputs.check_output_files`)."""
    p.add_argument("--force", action="store_true",
                   help="overwrite an existing output file that uavdyn did not write (or that "
                        "was changed since)" if single else
                        "write into a non-empty output that is not an earlier result of this "
                        "command (replaces only this command's files; an existing output file "
                        "uavdyn did not write is overwritten only with --force)")


def correction(args: argparse.Namespace, airframe):
    """The weights of a ``--hybrid``/``--model hybrid`` command and the airframe they run on:
    ``--weights`` on ``--airframe``, or for a preset the shipped safe correction on the
    identified airframe it was trained on."""
    if args.weights:
        return Path(args.weights), airframe  # an existing file: checked when parsed
    if args.airframe not in list_presets() and args.airframe not in ALIASES:
        raise CliError(f"no shipped correction for the airframe file {args.airframe}; give "
                       "--weights FILE (trained on this airframe with uavdyn train)")
    try:
        weights, identified = shipped_correction(airframe.name)
    except WeightFileError as exc:
        raise CliError(str(exc)) from None
    print(f"(shipped correction {weights.name} on {identified.name}, the identified airframe "
          "it was trained on)", file=sys.stderr)
    return weights, identified
