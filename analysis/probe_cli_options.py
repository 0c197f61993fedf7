"""Probe every option of every ``uavdyn`` subcommand with values that are invalid for it.

The parser of :func:`uavdyn.cli.app.build_parser` is walked, so an option added later is
probed too (an option this file does not describe is reported as ``undescribed``, a failure).
Each option is tried with the values that are really invalid for it (numbers: 0, -1, nan, inf,
1e308, a non-number and, for counts, a fractional or an absurdly large integer, each only when
outside the option's valid range, which is stated per option; input paths: a missing file, a
folder where a file is expected; output paths: a folder where a file is written, a file where
a folder is written; choices: an unknown one), plus a list of values that break a relation to
another option or to the data (e.g. a horizon longer than the sorties). Each run is
``uavdyn.cli.main(argv)`` in a forked child (the parent imported uavdyn once) with every other
argument at its smallest valid value, a wall-clock timeout and an address-space limit, and is
classified:

* ``refused``: exit code 2 and one line on stderr naming the option (good);
* ``accepted``: exit code 0 (the invalid value was silently used);
* ``unclear``: refused, but the message does not name the option or is not one line;
* ``traceback``: a Python traceback or an internal error;
* ``hang/OOM``: no answer within the timeout, or out of memory.

Writes ``<out>.json`` (summary and every run) and ``<out>.md`` (a table: option, valid range,
bad values tried, result, message) and prints the summary as JSON. Run from the repository
root (a few minutes on two cores)::

    python analysis/probe_cli_options.py --out docs/benchmarks/cli_option_probe
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import resource
import shutil
import signal
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
COMMAND = "python analysis/probe_cli_options.py --out docs/benchmarks/cli_option_probe"
NUMBERS = ("0", "-1", "nan", "inf", "1e308", "abc")


@dataclass(frozen=True)
class Num:
    """A number option: ``valid`` says whether a value is in range, ``text`` states the range."""

    text: str
    valid: object  # callable float -> bool
    integer: bool = False
    extra: tuple[str, ...] = ()  # more candidates (an absurd count, a value just out of range)

    def bad_values(self) -> list[tuple[str, str]]:
        out = []
        for value in (*NUMBERS, *(("1.5",) if self.integer else ()), *self.extra):
            why = self.why_invalid(value)
            if why:
                out.append((value, why))
        return out

    def why_invalid(self, value: str) -> str | None:
        try:
            x = int(value) if self.integer else float(value)
        except ValueError:
            return "not an integer" if self.integer else "not a number"
        if isinstance(x, float) and math.isnan(x):
            return "not a number (nan)"
        return None if self.valid(x) else "out of range"


@dataclass(frozen=True)
class Values:
    """An option whose bad values are listed with the reason each is invalid."""

    text: str
    bad: tuple[tuple[str, str], ...]

    def bad_values(self) -> list[tuple[str, str]]:
        return list(self.bad)


def finite(x) -> bool:
    return math.isfinite(x)


STEP = Num("1e-06 <= dt <= 1 s (an RK4 step of the body dynamics)",
           lambda x: finite(x) and 1e-6 <= x <= 1)
SEED = Num("0 <= seed < 2**63", lambda x: 0 <= x < 2**63, integer=True, extra=(str(2**64),))
AIRSPEED = Num("0 <= airspeed <= 100 m/s (0 = hover; the models' speed range)",
               lambda x: finite(x) and 0 <= x <= 100)
GAMMA = Num("-90 < gamma < 90 deg", lambda x: finite(x) and -90 < x < 90,
            extra=("90", "-90"))
WORKERS = Num("1 <= workers <= 64 processes", lambda x: 1 <= x <= 64, integer=True,
              extra=("100000",))
THREADS = Num("1 <= threads <= 256", lambda x: 1 <= x <= 256, integer=True,
              extra=("100000",))
MISSING, FOLDER, AFILE = "{F}/missing", "{F}/afolder", "{F}/afile.txt"
IN_FILE = Values("an existing file", ((MISSING, "does not exist"),
                                      (FOLDER, "a folder where a file is expected")))
AIRFRAME = Values("a preset name or an existing airframe file", (
    ("no_such_preset", "neither a preset nor a file"),
    (MISSING + ".toml", "a missing file"),
    (FOLDER, "a folder where a file is expected")))
DATASET = Values("a dataset folder (manifest.json) or a CSV file", (
    (MISSING, "does not exist"), (FOLDER, "a folder without manifest.json")))
OUT_FILE = Values("a file path (not a folder; its parent a folder)", (
    (FOLDER, "a folder where a file is written"),
    (AFILE + "/x", "its parent is a file")))
OUT_FOLDER = Values("a folder path (not an existing file)", (
    (AFILE, "an existing file where a folder is written"),))


def choice(text: str) -> Values:
    return Values(text, (("bogus", "not one of the choices"),))


def positive(text: str, hi: float | None = None, extra=()) -> Num:
    return Num(text, lambda x: finite(x) and x > 0 and (hi is None or x <= hi), extra=extra)


def count(text: str, hi: int, extra=()) -> Num:
    return Num(text, lambda x: 1 <= x <= hi, integer=True, extra=(str(hi + 1), *extra))


FRACTIONS = Values("three numbers >= 0 summing to 1 (train, validation, test)", (
    ("0.5,0.5", "two numbers"), ("0.7,0.2,0.2", "they sum to 1.1"),
    ("-0.1,0.6,0.5", "a negative share"), ("a,b,c", "not numbers"),
    ("1,0,0,0", "four numbers")))


# option -> description, per command ("*" for every command that has the option)
OPTIONS: dict[tuple[str, str], Num | Values] = {
    ("*", "--airframe"): AIRFRAME,
    ("*", "--airspeed"): AIRSPEED,
    ("*", "--gamma-deg"): GAMMA,
    ("*", "--weights"): IN_FILE,
    ("*", "--dt"): STEP,
    ("*", "--seed"): SEED,
    ("*", "--threads"): THREADS,
    ("*", "--workers"): WORKERS,
    ("modes", "--weights"): IN_FILE,
    ("simulate", "--input"): choice("step, doublet, 3211, chirp, none"),
    ("simulate", "--amplitude"): Num("a finite number inside the control's limits",
                                     finite, extra=("-inf",)),
    ("simulate", "--channel"): Values("0 or 1", (("2", "no such channel"),
                                                 ("-1", "no such channel"),
                                                 ("abc", "not an integer"))),
    ("simulate", "--duration"): positive("0 < duration, at most 2000000 rows at --dt"),
    ("simulate", "--out"): OUT_FILE,
    ("generate-data", "--recipe"): IN_FILE,
    ("generate-data", "--airframe"): AIRFRAME,
    ("generate-data", "--sorties"): count("1 <= sorties <= 100000 (the loader's bound)", 100000),
    ("generate-data", "--duration"): positive("0 < duration, at most 50000 log rows "
                                              "per sortie at --rate (memory)"),
    ("generate-data", "--rate"): positive("0 < rate <= 1000 Hz", 1000),
    ("generate-data", "--internal-dt"): STEP,
    ("generate-data", "--missions"): Values("comma-separated missions of the kind", (
        ("no_such_mission", "an unknown mission"), (",", "no mission named"),
        ("inspection", "a multirotor mission for a fixed-wing airframe"))),
    ("generate-data", "--turbulent-fraction"): Num("0 <= fraction <= 1",
                                                   lambda x: 0 <= x <= 1, extra=("1.5",)),
    ("generate-data", "--noise-scale"): Num("0 <= scale <= 100", lambda x: 0 <= x <= 100),
    ("generate-data", "--out"): OUT_FOLDER,
    ("generate-data", "--verify"): Values("'shipped' (with --recipe) or an existing file", (
        (MISSING, "does not exist"), (FOLDER, "a folder where a file is expected"))),
    ("generate-data", "--tolerance"): Num("0 <= tolerance < inf (with --verify)",
                                          lambda x: finite(x) and x >= 0),
    ("generate-data", "--write-fingerprint"): OUT_FILE,
    ("export-c", "--model"): choice("hybrid, rk4"),
    ("export-c", "--real"): choice("double, float"),
    ("export-c", "--rollout"): Num("0 <= steps <= 50000 (code generation memory)",
                                   lambda x: 0 <= x <= 50000, integer=True,
                                   extra=("50001", "1000000")),
    ("export-c", "--name"): Values("a C identifier (letters, digits, _; not a keyword)", (
        ("1abc", "starts with a digit"), ("a-b", "not a C identifier"),
        ("int", "a C keyword"), ("", "empty"))),
    ("export-c", "--out"): OUT_FOLDER,
    ("export-c", "--horizon"): count("1 <= intervals <= 200 (with --mpc)", 200),
    ("export-c", "--condensing"): choice("mx, sx (with --mpc)"),
    ("import-log", "log"): Values("an existing .ulg/.bin/.csv file or ALFA folder", (
        (MISSING, "does not exist"),)),
    ("import-log", "--format"): choice("auto, ulog, alfa, ardupilot, csv"),
    ("import-log", "--kind"): choice("fixed_wing, multirotor"),
    ("import-log", "--rate"): positive("0 < rate <= 1000 Hz", 1000),
    ("import-log", "--max-roll"): positive("0 < angle <= 90 deg", 90),
    ("import-log", "--max-yaw-rate"): positive("0 < rate <= 360 deg/s", 360),
    ("import-log", "--max-sideslip"): positive("0 < angle <= 90 deg", 90),
    ("import-log", "--min-duration"): positive("0 < duration <= 3600 s", 3600),
    ("import-log", "--min-speed"): Num("0 <= speed <= 200 m/s",
                                       lambda x: finite(x) and 0 <= x <= 200),
    ("import-log", "--control-map"): Values(
        "CONTROL=SOURCE:RAW_LOW:RAW_HIGH:VALUE_LOW:VALUE_HIGH, a control of the log's kind", (
            ("elevator", "no map after the control"),
            ("elevator=x:1:1:0:1", "the two raw readings are equal"),
            ("elevator=x:a:2:0:1", "not numbers"),
            ("rudder=x:1:2:0:1", "not a longitudinal control"),
            ("elevator=x:1:2:0:1", "a fixed-wing control for a multirotor log"))),
    ("import-log", "--split-by"): choice("sortie, time-block"),
    ("*", "--fractions"): FRACTIONS,
    ("import-log", "--out"): OUT_FOLDER,
    ("split", "dataset"): Values("a dataset folder holding manifest.json", (
        (MISSING, "does not exist"), (FOLDER, "a folder without manifest.json"))),
    ("split", "--by"): choice("sortie, time-block"),
    ("identify", "--dataset"): DATASET,
    ("identify", "--params"): Values("comma-separated parameter names of the model", (
        ("no_such_param", "not a parameter of the model"), (",", "no parameter named"))),
    ("identify", "--out"): OUT_FILE,
    ("identify", "--report"): OUT_FOLDER,
    ("identify", "--window"): positive("0 < window <= the shortest train sortie (s)"),
    ("identify", "--lowpass-hz"): positive("0 < cut-off < half the log rate (Hz)"),
    ("identify", "--max-delay"): Num("0 <= samples <= 100", lambda x: 0 <= x <= 100,
                                     integer=True, extra=("101",)),
    ("identify", "--bounds"): Values("NAME=LOW:HIGH[,...], LOW < HIGH, NAME in --params", (
        ("C_m_0", "no range"), ("C_m_0=1:0", "LOW above HIGH"),
        ("C_m_0=a:b", "not numbers"), ("C_m_q=-1:0", "a parameter not in --params"))),
    ("identify", "--structure"): choice("given, auto"),
    ("reproduce", "--airframes"): choice("quadrotor, fixed_wing"),
    ("reproduce", "--out"): OUT_FOLDER,
    ("reproduce", "--cache"): OUT_FOLDER,
    ("reproduce", "--cost-repeats"): count("1 <= repeats <= 1000", 1000),
    ("reproduce", "--sorties"): count("1 <= sorties <= 100000", 100000),
    ("reproduce", "--duration"): positive("0 < duration, at most 50000 log rows per sortie "
                                          "at the recipe's 100 Hz (memory)", 499.99),
    ("evaluate", "--dataset"): DATASET,
    ("evaluate", "--identified"): IN_FILE,
    ("evaluate", "--out"): OUT_FILE,
    ("train", "--dataset"): DATASET,
    ("train", "--lowpass-hz"): positive("0 < cut-off < half the log rate (Hz)"),
    ("train", "--formulation"): choice("improved, paper, hypersolver"),
    ("train", "--target"): choice("data, reference"),
    ("train", "--activation"): choice("relu, tanh"),
    ("train", "--hidden"): count("1 <= width <= 1024 (memory)", 1024),
    ("train", "--epochs"): count("1 <= epochs <= 100000", 100000),
    ("train", "--rollout-horizon"): count("1 <= samples, no longer than the shortest sortie",
                                          100000),
    ("train", "--rollout-weight"): Num("0 <= weight < inf", lambda x: finite(x) and x >= 0),
    ("train", "--lr"): positive("0 < lr <= 1", 1),
    ("train", "--patience"): count("1 <= epochs <= 100000", 100000),
    ("train", "--max-seconds"): positive("0 < budget <= 604800 s (a week)", 604800),
    ("train", "--stability-weight"): Num("0 <= weight < inf", lambda x: finite(x) and x >= 0),
    ("train", "--stability-margin"): Num("0 <= fraction <= 1", lambda x: 0 <= x <= 1,
                                         extra=("1.5",)),
    ("train", "--min-gain"): Num("0 <= fraction <= 0.5", lambda x: 0 <= x <= 0.5,
                                 extra=("0.6",)),
    ("train", "--restarts"): count("1 <= starts <= 20", 20),
    ("train", "--start-fit"): Num("0 <= seconds <= 2", lambda x: 0 <= x <= 2, extra=("2.5",)),
    ("train", "--envelope-fade"): Num("0.05 <= range widths <= 4", lambda x: 0.05 <= x <= 4,
                                      extra=("0.01", "5")),
    ("train", "--horizon"): positive("0 < horizon <= the shortest sortie (s)"),
    ("train", "--memory-tau"): positive("0 < tau <= 10 s each, at most 8", 10),
    ("train", "--out"): OUT_FILE,
    ("train", "--history"): OUT_FILE,
    ("montecarlo", "--weights"): Values("'shipped' or an existing file", (
        (MISSING, "does not exist"), (FOLDER, "a folder where a file is expected"))),
    ("montecarlo", "--runs"): count("1 <= runs <= 1000000 (memory)", 10**6),
    ("montecarlo", "--duration"): positive("0 < duration, at most 10000000 steps at --dt"),
    ("montecarlo", "--dispersions"): IN_FILE,
    ("montecarlo", "--mission"): Values("a mission or profile name, or an existing CSV", (
        ("no_such_mission", "neither a mission nor a file"),
        (FOLDER, "a folder where a CSV is expected"))),
    ("montecarlo", "--scheduler"): Values("a Dask scheduler address host:port", (
        ("nonsense", "no port"), ("tcp://host:99999", "port out of range"))),
    ("montecarlo", "--chunk-size"): count("1 <= runs per chunk <= 100000 (memory)", 100000),
    ("montecarlo", "--history-dt"): positive("--dt <= history-dt <= --duration"),
    ("montecarlo", "--out"): OUT_FOLDER,
    ("montecarlo", "--mpc"): choice("pitch-step, climb, speed-step"),
    ("montecarlo", "--controller"): choice("none, lqr, mpc"),
    ("montecarlo", "--scenario"): choice("pitch-step, climb, speed-step (with --controller)"),
    ("montecarlo", "--mpc-backend"): choice("auto, c, python (with --controller mpc)"),
    ("mpc", "--scenario"): choice("pitch-step, climb, speed-step"),
    ("mpc", "--plant"): AIRFRAME,
    ("mpc", "--horizon"): count("1 <= intervals <= 200", 200),
    ("mpc", "--dt"): Num("0.01 <= dt <= 1 s, a multiple of 0.01 s",
                         lambda x: finite(x) and 0.01 <= x <= 1 and abs(round(x / 0.01) * 0.01
                                                                        - x) < 1e-9,
                         extra=("0.015",)),
    ("mpc", "--model"): choice("hybrid, physics, both"),
    ("mpc", "--out"): OUT_FOLDER,
    ("generate-data", "--truth"): Values(
        "KEY=VALUE[,...]: truth parameters of the airframe's kind, each once; time constants "
        ">= 0, rate limits > 0, shares 0..1, gains >= 0, coefficients finite", (
            ("eta_slipstream", "no value"), ("no_such_key=1", "an unknown truth parameter"),
            ("eta_slipstream=abc", "not a number"), ("eta_slipstream=nan", "not finite"),
            ("eta_slipstream=0.5,eta_slipstream=0.6", "a key twice"),
            ("=1", "no key"), ("tau_elevator=-0.04", "a negative time constant"),
            ("rate_elevator=0", "a zero rate limit"),
            ("eta_slipstream=2", "a share of the tail above 1"))),
    ("import-log", "--max-bank"): positive("0 < angle <= 89 deg (with --turns)", 89,
                                           extra=("90", "95")),
    ("identify", "--prior"): Values("nominal or nominal:REL_SD, 0 < REL_SD < inf", (
        ("nominal:0", "a zero standard deviation"), ("nominal:-0.1", "negative"),
        ("nominal:nan", "not a number"), ("nominal:inf", "not finite"),
        ("nominal:abc", "not a number"), ("nominal:", "no REL_SD after the colon"),
        ("flat", "not 'nominal'"), ("", "empty"))),
    ("design-input", "--airframe"): AIRFRAME,
    ("design-input", "--out"): OUT_FOLDER,
    ("design-input", "--signal"): choice("mixed, 3211, doublet, multisine"),
    ("design-input", "--params"): Values("comma-separated parameter names of the airframe's "
                                         "model", (
        ("no_such_param", "not a parameter of the model"), (",", "no parameter named"),
        ("C_m_q,C_m_q", "a parameter twice"))),
    ("design-input", "--duration"): positive("0 < duration <= 600 s, long enough for one input "
                                             "and at most 50000 log rows per sortie at --rate",
                                             600, extra=("601",)),
    ("design-input", "--sorties"): count("1 <= sorties <= 500", 500),
    ("design-input", "--rate"): Num("10 <= rate <= 1000 Hz",
                                    lambda x: finite(x) and 10 <= x <= 1000,
                                    extra=("5", "1001")),
    ("design-input", "--alpha-deg"): Num("0.1 <= alpha <= 10 deg (fixed wing)",
                                         lambda x: finite(x) and 0.1 <= x <= 10,
                                         extra=("0.05", "11")),
    ("design-input", "--amplitude"): positive("0 < amplitude <= 80 % of the [limits] travel "
                                              "about trim (aerosonde elevator: about 0.3 rad)",
                                              0.3, extra=("5",)),
    ("design-input", "--mode-hz"): positive("0 < frequency <= 100 Hz, its inputs fitting in "
                                            "--duration", 100, extra=("101",)),
    ("design-input", "--turbulent-fraction"): Num("0 <= fraction <= 1", lambda x: 0 <= x <= 1,
                                                  extra=("1.5",)),
    ("train", "--inputs"): choice("state, physical (improved/data only)"),
    ("train", "--output"): choice("acceleration, coefficient (coefficient: fixed wing; "
                                  "improved/data only)"),
    ("train", "--linear-path"): choice("on, off (improved/data only)"),
    ("train", "--stability-trims"): choice("box, gate, repair (improved/data only)"),
}

# valid values that break a relation to another option or to the data: (command, argv added
# to the base, the options the message must name, why it is invalid)
RELATIONS: tuple[tuple[str, tuple[str, ...], tuple[str, ...], str], ...] = (
    ("simulate", ("--dt", "0.5", "--duration", "0.2"), ("--dt", "--duration"),
     "a step longer than the run"),
    ("simulate", ("--dt", "1e-6", "--duration", "1000"), ("--duration", "--dt"),
     "1e9 rows: more than the 2000000 written at once (memory)"),
    ("simulate", ("--input", "none", "--amplitude", "0.01"), ("--amplitude", "--input"),
     "an amplitude for no input profile is ignored"),
    ("modes", ("--dt", "0.01"), ("--dt", "--hybrid"), "--dt applies to --hybrid only"),
    ("modes", ("--weights", "{WEIGHTS}"), ("--weights", "--hybrid"),
     "--weights applies to --hybrid only"),
    ("export-c", ("--weights", "{WEIGHTS}"), ("--weights", "--model"),
     "--weights with --model rk4 is ignored"),
    ("export-c", ("--horizon", "5"), ("--horizon", "--mpc"), "--horizon applies to --mpc only"),
    ("export-c", ("--mpc", "--rollout", "5"), ("--rollout", "--mpc"),
     "the controller bundle has no rollout"),
    ("generate-data", ("--rate", "300"), ("--internal-dt", "--rate"),
     "the 0.001 s step does not divide the 1/300 s log interval"),
    ("generate-data", ("--duration", "1e6"), ("--duration", "--rate"),
     "1e8 log rows per sortie, more than 50000 (memory)"),
    ("generate-data", ("--tolerance", "1e-6"), ("--tolerance", "--verify"),
     "--tolerance without --verify is ignored"),
    ("generate-data", ("--verify", "shipped"), ("--verify", "--recipe"),
     "'shipped' names the recipe's reference: needs --recipe"),
    ("generate-data", ("--airframe", "f450", "--missions", "high_alpha"),
     ("--missions", "--airframe"), "a fixed-wing mission for a multirotor"),
    ("identify", ("--window", "1000"), ("--window", "--dataset"),
     "a window longer than every sortie"),
    ("identify", ("--lowpass-hz", "40"), ("--lowpass-hz", "--dataset"),
     "a cut-off above half the 50 Hz log rate"),
    ("identify", ("--airframe", "f450"), ("--airframe", "--dataset"),
     "a multirotor airframe on a fixed-wing dataset"),
    ("evaluate", ("--airframe", "f450"), ("--airframe", "--dataset"),
     "a multirotor airframe on a fixed-wing dataset"),
    ("train", ("--airframe", "f450"), ("--airframe", "--dataset"),
     "a multirotor airframe on a fixed-wing dataset"),
    ("train", ("--horizon", "100"), ("--horizon", "--dataset"),
     "a rollout window longer than the sorties"),
    ("train", ("--formulation", "paper", "--rollout-horizon", "100000"),
     ("--rollout-horizon", "--dataset"), "a rollout window longer than the sorties"),
    ("train", ("--lowpass-hz", "40"), ("--lowpass-hz", "--dataset"),
     "a cut-off above half the 50 Hz log rate"),
    ("train", ("--history", "w.npz"), ("--history", "--out"),
     "the history would overwrite the weights"),
    ("train", ("--dt", "0.01"), ("--dt", "--formulation"),
     "the safe correction steps once per log sample: --dt is ignored"),
    ("train", ("--rollout-horizon", "10"), ("--rollout-horizon", "--formulation"),
     "the safe correction has no one-step/rollout loss: ignored"),
    ("train", ("--rollout-weight", "0.5"), ("--rollout-weight", "--formulation"),
     "the safe correction has no one-step/rollout loss: ignored"),
    ("train", ("--formulation", "paper", "--horizon", "1"), ("--horizon", "--formulation"),
     "an improved/data option: ignored by the paper formulation"),
    ("train", ("--formulation", "paper", "--stability-margin", "0.3"),
     ("--stability-margin", "--formulation"), "an improved/data option: ignored"),
    ("train", ("--formulation", "paper", "--stability-weight", "1"),
     ("--stability-weight", "--formulation"), "an improved/data option: ignored"),
    ("train", ("--formulation", "paper", "--memory-tau", "0.1"),
     ("--memory-tau", "--formulation"), "an improved/data option: ignored"),
    ("train", ("--memory-tau", *["0.1"] * 9), ("--memory-tau",),
     "nine command-memory filters, at most 8"),
    ("montecarlo", ("--dt", "0.01", "--duration", "0.005"), ("--duration", "--dt"),
     "a run shorter than one step"),
    ("montecarlo", ("--duration", "1e6", "--dt", "1e-6"), ("--duration", "--dt"),
     "1e12 steps per run (memory)"),
    ("montecarlo", ("--duration", "10000", "--chunk-size", "100000"),
     ("--chunk-size", "--duration"), "one chunk of 1e11 run-steps, more than 1e7 (memory)"),
    ("montecarlo", ("--history-dt", "0.001"), ("--history-dt", "--dt"),
     "an envelope sample shorter than the step"),
    ("montecarlo", ("--history-dt", "100"), ("--history-dt", "--duration"),
     "an envelope sample longer than the run"),
    ("montecarlo", ("--mpc", "pitch-step", "--closed-loop"), ("--closed-loop", "--controller"),
     "the MPC runs have no batch closed loop"),
    ("montecarlo", ("--controller", "lqr", "--closed-loop"), ("--closed-loop", "--controller"),
     "the batch LQR beside a controller study"),
    ("montecarlo", ("--mpc", "pitch-step", "--controller", "lqr"), ("--mpc", "--controller"),
     "two controllers asked for"),
    ("montecarlo", ("--controller", "mpc", "--mission", "3211"), ("--mission", "--controller"),
     "the scenario sets the reference"),
    ("montecarlo", ("--controller", "lqr", "--dt", "0.02"), ("--dt", "--controller"),
     "the controller sets the interval"),
    ("montecarlo", ("--scenario", "climb"), ("--scenario", "--controller"),
     "--scenario applies to --controller lqr|mpc only"),
    ("montecarlo", ("--controller", "lqr", "--mpc-backend", "c"),
     ("--mpc-backend", "--controller"), "--mpc-backend applies to --controller mpc only"),
    ("montecarlo", ("--controller", "mpc", "--duration", "0.3"), ("--duration",),
     "a run that ends before the scenario's step"),
    ("montecarlo", ("--workers-write",), ("--workers-write", "--scheduler"),
     "--workers-write applies to --scheduler only"),
    ("mpc", ("--weights", "{WEIGHTS}"), ("--weights", "--model"),
     "--weights with --model physics is ignored"),
    ("reproduce", ("--no-identify",), ("--no-identify", "--retrain"),
     "--no-identify applies to --retrain only"),
    ("reproduce", ("--sorties", "100000", "--duration", "60"), ("--sorties", "--duration"),
     "6e8 log rows in the pipeline's dataset, more than 5e6 (memory)"),
    ("generate-data", ("--truth", "k_etl=0.1"), ("--truth",),
     "a multirotor truth parameter for a fixed-wing airframe"),
    ("import-log", ("--max-bank", "30"), ("--max-bank", "--turns"),
     "--max-bank applies with --turns only: ignored"),
    ("import-log", ("--turns", "--max-bank", "90"), ("--max-bank",),
     "a bank of 90 deg: no longitudinal flight left to model"),
    ("import-log", ("--turns", "--max-roll", "5"), ("--max-roll", "--turns"),
     "with --turns the log is cut by --max-bank: --max-roll is ignored"),
    ("import-log", ("--turns", "--max-yaw-rate", "5"), ("--max-yaw-rate", "--turns"),
     "with --turns the log is cut by --max-bank: --max-yaw-rate is ignored"),
    ("identify", ("--prior", "nominal:0"), ("--prior",), "a zero prior width"),
    ("identify", ("--prior", "nominal:-1"), ("--prior",), "a negative prior width"),
    ("identify", ("--prior", "nominal:nan"), ("--prior",), "a prior width that is not a number"),
    ("identify", ("--prior", "nominal:abc"), ("--prior",), "a prior width that is not a number"),
    ("identify", ("--prior", "nominal:"), ("--prior",), "a colon and no prior width"),
    ("design-input", ("--params", "pitch_mix"), ("--params", "--airframe"),
     "a multirotor parameter for the fixed-wing airframe"),
    ("design-input", ("--airframe", "f450", "--alpha-deg", "5"), ("--alpha-deg", "--airframe"),
     "--alpha-deg sizes a fixed wing's elevator input: ignored for a multirotor"),
    ("design-input", ("--duration", "1"), ("--duration",),
     "too short for one input after the lead-in"),
    ("design-input", ("--amplitude", "0.9"), ("--amplitude",),
     "beyond 80 % of the elevator's travel about trim"),
    ("design-input", ("--duration", "600", "--rate", "1000"), ("--duration", "--rate"),
     "6e5 log rows per sortie, more than 50000 (memory)"),
    ("design-input", ("--mode-hz", "0.01"), ("--mode-hz", "--duration"),
     "a 3-2-1-1 timed from 0.01 Hz is far longer than the sortie"),
    ("design-input", ("--airspeed", "0"), ("--airspeed", "--airframe"),
     "a fixed wing has no trim at 0 m/s"),
    ("train", ("--formulation", "paper", "--inputs", "state"), ("--inputs", "--formulation"),
     "an improved/data option: ignored by the paper formulation"),
    ("train", ("--target", "reference", "--output", "acceleration"),
     ("--output", "--target"), "an improved/data option: ignored with --target reference"),
    ("train", ("--formulation", "hypersolver", "--linear-path", "off"),
     ("--linear-path", "--formulation"), "an improved/data option: ignored"),
    ("train", ("--formulation", "paper", "--stability-trims", "gate"),
     ("--stability-trims", "--formulation"), "an improved/data option: ignored"),
)

# the smallest valid arguments of each command (cwd is the run's own folder; {F} fixtures)
BASE: dict[str, list[str]] = {
    "airframes": ["airframes"],
    "trim": ["trim"],
    "modes": ["modes"],
    "simulate": ["simulate", "--duration", "1", "--out", "sim.csv"],
    "generate-data": ["generate-data", "--airframe", "aerosonde", "--sorties", "1",
                      "--duration", "2", "--workers", "1", "--no-progress", "--out", "gd"],
    "export-c": ["export-c", "--model", "rk4", "--out", "cb"],
    "import-log": ["import-log", "{F}/log.ulg", "--fractions", "1,0,0", "--out", "imp"],
    "split": ["split", "{F}/splitds", "--fractions", "0.5,0.5,0"],
    # C_m_0: a constant term, which identify's excitation screen accepts on these 4 s sorties
    "identify": ["identify", "--dataset", "{DS}", "--params", "C_m_0", "--out",
                 "id.toml", "--quiet"],
    # (fixed wing only: at 327d4ea the quick quadrotor pipeline stops with a free-run departure)
    "reproduce": ["reproduce", "--quick", "--airframes", "fixed_wing", "--out", "rep", "--cache",
                  "{F}/cache"],
    "evaluate": ["evaluate", "--airframe", "aerosonde", "--dataset", "{DS}",
                 "--all-sorties", "--out", "m.json"],
    "train": ["train", "--dataset", "{DS}", "--epochs", "1", "--hidden", "4",
              "--max-seconds", "20", "--quiet", "--out", "w.npz"],
    "montecarlo": ["montecarlo", "--dispersions", "{DISP}", "--runs", "2", "--duration", "1",
                   "--chunk-size", "2", "--no-progress", "--out", "mc"],
    "mpc": ["mpc", "--scenario", "pitch-step", "--model", "physics", "--horizon", "5",
            "--out", "mpc"],
    "design-input": ["design-input", "--airframe", "aerosonde", "--sorties", "1",
                     "--duration", "5", "--out", "di"],
}
# flags take no value: nothing to probe
FLAGS_NOTE = "store_true flags take no value"


@dataclass
class Run:
    command: str
    option: str
    value: str
    why: str
    argv: list[str]
    names: tuple[str, ...]
    result: str = ""
    message: str = ""
    seconds: float = 0.0
    rss_mb: float = 0.0
    valid: str = ""                       # the option's valid range (option rows)
    relation: tuple[str, ...] = ()        # the arguments added to the base (relation rows)


def describe(command: str, option: str):
    return OPTIONS.get((command, option)) or OPTIONS.get(("*", option))


def with_value(base: list[str], option: str, values: list[str]) -> list[str]:
    """``base`` with ``option`` set to ``values`` (replaced where ``base`` has it)."""
    argv = list(base)
    if not option.startswith("-"):  # the positional of import-log: the second word
        return [argv[0], *values, *argv[2:]]
    if option in argv:
        i = argv.index(option)
        j = i + 1
        while j < len(argv) and not argv[j].startswith("--"):
            j += 1
        del argv[i:j]
    return argv + [option, *values] if values != [""] else argv + [f"{option}="]


def with_extra(base: list[str], extra: tuple[str, ...]) -> list[str]:
    argv = list(base)
    i = 0
    while i < len(extra):
        option, j = extra[i], i + 1
        while j < len(extra) and not extra[j].startswith("--"):
            j += 1
        argv = with_value(argv, option, list(extra[i + 1:j])) if j > i + 1 else (
            argv if option in argv else argv + [option])
        i = j
    return argv


def plan(parser: argparse.ArgumentParser) -> tuple[list[Run], list[dict]]:
    """Every run to make, and the options that were not probed (flags, undescribed)."""
    runs, skipped = [], []
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for command, p in sub.choices.items():
        base = BASE.get(command)
        for action in p._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            option = action.option_strings[0] if action.option_strings else action.dest
            if action.nargs == 0:
                skipped.append({"command": command, "option": option, "why": FLAGS_NOTE})
                continue
            spec = describe(command, option)
            if spec is None or base is None:
                skipped.append({"command": command, "option": option,
                                "why": "undescribed: add it to OPTIONS"})
                continue
            for value, why in spec.bad_values():
                runs.append(Run(command, option, value, why, with_value(base, option, [value]),
                                (option,), valid=spec.text))
    for command, extra, names, why in RELATIONS:
        runs.append(Run(command, " ".join(x for x in extra if x.startswith("--")),
                        " ".join(x for x in extra if not x.startswith("--")), why,
                        with_extra(BASE[command], extra), names, relation=extra))
    return runs, skipped


# ------------------------------------------------------------------------------- the runner

def _child(argv: list[str], folder: Path, limit: int) -> None:
    """In the forked child: limits, output to files, run the CLI, exit with its code."""
    code = 99
    try:
        os.setpgid(0, 0)
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
        os.chdir(folder)
        for fd, name in ((1, "stdout"), (2, "stderr")):
            f = os.open(folder / f".{name}", os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            os.dup2(f, fd)
            os.close(f)
        from uavdyn.cli import main

        try:
            code = main(argv)
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    except BaseException:  # noqa: BLE001 - a traceback out of main: the probe's finding
        import traceback

        traceback.print_exc()
        code = 99
    finally:
        try:
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(code if isinstance(code, int) else 99)


def _vm_bytes() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmSize:"):
            return int(line.split()[1]) * 1024
    return 0


def _mentions(line: str, option: str) -> bool:
    return re.search(rf"(?<![\w-]){re.escape(option)}(?![\w-])", line) is not None


def classify(run: Run, code: int | None, err: str) -> None:
    lines = [x for x in err.strip().splitlines() if x.strip()]
    run.message = " | ".join(lines)[:400]
    if code is None:
        run.result = "hang/OOM"
        return
    if "MemoryError" in err or "Unable to allocate" in err or "Cannot allocate" in err:
        run.result = "hang/OOM"
    elif code == 0:
        run.result = "accepted"
    elif "Traceback" in err or "internal error" in err or code == 99 or code < 0:
        run.result = "traceback"
    elif code == 2 and len(lines) == 1 and all(_mentions(lines[0], o) for o in run.names):
        run.result = "refused"
    else:
        run.result = "unclear"


def execute(runs: list[Run], fixtures: dict[str, str], work: Path, timeout: float,
            memory: int, jobs: int) -> None:
    """Run every probe in a forked child, ``jobs`` at a time."""
    pending = list(enumerate(runs))
    active: dict[int, tuple[Run, Path, float]] = {}
    limit = _vm_bytes() + memory
    while pending or active:
        while pending and len(active) < jobs:
            i, run = pending.pop(0)
            folder = work / f"run{i:04d}"
            folder.mkdir()
            run.argv = [a.format(**fixtures) for a in run.argv]
            sys.stdout.flush()
            sys.stderr.flush()
            pid = os.fork()
            if pid == 0:
                _child(run.argv, folder, limit)
            active[pid] = (run, folder, time.monotonic())
        time.sleep(0.02)
        for pid, (run, folder, t0) in list(active.items()):
            done, status, usage = os.wait4(pid, os.WNOHANG)
            elapsed = time.monotonic() - t0
            if done == 0 and elapsed < timeout:
                continue
            if done == 0:  # the whole group: compilers, workers
                with _suppress():
                    os.killpg(pid, signal.SIGKILL)
                _, status, usage = os.wait4(pid, 0)
                code = None
            else:
                code = os.waitstatus_to_exitcode(status)
                with _suppress():
                    os.killpg(pid, signal.SIGKILL)  # a worker left behind
            run.seconds = round(elapsed, 2)
            run.rss_mb = round(usage.ru_maxrss / 1024, 1)
            classify(run, code, (folder / ".stderr").read_text(errors="replace"))
            if code is None:
                run.message = f"no answer within {timeout:g} s (peak {run.rss_mb:g} MB)"
            del active[pid]
            print(f"{run.result:>9}  {run.command} {run.option} {run.value}"[:110],
                  file=sys.stderr)


class _suppress:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return exc[0] is not None and issubclass(exc[0], OSError)


# ------------------------------------------------------------------------------- fixtures

def make_fixtures(folder: Path) -> dict[str, str]:
    """A small fixed-wing dataset (2 sorties x 4 s at 50 Hz, split train/validation) and a
    copy of it to split, a real PX4 ULog (the SITL hover shipped in tests/data), a folder, a
    file, the shipped Aerosonde weights and a dispersion file."""
    from uavdyn.emulation import Recipe, generate_dataset
    from uavdyn.learned import shipped_correction

    ds = folder / "dataset"
    folder.mkdir(parents=True)
    generate_dataset(Recipe(airframe="aerosonde", sorties=2, duration_s=4.0, seed=1,
                            sample_rate_hz=50.0, missions=["sysid_doublet"],
                            turbulent_fraction=0.0, noise_scale=0.0,
                            split={"train": 0.5, "validation": 0.5, "test": 0.0}),
                     ds, workers=1, progress=False)
    (folder / "afolder").mkdir()
    (folder / "afile.txt").write_text("not what the option wants\n")
    shutil.copytree(ds, folder / "splitds")  # split rewrites its manifest: a copy of its own
    real_log = ROOT / "tests" / "data" / "reallogs" / "px4_sitl_hover.ulg"
    if real_log.is_file():  # the real PX4 SITL hover shipped with the tests
        shutil.copyfile(real_log, folder / "log.ulg")
    else:  # import-log's base run then fails, and the report says so
        print(f"(no ULog for import-log: {real_log} is absent)", file=sys.stderr)
    weights, _ = shipped_correction("aerosonde")
    return {"F": str(folder), "DS": str(ds), "WEIGHTS": str(weights),
            "DISP": "aerosonde_pm15" if (ROOT / "uavdyn/montecarlo/shipped/aerosonde_pm15.toml"
                                         ).exists() else str(ROOT / "data/dispersions/"
                                                             "aerosonde_pm15.toml")}


# ------------------------------------------------------------------------------- reports

RESULTS = ("refused", "accepted", "unclear", "traceback", "hang/OOM")


def check_bases(commands: list[str], fixtures: dict[str, str], work: Path, timeout: float,
                memory: int, jobs: int) -> list[dict]:
    """Each command's base arguments alone: they must be accepted (exit 0, or still working at
    the timeout), or the refusals of its probes would prove nothing."""
    runs = [Run(c, "(base)", "", "the smallest valid arguments", list(argv), ())
            for c, argv in BASE.items() if c in commands]
    execute(runs, fixtures, work / "base", timeout, memory, jobs)
    out = []
    for r in runs:
        verdict = "no weights written" in r.message  # train ran; its rules kept no weights
        ok = r.result == "accepted" or r.message.startswith("no answer within") or verdict
        out.append({"command": r.command, "argv": r.argv, "ok": ok, "seconds": r.seconds,
                    "result": "exit 0" if r.result == "accepted" else
                    "trained; the trainer's rules kept no weights (exit 2, not a refusal)"
                    if verdict else "still working at the timeout" if ok else
                    f"FAILED: {r.message}"})
    return out


def summary(runs: list[Run], skipped: list[dict], seconds: float) -> dict:
    counts = {r: sum(run.result == r for run in runs) for r in RESULTS}
    failing = sorted({f"{run.command} {run.option}" for run in runs if run.result != "refused"})
    return {"command": COMMAND, "runs": len(runs),
            "options": len({(r.command, r.option) for r in runs if not r.relation}),
            "relations": sum(bool(r.relation) for r in runs),
            "counts": counts, "failing_options": failing,
            "undescribed": [s for s in skipped if s["why"] != FLAGS_NOTE],
            "flags_not_probed": len([s for s in skipped if s["why"] == FLAGS_NOTE]),
            "seconds": round(seconds, 1)}


def markdown(runs: list[Run], info: dict) -> str:
    c = info["counts"]
    out = [
        "# CLI option probe",
        "",
        f"Produced by `{COMMAND}`"
        + (" `--before <this probe's JSON on the earlier code>`" if info.get("before") else "")
        + f" (from the repository root; {info['seconds']:g} s here). "
        "Every option of every `uavdyn` subcommand (the parser of "
        "`uavdyn.cli.app.build_parser()`, walked) is given values that are invalid for it, "
        "with every other argument at its smallest valid value; each run is "
        "`uavdyn.cli.main(argv)` in a forked child with a timeout and a memory limit. The "
        "second table tries valid values that break a relation to another option or to the "
        "data. `refused` = exit code 2 and one line on stderr naming the option(s).",
        "",
        f"**{info['runs']} runs over {info['options']} options and {info['relations']} "
        f"relations: {c['refused']} refused, {c['accepted']} silently accepted, "
        f"{c['unclear']} unclear, {c['traceback']} tracebacks, {c['hang/OOM']} hang/OOM; "
        f"{len(info['undescribed'])} options undescribed (not probed).** "
        + ("Undescribed: " + ", ".join(f"`{u['command']} {u['option']}`"
                                       for u in info["undescribed"]) + ". "
           if info["undescribed"] else "")
        + f"Flags (store_true, no value) are not probed ({info['flags_not_probed']}).",
    ]
    if info.get("before"):
        b, bc = info["before"], info["before"]["counts"]
        two = b["two_line_argparse"]
        out += ["", f"The same probe on {b['label']}: {b['runs']} runs, {bc['refused']} refused, "
                f"{bc['accepted']} silently accepted, {bc['unclear']} unclear ({two} of them "
                "argparse's own two-line refusals: usage, then the message), "
                f"{bc['traceback']} tracebacks, {bc['hang/OOM']} hang/OOM; "
                f"{len(b['failing_options'])} options or relations failing: "
                + ", ".join(f"`{o}`" for o in b["failing_options"]) + "."]
    if info.get("base_runs"):
        out += ["", "## Base runs", "",
                "Each command with only its base arguments (the ones every probe of it "
                "starts from) must be accepted, or the refusals below would prove nothing:",
                "", "| command | base arguments | result |", "|---|---|---|"]
        out += [f"| {b['command']} | `{_cell(' '.join(b['argv'][1:]))}` | "
                f"{_cell(b['result'])} |" for b in info["base_runs"]]
    out += [
        "",
        "## Option values",
        "",
        "| command | option | valid range | bad value tried (why invalid) | result | message |",
        "|---|---|---|---|---|---|",
    ]
    for r in runs:
        if r.relation:
            continue
        out.append(f"| {r.command} | `{r.option}` | {_cell(r.valid)} | "
                   f"`{r.value or '(empty)'}` ({_cell(r.why)}) | {r.result} | "
                   f"{_cell(r.message)} |")
    out += ["", "## Relations", "",
            "| command | arguments | must name | why invalid | result | message |",
            "|---|---|---|---|---|---|"]
    for r in runs:
        if not r.relation:
            continue
        args = " ".join(r.relation).replace("{WEIGHTS}", "<weights.npz>")
        out.append(f"| {r.command} | `{_cell(args)}` | {', '.join(r.names)} | {_cell(r.why)} "
                   f"| {r.result} | {_cell(r.message)} |")
    return "\n".join(out) + "\n"


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="docs/benchmarks/cli_option_probe",
                    help="writes <out>.json and <out>.md")
    ap.add_argument("--timeout", type=float, default=30.0, help="seconds per run")
    ap.add_argument("--memory-gb", type=float, default=3.0,
                    help="address space a run may add to the parent's")
    ap.add_argument("--jobs", type=int, default=2, help="runs at a time")
    ap.add_argument("--only", default=None, help="probe only this command")
    ap.add_argument("--base-timeout", type=float, default=120.0,
                    help="seconds for each command's valid base run")
    ap.add_argument("--no-base", action="store_true", help="skip the base runs")
    ap.add_argument("--before", default=None, metavar="JSON",
                    help="the JSON of this probe run on earlier code: its counts and failing "
                         "options are added to the report")
    ap.add_argument("--before-label", default="earlier code",
                    help="what --before was run on (e.g. a commit)")
    args = ap.parse_args(argv)
    t0 = time.monotonic()
    try:
        import torch  # noqa: F401 - imported once here: the children start warm
    except ImportError:
        pass
    from uavdyn.cli.app import build_parser

    work = Path(tempfile.mkdtemp(prefix="uavdyn-probe-"))
    try:
        fixtures = make_fixtures(work / "fixtures")
        runs, skipped = plan(build_parser())
        if args.only:
            runs = [r for r in runs if r.command == args.only]
        memory = int(args.memory_gb * 2**30)
        (work / "base").mkdir()
        bases = [] if args.no_base else check_bases(
            [args.only] if args.only else list(BASE), fixtures, work, args.base_timeout, memory,
            args.jobs)
        execute(runs, fixtures, work, args.timeout, memory, args.jobs)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    for r in runs:  # the temporary folder is gone: name it generically in the report
        r.argv = [a.replace(str(work), "<tmp>") for a in r.argv]
        r.message = r.message.replace(str(work), "<tmp>")
        r.value = r.value.replace(str(work), "<tmp>")
    for b in bases:
        b["argv"] = [a.replace(str(work), "<tmp>") for a in b["argv"]]
        b["result"] = b["result"].replace(str(work), "<tmp>")
    info = summary(runs, skipped, time.monotonic() - t0)
    info["base_runs"] = bases
    if args.before:
        earlier = json.loads(Path(args.before).read_text())
        info["before"] = {"label": args.before_label, "runs": earlier["runs"],
                          "counts": earlier["counts"],
                          "failing_options": earlier["failing_options"],
                          "two_line_argparse": sum(
                              r["result"] == "unclear" and r["message"].startswith("usage:")
                              for r in earlier["runs_detail"])}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(
        {**info, "runs_detail": [r.__dict__ for r in runs], "not_probed": skipped},
        indent=1) + "\n")
    out.with_suffix(".md").write_text(markdown(runs, info))
    print(json.dumps(info, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
