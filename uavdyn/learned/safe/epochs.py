"""The safe trainer's epoch loop: Adam with an exponentially decaying learning rate over
random mini-batches of windows, the stability penalty at trims, the validation figures and
fixed-window losses after every epoch (the history), a snapshot of every trained epoch (the
candidates of the final checks) and patience on the selection rank."""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
import torch

from uavdyn.interrupts import CheckedBar
from uavdyn.learned.safe.config import SafeConfig, SafeSetup
from uavdyn.learned.safe.data import WindowTensors
from uavdyn.learned.safe.scoring import (
    Predictor,
    ValidationReference,
    WindowLoss,
    rank,
    score,
)
from uavdyn.learned.safe.twin import CompiledTwin
from uavdyn.learned.stability import (
    TrimSample,
    body_abscissa,
    stability_penalty,
    training_target,
)
from uavdyn.learned.torch_model import TorchCorrection, seeded_generator


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
    twin: CompiledTwin | None = None  # the compiled rollouts and gradients (None: torch's)
    inputs: torch.Tensor | None = None  # the network's inputs at every training sample
    validation_predictor: Predictor | None = None  # scores the validation windows (None:
                                                    # the twin's or torch's free runs)
    train_starts: Callable[[TorchCorrection], torch.Tensor] | None = None  # the training
    # windows' starts fitted by a network (SafeConfig.train_refit_every; None: records)

    @property
    def predict(self) -> Predictor | None:
        if self.validation_predictor is not None:
            return self.validation_predictor
        return self.twin.predict if self.twin is not None else None

    def window_loss(self, model: TorchCorrection, D: WindowTensors) -> float:
        """The loss on the windows ``D`` (no gradient)."""
        with torch.no_grad():
            if self.twin is None:
                return float(self.loss(model, D))
            return float(self.loss.of_prediction(torch.as_tensor(self.twin.predict(model, D)),
                                                 D))


@dataclass(frozen=True)
class StabilityTargets:
    """Trim points and the allowed abscissa (minus a buffer) the penalty holds each to."""

    trims: list[TrimSample]
    targets: list[float]

    @classmethod
    def at(cls, setup: SafeSetup, trims: list[TrimSample]) -> StabilityTargets:
        """The training target of each of ``trims`` (from the physics' own abscissa there)."""
        phys, dt = setup.physics, setup.dt
        jp = phys.jacobians()
        sigma = [body_abscissa(np.array(jp(t.z[:phys.nx], t.u, t.p, dt)[1]), dt)[0]
                 for t in trims]
        margin = setup.config.stability_margin
        return cls(trims, [training_target(x, margin) for x in sigma])


@dataclass(frozen=True)
class EpochRun:
    """The loss history (epoch 0: the untrained network, the physics), every trained epoch's
    snapshot with a finite validation error, and the best by rank (epoch 0 if none beat it)."""

    history: list[dict]
    snapshots: list[Snapshot]
    best: Snapshot
    stopped: str = ""  # why the epochs ended
    screened: list[dict] = field(default_factory=list)  # restarts tried (cfg.restarts > 1)


def _state(model: TorchCorrection) -> dict:
    return {k: v.clone() for k, v in model.state_dict().items()}


def fixed_losses(model: TorchCorrection, data: TrainingData) -> dict:
    """The loss on the fixed training and validation windows."""
    return {"train_loss_fixed": data.window_loss(model, data.train.take(data.fixed[0])),
            "val_loss_fixed": data.window_loss(model, data.val.take(data.fixed[1]))}


OUTPUT_ROWS = 256  # training samples the output penalty looks at per optimiser step


def output_penalty(model: TorchCorrection, rows: torch.Tensor) -> torch.Tensor:
    """Mean square of the network's output over input ``rows`` in units of its output scale
    (the RMS one-step residual of the training data): the price of saying anything, so where
    the data cannot tell a correction from noise it stays near zero (a ridge penalty in
    function space)."""
    return torch.mean((model(rows) / model.out_scale) ** 2)


