"""The math namespaces every equation is written against, so one piece of code serves CasADi
(symbolic graphs), NumPy (checks, baselines) and torch (training).

Convention: data are *feature-first* — ``x[i]`` is feature ``i``, a scalar or a row of a batch.
``stack`` builds a column from per-feature scalars/rows, ``concat`` joins blocks of features,
``col`` turns a constant 1-D vector into a column that broadcasts over a batch, ``matmul`` is a
matrix times a feature-first block.
"""

from __future__ import annotations

import math
from functools import cache
from types import SimpleNamespace

import casadi as ca
import numpy as np


def ramp(x, ops):
    """``max(x, 0)`` as ``(x + |x|) / 2``: exact in floating point (``x + |x|`` is ``2x`` or
    ``0``), and ``fabs`` compiles to one instruction where C's ``fmax`` is a library call --
    this runs in every hybrid step (ReLU, the envelope gate)."""
    return 0.5 * (x + ops.fabs(x))

def pairwise_sum(terms: list):
    """Sum of ``terms`` as a balanced tree: in a compiled step its additions run side by side
    instead of in one chain."""
    terms = list(terms)
    while len(terms) > 1:
        terms = [terms[i] + terms[i + 1] if i + 1 < len(terms) else terms[i]
                 for i in range(0, len(terms), 2)]
    return terms[0]


def _ca_col(v):
    return v if isinstance(v, (ca.SX, ca.MX, ca.DM)) else ca.DM(np.asarray(v, float))


def _ca_matmul(w, z):
    return ca.mtimes(_ca_col(w), z)


CASADI_OPS = SimpleNamespace(
    name="casadi", sqrt=ca.sqrt, atan2=ca.atan2, exp=ca.exp, log1p=ca.log1p, sin=ca.sin,
    cos=ca.cos, tanh=ca.tanh, sinh=ca.sinh, asinh=ca.asinh, if_else=ca.if_else, sign=ca.sign,
    fabs=ca.fabs, fmax=ca.fmax, fmin=ca.fmin, pi=ca.pi,
    stack=ca.vertcat, vertcat=ca.vertcat, concat=ca.vertcat, col=_ca_col, matmul=_ca_matmul,
    zeros=lambda rows, like: ca.DM.zeros(rows, like.shape[1]),
)


def _np_stack(*rows):
    return np.array(rows, dtype=float) if all(np.ndim(r) == 0 for r in rows) else \
        np.stack(np.broadcast_arrays(*rows), axis=0)


NUMPY_OPS = SimpleNamespace(
    name="numpy", sqrt=np.sqrt, atan2=np.arctan2, exp=np.exp, log1p=np.log1p, sin=np.sin,
    cos=np.cos, tanh=np.tanh, sinh=np.sinh, asinh=np.arcsinh, if_else=np.where, sign=np.sign,
    fabs=np.abs, fmax=np.maximum, fmin=np.minimum,
    pi=np.pi, stack=_np_stack, vertcat=_np_stack,
    concat=lambda *blocks: np.concatenate([np.atleast_1d(b) for b in blocks], axis=0),
    col=lambda v: np.asarray(v, float).reshape(-1, 1),
    matmul=lambda w, z: np.asarray(w, float) @ z,
    zeros=lambda rows, like: np.zeros((rows,) + np.shape(like)[1:]),
)


@cache
def torch_ops() -> SimpleNamespace:
    """The torch namespace (imports torch on first use: torch is needed only for training)."""
    import torch

    def sqrt(a):
        return torch.sqrt(a) if isinstance(a, torch.Tensor) else math.sqrt(a)

    def stack(*rows):
        rows = [r if isinstance(r, torch.Tensor) else torch.tensor(r, dtype=torch.float64)
                for r in rows]
        return torch.stack(torch.broadcast_tensors(*rows), dim=0)

    def col(v):
        t = v if isinstance(v, torch.Tensor) else torch.as_tensor(np.asarray(v, float))
        return t.reshape(-1, 1)

    def matmul(w, z):
        w = w if isinstance(w, torch.Tensor) else torch.as_tensor(np.asarray(w, float))
        return w @ z

    return SimpleNamespace(
        name="torch", sqrt=sqrt, atan2=torch.atan2, exp=torch.exp, log1p=torch.log1p,
        sin=torch.sin, cos=torch.cos, tanh=torch.tanh, sinh=torch.sinh, asinh=torch.asinh,
        if_else=torch.where, sign=torch.sign, fabs=torch.abs,
        fmax=lambda a, b: torch.clamp(a, min=b) if not isinstance(b, torch.Tensor)
        else torch.maximum(a, b),
        fmin=lambda a, b: torch.clamp(a, max=b) if not isinstance(b, torch.Tensor)
        else torch.minimum(a, b),
        pi=math.pi, stack=stack, vertcat=stack,
        concat=lambda *blocks: torch.cat([b.reshape(1, -1) if b.dim() == 1 else b
                                          for b in blocks], dim=0),
        col=col, matmul=matmul,
        zeros=lambda rows, like: torch.zeros((rows,) + tuple(like.shape[1:]), dtype=like.dtype),
    )
