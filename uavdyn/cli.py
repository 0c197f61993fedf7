"""The ``uavdyn`` command line: one subcommand per step of the pipeline.

Errors are reported as one readable line on stderr with a non-zero exit code; ``--help`` works
on every command. Every ``--airframe`` takes a preset name or the path of a parameter file.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from uavdyn.airframes import AirframeError, list_presets, load_airframe


class CliError(Exception):
    """A user-facing error: printed as one line, exit code 2."""


def _add_airframe(parser: argparse.ArgumentParser, default: str | None = "aerosonde") -> None:
    parser.add_argument("--airframe", default=default, required=default is None,
                        help=f"preset name ({', '.join(list_presets())}) or path of a "
                             "TOML/JSON parameter file")


def _add_trim_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--airspeed", type=float, default=None,
                        help="trim airspeed in m/s (default: the airframe's nominal; 0 = hover)")
    parser.add_argument("--gamma-deg", type=float, default=0.0,
                        help="flight-path angle in degrees, climb positive (default 0)")


def _trim(args):
    from uavdyn.trim import trim

    airframe = load_airframe(args.airframe)
    return airframe, trim(airframe, args.airspeed, math.radians(args.gamma_deg))


def cmd_airframes(args: argparse.Namespace) -> int:
    """List the presets and their key numbers."""
    from uavdyn.trim import trim

    rows = ["| name | kind | mass (kg) | Jy (kg m^2) | nominal airspeed (m/s) | trim controls |",
            "|---|---|---|---|---|---|"]
    for name in list_presets():
        af = load_airframe(name)
        tp = trim(af)
        ctrl = ", ".join(f"{n}={v:.4f}" for n, v in zip(
            ("elevator", "throttle") if af.kind == "fixed_wing" else ("collective", "pitch_cmd"),
            tp.u))
        rows.append(f"| {af.name} | {af.kind} | {af.params.mass:g} | {af.params.Jy:g} | "
                    f"{af.nominal_airspeed:g} | {ctrl} |")
    print("\n".join(rows))
    return 0


def cmd_trim(args: argparse.Namespace) -> int:
    """Trim and print the trim point as JSON."""
    _, point = _trim(args)
    print(json.dumps(point.as_dict(), indent=2))
    return 0


def cmd_modes(args: argparse.Namespace) -> int:
    """Trim, linearise and print the modes as a Markdown table (or JSON)."""
    from uavdyn.stability import linearise, mode_table, modes

    airframe, point = _trim(args)
    A, B = linearise(airframe, point)
    found = modes(A, airframe.kind, B)
    if args.json:
        print(json.dumps({"trim": point.as_dict(), "A": A.tolist(), "B": B.tolist(),
                          "modes": [m.as_dict() for m in found]}, indent=2))
    else:
        print(f"{airframe.name} trimmed at {point.airspeed:g} m/s, gamma "
              f"{math.degrees(point.gamma):g} deg (residual {point.residual:.1e})\n")
        print(mode_table(found))
    return 0


def cmd_simulate(args: argparse.Namespace) -> int:
    """Simulate an input profile from trim with the compiled RK4 and write an interchange CSV."""
    from uavdyn.codegen import compile_function
    from uavdyn.flightdata import Sortie, write_csv
    from uavdyn.inputs import control_sequence
    from uavdyn.integrators import rk4_step, rollout
    from uavdyn.model import build_model

    if not (args.dt > 0 and math.isfinite(args.dt)):
        raise CliError(f"--dt must be a positive number of seconds, got {args.dt}")
    if not (args.duration > 0 and math.isfinite(args.duration)):
        raise CliError(f"--duration must be a positive number of seconds, got {args.duration}")
    n = int(round(args.duration / args.dt))
    if n < 1:
        raise CliError("--duration must be at least one step long")
    airframe, point = _trim(args)
    amplitude = args.amplitude
    if amplitude is None:
        amplitude = math.radians(2.0) if airframe.kind == "fixed_wing" else 0.05
    t = np.arange(n + 1) * args.dt
    controls = control_sequence(args.input, t, point.u, amplitude, channel=args.channel)
    model = build_model(airframe)
    sim = compile_function(rollout(rk4_step(model.f), n))
    traj = np.array(sim(point.x, controls[:-1].T, airframe.p, args.dt)).T
    states = np.vstack([point.x, traj])
    if not np.all(np.isfinite(states)):
        raise CliError("the simulation diverged (non-finite state); reduce --dt or --amplitude")
    sortie = Sortie(name=Path(args.out).stem, kind=airframe.kind, time=t, states=states,
                    controls=controls, mission=args.input)
    path = write_csv(sortie, args.out)
    theta = states[:, 3]
    print(f"wrote {path} ({n + 1} rows, dt {args.dt:g} s); pitch range "
          f"{math.degrees(theta.min()):.2f} .. {math.degrees(theta.max()):.2f} deg")
    return 0


def cmd_export_c(args: argparse.Namespace) -> int:
    """Write a dependency-free C bundle (step or rollout, double or float) and say how to build."""
    from uavdyn.deploy import BundleSpec, export_bundle
    from uavdyn.integrators import rk4_step
    from uavdyn.model import build_model

    if not (args.dt > 0 and math.isfinite(args.dt)):
        raise CliError(f"--dt must be a positive number of seconds, got {args.dt}")
    if args.rollout < 0:
        raise CliError(f"--rollout must be >= 0 steps, got {args.rollout}")
    airframe, point = _trim(args)
    model = build_model(airframe)
    step = rk4_step(model.f)
    amplitude, channel = ((math.radians(2.0), 0) if airframe.kind == "fixed_wing"
                          else (0.05, 1))
    spec = BundleSpec(args.name, model.state_names, model.control_names, model.param_names,
                      airframe.p, point.x, point.u, args.dt, amplitude, doublet_channel=channel,
                      real=args.real, rollout_steps=args.rollout)
    out = export_bundle(step, spec, args.out)
    what = f"rollout of {args.rollout} steps" if args.rollout else "one step"
    print(f"wrote {out}/ ({args.name}.h, {args.name}.c, {args.name}_generated.c, main.c, "
          f"Makefile; {args.real}, {what})")
    print(f"build and run: make -C {out} && {out}/example > trajectory.csv")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="uavdyn", description="Nonlinear longitudinal UAV flight dynamics with a "
        "learned-residual, compiled RK4 integrator.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    p = sub.add_parser("airframes", help="list the preset airframes and their key numbers")
    p.set_defaults(func=cmd_airframes)

    p = sub.add_parser("trim", help="trim an airframe (level/climb at an airspeed, or hover)")
    _add_airframe(p)
    _add_trim_args(p)
    p.set_defaults(func=cmd_trim)

    p = sub.add_parser("modes", help="trim, linearise and list the modes (short period, ...)")
    _add_airframe(p)
    _add_trim_args(p)
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=cmd_modes)

    p = sub.add_parser("simulate", help="simulate an input profile from trim, write a CSV")
    _add_airframe(p)
    _add_trim_args(p)
    p.add_argument("--input", default="doublet", choices=["step", "doublet", "3211", "chirp",
                                                          "none"], help="input profile")
    p.add_argument("--amplitude", type=float, default=None,
                   help="profile amplitude (rad for elevator, 0..1 units otherwise; default "
                        "2 deg elevator or 0.05)")
    p.add_argument("--channel", type=int, default=0, choices=[0, 1],
                   help="control channel (0: elevator/collective, 1: throttle/pitch_cmd)")
    p.add_argument("--dt", type=float, default=0.01, help="RK4 step in s (default 0.01)")
    p.add_argument("--duration", type=float, default=10.0, help="seconds (default 10)")
    p.add_argument("--out", default="results/simulation.csv", help="output CSV path")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("export-c", help="write a dependency-free C bundle of the step")
    _add_airframe(p)
    _add_trim_args(p)
    p.add_argument("--real", choices=["double", "float"], default="double",
                   help="floating-point type of the generated code (default double)")
    p.add_argument("--rollout", type=int, default=0,
                   help="export a rollout of N steps instead of one step (default 0: one step)")
    p.add_argument("--dt", type=float, default=0.005, help="default step in s (default 0.005)")
    p.add_argument("--name", default="uav_step", help="C name of the exported function")
    p.add_argument("--out", default="results/c_bundle", help="output folder")
    p.set_defaults(func=cmd_export_c)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from uavdyn.trim import TrimError

    try:
        return int(args.func(args) or 0)
    except (CliError, AirframeError, TrimError, FileNotFoundError, ValueError) as exc:
        print(f"uavdyn {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
