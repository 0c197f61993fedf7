"""Figures of the validation report (the paper's Figures 2-6 and a work-precision diagram),
drawn from measured results with matplotlib's non-interactive backend.
"""

from __future__ import annotations

import json
import math
import textwrap
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from matplotlib.ticker import FuncFormatter  # noqa: E402

from uavdyn.airframes import Airframe  # noqa: E402
from uavdyn.evaluation import Solver  # noqa: E402
from uavdyn.experiments.common import (  # noqa: E402
    condition,
    flight_mode,
    history_path,
    target_states,
)
from uavdyn.experiments.cost import (  # noqa: E402
    CVODES,
    EMULATOR,
    FAMILY_ORDER,
    NOMINAL,
    NOMINAL_VM,
)
from uavdyn.experiments.predictions import Candidate, PredictionStore  # noqa: E402
from uavdyn.integrate import StepUseError  # noqa: E402

STYLES = {"nominal physics": "C0--", "identified physics": "C1-", "corrected": "C3-",
          "hybrid paper": "C2:"}


def _models(rungs: list[Candidate], legacy: dict) -> list[tuple[Candidate, str]]:
    """(model, style): the ladder's models, and the earlier flight-data formulation
    (``paper``) at the ladder's step where it accepts it, else at 0.005 s, each on the
    airframe its weights were trained on."""
    out = [(r, STYLES.get(r.label, "C4-.")) for r in rungs]
    dt = rungs[0].solver.dt
    for label, (step, owner, _) in legacy.items():
        for d in (dt, 0.005):
            try:
                step.check_use(d, 0.0, 0.0)
            except StepUseError:
                continue
            physics = "nominal" if owner is rungs[0].airframe else "identified"
            out.append((Candidate(Solver(label, step, d), owner, physics, label),
                        STYLES.get(label, "C4-.")))
            break
    return out


