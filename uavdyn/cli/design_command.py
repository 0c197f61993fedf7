"""The ``design-input`` command: the flight-test input to fly, and the standard errors it
would give."""

from __future__ import annotations

import argparse
from pathlib import Path

from uavdyn.airframes import load_airframe
from uavdyn.cli.common import (
    FRACTION,
    MAX_SORTIE_ROWS,
    SEED,
    CliError,
    add_airframe,
    add_force,
    check_sortie_rows,
    count,
    folder_to_write,
    name_list,
    number,
    positive,
    seconds,
)
from uavdyn.excitation import SIGNALS, design_input, emulate_design, predict_errors
from uavdyn.excitation.design import MOMENT_PARAMS, MULTIROTOR_AMPLITUDE
from uavdyn.excitation.outputs import write_design
from uavdyn.excitation.predict import calm_screen, write_emulated
from uavdyn.linear import TrimError, trim
from uavdyn.outputs import output_folder

MAX_SORTIES = 500
MAX_DURATION_S = 600.0


def cmd_design_input(args: argparse.Namespace) -> int:
    """Design the input, fly it on the emulator, predict the standard errors, write it all."""
    check_sortie_rows(args.duration, args.rate, "--rate")  # the emulator's memory
    airframe = load_airframe(args.airframe)
    if airframe.kind != "fixed_wing" and args.alpha_deg is not None:
        raise CliError(f"--alpha-deg sizes a fixed wing's elevator input; --airframe "
                       f"{args.airframe} is a {airframe.kind} (its pitch input is "
                       f"{MULTIROTOR_AMPLITUDE:g}, or give --amplitude)")
    names = args.params or list(MOMENT_PARAMS[airframe.kind])
    unknown = [n for n in names if n not in airframe.param_names]
    if unknown:
        raise CliError(f"--params {', '.join(unknown)}: not in the {airframe.kind} model of "
                       f"--airframe {args.airframe}")
    if args.airspeed is not None:
        try:
            trim(airframe, args.airspeed)
        except TrimError as exc:
            raise CliError(f"--airspeed {args.airspeed:g} m/s: --airframe {args.airframe} has "
                           f"no trim there ({exc})") from None
    design = design_input(airframe, args.signal, args.duration, args.rate, args.airspeed,
                          3.0 if args.alpha_deg is None else args.alpha_deg, args.amplitude,
                          args.mode_hz)
    flights = emulate_design(design, airframe, args.sorties, args.seed,
                             args.turbulent_fraction)
    predicted = predict_errors(airframe, flights, names, max_windows=None)
    refused = calm_screen(flights, names)
    out = Path(args.out)
    with output_folder(out, "design-input", args.force) as tmp:
        written = write_design(tmp, design, predicted, args.sorties, refused)
        if args.emulate:
            write_emulated(flights, design, tmp / "emulated", {
                "sorties": args.sorties, "seed": args.seed,
                "turbulent_fraction": args.turbulent_fraction, "signal": args.signal,
                "duration_s": args.duration, "sample_rate_hz": args.rate})
            written.append("emulated/")
    m = design.mode
    print(f"{design.signal} on {design.controls[design.channel]} for '{design.airframe}' at "
          f"{design.speed:g} m/s, timed from the {m.name} ({m.natural_frequency:.4g} rad/s, "
          f"damping {m.damping:.3g})")
    print(f"  {design.rule}")
    print(f"  amplitude {design.amplitude:.4g} ({design.amplitude_why})")
    print(f"  predicted standard errors, {args.sorties} x {args.duration:g} s "
          "(Cramer-Rao: a lower bound; turbulence makes the real corrected ones larger):")
    for n, v, s, r in zip(predicted.names, predicted.nominal, predicted.std_error,
                          predicted.ratio()):
        tail = f"|value|/SE {r:.3g}" if v else f"file value 0: resolved if |value| > {3 * s:.3g}"
        print(f"    {n:>14} = {v:+.4g}  SE >= {s:.3g}  ({tail})")
    if predicted.collinear_groups:
        print("  collinear on this flight (Belsley): "
              + "; ".join(", ".join(g) for g in predicted.collinear_groups))
    for line in refused:
        print(f"  warning: on the calm sorties identify would refuse {line}")
    print(f"wrote {', '.join(written)} in {out}")
    return 0


def add_design_input(sub) -> None:
    """Register ``design-input``."""
    p = sub.add_parser("design-input", help="plan the flight-test input to fly (3-2-1-1, "
                       "doublets or a multisine timed from the airframe's pitch mode, inside "
                       "its [limits]) and predict the standard errors it would give")
    add_force(p)
    add_airframe(p, default=None)
    p.add_argument("--out", required=True, type=folder_to_write,
                   help="output folder: schedule.csv, design.json, design.md, "
                        "ardupilot_sysid.param (multirotor), emulated/ (--emulate)")
    p.add_argument("--signal", choices=SIGNALS, default="mixed",
                   help="mixed (default: 3-2-1-1 and doublets alternating), 3211, doublet or "
                        "multisine (Schroeder phases)")
    p.add_argument("--params", type=name_list("parameter"), default=None,
                   help="parameters whose standard errors to predict (default: the pitch "
                        "moment terms, C_m_alpha,C_m_q,C_m_delta_e,C_m_0 or pitch_mix,"
                        "pitch_damping,M_u,M_0)")
    p.add_argument("--duration", type=seconds(MAX_DURATION_S, "duration"), default=20.0,
                   help=f"one sortie's length in s (default 20; at most {MAX_SORTIE_ROWS} log "
                        "rows at --rate)")
    p.add_argument("--sorties", type=count(MAX_SORTIES, "sorties"), default=20,
                   help="sorties flown for the prediction (default 20)")
    p.add_argument("--rate", type=number(10.0, 1000.0, name="rate", unit="Hz"), default=100.0,
                   help="log rate of the schedule in Hz, 10..1000 (default 100)")
    p.add_argument("--airspeed", type=number(0.0, 100.0, name="airspeed", unit="m/s"),
                   default=None, help="trim speed in m/s (default the airframe's nominal)")
    p.add_argument("--alpha-deg", type=number(0.1, 10.0, name="alpha", unit="deg"),
                   default=None, help="fixed wing: static angle-of-attack change the "
                   "elevator input aims at, 0.1..10 deg (default 3)")
    p.add_argument("--amplitude", type=positive(name="amplitude"), default=None,
                   help="input amplitude in the control's units instead of the rule "
                        "(refused beyond the [limits] travel about trim)")
    p.add_argument("--mode-hz", type=positive(100.0, "frequency", "Hz"), default=None,
                   help="time the inputs from this frequency instead of the model's mode "
                        "(e.g. your own autopilot's closed-loop pitch mode)")
    p.add_argument("--emulate", action="store_true",
                   help="also write the emulated flights as a dataset (emulated/) to try "
                        "`uavdyn identify` on")
    p.add_argument("--turbulent-fraction", type=FRACTION, default=0.5,
                   help="share of emulated sorties in turbulence and wind (default 0.5)")
    p.add_argument("--seed", type=SEED, default=0, help="random seed >= 0 (default 0)")
    p.set_defaults(func=cmd_design_input)
