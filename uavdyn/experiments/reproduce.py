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
from tqdm import tqdm

from uavdyn.airframes import Airframe, load_airframe, perturb
from uavdyn.emulation import Emulator, plan_mission
from uavdyn.emulation.datagen import generate_dataset, generator_code_hash, shipped_recipe
from uavdyn.evaluation import (
    MODES,
    Solver,
    error_growth,
    evaluate_trajectory,
    fine_reference,
    pooled_stats,
)
from uavdyn.experiments.common import (
    IDENTIFIED_PHYSICS,
    IDENTIFY_PARAMS,
    NOMINAL_PHYSICS,
    condition,
    identification_sorties,
    provenance,
    refusal,
    target_states,
    usable,
)
from uavdyn.experiments.ladder import (
    Rung,
    headline,
    horizon_curves,
    ladder_rungs,
    per_sortie_rows,
)
from uavdyn.experiments.report import (
    _horizons,
    _per_sortie,
    _table1,
    _table4,
    headline_lines,
    write_report,
)
from uavdyn.flightdata import Dataset, Sortie, load_dataset, pitch_noise_std
from uavdyn.integrate import (
    cache_dir,
    physics_step,
)
from uavdyn.learned import (
    WeightFileError,
    hybrid_step,
    load_weights,
    not_kept_reason,
    save_weights,
    shipped_correction,
    shipped_history,
    shipped_identified,
    shipped_weights,
)
from uavdyn.learned.rules import is_worse, sortie_ratio
from uavdyn.model import sortie_params
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
    cost_repeats: int = 15  # interleaved repeats of the one timing harness
    cost_segment_s: float | None = 5.0  # the timed stretch of the cost sortie (None: whole)
    save_trajectories: bool = False  # compressed npz of every prediction (large)
    progress: bool = True
    force: bool = False  # write into a non-empty folder that is not a previous reproduce output
    identify: bool = True  # fit the physics on the train split first (nominal -> identified)
    extra: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------- data


def dataset_cache_key(recipe) -> str:
    """The cache key of a generated dataset: its recipe and the generator's code and version."""
    return hashlib.sha256((json.dumps(asdict(recipe), sort_keys=True) +
                           generator_code_hash()).encode()).hexdigest()[:12]


def dataset_for(airframe_name: str, config: ReproduceConfig) -> Dataset:
    """The emulated dataset of the shipped recipe (or its quick variant), generated once and
    reused from the cache folder while the recipe, the package version and the generator's
    code (:func:`~uavdyn.emulation.datagen.generator_code_hash`) are unchanged."""

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
    key = dataset_cache_key(recipe)
    folder = Path(config.cache or cache_dir() / "datasets") / f"{airframe_name}_{key}"
    if not (folder / "manifest.json").exists():
        folder.parent.mkdir(parents=True, exist_ok=True)  # the cache is ours to create
        generate_dataset(recipe, folder, progress=config.progress, force=True)
    return load_dataset(folder)


def weights_path(airframe: Airframe, formulation: str, config: ReproduceConfig) -> Path:
    """Where the weights of the paper's formulation live: ``<airframe>_paper.npz`` shipped
    with the package, or in ``config.weights_dir``."""
    if config.weights_dir is None:
        try:
            return shipped_weights(airframe.name, formulation)
        except WeightFileError:
            return Path(f"<no shipped {airframe.name} {formulation} weights>")
    return Path(config.weights_dir) / f"{airframe.name}_{formulation}.npz"


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


