"""The ``uavdyn`` command line: one subcommand per step of the pipeline.

Errors are reported as one readable line on stderr with a non-zero exit code; ``--help`` works
on every command. Every ``--airframe`` takes a preset name or the path of a parameter file.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np

from uavdyn import __version__
from uavdyn.airframes import AirframeError, list_presets, load_airframe
from uavdyn.cli.montecarlo import add_parser as add_montecarlo_parser
from uavdyn.cli.mpc import add_parser as add_mpc_parser
from uavdyn.deploy import export_bundle, model_bundle_spec
from uavdyn.emulation.datagen import Recipe, generate_dataset
from uavdyn.emulation.fingerprint import (
    DEFAULT_TOLERANCE,
    compare_fingerprints,
    dataset_fingerprint,
    read_fingerprint,
    shipped_reference,
    write_fingerprint,
)
from uavdyn.experiments.reproduce import (
    ReproduceConfig,
    _json,
    evaluate_dataset,
    evaluation_markdown,
    run,
)
from uavdyn.flightdata import (
    Sortie,
    import_alfa,
    import_ulog,
    load_dataset,
    write_csv,
    write_manifest,
)
from uavdyn.identify import identify, write_outputs
from uavdyn.integrate import (
    CompileError,
    DivergenceError,
    free_run,
    physics_step,
)
from uavdyn.integrate.inputs import control_sequence
from uavdyn.learned import WeightFileError, hybrid_step, load_weights, shipped_correction
from uavdyn.learned.stability import envelope_check
from uavdyn.linear import (
    TrimError,
    discrete_map_modes,
    linear_state_names,
    linearise,
    mode_table,
    modes,
    point_params,
    trim,
)
from uavdyn.model import build_model
from uavdyn.outputs import (
    atomic_file,
    check_output_file,
    check_output_folder,
    output_folder,
    write_text_atomic,
)


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

    airframe = load_airframe(args.airframe)
    return airframe, trim(airframe, args.airspeed, math.radians(args.gamma_deg))


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
    _, point = _trim(args)
    print(json.dumps(point.as_dict(), indent=2))
    return 0


def cmd_modes(args: argparse.Namespace) -> int:
    """Trim, linearise and print the modes as a Markdown table (or JSON)."""

    if args.hybrid:
        return _hybrid_modes(args)
    airframe, point = _trim(args)
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


def _correction(args: argparse.Namespace, airframe):
    """The weights of a ``--hybrid``/``--model hybrid`` command and the airframe they run on:
    ``--weights`` on ``--airframe``, or for a preset the shipped safe correction on the
    identified airframe it was trained on."""
    if args.weights:
        weights = Path(args.weights)
        if not weights.is_file():
            raise CliError(f"no weight file {weights}; give --weights FILE")
        return weights, airframe
    if args.airframe not in list_presets():
        raise CliError(f"no shipped correction for the airframe file {args.airframe}; give "
                       "--weights FILE (trained on this airframe with uavdyn train)")
    try:
        weights, identified = shipped_correction(airframe.name)
    except WeightFileError as exc:
        raise CliError(str(exc)) from None
    print(f"(shipped correction {weights.name} on {identified.name}, the identified airframe "
          "it was trained on)", file=sys.stderr)
    return weights, identified


def _hybrid_modes(args: argparse.Namespace) -> int:
    """Modes of the hybrid discrete map beside the physics model and exp(A dt) at the trim
    point, then the stability rule at trims over the weights' training envelope."""

    weights, airframe = _correction(args, load_airframe(args.airframe))
    net = load_weights(weights, airframe)
    dt = args.dt if args.dt is not None else net.dt
    if not (dt > 0 and math.isfinite(dt)):
        raise CliError(f"--dt must be a positive number of seconds, got {dt}")
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
        print(f"\nStability rule over the training envelope (largest growth rate of the body "
              f"block, margin {sweep.margin:g}):\n\n{sweep.table()}\n")
        print(sweep.describe() if sweep.ok else f"WARNING: {sweep.describe()}")
    return 0


