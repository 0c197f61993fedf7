"""The fitting commands: ``identify`` (physical parameters) and ``train`` (the correction)."""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path

from uavdyn.airframes import DELAY_MAX_SAMPLES, load_airframe
from uavdyn.cli.common import (
    SEED,
    STEP,
    THREADS,
    CliError,
    add_airframe,
    add_force,
    bound_list,
    check_dataset_fits,
    count,
    dataset_path,
    file_to_write,
    folder_to_write,
    name_list,
    number,
    positive,
    refuse_unused,
    seconds,
)
from uavdyn.flightdata import Sortie, load_dataset
from uavdyn.identify import identify, write_outputs
from uavdyn.identify.freerun import departure_line
from uavdyn.identify.prior import PRIOR_SD_DEFAULT
from uavdyn.identify.report import HELD_HEADLINE, estimate_line, structure_lines
from uavdyn.identify.selection import select_structure
from uavdyn.identify.unknowns import DELAY_PREFIX, control_names
from uavdyn.integrate import EvalGrid, GridError
from uavdyn.learned.stability import STABILITY_TRIMS
from uavdyn.learned.weights import MAX_MEMORY_FILTERS
from uavdyn.outputs import check_output_files, single_outputs

MAX_HIDDEN = 1024        # width of the correction's hidden layers (memory and time)
MAX_EPOCHS = 100_000
MAX_RESTARTS = 20
MAX_TRAIN_SECONDS = 7 * 86400.0  # a wall-clock budget that still ends the run