def damping_penalty(model: TorchCorrection, batch: WindowTensors, dt: float) -> torch.Tensor:
    """Mean hinge ``relu(M_q,hybrid - max(M_q,physics, 0))`` over the windows' first steps,
    ``M_q = (d q_next / d q - 1) / dt`` of each step (1/s): a sign prior on the hybrid's pitch
    damping. A correction may weaken the damping the physics has (the identified one may hold
    too much of it) but not reverse it: in rollouts a reversed damping feeds the model's own
    pitch-rate error back into its moment, which no one-step residual shows."""
    u0, p = batch.u[:, 0], batch.p.T

    def pitch_damping(step, trained: bool) -> torch.Tensor:
        z = batch.z0.detach().clone().requires_grad_(True)
        q_next = step(z, u0, p, dt)[:, 2]
        grad = torch.autograd.grad(q_next.sum(), z, create_graph=trained)[0][:, 2]
        return (grad - 1.0) / dt

    hybrid = pitch_damping(model.step, True)  # differentiated again, into the weights
    physics = pitch_damping(model.step_without_network, False).detach()
    return torch.mean(torch.relu(hybrid - torch.clamp(physics, min=0.0)))


class WeightAverage:
    """An exponential moving average of a network's weights over the optimiser steps (Polyak
    averaging): the network the epochs score and keep when ``cfg.average_decay`` > 0. The
    weights Adam visits scatter around a minimum by the step size; their average sits nearer
    its centre, so which epoch validation happens to pick matters less (averaging weights
    along the trajectory approximates an ensemble at the cost of one network: Izmailov et al.
    2018). The decay ramps up as ``(1 + n) / (10 + n)`` over the first steps, so the start's
    random weights do not linger."""

    def __init__(self, model: TorchCorrection, decay: float) -> None:
        self.model, self.decay, self.steps = copy.deepcopy(model), decay, 0

    def update(self, trained: TorchCorrection) -> None:
        self.steps += 1
        keep = min(self.decay, (1.0 + self.steps) / (10.0 + self.steps))
        with torch.no_grad():
            for mean, param in zip(self.model.parameters(), trained.parameters()):
                mean.lerp_(param.detach(), 1.0 - keep)


def train_epoch(model: TorchCorrection, opt: torch.optim.Optimizer, data: TrainingData,
                stab: StabilityTargets, cfg: SafeConfig, rng: np.random.Generator,
                average: WeightAverage | None = None, linear_stage: bool = False
                ) -> tuple[float, float, float]:
    """One epoch of ``cfg.batches_per_epoch`` Adam steps (each folded into ``average``); the
    mean loss, stability penalty and damping penalty. ``linear_stage``: the hidden layers
    are not updated (their output weights start at zero, so they stay silent)."""
    sum_l = sum_s = sum_d = 0.0
    n_w = data.train.count
    for _ in range(cfg.batches_per_epoch):
        idx = torch.as_tensor(rng.choice(n_w, min(cfg.batch_windows, n_w), replace=False))
        batch = data.train.take(idx)
        opt.zero_grad()
        if data.twin is None:
            loss_t = data.loss(model, batch)
            pen_t = (stability_penalty(model, stab.trims, stab.targets, data.loss.dt)
                     if stab.trims else loss_t * 0)
            (loss_t + cfg.stability_weight * pen_t).backward()
            loss, pen = loss_t.item(), float(pen_t.detach())
        else:  # the compiled twin's values and gradients
            loss, grad = data.twin.loss_and_grad(model, batch, data.loss.pooled_weight)
            pen, pen_grad = data.twin.penalty_and_grad(model, stab.trims, stab.targets,
                                                       data.loss.dt)
            grads = data.twin.unflatten(grad + cfg.stability_weight * pen_grad)
            for param, g in zip(model.parameters(), grads):
                param.grad = torch.as_tensor(g, dtype=param.dtype)
        if cfg.output_weight > 0 and data.inputs is not None:  # adds to the gradients
            rows = data.inputs[torch.as_tensor(rng.choice(len(data.inputs),
                                                          min(OUTPUT_ROWS, len(data.inputs)),
                                                          replace=False))]
            (cfg.output_weight * output_penalty(model, rows)).backward()
        if cfg.damping_weight > 0:  # adds to the gradients too
            damping = damping_penalty(model, batch, data.loss.dt)
            (cfg.damping_weight * damping).backward()
            sum_d += float(damping.detach())
        if linear_stage:
            model.drop_hidden_gradients()
        opt.step()
        model.hold_linear_only()
        if average is not None:
            average.update(model)
        sum_l, sum_s = sum_l + loss, sum_s + pen
    n = cfg.batches_per_epoch
    return sum_l / n, sum_s / n, sum_d / n


