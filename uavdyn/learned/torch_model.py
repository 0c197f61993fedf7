"""Torch twins of the physics RK4 step and of the correction network, for training.

The physics is NOT re-written here: the force functions of :mod:`uavdyn.model` are evaluated
with a torch ``ops`` namespace (the same pattern as its CasADi/NumPy namespaces), so the torch
hybrid step uses exactly the equations of the CasADi one. States are handled as ``(4, B)``
tensors inside the physics (so ``x[0]`` is the batch of ``u`` values) and ``(B, 4)`` outside.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from uavdyn.integrate.tableau import RK4, explicit_rk_step
from uavdyn.learned.envelope import Envelope
from uavdyn.learned.formulations import CorrectionLayout
from uavdyn.learned.formulations import formulation as get_formulation
from uavdyn.learned.mlp import mlp_forward
from uavdyn.learned.weights import N_HIDDEN_LAYERS, CorrectionNet
from uavdyn.model import ModelStructure, make_rhs, torch_ops

DTYPE = torch.float64


def seeded_generator(seed: int, threads: int) -> np.random.Generator:
    """Start a seeded training run: torch's global generator seeded and its thread count set;
    returns the run's NumPy generator (mini-batches), seeded alike."""
    torch.manual_seed(seed)
    torch.set_num_threads(threads)
    return np.random.default_rng(seed)


def torch_rhs(kind: str | ModelStructure):
    """``rhs(x (4,B), u (2,B), p (np,)) -> x_dot (4,B)`` from the model's own equations (a
    kind's default structure, or an airframe's)."""
    return make_rhs(kind, False, torch_ops())


