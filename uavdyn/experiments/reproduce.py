"""The validation pipeline behind ``uavdyn reproduce`` and ``uavdyn evaluate``: the paper's
Table 1 (accuracy), Table 2 (convergence), Table 3 (cost), Table 4 (robustness), Figures 2-6 and
a work-precision diagram, measured on held-out sorties and written as Markdown, JSON and PNG.

Numbers are measured, never copied: the paper's figures appear only in their own column, as the
paper's. Saved trajectories (``trajectories/*.npz``) let anyone recompute the accuracy metrics.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import casadi as ca
import numpy as np
import scipy.integrate
from tqdm import tqdm

from uavdyn.airframes import Airframe, load_airframe, perturb
from uavdyn.emulation import Emulator, open_loop_references, plan_mission
from uavdyn.emulation.datagen import generate_dataset, shipped_recipe
from uavdyn.evaluation import (
    MODES,
    Solver,
    error_growth,
    error_stats,
    evaluate_trajectory,
    fine_reference,
    pooled_stats,
    step_states,
)
from uavdyn.experiments.common import (
    FORMULATIONS,
    IDENTIFIED_PHYSICS,
    IDENTIFY_PARAMS,
    NOMINAL_PHYSICS,
    TARGETS,
    condition,
    hybrid_steps,
    identification_sorties,
    provenance,
    target_states,
)
from uavdyn.experiments.report import _table1, _table4, write_report
from uavdyn.flightdata import Dataset, Sortie, load_dataset
from uavdyn.integrate import (
    EvalGrid,
    StepUseError,
    cache_dir,
    check_use,
    compile_function,
    reference_step,
    rollout,
    takes_time,
)
from uavdyn.integrate.augmented import physics_step
from uavdyn.learned import (
    WeightFileError,
    hybrid_step,
    load_weights,
    save_weights,
    shipped_weights,
)
from uavdyn.model import build_model, numpy_rhs, sortie_params, structure_of
from uavdyn.outputs import output_folder

PAPER = {"rmse": 1.82e-3, "mae": 1.47e-3, "max": 2.31e-3, "cost_reduction": 0.38,
         "rk4_0.001_ms": 148.0, "rk4_0.0005_ms": 287.0, "hybrid_0.005_ms": 92.0}
RECIPES = {"quadrotor": "datagen_quadrotor", "fixed_wing": "datagen_fixed_wing"}


@dataclass
class ReproduceConfig:
    """What the pipeline runs. ``quick`` shrinks everything for tests."""

    airframes: tuple[str, ...] = ("quadrotor", "fixed_wing")
    out: str = "results"
    dts: tuple[float, ...] = (0.005, 0.01, 0.02)
    quick: bool = False
    sorties: int | None = None  # override the recipe's sortie count
    duration_s: float | None = None  # override the recipe's sortie duration
    retrain: bool = False
    weights_dir: str | None = None  # None: the weights shipped with the package
    cache: str | None = None
    cost_repeats: int = 5
    progress: bool = True
    force: bool = False  # write into a non-empty folder that is not a previous reproduce output
    identify: bool = True  # fit the physics on the train split first (nominal -> identified)
    extra: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------- data


def dataset_for(airframe_name: str, config: ReproduceConfig) -> Dataset:
    """The emulated dataset of the shipped recipe (or its quick variant), generated once and
    reused from the cache folder while the recipe is unchanged."""

    recipe = shipped_recipe(RECIPES[airframe_name])
    if config.quick:  # few, short sorties of a few missions, still split by sortie
        recipe.sorties, recipe.duration_s = 12, 20.0
        recipe.missions = ["sysid_3211", "survey"] + (
            ["high_alpha"] if airframe_name == "fixed_wing" else [])
        recipe.split = {"train": 0.5, "validation": 0.25, "test": 0.25}
    if config.sorties:
        recipe.sorties = config.sorties
    if config.duration_s:
        recipe.duration_s = config.duration_s
    key = hashlib.sha256(json.dumps(asdict(recipe), sort_keys=True).encode()).hexdigest()[:12]
    folder = Path(config.cache or cache_dir() / "datasets") / f"{airframe_name}_{key}"
    if not (folder / "manifest.json").exists():
        folder.parent.mkdir(parents=True, exist_ok=True)  # the cache is ours to create
        generate_dataset(recipe, folder, progress=config.progress, force=True)
    return load_dataset(folder)


def weights_path(airframe: Airframe, formulation: str, target: str,
                 config: ReproduceConfig) -> Path:
    """Where the weights of one (formulation, target) live: ``<airframe>_<formulation>.npz``
    for the shipped default target (flight data), ``<airframe>_<formulation>_reference.npz``
    for the pure numerical correction."""
    if config.weights_dir is None:
        try:
            return shipped_weights(airframe.name, formulation, target)
        except WeightFileError:
            return Path(f"<no shipped {airframe.name} {formulation} {target} weights>")
    suffix = "" if target == "data" else "_reference"
    return Path(config.weights_dir) / f"{airframe.name}_{formulation}{suffix}.npz"


def identify_physics(airframe: Airframe, ds: Dataset, config: ReproduceConfig, log
                     ) -> tuple[Airframe | None, dict]:
    """Fit :data:`IDENTIFY_PARAMS` of ``airframe`` on the train split (validation scores it);
    the fitted airframe file and its report are written under ``identified/``. Returns the
    fitted airframe as a user would load it, and a summary (or why there is none)."""
    from uavdyn.identify import IdentifyError, identify, write_outputs

    if not ds.train:
        return None, {"missing": "the dataset has no train split to identify on"}
    names = list(IDENTIFY_PARAMS[airframe.kind])
    fit_on, which = identification_sorties(ds.train)
    log(f"[{airframe.name}] identifying {', '.join(names)} on {len(fit_on)} {which} sorties ...")
    try:
        result = identify(airframe, fit_on, ds.validation, names,
                          max_windows=40 if config.quick else 120,
                          max_iterations=20 if config.quick else 60, progress=config.progress)
    except IdentifyError as exc:
        return None, {"missing": f"identification refused: {exc}"}
    out = Path(config.out) / "identified" / f"{airframe.name}.toml"
    out.parent.mkdir(parents=True, exist_ok=True)
    command = (f"uavdyn identify --airframe {airframe.name} --dataset {ds.path} --params "
               f"{','.join(names)} --out {out.name}")
    paths = write_outputs(result, airframe, str(ds.path), command, out,
                          out.parent / f"{airframe.name}_report")
    fitted = load_airframe(out)
    summary = {"file": str(paths["airframe"]), "report": str(paths["json"]),
               "plot": str(paths["png"]), "params": names, "seconds": result.seconds,
               "estimates": [{"name": e.name, "nominal": e.nominal, "value": e.value,
                              "std_error": e.std_error} for e in result.estimates],
               "flagged_pairs": [list(p) for p in result.flagged_pairs],
               "validation_theta_rmse": (result.fit.get("validation") or {}).get("theta_rmse"),
               "fitted_on": f"{len(fit_on)} {which} sorties",
               "window_s": result.window_s}
    return fitted, summary


def obtain_weights(airframe: Airframe, ds: Dataset, formulation: str, target: str,
                   config: ReproduceConfig, log) -> Path | None:
    """Shipped weights, or freshly trained ones with ``retrain`` (needs torch) on the physics of
    ``airframe`` (the identified airframe by default)."""
    path = weights_path(airframe, formulation, target, config)
    if config.retrain:
        suffix = "" if target == "data" else "_reference"
        path = Path(config.out) / "weights" / f"{airframe.name}_{formulation}{suffix}.npz"
        path.parent.mkdir(parents=True, exist_ok=True)
    if config.retrain and formulation == "improved" and target == "data":
        from uavdyn.learned.safe import SafeConfig, train_safe, write_safe_history

        out = path
        cfg = SafeConfig(progress=config.progress)
        if config.quick:
            cfg.epochs, cfg.max_seconds, cfg.batches_per_epoch = 3, 60.0, 3
        log(f"training the safe {formulation} correction for {airframe.name} ...")
        result = train_safe(ds.train, ds.validation, airframe, cfg)
        write_safe_history(result, out.with_name(out.stem + "_history.json"))
        if not result.kept:
            log(f"[{airframe.name}] correction not kept: {result.reason}")
            return None
        save_weights(result.net, out)
        return out
    if config.retrain:
        from uavdyn.learned.train import TrainConfig, train, write_history

        out = path
        cfg = TrainConfig(formulation=formulation, target=target, progress=config.progress)
        if config.quick:
            cfg.epochs, cfg.max_seconds = 8, 40.0
        log(f"training {formulation}/{target} weights for {airframe.name} ...")
        result = train(ds.train, ds.validation, airframe, cfg)
        save_weights(result.net, out)
        write_history(result, out.with_name(out.stem + "_history.json"))
        return out
    return path if path.exists() else None



# ----------------------------------------------------------------------------- Table 1


def altitude(sortie: Sortie) -> float | None:
    """The sortie's manifest ``altitude_m`` (None if the manifest does not give it)."""
    value = sortie.meta.get("manifest_entry", {}).get("altitude_m")
    return None if value is None else float(value)


