"""One prediction per model, step size, sortie and target in a run: the compared models
(:class:`Candidate`) and the store (:class:`PredictionStore`) that every table, the ladder
and the figures read their predictions from, so none is computed twice.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.evaluation import Solver, evaluate_trajectory, fine_reference, horizon_predictions
from uavdyn.experiments.common import target_states
from uavdyn.flightdata import Sortie
from uavdyn.model import sortie_params

TARGETS = ("data", "reference")


@dataclass(frozen=True)
class Candidate:
    """A model of a comparison at one step size.

    Attributes
    ----------
    solver : Solver
        Its row name in the tables, the discrete model and the step size.
    airframe : Airframe
        The airframe whose parameters it runs on.
    physics : str
        The rung of the ladder it sits on: ``"nominal"`` or ``"identified"`` physics.
    model : str or None
        What the model is, whatever its row is called (None: the solver's name): two
        candidates with the same ``model`` and step size make the same predictions, so a
        :class:`PredictionStore` computes them once.
    """

    solver: Solver
    airframe: Airframe
    physics: str = "nominal"
    model: str | None = None

    @property
    def label(self) -> str:
        """The row name (the solver's name)."""
        return self.solver.name

    @property
    def key(self) -> tuple[str, float]:
        """``(model, dt)``: what identifies its predictions."""
        return (self.model or self.solver.name, self.solver.dt)

    def named(self, name: str) -> Candidate:
        """The same model under another row name (its predictions are shared)."""
        return replace(self, solver=Solver(name, self.solver.model, self.solver.dt),
                       model=self.key[0])


class PredictionStore:
    """The predictions of one run, each computed on first use and then reused: per
    (model, step size, sortie) the :func:`~uavdyn.evaluation.evaluate_trajectory` result
    against the flight data and against the nominal fine-step reference, and the
    :func:`~uavdyn.evaluation.horizon_predictions` curve. Sortie names identify sorties (one
    dataset per run).

    Parameters
    ----------
    nominal : Airframe
        The nominal airframe: its fine-step RK4 on its own parameters is the reference target.
    """

    def __init__(self, nominal: Airframe) -> None:
        self.nominal = nominal
        self._made: dict[tuple, object] = {}

    def keys(self) -> list[tuple]:
        """The keys computed so far, in the order they were computed."""
        return list(self._made)

    def _get(self, key: tuple, compute):
        if key not in self._made:
            self._made[key] = compute()
        return self._made[key]

    def reference(self, sortie: Sortie) -> np.ndarray:
        """The nominal model's fine-step reference trajectory of ``sortie`` from its first
        flight-data state (:func:`~uavdyn.evaluation.fine_reference`)."""
        return self._get(("reference", sortie.name), lambda: fine_reference(
            self.nominal, sortie.time, target_states(sortie)[0], sortie.controls,
            self.nominal.p))

    def trajectory(self, cand: Candidate, sortie: Sortie, target: str = "data") -> dict:
        """One-step, 1 s and free-run predictions of ``cand`` on ``sortie`` against the flight
        data (``"data"``: :func:`target_states`) or the fine-step reference
        (``"reference"``), on the parameters of ``cand.airframe`` at the sortie's altitude."""
        if target not in TARGETS:
            raise ValueError(f"target must be one of {TARGETS}, got {target!r}")

        def compute() -> dict:
            states = target_states(sortie) if target == "data" else self.reference(sortie)
            return evaluate_trajectory(cand.solver, sortie.time, states, sortie.controls,
                                       sortie_params(cand.airframe, sortie.altitude_m))

        return self._get((*cand.key, sortie.name, target), compute)

    def horizons(self, cand: Candidate, sortie: Sortie, horizons_s) -> dict:
        """:func:`~uavdyn.evaluation.horizon_predictions` of ``cand`` on ``sortie`` against
        the flight data.

        Raises
        ------
        ValueError
            If the step refuses this step size or time range (every time it is asked).
        """
        horizons_s = tuple(float(h) for h in horizons_s)

        def compute():
            try:
                return horizon_predictions(cand.solver, sortie.time, target_states(sortie),
                                           sortie.controls,
                                           sortie_params(cand.airframe, sortie.altitude_m),
                                           horizons_s)
            except ValueError as exc:  # StepUseError is a ValueError: the step refuses
                return exc

        made = self._get((*cand.key, sortie.name, ("horizons", horizons_s)), compute)
        if isinstance(made, ValueError):
            raise made
        return made
