"""The rules a correction is judged by against the physics it sits on, torch-free: one
definition each, shared by the safe trainer (which refuses a correction that breaks them) and
``uavdyn evaluate`` (which reports where one does). They live here, not in ``evaluation``,
because the arrows point from ``learned`` to ``evaluation`` (SPEC section 1) and the trainer
needs them.

Errors against recorded (noisy) data are compared with each sortie's measurement noise taken
off (:func:`uavdyn.flightdata.excess_rmse`): noise adds the same amount to every model's error
and pulls a ratio towards 1, hiding a correction that is really worse.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uavdyn.flightdata import Sortie, excess_rmse, pitch_noise_std, white_noise_std
from uavdyn.integrate import DEPARTURE_RAD

WORSE_THAN = 1.0  # a ratio above this: the correction is worse on that sortie
# A validation free run (a whole sortie flown open loop) is not called worse for a pitch error
# that grows by less than this share of the sortie's pitch noise standard deviation: too
# small to see against the records (issue 40: the trainer's alpha-dot correction was refused
# for a sortie whose 30 s free-run error went from 1.4 to 1.9 mrad, the noise being 2.1 mrad).
FREE_RUN_NOISE_FLOOR = 0.5


def sortie_ratio(physics_rmse: float | None, corrected_rmse: float | None,
                 noise_std: float = 0.0, resolution: float = 0.0) -> float | None:
    """The corrected / physics ratio of one sortie's errors, the sortie's noise taken off
    both, each at least ``resolution``; None where it cannot be scored (a missing error, or
    physics within the noise and no resolution given).

    Parameters
    ----------
    physics_rmse, corrected_rmse : float or None
        RMSE of each model against the sortie's records (inf for a diverged run).
    noise_std : float
        Standard deviation of the records' measurement noise (0: records are the truth).
    resolution : float
        The smallest excess RMSE the noise subtraction resolves (:func:`noise_resolution`):
        below it two errors are the same, so a difference there is neither a gain nor a loss.
    """
    if physics_rmse is None or corrected_rmse is None:
        return None
    if math.isnan(corrected_rmse):  # a prediction that stopped being a number is worst
        corrected_rmse = math.inf
    e_p = max(excess_rmse(physics_rmse, noise_std), resolution)
    if not (e_p > 0 and math.isfinite(e_p)):
        return None
    return max(excess_rmse(corrected_rmse, noise_std), resolution) / e_p


def noise_resolution(noise_std: float, n_samples: int) -> float:
    """The smallest excess RMSE (:func:`uavdyn.flightdata.excess_rmse`) that ``n_samples``
    records with white noise ``noise_std`` resolve: the noise's share of a mean square error
    scatters by ``noise_std**2 sqrt(2 / n)``, so an excess below twice that, ``noise_std
    (8 / n)**0.25``, cannot be told from none (0.23 noise_std for 30 s at 100 Hz). Errors
    this close to the noise appear when windows start from fitted states
    (``SafeConfig.start_fit_s``): without a floor a calm sortie's ratio is a ratio
    of two noise estimates."""
    return noise_std * (8.0 / max(int(n_samples), 1)) ** 0.25 if noise_std > 0 else 0.0


def is_worse(ratio: float | None, limit: float = WORSE_THAN) -> bool:
    """Whether a sortie's ratio (:func:`sortie_ratio`) says the correction is worse there."""
    return ratio is not None and ratio > limit


@dataclass(frozen=True)
class RatioSummary:
    """Per-sortie ratios summarised: their geometric mean (what selects a correction), the
    worst one (what guards it), how many sorties were scored, and the gain's significance:
    ``-mean(log r)`` over its standard error across the sorties (a paired t statistic; inf
    when every sortie gains alike or only one was scored and it gains, -inf for none)."""

    geomean: float
    worst: float
    scored: int
    gain_t: float = math.inf


def summarise_ratios(ratios) -> RatioSummary:
    """:class:`RatioSummary` of the scored ratios (None and NaN are unscored); inf for both
    figures if none was scored or one is not finite."""
    r = np.array([v for v in ratios if v is not None and not math.isnan(v)], float)
    if not len(r) or not np.all(np.isfinite(r)):
        return RatioSummary(math.inf, math.inf, len(r), -math.inf)
    logs = np.log(r)
    return RatioSummary(float(np.exp(np.mean(logs))), float(np.max(r)), len(r),
                        gain_significance(logs))


