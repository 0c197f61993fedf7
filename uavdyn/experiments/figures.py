"""Figures of the validation report (the paper's Figures 2-6 and a work-precision diagram),
drawn from measured results with matplotlib's non-interactive backend.
"""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from uavdyn.airframes import Airframe  # noqa: E402
from uavdyn.evaluation import Solver, evaluate_trajectory  # noqa: E402
from uavdyn.experiments.common import condition, target_states  # noqa: E402
from uavdyn.integrate import StepUseError, check_use  # noqa: E402

STYLES = {"nominal physics": "C0--", "identified physics": "C1-", "corrected": "C3-",
          "hybrid paper": "C2:"}


def _solvers(rungs, legacy: dict) -> list[tuple[Solver, str, np.ndarray]]:
    """(solver, style, parameters): the ladder's models, and the earlier flight-data
    formulation (``paper``) at the ladder's step where it accepts it, each on the airframe its
    weights were trained on."""
    out = [(r.solver, STYLES.get(r.label, "C4-."), r.airframe.p) for r in rungs]
    dt = rungs[0].solver.dt
    for label, (step, owner, _) in legacy.items():
        if "numerical" in label:
            continue
        for d in (dt, 0.005):
            solver = Solver(label, step, d)
            try:
                check_use(step, d, 0.0, 0.0)
            except StepUseError:
                continue
            out.append((solver, STYLES.get(label, "C4-."), owner.p))
            break
    return out


def _save(fig, path: Path) -> str:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return str(path)


def _predict(solver: Solver, sortie, p, known: dict | None) -> dict:
    """The solver's predictions on a sortie: the pipeline's own where it made them already."""
    res = (known or {}).get((solver.name, sortie.name))
    if res is None:
        res = evaluate_trajectory(solver, sortie.time, target_states(sortie), sortie.controls, p)
    return res


def time_histories(airframe: Airframe, sortie, models: list, out: Path,
                   known: dict | None = None) -> dict[str, str]:
    """Figures 2 and 3: pitch angle and pitch rate against time on one test sortie."""

    truth = target_states(sortie)
    runs = [(s, style, _predict(s, sortie, p, known)) for s, style, p in models]
    # An open-loop quadrotor is neutrally stable in pitch: a whole-sortie replay of the logged
    # commands drifts away for any model short of the truth, so show 1 s predictions there.
    mode = "free_run" if airframe.kind == "fixed_wing" else "horizon_1s"
    how = ("free run from the first state" if mode == "free_run" else
           "1 s predictions restarted from the recorded state every second")
    paths = {}
    for number, idx, label, scale in ((2, 3, "pitch angle (deg)", np.degrees),
                                      (3, 2, "pitch rate (deg/s)", np.degrees)):
        fig, (ax, ax_err) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
        ax.plot(sortie.time, scale(truth[:, idx]), "k-", lw=1.2, label="flight data (true)")
        for solver, style, res in runs:
            if mode not in res:  # refused: outside the step's trained dt or time range
                ax.plot([], [], style, label=f"{solver.name}: not shown (outside its trained "
                                             "time range)")
                continue
            pred, targ = res[mode]
            t = res[f"{mode}_time"]
            ax.plot(t, scale(pred[:, idx]), style, lw=1, label=f"{solver.name} @ {solver.dt:g} s")
            ax_err.plot(t, scale(pred[:, idx] - targ[:, idx]), style, lw=1, label=solver.name)
        ax.set_ylabel(label)
        ax.set_title(f"Fig. {number}: {airframe.name}, {sortie.name} ({sortie.mission}), {how}",
                     fontsize=9)
        ax.legend(fontsize=8)
        ax_err.set_ylabel("error " + label[label.index("("):])
        ax_err.set_xlabel("time (s)")
        for a in (ax, ax_err):
            a.grid(alpha=0.3)
        paths[f"fig{number}"] = _save(fig, out / f"fig{number}_{airframe.name}.png")
    return paths


def loss_history(airframe: Airframe, weight_files: dict, out: Path) -> str | None:
    """Figure 4: the correction's training history, like against like: (a) the validation
    1 s pitch RMSE at the end of every epoch against the identified physics' own on the same
    sorties, (b) the rollout loss (relative to the physics: 1 = no improvement) on fixed
    training and validation windows after every epoch (older histories: the mean over each
    epoch's mini-batches, training only)."""
    path = weight_files.get("corrected")  # the weights, or the history of a run that kept none
    hist_path = (None if not path else Path(path) if str(path).endswith("_history.json")
                 else Path(path).with_name(Path(path).stem + "_history.json"))
    if hist_path is None or not hist_path.exists():
        return None
    doc = json.loads(hist_path.read_text())
    hist, kept = doc["history"], doc.get("kept", True)
    val = [(h["epoch"], h["val_theta_rmse"]) for h in hist if h.get("val_theta_rmse")]
    physics = next((h["physics_val_theta_rmse"] for h in hist
                    if h.get("physics_val_theta_rmse")), None)
    fixed = any("train_loss_fixed" in h for h in hist)
    key = "train_loss_fixed" if fixed else "train_loss"
    train = [(h["epoch"], h[key]) for h in hist if h.get(key) is not None]
    val_loss = [(h["epoch"], h["val_loss_fixed"]) for h in hist
                if h.get("val_loss_fixed") is not None]
    if not val:
        return None
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    ax.plot(*zip(*val), "C3o-", label="corrected (end of epoch)" + ("" if kept else
                                                                   ": not kept"))
    if physics:
        ax.axhline(physics, color="C1", ls="--", label="identified physics")
    ax.set_ylabel("validation 1 s pitch RMSE (rad)")
    ax.set_title(f"Fig. 4a: {airframe.name}, validation split, end of every epoch",
                 fontsize=9)
    if train:
        ax2.plot(*zip(*train), "C0o-", label="training windows")
        if val_loss:
            ax2.plot(*zip(*val_loss), "C3s-", label="validation windows")
        ax2.axhline(1.0, color="C1", ls="--", label="physics (= 1)")
    ax2.set_ylabel("rollout loss / physics loss")
    ax2.set_title("Fig. 4b: rollout loss on fixed windows after each epoch" if fixed else
                  "Fig. 4b: training loss, mean over each epoch's mini-batches", fontsize=9)
    for a in (ax, ax2):
        a.set_xlabel("epoch")
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    return _save(fig, out / f"fig4_{airframe.name}.png")


