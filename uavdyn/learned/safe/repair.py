"""The stability repair (``SafeConfig.stability_trims = "repair"``): training holds the modes
at the trims over the envelope's box only, and the exact check at the end also runs in the
margins out to where the gate reaches 0. Where a candidate at full output passes every other
check but fails there, the uniform output scale the search then falls back on shrinks the
correction everywhere for a failure at a few trims at the edge of the data (on the
knockout's trainer the power-effect correction failed only at 8.25 m/s, below its box, and
was kept at 0.75 of its output). The repair instead carries the best such candidate on for
``repair_epochs`` epochs with the penalty at every trim the check runs at, from the learning
rate it had, and lets those epochs compete with the others in the same final checks."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from uavdyn.learned.safe.epochs import EpochLoop, EpochRun, StabilityTargets, TrainingData
from uavdyn.learned.safe.selection import Checks, Search, search
from uavdyn.learned.stability import TrimSample


@dataclass(frozen=True)
class Repair:
    """What a stability repair did: the epoch it carried on, how many epochs at which
    learning rate, whether its candidate was kept, and its wall time."""

    from_epoch: int
    epochs: int
    lr: float
    n_trims: int
    kept: bool
    seconds: float

    def to_dict(self) -> dict:
        return {"from_epoch": self.from_epoch, "epochs": self.epochs, "lr": self.lr,
                "n_trims": self.n_trims, "kept": self.kept, "seconds": self.seconds}

    def describe(self) -> str:
        return (f"stability repair: epoch {self.from_epoch} trained on for {self.epochs} "
                f"epochs at learning rate {self.lr:.3g} with the penalty at all "
                f"{self.n_trims} trims of the exact check ({self.seconds:.0f} s); "
                + ("a repaired epoch kept" if self.kept else "no repaired epoch kept"))


def stability_only_failures(tried: list[dict], full_scale: float) -> list[dict]:
    """The candidates at full output (uniform) that passed every check but the stability
    one: their rows of the search's ``tried``."""
    return [r for r in tried if r.get("stable") is False and r["scale"] == full_scale
            and "channel_scales" not in r]


def repair_candidate(found: Search, full_scale: float) -> dict | None:
    """The row of the candidate to repair: of the stability-only failures, the best by mean
    validation ratio, if it beats what the search kept (None: nothing to repair)."""
    rows = stability_only_failures(found.tried, full_scale)
    if not rows:
        return None
    best = min(rows, key=lambda r: (r["val_ratio_geomean"], r["epoch"]))
    kept = found.chosen
    if kept is not None and kept.selection["val_ratio_geomean"] <= best["val_ratio_geomean"]:
        return None
    return best


def stability_repair(checks: Checks, run: EpochRun, found: Search, data: TrainingData,
                     check_trims: list[TrimSample], rng: np.random.Generator, start: float,
                     name: str) -> tuple[Search, EpochRun, Repair | None]:
    """The search's result after a repair (unchanged where there is nothing to repair).

    Parameters
    ----------
    checks, run, found : Checks, EpochRun, Search
        The final checks, the training run and what :func:`search` found on it.
    data : TrainingData
        What the epochs trained on.
    check_trims : list of TrimSample
        Every trim the exact check runs at (the repair's penalty holds them all; their
        targets are computed only when a repair is made).
    rng, start, name
        The run's generator, start time and airframe name (progress bar).

    Returns
    -------
    tuple
        The search with the repaired epochs competing (the best by mean validation ratio of
        what passed; every candidate tried of both), the run with the repair's epochs in its
        history (``phase`` "stability repair") and the repair (None if none was made).
    """
    cfg = checks.config
    row = repair_candidate(found, cfg.shrink[0])
    if row is None or cfg.repair_epochs <= 0:
        return found, run, None
    t0 = time.perf_counter()
    every_trim = StabilityTargets.at(checks.setup, check_trims)
    snapshot = next(s for s in run.snapshots if s.epoch == row["epoch"])
    checks.model.load_state_dict(snapshot.state)
    checks.scale(1.0, np.ones(len(checks.layout.bound)))
    lr = next(h["lr"] for h in run.history if h["epoch"] == snapshot.epoch)
    last = run.history[-1]["epoch"]
    loop = EpochLoop(checks.model, data, every_trim, cfg, rng, start, name,
                     first_epoch=last, lr=lr)
    loop.advance(last + cfg.repair_epochs, " stability repair")
    repaired = loop.result()
    again = search(checks, repaired)
    for r in again.tried:
        r["repair_of"] = snapshot.epoch
    passed = [c for c in (found.chosen, again.chosen) if c is not None]
    chosen = min(passed, key=lambda c: (c.selection["val_ratio_geomean"], c.epoch),
                 default=None)
    report = chosen.report if chosen is not None else (again.report or found.report)
    done = Repair(snapshot.epoch, loop.epoch - last, lr, len(every_trim.trims),
                  chosen is not None and chosen is again.chosen, time.perf_counter() - t0)
    history = run.history + [{**h, "phase": "stability repair", "repair_of": snapshot.epoch}
                             for h in repaired.history[1:]]
    merged = replace(run, history=history,
                     stopped=f"{run.stopped}; {done.describe()}")
    tried = found.tried + again.tried
    if chosen is not None:  # its weight file records every candidate and the repair
        chosen.net.info.update(shrink_tried=tried, stability_repair=done.to_dict(),
                               epochs_run=len(history) - 1,
                               train_seconds=time.perf_counter() - start)
    return Search(chosen, tried, report), merged, done
