"""``uavdyn evaluate``: Table 1, Table 4, the report's ladder and the per-sortie comparison of
each correction with its physics, on any dataset folder in the interchange format, for the
nominal airframe, an identified one and any weight files (each run on the airframe it was
trained on). Every prediction is made once (:class:`PredictionStore`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.evaluation import Solver
from uavdyn.experiments.common import (
    IDENTIFIED_PHYSICS,
    NOMINAL_PHYSICS,
    refusal,
    target_states,
)
from uavdyn.experiments.ladder import headline, horizon_curves, per_sortie_rows
from uavdyn.experiments.predictions import Candidate, PredictionStore
from uavdyn.experiments.tables import accuracy_tables, per_sortie_safety, robustness_rows
from uavdyn.flightdata import Sortie, load_dataset
from uavdyn.integrate import DiscreteModel, fitting_steps, physics_step, substeps_for
from uavdyn.learned import WeightFileError, hybrid_step, load_weights

TABLE1_DTS = (0.005, 0.01, 0.02)  # Table 1's step sizes (the paper's)
LADDER_MAX_DT = 0.01  # the ladder's step: the log interval, in whole sub-steps of at most this


def evaluate_dataset(airframe: Airframe, dataset: str | Path, weights: list[str | Path],
                     dts: tuple[float, ...] | None = None, split: str = "test",
                     identified: Airframe | None = None, all_sorties: bool = False) -> dict:
    """Table 1 and Table 4 figures on any dataset folder in the interchange format (its
    ``split`` sorties, or all if it has no split): the ladder of nominal physics, identified
    physics (``identified``, an airframe fitted by ``uavdyn identify``) and each hybrid weight
    file, run on the airframe its weights were trained on (checked by hash).

    A dataset without ``split`` sorties is an error (its sorties may be the ones a model was
    fitted on) unless ``all_sorties``. With ``all_sorties`` every sortie is scored, whatever
    its split (train, validation and test alike), and the result says so and how many of each
    split it scored.
    The solver steps are Table 1's (``dts``) where they fit the log interval, else the nearest
    whole fraction of it (:func:`~uavdyn.integrate.fitting_steps`): the data are never
    resampled."""

    ds = load_dataset(dataset)
    if ds.kind != airframe.kind:
        raise ValueError(f"dataset {dataset} is of kind '{ds.kind}' but airframe "
                         f"'{airframe.name}' is '{airframe.kind}'")
    # turning-flight sorties carry the lateral inputs: every model scored takes them too
    airframe = airframe.for_inputs(ds.lateral)
    if identified is not None:
        identified = identified.for_inputs(ds.lateral)
    sorties = ds.sorties if all_sorties else ds.split(split)
    if not sorties:
        raise ValueError(f"{dataset}: no '{split}' sorties (manifest split column); give "
                         "--all-sorties to score every sortie (the result then says so)")
    dts = fitting_steps(sorties[0].dt, dts or TABLE1_DTS)
    physics = physics_rungs(airframe, identified)
    nets = [load_weights(w) for w in weights]
    hybrids = [_hybrid(w, net, physics) for w, net in zip(weights, nets)]
    names = [Path(h.path).name for h in hybrids]
    hybrids = [replace(h, shown=str(h.path)) if names.count(Path(h.path).name) > 1 else h
               for h in hybrids]  # two files of one name: their rows name the paths
    candidates = [Candidate(Solver(f"{label} @ {dt:g} s", physics_step(af), dt), af, tag,
                            label) for label, af, tag in physics for dt in dts]
    candidates += [h.at(dt) for h in hybrids for dt in dts]
    store = PredictionStore(airframe)
    table1 = accuracy_tables(sorties, {"data": candidates, "reference": [
        c for c in candidates if c.physics == "nominal"]}, store)
    safety = per_sortie_safety(candidates, sorties, nets, store)
    ladder = _evaluation_ladder(airframe, identified, hybrids, sorties, store)
    table4 = robustness_rows(_robustness_scenarios(airframe, sorties),
                             [c for c in candidates if c.solver.dt == dts[0]], store)
    return {"airframe": airframe.name, "kind": airframe.kind, "dataset": str(dataset),
            "sorties": [s.name for s in sorties],
            "split": _scored_text(sorties, split) if all_sorties else split,
            "identified": identified.origin if identified is not None else None,
            "weights": [str(w) for w in weights], "table1": table1, "table4": table4,
            "per_sortie": safety, "ladder": ladder}


def _scored_text(sorties: list[Sortie], split: str) -> str:
    """What ``--all-sorties`` scored: every sortie, with its splits counted (the train ones
    are those a model may have been fitted on)."""
    counts = {}
    for s in sorties:
        counts[s.split or "no split"] = counts.get(s.split or "no split", 0) + 1
    parts = ", ".join(f"{n} {name}" for name, n in counts.items())
    return (f"all sorties: {len(sorties)} ({parts}; not only '{split}': those of train may "
            "be the ones a model was fitted on)")


def physics_rungs(airframe: Airframe, identified: Airframe | None
                  ) -> list[tuple[str, Airframe, str]]:
    """(label, airframe, physics tag) of the physics models: the nominal airframe, and the
    identified one where given (of the same kind)."""
    rungs = [(NOMINAL_PHYSICS, airframe, "nominal")]
    if identified is not None:
        if identified.kind != airframe.kind:
            raise ValueError(f"identified airframe '{identified.name}' is a {identified.kind}, "
                             f"airframe '{airframe.name}' a {airframe.kind}")
        rungs.append((IDENTIFIED_PHYSICS, identified, "identified"))
    return rungs


@dataclass(frozen=True)
class _Hybrid:
    """One weight file's hybrid step on the airframe its weights were trained on."""

    path: str | Path
    step: DiscreteModel
    airframe: Airframe
    physics: str  # "nominal" or "identified"
    formulation: str
    shown: str = ""  # how the file is named in rows: its name, or its path where two share one

    @property
    def name(self) -> str:
        shown = self.shown or Path(self.path).name
        return f"hybrid {self.formulation} ({shown}) on {self.physics} physics"

    def at(self, dt: float, name: str | None = None) -> Candidate:
        """The hybrid at ``dt`` as a candidate (row ``name``, default ``<name> @ <dt> s``);
        its model is named by the full path, so two files of one name stay apart."""
        model = f"hybrid {self.formulation} ({self.path}) on {self.physics} physics"
        return Candidate(Solver(name or f"{self.name} @ {dt:g} s", self.step, dt),
                         self.airframe, self.physics, model)


