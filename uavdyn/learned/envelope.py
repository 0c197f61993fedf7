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
    """Per input, the distance outside ``[low, high]`` in fade widths (negative inside),
    ``(|x - mid| - half) / fade``, from an envelope's :meth:`Envelope.terms` (numbers or
    symbols): one subtraction, ``fabs`` and multiply-add each."""
    mid, half, r = terms[0], terms[1], terms[2]
    return [ops.fabs(inp[i] - mid[i]) * r[i] - half[i] * r[i] for i in range(mid.shape[0])]


def gate_of_terms(inp, terms, ops=NUMPY_OPS, form: str = GUARDS[DEFAULT_GUARD][0]):
    """The gate from an envelope's :meth:`Envelope.terms` (numbers or symbols): the box's
    gate ``g``, and where the terms hold a steady box (rows 3-6, :class:`SteadyBox`),
    ``g (1 - s (1 - g_steady))`` with the steadiness ``s = 1 - smoothstep(r^2 - 1)`` of
    ``r^2 = sum_i (rate_i x_i)^2``: 1 while the pitch rate is within the steady flight's, 0
    from sqrt(2) times it; in manoeuvres the steady box has no say."""
    gate = gate_of_distances(outside_distances(inp, terms[:3], ops), ops, form)
    if len(terms) <= 3:
        return gate
    steady_gate = gate_of_distances(outside_distances(inp, terms[3:6], ops), ops, form)
    rate = terms[6]
    r2 = pairwise_sum([(inp[i] * rate[i]) ** 2 for i in range(rate.shape[0])])
    steadiness = 1.0 - smoothstep(r2 - 1.0, ops)
    return gate * (1.0 - steadiness * (1.0 - steady_gate))


def steady_samples(rate: np.ndarray, counts: tuple[int, ...], hold: int, limit: float
                   ) -> np.ndarray:
    """Which samples ``(N,)`` lie in steady flight: the rate input ``rate`` (the sorties'
    samples one after another, ``counts`` per sortie) within ``limit`` over ``hold`` samples
    either side (a pitch rate passing through zero in a manoeuvre is not steady flight)."""
    out, at = [], 0
    for n in counts:
        mag = np.abs(np.asarray(rate[at:at + n], float))
        padded = np.pad(mag, hold, mode="edge")
        worst = np.lib.stride_tricks.sliding_window_view(padded, 2 * hold + 1).max(axis=1)
        out.append(worst <= limit)
        at += n
    return np.concatenate(out) if out else np.zeros(0, bool)


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
class SteadyBox:
    """Where the training data held steady flight: per input the range ``[low, high]`` of its
    steady samples and the inverse fade beyond it (0: the input is not held to it, as the
    rates, which a steady flight has at zero), and per input the weight ``rate`` of the
    steadiness measure (one over the steady flight's largest pitch rate for the rate input,
    0 for every other). :func:`gate_of_terms` lets the correction act in steady flight only
    inside this box: a network fits the moment balance of the steady conditions it was
    trained on, and between them it has only manoeuvres, where that balance is not seen
    (issue 40: a calm survey's steady descent at a power no training flight held, made 39 %
    worse; ``analysis/knockout_residuals.py``)."""

    low: np.ndarray
    high: np.ndarray
    inv_fade: np.ndarray
    rate: np.ndarray

    def __post_init__(self) -> None:
        arrays = [np.asarray(v, float).ravel() for v in (self.low, self.high, self.inv_fade,
                                                         self.rate)]
        if len({len(a) for a in arrays}) != 1 or not all(np.all(np.isfinite(a))
                                                          for a in arrays):
            raise ValueError("steady box low, high, inv_fade and rate must be finite and of "
                             "one length")
        if np.any(arrays[1] < arrays[0]) or np.any(arrays[2] < 0) or np.any(arrays[3] < 0) \
                or not np.any(arrays[3] > 0):
            raise ValueError("steady box needs low <= high, inv_fade >= 0 and a positive rate "
                             "weight")
        for name, a in zip(("low", "high", "inv_fade", "rate"), arrays):
            object.__setattr__(self, name, a)

    @classmethod
    def from_steady(cls, rows: np.ndarray, checked: np.ndarray | None, free: list[int],
                    rate_index: int, quantile: float = 0.001) -> SteadyBox:
        """The box of the steady training samples ``rows`` (``(N, n_in)``), fading as far as
        any of them or of the steady validation samples ``checked`` lies beyond it
        (:meth:`Envelope.from_evidence`); the inputs ``free`` (the rates) not held to it; the
        steadiness weight one over the steady samples' largest rate input."""
        box = Envelope.from_evidence(rows, checked, quantile)
        inv = 1.0 / box.fade
        inv[list(free)] = 0.0
        rate = np.zeros(box.n_in)
        limit = float(np.quantile(np.abs(rows[:, rate_index]), 1.0 - quantile))
        rate[rate_index] = 1.0 / max(limit, 1e-12)
        return cls(box.low, box.high, inv, rate)

    @classmethod
    def neutral(cls, n_in: int, rate_index: int) -> SteadyBox:
        """A box that holds no input (every inverse fade 0): the gate is the envelope's own.
        A network trained with it has the steady box's terms in its compiled twin, so the
        real box can be put in for the final checks (:func:`uavdyn.learned.safe.trainer`)."""
        rate = np.zeros(n_in)
        rate[rate_index] = 1.0
        return cls(np.zeros(n_in), np.zeros(n_in), np.zeros(n_in), rate)

    def terms(self) -> np.ndarray:
        """``(4, n_in)``: centres, half widths, inverse fades and rate weights."""
        return np.array([0.5 * (self.low + self.high), 0.5 * (self.high - self.low),
                         self.inv_fade, self.rate])


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
    steady: SteadyBox | None = None

    def __post_init__(self) -> None:
        low, high, fade = (np.asarray(v, float).ravel() for v in (self.low, self.high, self.fade))
        if self.steady is not None and len(self.steady.low) != len(low):
            raise ValueError("the steady box must have one entry per input of the envelope")
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
        numbers :meth:`outside` uses (an input of a Function that takes them as symbols);
        ``(7, n_in)`` with the steady box's four rows (:meth:`SteadyBox.terms`)."""
        box = np.array([[0.5 * (float(lo) + float(hi)) for lo, hi in zip(self.low, self.high)],
                        [0.5 * (float(hi) - float(lo)) for lo, hi in zip(self.low, self.high)],
                        [1.0 / float(f) for f in self.fade]])
        return box if self.steady is None else np.vstack([box, self.steady.terms()])

    def gate(self, inp, ops=NUMPY_OPS, form: str = GUARDS[DEFAULT_GUARD][0]):
        """The gate of a feature-first block ``inp`` (``(n_in,)`` or ``(n_in, batch)``):
        ``distance`` (one smoothstep of the squared distance to the box) or ``product`` (one
        smoothstep per input); see the module docstring."""
        return gate_of_terms(inp, self.terms(), ops, form)

    def fraction_steady_held(self, inputs: np.ndarray) -> float | None:
        """Share of rows of ``inputs (N, n_in)`` where the steady box holds the correction
        back (the gate below the training box's own); None without a steady box."""
        if self.steady is None:
            return None
        block = np.atleast_2d(np.asarray(inputs, float)).T
        terms = self.terms()
        held = gate_of_terms(block, terms) < gate_of_terms(block, terms[:3]) - 1e-12
        return float(np.mean(held)) if held.size else 0.0

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