class EpochLoop:
    """The epochs of one network, resumable: :meth:`advance` trains up to an epoch number
    (patience and ``cfg.max_seconds`` end the run earlier), so several starts can be screened
    for a few epochs each and one carried on (:func:`screened_start`, ``restarts``)."""

    def __init__(self, model: TorchCorrection, data: TrainingData, stab: StabilityTargets,
                 cfg: SafeConfig, rng: np.random.Generator, start: float, name: str,
                 first_epoch: int = 0, lr: float | None = None) -> None:
        """``first_epoch``, ``lr``: a loop carrying on a trained ``model`` (a stability
        repair) counts its epochs from ``first_epoch`` at the fixed learning rate ``lr``;
        otherwise epochs count from 0 and the rate decays from ``cfg.lr`` to
        ``cfg.lr_final``."""
        self.model, self.data, self.stab, self.cfg, self.rng = model, data, stab, cfg, rng
        self.start, self.name = start, name
        self.average = WeightAverage(model, cfg.average_decay) if cfg.average_decay else None
        self.opt = torch.optim.Adam(model.parameters(), lr=cfg.lr if lr is None else lr)
        gamma = (1.0 if lr is not None
                 else (cfg.lr_final / cfg.lr) ** (1.0 / max(1, cfg.epochs)))
        self.sched = torch.optim.lr_scheduler.ExponentialLR(self.opt, gamma)
        sel0 = score(model, data.val, data.reference, data.loss.dt, data.predict)
        self.history = [{"epoch": first_epoch, **sel0, **fixed_losses(model, data),
                         "physics_val_theta_rmse": data.reference.physics_rmse,
                         "seconds": time.perf_counter() - start}]
        self.best = Snapshot((True, math.inf), first_epoch, _state(model), sel0)
        # patience counts epochs without progress: a better rank, or a better mean ratio over
        # the validation sorties (an epoch that makes one sortie a little worse still learns:
        # the final checks scale its output down until every sortie passes)
        self.best_mean, self.progress, self.epoch = math.inf, first_epoch, first_epoch
        self.snapshots: list[Snapshot] = []
        self.stopped = ""
        self.screened: list[dict] = []  # the starts screened before this one was chosen

    def advance(self, until: int, label: str = "") -> None:
        """Train epochs ``epoch + 1 .. until`` unless the run has already stopped."""
        cfg, data, model = self.cfg, self.data, self.model
        ref, physics_val = data.reference, data.reference.physics_rmse
        bar = CheckedBar(range(self.epoch + 1, until + 1), desc=f"train {self.name} (safe)"
                         + label, unit="epoch", disable=not cfg.progress)
        for epoch in bar:
            if self.stopped:
                break
            loss, penalty, damping = train_epoch(model, self.opt, data, self.stab, cfg,
                                                 self.rng, self.average,
                                                 epoch <= cfg.linear_first_epochs)
            self.sched.step()
            if (data.train_starts is not None and cfg.train_refit_every
                    and epoch % cfg.train_refit_every == 0):
                self.data = data = replace(data, train=replace(
                    data.train, z0=data.train_starts(self.scored)))
            sel = score(self.scored, data.val, ref, data.loss.dt, data.predict)
            elapsed = time.perf_counter() - self.start
            self.history.append({"epoch": epoch, "train_loss": loss,
                                 **fixed_losses(self.scored, data), "stability_penalty": penalty,
                                 "damping_penalty": damping,
                                 **sel, "physics_val_theta_rmse": physics_val,
                                 "lr": self.sched.get_last_lr()[0], "seconds": elapsed})
            bar.set_postfix(loss=f"{loss:.3g}", val=f"{sel['val_theta_rmse']:.3g}",
                            physics=f"{physics_val:.3g}",
                            ratio=f"{sel['val_ratio_geomean']:.3g}",
                            worst=f"{sel['val_ratio_worst']:.3g}", refresh=False)
            self.epoch = epoch
            self._keep(epoch, sel)
            counted_from = max(self.progress, cfg.linear_first_epochs)  # or the release
            if epoch - counted_from >= cfg.patience:
                self.stopped = (f"patience: no better validation rank or mean ratio in the "
                                f"{cfg.patience} epochs after epoch {counted_from}")
            elif elapsed > cfg.max_seconds:
                self.stopped = f"wall-clock budget: {elapsed:.0f} s > {cfg.max_seconds:g} s"
        bar.close()
        if not self.stopped and self.epoch >= cfg.epochs:
            self.stopped = f"epoch budget: {cfg.epochs} epochs"

    @property
    def scored(self) -> TorchCorrection:
        """The network the epochs score and keep: the trained one, or its weight average."""
        return self.model if self.average is None else self.average.model

    def _keep(self, epoch: int, sel: dict) -> None:
        if not math.isfinite(sel["val_theta_rmse"]):
            return
        self.snapshots.append(Snapshot(rank(sel, self.cfg), epoch, _state(self.scored), sel))
        if self.snapshots[-1].rank < self.best.rank:
            self.best, self.progress = self.snapshots[-1], epoch
        if sel["val_ratio_geomean"] < self.best_mean:
            self.best_mean, self.progress = sel["val_ratio_geomean"], epoch

    def result(self) -> EpochRun:
        return EpochRun(self.history, self.snapshots, self.best, self.stopped, self.screened)


