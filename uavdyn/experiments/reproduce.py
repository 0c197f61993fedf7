"""``uavdyn reproduce``: the validation pipeline. For every airframe: the emulated dataset,
the nominal -> identified -> corrected ladder on the held-out test sorties (headline, per
sortie, against horizon), the paper's Table 1 (accuracy), Table 2 (convergence), Table 3
(cost), Table 4 (robustness), Figures 2-6 and a work-precision diagram, written as Markdown,
JSON and PNG under one folder.

Numbers are measured, never copied: the paper's figures appear only in their own column, as the
paper's. Saved trajectories (``trajectories/*.npz``) let anyone recompute the accuracy metrics.
Each prediction is made once per run (:class:`~uavdyn.experiments.predictions.PredictionStore`)
and read by the ladder, the tables and the figures.

The pieces live in their own modules (:mod:`~uavdyn.experiments.data`,
:mod:`~uavdyn.experiments.tables`, :mod:`~uavdyn.experiments.evaluate`,
:mod:`~uavdyn.experiments.report`); their public names are importable from here too.
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from uavdyn.airframes import Airframe, load_airframe
from uavdyn.evaluation import Solver
from uavdyn.experiments.common import condition, provenance, usable
from uavdyn.experiments.config import ReproduceConfig
from uavdyn.experiments.data import (
    LEGACY,
    RECIPES,
    correction_inputs,
    dataset_cache_folder,
    dataset_cache_key,
    dataset_for,
    identify_physics,
    legacy_models,
    obtain_weights,
    weights_path,
)
from uavdyn.experiments.evaluate import evaluate_dataset
from uavdyn.experiments.ladder import headline, horizon_curves, ladder_rungs, per_sortie_rows
from uavdyn.experiments.predictions import Candidate, PredictionStore
from uavdyn.experiments.report import evaluation_markdown, write_report
from uavdyn.experiments.tables import (
    accuracy_tables,
    convergence_table,
    per_sortie_safety,
    perturbed_sorties,
    robustness_rows,
)
from uavdyn.flightdata import Dataset, Sortie
from uavdyn.integrate import cache_dir
from uavdyn.interrupts import CheckedBar
from uavdyn.outputs import output_folder

__all__ = ["PAPER", "ReproduceConfig", "run", "run_airframe", "table1_candidates",
           "cache_lines", "folder_bytes",
           "ladder_name", "robustness_scenarios", "json_default",
           # defined in the modules of each concept, importable from here as before
           "LEGACY", "RECIPES", "Candidate", "accuracy_tables", "convergence_table",
           "correction_inputs", "dataset_cache_key", "dataset_for", "evaluate_dataset",
           "evaluation_markdown", "identify_physics", "legacy_models", "obtain_weights",
           "per_sortie_safety", "perturbed_sorties", "weights_path"]

PAPER = {"rmse": 1.82e-3, "mae": 1.47e-3, "max": 2.31e-3, "cost_reduction": 0.38,
         "rk4_0.001_ms": 148.0, "rk4_0.0005_ms": 287.0, "hybrid_0.005_ms": 92.0}


def ladder_name(rung: Candidate) -> str:
    """A ladder model's row name in the tables: its label and step size."""
    return f"{rung.label} @ {rung.solver.dt:.3g} s"


def table1_candidates(airframe: Airframe, rungs: list[Candidate], legacy: dict, dts
                      ) -> dict[str, list[Candidate]]:
    """Table 1's models per target: the ladder at its step, physics at the other step sizes,
    and the paper's formulation at every step it accepts (against the flight data); the
    nominal physics at every step size (against the fine-step reference)."""
    data = [rung.named(ladder_name(rung)) for rung in rungs]
    reference = []
    nominal = rungs[0]
    for dt in dts:
        if abs(dt - nominal.solver.dt) > 1e-12:  # the nominal physics at the other step sizes
            data.append(Candidate(Solver(f"{nominal.label} @ {dt:g} s", nominal.solver.model,
                                         dt), nominal.airframe, nominal.physics,
                                  nominal.key[0]))
        reference.append(Candidate(Solver(f"{nominal.label} @ {dt:g} s",
                                          nominal.solver.model, dt), airframe, "nominal",
                                   nominal.key[0]))
    for label, (step, owner, _) in legacy.items():
        data += [Candidate(Solver(f"{label} @ {dt:g} s", step, dt), owner,
                           "nominal" if owner is airframe else "identified", label)
                 for dt in dts if usable(step, dt)]
    return {"data": data, "reference": reference}


def robustness_scenarios(airframe: Airframe, ds: Dataset, quick: bool = False
                         ) -> dict[str, tuple[list[Sortie], str]]:
    """Table 4's scenarios: the calm test sorties, the high-angle-of-attack test sorties
    (fixed wing only) and sorties flown by a truth model whose stability derivatives and mass
    terms are 15 % off (the models keep their own parameters). Only test sorties are scored;
    a group with none is reported missing, never filled with training or validation
    sorties."""
    test = [s for s in ds.test if condition(s) != "turbulent"]
    scenarios = {"nominal (calm test sorties)": (test, "no calm test sortie in the dataset")}
    if airframe.kind == "fixed_wing":  # alpha is meaningless for a hovering multirotor
        high = [s for s in ds.test if s.mission == "high_alpha"]
        scenarios["alpha > 20 deg (high-alpha test sorties)"] = (
            high, "no high-alpha test sortie in the dataset")
    missions = [s.mission for s in (test or ds.test)][:4 if not quick else 2]
    scenarios["+15 % stability derivatives and mass"] = (perturbed_sorties(
        airframe, missions, (test or ds.test)[0].duration if ds.test else 20.0),
        "no test sortie to take the missions from")
    return scenarios


