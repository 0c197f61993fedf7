"""The torch model's window rollouts as compiled CasADi code, its weights an input.

Training spends its time rolling the hybrid step through windows of a few hundred samples: in
torch every sample is a few hundred small tensor operations, each with its Python and dispatch
overhead, forward and backward. The same step is written once over an ``ops`` namespace
(:mod:`uavdyn.learned.formulations`, :func:`uavdyn.learned.mlp.mlp_forward`), so here it is
built in CasADi with the network's weights and normalisation as symbols, rolled through a
window with ``mapaccum`` and compiled to C with its reverse-mode derivative: one call gives a
window's loss term and its gradient with respect to every weight. Torch keeps the parameters,
Adam and the stability penalty; the gradients agree with torch's autograd to round-off
(``tests/test_safe_twin.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import partial

import casadi as ca
import numpy as np
import scipy.linalg
import torch

from uavdyn.integrate import compile_function, rollout
from uavdyn.integrate.compiler import QUICK_FLAGS
from uavdyn.integrate.start_fit import StartFits, fit_starts, start_fit_function, with_starts
from uavdyn.learned.envelope import GUARDS, gate_of_terms
from uavdyn.learned.mlp import mlp_forward
from uavdyn.learned.safe.data import WindowTensors
from uavdyn.learned.stability import TrimSample
from uavdyn.learned.torch_model import TorchCorrection
from uavdyn.model import CASADI_OPS, make_rhs
from uavdyn.model.equations import as_structure

BODY = 4


@dataclass(frozen=True)
class _Shapes:
    """Where each parameter and buffer sits in the extended parameter vector."""

    n_physics: int
    params: tuple[tuple[int, ...], ...]
    buffers: tuple[int, ...]  # in_mean, in_scale, out_mean, out_scale[, the output bound]

    @property
    def n_theta(self) -> int:
        return int(sum(np.prod(s) for s in self.params))

    @property
    def size(self) -> int:
        return self.n_physics + self.n_theta + sum(self.buffers)


def _unpack(vector, shapes: _Shapes) -> tuple[list, list]:
    """(parameter blocks in ``model.parameters()`` order, buffers) from the symbols."""
    at = shapes.n_physics
    blocks = []
    for shape in shapes.params:
        n = int(np.prod(shape))
        block = vector[at:at + n]
        # torch stores row-major; CasADi reshapes column-major: reshape transposed, transpose
        blocks.append(ca.reshape(block, shape[1], shape[0]).T if len(shape) == 2 else block)
        at += n
    buffers = []
    for n in shapes.buffers:
        buffers.append(vector[at:at + n])
        at += n
    return blocks, buffers


def _gate(inp, ops, terms: tuple, form: str):
    """The envelope's gate with its numbers as symbols (:func:`gate_of_terms`)."""
    return gate_of_terms(inp, terms, ops, form)