def obtain_weights(airframe: Airframe, ds: Dataset, formulation: str,
                   config: ReproduceConfig, log) -> Path | None:
    """Shipped weights, or freshly trained ones with ``retrain`` (needs torch) on the physics of
    ``airframe`` (the identified airframe by default)."""
    path = weights_path(airframe, formulation, config)
    if config.retrain:
        path = Path(config.out) / "weights" / f"{airframe.name}_{formulation}.npz"
        path.parent.mkdir(parents=True, exist_ok=True)
    if config.retrain and formulation == "improved":
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
        cfg = TrainConfig(formulation=formulation, progress=config.progress)
        if config.quick:
            cfg.epochs, cfg.max_seconds = 8, 40.0
        log(f"training {formulation} weights for {airframe.name} ...")
        result = train(ds.train, ds.validation, airframe, cfg)
        save_weights(result.net, out)
        write_history(result, out.with_name(out.stem + "_history.json"))
        return out
    return path if path.exists() else None



# ----------------------------------------------------------------------------- Table 1


@dataclass(frozen=True)
class Candidate:
    """A solver of the comparison with the airframe whose parameters it runs on and the rung of
    the ladder it stands for (``nominal`` or ``identified`` physics)."""

    solver: Solver
    airframe: Airframe
    physics: str


def accuracy_tables(airframe: Airframe, sorties: list[Sortie], solvers: dict,
                    traj_dir: Path | None = None, progress=None, known: dict | None = None
                    ) -> dict:
    """Table 1: pooled error statistics per target group, solver and mode; ``solvers`` maps a
    target to :class:`Candidate` objects (or plain solvers on ``airframe``'s parameters).
    ``known`` holds flight-data predictions already made, ``{(solver name, sortie): result}``
    (the ladder's), which are pooled instead of recomputed."""
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
            for s, states, tgt in members:
                res = (known or {}).get((solver.name, s.name)) if tgt == "data" else None
                if res is None:
                    res = evaluate_trajectory(solver, s.time, states, s.controls,
                                              sortie_params(cand.airframe, s.altitude_m))
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
    """Table 2 from the saved training histories (``{label: path}``: the weights, beside which
    the history lies, or the history itself for a run that kept no weights), one definition
    per column, stated in the row: the safe correction's validation figure is the 1 s pitch
    RMSE on the whole validation split at the end of each epoch; its losses are the rollout
    loss (relative to the physics, which scores 1) on the same fixed training and validation
    windows after every epoch (older histories: the mean over the epoch's mini-batches). The
    earlier trainers' columns are their own (named in the row)."""
    rows = []
    for label, path in weight_files.items():
        if path is None:
            continue
        hist_path = (Path(path) if str(path).endswith("_history.json") else
                     Path(path).with_name(Path(path).stem + "_history.json"))
        if not hist_path.exists():
            rows.append({"model": label, "weights": Path(path).name,
                         "note": "no training history saved"})
            continue
        doc = json.loads(hist_path.read_text())
        hist = doc["history"]
        safe = "val_theta_rmse" in hist[-1]
        fixed = safe and "train_loss_fixed" in hist[-1]
        train_key = ("train_loss_fixed" if fixed else "train_loss" if safe
                     else "train_total" if "train_total" in hist[-1] else "train_one_step")
        val_key = "val_theta_rmse" if safe else "val_total"
        val = [h.get(val_key) for h in hist if h.get(val_key) is not None]
        train = [h.get(train_key) for h in hist if h.get(train_key) is not None]
        val_loss = [h["val_loss_fixed"] for h in hist if h.get("val_loss_fixed") is not None]
        fixed_windows = range(doc.get("config", {}).get("eval_windows", 0) or 0)
        physics_val = next((h["physics_val_theta_rmse"] for h in hist
                            if h.get("physics_val_theta_rmse")), None)
        rows.append({
            "model": label, "weights": Path(path).name,
            "train_metric": (f"rollout loss / physics on {len(fixed_windows)} fixed training "
                             "windows after each epoch" if fixed else
                             "rollout loss / physics, mean over the epoch's mini-batches"
                             if safe else f"{train_key} (earlier trainer)"),
            "val_loss_metric": (f"the same loss on {len(fixed_windows)} fixed validation "
                                "windows" if fixed else None),
            "first_val_loss": val_loss[0] if val_loss else None,
            "best_val_loss": min(val_loss) if val_loss else None,
            "val_metric": ("1 s pitch RMSE (rad), whole validation split, end of epoch"
                           if safe else f"{val_key} (earlier trainer)"),
            "physics_val": physics_val,
            "first_train_loss": train[0] if train else None,
            "final_train_loss": train[-1] if train else None,
            "initial_val": val[0] if val else None,
            "best_val": min(val) if val else None,
            "epochs": len(hist) - 1, "best_epoch": doc.get("best_epoch"),
            "kept": doc.get("kept"), "reason": doc.get("reason"),
            "stopped": doc.get("stopped"),
            "monotonic_train": bool(np.all(np.diff(train) <= 0)) if len(train) > 1 else None,
            "monotonic_val": bool(np.all(np.diff(val) <= 0)) if len(val) > 1 else None,
            "history_file": str(hist_path),
        })
    return rows