def cmd_identify(args: argparse.Namespace) -> int:
    """Fit named physical parameters to a dataset; write the fitted airframe and a report."""
    nominal = load_airframe(args.airframe)
    check_dataset_fits(nominal, args.dataset, args.lowpass_hz)
    names = args.params
    delays = [DELAY_PREFIX + c for c in control_names(nominal.kind)]
    unknown = [n for n in names if n not in nominal.param_names and n not in delays]
    if unknown:
        raise CliError(f"--params {', '.join(unknown)}: not in the {nominal.kind} model of "
                       f"--airframe {args.airframe}; choose from "
                       f"{', '.join(nominal.param_names + tuple(delays))}")
    refuse_unused(args, ("--max-delay",), any(n in delays for n in names),
                  "with a delay_<control> name in --params")
    stray = sorted(set(args.bounds or {}) - set(names) | set(args.bounds or {}) & set(delays))
    if stray:
        raise CliError(f"--bounds {', '.join(stray)}: only a continuous parameter named in "
                       "--params takes bounds")
    out = Path(args.out)
    report = Path(args.report) if args.report else out.with_name(out.stem + "_report")
    outputs = (out, report / "identify.json", report / "identify.png")
    check_output_files(*outputs, force=args.force)  # before the work
    ds = load_dataset(args.dataset, lowpass_hz=args.lowpass_hz)
    if not ds.train:
        raise CliError(f"{args.dataset}: the dataset has no train split to fit on")
    _check_identify_steps(args, ds.train)
    if not ds.validation:
        print("warning: no validation split; the fit is scored on the training sorties only",
              file=sys.stderr)
    max_delay = 5 if args.max_delay is None else args.max_delay
    options = {"window_s": args.window, "dt": args.dt, "max_delay": max_delay,
               "bounds": args.bounds, "progress": not args.quiet, "prior_sd": args.prior,
               "keep_undetermined": args.keep_undetermined,
               "screen": not args.allow_low_excitation}
    log = None
    if args.structure == "auto":
        if not ds.validation:
            raise CliError(f"--structure auto: {args.dataset} has no validation split (terms "
                           "are kept only if they predict sorties they were not fitted on)")
        result, _, log = select_structure(
            nominal, ds.train, ds.validation, names,
            say=None if args.quiet else lambda m: print(m, file=sys.stderr), **options)
    else:
        result = identify(nominal, ds.train, ds.validation, names, **options)
    command = "uavdyn " + " ".join(sys.argv[1:]) if sys.argv[1:2] == ["identify"] else \
        f"uavdyn identify --airframe {args.airframe} --dataset {args.dataset} --params " \
        f"{args.params} --out {args.out}"
    for line in result.fit.get("excitation_advice", []):
        print(f"warning: {line}", file=sys.stderr)
    with single_outputs(*outputs, command="identify", force=args.force):
        paths = write_outputs(result, nominal, str(args.dataset), command, out, report, log)
    print(f"identified {len(names)} parameter(s) of '{nominal.name}' on {len(ds.train)} train "
          f"sorties in {result.seconds:.1f} s ({result.iterations} iterations)")
    left = result.fit.get("left_out")
    if left:
        print(f"  left out of the fit: {left['windows']} of {left['of']} windows "
              f"({', '.join(left['sorties'])}): {left['why']}")
    for e in result.estimates:
        if e.searched:
            print(f"  {e.name:>14} = {int(e.value):12d} samples (searched 0..{max_delay}; "
                  f"nominal {int(e.nominal)})")
            continue
        print("  " + estimate_line(e))
    for a, b, c in result.flagged_pairs:
        print(f"  highly correlated: {a} and {b} (r = {c:+.3f})")
    undetermined = [e for e in result.estimates if e.flags()]
    print(f"  {len(result.estimates) - len(undetermined)} of {len(result.estimates)} "
          "parameters determined by these data"
          + (f"; flagged: {'; '.join(_why_flagged(e) for e in undetermined)}"
             if undetermined else ""))
    kept = [e.name for e in result.estimates if e.kept]
    if kept:
        print(f"  kept the airframe file's value (not determined; the others refitted with "
              f"them fixed; --keep-undetermined writes the raw fit): {', '.join(kept)}")
    held = [e.name for e in result.estimates if e.held]
    if held:
        print(f"  {HELD_HEADLINE} (--keep-undetermined writes the raw fit): {', '.join(held)}")
    if args.prior is not None:
        under = [e.name for e in undetermined if not e.searched and not e.kept]
        print(f"  prior: Gaussian around the file's values, relative s.d. {args.prior:g} "
              "(maximum a posteriori; standard errors the posterior's)"
              + (f"; set under the prior, not by the data: {', '.join(under)}" if under
                 else ""))
    departed = departure_line(result.fit, len(ds.train))
    if departed:
        print("  " + departed)
    for line in structure_lines(log) if log else []:
        print("  " + line)
    for split in ("train", "validation"):
        fit = result.fit.get(split)
        if fit:
            print(f"  {split} pitch RMSE over {result.window_s:g} s windows: nominal "
                  f"{fit['theta_rmse']['nominal']:.3g} rad -> identified "
                  f"{fit['theta_rmse']['identified']:.3g} rad" + _inside_note(fit))
    print(f"wrote {paths['airframe']}, {paths['json']} and {paths['png']}")
    return 0


def _inside_note(fit: dict) -> str:
    """The same RMSE over the windows short of the stall onset, where some reach past it."""
    inside = fit.get("theta_rmse_inside")
    if not inside:
        return ""
    return (f"; without the {fit['windows_past_stall_onset']} windows past the stall onset "
            f"(not modelled, left out of the fit): {inside['nominal']:.3g} -> "
            f"{inside['identified']:.3g} rad")


PRIOR_FORM = re.compile(r"nominal(?::([0-9]+(?:\.[0-9]*)?(?:[eE][+-]?[0-9]+)?))?")


def prior_option(text: str) -> float:
    """``nominal[:REL_SD]``: a Gaussian prior around the file's values with relative standard
    deviation REL_SD (a finite number > 0; default :data:`PRIOR_SD_DEFAULT`)."""
    found = PRIOR_FORM.fullmatch(text.strip())
    value = (float(found.group(1)) if found and found.group(1) else PRIOR_SD_DEFAULT) \
        if found else math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(
            f"must be 'nominal' or 'nominal:REL_SD' with REL_SD a number > 0 (the prior's "
            f"standard deviation relative to each file value), got {text!r}")
    return value


