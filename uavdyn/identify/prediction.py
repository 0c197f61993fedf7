"""The standard errors a flight would give, before it is flown: the Cramer-Rao bound of the
output-error fit (:mod:`uavdyn.identify.output_error`) at the nominal parameters on an
emulated (or planned) flight, with known white measurement noise.

It is the same fit's information matrix (the same windows restarted from recorded states, the
same exact CasADi sensitivities, the start states profiled out: :func:`uncertainty.information`)
with each body state weighted by one over its noise standard deviation instead of by the fit's
own residual. It is a **lower bound**: coloured residuals (turbulence, model error) make the
corrected standard errors of the real fit larger (:mod:`uavdyn.identify.uncertainty`).
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.flightdata import Sortie
from uavdyn.identify.errors import IdentifyError
from uavdyn.identify.output_error import _prepare, identify
from uavdyn.identify.uncertainty import _inverse, collinearity, information
from uavdyn.identify.unknowns import _check_request
from uavdyn.identify.windows import N_BODY

# the fit's own default window cap (identify uses at most this many windows)
DEFAULT_MAX_WINDOWS = inspect.signature(identify).parameters["max_windows"].default


@dataclass(frozen=True)
class PredictedErrors:
    """Predicted (Cramer-Rao) standard errors of named parameters on a flight.

    Attributes
    ----------
    names : list of str
        The parameters.
    nominal : ndarray
        Their values in the airframe (where the bound is evaluated).
    std_error : ndarray
        The Cramer-Rao standard errors (lower bounds).
    correlation : ndarray
        Their correlation matrix.
    collinear_groups : list of list of str
        Parameters these data could not separate (Belsley's diagnostics).
    windows : int
        Windows of ``window_s`` the bound is computed on.
    window_s : float
        Window length (s).
    """

    names: list[str]
    nominal: np.ndarray
    std_error: np.ndarray
    correlation: np.ndarray
    collinear_groups: list[list[str]]
    windows: int
    window_s: float

    def ratio(self) -> np.ndarray:
        """``|nominal| / std_error``: the ratio the 3-standard-error rule asks to be >= 3."""
        return np.abs(self.nominal) / np.maximum(self.std_error, 1e-300)


def predict_standard_errors(airframe: Airframe, sorties: list[Sortie], names: list[str],
                            noise: np.ndarray, window_s: float = 1.0,
                            max_windows: int | None = DEFAULT_MAX_WINDOWS) -> PredictedErrors:
    """The Cramer-Rao standard errors the output-error fit of ``names`` would have on
    ``sorties`` with white measurement noise of standard deviation ``noise`` (per body state
    ``u, w, q, theta``).

    Parameters
    ----------
    airframe : Airframe
        The model; the bound is evaluated at its parameter values.
    sorties : list of Sortie
        The flight (noise-free states where the sorties carry them: ``true_states``).
    names : list of str
        Continuous parameters of the model.
    noise : ndarray
        Measurement noise standard deviation per body state.
    window_s : float
        The fit's window length (s).
    max_windows : int, optional
        As :func:`uavdyn.identify.identify` (default: its default; None: every window).

    Returns
    -------
    PredictedErrors

    Raises
    ------
    IdentifyError
        For a name not in the model or parameters these data cannot tell apart.
    """
    clean = [Sortie(s.name, s.kind, s.time, s.true_states if s.true_states is not None
                    else s.states, s.controls, s.mission, dict(s.meta)) for s in sorties]
    continuous, searched = _check_request(airframe, list(names), clean, 1)
    if searched:
        raise IdentifyError(f"{searched}: a searched delay has no standard error to predict")
    fit = _prepare(airframe, clean, continuous, [], window_s, None, None, max_windows, None,
                   None, True)
    sigma = np.asarray(noise, float)[:N_BODY]
    fit.noise = sigma
    fit.weights = 1.0 / sigma
    delays = list(airframe.delay_samples())
    _, J = fit.problem.evaluate(fit.with_dx(fit.unknowns.theta0), fit.data_for(delays))
    _, _, M = information(J, np.ones(N_BODY), fit.problem.n_theta, fit.windows.count, fit.L,
                          True)
    cov = _inverse(M)
    u = fit.unknowns
    std = np.sqrt(np.maximum(np.diag(cov), 0.0)) * u.scale
    d = np.sqrt(np.maximum(np.diag(cov), 1e-300))
    _, _, groups = collinearity(M)
    return PredictedErrors(list(continuous), u.p_nom[u.index].copy(), std,
                           cov / np.outer(d, d), [[continuous[j] for j in g] for g in groups],
                           fit.windows.count, fit.L * fit.interval)