def _save(fig, path: Path, layout: bool = True) -> str:
    """Write ``fig`` as PNG (``layout``: tight layout first) and close it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if layout:
        fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return str(path)


def time_histories(airframe: Airframe, sortie, models: list[tuple[Candidate, str]], out: Path,
                   store: PredictionStore) -> dict[str, str]:
    """Figures 2 and 3: pitch angle and pitch rate against time on one test sortie."""

    truth = target_states(sortie)
    runs = [(m.solver, style, store.trajectory(m, sortie)) for m, style in models]
    # An open-loop quadrotor is neutrally stable in pitch: a whole-sortie replay of the logged
    # commands drifts away for any model short of the truth, so show 1 s predictions there.
    mode = flight_mode(airframe.kind)
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
        ax.set_title(f"Fig. {number}: {airframe.name}, test sortie {sortie.name} "
                     f"({sortie.mission}, {condition(sortie)}), {how}", fontsize=9, wrap=True)
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
    hist_path = history_path(path) if path else None
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
    axes[0][0].set_ylabel("pitch RMSE (rad)")
    axes[0][0].legend(fontsize=8)
    fig.suptitle(f"Prediction error against horizon, {airframe.name}, held-out test split: "
                 "lines pooled RMSE, band per-sortie quartiles, v worst sortie", fontsize=9,
                 wrap=True)
    return _save(fig, out / f"error_vs_horizon_{airframe.name}.png")


def error_distribution(airframe: Airframe, sorties: list, models: list[tuple[Candidate, str]],
                       out: Path, store: PredictionStore) -> str:
    """Figure 6: distribution of free-run pitch errors over the test sorties, and each sortie's
    maximum error (the envelope), RK4 against the hybrid."""

    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 4.5))
    mode = flight_mode(airframe.kind)
    for k, (model, style) in enumerate(models):
        solver = model.solver
        errs, maxima = [], []
        for s in sorties:
            res = store.trajectory(model, s)
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
    ax.set_title(f"Fig. 6a: {airframe.name}, pitch error over the {len(sorties)} test sorties",
                 fontsize=9)
    ax2.set_xticks(range(len(sorties)))
    ax2.set_xticklabels([f"{s.name}\n{s.mission}\n{condition(s)}" for s in sorties],
                        rotation=30 if len(sorties) > 6 else 0, fontsize=7,
                        ha="right" if len(sorties) > 6 else "center")
    ax2.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:.3g}"))
    ax2.yaxis.set_minor_formatter(FuncFormatter(lambda v, _: f"{v:.3g}"))
    ax2.set_ylabel("max |pitch error| per sortie (deg)")
    ax2.set_title(f"Fig. 6b: {airframe.name}, worst pitch error of each test sortie",
                  fontsize=9)
    for a in (ax, ax2):
        a.legend(fontsize=8)
        a.grid(alpha=0.3)
    return _save(fig, out / f"fig6_{airframe.name}.png")


def _families(study: dict) -> list[str]:
    """Families in drawing order: nominal physics, the models, then the reference solvers."""
    names = list(dict.fromkeys(p["family"] for p in study["points"]))
    first = [f for f in (NOMINAL, NOMINAL_VM) if f in names]
    last = [f for f in FAMILY_ORDER[2:] if f in names]
    return first + [f for f in names if f not in first + last] + last


def work_precision_figure(airframe_name: str, study: dict, out_dir: str | Path) -> str:
    """The work-precision diagram of one :func:`uavdyn.experiments.cost.cost_study`: pitch
    RMSE against median wall time (log-log), one line per family (points ordered by time),
    two panels (against the flight data; free run against the fine-step reference). The
    legend lists only families with a drawable point in the figure; points without a finite
    positive error are counted in a footnote.

    Returns
    -------
    str
        Path of ``work_precision_<airframe_name>.png`` in ``out_dir``.
    """
    markers = "osD^v<>ph*Xd"
    fig, axes = plt.subplots(1, 2, figsize=(12, 5.2), sharex=True)
    handles: dict[str, object] = {}
    dropped = []
    mode = study.get("flight_mode", "free_run").replace("_", " ")
    for i, fam in enumerate(_families(study)):
        pts = sorted((p for p in study["points"] if p["family"] == fam),
                     key=lambda p: p["median_ms"])
        style = {"color": f"C{i % 10}", "marker": markers[i % len(markers)], "ms": 5, "lw": 1.2}
        for ax, key in zip(axes, ("theta_rmse_vs_flight", "theta_rmse_vs_reference")):
            ok = [p for p in pts if p[key] is not None and math.isfinite(p[key]) and p[key] > 0]
            dropped += [f"{p['label']} ({'flight' if 'flight' in key else 'reference'})"
                        for p in pts if p not in ok]
            if ok:
                (line,) = ax.loglog([p["median_ms"] for p in ok], [p[key] for p in ok],
                                    label=fam, **style)
                handles.setdefault(fam, line)
    fig.suptitle(f"Work-precision, {airframe_name}: free runs of the first "
                 f"{study['segment_s']:g} s of test sortie {study['sortie']}", fontsize=10)
    axes[0].set_title(f"{airframe_name}: against the flight data (true states, {mode})",
                      fontsize=9)
    axes[1].set_title(f"{airframe_name}: free run against the nominal fine-step reference",
                      fontsize=9)
    for ax in axes:
        low, high = ax.get_ylim()
        if 0 < low and high < 10 * low:  # within a decade: 0.0265, not 2.65x10^-2
            ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:.3g}"))
            ax.yaxis.set_minor_formatter(FuncFormatter(lambda v, _: f"{v:.3g}"))
        ax.set_xlabel(f"median wall time of the {study['segment_s']:g} s segment (ms, "
                      f"{study['repeats']} interleaved repeats)")
        ax.set_ylabel("pitch RMSE (rad)")
        ax.grid(alpha=0.3, which="both")
    fig.legend(list(handles.values()), list(handles), loc="lower center",
               bbox_to_anchor=(0.5, 0.025),
               ncol=min(4, max(1, len(handles))), fontsize=8, frameon=False)
    notes = "points along a line: step sizes or tolerances of one family, ordered by time"
    if dropped:
        notes += f"; not drawn (error zero or not finite): {', '.join(dropped)}"
    fig.text(0.01, 0.005, notes, fontsize=7, wrap=True)
    rows = math.ceil(len(handles) / 4)
    fig.tight_layout(rect=(0, 0.04 + 0.045 * rows, 1, 0.95))
    return _save(fig, Path(out_dir) / f"work_precision_{airframe_name}.png", layout=False)


def cost_figure(airframe_name: str, study: dict, out_dir: str | Path) -> str:
    """Figure 5: Table 3 of one :func:`uavdyn.experiments.cost.cost_study` as horizontal bars
    of the median wall time (log scale) with the minimum as a marker, coloured by kind of
    solver, with a legend.

    Returns
    -------
    str
        Path of ``fig5_cost_<airframe_name>.png`` in ``out_dir``.
    """
    rows = [p for p in study["points"] if p["in_table3"]]
    kinds = {"nominal physics (RK4)": "C0", "other physics (RK4)": "C9",
             "corrected models": "C3", "reference solvers": "C7",
             "emulator (truth model)": "C2"}

    def kind(p: dict) -> str:
        if p["family"] in (NOMINAL, NOMINAL_VM):
            return "nominal physics (RK4)"
        if p["family"] == EMULATOR:
            return "emulator (truth model)"
        if p["family"] == CVODES or p["family"].startswith("scipy"):
            return "reference solvers"
        return "other physics (RK4)" if "physics" in p["family"] else "corrected models"

    fig, ax = plt.subplots(figsize=(10, 0.38 * len(rows) + 2.4))
    y = np.arange(len(rows))
    labels = [p["label"] + (" in the CasADi VM" if p["family"] == CVODES else "")
              for p in rows]
    ax.barh(y, [p["median_ms"] for p in rows], color=[kinds[kind(p)] for p in rows],
            alpha=0.8)
    ax.plot([p["min_ms"] for p in rows], y, "k|", ms=12, mew=2)
    ax.set_yticks(y, labels, fontsize=8)
    ax.set_xscale("log")
    ax.invert_yaxis()
    ax.set_xlabel(f"wall time of the {study['segment_s']:g} s segment of test sortie "
                  f"{study['sortie']} (ms)")
    ax.set_title(f"Fig. 5: cost, {airframe_name} ({study['harness']})", fontsize=9)
    ax.grid(alpha=0.3, axis="x", which="both")
    used = dict.fromkeys(kind(p) for p in rows)
    legend = [Patch(color=kinds[k], alpha=0.8, label=f"{k}: median") for k in used]
    legend.append(Line2D([], [], color="k", marker="|", ls="", ms=12, mew=2,
                         label=f"minimum of {study['repeats']}"))
    ax.legend(handles=legend, fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.09),
              ncol=3, frameon=False)
    fig.tight_layout()
    return _save(fig, Path(out_dir) / f"fig5_cost_{airframe_name}.png", layout=False)


def per_sortie_figure(result: dict, path: str | Path) -> Path:
    """The figure of ``uavdyn evaluate``: the 1 s pitch RMSE of every sortie, one bar per rung
    of the ladder (nominal physics, identified physics, corrected), log scale, from the
    result's per-sortie table (:func:`uavdyn.experiments.ladder.per_sortie_rmse`)."""
    from uavdyn.experiments.ladder import per_sortie_rmse

    lad = result["ladder"]
    rmse = per_sortie_rmse(lad["per_sortie"], "horizon_1s")
    models = lad["models"]
    rows = {r["sortie"]: r for r in lad["per_sortie"]}
    sorties = list(rmse)
    fig, ax = plt.subplots(figsize=(max(7.0, 1.0 + 0.55 * len(sorties) * len(models) / 2), 4.8),
                           constrained_layout=True)
    width = 0.8 / max(1, len(models))
    for k, model in enumerate(models):
        x = np.arange(len(sorties)) + (k - (len(models) - 1) / 2) * width
        vals = [rmse[s].get(model, np.nan) for s in sorties]
        ax.bar(x, [v if np.isfinite(v) else np.nan for v in vals], width,
               color=STYLES.get(model, "C4-")[:2], label=model)
        for xi, v in zip(x, vals):
            if v == np.inf:
                ax.annotate("diverged", (xi, 0), xycoords=("data", "axes fraction"),
                            rotation=90, ha="center", va="bottom", fontsize=7)
    finite = [v for s in sorties for v in rmse[s].values() if np.isfinite(v) and v > 0]
    if finite and max(finite) > 30 * min(finite):  # bars from zero unless decades apart
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:.3g}"))
    ax.set_xticks(range(len(sorties)))
    ax.set_xticklabels([f"{s}\n{rows[s]['mission']}\n{rows[s]['condition']}" for s in sorties],
                       rotation=30 if len(sorties) > 8 else 0, fontsize=7,
                       ha="right" if len(sorties) > 8 else "center")
    ax.set_ylabel("1 s pitch RMSE (rad)")
    ax.grid(alpha=0.3, axis="y", which="both")
    ax.legend(fontsize=8)
    ax.set_title("\n".join(textwrap.wrap(
        f"{result['airframe']} on {result['dataset']}, {result['split']} "
        f"({len(sorties)} sorties): 1 s pitch RMSE per sortie, predictions restarted from the "
        f"recorded state every second, step {fmt_dt(lad['dt'])} s", 100)), fontsize=9)
    path = Path(path)
    fig.savefig(path, dpi=100, format="png")
    plt.close(fig)
    return path


def fmt_dt(dt) -> str:
    return "n/a" if dt is None else f"{dt:g}"


def make_all(airframe: Airframe, ds, rungs: list[Candidate], legacy: dict, result: dict,
             out: Path, store: PredictionStore) -> dict[str, str]:
    """Every figure for one airframe; returns name -> PNG path. The predictions come from
    ``store`` (the ones the tables were made of)."""
    out = Path(out)
    test = ds.test
    models = _models(rungs, legacy)
    calm = [s for s in test if condition(s) == "calm"] or test
    paths = {}
    horizon = error_vs_horizon(airframe, result["ladder"]["horizons"], out)
    if horizon:
        paths["error_vs_horizon"] = horizon
    paths.update(time_histories(airframe, calm[0], models, out, store))
    fig4 = loss_history(airframe, result["weights"], out)
    if fig4:
        paths["fig4"] = fig4
    paths["fig5"] = cost_figure(airframe.name, result["cost"], out)
    paths["fig6"] = error_distribution(airframe, test, models, out, store)
    paths["work_precision"] = work_precision_figure(airframe.name, result["cost"], out)
    return paths
