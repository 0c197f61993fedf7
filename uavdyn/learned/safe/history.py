"""The record of a safe-correction training run: its history, validation figures and
stability check as JSON, and a PNG of the validation pitch error and losses per epoch."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

from uavdyn.learned.safe.config import SafeResult


def write_safe_history(result: SafeResult, path) -> tuple[Path, Path]:
    """The run's history, validation figures and stability check as JSON (``path``) and a PNG
    beside it (validation pitch RMSE per epoch against the physics, training loss, penalty),
    put in place together (:func:`uavdyn.outputs.atomic_files`)."""
    from uavdyn.outputs import atomic_files

    path = Path(path)
    png = path.with_suffix(".png")
    with atomic_files(path, png) as (json_tmp, png_tmp):
        write_safe_history_files(result, json_tmp, png_tmp)
    return path, png


def write_safe_history_files(result: SafeResult, json_path: Path, png_path: Path) -> None:
    """Write the record of :func:`write_safe_history` to exactly these paths (temporary names
    that the caller renames into place with :func:`uavdyn.outputs.atomic_files`, with the
    weights they belong to)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    doc = {"kind": "safe correction training", "kept": result.kept, "reason": result.reason,
           "config": asdict(result.config), "best_epoch": result.best_epoch,
           "seconds": result.seconds, "validation": result.validation,
           "stability": result.stability.to_dict() if result.stability else None,
           "network": result.net.describe() if result.net is not None else None,
           "history": result.history}
    Path(json_path).write_text(json.dumps(doc, indent=2, default=str) + "\n")
    epochs = [h["epoch"] for h in result.history]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    ax = axes[0]
    ax.plot(epochs, [h["val_theta_rmse"] for h in result.history], "C0-o", ms=3,
            label="corrected (validation)")
    ax.axhline(result.history[0]["physics_val_theta_rmse"], color="k", ls="--",
               label="physics (validation)")
    ax.axvline(result.best_epoch, color="grey", lw=0.8)
    ax.set_xlabel("epoch")
    ax.set_ylabel(f"pitch RMSE at {result.validation.get('selection_horizon_s', 1):g} s (rad)")
    ax.legend(fontsize=8)
    ax = axes[1]
    rest = result.history[1:]
    if rest:
        ax.semilogy([h["epoch"] for h in rest], [h["train_loss"] for h in rest], "C1-o", ms=3,
                    label="train loss (physics = 1)")
        pen = [(h["epoch"], h["stability_penalty"]) for h in rest if h["stability_penalty"] > 0]
        if pen:
            ax.semilogy(*zip(*pen), "C3:o", ms=3, label="stability penalty")
    ax.set_xlabel("epoch")
    ax.legend(fontsize=8)
    fig.suptitle(result.reason[:150], fontsize=8)
    fig.tight_layout()
    fig.savefig(png_path, dpi=110, format="png")
    plt.close(fig)