def _why_flagged(estimate) -> str:
    """``C_L_0 (on its upper bound)``: the name and the short reason for the headline."""
    reasons = []
    if estimate.at_bound:
        reasons.append(f"on its {estimate.at_bound} bound")
    if estimate.undetermined:
        reasons.append("not determined")
    return f"{estimate.name} ({', '.join(reasons)})"


def _check_identify_steps(args: argparse.Namespace, train: list[Sortie]) -> None:
    """``--window`` no longer than the train sorties, ``--dt`` fitting their log interval."""
    longest = max(s.duration for s in train)
    if args.window > longest:
        raise CliError(f"--window {args.window:g} s is longer than every train sortie of "
                       f"--dataset {args.dataset} (the longest is {longest:g} s)")
    if args.dt is None:
        return
    if args.dt > args.window:
        raise CliError(f"--dt {args.dt:g} s is longer than --window {args.window:g} s")
    try:
        EvalGrid(train[0].dt, args.dt)
    except GridError as exc:
        raise CliError(f"--dt {args.dt:g} s does not fit the log interval of --dataset "
                       f"{args.dataset}: {exc}") from None


def training_module():
    """Import :mod:`uavdyn.learned.command` (needs torch, the ``[train]`` extra)."""
    try:
        import torch  # noqa: F401
    except ImportError:
        raise CliError("training needs PyTorch: pip install -e '.[train]'") from None
    from uavdyn.learned import command as module

    return module


SAFE_ONLY = ("--stability-weight", "--stability-margin", "--stability-trims", "--horizon",
             "--memory-tau", "--inputs", "--output", "--linear-path", "--min-gain", "--restarts",
             "--start-fit", "--envelope-fade", "--steady-gate", "--damping-weight")
LEGACY_ONLY = ("--dt", "--rollout-horizon", "--rollout-weight")


def check_train_options(args: argparse.Namespace) -> None:
    """The relations of ``train``'s options: each applies to one trainer (the safe correction
    of ``--formulation improved --target data``, or the legacy formulations), at most
    :data:`MAX_MEMORY_FILTERS` memory filters."""
    safe = args.formulation == "improved" and args.target == "data"
    refuse_unused(args, SAFE_ONLY, safe, "to the safe correction (--formulation improved "
                  "--target data)")
    refuse_unused(args, LEGACY_ONLY, not safe, "to --formulation paper/hypersolver or --target "
                  "reference (the safe correction steps once per log sample, with rollouts "
                  "of --horizon s)")
    if args.memory_tau is not None and len(args.memory_tau) > MAX_MEMORY_FILTERS:
        raise CliError(f"--memory-tau gives {len(args.memory_tau)} time constants, at most "
                       f"{MAX_MEMORY_FILTERS}")


def cmd_train(args: argparse.Namespace) -> int:
    """Train the learned correction on a dataset; write weights (.npz), loss history JSON and
    PNG. Checked first: the options' relations, the airframe's kind against the dataset's,
    then (:func:`uavdyn.learned.command.run`) the output files, that ``--dataset`` is given
    and the rollout windows against its sorties."""
    check_train_options(args)
    airframe = load_airframe(args.airframe)
    if args.dataset:
        check_dataset_fits(airframe, args.dataset, args.lowpass_hz)
    module = training_module()
    summary = module.run(args, airframe)
    print(json.dumps(summary, indent=2) if args.json else "\n".join(train_lines(summary)))
    return 0


def train_lines(summary: dict) -> list[str]:
    """What ``uavdyn train`` prints (without ``--json``): the verdict with its numbers, the
    network and how its run ended, and the files written."""
    epochs = summary.get("epochs_run")
    run = (f"best epoch {summary['best_epoch']}" + (f" of {epochs}" if epochs is not None
                                                    else "")
           + f", {summary['stopped']}; {summary['seconds']:g} s on {summary['n_train']} "
           f"train and {summary['n_val']} validation sorties")
    if "reason" in summary:  # the safe correction: its verdict says why it was kept
        head = f"kept: {summary['reason']}"
    else:
        head = (f"trained: validation loss {summary['val_total_initial']:.4g} -> "
                f"{summary['val_total_best']:.4g}")
    return [head, f"  {summary['network']}; {run}",
            f"wrote {summary['weights']}, {summary['history']} and {summary['png']}"]


