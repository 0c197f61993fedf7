"""Training loop of the correction network (torch, CPU, float64, seeded): one-step residual fit
plus a multi-step rollout loss through the hybrid step, early stopping on validation sorties,
loss history as JSON and PNG, export to a plain ``.npz``.

Entry point: ``python -m training.train --airframe aerosonde --out results/x.npz`` or
``uavdyn train`` (same options).

Losses are normalised per state by the physics-only RK4 error on the training set (one-step
residual RMS, and rollout error RMS), so both start at about 1 with the network's zero-initialised
output layer (the hybrid equals the physics step at initialisation) and read directly as "the
fraction of the physics-only squared error left".
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from uavdyn.airframes import Airframe, load_airframe
from uavdyn.flightdata import Sortie
from uavdyn.flightdata import dataset as flightdata
from uavdyn.learned.data import (
    Pairs,
    Windows,
    one_step_pairs,
    rollout_windows,
    split_sorties,
    synthetic_sorties,
    target_trajectories,
)
from uavdyn.learned.formulations import DEFAULT_FORMULATION
from uavdyn.learned.hybrid import correction_structure
from uavdyn.learned.torch_model import DTYPE, TorchCorrection
from uavdyn.learned.weights import CorrectionNet, WeightFileError, load_weights, save_weights
from uavdyn.outputs import atomic_file, write_text_atomic


@dataclass
class TrainConfig:
    """Everything that defines a training run (saved with the weights and the history)."""

    formulation: str = DEFAULT_FORMULATION
    target: str = "data"
    activation: str = "relu"
    hidden: int = 16
    dt: float = 0.005
    epochs: int = 60
    warmup_epochs: int = 5          # one-step loss only before the rollout loss joins
    batch_size: int = 512
    rollout_horizon: int = 25       # grid intervals (samples) per rollout window
    rollout_batch: int = 64
    rollout_batches_per_epoch: int = 4
    rollout_weight: float = 1.0
    lr: float = 3e-3
    lr_final: float = 2e-4
    weight_decay: float = 0.0
    patience: int = 12
    seed: int = 0
    threads: int = 1               # small tensors: one thread is fastest
    max_seconds: float = 270.0      # hard wall-clock budget (default run <= 5 min)
    progress: bool = True


@dataclass
class TrainResult:
    net: CorrectionNet
    history: list[dict]
    config: TrainConfig
    best_epoch: int
    seconds: float
    stopped: str
    scales: dict = field(default_factory=dict)


def _t(a: np.ndarray) -> torch.Tensor:
    return torch.as_tensor(np.ascontiguousarray(a), dtype=DTYPE)


def _multi_step(model: TorchCorrection, x, u, p, dt: float, substeps: int, t, physics=False):
    for j in range(substeps):
        if physics:
            x = model.physics_step(x, u, p, dt)
        else:
            x = model.step(x, u, p, dt, t + j * dt if t is not None else None)
    return x


def _rollout(model, W: dict, p, dt, substeps, physics=False) -> torch.Tensor:
    """Free run through each window; returns predicted states (W, H, 4)."""
    x = W["x"][:, 0]
    preds = []
    for k in range(W["u"].shape[1]):
        x = _multi_step(model, x, W["u"][:, k], p, dt, substeps, W["t"][:, k], physics)
        preds.append(x)
    return torch.stack(preds, dim=1)


def _normalisation(model_kind: str, formulation: str, pairs: Pairs, resid: np.ndarray,
                   interval: float, dt: float, substeps: int):
    x, u, t = pairs.x0, pairs.u, pairs.t
    inp = np.column_stack([t, x]) if formulation == "paper" else np.column_stack([x, u])
    in_mean = inp.mean(axis=0)
    in_scale = inp.std(axis=0)
    in_scale = np.where(in_scale > 1e-9 * (1 + np.abs(in_mean)), in_scale, 1.0)
    rms = np.sqrt(np.mean(resid**2, axis=0))
    if formulation == "improved":
        out_scale = rms[:3] / interval       # residual acceleration, SI units
    elif formulation == "paper":
        out_scale = rms / substeps           # state increment per hybrid step
    else:
        out_scale = rms / substeps / dt**5
    out_scale = np.where(out_scale > 0, out_scale, 1.0)
    return in_mean, in_scale, out_scale


def train(train_sorties: list[Sortie], val_sorties: list[Sortie], airframe: Airframe,
          config: TrainConfig | None = None, history_path: str | Path | None = None
          ) -> TrainResult:
    """Train the correction on ``train_sorties`` with early stopping on ``val_sorties``.

    Returns the best (lowest validation loss) network, exported as a :class:`CorrectionNet`
    tied to ``airframe.param_hash()``; the loss history has one entry per epoch, epoch 0 being
    the untrained network.
    """

    cfg = config or TrainConfig()
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    rng = np.random.default_rng(cfg.seed)
    start = time.perf_counter()
    tr = target_trajectories(train_sorties, airframe, cfg.target, cfg.dt)
    va = target_trajectories(val_sorties, airframe, cfg.target, cfg.dt)
    substeps = tr[0].substeps
    if any(t.substeps != substeps for t in tr + va):
        raise ValueError("all sorties must share one sample rate")
    interval = cfg.dt * substeps
    p = _t(airframe.p)
    pairs_tr, pairs_va = one_step_pairs(tr), one_step_pairs(va)
    horizon = min(cfg.rollout_horizon, min(len(t.time) for t in tr + va) - 1)
    win_tr, win_va = rollout_windows(tr, horizon), rollout_windows(va, horizon)

    structure = correction_structure(airframe, airframe.kind)
    probe = TorchCorrection(airframe.kind, cfg.formulation, cfg.hidden, cfg.activation,
                            np.zeros(6 if cfg.formulation != "paper" else 5),
                            np.ones(6 if cfg.formulation != "paper" else 5),
                            np.ones(3 if cfg.formulation == "improved" else 4), cfg.dt,
                            structure=structure)
    with torch.no_grad():
        base_tr = _multi_step(probe, _t(pairs_tr.x0), _t(pairs_tr.u), p, cfg.dt, substeps,
                              None, physics=True).numpy()
        resid = pairs_tr.x1 - base_tr
        W = _windows_t(win_tr)
        roll_err = (_rollout(probe, W, p, cfg.dt, substeps, physics=True) - W["x"][:, 1:])
        roll_scale = torch.sqrt(torch.mean(roll_err**2, dim=(0, 1)))
    step_scale = _t(np.sqrt(np.mean(resid**2, axis=0)))
    step_scale = torch.where(step_scale > 0, step_scale, torch.ones_like(step_scale))
    roll_scale = torch.where(roll_scale > 0, roll_scale, torch.ones_like(roll_scale))
    in_mean, in_scale, out_scale = _normalisation(airframe.kind, cfg.formulation, pairs_tr,
                                                  resid, interval, cfg.dt, substeps)
    model = TorchCorrection(airframe.kind, cfg.formulation, cfg.hidden, cfg.activation,
                            in_mean, in_scale, out_scale, cfg.dt, seed=cfg.seed,
                            structure=structure)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    gamma = (cfg.lr_final / cfg.lr) ** (1.0 / max(1, cfg.epochs))
    sched = torch.optim.lr_scheduler.ExponentialLR(opt, gamma)

    P_tr = {k: _t(getattr(pairs_tr, k)) for k in ("t", "x0", "u", "x1")}
    P_va = {k: _t(getattr(pairs_va, k)) for k in ("t", "x0", "u", "x1")}
    W_tr, W_va = _windows_t(win_tr), _windows_t(win_va)

    def one_step_loss(P, idx=None):
        sel = (lambda a: a) if idx is None else (lambda a: a[idx])
        pred = _multi_step(model, sel(P["x0"]), sel(P["u"]), p, cfg.dt, substeps, sel(P["t"]))
        return torch.mean(((pred - sel(P["x1"])) / step_scale) ** 2)

    def rollout_loss(Wd, idx=None):
        sub = Wd if idx is None else {k: v[idx] for k, v in Wd.items()}
        pred = _rollout(model, sub, p, cfg.dt, substeps)
        return torch.mean(((pred - sub["x"][:, 1:]) / roll_scale) ** 2)

    def evaluate(Pd, Wd):
        with torch.no_grad():
            a, b = float(one_step_loss(Pd)), float(rollout_loss(Wd))
        return a, b, a + cfg.rollout_weight * b

    history = []
    v1, v2, vt = evaluate(P_va, W_va)
    t1, t2, tt = evaluate(P_tr, W_tr)
    history.append({"epoch": 0, "train_one_step": t1, "train_rollout": t2, "train_total": tt,
                    "val_one_step": v1, "val_rollout": v2, "val_total": vt, "lr": cfg.lr,
                    "seconds": time.perf_counter() - start})
    best = (vt, 0, {k: v.clone() for k, v in model.state_dict().items()})
    n_pairs = len(pairs_tr.t)
    n_batches = max(1, n_pairs // cfg.batch_size)
    stopped = "epochs"
    bar = tqdm(range(1, cfg.epochs + 1), desc=f"train {airframe.name}", unit="epoch",
               disable=not cfg.progress)
    for epoch in bar:
        model.train()
        perm = torch.as_tensor(rng.permutation(n_pairs))
        use_roll = epoch > cfg.warmup_epochs and cfg.rollout_weight > 0
        roll_every = max(1, n_batches // max(1, cfg.rollout_batches_per_epoch))
        sum1 = sum2 = 0.0
        n1 = n2 = 0
        for b in range(n_batches):
            idx = perm[b * cfg.batch_size:(b + 1) * cfg.batch_size]
            loss = one_step_loss(P_tr, idx)
            sum1, n1 = sum1 + loss.item(), n1 + 1
            if use_roll and b % roll_every == 0:
                widx = torch.as_tensor(rng.choice(len(W_tr["x"]),
                                                  min(cfg.rollout_batch, len(W_tr["x"])),
                                                  replace=False))
                lr_ = rollout_loss(W_tr, widx)
                sum2, n2 = sum2 + lr_.item(), n2 + 1
                loss = loss + cfg.rollout_weight * lr_
            opt.zero_grad()
            loss.backward()
            opt.step()
        sched.step()
        v1, v2, vt = evaluate(P_va, W_va)
        elapsed = time.perf_counter() - start
        history.append({"epoch": epoch, "train_one_step": sum1 / max(1, n1),
                        "train_rollout": sum2 / n2 if n2 else None,
                        "train_total": sum1 / max(1, n1) + cfg.rollout_weight * sum2 / max(1, n2),
                        "val_one_step": v1, "val_rollout": v2, "val_total": vt,
                        "lr": sched.get_last_lr()[0], "seconds": elapsed})
        bar.set_postfix(val=f"{vt:.3g}", one=f"{v1:.3g}", roll=f"{v2:.3g}")
        if vt < best[0] and math.isfinite(vt):
            best = (vt, epoch, {k: v.clone() for k, v in model.state_dict().items()})
        elif epoch - best[1] >= cfg.patience and epoch > cfg.warmup_epochs:
            stopped = f"early stop (no improvement for {cfg.patience} epochs)"
            break
        if elapsed > cfg.max_seconds:
            stopped = f"time budget ({cfg.max_seconds:g} s)"
            break
    bar.close()
    model.load_state_dict(best[2])
    seconds = time.perf_counter() - start
    info = {"config": asdict(cfg), "airframe": airframe.name, "best_epoch": best[1],
            "best_val_total": best[0], "initial_val_total": history[0]["val_total"],
            "epochs_run": len(history) - 1, "stopped": stopped, "train_seconds": seconds,
            "n_train_sorties": len(train_sorties), "n_val_sorties": len(val_sorties),
            "substeps_per_sample": substeps,
            "train_sorties_source": sorted({str(s.meta.get("source", "")) for s in
                                            train_sorties})}
    # time range seen in training (time since each sortie's start), for a time-taking step
    t_range = (0.0, float(max(tr_.time[-1] for tr_ in tr + va)))
    net = model.export(airframe.param_hash(), info,
                       t_range if model.form.takes_time else None)
    result = TrainResult(net, history, cfg, best[1], seconds, stopped,
                         {"step_scale": step_scale.tolist(), "rollout_scale": roll_scale.tolist()})
    if history_path is not None:
        write_history(result, history_path)
    return result


def _windows_t(w: Windows) -> dict:
    return {"t": _t(w.t), "x": _t(w.x), "u": _t(w.u)}


def write_history(result: TrainResult, path: str | Path) -> tuple[Path, Path | None]:
    """Loss history as JSON (``path``) and a PNG plot beside it (if matplotlib works)."""
    path = Path(path)
    doc = {"config": asdict(result.config), "best_epoch": result.best_epoch,
           "stopped": result.stopped, "seconds": result.seconds, "scales": result.scales,
           "network": result.net.describe(), "history": result.history}
    write_text_atomic(path, json.dumps(doc, indent=2) + "\n")
    png = path.with_suffix(".png")
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:  # pragma: no cover
        return path, None
    ep = [h["epoch"] for h in result.history]
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for key, style in (("train_one_step", "C0-"), ("val_one_step", "C0--"),
                       ("train_rollout", "C1-"), ("val_rollout", "C1--"),
                       ("val_total", "k:")):
        vals = [h[key] for h in result.history]
        pts = [(e, v) for e, v in zip(ep, vals) if v is not None]
        if pts:
            ax.semilogy(*zip(*pts), style, label=key.replace("_", " "))
    ax.axvline(result.best_epoch, color="grey", lw=0.8)
    ax.set_xlabel("epoch (0 = untrained: hybrid = physics RK4)")
    ax.set_ylabel("loss (normalised by physics-only error)")
    ax.set_title(result.net.describe(), fontsize=8)
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_file(png) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)
    return path, png


def load_training_sorties(dataset: str | None, airframe: Airframe, n: int, seed: int,
                          duration: float, lowpass_hz: float | None = None
                          ) -> tuple[list[Sortie], list[Sortie], list[Sortie], str]:
    """Train/validation/test sorties: a dataset folder (``uavdyn.flightdata.load_dataset``)
    if given, else the perturbed-model stand-in data. Returns the split and a source label."""
    if dataset:

        if not hasattr(flightdata, "load_dataset"):
            raise ValueError("this uavdyn has no flightdata.load_dataset; omit --dataset to "
                             "train on generated perturbed-model sorties")
        ds = flightdata.load_dataset(dataset, lowpass_hz=lowpass_hz)
        parts = []
        for name in ("train", "validation", "test"):
            part = getattr(ds, name, None)
            if callable(part):
                part = part()
            parts.append(list(part or []))
        if not parts[0] or not parts[1]:
            raise ValueError(f"{dataset}: the dataset needs train and validation sorties")
        label = f"dataset {dataset}" + (f" (low-pass {lowpass_hz:g} Hz)" if lowpass_hz else "")
        return parts[0], parts[1], parts[2], label

    sorties = synthetic_sorties(airframe, n, seed=seed, duration=duration)
    a, b, c = split_sorties(sorties, seed=seed)
    return a, b, c, "perturbed-model stand-in sorties (uavdyn.learned.data.synthetic_sorties)"


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
    safe = args.formulation == "improved" and args.target == "data"
    if not safe:  # the legacy trainer's own defaults where an option was not given
        args = argparse.Namespace(**{**vars(args), **{
            k: (TrainConfig.__dataclass_fields__[k].default if getattr(args, k) is None
                else getattr(args, k)) for k in ("epochs", "patience", "max_seconds",
                                                 "hidden")}})
    cfg = TrainConfig(formulation=args.formulation, target=args.target,
                      rollout_batch=getattr(args, "rollout_batch", TrainConfig.rollout_batch),
                      activation=args.activation, hidden=args.hidden, dt=args.dt,
                      epochs=args.epochs, rollout_horizon=args.rollout_horizon,
                      rollout_weight=args.rollout_weight, lr=args.lr, patience=args.patience,
                      max_seconds=args.max_seconds, seed=args.seed, threads=args.threads,
                      progress=not args.quiet)
    tr, va, te, source = load_training_sorties(args.dataset, airframe, args.sorties, args.seed,
                                               args.duration, getattr(args, "lowpass_hz", None))
    out = Path(args.out or f"results/weights/{airframe.name}_{args.formulation}.npz")
    hist = Path(args.history) if args.history else out.with_name(out.stem + "_history.json")
    _check_replaceable(out, hist, getattr(args, "force", False))
    if args.formulation == "improved" and args.target == "data":
        return _run_safe(args, airframe, tr, va, te, source, out, hist)
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


class NotKept(ValueError):
    """Training ran but its correction is not written (unstable map or physics not beaten)."""


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
