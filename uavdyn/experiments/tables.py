"""The tables of the validation, built from a run's :class:`PredictionStore`: Table 1
(accuracy), Table 2 (convergence, from the training histories), Table 4 (robustness) and the
per-sortie comparison of each correction with the physics it sits on. Each table is a list or
dict of JSON-able rows; :mod:`uavdyn.experiments.report` writes them as Markdown.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from uavdyn.airframes import Airframe, perturb
from uavdyn.emulation import Emulator, plan_mission
from uavdyn.evaluation import MODES, error_growth, pooled_stats
from uavdyn.experiments.common import condition, history_path
from uavdyn.experiments.predictions import Candidate, PredictionStore
from uavdyn.flightdata import Sortie, pitch_noise_std
from uavdyn.learned.formulations import network_inputs
from uavdyn.learned.hybrid import correction_structure
from uavdyn.learned.rules import is_worse, sortie_ratio
from uavdyn.learned.stability import map_pitch_damping
from uavdyn.model import sortie_params

# ----------------------------------------------------------------------------- Table 1


def accuracy_tables(sorties: list[Sortie], candidates: dict[str, list[Candidate]],
                    store: PredictionStore, traj_dir: Path | None = None, progress=None
                    ) -> dict:
    """Table 1: pooled error statistics per target group, model and mode.

    Parameters
    ----------
    sorties : list of Sortie
        The scored sorties; each is in a flight-data group (by condition, where the data are
        labelled calm or turbulent) and in the group of the nominal fine-step reference.
    candidates : dict
        ``{"data": [...], "reference": [...]}``: the models scored against the flight data
        and against the reference.
    store : PredictionStore
        Where the predictions are made (once per model, step size, sortie and target).
    traj_dir : Path, optional
        Where to save every prediction as compressed npz (one file per group and model).
    progress : callable, optional
        Called once per (model, sortie).
    """
    groups: dict[str, list[tuple[Sortie, str]]] = {}
    for s in sorties:
        cond = condition(s)
        label = f"flight data ({cond})" if cond in ("calm", "turbulent") else "flight data"
        groups.setdefault(label, []).append((s, "data"))
        store.reference(s)
        groups.setdefault("baseline fine-step reference", []).append((s, "reference"))
    tables: dict = {}
    for label, members in groups.items():
        target = members[0][1]
        rows = []
        for cand in candidates[target]:
            saved = {s.name: store.trajectory(cand, s, tgt) for s, tgt in members}
            if progress:
                for _ in members:
                    progress()
            rows.append(_accuracy_row(cand, saved))
            if traj_dir is not None:
                _save_trajectories(traj_dir, store.nominal.name, label, cand.label, saved)
        tables[label] = {"target": target, "sorties": [m[0].name for m in members],
                         "rows": rows}
    return tables


def _accuracy_row(cand: Candidate, saved: dict[str, dict]) -> dict:
    """One row of Table 1: each mode pooled over the sorties, or missing with the reason;
    ``departed`` lists the sorties whose free run left the physical ranges (when and how)."""
    results = list(saved.values())
    row = {"solver": cand.label, "dt": cand.solver.dt, "physics": cand.physics}
    departed = {name: res["free_run_departure"] for name, res in saved.items()
                if "free_run_departure" in res}
    if departed:
        row["departed"] = departed
    for m in MODES:
        pairs = [res[m] for res in results if m in res]
        refusals = [res["refused"][m] for res in results
                    if m not in res and m in res.get("refused", {})]
        if pairs:
            row[m] = pooled_stats(pairs)
        elif refusals:  # reported as missing, with the reason
            row.setdefault("missing", {})[m] = refusals[0]
    return row


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
        hist_path = history_path(path)
        if not hist_path.exists():
            rows.append({"model": label, "weights": Path(path).name,
                         "note": "no training history saved"})
            continue
        rows.append(_convergence_row(label, Path(path), hist_path))
    return rows


def _convergence_row(label: str, path: Path, hist_path: Path) -> dict:
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
    return {
        "model": label, "weights": path.name,
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
    }


# ----------------------------------------------------------------------------- Table 4


def robustness_rows(scenarios: dict[str, tuple[list[Sortie], str]],
                    candidates: list[Candidate], store: PredictionStore) -> list[dict]:
    """Table 4: per scenario and model, the free run's pitch-error growth (mean slope over the
    sorties), its maximum error before divergence and how many runs diverged.

    Parameters
    ----------
    scenarios : dict
        ``{scenario: (sorties, why)}``; a scenario without sorties is reported missing with
        ``why``, never filled with other sorties.
    candidates : list of Candidate
        The models, each row named by its label.
    store : PredictionStore
        Where the predictions are made (once per model, step size and sortie).
    """
    rows = []
    for scenario, (sorties, why) in scenarios.items():
        for cand in candidates:
            head = {"scenario": scenario, "solver": cand.label, "sorties": len(sorties)}
            if not sorties:
                rows.append({**head, "missing": why})
                continue
            growth, refused = [], None
            for s in sorties:
                res = store.trajectory(cand, s)
                if "free_run" not in res:  # outside what the step was trained for
                    refused = res.get("refused", {}).get("free_run", "not evaluated")
                    break
                growth.append(error_growth(res["free_run_time"], *res["free_run"]))
            if refused:
                rows.append({**head, "missing": refused})
                continue
            rows.append({
                **head, "sortie_names": [s.name for s in sorties],
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


# ----------------------------------------------------------------------------- per sortie


def _pitch_rmse(res: dict, mode: str) -> float | None:
    if mode not in res:
        return None
    pred, targ = res[mode]
    with np.errstate(over="ignore", invalid="ignore"):
        value = float(np.sqrt(np.mean((pred[..., 3] - targ[..., 3]) ** 2)))
    return value if math.isfinite(value) else math.inf


def _safety_pairs(candidates: list[Candidate]) -> list[tuple[Candidate, Candidate]]:
    """(correction, the physics it sits on at the same step size): one step size per
    correction, the first listed."""
    pairs = []
    hybrids = [c for c in candidates if c.label.startswith("hybrid")]
    for k, cand in enumerate(hybrids):
        physics = next((c for c in candidates if c.physics == cand.physics
                        and not c.label.startswith("hybrid")
                        and c.solver.dt == cand.solver.dt), None)
        if physics is None or any(h.solver.dt < cand.solver.dt and h.label.split(" @ ")[0]
                                  == cand.label.split(" @ ")[0] for h in hybrids[:k]):
            continue
        pairs.append((cand, physics))
    return pairs


def per_sortie_safety(candidates: list[Candidate], sorties: list[Sortie], nets: list,
                      store: PredictionStore) -> list[dict]:
    """For every correction (at the sample interval, or the first step size it allows), per
    sortie: its pitch RMSE at 1 s and over the free run against the physics it sits on, the
    ratio corrected/physics, a flag where the correction is worse, and the share of samples
    outside the correction's training envelope (where its gate is below 1). Where a sortie has
    no true states the ratio compares the errors with its pitch noise taken off
    (:func:`uavdyn.flightdata.excess_rmse`, ``pitch_noise_std`` in the row)."""
    out = []
    for cand, physics in _safety_pairs(candidates):
        net = next((n for n in nets if n.airframe_hash == cand.airframe.param_hash()
                    and cand.label.startswith(f"hybrid {n.formulation}")), None)
        rows = [_safety_row(cand, physics, s, net, store) for s in sorties]
        out.append({"correction": cand.label, "physics": physics.label, "sorties": rows,
                    "worse_at_1s": sum("horizon_1s" in r["worse"] for r in rows),
                    "worse_free_run": sum("free_run" in r["worse"] for r in rows)})
    return out


def _safety_row(cand: Candidate, physics: Candidate, s: Sortie, net,
                store: PredictionStore) -> dict:
    rh, rp = store.trajectory(cand, s), store.trajectory(physics, s)
    # against records (no truth in the data) the ratio compares errors with the sortie's
    # pitch noise taken off; noise pulls raw ratios towards 1
    noise = 0.0 if s.true_states is not None else pitch_noise_std(s.time, s.states)
    row = {"sortie": s.name, "condition": condition(s), "pitch_noise_std": noise}
    for mode in ("horizon_1s", "free_run"):
        a, b = _pitch_rmse(rp, mode), _pitch_rmse(rh, mode)
        row[f"{mode}_physics"], row[f"{mode}_corrected"] = a, b
        row[f"{mode}_ratio"] = sortie_ratio(a, b, noise)
    row["worse"] = [m for m in ("horizon_1s", "free_run") if is_worse(row[f"{m}_ratio"])]
    if net is not None and net.envelope is not None:
        p = sortie_params(cand.airframe, s.altitude_m)
        dt = float(np.median(np.diff(s.time)))
        z = cand.solver.model.initial_state(s.states, s.controls, p, dt)
        layout = net.layout(correction_structure(cand.airframe, net.kind, net.formulation))
        inputs = network_inputs(layout, z, s.controls, p)[0]
        row["outside_envelope"] = net.envelope.fraction_outside(inputs)
        if net.envelope.steady is not None:  # --steady-gate on: where it held the network
            row["steady_held"] = net.envelope.fraction_steady_held(inputs)
        row["damping_reversed"] = _damping_reversed(cand, physics, s, p, z, dt)
    return row


def _damping_reversed(cand: Candidate, physics: Candidate, s: Sortie, p: np.ndarray,
                      z: np.ndarray, dt: float) -> float:
    """The share of the sortie's recorded states where the corrected step's pitch damping
    is positive beyond the physics' own (the sign the trainer's damping prior holds; ``z``
    the corrected step's states)."""
    z_physics = physics.solver.model.initial_state(s.states, s.controls, p, dt)
    hybrid = map_pitch_damping(cand.solver.model, z, s.controls, p, dt)
    own = map_pitch_damping(physics.solver.model, z_physics, s.controls, p, dt)
    return float(np.mean(hybrid > np.maximum(own, 0.0)))