def free_run_runner(step, x0: np.ndarray, controls: np.ndarray, p: np.ndarray,
                    sample_dt: float, dt: float, compiled: bool = True):
    """A callable running one whole-sortie free run of ``step`` (``controls`` one row per log
    interval) and returning the ``(N+1) x 4`` body states at the log times: what is timed
    (inputs converted once, outside the callable). A step on an augmented state starts from
    the state its own ``start_states`` builds from ``x0`` and the first command."""
    g = EvalGrid(sample_dt, dt)
    check_use(step, dt, 0.0, len(controls) * sample_dt)
    func = rollout(step, len(controls), g.substeps)
    func = compile_function(func) if compiled else func
    z0 = (x0 if step.size1_in(0) == len(x0)
          else step_states(step, None, x0[None, :], controls[:1], p, g)[0])
    args = [ca.DM(z0), ca.DM(np.ascontiguousarray(controls.T)), ca.DM(p), dt]
    if takes_time(step):
        args.append(0.0)

    def run() -> np.ndarray:
        return np.vstack([x0, np.asarray(func(*args))[:len(x0)].T])

    return run


def refusal(step, dt: float, t_end: float = 0.0) -> str | None:
    """Why ``step`` may not be used at ``dt`` up to ``t_end`` s into a sortie (a correction
    tied to its trained step size or time range), or None."""
    try:
        check_use(step, dt, 0.0, t_end)
    except StepUseError as exc:
        return str(exc)
    return None


