"""Training loop of the correction network (torch, CPU, float64, seeded): one-step residual fit
plus a multi-step rollout loss through the hybrid step, early stopping on validation sorties,
loss history as JSON and PNG, export to a plain ``.npz``. It trains the paper's formulation
(``reproduce --retrain``) and the other legacy formulations; the safe correction has its own
trainer (:mod:`uavdyn.learned.safe`).

Entry point: ``uavdyn train --formulation paper --dataset DIR`` or ``python -m training.train``
(same options).

Losses are normalised per state by the physics-only RK4 error on the training set (one-step
residual RMS, and rollout error RMS), so both start at about 1 with the network's zero-initialised
output layer (the hybrid equals the physics step at initialisation) and read directly as "the
fraction of the physics-only squared error left".
"""

from __future__ import annotations

import json
import math
import textwrap
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from uavdyn.airframes import Airframe
from uavdyn.flightdata import Sortie, Windows
from uavdyn.interrupts import CheckedBar
from uavdyn.learned.data import (
    Pairs,
    one_step_pairs,
    rollout_windows,
    target_trajectories,
    window_times,
)
from uavdyn.learned.formulations import DEFAULT_FORMULATION
from uavdyn.learned.hybrid import correction_structure
from uavdyn.learned.torch_model import DTYPE, TorchCorrection, seeded_generator
from uavdyn.learned.weights import CorrectionNet
from uavdyn.model import ModelStructure
from uavdyn.outputs import atomic_files


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


@dataclass(frozen=True)
class TrainingData:
    """The target trajectories of both splits cut into one-step pairs and rollout windows."""

    pairs_train: Pairs
    pairs_val: Pairs
    windows_train: Windows
    windows_val: Windows
    substeps: int     # hybrid steps per grid interval
    interval: float   # grid interval (s)
    t_max: float      # the longest trajectory's time since its start (s)


def training_data(train_sorties: list[Sortie], val_sorties: list[Sortie], airframe: Airframe,
                  cfg: TrainConfig) -> TrainingData:
    """:class:`TrainingData` of the sorties for ``cfg.target`` at step ``cfg.dt``.

    Raises
    ------
    ValueError
        If the sorties are not all at one sample rate (or :class:`DatasetError`).
    """
    tr = target_trajectories(train_sorties, airframe, cfg.target, cfg.dt)
    va = target_trajectories(val_sorties, airframe, cfg.target, cfg.dt)
    substeps = tr[0].substeps
    if any(t.substeps != substeps for t in tr + va):
        raise ValueError("all sorties must share one sample rate")
    horizon = min(cfg.rollout_horizon, min(len(t.time) for t in tr + va) - 1)
    return TrainingData(one_step_pairs(tr), one_step_pairs(va), rollout_windows(tr, horizon),
                        rollout_windows(va, horizon), substeps, cfg.dt * substeps,
                        float(max(tr_.time[-1] for tr_ in tr + va)))


def window_tensors(w: Windows) -> dict:
    """Rollout windows as tensors: ``x[:, 0]`` the start, ``x[:, k+1]`` the target after
    ``u[:, k]`` held from time ``t[:, k]``."""
    x = np.concatenate([w.x0[:, None, :], w.y], axis=1)
    return {"t": _t(window_times(w)), "x": _t(x), "u": _t(w.u)}


def pair_tensors(pairs: Pairs) -> dict:
    return {k: _t(getattr(pairs, k)) for k in ("t", "x0", "u", "x1")}


