"""Diagnostics of an imported flight: integrated pitch rate against pitch, one-row summary."""

from __future__ import annotations

import numpy as np

from uavdyn.flightdata.checks import _running_integral
from uavdyn.flightdata.sortie import Sortie


def integrated_pitch_rms(sortie: Sortie, window_s: float | None = None) -> float:
    """How well the integrated pitch rate follows pitch (a check of an import's conventions).

    Parameters
    ----------
    sortie : Sortie
        An imported flight.
    window_s : float, optional
        Restart the integral every ``window_s`` seconds, so that slow gyro bias drift does
        not accumulate; default one integral over the whole flight.

    Returns
    -------
    float
        RMS (rad) of ``theta - (theta_0 + integral of q)``.
    """
    t, q, theta = sortie.time, sortie.states[:, 2], sortie.states[:, 3]
    cum = _running_integral(t, q)
    if window_s is None:
        return float(np.sqrt(np.mean((theta - theta[0] - cum) ** 2)))
    seg = np.floor((t - t[0]) / window_s).astype(int)
    err = np.empty_like(theta)
    for s in np.unique(seg):
        i = np.flatnonzero(seg == s)
        err[i] = (theta[i] - theta[i[0]]) - (cum[i] - cum[i[0]])
    return float(np.sqrt(np.mean(err**2)))


def summary(sortie: Sortie) -> dict:
    """One row of numbers describing an imported log, for comparison tables.

    Parameters
    ----------
    sortie : Sortie
        An imported flight.

    Returns
    -------
    dict
        Name, kind, rows, duration, rate, ranges of each channel, maximum roll and the
        integrated-pitch-rate RMS (whole flight and 1 s windows).
    """
    S, U = sortie.states, sortie.controls

    def span(x, digits):
        return (round(float(np.min(x)), digits), round(float(np.max(x)), digits))

    roll = sortie.meta.get("roll")
    return {
        "name": sortie.name, "kind": sortie.kind, "rows": len(sortie.time),
        "duration_s": round(sortie.duration, 2), "rate_hz": round(1 / sortie.dt, 2),
        "theta_deg": span(np.degrees(S[:, 3]), 2), "q_radps": span(S[:, 2], 3),
        "u_mps": span(S[:, 0], 2), "w_mps": span(S[:, 1], 2),
        "u0": span(U[:, 0], 3), "u1": span(U[:, 1], 3),
        "roll_max_deg": None if roll is None else round(float(np.degrees(np.abs(roll).max())), 1),
        "rms_int_q_vs_theta_rad": integrated_pitch_rms(sortie),
        "rms_int_q_vs_theta_1s_rad": integrated_pitch_rms(sortie, 1.0),
    }
