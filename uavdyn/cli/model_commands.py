"""The model commands: ``airframes``, ``trim``, ``modes``, ``simulate`` and ``export-c``."""

from __future__ import annotations

import argparse
import json
import math
import sys
import warnings
from pathlib import Path

import numpy as np

from uavdyn.airframes import list_presets, load_airframe
from uavdyn.cli.common import (
    STEP,
    CliError,
    add_airframe,
    add_force,
    add_trim_args,
    c_identifier,
    correction,
    existing_file,
    file_to_write,
    folder_to_write,
    number,
    refuse_unused,
    seconds,
    trim_from_args,
)
from uavdyn.deploy import export_bundle, model_bundle_spec
from uavdyn.flightdata import Sortie, write_csv
from uavdyn.integrate import free_run, physics_step
from uavdyn.integrate.inputs import control_sequence
from uavdyn.learned import hybrid_step, load_weights
from uavdyn.learned.stability import envelope_check
from uavdyn.linear import (
    discrete_map_modes,
    linear_state_names,
    linearise,
    mode_table,
    modes,
    point_params,
    trim,
)
from uavdyn.linear.stiffness import step_stiffness
from uavdyn.model import build_model
from uavdyn.outputs import atomic_file, check_output_files, single_outputs


def cmd_airframes(args: argparse.Namespace) -> int:
    """List the presets and their key numbers."""

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
    _, point = trim_from_args(args)
    print(json.dumps(point.as_dict(), indent=2))
    return 0


def cmd_modes(args: argparse.Namespace) -> int:
    """Trim, linearise and print the modes as a Markdown table (or JSON)."""

    refuse_unused(args, ("--weights", "--dt"), args.hybrid, "with --hybrid")
    if args.hybrid:
        return _hybrid_modes(args)
    airframe, point = trim_from_args(args)
    A, B = linearise(airframe, point)
    names = linear_state_names(airframe)
    found = modes(A, airframe.kind, B, names)
    if args.json:
        print(json.dumps({"trim": point.as_dict(), "state_names": list(names),
                          "A": A.tolist(), "B": B.tolist(),
                          "modes": [m.as_dict() for m in found]}, indent=2))
    else:
        print(f"{airframe.name} trimmed at {point.airspeed:g} m/s, gamma "
              f"{math.degrees(point.gamma):g} deg (residual {point.residual:.1e})\n")
        print(mode_table(found))
    return 0


def _hybrid_modes(args: argparse.Namespace) -> int:
    """Modes of the hybrid discrete map beside the physics model and exp(A dt) at the trim
    point, then the stability rule at trims over the weights' training envelope."""

    weights, airframe = correction(args, load_airframe(args.airframe))
    net = load_weights(weights, airframe)
    dt = args.dt if args.dt is not None else net.dt
    model = hybrid_step(net, airframe, compile=False)
    if model.takes_time:
        raise CliError(f"{weights.name}: this correction takes time t as an input, so its map "
                       "changes along the flight and has no modes at a trim point; use weights "
                       "of the 'improved' formulation")
    model.check_use(dt)
    point = trim(airframe, args.airspeed, math.radians(args.gamma_deg))
    comp = discrete_map_modes(model, point, dt)
    sweep = envelope_check(net, airframe, dt, model=model) if net.envelope is not None else None
    if args.json:
        print(json.dumps({
            "trim": point.as_dict(), "dt": dt, "weights": str(weights),
            "airframe": airframe.name,
            "map_eigenvalues": [[z.real, z.imag] for z in comp.map_eigenvalues],
            "exp_A_dt_eigenvalues": [[z.real, z.imag] for z in comp.exact_eigenvalues],
            "hybrid_modes": [m.as_dict() for m in comp.map_modes],
            "physics_modes": [m.as_dict() for m in comp.physics_modes],
            "unstable": comp.unstable, "made_unstable": comp.made_unstable,
            "envelope_sweep": sweep.to_dict() if sweep is not None else None}, indent=2))
        return 0
    print(f"{airframe.name} trimmed at {point.airspeed:g} m/s; hybrid map at dt {dt:g} s "
          f"({weights.name})\n")
    print("Physics model:\n\n" + mode_table(comp.physics_modes))
    print("\nHybrid map (continuous equivalents log(lambda)/dt):\n\n"
          + mode_table(comp.map_modes))
    print("\nHybrid map eigenvalues beside exp(A dt):\n\n" + comp.table())
    if comp.made_unstable:
        print(f"\nWARNING: the correction made map eigenvalue(s) {comp.made_unstable} unstable")
    if sweep is not None:
        print(f"\nStability rule over the training envelope and out to where the gate reaches 0 "
              f"(largest growth rate of the body block, margin {sweep.margin:g}):\n\n"
              f"{sweep.table()}\n")
        print(sweep.describe() if sweep.ok else f"WARNING: {sweep.describe()}")
    return 0


