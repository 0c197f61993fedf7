"""The fitting commands: ``identify`` (physical parameters) and ``train`` (the correction)."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from uavdyn.airframes import AirframeError, load_airframe
from uavdyn.cli.common import (
    CliError,
    add_airframe,
    add_force,
)
from uavdyn.flightdata import load_dataset
from uavdyn.identify import identify, write_outputs


def cmd_identify(args: argparse.Namespace) -> int:
    """Fit named physical parameters to a dataset; write the fitted airframe and a report."""
    nominal = load_airframe(args.airframe)
    names = [n.strip() for n in args.params.split(",") if n.strip()]
    out = Path(args.out)
    if out.exists() and not args.force:
        try:
            load_airframe(out)
        except AirframeError:
            raise CliError(f"{out} exists and is not an airframe file; choose another --out or "
                           "give --force") from None
    if not (args.window > 0 and math.isfinite(args.window)):
        raise CliError(f"--window must be a positive number of seconds, got {args.window}")
    ds = load_dataset(args.dataset, lowpass_hz=args.lowpass_hz)
    if not ds.train:
        raise CliError(f"{args.dataset}: the dataset has no train split to fit on")
    if not ds.validation:
        print("warning: no validation split; the fit is scored on the training sorties only",
              file=sys.stderr)
    if args.max_delay < 0:
        raise CliError(f"--max-delay must be >= 0 samples, got {args.max_delay}")
    result = identify(nominal, ds.train, ds.validation, names, window_s=args.window,
                      dt=args.dt, max_delay=args.max_delay, progress=not args.quiet)
    report = Path(args.report) if args.report else out.with_name(out.stem + "_report")
    command = "uavdyn " + " ".join(sys.argv[1:]) if sys.argv[1:2] == ["identify"] else \
        f"uavdyn identify --airframe {args.airframe} --dataset {args.dataset} --params " \
        f"{args.params} --out {args.out}"
    paths = write_outputs(result, nominal, str(args.dataset), command, out, report)
    print(f"identified {len(names)} parameter(s) of '{nominal.name}' on {len(ds.train)} train "
          f"sorties in {result.seconds:.1f} s ({result.iterations} iterations)")
    for e in result.estimates:
        if e.searched:
            print(f"  {e.name:>14} = {int(e.value):12d} samples (searched 0..{args.max_delay}; "
                  f"nominal {int(e.nominal)})")
            continue
        change = f", {100 * e.relative_change:+.2f} %" if e.nominal else ""
        bound = f", on its {e.at_bound} bound" if e.at_bound else ""
        print(f"  {e.name:>14} = {e.value:12.6g} +- {e.std_error:.2g}  (nominal "
              f"{e.nominal:.6g}{change}{bound})")
    for a, b, c in result.flagged_pairs:
        print(f"  highly correlated: {a} and {b} (r = {c:+.3f})")
    for split in ("train", "validation"):
        fit = result.fit.get(split)
        if fit:
            print(f"  {split} pitch RMSE over {result.window_s:g} s windows: nominal "
                  f"{fit['theta_rmse']['nominal']:.3g} rad -> identified "
                  f"{fit['theta_rmse']['identified']:.3g} rad")
    print(f"wrote {paths['airframe']}, {paths['json']} and {paths['png']}")
    return 0


def training_module():
    """Import :mod:`uavdyn.learned.command` (needs torch, the ``[train]`` extra)."""
    try:
        import torch  # noqa: F401
    except ImportError:
        raise CliError("training needs PyTorch: pip install -e '.[train]'") from None
    from uavdyn.learned import command as module

    return module


def cmd_train(args: argparse.Namespace) -> int:
    """Train the learned correction on a dataset; write weights (.npz), loss history JSON and
    PNG (the output files are checked first, then ``--dataset`` is required)."""
    module = training_module()
    summary = module.run(args)
    print(json.dumps(summary, indent=2))
    return 0


def add_identify(sub) -> None:
    """Register ``identify``."""
    p = sub.add_parser("identify", help="fit named physical parameters to flight data "
                       "(output error); write the fitted airframe file and a report")
    add_force(p)
    add_airframe(p)
    p.add_argument("--dataset", required=True, help="dataset folder (manifest.json + CSVs)")
    p.add_argument("--params", required=True,
                   help="comma-separated parameter names, e.g. C_m_alpha,C_m_q,rho")
    p.add_argument("--out", required=True, help="fitted airframe file (.toml)")
    p.add_argument("--report", default=None,
                   help="report folder (JSON + PNG; default <out>_report beside --out)")
    p.add_argument("--window", type=float, default=1.0,
                   help="prediction window in s, restarted from recorded states (default 1)")
    p.add_argument("--dt", type=float, default=None,
                   help="RK4 step in s (default half the log interval)")
    p.add_argument("--lowpass-hz", type=float, default=None,
                   help="zero-phase low-pass filter of the data before fitting")
    p.add_argument("--max-delay", type=int, default=5,
                   help="largest transport delay (samples) searched for delay_<control> names "
                        "(default 5)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_identify)


def add_train(sub) -> None:
    """Register ``train``."""
    p = sub.add_parser("train", help="train the learned correction (torch) and export its "
                       "weights as .npz")
    add_force(p)
    add_airframe(p)
    p.add_argument("--dataset", default=None, metavar="DIR",
                   help="required: dataset folder (manifest.json + CSVs, with a train/validation "
                        "split), e.g. from `uavdyn generate-data`")
    p.add_argument("--lowpass-hz", type=float, default=None,
                   help="zero-phase low-pass filter of the dataset's measured states (Hz)")
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
    p.add_argument("--hidden", type=int, default=None,
                   help="hidden-layer width (default for the safe correction: 8 for a fixed "
                        "wing, 6 for a multirotor, whose physics step is cheaper; 16 for the "
                        "legacy formulations)")
    p.add_argument("--dt", type=float, default=0.005,
                   help="hybrid step in s (default 0.005; the improved correction on flight "
                        "data steps once per log sample)")
    p.add_argument("--epochs", type=int, default=None,
                   help="maximum epochs (default 100 for the safe correction, 60 otherwise)")
    p.add_argument("--rollout-horizon", type=int, default=25,
                   help="rollout-loss window in samples (default 25)")
    p.add_argument("--rollout-weight", type=float, default=1.0,
                   help="weight of the rollout loss (default 1, 0 = one-step loss only)")
    p.add_argument("--lr", type=float, default=3e-3, help="initial Adam learning rate")
    p.add_argument("--patience", type=int, default=None,
                   help="early stopping: epochs without validation improvement (default 8 for "
                        "the safe correction, 12 otherwise)")
    p.add_argument("--max-seconds", type=float, default=None,
                   help="wall-clock budget in s (default 3600 for the safe correction, a safety "
                        "net only; 270 otherwise)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("--stability-weight", type=float, default=None,
                   help="improved/data: weight of the stability penalty at trims over the "
                        "training envelope (default 10)")
    p.add_argument("--stability-margin", type=float, default=0.5,
                   help="improved/data: how much a stable physics mode's decay rate may shrink "
                        "(fraction, default 0.5); a neutral mode may never grow")
    p.add_argument("--horizon", type=float, default=2.0,
                   help="improved/data: rollout window from recorded states in s (default 2)")
    p.add_argument("--memory-tau", type=float, nargs="*", default=None,
                   help="improved/data: command-memory time constants in s (default 0.05 0.2 "
                        "when the airframe has no actuator lag, none otherwise)")
    p.add_argument("--out", default=None,
                   help="weight file (default results/weights/<airframe>_<formulation>.npz)")
    p.add_argument("--history", default=None,
                   help="loss-history JSON (default beside --out; a PNG is written too)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_train)
