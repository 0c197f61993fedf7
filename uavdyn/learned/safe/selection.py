"""The safe trainer's final checks: through the best epochs by rank, the largest output scale
at which no validation sortie is worse than the physics (at the selection horizon and over free
runs), no body state's error grows beyond the per-state limit and the map keeps the stability
rule. These are post-hoc guards on every sortie, state and trim, not only on the pooled
figure; the first epoch and scale passing all of them is kept. Where a scale beats the physics
in pitch but makes a state worse beyond the limit, the output channel behind it may be the one
to cut (the forward-force residual, say, while the moment residual helps): one channel at a
time is scaled down before the next scale."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace

import numpy as np
import torch

from uavdyn.airframes import Airframe
from uavdyn.integrate import DiscreteModel
from uavdyn.learned.formulations import CorrectionLayout
from uavdyn.learned.hybrid import hybrid_step
from uavdyn.learned.safe.config import SafeConfig, SafeSetup
from uavdyn.learned.safe.data import WindowTensors, as_tensor
from uavdyn.learned.safe.epochs import EpochRun, Snapshot
from uavdyn.learned.safe.freerun import FreeRunGuard
from uavdyn.learned.safe.scoring import (
    Predictor,
    ValidationReference,
    beats_physics_in_pitch,
    score,
)
from uavdyn.learned.stability import StabilityReport, TrimSample, check_map_stability
from uavdyn.learned.torch_model import TorchCorrection
from uavdyn.learned.weights import CorrectionNet


@dataclass(frozen=True)
class RunFacts:
    """What a weight file's ``info`` records about the run besides the chosen candidate."""

    config: SafeConfig
    airframe: str
    physics_rmse: float
    selection_horizon_s: float
    epochs_run: int
    n_train_sorties: int
    n_val_sorties: int
    trims: list[str]
    trims_skipped: list[str]
    memory_tau: tuple[float, ...]
    start: float  # the run's time.perf_counter()
    screened: list[dict] = field(default_factory=list)  # the starts screened (restarts > 1)
    start_fits: dict = field(default_factory=dict)  # how window starts were fitted, per split

    def info(self, alpha: float, channels: np.ndarray, final: dict, tried: list, epoch: int
             ) -> dict:
        """The ``info`` of the network at output scale ``alpha`` x ``channels`` of ``epoch``
        (validation figures ``final``, candidates ``tried``)."""
        return {"config": asdict(self.config), "airframe": self.airframe, "best_epoch": epoch,
                "output_scale": alpha, "channel_scales": [float(c) for c in channels],
                "shrink_tried": tried,
                "val_theta_rmse": final["val_theta_rmse"],
                "val_ratio_geomean": final["val_ratio_geomean"],
                "val_ratio_worst": final["val_ratio_worst"],
                "physics_val_theta_rmse": self.physics_rmse,
                "selection_horizon_s": self.selection_horizon_s, "epochs_run": self.epochs_run,
                "n_train_sorties": self.n_train_sorties, "n_val_sorties": self.n_val_sorties,
                "trims": list(self.trims), "trims_skipped": self.trims_skipped,
                "memory_tau": list(self.memory_tau), "screened": list(self.screened),
                "start_fits": dict(self.start_fits),
                "train_seconds": time.perf_counter() - self.start}


@dataclass(frozen=True)
class SeenSorties:
    """The training sorties' windows, scored by the final checks as the validation ones are
    (``SafeConfig.seen_guard``): the rule that no sortie gets worse covers every regime flown,
    not only those the validation split happens to hold."""

    windows: WindowTensors
    reference: ValidationReference
    predict: Predictor | None = None


@dataclass(frozen=True)
class Checks:
    """Everything the final checks of a trained model use."""

    model: TorchCorrection
    layout: CorrectionLayout    # as trained: scales and bounds are relative to it
    out_scale: torch.Tensor     # as trained
    airframe: Airframe
    setup: SafeSetup
    trims: list[TrimSample]
    skipped: list[str]
    val: WindowTensors
    reference: ValidationReference
    guard: FreeRunGuard
    facts: RunFacts
    predict: Predictor | None = None  # the compiled twin's free runs (None: torch's)
    seen: SeenSorties | None = None   # the training sorties' guard (None: not checked)

    @property
    def config(self) -> SafeConfig:
        return self.setup.config

    def scale(self, alpha: float, channels: np.ndarray) -> None:
        """Set the model's outputs to ``alpha`` x ``channels`` of the trained ones (a channel
        switched off keeps a positive bound: its output is 0 through the bound)."""
        bound0 = np.asarray(self.layout.bound, float)
        with torch.no_grad():
            self.model.out_scale.copy_(self.out_scale * as_tensor(alpha * channels))
        self.model.layout = replace(self.layout, bound=bound0 * alpha
                                    * np.where(channels > 0, channels, 1.0))

    def export(self, alpha: float, channels: np.ndarray, final: dict, tried: list,
               epoch: int) -> CorrectionNet:
        return self.model.export(self.airframe.param_hash(),
                                 self.facts.info(alpha, channels, final, tried, epoch))

    def step(self, net: CorrectionNet) -> DiscreteModel:
        """``net``'s hybrid step (CasADi VM: each is used a few times)."""
        return hybrid_step(net, self.airframe, compile=False)

    def stability(self, step: DiscreteModel) -> StabilityReport:
        """The exact stability check of a hybrid ``step``'s map at the trims."""
        return check_map_stability(step, self.setup.physics, self.trims, self.setup.dt,
                                   self.config.stability_margin, self.skipped)