MAX_SIMULATION_ROWS = 2_000_000  # ~100 MB of CSV; beyond that, simulate in pieces
# steps of an exported rollout: generating its code peaked at 0.3 GB for 50 000 steps, 1.9 GB
# for 100 000 and 18 GB for 1 000 000 (measured, CasADi 3.6)
MAX_ROLLOUT = 50_000
MAX_MPC_HORIZON = 200
MODEL_DT, MPC_DT = 0.005, 0.05  # default step of a model bundle, interval of the MPC
DEFAULT_NAME = "uav_step"


def cmd_simulate(args: argparse.Namespace) -> int:
    """Simulate an input profile from trim with the compiled RK4 and write an interchange CSV."""

    check_output_files(args.out, force=args.force)  # before any work
    n = int(round(args.duration / args.dt))
    if n < 1:
        raise CliError(f"--duration {args.duration:g} s must be at least one --dt step "
                       f"({args.dt:g} s) long")
    if n + 1 > MAX_SIMULATION_ROWS:
        raise CliError(f"--duration {args.duration:g} s at --dt {args.dt:g} s is {n + 1} rows, "
                       f"more than the {MAX_SIMULATION_ROWS} this command writes at once "
                       "(memory); simulate in pieces")
    refuse_unused(args, ("--amplitude",), args.input != "none", "with an --input profile "
                  "other than none")
    airframe, point = trim_from_args(args)
    amplitude = args.amplitude
    if amplitude is None:
        amplitude = math.radians(2.0) if airframe.kind == "fixed_wing" else 0.05
    t = np.arange(n + 1) * args.dt
    controls = control_sequence(args.input, t, point.u, amplitude, channel=args.channel)
    name = build_model(airframe).control_names[args.channel]
    lo, hi = airframe.control_bounds()[args.channel]  # the airframe's [limits] if it sets them
    used = controls[:, args.channel]
    if used.min() < lo - 1e-12 or used.max() > hi + 1e-12:
        unit = " rad (radians, not degrees)" if name == "elevator" else ""
        whose = (f"limits.{name} of airframe '{airframe.name}'; " if name in airframe.limits
                 else "")
        raise CliError(f"--amplitude {amplitude:g} takes {name} to {used.min():.4g}..."
                       f"{used.max():.4g}{unit}, outside its limits [{lo:g}, {hi:g}] "
                       f"({whose}trim {point.u[args.channel]:.4g})")
    # the airframe's step (actuator lags and delays as augmented states, at rest on the trim
    # command); compiled; raises DivergenceError with its time; the body states are written
    model = physics_step(airframe)
    p = point_params(airframe, point)
    states = free_run(model, model.initial_state(point.x, point.u, p, args.dt), controls[:-1],
                      p, args.dt)[:, :4]
    sortie = Sortie(name=Path(args.out).stem, kind=airframe.kind, time=t, states=states,
                    controls=controls, mission=args.input)
    with single_outputs(args.out, command="simulate", force=args.force), \
            atomic_file(args.out, create_parents=True) as tmp:
        write_csv(sortie, tmp)
    theta = states[:, 3]
    print(f"wrote {args.out} ({n + 1} rows, dt {args.dt:g} s); pitch range "
          f"{math.degrees(theta.min()):.2f} .. {math.degrees(theta.max()):.2f} deg")
    return 0