@dataclass(frozen=True)
class Losses:
    """The one-step and rollout losses of ``model``, each normalised per state by the
    physics-only error on the training set."""

    model: TorchCorrection
    p: torch.Tensor
    dt: float
    substeps: int
    step_scale: torch.Tensor
    rollout_scale: torch.Tensor
    rollout_weight: float

    def one_step(self, P: dict, idx=None) -> torch.Tensor:
        sel = (lambda a: a) if idx is None else (lambda a: a[idx])
        pred = _multi_step(self.model, sel(P["x0"]), sel(P["u"]), self.p, self.dt,
                           self.substeps, sel(P["t"]))
        return torch.mean(((pred - sel(P["x1"])) / self.step_scale) ** 2)

    def rollout(self, Wd: dict, idx=None) -> torch.Tensor:
        sub = Wd if idx is None else {k: v[idx] for k, v in Wd.items()}
        pred = _rollout(self.model, sub, self.p, self.dt, self.substeps)
        return torch.mean(((pred - sub["x"][:, 1:]) / self.rollout_scale) ** 2)

    def evaluate(self, Pd: dict, Wd: dict) -> tuple[float, float, float]:
        """One-step, rollout and total loss, without gradients."""
        with torch.no_grad():
            a, b = float(self.one_step(Pd)), float(self.rollout(Wd))
        return a, b, a + self.rollout_weight * b


def _physics_scales(airframe: Airframe, structure: ModelStructure, data: TrainingData,
                    p: torch.Tensor, cfg: TrainConfig
                    ) -> tuple[np.ndarray, torch.Tensor, torch.Tensor]:
    """The physics-only step's one-step residuals on the training pairs, and its one-step and
    rollout error RMS per state (1 where zero): the losses' normalisation."""
    probe = TorchCorrection(airframe.kind, cfg.formulation, cfg.hidden, cfg.activation,
                            np.zeros(6 if cfg.formulation != "paper" else 5),
                            np.ones(6 if cfg.formulation != "paper" else 5),
                            np.ones(3 if cfg.formulation == "improved" else 4), cfg.dt,
                            structure=structure)
    pairs = data.pairs_train
    with torch.no_grad():
        base_tr = _multi_step(probe, _t(pairs.x0), _t(pairs.u), p, cfg.dt, data.substeps,
                              None, physics=True).numpy()
        resid = pairs.x1 - base_tr
        W = window_tensors(data.windows_train)
        roll_err = (_rollout(probe, W, p, cfg.dt, data.substeps, physics=True) - W["x"][:, 1:])
        roll_scale = torch.sqrt(torch.mean(roll_err**2, dim=(0, 1)))
    step_scale = _t(np.sqrt(np.mean(resid**2, axis=0)))
    step_scale = torch.where(step_scale > 0, step_scale, torch.ones_like(step_scale))
    roll_scale = torch.where(roll_scale > 0, roll_scale, torch.ones_like(roll_scale))
    return resid, step_scale, roll_scale


def _history_row(epoch: int, train: tuple, val: tuple, lr: float, seconds: float) -> dict:
    return {"epoch": epoch, "train_one_step": train[0], "train_rollout": train[1],
            "train_total": train[2], "val_one_step": val[0], "val_rollout": val[1],
            "val_total": val[2], "lr": lr, "seconds": seconds}


