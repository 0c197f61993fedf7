"""What an output-error identification returns: the estimates, their uncertainty and the fit."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from uavdyn.airframes import Airframe

DEFAULT_SUBSTEPS = 2     # RK steps per log sample (dt = half the log interval)


@dataclass(frozen=True)
class Estimate:
    """One identified parameter (``searched``: an integer delay found by search, in samples,
    whose standard error is 0 by convention)."""

    name: str
    nominal: float
    value: float
    std_error: float
    searched: bool = False
    at_bound: str = ""  # "lower"/"upper" where the estimate ended on a bound of the fit


    @property
    def relative_change(self) -> float:
        return (self.value - self.nominal) / self.nominal if self.nominal else math.nan


@dataclass
class IdentificationResult:
    """Estimates, their uncertainty and the fit they give (see :func:`identify`)."""

    airframe: Airframe
    estimates: list[Estimate]
    correlation: np.ndarray
    flagged_pairs: list[tuple[str, str, float]]
    state_sigma: np.ndarray
    cost_initial: float
    cost_final: float
    iterations: int
    seconds: float
    window_s: float
    dt: float
    fit: dict = field(default_factory=dict)
    substeps: int = DEFAULT_SUBSTEPS
    search: list[dict] = field(default_factory=list)

    def to_dict(self) -> dict:
        def number(v: float):
            return None if not math.isfinite(v) else v

        names = [e.name for e in self.estimates if not e.searched]
        return {
            "airframe": self.airframe.name,
            "estimates": [{"name": e.name, "nominal": e.nominal, "value": e.value,
                           "std_error": e.std_error,
                           "relative_change": number(e.relative_change),
                           **({"searched": True} if e.searched else {}),
                           **({"at_bound": e.at_bound} if e.at_bound else {})}
                          for e in self.estimates],
            "correlation_names": names,
            "correlation": self.correlation.tolist(),
            "flagged_pairs": [list(p) for p in self.flagged_pairs],
            "state_sigma": self.state_sigma.tolist(), "cost_initial": self.cost_initial,
            "cost_final": self.cost_final, "iterations": self.iterations,
            "seconds": self.seconds, "window_s": self.window_s, "dt": self.dt,
            "substeps": self.substeps, "search": self.search, "fit": self.fit,
            "note": "standard errors are Cramer-Rao bounds from the Gauss-Newton Hessian with "
                    "white residuals assumed; correlated residuals make them optimistic; "
                    "delays are searched integers (standard error 0 by convention)",
        }