class CompiledTwin:
    """Compiled window rollouts of ``model``'s hybrid step (its current weights read at each
    call): :meth:`predict` and :meth:`loss_and_grad` over ``horizon`` samples of step
    ``dt``.

    Raises
    ------
    ValueError
        If the model is not the ``improved`` formulation on a state layout (the safe
        trainer's).
    """

    def __init__(self, model: TorchCorrection, horizon: int, dt: float,
                 state_scale: np.ndarray, growth: np.ndarray):
        if model.formulation != "improved" or model.layout is None:
            raise ValueError("the compiled twin covers the safe trainer's improved step")
        layout = model.layout
        structure = layout.structure or as_structure(model.kind)
        # the envelope's numbers are inputs too: the compiled code depends on the network's
        # shape, the physics structure, the horizon and the step, so it is reused across data
        self._gate_terms = layout.gate is not None and model.envelope is not None
        self.shapes = _Shapes(structure.np, tuple(tuple(q.shape) for q in model.parameters()),
                              tuple(len(b) for b in self._buffers(model)))
        n_physics = structure.np
        self.horizon, self.dt = horizon, float(dt)
        self.state_scale = np.asarray(state_scale, float)
        self.growth = np.asarray(growth, float)
        nz, nu = layout.n_state, layout.nu
        z, u = ca.SX.sym("z", nz), ca.SX.sym("u", nu)
        pe, h = ca.SX.sym("p", self.shapes.size), ca.SX.sym("dt")
        blocks, buffers = _unpack(pe, self.shapes)
        in_mean, in_scale, out_mean, out_scale = buffers[:4]
        rest = buffers[4:]
        if layout.bound is not None:  # the final checks scale it: an input, like the weights
            layout, rest = replace(layout, bound=rest[0]), rest[1:]
        if self._gate_terms:
            form = GUARDS[layout.guard][0]
            layout = replace(layout, gate=partial(_gate, terms=tuple(rest), form=form))

        # the linear path, where there is one, is a parameter of its own among the layers'
        at = [i for i, q in enumerate(model.parameters()) if q is model.skip]
        skip = blocks[at[0]] if at else None
        layers = [b for i, b in enumerate(blocks) if i not in at]

        def net(inp):
            return mlp_forward(layers[0::2], layers[1::2], in_mean, in_scale, out_mean,
                               out_scale, inp, CASADI_OPS, model.activation, skip=skip)

        z_next = model.form.step(make_rhs(structure), z, u,
                                 pe[:n_physics], h, net, CASADI_OPS, None, layout)
        step = ca.Function("twin_step", [z, u, pe, h], [z_next])
        self._step, self._fits = step, {}
        theta = slice(n_physics, n_physics + self.shapes.n_theta)
        sim = rollout(step, horizon, name="twin_rollout")
        z0, U = ca.MX.sym("z0", nz), ca.MX.sym("u", nu, horizon)
        P, Y = ca.MX.sym("p", self.shapes.size), ca.MX.sym("y", BODY, horizon)
        scale, grow = ca.MX.sym("state_scale", BODY), ca.MX.sym("growth", 1, horizon)
        pred = sim(z0, U, P, self.dt)[:BODY, :]
        sq = ((pred - Y) / ca.repmat(scale, 1, horizon)) ** 2
        e = ca.sum2(ca.sum1(sq) / BODY / grow) / horizon
        grad = ca.gradient(e, P)[theta.start:theta.stop]
        # the stability penalty's map Jacobian at a trim (body block) and its derivative
        jac = ca.jacobian(z_next[:BODY], z)[:, :BODY]
        djac = ca.jacobian(ca.vec(jac), pe)[:, theta.start:theta.stop]
        self._jacobian = compile_function(ca.Function("twin_jacobian", [z, u, pe, h],
                                                      [jac, djac]), QUICK_FLAGS)
        self._predict = compile_function(ca.Function("twin_predict", [z0, U, P], [pred]),
                                         QUICK_FLAGS)
        self._grad = compile_function(ca.Function("twin_grad", [z0, U, P, Y, scale, grow],
                                                  [e, grad]), QUICK_FLAGS)
        self._mapped: dict = {}
        self.size = self.shapes.size

    def _buffers(self, model: TorchCorrection) -> list[np.ndarray]:
        """The normalisation, the output bound (where there is one) and the envelope's
        terms (where it gates: :meth:`Envelope.terms`), as they are now."""
        arrays = [b.detach().numpy().ravel() for b in (model.in_mean, model.in_scale,
                                                       model.out_mean, model.out_scale)]
        bound = model.layout.bound
        arrays += [] if bound is None else [np.asarray(bound, float).ravel()]
        return arrays + (list(model.envelope.terms()) if self._gate_terms else [])

    def _shared(self, model: TorchCorrection) -> np.ndarray:
        """The weights (``model.parameters()`` order, row-major) and buffers, as they are."""
        shared = np.concatenate([q.detach().numpy().ravel() for q in model.parameters()]
                                + self._buffers(model))
        if len(shared) != self.size - self.shapes.n_physics:
            raise ValueError("the model's layout changed since its twin was built")
        return shared

    def _extended(self, model: TorchCorrection, p: torch.Tensor) -> np.ndarray:
        """``(size, W)``: each window's physics parameters, then the weights and buffers."""
        p = p.detach().numpy()
        return np.vstack([p.T, np.repeat(self._shared(model)[:, None], len(p), axis=1)])

    def unflatten(self, flat: np.ndarray) -> list[np.ndarray]:
        """A gradient over the weights, one array per ``model.parameters()`` entry."""
        out, at = [], 0
        for shape in self.shapes.params:
            n = int(np.prod(shape))
            out.append(flat[at:at + n].reshape(shape))
            at += n
        return out

    def _map(self, which: str, n: int) -> ca.Function:
        key = (which, n)
        if key not in self._mapped:
            self._mapped[key] = (self._predict if which == "predict" else self._grad).map(n)
        return self._mapped[key]

    def predict(self, model: TorchCorrection, D: WindowTensors) -> np.ndarray:
        """Body states ``(W, horizon, 4)`` of the hybrid step's free run through each
        window."""
        W = D.count
        U = D.u.detach().numpy()[:, :self.horizon].transpose(2, 0, 1).reshape(D.u.shape[2], -1)
        out = self._map("predict", W)(D.z0.detach().numpy().T, U, self._extended(model, D.p))
        return np.asarray(out).reshape(BODY, W, self.horizon).transpose(1, 2, 0)

    def loss_and_grad(self, model: TorchCorrection, D: WindowTensors, pooled_weight: float
                      ) -> tuple[float, np.ndarray]:
        """The training loss of :class:`~uavdyn.learned.safe.scoring.WindowLoss` over the
        windows ``D`` and its gradient over the weights (flat: :meth:`unflatten`)."""
        W = D.count
        U = D.u.detach().numpy()[:, :self.horizon].transpose(2, 0, 1).reshape(D.u.shape[2], -1)
        Y = D.y.detach().numpy()[:, :self.horizon].transpose(2, 0, 1).reshape(BODY, -1)
        e, g = self._map("grad", W)(D.z0.detach().numpy().T, U, self._extended(model, D.p), Y,
                                    self.state_scale, self.growth[None, :self.horizon])
        e, g = np.asarray(e).ravel(), np.asarray(g)
        c = ((1.0 - pooled_weight) * D.weight.detach().numpy() + pooled_weight) / W
        return float(np.sum(c * e)), g @ c

    def fit_starts(self, model: TorchCorrection, D: WindowTensors, noise: np.ndarray,
                   span: int) -> StartFits:
        """The starts of the windows ``D`` where the hybrid step (its current weights) fits
        each window's first ``span`` records best (:func:`uavdyn.integrate.start_fit.fit_starts`;
        ``noise``: ``(W, 4)`` the records' white noise)."""
        if span not in self._fits:
            self._fits[span] = start_fit_function(self._step, span)
        return fit_starts(self._fits[span], D.z0.detach().numpy(), D.u.detach().numpy(),
                          D.y.detach().numpy(), self._extended(model, D.p), self.dt, noise,
                          span)

    def penalty_and_grad(self, model: TorchCorrection, trims: list[TrimSample],
                         targets: list[float], dt: float) -> tuple[float, np.ndarray]:
        """:func:`uavdyn.learned.stability.stability_penalty` and its gradient over the
        weights: ``sigma = ln |lambda_max| / dt`` of the body block of the step's Jacobian at
        each trim; a simple eigenvalue's derivative is ``y^H dJ x / y^H x`` (left and right
        eigenvectors), so ``d sigma = Re(d lambda / lambda) / dt``."""
        shared = self._shared(model)
        total, grad = 0.0, np.zeros(self.shapes.n_theta)
        for trim, target in zip(trims, targets):
            pe = np.concatenate([np.asarray(trim.p, float), shared])
            J, dJ = (np.asarray(a) for a in self._jacobian(trim.z, trim.u, pe, dt))
            lam, left, right = scipy.linalg.eig(J, left=True, right=True)
            i = int(np.argmax(np.abs(lam)))
            excess = math.log(abs(lam[i])) / dt - float(target) if lam[i] != 0 else math.inf
            if not math.isfinite(excess) or excess <= 0:
                continue
            total += excess
            y, x = left[:, i], right[:, i]
            d_lam = (np.outer(y.conj(), x).ravel(order="F") @ dJ) / (y.conj() @ x)
            grad += np.real(d_lam / lam[i]) / dt
        return total, grad


@dataclass(frozen=True)
class FittedStartPredictor:
    """Free runs through the validation windows from the starts each scored network fits
    itself (``SafeConfig.start_fit_s``): the hybrid's counterpart of
    :func:`uavdyn.learned.safe.data.physics_fitted`, so neither is scored from a start the
    other fitted."""

    twin: CompiledTwin
    noise: np.ndarray  # (W, 4) white noise of the records of each validation window
    span: int

    def __call__(self, model: TorchCorrection, V: WindowTensors) -> np.ndarray:
        return self.twin.predict(model, replace(V, z0=self.starts(model, V)))

    def starts(self, model: TorchCorrection, V: WindowTensors) -> torch.Tensor:
        """The start states of the windows ``V`` fitted by ``model`` from their records."""
        if V.count != len(self.noise):
            raise ValueError(f"{V.count} windows but the noise of {len(self.noise)}")
        fits = self.twin.fit_starts(model, V, self.noise, self.span)
        return torch.as_tensor(with_starts(V.z0.detach().numpy(), fits), dtype=V.z0.dtype)
