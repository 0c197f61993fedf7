"""The report's first question, measured: does fitting to flight data help, by how much and
where does it fail. Nominal physics -> identified physics -> corrected model on the held-out
test sorties, per sortie, against horizon, and the headline statistics with their spread.

Every figure of the headline is recomputed from the per-sortie rows (sum of squared pitch
error and sample count per sortie and model): :func:`headline` takes nothing else.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.evaluation import (
    Solver,
    SortieError,
    compare_paired,
    error_growth,
    error_share,
    pooled_with_interval,
    squared_error,
)
from uavdyn.experiments.common import IDENTIFIED_PHYSICS, NOMINAL_PHYSICS, condition
from uavdyn.experiments.predictions import Candidate, PredictionStore
from uavdyn.flightdata import Sortie
from uavdyn.integrate import physics_step
from uavdyn.learned import hybrid_step, load_weights

LADDER = (NOMINAL_PHYSICS, IDENTIFIED_PHYSICS, "corrected")
CONDITIONS = ("calm", "turbulent")
HEADLINE_MODES = {"horizon_1s": "1 s", "free_run": "free run"}
HORIZONS_S = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0)
# Sortie-by-sortie comparisons in the headline: each rung against the one below it.
PAIRED = {"identified_vs_nominal": (NOMINAL_PHYSICS, IDENTIFIED_PHYSICS),
          "corrected_vs_identified": (IDENTIFIED_PHYSICS, "corrected")}
WORSE_TOLERANCE = 0.10  # "never worse by more than 10 % on any sortie" (the safe rule)


def ladder_rungs(nominal: Airframe, identified: Airframe | None,
                 correction: str | Path | None, dt: float | None = None,
                 why_no_correction: str | None = None
                 ) -> tuple[list[Candidate], dict[str, str]]:
    """The three models at one step size (the correction's trained step; ``dt`` when there is
    no correction), and why any rung is missing. Each rung's row name is its label.

    Parameters
    ----------
    nominal
        The airframe as the user wrote it.
    identified
        The airframe with parameters identified from the train split (None: missing).
    correction
        Weights of the safe correction trained on top of ``identified`` (None: missing).
    """
    missing: dict[str, str] = {}
    net = None
    if correction is not None and identified is not None:
        net = load_weights(correction, identified)
        dt = net.dt
    elif correction is None:
        missing["corrected"] = why_no_correction or "no correction (none shipped, or " \
                                                    "training did not keep one)"
    else:
        missing["corrected"] = "no identified physics for the correction to run on"
    dt = float(dt if dt is not None else 0.01)
    rungs = [Candidate(Solver(NOMINAL_PHYSICS, physics_step(nominal), dt), nominal)]
    if identified is not None:
        rungs.append(Candidate(Solver(IDENTIFIED_PHYSICS, physics_step(identified), dt),
                               identified, "identified"))
    else:
        missing[IDENTIFIED_PHYSICS] = "identification not run or refused"
    if net is not None:
        rungs.append(Candidate(Solver("corrected", hybrid_step(net, identified, compile=False),
                                      dt), identified, "identified"))
    return rungs, missing


def _error(pair) -> dict:
    sse, n = squared_error(*pair)
    return {"sse": sse, "n": n}


def per_sortie_rows(rungs: list[Candidate], sorties: list[Sortie], store: PredictionStore,
                    horizons_s=HORIZONS_S, progress=None) -> list[dict]:
    """One row per (sortie, model): pitch squared-error sums and counts for one step, 1 s
    windows, the whole-sortie free run and every horizon of ``horizons_s``, the free run's
    departure time (pitch error above 0.5 rad) and the reason for any mode the step refused.
    The row's model is the rung's label; the predictions come from ``store`` (made there
    once, for the tables that pool them too)."""
    rows = []
    for s in sorties:
        for rung in rungs:
            res = store.trajectory(rung, s)
            row = {"sortie": s.name, "mission": s.mission, "condition": condition(s),
                   "model": rung.label, "dt": rung.solver.dt}
            for mode in ("one_step", "horizon_1s", "free_run"):
                if mode in res:
                    row[mode] = _error(res[mode])
                else:
                    row.setdefault("refused", {})[mode] = res.get("refused", {}).get(
                        mode, "sortie shorter than one window")
            if "free_run" in res:
                growth = error_growth(res["free_run_time"], *res["free_run"])
                row["free_run_departure_s"] = growth["time_to_divergence_s"]
            try:
                curve = store.horizons(rung, s, horizons_s)
            except ValueError as exc:  # StepUseError is a ValueError: the step refuses
                row.setdefault("refused", {})["horizons"] = str(exc)
                curve = {}
            row["horizons"] = {f"{h:g}": _error(pair) for h, pair in curve.items()}
            rows.append(row)
            if progress:
                progress()
    return rows


def _sortie_errors(rows: list[dict], model: str, mode: str, horizon: str | None = None
                   ) -> list[SortieError]:
    out = []
    for r in rows:
        if r["model"] != model:
            continue
        cell = r.get("horizons", {}).get(horizon) if horizon else r.get(mode)
        if cell is not None:
            out.append(SortieError(r["sortie"], cell["sse"], cell["n"]))
    return out


def _conditions(rows: list[dict], conditions) -> tuple[str, ...]:
    """The groups to report: ``conditions`` if given; else calm and turbulent (each reported,
    missing or not) when the data are labelled so, plus any other label present."""
    if conditions is not None:
        return tuple(conditions)
    present = tuple(dict.fromkeys(r["condition"] for r in rows))
    if any(c in CONDITIONS for c in present):
        return CONDITIONS + tuple(c for c in present if c not in CONDITIONS)
    return present


def headline(rows: list[dict], conditions=None) -> list[dict]:
    """Per condition and headline mode: each model's pooled pitch RMSE with its 95 % bootstrap
    interval over sorties, the identified physics against the nominal and the corrected model
    against the identified physics sortie by sortie (sorties worse, worse by more than 10 %,
    free runs diverging only in the upper rung).
    Computed from ``rows`` (:func:`per_sortie_rows`) only. A condition with no sortie is
    listed with ``missing``."""
    models = [m for m in LADDER if any(r["model"] == m for r in rows)]
    out = []
    for cond in _conditions(rows, conditions):
        members = [r for r in rows if r["condition"] == cond]
        sorties = sorted({r["sortie"] for r in members})
        if not sorties:
            out.append({"condition": cond, "missing": f"no {cond} test sortie"})
            continue
        for mode, label in HEADLINE_MODES.items():
            entry = {"condition": cond, "mode": mode, "label": label,
                     "sorties": len(sorties), "models": {}}
            errors = {m: _sortie_errors(members, m, mode) for m in models}
            for m in models:
                if errors[m]:
                    entry["models"][m] = pooled_with_interval(errors[m]).to_dict()
                    if mode == "free_run":  # pitch error above 0.5 rad: the run has left
                        times = [r.get("free_run_departure_s") for r in members
                                 if r["model"] == m and "free_run" in r]
                        left = [t for t in times if t is not None]
                        entry["models"][m]["departed"] = len(left)
                        entry["models"][m]["median_departure_s"] = (
                            float(np.median(left)) if left else None)
            for key, (base, model) in PAIRED.items():
                a, b = errors.get(base), errors.get(model)
                if a and b and len(a) == len(b):
                    entry[key] = compare_paired(a, b, WORSE_TOLERANCE).to_dict()
                    entry[key]["share_removed"] = error_share(a, b).to_dict()
            out.append(entry)
    return out


def horizon_curves(rows: list[dict], conditions=None) -> dict:
    """Pooled pitch RMSE and the per-sortie spread (min, quartiles, max of per-sortie RMSE)
    per condition, model and horizon: the data of the error-against-horizon figure."""
    out: dict = {}
    horizons = sorted({h for r in rows for h in r.get("horizons", {})}, key=float)
    for cond in _conditions(rows, conditions):
        members = [r for r in rows if r["condition"] == cond]
        for model in LADDER:
            points = []
            for h in horizons:
                errors = _sortie_errors(members, model, "", h)
                finite = [e.rmse for e in errors if e.finite]
                if not errors:
                    continue
                pooled = pooled_with_interval(errors)
                q = (np.percentile(finite, [0, 25, 50, 75, 100]).tolist() if finite
                     else [math.nan] * 5)
                points.append({"horizon_s": float(h), "pooled": pooled.rmse,
                               "ci": [pooled.low, pooled.high], "diverged": pooled.diverged,
                               "per_sortie_min": q[0], "per_sortie_q1": q[1],
                               "per_sortie_median": q[2], "per_sortie_q3": q[3],
                               "per_sortie_max": q[4], "sorties": len(errors)})
            if points:
                out.setdefault(cond, {})[model] = points
    return out


def per_sortie_rmse(rows: list[dict], mode: str) -> dict[str, dict[str, float]]:
    """``{sortie: {model: pitch RMSE}}`` of one mode (inf where the model diverged)."""
    out: dict = {}
    for r in rows:
        cell = r.get(mode)
        if cell is not None:
            out.setdefault(r["sortie"], {})[r["model"]] = SortieError(
                r["sortie"], cell["sse"], cell["n"]).rmse
    return out
