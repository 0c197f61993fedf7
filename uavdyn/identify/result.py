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
    whose standard errors are 0 by convention).

    ``std_error`` is the Cramer-Rao bound (white residuals), ``std_error_corrected`` the one
    corrected for the residuals' autocorrelation (:mod:`uavdyn.identify.uncertainty`): the one
    to use. ``undetermined`` says why the data do not determine the value (empty: they do) and
    ``excitation`` what flight data would. ``kept`` says why ``value`` is the airframe file's
    value rather than the fit's (a parameter the data do not determine keeps it by default;
    the others were refitted with it fixed). Under a prior (maximum a posteriori),
    ``data_value`` is the data-only estimate, ``prior_share`` the prior's share of the
    information, ``1 - var_posterior / var_data`` (corrected variances: 0 = the data alone,
    1 = the prior alone), and the standard errors are the posterior's. ``held`` says that the
    value was fitted with the combination of a collinear group the data cannot determine held
    at the file's values (``data_value``: the unconstrained fit's)."""

    name: str
    nominal: float
    value: float
    std_error: float
    searched: bool = False
    at_bound: str = ""  # "lower"/"upper" where the estimate ended on a bound of the fit
    std_error_corrected: float = math.nan
    undetermined: tuple[str, ...] = ()
    excitation: str = ""
    kept: str = ""
    data_value: float = math.nan
    prior_share: float = math.nan
    held: str = ""

    @property
    def determined(self) -> bool:
        return not self.undetermined and not self.at_bound

    def flags(self) -> list[str]:
        """Everything that makes the value unreliable, as phrases for the headline."""
        out = list(self.undetermined)
        if self.at_bound:
            out.append(f"the fit ended on its {self.at_bound} bound")
        return out

    def pull(self) -> str:
        """How much a prior set the value (empty without one)."""
        if not math.isfinite(self.prior_share):
            return ""
        return (f"prior {100 * self.prior_share:.0f} % of the information; data alone "
                f"{self.data_value:.6g}")

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
    diagnostics: dict = field(default_factory=dict)

    @property
    def fitted_names(self) -> list[str]:
        """The continuous parameters of the final fit (the rows of ``correlation``): not the
        searched delays, nor those that kept the file's value."""
        return [e.name for e in self.estimates if not e.searched and not e.kept]

    def to_dict(self) -> dict:
        def number(v: float):
            return None if not math.isfinite(v) else v

        names = self.fitted_names
        return {
            "airframe": self.airframe.name,
            "estimates": [{"name": e.name, "nominal": e.nominal, "value": e.value,
                           "std_error": e.std_error,
                           "std_error_corrected": number(e.std_error_corrected),
                           "relative_change": number(e.relative_change),
                           "determined": e.determined, "flags": e.flags(),
                           **({"excitation": e.excitation} if e.excitation else {}),
                           **({"kept_file_value": e.kept} if e.kept else {}),
                           **({"held": e.held, "unconstrained_value": e.data_value}
                              if e.held else {}),
                           **({"data_only_value": e.data_value,
                               "prior_share": e.prior_share}
                              if math.isfinite(e.prior_share) else {}),
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
            "diagnostics": self.diagnostics,
            "note": "std_error is the Cramer-Rao bound (white residuals assumed; optimistic "
                    "when the residuals are correlated); std_error_corrected accounts for the "
                    "residuals' autocorrelation within each window (Morelli and Klein) and is "
                    "the one to use; delays are searched integers (standard error 0 by "
                    "convention)",
        }