def usable(step, dt: float) -> bool:
    """Whether ``step`` may be used at ``dt`` (a dt-bound correction only at its own)."""
    return refusal(step, dt) is None


@dataclass(frozen=True)
class Candidate:
    """A solver of the comparison with the airframe whose parameters it runs on and the rung of
    the ladder it stands for (``nominal`` or ``identified`` physics)."""

    solver: Solver
    airframe: Airframe
    physics: str


def build_solvers(airframe: Airframe, nets: dict, dts, identified: Airframe | None = None,
                  net_airframes: dict | None = None) -> dict[str, list[Candidate]]:
    """Solvers per target, the ladder of SPEC section 4: nominal physics, identified physics
    (flight-data target only) and each hybrid formulation with weights, on the physics its
    weights were trained on (``net_airframes[target]``, default the nominal airframe)."""
    out: dict[str, list[Candidate]] = {}
    rungs = [(NOMINAL_PHYSICS, airframe, "nominal")]
    if identified is not None:
        rungs.append((IDENTIFIED_PHYSICS, identified, "identified"))
    for target in TARGETS:
        cands = []
        for label, af, physics in rungs:
            if physics == "identified" and target != "data":
                continue  # the reference target is the nominal model's own fine-step solution
            step = physics_step(af)
            cands += [Candidate(Solver(f"{label} @ {dt:g} s", step, dt, structure_of(af)), af,
                                physics)
                      for dt in dts]
        base = (net_airframes or {}).get(target, airframe)
        physics = "identified" if base is not airframe else "nominal"
        suffix = " on identified physics" if physics == "identified" else ""
        for name, step in hybrid_steps(base, nets, target, suffix).items():
            cands += [Candidate(Solver(f"{name} @ {dt:g} s", step, dt), base, physics)
                      for dt in dts if usable(step, dt)]
        out[target] = cands
    return out


def accuracy_tables(airframe: Airframe, sorties: list[Sortie], solvers: dict,
                    traj_dir: Path | None = None, progress=None) -> dict:
    """Table 1: pooled error statistics per target group, solver and mode; ``solvers`` maps a
    target to :class:`Candidate` objects (or plain solvers on ``airframe``'s parameters)."""
    groups: dict[str, list[tuple[Sortie, np.ndarray, str]]] = {}
    for s in sorties:
        truth = target_states(s)
        cond = condition(s)
        label = f"flight data ({cond})" if cond in ("calm", "turbulent") else "flight data"
        groups.setdefault(label, []).append((s, truth, "data"))
        ref = fine_reference(airframe, s.time, truth[0], s.controls, airframe.p)
        groups.setdefault("baseline fine-step reference", []).append((s, ref, "reference"))
    tables: dict = {}
    for label, members in groups.items():
        target = members[0][2]
        rows = []
        for cand in solvers[target]:
            if not isinstance(cand, Candidate):
                cand = Candidate(cand, airframe, "nominal")
            solver = cand.solver
            pairs: dict[str, list] = {m: [] for m in MODES}
            refusals: dict[str, list] = {m: [] for m in MODES}
            saved = {}
            for s, states, _ in members:
                res = evaluate_trajectory(solver, s.time, states, s.controls,
                                          sortie_params(cand.airframe, altitude(s)))
                for m in MODES:
                    if m in res:
                        pairs[m].append(res[m])
                    elif m in res.get("refused", {}):
                        refusals[m].append(res["refused"][m])
                saved[s.name] = res
                if progress:
                    progress()
            row = {"solver": solver.name, "dt": solver.dt, "physics": cand.physics}
            for m in MODES:
                if pairs[m]:
                    row[m] = pooled_stats(pairs[m])
                elif refusals[m]:  # reported as missing, with the reason
                    row.setdefault("missing", {})[m] = refusals[m][0]
            rows.append(row)
            if traj_dir is not None:
                _save_trajectories(traj_dir, airframe.name, label, solver.name, saved)
        tables[label] = {"target": target, "sorties": [m[0].name for m in members],
                         "rows": rows}
    return tables


def _slug(text: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in text).strip("_")


def _save_trajectories(folder: Path, airframe: str, group: str, solver: str, saved: dict
                       ) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    arrays = {}
    for sortie, res in saved.items():
        for m in MODES:
            if m in res:
                arrays[f"{sortie}__{m}__predicted"] = res[m][0]
                arrays[f"{sortie}__{m}__target"] = res[m][1]
    np.savez_compressed(folder / f"{airframe}__{_slug(group)}__{_slug(solver)}.npz", **arrays)


# ----------------------------------------------------------------------------- Table 2


