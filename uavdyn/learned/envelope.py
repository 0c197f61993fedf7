"""The correction's envelope guard, written once against ``ops``: a smooth gate that is exactly 1
inside the training data's input range and fades to exactly 0 a stated distance outside it, and a
bound on the correction's magnitude, so far from the data the hybrid step IS the physics step
and nowhere can the network add more than a stated acceleration.

Per input ``i`` with range ``[low_i, high_i]`` and fade width ``fade_i``::

    g_i = s((x_i - low_i + fade_i) / fade_i) * s((high_i + fade_i - x_i) / fade_i)
    s(t) = 3 c^2 - 2 c^3 with c = min(max(t, 0), 1)      (C1, exactly 0 or 1 outside [0, 1])
    gate = prod_i g_i,   correction = gate * bound * tanh(raw / bound)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavdyn.model.ops import NUMPY_OPS, ramp


def smoothstep(t, ops=NUMPY_OPS):
    """``3c^2 - 2c^3`` of ``t`` clamped to [0, 1]: exactly 0 below 0 and 1 above 1, C1 in
    between (the clamp written with :func:`uavdyn.model.ops.ramp`, exact at both ends)."""
    c = 1.0 - ramp(1.0 - ramp(t, ops), ops)
    return c * c * (3.0 - 2.0 * c)


@dataclass(frozen=True)
class Envelope:
    """Per-input range ``[low, high]`` of the training inputs and the fade width outside it.

    Attributes
    ----------
    low, high : ndarray
        The range of each network input seen in training (robust quantiles).
    fade : ndarray
        Distance beyond the range over which the gate falls from 1 to 0 (> 0).
    """

    low: np.ndarray
    high: np.ndarray
    fade: np.ndarray

    def __post_init__(self) -> None:
        low, high, fade = (np.asarray(v, float).ravel() for v in (self.low, self.high, self.fade))
        if not (len(low) == len(high) == len(fade)) or not np.all(np.isfinite(low)) \
                or not np.all(np.isfinite(high)) or not np.all(np.isfinite(fade)):
            raise ValueError("envelope low, high and fade must be finite and of one length")
        if np.any(high < low) or np.any(fade <= 0):
            raise ValueError("envelope needs low <= high and fade > 0 for every input")
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)
        object.__setattr__(self, "fade", fade)

    @classmethod
    def from_samples(cls, inputs: np.ndarray, quantile: float = 0.001,
                     fade_fraction: float = 0.25, min_width: np.ndarray | None = None
                     ) -> Envelope:
        """The envelope of training inputs ``(N, n_in)``: the ``quantile``/``1 - quantile``
        range of each input, fading over ``fade_fraction`` of its width (at least
        ``min_width`` or a tiny positive width for an input that never varied)."""
        inputs = np.asarray(inputs, float)
        low = np.quantile(inputs, quantile, axis=0)
        high = np.quantile(inputs, 1.0 - quantile, axis=0)
        width = high - low
        floor = (np.asarray(min_width, float) if min_width is not None
                 else 1e-6 * (1.0 + np.abs(high)))
        fade = np.maximum(fade_fraction * width, floor)
        return cls(low, high, fade)

    @property
    def n_in(self) -> int:
        return len(self.low)

    def gate(self, inp, ops=NUMPY_OPS):
        """The gate of a feature-first block ``inp`` (``(n_in,)`` or ``(n_in, batch)``).

        Per input, ``g_i = 1 - s(d_i)`` with ``d_i`` the distance outside ``[low, high]`` in
        fade widths (negative inside): the same function as the two-sided product in the module
        docstring (``s(1 - t) = 1 - s(t)``), with one smoothstep and no division per input,
        because the gate runs in every hybrid step."""
        out = 1.0
        for i in range(self.n_in):
            lo, hi, r = float(self.low[i]), float(self.high[i]), 1.0 / float(self.fade[i])
            below, above = (lo - inp[i]) * r, (inp[i] - hi) * r
            d = above + ramp(below - above, ops)  # max(below, above)
            out = out * (1.0 - smoothstep(d, ops))
        return out

    def fraction_outside(self, inputs: np.ndarray) -> float:
        """Share of rows of ``inputs (N, n_in)`` outside ``[low, high]`` in any input (where the
        gate is below 1)."""
        inputs = np.atleast_2d(np.asarray(inputs, float))
        outside = np.any((inputs < self.low) | (inputs > self.high), axis=1)
        return float(np.mean(outside)) if len(outside) else 0.0


def bounded(raw, bound, ops=NUMPY_OPS):
    """``bound * tanh(raw / bound)`` per output: the identity for small ``raw``, never beyond
    ``+-bound`` (``bound`` a positive vector, one entry per output)."""
    b = ops.col(bound)
    return b * ops.tanh(raw / b)