def restart_seed(seed: int, start: int) -> int:
    """The seed of restart ``start`` (0: the run's own seed)."""
    return seed + 1000 * start


def screened_start(model: TorchCorrection, network: Callable[[int], TorchCorrection],
                   data: TrainingData, stab: StabilityTargets, cfg: SafeConfig,
                   rng: np.random.Generator, start: float, name: str) -> EpochLoop:
    """The loop to carry on: ``model``'s own, or with ``cfg.restarts`` > 1 the one of that
    many networks (``network(seed)``, seeds :func:`restart_seed`) with the lowest loss on the
    fixed training windows after ``cfg.restart_epochs`` epochs each (its least over them).
    Where a run lands depends on its start as much as on the design (knockout benchmark: the
    F450's inflow term recovered 0.45, 0.89 or 0.72 of the term over three seeds). The
    training loss chooses, not the validation error: a start picked by validation would be
    the one that is luckiest on the very sorties that then decide whether to keep it."""
    loops = [EpochLoop(model, data, stab, cfg, rng, start, name)]
    for i in range(1, cfg.restarts):
        seed = restart_seed(cfg.seed, i)
        loops.append(EpochLoop(network(seed), data, stab, cfg,
                               seeded_generator(seed, cfg.threads), start, name))
    if len(loops) == 1:
        return loops[0]
    for i, loop in enumerate(loops):
        loop.advance(min(cfg.restart_epochs, cfg.epochs), f" start {i + 1}/{len(loops)}")
    losses = [min(h["train_loss_fixed"] for h in loop.history[1:]) if len(loop.history) > 1
              else math.inf for loop in loops]
    chosen = int(np.argmin(losses))
    loops[chosen].screened = [
        {"seed": restart_seed(cfg.seed, i), "train_loss_fixed": losses[i],
         "best_epoch": lp.best.epoch, "chosen": i == chosen} for i, lp in enumerate(loops)]
    return loops[chosen]
