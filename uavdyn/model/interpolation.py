"""Breakpoint-table interpolation written once against an ``ops`` namespace.

Piecewise linear between breakpoints and held constant beyond the end points, written as a sum
of hat functions (linear B-splines) ``sum_k v_k hat_k(x)`` so the same formula runs in CasADi,
NumPy and torch and the table values may be symbolic (entries of ``p``, hence identifiable).
Between ``b_k`` and ``b_{k+1}`` only ``hat_k = (b_{k+1} - x) / h_k`` and
``hat_{k+1} = (x - b_k) / h_k`` are nonzero (the others are exact zeros), so the result is
``v_k (1 - t) + v_{k+1} t`` to a rounding of ``|v|``, exactly ``v_k`` at a breakpoint, whatever
the spacing of the breakpoints or the number of points. (A sum of hinges ``max(x - b_i, 0)``
is the same function in exact arithmetic but cancels terms of the size of slope times distance:
1e-10 relative on a random 200-point table.) Continuous everywhere, differentiable between
breakpoints (at a breakpoint CasADi's derivative is the mean of the two sides' slopes: the
``fmin``/``fmax`` ties split evenly); inside the table it equals CasADi's own
``interpolant(..., 'linear')`` (tests check it), which extrapolates where this holds the end
values. Linear in the values.
"""

from __future__ import annotations

from collections.abc import Sequence

from uavdyn.model.ops import CASADI_OPS


def hat_weights(breaks: Sequence[float], x, ops=CASADI_OPS) -> list:
    """The weight of each breakpoint at ``x``: hat functions, 1 at their own breakpoint, 0 from
    the neighbouring ones on, the first and last held at 1 beyond the ends (clamped).

    Parameters
    ----------
    breaks : sequence of float
        Strictly increasing breakpoints, at least two.
    x : scalar, array, tensor or CasADi expression
        Where to evaluate (feature-first: a scalar or a row of a batch).
    ops : namespace
        The math namespace (:mod:`uavdyn.model.ops`).

    Returns
    -------
    list
        ``len(breaks)`` weights, non-negative, summing to 1 (to rounding).
    """
    n = len(breaks)
    if n < 2:
        raise ValueError(f"a table needs at least 2 breakpoints, got {n}")
    widths = [float(breaks[k + 1]) - float(breaks[k]) for k in range(n - 1)]
    if not all(h > 0 for h in widths):
        raise ValueError("breakpoints must be strictly increasing")
    rising = [(x - float(breaks[k])) / widths[k] for k in range(n - 1)]        # hat k+1, left
    falling = [(float(breaks[k + 1]) - x) / widths[k] for k in range(n - 1)]  # hat k, right
    out = [ops.fmin(ops.fmax(falling[0], 0.0), 1.0)]
    out += [ops.fmax(ops.fmin(rising[k - 1], falling[k]), 0.0) for k in range(1, n - 1)]
    out.append(ops.fmin(ops.fmax(rising[n - 2], 0.0), 1.0))
    return out


def interp1(breaks: Sequence[float], values: Sequence, x, ops=CASADI_OPS):
    """Clamped piecewise-linear interpolation of ``values`` at ``x`` (breaks increasing).

    Parameters
    ----------
    breaks : sequence of float
        Strictly increasing breakpoints (numbers: they fix the graph).
    values : sequence
        One value per breakpoint (numbers or symbols, e.g. entries of ``p``).
    x : scalar, array, tensor or CasADi expression
        Where to evaluate.
    ops : namespace
        The math namespace.
    """
    if len(values) != len(breaks):
        raise ValueError(f"{len(values)} values for {len(breaks)} breakpoints")
    weights = hat_weights(breaks, x, ops)
    out = values[0] * weights[0]
    for v, w in zip(values[1:], weights[1:]):
        out = out + v * w
    return out


def interp2(breaks0: Sequence[float], breaks1: Sequence[float], values: Sequence, x0, x1,
            ops=CASADI_OPS):
    """Clamped bilinear interpolation; ``values`` row-major (``breaks0`` slowest).

    Parameters
    ----------
    breaks0, breaks1 : sequence of float
        Strictly increasing breakpoints of the first and second axis.
    values : sequence
        ``len(breaks0) * len(breaks1)`` values, row ``i`` (first axis) after row ``i - 1``.
    x0, x1
        Where to evaluate, on the first and second axis.
    ops : namespace
        The math namespace.
    """
    n0, n1 = len(breaks0), len(breaks1)
    if len(values) != n0 * n1:
        raise ValueError(f"{len(values)} values for a {n0} x {n1} table")
    w0 = hat_weights(breaks0, x0, ops)
    w1 = hat_weights(breaks1, x1, ops)
    out = None
    for i in range(n0):
        row = values[i * n1] * w1[0]
        for j in range(1, n1):
            row = row + values[i * n1 + j] * w1[j]
        out = row * w0[i] if out is None else out + row * w0[i]
    return out