def gain_significance(log_ratios: np.ndarray) -> float:
    """``-mean / (std / sqrt(n))`` of the per-sortie log ratios: how many standard errors the
    mean gain is away from none (sortie to sortie spread as the noise)."""
    mean = float(np.mean(log_ratios))
    if len(log_ratios) < 2:
        return math.inf if mean < 0 else -math.inf
    se = float(np.std(log_ratios, ddof=1)) / math.sqrt(len(log_ratios))
    if se == 0.0:
        return math.inf if mean < 0 else (-math.inf if mean > 0 else 0.0)
    return -mean / se


def state_noise(sortie: Sortie) -> np.ndarray:
    """The white measurement noise of a sortie's body states ``u, w, q, theta`` from its
    records alone (pitch: the kinematic estimate; u, w, q: the second-difference one)."""
    return np.array([white_noise_std(sortie.states[:, i]) for i in range(3)]
                    + [pitch_noise_std(sortie.time, sortie.states)])


def pooled_state_errors(pred: np.ndarray, records: np.ndarray, noise: np.ndarray
                        ) -> np.ndarray:
    """Pooled RMSE of each body state of windowed predictions against noisy records, with the
    records' white noise taken off (:func:`uavdyn.flightdata.excess_rmse`).

    Parameters
    ----------
    pred, records : ndarray, shape (W, H, 4)
        Predicted and recorded ``u, w, q, theta`` over W windows of H samples.
    noise : ndarray, shape (W, 4)
        Standard deviation of each window's measurement noise per state (its sortie's).

    Returns
    -------
    ndarray, shape (4,)
        The RMSE the truth would show (inf where the prediction is not finite).
    """
    with np.errstate(over="ignore", invalid="ignore"):
        mse = np.mean((pred - records) ** 2, axis=(0, 1))
    noise_var = np.mean(np.asarray(noise, float) ** 2, axis=0)
    return np.array([excess_rmse(math.sqrt(m), math.sqrt(v)) if math.isfinite(m)
                     else math.inf for m, v in zip(mse, noise_var)])


def departed(predicted_pitch: np.ndarray, recorded_pitch: np.ndarray) -> bool:
    """Whether a free run left the data: its pitch error passed :data:`DEPARTURE_RAD` or its
    state stopped being finite (after that its error says nothing)."""
    with np.errstate(all="ignore"):
        err = np.abs(np.asarray(predicted_pitch) - np.asarray(recorded_pitch))
        return bool(np.any(~np.isfinite(err) | (err > DEPARTURE_RAD)))


def free_run_verdict(physics: list[tuple[float, bool]], corrected: list[tuple[float, bool]],
                     worst_ratio: float, noise_std: list[float] | None = None) -> dict:
    """The free-run rule over sorties: no corrected run departs where the physics' did not,
    and where the physics' stayed with the data the corrected pitch RMSE is at most
    ``worst_ratio`` times the physics' (:func:`sortie_ratio`) or above it by less than
    :data:`FREE_RUN_NOISE_FLOOR` of the sortie's pitch noise (a noise-level difference: a
    physics run that follows the data to a fraction of the noise turns a few hundredths of a
    degree into a large ratio). Sorties where the physics departed only count for departures
    (their RMSE says nothing); a sortie the physics follows to within the noise is not scored.

    Parameters
    ----------
    physics, corrected : list of (float, bool)
        Per sortie: pitch RMSE of the free run and whether it departed (:func:`departed`).
    worst_ratio : float
        The largest ratio allowed on any scored sortie.
    noise_std : list of float, optional
        Per sortie pitch noise (rad) taken off both RMSEs.

    Returns
    -------
    dict
        ``free_run_worst`` (the largest ratio), ``free_run_noise_level`` (sorties above
        ``worst_ratio`` by a noise-level difference), ``free_run_new_departures``,
        ``free_run_scored``, ``free_run_ok``.
    """
    noise = noise_std if noise_std is not None else [0.0] * len(physics)
    ratios, failing, noise_level = [], 0, 0
    for p, c, n in zip(physics, corrected, noise):
        r = None if p[1] or c[1] else sortie_ratio(p[0], c[0], n)
        if r is None:
            continue
        ratios.append(r)
        if r > worst_ratio:
            grew = excess_rmse(c[0], n) - excess_rmse(p[0], n)
            if grew > FREE_RUN_NOISE_FLOOR * n:
                failing += 1
            else:
                noise_level += 1
    new_departures = sum(1 for p, c in zip(physics, corrected) if c[1] and not p[1])
    worst = max(ratios) if ratios else None
    return {"free_run_worst": worst, "free_run_noise_level": noise_level,
            "free_run_new_departures": new_departures, "free_run_scored": len(ratios),
            "free_run_ok": new_departures == 0 and failing == 0}