def convergence_table(weight_files: dict) -> list[dict]:
    """Table 2 from the saved training histories beside the weights."""
    rows = []
    for (formulation, target), path in weight_files.items():
        if path is None:
            continue
        hist_path = Path(path).with_name(Path(path).stem + "_history.json")
        if not hist_path.exists():
            rows.append({"weights": str(path), "note": "no training history saved"})
            continue
        doc = json.loads(hist_path.read_text())
        hist = doc["history"]
        # the safe trainer's losses: training rollout loss (physics = 1) and the validation
        # 1 s pitch RMSE it selects by
        safe = "val_theta_rmse" in hist[-1]
        train_key = ("train_loss" if safe else "train_total" if "train_total" in hist[-1]
                     else "train_one_step")
        val_key = "val_theta_rmse" if safe else "val_total"
        val = [h.get(val_key) for h in hist if h.get(val_key) is not None]
        train = [h.get(train_key) for h in hist if h.get(train_key) is not None]
        rows.append({
            "weights": Path(path).name, "formulation": formulation, "target": target,
            "initial_train_loss": train[0] if train else None,
            "final_train_loss": train[-1] if train else None,
            "initial_val_loss": val[0] if val else None,
            "best_val_loss": min(val) if val else None,
            "epochs": len(hist) - 1, "best_epoch": doc.get("best_epoch"),
            "stopped": doc.get("stopped"),
            "monotonic_train": bool(np.all(np.diff(train) <= 0)) if len(train) > 1 else None,
            "monotonic_val": bool(np.all(np.diff(val) <= 0)) if len(val) > 1 else None,
            "history_file": str(hist_path),
            **({"validation_metric": "1 s pitch RMSE (rad)", "train_metric":
                "rollout loss (physics = 1)"} if safe else {}),
        })
    return rows


# ----------------------------------------------------------------------------- Table 3