MAX_SIMULATION_ROWS = 2_000_000  # ~100 MB of CSV; beyond that, simulate in pieces


def cmd_simulate(args: argparse.Namespace) -> int:
    """Simulate an input profile from trim with the compiled RK4 and write an interchange CSV."""

    if not (args.dt > 0 and math.isfinite(args.dt)):
        raise CliError(f"--dt must be a positive number of seconds, got {args.dt}")
    if not (args.duration > 0 and math.isfinite(args.duration)):
        raise CliError(f"--duration must be a positive number of seconds, got {args.duration}")
    check_output_file(args.out)
    n = int(round(args.duration / args.dt))
    if n < 1:
        raise CliError("--duration must be at least one step long")
    if n + 1 > MAX_SIMULATION_ROWS:
        raise CliError(f"--duration {args.duration:g} s at --dt {args.dt:g} s is {n + 1} rows, "
                       f"more than the {MAX_SIMULATION_ROWS} this command writes at once")
    airframe, point = _trim(args)
    amplitude = args.amplitude
    if amplitude is None:
        amplitude = math.radians(2.0) if airframe.kind == "fixed_wing" else 0.05
    if not math.isfinite(amplitude):
        raise CliError(f"--amplitude must be a finite number, got {amplitude}")
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
    with atomic_file(args.out, create_parents=True) as tmp:
        write_csv(sortie, tmp)
    theta = states[:, 3]
    print(f"wrote {args.out} ({n + 1} rows, dt {args.dt:g} s); pitch range "
          f"{math.degrees(theta.min()):.2f} .. {math.degrees(theta.max()):.2f} deg")
    return 0


def cmd_export_c(args: argparse.Namespace) -> int:
    """Write a dependency-free C bundle (step or rollout, double or float) and say how to build."""

    if not (args.dt > 0 and math.isfinite(args.dt)):
        raise CliError(f"--dt must be a positive number of seconds, got {args.dt}")
    if args.rollout < 0:
        raise CliError(f"--rollout must be >= 0 steps, got {args.rollout}")
    airframe = load_airframe(args.airframe)
    if args.model == "hybrid":  # the correction runs on the airframe it was trained on
        weights, airframe = _correction(args, airframe)
        model = hybrid_step(load_weights(weights, airframe), airframe, compile=False)
    else:
        model = physics_step(airframe)
    point = trim(airframe, args.airspeed, math.radians(args.gamma_deg))
    spec = model_bundle_spec(args.name, model, point, args.dt, real=args.real,
                             rollout_steps=args.rollout)
    out = export_bundle(model, spec, args.out, force=args.force)
    what = f"rollout of {args.rollout} steps" if args.rollout else "one step"
    print(f"wrote {out}/ ({args.name}.h, {args.name}.c, {args.name}_generated.c, main.c, "
          f"Makefile; {args.real}, {what})")
    print(f"build and run: make -C {out} && {out}/example > trajectory.csv")
    return 0


def cmd_generate_data(args: argparse.Namespace) -> int:
    """Generate an emulated flight-data set (manifest.json + CSVs) from a recipe and options."""


    recipe = Recipe.from_json(args.recipe) if args.recipe else Recipe()
    overrides = {"airframe": args.airframe, "sorties": args.sorties, "seed": args.seed,
                 "duration_s": args.duration, "sample_rate_hz": args.rate,
                 "internal_dt_s": args.internal_dt, "turbulent_fraction": args.turbulent_fraction,
                 "noise_scale": args.noise_scale,
                 "missions": args.missions.split(",") if args.missions else None}
    values = asdict(recipe)
    values.update({k: v for k, v in overrides.items() if v is not None})
    recipe = Recipe(**values)
    if args.workers is not None and args.workers < 1:
        raise CliError(f"--workers must be >= 1, got {args.workers}")
    manifest = generate_dataset(recipe, args.out, workers=args.workers, force=args.force,
                                progress=not args.no_progress)
    print(f"wrote {manifest} ({recipe.sorties} sorties x {recipe.duration_s:g} s at "
          f"{recipe.sample_rate_hz:g} Hz, seed {recipe.seed})")
    if args.write_fingerprint or args.verify:
        found = dataset_fingerprint(args.out)
    if args.write_fingerprint:
        print(f"wrote {write_fingerprint(found, args.write_fingerprint)}")
    if args.verify:
        reference = (shipped_reference(Path(args.recipe).stem) if args.verify == "shipped"
                     and args.recipe else read_fingerprint(args.verify))
        comparison = compare_fingerprints(found, reference)
        message = comparison.describe(args.tolerance)
        if not comparison.matches(args.tolerance):
            raise CliError(f"dataset {args.out} differs from the reference: {message}")
        print(f"dataset matches the reference: {message}")
    return 0


