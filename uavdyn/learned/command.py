"""``uavdyn train`` from parsed options: the dataset's splits, the trainer (the safe
correction for the improved formulation on flight data, :func:`uavdyn.learned.train.train`
otherwise), and the weights, history JSON and PNG it writes (needs torch)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from uavdyn.airframes import Airframe, load_airframe
from uavdyn.flightdata import Sortie, load_dataset
from uavdyn.learned.train import TrainConfig, train, write_history
from uavdyn.learned.weights import CorrectionNet, WeightFileError, load_weights, save_weights


class NotKept(ValueError):
    """Training ran but its correction is not written (unstable map or physics not beaten)."""


def load_training_sorties(dataset: str | None, lowpass_hz: float | None = None
                          ) -> tuple[list[Sortie], list[Sortie], list[Sortie], str]:
    """Train/validation/test sorties of a dataset folder
    (:func:`uavdyn.flightdata.load_dataset`) and a label saying where they come from.

    Raises
    ------
    ValueError
        If no dataset is given or it has no train or no validation sorties.
    """
    if not dataset:
        raise ValueError("--dataset DIR is required: a dataset folder with train and "
                         "validation splits (make one with `uavdyn generate-data --airframe A "
                         "--out DIR`, or import logs with `uavdyn import-log`)")
    ds = load_dataset(dataset, lowpass_hz=lowpass_hz)
    if not ds.train or not ds.validation:
        raise ValueError(f"{dataset}: the dataset needs train and validation sorties")
    label = f"dataset {dataset}" + (f" (low-pass {lowpass_hz:g} Hz)" if lowpass_hz else "")
    return list(ds.train), list(ds.validation), list(ds.test), label


def _check_replaceable(weights: Path, history: Path, force: bool) -> None:
    """Refuse, before training, to overwrite files that are not earlier training outputs."""
    if force:
        return
    if weights.exists():
        try:
            load_weights(weights)
        except WeightFileError:
            raise ValueError(f"{weights} exists and is not a uavdyn weight file; choose another "
                             "--out or give --force") from None
    if history.exists():
        try:
            ok = "history" in json.loads(history.read_text())
        except (OSError, ValueError, TypeError):
            ok = False
        if not ok:
            raise ValueError(f"{history} exists and is not a uavdyn loss history; choose another "
                             "--history or give --force")


def run(args: argparse.Namespace) -> dict:
    """Train from parsed options; write weights, history JSON and PNG; return a summary."""
    airframe = load_airframe(args.airframe)
    if (args.hidden is not None and args.hidden < 1) or (args.epochs is not None
                                                         and args.epochs < 1):
        raise ValueError("--hidden and --epochs must be >= 1")
    out = Path(args.out or f"results/weights/{airframe.name}_{args.formulation}.npz")
    hist = Path(args.history) if args.history else out.with_name(out.stem + "_history.json")
    _check_replaceable(out, hist, getattr(args, "force", False))
    tr, va, te, source = load_training_sorties(args.dataset, getattr(args, "lowpass_hz", None))
    if args.formulation == "improved" and args.target == "data":
        return _run_safe(args, airframe, tr, va, te, source, out, hist)
    # the legacy trainer's own defaults where an option was not given
    args = argparse.Namespace(**{**vars(args), **{
        k: (TrainConfig.__dataclass_fields__[k].default if getattr(args, k) is None
            else getattr(args, k)) for k in ("epochs", "patience", "max_seconds", "hidden")}})
    cfg = TrainConfig(formulation=args.formulation, target=args.target,
                      rollout_batch=getattr(args, "rollout_batch", TrainConfig.rollout_batch),
                      activation=args.activation, hidden=args.hidden, dt=args.dt,
                      epochs=args.epochs, rollout_horizon=args.rollout_horizon,
                      rollout_weight=args.rollout_weight, lr=args.lr, patience=args.patience,
                      max_seconds=args.max_seconds, seed=args.seed, threads=args.threads,
                      progress=not args.quiet)
    result = train(tr, va, airframe, cfg)
    net = CorrectionNet(**{**result.net.__dict__,
                           "info": {**result.net.info, "data_source": source}})
    save_weights(net, out)  # the weights first (atomic), then their history
    write_history(result, hist)
    h0, hb = result.history[0], result.history[result.best_epoch]
    return {"weights": str(out), "history": str(hist), "png": str(hist.with_suffix(".png")),
            "network": net.describe(), "data_source": source, "n_train": len(tr),
            "n_val": len(va), "n_test": len(te), "best_epoch": result.best_epoch,
            "stopped": result.stopped, "seconds": round(result.seconds, 1),
            "val_total_initial": h0["val_total"], "val_total_best": hb["val_total"]}


def _run_safe(args, airframe: Airframe, tr, va, te, source: str, out: Path, hist: Path) -> dict:
    """``uavdyn train`` of the safe correction (improved formulation on flight data)."""
    from uavdyn.learned.safe import SafeConfig, train_safe, write_safe_history

    given = {k: getattr(args, k) for k in ("epochs", "patience", "max_seconds",
                                           "stability_weight", "hidden")
             if getattr(args, k) is not None}
    cfg = SafeConfig(activation=args.activation, lr=args.lr,
                     seed=args.seed, threads=args.threads, progress=not args.quiet,
                     stability_margin=args.stability_margin, horizon_s=args.horizon,
                     memory_tau=(tuple(args.memory_tau) if args.memory_tau is not None
                                 else None), **given)
    result = train_safe(tr, va, airframe, cfg)
    write_safe_history(result, hist)
    if not result.kept:
        raise NotKept(f"no weights written: {result.reason} (history: {hist})")
    net = CorrectionNet(**{**result.net.__dict__,
                           "info": {**result.net.info, "data_source": source}})
    save_weights(net, out)
    return {"weights": str(out), "history": str(hist), "png": str(hist.with_suffix(".png")),
            "network": net.describe(), "data_source": source, "n_train": len(tr),
            "n_val": len(va), "n_test": len(te), "best_epoch": result.best_epoch,
            "seconds": round(result.seconds, 1), "validation": result.validation,
            "stability": result.stability.describe() if result.stability else None}