def error_vs_horizon(airframe: Airframe, curves: dict, out: Path) -> str | None:
    """Prediction error against horizon (log axes), one panel per condition: the pooled pitch
    RMSE of every model of the ladder and the spread over sorties (band: per-sortie
    quartiles; dots: per-sortie minimum and maximum)."""
    conditions = [c for c in ("calm", "turbulent") if c in curves]
    if not conditions:
        return None
    fig, axes = plt.subplots(1, len(conditions), figsize=(5.5 * len(conditions), 4.2),
                             squeeze=False, sharey=True)
    for ax, cond in zip(axes[0], conditions):
        for model, points in curves[cond].items():
            color = STYLES.get(model, "C4-")[:2]
            h = [p["horizon_s"] for p in points]
            ax.loglog(h, [p["pooled"] for p in points], "o-", color=color,
                      label=f"{model} (pooled)")
            ax.fill_between(h, [p["per_sortie_q1"] for p in points],
                            [p["per_sortie_q3"] for p in points], color=color, alpha=0.15,
                            lw=0)
            ax.plot(h, [p["per_sortie_max"] for p in points], "v", color=color, ms=3,
                    alpha=0.6)
        n = max(p["sorties"] for pts in curves[cond].values() for p in pts)
        ax.set_title(f"{airframe.name}, {cond} test sorties ({n})", fontsize=9)
        ax.set_xlabel("prediction horizon (s), restarted from the recorded state")
        ax.grid(alpha=0.3, which="both")
    axes[0][0].set_ylabel("pitch RMSE (rad); band: per-sortie quartiles, v: worst sortie")
    axes[0][0].legend(fontsize=8)
    return _save(fig, out / f"error_vs_horizon_{airframe.name}.png")


def error_distribution(airframe: Airframe, sorties: list, models: list, out: Path,
                       known: dict | None = None) -> str:
    """Figure 6: distribution of free-run pitch errors over the test sorties, and each sortie's
    maximum error (the envelope), RK4 against the hybrid."""

    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 4.5))
    mode = "free_run" if airframe.kind == "fixed_wing" else "horizon_1s"
    for k, (solver, style, p) in enumerate(models):
        errs, maxima = [], []
        for s in sorties:
            res = _predict(solver, s, p, known)
            if mode not in res:  # refused: outside the step's trained dt or time range
                continue
            pred, targ = res[mode]
            e = pred[:, 3] - targ[:, 3]
            e = e[np.isfinite(e)]
            errs.append(e)
            maxima.append(np.abs(e).max() if len(e) else np.nan)
        if not errs:
            ax.plot([], [], style[:2], label=f"{solver.name}: not shown (outside its trained "
                                             "time range)")
            continue
        allerr = np.degrees(np.concatenate(errs))
        ax.hist(allerr, bins=80, histtype="step", color=style[:2], label=solver.name)
        ax2.semilogy(np.arange(len(maxima)) + 0.1 * k, np.degrees(maxima), style[:2] + "o",
                     label=solver.name)
    ax.set_yscale("log")
    ax.set_xlabel(f"{mode.replace('_', ' ')} pitch error (deg)")
    ax.set_ylabel("samples")
    ax.set_title(f"Fig. 6a: error distribution, {airframe.name}")
    ax2.set_xticks(range(len(sorties)))
    ax2.set_xticklabels([f"{s.name} {s.mission} ({condition(s)})" for s in sorties],
                        rotation=75, fontsize=6)
    ax2.set_ylabel("max |pitch error| per sortie (deg)")
    ax2.set_title("Fig. 6b: error envelope per test sortie")
    for a in (ax, ax2):
        a.legend(fontsize=8)
        a.grid(alpha=0.3)
    return _save(fig, out / f"fig6_{airframe.name}.png")


def make_all(airframe: Airframe, ds, rungs, legacy: dict, result: dict, out: Path,
             known: dict | None = None) -> dict[str, str]:
    """Every figure for one airframe; returns name -> PNG path. ``known``: predictions the
    pipeline already made, ``{(model, sortie): result}``, reused instead of recomputed."""
    from uavdyn.experiments import cost

    out = Path(out)
    test = ds.test
    models = _solvers(rungs, legacy)
    calm = [s for s in test if condition(s) == "calm"] or test
    paths = {}
    horizon = error_vs_horizon(airframe, result["ladder"]["horizons"], out)
    if horizon:
        paths["error_vs_horizon"] = horizon
    paths.update(time_histories(airframe, calm[0], models, out, known))
    fig4 = loss_history(airframe, result["weights"], out)
    if fig4:
        paths["fig4"] = fig4
    paths["fig5"] = cost.cost_figure(airframe.name, result["cost"], out)
    paths["fig6"] = error_distribution(airframe, test, models, out, known)
    paths["work_precision"] = cost.work_precision_figure(airframe.name, result["cost"], out)
    return paths
