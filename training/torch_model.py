"""Torch twins of the physics RK4 step and of the correction network, for training.

The physics is NOT re-written here: the force functions of :mod:`uavdyn.model` are evaluated
with a torch ``ops`` namespace (the same pattern as its CasADi/NumPy namespaces), so the torch
hybrid step uses exactly the equations of the CasADi one. States are handled as ``(4, B)``
tensors inside the physics (so ``x[0]`` is the batch of ``u`` values) and ``(B, 4)`` outside.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import torch
from torch import nn

from uavdyn.airframes import param_names
from uavdyn.correction import (
    FORMULATIONS,
    HYPERSOLVER_ORDER,
    N_HIDDEN_LAYERS,
    CorrectionNet,
)
from uavdyn.model import FORCE_MODELS, rigid_body_rates


def _sqrt(a):
    return torch.sqrt(a) if isinstance(a, torch.Tensor) else math.sqrt(a)


TORCH_OPS = SimpleNamespace(
    sqrt=_sqrt, atan2=torch.atan2, exp=torch.exp, sin=torch.sin, cos=torch.cos,
    sign=torch.sign, fabs=torch.abs, fmax=lambda a, b: torch.clamp(a, min=b), pi=math.pi,
    vertcat=lambda *a: torch.stack(torch.broadcast_tensors(*a), dim=0),
)
DTYPE = torch.float64


def torch_rhs(kind: str):
    """``rhs(x (B,4), u (B,2), p (np,)) -> x_dot (B,4)`` from the model's own equations."""
    names = param_names(kind)
    forces = FORCE_MODELS[kind]
    i_mass, i_jy, i_g = (names.index(n) for n in ("mass", "Jy", "gravity"))

    def rhs(x: torch.Tensor, u: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        xt, ut = x.T, u.T
        X, Z, M = forces(xt, ut, p, TORCH_OPS)[:3]
        return rigid_body_rates(xt, X, Z, M, p[i_mass], p[i_jy], p[i_g], False, TORCH_OPS).T

    return rhs


def rk4(rhs, x: torch.Tensor, u: torch.Tensor, p: torch.Tensor, dt,
        extra: torch.Tensor | None = None) -> torch.Tensor:
    """One RK4 step of ``rhs + extra`` (``extra``: (B,4) held over the step, or None)."""
    def f(xx):
        out = rhs(xx, u, p)
        return out if extra is None else out + extra

    k1 = f(x)
    k2 = f(x + dt / 2 * k1)
    k3 = f(x + dt / 2 * k2)
    k4 = f(x + dt * k3)
    return x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


class TorchCorrection(nn.Module):
    """The correction MLP (normalisation folded in) and the hybrid step it defines; mirrors
    :func:`uavdyn.correction.mlp_expression` and :func:`uavdyn.hybrid.hybrid_step`."""

    def __init__(self, kind: str, formulation: str, hidden: int, activation: str,
                 in_mean: np.ndarray, in_scale: np.ndarray, out_scale: np.ndarray,
                 dt: float, seed: int = 0) -> None:
        super().__init__()
        if formulation not in FORMULATIONS:
            raise ValueError(f"unknown formulation '{formulation}'; expected one of "
                             f"{tuple(FORMULATIONS)}")
        if activation not in ("relu", "tanh"):
            raise ValueError(f"unknown activation '{activation}'; expected relu or tanh")
        self.kind, self.formulation, self.activation = kind, formulation, activation
        self.dt = float(dt)
        n_in, n_out = len(FORMULATIONS[formulation][0]), FORMULATIONS[formulation][1]
        gen = torch.Generator().manual_seed(seed)
        sizes = [n_in] + [hidden] * N_HIDDEN_LAYERS + [n_out]
        self.layers = nn.ModuleList()
        for i in range(len(sizes) - 1):
            layer = nn.Linear(sizes[i], sizes[i + 1], dtype=DTYPE)
            with torch.no_grad():
                bound = 1.0 / math.sqrt(sizes[i])
                gain = math.sqrt(2.0) if activation == "relu" else 1.0
                layer.weight.uniform_(-gain * bound * math.sqrt(3), gain * bound * math.sqrt(3),
                                      generator=gen)
                layer.bias.zero_()
                if i == len(sizes) - 2:  # start from the physics-only step
                    layer.weight.zero_()
            self.layers.append(layer)
        self.register_buffer("in_mean", torch.as_tensor(in_mean, dtype=DTYPE))
        self.register_buffer("in_scale", torch.as_tensor(in_scale, dtype=DTYPE))
        self.register_buffer("out_mean", torch.zeros(n_out, dtype=DTYPE))
        self.register_buffer("out_scale", torch.as_tensor(out_scale, dtype=DTYPE))
        self.rhs = torch_rhs(kind)

    def forward(self, inp: torch.Tensor) -> torch.Tensor:
        z = (inp - self.in_mean) / self.in_scale
        for layer in self.layers[:-1]:
            z = layer(z)
            z = torch.relu(z) if self.activation == "relu" else torch.tanh(z)
        return self.layers[-1](z) * self.out_scale + self.out_mean

    def step(self, x: torch.Tensor, u: torch.Tensor, p: torch.Tensor, dt,
             t: torch.Tensor | None = None) -> torch.Tensor:
        """Hybrid step on a batch: ``x (B,4)``, ``u (B,2)``, ``t (B,)`` for ``paper``."""
        if self.formulation == "improved":
            accel = self.forward(torch.cat([x, u], dim=1))
            extra = torch.cat([accel, torch.zeros_like(accel[:, :1])], dim=1)
            return rk4(self.rhs, x, u, p, dt, extra)
        base = rk4(self.rhs, x, u, p, dt)
        if self.formulation == "paper":
            if t is None:
                raise ValueError("the paper formulation needs the absolute time t")
            return base + self.forward(torch.cat([t.reshape(-1, 1), base], dim=1))
        return base + dt**HYPERSOLVER_ORDER * self.forward(torch.cat([x, u], dim=1))

    def physics_step(self, x, u, p, dt) -> torch.Tensor:
        return rk4(self.rhs, x, u, p, dt)

    def export(self, airframe_hash: str, info: dict | None = None) -> CorrectionNet:
        """Frozen weights as a :class:`uavdyn.correction.CorrectionNet` (float64 copies)."""
        def arr(t: torch.Tensor) -> np.ndarray:
            return t.detach().cpu().numpy().astype(float).copy()

        return CorrectionNet(
            formulation=self.formulation, activation=self.activation, kind=self.kind,
            airframe_hash=airframe_hash, dt=self.dt,
            weights=tuple(arr(layer.weight) for layer in self.layers),
            biases=tuple(arr(layer.bias) for layer in self.layers),
            in_mean=arr(self.in_mean), in_scale=arr(self.in_scale),
            out_mean=arr(self.out_mean), out_scale=arr(self.out_scale), info=info or {})

    @classmethod
    def from_net(cls, net: CorrectionNet) -> TorchCorrection:
        """Rebuild a torch module from exported weights (for checks and fine-tuning)."""
        module = cls(net.kind, net.formulation, net.hidden[0], net.activation, net.in_mean,
                     net.in_scale, net.out_scale, net.dt)
        if len(set(net.hidden)) != 1:
            raise ValueError("TorchCorrection expects equal hidden widths")
        with torch.no_grad():
            for layer, w, b in zip(module.layers, net.weights, net.biases):
                layer.weight.copy_(torch.as_tensor(w))
                layer.bias.copy_(torch.as_tensor(b))
            module.out_mean.copy_(torch.as_tensor(net.out_mean))
        return module