def _train_epoch(losses: Losses, opt: torch.optim.Optimizer, P_tr: dict, W_tr: dict,
                 use_roll: bool, cfg: TrainConfig, rng: np.random.Generator) -> tuple:
    """One pass over the training pairs in mini-batches, a rollout batch joining every few
    batches once ``use_roll``; the mean one-step, rollout and total losses."""
    n_pairs = len(P_tr["t"])
    n_batches = max(1, n_pairs // cfg.batch_size)
    losses.model.train()
    perm = torch.as_tensor(rng.permutation(n_pairs))
    roll_every = max(1, n_batches // max(1, cfg.rollout_batches_per_epoch))
    sum1 = sum2 = 0.0
    n1 = n2 = 0
    for b in range(n_batches):
        idx = perm[b * cfg.batch_size:(b + 1) * cfg.batch_size]
        loss = losses.one_step(P_tr, idx)
        sum1, n1 = sum1 + loss.item(), n1 + 1
        if use_roll and b % roll_every == 0:
            widx = torch.as_tensor(rng.choice(len(W_tr["x"]),
                                              min(cfg.rollout_batch, len(W_tr["x"])),
                                              replace=False))
            lr_ = losses.rollout(W_tr, widx)
            sum2, n2 = sum2 + lr_.item(), n2 + 1
            loss = loss + cfg.rollout_weight * lr_
        opt.zero_grad()
        loss.backward()
        opt.step()
    return (sum1 / max(1, n1), sum2 / n2 if n2 else None,
            sum1 / max(1, n1) + cfg.rollout_weight * sum2 / max(1, n2))


@dataclass(frozen=True)
class EpochRun:
    history: list[dict]
    best_epoch: int
    best_val_total: float
    best_state: dict
    stopped: str


def _epochs(losses: Losses, data: TrainingData, cfg: TrainConfig, rng: np.random.Generator,
            start: float, name: str) -> EpochRun:
    """Adam with exponential learning-rate decay, early stopping on the validation total."""
    model = losses.model
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    gamma = (cfg.lr_final / cfg.lr) ** (1.0 / max(1, cfg.epochs))
    sched = torch.optim.lr_scheduler.ExponentialLR(opt, gamma)
    P_tr, P_va = pair_tensors(data.pairs_train), pair_tensors(data.pairs_val)
    W_tr, W_va = window_tensors(data.windows_train), window_tensors(data.windows_val)
    val = losses.evaluate(P_va, W_va)
    history = [_history_row(0, losses.evaluate(P_tr, W_tr), val, cfg.lr,
                            time.perf_counter() - start)]
    best = (val[2], 0, {k: v.clone() for k, v in model.state_dict().items()})
    stopped = "epochs"
    bar = CheckedBar(range(1, cfg.epochs + 1), desc=f"train {name}", unit="epoch",
                     disable=not cfg.progress)
    for epoch in bar:
        use_roll = epoch > cfg.warmup_epochs and cfg.rollout_weight > 0
        train = _train_epoch(losses, opt, P_tr, W_tr, use_roll, cfg, rng)
        sched.step()
        v1, v2, vt = losses.evaluate(P_va, W_va)
        elapsed = time.perf_counter() - start
        history.append(_history_row(epoch, train, (v1, v2, vt), sched.get_last_lr()[0],
                                    elapsed))
        bar.set_postfix(val=f"{vt:.3g}", one=f"{v1:.3g}", roll=f"{v2:.3g}", refresh=False)
        if vt < best[0] and math.isfinite(vt):
            best = (vt, epoch, {k: v.clone() for k, v in model.state_dict().items()})
        elif epoch - best[1] >= cfg.patience and epoch > cfg.warmup_epochs:
            stopped = f"early stop (no improvement for {cfg.patience} epochs)"
            break
        if elapsed > cfg.max_seconds:
            stopped = f"time budget ({cfg.max_seconds:g} s)"
            break
    bar.close()
    return EpochRun(history, best[1], best[0], best[2], stopped)


def train(train_sorties: list[Sortie], val_sorties: list[Sortie], airframe: Airframe,
          config: TrainConfig | None = None, history_path: str | Path | None = None
          ) -> TrainResult:
    """Train the correction on ``train_sorties`` with early stopping on ``val_sorties``.

    Returns the best (lowest validation loss) network, exported as a :class:`CorrectionNet`
    tied to ``airframe.param_hash()``; the loss history has one entry per epoch, epoch 0 being
    the untrained network.
    """
    cfg = config or TrainConfig()
    rng = seeded_generator(cfg.seed, cfg.threads)
    start = time.perf_counter()
    data = training_data(train_sorties, val_sorties, airframe, cfg)
    p = _t(airframe.p)
    structure = correction_structure(airframe, airframe.kind)
    resid, step_scale, roll_scale = _physics_scales(airframe, structure, data, p, cfg)
    in_mean, in_scale, out_scale = _normalisation(airframe.kind, cfg.formulation,
                                                  data.pairs_train, resid, data.interval,
                                                  cfg.dt, data.substeps)
    model = TorchCorrection(airframe.kind, cfg.formulation, cfg.hidden, cfg.activation,
                            in_mean, in_scale, out_scale, cfg.dt, seed=cfg.seed,
                            structure=structure)
    losses = Losses(model, p, cfg.dt, data.substeps, step_scale, roll_scale,
                    cfg.rollout_weight)
    run = _epochs(losses, data, cfg, rng, start, airframe.name)
    model.load_state_dict(run.best_state)
    seconds = time.perf_counter() - start
    info = {"config": asdict(cfg), "airframe": airframe.name, "best_epoch": run.best_epoch,
            "best_val_total": run.best_val_total,
            "initial_val_total": run.history[0]["val_total"],
            "epochs_run": len(run.history) - 1, "stopped": run.stopped, "train_seconds": seconds,
            "n_train_sorties": len(train_sorties), "n_val_sorties": len(val_sorties),
            "substeps_per_sample": data.substeps,
            "train_sorties_source": sorted({str(s.meta.get("source", "")) for s in
                                            train_sorties})}
    # time range seen in training (time since each sortie's start), for a time-taking step
    net = model.export(airframe.param_hash(), info,
                       (0.0, data.t_max) if model.form.takes_time else None)
    result = TrainResult(net, run.history, cfg, run.best_epoch, seconds, run.stopped,
                         {"step_scale": step_scale.tolist(), "rollout_scale": roll_scale.tolist()})
    if history_path is not None:
        write_history(result, history_path)
    return result


def write_history(result: TrainResult, path: str | Path, data: str = "") -> tuple[Path, Path]:
    """Loss history as JSON (``path``) and a PNG plot beside it (``data``: the airframe and
    dataset, for its title), put in place together (:func:`uavdyn.outputs.atomic_files`)."""
    path = Path(path)
    png = path.with_suffix(".png")
    with atomic_files(path, png) as (json_tmp, png_tmp):
        write_history_files(result, json_tmp, png_tmp, data)
    return path, png


def write_history_files(result: TrainResult, json_path: Path, png_path: Path,
                        data: str = "") -> None:
    """Write the loss history JSON and its PNG to exactly these paths (temporary names that
    the caller renames into place with :func:`uavdyn.outputs.atomic_files`, with the weights
    they belong to)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, MaxNLocator, NullFormatter

    doc = {"config": asdict(result.config), "best_epoch": result.best_epoch,
           "stopped": result.stopped, "seconds": result.seconds, "scales": result.scales,
           "network": result.net.describe(), "history": result.history}
    Path(json_path).write_text(json.dumps(doc, indent=2) + "\n")
    ep = [h["epoch"] for h in result.history]
    fig, ax = plt.subplots(figsize=(7.2, 4.6), constrained_layout=True)
    for key, style in (("train_one_step", "C0-"), ("val_one_step", "C0--"),
                       ("train_rollout", "C1-"), ("val_rollout", "C1--"),
                       ("val_total", "k:")):
        vals = [h[key] for h in result.history]
        pts = [(e, v) for e, v in zip(ep, vals) if v is not None]
        if pts:
            ax.semilogy(*zip(*pts), style, label=key.replace("_", " "))
    ax.axvline(result.best_epoch, color="grey", lw=0.8)
    ax.set_xlabel("epoch (0 = untrained: hybrid = physics RK4)")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    plain = FuncFormatter(lambda v, _: f"{v:.3g}")  # 0.6, not 6x10^-1
    ax.yaxis.set_major_formatter(plain)
    low, high = ax.get_ylim()
    ax.yaxis.set_minor_formatter(plain if high < 10 * low else NullFormatter())
    ax.set_ylabel("loss / physics-only loss")
    ax.set_title(textwrap.fill(f"Training history{': ' + data if data else ''}; "
                               f"{result.net.describe()}; best epoch {result.best_epoch} "
                               "(grey)", 90), fontsize=8)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.savefig(png_path, dpi=120, format="png")
    plt.close(fig)
