"""How each row of the output-error least squares is weighted: each body state by its residual
after the fit, each sortie by its own residual level (the weights the Cramer-Rao bound
assumes), and the rows that hold a collinear group's undetermined combination at the file's
values (:mod:`uavdyn.identify.fallback`)."""

from __future__ import annotations

import math

import numpy as np

from uavdyn.identify.errors import IdentifyError
from uavdyn.identify.fitstate import _Fit
from uavdyn.identify.uncertainty import N_BODY

REWEIGHT_FLOOR = 1e-3    # a state's weight: down to this fraction of the nominal residual
SORTIE_WEIGHT_FLOOR = 0.01  # a sortie's: down to this fraction of the pooled one


def window_residuals(fit: _Fit, z: np.ndarray, delays: list[int]) -> np.ndarray:
    """The body-state residuals ``(W, L, N_BODY)`` after the fit, in the states' units (the
    state and window weights taken off)."""
    r = np.asarray(fit.problem.residual(z, fit.data_for(delays))).ravel()
    W, L = fit.windows.count, fit.L
    resid = r[:W * L * N_BODY].reshape(W, L, N_BODY) / fit.weights
    if fit.window_weights is not None:
        resid = resid / fit.window_weights[:, None, None]
    return resid


def sortie_weights(fit: _Fit, resid: np.ndarray) -> np.ndarray:
    """Each window's weight: 1 / its sortie's residual RMS (in units of the pooled RMS, the
    states on the state weights' scale), so a calm sortie counts as much as its small noise
    says."""
    ms = np.mean((resid * fit.weights) ** 2, axis=(1, 2))
    sortie = np.array([i for i, _ in fit.windows.starts])
    pooled = math.sqrt(float(np.mean(ms)))
    rms = {i: math.sqrt(float(np.mean(ms[sortie == i]))) for i in set(sortie.tolist())}
    return np.array([pooled / max(rms[i], SORTIE_WEIGHT_FLOOR * pooled) for i in sortie])


def per_sortie_weights(fit: _Fit) -> dict[int, float]:
    """The window weights by training sortie (index in the train list)."""
    if fit.window_weights is None:
        return {}
    return {int(i): float(w) for (i, _), w in zip(fit.windows.starts, fit.window_weights)}


def residual_weights(fit: _Fit, resid: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each state's residual RMS after the fit (unweighted), its floor, and the weights it
    gives."""
    rms = np.sqrt(np.mean(resid.reshape(-1, N_BODY) ** 2, axis=0))
    floor = REWEIGHT_FLOOR / fit.weights_nominal
    return rms, floor, 1.0 / np.maximum(rms, floor)


HOLD_WEIGHT = 1e4  # held rows' weight over the largest data column norm: a hard constraint


def hold_rows(fit: _Fit, hold: list[dict[str, float]]) -> np.ndarray:
    """The rows holding ``hold``'s combinations at the file's values, in the scaled unknowns
    (``theta = 0`` at the file), weighted far above the data; set as the fit's prior rows."""
    u = fit.unknowns
    unknown = sorted({n for row in hold for n in row} - set(fit.continuous))
    if unknown:
        raise IdentifyError(f"held combination names {', '.join(unknown)}, which this fit "
                            "does not estimate")
    rows = np.array([[row.get(n, 0.0) * s for n, s in zip(fit.continuous, u.scale)]
                     for row in hold], float)
    rows /= np.maximum(np.linalg.norm(rows, axis=1, keepdims=True), 1e-300)
    delays = list(fit.airframe.delay_samples())
    _, J = fit.problem.evaluate(fit.with_dx(u.theta0), fit.data_for(delays))
    column = np.sqrt(np.max(np.asarray(J[:, :fit.problem.n_theta].power(2).sum(axis=0))))
    fit.prior = HOLD_WEIGHT * max(column, 1.0) * rows
    fit.data_cache.clear()
    return fit.prior
