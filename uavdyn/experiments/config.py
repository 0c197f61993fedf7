"""What the validation pipeline runs: :class:`ReproduceConfig`, the one configuration that
``uavdyn reproduce``, its data preparation and its stages read."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class ReproduceConfig:
    """What the pipeline runs. ``quick`` shrinks everything for tests."""

    airframes: tuple[str, ...] = ("quadrotor", "fixed_wing")
    out: str = "results"
    dts: tuple[float, ...] = (0.005, 0.01, 0.02)
    quick: bool = False
    sorties: int | None = None  # override the recipe's sortie count
    duration_s: float | None = None  # override the recipe's sortie duration
    retrain: bool = False
    weights_dir: str | None = None  # None: the weights shipped with the package
    cache: str | None = None
    cost_repeats: int = 15  # interleaved repeats of the one timing harness
    cost_segment_s: float | None = 5.0  # the timed stretch of the cost sortie (None: whole)
    save_trajectories: bool = False  # compressed npz of every prediction (large)
    progress: bool = True
    force: bool = False  # write into a non-empty folder that is not a previous reproduce output
    identify: bool = True  # fit the physics on the train split first (nominal -> identified)
    extra: dict = field(default_factory=dict)