def _bar(config: ReproduceConfig, total: int, desc: str):
    return CheckedBar(total=total, desc=desc, disable=not config.progress, unit="run",
                      mininterval=1.0)


def _cost(airframe: Airframe, test: list[Sortie], rungs: list[Candidate], legacy: dict,
          config: ReproduceConfig) -> dict:
    """Table 3 and the work-precision points: one interleaved timing run on the first calm
    test sortie, for the nominal physics and every other model."""
    from uavdyn.experiments import cost

    calm = [s for s in test if condition(s) == "calm"] or test
    models = {r.label: (r.solver.model, r.airframe) for r in rungs[1:]}
    models.update({k: (v[0], v[1]) for k, v in legacy.items()})
    with _bar(config, 1, f"[{airframe.name}] cost (interleaved timing)") as bar:  # resized
        return cost.cost_study(airframe, calm[0], models, repeats=config.cost_repeats,
                               segment_s=config.cost_segment_s, progress=bar.update)


def run_airframe(name: str, config: ReproduceConfig, log) -> dict:
    """Everything for one airframe: dataset, the nominal -> identified -> corrected ladder
    (headline, per sortie, against horizon), Tables 1-4, work-precision, figures."""

    from uavdyn.experiments import figures

    airframe = load_airframe(name)
    out = Path(config.out)
    log(f"[{airframe.name}] dataset ...")
    ds = dataset_for(name, config)
    test = ds.test
    identified, correction, identification = correction_inputs(airframe, ds, config, log)
    rungs, ladder_missing = ladder_rungs(airframe, identified, correction,
                                         why_no_correction=identification.get("correction"))
    store = PredictionStore(airframe)
    with _bar(config, len(test) * len(rungs), f"[{airframe.name}] ladder per sortie") as bar:
        rows = per_sortie_rows(rungs, test, store, progress=bar.update)
    legacy = legacy_models(airframe, ds, config, log)
    candidates = table1_candidates(airframe, rungs, legacy, config.dts)
    with _bar(config, len(test) * (len(candidates["data"]) + len(candidates["reference"])),
              f"[{airframe.name}] Table 1") as bar:
        table1 = accuracy_tables(test, candidates, store,
                                 out / "trajectories" if config.save_trajectories else None,
                                 bar.update)
    weight_files = {"corrected": correction or identification.get("history"),
                    **{k: v[2] for k, v in legacy.items()}}
    table2 = convergence_table(weight_files)
    timing = _cost(airframe, test, rungs, legacy, config)
    log(f"[{airframe.name}] Table 4 ...")
    table4 = robustness_rows(robustness_scenarios(airframe, ds, config.quick),
                             [r.named(ladder_name(r)) for r in rungs], store)
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
    result["figures"] = figures.make_all(airframe, ds, rungs, legacy, result, out, store)
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
        (tmp / "metrics.json").write_text(json.dumps(
            _portable(results, tmp, out, config.cache), indent=2, default=json_default) + "\n")
        write_report(results, tmp / "report.md")
    results = _relocate(results, str(tmp) + os.sep, str(out) + os.sep)
    results["size_bytes"] = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    log(f"wrote {out / 'report.md'} and {out / 'metrics.json'} "
        f"(total {results['wall_s']:.0f} s, {results['size_bytes'] / 1e6:.1f} MB)")
    return results


def folder_bytes(folder: str | Path) -> int:
    """Bytes of the files under ``folder`` (0 if it does not exist)."""
    folder = Path(folder)
    return sum(f.stat().st_size for f in folder.rglob("*") if f.is_file()) \
        if folder.is_dir() else 0


def cache_lines(cache: str | Path | None = None) -> list[str]:
    """Where the pipeline's caches live and their size now: the compile cache
    (:func:`uavdyn.integrate.cache_dir`, ``$UAVDYN_CACHE``) and the dataset cache
    (``cache``: ``uavdyn reproduce --cache``, default inside the compile cache). Both are
    rebuilt when deleted."""
    compiled, datasets = cache_dir(), dataset_cache_folder(cache)

    def size(folder: Path, minus: int = 0) -> str:
        if not folder.is_dir():
            return "not created"
        return f"{(folder_bytes(folder) - minus) / 1e6:.1f} MB"

    inside = datasets.resolve().is_relative_to(compiled.resolve())
    return ["caches (deleting them is safe: they are rebuilt, slower, on the next run):",
            f"  compiled steps: {compiled} ("
            + size(compiled, folder_bytes(datasets) if inside else 0)
            + (" without the datasets in it" if inside and datasets.is_dir() else "")
            + "; $UAVDYN_CACHE moves it)",
            f"  datasets: {datasets} ({size(datasets)}; --cache moves it)"]


def _portable(results: dict, tmp: Path, out: Path, cache: str | None) -> dict:
    """``results`` as ``metrics.json`` holds them: paths relative to the output folder, the
    dataset cache and the package (no absolute path of the machine that ran it)."""
    relative = _relocate(results, str(tmp) + os.sep, "")
    relative = _relocate(relative, str(out).rstrip(os.sep) + os.sep, "")
    for folder, label in ((cache, "<dataset cache>/"), (cache_dir(), "<uavdyn cache>/")):
        if folder:
            relative = _relocate(relative, str(folder).rstrip(os.sep) + os.sep, label)
            relative = _relocate(relative, str(Path(folder).resolve()) + os.sep, label)
    return _relocate(relative, str(Path(__file__).resolve().parents[1]) + os.sep,
                     "<uavdyn package>/")


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


def json_default(value):
    """``default=`` of :func:`json.dumps` for the results: NumPy scalars and arrays as Python
    numbers and lists, anything else as its text."""
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return str(value)


_json = json_default  # the name ``uavdyn.cli.app`` imports