# ----------------------------------------------------------------------------- Table 3


# ----------------------------------------------------------------------------- Table 4


def robustness_table(airframe: Airframe, ds: Dataset, rungs, config: ReproduceConfig,
                     known: dict | None = None) -> list[dict]:
    """Table 4: error growth, maximum error before divergence and divergence of the ladder's
    models (at their step) in the calm test sorties, the high-angle-of-attack test sorties
    (fixed wing only) and sorties flown by a truth model whose stability derivatives and mass
    terms are 15 % off (the models keep their own parameters). Only test sorties are scored;
    a group with none is reported missing, never filled with training or validation sorties."""
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
        for rung in rungs:
            name = ladder_name(rung)
            if not sorties:
                rows.append({"scenario": scenario, "solver": name, "sorties": 0,
                             "missing": why})
                continue
            growth, refused = [], None
            for s in sorties:
                res = (known or {}).get((rung.label, s.name))  # the ladder's, test sorties
                if res is None:
                    res = evaluate_trajectory(rung.solver, s.time, target_states(s),
                                              s.controls, sortie_params(rung.airframe,
                                                                        s.altitude_m))
                if "free_run" not in res:  # outside what the step was trained for
                    refused = res.get("refused", {}).get("free_run", "not evaluated")
                    break
                growth.append(error_growth(res["free_run_time"], *res["free_run"]))
            if refused:
                rows.append({"scenario": scenario, "solver": name, "sorties": len(sorties),
                             "missing": refused})
                continue
            rows.append({
                "scenario": scenario, "solver": name, "sorties": len(sorties),
                "sortie_names": [s.name for s in sorties],
                "slope_rad_per_s": float(np.mean([g["slope_rad_per_s"] for g in growth])),
                "max_error_rad": float(np.nanmax([g["max_error_rad"] for g in growth])),
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


# the paper's own method (time and state in, state increment out), compared in its own column
LEGACY = {"paper": "hybrid paper"}


def correction_inputs(airframe: Airframe, ds: Dataset, config: ReproduceConfig, log
                      ) -> tuple[Airframe | None, Path | None, dict]:
    """The identified airframe and the safe correction trained on top of it, with where they
    come from: by default the pair shipped with the package (made by ``python -m
    training.ship_safe`` from this dataset recipe); with ``retrain`` the physics is identified
    on the train split and the correction trained here."""
    if config.retrain:
        if not config.identify:
            return None, None, {"missing": "not requested (--no-identify)"}
        identified, identification = identify_physics(airframe, ds, config, log)
        if identified is None:
            return None, None, identification
        path = obtain_weights(identified, ds, "improved", config, log)
        identification["history"] = str(Path(config.out) / "weights" /
                                        f"{identified.name}_improved_history.json")
        identification["correction"] = (str(path) if path else
                                        "training kept no correction (see the history)")
        return identified, path, identification
    try:
        identified = shipped_identified(airframe.name)
    except WeightFileError as exc:
        return None, None, {"missing": str(exc)}
    try:
        path, _ = shipped_correction(airframe.name)
    except WeightFileError:
        path = None
    names = list(IDENTIFY_PARAMS[airframe.kind])
    history = shipped_history(airframe.name)
    return identified, path, {
        "history": str(history) if history else None,
        "source": "shipped with the package (python -m training.ship_safe on this dataset "
                  "recipe: identified on the calm train sorties, correction trained on top)",
        "file": str(identified.origin), "params": names,
        "correction": str(path) if path else (
            f"none shipped: {not_kept_reason(airframe.name) or 'no weights'}"),
        "estimates": [{"name": n, "nominal": getattr(airframe.params, n),
                       "value": getattr(identified.params, n)} for n in names]}


def legacy_models(airframe: Airframe, ds: Dataset, config: ReproduceConfig, log
                  ) -> dict[str, tuple[ca.Function, Airframe, Path]]:
    """The paper's own formulation, compared with the default (SPEC section 4), on the nominal
    ``airframe``: that is
    what their shipped weights sit on, and the ``paper`` formulation cannot carry the actuator
    states an identified airframe may have. Label -> (step, airframe it runs on, weight file).
    Skipped with ``quick`` unless retraining."""
    if config.quick and not config.retrain:
        return {}
    out = {}
    for formulation, label in LEGACY.items():
        path = obtain_weights(airframe, ds, formulation, config, log)
        if path is not None:
            out[label] = (hybrid_step(path, airframe, compile=False), airframe, path)
    return out


def ladder_name(rung) -> str:
    """A ladder model's row name in the tables: its label and step size."""
    return f"{rung.label} @ {rung.solver.dt:.3g} s"


def table1_candidates(airframe: Airframe, rungs, legacy: dict, dts
                      ) -> dict[str, list[Candidate]]:
    """Table 1's solvers per target: the ladder at its step, physics at the other step sizes,
    and the paper's formulation at every step it accepts."""
    data, reference = [], []
    for rung in rungs:
        data.append(Candidate(Solver(ladder_name(rung), rung.solver.model, rung.solver.dt),
                              rung.airframe,
                              "nominal" if rung.airframe is airframe else "identified"))
    for dt in dts:
        for rung in rungs[:1]:  # the nominal physics at the other step sizes
            if abs(dt - rung.solver.dt) > 1e-12:
                data.append(Candidate(Solver(f"{rung.label} @ {dt:g} s", rung.solver.model,
                                             dt), rung.airframe,
                                      "nominal" if rung.airframe is airframe else "identified"))
        reference.append(Candidate(Solver(f"nominal physics @ {dt:g} s",
                                          rungs[0].solver.model, dt), airframe, "nominal"))
    for label, (step, owner, _) in legacy.items():
        data += [Candidate(Solver(f"{label} @ {dt:g} s", step, dt), owner,
                            "nominal" if owner is airframe else "identified")
                  for dt in dts if usable(step, dt)]
    return {"data": data, "reference": reference}


def _bar(config: ReproduceConfig, total: int, desc: str):
    return tqdm(total=total, desc=desc, disable=not config.progress, unit="run",
                mininterval=1.0)


def run_airframe(name: str, config: ReproduceConfig, log) -> dict:
    """Everything for one airframe: dataset, the nominal -> identified -> corrected ladder
    (headline, per sortie, against horizon), Tables 1-4, work-precision, figures."""

    from uavdyn.experiments import cost, figures

    airframe = load_airframe(name)
    out = Path(config.out)
    log(f"[{airframe.name}] dataset ...")
    ds = dataset_for(name, config)
    test = ds.test
    identified, correction, identification = correction_inputs(airframe, ds, config, log)
    rungs, ladder_missing = ladder_rungs(airframe, identified, correction,
                                         why_no_correction=identification.get("correction"))
    bar = _bar(config, len(test) * len(rungs), f"[{airframe.name}] ladder per sortie")
    predictions: dict = {}
    rows = per_sortie_rows(rungs, test, progress=bar.update, keep=predictions)
    known = {(ladder_name(r), sortie): res for r in rungs for (label, sortie), res
             in predictions.items() if label == r.label}
    bar.close()
    legacy = legacy_models(airframe, ds, config, log)
    candidates = table1_candidates(airframe, rungs, legacy, config.dts)
    bar = _bar(config, len(test) * (len(candidates["data"]) + len(candidates["reference"])),
               f"[{airframe.name}] Table 1")
    table1 = accuracy_tables(airframe, test, candidates,
                             out / "trajectories" if config.save_trajectories else None,
                             bar.update, known)
    bar.close()
    weight_files = {"corrected": correction or identification.get("history"),
                    **{k: v[2] for k, v in legacy.items()}}
    table2 = convergence_table(weight_files)
    calm = [s for s in test if condition(s) == "calm"] or test
    models = {r.label: (r.solver.model, r.airframe) for r in rungs[1:]}
    models.update({k: (v[0], v[1]) for k, v in legacy.items()})
    bar = _bar(config, 1, f"[{airframe.name}] cost (interleaved timing)")  # sized by the study
    timing = cost.cost_study(airframe, calm[0], models, repeats=config.cost_repeats,
                             segment_s=config.cost_segment_s, progress=bar.update)
    bar.close()
    log(f"[{airframe.name}] Table 4 ...")
    table4 = robustness_table(airframe, ds, rungs, config, predictions)
    result = {"airframe": airframe.name, "kind": airframe.kind,
              "dataset": {"path": str(ds.path), "sorties": len(ds.sorties),
                          "test_sorties": [s.name for s in test],
                          "sample_rate_hz": ds.sample_rate_hz},
              "ladder": {"dt": rungs[0].solver.dt, "models": [r.label for r in rungs],
                         "missing": ladder_missing, "per_sortie": rows,
                         "headline": headline(rows), "horizons": horizon_curves(rows)},
              "weights": {k: (str(v) if v else None) for k, v in weight_files.items()},
              "identification": identification,
              "table1": table1, "table2": table2, "cost": timing, "table4": table4}
    log(f"[{airframe.name}] figures ...")
    result["figures"] = figures.make_all(airframe, ds, rungs, legacy, result, out,
                                         predictions)
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
    results["size_bytes"] = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    log(f"wrote {out / 'report.md'} and {out / 'metrics.json'} "
        f"(total {results['wall_s']:.0f} s, {results['size_bytes'] / 1e6:.1f} MB)")
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
    solvers = [Candidate(Solver(f"{label} @ {dt:g} s", physics_step(af), dt), af, physics)
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
    ladder = _evaluation_ladder(airframe, identified, weights, sorties)
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
                                        sortie_params(cand.airframe, s.altitude_m))
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
            "per_sortie": safety, "ladder": ladder}


def _evaluation_ladder(airframe: Airframe, identified: Airframe | None, weights: list,
                       sorties: list[Sortie]) -> dict:
    """The report's ladder on a user's dataset, at the log interval: nominal physics,
    identified physics and the first weight file ("corrected", on the airframe it was
    trained on), per sortie, against horizon, and the headline with bootstrap intervals."""
    dt = float(np.median(np.diff(sorties[0].time)))
    rungs = [Rung(NOMINAL_PHYSICS, Solver(NOMINAL_PHYSICS, physics_step(airframe), dt),
                  airframe)]
    missing = {}
    if identified is not None:
        rungs.append(Rung(IDENTIFIED_PHYSICS, Solver(IDENTIFIED_PHYSICS,
                                                     physics_step(identified), dt), identified))
    else:
        missing[IDENTIFIED_PHYSICS] = "no --identified airframe given"
    if weights:
        net = load_weights(weights[0])
        owner = next(af for af in (identified, airframe)
                     if af is not None and af.param_hash() == net.airframe_hash)
        step = hybrid_step(net, owner, compile=False)
        why = refusal(step, dt)
        if why is None:
            rungs.append(Rung("corrected", Solver("corrected", step, dt), owner))
        else:
            missing["corrected"] = why
        if len(weights) > 1:
            missing["other weights"] = ("the ladder takes the first weight file; the others "
                                        "are in Table 1 and the per-sortie comparison")
    else:
        missing["corrected"] = "no --weights given"
    rows = per_sortie_rows(rungs, sorties)
    return {"dt": dt, "models": [r.label for r in rungs], "missing": missing,
            "per_sortie": rows, "headline": headline(rows), "horizons": horizon_curves(rows)}


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
    outside the correction's training envelope (where its gate is below 1). Where a sortie has
    no true states the ratio compares the errors with its pitch noise taken off
    (:func:`uavdyn.flightdata.excess_rmse`, ``pitch_noise_std`` in the row)."""
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
            p = sortie_params(cand.airframe, s.altitude_m)
            truth = target_states(s)
            rh = evaluate_trajectory(cand.solver, s.time, truth, s.controls, p)
            rp = evaluate_trajectory(physics.solver, s.time, truth, s.controls, p)
            # against records (no truth in the data) the ratio compares errors with the
            # sortie's pitch noise taken off; noise pulls raw ratios towards 1
            noise = 0.0 if s.true_states is not None else pitch_noise_std(s.time, s.states)
            row = {"sortie": s.name, "condition": condition(s), "pitch_noise_std": noise}
            for mode in ("horizon_1s", "free_run"):
                a, b = _pitch_rmse(rp, mode), _pitch_rmse(rh, mode)
                row[f"{mode}_physics"], row[f"{mode}_corrected"] = a, b
                row[f"{mode}_ratio"] = sortie_ratio(a, b, noise)
            row["worse"] = [m for m in ("horizon_1s", "free_run")
                            if is_worse(row[f"{m}_ratio"])]
            if net is not None and net.envelope is not None:
                z = cand.solver.model.initial_state(s.states, s.controls, p,
                                                    float(np.median(np.diff(s.time))))
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
             + (", ".join(result["weights"]) or "none"), ""]
    if result.get("ladder"):
        lines += ["## Headline", "", "Pitch RMSE in rad at the log interval, pooled over the "
                  "sorties of a group [95 % bootstrap over sorties].", ""]
        lines += headline_lines(result) + ["", "## Error against horizon", ""]
        lines += _horizons(result) + ["## Per sortie (pitch RMSE, rad)", ""]
        lines += _per_sortie(result)
    lines += ["## Table 1: accuracy", ""]
    lines += _table1(result) + ["## Table 4: robustness (free run, dt = 0.005 s)", ""]
    lines += _table4(result)
    for entry in result.get("per_sortie", []):
        lines += ["", f"## Per sortie: {entry['correction']} against {entry['physics']}", "",
                  f"Worse than its physics at 1 s on {entry['worse_at_1s']} of "
                  f"{len(entry['sorties'])} sorties, over the free run on "
                  f"{entry['worse_free_run']}.", "",
                  "Ratios compare errors against the truth where the data have it; against "
                  "records, with the pitch noise estimated from them (d theta/dt = q) taken off.",
                  "",
                  "| sortie | condition | 1 s: physics | corrected | ratio | free run: physics "
                  "| corrected | ratio | pitch noise taken off | outside envelope | worse |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in entry["sorties"]:
            def f(v):
                return "n/a" if v is None else f"{v:.4g}"
            outside = r.get("outside_envelope")
            lines.append(
                f"| {r['sortie']} | {r['condition']} | {f(r['horizon_1s_physics'])} | "
                f"{f(r['horizon_1s_corrected'])} | {f(r['horizon_1s_ratio'])} | "
                f"{f(r['free_run_physics'])} | {f(r['free_run_corrected'])} | "
                f"{f(r['free_run_ratio'])} | {r.get('pitch_noise_std', 0.0):.2g} | "
                f"{'n/a' if outside is None else f'{100 * outside:.1f} %'} | "
                f"{'**' + ', '.join(r['worse']) + '**' if r['worse'] else ''} |")
    return "\n".join(lines)