def _training_module():
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
    module = _training_module()
    summary = module.run(args)
    print(json.dumps(summary, indent=2))
    return 0


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


def cmd_import_log(args: argparse.Namespace) -> int:
    """Import a PX4 ULog file or an ALFA folder into a one-sortie interchange dataset."""
    source = Path(args.log)
    fmt = args.format
    if fmt == "auto":
        fmt = "alfa" if source.is_dir() else "ulog"
    check_output_folder(args.out, "import-log", args.force)
    if fmt == "ulog":
        sortie = import_ulog(source, **({"rate_hz": args.rate} if args.rate else {}))
    else:
        sortie = import_alfa(source, **({"rate_hz": args.rate} if args.rate else {}))
    name = "".join(c if c.isalnum() or c in "_-" else "_" for c in sortie.name)[:64] or "log"
    with output_folder(args.out, "import-log", args.force) as tmp:
        write_csv(sortie, tmp / f"{name}.csv")
        write_manifest(tmp, airframe="", kind=sortie.kind,
                       sample_rate_hz=round(1.0 / float(np.median(np.diff(sortie.time))), 9),
                       source=f"uavdyn import-log ({fmt}) of {source.name}",
                       sorties=[{"file": f"{name}.csv", "mission": sortie.mission,
                                 "duration_s": sortie.duration}])
    print(f"wrote {args.out}/ ({sortie.kind}, {len(sortie.time)} rows, "
          f"{sortie.duration:.1f} s from {source.name})")
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    """The validation pipeline: dataset, weights, Tables 1-4, figures, report."""

    if args.cost_repeats < 1:
        raise CliError(f"--cost-repeats must be >= 1, got {args.cost_repeats}")
    config = ReproduceConfig(airframes=tuple(args.airframes), out=args.out, quick=args.quick,
                             retrain=args.retrain, cache=args.cache,
                             cost_repeats=args.cost_repeats, sorties=args.sorties,
                             duration_s=args.duration, force=args.force,
                             identify=not args.no_identify,
                             save_trajectories=args.save_trajectories)
    result = run(config)
    print(f"report: {Path(args.out) / 'report.md'} ({result['wall_s']:.0f} s, "
          f"{result['size_bytes'] / 1e6:.1f} MB written)")
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    """Table 1 and Table 4 for any dataset folder, as JSON and Markdown."""

    out = Path(args.out)
    md = out.with_suffix(".md")
    for path in (out, md):
        check_output_file(path)  # before the work, not after it
    airframe = load_airframe(args.airframe)
    for path in (out, md):
        if path.exists() and not args.force and not _own_json(out):
            raise CliError(f"{path} exists and is not an earlier 'uavdyn evaluate' result; "
                           "choose another --out or give --force")
    identified = load_airframe(args.identified) if args.identified else None
    result = evaluate_dataset(airframe, args.dataset, args.weights or [],
                              identified=identified, all_sorties=args.all_sorties)
    result["command"] = "evaluate"
    write_text_atomic(out, json.dumps(result, indent=2, default=_json) + "\n")
    write_text_atomic(md, evaluation_markdown(result))
    print(f"wrote {out} and {md}")
    return 0