def _median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def cost_table(airframe: Airframe, sortie: Sortie, nets: dict, repeats: int,
               net_airframe: Airframe | None = None) -> dict:
    """Table 3: wall time of one test sortie's free run for every solver that matters,
    compiled and VM, with the pitch RMSE each reaches against the flight data (true states)
    and against the baseline fine-step reference."""


    truth = target_states(sortie)
    ref = fine_reference(airframe, sortie.time, truth[0], sortie.controls, airframe.p)
    sample_dt = sortie.dt
    controls = sortie.controls[:-1]
    x0 = truth[0]
    p = airframe.p
    rows = []

    def add(name, dt, run, n_rep, compiled):
        traj = run()  # warm-up; also the accuracy
        wall = _median_time(run, n_rep)
        rows.append({"solver": name, "dt": dt, "compiled": compiled, "wall_ms": wall * 1e3,
                     "theta_rmse_vs_flight": error_stats(traj, truth)["theta_rmse"],
                     "theta_rmse_vs_reference": error_stats(traj, ref)["theta_rmse"]})

    net_p = (net_airframe or airframe).p  # a correction runs on the airframe it was trained on
    steps = {"RK4": physics_step(airframe), **hybrid_steps(net_airframe or airframe, nets)}
    plan = [("RK4", 0.001), ("RK4", 0.0005), ("RK4", 0.005), ("hybrid improved", 0.005),
            ("hybrid paper", 0.005)]
    missing: list[dict] = []
    for name, dt in plan:
        if name not in steps:
            continue
        why = refusal(steps[name], dt, sortie.time[-1] - sortie.time[0])
        if why:  # reported as missing, never run outside what the step was trained for
            missing.append({"solver": name, "dt": dt, "missing": why})
            continue
        for compiled in (True, False):
            run = free_run_runner(steps[name], x0, controls,
                                  net_p if name.startswith("hybrid") else p, sample_dt, dt,
                                  compiled)
            add(f"{name} {'compiled' if compiled else 'CasADi VM'}", dt, run,
                repeats if compiled else max(1, repeats // 2), compiled)
    # CVODES on the same zero-order-held grid (one integrator call per log interval)
    cv = rollout(reference_step(build_model(airframe).f, tol=1e-8), len(controls))

    def run_cvodes():
        return np.vstack([x0, np.asarray(cv(x0, controls.T, p, sample_dt)).T])

    add("CVODES (tol 1e-8)", None, run_cvodes, 1, False)
    rhs = numpy_rhs(airframe.kind)

    def run_rk45():
        out = [x0]
        x = x0
        for u in controls:
            sol = scipy.integrate.solve_ivp(lambda t, y, u=u: rhs(y, u, p), (0.0, sample_dt), x,
                                            method="RK45", rtol=1e-6, atol=1e-8)
            x = sol.y[:, -1]
            out.append(x)
        return np.array(out)

    add("scipy RK45 (rtol 1e-6)", None, run_rk45, 1, False)
    emulator = Emulator(airframe)
    xe0 = emulator.initial_state(x0, controls[0], 100.0)
    refs = open_loop_references(sortie.controls)

    def run_emulator():
        return emulator.fly(xe0, refs).true_states

    add("emulator (truth model, RK4 @ 0.001 s + actuators, unsteady aero)", 0.001,
        run_emulator, 1, True)
    base = next((r for r in rows if r["solver"] == "hybrid improved compiled"), None)
    for r in rows:
        r["ratio_to_hybrid_0.005"] = r["wall_ms"] / base["wall_ms"] if base else None
    return {"sortie": sortie.name, "duration_s": sortie.duration, "rows": rows, "missing": missing,
            "grid": f"logged controls held over each {sample_dt:g} s interval (ZOH)"}


def flight_mode(kind: str) -> str:
    """How accuracy against flight data is measured: whole-sortie free run for the fixed wing;
    1 s predictions restarted from the recorded state for the quadrotor, whose open-loop pitch
    is neutrally stable (a replay of logged commands drifts away for any imperfect model)."""
    return "free_run" if kind == "fixed_wing" else "horizon_1s"


def work_precision(airframe: Airframe, sortie: Sortie, nets: dict, repeats: int,
                   missing: list | None = None, net_airframe: Airframe | None = None
                   ) -> list[dict]:
    """Error against wall time for every solver and step size, on one test sortie: wall time of
    the compiled whole-sortie free run; pitch RMSE against the flight data (see
    :func:`flight_mode`) and, free run, against the baseline fine-step reference. A point the
    step refuses (outside its trained dt or time range) goes to ``missing`` with the reason."""
    truth = target_states(sortie)
    ref = fine_reference(airframe, sortie.time, truth[0], sortie.controls, airframe.p)
    controls, x0, p, sample_dt = sortie.controls[:-1], truth[0], airframe.p, sortie.dt
    mode = flight_mode(airframe.kind)
    families = {"RK4": (physics_step(airframe), (0.01, 0.005, 0.0025, 0.002, 0.001,
                                                             0.0005), p)}
    for target, label in (("data", ""), ("reference", " (numerical)")):
        owner = (net_airframe or airframe) if target == "data" else airframe
        for name, step in hybrid_steps(owner, nets, target).items():
            families[f"{name}{label}"] = (step, (0.01, 0.005, 0.0025), owner.p)
    points = []
    for family, (step, dts, p) in families.items():
        for dt in dts:
            why = refusal(step, dt, sortie.time[-1] - sortie.time[0])
            if why:
                if missing is not None:
                    missing.append({"family": family, "dt": dt, "missing": why})
                continue
            run = free_run_runner(step, x0, controls, p, sample_dt, dt)
            run()
            wall = _median_time(run, repeats)
            solver = Solver(family, step, dt)
            flight = evaluate_trajectory(solver, sortie.time, truth, sortie.controls, p)[mode]
            free = evaluate_trajectory(solver, sortie.time, ref, sortie.controls, p)["free_run"]
            points.append({
                "family": family, "dt": dt, "wall_ms": wall * 1e3, "flight_mode": mode,
                "theta_rmse_vs_flight": error_stats(*flight)["theta_rmse"],
                "theta_rmse_vs_reference": error_stats(*free)["theta_rmse"],
            })
    return points


# ----------------------------------------------------------------------------- Table 4


def robustness_table(airframe: Airframe, ds: Dataset, nets: dict, config: ReproduceConfig,
                     dt: float = 0.005, identified: Airframe | None = None,
                     net_airframe: Airframe | None = None) -> list[dict]:
    """Table 4: error growth, maximum error and divergence of RK4 and the hybrid in the nominal
    test sorties, the high-angle-of-attack sorties (fixed wing) and sorties flown by a truth
    model whose stability derivatives and mass terms are 15 % off (the solvers keep nominal p)."""
    solvers = [(Solver(NOMINAL_PHYSICS, physics_step(airframe), dt, structure_of(airframe)),
                airframe)]
    if identified is not None:
        solvers.append((Solver(IDENTIFIED_PHYSICS, physics_step(identified), dt,
                               structure_of(identified)), identified))
    base = net_airframe or airframe
    suffix = " on identified physics" if base is not airframe else ""
    solvers += [(Solver(name, step, dt), base)
                for name, step in hybrid_steps(base, nets, "data", suffix).items()]
    # only test sorties are scored; a group with none is reported missing, never filled with
    # training or validation sorties
    test = [s for s in ds.test if condition(s) != "turbulent"]
    scenarios = {"nominal (calm test sorties)": (test, "no calm test sortie in the dataset")}
    if airframe.kind == "fixed_wing":  # alpha is meaningless for a hovering multirotor
        high = [s for s in ds.test if s.mission == "high_alpha"]
        scenarios["alpha > 20 deg (high-alpha test sorties)"] = (
            high, "no high-alpha test sortie in the dataset")
    missions = [s.mission for s in (test or ds.test)][:4 if not config.quick else 2]
    scenarios["+15 % stability derivatives and mass"] = (perturbed_sorties(
        airframe, missions, (test or ds.test)[0].duration if ds.test else 20.0),
        "no test sortie to take the missions from")
    rows = []
    for scenario, (sorties, why) in scenarios.items():
        for solver, solver_airframe in solvers:
            if not sorties:
                rows.append({"scenario": scenario, "solver": solver.name, "sorties": 0,
                             "missing": why})
                continue
            growth, refused = [], None
            for s in sorties:
                res = evaluate_trajectory(solver, s.time, target_states(s), s.controls,
                                          sortie_params(solver_airframe, altitude(s)))
                if "free_run" not in res:  # outside what the step was trained for
                    refused = res.get("refused", {}).get("free_run", "not evaluated")
                    break
                pred, targ = res["free_run"]
                growth.append(error_growth(res["free_run_time"], pred, targ))
            if refused:
                rows.append({"scenario": scenario, "solver": f"{solver.name} @ {dt:g} s",
                             "sorties": len(sorties), "missing": refused})
                continue
            rows.append({
                "scenario": scenario, "solver": f"{solver.name} @ {dt:g} s",
                "sorties": len(sorties),
                "slope_rad_per_s": float(np.mean([g["slope_rad_per_s"] for g in growth])),
                "max_error_rad": float(np.max([g["max_error_rad"] for g in growth])),
                "diverged": int(sum(g["diverged"] for g in growth)),
                "first_divergence_s": min((g["time_to_divergence_s"] for g in growth
                                           if g["diverged"]), default=None),
            })
    return rows


def perturbed_sorties(airframe: Airframe, missions: list[str], duration: float
                      ) -> list[Sortie]:
    """Calm, noise-free sorties flown by the emulator on an airframe whose stability
    derivatives and mass terms are scaled by 1.15 (the paper's robustness case)."""

    truth_airframe = perturb(airframe, 1.15)
    emulator = Emulator(truth_airframe)
    out = []
    for i, mission in enumerate(missions):
        rng = np.random.default_rng([7, i])
        plan = plan_mission(mission, truth_airframe, duration, emulator.sample_rate_hz, rng)
        flight = emulator.fly(emulator.initial_state(plan.x0, plan.u0, plan.altitude),
                              plan.references)
        out.append(Sortie(f"perturbed_{i}_{mission}", airframe.kind, flight.time,
                          flight.true_states, flight.controls, mission,
                          {"condition": "calm"}, true_states=flight.true_states))
    return out


# ----------------------------------------------------------------------------- pipeline


def run_airframe(name: str, config: ReproduceConfig, log) -> dict:
    """Everything for one airframe: dataset, weights, Tables 1-4, work-precision, figures."""

    from uavdyn.experiments import figures

    airframe = load_airframe(name)
    out = Path(config.out)
    log(f"[{airframe.name}] dataset ...")
    ds = dataset_for(name, config)
    identified, identification = (identify_physics(airframe, ds, config, log) if config.identify
                                  else (None, {"missing": "not requested (--no-identify)"}))
    # retrained flight-data corrections learn on top of the identified physics; the numerical
    # (reference-target) correction and shipped weights belong to the nominal model
    net_airframes = {"data": identified if (config.retrain and identified) else airframe,
                     "reference": airframe}
    nets = {(f, t): obtain_weights(net_airframes[t], ds, f, t, config, log)
            for f in FORMULATIONS for t in TARGETS}
    solvers = build_solvers(airframe, nets, config.dts, identified, net_airframes)
    test = ds.test
    n_work = sum(len(v) for v in solvers.values()) * len(test)  # one run per solver and sortie
    bar = tqdm(total=n_work, desc=f"[{airframe.name}] Table 1", disable=not config.progress,
               unit="run")
    table1 = accuracy_tables(airframe, test, solvers, out / "trajectories", bar.update)
    bar.close()
    log(f"[{airframe.name}] Tables 2-4, work-precision ...")
    table2 = convergence_table(nets)
    calm = [s for s in test if condition(s) == "calm"] or test
    table3 = cost_table(airframe, calm[0], nets, config.cost_repeats, net_airframes["data"])
    wp_missing: list[dict] = []
    wp = work_precision(airframe, calm[0], nets, max(1, config.cost_repeats // 2), wp_missing,
                        net_airframes["data"])
    table4 = robustness_table(airframe, ds, nets, config, identified=identified,
                              net_airframe=net_airframes["data"])
    result = {"airframe": airframe.name, "kind": airframe.kind,
              "dataset": {"path": str(ds.path), "sorties": len(ds.sorties),
                          "test_sorties": [s.name for s in test],
                          "sample_rate_hz": ds.sample_rate_hz},
              "weights": {f"{f}/{t}": (str(p) if p else None) for (f, t), p in nets.items()},
              "identification": identification,
              "corrections_trained_on": {t: ("identified" if a is not airframe else "nominal")
                                         for t, a in net_airframes.items()},
              "table1": table1, "table2": table2, "table3": table3,
              "work_precision": wp, "work_precision_missing": wp_missing, "table4": table4}
    result["figures"] = figures.make_all(airframe, ds, nets, result, out, net_airframes["data"])
    return result


def run(config: ReproduceConfig) -> dict:
    """The whole pipeline; writes ``metrics.json`` and ``report.md`` under ``config.out``."""

    t0 = time.perf_counter()
    out = Path(config.out)

    def log(msg: str) -> None:
        if config.progress:
            print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", flush=True)

    # everything is written into a temporary sibling and renamed into place at the end, so an
    # interrupted run never leaves a folder that mixes two runs
    with output_folder(out, "reproduce", config.force) as tmp:
        work = replace(config, out=str(tmp))
        results = {"config": asdict(config), "paper": PAPER,
                   "airframes": [run_airframe(a, work, log) for a in config.airframes]}
        results["wall_s"] = time.perf_counter() - t0
        results["provenance"] = provenance()
        # metrics.json: paths relative to the output folder, the dataset cache and the package
        # (no absolute path of the machine that ran it)
        relative = _relocate(results, str(tmp) + os.sep, "")
        relative = _relocate(relative, str(out).rstrip(os.sep) + os.sep, "")
        for folder, label in ((config.cache, "<dataset cache>/"), (cache_dir(), "<uavdyn cache>/")):
            if folder:
                relative = _relocate(relative, str(folder).rstrip(os.sep) + os.sep, label)
                relative = _relocate(relative, str(Path(folder).resolve()) + os.sep, label)
        relative = _relocate(relative, str(Path(__file__).resolve().parents[1]) + os.sep,
                             "<uavdyn package>/")
        (tmp / "metrics.json").write_text(json.dumps(relative, indent=2, default=_json) + "\n")
        write_report(results, tmp / "report.md")
    results = _relocate(results, str(tmp) + os.sep, str(out) + os.sep)
    log(f"wrote {out / 'report.md'} and {out / 'metrics.json'} "
        f"(total {results['wall_s']:.0f} s)")
    return results


def _relocate(obj, old: str, new: str):
    """A copy of ``obj`` with every string starting with ``old`` starting with ``new``."""
    if isinstance(obj, dict):
        return {k: _relocate(v, old, new) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_relocate(v, old, new) for v in obj]
    if isinstance(obj, str) and obj.startswith(old):
        return new + obj[len(old):]
    if isinstance(obj, str) and obj == old.rstrip(os.sep):  # the folder itself
        return new.rstrip("/") or "."
    return obj


def _json(value):
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return str(value)


# ----------------------------------------------------------------------------- evaluate


def evaluate_dataset(airframe: Airframe, dataset: str | Path, weights: list[str | Path],
                     dts=(0.005, 0.01, 0.02), split: str = "test",
                     identified: Airframe | None = None, all_sorties: bool = False) -> dict:
    """Table 1 and Table 4 figures on any dataset folder in the interchange format (its
    ``split`` sorties, or all if it has no split): the ladder of nominal physics, identified
    physics (``identified``, an airframe fitted by ``uavdyn identify``) and each hybrid weight
    file, run on the airframe its weights were trained on (checked by hash).

    A dataset without ``split`` sorties is an error (its sorties may be the ones a model was
    fitted on) unless ``all_sorties``: then every sortie is scored and the result says so."""

    ds = load_dataset(dataset)
    if ds.kind != airframe.kind:
        raise ValueError(f"dataset {dataset} is of kind '{ds.kind}' but airframe "
                         f"'{airframe.name}' is '{airframe.kind}'")
    sorties = ds.split(split)
    if not sorties:
        if not all_sorties:
            raise ValueError(f"{dataset}: no '{split}' sorties (manifest split column); give "
                             "--all-sorties to score every sortie (the result then says so)")
        sorties = ds.sorties
    rungs = [(NOMINAL_PHYSICS, airframe, "nominal")]
    if identified is not None:
        if identified.kind != airframe.kind:
            raise ValueError(f"identified airframe '{identified.name}' is a {identified.kind}, "
                             f"airframe '{airframe.name}' a {airframe.kind}")
        rungs.append((IDENTIFIED_PHYSICS, identified, "identified"))
    solvers = [Candidate(Solver(f"{label} @ {dt:g} s", physics_step(af), dt, structure_of(af)),
                         af, physics)
               for label, af, physics in rungs for dt in dts]
    for w in weights:
        net = load_weights(w)
        owners = [(af, physics) for _, af, physics in rungs
                  if af.param_hash() == net.airframe_hash]
        if not owners:
            names = " or ".join(f"'{af.name}'" for _, af, _ in rungs)
            raise WeightFileError(f"{w}: weights trained on airframe hash {net.airframe_hash}, "
                                  f"which is neither {names}: give the airframe they were "
                                  "trained on (--airframe or --identified)")
        af, physics = owners[-1]
        step = hybrid_step(net, af, compile=False)
        solvers += [Candidate(Solver(f"hybrid {net.formulation} ({Path(w).name}) on {physics} "
                                     f"physics @ {dt:g} s", step, dt), af, physics)
                    for dt in dts]
    table1 = accuracy_tables(airframe, sorties, {"data": solvers, "reference": [
        c for c in solvers if c.physics == "nominal"]})
    safety = per_sortie_safety(solvers, sorties, [load_weights(w) for w in weights])
    alpha_max = {s.name: float(np.degrees(np.max(np.arctan2(target_states(s)[:, 1],
                                                            target_states(s)[:, 0]))))
                 for s in sorties}
    groups = {"nominal (all evaluated sorties)": sorties}
    if airframe.kind == "fixed_wing":  # alpha is meaningless for a hovering multirotor
        groups["alpha > 20 deg (sorties that reach it)"] = [s for s in sorties
                                                            if alpha_max[s.name] > 20.0]
    table4 = []
    for scenario, members in groups.items():
        for cand in solvers:
            solver = cand.solver
            if solver.dt != 0.005:
                continue
            runs = [evaluate_trajectory(solver, s.time, target_states(s), s.controls,
                                        sortie_params(cand.airframe, altitude(s)))
                    for s in members]
            refused = next((r["refused"]["free_run"] for r in runs
                            if "free_run" not in r and "refused" in r), None)
            if refused:
                table4.append({"scenario": scenario, "solver": solver.name,
                               "sorties": len(members), "missing": refused})
                continue
            growth = [error_growth(r["free_run_time"], *r["free_run"]) for r in runs]
            table4.append({
                "scenario": scenario, "solver": solver.name, "sorties": len(members),
                "slope_rad_per_s": float(np.mean([g["slope_rad_per_s"] for g in growth]))
                if growth else None,
                "max_error_rad": float(np.max([g["max_error_rad"] for g in growth]))
                if growth else None,
                "diverged": int(sum(g["diverged"] for g in growth)),
            })
    return {"airframe": airframe.name, "kind": airframe.kind, "dataset": str(dataset),
            "sorties": [s.name for s in sorties],
            "split": split if ds.split(split) else f"all sorties (the dataset has no '{split}' "
                                                    "split: they may include fitted ones)",
            "identified": identified.origin if identified is not None else None,
            "weights": [str(w) for w in weights], "table1": table1, "table4": table4,
            "per_sortie": safety}


def _pitch_rmse(res: dict, mode: str) -> float | None:
    if mode not in res:
        return None
    pred, targ = res[mode]
    with np.errstate(over="ignore", invalid="ignore"):
        value = float(np.sqrt(np.mean((pred[..., 3] - targ[..., 3]) ** 2)))
    return value if math.isfinite(value) else math.inf


def per_sortie_safety(candidates: list[Candidate], sorties: list[Sortie], nets: list
                      ) -> list[dict]:
    """For every correction (at the sample interval, or the first step size it allows), per
    sortie: its pitch RMSE at 1 s and over the free run against the physics it sits on, the
    ratio corrected/physics, a flag where the correction is worse, and the share of samples
    outside the correction's training envelope (where its gate is below 1)."""
    out = []
    hybrids = [c for c in candidates if c.solver.name.startswith("hybrid")]
    for k, cand in enumerate(hybrids):
        physics = next((c for c in candidates if c.physics == cand.physics
                        and not c.solver.name.startswith("hybrid")
                        and c.solver.dt == cand.solver.dt), None)
        if physics is None or any(h.solver.dt < cand.solver.dt and h.solver.name.split(" @ ")[0]
                                  == cand.solver.name.split(" @ ")[0] for h in hybrids[:k]):
            continue  # one step size per correction: the first listed
        net = next((n for n in nets if n.airframe_hash == cand.airframe.param_hash()
                    and cand.solver.name.startswith(f"hybrid {n.formulation}")), None)
        rows = []
        for s in sorties:
            p = sortie_params(cand.airframe, altitude(s))
            truth = target_states(s)
            rh = evaluate_trajectory(cand.solver, s.time, truth, s.controls, p)
            rp = evaluate_trajectory(physics.solver, s.time, truth, s.controls, p)
            row = {"sortie": s.name, "condition": condition(s)}
            for mode in ("horizon_1s", "free_run"):
                a, b = _pitch_rmse(rp, mode), _pitch_rmse(rh, mode)
                row[f"{mode}_physics"], row[f"{mode}_corrected"] = a, b
                row[f"{mode}_ratio"] = (b / a if a and b is not None and math.isfinite(a)
                                        else None)
            row["worse"] = [m for m in ("horizon_1s", "free_run")
                            if row[f"{m}_ratio"] is not None and row[f"{m}_ratio"] > 1.0]
            start = getattr(cand.solver.step, "start_states", None)
            if net is not None and net.envelope is not None:
                z = (start(s.states, s.controls, p, float(np.median(np.diff(s.time))))
                     if start is not None else s.states)
                row["outside_envelope"] = net.envelope.fraction_outside(
                    np.hstack([z, s.controls]))
            rows.append(row)
        out.append({"correction": cand.solver.name, "physics": physics.solver.name,
                    "sorties": rows,
                    "worse_at_1s": sum("horizon_1s" in r["worse"] for r in rows),
                    "worse_free_run": sum("free_run" in r["worse"] for r in rows)})
    return out


def evaluation_markdown(result: dict) -> str:
    """Markdown of :func:`evaluate_dataset` (Table 1 and Table 4)."""

    lines = [f"# Evaluation of {result['airframe']} on {result['dataset']}", "",
             f"{len(result['sorties'])} sorties ({result['split']}); weights: "
             + (", ".join(result["weights"]) or "none"), "", "## Table 1: accuracy", ""]
    lines += _table1(result) + ["## Table 4: robustness (free run, dt = 0.005 s)", ""]
    lines += _table4(result)
    for entry in result.get("per_sortie", []):
        lines += ["", f"## Per sortie: {entry['correction']} against {entry['physics']}", "",
                  f"Worse than its physics at 1 s on {entry['worse_at_1s']} of "
                  f"{len(entry['sorties'])} sorties, over the free run on "
                  f"{entry['worse_free_run']}.", "",
                  "| sortie | condition | 1 s: physics | corrected | ratio | free run: physics "
                  "| corrected | ratio | outside envelope | worse |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for r in entry["sorties"]:
            def f(v):
                return "n/a" if v is None else f"{v:.4g}"
            outside = r.get("outside_envelope")
            lines.append(
                f"| {r['sortie']} | {r['condition']} | {f(r['horizon_1s_physics'])} | "
                f"{f(r['horizon_1s_corrected'])} | {f(r['horizon_1s_ratio'])} | "
                f"{f(r['free_run_physics'])} | {f(r['free_run_corrected'])} | "
                f"{f(r['free_run_ratio'])} | "
                f"{'n/a' if outside is None else f'{100 * outside:.1f} %'} | "
                f"{'**' + ', '.join(r['worse']) + '**' if r['worse'] else ''} |")
    return "\n".join(lines)