@dataclass(frozen=True)
class Chosen:
    """The candidate that passed every check."""

    scale: float
    channels: np.ndarray
    selection: dict
    net: CorrectionNet
    epoch: int
    report: StabilityReport
    row: dict  # its row of the tried candidates (figures and verdicts)


@dataclass(frozen=True)
class Search:
    """What the final checks found: the kept candidate (or None), every candidate tried (rows
    with their figures and verdicts) and the last stability report made (None if none)."""

    chosen: Chosen | None
    tried: list[dict]
    report: StabilityReport | None


def final_checks(checks: Checks, alpha: float, channels: np.ndarray, sel: dict, row: dict,
                 epoch: int, tried: list) -> tuple[Chosen | None, StabilityReport | None]:
    """The free-run guard and the exact stability check of one candidate (recorded in
    ``row``): what is kept (or None) and the stability report (None if not reached)."""
    net = checks.export(alpha, channels, sel, tried, epoch)
    step = checks.step(net)
    if checks.config.free_run_guard:
        row.update(checks.guard.verdict(step))
        if not row["free_run_ok"]:
            return None, None
    report = checks.stability(step)
    row["stable"] = report.ok
    return (Chosen(alpha, channels, sel, net, epoch, report, row) if report.ok else None), report


def _try_scale(checks: Checks, epoch: int, alpha: float, tried: list,
               report: StabilityReport | None) -> tuple[Chosen | None, StabilityReport | None]:
    """Output scale ``alpha`` of the loaded epoch, uniform, then (where it beats the physics
    in pitch but a state got worse) one channel at a time; each try appended to ``tried``."""
    cfg = checks.config
    n_out = len(checks.layout.bound)
    uniform = np.ones(n_out)
    trials = [(uniform, True)]
    for channels, is_uniform in trials:  # grows by the channel variants at most once
        checks.scale(alpha, channels)
        sel = score(checks.model, checks.val, checks.reference, checks.setup.dt,
                    checks.predict)
        row = {"epoch": epoch, "scale": alpha,
               **({} if is_uniform else {"channel_scales": [float(c) for c in channels]}),
               **{k: v for k, v in sel.items() if k != "val_sortie_ratios"}}
        tried.append(row)
        if not beats_physics_in_pitch(sel, cfg, checks.reference.physics_rmse):
            continue
        if sel["val_state_ratio_worst"] > cfg.state_ratio_limit:
            if is_uniform:
                trials.extend((np.where(np.arange(n_out) == c, f, 1.0), False)
                              for f in cfg.channel_scales for c in range(n_out))
            continue
        if not _seen_sorties_kept(checks, row):
            continue
        chosen, made = final_checks(checks, alpha, channels, sel, row, epoch, tried)
        report = made if made is not None else report
        if chosen is not None:
            return chosen, report
    return None, report


def _seen_sorties_kept(checks: Checks, row: dict) -> bool:
    """Whether no training sortie is worse than the physics beyond the per-sortie limit
    (noise taken off, at the selection horizon); the worst ratio and the sorties beyond it
    recorded in ``row``. True without a guard."""
    seen = checks.seen
    if seen is None:
        return True
    sel = score(checks.model, seen.windows, seen.reference, checks.setup.dt, seen.predict)
    limit = checks.config.worst_sortie_ratio
    row["train_ratio_worst"] = sel["val_ratio_worst"]
    row["train_sorties_worse"] = [name for name, r in zip(seen.reference.names,
                                                         sel["val_sortie_ratios"])
                                  if r is not None and r > limit]
    row["train_ok"] = sel["val_ratio_worst"] <= limit
    return row["train_ok"]


def search(checks: Checks, run: EpochRun) -> Search:
    """Through the best ``candidate_epochs`` snapshots of ``run`` by rank and as many by mean
    validation ratio (an epoch that learned more but made one sortie a little worse may pass
    at a smaller output scale), each output scale of ``config.shrink`` in turn until one
    passes every check; of the candidates that pass, the one with the best mean validation
    ratio at its scale is kept."""
    cfg = checks.config
    n = max(1, cfg.candidate_epochs)
    by_rank = sorted(run.snapshots, key=lambda c: (c.rank, c.epoch))[:n]
    by_mean = sorted(run.snapshots, key=lambda c: (c.selection["val_ratio_geomean"],
                                                   c.epoch))[:n]
    candidates = (list({c.epoch: c for c in by_rank + by_mean}.values())
                  or [run.best])  # no finite epoch: the untrained (zero) network, never kept
    tried: list[dict] = []
    report = None
    passed: list[Chosen] = []
    for snapshot in candidates:
        checks.model.load_state_dict(snapshot.state)
        for alpha in cfg.shrink:
            chosen, report = _try_scale(checks, snapshot.epoch, alpha, tried, report)
            if chosen is not None:
                passed.append(chosen)
                break
    if not passed:
        return Search(None, tried, report)
    best = min(passed, key=lambda c: (c.selection["val_ratio_geomean"], c.epoch))
    return Search(best, tried, best.report)


def fallback(checks: Checks, best: Snapshot, tried: list, report: StabilityReport | None
             ) -> StabilityReport:
    """Nothing kept: the best epoch at the first output scale, its stability report (the last
    one made, or one made now)."""
    cfg = checks.config
    checks.model.load_state_dict(best.state)
    uniform = np.ones(len(checks.layout.bound))
    checks.scale(cfg.shrink[0], uniform)
    if report is not None:
        return report
    return checks.stability(checks.step(checks.export(cfg.shrink[0], uniform, best.selection,
                                                      tried, best.epoch)))
