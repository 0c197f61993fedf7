"""The safe trainer's free-run guard: every validation sortie flown open loop by the physics
and by the corrected step from the same fitted start, judged by
:func:`uavdyn.learned.rules.free_run_verdict` (no new departure, no sortie the physics follows
made worse beyond the per-sortie limit)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.flightdata import Sortie
from uavdyn.integrate import DiscreteModel, estimate_start, sortie_free_run
from uavdyn.learned.rules import departed, free_run_verdict
from uavdyn.learned.safe.config import THETA
from uavdyn.model import sortie_params

START_FIT_S = 1.0  # the free-run guard fits each run's start to this much of the sortie


def free_run_errors(model: DiscreteModel, sorties: list[Sortie], airframe: Airframe,
                    sample_dt: float, body_starts: list[np.ndarray]
                    ) -> list[tuple[float, bool]]:
    """Per sortie: pitch RMSE of its free run (:func:`uavdyn.integrate.sortie_free_run`) from
    ``body_starts[i]``, and whether it departed from the data
    (:func:`uavdyn.learned.rules.departed`)."""
    out = []
    for s, body in zip(sorties, body_starts):
        traj = sortie_free_run(model, s, airframe, sample_dt, body0=body, check=False)
        with np.errstate(all="ignore"):
            err = np.abs(traj[:, THETA] - s.states[:, THETA])
            rmse = float(np.sqrt(np.mean(err**2))) if np.all(np.isfinite(err)) else math.inf
        out.append((rmse, departed(traj[:, THETA], s.states[:, THETA])))
    return out


def fitted_start(phys: DiscreteModel, sortie: Sortie, airframe: Airframe, sample_dt: float,
                 noise: np.ndarray) -> np.ndarray:
    """Body states to start a validation free run from: fitted through the physics to the
    first :data:`START_FIT_S` of records (:func:`uavdyn.integrate.estimate_start`), each state
    weighted by its ``noise`` (:func:`uavdyn.learned.rules.state_noise`). Both the physics'
    run and the corrected one start there, so neither inherits the noise of the first sample,
    which would add an error common to both and pull their ratio to 1."""
    p = sortie_params(airframe, sortie.altitude_m)
    z0 = phys.initial_state(sortie.states[0], sortie.controls[:1], p, sample_dt)
    n = max(1, min(len(sortie.time) - 1, int(round(START_FIT_S / sample_dt))))
    spread = np.std(sortie.states[:n + 1, :4], axis=0)
    scale = np.maximum(noise, 1e-6 * (1.0 + spread))
    return estimate_start(phys, z0, sortie.controls[:n], sortie.states[:n + 1], p, sample_dt,
                          scale)[:4]


def _finite(rmse: float) -> float | None:
    """An RMSE for a JSON record (None for a run that diverged)."""
    return float(rmse) if math.isfinite(rmse) else None


@dataclass
class FreeRunGuard:
    """The free-run rule over the validation ``sorties``; the physics' runs are flown once,
    when the first candidate is judged."""

    physics: DiscreteModel
    sorties: list[Sortie]
    airframe: Airframe
    sample_dt: float
    state_noise: np.ndarray  # (n, 4) per sortie
    worst_ratio: float

    @cached_property
    def starts(self) -> list[np.ndarray]:
        """The fitted start of every sortie (:func:`fitted_start`)."""
        return [fitted_start(self.physics, s, self.airframe, self.sample_dt, n)
                for s, n in zip(self.sorties, self.state_noise)]

    @cached_property
    def physics_runs(self) -> list[tuple[float, bool]]:
        """:func:`free_run_errors` of the physics."""
        return free_run_errors(self.physics, self.sorties, self.airframe, self.sample_dt,
                               self.starts)

    def verdict(self, step: DiscreteModel) -> dict:
        """:func:`uavdyn.learned.rules.free_run_verdict` of ``step`` against the physics."""
        physics = self.physics_runs
        corrected = free_run_errors(step, self.sorties, self.airframe, self.sample_dt,
                                    self.starts)
        verdict = free_run_verdict(physics, corrected, self.worst_ratio,
                                   [float(n) for n in self.state_noise[:, THETA]])
        # the figures behind it, per sortie: pitch RMSE of each free run (rad)
        verdict["free_run_rmse"] = {s.name: [_finite(p[0]), _finite(c[0])] for s, p, c in
                                    zip(self.sorties, physics, corrected)}
        return verdict
