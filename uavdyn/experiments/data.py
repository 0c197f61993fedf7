"""What the validation pipeline runs on: the emulated dataset of each shipped recipe (cached),
the identified airframe and the correction trained on top of it (shipped, or made here with
``retrain``), and the paper's own formulation compared beside them.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import casadi as ca

from uavdyn.airframes import Airframe, load_airframe
from uavdyn.emulation.datagen import generate_dataset, generator_code_hash, shipped_recipe
from uavdyn.experiments.common import IDENTIFY_PARAMS, history_path, identification_sorties
from uavdyn.experiments.config import ReproduceConfig
from uavdyn.flightdata import Dataset, load_dataset
from uavdyn.integrate import cache_dir
from uavdyn.learned import (
    WeightFileError,
    hybrid_step,
    not_kept_reason,
    save_weights,
    shipped_correction,
    shipped_history,
    shipped_identified,
    shipped_weights,
)

RECIPES = {"quadrotor": "datagen_quadrotor", "fixed_wing": "datagen_fixed_wing"}
# the paper's own method (time and state in, state increment out), compared in its own column
LEGACY = {"paper": "hybrid paper"}

# ----------------------------------------------------------------------------- datasets


def dataset_cache_key(recipe) -> str:
    """The cache key of a generated dataset: its recipe and the generator's code and version."""
    return hashlib.sha256((json.dumps(recipe.to_dict(), sort_keys=True) +
                           generator_code_hash()).encode()).hexdigest()[:12]


def dataset_cache_folder(cache: str | Path | None) -> Path:
    """Where the pipeline keeps its generated datasets: ``cache`` (``uavdyn reproduce
    --cache``) or ``datasets/`` in the compile cache (:func:`uavdyn.integrate.cache_dir`)."""
    return Path(cache or cache_dir() / "datasets")


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
    folder = dataset_cache_folder(config.cache) / f"{airframe_name}_{key}"
    if not (folder / "manifest.json").exists():
        folder.parent.mkdir(parents=True, exist_ok=True)  # the cache is ours to create
        generate_dataset(recipe, folder, progress=config.progress, force=True)
    return load_dataset(folder)


# ----------------------------------------------------------------------------- weights


def weights_path(airframe: Airframe, formulation: str, config: ReproduceConfig) -> Path:
    """Where the weights of the paper's formulation live: ``<airframe>_paper.npz`` shipped
    with the package, or in ``config.weights_dir``."""
    if config.weights_dir is None:
        try:
            return shipped_weights(airframe.name, formulation)
        except WeightFileError:
            return Path(f"<no shipped {airframe.name} {formulation} weights>")
    return Path(config.weights_dir) / f"{airframe.name}_{formulation}.npz"


def obtain_weights(airframe: Airframe, ds: Dataset, formulation: str,
                   config: ReproduceConfig, log) -> Path | None:
    """Shipped weights, or freshly trained ones with ``retrain`` (needs torch) on the physics of
    ``airframe`` (the identified airframe by default): the safe trainer for ``improved``, the
    formulation's own trainer otherwise. None where there are none (or training kept none)."""
    if not config.retrain:
        path = weights_path(airframe, formulation, config)
        return path if path.exists() else None
    out = Path(config.out) / "weights" / f"{airframe.name}_{formulation}.npz"
    out.parent.mkdir(parents=True, exist_ok=True)
    if formulation == "improved":
        return _train_safe(airframe, ds, formulation, config, log, out)
    return _train_formulation(airframe, ds, formulation, config, log, out)


def _train_safe(airframe: Airframe, ds: Dataset, formulation: str, config: ReproduceConfig,
                log, out: Path) -> Path | None:
    from uavdyn.learned.safe import SafeConfig, train_safe, write_safe_history

    cfg = SafeConfig(progress=config.progress)
    if config.quick:
        cfg.epochs, cfg.max_seconds, cfg.batches_per_epoch = 3, 60.0, 3
    log(f"training the safe {formulation} correction for {airframe.name} ...")
    result = train_safe(ds.train, ds.validation, airframe, cfg)
    write_safe_history(result, history_path(out),
                       f"{airframe.name} on the emulated dataset ({len(ds.train)} train, "
                       f"{len(ds.validation)} validation sorties)")
    if not result.kept:
        log(f"[{airframe.name}] correction not kept: {result.reason}")
        return None
    save_weights(result.net, out)
    return out


def _train_formulation(airframe: Airframe, ds: Dataset, formulation: str,
                       config: ReproduceConfig, log, out: Path) -> Path:
    from uavdyn.learned.train import TrainConfig, train, write_history

    cfg = TrainConfig(formulation=formulation, progress=config.progress)
    if config.quick:
        cfg.epochs, cfg.max_seconds = 8, 40.0
    log(f"training {formulation} weights for {airframe.name} ...")
    result = train(ds.train, ds.validation, airframe, cfg)
    save_weights(result.net, out)
    write_history(result, history_path(out),
                  f"{airframe.name} on the emulated dataset ({len(ds.train)} train, "
                  f"{len(ds.validation)} validation sorties)")
    return out


# ----------------------------------------------------------------------------- identification


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
                              "std_error": e.std_error,
                              "std_error_corrected": e.std_error_corrected,
                              "flags": e.flags()} for e in result.estimates],
               "flagged_pairs": [list(p) for p in result.flagged_pairs],
               "validation_theta_rmse": (result.fit.get("validation") or {}).get("theta_rmse"),
               "fitted_on": f"{len(fit_on)} {which} sorties",
               "window_s": result.window_s}
    return fitted, summary


def correction_inputs(airframe: Airframe, ds: Dataset, config: ReproduceConfig, log
                      ) -> tuple[Airframe | None, Path | None, dict]:
    """The identified airframe and the safe correction trained on top of it, with where they
    come from: by default the pair shipped with the package (made by ``python -m
    training.ship_safe`` from this dataset recipe); with ``retrain`` the physics is identified
    on the train split and the correction trained here."""
    if not config.retrain:
        return _shipped_inputs(airframe)
    if not config.identify:
        return None, None, {"missing": "not requested (--no-identify)"}
    identified, identification = identify_physics(airframe, ds, config, log)
    if identified is None:
        return None, None, identification
    path = obtain_weights(identified, ds, "improved", config, log)
    identification["history"] = str(history_path(
        Path(config.out) / "weights" / f"{identified.name}_improved.npz"))
    identification["correction"] = (str(path) if path else
                                    "training kept no correction (see the history)")
    return identified, path, identification


def _shipped_inputs(airframe: Airframe) -> tuple[Airframe | None, Path | None, dict]:
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
    ``airframe``: that is what their shipped weights sit on, and the ``paper`` formulation
    cannot carry the actuator states an identified airframe may have. Label -> (step,
    airframe it runs on, weight file). Skipped with ``quick`` unless retraining."""
    if config.quick and not config.retrain:
        return {}
    out = {}
    for formulation, label in LEGACY.items():
        path = obtain_weights(airframe, ds, formulation, config, log)
        if path is not None:
            out[label] = (hybrid_step(path, airframe, compile=False), airframe, path)
    return out
