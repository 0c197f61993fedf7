"""Excitation signals beyond the flight-test classics of :mod:`uavdyn.integrate.inputs`: the
Schroeder-phased multisine and its relative peak factor, and the timing rules that tie the
3-2-1-1 and the doublet to a mode's natural frequency.

Timing rules (Jategaonkar, *Flight Vehicle System Identification*, 2nd ed., AIAA 2015, ch. 2;
Plaetschke and Schulz, AGARD-LS-104, 1979):

* doublet: pulse width ``dt = 2.3 / omega_n``. A doublet of pulse width ``dt`` has its energy
  peak at ``omega dt = 2.33`` (:func:`energy_spectrum`), so the peak lands on the mode;
* 3-2-1-1: time step ``dt = 1.6 / omega_n``. The 3-2-1-1's half-power band is ``0.28/dt`` to
  ``2.65/dt``; the mode then sits in its upper part, with the longer steps exciting the slower
  dynamics (speed, phugoid onset) below it.

Multisine (Morelli, "Multiple input design for real-time parameter estimation in the frequency
domain", IFAC SYSID 2003): harmonics of the base period with Schroeder's phases
``phi_k = -pi k (k - 1) / M`` (Schroeder, IEEE Trans. Inf. Theory, 1970), which keep the peak
of a flat-spectrum sum of ``M`` sines low (relative peak factor near 1.1-1.5 instead of
``sqrt(2 M)`` for zero phases).
"""

from __future__ import annotations

import math

import numpy as np

DOUBLET_RULE = 2.3   # omega_n * pulse width
RULE_3211 = 1.6      # omega_n * time step


def schroeder_phases(m: int) -> np.ndarray:
    """Schroeder's phases ``-pi k (k - 1) / m`` of ``m`` equal-power harmonics (``k = 1..m``)."""
    k = np.arange(1, m + 1)
    return -math.pi * k * (k - 1) / m


def multisine_frequencies(band_hz: tuple[float, float], period_s: float) -> np.ndarray:
    """The harmonics of ``1 / period_s`` inside ``band_hz`` (Hz), so the signal is periodic
    over ``period_s`` and each component is orthogonal to the others over it."""
    f0 = 1.0 / period_s
    k = np.arange(max(1, math.ceil(band_hz[0] / f0 - 1e-9)),
                  math.floor(band_hz[1] / f0 + 1e-9) + 1)
    return k * f0


def schroeder_multisine(t: np.ndarray, peak: float, band_hz: tuple[float, float],
                        period_s: float, start: float = 0.0, length: float | None = None,
                        phases: np.ndarray | None = None) -> np.ndarray:
    """A flat-spectrum multisine over ``band_hz`` with Schroeder phases, scaled so its largest
    value over one period is exactly ``peak``; zero outside ``[start, start + length)``.

    Parameters
    ----------
    t : ndarray
        Time grid (s).
    peak : float
        The largest absolute value of the signal.
    band_hz : (float, float)
        Lowest and highest frequency (Hz); the components are the harmonics of ``1/period_s``
        inside it.
    period_s : float
        The base period (s).
    start, length : float
        Where the signal is on (default: from ``start`` for one period).
    phases : ndarray, optional
        Phases of the components (default Schroeder's).

    Returns
    -------
    ndarray
        The signal on ``t``.
    """
    freqs = multisine_frequencies(band_hz, period_s)
    if len(freqs) == 0:
        raise ValueError(f"no harmonic of 1/{period_s:g} s in the band {band_hz} Hz")
    phi = schroeder_phases(len(freqs)) if phases is None else np.asarray(phases, float)
    length = period_s if length is None else length

    def raw(tau: np.ndarray) -> np.ndarray:
        return np.cos(2 * np.pi * np.outer(tau, freqs) + phi).sum(axis=1)

    grid = np.linspace(0.0, period_s, 4001)
    scale = peak / np.max(np.abs(raw(grid)))
    on = (t >= start) & (t < start + length)
    out = np.zeros_like(t, dtype=float)
    out[on] = scale * raw(t[on] - start)
    return out


def relative_peak_factor(u: np.ndarray) -> float:
    """Morelli's relative peak factor ``(max - min) / (2 sqrt(2) rms)``: 1 for a single sine,
    near 1 for a well-phased multisine, ``sqrt(2 M)``-like for ``M`` sines in phase."""
    u = np.asarray(u, float)
    rms = float(np.sqrt(np.mean((u - u.mean()) ** 2)))
    return float((u.max() - u.min()) / (2 * math.sqrt(2) * rms)) if rms > 0 else math.inf


def energy_spectrum(u: np.ndarray, dt: float, omega: np.ndarray) -> np.ndarray:
    """``|U(omega)|^2`` of a sampled input ``u`` (zero-order hold over ``dt``), at ``omega``
    (rad/s): where an input puts its energy."""
    t = np.arange(len(u)) * dt
    hold = np.where(omega > 0, (1 - np.exp(-1j * omega * dt)) / (1j * np.maximum(omega, 1e-300)),
                    dt)
    return np.abs(hold * (np.exp(-1j * np.outer(omega, t)) @ u)) ** 2
