"""The correction's envelope guard, written once against ``ops``: a smooth gate that is exactly 1
inside the training data's input range and fades to exactly 0 a stated distance outside it, and a
bound on the correction's magnitude, so far from the data the hybrid step IS the physics step
and nowhere can the network add more than a stated acceleration.

Per input ``i`` with range ``[low_i, high_i]`` and fade width ``fade_i``, the distance outside
the range in fade widths is ``d_i = (|x_i - mid_i| - half_i) / fade_i`` (negative inside), and
``s(t) = 3c^2 - 2c^3`` with ``c = min(max(t, 0), 1)`` (C1, exactly 0 or 1 outside [0, 1]).
Two guards (the weight file names its own):

``distance-clamp`` (default, weight-file format 4)::

    gate = 1 - s(sum_i max(d_i, 0)^2)           (the squared distance to the box, in fades)
    correction = gate * clamp(raw, -bound, bound)

``product-tanh`` (format 3)::

    gate = prod_i (1 - s(d_i)),   correction = gate * bound * tanh(raw / bound)

Both are exactly 1 inside the box and exactly 0 once an input is a fade width outside it. In a
compiled step the default guard costs less than half as much as the other (one smoothstep
instead of one per input, no ``tanh`` call; the step costs are in ``analysis/bench_hybrid.py``'s
output); the clamp's kink lies at the bound, far beyond the corrections the data ask for (twice
their 99.9 % quantile).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavdyn.model.ops import NUMPY_OPS, pairwise_sum, ramp

GUARDS = {"distance-clamp": ("distance", "clamp"), "product-tanh": ("product", "tanh")}
DEFAULT_GUARD = "distance-clamp"
EVIDENCE_FADE_FLOOR = 0.1  # the least fade of Envelope.from_evidence, in range widths: the
# gate's slope times the correction is a derivative the hybrid map gains at the box's edge; at
# 0.01 widths it broke the stability rule at trims in the margin (the Aerosonde's power-effect
# correction of the knockout benchmark was kept only at a third of its output)
LEGACY_GUARD = "product-tanh"  # what weight files of format 3 were trained with


def smoothstep(t, ops=NUMPY_OPS):
    """``3c^2 - 2c^3`` of ``t`` clamped to [0, 1]: exactly 0 below 0 and 1 above 1, C1 in
    between (the clamp written with :func:`uavdyn.model.ops.ramp`, exact at both ends)."""
    c = 1.0 - ramp(1.0 - ramp(t, ops), ops)
    return c * c * (3.0 - 2.0 * c)


def outside_distances(inp, terms, ops=NUMPY_OPS) -> list:
    """:meth:`Envelope.outside` from its :meth:`Envelope.terms` (numbers or symbols)."""
    mid, half, r = terms[0], terms[1], terms[2]
    return [ops.fabs(inp[i] - mid[i]) * r[i] - half[i] * r[i] for i in range(mid.shape[0])]


def gate_of_distances(d: list, ops=NUMPY_OPS, form: str = GUARDS[DEFAULT_GUARD][0]):
    """:meth:`Envelope.gate` from the distances of :func:`outside_distances`."""
    if form == "distance":
        # ramp(d)^2 = (d + |d|)^2 / 4: the 1/4 applied once, after the sum
        doubled = [di + ops.fabs(di) for di in d]
        return 1.0 - smoothstep(0.25 * pairwise_sum([e * e for e in doubled]), ops)
    if form == "product":
        out = 1.0
        for di in d:
            out = out * (1.0 - smoothstep(di, ops))
        return out
    raise ValueError(f"unknown gate form '{form}'; expected distance or product")


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
                     fade_fraction: float = 1.0, min_width: np.ndarray | None = None
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

    @classmethod
    def from_evidence(cls, inputs: np.ndarray, checked: np.ndarray | None = None,
                      quantile: float = 0.001, floor: float = EVIDENCE_FADE_FLOOR,
                      cap: float = 1.0) -> Envelope:
        """The box of :meth:`from_samples` (``inputs (N, n_in)``, the training data), fading
        per input over the farthest any trained-on or checked sample (``inputs`` and
        ``checked``, the validation data) lies beyond it: between ``floor`` and ``cap``
        range widths. Beyond that reach no data vouch for the network, so there the step
        is the physics."""
        box = cls.from_samples(inputs, quantile, cap)
        rows = np.asarray(inputs, float)
        if checked is not None and len(checked):
            rows = np.vstack([rows, np.asarray(checked, float)])
        beyond = np.max(np.maximum(np.maximum(rows - box.high, box.low - rows), 0.0), axis=0)
        width = box.high - box.low
        fade = np.clip(beyond, floor * width, cap * width)
        return cls(box.low, box.high, np.maximum(fade, 1e-6 * (1.0 + np.abs(box.high))))

    @property
    def n_in(self) -> int:
        return len(self.low)

    def terms(self) -> np.ndarray:
        """``(3, n_in)``: each input's box centre, half width and inverse fade width, the
        numbers :meth:`outside` uses (an input of a Function that takes them as symbols)."""
        return np.array([[0.5 * (float(lo) + float(hi)) for lo, hi in zip(self.low, self.high)],
                         [0.5 * (float(hi) - float(lo)) for lo, hi in zip(self.low, self.high)],
                         [1.0 / float(f) for f in self.fade]])

    def outside(self, inp, ops=NUMPY_OPS) -> list:
        """Per input, the distance outside ``[low, high]`` in fade widths (negative inside),
        ``(|x - mid| - half) / fade``: one subtraction, ``fabs`` and multiply-add each."""
        return outside_distances(inp, self.terms(), ops)

    def gate(self, inp, ops=NUMPY_OPS, form: str = GUARDS[DEFAULT_GUARD][0]):
        """The gate of a feature-first block ``inp`` (``(n_in,)`` or ``(n_in, batch)``):
        ``distance`` (one smoothstep of the squared distance to the box) or ``product`` (one
        smoothstep per input); see the module docstring."""
        return gate_of_distances(self.outside(inp, ops), ops, form)

    def fraction_outside(self, inputs: np.ndarray) -> float:
        """Share of rows of ``inputs (N, n_in)`` outside ``[low, high]`` in any input (where the
        gate is below 1)."""
        inputs = np.atleast_2d(np.asarray(inputs, float))
        outside = np.any((inputs < self.low) | (inputs > self.high), axis=1)
        return float(np.mean(outside)) if len(outside) else 0.0


def bounded(raw, bound, ops=NUMPY_OPS, form: str = GUARDS[DEFAULT_GUARD][1]):
    """The output ``raw`` limited to ``+-bound`` per output (``bound`` a positive vector, one
    entry per output): ``clamp`` (the identity up to the bound, written with ramps: no library
    call) or ``tanh`` (``bound * tanh(raw / bound)``)."""
    b = ops.col(bound)
    if form == "clamp":
        return raw - ramp(raw - b, ops) + ramp(-b - raw, ops)
    if form == "tanh":
        return b * ops.tanh(raw / b)
    raise ValueError(f"unknown bound form '{form}'; expected clamp or tanh")
