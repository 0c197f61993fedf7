"""``uavdyn train`` from parsed options: the dataset's splits, the trainer (the safe
correction for the improved formulation on flight data, :func:`uavdyn.learned.train.train`
otherwise), and the weights, history JSON and PNG it writes (needs torch).

The weights and their history JSON and PNG are one output: written under temporary names,
then renamed into place together by :func:`uavdyn.outputs.atomic_files`, so an interrupt at
any point leaves the old three files or the new three, never weights beside a history that
does not belong to them. A safe run that keeps no weights leaves the weights already at
``--out`` and their history as they are; its own record goes beside them
(``<history>_not_kept.json``), or to the history path when there are no weights yet."""

from __future__ import annotations

import argparse
from pathlib import Path

from uavdyn.airframes import Airframe, load_airframe
from uavdyn.flightdata import Sortie, load_dataset
from uavdyn.learned.train import TrainConfig, train, write_history_files
from uavdyn.learned.weights import CorrectionNet, save_weights
from uavdyn.outputs import atomic_files, check_output_files, single_outputs


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


def not_kept_path(history: Path) -> Path:
    """Where a safe run that kept no weights leaves its record when a weight file is already
    at ``--out``: beside the history that belongs to those weights, not over it."""
    return history.with_name(history.stem + "_not_kept.json")


def check_horizons(args: argparse.Namespace, sorties: list[Sortie]) -> None:
    """Refuse a rollout window longer than the shortest train or validation sortie
    (``--horizon`` of the safe correction in s, ``--rollout-horizon`` in log samples)."""
    shortest = min(sorties, key=lambda s: s.duration)
    if getattr(args, "horizon", None) is not None and args.horizon > shortest.duration:
        raise ValueError(f"--horizon {args.horizon:g} s is longer than sortie {shortest.name} "
                         f"({shortest.duration:g} s) of --dataset {args.dataset}")
    samples = len(shortest.time) - 1
    if getattr(args, "rollout_horizon", None) is not None and args.rollout_horizon > samples:
        raise ValueError(f"--rollout-horizon {args.rollout_horizon} samples is longer than "
                         f"sortie {shortest.name} ({samples} samples) of --dataset "
                         f"{args.dataset}")


def run(args: argparse.Namespace, airframe: Airframe | None = None) -> dict:
    """Train from parsed options (on ``airframe``, default ``--airframe`` loaded); write the
    weights, history JSON and PNG as one output; return a summary."""
    airframe = airframe if airframe is not None else load_airframe(args.airframe)
    out = Path(args.out or f"results/weights/{airframe.name}_{args.formulation}.npz")
    hist = Path(args.history) if args.history else out.with_name(out.stem + "_history.json")
    if len({p.resolve() for p in (out, hist, hist.with_suffix(".png"))}) < 3:
        raise ValueError(f"--history {hist} and its PNG {hist.with_suffix('.png')} must not be "
                         f"the --out weight file {out}")
    kept_aside = not_kept_path(hist)
    check_output_files(out, hist, hist.with_suffix(".png"), kept_aside,  # before training
                       kept_aside.with_suffix(".png"), force=getattr(args, "force", False))
    tr, va, te, source = load_training_sorties(args.dataset, getattr(args, "lowpass_hz", None))
    # turning-flight sorties carry the lateral inputs: the physics (and the correction's
    # inputs, which are the step's) take them too
    airframe = airframe.for_inputs(bool(tr) and tr[0].lateral)
    check_horizons(args, tr + va)
    if args.formulation == "improved" and args.target == "data":
        return _run_safe(args, airframe, tr, va, te, source, out, hist)
    # the legacy trainer's own defaults where an option was not given
    fields = TrainConfig.__dataclass_fields__
    args = argparse.Namespace(**{**vars(args), **{
        k: (fields[k].default if getattr(args, k, None) is None else getattr(args, k))
        for k in ("epochs", "patience", "max_seconds", "hidden", "dt", "rollout_horizon",
                  "rollout_weight")}})
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
    png = hist.with_suffix(".png")
    with single_outputs(out, hist, png, command="train",
                        force=getattr(args, "force", False)), \
            atomic_files(out, hist, png) as (w_tmp, h_tmp, p_tmp):  # one output: all or none
        save_weights(net, w_tmp)
        write_history_files(result, h_tmp, p_tmp, f"{airframe.name} on {args.dataset} "
                            f"({len(tr)} train, {len(va)} validation sorties)")
    h0, hb = result.history[0], result.history[result.best_epoch]
    return {"weights": str(out), "history": str(hist), "png": str(png),
            "network": net.describe(), "data_source": source, "n_train": len(tr),
            "n_val": len(va), "n_test": len(te), "best_epoch": result.best_epoch,
            "stopped": result.stopped, "seconds": round(result.seconds, 1),
            "val_total_initial": h0["val_total"], "val_total_best": hb["val_total"]}


