"""Breakpoint-table interpolation written once against an ``ops`` namespace.

Piecewise linear between breakpoints and held constant beyond the end points, written as a sum
of hinges ``max(x - b_i, 0)`` so the same formula runs in CasADi, NumPy and torch and the table
values may be symbolic (entries of ``p``, hence identifiable). Continuous everywhere,
differentiable between breakpoints (at a breakpoint CasADi takes one side's slope); inside the
table it equals CasADi's own ``interpolant(..., 'linear')`` (tests check it).
"""

from __future__ import annotations

from collections.abc import Sequence

from uavdyn.model.ops import CASADI_OPS


def interp1(breaks: Sequence[float], values: Sequence, x, ops=CASADI_OPS):
    """Clamped piecewise-linear interpolation of ``values`` at ``x`` (breaks increasing)."""
    n = len(breaks)
    out = values[0]
    previous = 0.0
    for i in range(n - 1):
        slope = (values[i + 1] - values[i]) / (breaks[i + 1] - breaks[i])
        out = out + (slope - previous) * ops.fmax(x - breaks[i], 0.0)
        previous = slope
    return out - previous * ops.fmax(x - breaks[-1], 0.0)


def interp2(breaks0: Sequence[float], breaks1: Sequence[float], values: Sequence, x0, x1,
            ops=CASADI_OPS):
    """Clamped bilinear interpolation; ``values`` row-major (``breaks0`` slowest)."""
    n1 = len(breaks1)
    out = 0.0
    for j in range(n1):
        column = [values[i * n1 + j] for i in range(len(breaks0))]
        hat = interp1(breaks1, [1.0 if k == j else 0.0 for k in range(n1)], x1, ops)
        out = out + hat * interp1(breaks0, column, x0, ops)
    return out