def cmd_export_c(args: argparse.Namespace) -> int:
    """Write a dependency-free C bundle (step or rollout, double or float; or with ``--mpc``
    the real-time-iteration controller) and say how to build."""

    refuse_unused(args, ("--weights",), args.model != "rk4", "with --model hybrid")
    refuse_unused(args, ("--horizon", "--condensing"), args.mpc, "with --mpc")
    if args.mpc:
        return _export_mpc(args)
    airframe = load_airframe(args.airframe)
    if args.lateral:  # turning flight: the step takes phi, p, r, beta after the controls
        airframe = airframe.with_lateral()
    chosen = args.model or ("hybrid" if args.weights or args.airframe in list_presets()
                            else "rk4")
    if args.model is None and chosen == "rk4":
        print(f"(no correction for the airframe file {args.airframe}: exporting its physics "
              "step; --weights FILE adds one)", file=sys.stderr)
    if chosen == "hybrid":  # the correction runs on the airframe it was trained on
        weights, airframe = correction(args, airframe)
        model = hybrid_step(load_weights(weights, airframe), airframe, compile=False)
    else:
        model = physics_step(airframe)
    point = trim(airframe, args.airspeed, math.radians(args.gamma_deg))
    stiff = step_stiffness(airframe, args.dt or MODEL_DT, point)
    if stiff.too_stiff:  # the bundle would be written, and would diverge when run
        warnings.warn(f"the exported step diverges: {stiff.describe()}; give --dt "
                      f"{stiff.max_stable_dt:.3g} or less, or check the airframe's parameters",
                      stacklevel=1)
    spec = model_bundle_spec(args.name, model, point, args.dt or MODEL_DT, real=args.real,
                             rollout_steps=args.rollout)
    out = export_bundle(model, spec, args.out, force=args.force)
    what = f"rollout of {args.rollout} steps" if args.rollout else "one step"
    print(f"wrote {out}/ ({args.name}.h, {args.name}.c, {args.name}_generated.c, main.c, "
          f"Makefile; {args.real}, {what})")
    print(f"build and run: make -C {out} && {out}/example > trajectory.csv")
    return 0


def _export_mpc(args: argparse.Namespace) -> int:
    """``export-c --mpc``: the RTI controller of ``uavdyn mpc --rti`` (same prediction models)
    with the pitch step against the airframe's physics step as its example."""
    from uavdyn.deploy.mpc_bundle import example_closed_loop, export_mpc_bundle
    from uavdyn.mpc import MPCConfig, TrackingProblem
    from uavdyn.mpc.study import prediction_models

    refuse_unused(args, ("--lateral", "--airspeed"), False, "without --mpc")
    if args.rollout or args.name != DEFAULT_NAME or args.gamma_deg:
        raise CliError("--rollout, --name and --gamma-deg apply only without --mpc (the "
                       "controller's API is mpc_init/mpc_step; its example flies the pitch "
                       "step from level trim)")
    which = "physics" if args.model == "rk4" else "hybrid"
    setup = prediction_models(args.airframe, args.weights, mode="rti", models=(which,))
    if which not in setup.models:
        raise CliError(f"no hybrid prediction for {args.airframe}: "
                       f"{setup.missing.get(which, 'no correction')}; --model rk4 exports the "
                       "physics-only controller")
    chosen = setup.models[which]
    config = MPCConfig(horizon=args.horizon or 20, dt=args.dt or MPC_DT, mode="rti")
    problem = TrackingProblem(chosen.model, chosen.trim.u, config,
                              speed_trim=max(chosen.trim.airspeed, 1.0))
    example = example_closed_loop(setup.plant_airframe, config.dt)
    out = export_mpc_bundle(problem, example, args.out, real=args.real, force=args.force,
                            condensing=args.condensing or "mx")
    print(f"wrote {out}/ (mpc_rti.h, mpc_rti.c, mpc_generated.c, qp_dense.c, main.c, Makefile; "
          f"{args.real}; {chosen.description}, horizon {config.horizon} x {config.dt:g} s)")
    print(f"build and run: make -C {out} && {out}/example > closed_loop.csv "
          f"(solve times: make -C {out} bench && {out}/bench)")
    return 0


def add_airframes(sub) -> None:
    """Register ``airframes``."""
    p = sub.add_parser("airframes", help="list the preset airframes and their key numbers")
    p.set_defaults(func=cmd_airframes)


def add_trim(sub) -> None:
    """Register ``trim``."""
    p = sub.add_parser("trim", help="trim an airframe (level/climb at an airspeed, or hover)")
    add_airframe(p)
    add_trim_args(p)
    p.set_defaults(func=cmd_trim)


