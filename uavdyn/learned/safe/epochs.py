"""The safe trainer's epoch loop: Adam with an exponentially decaying learning rate over
random mini-batches of windows, the stability penalty at trims, the validation figures and
fixed-window losses after every epoch (the history), a snapshot of every trained epoch (the
candidates of the final checks) and patience on the selection rank."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import torch
from tqdm import tqdm

from uavdyn.learned.safe.config import SafeConfig
from uavdyn.learned.safe.data import WindowTensors
from uavdyn.learned.safe.scoring import ValidationReference, WindowLoss, rank, score
from uavdyn.learned.stability import TrimSample, stability_penalty
from uavdyn.learned.torch_model import TorchCorrection


@dataclass(frozen=True)
class Snapshot:
    """One epoch's network (its ``state_dict``) with its validation figures and rank."""

    rank: tuple
    epoch: int
    state: dict
    selection: dict


@dataclass(frozen=True)
class TrainingData:
    """What the epochs train and score on."""

    train: WindowTensors
    val: WindowTensors
    fixed: tuple[torch.Tensor, torch.Tensor]  # windows of ``train``, ``val`` scored each epoch
    loss: WindowLoss
    reference: ValidationReference


@dataclass(frozen=True)
class StabilityTargets:
    """Trim points and the allowed abscissa (minus a buffer) the penalty holds each to."""

    trims: list[TrimSample]
    targets: list[float]


@dataclass(frozen=True)
class EpochRun:
    """The loss history (epoch 0: the untrained network, the physics), every trained epoch's
    snapshot with a finite validation error, and the best by rank (epoch 0 if none beat it)."""

    history: list[dict]
    snapshots: list[Snapshot]
    best: Snapshot


def _state(model: TorchCorrection) -> dict:
    return {k: v.clone() for k, v in model.state_dict().items()}


def fixed_losses(model: TorchCorrection, data: TrainingData) -> dict:
    """The loss on the fixed training and validation windows."""
    with torch.no_grad():
        return {"train_loss_fixed": float(data.loss(model, data.train.take(data.fixed[0]))),
                "val_loss_fixed": float(data.loss(model, data.val.take(data.fixed[1])))}


def train_epoch(model: TorchCorrection, opt: torch.optim.Optimizer, data: TrainingData,
                stab: StabilityTargets, cfg: SafeConfig, rng: np.random.Generator
                ) -> tuple[float, float]:
    """One epoch of ``cfg.batches_per_epoch`` Adam steps; the mean loss and penalty."""
    sum_l = sum_s = 0.0
    n_w = data.train.count
    for _ in range(cfg.batches_per_epoch):
        idx = torch.as_tensor(rng.choice(n_w, min(cfg.batch_windows, n_w), replace=False))
        loss = data.loss(model, data.train.take(idx))
        pen = (stability_penalty(model, stab.trims, stab.targets, data.loss.dt) if stab.trims
               else loss * 0)
        total = loss + cfg.stability_weight * pen
        opt.zero_grad()
        total.backward()
        opt.step()
        sum_l, sum_s = sum_l + loss.item(), sum_s + float(pen.detach())
    return sum_l / cfg.batches_per_epoch, sum_s / cfg.batches_per_epoch


def run_epochs(model: TorchCorrection, data: TrainingData, stab: StabilityTargets,
               cfg: SafeConfig, rng: np.random.Generator, start: float, name: str
               ) -> EpochRun:
    """Train ``model`` in place for at most ``cfg.epochs`` epochs (patience and
    ``cfg.max_seconds`` end a run earlier); ``start`` is the run's ``time.perf_counter()``."""
    dt, ref = data.loss.dt, data.reference
    physics_val = ref.physics_rmse
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    gamma = (cfg.lr_final / cfg.lr) ** (1.0 / max(1, cfg.epochs))
    sched = torch.optim.lr_scheduler.ExponentialLR(opt, gamma)
    sel0 = score(model, data.val, ref, dt)
    history = [{"epoch": 0, **sel0, **fixed_losses(model, data),
                "physics_val_theta_rmse": physics_val, "seconds": time.perf_counter() - start}]
    best = Snapshot((True, math.inf), 0, _state(model), sel0)
    snapshots = []
    bar = tqdm(range(1, cfg.epochs + 1), desc=f"train {name} (safe)", unit="epoch",
               disable=not cfg.progress)
    for epoch in bar:
        loss, penalty = train_epoch(model, opt, data, stab, cfg, rng)
        sched.step()
        sel = score(model, data.val, ref, dt)
        fixed_now = fixed_losses(model, data)
        elapsed = time.perf_counter() - start
        history.append({"epoch": epoch, "train_loss": loss, **fixed_now,
                        "stability_penalty": penalty, **sel,
                        "physics_val_theta_rmse": physics_val,
                        "lr": sched.get_last_lr()[0], "seconds": elapsed})
        bar.set_postfix(loss=f"{loss:.3g}", val=f"{sel['val_theta_rmse']:.3g}",
                        physics=f"{physics_val:.3g}", ratio=f"{sel['val_ratio_geomean']:.3g}",
                        worst=f"{sel['val_ratio_worst']:.3g}")
        if math.isfinite(sel["val_theta_rmse"]):
            snapshots.append(Snapshot(rank(sel, cfg), epoch, _state(model), sel))
        if rank(sel, cfg) < best.rank and math.isfinite(sel["val_theta_rmse"]):
            best = snapshots[-1]
        elif epoch - best.epoch >= cfg.patience:
            break
        if elapsed > cfg.max_seconds:
            break
    bar.close()
    return EpochRun(history, snapshots, best)
