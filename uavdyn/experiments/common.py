"""Helpers shared by the reproduce pipeline and its figures: which steps are compared, what a
sortie's target states are and which condition it was flown in."""

from __future__ import annotations

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.flightdata import Sortie
from uavdyn.learned import hybrid_step

FORMULATIONS = ("improved", "paper")
TARGETS = ("data", "reference")


def target_states(sortie: Sortie) -> np.ndarray:
    """The flight-data target: noise-free true states where the data has them."""
    return sortie.true_states if sortie.true_states is not None else sortie.states


def condition(sortie: Sortie) -> str:
    return str(sortie.meta.get("condition", "") or "unknown")


def hybrid_steps(airframe: Airframe, nets: dict, target: str = "data") -> dict:
    """``{"hybrid <formulation>": step}`` for every formulation with weights for ``target``
    (uncompiled SX steps: exact derivatives, compiled where a rollout is timed)."""

    return {f"hybrid {f}": hybrid_step(nets[(f, target)], airframe, compile=False)
            for f in FORMULATIONS if nets.get((f, target)) is not None}