def add_modes(sub) -> None:
    """Register ``modes``."""
    p = sub.add_parser("modes", help="trim, linearise and list the modes (short period, ...)")
    add_airframe(p)
    add_trim_args(p)
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--hybrid", action="store_true",
                   help="also linearise the hybrid discrete map (eigenvalues, log(lambda)/dt, "
                        "exp(A dt))")
    p.add_argument("--weights", default=None, type=existing_file("weight file"),
                   help="weight file for --hybrid (default: the shipped safe correction, on "
                        "the identified airframe it was trained on)")
    p.add_argument("--dt", type=STEP, default=None,
                   help="map step in s for --hybrid, 1e-6..1 (default: the step the weights "
                        "were trained at)")
    p.set_defaults(func=cmd_modes)


def add_simulate(sub) -> None:
    """Register ``simulate``."""
    p = sub.add_parser("simulate", help="simulate an input profile from trim, write a CSV")
    add_force(p, single=True)
    add_airframe(p)
    add_trim_args(p)
    p.add_argument("--input", default="doublet", choices=["step", "doublet", "3211", "chirp",
                                                          "none"], help="input profile")
    p.add_argument("--amplitude", type=number(name="amplitude"), default=None,
                   help="profile amplitude (rad for elevator, 0..1 units otherwise; default "
                        "2 deg elevator or 0.05); the profile must stay inside the control's "
                        "limits")
    p.add_argument("--channel", type=int, default=0, choices=[0, 1],
                   help="control channel (0: elevator/collective, 1: throttle/pitch_cmd)")
    p.add_argument("--dt", type=STEP, default=0.01, help="RK4 step in s, 1e-6..1 (default "
                   "0.01)")
    p.add_argument("--duration", type=seconds(name="duration"), default=10.0,
                   help=f"seconds (default 10; at most {MAX_SIMULATION_ROWS} rows at --dt)")
    p.add_argument("--out", default="results/simulation.csv", type=file_to_write,
                   help="output CSV path")
    p.set_defaults(func=cmd_simulate)


def add_export_c(sub) -> None:
    """Register ``export-c``."""
    p = sub.add_parser("export-c", help="write a dependency-free C bundle of the step")
    add_force(p)
    add_airframe(p)
    add_trim_args(p)
    p.add_argument("--model", choices=["hybrid", "rk4"], default=None,
                   help="hybrid step (shipped or --weights) or the airframe's physics RK4 "
                        "(default: hybrid for a preset or with --weights, else physics)")
    p.add_argument("--weights", default=None, type=existing_file("weight file"),
                   help="weight file for --model hybrid")
    p.add_argument("--real", choices=["double", "float"], default="double",
                   help="floating-point type of the generated code (default double)")
    p.add_argument("--rollout", type=number(0, MAX_ROLLOUT, integer=True, name="steps"),
                   default=0, help=f"export a rollout of N steps instead of one step, "
                   f"0..{MAX_ROLLOUT} (default 0: one step)")
    p.add_argument("--dt", type=STEP, default=None, help="default step in s, 1e-6..1 "
                   f"(default {MODEL_DT}; with --mpc the MPC interval, default {MPC_DT})")
    p.add_argument("--mpc", action="store_true",
                   help="export the real-time-iteration tracking MPC (the controller of "
                        "'uavdyn mpc --rti') instead of the step: C controller, QP solver and "
                        "an example flying the pitch step against the physics step")
    p.add_argument("--horizon", type=number(1, MAX_MPC_HORIZON, integer=True, name="intervals"),
                   default=None, help=f"--mpc prediction intervals, 1..{MAX_MPC_HORIZON} "
                   "(default 20)")
    p.add_argument("--condensing", choices=["mx", "sx"], default=None,
                   help="--mpc condensing code: mx (default; compact, builds in seconds) or sx "
                        "(scalar code: about 4x faster condensing at horizon 20, megabytes of C "
                        "that take tens of seconds to build; grows with the horizon squared)")
    p.add_argument("--lateral", action="store_true",
                   help="the step with the turning-flight inputs phi, p, r, beta after the "
                        "controls (needs Jx, Jz, Jxz in the airframe file; the weights of a "
                        "correction trained on turning-flight data need it)")
    p.add_argument("--name", default=DEFAULT_NAME, type=c_identifier,
                   help="C name of the exported function (a C identifier)")
    p.add_argument("--out", default="results/c_bundle", type=folder_to_write,
                   help="output folder")
    p.set_defaults(func=cmd_export_c)
