"""The correction MLP's forward pass, written once against an ``ops`` namespace so CasADi (the
hybrid step), NumPy (checks) and torch (training) evaluate the same function.

Layout: ``z = (input - in_mean) / in_scale``; hidden layers ``act(W z + b)``; a linear output
de-normalised as ``y * out_scale + out_mean``, optionally plus a linear path ``S z`` beside the
hidden layers (``skip``: a correction that is partly a change of the physics' derivatives is
learned there directly). Data are feature-first (``(n_in, batch)``).
"""

from __future__ import annotations

from collections.abc import Sequence

from uavdyn.model.ops import pairwise_sum, ramp

ACTIVATIONS = ("relu", "tanh")


def activation(name: str, z, ops, relu_smoothing: float | None = None):
    """``relu`` (optionally a softplus of sharpness ``k`` for optimisers, which stall on ReLU
    kinks; its error is at most ln 2 / k) or ``tanh``."""
    if name == "relu":
        if relu_smoothing:
            k = relu_smoothing
            return ramp(z, ops) + ops.log1p(ops.exp(-k * ops.fabs(z))) / k
        return ramp(z, ops)
    if name == "tanh":
        return ops.tanh(z)
    raise ValueError(f"unknown activation '{name}'; expected one of {ACTIVATIONS}")


def mlp_forward(weights: Sequence, biases: Sequence, in_mean, in_scale, out_mean, out_scale,
                inp, ops, act: str, relu_smoothing: float | None = None, skip=None):
    """The network applied to the feature-first block ``inp`` with ``ops``.

    Parameters
    ----------
    weights, biases : sequences of arrays
        ``weights[i]`` of shape ``(n_out_i, n_in_i)`` (torch ``nn.Linear`` layout), biases
        ``(n_out_i,)``; the last pair is the linear output layer.
    in_mean, in_scale, out_mean, out_scale : array_like
        Input normalisation and output de-normalisation.
    inp
        ``(n_in,)`` column (CasADi) or ``(n_in, batch)`` block (NumPy, torch).
    ops : namespace
        :data:`uavdyn.model.CASADI_OPS`, :data:`uavdyn.model.NUMPY_OPS` or
        :func:`uavdyn.model.torch_ops`.
    act : str
        Hidden activation.
    skip : array_like, optional
        ``(n_out, n_in)``: the linear path from the normalised input to the output.
    """
    x = (inp - ops.col(in_mean)) / ops.col(in_scale)
    z = x
    for w, b in zip(weights[:-1], biases[:-1]):
        z = activation(act, ops.matmul(w, z) + ops.col(b), ops, relu_smoothing)
    y = ops.matmul(weights[-1], z) + ops.col(biases[-1])
    if skip is not None:
        y = y + ops.matmul(skip, x)
    return y * ops.col(out_scale) + ops.col(out_mean)


def folded_layers(weights: Sequence, biases: Sequence, in_mean, in_scale, out_mean, out_scale,
                  skip=None) -> tuple[list, list, object]:
    """The same ReLU network with its normalisation and ReLU's factor 1/2 folded into the
    weights, for the compiled step (fewer instructions per call; the result differs from
    :func:`mlp_forward` by round-off only).

    :func:`folded_forward` evaluates it: the first layer takes the raw input, each hidden
    layer returns ``z + |z|`` (twice the ReLU; the next layer's weights are halved) and the
    output layer returns de-normalised values.

    Returns
    -------
    weights, biases : lists of arrays
        The folded layers.
    skip : array or None
        The folded linear path (from the raw input).
    """
    import numpy as np

    mean = np.asarray(in_mean, float).ravel()
    inv = 1.0 / np.asarray(in_scale, float).ravel()
    o_scale = np.asarray(out_scale, float).ravel()
    o_mean = np.asarray(out_mean, float).ravel()
    ws = [np.array(w, float) for w in weights]
    bs = [np.array(b, float).ravel() for b in biases]
    # first layer: W ((x - m) / s) + b = (W / s) x + (b - W (m / s))
    bs[0] = bs[0] - ws[0] @ (mean * inv)
    ws[0] = ws[0] * inv[None, :]
    for i in range(1, len(ws)):  # each of these takes 2 relu(z)
        ws[i] = 0.5 * ws[i]
    new_skip = None
    if skip is not None:
        s = np.asarray(skip, float) * inv[None, :]
        bs[-1] = bs[-1] - s @ mean
        new_skip = o_scale[:, None] * s
    ws[-1] = o_scale[:, None] * ws[-1]
    bs[-1] = o_scale * bs[-1] + o_mean
    return ws, bs, new_skip


def folded_forward(weights: Sequence, biases: Sequence, inp, ops, skip=None):
    """The network of :func:`folded_layers` on the column ``inp`` with ``ops``: every row's
    products summed as a balanced tree (:func:`uavdyn.model.ops.pairwise_sum`), so in a
    compiled step the additions run side by side instead of in one chain per row."""
    rows = [inp[j] for j in range(inp.shape[0])]
    for w, b in zip(weights[:-1], biases[:-1]):
        h = _tree_affine(w, b, rows)
        rows = [hi + ops.fabs(hi) for hi in h]
    y = _tree_affine(weights[-1], biases[-1], rows)
    if skip is not None:
        x = [inp[j] for j in range(inp.shape[0])]
        y = [yi + si for yi, si in zip(y, _tree_affine(skip, None, x))]
    return ops.stack(*y)


def _tree_affine(w, b, rows: list) -> list:
    """``w @ rows + b`` as one balanced sum per output (zero weights left out)."""
    out = []
    for i in range(w.shape[0]):
        terms = [float(w[i, j]) * rows[j] for j in range(w.shape[1]) if w[i, j] != 0.0]
        if b is not None and b[i] != 0.0:
            terms.append(float(b[i]))
        out.append(pairwise_sum(terms) if terms else 0.0 * rows[0])
    return out
