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
from uavdyn.experiments.common import condition, hybrid_steps, target_states  # noqa: E402
from uavdyn.integrate import physics_step  # noqa: E402


def _solvers(airframe: Airframe, nets: dict, dt: float = 0.005,
             net_airframe: Airframe | None = None) -> list[tuple[Solver, str, np.ndarray]]:
    """(solver, style, parameters): the nominal physics, and each flight-data correction on
    the airframe its weights were trained on (``net_airframe``, default ``airframe``)."""
    styles = {"hybrid improved": "C3-", "hybrid paper": "C2:"}
    base = net_airframe or airframe
    out = [(Solver("RK4 nominal physics", physics_step(airframe), dt), "C0--", airframe.p)]
    out += [(Solver(name, step, dt), styles.get(name, "C4-."), base.p)
            for name, step in hybrid_steps(base, nets).items()]
    return out


def _save(fig, path: Path) -> str:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return str(path)


def time_histories(airframe: Airframe, sortie, nets: dict, out: Path,
                   net_airframe: Airframe | None = None) -> dict[str, str]:
    """Figures 2 and 3: pitch angle and pitch rate against time on one test sortie."""

    truth = target_states(sortie)
    runs = [(s, style, evaluate_trajectory(s, sortie.time, truth, sortie.controls, p))
            for s, style, p in _solvers(airframe, nets, net_airframe=net_airframe)]
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


def loss_history(airframe: Airframe, nets: dict, out: Path) -> str | None:
    """Figure 4: training and validation loss per epoch of each network."""
    fig, ax = plt.subplots(figsize=(8, 4.5))
    drawn = False
    for (formulation, target), path in nets.items():
        if path is None:
            continue
        hist_path = Path(path).with_name(Path(path).stem + "_history.json")
        if not hist_path.exists():
            continue
        hist = json.loads(hist_path.read_text())["history"]
        ep = [h["epoch"] for h in hist]
        for key, style in (("train_one_step", "-"), ("val_total", "--")):
            vals = [h.get(key) for h in hist]
            pts = [(e, v) for e, v in zip(ep, vals) if v is not None]
            if pts:
                ax.semilogy(*zip(*pts), style, label=f"{formulation}/{target} {key}")
                drawn = True
    if not drawn:
        plt.close(fig)
        return None
    ax.set_xlabel("epoch")
    ax.set_ylabel("loss (relative to physics-only error)")
    ax.set_title(f"Fig. 4: training history, {airframe.name}")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    return _save(fig, out / f"fig4_{airframe.name}.png")


def cost_bars(airframe: Airframe, table3: dict, out: Path) -> str:
    """Figure 5: wall time of each solver on the same sortie (log scale)."""
    rows = table3["rows"]
    fig, ax = plt.subplots(figsize=(9, 0.45 * len(rows) + 1.5))
    names = [f"{r['solver']}" + (f" @ {r['dt']:g} s" if r["dt"] else "") for r in rows]
    ax.barh(names, [r["wall_ms"] for r in rows],
            color=["C3" if "hybrid" in n else "C0" for n in names])
    ax.set_xscale("log")
    ax.set_xlabel(f"wall time for one {table3['duration_s']:.0f} s sortie (ms, median)")
    ax.set_title(f"Fig. 5: cost, {airframe.name}")
    ax.invert_yaxis()
    ax.grid(alpha=0.3, axis="x")
    return _save(fig, out / f"fig5_{airframe.name}.png")


def error_distribution(airframe: Airframe, sorties: list, nets: dict, out: Path,
                       net_airframe: Airframe | None = None) -> str:
    """Figure 6: distribution of free-run pitch errors over the test sorties, and each sortie's
    maximum error (the envelope), RK4 against the hybrid."""

    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 4.5))
    mode = "free_run" if airframe.kind == "fixed_wing" else "horizon_1s"
    for k, (solver, style, p) in enumerate(_solvers(airframe, nets, net_airframe=net_airframe)):
        errs, maxima = [], []
        for s in sorties:
            res = evaluate_trajectory(solver, s.time, target_states(s), s.controls, p)
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
    ax2.set_xticklabels([s.mission[:10] for s in sorties], rotation=70, fontsize=7)
    ax2.set_ylabel("max |pitch error| per sortie (deg)")
    ax2.set_title("Fig. 6b: error envelope per test sortie")
    for a in (ax, ax2):
        a.legend(fontsize=8)
        a.grid(alpha=0.3)
    return _save(fig, out / f"fig6_{airframe.name}.png")


def work_precision_plot(airframe: Airframe, points: list[dict], out: Path) -> str:
    """Error against wall time, every solver family and step size, two targets."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    families = sorted({p["family"] for p in points})
    for i, fam in enumerate(families):
        pts = sorted((p for p in points if p["family"] == fam), key=lambda p: p["wall_ms"])
        for ax, key in zip(axes, ("theta_rmse_vs_flight", "theta_rmse_vs_reference")):
            ax.loglog([p["wall_ms"] for p in pts], [max(p[key], 1e-16) for p in pts], "o-",
                      color=f"C{i}", label=fam)
            for p in pts:
                ax.annotate(f"{p['dt']:g}", (p["wall_ms"], max(p[key], 1e-16)), fontsize=6)
    mode = points[0]["flight_mode"].replace("_", " ") if points else ""
    axes[0].set_title(f"{airframe.name}: vs flight data (true states, {mode})", fontsize=9)
    axes[1].set_title(f"{airframe.name}: vs baseline fine-step reference (free run)", fontsize=9)
    for ax in axes:
        ax.set_xlabel("wall time per sortie (ms, compiled)")
        ax.set_ylabel("pitch RMSE (rad)")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    return _save(fig, out / f"work_precision_{airframe.name}.png")


def make_all(airframe: Airframe, ds, nets: dict, result: dict, out: Path,
             net_airframe: Airframe | None = None) -> dict[str, str]:
    """Every figure for one airframe; returns name -> PNG path."""

    out = Path(out)
    test = ds.test
    calm = [s for s in test if condition(s) == "calm"] or test
    paths = time_histories(airframe, calm[0], nets, out, net_airframe)
    fig4 = loss_history(airframe, nets, out)
    if fig4:
        paths["fig4"] = fig4
    paths["fig5"] = cost_bars(airframe, result["table3"], out)
    paths["fig6"] = error_distribution(airframe, test, nets, out, net_airframe)
    paths["work_precision"] = work_precision_plot(airframe, result["work_precision"], out)
    return paths
