"""The record of a safe-correction training run: its history, validation figures and
stability check as JSON, and a PNG of the validation pitch error and losses per epoch."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

from uavdyn.learned.safe.config import SafeResult


def write_safe_history(result: SafeResult, path, data: str = "") -> tuple[Path, Path]:
    """The run's history, validation figures and stability check as JSON (``path``) and a PNG
    beside it (validation pitch RMSE per epoch against the physics, training loss, penalty;
    ``data``: the airframe and dataset, for its title), put in place together
    (:func:`uavdyn.outputs.atomic_files`)."""
    from uavdyn.outputs import atomic_files

    path = Path(path)
    png = path.with_suffix(".png")
    with atomic_files(path, png) as (json_tmp, png_tmp):
        write_safe_history_files(result, json_tmp, png_tmp, data)
    return path, png


def write_safe_history_files(result: SafeResult, json_path: Path, png_path: Path,
                             data: str = "") -> None:
    """Write the record of :func:`write_safe_history` to exactly these paths (temporary names
    that the caller renames into place with :func:`uavdyn.outputs.atomic_files`, with the
    weights they belong to)."""
    doc = {"kind": "safe correction training", "kept": result.kept, "reason": result.reason,
           "config": asdict(result.config), "best_epoch": result.best_epoch,
           "epochs_run": len(result.history) - 1, "stopped": result.stopped,
           "screened": result.screened, "start_fits": result.start_fits,
           "seconds": result.seconds, "validation": result.validation,
           "stability": result.stability.to_dict() if result.stability else None,
           "network": result.net.describe() if result.net is not None else None,
           "history": result.history}
    Path(json_path).write_text(json.dumps(doc, indent=2, default=str) + "\n")
    _plot(result, png_path, data)


def _plot(result: SafeResult, png_path: Path, data: str) -> None:
    """Validation pitch RMSE per epoch against the physics, training loss and penalty; the
    title says what was trained on what, and whether it was kept and why."""
    import textwrap

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, MaxNLocator, NullFormatter

    epochs = [h["epoch"] for h in result.history]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), constrained_layout=True)
    horizon = result.validation.get("selection_horizon_s", 1)
    ax = axes[0]
    ax.plot(epochs, [h["val_theta_rmse"] for h in result.history], "C0-o", ms=3,
            label="corrected (validation)")
    ax.axhline(result.history[0]["physics_val_theta_rmse"], color="k", ls="--",
               label="physics alone (validation)")
    ax.axvline(result.best_epoch, color="grey", lw=0.8, label=f"best epoch {result.best_epoch}")
    ax.set_ylabel(f"pitch RMSE at {horizon:g} s (rad)")
    ax.set_title(f"validation split: {horizon:g} s pitch RMSE after each epoch", fontsize=9)
    ax = axes[1]
    rest = result.history[1:]
    if rest:
        ax.semilogy([h["epoch"] for h in rest], [h["train_loss"] for h in rest], "C1-o", ms=3,
                    label="train loss (physics = 1)")
        for key, style in (("stability_penalty", "C3:o"), ("damping_penalty", "C4:s")):
            pen = [(h["epoch"], h[key]) for h in rest if h.get(key, 0) > 0]
            if pen:
                ax.semilogy(*zip(*pen), style, ms=3, label=key.replace("_", " "))
        low, high = ax.get_ylim()
        plain = FuncFormatter(lambda v, _: f"{v:.3g}")  # not 1.07x10^0
        ax.yaxis.set_major_formatter(plain)
        ax.yaxis.set_minor_formatter(plain if high < 10 * low else NullFormatter())
    ax.set_ylabel("loss relative to the physics")
    ax.set_title("train split: loss over each epoch's mini-batches", fontsize=9)
    repaired = [h for h in result.history if h.get("phase") == "stability repair"]
    for ax in axes:
        if repaired:  # epochs carrying an earlier one on (SafeConfig.stability_trims)
            ax.axvspan(repaired[0]["epoch"] - 0.5, repaired[-1]["epoch"] + 0.5, color="C2",
                       alpha=0.12, label=f"stability repair of epoch {repaired[0]['repair_of']}")
        ax.set_xlabel("epoch (0 = untrained: the physics)")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    head = (f"Safe correction training{': ' + data if data else ''}: "
            f"{'kept' if result.kept else 'NOT kept (the physics is used)'}")
    reason = result.reason if len(result.reason) <= 400 else result.reason[:397] + "..."
    fig.suptitle(head + "\n" + textwrap.fill(reason, 160), fontsize=8)
    fig.savefig(png_path, dpi=110, format="png")
    plt.close(fig)