class TorchCorrection(nn.Module):
    """The correction MLP (normalisation folded in) and the hybrid step it defines; mirrors
    :func:`uavdyn.correction.mlp_expression` and :func:`uavdyn.hybrid.hybrid_step`."""

    def __init__(self, kind: str, formulation: str, hidden: int, activation: str,
                 in_mean: np.ndarray, in_scale: np.ndarray, out_scale: np.ndarray,
                 dt: float, seed: int = 0, structure: ModelStructure | None = None,
                 layout: CorrectionLayout | None = None, envelope: Envelope | None = None,
                 linear: bool = False, linear_only: tuple[int, ...] = ()) -> None:
        super().__init__()
        self.form = get_formulation(formulation)
        if activation not in ("relu", "tanh"):
            raise ValueError(f"unknown activation '{activation}'; expected relu or tanh")
        self.kind, self.formulation, self.activation = kind, formulation, activation
        self.dt = float(dt)
        self.layout, self.envelope = layout, envelope
        n_in = layout.n_inputs if layout is not None else self.form.n_in
        n_out = self.form.n_out
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
        # the linear path beside the hidden layers (after them in parameters()), from zero
        self.skip = (nn.Parameter(torch.zeros(n_out, n_in, dtype=DTYPE)) if linear else None)
        # inputs the hidden layers do not see (their first-layer columns held at zero:
        # :meth:`hold_linear_only` after every optimiser step)
        self.linear_only = tuple(int(i) for i in linear_only)
        if self.linear_only and self.skip is None:
            raise ValueError("inputs seen only through the linear path need one "
                             "(linear=True)")
        self.hold_linear_only()
        self.register_buffer("in_mean", torch.as_tensor(in_mean, dtype=DTYPE))
        self.register_buffer("in_scale", torch.as_tensor(in_scale, dtype=DTYPE))
        self.register_buffer("out_mean", torch.zeros(n_out, dtype=DTYPE))
        self.register_buffer("out_scale", torch.as_tensor(out_scale, dtype=DTYPE))
        self.rhs = torch_rhs(structure or (layout.structure if layout is not None
                                           and layout.structure is not None else kind))

    def hold_linear_only(self) -> None:
        """Zero the first hidden layer's weights from the inputs seen only linearly."""
        if self.linear_only:
            with torch.no_grad():
                self.layers[0].weight[:, list(self.linear_only)] = 0.0

    def drop_hidden_gradients(self) -> None:
        """Forget the gradients of the hidden layers and of the output layer's weights, so
        an optimiser step moves only the linear path and the output bias (the linear stage of
        ``SafeConfig.linear_first_epochs``: the output weights start at zero, so the hidden
        layers stay silent until they are released, from their initial weights)."""
        for layer in self.layers[:-1]:
            for param in layer.parameters():
                param.grad = None
        self.layers[-1].weight.grad = None

    def forward(self, inp: torch.Tensor) -> torch.Tensor:
        """The network on a batch ``(B, n_in)`` -> ``(B, n_out)`` (the one MLP forward)."""
        return self._net(inp.T).T

    def _net(self, inp_t: torch.Tensor) -> torch.Tensor:
        return mlp_forward([layer.weight for layer in self.layers],
                           [layer.bias for layer in self.layers], self.in_mean, self.in_scale,
                           self.out_mean, self.out_scale, inp_t, torch_ops(), self.activation,
                           skip=self.skip)

    def step(self, x: torch.Tensor, u: torch.Tensor, p: torch.Tensor, dt,
             t: torch.Tensor | None = None) -> torch.Tensor:
        """Hybrid step on a batch: ``x (B,4)``, ``u (B,2)``, ``t (B,)`` (time since the sortie
        start) for a time-dependent formulation; the formulation's own code."""
        tt = None if t is None else t.reshape(1, -1)
        if isinstance(dt, torch.Tensor) and dt.dim() == 2:  # a (B, 1) step size per sample
            dt = dt.T
        return self.form.step(self.rhs, x.T, u.T, p, dt, self._net, torch_ops(), tt,
                              self.layout).T

    def step_without_network(self, x: torch.Tensor, u: torch.Tensor, p: torch.Tensor, dt
                             ) -> torch.Tensor:
        """:meth:`step` with the network's output zero: the physics the correction is added
        to, on the hybrid's full state (actuator and memory states included)."""
        def silent(inp_t: torch.Tensor) -> torch.Tensor:
            return torch.zeros((len(self.out_scale), inp_t.shape[1]), dtype=inp_t.dtype)
        return self.form.step(self.rhs, x.T, u.T, p, dt, silent, torch_ops(), None,
                              self.layout).T

    def physics_step(self, x, u, p, dt) -> torch.Tensor:
        """The physics-only RK4 step on a batch (same tableau routine as the CasADi step)."""
        xt, ut = x.T, u.T
        return explicit_rk_step(RK4, lambda xx: self.rhs(xx, ut, p), xt, dt).T

    def export(self, airframe_hash: str, info: dict | None = None,
               t_range: tuple[float, float] | None = None) -> CorrectionNet:
        """Frozen weights as a :class:`uavdyn.correction.CorrectionNet` (float64 copies)."""
        def arr(t: torch.Tensor) -> np.ndarray:
            return t.detach().cpu().numpy().astype(float).copy()

        extra = {}
        if self.layout is not None:
            extra = {"n_state": self.layout.n_state, "memory_tau": tuple(self.layout.memory_tau),
                     "n_controls": self.layout.nu,
                     "envelope": self.envelope, "guard": self.layout.guard,
                     "inputs": self.layout.inputs, "output": self.layout.output,
                     "out_bound": (None if self.layout.bound is None
                                   else np.asarray(self.layout.bound, float).copy())}
        return CorrectionNet(
            formulation=self.formulation, activation=self.activation, kind=self.kind,
            airframe_hash=airframe_hash, dt=self.dt, t_range=t_range, **extra,
            weights=tuple(arr(layer.weight) for layer in self.layers),
            biases=tuple(arr(layer.bias) for layer in self.layers),
            in_mean=arr(self.in_mean), in_scale=arr(self.in_scale),
            out_mean=arr(self.out_mean), out_scale=arr(self.out_scale), info=info or {},
            skip=None if self.skip is None else arr(self.skip))

    @classmethod
    def from_net(cls, net: CorrectionNet, structure: ModelStructure | None = None
                 ) -> TorchCorrection:
        """Rebuild a torch module from exported weights (for checks and fine-tuning) on the
        physics ``structure`` (default: the kind's)."""
        layout = None
        if net.formulation == "improved" and (structure is not None or net.n_state != 4
                                              or net.envelope is not None
                                              or net.out_bound is not None
                                              or net.inputs != "state"
                                              or net.output != "acceleration"):
            layout = net.layout(structure)
        module = cls(net.kind, net.formulation, net.hidden[0], net.activation, net.in_mean,
                     net.in_scale, net.out_scale, net.dt, structure=structure, layout=layout,
                     envelope=net.envelope, linear=net.skip is not None)
        if len(set(net.hidden)) != 1:
            raise ValueError("TorchCorrection expects equal hidden widths")
        with torch.no_grad():
            for layer, w, b in zip(module.layers, net.weights, net.biases):
                layer.weight.copy_(torch.as_tensor(w))
                layer.bias.copy_(torch.as_tensor(b))
            module.out_mean.copy_(torch.as_tensor(net.out_mean))
            if net.skip is not None:
                module.skip.copy_(torch.as_tensor(net.skip))
        return module
