"""Preprocessing of sorties: normalisation statistics of the training split, low-pass filter.

Normalisation statistics come from the training split only; the zero-phase low-pass filter
acts on the measured states (controls are commands, held per interval, and stay as they are).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.signal import butter, filtfilt

from uavdyn.flightdata.errors import FlightDataError
from uavdyn.flightdata.sortie import Sortie


@dataclass(frozen=True)
class Normalisation:
    """Mean and standard deviation of states and controls (from the training split only)."""

    state_mean: np.ndarray
    state_std: np.ndarray
    control_mean: np.ndarray
    control_std: np.ndarray
    sorties: tuple[str, ...] = ()

    def normalise(self, states: np.ndarray, controls: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Zero-mean, unit-std states and controls (statistics of the training split)."""
        return ((states - self.state_mean) / self.state_std,
                (controls - self.control_mean) / self.control_std)

    def denormalise(self, states: np.ndarray, controls: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
        """Inverse of :meth:`normalise`."""
        return (states * self.state_std + self.state_mean,
                controls * self.control_std + self.control_mean)

    def as_dict(self) -> dict:
        """JSON-friendly form (to store beside trained weights)."""
        return {"state_mean": self.state_mean.tolist(), "state_std": self.state_std.tolist(),
                "control_mean": self.control_mean.tolist(),
                "control_std": self.control_std.tolist(), "sorties": list(self.sorties)}


def normalisation(sorties: list[Sortie]) -> Normalisation:
    """Statistics pooled over ``sorties`` (pass the training split only). A channel that is
    constant gets std 1 so normalising never divides by zero."""
    if not sorties:
        raise FlightDataError("no sorties to compute normalisation statistics from (is the "
                              "training split empty?)")
    S = np.vstack([s.states for s in sorties])
    U = np.vstack([s.controls for s in sorties])

    def std(a):
        sd = a.std(axis=0)
        return np.where(sd > 1e-12, sd, 1.0)

    return Normalisation(S.mean(axis=0), std(S), U.mean(axis=0), std(U),
                         tuple(s.name for s in sorties))


def lowpass(sortie: Sortie, cutoff_hz: float, order: int = 4) -> Sortie:
    """Zero-phase Butterworth low-pass (``scipy.signal.filtfilt``) of the measured states.
    Controls (commands, held per interval) and true states are left as they are."""

    fs = 1.0 / sortie.dt
    if not 0 < cutoff_hz < fs / 2:
        raise FlightDataError(f"sortie '{sortie.name}': cutoff {cutoff_hz} Hz must be between 0 "
                              f"and the Nyquist frequency {fs / 2:g} Hz")
    b, a = butter(order, cutoff_hz / (fs / 2))
    if len(sortie.time) <= 3 * max(len(a), len(b)):
        raise FlightDataError(f"sortie '{sortie.name}' is too short ({len(sortie.time)} rows) "
                              f"for an order-{order} zero-phase filter")
    states = filtfilt(b, a, sortie.states, axis=0)
    meta = dict(sortie.meta, lowpass_hz=cutoff_hz, lowpass_order=order)
    return replace(sortie, states=states, meta=meta)