def _run_safe(args, airframe: Airframe, tr, va, te, source: str, out: Path, hist: Path) -> dict:
    """``uavdyn train`` of the safe correction (improved formulation on flight data)."""
    from uavdyn.learned.formulations import design_problem
    from uavdyn.learned.safe import SafeConfig, train_safe
    from uavdyn.learned.safe.history import write_safe_history_files

    given = {k: getattr(args, k) for k in ("epochs", "patience", "max_seconds",
                                           "stability_weight", "hidden", "stability_margin",
                                           "min_gain", "restarts", "stability_trims",
                                           "damping_weight")
             if getattr(args, k, None) is not None}
    if getattr(args, "horizon", None) is not None:
        given["horizon_s"] = args.horizon
    if getattr(args, "start_fit", None) is not None:
        given["start_fit_s"] = args.start_fit
    if getattr(args, "envelope_fade", None) is not None:
        given["envelope_fade"] = args.envelope_fade
    if getattr(args, "steady_gate", None) is not None:
        given["steady_gate"] = args.steady_gate == "on"
    given.update({k: getattr(args, k) for k in ("inputs", "output")
                  if getattr(args, k, None) is not None})
    if "output" in given:  # the design rule, said in terms of the option
        problem = design_problem(given.get("inputs", "state"), given["output"], airframe.kind)
        if problem:
            raise ValueError(f"--output {given['output']} on {airframe.kind} airframe "
                             f"'{airframe.name}': {problem}")
    if getattr(args, "linear_path", None) is not None:
        given["linear"] = args.linear_path == "on"
    cfg = SafeConfig(activation=args.activation, lr=args.lr,
                     seed=args.seed, threads=args.threads, progress=not args.quiet,
                     memory_tau=(tuple(args.memory_tau) if args.memory_tau is not None
                                 else None), **given)
    result = train_safe(tr, va, airframe, cfg)
    data = (f"{airframe.name} on {args.dataset} ({len(tr)} train, {len(va)} validation "
            "sorties)")
    if not result.kept:  # the weights at --out (if any) and their history stay as they are
        record = not_kept_path(hist) if out.exists() else hist
        with single_outputs(record, record.with_suffix(".png"), command="train",
                            force=getattr(args, "force", False)), \
                atomic_files(record, record.with_suffix(".png")) as (h_tmp, p_tmp):
            write_safe_history_files(result, h_tmp, p_tmp, data)
        raise NotKept(f"no weights written: {result.reason} (history: {record})")
    net = CorrectionNet(**{**result.net.__dict__,
                           "info": {**result.net.info, "data_source": source}})
    png = hist.with_suffix(".png")
    with single_outputs(out, hist, png, command="train", force=getattr(args, "force", False)), \
            atomic_files(out, hist, png) as (w_tmp, h_tmp, p_tmp):  # one output: all or none
        save_weights(net, w_tmp)
        write_safe_history_files(result, h_tmp, p_tmp, data)
    return {"weights": str(out), "history": str(hist), "png": str(png),
            "network": net.describe(), "data_source": source, "n_train": len(tr),
            "n_val": len(va), "n_test": len(te), "best_epoch": result.best_epoch,
            "epochs_run": len(result.history) - 1, "stopped": result.stopped,
            "screened": result.screened, "start_fits": result.start_fits,
            "seconds": round(result.seconds, 1), "validation": result.validation,
            "stability": result.stability.describe() if result.stability else None,
            "reason": result.reason,
            **({"steady_gate": result.steady_gate} if result.steady_gate else {})}