def _hybrid(path, net, physics: list[tuple[str, Airframe, str]]) -> _Hybrid:
    owners = [(af, tag) for _, af, tag in physics if af.param_hash() == net.airframe_hash]
    if not owners:
        names = " or ".join(f"'{af.name}'" for _, af, _ in physics)
        raise WeightFileError(f"{path}: weights trained on airframe hash {net.airframe_hash}, "
                              f"which is neither {names}: give the airframe they were "
                              "trained on (--airframe or --identified)")
    af, tag = owners[-1]  # the identified airframe where both match
    return _Hybrid(path, hybrid_step(net, af, compile=False), af, tag, net.formulation)


def _robustness_scenarios(airframe: Airframe, sorties: list[Sortie]
                          ) -> dict[str, tuple[list[Sortie], str]]:
    """Table 4's scenarios on a user's dataset: every evaluated sortie, and (fixed wing) the
    sorties whose angle of attack passes 20 deg."""
    scenarios = {"nominal (all evaluated sorties)": (sorties, "no sortie")}
    if airframe.kind == "fixed_wing":  # alpha is meaningless for a hovering multirotor
        high = []
        for s in sorties:
            x = target_states(s)
            if float(np.degrees(np.max(np.arctan2(x[:, 1], x[:, 0])))) > 20.0:
                high.append(s)
        scenarios["alpha > 20 deg (sorties that reach it)"] = (high, "no sortie")
    return scenarios


def _evaluation_ladder(airframe: Airframe, identified: Airframe | None, hybrids: list,
                       sorties: list[Sortie], store: PredictionStore) -> dict:
    """The report's ladder on a user's dataset, at the log interval: nominal physics,
    identified physics and the first weight file ("corrected", on the airframe it was
    trained on), per sortie, against horizon, and the headline with bootstrap intervals."""
    sample_dt = float(np.median(np.diff(sorties[0].time)))
    dt = sample_dt / substeps_for(sample_dt, LADDER_MAX_DT)
    rungs = [Candidate(Solver(NOMINAL_PHYSICS, physics_step(airframe), dt), airframe)]
    missing = {}
    if identified is not None:
        rungs.append(Candidate(Solver(IDENTIFIED_PHYSICS, physics_step(identified), dt),
                               identified, "identified"))
    else:
        missing[IDENTIFIED_PHYSICS] = "no --identified airframe given"
    if hybrids:
        why = refusal(hybrids[0].step, sample_dt)  # it was trained one step per sample
        if why is None:
            rungs.append(hybrids[0].at(sample_dt, "corrected"))
        else:
            missing["corrected"] = why
        if len(hybrids) > 1:
            missing["other weights"] = ("the ladder takes the first weight file; the others "
                                        "are in Table 1 and the per-sortie comparison")
    else:
        missing["corrected"] = "no --weights given"
    rows = per_sortie_rows(rungs, sorties, store)
    return {"dt": dt, "models": [r.label for r in rungs], "missing": missing,
            "per_sortie": rows, "headline": headline(rows), "horizons": horizon_curves(rows)}
