"""Input profiles used in flight test and system identification (step, doublet, 3-2-1-1,
chirp), sampled on a time grid and added to a trim control.

Each profile is a pure function of time returning the perturbation of one control channel; a
zero-order hold over the solver step is applied by the caller (row k is held over step k).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

PROFILES = ("step", "doublet", "3211", "chirp", "none")


def step(t: np.ndarray, amplitude: float, start: float = 1.0) -> np.ndarray:
    """A step of ``amplitude`` at ``start`` seconds."""
    return np.where(t >= start, amplitude, 0.0)


def doublet(t: np.ndarray, amplitude: float, start: float = 1.0, width: float = 0.5
            ) -> np.ndarray:
    """+amplitude for ``width`` s then -amplitude for ``width`` s."""
    out = np.zeros_like(t, dtype=float)
    out[(t >= start) & (t < start + width)] = amplitude
    out[(t >= start + width) & (t < start + 2 * width)] = -amplitude
    return out


def multistep_3211(t: np.ndarray, amplitude: float, start: float = 1.0, unit: float = 0.3
                   ) -> np.ndarray:
    """The 3-2-1-1 sequence: +3u, -2u, +1u, -1u time units of alternating sign."""
    out = np.zeros_like(t, dtype=float)
    edges = start + unit * np.cumsum([0, 3, 2, 1, 1])
    for k, sign in enumerate((1, -1, 1, -1)):
        out[(t >= edges[k]) & (t < edges[k + 1])] = sign * amplitude
    return out


def chirp(t: np.ndarray, amplitude: float, start: float = 1.0, duration: float = 10.0,
          f0: float = 0.1, f1: float = 2.0) -> np.ndarray:
    """Linear frequency sweep from ``f0`` to ``f1`` Hz over ``duration`` s."""
    tau = np.clip(t - start, 0.0, duration)
    phase = 2 * np.pi * (f0 * tau + 0.5 * (f1 - f0) / duration * tau**2)
    return np.where((t >= start) & (t <= start + duration), amplitude * np.sin(phase), 0.0)


PROFILE_FUNCTIONS: dict[str, Callable[..., np.ndarray]] = {
    "step": step, "doublet": doublet, "3211": multistep_3211, "chirp": chirp,
    "none": lambda t, amplitude, **_: np.zeros_like(t, dtype=float),
}


def control_sequence(profile: str, t: np.ndarray, u_trim: np.ndarray, amplitude: float,
                     channel: int = 0, **kwargs) -> np.ndarray:
    """``len(t) x nu`` controls: trim plus ``profile`` on ``channel``."""
    if profile not in PROFILE_FUNCTIONS:
        raise ValueError(f"unknown input profile '{profile}'; expected one of {PROFILES}")
    u = np.tile(np.asarray(u_trim, dtype=float), (len(t), 1))
    u[:, channel] += PROFILE_FUNCTIONS[profile](np.asarray(t, float), amplitude, **kwargs)
    return u