def _add_force(p: argparse.ArgumentParser) -> None:
    p.add_argument("--force", action="store_true",
                   help="write into a non-empty output that is not an earlier result of this "
                        "command (replaces only this command's files)")


def _own_json(path: Path) -> bool:
    """Whether ``path`` is a JSON result of ``uavdyn evaluate`` (safe to replace)."""
    try:
        return json.loads(path.read_text()).get("command") == "evaluate"
    except (OSError, ValueError, AttributeError):
        return False


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="uavdyn", description="Nonlinear longitudinal UAV flight dynamics with a "
        "learned-residual, compiled RK4 integrator.")
    parser.add_argument("--version", action="version", version=f"uavdyn {__version__}")
    parser.add_argument("--debug", action="store_true",
                        help="show the Python traceback of an unexpected error")
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
    p.add_argument("--hybrid", action="store_true",
                   help="also linearise the hybrid discrete map (eigenvalues, log(lambda)/dt, "
                        "exp(A dt))")
    p.add_argument("--weights", default=None,
                   help="weight file for --hybrid (default: the shipped safe correction, on "
                        "the identified airframe it was trained on)")
    p.add_argument("--dt", type=float, default=None,
                   help="map step for --hybrid (default: the step the weights were trained at)")
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

    p = sub.add_parser("generate-data", help="generate an emulated flight-data set (SPEC 3 "
                       "format: manifest.json + one CSV per sortie)")
    _add_force(p)
    p.add_argument("--recipe", default=None,
                   help="JSON recipe (e.g. data/datagen_quadrotor.json); options given here "
                        "override it")
    p.add_argument("--airframe", default=None,
                   help=f"preset ({', '.join(list_presets())}, quadrotor, fixed_wing) or "
                        "parameter file (default quadrotor)")
    p.add_argument("--sorties", type=int, default=None, help="number of sorties (default 100)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    p.add_argument("--duration", type=float, default=None, help="seconds per sortie (60)")
    p.add_argument("--rate", type=float, default=None, help="log rate in Hz (default 100)")
    p.add_argument("--internal-dt", type=float, default=None,
                   help="emulator RK4 step in s (default 0.001)")
    p.add_argument("--missions", default=None,
                   help="comma-separated mission names (default: all for the airframe kind)")
    p.add_argument("--turbulent-fraction", type=float, default=None,
                   help="fraction of turbulent sorties (default 0.5)")
    p.add_argument("--noise-scale", type=float, default=None,
                   help="sensor-noise multiplier (default 1, 0 = noise-free logs)")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes (default: all cores)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--verify", default=None, metavar="FINGERPRINT",
                   help="compare the values with a reference fingerprint JSON (by tolerance, "
                        "not bytes)")
    p.add_argument("--tolerance", type=float, default=DEFAULT_TOLERANCE,
                   help="largest allowed absolute difference for --verify (default 1e-9)")
    p.add_argument("--write-fingerprint", default=None, metavar="FINGERPRINT",
                   help="write the dataset's value fingerprint (JSON)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_generate_data)

    p = sub.add_parser("export-c", help="write a dependency-free C bundle of the step")
    _add_force(p)
    _add_airframe(p)
    _add_trim_args(p)
    p.add_argument("--model", choices=["hybrid", "rk4"], default="hybrid",
                   help="hybrid step (default; shipped or --weights) or plain physics RK4")
    p.add_argument("--weights", default=None, help="weight file for --model hybrid")
    p.add_argument("--real", choices=["double", "float"], default="double",
                   help="floating-point type of the generated code (default double)")
    p.add_argument("--rollout", type=int, default=0,
                   help="export a rollout of N steps instead of one step (default 0: one step)")
    p.add_argument("--dt", type=float, default=0.005, help="default step in s (default 0.005)")
    p.add_argument("--name", default="uav_step", help="C name of the exported function")
    p.add_argument("--out", default="results/c_bundle", help="output folder")
    p.set_defaults(func=cmd_export_c)

    p = sub.add_parser("import-log", help="import a PX4 ULog file or an ALFA folder as a "
                       "one-sortie interchange dataset")
    _add_force(p)
    p.add_argument("log", help="the .ulg file or ALFA sequence folder")
    p.add_argument("--format", choices=["auto", "ulog", "alfa"], default="auto",
                   help="auto: a folder is ALFA, a file is ULog")
    p.add_argument("--rate", type=float, default=None, help="grid rate in Hz (default: the "
                   "attitude topic's rate for ULog, 10 Hz for ALFA)")
    p.add_argument("--out", required=True, help="output dataset folder")
    p.set_defaults(func=cmd_import_log)

    p = sub.add_parser("identify", help="fit named physical parameters to flight data "
                       "(output error); write the fitted airframe file and a report")
    _add_force(p)
    _add_airframe(p)
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

    p = sub.add_parser("reproduce", help="run the validation pipeline (Tables 1-4, figures, "
                       "report) on the shipped recipe and weights")
    _add_force(p)
    p.add_argument("--airframes", nargs="+", default=["quadrotor", "fixed_wing"],
                   choices=["quadrotor", "fixed_wing"], help="which airframes (default both)")
    p.add_argument("--out", default="results", help="output folder (default results/)")
    p.add_argument("--quick", action="store_true", help="tiny configuration (seconds)")
    p.add_argument("--no-identify", action="store_true",
                   help="with --retrain: skip the identification (then no identified physics "
                        "and no correction rung)")
    p.add_argument("--retrain", action="store_true",
                   help="identify the physics and train the networks here (needs torch) "
                        "instead of using the shipped identified airframe and weights")
    p.add_argument("--cache", default=None, help="dataset cache folder (default: user cache)")
    p.add_argument("--cost-repeats", type=int, default=15,
                   help="interleaved timing repeats (default 15)")
    p.add_argument("--save-trajectories", action="store_true",
                   help="also write every Table 1 prediction as compressed npz (large)")
    p.add_argument("--sorties", type=int, default=None, help="override the recipe's count")
    p.add_argument("--duration", type=float, default=None,
                   help="override the recipe's sortie duration (s)")
    p.set_defaults(func=cmd_reproduce)

    p = sub.add_parser("evaluate", help="Table 1 and Table 4 metrics on any dataset folder")
    _add_force(p)
    _add_airframe(p, default=None)
    p.add_argument("--dataset", required=True, help="dataset folder (manifest.json + CSVs)")
    p.add_argument("--identified", default=None,
                   help="airframe file fitted by 'uavdyn identify': adds the identified-physics "
                        "rung (weights trained on it are run on it)")
    p.add_argument("--weights", nargs="*", default=None, help="weight file(s) of the hybrid")
    p.add_argument("--all-sorties", action="store_true",
                   help="score every sortie of a dataset without a test split (the result "
                        "says so; they may include sorties a model was fitted on)")
    p.add_argument("--out", default="results/metrics.json", help="JSON output (Markdown beside)")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("train", help="train the learned correction (torch) and export its "
                       "weights as .npz")
    _add_force(p)
    _add_airframe(p)
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
    add_montecarlo_parser(sub)
    add_mpc_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)

    try:
        return int(args.func(args) or 0)
    except (CliError, AirframeError, TrimError, FileNotFoundError, ValueError,
            DivergenceError, CompileError) as exc:
        if args.debug:
            raise
        print(f"uavdyn {args.command}: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"uavdyn {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # an internal error: one line, the traceback on request
        if args.debug:
            raise
        print(f"uavdyn {args.command}: internal error: {type(exc).__name__}: "
              f"{_one_line(exc)} (run with --debug for the traceback)", file=sys.stderr)
        return 2


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


if __name__ == "__main__":
    sys.exit(main())
