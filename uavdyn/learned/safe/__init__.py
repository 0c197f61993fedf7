"""Training of the safe correction (the ``improved`` formulation, weight format 4): causal,
state-complete inputs on the identified physics' augmented state plus a command memory, an
envelope gate and an output bound, rollout losses over several horizons from recorded states, a
stability penalty at trims over the training envelope, selection by the validation 1 s error,
an exact stability check before anything is written, and the rule that a correction which does
not beat the physics on the validation split is not kept.

Losses are normalised so the physics-only step scores exactly 1 (per state by the physics'
rollout error, per horizon step by the physics' error growth), so every number reads as "the
fraction of the physics' squared error left".

One module per stage: :mod:`~uavdyn.learned.safe.config` (configuration, result, derived
setup), :mod:`~uavdyn.learned.safe.data` (windows, network scaling, loss normalisation),
:mod:`~uavdyn.learned.safe.scoring` (loss and validation figures),
:mod:`~uavdyn.learned.safe.epochs` (the epoch loop), :mod:`~uavdyn.learned.safe.selection`
and :mod:`~uavdyn.learned.safe.freerun` (the final checks), :mod:`~uavdyn.learned.safe.verdict`
(validation figures and reasons), :mod:`~uavdyn.learned.safe.trainer` (:func:`train_safe`)
and :mod:`~uavdyn.learned.safe.history` (the record).
"""

from uavdyn.learned.safe.config import (
    DEFAULT_HIDDEN,
    SafeConfig,
    SafeResult,
    SafeTrainingError,
)
from uavdyn.learned.safe.freerun import START_FIT_S
from uavdyn.learned.safe.history import write_safe_history
from uavdyn.learned.safe.trainer import train_safe

__all__ = ["DEFAULT_HIDDEN", "START_FIT_S", "SafeConfig", "SafeResult", "SafeTrainingError",
           "train_safe", "write_safe_history"]
