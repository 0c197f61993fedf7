"""Measurement-noise estimates from the records alone, and the error they imply against truth.

One estimator per statistic: :func:`pitch_noise_std` for the pitch channel (theta, with its
pitch-rate record q as the reference) and :func:`white_noise_std` for any other channel (u, w,
q: the signal alone). Both take the spread robustly with :func:`_robust_std`.
"""

from __future__ import annotations

import math

import numpy as np

from uavdyn.flightdata.checks import kinematic_residual


def _robust_std(values: np.ndarray) -> float:
    """Standard deviation of the Gaussian bulk of ``values`` from their median absolute
    deviation (1.4826 MAD), which a few spikes or outliers do not move."""
    return 1.4826 * float(np.median(np.abs(values - np.median(values))))


def pitch_noise_std(time: np.ndarray, states: np.ndarray) -> float:
    """Standard deviation of the white pitch (theta) measurement noise (rad), estimated from the
    recorded pitch and pitch rate alone.

    Over one sample the pitch change minus the trapezoid integral of q leaves the difference of
    two independent pitch noise samples (variance ``2 sigma^2``); the dynamics contribute
    ``O(dt^3)`` and a gyro bias only a constant, so the residual's spread, taken robustly (the
    median absolute deviation, which a few spikes do not move), gives ``sigma``. A pitch that is
    itself the integral of q, or heavily filtered, gives about 0: nothing is then subtracted
    where the estimate is used (:func:`excess_rmse`). This is the estimator of the pitch
    channel's noise; :func:`white_noise_std` is the one for channels without a kinematic
    reference.

    Parameters
    ----------
    time : ndarray, shape (N,)
        Sample times (s), N >= 3.
    states : ndarray, shape (N, 4)
        Recorded ``u, w, q, theta``.

    Returns
    -------
    float
        Estimated standard deviation of the pitch noise (rad).
    """
    dt = float(np.median(np.diff(time)))
    residual = kinematic_residual(time, states, dt)[0][:, 2]
    return _robust_std(residual) / math.sqrt(2.0)


def white_noise_std(signal: np.ndarray) -> float:
    """Standard deviation of the white noise of one sampled signal (in the signal's units),
    estimated from the signal alone.

    The second difference of a signal sampled fast against its dynamics is mostly noise
    (variance ``6 sigma^2`` for white noise), taken robustly (median absolute deviation).
    Content above the sampling's reach (gusts in air-relative velocities) counts as noise,
    which for weighting residuals is what it is. This is the estimator for u, w and q; the
    pitch channel's noise is :func:`pitch_noise_std` (q removes the dynamics there).

    Parameters
    ----------
    signal : ndarray, shape (N,)
        Uniformly sampled values of one channel.

    Returns
    -------
    float
        Estimated noise standard deviation (0 for fewer than 3 samples).
    """
    second = np.diff(np.asarray(signal, float), 2)
    if len(second) == 0:
        return 0.0
    return _robust_std(second) / math.sqrt(6.0)


def excess_rmse(rmse: float, noise_std: float) -> float:
    """The RMSE against the true states that an RMSE against noisy records implies: white
    measurement noise adds its variance to the expected squared error of any prediction that
    does not see it, so it is taken off (clamped at 0; an infinite RMSE stays infinite).

    Ratios of raw RMSEs shrink towards 1 as errors approach the noise level: on a calm sortie
    whose free-run pitch error is near a 0.002 rad pitch noise, a correction 1.3x worse against
    the truth scores 1.08x against the records. Ratios of these excess RMSEs do not.
    """
    if not math.isfinite(rmse):
        return rmse
    return math.sqrt(max(rmse * rmse - noise_std * noise_std, 0.0))
