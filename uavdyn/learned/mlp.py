"""The correction MLP's forward pass, written once against an ``ops`` namespace so CasADi (the
hybrid step), NumPy (checks) and torch (training) evaluate the same function.

Layout: ``z = (input - in_mean) / in_scale``; hidden layers ``act(W z + b)``; a linear output
de-normalised as ``y * out_scale + out_mean``, optionally plus a linear path ``S z`` beside the
hidden layers (``skip``: a correction that is partly a change of the physics' derivatives is
learned there directly). Data are feature-first (``(n_in, batch)``).
"""

from __future__ import annotations

from collections.abc import Sequence

from uavdyn.model.ops import ramp

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