def add_identify(sub) -> None:
    """Register ``identify``."""
    p = sub.add_parser("identify", help="fit named physical parameters to flight data "
                       "(output error); write the fitted airframe file and a report")
    add_force(p, single=True)
    add_airframe(p)
    p.add_argument("--dataset", required=True, type=dataset_path,
                   help="dataset folder (manifest.json + CSVs)")
    p.add_argument("--params", required=True, type=name_list("parameter"),
                   help="comma-separated parameter names, e.g. C_m_alpha,C_m_q,rho")
    p.add_argument("--out", required=True, type=file_to_write,
                   help="fitted airframe file (.toml)")
    p.add_argument("--report", default=None, type=folder_to_write,
                   help="report folder (JSON + PNG; default <out>_report beside --out)")
    p.add_argument("--window", type=seconds(name="window"), default=1.0,
                   help="prediction window in s, restarted from recorded states, no longer "
                        "than the train sorties (default 1)")
    p.add_argument("--dt", type=STEP, default=None,
                   help="RK4 step in s, fitting the log interval (default: the log interval "
                        "in whole sub-steps of at most 0.005 s, at least 2)")
    p.add_argument("--lowpass-hz", type=positive(name="cut-off", unit="Hz"), default=None,
                   help="zero-phase low-pass filter of the data before fitting (Hz, below half "
                        "the log rate)")
    p.add_argument("--max-delay", type=number(1, DELAY_MAX_SAMPLES, integer=True,
                                              name="samples"), default=None,
                   help=f"largest transport delay (samples, 1..{DELAY_MAX_SAMPLES}) searched for "
                        "delay_<control> names (default 5)")
    p.add_argument("--bounds", type=bound_list, default=None,
                   help="NAME=LOW:HIGH[,...]: narrow a fitted parameter's range (default: its "
                        "physical range by meaning and sign convention: C_L_alpha > 0, "
                        "C_m_q < 0, C_m_delta_e < 0, C_m_alpha < 0 unless the airframe file "
                        "declares relaxed_stability, other coefficients of either sign, a "
                        "time constant >= 0, a share in [0, 1])")
    p.add_argument("--structure", choices=("given", "auto"), default="given",
                   help="given (default): fit --params; auto: also try the model's optional "
                        "terms and a C_m(alpha) table, keeping those that lower the validation "
                        "1 s pitch error by >= 2 %% (needs a validation split)")
    p.add_argument("--prior", type=prior_option, default=None, metavar="nominal[:REL_SD]",
                   help="a Gaussian prior on each fitted parameter around the airframe file's "
                        "value, standard deviation REL_SD x its magnitude (default "
                        f"{PRIOR_SD_DEFAULT:g}; none for a file value of 0): the maximum a "
                        "posteriori, with each parameter's prior share of the information "
                        "reported")
    p.add_argument("--keep-undetermined", action="store_true",
                   help="write every fitted value, also of parameters the data do not "
                        "determine (default: one whose interval spans zero or that ends on a "
                        "bound keeps the file's value and the others are refitted with it "
                        "fixed; a collinear group is refitted with only the combination the "
                        "data cannot determine held at the file's values; with --prior they "
                        "are fitted under it, and only one still on a bound keeps the file's "
                        "value)")
    p.add_argument("--allow-low-excitation", action="store_true",
                   help="fit also parameters whose signal the train data do not move above "
                        "its noise (default: refused before the fit; a signal above its noise "
                        "but below the advisory floor is only a warning)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_identify)


def add_train(sub) -> None:
    """Register ``train``."""
    p = sub.add_parser("train", help="train the learned correction (torch) and export its "
                       "weights as .npz")
    add_force(p, single=True)
    add_airframe(p)
    p.add_argument("--dataset", default=None, metavar="DIR", type=dataset_path,
                   help="required: dataset folder (manifest.json + CSVs, with a train/validation "
                        "split), e.g. from `uavdyn generate-data`")
    p.add_argument("--lowpass-hz", type=positive(name="cut-off", unit="Hz"), default=None,
                   help="zero-phase low-pass filter of the dataset's measured states (Hz, "
                        "below half the log rate)")
    p.add_argument("--formulation", default="improved",
                   choices=["improved", "paper", "hypersolver"],
                   help="improved (default): residual force/moment inside RK4; paper: "
                        "x_base + NN(t, x_base); hypersolver: RK4 + dt^5 g(x, u)")
    p.add_argument("--target", default="data", choices=["data", "reference"],
                   help="data (default): model-discrepancy correction; reference: fine-step "
                        "baseline (pure numerical correction)")
    p.add_argument("--activation", default="relu", choices=["relu", "tanh"],
                   help="hidden-layer activation (default relu: cheapest in C; tanh is smooth "
                        "and bounded)")
    p.add_argument("--hidden", type=count(MAX_HIDDEN, "width"), default=None,
                   help="hidden-layer width (default for the safe correction: 8 for a fixed "
                        "wing, 5 for a multirotor, whose physics step is cheaper; 16 for the "
                        f"legacy formulations; at most {MAX_HIDDEN})")
    p.add_argument("--dt", type=STEP, default=None,
                   help="paper/hypersolver/reference: hybrid step in s (default 0.005; the "
                        "safe correction steps once per log sample)")
    p.add_argument("--epochs", type=count(MAX_EPOCHS, "epochs"), default=None,
                   help="maximum epochs (default 300 for the safe correction, 60 otherwise)")
    p.add_argument("--rollout-horizon", type=count(MAX_EPOCHS, "samples"), default=None,
                   help="paper/hypersolver/reference: rollout-loss window in samples, no longer "
                        "than the sorties (default 25)")
    p.add_argument("--rollout-weight", type=number(0.0, name="weight"), default=None,
                   help="paper/hypersolver/reference: weight of the rollout loss (default 1, "
                        "0 = one-step loss only)")
    p.add_argument("--lr", type=number(0.0, 1.0, low_open=True, name="lr"), default=3e-3,
                   help="initial Adam learning rate, 0 < lr <= 1 (default 0.003)")
    p.add_argument("--patience", type=count(MAX_EPOCHS, "epochs"), default=None,
                   help="early stopping: epochs without validation improvement (default 40 for "
                        "the safe correction, 12 otherwise)")
    p.add_argument("--max-seconds", type=seconds(MAX_TRAIN_SECONDS, "budget"), default=None,
                   help="wall-clock budget in s, at most a week (default 3600 for the safe "
                        "correction, a safety net only; 270 otherwise)")
    p.add_argument("--seed", type=SEED, default=0, help="random seed >= 0 (default 0)")
    p.add_argument("--threads", type=THREADS, default=1, help="torch threads (default 1)")
    p.add_argument("--stability-weight", type=number(0.0, name="weight"), default=None,
                   help="improved/data: weight of the stability penalty at trims over the "
                        "training envelope, >= 0 (default 10)")
    p.add_argument("--damping-weight", type=number(0.0, name="weight"), default=None,
                   help="improved/data: weight of the damping prior, >= 0: the hybrid's pitch "
                        "damping at the training windows' starts may weaken the physics' but "
                        "not turn positive (default 10; 0 switches it off; measured: "
                        "docs/learned_correction.md)")
    p.add_argument("--stability-margin", type=number(0.0, 1.0, name="fraction"), default=None,
                   help="improved/data: how much a stable physics mode's decay rate may shrink "
                        "(fraction 0..1, default 0.5); a neutral mode may never grow")
    p.add_argument("--stability-trims", choices=STABILITY_TRIMS, default=None,
                   help="improved/data: where the training penalty holds the hybrid's modes: "
                        "box, the trims over the training envelope's airspeeds; gate, those "
                        "and the ones beyond out to where the gate reaches 0, every trim the "
                        "final stability check runs at; repair (default), box, and where a "
                        "candidate at full output fails only the final check, the best of "
                        "them trained on for 40 epochs with the penalty at every trim the "
                        "check runs at (measured: docs/learned_correction.md)")
    p.add_argument("--steady-gate", choices=("on", "off"), default=None,
                   help="improved/data: on, in steady flight (pitch rate held near zero) the "
                        "correction acts only inside the box of the training data's steady "
                        "flight, fading beyond it as far as the steady validation data reach; "
                        "off (default), the training box alone (measured: "
                        "docs/learned_correction.md)")
    p.add_argument("--min-gain", type=number(0.0, 0.5, name="fraction"), default=None,
                   help="improved/data: the least gain a correction must show on the "
                        "validation sorties to be kept (geometric mean of the per-sortie "
                        "ratios at most 1 - this; fraction 0..0.5, default 0.02: a gain "
                        "smaller than the 2 %% a sortie may lose within noise is refused)")
    p.add_argument("--restarts", type=count(MAX_RESTARTS, "starts"), default=None,
                   help="improved/data: networks started from different seeds, each trained "
                        "for 40 epochs, the one with the least training loss trained on "
                        f"(1 to {MAX_RESTARTS}; default 1: measured in "
                        "docs/learned_correction.md, more starts kept more corrections that "
                        "lose calm test sorties)")
    p.add_argument("--start-fit", type=number(0.0, 2.0, name="seconds"), default=None,
                   help="improved/data: each validation window starts from the state each "
                        "scored model fits to its first this-many seconds of records (0..2 s; "
                        "default 0.2; 0: from the recorded state, whose noise a correction can "
                        "earn a gain by damping)")
    p.add_argument("--envelope-fade", type=number(0.05, 4.0, name="range widths"),
                   default=None,
                   help="improved/data: how far beyond the training data the correction may "
                        "act: its gate falls from 1 to 0 over this many widths of each "
                        "input's training range (0.05..4; default: per input, as far as the "
                        "training and validation data reach beyond it, 0.1..1 widths; the "
                        "stability check runs out to where it reaches 0)")
    p.add_argument("--horizon", type=seconds(name="horizon"), default=None,
                   help="improved/data: rollout window from recorded states in s, no longer "
                        "than the sorties (default 2)")
    p.add_argument("--memory-tau", type=seconds(10.0, "tau"), nargs="*", default=None,
                   help="improved/data: command-memory time constants in s (0 < tau <= 10, at "
                        f"most {MAX_MEMORY_FILTERS}; default 0.05 0.2 when the airframe has no "
                        "actuator lag, none otherwise)")
    p.add_argument("--inputs", default=None, choices=["state", "physical"],
                   help="improved/data: what the network sees in place of the body states: "
                        "state (u, w, q, theta) or physical (a fixed wing's alpha, V, q c/2V, "
                        "alpha-dot c/2V, thrust coefficient; a multirotor's u, w, q, thrust "
                        "per weight, rotor speed times u and w, front-rear rotor-speed "
                        "difference times u and w); default physical "
                        "(docs/learned_correction.md)")
    p.add_argument("--output", default=None, choices=["acceleration", "coefficient"],
                   help="improved/data: the network's output: residual accelerations or (a "
                        "fixed wing) force and moment coefficients times dynamic pressure; "
                        "default coefficient for a fixed wing, acceleration for a multirotor")
    p.add_argument("--linear-path", default=None, choices=["on", "off"],
                   help="improved/data: a linear path from the inputs to the outputs beside "
                        "the hidden layers (default on)")
    p.add_argument("--out", default=None, type=file_to_write,
                   help="weight file (default results/weights/<airframe>_<formulation>.npz)")
    p.add_argument("--history", default=None, type=file_to_write,
                   help="loss-history JSON (default beside --out; a PNG is written too)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true",
                   help="print the run's summary as JSON (default: its verdict in words)")
    p.set_defaults(func=cmd_train)
